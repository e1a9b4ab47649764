"""CrossRegression: Choi24's cross-regression pilots (Choi24 s.4.1, eqs. (4)-(7)).

Two independent half-buffers y^A, y^B (the model passes log1p of the radiance), albedo rho and
normal n (N, 3, H, W) each. For buffer A (then the same with A and B swapped):

- variance: var_p = || y^A_p - mean_{q in 3x3(p), q != p, q in the image} y^A_q ||^2 (summed
  over RGB; Choi24 s.4.1 "squared difference ... average of its neighboring pixels");
- centres c on the grid (stride * i, stride * j), i < ceil(H / stride), j < ceil(W / stride);
  windows of window x window pixels q = mirror(c + d), mirror(k) reflecting at the borders
  without repeating the edge (period 2 (n - 1));
- per colour channel k, P = 6 variables (eq. (6), per channel as in the official code):
  x = [1, (y^A_q,k - y^A_c,k) / (sigma_c + sigma_q + 1e-2), rho_q,k - rho_c,k, n_q - n_c (xyz)],
  sigma = sqrt(var);
- weight (eq. (7) + the code's floor): w = exp(-||y^A_q - y^A_c||^2 / (var_c + var_q + 1e-4))
  + 1e-7;
- solve (eq. (4), ridge 1e-3, Cholesky): (X^T W X + 1e-3 I) beta_c,k = X^T W y^B_k;
- reconstruct every pixel p (eq. (5)) from the centres c with |p - c| <= window // 2 on both
  axes (no mirroring: centres in the image), with x and w of p relative to c:
  pilot_a_p,k = max(0, sum_c w(c, p) x(p; c)^T beta_c,k / sum_c w(c, p)).

pilot_a regresses y^B on A's variables (it is a linear function of y^A: Choi24 f~(x^A));
pilot_b regresses y^A on B's. All forms compute in float64 (the 6 x 6 systems are badly
conditioned where the variables are nearly collinear) and return float32.
"""

from __future__ import annotations

import numpy as np

from .spec import Arg, OpSpec, same_nhw

INPUTS = ("y_a", "y_b", "albedo", "normal")


def centre_count(n: int, stride: int) -> int:
    """Number of regression centres along an axis of n pixels: ceil(n / stride)."""
    return -(-n // stride)


def reconstruction_offsets(window: int, stride: int) -> range:
    """Centre-index offsets dj (relative to p // stride) that can cover a pixel p."""
    r = window // 2
    return range(-(r // stride), (r + stride - 1) // stride + 1)


def _check(shapes, attrs) -> None:
    window, stride = attrs["window"], attrs["stride"]
    if window < 3 or window % 2 == 0 or stride < 1 or stride > window // 2 + 1:
        raise ValueError(
            "CrossRegression needs an odd window >= 3 and 1 <= stride <= window // 2 + 1 "
            f"(every pixel covered), got window={window}, stride={stride}"
        )
    same_nhw("CrossRegression", shapes, INPUTS)
    for name, shape in zip(INPUTS, shapes, strict=True):
        if shape[1] != 3:
            raise ValueError(f"CrossRegression: {name} has {shape[1]} channels; expected 3")
    if shapes[0][2] < 2 or shapes[0][3] < 2:
        raise ValueError(
            f"CrossRegression: image {tuple(shapes[0])} is too small to mirror (H, W >= 2)"
        )


def _example_inputs(shape, attrs, rng: np.random.Generator) -> list[np.ndarray]:
    """Two noisy log-radiance buffers of one smooth image with an edge, albedo, unit normals."""
    n, _, h, w = shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    base = 0.6 + 0.3 * np.sin(xx / 3.0 + np.arange(3)[:, None, None]) * np.cos(yy / 4.0)
    base = base + 0.5 * (xx > w / 2)
    y = [np.log1p(base * rng.exponential(1.0, (n, 3, h, w))).astype(np.float32) for _ in range(2)]
    albedo = (0.5 + 0.4 * np.sin(xx / 5.0 + np.arange(3)[:, None, None])) * np.ones((n, 1, 1, 1))
    normal = rng.standard_normal((n, 3, h, w)) * 0.2 + np.array([0, 0, 1.0])[None, :, None, None]
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    return [*y, albedo.astype(np.float32), normal.astype(np.float32)]


SPEC = OpSpec(
    name="CrossRegression",
    doc="Choi24 cross-regression (s.4.1, eqs. 4-7): per colour channel, weighted ridge "
    "regression (P = 6: 1, dy^A/(sigma_c+sigma_q+1e-2), d albedo, d normal xyz; "
    "w = exp(-||dy^A||^2/(var_c+var_q+1e-4)) + 1e-7; + 1e-3 I) of y^B on buffer A's variables at "
    "centres every `stride` pixels over mirrored `window`^2 windows, reconstructed with eq. 5 over "
    "the covering centres and clamped >= 0 -> pilot_a; A and B swapped -> pilot_b",
    inputs=tuple(Arg(name) for name in INPUTS),
    outputs=(Arg("pilot_a"), Arg("pilot_b")),
    attrs=("window", "stride"),
    output_shapes=lambda shapes, attrs: [tuple(shapes[0]), tuple(shapes[0])],
    check=_check,
    example_inputs=_example_inputs,
    default_attrs={"window": 17, "stride": 4},
    example_attrs=({"window": 17, "stride": 4}, {"window": 7, "stride": 2}),
    example_shapes=((1, 3, 13, 17), (2, 3, 20, 9)),
)

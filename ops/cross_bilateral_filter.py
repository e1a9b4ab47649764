"""CrossBilateralFilter: Choi24's spatial filter of the two pilots (Choi24 eqs. (8)-(9)).

Inputs (N, C, H, W): pilot_a, pilot_b, albedo rho, normal n (C = 3 each) and the per-pixel
bandwidths band (N, 5, H, W) = [band_A, band_B, band_rho, band_n, band_p] (the network's
1 / (x^2 + 1e-4)). For centre c and tap i of the window x window window, i = mirror(c + d)
(reflecting at the borders without repeating the edge), r = window // 2:

  m^A_i = exp(-band_A ||f^A_i - f^A_c||^2 - band_rho ||rho_i - rho_c||^2
              - band_n ||n_i - n_c||^2 - band_p (dx^2 + dy^2) / r^2)

(eq. (9) as the official code computes it: one exp, theta_p on the pixel distance, bandwidths
multiplying the squared distances), m^B the same with f^B and band_B. Outputs:

- sum_a (N, 4, H, W) = [sum_i m^A_i f^A_i (3 channels), sum_i m^A_i]; sum_b likewise;
- dsum_a (N, 16, H, W): for each distance k in (colour, albedo, normal, position), 4 channels
  [sum_i m^A_i D_k(i) f^A_i (3), sum_i m^A_i D_k(i)] with D_k the squared distance that band_k
  multiplies; dsum_b likewise. They are what the bandwidth gradient needs:
  d sum_a / d band_k = -dsum_a[k] (the rest of the backward pass is standard ops).

The model divides and blends (eqs. (8), (10)) in standard ops.
"""

from __future__ import annotations

import numpy as np

from .spec import Arg, OpSpec, same_nhw

INPUTS = ("pilot_a", "pilot_b", "albedo", "normal", "band")
BANDS = 5  # band_A, band_B, band_rho, band_n, band_p
DISTANCES = ("colour", "albedo", "normal", "position")  # the blocks of dsum_a / dsum_b


def _check(shapes, attrs) -> None:
    window = attrs["window"]
    if window < 3 or window % 2 == 0:
        raise ValueError(f"CrossBilateralFilter needs an odd window >= 3, got {window}")
    same_nhw("CrossBilateralFilter", shapes, INPUTS)
    for name, shape in zip(INPUTS[:4], shapes[:4], strict=True):
        if shape[1] != 3:
            raise ValueError(f"CrossBilateralFilter: {name} has {shape[1]} channels; expected 3")
    if shapes[4][1] != BANDS:
        raise ValueError(
            f"CrossBilateralFilter: band has {shapes[4][1]} channels; expected {BANDS} "
            "(band_A, band_B, band_albedo, band_normal, band_position)"
        )
    if shapes[0][2] < 2 or shapes[0][3] < 2:
        raise ValueError(
            f"CrossBilateralFilter: image {tuple(shapes[0])} is too small to mirror (H, W >= 2)"
        )


def _output_shapes(shapes, attrs):
    n, _, h, w = shapes[0]
    return [(n, 4, h, w), (n, 4, h, w), (n, 16, h, w), (n, 16, h, w)]


def _example_inputs(shape, attrs, rng: np.random.Generator) -> list[np.ndarray]:
    """Two log-radiance pilots, albedo, unit normals and bandwidths 1 / (x^2 + 1e-4)."""
    n, _, h, w = shape
    pilots = [rng.random((n, 3, h, w), dtype=np.float32) * 2.0 for _ in range(2)]
    albedo = rng.random((n, 3, h, w), dtype=np.float32)
    normal = rng.standard_normal((n, 3, h, w)) + np.array([0, 0, 2.0])[None, :, None, None]
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    x = rng.standard_normal((n, BANDS, h, w)) * 0.7
    band = 1.0 / (x * x + 1e-4)
    band = np.minimum(band, 50.0)  # keep several taps alive so that every sum is exercised
    return [*pilots, albedo, normal.astype(np.float32), band.astype(np.float32)]


SPEC = OpSpec(
    name="CrossBilateralFilter",
    doc="Choi24 eq. 9 (official code): m = exp(-band_A ||d f^A||^2 - band_rho ||d albedo||^2 - "
    "band_n ||d n||^2 - band_p (dx^2+dy^2)/r^2) over mirrored window^2 taps; sum_a = [sum m f^A, "
    "sum m], dsum_a = [sum m D_k f^A, sum m D_k] for k in (colour, albedo, normal, position) "
    "(d sum_a / d band_k = -dsum_a[k]); B likewise with band_B",
    inputs=tuple(Arg(name) for name in INPUTS),
    outputs=(Arg("sum_a"), Arg("sum_b"), Arg("dsum_a"), Arg("dsum_b")),
    attrs=("window",),
    output_shapes=_output_shapes,
    check=_check,
    example_inputs=_example_inputs,
    default_attrs={"window": 11},
    example_attrs=({"window": 11}, {"window": 5}),
    example_shapes=((1, 3, 13, 17), (2, 3, 8, 6)),
)

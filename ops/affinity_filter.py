"""AffinityFilter: a dilated spatial kernel from the affinity of neural features (Isik21 eq. 4, 6).

out[n, :, p] = (c_p image_p + sum_{q != p} w_pq image_q) / (1e-10 + c_p + sum_{q != p} w_pq)
w_pq = exp(-a_p ||f_p - f_q||^2)                                        (Isik21 eq. (4))

q runs over the k x k taps q = p + (i - k//2, j - k//2) * dilation; taps outside the image have
weight 0 (they are left out of both sums). image (N, C, H, W), features f (N, D, H, W),
bandwidth a >= 0 (N, 1, H, W), centre weight c (N, 1, H, W). The kernel size k is a float32
scalar *input* (an odd integer), not an attribute, so that a model exported at k = 13 runs at
another k without re-export (Isik21 3.6; the runtime option `kernel_size`); the dilation is an
int attribute.

`TemporalAffinityFilter` (ops/temporal_affinity_filter.py) is the final step, eq. (7)-(8).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .spec import Arg, OpSpec, Shape, same_nhw

EPS = 1e-10  # Isik21 eq. (6)
EXAMPLE_KERNEL_SIZE = 13  # Isik21 3.5.1: 13 x 13 taps
EXAMPLE_FEATURES = 8  # Isik21: d = 8 affinity features
MAX_KERNEL_SIZE = 63


def kernel_size_value(k: float | np.ndarray, op: str = "AffinityFilter") -> int:
    """The int of a kernel-size input; ValueError unless an odd integer in [1, MAX_KERNEL_SIZE]."""
    value = float(np.asarray(k).reshape(()))
    size = int(round(value))
    if size != value or size < 1 or size % 2 == 0 or size > MAX_KERNEL_SIZE:
        raise ValueError(
            f"{op}: kernel size must be an odd integer in [1, {MAX_KERNEL_SIZE}], got {value:g}"
        )
    return size


def check_guides(op: str, shapes: Sequence[Shape], names: Sequence[str]) -> None:
    """ValueError unless the (N, C, H, W) shapes agree on N, H, W and the guides named after
    the first two (image, features) have 1 channel."""
    same_nhw(op, shapes, names)
    for name, shape in zip(names[2:], shapes[2:], strict=True):
        if shape[1] != 1:
            raise ValueError(f"{op}: {name} has {shape[1]} channels; expected 1")


def _check(shapes, attrs) -> None:
    if attrs["dilation"] < 1:
        raise ValueError(f"AffinityFilter needs dilation >= 1, got {attrs['dilation']}")
    check_guides("AffinityFilter", shapes[:4], ("image", "features", "bandwidth", "centre"))


def example_guides(
    n: int, h: int, w: int, rng: np.random.Generator, d: int = EXAMPLE_FEATURES
) -> list[np.ndarray]:
    """features (N, d, H, W) ~ normal, bandwidth in [0, 0.4), centre in [0.05, 1)."""
    features = rng.standard_normal((n, d, h, w), dtype=np.float32)
    bandwidth = (0.4 * rng.random((n, 1, h, w), dtype=np.float32)).astype(np.float32)
    centre = (0.05 + 0.95 * rng.random((n, 1, h, w), dtype=np.float32)).astype(np.float32)
    return [features, bandwidth, centre]


def _example_inputs(shape, attrs, rng: np.random.Generator) -> list[np.ndarray]:
    """HDR-ish image in [0, 4), the guides of `example_guides`, k = 13 (d = 8 features)."""
    n, _, h, w = shape
    image = (4.0 * rng.random(shape, dtype=np.float32)).astype(np.float32)
    return [image, *example_guides(n, h, w, rng), np.array(EXAMPLE_KERNEL_SIZE, np.float32)]


SPEC = OpSpec(
    name="AffinityFilter",
    doc="out_p = (c_p x_p + sum_{q != p} w_pq x_q) / (1e-10 + c_p + sum_{q != p} w_pq), "
    "w_pq = exp(-a_p ||f_p - f_q||^2), q over k x k taps at the dilation, inside the image "
    "(Isik21 eq. 4, 6); k = the kernel_size input (odd)",
    inputs=(
        Arg("image"),
        Arg("features"),
        Arg("bandwidth"),
        Arg("centre"),
        Arg("kernel_size", 0),
    ),
    outputs=(Arg("output"),),
    attrs=("dilation",),
    output_shapes=lambda shapes, attrs: [tuple(shapes[0])],
    check=_check,
    example_inputs=_example_inputs,
    default_attrs={"dilation": 1},
    example_attrs=({"dilation": 1}, {"dilation": 2}, {"dilation": 4}),
    example_shapes=((1, 3, 13, 17), (2, 1, 8, 6), (1, 3, 30, 41)),
)

"""WeightSharingFilter: Fan21's weight-sharing kernels, several box sizes at once.

For box size s_i = size_min + i * size_step (i < count; odd sizes) and importance map w_i:

    out_i = boxsum_{s_i}(w_i * image) / boxsum_{s_i}(w_i)      (0 where boxsum_{s_i}(w_i) <= 0)

boxsum_s is the sum over the s x s window centred on the pixel, restricted to in-bounds pixels
(zero padding of numerator and denominator). One importance map per size is shared by all the
window's taps: the weight of tap q for pixel p is w_i(q) / sum_window w_i (Fan21). Output block
i holds channels i*C .. i*C + C - 1. Weights are >= 0 (the model feeds exp(...)).

The sizes travel as three int attributes (size_min, size_step, count) because ONNX Runtime
extension ops take no list attributes; `sizes_to_attrs` / `attrs_to_sizes` are the one
conversion, e.g. Fan21's [3, 5, 7, 9, 11, 13] <-> (3, 2, 6).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .spec import Arg, OpSpec, same_nhw

FAN21_SIZES = (3, 5, 7, 9, 11, 13)


def attrs_to_sizes(size_min: int, size_step: int, count: int) -> list[int]:
    """The box sizes [size_min + i * size_step for i < count]; ValueError unless all odd >= 1."""
    if count < 1 or size_min < 1 or size_min % 2 == 0 or size_step < 0 or size_step % 2:
        raise ValueError(
            "WeightSharingFilter needs count >= 1, odd size_min >= 1 and even size_step >= 0, "
            f"got size_min={size_min}, size_step={size_step}, count={count}"
        )
    return [size_min + i * size_step for i in range(count)]


def sizes_to_attrs(sizes: Sequence[int]) -> dict[str, int]:
    """{size_min, size_step, count} for an arithmetic list of odd box sizes; else ValueError."""
    sizes = [int(s) for s in sizes]
    if not sizes:
        raise ValueError("WeightSharingFilter needs at least one box size")
    step = sizes[1] - sizes[0] if len(sizes) > 1 else 2
    attrs = {"size_min": sizes[0], "size_step": step, "count": len(sizes)}
    if sizes != attrs_to_sizes(**attrs):
        raise ValueError(
            f"box sizes must be odd, >= 1 and evenly spaced (s0 + i*step), got {sizes}"
        )
    return attrs


def _check(shapes, attrs) -> None:
    attrs_to_sizes(attrs["size_min"], attrs["size_step"], attrs["count"])
    same_nhw("WeightSharingFilter", shapes, ("image", "weights"))
    if shapes[1][1] != attrs["count"]:
        raise ValueError(
            f"WeightSharingFilter: weights have {shapes[1][1]} channels; expected count = "
            f"{attrs['count']} (one importance map per box size)"
        )


def _output_shapes(shapes, attrs):
    n, c, h, w = shapes[0]
    return [(n, attrs["count"] * c, h, w)]


def _example_inputs(shape, attrs, rng: np.random.Generator) -> list[np.ndarray]:
    """image (N, C, H, W) in [0, 1) and importance maps exp(2 * normal) > 0 (N, count, H, W)."""
    n, _, h, w = shape
    image = rng.random(shape, dtype=np.float32)
    weights = np.exp(2.0 * rng.standard_normal((n, attrs["count"], h, w), dtype=np.float32))
    return [image, weights.astype(np.float32)]


SPEC = OpSpec(
    name="WeightSharingFilter",
    doc="out[:, i*C:(i+1)*C] = boxsum_s(w_i * image) / boxsum_s(w_i) (0 where boxsum_s(w_i) <= 0),"
    " s = size_min + i*size_step, zero-padded s x s boxes (Fan21 weight-sharing kernels)",
    inputs=(Arg("image"), Arg("weights")),
    outputs=(Arg("output"),),
    attrs=("size_min", "size_step", "count"),
    output_shapes=_output_shapes,
    check=_check,
    example_inputs=_example_inputs,
    default_attrs=sizes_to_attrs(FAN21_SIZES),
    example_attrs=(sizes_to_attrs(FAN21_SIZES), sizes_to_attrs([1, 5]), sizes_to_attrs([9])),
)

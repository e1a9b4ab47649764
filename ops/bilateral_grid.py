"""BilateralGrid: splat an image into a guide-driven bilateral grid and slice it back (Meng20).

One grid of Gh x Gw x D cells, Gh = ceil(H / s), Gw = ceil(W / s) (Meng20 eq. (8); the official
code truncates, H / s, which leaves the last rows and columns of a size not divisible by s
without a covering cell; the ceiling covers every pixel). Pixel (x, y) with guide value g sits at

    p = ((x + 0.5) / s, (y + 0.5) / s, (clamp(g, 0, 255) + 0.5) * D / 256)    (Meng20 eq. (12))

(the official kernels' coordinates: cell k of an axis has its centre at k + 0.5; the guide range
256 / D per depth cell is the official `sr`, D = 64, 32, 16 for s = 4, 8, 16). The tent weight
of pixel j for cell q is the product over the three axes of

    T(u) = max(1 - sqrt(u^2 + 1e-7), 0),   u = p_axis - (q_axis + 0.5)        (Meng20 eq. (9))

(the sqrt(u^2 + eps) replaces |u| so that T has a gradient everywhere; eps = 1e-7 as in the
paper's text, the official CUDA uses 1e-8). A pixel touches the 2 x 2 x 2 cells around it
(T = 0 farther away); cells outside the grid are dropped.

    splat:  M(q) = sum_j T_qj image(j) / sum_j T_qj   where W(q) = sum_j T_qj > 0, else 0
                                                                     (Meng20 eqs. (10)-(11))
    slice:  out(j) = sum_{q: W(q) > 0} T_qj M(q) / sum_{q: W(q) > 0} T_qj   (0 if no such q)
                                                                     (Meng20 eq. (13))

A cell counts as non-empty when its shared weight sum W(q) is positive (the official kernel tests
each channel's value > 0 instead, which also drops cells whose average is 0 or negative). The
guide is clamped to [0, 255] first (GuideNet's sigmoid x 255 stays inside; the clamp keeps every
pixel's own cell non-empty, so the slice never divides by zero for finite inputs).

Slicing reuses the splat weights: a pixel reads only cells it splatted into, so the output is
continuous in the guide (a cell leaving a pixel's support has weight -> 0 there).
"""

from __future__ import annotations

import numpy as np

from .spec import Arg, OpSpec, same_nhw

GUIDE_MAX = 255.0  # guides are clamped to [0, GUIDE_MAX] (Meng20: "the range of the guide")
GUIDE_RANGE = 256.0  # depth cell k covers guides [k, k + 1) * GUIDE_RANGE / D (official `sr`)
TENT_EPS = 1e-7  # T(u) = max(1 - sqrt(u^2 + TENT_EPS), 0) (Meng20 s.4.2)

# Meng20's three grids (s, D): (eta_xy, eta_d) = (4, 4), (8, 8), (16, 16) with D = 256 / eta_d
MENG20_GRIDS = ((4, 64), (8, 32), (16, 16))


def grid_shape(h: int, w: int, cell_size: int, grid_depth: int) -> tuple[int, int, int]:
    """(Gh, Gw, D) = (ceil(H / s), ceil(W / s), D) (Meng20 eq. (8), ceiling)."""
    return -(-h // cell_size), -(-w // cell_size), grid_depth


def _check(shapes, attrs) -> None:
    s, d = attrs["cell_size"], attrs["grid_depth"]
    if s < 1 or d < 1:
        raise ValueError(f"BilateralGrid needs cell_size >= 1 and grid_depth >= 1, got {s}, {d}")
    same_nhw("BilateralGrid", shapes, ("image", "guide"))
    if shapes[1][1] != 1:
        raise ValueError(
            f"BilateralGrid: guide has {shapes[1][1]} channels; expected 1 (one guide per grid)"
        )


def _example_inputs(shape, attrs, rng: np.random.Generator) -> list[np.ndarray]:
    """HDR image (N, C, H, W) in [0, 4) and a guide (N, 1, H, W) in [0, 255], smooth plus noise
    (pixels of a neighbourhood share some depth cells and miss others: empty cells occur)."""
    n, _, h, w = shape
    image = 4.0 * rng.random(shape, dtype=np.float32)
    ys, xs = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    smooth = 127.5 + 100.0 * np.sin(0.3 * xs + 0.2 * ys)
    guide = smooth[None, None] + 10.0 * rng.standard_normal((n, 1, h, w))
    return [image, np.clip(guide, 0.0, GUIDE_MAX).astype(np.float32)]


SPEC = OpSpec(
    name="BilateralGrid",
    doc="Splat image into a ceil(H/s) x ceil(W/s) x D bilateral grid at ((x+.5)/s, (y+.5)/s, "
    "(clamp(guide,0,255)+.5)*D/256) with tent weights max(1-sqrt(u^2+1e-7),0) per axis, "
    "normalised by the weight sum; slice back trilinearly, renormalised over cells with a "
    "positive weight sum (Meng20 eqs. 8-13)",
    inputs=(Arg("image"), Arg("guide")),
    outputs=(Arg("output"),),
    attrs=("cell_size", "grid_depth"),
    output_shapes=lambda shapes, attrs: [tuple(shapes[0])],
    check=_check,
    example_inputs=_example_inputs,
    default_attrs={"cell_size": 4, "grid_depth": 64},
    example_attrs=(
        {"cell_size": 4, "grid_depth": 64},
        {"cell_size": 8, "grid_depth": 32},
        {"cell_size": 16, "grid_depth": 16},
        {"cell_size": 3, "grid_depth": 10},  # odd s, D not dividing 256
    ),
)

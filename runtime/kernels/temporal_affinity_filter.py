"""TemporalAffinityFilter as a fast kernel (Isik21 eq. (7)-(8)); defined in
rtdenoise.ops.temporal_affinity_filter.

AffinityFilter's row loops (runtime.kernels.affinity_filter) twice into the same sums: the
spatial taps with the centre weight, then the temporal taps over the warped previous output
(dilation 1, features compared with the warped previous features, the validity as mask),
then one joint normalisation.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from rtdenoise.ops.affinity_filter import kernel_size_value

from .affinity_filter import TILE, affinity_taps, normalise, spatial_sums
from .fast_kernel import fast_kernel
from .nonfinite import nan_on_nonfinite


@njit(parallel=True, cache=True, fastmath=True, error_model="numpy")
def _temporal_affinity_filter_nb(
    image, features, bandwidth, centre, previous, previous_features, temporal_bandwidth,
    valid, out, k, kt, d,
):  # fmt: skip
    n_img, h, w = image.shape[0], image.shape[2], image.shape[3]
    tiles = -(-w // TILE)
    for unit in prange(n_img * h * tiles):
        u = np.int64(unit)  # the parfor index is unsigned: int64 keeps the arithmetic integer
        n = u // (h * tiles)
        y = (u // tiles) % h
        tile = u % tiles
        xa, xb = tile * TILE, min(w, (tile + 1) * TILE)
        # Isik21 eq. (4), the K-th spatial kernel (the mask is not read there)
        num, den, dist, weight = spatial_sums(
            image, features, bandwidth, centre, valid[n, 0], n, y, xa, xb, k, d
        )
        affinity_taps(  # eq. (7), the temporal kernel: no centre weight, masked
            num, den, features[n], temporal_bandwidth[n, 0, y], previous[n],
            previous_features[n], valid[n, 0], y, xa, xb, kt, 1, False, True, dist, weight,
        )  # fmt: skip
        normalise(out[n], num, den, y, xa, xb)  # eq. (8): normalised jointly


@fast_kernel("TemporalAffinityFilter")
@nan_on_nonfinite(10)
def temporal_affinity_filter(
    image: np.ndarray,
    features: np.ndarray,
    bandwidth: np.ndarray,
    centre: np.ndarray,
    previous: np.ndarray,
    previous_features: np.ndarray,
    temporal_bandwidth: np.ndarray,
    valid: np.ndarray,
    kernel_size: np.ndarray,
    temporal_size: np.ndarray,
    out: np.ndarray,
    dilation: int,
) -> None:
    """The inputs of rtdenoise.ops.temporal_affinity_filter -> out (N, C, H, W)."""
    op = "TemporalAffinityFilter"
    k = kernel_size_value(kernel_size, op)
    kt = kernel_size_value(temporal_size, op)
    _temporal_affinity_filter_nb(
        image, features, bandwidth, centre, previous, previous_features, temporal_bandwidth,
        valid, out, k, kt, dilation,
    )  # fmt: skip

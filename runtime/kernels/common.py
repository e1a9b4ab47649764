"""numba row helpers shared by the kernels (no torch: runtime/ must run without it).

The exponential: numba has no SVML here (libm `exp` is scalar, ~9x slower than a polynomial
that vectorises), so kernels that need exp(v) for v <= 0 split v = k ln2 + f, |f| <= ln2 / 2,
evaluate exp(f) by its degree-6 Taylor polynomial (relative error < 5e-7 in all) and multiply
by 2^k with an integer add to the exponent bits: `exp_parts` (one element: exp(f) and k << 23) and
`times_pow2` (the integer pass over a row, kept separate so that both loops vectorise);
`exp_nonpositive` is the row form of the first step. `exp_neg` is the whole exponential of one
element, 2^k made by reinterpreting the bits (k + 127) << 23 as a float32 (`bits_to_float32`,
an LLVM bitcast), for loops that fuse the exponential with other work. `exp_row` (base 2,
one row in one pass) serves the cross-bilateral filter.
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

LOG2E = np.float32(1.4426950408889634)
LN2_HI = np.float32(0.693145751953125)  # ln 2 split in two for an exact k * ln2_hi
LN2_LO = np.float32(1.428606765330187e-06)
EXP_MIN = np.float32(-80.0)  # exp(-80) ~ 1.8e-35: 2^k * p stays a normal float32


@njit(cache=True, fastmath=True)
def add_into(dst, a):
    """dst += a, element-wise over a contiguous float32 row (vectorises)."""
    for x in range(dst.shape[0]):
        dst[x] += a[x]


@njit(cache=True, fastmath=True)
def exp_parts(v):
    """(exp(f), k << 23) with max(v, -80) = k ln2 + f, |f| <= ln2 / 2, for v <= 0:
    exp(v) = exp(f) * 2^k (`times_pow2`). Below -80 the argument is clamped."""
    v = max(v, EXP_MIN)
    k = np.floor(v * LOG2E + np.float32(0.5))
    f = v - k * LN2_HI - k * LN2_LO
    p = np.float32(0.0013888889) * f + np.float32(0.008333333)
    p = p * f + np.float32(0.041666664)
    p = p * f + np.float32(0.16666666)
    p = p * f + np.float32(0.5)
    p = p * f + np.float32(1.0)
    return p * f + np.float32(1.0), np.int32(k) << np.int32(23)


@njit(cache=True, fastmath=True)
def exp_nonpositive(out, bits, a, m):
    """out, bits = exp_parts(a - m) over a row (a <= m); then `times_pow2(out, bits)`."""
    for x in range(out.shape[0]):
        out[x], bits[x] = exp_parts(a[x] - m[x])


@njit(cache=True, fastmath=True)
def times_pow2(out, bits):
    """out *= 2^k, given bits = k << 23 and out in [0.5, 2): an integer add to the exponent."""
    ob = out.view(np.int32)
    for x in range(out.shape[0]):
        ob[x] += bits[x]


@intrinsic
def bits_to_float32(typingctx, bits):
    """The float32 whose bit pattern is the int32 `bits` (an LLVM bitcast: no memory)."""
    if bits != types.int32:
        return None

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.FloatType())

    return types.float32(types.int32), codegen


@njit(cache=True, fastmath=True)
def exp_neg(v):
    """exp(v) for v <= 0 (relative error < 2e-7; below -80 the argument is clamped)."""
    p, bits = exp_parts(v)
    return p * bits_to_float32(np.int32(bits + np.int32(127 << 23)))


# 2^f = exp(f ln 2) on [-1/2, 1/2]: Taylor to degree 6, relative error < 2e-7
_P = (1.0, 0.6931472, 0.2402265, 0.05550411, 0.009618129, 0.001333355, 0.0001540353)


@njit(cache=True, fastmath=True)
def exp_row(dst, arg):
    """dst = exp(arg) for arg <= 0 over a contiguous float32 row, in a loop LLVM vectorises
    (numba has no vector libm here): 2^k (k = round(arg log2 e)) from the exponent bits, 2^f
    from a polynomial. Arguments below -87 give ~1e-38 instead of 0 (negligible as weights)."""
    bits = dst.view(np.int32)
    for x in range(dst.shape[0]):
        t = max(arg[x] * np.float32(1.442695), np.float32(-126.0))
        k = np.floor(t + np.float32(0.5))
        f = t - k
        p = np.float32(_P[6])
        p = p * f + np.float32(_P[5])
        p = p * f + np.float32(_P[4])
        p = p * f + np.float32(_P[3])
        p = p * f + np.float32(_P[2])
        p = p * f + np.float32(_P[1])
        p = p * f + np.float32(_P[0])
        bits[x] = (np.int32(k) + np.int32(127)) << np.int32(23)
        dst[x] = dst[x] * p

/* What the kernels of rtdenoise_ops share: the row helpers of runtime/kernels/common.py and
 * friends (numba's max and min, the polynomial exponential, the finiteness test) and the
 * spec-check helpers. Included by kernels.cpp (ops without fastmath on the numba side:
 * exact float32, no fused multiply-adds) and filters.cpp (the fastmath ones). */
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include "kernels.h"

/* On x86-64 Linux each row worker is compiled three times, for the wheel's x86-64 baseline,
 * x86-64-v3 (AVX2, FMA) and x86-64-v4 (AVX-512), and the loader picks one for the CPU
 * (GCC's target_clones, an ifunc). */
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__linux__) && \
    !defined(RTD_NO_CLONES)
#define RTD_CLONES __attribute__((target_clones("default", "arch=x86-64-v3", "arch=x86-64-v4")))
#else
#define RTD_CLONES
#endif

#define RESTRICT __restrict__

/* The row helpers are inlined into each clone of the row worker that calls them (an
 * out-of-line helper is compiled once, for the x86-64 baseline: measured, AffinityFilter
 * then ran at 0.55x numba's speed at 320x240). */
#if defined(__GNUC__)
#define RTD_INLINE inline __attribute__((always_inline))
#else
#define RTD_INLINE inline
#endif

namespace rtd {
namespace detail {
namespace {  // each file its own copy, compiled with its own contraction setting


inline float max_like_numba(float acc, float v) { return v > acc ? v : acc; }  // numba's max(acc, v)
inline float min_like_numba(float acc, float v) { return v < acc ? v : acc; }  // numba's min(acc, v)

/* v clamped to [0, last] by selects (no branch); NaN lands on 0 (it compares false). */
inline float clamped(float v, float last) {
    v = v > 0.0f ? v : 0.0f;
    return v < last ? v : last;
}

inline float bits_to_float(int32_t bits) {
    float f;
    std::memcpy(&f, &bits, sizeof f);
    return f;
}

inline constexpr float LOG2E = 1.4426950408889634f;
inline constexpr float LN2_HI = 0.693145751953125f;
inline constexpr float LN2_LO = 1.428606765330187e-06f;
inline constexpr float EXP_MIN = -80.0f;

/* kernels/common.py exp_parts: (exp(f), k << 23) with max(v, -80) = k ln2 + f, v <= 0. The
 * floor is spelled with a truncation and a subtraction of the bits of 1.0 (the argument lies
 * in [-115.5, 0.5]): GCC vectorises neither floorf on SSE2 nor a select here on AVX2. */
inline float exp_parts(float v, int32_t &bits) {
    v = max_like_numba(v, EXP_MIN);
    float t = v * LOG2E + 0.5f;
    float k = static_cast<float>(static_cast<int32_t>(t));
    k -= bits_to_float(-static_cast<int32_t>(k > t) & 0x3f800000);  // 1 where it truncated up
    float f = v - k * LN2_HI - k * LN2_LO;
    float p = 0.0013888889f * f + 0.008333333f;
    p = p * f + 0.041666664f;
    p = p * f + 0.16666666f;
    p = p * f + 0.5f;
    p = p * f + 1.0f;
    bits = static_cast<int32_t>(static_cast<uint32_t>(static_cast<int32_t>(k)) << 23);
    return p * f + 1.0f;
}

/* kernels/common.py exp_neg: exp(v) for v <= 0. */
inline float exp_neg(float v) {
    int32_t bits;
    float p = exp_parts(v, bits);
    return p * bits_to_float(bits + (127 << 23));
}

/* Bit 31 set where v is NaN or +-Inf (all exponent bits set: adding one to the exponent
 * carries out of it), in integer arithmetic that vectorises. */
inline uint32_t nonfinite_bit(float v) {
    uint32_t b;
    std::memcpy(&b, &v, sizeof b);
    return ((b & 0x7f800000u) + 0x00800000u) & 0x80000000u;
}

inline bool all_finite(const float *RESTRICT a, int64_t n) {
    uint32_t bad = 0;
    for (int64_t i = 0; i < n; ++i) bad |= nonfinite_bit(a[i]);
    return !bad;
}

/* acc[x] = max(acc[x], v[x]) as numba's max (v > acc ? v : acc). */
inline void max_into(float *RESTRICT acc, const float *RESTRICT v, int64_t w) {
    for (int64_t x = 0; x < w; ++x) acc[x] = max_like_numba(acc[x], v[x]);
}

inline std::string fmt_shape(const Tensor &t) {
    std::string s = "(";
    for (int d = 0; d < t.rank; ++d) s += (d ? ", " : "") + std::to_string(t.dims[d]);
    return s + (t.rank == 1 ? ",)" : ")");
}

inline std::string same_nhw(const char *op, const Tensor *in, const char *const *names, int count) {
    const Tensor &a = in[0];
    for (int i = 1; i < count; ++i) {
        const Tensor &b = in[i];
        if (b.dims[0] != a.dims[0] || b.dims[2] != a.dims[2] || b.dims[3] != a.dims[3])
            return std::string(op) + ": " + names[i] + " has shape " + fmt_shape(b) +
                   "; expected N, H, W = " + std::to_string(a.dims[0]) + ", " +
                   std::to_string(a.dims[2]) + ", " + std::to_string(a.dims[3]) + " like " +
                   names[0];
    }
    return "";
}

inline void copy_shape(const Tensor &t, Shape &s) {
    s.rank = t.rank;
    for (int d = 0; d < t.rank; ++d) s.dims[d] = t.dims[d];
}

inline void set_shape(Shape &s, int64_t n, int64_t c, int64_t h, int64_t w) {
    s.rank = 4;
    s.dims[0] = n, s.dims[1] = c, s.dims[2] = h, s.dims[3] = w;
}

inline constexpr int R4[] = {4, 4, 4, 4, 4, 4, 4, 4};

}  // namespace
}  // namespace detail
}  // namespace rtd

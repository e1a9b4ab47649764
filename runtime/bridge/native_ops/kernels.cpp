/* Forward kernels of rtdenoise_ops, each the arithmetic of its numba kernel
 * (runtime/kernels/<op>.py) in the same loop order and in float32, so that the two agree to
 * the bit or within rounding (the fastmath numba kernels may fuse a multiply-add where this
 * file, built with -ffp-contract=off, does not); Reproject and TemporalAccumulation, built
 * without fastmath on the numba side, agree to the bit. Row loops are plain contiguous loops
 * over restrict pointers that the compiler vectorises; on x86-64 Linux each row worker is
 * also compiled for x86-64-v3 (AVX2) and picked at load time (`target_clones`), so the
 * default build stays safe for any x86-64 wheel.
 *
 * Non-finite inputs: KernelFusion checks its logits before and its output after and fills
 * the output with NaN, as its numba driver (`nan_on_nonfinite`) does; elsewhere NaN and Inf
 * go through IEEE arithmetic (the numba kernels give an unspecified value there, the
 * runtime's input guard keeps them out of the graph).
 */

#include "kernels.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <exception>
#include <string>
#include <thread>
#include <vector>

#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__linux__) && \
    !defined(RTD_NO_CLONES)
#define RTD_CLONES __attribute__((target_clones("default", "arch=x86-64-v3")))
#else
#define RTD_CLONES
#endif

#define RESTRICT __restrict__

namespace rtd {

/* ------------------------------------------------------------------ threads */

void parallel_rows(int64_t rows, int threads, void (*fn)(void *, int64_t, int64_t), void *ctx) {
    if (rows <= 0) return;
    const int64_t team = std::max<int64_t>(1, std::min<int64_t>(threads, rows));
    if (team == 1) {
        fn(ctx, 0, rows);
        return;
    }
    auto bounds = [&](int64_t t) { return rows * t / team; };
    std::vector<std::exception_ptr> errors(static_cast<size_t>(team));
    auto chunk = [&](int64_t t, int64_t begin, int64_t end) {
        try {  // nothing may leave a thread (std::terminate): rethrown on the caller's below
            fn(ctx, begin, end);
        } catch (...) {
            errors[static_cast<size_t>(t)] = std::current_exception();
        }
    };
    std::vector<std::thread> workers;
    int64_t started = 0;  // workers 1..started run chunks 1..started
    try {
        workers.reserve(static_cast<size_t>(team - 1));
        for (int64_t t = 1; t < team; ++t) {
            workers.emplace_back(chunk, t, bounds(t), bounds(t + 1));
            ++started;
        }
    } catch (...) {  // no more threads to be had: the caller runs the chunks left
        chunk(team - 1, bounds(started + 1), rows);
    }
    chunk(0, 0, bounds(1));
    for (auto &w : workers) w.join();
    for (auto &e : errors)
        if (e) std::rethrow_exception(e);
}

/* ------------------------------------------------------------------ helpers */

namespace {

inline float max_like_numba(float acc, float v) { return v > acc ? v : acc; }  // numba's max(acc, v)
inline float min_like_numba(float acc, float v) { return v < acc ? v : acc; }  // numba's min(acc, v)

inline float bits_to_float(int32_t bits) {
    float f;
    std::memcpy(&f, &bits, sizeof f);
    return f;
}

constexpr float LOG2E = 1.4426950408889634f;
constexpr float LN2_HI = 0.693145751953125f;
constexpr float LN2_LO = 1.428606765330187e-06f;
constexpr float EXP_MIN = -80.0f;

/* kernels/common.py exp_parts: (exp(f), k << 23) with max(v, -80) = k ln2 + f, v <= 0. The
 * floor is spelled with a truncation (the argument lies in [-115.5, 0.5]) so that the loop
 * vectorises without SSE4.1. */
inline float exp_parts(float v, int32_t &bits) {
    v = max_like_numba(v, EXP_MIN);
    float t = v * LOG2E + 0.5f;
    float k = static_cast<float>(static_cast<int32_t>(t));
    k = k > t ? k - 1.0f : k;
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

inline bool finite(float v) {
    uint32_t b;
    std::memcpy(&b, &v, sizeof b);
    return (b & 0x7f800000u) != 0x7f800000u;
}

bool all_finite(const float *RESTRICT a, int64_t n) {
    int bad = 0;
    for (int64_t i = 0; i < n; ++i) bad |= !finite(a[i]);
    return !bad;
}

std::string fmt_shape(const Tensor &t) {
    std::string s = "(";
    for (int d = 0; d < t.rank; ++d) s += (d ? ", " : "") + std::to_string(t.dims[d]);
    return s + (t.rank == 1 ? ",)" : ")");
}

std::string same_nhw(const char *op, const Tensor *in, const char *const *names, int count) {
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

void copy_shape(const Tensor &t, Shape &s) {
    s.rank = t.rank;
    for (int d = 0; d < t.rank; ++d) s.dims[d] = t.dims[d];
}

void set_shape(Shape &s, int64_t n, int64_t c, int64_t h, int64_t w) {
    s.rank = 4;
    s.dims[0] = n, s.dims[1] = c, s.dims[2] = h, s.dims[3] = w;
}

constexpr int R4[] = {4, 4, 4, 4, 4, 4, 4, 4};

/* ------------------------------------------------------------------ KernelApply */

std::string kernel_check(const char *op, const char *kernel, const Tensor *in, const int64_t *attrs) {
    int64_t k = attrs[0], d = attrs[1];
    if (k < 1 || k % 2 == 0 || d < 1)
        return std::string(op) + " needs odd kernel_size and dilation >= 1, got " +
               std::to_string(k) + ", " + std::to_string(d);
    const char *names[] = {"image", kernel};
    std::string e = same_nhw(op, in, names, 2);
    if (!e.empty()) return e;
    if (in[1].dims[1] != k * k)
        return std::string(op) + ": " + kernel + " has " + std::to_string(in[1].dims[1]) +
               " channels; expected kernel_size^2 = " + std::to_string(k * k);
    return "";
}

std::string kernel_apply_shapes(const Tensor *in, const int64_t *attrs, Shape *out) {
    std::string e = kernel_check("KernelApply", "kernel", in, attrs);
    if (e.empty()) copy_shape(in[0], out[0]);
    return e;
}

std::string softmax_kernel_apply_shapes(const Tensor *in, const int64_t *attrs, Shape *out) {
    std::string e = kernel_check("SoftmaxKernelApply", "logits", in, attrs);
    if (e.empty()) copy_shape(in[0], out[0]);
    return e;
}

/* dst[p + x] = src[x]; dst[:p] = src[0]; dst[p + w:] = src[w - 1]. */
inline void pad_row(const float *RESTRICT src, float *RESTRICT dst, int64_t p, int64_t w) {
    const float left = src[0], right = src[w - 1];
    for (int64_t x = 0; x < p; ++x) dst[x] = left;
    for (int64_t x = 0; x < w; ++x) dst[p + x] = src[x];
    for (int64_t x = p + w; x < w + 2 * p; ++x) dst[x] = right;
}

inline void fma_row(float *RESTRICT acc, const float *RESTRICT wt, const float *RESTRICT src,
                    int64_t w) {
    for (int64_t x = 0; x < w; ++x) acc[x] += wt[x] * src[x];
}

inline void fma2_row(float *RESTRICT acc, const float *RESTRICT w0, const float *RESTRICT w1,
                     const float *RESTRICT s0, const float *RESTRICT s1, int64_t w) {
    for (int64_t x = 0; x < w; ++x) acc[x] += w0[x] * s0[x] + w1[x] * s1[x];
}

struct FilterArgs {  // an image (N, C, H, W) filtered with per-pixel k x k weights
    const float *image;
    const float *weights;  // (N, k*k, H, W): a kernel or logits
    float *out;
    int64_t n_ch, h, w, k, d;
};

/* The source rows for kernel row i of output row (n, y), edge-replicated. */
inline void pad_source_rows(const FilterArgs &a, int64_t n, int64_t y, int64_t i, float *padded) {
    const int64_t p = (a.k / 2) * a.d, wp = a.w + 2 * p;
    int64_t yy = std::min(std::max(y + (i - a.k / 2) * a.d, int64_t(0)), a.h - 1);
    for (int64_t c = 0; c < a.n_ch; ++c)
        pad_row(a.image + ((n * a.n_ch + c) * a.h + yy) * a.w, padded + c * wp, p, a.w);
}

RTD_CLONES void kernel_apply_rows(const FilterArgs &a, int64_t begin, int64_t end) {
    const int64_t k = a.k, d = a.d, w = a.w, h = a.h, kk = k * k;
    const int64_t wp = w + 2 * (k / 2) * d;
    std::vector<float> buffer(static_cast<size_t>(a.n_ch * wp));
    float *padded = buffer.data();
    for (int64_t row = begin; row < end; ++row) {
        const int64_t n = row / h, y = row - n * h;
        float *out = a.out + (n * a.n_ch * h + y) * w;  // channel c at out + c h w
        for (int64_t c = 0; c < a.n_ch; ++c) std::fill(out + c * h * w, out + c * h * w + w, 0.0f);
        for (int64_t i = 0; i < k; ++i) {
            pad_source_rows(a, n, y, i, padded);
            const int64_t t0 = i * k;
            for (int64_t j = 0; j + 1 < k; j += 2) {
                const float *w0 = a.weights + ((n * kk + t0 + j) * h + y) * w;
                const float *w1 = w0 + h * w;
                for (int64_t c = 0; c < a.n_ch; ++c)
                    fma2_row(out + c * h * w, w0, w1, padded + c * wp + j * d,
                             padded + c * wp + (j + 1) * d, w);
            }
            if (k % 2 == 1) {
                const float *wt = a.weights + ((n * kk + t0 + k - 1) * h + y) * w;
                for (int64_t c = 0; c < a.n_ch; ++c)
                    fma_row(out + c * h * w, wt, padded + c * wp + (k - 1) * d, w);
            }
        }
    }
}

FilterArgs filter_args(const Tensor *in, Tensor *out, const int64_t *attrs) {
    return {in[0].data, in[1].data, out[0].data, in[0].dims[1], in[0].dims[2], in[0].dims[3],
            attrs[0], attrs[1]};
}

void kernel_apply_run(const Tensor *in, Tensor *out, const int64_t *attrs, int threads) {
    FilterArgs a = filter_args(in, out, attrs);
    parallel_for(in[0].dims[0] * a.h, threads,
                 [&](int64_t b, int64_t e) { kernel_apply_rows(a, b, e); });
}

/* ------------------------------------------------------------------ SoftmaxKernelApply */

inline void exp_row(float *RESTRICT e, float *RESTRICT total, const float *RESTRICT logit,
                    const float *RESTRICT top, int64_t w) {
    for (int64_t x = 0; x < w; ++x) {
        float v = exp_neg(logit[x] - top[x]);
        e[x] = v;
        total[x] += v;
    }
}

RTD_CLONES void softmax_kernel_apply_rows(const FilterArgs &a, int64_t begin, int64_t end) {
    const int64_t k = a.k, d = a.d, w = a.w, h = a.h, kk = k * k;
    const int64_t wp = w + 2 * (k / 2) * d;
    std::vector<float> buffer(static_cast<size_t>(a.n_ch * wp + 3 * w));
    float *padded = buffer.data(), *e = padded + a.n_ch * wp, *top = e + w, *total = top + w;
    for (int64_t row = begin; row < end; ++row) {
        const int64_t n = row / h, y = row - n * h;
        const float *logits = a.weights + (n * kk * h + y) * w;  // tap t at logits + t h w
        float *out = a.out + (n * a.n_ch * h + y) * w;
        std::copy(logits, logits + w, top);
        for (int64_t t = 1; t < kk; ++t) {
            const float *l = logits + t * h * w;
            for (int64_t x = 0; x < w; ++x) top[x] = max_like_numba(top[x], l[x]);
        }
        std::fill(total, total + w, 0.0f);
        for (int64_t c = 0; c < a.n_ch; ++c) std::fill(out + c * h * w, out + c * h * w + w, 0.0f);
        for (int64_t i = 0; i < k; ++i) {
            pad_source_rows(a, n, y, i, padded);
            for (int64_t j = 0; j < k; ++j) {
                exp_row(e, total, logits + (i * k + j) * h * w, top, w);
                for (int64_t c = 0; c < a.n_ch; ++c)
                    fma_row(out + c * h * w, e, padded + c * wp + j * d, w);
            }
        }
        for (int64_t x = 0; x < w; ++x) total[x] = 1.0f / total[x];
        for (int64_t c = 0; c < a.n_ch; ++c) {
            float *o = out + c * h * w;
            for (int64_t x = 0; x < w; ++x) o[x] *= total[x];
        }
    }
}

void softmax_kernel_apply_run(const Tensor *in, Tensor *out, const int64_t *attrs, int threads) {
    FilterArgs a = filter_args(in, out, attrs);
    parallel_for(in[0].dims[0] * a.h, threads,
                 [&](int64_t b, int64_t e) { softmax_kernel_apply_rows(a, b, e); });
}

/* ------------------------------------------------------------------ KernelFusion */

std::string kernel_fusion_shapes(const Tensor *in, const int64_t *, Shape *out) {
    const char *names[] = {"images", "logits"};
    std::string e = same_nhw("KernelFusion", in, names, 2);
    if (!e.empty()) return e;
    int64_t sc = in[0].dims[1], s = in[1].dims[1];
    if (s < 1 || sc % s)
        return "KernelFusion: images " + fmt_shape(in[0]) + " and logits " + fmt_shape(in[1]) +
               ": expected (N, S*C, H, W) and (N, S, H, W)";
    set_shape(out[0], in[0].dims[0], sc / s, in[0].dims[2], in[0].dims[3]);
    return "";
}

struct FusionArgs {
    const float *images, *logits;
    float *out;
    int64_t n_s, n_ch, h, w;
};

RTD_CLONES void kernel_fusion_rows(const FusionArgs &a, int64_t begin, int64_t end) {
    const int64_t n_s = a.n_s, h = a.h, w = a.w, hw = h * w;
    std::vector<float> buffer(static_cast<size_t>((n_s + 2) * w));
    std::vector<int32_t> bits(static_cast<size_t>(w));
    float *prob = buffer.data(), *top = prob + n_s * w, *total = top + w;
    int32_t *b = bits.data();
    for (int64_t row = begin; row < end; ++row) {
        const int64_t n = row / h, y = row - n * h;
        const float *logits = a.logits + (n * n_s * h + y) * w;
        const float *images = a.images + (n * n_s * a.n_ch * h + y) * w;
        float *out = a.out + (n * a.n_ch * h + y) * w;
        std::copy(logits, logits + w, top);
        for (int64_t i = 1; i < n_s; ++i) {
            const float *l = logits + i * hw;
            for (int64_t x = 0; x < w; ++x) top[x] = max_like_numba(top[x], l[x]);
        }
        for (int64_t i = 0; i < n_s; ++i) {  // softmax, max subtracted
            float *RESTRICT p = prob + i * w;
            const float *RESTRICT l = logits + i * hw;
            for (int64_t x = 0; x < w; ++x) p[x] = exp_parts(l[x] - top[x], b[x]);
            for (int64_t x = 0; x < w; ++x) {  // times 2^k: an add to the exponent bits
                int32_t v;
                std::memcpy(&v, p + x, sizeof v);
                v += b[x];
                std::memcpy(p + x, &v, sizeof v);
            }
        }
        std::copy(prob, prob + w, total);
        for (int64_t i = 1; i < n_s; ++i) {
            const float *RESTRICT p = prob + i * w;
            for (int64_t x = 0; x < w; ++x) total[x] += p[x];
        }
        for (int64_t x = 0; x < w; ++x) top[x] = 1.0f / total[x];
        for (int64_t i = 0; i < n_s; ++i) {
            float *RESTRICT p = prob + i * w;
            for (int64_t x = 0; x < w; ++x) p[x] *= top[x];
        }
        for (int64_t c = 0; c < a.n_ch; ++c) {
            float *RESTRICT o = out + c * hw;
            const float *RESTRICT src = images + c * hw;
            for (int64_t x = 0; x < w; ++x) o[x] = prob[x] * src[x];
            for (int64_t i = 1; i < n_s; ++i) {
                const float *RESTRICT p = prob + i * w;
                const float *RESTRICT s = images + (i * a.n_ch + c) * hw;
                for (int64_t x = 0; x < w; ++x) o[x] += p[x] * s[x];
            }
        }
    }
}

void kernel_fusion_run(const Tensor *in, Tensor *out, const int64_t *, int threads) {
    float *o = out[0].data;
    const int64_t size = out[0].size();
    if (!all_finite(in[1].data, in[1].size())) {  // as nan_on_nonfinite(2, inputs=(1,))
        std::fill(o, o + size, std::nanf(""));
        return;
    }
    FusionArgs a{in[0].data, in[1].data, o, in[1].dims[1], out[0].dims[1], in[0].dims[2],
                 in[0].dims[3]};
    parallel_for(in[0].dims[0] * a.h, threads,
                 [&](int64_t b, int64_t e) { kernel_fusion_rows(a, b, e); });
    if (!all_finite(o, size)) std::fill(o, o + size, std::nanf(""));
}

/* ------------------------------------------------------------------ AdaptiveFusion */

std::string adaptive_fusion_shapes(const Tensor *in, const int64_t *, Shape *out) {
    const int64_t n = in[0].dims[0], c = in[0].dims[1], h = in[0].dims[2], w = in[0].dims[3];
    if (h % 2 || w % 2)
        return "AdaptiveFusion needs even H and W, got " + std::to_string(h) + "x" +
               std::to_string(w);
    const Tensor &low = in[1], &alpha = in[2];
    if (low.dims[0] != n || low.dims[1] != c || low.dims[2] != h / 2 || low.dims[3] != w / 2)
        return "AdaptiveFusion: d_low has shape " + fmt_shape(low) + "; expected (" +
               std::to_string(n) + ", " + std::to_string(c) + ", " + std::to_string(h / 2) +
               ", " + std::to_string(w / 2) + ")";
    if (alpha.dims[0] != n || alpha.dims[1] != 1 || alpha.dims[2] != h || alpha.dims[3] != w)
        return "AdaptiveFusion: alpha has shape " + fmt_shape(alpha) + "; expected (" +
               std::to_string(n) + ", 1, " + std::to_string(h) + ", " + std::to_string(w) + ")";
    copy_shape(in[0], out[0]);
    return "";
}

struct AdaptiveArgs {
    const float *ta, *low, *alpha;
    float *out;
    int64_t n_ch, h, w;
};

RTD_CLONES void adaptive_fusion_rows(const AdaptiveArgs &a, int64_t begin, int64_t end) {
    const int64_t h = a.h, w = a.w, h2 = h / 2, w2 = w / 2;
    std::vector<float> buffer(static_cast<size_t>(w2));
    float *RESTRICT diff = buffer.data();
    for (int64_t row = begin; row < end; ++row) {
        const int64_t n = row / (a.n_ch * h2), rem = row - n * a.n_ch * h2;
        const int64_t c = rem / h2, yl = rem - c * h2;
        const float *RESTRICT low = a.low + ((n * a.n_ch + c) * h2 + yl) * w2;
        const float *RESTRICT top = a.ta + ((n * a.n_ch + c) * h + 2 * yl) * w;
        const float *RESTRICT bottom = top + w;
        for (int64_t x = 0; x < w2; ++x) {
            float pooled = (top[2 * x] + top[2 * x + 1] + bottom[2 * x] + bottom[2 * x + 1]) * 0.25f;
            diff[x] = low[x] - pooled;
        }
        for (int64_t y = 2 * yl; y < 2 * yl + 2; ++y) {
            const float *RESTRICT ta = a.ta + ((n * a.n_ch + c) * h + y) * w;
            const float *RESTRICT alpha = a.alpha + (n * h + y) * w;
            float *RESTRICT out = a.out + ((n * a.n_ch + c) * h + y) * w;
            for (int64_t x = 0; x < w; ++x) out[x] = ta[x] + alpha[x] * diff[x >> 1];
        }
    }
}

void adaptive_fusion_run(const Tensor *in, Tensor *out, const int64_t *, int threads) {
    AdaptiveArgs a{in[0].data, in[1].data, in[2].data, out[0].data, in[0].dims[1],
                   in[0].dims[2], in[0].dims[3]};
    parallel_for(in[0].dims[0] * a.n_ch * (a.h / 2), threads,
                 [&](int64_t b, int64_t e) { adaptive_fusion_rows(a, b, e); });
}

/* ------------------------------------------------------------------ Reproject */

std::string reproject_shapes(const Tensor *in, const int64_t *, Shape *out) {
    const char *names[] = {"previous", "motion"};
    std::string e = same_nhw("Reproject", in, names, 2);
    if (!e.empty()) return e;
    if (in[1].dims[1] != 2)
        return "Reproject: motion has " + std::to_string(in[1].dims[1]) +
               " channels; expected 2 (x, y)";
    copy_shape(in[0], out[0]);
    return "";
}

/* kernels/reproject.py _taps: the flat offsets of each pixel's four bilinear taps and their
 * weights, in float32 as the torch form computes them. */
inline void taps_row(const float *RESTRICT mx, const float *RESTRICT my, int64_t y, int64_t h,
                     int64_t w, int64_t *RESTRICT taps, float *RESTRICT weights) {
    const float zero = 0.0f, one = 1.0f, fw1 = static_cast<float>(w - 1),
                fh1 = static_cast<float>(h - 1);
    for (int64_t x = 0; x < w; ++x) {
        float px = static_cast<float>(x) + mx[x];
        float py = static_cast<float>(y) + my[x];
        if (!(px > zero)) px = zero;  // NaN lands in the image too
        if (!(px < fw1)) px = fw1;
        if (!(py > zero)) py = zero;
        if (!(py < fh1)) py = fh1;
        int64_t cx = static_cast<int64_t>(px), cy = static_cast<int64_t>(py);
        int64_t x1 = std::min(cx + 1, w - 1), y1 = std::min(cy + 1, h - 1);
        float wx = px - static_cast<float>(cx), wy = py - static_cast<float>(cy);
        float ex = one - wx, ey = one - wy;
        taps[x] = cy * w + cx;
        taps[w + x] = cy * w + x1;
        taps[2 * w + x] = y1 * w + cx;
        taps[3 * w + x] = y1 * w + x1;
        weights[x] = ey * ex;
        weights[w + x] = ey * wx;
        weights[2 * w + x] = wy * ex;
        weights[3 * w + x] = wy * wx;
    }
}

inline void gather_row(const float *RESTRICT plane, float *RESTRICT out, const int64_t *RESTRICT t,
                       const float *RESTRICT wt, int64_t w) {
    for (int64_t x = 0; x < w; ++x)
        out[x] = plane[t[x]] * wt[x] + plane[t[w + x]] * wt[w + x] +
                 plane[t[2 * w + x]] * wt[2 * w + x] + plane[t[3 * w + x]] * wt[3 * w + x];
}

struct ReprojectArgs {
    const float *previous, *motion;
    float *out;
    int64_t n_ch, h, w;
};

RTD_CLONES void reproject_rows(const ReprojectArgs &a, int64_t begin, int64_t end) {
    const int64_t h = a.h, w = a.w, hw = h * w;
    std::vector<int64_t> taps(static_cast<size_t>(4 * w));
    std::vector<float> weights(static_cast<size_t>(4 * w));
    for (int64_t row = begin; row < end; ++row) {
        const int64_t n = row / h, y = row - n * h;
        const float *m = a.motion + (n * 2 * h + y) * w;
        taps_row(m, m + hw, y, h, w, taps.data(), weights.data());
        for (int64_t c = 0; c < a.n_ch; ++c)
            gather_row(a.previous + (n * a.n_ch + c) * hw, a.out + ((n * a.n_ch + c) * h + y) * w,
                       taps.data(), weights.data(), w);
    }
}

void reproject_run(const Tensor *in, Tensor *out, const int64_t *, int threads) {
    ReprojectArgs a{in[0].data, in[1].data, out[0].data, in[0].dims[1], in[0].dims[2],
                    in[0].dims[3]};
    parallel_for(in[0].dims[0] * a.h, threads,
                 [&](int64_t b, int64_t e) { reproject_rows(a, b, e); });
}

/* ------------------------------------------------------------------ TemporalAccumulation */

std::string temporal_accumulation_shapes(const Tensor *in, const int64_t *, Shape *out) {
    static const char *names[] = {"current", "motion", "depth", "normal", "ta_state",
                                  "geometry_state"};
    std::string e = same_nhw("TemporalAccumulation", in, names, 6);
    if (!e.empty()) return e;
    const int64_t n = in[0].dims[0], c = in[0].dims[1], h = in[0].dims[2], w = in[0].dims[3];
    const int64_t expected[] = {0, 2, 1, 3, c + 1, 4};
    for (int i = 1; i < 6; ++i)
        if (in[i].dims[1] != expected[i])
            return std::string("TemporalAccumulation: ") + names[i] + " has " +
                   std::to_string(in[i].dims[1]) + " channels; expected " +
                   std::to_string(expected[i]) + " (current has " + std::to_string(c) + ")";
    set_shape(out[0], n, c, h, w);
    set_shape(out[1], n, 1, h, w);
    set_shape(out[2], n, c + 1, h, w);
    set_shape(out[3], n, 4, h, w);
    return "";
}

struct TaArgs {
    const float *current, *motion, *depth, *normal, *ta_state, *geometry;
    float keep, tolerance, threshold, min_alpha, max_history;
    float *accumulated, *blend, *next_ta, *next_geometry;
    int64_t n_ch, h, w;
};

RTD_CLONES void temporal_accumulation_rows(const TaArgs &a, int64_t begin, int64_t end) {
    const int64_t n_ch = a.n_ch, h = a.h, w = a.w, hw = h * w;
    std::vector<int64_t> taps(static_cast<size_t>(4 * w));
    std::vector<float> weights(static_cast<size_t>(4 * w));
    std::vector<float> warped_buffer(static_cast<size_t>((n_ch + 5) * w));
    std::vector<unsigned char> ok_buffer(static_cast<size_t>(w));
    float *warped = warped_buffer.data();
    unsigned char *RESTRICT ok = ok_buffer.data();
    const float zero = 0.0f, one = 1.0f, half = 0.5f;
    const float lo = -0.5f, hi_x = static_cast<float>(w) - half, hi_y = static_cast<float>(h) - half;
    for (int64_t row = begin; row < end; ++row) {
        const int64_t n = row / h, y = row - n * h;
        const float *RESTRICT mx = a.motion + (n * 2 * h + y) * w;
        const float *RESTRICT my = mx + hw;
        taps_row(mx, my, y, h, w, taps.data(), weights.data());
        for (int64_t c = 0; c < n_ch + 1; ++c)
            gather_row(a.ta_state + (n * (n_ch + 1) + c) * hw, warped + c * w, taps.data(),
                       weights.data(), w);
        for (int64_t c = 0; c < 4; ++c)
            gather_row(a.geometry + (n * 4 + c) * hw, warped + (n_ch + 1 + c) * w, taps.data(),
                       weights.data(), w);
        const float *RESTRICT d_row = a.depth + (n * h + y) * w;
        const float *RESTRICT nx = a.normal + (n * 3 * h + y) * w;
        const float *RESTRICT ny = nx + hw;
        const float *RESTRICT nz = ny + hw;
        const float *RESTRICT count = warped + n_ch * w;
        const float *RESTRICT pnx = count + w;
        const float *RESTRICT pny = pnx + w;
        const float *RESTRICT pnz = pny + w;
        const float *RESTRICT prev_depth = pnz + w;
        float *RESTRICT alpha = a.blend + (n * h + y) * w;
        float *RESTRICT new_len = a.next_ta + ((n * (n_ch + 1) + n_ch) * h + y) * w;
        const float y_f = static_cast<float>(y);
        for (int64_t x = 0; x < w; ++x) {
            float px = static_cast<float>(x) + mx[x];
            float py = y_f + my[x];
            bool inside = (px >= lo) & (px <= hi_x) & (py >= lo) & (py <= hi_y);
            float d = d_row[x];
            bool depth_ok = std::fabs(prev_depth[x] - d) < a.tolerance * std::fabs(d);
            float dot = pnx[x] * nx[x];
            dot += pny[x] * ny[x];
            dot += pnz[x] * nz[x];
            float valid = (inside & depth_ok & (dot > a.threshold)) ? one : zero;
            bool kept = valid * a.keep > half;
            ok[x] = kept;
            float n_next = (kept ? count[x] : zero) + one;
            alpha[x] = max_like_numba(one / n_next, a.min_alpha);
            new_len[x] = min_like_numba(n_next, a.max_history);
        }
        for (int64_t c = 0; c < n_ch; ++c) {  // the blend, one channel row at a time
            const float *RESTRICT cur = a.current + ((n * n_ch + c) * h + y) * w;
            const float *RESTRICT hist = warped + c * w;
            float *RESTRICT acc = a.accumulated + ((n * n_ch + c) * h + y) * w;
            float *RESTRICT nta = a.next_ta + ((n * (n_ch + 1) + c) * h + y) * w;
            for (int64_t x = 0; x < w; ++x) {
                float al = alpha[x];
                float kept = ok[x] ? hist[x] : zero;
                float value = al * cur[x] + (one - al) * kept;
                acc[x] = value;
                nta[x] = value;
            }
        }
        for (int64_t c = 0; c < 3; ++c)
            std::copy(nx + c * hw, nx + c * hw + w, a.next_geometry + ((n * 4 + c) * h + y) * w);
        std::copy(d_row, d_row + w, a.next_geometry + ((n * 4 + 3) * h + y) * w);
    }
}

void temporal_accumulation_run(const Tensor *in, Tensor *out, const int64_t *, int threads) {
    TaArgs a{in[0].data, in[1].data, in[2].data, in[3].data, in[4].data, in[5].data,
             1.0f - in[6].data[0], in[7].data[0], in[8].data[0], in[9].data[0], in[10].data[0],
             out[0].data, out[1].data, out[2].data, out[3].data,
             in[0].dims[1], in[0].dims[2], in[0].dims[3]};
    parallel_for(in[0].dims[0] * a.h, threads,
                 [&](int64_t b, int64_t e) { temporal_accumulation_rows(a, b, e); });
}

/* ------------------------------------------------------------------ WeightSharingFilter */

std::string wsf_sizes(const int64_t *attrs) {
    int64_t size_min = attrs[0], size_step = attrs[1], count = attrs[2];
    if (count < 1 || size_min < 1 || size_min % 2 == 0 || size_step < 0 || size_step % 2)
        return "WeightSharingFilter needs count >= 1, odd size_min >= 1 and even size_step >= 0, "
               "got size_min=" + std::to_string(size_min) + ", size_step=" +
               std::to_string(size_step) + ", count=" + std::to_string(count);
    return "";
}

std::string weight_sharing_filter_shapes(const Tensor *in, const int64_t *attrs, Shape *out) {
    std::string e = wsf_sizes(attrs);
    if (!e.empty()) return e;
    const char *names[] = {"image", "weights"};
    e = same_nhw("WeightSharingFilter", in, names, 2);
    if (!e.empty()) return e;
    if (in[1].dims[1] != attrs[2])
        return "WeightSharingFilter: weights have " + std::to_string(in[1].dims[1]) +
               " channels; expected count = " + std::to_string(attrs[2]) +
               " (one importance map per box size)";
    set_shape(out[0], in[0].dims[0], attrs[2] * in[0].dims[1], in[0].dims[2], in[0].dims[3]);
    return "";
}

constexpr int64_t STRIP_ROWS = 96;  // output rows per task (kernels/weight_sharing_filter.py)

struct WsfArgs {
    const float *image, *weights;
    float *out;
    int64_t n_ch, h, w, count, size_min, size_step;
    std::vector<int64_t> task_n, task_i, task_b0, task_b1;
};

inline void add3(float *RESTRICT dst, const float *RESTRICT a, const float *RESTRICT b, int64_t n) {
    for (int64_t x = 0; x < n; ++x) dst[x] = a[x] + b[x];
}

inline void add_into(float *RESTRICT dst, const float *RESTRICT a, int64_t n) {
    for (int64_t x = 0; x < n; ++x) dst[x] += a[x];
}

/* rows[t] (t < s) = plane p of source row y0 + t (w_i * image_p, or w_i for p == C); 0
 * outside the image. */
inline void wsf_source_rows(const WsfArgs &a, int64_t n, int64_t i, int64_t p, int64_t y0,
                            int64_t s, float *rows) {
    const int64_t h = a.h, w = a.w;
    for (int64_t t = 0; t < s; ++t) {
        const int64_t y = y0 + t;
        float *RESTRICT row = rows + t * w;
        if (y < 0 || y >= h) {
            std::fill(row, row + w, 0.0f);
            continue;
        }
        const float *RESTRICT wt = a.weights + ((n * a.count + i) * h + y) * w;
        if (p < a.n_ch) {
            const float *RESTRICT img = a.image + ((n * a.n_ch + p) * h + y) * w;
            for (int64_t x = 0; x < w; ++x) row[x] = wt[x] * img[x];
        } else {
            std::copy(wt, wt + w, row);
        }
    }
}

/* kernels/weight_sharing_filter.py _horizontal: suf[j, t*nb + b] = the s x s box sum of
 * output row t of the block at column b*s + j. */
inline void wsf_horizontal(const float *cur, const float *vpre, int64_t s, int64_t r, int64_t w,
                           int64_t nb, float *q, float *qt, float *suf) {
    const int64_t m = s * nb;
    float *q_row = q + r;  // q: (nb, s) zero-padded row, the window's row at [r, r + w)
    for (int64_t t = 0; t < s; ++t) {
        if (t == 0)
            std::copy(cur, cur + w, q_row);
        else
            add3(q_row, cur + t * w, vpre + (t - 1) * w, w);
        float *qt_t = qt + t * nb;  // qt[j, t*nb + b] = q[b, j]
        for (int64_t j = 0; j < s; ++j)
            for (int64_t b = 0; b < nb; ++b) qt_t[j * m + b] = q[b * s + j];
    }
    std::copy(qt + (s - 1) * m, qt + s * m, suf + (s - 1) * m);
    for (int64_t j = s - 2; j >= 0; --j) add3(suf + j * m, suf + (j + 1) * m, qt + j * m, m);
    for (int64_t j = 1; j < s - 1; ++j) add_into(qt + j * m, qt + (j - 1) * m, m);
    for (int64_t j = 1; j < s; ++j) add_into(suf + j * m, qt + (j - 1) * m + 1, m - 1);
}

RTD_CLONES void wsf_tasks(const WsfArgs &a, int64_t begin, int64_t end) {
    const int64_t n_ch = a.n_ch, h = a.h, w = a.w, planes = n_ch + 1;
    std::vector<float> cur_b, nxt_b, vpre_b, q, qt, suf, inv;
    for (int64_t task = begin; task < end; ++task) {
        const int64_t n = a.task_n[task], i = a.task_i[task];
        const int64_t b0 = a.task_b0[task], b1 = a.task_b1[task];
        const int64_t s = a.size_min + i * a.size_step, r = s / 2;
        const int64_t nb = (w + 2 * r + s - 1) / s, m = s * nb;
        const int64_t plane = s * w;
        cur_b.resize(static_cast<size_t>(planes * plane));
        nxt_b.resize(static_cast<size_t>(planes * plane));
        vpre_b.resize(static_cast<size_t>(planes * plane));
        q.assign(static_cast<size_t>(nb * s), 0.0f);
        qt.resize(static_cast<size_t>(s * m));
        suf.resize(static_cast<size_t>(s * m));
        inv.resize(static_cast<size_t>(s * m));
        float *cur = cur_b.data(), *nxt = nxt_b.data(), *vpre = vpre_b.data();
        for (int64_t p = 0; p < planes; ++p)
            wsf_source_rows(a, n, i, p, b0 * s - r, s, cur + p * plane);
        for (int64_t b = b0; b < b1; ++b) {
            for (int64_t p = 0; p < planes; ++p) {  // vertical: suffix sums, next block's prefix
                float *cp = cur + p * plane, *np_ = nxt + p * plane, *vp = vpre + p * plane;
                wsf_source_rows(a, n, i, p, (b + 1) * s - r, s, np_);
                for (int64_t t = s - 2; t >= 0; --t) add_into(cp + t * w, cp + (t + 1) * w, w);
                std::copy(np_, np_ + w, vp);
                for (int64_t t = 1; t < s - 1; ++t) add3(vp + t * w, vp + (t - 1) * w, np_ + t * w, w);
            }
            wsf_horizontal(cur + n_ch * plane, vpre + n_ch * plane, s, r, w, nb, q.data(),
                           qt.data(), suf.data());
            for (int64_t x = 0; x < s * m; ++x) {  // 1 / denominator where > 0, else 0
                float d = suf[x];
                float safe = d > 0.0f ? d : 1.0f;
                float v = 1.0f / safe;
                inv[x] = d > 0.0f ? v : 0.0f;
            }
            for (int64_t c = 0; c < n_ch; ++c) {
                wsf_horizontal(cur + c * plane, vpre + c * plane, s, r, w, nb, q.data(), qt.data(),
                               suf.data());
                for (int64_t t = 0; t < std::min(s, h - b * s); ++t) {
                    float *out_row = a.out + ((n * a.count * n_ch + i * n_ch + c) * h + b * s + t) * w;
                    const float *num_t = suf.data() + t * nb, *inv_t = inv.data() + t * nb;
                    for (int64_t j = 0; j < s; ++j)
                        for (int64_t bb = 0; bb < (w - j + s - 1) / s; ++bb)
                            out_row[bb * s + j] = num_t[j * m + bb] * inv_t[j * m + bb];
                }
            }
            std::swap(cur, nxt);
        }
    }
}

void weight_sharing_filter_run(const Tensor *in, Tensor *out, const int64_t *attrs, int threads) {
    WsfArgs a{in[0].data, in[1].data, out[0].data, in[0].dims[1], in[0].dims[2], in[0].dims[3],
              attrs[2], attrs[0], attrs[1], {}, {}, {}, {}};
    for (int64_t i = 0; i < a.count; ++i) {  // kernels/weight_sharing_filter.py _tasks
        const int64_t s = a.size_min + i * a.size_step;
        const int64_t per = std::max<int64_t>(1, static_cast<int64_t>(std::nearbyint(double(STRIP_ROWS) / double(s))));
        const int64_t blocks = (a.h + s - 1) / s;
        for (int64_t n = 0; n < in[0].dims[0]; ++n)
            for (int64_t b0 = 0; b0 < blocks; b0 += per) {
                a.task_n.push_back(n);
                a.task_i.push_back(i);
                a.task_b0.push_back(b0);
                a.task_b1.push_back(std::min(b0 + per, blocks));
            }
    }
    parallel_for(static_cast<int64_t>(a.task_n.size()), threads,
                 [&](int64_t b, int64_t e) { wsf_tasks(a, b, e); });
}

/* ------------------------------------------------------------------ the table */

const char *const KERNEL_ATTRS[] = {"kernel_size", "dilation"};
constexpr int TA_RANKS[] = {4, 4, 4, 4, 4, 4, 0, 0, 0, 0, 0};
const char *const KA_IN[] = {"image", "kernel"};
const char *const SKA_IN[] = {"image", "logits"};
const char *const KF_IN[] = {"images", "logits"};
const char *const AF_IN[] = {"d_ta", "d_low", "alpha"};
const char *const RP_IN[] = {"previous", "motion"};
const char *const WSF_ATTRS[] = {"size_min", "size_step", "count"};
const char *const WSF_IN[] = {"image", "weights"};
const char *const TA_IN[] = {"current", "motion", "depth", "normal", "ta_state",
                             "geometry_state", "reset", "depth_tolerance", "normal_threshold",
                             "min_alpha", "max_history"};

const OpDef OPS[] = {
    {"KernelApply", 2, 1, R4, KA_IN, KERNEL_ATTRS, 2, kernel_apply_shapes, kernel_apply_run},
    {"SoftmaxKernelApply", 2, 1, R4, SKA_IN, KERNEL_ATTRS, 2, softmax_kernel_apply_shapes,
     softmax_kernel_apply_run},
    {"KernelFusion", 2, 1, R4, KF_IN, nullptr, 0, kernel_fusion_shapes, kernel_fusion_run},
    {"AdaptiveFusion", 3, 1, R4, AF_IN, nullptr, 0, adaptive_fusion_shapes, adaptive_fusion_run},
    {"Reproject", 2, 1, R4, RP_IN, nullptr, 0, reproject_shapes, reproject_run},
    {"TemporalAccumulation", 11, 4, TA_RANKS, TA_IN, nullptr, 0, temporal_accumulation_shapes,
     temporal_accumulation_run},
    {"WeightSharingFilter", 2, 1, R4, WSF_IN, WSF_ATTRS, 3, weight_sharing_filter_shapes,
     weight_sharing_filter_run},
};

}  // namespace

const OpDef *op_table(int *count) {
    *count = static_cast<int>(sizeof OPS / sizeof OPS[0]);
    return OPS;
}

}  // namespace rtd

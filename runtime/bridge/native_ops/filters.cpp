/* The kernels of rtdenoise_ops whose numba kernels are compiled with fastmath: KernelApply,
 * SoftmaxKernelApply, KernelFusion, AdaptiveFusion, WeightSharingFilter, each the numba
 * kernel's loops in float32 (runtime/kernels/<op>.py). Like numba's fastmath (its LLVM
 * contracts a multiply and an add into one FMA where the CPU has it), this file lets the
 * compiler fuse them (the AVX2 and AVX-512 clones), so the two agree within an ulp or two and
 * run the same instructions; nothing is reassociated (no -ffast-math).
 *
 * Non-finite inputs: KernelFusion checks its logits before and its output after and fills
 * the output with NaN, as its numba driver (`nan_on_nonfinite`) does; the others let NaN and
 * Inf through IEEE arithmetic (the numba kernels give an unspecified value there; the
 * runtime's input guard keeps them out of the graph).
 */
#if defined(__clang__)
#pragma clang fp contract(fast)
#elif defined(__GNUC__)
#pragma GCC optimize("fp-contract=fast")
#endif

#include <atomic>
#include <mutex>

#include "kernels_common.h"

namespace rtd {
namespace filters {

using namespace detail;

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
    parallel_for(in[0].dims[0] * a.h, threads, out[0].size() * a.k * a.k,
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

constexpr int64_t SKA_TILE = 256;  // pixels of a row taken through all the taps at once

/* Per output row: the k source rows padded once, then tiles of SKA_TILE pixels, each through
 * all k x k taps (max, exponentials, their sum, the channels' weighted sums) while its rows
 * stay in L1 (a whole 1080p row's exponentials, sums and outputs do not). Each value is the
 * same sum in the same tap order as row by row. */
RTD_CLONES void softmax_kernel_apply_rows(const FilterArgs &a, int64_t begin, int64_t end) {
    const int64_t k = a.k, d = a.d, w = a.w, h = a.h, kk = k * k, hw = h * w;
    const int64_t wp = w + 2 * (k / 2) * d, n_ch = a.n_ch;
    std::vector<float> buffer(static_cast<size_t>(k * n_ch * wp + 3 * SKA_TILE));
    float *padded = buffer.data(), *e = padded + k * n_ch * wp, *top = e + SKA_TILE;
    float *total = top + SKA_TILE;
    for (int64_t row = begin; row < end; ++row) {
        const int64_t n = row / h, y = row - n * h;
        const float *logits = a.weights + (n * kk * h + y) * w;  // tap t at logits + t h w
        float *out = a.out + (n * n_ch * h + y) * w;
        for (int64_t i = 0; i < k; ++i) pad_source_rows(a, n, y, i, padded + i * n_ch * wp);
        for (int64_t x0 = 0; x0 < w; x0 += SKA_TILE) {
            const int64_t m = std::min(SKA_TILE, w - x0);
            std::copy(logits + x0, logits + x0 + m, top);
            for (int64_t t = 1; t < kk; ++t) max_into(top, logits + t * hw + x0, m);
            std::fill(total, total + m, 0.0f);
            for (int64_t c = 0; c < n_ch; ++c) std::fill(out + c * hw + x0, out + c * hw + x0 + m, 0.0f);
            for (int64_t i = 0; i < k; ++i) {
                const float *rows_i = padded + i * n_ch * wp + x0;
                for (int64_t j = 0; j < k; ++j) {
                    exp_row(e, total, logits + (i * k + j) * hw + x0, top, m);
                    for (int64_t c = 0; c < n_ch; ++c)
                        fma_row(out + c * hw + x0, e, rows_i + c * wp + j * d, m);
                }
            }
            for (int64_t x = 0; x < m; ++x) total[x] = 1.0f / total[x];
            for (int64_t c = 0; c < n_ch; ++c) {
                float *o = out + c * hw + x0;
                for (int64_t x = 0; x < m; ++x) o[x] *= total[x];
            }
        }
    }
}

void softmax_kernel_apply_run(const Tensor *in, Tensor *out, const int64_t *attrs, int threads) {
    FilterArgs a = filter_args(in, out, attrs);
    parallel_for(in[0].dims[0] * a.h, threads, (out[0].size() + in[1].size()) * a.k * a.k,
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
    std::atomic<bool> *nonfinite;  // set by a row whose logits or output are not all finite
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
        bool finite = true;  // tested on the rows in hand, not in passes of their own
        for (int64_t i = 0; i < n_s; ++i) finite = finite && all_finite(logits + i * hw, w);
        if (!finite) {  // the whole output becomes NaN (kernel_fusion_run)
            a.nonfinite->store(true, std::memory_order_relaxed);
            continue;
        }
        std::copy(logits, logits + w, top);
        for (int64_t i = 1; i < n_s; ++i) max_into(top, logits + i * hw, w);
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
            if (!all_finite(o, w)) a.nonfinite->store(true, std::memory_order_relaxed);
        }
    }
}

void kernel_fusion_run(const Tensor *in, Tensor *out, const int64_t *, int threads) {
    float *o = out[0].data;
    const int64_t size = out[0].size();
    std::atomic<bool> nonfinite{false};
    FusionArgs a{in[0].data, in[1].data, o, in[1].dims[1], out[0].dims[1], in[0].dims[2],
                 in[0].dims[3], &nonfinite};
    parallel_for(in[0].dims[0] * a.h, threads, in[0].size() + 8 * in[1].size(),
                 [&](int64_t b, int64_t e) { kernel_fusion_rows(a, b, e); });
    // as nan_on_nonfinite(2, inputs=(1,)): a non-finite logit or output, NaN everywhere
    if (nonfinite.load()) std::fill(o, o + size, std::nanf(""));
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
    parallel_for(in[0].dims[0] * a.n_ch * (a.h / 2), threads, 2 * out[0].size(),
                 [&](int64_t b, int64_t e) { adaptive_fusion_rows(a, b, e); });
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
#pragma GCC unroll 8
            for (int64_t b = 0; b < nb; ++b) qt_t[j * m + b] = q[b * s + j];
    }
    std::copy(qt + (s - 1) * m, qt + s * m, suf + (s - 1) * m);
    for (int64_t j = s - 2; j >= 0; --j) add3(suf + j * m, suf + (j + 1) * m, qt + j * m, m);
    for (int64_t j = 1; j < s - 1; ++j) add_into(qt + j * m, qt + (j - 1) * m, m);
    for (int64_t j = 1; j < s; ++j) add_into(suf + j * m, qt + (j - 1) * m + 1, m - 1);
}

RTD_CLONES void wsf_tasks(const WsfArgs &a, int64_t begin, int64_t end) {
    const int64_t n_ch = a.n_ch, h = a.h, w = a.w, planes = n_ch + 1;
    // kept by each thread from call to call (a few MB at 1080p): fresh buffers per call
    // would fault their pages in again on every call
    thread_local std::vector<float> cur_b, nxt_b, vpre_b, q, qt, suf, inv;
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
#pragma GCC unroll 8
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
    parallel_for(static_cast<int64_t>(a.task_n.size()), threads, 12 * out[0].size(),
                 [&](int64_t b, int64_t e) { wsf_tasks(a, b, e); });
}

/* ------------------------------------------------------------------ BilateralGrid */

constexpr int64_t CELL = 4;  // floats per grid cell: 3 channels and the weight sum
constexpr float TENT_EPS = 1e-7f, GUIDE_MAX = 255.0f, GUIDE_RANGE = 256.0f;

std::string bilateral_grid_shapes(const Tensor *in, const int64_t *attrs, Shape *out) {
    const int64_t s = attrs[0], d = attrs[1];
    if (s < 1 || d < 1)
        return "BilateralGrid needs cell_size >= 1 and grid_depth >= 1, got " + std::to_string(s) +
               ", " + std::to_string(d);
    const char *names[] = {"image", "guide"};
    std::string e = same_nhw("BilateralGrid", in, names, 2);
    if (!e.empty()) return e;
    if (in[1].dims[1] != 1)
        return "BilateralGrid: guide has " + std::to_string(in[1].dims[1]) +
               " channels; expected 1 (one guide per grid)";
    copy_shape(in[0], out[0]);
    return "";
}

inline uint32_t float_bits(float f) {
    uint32_t b;
    std::memcpy(&b, &f, sizeof b);
    return b;
}

inline float tent(float u) {
    float v = 1.0f - std::sqrt(u * u + TENT_EPS);
    return v > 0.0f ? v : 0.0f;
}

struct AxisTable {  // kernels/bilateral_grid.py _axis_table
    std::vector<int64_t> i0, i1;
    std::vector<float> w0, w1;
};

AxisTable axis_table(int64_t size, int64_t cell_size, int64_t cells) {
    AxisTable t;
    for (int64_t x = 0; x < size; ++x) {
        float v = (static_cast<float>(x) + 0.5f) / static_cast<float>(cell_size) - 0.5f;
        float first = std::floor(v);
        float u = v - first;
        int64_t i0 = static_cast<int64_t>(first);
        t.w0.push_back(i0 >= 0 ? tent(u) : 0.0f);
        t.w1.push_back(i0 + 1 < cells ? tent(u - 1.0f) : 0.0f);
        t.i0.push_back(std::min(std::max(i0, int64_t(0)), cells - 1));
        t.i1.push_back(std::min(std::max(i0 + 1, int64_t(0)), cells - 1));
    }
    return t;
}

/* The per-call buffers (hom, z0, z1, wz0, wz1, grid), kept from one call to the next: fresh
 * ones each call cost a page fault per 4 KiB page on first touch (at 720p, s = 4, D = 64 the
 * grid alone is 59 MB; measured, the kernel's fault handling was about a fifth of the op's
 * time, and the numba kernel pays it too). They grow to the largest call and stay (1080p,
 * s = 4, D = 64: about 200 MB). Not zero-filled: every element is written before it is read.
 * One call at a time uses the kept ones (try_lock); another meanwhile allocates its own. */
struct GridBuffers {
    std::unique_ptr<float[]> hom, wz0, wz1, grid;
    std::unique_ptr<int32_t[]> z0, z1;
    int64_t pixels = 0, grid_size = 0;  // capacities

    void reserve(int64_t n_pixels, int64_t n_grid) {
        if (n_pixels > pixels) {
            hom.reset(), z0.reset(), z1.reset(), wz0.reset(), wz1.reset(), pixels = 0;
            hom.reset(new float[static_cast<size_t>(n_pixels * CELL)]);
            z0.reset(new int32_t[static_cast<size_t>(n_pixels)]);
            z1.reset(new int32_t[static_cast<size_t>(n_pixels)]);
            wz0.reset(new float[static_cast<size_t>(n_pixels)]);
            wz1.reset(new float[static_cast<size_t>(n_pixels)]);
            pixels = n_pixels;
        }
        if (n_grid > grid_size) {
            grid.reset(), grid_size = 0;
            grid.reset(new float[static_cast<size_t>(n_grid)]);
            grid_size = n_grid;
        }
    }
};

struct KeptGridBuffers {
    std::mutex in_use;
    GridBuffers buffers;
};

KeptGridBuffers &kept_grid_buffers() {
    static KeptGridBuffers *kept = new KeptGridBuffers();  // never destroyed (as the pool)
    return *kept;
}

struct GridArgs {
    const float *image, *guide;
    float *out;
    int64_t n_img, n_ch, h, w, gh, gw, depth, row_size, c0;
    AxisTable ys, xs;               // xs offsets: cells x (D x CELL)
    std::vector<float> rows;        // (gh, h): the weight of pixel row y for grid row i
    std::vector<int64_t> y_lo, y_hi;
    float *hom, *wz0, *wz1, *grid;  // GridBuffers'
    int32_t *z0, *z1;
    int64_t grid_size = 0;
};

RTD_CLONES void grid_prepare(GridArgs &a, int64_t begin, int64_t end) {
    const int64_t h = a.h, w = a.w, depth = a.depth;
    const float depth_f = static_cast<float>(depth);
    for (int64_t task = begin; task < end; ++task) {
        const int64_t n = task / h, y = task % h;
        float *RESTRICT row = a.hom + (n * h + y) * w * CELL;
        for (int64_t k = 0; k < CELL - 1; ++k) {
            if (a.c0 + k < a.n_ch) {
                const float *RESTRICT src = a.image + ((n * a.n_ch + a.c0 + k) * h + y) * w;
                for (int64_t x = 0; x < w; ++x) row[x * CELL + k] = src[x];
            } else {
                for (int64_t x = 0; x < w; ++x) row[x * CELL + k] = 0.0f;
            }
        }
        for (int64_t x = 0; x < w; ++x) row[x * CELL + CELL - 1] = 1.0f;
        const float *RESTRICT g_row = a.guide + (n * h + y) * w;
        const int64_t at = (n * h + y) * w;
        for (int64_t x = 0; x < w; ++x) {
            float g = min_like_numba(max_like_numba(g_row[x], 0.0f), GUIDE_MAX);
            float t = (g + 0.5f) * depth_f / GUIDE_RANGE - 0.5f;
            float first = std::floor(t);
            float u = t - first;
            int64_t i0 = std::min(std::max(static_cast<int64_t>(first), int64_t(-1)), depth - 1);
            a.z0[at + x] = static_cast<int32_t>(std::max(i0, int64_t(0)) * CELL);
            a.z1[at + x] = static_cast<int32_t>(std::min(i0 + 1, depth - 1) * CELL);
            a.wz0[at + x] = i0 >= 0 ? tent(u) : 0.0f;
            a.wz1[at + x] = i0 + 1 < depth ? tent(u - 1.0f) : 0.0f;
        }
    }
}

inline void cell_add(float *RESTRICT grid, int64_t at, float c0, float c1, float c2, float c3) {
    grid[at] += c0;
    grid[at + 1] += c1;
    grid[at + 2] += c2;
    grid[at + 3] += c3;
}

/* kernels/bilateral_grid.py _splat_row: one pixel row into its column cells xo (weights
 * wy wx), the pair of cells' sums kept while neighbours add to the same pair. */
inline void splat_row(float *RESTRICT grid, int64_t base, const float *RESTRICT pixels,
                      const int64_t *RESTRICT xo, const float *RESTRICT wx, float wy,
                      const int32_t *RESTRICT za, const int32_t *RESTRICT zb,
                      const float *RESTRICT wza, const float *RESTRICT wzb, int64_t w) {
    int64_t key_open = -1, at = 0, at_z = 0;
    float s0 = 0, s1 = 0, s2 = 0, s3 = 0, t0 = 0, t1 = 0, t2 = 0, t3 = 0;
    for (int64_t x = 0; x < w; ++x) {
        const float *p = pixels + x * CELL;
        const int64_t zs = za[x];
        const int64_t key = 2 * (xo[x] + zs) + (zs == zb[x] ? 1 : 0);
        if (key != key_open) {
            if (key_open >= 0) {
                cell_add(grid, at, s0, s1, s2, s3);
                cell_add(grid, at_z, t0, t1, t2, t3);
            }
            key_open = key, at = base + xo[x] + zs, at_z = base + xo[x] + zb[x];
            s0 = s1 = s2 = s3 = t0 = t1 = t2 = t3 = 0.0f;
        }
        float wxy = wy * wx[x];
        float wa = wxy * wza[x], wb = wxy * wzb[x];
        s0 += wa * p[0];
        s1 += wa * p[1];
        s2 += wa * p[2];
        s3 += wa * p[3];
        t0 += wb * p[0];
        t1 += wb * p[1];
        t2 += wb * p[2];
        t3 += wb * p[3];
    }
    if (key_open >= 0) {
        cell_add(grid, at, s0, s1, s2, s3);
        cell_add(grid, at_z, t0, t1, t2, t3);
    }
}

RTD_CLONES void grid_splat(GridArgs &a, int64_t begin, int64_t end) {
    const int64_t h = a.h, w = a.w, gh = a.gh;
    for (int64_t task = begin; task < end; ++task) {
        const int64_t n = task / gh, i = task % gh, base = task * a.row_size;
        float *grid = a.grid;
        std::fill(grid + base, grid + base + a.row_size, 0.0f);
        for (int64_t y = a.y_lo[i]; y < a.y_hi[i]; ++y) {
            float wy = a.rows[i * h + y];
            if (wy > 0.0f) {
                const int64_t at = (n * h + y) * w;
                const float *pixels = a.hom + at * CELL;
                splat_row(grid, base, pixels, a.xs.i0.data(), a.xs.w0.data(), wy, &a.z0[at],
                          &a.z1[at], &a.wz0[at], &a.wz1[at], w);
                splat_row(grid, base, pixels, a.xs.i1.data(), a.xs.w1.data(), wy, &a.z0[at],
                          &a.z1[at], &a.wz0[at], &a.wz1[at], w);
            }
        }
        float *RESTRICT cells = grid + base;  // Meng20 eq. (10), branch-free
        for (int64_t j = 0; j < a.row_size / CELL; ++j) {
            float total = cells[j * CELL + CELL - 1];
            float inv = total > 0.0f ? 1.0f / total : 0.0f;
            for (int64_t k = 0; k < CELL - 1; ++k) cells[j * CELL + k] *= inv;
        }
    }
}

RTD_CLONES void grid_slice(GridArgs &a, int64_t begin, int64_t end) {
    const int64_t h = a.h, w = a.w, n_ch = a.n_ch, c0 = a.c0;
    const float *RESTRICT grid = a.grid;  // only read here: the stores cannot change it
    const int64_t *RESTRICT x0 = a.xs.i0.data(), *RESTRICT x1 = a.xs.i1.data();
    const float *RESTRICT wx0 = a.xs.w0.data(), *RESTRICT wx1 = a.xs.w1.data();
    for (int64_t task = begin; task < end; ++task) {
        const int64_t n = task / h, y = task % h;
        const int64_t at_a = (n * a.gh + a.ys.i0[y]) * a.row_size;
        const int64_t at_b = (n * a.gh + a.ys.i1[y]) * a.row_size;
        const float wya = a.ys.w0[y], wyb = a.ys.w1[y];
        const int64_t at = (n * h + y) * w;
        const int32_t *RESTRICT za = a.z0 + at, *RESTRICT zb = a.z1 + at;
        const float *RESTRICT wza = a.wz0 + at, *RESTRICT wzb = a.wz1 + at;
        float *o0 = a.out + ((n * n_ch + c0) * h + y) * w;
        float *o1 = a.out + ((n * n_ch + std::min(c0 + 1, n_ch - 1)) * h + y) * w;
        float *o2 = a.out + ((n * n_ch + std::min(c0 + 2, n_ch - 1)) * h + y) * w;
        for (int64_t x = 0; x < w; ++x) {
            float m0 = 0, m1 = 0, m2 = 0, den = 0;
            auto corner = [&](int64_t at_y, float wxy, int64_t zo, float wz) {
                const float *RESTRICT c = grid + at_y + zo;
                // wt = wxy wz where the cell's weight sum is positive, else 0, as a bit mask
                // (a branch mispredicted: empty cells come at random)
                const uint32_t keep = 0u - static_cast<uint32_t>(c[3] > 0.0f);
                const float wt = bits_to_float(static_cast<int32_t>(float_bits(wxy * wz) & keep));
                m0 += wt * c[0];
                m1 += wt * c[1];
                m2 += wt * c[2];
                den += wt;
            };
            const int64_t xa = x0[x], xb = x1[x], zs = za[x], zt = zb[x];
            const float wa = wza[x], wb = wzb[x];
            float wxy = wya * wx0[x];  // the corners in the numba kernel's order
            corner(at_a + xa, wxy, zs, wa);
            corner(at_a + xa, wxy, zt, wb);
            wxy = wya * wx1[x];
            corner(at_a + xb, wxy, zs, wa);
            corner(at_a + xb, wxy, zt, wb);
            wxy = wyb * wx0[x];
            corner(at_b + xa, wxy, zs, wa);
            corner(at_b + xa, wxy, zt, wb);
            wxy = wyb * wx1[x];
            corner(at_b + xb, wxy, zs, wa);
            corner(at_b + xb, wxy, zt, wb);
            float inv = den > 0.0f ? 1.0f / den : 0.0f;
            o2[x] = m2 * inv;  // channels past the last alias it: written first
            o1[x] = m1 * inv;
            o0[x] = m0 * inv;
        }
    }
}

void bilateral_grid_run(const Tensor *in, Tensor *out, const int64_t *attrs, int threads) {
    const int64_t cell_size = attrs[0], depth = attrs[1];
    GridArgs a;
    a.image = in[0].data, a.guide = in[1].data, a.out = out[0].data;
    a.n_img = in[0].dims[0], a.n_ch = in[0].dims[1], a.h = in[0].dims[2], a.w = in[0].dims[3];
    a.gh = (a.h + cell_size - 1) / cell_size, a.gw = (a.w + cell_size - 1) / cell_size;
    a.depth = depth, a.row_size = a.gw * depth * CELL;
    a.ys = axis_table(a.h, cell_size, a.gh);
    a.xs = axis_table(a.w, cell_size, a.gw);
    for (auto *v : {&a.xs.i0, &a.xs.i1})
        for (auto &o : *v) o *= depth * CELL;  // offsets within a grid row
    a.rows.assign(static_cast<size_t>(a.gh * a.h), 0.0f);
    for (int64_t y = 0; y < a.h; ++y) a.rows[a.ys.i0[y] * a.h + y] += a.ys.w0[y];
    for (int64_t y = 0; y < a.h; ++y) a.rows[a.ys.i1[y] * a.h + y] += a.ys.w1[y];
    for (int64_t i = 0; i < a.gh; ++i) {
        int64_t lo = -1, hi = 0;
        for (int64_t y = 0; y < a.h; ++y)
            if (a.rows[i * a.h + y] > 0.0f) {
                if (lo < 0) lo = y;
                hi = y + 1;
            }
        a.y_lo.push_back(lo < 0 ? 0 : lo);
        a.y_hi.push_back(lo < 0 ? 0 : hi);
    }
    const int64_t pixels = a.n_img * a.h * a.w;
    a.grid_size = a.n_img * a.gh * a.row_size;
    KeptGridBuffers &kept = kept_grid_buffers();
    std::unique_lock<std::mutex> lock(kept.in_use, std::try_to_lock);
    GridBuffers own;
    GridBuffers &buffers = lock.owns_lock() ? kept.buffers : own;
    buffers.reserve(pixels, a.grid_size);
    a.hom = buffers.hom.get(), a.grid = buffers.grid.get();
    a.z0 = buffers.z0.get(), a.z1 = buffers.z1.get();
    a.wz0 = buffers.wz0.get(), a.wz1 = buffers.wz1.get();
    for (a.c0 = 0; a.c0 < a.n_ch; a.c0 += CELL - 1) {  // channels 3 at a time
        parallel_for(a.n_img * a.h, threads, 8 * pixels,
                     [&](int64_t b, int64_t e) { grid_prepare(a, b, e); });
        parallel_for(a.n_img * a.gh, threads, 32 * pixels + a.grid_size,
                     [&](int64_t b, int64_t e) { grid_splat(a, b, e); });
        parallel_for(a.n_img * a.h, threads, 32 * pixels,
                     [&](int64_t b, int64_t e) { grid_slice(a, b, e); });
    }
}

}  // namespace filters
}  // namespace rtd

/* The kernels of rtdenoise_ops for demo:affinity (Isik21): AffinityFilter and
 * TemporalAffinityFilter, the loops of runtime/kernels/affinity_filter.py and
 * temporal_affinity_filter.py in float32, one output row per work unit (the numba kernel's
 * tiles of 2048 pixels split a row only where it is wider; every pixel's sums run tap by tap
 * in the same order either way). Like numba's fastmath (its LLVM fuses a multiply and an add
 * where the CPU has FMA), this file lets the compiler contract them in the AVX2 and AVX-512
 * clones; nothing is reassociated.
 *
 * Non-finite inputs: as the numba drivers (`nan_on_nonfinite` over every input), one
 * finiteness pass per input before the kernel; a NaN or Inf anywhere fills the output with
 * NaN and the kernel does not run (docs/reliability.md).
 */
#if defined(__clang__)
#pragma clang fp contract(fast)
#elif defined(__GNUC__)
#pragma GCC optimize("fp-contract=fast")
#endif

#include <cstdio>

#include "kernels_common.h"

namespace rtd {
namespace affinity {

using namespace detail;

namespace {

constexpr float EPS = 1e-10f;  // ops/affinity_filter.py EPS (Isik21 eq. (6))
constexpr int64_t MAX_KERNEL_SIZE = 63;

bool inputs_finite(const Tensor *in, int count) {
    for (int i = 0; i < count; ++i)
        if (!all_finite(in[i].data, in[i].size())) return false;
    return true;
}

bool any_empty(const Tensor *in, int count) {
    for (int i = 0; i < count; ++i)
        if (in[i].size() == 0) return true;
    return false;
}

/* ops/affinity_filter.py kernel_size_value: the int of a kernel-size input, or "" in `error`
 * when it is an odd integer in [1, 63]. */
int64_t kernel_size_value(const char *op, const Tensor &t, std::string &error) {
    const double value = static_cast<double>(t.data[0]);
    const double rounded = std::nearbyint(value);
    if (rounded == value && rounded >= 1 && rounded <= MAX_KERNEL_SIZE &&
        static_cast<int64_t>(rounded) % 2 == 1)
        return static_cast<int64_t>(rounded);
    char text[64];
    std::snprintf(text, sizeof text, "%g", value);
    error = std::string(op) + ": kernel size must be an odd integer in [1, " +
            std::to_string(MAX_KERNEL_SIZE) + "], got " + text;
    return 0;
}

/* The kernel-size inputs `sizes` of a call, checked as the numba driver checks them: after
 * its finiteness guard, so a call with a NaN or Inf anywhere (the guard's NaN output) or an
 * empty array (zeros, no driver) is not refused for its kernel size. */
std::string check_sizes(const char *op, const Tensor *in, int n_in, const int *sizes, int count) {
    if (any_empty(in, n_in)) return "";
    for (int s = 0; s < count; ++s) {
        std::string error;
        kernel_size_value(op, in[sizes[s]], error);
        if (!error.empty()) return inputs_finite(in, n_in) ? error : "";
    }
    return "";
}

/* ops/affinity_filter.py check_guides: N, H, W of the first, 1 channel from the third on. */
std::string check_guides(const char *op, const Tensor *in, const char *const *names, int count) {
    std::string e = same_nhw(op, in, names, count);
    if (!e.empty()) return e;
    for (int i = 2; i < count; ++i)
        if (in[i].dims[1] != 1)
            return std::string(op) + ": " + names[i] + " has " + std::to_string(in[i].dims[1]) +
                   " channels; expected 1";
    return "";
}

std::string check_dilation(const char *op, int64_t d) {
    return d < 1 ? std::string(op) + " needs dilation >= 1, got " + std::to_string(d) : "";
}

/* ---- the row loops of kernels/affinity_filter.py (x in [x0, x1), neighbours at x + off) */

/* dist (= or +=) sum_{c' < c + 4} (f[c'][x] - g[c'][x + off])^2; f, g rows a plane apart. */
RTD_INLINE void dist4(float *RESTRICT dist, const float *RESTRICT f, const float *RESTRICT g,
                      int64_t hw, int64_t off, int64_t x0, int64_t x1, bool first) {
    const float *RESTRICT f1 = f + hw, *RESTRICT f2 = f1 + hw, *RESTRICT f3 = f2 + hw;
    const float *RESTRICT g1 = g + hw, *RESTRICT g2 = g1 + hw, *RESTRICT g3 = g2 + hw;
    if (first) {
        for (int64_t x = x0; x < x1; ++x) {
            const int64_t v = x + off;
            float t0 = f[x] - g[v], t1 = f1[x] - g1[v], t2 = f2[x] - g2[v], t3 = f3[x] - g3[v];
            dist[x] = t0 * t0 + t1 * t1 + t2 * t2 + t3 * t3;
        }
    } else {
        for (int64_t x = x0; x < x1; ++x) {
            const int64_t v = x + off;
            float t0 = f[x] - g[v], t1 = f1[x] - g1[v], t2 = f2[x] - g2[v], t3 = f3[x] - g3[v];
            dist[x] = dist[x] + (t0 * t0 + t1 * t1 + t2 * t2 + t3 * t3);
        }
    }
}

RTD_INLINE void dist1(float *RESTRICT dist, const float *RESTRICT f, const float *RESTRICT g,
                      int64_t off, int64_t x0, int64_t x1, bool first) {
    if (first) {
        for (int64_t x = x0; x < x1; ++x) {
            float t0 = f[x] - g[x + off];
            dist[x] = t0 * t0;
        }
    } else {
        for (int64_t x = x0; x < x1; ++x) {
            float t0 = f[x] - g[x + off];
            dist[x] = dist[x] + t0 * t0;
        }
    }
}

/* The last four feature channels of the distance, then w = exp(-a d) (`_weights4`). */
RTD_INLINE void weights4(float *RESTRICT weight, const float *RESTRICT dist, const float *RESTRICT a,
                         const float *RESTRICT f, const float *RESTRICT g, int64_t hw, int64_t off,
                         int64_t x0, int64_t x1, bool first) {
    const float *RESTRICT f1 = f + hw, *RESTRICT f2 = f1 + hw, *RESTRICT f3 = f2 + hw;
    const float *RESTRICT g1 = g + hw, *RESTRICT g2 = g1 + hw, *RESTRICT g3 = g2 + hw;
    if (first) {
        for (int64_t x = x0; x < x1; ++x) {
            const int64_t v = x + off;
            float t0 = f[x] - g[v], t1 = f1[x] - g1[v], t2 = f2[x] - g2[v], t3 = f3[x] - g3[v];
            float s = t0 * t0 + t1 * t1 + t2 * t2 + t3 * t3;
            weight[x] = exp_neg(-a[x] * s);
        }
    } else {
        for (int64_t x = x0; x < x1; ++x) {
            const int64_t v = x + off;
            float t0 = f[x] - g[v], t1 = f1[x] - g1[v], t2 = f2[x] - g2[v], t3 = f3[x] - g3[v];
            float s = t0 * t0 + t1 * t1 + t2 * t2 + t3 * t3;
            s += dist[x];
            weight[x] = exp_neg(-a[x] * s);
        }
    }
}

RTD_INLINE void weights(float *RESTRICT weight, const float *RESTRICT dist, const float *RESTRICT a,
                        int64_t x0, int64_t x1) {
    for (int64_t x = x0; x < x1; ++x) weight[x] = exp_neg(-a[x] * dist[x]);
}

RTD_INLINE void apply_mask(float *RESTRICT weight, const float *RESTRICT mask, int64_t off, int64_t x0,
                           int64_t x1) {
    for (int64_t x = x0; x < x1; ++x) weight[x] *= mask[x + off];
}

/* den += w; num[c] += w * values[c][x + off], three channels in one pass (`_accumulate3`). */
RTD_INLINE void accumulate3(float *RESTRICT num, float *RESTRICT den, const float *RESTRICT weight,
                            const float *RESTRICT values, int64_t w, int64_t hw, int64_t off,
                            int64_t x0, int64_t x1) {
    float *RESTRICT n0 = num, *RESTRICT n1 = num + w, *RESTRICT n2 = num + 2 * w;
    const float *RESTRICT v0 = values, *RESTRICT v1 = values + hw, *RESTRICT v2 = values + 2 * hw;
    for (int64_t x = x0; x < x1; ++x) {
        const int64_t v = x + off;
        const float wt = weight[x];
        den[x] += wt;
        n0[x] += wt * v0[v];
        n1[x] += wt * v1[v];
        n2[x] += wt * v2[v];
    }
}

RTD_INLINE void accumulate(float *RESTRICT num, float *RESTRICT den, const float *RESTRICT weight,
                           const float *RESTRICT values, int64_t n_ch, int64_t w, int64_t hw,
                           int64_t off, int64_t x0, int64_t x1) {
    for (int64_t x = x0; x < x1; ++x) den[x] += weight[x];
    for (int64_t c = 0; c < n_ch; ++c) {
        float *RESTRICT nc = num + c * w;
        const float *RESTRICT vc = values + c * hw;
        for (int64_t x = x0; x < x1; ++x) nc[x] += weight[x] * vc[x + off];
    }
}

struct Taps {  // one affinity_taps call: what the taps of one k x k kernel read
    const float *feats;   // (D, H, W) of image n: row y is compared
    const float *a;       // (W): the bandwidth of row y
    const float *values;  // (C, H, W): what the taps gather
    const float *guides;  // (D, H, W): what the taps compare with
    const float *mask;    // (H, W), or nullptr: no mask
    int64_t k, d;
    bool skip_centre;
};

/* kernels/affinity_filter.py affinity_taps: the taps of one kernel into num (C, W), den (W)
 * of output row y; dist, weight (W) scratch. */
RTD_INLINE void affinity_taps(const Taps &t, float *num, float *den, float *dist, float *weight,
                              int64_t n_ch, int64_t n_feat, int64_t h, int64_t w, int64_t y) {
    const int64_t hw = h * w;
    const bool fused = n_feat >= 4 && n_feat % 4 == 0;  // the last four go with the exp
    const int64_t plain = fused ? n_feat - 4 : n_feat;  // channels summed into dist first
    const int64_t r = t.k / 2;
    for (int64_t i = 0; i < t.k; ++i) {
        const int64_t yy = y + (i - r) * t.d;
        if (yy < 0 || yy >= h) continue;  // the whole tap row lies outside: weight 0
        for (int64_t j = 0; j < t.k; ++j) {
            if (t.skip_centre && i == r && j == r) continue;
            const int64_t off = (j - r) * t.d;
            const int64_t x0 = std::max<int64_t>(0, -off), x1 = std::min<int64_t>(w, w - off);
            if (x1 <= x0) continue;
            const float *f_row = t.feats + y * w, *g_row = t.guides + yy * w;
            // 1-2. w = exp(-a ||f_p - f_q||^2) (Isik21 eq. (4) / (7)): the distance four
            // channels per pass, the last four fused with the exp (fusing all eight into one
            // pass was slower: 0.89x numba against 1.16x at 720p, measured interleaved)
            for (int64_t c = 0; c < plain - plain % 4; c += 4)
                dist4(dist, f_row + c * hw, g_row + c * hw, hw, off, x0, x1, c == 0);
            for (int64_t c = plain - plain % 4; c < plain; ++c)
                dist1(dist, f_row + c * hw, g_row + c * hw, off, x0, x1, c == 0);
            if (fused)
                weights4(weight, dist, t.a, f_row + plain * hw, g_row + plain * hw, hw, off, x0,
                         x1, plain == 0);
            else
                weights(weight, dist, t.a, x0, x1);
            if (t.mask) apply_mask(weight, t.mask + yy * w, off, x0, x1);
            const float *v_row = t.values + yy * w;
            if (n_ch == 3)
                accumulate3(num, den, weight, v_row, w, hw, off, x0, x1);
            else
                accumulate(num, den, weight, v_row, n_ch, w, hw, off, x0, x1);
        }
    }
}

struct AffinityArgs {
    const float *image, *features, *bandwidth, *centre;
    const float *previous = nullptr, *previous_features = nullptr, *temporal_bandwidth = nullptr,
                *valid = nullptr;  // TemporalAffinityFilter only
    float *out;
    int64_t n_ch, n_feat, h, w, k, kt, d;
};

/* kernels/affinity_filter.py spatial_sums + normalise (and, with a previous frame,
 * temporal_affinity_filter.py's temporal taps between them) for output rows [begin, end). */
RTD_CLONES void affinity_rows(const AffinityArgs &a, int64_t begin, int64_t end) {
    const int64_t n_ch = a.n_ch, n_feat = a.n_feat, h = a.h, w = a.w, hw = h * w;
    std::vector<float> buffer(static_cast<size_t>((n_ch + 3) * w));
    float *num = buffer.data(), *den = num + n_ch * w, *dist = den + w, *weight = dist + w;
    for (int64_t row = begin; row < end; ++row) {
        const int64_t n = row / h, y = row - n * h;
        const float *image = a.image + n * n_ch * hw;
        const float *feats = a.features + n * n_feat * hw;
        {  // the centre tap starts the sums (Isik21 eq. (4))
            const float *RESTRICT c_row = a.centre + n * hw + y * w;
            float *RESTRICT dn = den;
            for (int64_t x = 0; x < w; ++x) dn[x] = c_row[x];
            for (int64_t c = 0; c < n_ch; ++c) {
                float *RESTRICT nc = num + c * w;
                const float *RESTRICT src = image + c * hw + y * w;
                for (int64_t x = 0; x < w; ++x) nc[x] = c_row[x] * src[x];
            }
        }
        Taps spatial{feats, a.bandwidth + n * hw + y * w, image, feats, nullptr, a.k, a.d, true};
        affinity_taps(spatial, num, den, dist, weight, n_ch, n_feat, h, w, y);
        if (a.previous) {  // eq. (7): the temporal kernel, no centre weight, masked
            Taps temporal{feats, a.temporal_bandwidth + n * hw + y * w, a.previous + n * n_ch * hw,
                          a.previous_features + n * n_feat * hw, a.valid + n * hw, a.kt, 1, false};
            affinity_taps(temporal, num, den, dist, weight, n_ch, n_feat, h, w, y);
        }
        {  // eq. (6) / (8): out = num / (1e-10 + den)
            float *RESTRICT dn = den;
            for (int64_t x = 0; x < w; ++x) dn[x] = 1.0f / (EPS + dn[x]);
            for (int64_t c = 0; c < n_ch; ++c) {
                float *RESTRICT o = a.out + (n * n_ch + c) * hw + y * w;
                const float *RESTRICT nc = num + c * w;
                for (int64_t x = 0; x < w; ++x) o[x] = nc[x] * dn[x];
            }
        }
    }
}

void run_rows(const AffinityArgs &a, int64_t n_img, int threads) {
    const int64_t taps = a.k * a.k + (a.previous ? a.kt * a.kt : 0);
    parallel_for(n_img * a.h, threads, n_img * a.h * a.w * taps * (a.n_feat + a.n_ch + 4),
                 [&](int64_t b, int64_t e) { affinity_rows(a, b, e); });
}

bool nan_if_nonfinite(const Tensor *in, int n_in, Tensor &out) {
    if (inputs_finite(in, n_in)) return false;
    std::fill(out.data, out.data + out.size(), std::nanf(""));
    return true;
}

const char *const AFFINITY_IN[] = {"image", "features", "bandwidth", "centre", "kernel_size"};
const char *const TEMPORAL_IN[] = {"image", "features", "bandwidth", "centre", "previous",
                                   "previous_features", "temporal_bandwidth", "valid",
                                   "kernel_size", "temporal_size"};

}  // namespace

/* ------------------------------------------------------------------ AffinityFilter */

std::string affinity_filter_shapes(const Tensor *in, const int64_t *attrs, Shape *out) {
    const char *op = "AffinityFilter";
    std::string e = check_dilation(op, attrs[0]);
    if (e.empty()) e = check_guides(op, in, AFFINITY_IN, 4);
    const int sizes[] = {4};
    if (e.empty()) e = check_sizes(op, in, 5, sizes, 1);
    if (e.empty()) copy_shape(in[0], out[0]);
    return e;
}

void affinity_filter_run(const Tensor *in, Tensor *out, const int64_t *attrs, int threads) {
    if (nan_if_nonfinite(in, 5, out[0])) return;  // as nan_on_nonfinite(5)
    std::string error;
    AffinityArgs a{};
    a.image = in[0].data, a.features = in[1].data, a.bandwidth = in[2].data, a.centre = in[3].data;
    a.out = out[0].data;
    a.n_ch = in[0].dims[1], a.n_feat = in[1].dims[1], a.h = in[0].dims[2], a.w = in[0].dims[3];
    a.k = kernel_size_value("AffinityFilter", in[4], error), a.kt = 0, a.d = attrs[0];
    run_rows(a, in[0].dims[0], threads);
}

/* ------------------------------------------------------------------ TemporalAffinityFilter */

std::string temporal_affinity_filter_shapes(const Tensor *in, const int64_t *attrs, Shape *out) {
    const char *op = "TemporalAffinityFilter";
    std::string e = check_dilation(op, attrs[0]);
    if (e.empty()) e = check_guides(op, in, TEMPORAL_IN, 4);
    if (e.empty()) e = check_guides(op, in + 4, TEMPORAL_IN + 4, 4);
    if (e.empty()) {
        const Tensor pair[] = {in[0], in[4]};
        const char *names[] = {"image", "previous"};
        e = same_nhw(op, pair, names, 2);
    }
    if (e.empty()) {
        bool same = true;
        for (int d = 0; d < 4; ++d)
            same = same && in[4].dims[d] == in[0].dims[d] && in[5].dims[d] == in[1].dims[d];
        if (!same)
            e = std::string(op) + ": previous " + fmt_shape(in[4]) + " and previous_features " +
                fmt_shape(in[5]) + " must have the shapes of image " + fmt_shape(in[0]) +
                " and features " + fmt_shape(in[1]);
    }
    const int sizes[] = {8, 9};
    if (e.empty()) e = check_sizes(op, in, 10, sizes, 2);
    if (e.empty()) copy_shape(in[0], out[0]);
    return e;
}

void temporal_affinity_filter_run(const Tensor *in, Tensor *out, const int64_t *attrs,
                                  int threads) {
    if (nan_if_nonfinite(in, 10, out[0])) return;  // as nan_on_nonfinite(10)
    std::string error;
    AffinityArgs a{};
    a.image = in[0].data, a.features = in[1].data, a.bandwidth = in[2].data, a.centre = in[3].data;
    a.previous = in[4].data, a.previous_features = in[5].data;
    a.temporal_bandwidth = in[6].data, a.valid = in[7].data;
    a.out = out[0].data;
    a.n_ch = in[0].dims[1], a.n_feat = in[1].dims[1], a.h = in[0].dims[2], a.w = in[0].dims[3];
    a.k = kernel_size_value("TemporalAffinityFilter", in[8], error);
    a.kt = kernel_size_value("TemporalAffinityFilter", in[9], error);
    a.d = attrs[0];
    run_rows(a, in[0].dims[0], threads);
}

/* ------------------------------------------------------------------ the table */

namespace {
const char *const DILATION[] = {"dilation"};
constexpr int AF_RANKS[] = {4, 4, 4, 4, 0};
constexpr int TAF_RANKS[] = {4, 4, 4, 4, 4, 4, 4, 4, 0, 0};

const OpDef OPS[] = {
    {"AffinityFilter", 5, 1, AF_RANKS, AFFINITY_IN, DILATION, 1, affinity_filter_shapes,
     affinity_filter_run},
    {"TemporalAffinityFilter", 10, 1, TAF_RANKS, TEMPORAL_IN, DILATION, 1,
     temporal_affinity_filter_shapes, temporal_affinity_filter_run},
};
}  // namespace

}  // namespace affinity

const OpDef *affinity_op_table(int *count) {
    *count = static_cast<int>(sizeof affinity::OPS / sizeof affinity::OPS[0]);
    return affinity::OPS;
}

}  // namespace rtd

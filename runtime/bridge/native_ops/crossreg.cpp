/* The kernels of rtdenoise_ops for demo:crossreg (Choi24): CrossRegression (float64
 * throughout, as every form of it) and CrossBilateralFilter (float32), the loops of
 * runtime/kernels/cross_regression.py and cross_bilateral_filter.py. Like numba's fastmath,
 * this file lets the compiler contract a multiply and an add into an FMA in the AVX2 and
 * AVX-512 clones; nothing is reassociated.
 *
 * Non-finite inputs: CrossRegression as its numba driver (`nan_on_nonfinite(4)`): one
 * finiteness pass per input before the kernel, a NaN or Inf anywhere fills both pilots with
 * NaN (docs/reliability.md). CrossBilateralFilter, like its numba kernel, has no guard: NaN
 * and Inf go through IEEE arithmetic (the runtime's input guard keeps them out of the graph,
 * and CrossRegression's NaN pilots reach it only as NaN).
 */
#if defined(__clang__)
#pragma clang fp contract(fast)
#elif defined(__GNUC__)
#pragma GCC optimize("fp-contract=fast")
#endif

#include <cstdlib>

#include "kernels_common.h"

namespace rtd {
namespace crossreg {

using namespace detail;

namespace {

/* kernels/cross_bilateral_filter.py mirror: k reflected into [0, n) without repeating the
 * edge (period 2 (n - 1)); n >= 2. */
inline int64_t mirror(int64_t k, int64_t n) {
    if (k >= 0 && k < n) return k;
    const int64_t period = 2 * (n - 1);
    const int64_t a = (k < 0 ? -k : k) % period;
    return a >= n ? period - a : a;
}

std::string three_channels(const char *op, const Tensor *in, const char *const *names, int count) {
    for (int i = 0; i < count; ++i)
        if (in[i].dims[1] != 3)
            return std::string(op) + ": " + names[i] + " has " + std::to_string(in[i].dims[1]) +
                   " channels; expected 3";
    return "";
}

std::string mirrorable(const char *op, const Tensor &t) {
    if (t.dims[2] >= 2 && t.dims[3] >= 2) return "";
    return std::string(op) + ": image " + fmt_shape(t) + " is too small to mirror (H, W >= 2)";
}

/* ================================================================== CrossBilateralFilter */

const char *const CBF_IN[] = {"pilot_a", "pilot_b", "albedo", "normal", "band"};
constexpr int64_t BANDS = 5;
constexpr int64_t GUIDES = 12;  // pilot A, pilot B, albedo, normal: 3 channels each
constexpr int64_t SUMS = 20;    // per pilot: [m f, m], then [m D_k f, m D_k] for 4 distances

/* One output row's chunk of at most CBF_CHUNK pixels, all taps: the chunk's 40 sums (20 per
 * pilot: [m f, m], then [m D_k f, m D_k] for k = colour, albedo, normal, position) stay in
 * L1-sized local rows for the whole window, and each tap is one fused, branch-free loop over
 * the chunk (the four squared distances, both exponents of eq. (9), both weights, the 40
 * sums). Each sum adds the same terms in the same (iy, ix) order as the numba kernel
 * (kernels/cross_bilateral_filter.py `_distances`, `exp_row`, `_accumulate`), which streams
 * the whole row's 40 sums through the cache once per tap instead. */
constexpr int64_t CBF_CHUNK = 64;

struct CbfArgs {
    const float *guides[4];  // pilot_a, pilot_b, albedo, normal (N, 3, H, W)
    const float *band;       // (N, 5, H, W)
    float *sum_a, *sum_b, *dsum_a, *dsum_b;
    int64_t h, w, window;
};

/* kernels/common.py exp_row: exp(arg) for arg <= 0 (2^k from the exponent bits, 2^f from a
 * degree-6 polynomial). */
RTD_INLINE void exp_row(float *RESTRICT dst, const float *RESTRICT arg, int64_t w) {
    for (int64_t x = 0; x < w; ++x) {
        float t = max_like_numba(arg[x] * 1.442695f, -126.0f);
        float s = t + 0.5f;  // floor(s), s in [-125.5, 0.5]: a truncation, one down if above
        float k = static_cast<float>(static_cast<int32_t>(s));
        k -= bits_to_float(-static_cast<int32_t>(k > s) & 0x3f800000);
        float f = t - k;
        float p = 0.0001540353f;
        p = p * f + 0.001333355f;
        p = p * f + 0.009618129f;
        p = p * f + 0.05550411f;
        p = p * f + 0.2402265f;
        p = p * f + 0.6931472f;
        p = p * f + 1.0f;
        dst[x] = bits_to_float(static_cast<int32_t>(static_cast<uint32_t>(static_cast<int32_t>(k) + 127) << 23)) * p;
    }
}

/* The squared distances of tap `off` (colour A, colour B, albedo, normal) and the exponents
 * of m^A, m^B (eq. (9)) over the row (`_distances`). */
RTD_INLINE void distances(const float *RESTRICT pad, int64_t wp, const float *const *cen,
                          const float *RESTRICT band, int64_t hw, int64_t off, float dist_p,
                          float *RESTRICT d, float *RESTRICT arg_a, float *RESTRICT arg_b, int64_t w) {
    const float *RESTRICT p0 = pad + off, *RESTRICT p1 = p0 + wp, *RESTRICT p2 = p1 + wp,
                          *RESTRICT p3 = p2 + wp, *RESTRICT p4 = p3 + wp, *RESTRICT p5 = p4 + wp,
                          *RESTRICT p6 = p5 + wp, *RESTRICT p7 = p6 + wp, *RESTRICT p8 = p7 + wp,
                          *RESTRICT p9 = p8 + wp, *RESTRICT p10 = p9 + wp, *RESTRICT p11 = p10 + wp;
    const float *RESTRICT c0 = cen[0], *RESTRICT c1 = cen[1], *RESTRICT c2 = cen[2],
                          *RESTRICT c3 = cen[3], *RESTRICT c4 = cen[4], *RESTRICT c5 = cen[5],
                          *RESTRICT c6 = cen[6], *RESTRICT c7 = cen[7], *RESTRICT c8 = cen[8],
                          *RESTRICT c9 = cen[9], *RESTRICT c10 = cen[10], *RESTRICT c11 = cen[11];
    const float *RESTRICT b0 = band, *RESTRICT b1 = b0 + hw, *RESTRICT b2 = b1 + hw,
                          *RESTRICT b3 = b2 + hw, *RESTRICT b4 = b3 + hw;
    float *RESTRICT d0 = d, *RESTRICT d1 = d + w, *RESTRICT d2 = d + 2 * w, *RESTRICT d3 = d + 3 * w;
    for (int64_t x = 0; x < w; ++x) {
        float e0 = p0[x] - c0[x], e1 = p1[x] - c1[x], e2 = p2[x] - c2[x];
        float da = e0 * e0 + e1 * e1 + e2 * e2;
        e0 = p3[x] - c3[x], e1 = p4[x] - c4[x], e2 = p5[x] - c5[x];
        float db = e0 * e0 + e1 * e1 + e2 * e2;
        e0 = p6[x] - c6[x], e1 = p7[x] - c7[x], e2 = p8[x] - c8[x];
        float dr = e0 * e0 + e1 * e1 + e2 * e2;
        e0 = p9[x] - c9[x], e1 = p10[x] - c10[x], e2 = p11[x] - c11[x];
        float dn = e0 * e0 + e1 * e1 + e2 * e2;
        float shared = b2[x] * dr + b3[x] * dn + b4[x] * dist_p;
        d0[x] = da;
        d1[x] = db;
        d2[x] = dr;
        d3[x] = dn;
        arg_a[x] = -(b0[x] * da + shared);
        arg_b[x] = -(b1[x] * db + shared);
    }
}

/* Buffer `f`'s (pilot A or B, 3 padded rows) terms of one tap into its 20 row sums `acc`
 * (`_accumulate`). */
RTD_INLINE void accumulate(const float *RESTRICT f, int64_t wp, const float *RESTRICT m,
                           const float *RESTRICT dist_f, const float *RESTRICT dist_r,
                           const float *RESTRICT dist_n, float dist_p, float *RESTRICT acc, int64_t w) {
    const float *RESTRICT fa = f, *RESTRICT fb = f + wp, *RESTRICT fc = f + 2 * wp;
    for (int64_t x = 0; x < w; ++x) {
        float wt = m[x];
        float f0 = fa[x], f1 = fb[x], f2 = fc[x];
        acc[x] += wt * f0;
        acc[w + x] += wt * f1;
        acc[2 * w + x] += wt * f2;
        acc[3 * w + x] += wt;
        float wd = wt * dist_f[x];
        acc[4 * w + x] += wd * f0;
        acc[5 * w + x] += wd * f1;
        acc[6 * w + x] += wd * f2;
        acc[7 * w + x] += wd;
        wd = wt * dist_r[x];
        acc[8 * w + x] += wd * f0;
        acc[9 * w + x] += wd * f1;
        acc[10 * w + x] += wd * f2;
        acc[11 * w + x] += wd;
        wd = wt * dist_n[x];
        acc[12 * w + x] += wd * f0;
        acc[13 * w + x] += wd * f1;
        acc[14 * w + x] += wd * f2;
        acc[15 * w + x] += wd;
        wd = wt * dist_p;
        acc[16 * w + x] += wd * f0;
        acc[17 * w + x] += wd * f1;
        acc[18 * w + x] += wd * f2;
        acc[19 * w + x] += wd;
    }
}

RTD_CLONES void cbf_rows(const CbfArgs &a, int64_t begin, int64_t end) {
    constexpr int64_t C = CBF_CHUNK;
    const int64_t h = a.h, w = a.w, r = a.window / 2, pw = C + 2 * r;  // pw: a pad row
    const float inv_r2 = static_cast<float>(1.0 / static_cast<double>(r * r));
    // pad: the 12 guide rows of the chunk and its margins; cen: the 12 centre rows; bnd: the
    // 5 band rows; acc: 2 x 20 sums; d, arg, m: one tap's distances, exponents, weights
    std::vector<float> buffer(static_cast<size_t>(GUIDES * pw + (GUIDES + BANDS + 2 * SUMS + 8) * C));
    float *pad = buffer.data(), *cen_rows = pad + GUIDES * pw, *bnd = cen_rows + GUIDES * C,
          *acc_a = bnd + BANDS * C, *acc_b = acc_a + SUMS * C, *d = acc_b + SUMS * C,
          *arg_a = d + 4 * C, *arg_b = arg_a + C, *m_a = arg_b + C, *m_b = m_a + C;
    const float *cen[GUIDES];
    for (int64_t g = 0; g < GUIDES; ++g) cen[g] = cen_rows + g * C;
    // a chunk's pad column x reads image column sx_of[x0 + x] (mirrored); past the image's
    // last chunk it repeats the last column (those pixels are computed and dropped)
    std::vector<int64_t> sx_of(static_cast<size_t>(w + C + 2 * r));
    for (int64_t x = 0; x < w + C + 2 * r; ++x)
        sx_of[static_cast<size_t>(x)] = x - r < w + r ? mirror(x - r, w) : mirror(w - 1 + r, w);
    for (int64_t row = begin; row < end; ++row) {
        const int64_t n = row / h, y = row - n * h;
        for (int64_t x0 = 0; x0 < w; x0 += C) {
            const int64_t cw = std::min<int64_t>(C, w - x0);  // the chunk's image pixels
            for (int64_t g = 0; g < 4; ++g)
                for (int64_t c = 0; c < 3; ++c) {
                    const float *src = a.guides[g] + ((n * 3 + c) * h + y) * w + x0;
                    std::copy_n(src, cw, cen_rows + (g * 3 + c) * C);
                    std::fill(cen_rows + (g * 3 + c) * C + cw, cen_rows + (g * 3 + c + 1) * C, src[cw - 1]);
                }
            for (int64_t b = 0; b < BANDS; ++b) {
                const float *src = a.band + ((n * BANDS + b) * h + y) * w + x0;
                std::copy_n(src, cw, bnd + b * C);
                std::fill(bnd + b * C + cw, bnd + (b + 1) * C, src[cw - 1]);
            }
            std::fill(acc_a, acc_a + 2 * SUMS * C, 0.0f);
            for (int64_t iy = 0; iy < a.window; ++iy) {
                const int64_t sy = mirror(y + iy - r, h);
                for (int64_t g = 0; g < 4; ++g)
                    for (int64_t c = 0; c < 3; ++c) {
                        const float *RESTRICT src = a.guides[g] + ((n * 3 + c) * h + sy) * w;
                        float *RESTRICT dst = pad + (g * 3 + c) * pw;
                        const int64_t *RESTRICT sx = sx_of.data() + x0;
                        for (int64_t x = 0; x < pw; ++x) dst[x] = src[sx[x]];
                    }
                for (int64_t ix = 0; ix < a.window; ++ix) {
                    const float dist_p =
                        static_cast<float>((iy - r) * (iy - r) + (ix - r) * (ix - r)) * inv_r2;
                    distances(pad, pw, cen, bnd, C, ix, dist_p, d, arg_a, arg_b, C);
                    exp_row(m_a, arg_a, C);
                    exp_row(m_b, arg_b, C);
                    accumulate(pad + ix, pw, m_a, d, d + 2 * C, d + 3 * C, dist_p, acc_a, C);
                    accumulate(pad + 3 * pw + ix, pw, m_b, d + C, d + 2 * C, d + 3 * C, dist_p, acc_b, C);
                }
            }
            for (int64_t c = 0; c < 4; ++c) {
                std::copy_n(acc_a + c * C, cw, a.sum_a + ((n * 4 + c) * h + y) * w + x0);
                std::copy_n(acc_b + c * C, cw, a.sum_b + ((n * 4 + c) * h + y) * w + x0);
            }
            for (int64_t c = 0; c < 16; ++c) {
                std::copy_n(acc_a + (4 + c) * C, cw, a.dsum_a + ((n * 16 + c) * h + y) * w + x0);
                std::copy_n(acc_b + (4 + c) * C, cw, a.dsum_b + ((n * 16 + c) * h + y) * w + x0);
            }
        }
    }
}

/* ================================================================== CrossRegression */

const char *const CR_IN[] = {"y_a", "y_b", "albedo", "normal"};
constexpr int64_t P = 6;
constexpr int64_t NQ = 14;  // y (3), albedo (3), normal (3), sigma, var, target (3)
constexpr int64_t NSUM = 61;

struct CrArgs {
    const float *y_a, *y_b, *albedo, *normal;
    float *pilot_a, *pilot_b;
    int64_t n, h, w, window, stride, hc, wc, lo, hi;
    double *q;     // (2N, 14, H, W)
    double *beta;  // (2N, Hc, Wc, 3, 6)
};

/* kernels/cross_regression.py _stack: q of regression b (A's variables against y^B for
 * b < N, then B's against y^A), var over the in-image 3x3 neighbours. */
RTD_CLONES void cr_stack(const CrArgs &a, int64_t begin, int64_t end) {
    const int64_t n_img = a.n, h = a.h, w = a.w, hw = h * w;
    for (int64_t row = begin; row < end; ++row) {
        const int64_t b = row / h, yy = row - b * h, m = b % n_img;
        const float *y = (b < n_img ? a.y_a : a.y_b) + m * 3 * hw;
        const float *target = (b < n_img ? a.y_b : a.y_a) + m * 3 * hw;
        const float *albedo = a.albedo + m * 3 * hw, *normal = a.normal + m * 3 * hw;
        double *q = a.q + b * NQ * hw;
        for (int64_t c = 0; c < 3; ++c)
            for (int64_t x = 0; x < w; ++x) {
                const int64_t at = c * hw + yy * w + x;
                q[c * hw + yy * w + x] = y[at];
                q[(3 + c) * hw + yy * w + x] = albedo[at];
                q[(6 + c) * hw + yy * w + x] = normal[at];
                q[(11 + c) * hw + yy * w + x] = target[at];
            }
        const int64_t y0 = std::max<int64_t>(0, yy - 1), y1 = std::min<int64_t>(h, yy + 2);
        for (int64_t x = 0; x < w; ++x) {
            const int64_t x0 = std::max<int64_t>(0, x - 1), x1 = std::min<int64_t>(w, x + 2);
            const int64_t count = (y1 - y0) * (x1 - x0) - 1;
            double var = 0.0;
            for (int64_t c = 0; c < 3; ++c) {
                double total = 0.0;
                for (int64_t sy = y0; sy < y1; ++sy)
                    for (int64_t sx = x0; sx < x1; ++sx) total += y[c * hw + sy * w + sx];
                const double centre = y[c * hw + yy * w + x];
                const double dv = centre - (total - centre) / static_cast<double>(count);
                var += dv * dv;
            }
            q[9 * hw + yy * w + x] = std::sqrt(var);
            q[10 * hw + yy * w + x] = var;
        }
    }
}

/* kernels/cross_regression.py _centre_sums: the 61 distinct sums of X^T W X and X^T W y over
 * the mirrored window of centre (cy, cx), in local accumulators. */
RTD_INLINE void centre_sums(const double *q, int64_t h, int64_t w, int64_t cy, int64_t cx, int64_t r,
                            double *RESTRICT acc) {
    const int64_t hw = h * w, at = cy * w + cx;
    const double c0 = q[at], c1 = q[hw + at], c2 = q[2 * hw + at];
    const double ca[3] = {q[3 * hw + at], q[4 * hw + at], q[5 * hw + at]};
    const double cn0 = q[6 * hw + at], cn1 = q[7 * hw + at], cn2 = q[8 * hw + at];
    const double csig = q[9 * hw + at], cvar = q[10 * hw + at];
    for (int64_t k = 0; k < NSUM; ++k) acc[k] = 0.0;
    for (int64_t dy = -r; dy <= r; ++dy) {
        const int64_t sy = mirror(cy + dy, h);
        for (int64_t dx = -r; dx <= r; ++dx) {
            const int64_t s = sy * w + mirror(cx + dx, w);
            const double d0 = q[s] - c0, d1 = q[hw + s] - c1, d2 = q[2 * hw + s] - c2;
            double wgt = std::exp(-(d0 * d0 + d1 * d1 + d2 * d2) / (cvar + q[10 * hw + s] + 1e-4));
            wgt += 1e-7;
            const double inv = 1.0 / (csig + q[9 * hw + s] + 1e-2);
            const double n0 = q[6 * hw + s] - cn0, n1 = q[7 * hw + s] - cn1, n2 = q[8 * hw + s] - cn2;
            const double wn0 = wgt * n0, wn1 = wgt * n1, wn2 = wgt * n2;
            acc[0] += wgt;
            acc[1] += wn0;
            acc[2] += wn1;
            acc[3] += wn2;
            acc[4] += wn0 * n0;
            acc[5] += wn0 * n1;
            acc[6] += wn0 * n2;
            acc[7] += wn1 * n1;
            acc[8] += wn1 * n2;
            acc[9] += wn2 * n2;
            const double dc[3] = {d0, d1, d2};
            for (int64_t c = 0; c < 3; ++c) {
                const double x1 = dc[c] * inv;
                const double x2 = q[(3 + c) * hw + s] - ca[c];
                const double t = q[(11 + c) * hw + s];
                const double wx1 = wgt * x1, wx2 = wgt * x2, wt = wgt * t;
                double *RESTRICT k = acc + 10 + 17 * c;
                k[0] += wx1;
                k[1] += wx2;
                k[2] += wx1 * x1;
                k[3] += wx1 * x2;
                k[4] += wx2 * x2;
                k[5] += wx1 * n0;
                k[6] += wx1 * n1;
                k[7] += wx1 * n2;
                k[8] += wx2 * n0;
                k[9] += wx2 * n1;
                k[10] += wx2 * n2;
                k[11] += wt;
                k[12] += wx1 * t;
                k[13] += wx2 * t;
                k[14] += wt * n0;
                k[15] += wt * n1;
                k[16] += wt * n2;
            }
        }
    }
}

/* kernels/cross_regression.py _solve: beta (6) of channel c, a Cholesky solve of the ridge
 * system assembled from the sums. */
RTD_INLINE void solve(const double *acc, int64_t c, double *RESTRICT beta) {
    double a[P][P], rhs[P], low[P][P] = {}, z[P];
    const int64_t k = 10 + 17 * c;
    a[0][0] = acc[0];
    a[0][1] = acc[k];
    a[0][2] = acc[k + 1];
    a[0][3] = acc[1];
    a[0][4] = acc[2];
    a[0][5] = acc[3];
    a[1][1] = acc[k + 2];
    a[1][2] = acc[k + 3];
    a[1][3] = acc[k + 5];
    a[1][4] = acc[k + 6];
    a[1][5] = acc[k + 7];
    a[2][2] = acc[k + 4];
    a[2][3] = acc[k + 8];
    a[2][4] = acc[k + 9];
    a[2][5] = acc[k + 10];
    a[3][3] = acc[4];
    a[3][4] = acc[5];
    a[3][5] = acc[6];
    a[4][4] = acc[7];
    a[4][5] = acc[8];
    a[5][5] = acc[9];
    for (int64_t i = 0; i < P; ++i) {
        a[i][i] += 1e-3;
        rhs[i] = acc[k + 11 + i];
    }
    for (int64_t i = 0; i < P; ++i)
        for (int64_t m = 0; m <= i; ++m) {
            double s = a[m][i];  // the upper triangle holds the sums
            for (int64_t t = 0; t < m; ++t) s -= low[i][t] * low[m][t];
            low[i][m] = i == m ? std::sqrt(s) : s / low[m][m];
        }
    for (int64_t i = 0; i < P; ++i) {
        double s = rhs[i];
        for (int64_t t = 0; t < i; ++t) s -= low[i][t] * z[t];
        z[i] = s / low[i][i];
    }
    for (int64_t i = P - 1; i >= 0; --i) {
        double s = z[i];
        for (int64_t t = i + 1; t < P; ++t) s -= low[t][i] * beta[t];
        beta[i] = s / low[i][i];
    }
}

/* kernels/cross_regression.py _regress: tasks (regression b, centre row i). */
RTD_CLONES void cr_regress(const CrArgs &a, int64_t begin, int64_t end) {
    const int64_t h = a.h, w = a.w, hc = a.hc, wc = a.wc, r = a.window / 2;
    double acc[NSUM];
    for (int64_t task = begin; task < end; ++task) {
        const int64_t b = task / hc, i = task - b * hc;
        const double *q = a.q + b * NQ * h * w;
        for (int64_t j = 0; j < wc; ++j) {
            centre_sums(q, h, w, a.stride * i, a.stride * j, r, acc);
            for (int64_t c = 0; c < 3; ++c) solve(acc, c, a.beta + (((b * hc + i) * wc + j) * 3 + c) * P);
        }
    }
}

/* kernels/cross_regression.py _reconstruct: eq. (5) over the covering centres, clamped >= 0,
 * rows of regression b into pilot_a (b < N) or pilot_b. */
RTD_CLONES void cr_reconstruct(const CrArgs &a, int64_t begin, int64_t end) {
    const int64_t h = a.h, w = a.w, hw = h * w, hc = a.hc, wc = a.wc, r = a.window / 2;
    const int64_t stride = a.stride, lo = a.lo, hi = a.hi;
    for (int64_t row = begin; row < end; ++row) {
        const int64_t b = row / h, y = row - b * h;
        const double *q = a.q + b * NQ * hw;
        float *pilot = b < a.n ? a.pilot_a + b * 3 * hw : a.pilot_b + (b - a.n) * 3 * hw;
        for (int64_t x = 0; x < w; ++x) {
            const int64_t p = y * w + x;
            const double p0 = q[p], p1 = q[hw + p], p2 = q[2 * hw + p];
            const double psig = q[9 * hw + p], pvar = q[10 * hw + p];
            double num0 = 0.0, num1 = 0.0, num2 = 0.0, den = 0.0;
            for (int64_t dj = -lo; dj <= hi; ++dj) {
                const int64_t jy = y / stride + dj;
                if (jy < 0 || jy >= hc || std::abs(y - stride * jy) > r) continue;
                const int64_t cy = stride * jy;
                for (int64_t di = -lo; di <= hi; ++di) {
                    const int64_t ix = x / stride + di;
                    if (ix < 0 || ix >= wc || std::abs(x - stride * ix) > r) continue;
                    const int64_t cx = stride * ix, c_at = cy * w + cx;
                    const double dy0 = p0 - q[c_at], dy1 = p1 - q[hw + c_at], dy2 = p2 - q[2 * hw + c_at];
                    const double spread = q[10 * hw + c_at] + pvar + 1e-4;
                    const double wgt = std::exp(-(dy0 * dy0 + dy1 * dy1 + dy2 * dy2) / spread) + 1e-7;
                    const double inv = 1.0 / (q[9 * hw + c_at] + psig + 1e-2);
                    const double n0 = q[6 * hw + p] - q[6 * hw + c_at];
                    const double n1 = q[7 * hw + p] - q[7 * hw + c_at];
                    const double n2 = q[8 * hw + p] - q[8 * hw + c_at];
                    const double dyc[3] = {dy0, dy1, dy2};
                    double *num[3] = {&num0, &num1, &num2};
                    for (int64_t c = 0; c < 3; ++c) {
                        const double *co = a.beta + (((b * hc + jy) * wc + ix) * 3 + c) * P;
                        const double x2 = q[(3 + c) * hw + p] - q[(3 + c) * hw + c_at];
                        double pred = co[0] + co[1] * dyc[c] * inv + co[2] * x2;
                        pred += co[3] * n0 + co[4] * n1 + co[5] * n2;
                        *num[c] += wgt * pred;
                    }
                    den += wgt;
                }
            }
            // numba's max(v, 0.0): 0 where 0 > v, else v (NaN stays NaN)
            const double v0 = num0 / den, v1 = num1 / den, v2 = num2 / den;
            pilot[p] = static_cast<float>(0.0 > v0 ? 0.0 : v0);
            pilot[hw + p] = static_cast<float>(0.0 > v1 ? 0.0 : v1);
            pilot[2 * hw + p] = static_cast<float>(0.0 > v2 ? 0.0 : v2);
        }
    }
}

}  // namespace

/* ------------------------------------------------------------------ CrossBilateralFilter */

std::string cross_bilateral_filter_shapes(const Tensor *in, const int64_t *attrs, Shape *out) {
    const char *op = "CrossBilateralFilter";
    const int64_t window = attrs[0];
    if (window < 3 || window % 2 == 0)
        return std::string(op) + " needs an odd window >= 3, got " + std::to_string(window);
    std::string e = same_nhw(op, in, CBF_IN, 5);
    if (e.empty()) e = three_channels(op, in, CBF_IN, 4);
    if (e.empty() && in[4].dims[1] != BANDS)
        e = std::string(op) + ": band has " + std::to_string(in[4].dims[1]) +
            " channels; expected 5 (band_A, band_B, band_albedo, band_normal, band_position)";
    if (e.empty()) e = mirrorable(op, in[0]);
    if (!e.empty()) return e;
    const int64_t n = in[0].dims[0], h = in[0].dims[2], w = in[0].dims[3];
    set_shape(out[0], n, 4, h, w);
    set_shape(out[1], n, 4, h, w);
    set_shape(out[2], n, 16, h, w);
    set_shape(out[3], n, 16, h, w);
    return "";
}

void cross_bilateral_filter_run(const Tensor *in, Tensor *out, const int64_t *attrs, int threads) {
    CbfArgs a{{in[0].data, in[1].data, in[2].data, in[3].data}, in[4].data,
              out[0].data, out[1].data, out[2].data, out[3].data,
              in[0].dims[2], in[0].dims[3], attrs[0]};
    const int64_t rows = in[0].dims[0] * a.h;
    parallel_for(rows, threads, rows * a.w * a.window * a.window * 100,
                 [&](int64_t b, int64_t e) { cbf_rows(a, b, e); });
}

/* ------------------------------------------------------------------ CrossRegression */

std::string cross_regression_shapes(const Tensor *in, const int64_t *attrs, Shape *out) {
    const char *op = "CrossRegression";
    const int64_t window = attrs[0], stride = attrs[1];
    if (window < 3 || window % 2 == 0 || stride < 1 || stride > window / 2 + 1)
        return std::string(op) + " needs an odd window >= 3 and 1 <= stride <= window // 2 + 1 "
               "(every pixel covered), got window=" + std::to_string(window) + ", stride=" +
               std::to_string(stride);
    std::string e = same_nhw(op, in, CR_IN, 4);
    if (e.empty()) e = three_channels(op, in, CR_IN, 4);
    if (e.empty()) e = mirrorable(op, in[0]);
    if (!e.empty()) return e;
    copy_shape(in[0], out[0]);
    copy_shape(in[0], out[1]);
    return "";
}

void cross_regression_run(const Tensor *in, Tensor *out, const int64_t *attrs, int threads) {
    bool finite = true;  // as nan_on_nonfinite(4): every input before the kernel
    for (int i = 0; i < 4 && finite; ++i) finite = all_finite(in[i].data, in[i].size());
    if (!finite) {
        for (int o = 0; o < 2; ++o) std::fill(out[o].data, out[o].data + out[o].size(), std::nanf(""));
        return;
    }
    CrArgs a{};
    a.y_a = in[0].data, a.y_b = in[1].data, a.albedo = in[2].data, a.normal = in[3].data;
    a.pilot_a = out[0].data, a.pilot_b = out[1].data;
    a.n = in[0].dims[0], a.h = in[0].dims[2], a.w = in[0].dims[3];
    a.window = attrs[0], a.stride = attrs[1];
    a.hc = (a.h + a.stride - 1) / a.stride, a.wc = (a.w + a.stride - 1) / a.stride;
    const int64_t r = a.window / 2;  // ops/cross_regression.py reconstruction_offsets
    a.lo = r / a.stride, a.hi = (r + a.stride - 1) / a.stride;
    const int64_t nb = 2 * a.n, hw = a.h * a.w;
    // not zero-filled: every element is written before it is read
    std::unique_ptr<double[]> q(new double[static_cast<size_t>(nb * NQ * hw)]);
    std::unique_ptr<double[]> beta(new double[static_cast<size_t>(nb * a.hc * a.wc * 3 * P)]);
    a.q = q.get(), a.beta = beta.get();
    parallel_for(nb * a.h, threads, nb * hw * 64,
                 [&](int64_t b, int64_t e) { cr_stack(a, b, e); });
    parallel_for(nb * a.hc, threads, nb * a.hc * a.wc * a.window * a.window * 80,
                 [&](int64_t b, int64_t e) { cr_regress(a, b, e); });
    const int64_t cover = (a.lo + a.hi + 1) * (a.lo + a.hi + 1);
    parallel_for(nb * a.h, threads, nb * hw * cover * 40,
                 [&](int64_t b, int64_t e) { cr_reconstruct(a, b, e); });
}

/* ------------------------------------------------------------------ the table */

namespace {
const char *const WINDOW[] = {"window"};
const char *const WINDOW_STRIDE[] = {"window", "stride"};

const OpDef OPS[] = {
    {"CrossBilateralFilter", 5, 4, R4, CBF_IN, WINDOW, 1, cross_bilateral_filter_shapes,
     cross_bilateral_filter_run},
    {"CrossRegression", 4, 2, R4, CR_IN, WINDOW_STRIDE, 2, cross_regression_shapes,
     cross_regression_run},
};
}  // namespace

}  // namespace crossreg

const OpDef *crossreg_op_table(int *count) {
    *count = static_cast<int>(sizeof crossreg::OPS / sizeof crossreg::OPS[0]);
    return crossreg::OPS;
}

}  // namespace rtd

/* The kernels of rtdenoise_ops for demo:crossreg (Choi24): CrossRegression (float64
 * throughout, as every form of it) and CrossBilateralFilter (float32), the arithmetic of
 * runtime/kernels/cross_regression.py and cross_bilateral_filter.py, each sum adding the same
 * terms in the same order, in a cache- and SIMD-friendlier loop order (CrossBilateralFilter in
 * L1-sized chunks, CrossRegression 8 centres or pixels in lanes; benchmarks/README.md,
 * "crossreg's custom ops"). CrossRegression's exp is a vectorisable polynomial within ~1 ulp
 * of std::exp's. Like numba's fastmath,
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

/* Lanes: centres (regression) or pixels (reconstruction) at once. 8 doubles fill one AVX-512
 * register or two AVX2 ones; measured against 4 at 720p, the same bits: 754 -> 507 ms with
 * the AVX-512 clone, 648 -> 499 with AVX2 code only; 16 spills (558). */
constexpr int64_t L = 8;

/* The planes q (y, albedo, normal, sigma, var, target) of regression b are kept in a
 * phase-split, mirror-padded layout: padded column xp = x + R (R = stride * ceil(r / stride)
 * >= r, so that every window of a centre and every covering centre of a pixel lies inside)
 * is stored at phase xp % stride, position xp / stride. Pixels stride apart are then
 * neighbours: the same tap of L consecutive centres, the same phase of L pixels, and their L
 * covering centres are contiguous loads (the vectorised lanes below). */
struct CrArgs {
    const float *y_a, *y_b, *albedo, *normal;
    float *pilot_a, *pilot_b;
    int64_t n, h, w, window, stride, hc, wc, lo, hi;
    int64_t rb;      // R / stride
    int64_t xx;      // positions per phase of a padded row (a row: stride * xx)
    double *q;       // (2N, 14, H, stride, xx)
    int64_t bm, bw;  // beta: (2N, Hc, 3, 6, bw), centre j at bm + j, the margins 0
    double *beta;
    int64_t row() const { return stride * xx; }
    int64_t at(int64_t x) const {  // a row's offset of pixel column x, -R <= x < W + R
        const int64_t xp = x + rb * stride;
        return (xp % stride) * xx + xp / stride;
    }
};

/* kernels/cross_regression.py _stack: q of regression b (A's variables against y^B for
 * b < N, then B's against y^A), var over the in-image 3x3 neighbours; the padded columns
 * repeat their mirrored pixel (as the other forms read mirror(x)). */
RTD_CLONES void cr_stack(const CrArgs &a, int64_t begin, int64_t end) {
    const int64_t n_img = a.n, h = a.h, w = a.w, hw = h * w, row_len = a.row(), rs = a.rb * a.stride;
    std::vector<double> tmp(static_cast<size_t>(NQ * w));
    std::vector<int64_t> src_of(static_cast<size_t>(row_len)), dst_of(static_cast<size_t>(row_len));
    for (int64_t xp = 0; xp < row_len; ++xp) {
        src_of[static_cast<size_t>(xp)] = mirror(xp - rs, w);
        dst_of[static_cast<size_t>(xp)] = (xp % a.stride) * a.xx + xp / a.stride;
    }
    for (int64_t row = begin; row < end; ++row) {
        const int64_t b = row / h, yy = row - b * h, m = b % n_img;
        const float *y = (b < n_img ? a.y_a : a.y_b) + m * 3 * hw;
        const float *target = (b < n_img ? a.y_b : a.y_a) + m * 3 * hw;
        const float *albedo = a.albedo + m * 3 * hw, *normal = a.normal + m * 3 * hw;
        double *t = tmp.data();
        for (int64_t c = 0; c < 3; ++c)
            for (int64_t x = 0; x < w; ++x) {
                const int64_t at = c * hw + yy * w + x;
                t[c * w + x] = y[at];
                t[(3 + c) * w + x] = albedo[at];
                t[(6 + c) * w + x] = normal[at];
                t[(11 + c) * w + x] = target[at];
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
            t[9 * w + x] = std::sqrt(var);
            t[10 * w + x] = var;
        }
        for (int64_t k = 0; k < NQ; ++k) {
            double *dst = a.q + ((b * NQ + k) * h + yy) * row_len;
            const double *src = t + k * w;
            for (int64_t xp = 0; xp < row_len; ++xp)
                dst[dst_of[static_cast<size_t>(xp)]] = src[src_of[static_cast<size_t>(xp)]];
        }
    }
}

/* exp(v) for v <= 0 in double precision, in branch-free arithmetic that vectorises (std::exp
 * does not): v = k ln 2 + f (k = round(v log2 e) by the 1.5 * 2^52 shift, Cody-Waite ln 2),
 * exp(f) by its Taylor series to f^13 / 13! (|f| <= ln2 / 2: truncation below 1e-17), 2^k
 * from the exponent bits. Within about 1 ulp of std::exp; arguments below -708 give
 * exp(-708) ~ 3e-308, which every caller adds to 1e-7 (the weights' floor), as it does 0. */
RTD_INLINE double exp_nonpos(double v) {
    v = v > -708.0 ? v : -708.0;
    const double shifter = 6755399441055744.0;  // 1.5 * 2^52
    const double t = v * 1.4426950408889634 + shifter;
    const double k = t - shifter;
    const double f = (v - k * 6.93147180369123816490e-01) - k * 1.90821492927058770002e-10;
    double p = 1.0 / 6227020800.0;
    p = p * f + 1.0 / 479001600.0;
    p = p * f + 1.0 / 39916800.0;
    p = p * f + 1.0 / 3628800.0;
    p = p * f + 1.0 / 362880.0;
    p = p * f + 1.0 / 40320.0;
    p = p * f + 1.0 / 5040.0;
    p = p * f + 1.0 / 720.0;
    p = p * f + 1.0 / 120.0;
    p = p * f + 1.0 / 24.0;
    p = p * f + 1.0 / 6.0;
    p = p * f + 0.5;
    p = p * f + 1.0;
    p = p * f + 1.0;
    int64_t bits;
    std::memcpy(&bits, &t, sizeof bits);  // 0x4338... + k: its low 12 bits are k mod 4096
    bits = static_cast<int64_t>(static_cast<uint64_t>(bits + 1023) << 52);
    double scale;
    std::memcpy(&scale, &bits, sizeof scale);
    return p * scale;
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

/* One window row's tap variables, per lane: [w, n0, n1, n2, x1 (3 channels), x2 (3), t (3)]. */
constexpr int64_t NV = 13;
constexpr int64_t SEG = 32;  // taps per pass

/* The 10 sums shared by the channels over `taps` taps, in their order (`_centre_sums`). */
RTD_INLINE void sums_shared(const double (*RESTRICT v)[NV][L], int64_t taps, double (*RESTRICT acc)[L]) {
    alignas(64) double s[10][L];
    for (int64_t i = 0; i < 10; ++i)
        for (int64_t l = 0; l < L; ++l) s[i][l] = acc[i][l];
    for (int64_t t = 0; t < taps; ++t)
        for (int64_t l = 0; l < L; ++l) {
            const double wgt = v[t][0][l], n0 = v[t][1][l], n1 = v[t][2][l], n2 = v[t][3][l];
            const double wn0 = wgt * n0, wn1 = wgt * n1, wn2 = wgt * n2;
            s[0][l] += wgt;
            s[1][l] += wn0;
            s[2][l] += wn1;
            s[3][l] += wn2;
            s[4][l] += wn0 * n0;
            s[5][l] += wn0 * n1;
            s[6][l] += wn0 * n2;
            s[7][l] += wn1 * n1;
            s[8][l] += wn1 * n2;
            s[9][l] += wn2 * n2;
        }
    for (int64_t i = 0; i < 10; ++i)
        for (int64_t l = 0; l < L; ++l) acc[i][l] = s[i][l];
}

/* Channel c's 17 sums over `taps` taps, in their order. */
RTD_INLINE void sums_channel(const double (*RESTRICT v)[NV][L], int64_t taps, int64_t c,
                             double (*RESTRICT k)[L]) {
    alignas(64) double s[17][L];
    for (int64_t i = 0; i < 17; ++i)
        for (int64_t l = 0; l < L; ++l) s[i][l] = k[i][l];
    for (int64_t t = 0; t < taps; ++t)
        for (int64_t l = 0; l < L; ++l) {
            const double wgt = v[t][0][l], n0 = v[t][1][l], n1 = v[t][2][l], n2 = v[t][3][l];
            const double x1 = v[t][4 + c][l], x2 = v[t][7 + c][l], tg = v[t][10 + c][l];
            const double wx1 = wgt * x1, wx2 = wgt * x2, wt = wgt * tg;
            s[0][l] += wx1;
            s[1][l] += wx2;
            s[2][l] += wx1 * x1;
            s[3][l] += wx1 * x2;
            s[4][l] += wx2 * x2;
            s[5][l] += wx1 * n0;
            s[6][l] += wx1 * n1;
            s[7][l] += wx1 * n2;
            s[8][l] += wx2 * n0;
            s[9][l] += wx2 * n1;
            s[10][l] += wx2 * n2;
            s[11][l] += wt;
            s[12][l] += wx1 * tg;
            s[13][l] += wx2 * tg;
            s[14][l] += wt * n0;
            s[15][l] += wt * n1;
            s[16][l] += wt * n2;
        }
    for (int64_t i = 0; i < 17; ++i)
        for (int64_t l = 0; l < L; ++l) k[i][l] = s[i][l];
}

/* kernels/cross_regression.py _centre_sums and _regress: tasks (regression b, centre row i);
 * per block of L consecutive centres (one lane each), the 61 distinct sums of X^T W X and
 * X^T W y over the mirrored window (10 shared by the colour channels, 17 per channel), each
 * lane adding its terms in the window's order, then a 6 x 6 Cholesky solve per channel. */
RTD_CLONES void cr_regress(const CrArgs &a, int64_t begin, int64_t end) {
    const int64_t h = a.h, hc = a.hc, wc = a.wc, r = a.window / 2, s = a.stride, xx = a.xx;
    const int64_t row_len = a.row(), plane = h * row_len, rs = a.rb * s;
    alignas(64) double acc[NSUM][L];
    double sums[NSUM], beta6[P];
    alignas(64) double var[SEG][NV][L];  // the tap variables of up to SEG taps of a row
    for (int64_t task = begin; task < end; ++task) {
        const int64_t b = task / hc, i = task - b * hc, cy = s * i;
        const double *q = a.q + b * NQ * plane;
        for (int64_t j0 = 0; j0 < wc; j0 += L) {
            // the centres' own values: phase 0, positions rb + j0 + l
            alignas(64) double cv[11][L];
            for (int64_t k = 0; k < 11; ++k)
                for (int64_t l = 0; l < L; ++l) cv[k][l] = q[k * plane + cy * row_len + a.rb + j0 + l];
            for (int64_t k = 0; k < NSUM; ++k)
                for (int64_t l = 0; l < L; ++l) acc[k][l] = 0.0;
            for (int64_t dy = -r; dy <= r; ++dy) {
                const double *qr = q + mirror(cy + dy, h) * row_len;
                for (int64_t dx0 = -r; dx0 <= r; dx0 += SEG) {
                    const int64_t taps = std::min<int64_t>(SEG, r + 1 - dx0);
                    // pass 1: each tap's weight and variables, per lane
                    for (int64_t dx = dx0; dx < dx0 + taps; ++dx) {
                        const double *RESTRICT qt = qr + ((dx + rs) % s) * xx + (dx + rs) / s + j0;
                        double *RESTRICT v = &var[dx - dx0][0][0];
                        for (int64_t l = 0; l < L; ++l) {
                            const double d0 = qt[l] - cv[0][l], d1 = qt[plane + l] - cv[1][l],
                                         d2 = qt[2 * plane + l] - cv[2][l];
                            double wgt = exp_nonpos(-(d0 * d0 + d1 * d1 + d2 * d2) /
                                                    (cv[10][l] + qt[10 * plane + l] + 1e-4));
                            wgt += 1e-7;
                            const double inv = 1.0 / (cv[9][l] + qt[9 * plane + l] + 1e-2);
                            v[l] = wgt;
                            v[L + l] = qt[6 * plane + l] - cv[6][l];
                            v[2 * L + l] = qt[7 * plane + l] - cv[7][l];
                            v[3 * L + l] = qt[8 * plane + l] - cv[8][l];
                            v[4 * L + l] = d0 * inv;
                            v[5 * L + l] = d1 * inv;
                            v[6 * L + l] = d2 * inv;
                            v[7 * L + l] = qt[3 * plane + l] - cv[3][l];
                            v[8 * L + l] = qt[4 * plane + l] - cv[4][l];
                            v[9 * L + l] = qt[5 * plane + l] - cv[5][l];
                            v[10 * L + l] = qt[11 * plane + l];
                            v[11 * L + l] = qt[12 * plane + l];
                            v[12 * L + l] = qt[13 * plane + l];
                        }
                    }
                    // pass 2: the sums, a few at a time over the taps (in registers)
                    sums_shared(var, taps, acc);
                    for (int64_t c = 0; c < 3; ++c) sums_channel(var, taps, c, acc + 10 + 17 * c);
                }
            }
            for (int64_t l = 0; l < L && j0 + l < wc; ++l) {
                for (int64_t k = 0; k < NSUM; ++k) sums[k] = acc[k][l];
                for (int64_t c = 0; c < 3; ++c) {
                    solve(sums, c, beta6);
                    for (int64_t t = 0; t < P; ++t)
                        a.beta[(((b * hc + i) * 3 + c) * P + t) * a.bw + a.bm + j0 + l] = beta6[t];
                }
            }
        }
    }
}

/* kernels/cross_regression.py _reconstruct: eq. (5) over the covering centres, clamped >= 0,
 * rows of regression b into pilot_a (b < N) or pilot_b. The pixels x = stride m + ph of one
 * phase ph go L at a time (one lane each): their covering centres are stride apart too and
 * pass the window test together; a centre outside the grid (near the left and right edges)
 * adds nothing to its lane, as it is skipped in the other forms. */
RTD_CLONES void cr_reconstruct(const CrArgs &a, int64_t begin, int64_t end) {
    const int64_t h = a.h, w = a.w, hw = h * w, hc = a.hc, wc = a.wc, r = a.window / 2;
    const int64_t s = a.stride, lo = a.lo, hi = a.hi, row_len = a.row(), plane = h * row_len;
    for (int64_t row = begin; row < end; ++row) {
        const int64_t b = row / h, y = row - b * h;
        const double *q = a.q + b * NQ * plane;
        float *pilot = b < a.n ? a.pilot_a + b * 3 * hw : a.pilot_b + (b - a.n) * 3 * hw;
        for (int64_t ph = 0; ph < s && ph < w; ++ph) {
            const int64_t count = (w - ph + s - 1) / s;  // pixels of this phase
            const double *qp = q + y * row_len + ((ph + a.rb * s) % s) * a.xx + (ph + a.rb * s) / s;
            for (int64_t m0 = 0; m0 < count; m0 += L) {
                alignas(64) double num0[L] = {}, num1[L] = {}, num2[L] = {}, den[L] = {};
                const double *RESTRICT pv = qp + m0;  // pixel m0 + l at pv[k * plane + l]
                for (int64_t dj = -lo; dj <= hi; ++dj) {
                    const int64_t jy = y / s + dj;
                    if (jy < 0 || jy >= hc || std::abs(y - s * jy) > r) continue;
                    const int64_t cy = s * jy;
                    for (int64_t di = -lo; di <= hi; ++di) {
                        if (std::abs(ph - s * di) > r) continue;  // |x - stride ix| of every lane
                        const int64_t ix0 = m0 + di;  // lane l's centre: ix0 + l
                        const double *RESTRICT cq = q + cy * row_len + a.rb + ix0;  // phase 0
                        const double *RESTRICT co = a.beta + ((b * hc + jy) * 3 * P) * a.bw + a.bm + ix0;
                        alignas(64) double inside[L];  // 1 for a centre of the grid, 0 outside
                        for (int64_t l = 0; l < L; ++l) inside[l] = ix0 + l >= 0 && ix0 + l < wc ? 1.0 : 0.0;
                        for (int64_t l = 0; l < L; ++l) {
                            const double in = inside[l];
                            const double dy0 = pv[l] - cq[l], dy1 = pv[plane + l] - cq[plane + l],
                                         dy2 = pv[2 * plane + l] - cq[2 * plane + l];
                            const double spread = cq[10 * plane + l] + pv[10 * plane + l] + 1e-4;
                            const double wgt =
                                (exp_nonpos(-(dy0 * dy0 + dy1 * dy1 + dy2 * dy2) / spread) + 1e-7) * in;
                            const double inv = 1.0 / (cq[9 * plane + l] + pv[9 * plane + l] + 1e-2);
                            const double n0 = pv[6 * plane + l] - cq[6 * plane + l];
                            const double n1 = pv[7 * plane + l] - cq[7 * plane + l];
                            const double n2 = pv[8 * plane + l] - cq[8 * plane + l];
                            const double dyc[3] = {dy0, dy1, dy2};
                            double pred[3];
                            for (int64_t c = 0; c < 3; ++c) {
                                const double *RESTRICT cc = co + c * P * a.bw;
                                const double x2 = pv[(3 + c) * plane + l] - cq[(3 + c) * plane + l];
                                double v = cc[l] + cc[a.bw + l] * dyc[c] * inv + cc[2 * a.bw + l] * x2;
                                v += cc[3 * a.bw + l] * n0 + cc[4 * a.bw + l] * n1 + cc[5 * a.bw + l] * n2;
                                pred[c] = v;
                            }
                            // a centre outside adds (+-)0 (its terms are finite): the sums do not
                            // change, as where the other forms skip it
                            num0[l] += wgt * pred[0];
                            num1[l] += wgt * pred[1];
                            num2[l] += wgt * pred[2];
                            den[l] += wgt;
                        }
                    }
                }
                for (int64_t l = 0; l < L && m0 + l < count; ++l) {
                    const int64_t p = y * w + s * (m0 + l) + ph;
                    // numba's max(v, 0.0): 0 where 0 > v, else v (NaN stays NaN)
                    const double v0 = num0[l] / den[l], v1 = num1[l] / den[l], v2 = num2[l] / den[l];
                    pilot[p] = static_cast<float>(0.0 > v0 ? 0.0 : v0);
                    pilot[hw + p] = static_cast<float>(0.0 > v1 ? 0.0 : v1);
                    pilot[2 * hw + p] = static_cast<float>(0.0 > v2 ? 0.0 : v2);
                }
            }
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
    a.rb = a.hi;  // ceil(r / stride)
    // every read of a lane stays inside: centres j + rb + (dx + R) / stride < wc + 2 rb + L,
    // pixels and covering centres below that too
    a.xx = a.wc + 2 * a.rb + L + 2;
    a.bm = a.lo + 1, a.bw = a.wc + a.lo + a.hi + L + 2;
    const int64_t nb = 2 * a.n, hw = a.h * a.w;
    // q: not zero-filled, every element is written before it is read; beta: its margins are
    // read by lanes whose centre lies outside the grid (their terms are dropped), zeros
    std::unique_ptr<double[]> q(new double[static_cast<size_t>(nb * NQ * a.h * a.row())]);
    std::unique_ptr<double[]> beta(new double[static_cast<size_t>(nb * a.hc * 3 * P * a.bw)]());
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

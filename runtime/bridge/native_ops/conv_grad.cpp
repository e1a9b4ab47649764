/* ConvWeightGrad of rtdenoise_ops: the weight gradient of a stride-1 K x K convolution (the
 * backward pass of demo:crossreg's U-Net), the sums of runtime/kernels/conv_weight_grad.py
 * in another order: a register tile of OB output channels x KB kernel columns (12 vector
 * accumulators) over a chunk of up to CHUNK pixels of a gradient row, the input row under the
 * chunk copied once with its zero padding. Each block of ROWS gradient rows sums
 * into its own float64 partial, and the partials are added in block order, so the result does
 * not depend on the thread count. Like numba's fastmath, the compiler may contract a
 * multiply and an add into an FMA here (the AVX2 and AVX-512 clones). */
#if defined(__clang__)
#pragma clang fp contract(fast)
#elif defined(__GNUC__)
#pragma GCC optimize("fp-contract=fast")
#endif
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic ignored "-Wpsabi"
#endif

#include "kernels_common.h"

namespace rtd {
namespace conv_grad {

using namespace detail;

namespace {

#if defined(__GNUC__)  // 8 lanes: two SSE registers on the baseline, one AVX register in v3/v4
typedef float VF __attribute__((vector_size(32)));
constexpr int64_t LANES = 8;
RTD_INLINE double lane_sum(VF v) {
    double s = 0.0;
    for (int l = 0; l < LANES; ++l) s += v[l];
    return s;
}
#else
typedef float VF;
constexpr int64_t LANES = 1;
RTD_INLINE double lane_sum(float v) { return v; }
#endif

RTD_INLINE VF load(const float *p) {
    VF v;
    std::memcpy(&v, p, sizeof v);
    return v;
}

constexpr int64_t OB = 4;      // output channels per register tile
constexpr int64_t KB = 3;      // kernel columns per register tile
/* Gradient pixels per chunk (a multiple of LANES): a whole row up to 2048. Each chunk ends in
 * 12 lane sums; measured on the loaded 2-core AVX2 VM at 720p layer shapes, 256-pixel chunks
 * ran at 0.65-0.8x this speed, 128 at 0.6x, and vector sums kept over 8 rows (loaded and
 * stored per chunk) at 0.6x. */
constexpr int64_t CHUNK = 2048;
constexpr int64_t ROWS = 8;    // gradient rows per partial sum

struct CwgArgs {
    const float *x, *g;
    double *partial;  // blocks x (C_out C_in K K)
    int64_t n, ci, co, h, w, ho, wo, k, p;
};

/* Full tile: OB gradient rows `gr` against KB shifts of the padded input row `xr` over `cw`
 * pixels; adds each of the OB x KB sums to acc[j * stride_o + t]. */
RTD_INLINE void tile_full(const float *const *gr, const float *RESTRICT xr, int64_t cw,
                          double *acc, int64_t stride_o) {
    VF s[OB][KB];
    for (int64_t j = 0; j < OB; ++j)
        for (int64_t t = 0; t < KB; ++t) s[j][t] = VF{};
    const int64_t vw = cw - cw % LANES;
    for (int64_t x = 0; x < vw; x += LANES) {
        VF xv[KB];
        for (int64_t t = 0; t < KB; ++t) xv[t] = load(xr + t + x);
        for (int64_t j = 0; j < OB; ++j) {
            const VF gv = load(gr[j] + x);
            for (int64_t t = 0; t < KB; ++t) s[j][t] += gv * xv[t];
        }
    }
    for (int64_t j = 0; j < OB; ++j)
        for (int64_t t = 0; t < KB; ++t) {
            double total = lane_sum(s[j][t]);
            for (int64_t x = vw; x < cw; ++x) total += gr[j][x] * xr[t + x];
            acc[j * stride_o + t] += total;
        }
}

/* Any tile (the remainders): ob rows x kb shifts, one float sum per pixel run. */
RTD_INLINE void tile_any(const float *const *gr, const float *RESTRICT xr, int64_t cw,
                         int64_t ob, int64_t kb, double *acc, int64_t stride_o) {
    for (int64_t j = 0; j < ob; ++j)
        for (int64_t t = 0; t < kb; ++t) {
            float s = 0.0f;
            for (int64_t x = 0; x < cw; ++x) s += gr[j][x] * xr[t + x];
            acc[j * stride_o + t] += s;
        }
}

RTD_CLONES void cwg_blocks(const CwgArgs &a, int64_t begin, int64_t end) {
    const int64_t kk = a.k * a.k, size = a.co * a.ci * kk, rows = a.n * a.ho;
    std::vector<float> xr(static_cast<size_t>(CHUNK + a.k + LANES));
    const float *gr[OB];
    for (int64_t b = begin; b < end; ++b) {
        double *acc = a.partial + b * size;
        std::fill(acc, acc + size, 0.0);
        for (int64_t row = b * ROWS; row < std::min(rows, (b + 1) * ROWS); ++row) {
            const int64_t n = row / a.ho, y = row - n * a.ho;
            for (int64_t x0 = 0; x0 < a.wo; x0 += CHUNK) {
                const int64_t cw = std::min(CHUNK, a.wo - x0);
                for (int64_t ky = 0; ky < a.k; ++ky) {
                    const int64_t sy = y + ky - a.p;
                    if (sy < 0 || sy >= a.h) continue;  // zero padding: no terms
                    for (int64_t i = 0; i < a.ci; ++i) {
                        // xr[t] = input column x0 + t - p (0 outside), t < cw + k - 1
                        const float *src = a.x + ((n * a.ci + i) * a.h + sy) * a.w;
                        for (int64_t t = 0; t < cw + a.k - 1; ++t) {
                            const int64_t sx = x0 + t - a.p;
                            xr[static_cast<size_t>(t)] = sx >= 0 && sx < a.w ? src[sx] : 0.0f;
                        }
                        for (int64_t o0 = 0; o0 < a.co; o0 += OB) {
                            const int64_t ob = std::min(OB, a.co - o0);
                            for (int64_t j = 0; j < ob; ++j)
                                gr[j] = a.g + ((n * a.co + o0 + j) * a.ho + y) * a.wo + x0;
                            for (int64_t kx0 = 0; kx0 < a.k; kx0 += KB) {
                                const int64_t kb = std::min(KB, a.k - kx0);
                                double *at = acc + (o0 * a.ci + i) * kk + ky * a.k + kx0;
                                if (ob == OB && kb == KB)
                                    tile_full(gr, xr.data() + kx0, cw, at, a.ci * kk);
                                else
                                    tile_any(gr, xr.data() + kx0, cw, ob, kb, at, a.ci * kk);
                            }
                        }
                    }
                }
            }
        }
    }
}

const char *const CWG_IN[] = {"input", "grad_output"};
const char *const CWG_ATTRS[] = {"kernel_size", "padding"};

}  // namespace

std::string conv_weight_grad_shapes(const Tensor *in, const int64_t *attrs, Shape *out) {
    const int64_t k = attrs[0], p = attrs[1];
    if (k < 1 || p < 0 || p >= k)
        return "ConvWeightGrad: kernel_size " + std::to_string(k) + ", padding " +
               std::to_string(p) + "; need 0 <= padding < K";
    const int64_t ho = in[0].dims[2] + 2 * p - k + 1, wo = in[0].dims[3] + 2 * p - k + 1;
    if (in[1].dims[0] != in[0].dims[0] || in[1].dims[2] != ho || in[1].dims[3] != wo)
        return "ConvWeightGrad: grad_output has shape " + fmt_shape(in[1]) + "; expected N = " +
               std::to_string(in[0].dims[0]) + " and H, W = " + std::to_string(ho) + ", " +
               std::to_string(wo) + " (input " + fmt_shape(in[0]) + ", kernel " +
               std::to_string(k) + ", padding " + std::to_string(p) + ")";
    set_shape(out[0], in[1].dims[1], in[0].dims[1], k, k);
    return "";
}

void conv_weight_grad_run(const Tensor *in, Tensor *out, const int64_t *attrs, int threads) {
    CwgArgs a{};
    a.x = in[0].data, a.g = in[1].data;
    a.n = in[0].dims[0], a.ci = in[0].dims[1], a.h = in[0].dims[2], a.w = in[0].dims[3];
    a.co = in[1].dims[1], a.ho = in[1].dims[2], a.wo = in[1].dims[3];
    a.k = attrs[0], a.p = attrs[1];
    const int64_t size = a.co * a.ci * a.k * a.k, blocks = (a.n * a.ho + ROWS - 1) / ROWS;
    std::unique_ptr<double[]> partial(new double[static_cast<size_t>(blocks * size)]);
    a.partial = partial.get();
    parallel_for(blocks, threads, a.n * a.ho * a.wo * size,
                 [&](int64_t b, int64_t e) { cwg_blocks(a, b, e); });
    for (int64_t j = 0; j < size; ++j) {
        double total = 0.0;
        for (int64_t b = 0; b < blocks; ++b) total += a.partial[b * size + j];
        out[0].data[j] = static_cast<float>(total);
    }
}

/* ------------------------------------------------------------------ the table */

namespace {
const OpDef OPS[] = {
    {"ConvWeightGrad", 2, 1, R4, CWG_IN, CWG_ATTRS, 2, conv_weight_grad_shapes,
     conv_weight_grad_run},
};
}  // namespace

}  // namespace conv_grad

const OpDef *conv_grad_op_table(int *count) {
    *count = static_cast<int>(sizeof conv_grad::OPS / sizeof conv_grad::OPS[0]);
    return conv_grad::OPS;
}

}  // namespace rtd

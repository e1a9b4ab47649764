/* SvgfReproject of rtdenoise_ops (demo:crossreg's history warp): the float32 arithmetic of
 * runtime/kernels/svgf_reproject.py and of the torch form, step by step and without fused
 * multiply-adds (this file keeps setup.py's -ffp-contract=off), so the forms agree to the
 * bit. */
#include <cmath>
#include <memory>

#include "kernels_common.h"

namespace rtd {
namespace crossreg_step {

using namespace detail;

/* ======================================================================== SvgfReproject */

const char *const SR_IN[] = {"previous", "prev_geometry", "motion", "normal", "depth",
                             "depth_threshold", "normal_threshold"};
constexpr int SR_RANKS[] = {4, 4, 4, 4, 4, 0, 0};
const char *const SR_ATTRS[] = {"fallback", "erode"};

std::string svgf_reproject_shapes(const Tensor *in, const int64_t *attrs, Shape *out) {
    for (int a = 0; a < 2; ++a)
        if (attrs[a] != 0 && attrs[a] != 1)
            return std::string("SvgfReproject: ") + SR_ATTRS[a] + " is " +
                   std::to_string(attrs[a]) + "; expected 0 or 1";
    std::string e = same_nhw("SvgfReproject", in, SR_IN, 5);
    if (!e.empty()) return e;
    const int64_t expected[] = {0, 4, 2, 3, 1};
    for (int i = 1; i < 5; ++i)
        if (in[i].dims[1] != expected[i])
            return std::string("SvgfReproject: ") + SR_IN[i] + " has " +
                   std::to_string(in[i].dims[1]) + " channels; expected " +
                   std::to_string(expected[i]);
    if (in[0].dims[2] < 2 || in[0].dims[3] < 2)
        return "SvgfReproject: image " + fmt_shape(in[0]) + " is below 2 x 2 (fwidth)";
    copy_shape(in[0], out[0]);
    set_shape(out[1], in[0].dims[0], 1, in[0].dims[2], in[0].dims[3]);
    return "";
}

namespace {

struct SrArgs {
    const float *previous, *geo, *motion, *normal, *depth;
    float depth_thr, normal_thr;
    bool fallback, erode;
    float *unmasked, *before, *valid;  // unmasked: the output, masked in place
    int64_t c, h, w;
};

/* kernels/svgf_reproject.py _clamped_index: an integer-valued float position -> its clamped
 * pixel index (NaN and below 0: 0). */
RTD_INLINE int64_t clamped_index(float f, int64_t size) {
    return static_cast<int64_t>(clamped(f, static_cast<float>(size - 1)));  // exact: size < 2^24
}

struct Pixel {
    float z, n0, n1, n2, depth_tol, normal_tol;
};

/* _tap_ok: the clamped tap's flat index; whether it passes the in-image, depth and normal
 * tests. */
RTD_INLINE bool tap_ok(const SrArgs &a, const float *geo, float fx, float fy, const Pixel &p,
                       int64_t *index) {
    const int64_t hw = a.h * a.w;
    const int64_t i = clamped_index(fy, a.h) * a.w + clamped_index(fx, a.w);
    *index = i;
    // bitwise: no branch on the tests, whose outcomes vary from pixel to pixel
    const bool inside = (fx >= 0.0f) & (fx <= static_cast<float>(a.w - 1)) & (fy >= 0.0f) &
                        (fy <= static_cast<float>(a.h - 1));
    const float d0 = geo[i] - p.n0, d1 = geo[hw + i] - p.n1, d2 = geo[2 * hw + i] - p.n2;
    const float dn = std::sqrt(d0 * d0 + d1 * d1 + d2 * d2);
    const bool depth_ok = std::fabs(geo[3 * hw + i] - p.z) <= p.depth_tol;
    return inside & depth_ok & (dn <= p.normal_tol);
}

/* The taps' flat indices and weights (0 for a failed tap) come first, branch-free; then each
 * channel sums its taps in a register, in the order the numba kernel adds them into its
 * accumulator array ((0 + w0 v0) + w1 v1 ...), so the sums are the same bits. */
RTD_CLONES void sr_warp(const SrArgs &a, int64_t begin, int64_t end) {
    const int64_t c = a.c, h = a.h, w = a.w, hw = h * w;
    const float eps = 1e-2f, zero = 0.0f, one = 1.0f;
    for (int64_t row = begin; row < end; ++row) {
        const int64_t n = row / h, y = row - n * h;
        const float *prev = a.previous + n * c * hw, *geo = a.geo + n * 4 * hw;
        const float *depth = a.depth + n * hw, *normal = a.normal + n * 3 * hw;
        const float *mx = a.motion + n * 2 * hw, *my = mx + hw;
        float *out_row = a.unmasked + n * c * hw + y * w;
        float *before_row = a.before + n * hw + y * w;
        const int64_t yd = y < h - 1 ? y + 1 : y, yu = y < h - 1 ? y : y - 1;
        for (int64_t x = 0; x < w; ++x) {
            const int64_t xr = x < w - 1 ? x + 1 : x, xl = x < w - 1 ? x : x - 1;
            const int64_t at = y * w + x;
            Pixel p{};
            p.z = depth[at];
            const float dzx = std::fabs(depth[y * w + xr] - depth[y * w + xl]);
            const float dzy = std::fabs(depth[yd * w + x] - depth[yu * w + x]);
            const float fw_z = dzy > dzx ? dzy : dzx;  // numba's max(dzx, dzy)
            float s[3];
            for (int k = 0; k < 3; ++k) {
                const float *nk = normal + k * hw;
                s[k] = std::fabs(nk[y * w + xr] - nk[y * w + xl]) +
                       std::fabs(nk[yd * w + x] - nk[yu * w + x]);
            }
            const float fw_n = std::sqrt(s[0] * s[0] + s[1] * s[1] + s[2] * s[2]);
            p.depth_tol = a.depth_thr * (fw_z + eps);
            p.normal_tol = a.normal_thr * (fw_n + eps);
            p.n0 = normal[at], p.n1 = normal[hw + at], p.n2 = normal[2 * hw + at];
            const float px = static_cast<float>(x) + mx[at];
            const float py = static_cast<float>(y) + my[at];
            const float x0 = std::floor(px), y0 = std::floor(py);
            const float ax = px - x0, ay = py - y0;
            int64_t idx[4];
            float wgt[4];
            float total = zero;
            for (int t = 0; t < 4; ++t) {
                const int ox = t & 1, oy = t >> 1;
                const float wx = ox ? ax : one - ax, wy = oy ? ay : one - ay;
                const bool ok = tap_ok(a, geo, x0 + static_cast<float>(ox),
                                       y0 + static_cast<float>(oy), p, &idx[t]);
                wgt[t] = ok ? wx * wy : zero;
                total = total + wgt[t];
            }
            bool ok_all = total >= eps;
            float *out = out_row + x;
            if (ok_all) {
                const float *p0 = prev + idx[0], *p1 = prev + idx[1];
                const float *p2 = prev + idx[2], *p3 = prev + idx[3];
                for (int64_t k = 0; k < c; ++k) {
                    const int64_t o = k * hw;
                    float acc = zero + wgt[0] * p0[o];
                    acc = acc + wgt[1] * p1[o];
                    acc = acc + wgt[2] * p2[o];
                    acc = acc + wgt[3] * p3[o];
                    out[o] = acc / total;
                }
            } else {
                for (int64_t k = 0; k < c; ++k) out[k * hw] = zero;
            }
            if (a.fallback && !ok_all) {
                const float rx = std::floor(px + 0.5f), ry = std::floor(py + 0.5f);
                int64_t taps[9];
                int count_taps = 0;
                for (int oy = -1; oy <= 1; ++oy)
                    for (int ox = -1; ox <= 1; ++ox) {
                        int64_t i = 0;
                        if (tap_ok(a, geo, rx + static_cast<float>(ox),
                                   ry + static_cast<float>(oy), p, &i))
                            taps[count_taps++] = i;
                    }
                if (count_taps > 0) {
                    const float count = static_cast<float>(count_taps);
                    for (int64_t k = 0; k < c; ++k) {
                        const float *pk = prev + k * hw;
                        float acc = zero;
                        for (int t = 0; t < count_taps; ++t) acc = acc + pk[taps[t]];
                        out[k * hw] = acc / count;
                    }
                    ok_all = true;
                }
            }
            before_row[x] = ok_all ? one : zero;
        }
    }
}

RTD_CLONES void sr_erode(const SrArgs &a, int64_t begin, int64_t end) {
    const int64_t c = a.c, h = a.h, w = a.w, hw = h * w;
    for (int64_t row = begin; row < end; ++row) {
        const int64_t n = row / h, y = row - n * h;
        const float *before = a.before + n * hw;
        for (int64_t x = 0; x < w; ++x) {
            float m = before[y * w + x];
            if (a.erode)
                for (int64_t yy = y > 0 ? y - 1 : 0; yy < (y + 2 < h ? y + 2 : h); ++yy)
                    for (int64_t xx = x > 0 ? x - 1 : 0; xx < (x + 2 < w ? x + 2 : w); ++xx)
                        m = min_like_numba(m, before[yy * w + xx]);
            a.valid[n * hw + y * w + x] = m;
            // masked in place: a mask of 1 leaves every value as it is (x * 1 == x, NaN too)
            if (m == 1.0f) continue;
            for (int64_t k = 0; k < c; ++k) {
                const int64_t i = (n * c + k) * hw + y * w + x;
                a.unmasked[i] = a.unmasked[i] * m;
            }
        }
    }
}

}  // namespace

void svgf_reproject_run(const Tensor *in, Tensor *out, const int64_t *attrs, int threads) {
    SrArgs a{};
    a.previous = in[0].data, a.geo = in[1].data, a.motion = in[2].data, a.normal = in[3].data;
    a.depth = in[4].data, a.depth_thr = in[5].data[0], a.normal_thr = in[6].data[0];
    a.fallback = attrs[0] != 0, a.erode = attrs[1] != 0;
    a.c = in[0].dims[1], a.h = in[0].dims[2], a.w = in[0].dims[3];
    const int64_t n = in[0].dims[0], hw = a.h * a.w;
    // the warp writes its unmasked result into the output, which the erode pass then masks
    // in place (element by element: no pixel reads another's), saving a frame-sized buffer
    std::unique_ptr<float[]> before(new float[static_cast<size_t>(n * hw)]);
    a.unmasked = out[0].data, a.before = before.get();
    a.valid = out[1].data;
    parallel_for(n * a.h, threads, n * hw * (a.c + 8) * 13,
                 [&](int64_t b, int64_t e) { sr_warp(a, b, e); });
    parallel_for(n * a.h, threads, n * hw * (a.c + 9),
                 [&](int64_t b, int64_t e) { sr_erode(a, b, e); });
}

/* ------------------------------------------------------------------ the table */

namespace {
const OpDef OPS[] = {
    {"SvgfReproject", 7, 2, SR_RANKS, SR_IN, SR_ATTRS, 2, svgf_reproject_shapes,
     svgf_reproject_run, 0, nullptr, true},
};
}  // namespace

}  // namespace crossreg_step

const OpDef *crossreg_step_op_table(int *count) {
    *count = static_cast<int>(sizeof crossreg_step::OPS / sizeof crossreg_step::OPS[0]);
    return crossreg_step::OPS;
}

}  // namespace rtd

/* The kernels of rtdenoise_ops for demo:affinity (Isik21): AffinityFilter and
 * TemporalAffinityFilter, the arithmetic of runtime/kernels/affinity_filter.py and
 * temporal_affinity_filter.py in float32, rows split over the threads, each row a tile of
 * TILE pixels at a time, each pixel's sums tap by tap in the numba kernel's order (the loops
 * differ: see "the taps" below). Like numba's fastmath (its LLVM fuses a multiply and an add
 * where the CPU has FMA), this file lets the compiler contract them in the AVX2 and AVX-512
 * clones; nothing is reassociated but the distance's four-channel groups, summed in pairs,
 * and the exponential's polynomial (`exp_short`): within 1e-6 of numba and torch.
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
#if defined(__GNUC__) && !defined(__clang__)
// 8-lane vectors pass between inlined helpers only: the ABI note about passing them is moot
#pragma GCC diagnostic ignored "-Wpsabi"
#endif

#include <cstdio>

#include "kernels_common.h"

namespace rtd {
namespace affinity {

using namespace detail;

namespace {

constexpr float EPS = 1e-10f;  // ops/affinity_filter.py EPS (Isik21 eq. (6))
constexpr int64_t MAX_KERNEL_SIZE = 63;
/* Output pixels of a row per tile (below): its scratch (the sums, and each tap row's
 * 12 guide, value and mask rows for demo:affinity) fits a 32 KiB L1 cache. */
constexpr int64_t TILE = 128;
/* The stride of a tile's padded tap rows when their margins fit it (a dilation up to 8 at
 * 13 x 13 taps), else TILE + the margins. */
constexpr int64_t PAD_STRIDE = 2 * TILE;

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

/* ---- the taps of kernels/affinity_filter.py, register-blocked
 *
 * The numba kernel runs each tap over the whole row in three passes (distance, weight, sums),
 * so every tap reads and writes W-long scratch rows (at 720p more than the L1 cache holds).
 * Here a block of LANES pixels keeps its sums in registers over the k taps of one tap row:
 * per tap it only loads the neighbours' guides and values. Each pixel still sums its taps in
 * the numba kernel's order (tap rows outer, taps inner), so only FMA contraction and the
 * exponential's rounding differ. A row runs a tile of TILE pixels at a time, and a thread
 * takes each tile down all its rows before the next (the tile's scratch stays in L1, the
 * input rows its taps read in L2). Measured interleaved on the loaded 2-core VM, numba / C++
 * at 720p on one thread: 0.9-1.0 with whole rows (before, and with the register blocking
 * alone), 1.0-1.15 with the tiles, 1.3-1.4 with the compile-time strides of block_taps;
 * 1.30 on two threads (AffinityFilter; TemporalAffinityFilter 1.21 at dilation 4).
 * Borders: each tap row's guides, values and mask under the tile are copied into rows
 * padded with zeros on either side, and a tap whose neighbour lies outside the image has its
 * weight cleared by an AND with `inside` (all bits set in the image, 0 in the padding):
 * exact, as the numba kernel's skipped tap, and with no branch per tap. */

#if defined(__GNUC__)  // GCC and clang vector extensions: 8 lanes (two SSE registers on
                       // the x86-64 baseline, one AVX register in the v3 and v4 clones)
typedef float VF __attribute__((vector_size(32)));
typedef int32_t VI __attribute__((vector_size(32)));
constexpr int64_t LANES = 8;

RTD_INLINE VI as_bits(VF v) { return (VI)v; }
RTD_INLINE VF from_bits(VI b) { return (VF)b; }
RTD_INLINE void store(float *p, VF v) { std::memcpy(p, &v, sizeof v); }
#else  // one lane: the compiler's own vectoriser gets the loops over blocks
constexpr int64_t LANES = 1;
#endif

RTD_INLINE int32_t as_bits(float v) {
    int32_t b;
    std::memcpy(&b, &v, sizeof b);
    return b;
}
RTD_INLINE float from_bits(int32_t b) { return bits_to_float(b); }
RTD_INLINE void store(float *p, float v) { *p = v; }

template <class V>
RTD_INLINE V load(const void *p) {
    V v;
    std::memcpy(&v, p, sizeof v);
    return v;
}

template <class V>
RTD_INLINE V splat(float x) {
    return V{} + x;
}

/* exp(v) for v <= 0: kernels/common.py exp_neg (the same range reduction and polynomial)
 * with a shorter chain of dependent instructions (the ops' outputs stay within 4.4e-7 of
 * numba's, relative, as with exp_neg's steps: benchmarks/README.md). The kernel is bound by
 * that chain's latency where two processes share a core (each has half its out-of-order
 * window): here the nearest integer k comes from adding and subtracting 1.5 * 2^23 (rather
 * than exp_neg's floor(v log2(e) + 0.5) in five steps), and the degree-6 polynomial is
 * evaluated by Estrin's scheme (three steps deep rather than Horner's six). */
template <class V>
RTD_INLINE V exp_short(V v) {
    constexpr float SHIFT = 12582912.0f;  // 1.5 * 2^23: its last bit is worth 1
    const V lo = splat<V>(EXP_MIN);
    v = lo > v ? lo : v;  // numba's max(v, -80): a NaN stays
    const V shifted = v * LOG2E + SHIFT;
    const V k = shifted - SHIFT;
    const auto two_k = (as_bits(shifted) - as_bits(SHIFT) + 127) << 23;
    const V f = v - k * LN2_HI - k * LN2_LO;
    const V f2 = f * f;
    const V low = (f + 1.0f) + f2 * (f * 0.16666666f + 0.5f);                // 1 .. f^3
    const V high = (f * 0.008333333f + 0.041666664f) + f2 * 0.0013888889f;  // f^4 ..
    return (low + (f2 * f2) * high) * from_bits(two_k);
}

struct TapRow {  // one tap row of one kernel for one tile of output row y
    const float *feats;  // (D, H, W) of image n, at the tile's first pixel: what it compares
    const float *a;      // the bandwidth at the tile's first pixel
    const float *pad;    // the tap row's D guide, C value and (with `masked`) one mask rows
                         // under the tile, `stride` apart: the image from `margin` on
    const int32_t *inside;  // all bits set where `pad` lies in the image, else 0
    float *num, *den;    // (C, TILE), (TILE): the tile's sums
    int64_t n_feat, n_ch, hw, w, stride, margin, k, d, skip;  // w: the tile's width; skip:
    bool masked;                                              // the tap left out (-1: none)
};

/* The taps of one tap row into the sums of pixels [x, x + lanes of V) of a tile (Isik21
 * eq. (4) / (7): w = exp(-a ||f_p - f_q||^2), times the mask; den += w, num += w v). NF, NC,
 * STRIDE: the feature and colour channel counts and the stride of `pad` when known at
 * compile time (0: read them from t); known, every address of the tap loop is one register
 * plus a constant (with run-time strides GCC ran out of registers for them). */
template <class V, int NF, int NC, int64_t STRIDE>
RTD_INLINE void block_taps(const TapRow &t, int64_t x) {
    const int64_t nf = NF ? NF : t.n_feat, nc = NC ? NC : t.n_ch;
    const int64_t wp = STRIDE ? STRIDE : t.stride, r = t.k / 2;
    const float *RESTRICT values = t.pad + nf * wp;
    const float *RESTRICT mask = values + nc * wp;
    V f[NF ? NF : 1];  // this block's features, held over its taps
    for (int64_t c = 0; c < NF; ++c) f[c] = load<V>(t.feats + c * t.hw + x);
    auto feature = [&](int64_t c) { return NF ? f[c] : load<V>(t.feats + c * t.hw + x); };
    const V neg_a = -load<V>(t.a + x);
    using Bits = decltype(as_bits(neg_a));
    V den = load<V>(t.den + x);
    V acc[NC ? NC : 1];
    for (int64_t c = 0; c < NC; ++c) acc[c] = load<V>(t.num + c * TILE + x);
    for (int64_t j = 0; j < t.k; ++j) {
        if (j == t.skip) continue;
        const int64_t p = t.margin + x + (j - r) * t.d;  // the neighbour in `pad`
        // the distance as the numba kernel groups it: four channels at a time, then the rest
        V s{};
        int64_t c = 0;
        for (; c + 4 <= nf; c += 4) {
            V d0 = feature(c) - load<V>(t.pad + c * wp + p);
            V d1 = feature((c + 1)) - load<V>(t.pad + (c + 1) * wp + p);
            V d2 = feature((c + 2)) - load<V>(t.pad + (c + 2) * wp + p);
            V d3 = feature((c + 3)) - load<V>(t.pad + (c + 3) * wp + p);
            V g = (d0 * d0 + d1 * d1) + (d2 * d2 + d3 * d3);
            s = c == 0 ? g : g + s;
        }
        for (; c < nf; ++c) {
            V d0 = feature(c) - load<V>(t.pad + c * wp + p);
            s = c == 0 ? d0 * d0 : s + d0 * d0;
        }
        V wt = from_bits(as_bits(exp_short(neg_a * s)) & load<Bits>(t.inside + p));
        if (t.masked) wt = wt * load<V>(mask + p);
        den = den + wt;
        if (NC) {
            for (int64_t ch = 0; ch < NC; ++ch) acc[ch] = acc[ch] + wt * load<V>(values + ch * wp + p);
        } else {
            for (int64_t ch = 0; ch < nc; ++ch) {
                float *num = t.num + ch * TILE + x;
                store(num, load<V>(num) + wt * load<V>(values + ch * wp + p));
            }
        }
    }
    store(t.den + x, den);
    for (int64_t c = 0; c < NC; ++c) store(t.num + c * TILE + x, acc[c]);
}

/* One tap row over a tile: blocks of LANES pixels, then the rest one by one. */
template <int NF, int NC, int64_t STRIDE>
RTD_INLINE void tile_taps(const TapRow &t) {
    const int64_t blocked = t.w - t.w % LANES;
    for (int64_t x = 0; x < blocked; x += LANES)
#if defined(__GNUC__)
        block_taps<VF, NF, NC, STRIDE>(t, x);
#else
        block_taps<float, NF, NC, STRIDE>(t, x);
#endif
    for (int64_t x = blocked; x < t.w; ++x) block_taps<float, NF, NC, STRIDE>(t, x);
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

struct Tile {  // output pixels [x0, x1) of a row, and its scratch
    int64_t x0, x1, margin, span, stride;  // pad: [x0 - margin, x0 - margin + span) of a tap
                                           // row per channel, `stride` apart
    float *num, *den, *pad;
    const int32_t *inside;
};

/* `count` floats of `src` from column `from` into dst, zeros where a column lies outside
 * [0, w) (the padding's values must be finite: a cleared weight multiplies them). */
RTD_INLINE void copy_padded(float *dst, const float *src, int64_t from, int64_t count, int64_t w) {
    const int64_t lo = std::max<int64_t>(0, -from), hi = std::min(count, w - from);
    std::fill(dst, dst + lo, 0.0f);
    std::memcpy(dst + lo, src + from + lo, static_cast<size_t>(hi - lo) * sizeof(float));
    std::fill(dst + hi, dst + count, 0.0f);
}

/* kernels/affinity_filter.py affinity_taps: the taps of one kernel into the sums of one tile
 * of output row y. */
RTD_INLINE void affinity_taps(const Taps &t, const Tile &tile, int64_t n_ch, int64_t n_feat,
                              int64_t h, int64_t w, int64_t y) {
    const int64_t hw = h * w, r = t.k / 2, wp = tile.stride, span = tile.span;
    const int64_t from = tile.x0 - tile.margin;
    TapRow row{t.feats + y * w + tile.x0, t.a + tile.x0, tile.pad, tile.inside, tile.num,
               tile.den, n_feat, n_ch, hw, tile.x1 - tile.x0, wp, tile.margin, t.k, t.d, -1,
               t.mask != nullptr};
    for (int64_t i = 0; i < t.k; ++i) {
        const int64_t yy = y + (i - r) * t.d;
        if (yy < 0 || yy >= h) continue;  // the whole tap row lies outside: weight 0
        for (int64_t c = 0; c < n_feat; ++c)
            copy_padded(tile.pad + c * wp, t.guides + c * hw + yy * w, from, span, w);
        for (int64_t c = 0; c < n_ch; ++c)
            copy_padded(tile.pad + (n_feat + c) * wp, t.values + c * hw + yy * w, from, span, w);
        if (t.mask) copy_padded(tile.pad + (n_feat + n_ch) * wp, t.mask + yy * w, from, span, w);
        row.skip = t.skip_centre && i == r ? r : -1;
        if (n_feat == 8 && n_ch == 3 && wp == PAD_STRIDE)  // demo:affinity's: all unrolled
            tile_taps<8, 3, PAD_STRIDE>(row);
        else
            tile_taps<0, 0, 0>(row);
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
 * temporal_affinity_filter.py's temporal taps between them) for one tile of output row
 * `row` (image n = row / h). */
RTD_INLINE void affinity_tile(const AffinityArgs &a, const Tile &tile, int64_t row) {
    const int64_t n_ch = a.n_ch, n_feat = a.n_feat, h = a.h, w = a.w, hw = h * w;
    const int64_t n = row / h, y = row - n * h, x0 = tile.x0, tw = tile.x1 - x0;
    const float *image = a.image + n * n_ch * hw;
    const float *feats = a.features + n * n_feat * hw;
    {  // the centre tap starts the sums (Isik21 eq. (4))
        const float *RESTRICT c_row = a.centre + n * hw + y * w + x0;
        float *RESTRICT dn = tile.den;
        for (int64_t x = 0; x < tw; ++x) dn[x] = c_row[x];
        for (int64_t c = 0; c < n_ch; ++c) {
            float *RESTRICT nc = tile.num + c * TILE;
            const float *RESTRICT src = image + c * hw + y * w + x0;
            for (int64_t x = 0; x < tw; ++x) nc[x] = c_row[x] * src[x];
        }
    }
    Taps spatial{feats, a.bandwidth + n * hw + y * w, image, feats, nullptr, a.k, a.d, true};
    affinity_taps(spatial, tile, n_ch, n_feat, h, w, y);
    if (a.previous) {  // eq. (7): the temporal kernel, no centre weight, masked
        Taps temporal{feats, a.temporal_bandwidth + n * hw + y * w, a.previous + n * n_ch * hw,
                      a.previous_features + n * n_feat * hw, a.valid + n * hw, a.kt, 1, false};
        affinity_taps(temporal, tile, n_ch, n_feat, h, w, y);
    }
    {  // eq. (6) / (8): out = num / (1e-10 + den)
        float *RESTRICT dn = tile.den;
        for (int64_t x = 0; x < tw; ++x) dn[x] = 1.0f / (EPS + dn[x]);
        for (int64_t c = 0; c < n_ch; ++c) {
            float *RESTRICT o = a.out + (n * n_ch + c) * hw + y * w + x0;
            const float *RESTRICT nc = tile.num + c * TILE;
            for (int64_t x = 0; x < tw; ++x) o[x] = nc[x] * dn[x];
        }
    }
}

/* Output rows [begin, end), a tile of TILE columns at a time down all of them: a tile's
 * scratch stays in L1 over its taps, and the input rows its taps read stay in L2 from one
 * output row to the next (whole 720p rows, as the numba kernel runs them, thrash both). */
RTD_CLONES void affinity_rows(const AffinityArgs &a, int64_t begin, int64_t end) {
    const int64_t margin = std::max((a.k / 2) * a.d, a.kt / 2);  // the widest reach in x
    const int64_t span = TILE + 2 * margin, wp = std::max(span, PAD_STRIDE);
    std::vector<float> buffer(static_cast<size_t>((a.n_ch + 1) * TILE +
                                                  (a.n_feat + a.n_ch + 1) * wp));
    std::vector<int32_t> inside(static_cast<size_t>(span));
    Tile tile{0, 0, margin, span, wp, buffer.data(), buffer.data() + a.n_ch * TILE,
              buffer.data() + (a.n_ch + 1) * TILE, inside.data()};
    for (tile.x0 = 0; tile.x0 < a.w; tile.x0 += TILE) {
        tile.x1 = std::min(a.w, tile.x0 + TILE);
        for (int64_t p = 0; p < span; ++p) {
            const int64_t x = tile.x0 - margin + p;
            inside[static_cast<size_t>(p)] = x >= 0 && x < a.w ? -1 : 0;
        }
        for (int64_t row = begin; row < end; ++row) affinity_tile(a, tile, row);
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

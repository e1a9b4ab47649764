/* The input guard of runtime/guard.py as C functions (rtdenoise_guard.h): what a C or C++
 * host applies to every buffer before `session.Run`, as `Denoiser.process` does.
 *
 * Bit-identical to `guard.guard_buffer` in float32 (tests/test_native_guard.py), so each step
 * below is the NumPy call it mirrors, in the same order:
 *   1. min and max of the buffer (NaN propagates): the early return when every value is
 *      finite and in range and, for colour, none is above 64 x 16 (no outlier is possible);
 *   2. when any value is NaN/Inf: `np.nan_to_num` with the rule's values, the pixels counted;
 *   3. when any value is outside the range: the pixels counted, colour above it made 0, then
 *      `np.clip` to the range over the whole buffer;
 *   4. colour: `replace_outliers`, the per-pixel maximum over the planes (`m`), each pixel of
 *      m above 1024 compared with the maximum of its 8 neighbours in m (outside the frame: 0)
 *      and scaled by neighbour maximum / own maximum (a float32 division, a float32 multiply);
 *      every pixel against the unscaled m, as the vectorised NumPy code does;
 *   5. zero: no value is non-zero.
 * The bounds are compared as NumPy does: the early return's in doubles (Python floats), the
 * masks and the clip in float32 (NumPy casts a Python float to the array's float32). Ties
 * between signed zeros resolve as NumPy's loops do (np.maximum(a, b): b; np.clip: the value),
 * which only ever decides the sign of a zero.
 *
 * Built into librtdenoise_ops (setup.py) with -ffp-contract=off: nothing here is fused.
 * No exception leaves a function: every failure is a negative return value.
 */

#define RTDENOISE_GUARD_BUILD
#include "rtdenoise_guard.h"

#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <new>
#include <vector>

namespace {

// runtime/guard.py and runtime/contract.py
constexpr double HALF_MAX = 65504.0;
constexpr double ALBEDO_MAX = 1.0;
constexpr double DEPTH_MAX = 1e10;
constexpr double MOTION_FRAMES = 2.0;  // motion bound in multiples of max(H, W)
constexpr float OUTLIER_RATIO = 64.0f;
constexpr float OUTLIER_FLOOR = 16.0f;

/* guard.Rule, in absolute values for the frame (Rule.scaled). */
struct Rule {
    double low, high, nan, posinf, neginf;
    bool has_above;  // values above `high` become `above` (else `high`)
    double above;
    bool outliers;
};

bool is(const char *name, const char *what) { return std::strcmp(name, what) == 0; }

Rule rule_for(const char *name, int64_t h, int64_t w) {
    if (is(name, "color") || is(name, "color_b")) return {0.0, HALF_MAX, 0.0, 0.0, 0.0, true, 0.0, true};
    if (is(name, "albedo")) return {0.0, ALBEDO_MAX, 0.0, 0.0, 0.0, false, 0.0, false};
    if (is(name, "normal")) return {-1.0, 1.0, 0.0, 0.0, 0.0, false, 0.0, false};
    if (is(name, "depth")) return {0.0, DEPTH_MAX, 0.0, DEPTH_MAX, 0.0, false, 0.0, false};
    if (is(name, "motion")) {
        const double s = static_cast<double>(h > w ? h : w);
        return {-MOTION_FRAMES * s, MOTION_FRAMES * s, MOTION_FRAMES * s, MOTION_FRAMES * s,
                -MOTION_FRAMES * s, false, 0.0, false};
    }
    return {-HALF_MAX, HALF_MAX, 0.0, 0.0, 0.0, false, 0.0, false};  // DEFAULT_RULE
}

bool is_guide(const char *name) { return is(name, "albedo") || is(name, "normal") || is(name, "depth"); }

/* planes x height x width values, each >= 1, countable in size_t and int64_t. */
bool value_count(int64_t planes, int64_t height, int64_t width, size_t *pixels, size_t *values) {
    if (planes < 1 || height < 1 || width < 1) return false;
    const uint64_t limit = static_cast<uint64_t>(std::numeric_limits<int64_t>::max()) / sizeof(float);
    const uint64_t h = static_cast<uint64_t>(height), w = static_cast<uint64_t>(width);
    const uint64_t p = static_cast<uint64_t>(planes);
    if (h > limit / w || h * w > limit / p) return false;
    if (h * w * p > std::numeric_limits<size_t>::max() / sizeof(float)) return false;
    *pixels = static_cast<size_t>(h * w);
    *values = static_cast<size_t>(h * w * p);
    return true;
}

/* Lane k of `count` (<= the lanes) values: its min, max and whether any is NaN/Inf. */
inline void scan(const float *x, float *lo, float *hi, uint32_t *bad, size_t count) {
    for (size_t k = 0; k < count; ++k) {
        uint32_t bits;
        std::memcpy(&bits, x + k, sizeof bits);
        bad[k] |= static_cast<uint32_t>((bits & 0x7f800000u) == 0x7f800000u);
        lo[k] = x[k] < lo[k] ? x[k] : lo[k];
        hi[k] = x[k] > hi[k] ? x[k] : hi[k];
    }
}

size_t ones(const std::vector<uint8_t> &mask) {
    size_t n = 0;
    for (uint8_t v : mask) n += v;
    return n;
}

int guard(const char *name, const float *input, float *output, int64_t planes, int64_t height,
          int64_t width, rtdenoise_guard_counts *counts, uint8_t *nonfinite_mask) {
    if (!name || !input || !output) return RTDENOISE_GUARD_NULL_ARGUMENT;
    size_t pixels = 0, n = 0;
    if (!value_count(planes, height, width, &pixels, &n)) return RTDENOISE_GUARD_BAD_SHAPE;
    const uintptr_t a = reinterpret_cast<uintptr_t>(input), b = reinterpret_cast<uintptr_t>(output);
    const uintptr_t bytes = static_cast<uintptr_t>(n * sizeof(float));
    if (a != b && a < b + bytes && b < a + bytes) return RTDENOISE_GUARD_OVERLAP;
    const Rule r = rule_for(name, height, width);

    // 1. min, max (NaN propagates in NumPy: here a NaN/Inf flag from the exponent bits),
    // in LANES independent lanes so that the compiler vectorises the pass
    constexpr size_t LANES = 16;
    float los[LANES], his[LANES];
    uint32_t bad[LANES];
    for (size_t k = 0; k < LANES; ++k)
        los[k] = std::numeric_limits<float>::infinity(), his[k] = -los[k], bad[k] = 0;
    size_t i = 0;
    for (; i + LANES <= n; i += LANES) scan(input + i, los, his, bad, LANES);
    scan(input + i, los, his, bad, n - i);
    float lo = los[0], hi = his[0];
    uint32_t nonfinite = bad[0];
    for (size_t k = 1; k < LANES; ++k) {
        lo = los[k] < lo ? los[k] : lo;
        hi = his[k] > hi ? his[k] : hi;
        nonfinite |= bad[k];
    }
    const bool finite = nonfinite == 0;
    const bool in_range = finite && r.low <= lo && hi <= r.high;
    const double outlier_min = static_cast<double>(OUTLIER_RATIO) * OUTLIER_FLOOR;
    rtdenoise_guard_counts c{0, 0, 0, 0, 0};
    if (in_range && !(r.outliers && hi > outlier_min)) {
        if (output != input) std::memcpy(output, input, n * sizeof(float));
        c.zero = lo == 0.0f && hi == 0.0f;
        if (counts) *counts = c;
        return RTDENOISE_GUARD_OK;
    }
    std::vector<uint8_t> pixel;  // (H, W): the pixel mask of one step
    std::vector<float> m;        // (H, W): the largest value over the planes
    try {
        pixel.assign(pixels, 0);
        if (r.outliers) m.resize(pixels);
    } catch (const std::bad_alloc &) {
        return RTDENOISE_GUARD_OUT_OF_MEMORY;
    }
    if (output != input) std::memcpy(output, input, n * sizeof(float));
    float *data = output;

    // 2. np.nan_to_num(a, nan=r.nan, posinf=r.posinf, neginf=r.neginf)
    if (!finite) {
        const float vnan = static_cast<float>(r.nan), vpos = static_cast<float>(r.posinf),
                    vneg = static_cast<float>(r.neginf);
        for (float *plane = data; plane != data + n; plane += pixels)
            for (size_t i = 0; i < pixels; ++i) {
                const float x = plane[i];
                if (!std::isfinite(x)) {
                    pixel[i] = 1;
                    plane[i] = std::isnan(x) ? vnan : (x > 0.0f ? vpos : vneg);
                }
            }
        c.nonfinite = static_cast<int64_t>(ones(pixel));
        if (nonfinite_mask)
            for (size_t i = 0; i < pixels; ++i)
                if (pixel[i]) nonfinite_mask[i] = 1;
    }

    // 3. pixels outside [low, high]; a[a > high] = above; np.clip(a, low, high)
    if (!in_range) {
        std::fill(pixel.begin(), pixel.end(), uint8_t{0});
        const float low = static_cast<float>(r.low), high = static_cast<float>(r.high);
        const float above = static_cast<float>(r.above);
        for (float *plane = data; plane != data + n; plane += pixels)
            for (size_t i = 0; i < pixels; ++i) {
                float x = plane[i];
                const bool over = x > high;
                pixel[i] |= static_cast<uint8_t>(over || x < low);
                if (over && r.has_above) x = above;
                x = x < low ? low : x;  // np.clip: the value itself on a tie
                x = x > high ? high : x;
                plane[i] = x;
            }
        c.clamped = static_cast<int64_t>(ones(pixel));
    }

    // 4. replace_outliers
    if (r.outliers) {
        const size_t np_ = static_cast<size_t>(planes);
        std::memcpy(m.data(), data, pixels * sizeof(float));
        for (size_t p = 1; p < np_; ++p)
            for (size_t i = 0; i < pixels; ++i) {
                const float v = data[p * pixels + i];
                m[i] = m[i] > v ? m[i] : v;  // np.maximum
            }
        const float candidate = OUTLIER_RATIO * OUTLIER_FLOOR;
        const int64_t h = height, w = width;
        for (int64_t y = 0; y < h; ++y)
            for (int64_t x = 0; x < w; ++x) {
                const size_t i = static_cast<size_t>(y * w + x);
                const float peak = m[i];
                if (!(peak > candidate)) continue;
                float near = 0.0f;  // _neighbour_max: np.maximum(best, where(inside, m, 0))
                for (int dy = -1; dy <= 1; ++dy)
                    for (int dx = -1; dx <= 1; ++dx) {
                        if (dy == 0 && dx == 0) continue;
                        const int64_t yy = y + dy, xx = x + dx;
                        const bool inside = yy >= 0 && yy < h && xx >= 0 && xx < w;
                        const float v = inside ? m[static_cast<size_t>(yy * w + xx)] : 0.0f;
                        near = near > v ? near : v;
                    }
                const float floor = near > OUTLIER_FLOOR ? near : OUTLIER_FLOOR;
                if (!(peak > OUTLIER_RATIO * floor)) continue;
                const float scale = near / peak;
                for (size_t p = 0; p < np_; ++p) data[p * pixels + i] *= scale;
                ++c.outliers;
            }
    }

    // 5. zero: not a.any()
    bool any = false;
    for (size_t i = 0; i < n && !any; ++i) any = data[i] != 0.0f;
    c.zero = !any;
    if (counts) *counts = c;
    return RTDENOISE_GUARD_OK;
}

}  // namespace

extern "C" {

RTDENOISE_GUARD_API int rtdenoise_guard_buffer(const char *name, const float *input, float *output,
                                               int64_t planes, int64_t height, int64_t width,
                                               rtdenoise_guard_counts *counts,
                                               uint8_t *nonfinite_mask) {
    try {
        return guard(name, input, output, planes, height, width, counts, nonfinite_mask);
    } catch (...) {
        return RTDENOISE_GUARD_FAILED;
    }
}

RTDENOISE_GUARD_API int rtdenoise_guard_zero_guide(const char *name, const float *data, int64_t count) {
    if (!name || !data) return RTDENOISE_GUARD_NULL_ARGUMENT;
    if (count < 1) return RTDENOISE_GUARD_BAD_SHAPE;
    if (!is_guide(name)) return 0;
    for (int64_t i = 0; i < count; ++i)
        if (data[i] != 0.0f) return 0;
    return 1;
}

RTDENOISE_GUARD_API const char *rtdenoise_guard_error(int code) {
    switch (code) {
        case RTDENOISE_GUARD_OK: return "ok";
        case RTDENOISE_GUARD_NULL_ARGUMENT: return "a required pointer (name, input, output) is NULL";
        case RTDENOISE_GUARD_BAD_SHAPE: return "planes, height and width must be >= 1 (and count the values in 64 bits)";
        case RTDENOISE_GUARD_OVERLAP: return "output overlaps input without being it";
        case RTDENOISE_GUARD_OUT_OF_MEMORY: return "out of memory";
        case RTDENOISE_GUARD_FAILED: return "the guard failed";
        default: return "not a return value of rtdenoise_guard_*";
    }
}

}  // extern "C"

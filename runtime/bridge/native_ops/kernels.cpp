/* The kernels of rtdenoise_ops whose numba kernels are compiled without fastmath: Reproject
 * and TemporalAccumulation, in the torch form's float32 arithmetic step by step, no fused
 * multiply-add (built with -ffp-contract=off), so that they agree with numba and torch to the
 * bit (a history-validity decision that flipped between forms would change a pixel's whole
 * history); the thread split every op uses; the table of ops (filters.cpp holds the others).
 */
#if defined(__unix__) || defined(__APPLE__)
#include <pthread.h>
#endif

#include <atomic>
#include <condition_variable>
#include <exception>
#include <functional>
#include <limits>
#include <mutex>
#include <thread>

#if defined(__x86_64__) || defined(_M_X64) || defined(__i386__) || defined(_M_IX86)
#include <xmmintrin.h>
#define RTD_HAS_MXCSR 1
#endif

#include "kernels_common.h"

namespace rtd {

namespace filters {  // filters.cpp
std::string kernel_apply_shapes(const Tensor *in, const int64_t *attrs, Shape *out);
void kernel_apply_run(const Tensor *in, Tensor *out, const int64_t *attrs, int threads);
std::string softmax_kernel_apply_shapes(const Tensor *in, const int64_t *attrs, Shape *out);
void softmax_kernel_apply_run(const Tensor *in, Tensor *out, const int64_t *attrs, int threads);
std::string kernel_fusion_shapes(const Tensor *in, const int64_t *attrs, Shape *out);
void kernel_fusion_run(const Tensor *in, Tensor *out, const int64_t *attrs, int threads);
std::string adaptive_fusion_shapes(const Tensor *in, const int64_t *attrs, Shape *out);
void adaptive_fusion_run(const Tensor *in, Tensor *out, const int64_t *attrs, int threads);
std::string weight_sharing_filter_shapes(const Tensor *in, const int64_t *attrs, Shape *out);
void weight_sharing_filter_run(const Tensor *in, Tensor *out, const int64_t *attrs, int threads);
std::string bilateral_grid_shapes(const Tensor *in, const int64_t *attrs, Shape *out);
void bilateral_grid_run(const Tensor *in, Tensor *out, const int64_t *attrs, int threads);
}  // namespace filters

/* ------------------------------------------------------------------ floating-point mode */

#ifdef RTD_HAS_MXCSR
constexpr unsigned FTZ_DAZ = 0x8040;  // MXCSR flush-to-zero (bit 15), denormals-are-zero (6)
unsigned FpMode::current() { return _mm_getcsr(); }
unsigned FpMode::flushed() { return _mm_getcsr() | FTZ_DAZ; }
FpMode::FpMode(unsigned mode) : saved_(_mm_getcsr()) { _mm_setcsr(mode); }
FpMode::~FpMode() { _mm_setcsr(saved_); }
#else
unsigned FpMode::current() { return 0; }
unsigned FpMode::flushed() { return 0; }
FpMode::FpMode(unsigned) {}
FpMode::~FpMode() {}
#endif

/* ------------------------------------------------------------------ threads */

namespace {

/* The threads that run the chunks after the caller's first: started once, on first use, and
 * kept (a thread started per call waits for the scheduler on a busy machine: measured,
 * TemporalAccumulation at 720p on 2 threads ran slower than on 1). One caller at a time
 * uses them; a second caller meanwhile runs its chunks on threads of its own. A forked child
 * (Python's multiprocessing) has none of the parent's threads: it starts a pool anew. */
class Pool {
  public:
    static Pool &instance() {
        static bool hooked = [] {
#if defined(__unix__) || defined(__APPLE__)
            pthread_atfork(nullptr, nullptr, [] { current() = new Pool(); });  // old one leaked
#endif
            return true;
        }();
        (void)hooked;
        return *current();
    }

    /* Run chunk(t) for t in [1, team) on the pool; false (nothing run) if it is busy or
     * cannot grow to team - 1 workers. */
    bool run(int64_t team, const std::function<void(int64_t)> &chunk, std::function<void()> own) {
        std::unique_lock<std::mutex> busy(use_, std::try_to_lock);
        if (!busy.owns_lock()) return false;
        try {
            while (static_cast<int64_t>(workers_.size()) < team - 1)
                workers_.emplace_back([this, i = workers_.size()] { loop(static_cast<int64_t>(i)); });
        } catch (...) {
            if (static_cast<int64_t>(workers_.size()) < team - 1) return false;
        }
        {
            std::lock_guard<std::mutex> lock(m_);
            job_ = &chunk;
            active_ = team - 1;
            pending_ = team - 1;
            ++generation_;
        }
        wake_.notify_all();
        own();
        std::unique_lock<std::mutex> lock(m_);
        done_.wait(lock, [this] { return pending_ == 0; });
        job_ = nullptr;
        return true;
    }

  private:
    static Pool *&current() {
        static Pool *pool = new Pool();  // never destroyed: workers may outlive static dtors
        return pool;
    }

    void loop(int64_t index) {
        uint64_t seen = 0;
        std::unique_lock<std::mutex> lock(m_);
        for (;;) {
            wake_.wait(lock, [&] { return generation_ != seen; });
            seen = generation_;
            if (index >= active_) continue;  // not needed this time
            const std::function<void(int64_t)> *job = job_;
            lock.unlock();
            (*job)(index + 1);
            lock.lock();
            if (--pending_ == 0) done_.notify_one();
        }
    }

    std::mutex use_;  // one caller at a time
    std::mutex m_;
    std::condition_variable wake_, done_;
    std::vector<std::thread> workers_;
    const std::function<void(int64_t)> *job_ = nullptr;
    int64_t active_ = 0, pending_ = 0;
    uint64_t generation_ = 0;
};

}  // namespace

void parallel_rows(int64_t rows, int threads, int64_t work, void (*fn)(void *, int64_t, int64_t),
                   void *ctx) {
    if (rows <= 0) return;
    const int64_t team = std::max<int64_t>(1, std::min<int64_t>({threads, rows, work / GRAIN}));
    if (team == 1) {
        fn(ctx, 0, rows);
        return;
    }
    // Chunks taken in turn from a counter, 8 per thread: on a loaded machine one thread gets
    // less of a core, and with one fixed half each the others waited for it (BilateralGrid at
    // 720p ran slower on 2 threads than on 1). The split does not change any number.
    const int64_t chunks = std::min<int64_t>(rows, 8 * team);
    auto bounds = [&](int64_t c) { return rows * c / chunks; };
    std::atomic<int64_t> next{0};
    std::vector<std::exception_ptr> errors(static_cast<size_t>(team));
    const unsigned mode = FpMode::current();  // the workers take the caller's
    std::function<void(int64_t)> chunk = [&](int64_t t) {
        try {  // nothing may leave a thread (std::terminate): rethrown on the caller's below
            const FpMode same_mode(mode);
            for (int64_t c = next++; c < chunks; c = next++) fn(ctx, bounds(c), bounds(c + 1));
        } catch (...) {
            errors[static_cast<size_t>(t)] = std::current_exception();
            next = chunks;  // the others stop too
        }
    };
    if (!Pool::instance().run(team, chunk, [&] { chunk(0); })) {
        std::vector<std::thread> workers;  // the pool is busy: threads of this call's own
        int64_t started = 1;
        try {
            workers.reserve(static_cast<size_t>(team - 1));
            for (; started < team; ++started) workers.emplace_back(chunk, started);
        } catch (...) {  // no more threads to be had: the caller runs the chunks left
        }
        for (int64_t t = started; t < team; ++t) chunk(t);
        chunk(0);
        for (auto &w : workers) w.join();
    }
    for (auto &e : errors)
        if (e) std::rethrow_exception(e);
}

namespace {

using namespace detail;
using namespace filters;

/* ------------------------------------------------------------------ Reproject */

std::string reproject_shapes(const Tensor *in, const int64_t *attrs, Shape *out) {
    const char *names[] = {"previous", "motion"};
    std::string e = same_nhw("Reproject", in, names, 2);
    if (!e.empty()) return e;
    if (in[1].dims[1] != 2)
        return "Reproject: motion has " + std::to_string(in[1].dims[1]) +
               " channels; expected 2 (x, y)";
    if (attrs[0] != 0 && attrs[0] != 1)
        return "Reproject: nearest is " + std::to_string(attrs[0]) + "; expected 0 or 1";
    copy_shape(in[0], out[0]);
    return "";
}

/* kernels/reproject.py _taps: the flat offsets of each pixel's four bilinear taps and their
 * weights, in float32 as the torch form computes them. Two loops, the offsets then the weights
 * (each position computed twice, the same bits): GCC vectorises either, not one loop with all
 * eight stores. */
RTD_INLINE void taps_row(const float *RESTRICT mx, const float *RESTRICT my, int64_t y,
                         int64_t h, int64_t w, int32_t *RESTRICT taps,
                         float *RESTRICT weights) {
    const float one = 1.0f, fw1 = static_cast<float>(w - 1), fh1 = static_cast<float>(h - 1);
    const float y_f = static_cast<float>(y);
    const int32_t w32 = static_cast<int32_t>(w), wm1 = w32 - 1, hm1 = static_cast<int32_t>(h) - 1;
    for (int32_t x = 0; x < w32; ++x) {  // int32: converts to float in vectors
        const float px = clamped(static_cast<float>(x) + mx[x], fw1);
        const float py = clamped(y_f + my[x], fh1);
        const int32_t cx = static_cast<int32_t>(px), cy = static_cast<int32_t>(py);  // >= 0
        const int32_t x1 = cx + 1 < wm1 ? cx + 1 : wm1, y1 = cy + 1 < hm1 ? cy + 1 : hm1;
        taps[x] = cy * w32 + cx;  // offsets into one plane (the pixel cap keeps them < 2^31)
        taps[w + x] = cy * w32 + x1;
        taps[2 * w + x] = y1 * w32 + cx;
        taps[3 * w + x] = y1 * w32 + x1;
    }
    for (int32_t x = 0; x < w32; ++x) {  // int32: converts to float in vectors
        const float px = clamped(static_cast<float>(x) + mx[x], fw1);
        const float py = clamped(y_f + my[x], fh1);
        const float wx = px - std::trunc(px);
        const float wy = py - std::trunc(py);
        const float ex = one - wx, ey = one - wy;
        weights[x] = ey * ex;
        weights[w + x] = ey * wx;
        weights[2 * w + x] = wy * ex;
        weights[3 * w + x] = wy * wx;
    }
}

/* Bilinear samples of `count` planes into rows of `out`, `stride` apart: each pixel's four
 * taps and weights are read once for all the planes (TemporalAccumulation's C + 5,
 * Reproject's C), not once a plane; each value is the four corner terms in the torch form's
 * order (kernels/reproject.py _gather_row). (A plane loop unrolled for a count known at
 * compile time ran slower: 0.74x at 320x240.) */
inline void gather_rows(const float *const *planes, int64_t count, float *RESTRICT out,
                        int64_t stride, const int32_t *RESTRICT t, const float *RESTRICT wt,
                        int64_t w) {
    for (int64_t x = 0; x < w; ++x) {
        const int32_t t0 = t[x], t1 = t[w + x], t2 = t[2 * w + x], t3 = t[3 * w + x];
        const float w0 = wt[x], w1 = wt[w + x], w2 = wt[2 * w + x], w3 = wt[3 * w + x];
        for (int64_t p = 0; p < count; ++p) {
            const float *RESTRICT plane = planes[p];
            out[p * stride + x] = plane[t0] * w0 + plane[t1] * w1 + plane[t2] * w2 + plane[t3] * w3;
        }
    }
}

struct ReprojectArgs {
    const float *previous, *motion;
    float *out;
    int64_t n_ch, h, w;
};

RTD_CLONES void reproject_rows(const ReprojectArgs &a, int64_t begin, int64_t end) {
    const int64_t h = a.h, w = a.w, hw = h * w;
    std::vector<int32_t> taps(static_cast<size_t>(4 * w));
    std::vector<float> weights(static_cast<size_t>(4 * w));
    std::vector<const float *> planes(static_cast<size_t>(a.n_ch));
    for (int64_t row = begin; row < end; ++row) {
        const int64_t n = row / h, y = row - n * h;
        const float *m = a.motion + (n * 2 * h + y) * w;
        taps_row(m, m + hw, y, h, w, taps.data(), weights.data());
        for (int64_t c = 0; c < a.n_ch; ++c) planes[c] = a.previous + (n * a.n_ch + c) * hw;
        gather_rows(planes.data(), a.n_ch, a.out + (n * a.n_ch * h + y) * w, hw, taps.data(),
                    weights.data(), w);
    }
}

/* kernels/reproject.py _nearest: the flat offset of each pixel's nearest source pixel,
 * floor(p + 0.5) of the clamped position (>= 0.5, so truncation is the floor). */
RTD_INLINE void nearest_row(const float *RESTRICT mx, const float *RESTRICT my, int64_t y,
                            int64_t h, int64_t w, int32_t *RESTRICT index) {
    const float half = 0.5f, fw1 = static_cast<float>(w - 1), fh1 = static_cast<float>(h - 1);
    const float y_f = static_cast<float>(y);
    const int32_t w32 = static_cast<int32_t>(w);
    for (int32_t x = 0; x < w32; ++x) {
        const int32_t cx = static_cast<int32_t>(clamped(static_cast<float>(x) + mx[x], fw1) + half);
        const int32_t cy = static_cast<int32_t>(clamped(y_f + my[x], fh1) + half);
        index[x] = cy * w32 + cx;
    }
}

RTD_CLONES void reproject_nearest_rows(const ReprojectArgs &a, int64_t begin, int64_t end) {
    const int64_t h = a.h, w = a.w, hw = h * w;
    std::vector<int32_t> index(static_cast<size_t>(w));
    for (int64_t row = begin; row < end; ++row) {
        const int64_t n = row / h, y = row - n * h;
        const float *m = a.motion + (n * 2 * h + y) * w;
        nearest_row(m, m + hw, y, h, w, index.data());
        for (int64_t c = 0; c < a.n_ch; ++c) {
            const float *RESTRICT plane = a.previous + (n * a.n_ch + c) * hw;
            float *RESTRICT dst = a.out + ((n * a.n_ch + c) * h + y) * w;
            for (int64_t x = 0; x < w; ++x) dst[x] = plane[index[x]];
        }
    }
}

void reproject_run(const Tensor *in, Tensor *out, const int64_t *attrs, int threads) {
    ReprojectArgs a{in[0].data, in[1].data, out[0].data, in[0].dims[1], in[0].dims[2],
                    in[0].dims[3]};
    if (attrs[0] == 1) {
        parallel_for(in[0].dims[0] * a.h, threads, out[0].size() + 4 * in[1].size(),
                     [&](int64_t b, int64_t e) { reproject_nearest_rows(a, b, e); });
        return;
    }
    parallel_for(in[0].dims[0] * a.h, threads, 4 * out[0].size() + 8 * in[1].size(),
                 [&](int64_t b, int64_t e) { reproject_rows(a, b, e); });
}

/* ------------------------------------------------------------------ TemporalAccumulation */

std::string temporal_accumulation_shapes(const Tensor *in, const int64_t *attrs, Shape *out) {
    static const char *names[] = {"current", "motion", "depth", "normal", "ta_state",
                                  "geometry_state"};
    if (attrs[0] < 0 || attrs[0] > 3)
        return "TemporalAccumulation: per_tap is " + std::to_string(attrs[0]) +
               "; expected 0, 1, 2 or 3";
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

/* TemporalAccumulation's per-pixel step of a row: the history test, n and alpha. Every value
 * is computed and chosen by selects, nothing branched on (the tests' outcomes vary from pixel
 * to pixel): a loop of its own over plain row pointers, which GCC vectorises. */
RTD_INLINE void ta_validity_row(const TaArgs &a, const float *RESTRICT mx,
                                const float *RESTRICT my, float y_f, const float *RESTRICT d_row,
                                const float *RESTRICT nx, const float *RESTRICT ny,
                                const float *RESTRICT nz, const float *RESTRICT count,
                                const float *RESTRICT pnx, const float *RESTRICT pny,
                                const float *RESTRICT pnz, const float *RESTRICT prev_depth,
                                float *RESTRICT ok, float *RESTRICT alpha,
                                float *RESTRICT new_len, int64_t w) {
    const float zero = 0.0f, one = 1.0f, half = 0.5f, lo = -0.5f;
    const float hi_x = static_cast<float>(w) - half, hi_y = static_cast<float>(a.h) - half;
    const float keep = a.keep, tolerance = a.tolerance, threshold = a.threshold;
    const float min_alpha = a.min_alpha, max_history = a.max_history;
    for (int32_t x = 0; x < static_cast<int32_t>(w); ++x) {
        const float px = static_cast<float>(x) + mx[x];
        const float py = y_f + my[x];
        const bool inside = (px >= lo) & (px <= hi_x) & (py >= lo) & (py <= hi_y);
        const float d = d_row[x];
        const bool depth_ok = std::fabs(prev_depth[x] - d) < tolerance * std::fabs(d);
        float dot = pnx[x] * nx[x];
        dot += pny[x] * ny[x];
        dot += pnz[x] * nz[x];
        const float valid = (inside & depth_ok & (dot > threshold)) ? one : zero;
        const bool kept = valid * keep > half;
        ok[x] = kept ? one : zero;
        const float n_next = (kept ? count[x] : zero) + one;
        alpha[x] = max_like_numba(one / n_next, min_alpha);
        new_len[x] = min_like_numba(n_next, max_history);
    }
}

RTD_CLONES void temporal_accumulation_rows(const TaArgs &a, int64_t begin, int64_t end) {
    const int64_t n_ch = a.n_ch, h = a.h, w = a.w, hw = h * w;
    std::vector<int32_t> taps(static_cast<size_t>(4 * w));
    std::vector<float> weights(static_cast<size_t>(4 * w));
    std::vector<float> warped_buffer(static_cast<size_t>((n_ch + 5) * w));
    std::vector<float> ok_buffer(static_cast<size_t>(w));  // 1 / 0: float, as the other rows
    std::vector<const float *> planes(static_cast<size_t>(n_ch + 5));
    float *warped = warped_buffer.data();
    float *RESTRICT ok = ok_buffer.data();
    const float zero = 0.0f, one = 1.0f;
    for (int64_t row = begin; row < end; ++row) {
        const int64_t n = row / h, y = row - n * h;
        const float *RESTRICT mx = a.motion + (n * 2 * h + y) * w;
        const float *RESTRICT my = mx + hw;
        taps_row(mx, my, y, h, w, taps.data(), weights.data());
        for (int64_t c = 0; c < n_ch + 1; ++c) planes[c] = a.ta_state + (n * (n_ch + 1) + c) * hw;
        for (int64_t c = 0; c < 4; ++c) planes[n_ch + 1 + c] = a.geometry + (n * 4 + c) * hw;
        gather_rows(planes.data(), n_ch + 5, warped, w, taps.data(), weights.data(), w);
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
        ta_validity_row(a, mx, my, y_f, d_row, nx, ny, nz, count, pnx, pny, pnz, prev_depth, ok,
                        alpha, new_len, w);
        for (int64_t c = 0; c < n_ch; ++c) {  // the blend, one channel row at a time
            const float *RESTRICT cur = a.current + ((n * n_ch + c) * h + y) * w;
            const float *RESTRICT hist = warped + c * w;
            float *RESTRICT acc = a.accumulated + ((n * n_ch + c) * h + y) * w;
            float *RESTRICT nta = a.next_ta + ((n * (n_ch + 1) + c) * h + y) * w;
            for (int64_t x = 0; x < w; ++x) {
                float al = alpha[x];
                float kept = ok[x] != zero ? hist[x] : zero;
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

/* per_tap = 1 (kernels/temporal_accumulation.py _temporal_accumulation_per_tap_nb): one pixel
 * at a time, its four taps (nw, ne, sw, se) tested and their weights and states summed in the
 * torch form's order, a rejected tap adding nothing; then the renormalisation and the blend.
 * hdr 1 (per_tap = 2): each accepted tap's averaging weight is divided by 1 + its brightness
 * (channel mean, summed in channel order, at least 0) above kHdrRatio x the darkest accepted
 * tap's + kHdrFloor (ops/temporal_accumulation.py HDR_RATIO, HDR_FLOOR), the 0.01 cut on the
 * plain weights; hdr 2 (per_tap = 3): by the square of that, a product. */
constexpr float kHdrRatio = 4.0f, kHdrFloor = 1.0f;
RTD_CLONES void temporal_accumulation_per_tap_rows(const TaArgs &a, int hdr, int64_t begin,
                                                   int64_t end) {
    const int64_t n_ch = a.n_ch, h = a.h, w = a.w, hw = h * w;
    const float zero = 0.0f, one = 1.0f, half = 0.5f, cut = 0.01f;
    const float x_max = static_cast<float>(w - 1), y_max = static_cast<float>(h - 1);
    for (int64_t row = begin; row < end; ++row) {
        const int64_t n = row / h, y = row - n * h;
        const float *mx = a.motion + (n * 2 * h + y) * w;
        const float *my = mx + hw;
        const float *d_row = a.depth + (n * h + y) * w;
        const float *nx = a.normal + (n * 3 * h + y) * w;
        const float *ny = nx + hw;
        const float *nz = ny + hw;
        const float *ta = a.ta_state + n * (n_ch + 1) * hw;
        const float *geo = a.geometry + n * 4 * hw;
        float *alpha = a.blend + (n * h + y) * w;
        float *new_len = a.next_ta + ((n * (n_ch + 1) + n_ch) * h + y) * w;
        const float y_f = static_cast<float>(y);
        for (int64_t x = 0; x < w; ++x) {
            const float px = static_cast<float>(x) + mx[x];
            const float py = y_f + my[x];
            const float x0 = std::floor(px), y0 = std::floor(py);
            const float ax = px - x0, ay = py - y0;
            const float ex = one - ax, ey = one - ay;
            const float d = d_row[x];
            const float tol = a.tolerance * std::fabs(d);
            // the four taps tested first, by selects (their outcomes vary pixel to pixel); a
            // rejected tap reads a safe pixel and adds nothing (acc kept, as numba's continue)
            int64_t idx[4];
            float wt[4];
            bool ok[4];
            for (int t = 0; t < 4; ++t) {
                const bool right = t & 1, down = t >> 1;
                const float fx = right ? x0 + one : x0;
                const float fy = down ? y0 + one : y0;
                wt[t] = (right ? ax : ex) * (down ? ay : ey);
                const bool inside = (fx >= zero) & (fx <= x_max) & (fy >= zero) & (fy <= y_max);
                const int64_t i = static_cast<int64_t>(inside ? fy : zero) * w +
                                  static_cast<int64_t>(inside ? fx : zero);
                const bool depth_ok = std::fabs(geo[3 * hw + i] - d) < tol;
                float dot = geo[i] * nx[x];
                dot += geo[hw + i] * ny[x];
                dot += geo[2 * hw + i] * nz[x];
                idx[t] = i;
                ok[t] = inside & depth_ok & (dot > a.threshold);
            }
            float av[4] = {wt[0], wt[1], wt[2], wt[3]};  // the averaging weights
            if (hdr) {  // models/temporal.py outlier_bound, then each tap over its excess
                float bright[4];
                float darkest = std::numeric_limits<float>::infinity();
                for (int t = 0; t < 4; ++t) {
                    float b = ta[idx[t]];
                    for (int64_t c = 1; c < n_ch; ++c) b = b + ta[c * hw + idx[t]];
                    b = b / static_cast<float>(n_ch);
                    bright[t] = b < zero ? zero : b;  // NaN stays NaN, as torch's clamp
                    darkest = ok[t] && bright[t] < darkest ? bright[t] : darkest;
                }
                const float bound = kHdrRatio * darkest + kHdrFloor;
                for (int t = 0; t < 4; ++t) {
                    const float excess = bright[t] - bound;
                    float scale = one + (excess < zero ? zero : excess);
                    if (hdr == 2) scale = scale * scale;
                    av[t] = wt[t] / scale;
                }
            }
            float total = zero, weighed = zero;  // the cut's weight; the averaging weight
            for (int t = 0; t < 4; ++t) {
                total = ok[t] ? total + wt[t] : total;
                weighed = ok[t] ? weighed + av[t] : weighed;
            }
            float count_sum = zero;
            for (int t = 0; t < 4; ++t) {
                const float v = ta[n_ch * hw + idx[t]];
                count_sum = ok[t] ? count_sum + av[t] * v : count_sum;
            }
            const float valid = total >= cut ? one : zero;
            const bool kept = valid * a.keep > half;
            const float n_next = (kept ? count_sum / weighed : zero) + one;
            const float al = max_like_numba(one / n_next, a.min_alpha);
            alpha[x] = al;
            new_len[x] = min_like_numba(n_next, a.max_history);
            for (int64_t c = 0; c < n_ch; ++c) {
                const float *plane = ta + c * hw;
                float sum = zero;
                for (int t = 0; t < 4; ++t) sum = ok[t] ? sum + av[t] * plane[idx[t]] : sum;
                const float hist = kept ? sum / weighed : zero;
                const float value = al * a.current[((n * n_ch + c) * h + y) * w + x] + (one - al) * hist;
                a.accumulated[((n * n_ch + c) * h + y) * w + x] = value;
                a.next_ta[((n * (n_ch + 1) + c) * h + y) * w + x] = value;
            }
        }
        for (int64_t c = 0; c < 3; ++c)
            std::copy(nx + c * hw, nx + c * hw + w, a.next_geometry + ((n * 4 + c) * h + y) * w);
        std::copy(d_row, d_row + w, a.next_geometry + ((n * 4 + 3) * h + y) * w);
    }
}

void temporal_accumulation_run(const Tensor *in, Tensor *out, const int64_t *attrs, int threads) {
    TaArgs a{in[0].data, in[1].data, in[2].data, in[3].data, in[4].data, in[5].data,
             1.0f - in[6].data[0], in[7].data[0], in[8].data[0], in[9].data[0], in[10].data[0],
             out[0].data, out[1].data, out[2].data, out[3].data,
             in[0].dims[1], in[0].dims[2], in[0].dims[3]};
    const int64_t work = 4 * (in[4].size() + in[5].size()) + 16 * in[2].size();
    const int hdr = attrs[0] > 1 ? static_cast<int>(attrs[0] - 1) : 0;
    if (attrs[0])  // per_tap
        parallel_for(in[0].dims[0] * a.h, threads, work, [&](int64_t b, int64_t e) {
            temporal_accumulation_per_tap_rows(a, hdr, b, e);
        });
    else
        parallel_for(in[0].dims[0] * a.h, threads, work,
                     [&](int64_t b, int64_t e) { temporal_accumulation_rows(a, b, e); });
}

/* ------------------------------------------------------------------ the table */

const char *const KERNEL_ATTRS[] = {"kernel_size", "dilation"};
constexpr int TA_RANKS[] = {4, 4, 4, 4, 4, 4, 0, 0, 0, 0, 0};
const char *const KA_IN[] = {"image", "kernel"};
const char *const SKA_IN[] = {"image", "logits"};
const char *const KF_IN[] = {"images", "logits"};
const char *const AF_IN[] = {"d_ta", "d_low", "alpha"};
const char *const RP_IN[] = {"previous", "motion"};
const char *const RP_ATTRS[] = {"nearest"};
const int64_t RP_OPTIONAL[] = {0};  // nearest: nodes exported before it are bilinear
const char *const WSF_ATTRS[] = {"size_min", "size_step", "count"};
const char *const WSF_IN[] = {"image", "weights"};
const char *const BG_ATTRS[] = {"cell_size", "grid_depth"};
const char *const BG_IN[] = {"image", "guide"};
const char *const TA_ATTRS[] = {"per_tap"};
const int64_t TA_OPTIONAL[] = {0};  // per_tap: nodes exported before it are bilinear
const char *const TA_IN[] = {"current", "motion", "depth", "normal", "ta_state",
                             "geometry_state", "reset", "depth_tolerance", "normal_threshold",
                             "min_alpha", "max_history"};

const OpDef OPS[] = {
    {"KernelApply", 2, 1, R4, KA_IN, KERNEL_ATTRS, 2, kernel_apply_shapes, kernel_apply_run},
    {"SoftmaxKernelApply", 2, 1, R4, SKA_IN, KERNEL_ATTRS, 2, softmax_kernel_apply_shapes,
     softmax_kernel_apply_run},
    {"KernelFusion", 2, 1, R4, KF_IN, nullptr, 0, kernel_fusion_shapes, kernel_fusion_run},
    {"AdaptiveFusion", 3, 1, R4, AF_IN, nullptr, 0, adaptive_fusion_shapes, adaptive_fusion_run},
    {"Reproject", 2, 1, R4, RP_IN, RP_ATTRS, 1, reproject_shapes, reproject_run, 1, RP_OPTIONAL,
     true},
    {"TemporalAccumulation", 11, 4, TA_RANKS, TA_IN, TA_ATTRS, 1, temporal_accumulation_shapes,
     temporal_accumulation_run, 1, TA_OPTIONAL, true},
    {"WeightSharingFilter", 2, 1, R4, WSF_IN, WSF_ATTRS, 3, weight_sharing_filter_shapes,
     weight_sharing_filter_run},
    {"BilateralGrid", 2, 1, R4, BG_IN, BG_ATTRS, 2, bilateral_grid_shapes, bilateral_grid_run},
};

}  // namespace

const OpDef *op_table(int *count) {
    *count = static_cast<int>(sizeof OPS / sizeof OPS[0]);
    return OPS;
}

}  // namespace rtd

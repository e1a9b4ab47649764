/* rtdenoise_guard.h: the input guard of rtdenoise as C functions of librtdenoise_ops.
 *
 * The same rules as runtime/guard.py (what `Denoiser.process` applies to every buffer of
 * every frame), bit for bit in float32 (tests/test_native_guard.py compares the two):
 *
 *   buffer           range                    NaN      +Inf     -Inf     above the range
 *   color, color_b   [0, 65504]               0        0        0        0
 *   albedo           [0, 1]                   0        0        0        clamped
 *   normal           [-1, 1]                  0        0        0        clamped
 *   depth            [0, 1e10]                0        1e10     0        clamped
 *   motion           [-2 max(H,W), 2 max(H,W)] +bound  +bound   -bound   clamped
 *   anything else    [-65504, 65504]          0        0        0        clamped
 *
 * Values below the range are clamped. Then, for color and color_b, a pixel whose largest
 * channel exceeds 64 x the largest channel among its 8 neighbours (taken as at least 16) is
 * scaled down to that neighbour maximum (two adjacent outliers shield each other). A guide
 * buffer (albedo, normal, depth) that is zero everywhere after the guard is a missing render
 * pass: run that frame with reset = 1 and the next one with reset = 1 too, as `Denoiser` does.
 *
 * A host calls rtdenoise_guard_buffer on each buffer of a frame, unpadded (the motion bound
 * and the outlier neighbourhoods are those of the H x W frame), before padding it to the
 * model's multiple; examples/host_c/host.c does, and docs/contract.md shows the loop.
 *
 * Plain C linkage; no function throws or aborts: a bad argument is a negative return value
 * (RTDENOISE_GUARD_*; rtdenoise_guard_error names it). Thread-safe: no global state.
 * The functions are exported by librtdenoise_ops (.so, .dylib; rtdenoise_ops.dll): link with
 * it, or dlopen it and dlsym the names below, as host.c does.
 */
#ifndef RTDENOISE_GUARD_H
#define RTDENOISE_GUARD_H

#include <stdint.h>

#if defined(_WIN32) && defined(RTDENOISE_GUARD_BUILD) /* guard.cpp, building the library */
#define RTDENOISE_GUARD_API __declspec(dllexport)
#elif defined(_WIN32)
#define RTDENOISE_GUARD_API __declspec(dllimport)
#else
#define RTDENOISE_GUARD_API __attribute__((visibility("default")))
#endif

#ifdef __cplusplus
extern "C" {
#endif

/* Return values. */
#define RTDENOISE_GUARD_OK 0
#define RTDENOISE_GUARD_NULL_ARGUMENT (-1) /* name, input or output is NULL */
#define RTDENOISE_GUARD_BAD_SHAPE (-2)     /* planes, height or width < 1, or too many values */
#define RTDENOISE_GUARD_OVERLAP (-3)       /* output overlaps input without being it */
#define RTDENOISE_GUARD_OUT_OF_MEMORY (-4) /* the H x W scratch mask could not be allocated */
#define RTDENOISE_GUARD_FAILED (-5)        /* anything else (never expected) */

/* What the guard did to one buffer: runtime/guard.py's `Guarded` (its counts are pixels of the
 * H x W frame: a pixel counts once however many of its planes were affected). */
typedef struct rtdenoise_guard_counts {
    int64_t nonfinite; /* pixels with NaN or Inf in any plane, replaced by the rule's values */
    int64_t clamped;   /* pixels with a value outside the range in any plane (after the
                          NaN/Inf replacement), clamped or, colour above it, made 0 */
    int64_t outliers;  /* isolated colour outliers scaled down to their neighbour maximum */
    int32_t zero;      /* 1: every value is 0 after the guard (for a guide: a missing pass) */
    int32_t reserved;  /* 0 */
} rtdenoise_guard_counts;

/* Guard one buffer: `planes` x `height` x `width` float32 values, C order (a planar C x H x W
 * buffer, or 1 x C x H x W: planes = C), read from `input`, written to `output`, which may
 * be `input` itself (in place) but must not overlap it otherwise. `name` picks the rule
 * (the table above; any other name: the last row). `counts` (may be NULL) receives what was
 * done; `nonfinite_mask` (may be NULL; height x width bytes) gets 1 at each pixel that had
 * NaN/Inf in any plane and is left as it is elsewhere, so that one mask collects a whole
 * frame (GuardReport.nonfinite_pixels counts its ones). Costs one pass when nothing needs
 * fixing (plus the copy when output is not input). Returns RTDENOISE_GUARD_OK or an error
 * (then output, counts and mask are left as they were). */
RTDENOISE_GUARD_API int rtdenoise_guard_buffer(const char *name, const float *input, float *output,
                                               int64_t planes, int64_t height, int64_t width,
                                               rtdenoise_guard_counts *counts,
                                               uint8_t *nonfinite_mask);

/* 1 when `name` is a guide buffer (albedo, normal, depth) and all `count` values of `data`
 * are 0 (call it on the guarded buffer, as `Denoiser` does): the frame runs with reset = 1
 * and the next frame starts a new history too. 0 otherwise (any other buffer, a non-zero or
 * NaN value), or RTDENOISE_GUARD_NULL_ARGUMENT / RTDENOISE_GUARD_BAD_SHAPE (count < 1). */
RTDENOISE_GUARD_API int rtdenoise_guard_zero_guide(const char *name, const float *data,
                                                   int64_t count);

/* A short English text for a return value of the functions above (never NULL). */
RTDENOISE_GUARD_API const char *rtdenoise_guard_error(int code);

#ifdef __cplusplus
}
#endif

#endif /* RTDENOISE_GUARD_H */

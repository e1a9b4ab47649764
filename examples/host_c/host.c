/* A C host of an exported rtdenoise model: ONNX Runtime's C API and the native custom-op
 * library rtdenoise_ops, no Python.
 *
 *     mkdir lib && ln -s <site-packages>/onnxruntime/capi/libonnxruntime.so.1.* lib/libonnxruntime.so.1
 *     ln -s libonnxruntime.so.1 lib/libonnxruntime.so
 *     cc -O2 -I<site-packages>/rtdenoise/runtime/bridge/native_ops -o host host.c \
 *         -Llib -lonnxruntime -Wl,-rpath,$PWD/lib -ldl
 *     ./host plan.txt <folder>
 *
 * (the onnxruntime wheel ships libonnxruntime.so.1.<minor>.<patch> without the links of its
 * soname, libonnxruntime.so.1; tests/test_host_c.py builds it that way and runs it).
 *
 * It loads the model, registers the custom ops by calling the library's RegisterCustomOps
 * (what ORT's RegisterCustomOpsLibrary does; dlopen + dlsym here, so this file needs no
 * OrtApi entry beyond the version-1 ones), then runs the frames of the plan in order with
 * the state fed back: `state.<name>` zero and `reset` = 1 on the first frame, then each
 * frame's `state_next.<name>` as the next frame's `state.<name>` and `reset` = 0.
 *
 * Every input buffer of every frame first passes the input guard, the same rules as
 * runtime/guard.py (what `Denoiser.process` applies): the library's rtdenoise_guard_buffer
 * (rtdenoise_guard.h, found by dlsym in the same library) on the H x W frame, before it is
 * padded to the model's multiple by repeating the last row and column. As `Denoiser` does, a
 * frame whose albedo, normal or depth is zero everywhere after the guard
 * (rtdenoise_guard_zero_guide: a missing render pass) runs with zero state and reset = 1, and
 * so does the next frame; so does the frame after one whose output had NaN/Inf (replaced by
 * 0). A frame the guard changed or restarted prints one line:
 *     frame <t>: nonfinite <pixels> clamped <pixels> outliers <pixels> unusable <names|-> reset <0|1>
 * (the counts of `Denoiser.last_guard`: NaN/Inf pixels of any buffer, clamped and outlier
 * pixels summed over the buffers).
 *
 * The plan (a text file, written by tests/test_host_c.py from the model's metadata as
 * docs/contract.md, "Driving a model", says) names the model, the library, the frame count,
 * the frame size H W, each per-frame input (name, shape of the padded tensor; its H x W data
 * in <folder>/f<t>.<name>.f32) and each state (name, shape); the program writes each frame's
 * padded `output` to <folder>/out<t>.f32 (raw float32, C order).
 *
 * ORT's headers are not in the onnxruntime wheel, so the part of the C API used here is
 * declared below as runtime/bridge/native_ops/ort_abi.h declares it: positions in the
 * version-1 OrtApi table, which never change.
 */

#include <dlfcn.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "rtdenoise_guard.h"

typedef void OrtStatus;
typedef void (*ApiFn)(void);
typedef struct {
    const ApiFn *(*GetApi)(uint32_t version);
    const char *(*GetVersionString)(void);
} OrtApiBase;
extern const OrtApiBase *OrtGetApiBase(void);

enum {
    GET_ERROR_MESSAGE = 2, CREATE_ENV = 3, CREATE_SESSION = 7, RUN = 9,
    CREATE_SESSION_OPTIONS = 10, CREATE_TENSOR_WITH_DATA = 49, GET_TENSOR_MUTABLE_DATA = 51,
    CREATE_CPU_MEMORY_INFO = 69, RELEASE_ENV = 92, RELEASE_STATUS = 93,
    RELEASE_MEMORY_INFO = 94, RELEASE_SESSION = 95, RELEASE_VALUE = 96,
    RELEASE_SESSION_OPTIONS = 100,
};
enum { API_VERSION = 20, ELEMENT_FLOAT = 1, LOG_WARNING = 2, DEVICE_ALLOCATOR = 0 };
#define MAX_TENSORS 32
#define MAX_RANK 8
#define NAME_LEN 128

static const ApiFn *api;
#define FN(index, type) ((type)api[index])

/* Exit with ORT's message when `status` is a failure. */
static void check(OrtStatus *status, const char *what) {
    if (!status) return;
    fprintf(stderr, "%s: %s\n", what,
            FN(GET_ERROR_MESSAGE, const char *(*)(const OrtStatus *))(status));
    FN(RELEASE_STATUS, void (*)(OrtStatus *))(status);
    exit(1);
}

typedef struct {
    char name[NAME_LEN];  /* the graph input's name */
    char out[NAME_LEN];   /* state: its state_next output */
    int rank;
    int64_t dims[MAX_RANK];
    size_t count;
    float *data;
} Tensor;

static int read_tensor_line(FILE *plan, Tensor *t) {
    if (fscanf(plan, "%127s %d", t->name, &t->rank) != 2 || t->rank < 0 || t->rank > MAX_RANK)
        return 1;
    t->count = 1;
    for (int d = 0; d < t->rank; ++d) {
        if (fscanf(plan, "%lld", (long long *)&t->dims[d]) != 1 || t->dims[d] < 0) return 1;
        t->count *= (size_t)t->dims[d];
    }
    t->data = calloc(t->count ? t->count : 1, sizeof(float));
    return t->data == NULL;
}

/* The library's guard functions (rtdenoise_guard.h), found by dlsym. */
typedef int (*GuardBufferFn)(const char *, const float *, float *, int64_t, int64_t, int64_t,
                             rtdenoise_guard_counts *, uint8_t *);
typedef int (*ZeroGuideFn)(const char *, const float *, int64_t);
typedef const char *(*GuardErrorFn)(int);

/* Repeat the last row and column: C x H x W `src` -> the C x HP x WP tensor `t`. */
static void pad_edge(const float *src, int64_t h, int64_t w, Tensor *t) {
    const int64_t c = t->dims[1], hp = t->dims[2], wp = t->dims[3];
    for (int64_t k = 0; k < c; ++k)
        for (int64_t y = 0; y < hp; ++y)
            for (int64_t x = 0; x < wp; ++x)
                t->data[(k * hp + y) * wp + x] =
                    src[(k * h + (y < h ? y : h - 1)) * w + (x < w ? x : w - 1)];
}

static void read_file(const char *path, float *data, size_t count) {
    FILE *f = fopen(path, "rb");
    if (!f || fread(data, sizeof(float), count, f) != count) {
        fprintf(stderr, "%s: cannot read %zu floats\n", path, count);
        exit(1);
    }
    fclose(f);
}

int main(int argc, char **argv) {
    if (argc != 3) {
        fprintf(stderr, "usage: %s PLAN FOLDER\n", argv[0]);
        return 2;
    }
    char model[1024], library[1024];
    int frames = 0, n_in = 0, n_state = 0, height = 0, width = 0;
    Tensor in[MAX_TENSORS], state[MAX_TENSORS], output;
    FILE *plan = fopen(argv[1], "r");
    if (!plan ||
        fscanf(plan, "model %1023s library %1023s frames %d size %d %d", model, library, &frames,
               &height, &width) != 5 || height < 1 || width < 1 ||
        fscanf(plan, " inputs %d", &n_in) != 1 || n_in < 1 || n_in > MAX_TENSORS) {
        fprintf(stderr, "%s: not a plan\n", argv[1]);
        return 2;
    }
    size_t stage_count = 0; /* the largest C x H x W buffer, read and guarded before padding */
    for (int i = 0; i < n_in; ++i) {
        if (read_tensor_line(plan, &in[i])) return fprintf(stderr, "bad input line\n"), 2;
        if (strcmp(in[i].name, "reset") == 0) continue;
        if (in[i].rank != 4 || in[i].dims[0] != 1 || in[i].dims[2] < height || in[i].dims[3] < width)
            return fprintf(stderr, "%s: not a 1 x C x HP x WP tensor of the frame\n", in[i].name), 2;
        size_t count = (size_t)in[i].dims[1] * (size_t)height * (size_t)width;
        if (count > stage_count) stage_count = count;
    }
    if (fscanf(plan, " state %d", &n_state) != 1 || n_state < 0 || n_state + 1 > MAX_TENSORS)
        return fprintf(stderr, "bad state count\n"), 2;
    for (int s = 0; s < n_state; ++s) {
        if (read_tensor_line(plan, &state[s])) return fprintf(stderr, "bad state line\n"), 2;
        snprintf(state[s].out, NAME_LEN, "state_next.%s", state[s].name + strlen("state."));
    }
    if (fscanf(plan, " output") != 0 || read_tensor_line(plan, &output) || output.rank != 4 ||
        output.dims[2] < height || output.dims[3] < width)
        return fprintf(stderr, "bad output line\n"), 2;
    fclose(plan);

    const OrtApiBase *base = OrtGetApiBase();
    api = base->GetApi(API_VERSION);
    if (!api) return fprintf(stderr, "this ONNX Runtime lacks API version %d\n", API_VERSION), 1;
    void *env = NULL, *options = NULL, *session = NULL, *memory = NULL;
    check(FN(CREATE_ENV, OrtStatus *(*)(int, const char *, void **))(LOG_WARNING, "host_c", &env),
          "CreateEnv");
    check(FN(CREATE_SESSION_OPTIONS, OrtStatus *(*)(void **))(&options), "CreateSessionOptions");

    /* the custom ops: the library's own registration entry point */
    void *handle = dlopen(library, RTLD_NOW | RTLD_LOCAL);
    if (!handle) return fprintf(stderr, "%s\n", dlerror()), 1;
    OrtStatus *(*register_ops)(void *, const OrtApiBase *) =
        (OrtStatus * (*)(void *, const OrtApiBase *)) dlsym(handle, "RegisterCustomOps");
    if (!register_ops) return fprintf(stderr, "%s: no RegisterCustomOps\n", library), 1;
    check(register_ops(options, base), "RegisterCustomOps");
    GuardBufferFn guard_buffer = (GuardBufferFn)dlsym(handle, "rtdenoise_guard_buffer");
    ZeroGuideFn zero_guide = (ZeroGuideFn)dlsym(handle, "rtdenoise_guard_zero_guide");
    GuardErrorFn guard_error = (GuardErrorFn)dlsym(handle, "rtdenoise_guard_error");
    if (!guard_buffer || !zero_guide || !guard_error)
        return fprintf(stderr, "%s: no rtdenoise_guard_* functions\n", library), 1;
    float *stage = malloc((stage_count ? stage_count : 1) * sizeof(float));
    uint8_t *nonfinite_mask = malloc((size_t)height * (size_t)width);
    if (!stage || !nonfinite_mask) return fprintf(stderr, "out of memory\n"), 1;

    check(FN(CREATE_SESSION, OrtStatus *(*)(void *, const char *, void *, void **))(
              env, model, options, &session), "CreateSession");
    check(FN(CREATE_CPU_MEMORY_INFO, OrtStatus *(*)(int, int, void **))(DEVICE_ALLOCATOR, 0, &memory),
          "CreateCpuMemoryInfo");

    const char *in_names[MAX_TENSORS * 2], *out_names[MAX_TENSORS];
    void *in_values[MAX_TENSORS * 2], *out_values[MAX_TENSORS];
    int restart = 1; /* the next frame starts a new history: the first one, as Denoiser's */
    int64_t no_dims[1] = {0};
    for (int t = 0; t < frames; ++t) {
        int k = 0;
        char path[2048], unusable[256] = "";
        long long nonfinite = 0, clamped = 0, outliers = 0;
        memset(nonfinite_mask, 0, (size_t)height * (size_t)width);
        for (int i = 0; i < n_in; ++i) { /* the input guard, then the padding */
            if (strcmp(in[i].name, "reset") == 0) continue;
            const int64_t planes = in[i].dims[1], count = planes * height * width;
            snprintf(path, sizeof path, "%.1800s/f%d.%.127s.f32", argv[2], t, in[i].name);
            read_file(path, stage, (size_t)count);
            rtdenoise_guard_counts counts;
            int rc = guard_buffer(in[i].name, stage, stage, planes, height, width, &counts,
                                  nonfinite_mask);
            if (rc != RTDENOISE_GUARD_OK)
                return fprintf(stderr, "%s: %s\n", in[i].name, guard_error(rc)), 1;
            clamped += counts.clamped;
            outliers += counts.outliers;
            if (zero_guide(in[i].name, stage, count) == 1) /* a missing render pass */
                snprintf(unusable + strlen(unusable), sizeof unusable - strlen(unusable), "%s%s",
                         unusable[0] ? "," : "", in[i].name);
            pad_edge(stage, height, width, &in[i]);
        }
        for (int64_t p = 0; p < (int64_t)height * width; ++p) nonfinite += nonfinite_mask[p];
        const int reset_now = restart || unusable[0];
        if (reset_now) /* a new history: zero state (the graph ignores it with reset = 1) */
            for (int s = 0; s < n_state; ++s) memset(state[s].data, 0, state[s].count * sizeof(float));
        if (nonfinite || clamped || outliers || unusable[0] || (reset_now && t > 0))
            printf("frame %d: nonfinite %lld clamped %lld outliers %lld unusable %s reset %d\n", t,
                   nonfinite, clamped, outliers, unusable[0] ? unusable : "-", reset_now);
        for (int i = 0; i < n_in; ++i, ++k) {
            if (strcmp(in[i].name, "reset") == 0) in[i].data[0] = reset_now ? 1.0f : 0.0f;
            in_names[k] = in[i].name;
            check(FN(CREATE_TENSOR_WITH_DATA,
                     OrtStatus *(*)(void *, void *, size_t, const int64_t *, size_t, int, void **))(
                      memory, in[i].data, in[i].count * sizeof(float),
                      in[i].rank ? in[i].dims : no_dims, (size_t)in[i].rank, ELEMENT_FLOAT,
                      &in_values[k]), "CreateTensorWithDataAsOrtValue");
        }
        for (int s = 0; s < n_state; ++s, ++k) {
            in_names[k] = state[s].name;
            check(FN(CREATE_TENSOR_WITH_DATA,
                     OrtStatus *(*)(void *, void *, size_t, const int64_t *, size_t, int, void **))(
                      memory, state[s].data, state[s].count * sizeof(float), state[s].dims,
                      (size_t)state[s].rank, ELEMENT_FLOAT, &in_values[k]),
                  "CreateTensorWithDataAsOrtValue");
        }
        out_names[0] = "output";
        for (int s = 0; s < n_state; ++s) out_names[1 + s] = state[s].out;
        for (int o = 0; o <= n_state; ++o) out_values[o] = NULL;  /* ORT allocates them */
        check(FN(RUN, OrtStatus *(*)(void *, const void *, const char *const *, const void *const *,
                                     size_t, const char *const *, size_t, void **))(
                  session, NULL, in_names, (const void *const *)in_values, (size_t)k, out_names,
                  (size_t)n_state + 1, out_values), "Run");
        for (int o = 0; o <= n_state; ++o) {
            float *data = NULL;
            check(FN(GET_TENSOR_MUTABLE_DATA, OrtStatus *(*)(void *, void **))(out_values[o],
                                                                            (void **)&data),
                  "GetTensorMutableData");
            if (o == 0) { /* NaN/Inf in the frame's output: 0, and the next frame restarts */
                const int64_t hp = output.dims[2], wp = output.dims[3];
                restart = unusable[0] != 0;
                for (int64_t c = 0; c < output.dims[1]; ++c)
                    for (int64_t y = 0; y < height; ++y)
                        for (int64_t x = 0; x < width; ++x) {
                            float *v = &data[(c * hp + y) * wp + x];
                            if (!isfinite(*v)) *v = 0.0f, restart = 1;
                        }
                snprintf(path, sizeof path, "%.1800s/out%d.f32", argv[2], t);
                FILE *f = fopen(path, "wb");
                if (!f || fwrite(data, sizeof(float), output.count, f) != output.count)
                    return fprintf(stderr, "%s: cannot write\n", path), 1;
                fclose(f);
            } else { /* the state the next frame reads */
                memcpy(state[o - 1].data, data, state[o - 1].count * sizeof(float));
            }
            FN(RELEASE_VALUE, void (*)(void *))(out_values[o]);
        }
        for (int i = 0; i < k; ++i) FN(RELEASE_VALUE, void (*)(void *))(in_values[i]);
    }
    free(stage);
    free(nonfinite_mask);
    FN(RELEASE_MEMORY_INFO, void (*)(void *))(memory);
    FN(RELEASE_SESSION, void (*)(void *))(session);
    FN(RELEASE_SESSION_OPTIONS, void (*)(void *))(options);
    FN(RELEASE_ENV, void (*)(void *))(env);
    printf("%d frames\n", frames);
    return 0;
}

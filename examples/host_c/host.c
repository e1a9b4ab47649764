/* A C host of an exported rtdenoise model: ONNX Runtime's C API and the native custom-op
 * library rtdenoise_ops, no Python.
 *
 *     mkdir lib && ln -s <site-packages>/onnxruntime/capi/libonnxruntime.so.1.* lib/libonnxruntime.so.1
 *     ln -s libonnxruntime.so.1 lib/libonnxruntime.so
 *     cc -O2 -o host host.c -Llib -lonnxruntime -Wl,-rpath,$PWD/lib -ldl
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
 * The plan (a text file, written by tests/test_host_c.py from the model's metadata as
 * docs/contract.md, "Driving a model", says) names the model, the library, the frame count,
 * each per-frame input (name, shape; its data in <folder>/f<t>.<name>.f32, the frame padded
 * to the model's multiple) and each state (name, shape); the program writes each frame's
 * `output` to <folder>/out<t>.f32 (raw float32, C order).
 *
 * ORT's headers are not in the onnxruntime wheel, so the part of the C API used here is
 * declared below as runtime/bridge/native_ops/ort_abi.h declares it: positions in the
 * version-1 OrtApi table, which never change.
 */

#include <dlfcn.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

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
    int frames = 0, n_in = 0, n_state = 0;
    Tensor in[MAX_TENSORS], state[MAX_TENSORS], output;
    FILE *plan = fopen(argv[1], "r");
    if (!plan || fscanf(plan, "model %1023s library %1023s frames %d", model, library, &frames) != 3 ||
        fscanf(plan, " inputs %d", &n_in) != 1 || n_in < 1 || n_in > MAX_TENSORS) {
        fprintf(stderr, "%s: not a plan\n", argv[1]);
        return 2;
    }
    for (int i = 0; i < n_in; ++i)
        if (read_tensor_line(plan, &in[i])) return fprintf(stderr, "bad input line\n"), 2;
    if (fscanf(plan, " state %d", &n_state) != 1 || n_state < 0 || n_state + 1 > MAX_TENSORS)
        return fprintf(stderr, "bad state count\n"), 2;
    for (int s = 0; s < n_state; ++s) {
        if (read_tensor_line(plan, &state[s])) return fprintf(stderr, "bad state line\n"), 2;
        snprintf(state[s].out, NAME_LEN, "state_next.%s", state[s].name + strlen("state."));
    }
    if (fscanf(plan, " output") != 0 || read_tensor_line(plan, &output))
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

    check(FN(CREATE_SESSION, OrtStatus *(*)(void *, const char *, void *, void **))(
              env, model, options, &session), "CreateSession");
    check(FN(CREATE_CPU_MEMORY_INFO, OrtStatus *(*)(int, int, void **))(DEVICE_ALLOCATOR, 0, &memory),
          "CreateCpuMemoryInfo");

    const char *in_names[MAX_TENSORS * 2], *out_names[MAX_TENSORS];
    void *in_values[MAX_TENSORS * 2], *out_values[MAX_TENSORS];
    float reset = 1.0f;
    int64_t no_dims[1] = {0};
    for (int t = 0; t < frames; ++t) {
        int k = 0;
        char path[2048];
        for (int i = 0; i < n_in; ++i, ++k) {
            if (strcmp(in[i].name, "reset") == 0) { /* not from a file: 1 on the first frame */
                in[i].data[0] = reset;
            } else {
                snprintf(path, sizeof path, "%.1800s/f%d.%.127s.f32", argv[2], t, in[i].name);
                read_file(path, in[i].data, in[i].count);
            }
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
            if (o == 0) {
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
        reset = 0.0f;
    }
    FN(RELEASE_MEMORY_INFO, void (*)(void *))(memory);
    FN(RELEASE_SESSION, void (*)(void *))(session);
    FN(RELEASE_SESSION_OPTIONS, void (*)(void *))(options);
    FN(RELEASE_ENV, void (*)(void *))(env);
    printf("%d frames\n", frames);
    return 0;
}

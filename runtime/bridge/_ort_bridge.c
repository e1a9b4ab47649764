/* Native custom-op bridge: ONNX Runtime calls the rtdenoise fast kernels without copies.
 *
 * ONNX Runtime loads this library with SessionOptions.register_custom_ops_library and calls
 * RegisterCustomOps, which adds one custom op per kernel that Python declared beforehand
 * (rtd_declare_op) to the "rtdenoise" domain. Each op's compute reads ORT's input tensors in
 * place, asks Python for the output shapes (the op spec's rule), lets ORT allocate the outputs
 * and hands Python the raw input and output buffers, on which the numba driver runs as numpy
 * views: no input or output is copied (runtime/bridge/native.py is the Python side).
 *
 * Only the stable part of ONNX Runtime's C ABI is used: OrtApiBase.GetApi, version-1 entries
 * of the OrtApi function table (append-only, so their positions never change) and the
 * OrtCustomOp layout of API version 20 (ONNX Runtime 1.20, the oldest the package supports;
 * the fields only ever grow at the end). The table positions are checked when the library
 * registers (an OrtStatus round trip).
 *
 * Failures never unwind through ONNX Runtime: Python's callbacks catch every exception and
 * record it (runtime/bridge/extensions.py raises it after the run); the outputs are then NaN or, when
 * even their shapes are unknown, empty.
 */

#include <Python.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#ifdef _WIN32
#define EXPORT __declspec(dllexport)
#else
#define EXPORT __attribute__((visibility("default")))
#endif

#define MAX_OPS 32
#define MAX_IO 16
#define MAX_RANK 8
#define MAX_ATTRS 8
#define NAME_LEN 64

typedef void OrtStatusT;
typedef void (*ApiFn)(void); /* an entry of the OrtApi table, cast to its type to call */

/* Positions in the OrtApi function table (version-1 entries). */
enum {
    API_CREATE_STATUS = 0,
    API_GET_ERROR_CODE = 1,
    API_GET_ERROR_MESSAGE = 2,
    API_CREATE_CUSTOM_OP_DOMAIN = 26,
    API_CUSTOM_OP_DOMAIN_ADD = 27,
    API_ADD_CUSTOM_OP_DOMAIN = 28,
    API_GET_TENSOR_MUTABLE_DATA = 51,
    API_GET_TENSOR_ELEMENT_TYPE = 60,
    API_GET_DIMENSIONS_COUNT = 61,
    API_GET_DIMENSIONS = 62,
    API_GET_TENSOR_TYPE_AND_SHAPE = 65,
    API_KERNEL_INFO_GET_ATTRIBUTE_INT64 = 86,
    API_KERNEL_CONTEXT_GET_INPUT_COUNT = 88,
    API_KERNEL_CONTEXT_GET_OUTPUT_COUNT = 89,
    API_KERNEL_CONTEXT_GET_INPUT = 90,
    API_KERNEL_CONTEXT_GET_OUTPUT = 91,
    API_RELEASE_STATUS = 93,
    API_RELEASE_TENSOR_TYPE_AND_SHAPE_INFO = 99,
};

enum { ORT_FAIL_CODE = 1, ELEMENT_FLOAT = 1, CUSTOM_OP_VERSION = 20, API_VERSION = 20 };

typedef struct {
    const void *(*GetApi)(uint32_t version);
    const char *(*GetVersionString)(void);
} ApiBase;

static const ApiFn *api; /* the OrtApi table */
#define FN(index, type) ((type)api[index])

/* The Python side: output shapes (0 = ok), compute (0 = ok), and a failure report. */
typedef int (*ShapeCallback)(int op, int n_in, const int64_t *in_dims, const int64_t *in_rank,
                             const int64_t *attrs, int64_t *out_dims, int64_t *out_rank);
typedef int (*ComputeCallback)(int op, int n_in, void *const *in_data, const int64_t *in_dims,
                               const int64_t *in_rank, int n_out, void *const *out_data,
                               const int64_t *out_dims, const int64_t *out_rank,
                               const int64_t *attrs);
typedef void (*FailCallback)(int op, const char *message);

static ShapeCallback shape_callback;
static ComputeCallback compute_callback;
static FailCallback fail_callback;

/* One custom op: the fields of OrtCustomOp up to its version 20 first, then ours. */
typedef struct Op {
    uint32_t version;
    void *(*CreateKernel)(struct Op *op, const void *api, const void *info);
    const char *(*GetName)(struct Op *op);
    const char *(*GetExecutionProviderType)(struct Op *op);
    int (*GetInputType)(struct Op *op, size_t index);
    size_t (*GetInputTypeCount)(struct Op *op);
    int (*GetOutputType)(struct Op *op, size_t index);
    size_t (*GetOutputTypeCount)(struct Op *op);
    void (*KernelCompute)(void *kernel, void *context);
    void (*KernelDestroy)(void *kernel);
    int (*GetInputCharacteristic)(struct Op *op, size_t index);  /* version 8 */
    int (*GetOutputCharacteristic)(struct Op *op, size_t index);
    int (*GetInputMemoryType)(struct Op *op, size_t index);  /* 11 */
    int (*GetVariadicInputMinArity)(struct Op *op);  /* 14 */
    int (*GetVariadicInputHomogeneity)(struct Op *op);
    int (*GetVariadicOutputMinArity)(struct Op *op);
    int (*GetVariadicOutputHomogeneity)(struct Op *op);
    void *CreateKernelV2;  /* 16; NULL: CreateKernel and KernelCompute are used */
    void *KernelComputeV2;
    void *InferOutputShapeFn;  /* 17; NULL: no shape inference */
    int (*GetStartVersion)(struct Op *op);
    int (*GetEndVersion)(struct Op *op);
    size_t (*GetMayInplace)(int **input_index, int **output_index);  /* 18 */
    void (*ReleaseMayInplace)(int *input_index, int *output_index);
    size_t (*GetAliasMap)(int **input_index, int **output_index);  /* 20 */
    void (*ReleaseAliasMap)(int *input_index, int *output_index);
    void *reserved[16]; /* NULL: room for fields a later ORT adds (it checks them for NULL) */
    int id, n_in, n_out, n_attrs;
    char name[NAME_LEN];
    char attrs[MAX_ATTRS][NAME_LEN];
    int has_default[MAX_ATTRS]; /* an optional attribute: a node may omit it */
    int64_t defaults[MAX_ATTRS];
} Op;

typedef struct {
    Op *op;
    int64_t attrs[MAX_ATTRS];
    int attrs_ok;
} Kernel;

static Op ops[MAX_OPS];
static int n_ops;

static void report(const Op *op, const char *message) {
    if (fail_callback) fail_callback(op->id, message);
}

/* True (and the failure reported) when an ORT call failed. */
static int failed(const Op *op, OrtStatusT *status, const char *what) {
    if (!status) return 0;
    char message[512];
    const char *text = FN(API_GET_ERROR_MESSAGE, const char *(*)(const OrtStatusT *))(status);
    snprintf(message, sizeof message, "%s: %s", what, text ? text : "(no message)");
    FN(API_RELEASE_STATUS, void (*)(OrtStatusT *))(status);
    report(op, message);
    return 1;
}

static void *create_kernel(Op *op, const void *api_, const void *info) {
    (void)api_;
    Kernel *kernel = calloc(1, sizeof(Kernel));
    if (!kernel) return NULL;
    kernel->op = op;
    kernel->attrs_ok = 1;
    for (int a = 0; a < op->n_attrs; ++a) {
        OrtStatusT *status = FN(API_KERNEL_INFO_GET_ATTRIBUTE_INT64,
                                OrtStatusT *(*)(const void *, const char *, int64_t *))(
            info, op->attrs[a], &kernel->attrs[a]);
        if (status) { /* reported at compute: a missing attribute fails every call */
            FN(API_RELEASE_STATUS, void (*)(OrtStatusT *))(status);
            if (op->has_default[a])
                kernel->attrs[a] = op->defaults[a]; /* newer than the node: its default */
            else
                kernel->attrs_ok = 0;
        }
    }
    return kernel;
}

static const char *get_name(Op *op) { return op->name; }
static const char *get_provider(Op *op) { (void)op; return NULL; } /* CPU */
static int element_float(Op *op, size_t index) { (void)op; (void)index; return ELEMENT_FLOAT; }
static size_t input_count(Op *op) { return (size_t)op->n_in; }
static size_t output_count(Op *op) { return (size_t)op->n_out; }
static void destroy_kernel(void *kernel) { free(kernel); }
static int required(Op *op, size_t index) { (void)op; (void)index; return 0; }
static int default_memory(Op *op, size_t index) { (void)op; (void)index; return 0; }
static int one(Op *op) { (void)op; return 1; }
static int last_version(Op *op) { (void)op; return 0x7fffffff; }
static size_t no_pairs(int **input_index, int **output_index) {
    *input_index = NULL;
    *output_index = NULL;
    return 0;
}
static void release_pairs(int *input_index, int *output_index) {
    (void)input_index;
    (void)output_index;
}

/* Outputs that exist but are empty: what a call whose shapes are unknown leaves behind. */
static void empty_outputs(const Op *op, void *context, size_t n_out) {
    int64_t zero = 0;
    void *value;
    for (size_t i = 0; i < n_out; ++i) {
        OrtStatusT *status = FN(API_KERNEL_CONTEXT_GET_OUTPUT,
                                OrtStatusT *(*)(void *, size_t, const int64_t *, size_t, void **))(
            context, i, &zero, 1, &value);
        failed(op, status, "allocating an empty output");
    }
}

/* Shape and data of one tensor; 0 on success. */
static int read_tensor(const Op *op, void *value, int64_t *dims, int64_t *rank, void **data) {
    void *info = NULL;
    size_t count = 0;
    int element = 0;
    if (failed(op, FN(API_GET_TENSOR_TYPE_AND_SHAPE, OrtStatusT *(*)(const void *, void **))(
                       value, &info), "reading a tensor's shape"))
        return 1;
    int bad = failed(op, FN(API_GET_TENSOR_ELEMENT_TYPE, OrtStatusT *(*)(const void *, int *))(
                             info, &element), "reading a tensor's type") ||
              failed(op, FN(API_GET_DIMENSIONS_COUNT, OrtStatusT *(*)(const void *, size_t *))(
                             info, &count), "reading a tensor's rank");
    if (!bad && count > MAX_RANK) {
        report(op, "a tensor has more than 8 dimensions");
        bad = 1;
    }
    if (!bad && element != ELEMENT_FLOAT) {
        report(op, "a tensor is not float32");
        bad = 1;
    }
    if (!bad)
        bad = failed(op, FN(API_GET_DIMENSIONS, OrtStatusT *(*)(const void *, int64_t *, size_t))(
                             info, dims, count), "reading a tensor's dimensions");
    FN(API_RELEASE_TENSOR_TYPE_AND_SHAPE_INFO, void (*)(void *))(info);
    *rank = (int64_t)count;
    if (bad) return 1;
    return failed(op, FN(API_GET_TENSOR_MUTABLE_DATA, OrtStatusT *(*)(void *, void **))(value, data),
                  "reading a tensor's data");
}

static void compute(void *kernel_, void *context) {
    Kernel *kernel = kernel_;
    Op *op = kernel->op;
    size_t n_in = 0, n_out = 0;
    void *in_data[MAX_IO], *out_data[MAX_IO];
    int64_t in_dims[MAX_IO * MAX_RANK], in_rank[MAX_IO];
    int64_t out_dims[MAX_IO * MAX_RANK], out_rank[MAX_IO];

    if (failed(op, FN(API_KERNEL_CONTEXT_GET_INPUT_COUNT, OrtStatusT *(*)(const void *, size_t *))(
                       context, &n_in), "counting inputs") ||
        failed(op, FN(API_KERNEL_CONTEXT_GET_OUTPUT_COUNT, OrtStatusT *(*)(const void *, size_t *))(
                       context, &n_out), "counting outputs"))
        return;
    if (n_out > MAX_IO) {
        report(op, "more than 16 outputs");
        return;
    }
    if (n_in > MAX_IO || (int)n_in != op->n_in || (int)n_out != op->n_out || !kernel->attrs_ok) {
        report(op, !kernel->attrs_ok ? "a declared attribute is missing on the node"
                                     : "unexpected number of inputs or outputs");
        empty_outputs(op, context, n_out);
        return;
    }
    for (size_t i = 0; i < n_in; ++i) {
        void *value = NULL;
        if (failed(op, FN(API_KERNEL_CONTEXT_GET_INPUT, OrtStatusT *(*)(const void *, size_t, void **))(
                           context, i, &value), "reading an input") ||
            read_tensor(op, value, in_dims + i * MAX_RANK, in_rank + i, in_data + i)) {
            empty_outputs(op, context, n_out);
            return;
        }
    }
    if (!shape_callback || !compute_callback ||
        shape_callback(op->id, (int)n_in, in_dims, in_rank, kernel->attrs, out_dims, out_rank)) {
        empty_outputs(op, context, n_out);
        return;
    }
    for (size_t i = 0; i < n_out; ++i) {
        void *value = NULL;
        if (out_rank[i] < 0 || out_rank[i] > MAX_RANK) {
            report(op, "an output shape has an invalid rank");
            return;
        }
        if (failed(op, FN(API_KERNEL_CONTEXT_GET_OUTPUT,
                          OrtStatusT *(*)(void *, size_t, const int64_t *, size_t, void **))(
                           context, i, out_dims + i * MAX_RANK, (size_t)out_rank[i], &value),
                   "allocating an output") ||
            failed(op, FN(API_GET_TENSOR_MUTABLE_DATA, OrtStatusT *(*)(void *, void **))(
                           value, out_data + i), "reading an output's buffer"))
            return;
    }
    compute_callback(op->id, (int)n_in, in_data, in_dims, in_rank, (int)n_out, out_data, out_dims,
                     out_rank, kernel->attrs);
}

/* ---- what Python calls (ctypes) ---- */

/* Declare op `name` (id = its index) with n_in float inputs, n_out float outputs and the int
 * attributes named in `attrs` (comma-separated; `name=value` for an optional one, which a node
 * may omit). Returns the id, or -1 if it does not fit. */
EXPORT int rtd_declare_op(const char *name, int n_in, int n_out, const char *attrs) {
    if (n_ops >= MAX_OPS || n_in < 1 || n_in > MAX_IO || n_out < 1 || n_out > MAX_IO ||
        strlen(name) >= NAME_LEN)
        return -1;
    Op *op = &ops[n_ops];
    memset(op, 0, sizeof *op);
    op->version = CUSTOM_OP_VERSION;
    op->CreateKernel = create_kernel;
    op->GetName = get_name;
    op->GetExecutionProviderType = get_provider;
    op->GetInputType = element_float;
    op->GetInputTypeCount = input_count;
    op->GetOutputType = element_float;
    op->GetOutputTypeCount = output_count;
    op->KernelCompute = compute;
    op->KernelDestroy = destroy_kernel;
    op->GetInputCharacteristic = required;
    op->GetOutputCharacteristic = required;
    op->GetInputMemoryType = default_memory;
    op->GetVariadicInputMinArity = one;
    op->GetVariadicInputHomogeneity = one;
    op->GetVariadicOutputMinArity = one;
    op->GetVariadicOutputHomogeneity = one;
    op->GetStartVersion = one;
    op->GetEndVersion = last_version;
    op->GetMayInplace = no_pairs;
    op->ReleaseMayInplace = release_pairs;
    op->GetAliasMap = no_pairs;
    op->ReleaseAliasMap = release_pairs;
    op->id = n_ops;
    op->n_in = n_in;
    op->n_out = n_out;
    strcpy(op->name, name);
    const char *p = attrs;
    while (p && *p) {
        const char *end = strchr(p, ',');
        size_t len = end ? (size_t)(end - p) : strlen(p);
        const char *eq = memchr(p, '=', len);
        size_t name_len = eq ? (size_t)(eq - p) : len;
        if (op->n_attrs >= MAX_ATTRS || name_len == 0 || name_len >= NAME_LEN) return -1;
        memcpy(op->attrs[op->n_attrs], p, name_len);
        op->attrs[op->n_attrs][name_len] = '\0';
        if (eq) {
            op->has_default[op->n_attrs] = 1;
            op->defaults[op->n_attrs] = strtoll(eq + 1, NULL, 10);
        }
        op->n_attrs++;
        p = end ? end + 1 : NULL;
    }
    return n_ops++;
}

EXPORT void rtd_set_callbacks(ShapeCallback shape, ComputeCallback compute_, FailCallback fail) {
    shape_callback = shape;
    compute_callback = compute_;
    fail_callback = fail;
}

EXPORT int rtd_op_count(void) { return n_ops; }

/* ---- what ONNX Runtime calls ---- */

static OrtStatusT *error_status(const char *message) {
    return FN(API_CREATE_STATUS, OrtStatusT *(*)(int, const char *))(ORT_FAIL_CODE, message);
}

/* The OrtApi positions this file uses are right if a status round-trips through them. */
static int api_positions_ok(void) {
    OrtStatusT *status = error_status("rtdenoise probe");
    if (!status) return 0;
    int ok = FN(API_GET_ERROR_CODE, int (*)(const OrtStatusT *))(status) == ORT_FAIL_CODE &&
             strcmp(FN(API_GET_ERROR_MESSAGE, const char *(*)(const OrtStatusT *))(status),
                    "rtdenoise probe") == 0;
    FN(API_RELEASE_STATUS, void (*)(OrtStatusT *))(status);
    return ok;
}

EXPORT OrtStatusT *RegisterCustomOps(void *options, const ApiBase *base) {
    api = (const ApiFn *)base->GetApi(API_VERSION);
    if (!api) return NULL; /* cannot even say why: ORT then fails on the unknown ops */
    if (!api_positions_ok()) return error_status("rtdenoise bridge: unexpected OrtApi layout");
    if (n_ops == 0) return error_status("rtdenoise bridge: no op declared (runtime/bridge/native.py)");
    void *domain = NULL; /* one per registration, kept for the process (sessions may outlive it) */
    OrtStatusT *status = FN(API_CREATE_CUSTOM_OP_DOMAIN, OrtStatusT *(*)(const char *, void **))(
        "rtdenoise", &domain);
    if (status) return status;
    for (int i = 0; i < n_ops; ++i) {
        status = FN(API_CUSTOM_OP_DOMAIN_ADD, OrtStatusT *(*)(void *, void *))(domain, &ops[i]);
        if (status) return status;
    }
    return FN(API_ADD_CUSTOM_OP_DOMAIN, OrtStatusT *(*)(void *, void *))(options, domain);
}

/* Built as an extension module so that pip compiles it; it is loaded with ctypes, not
 * imported. */
PyMODINIT_FUNC PyInit__ort_bridge(void) {
    PyErr_SetString(PyExc_ImportError,
                    "rtdenoise.runtime.bridge._ort_bridge is loaded by ONNX Runtime, not imported");
    return NULL;
}

/* rtdenoise_ops: the rtdenoise custom ops as an ONNX Runtime custom-op library, no Python
 * inside. Any ORT host loads it (SessionOptions.register_custom_ops_library in Python,
 * RegisterCustomOpsLibrary / RegisterCustomOps in C and C++), and every op of domain
 * `rtdenoise` that it holds (the tables of kernels.cpp, affinity.cpp and crossreg.cpp) then
 * runs its forward kernel here on ORT's own buffers, in place of the model-local function
 * body.
 *
 * Every failure is an OrtStatus naming the op and the cause (the spec's check, a missing
 * attribute, a wrong element type, memory): nothing aborts and no exception crosses ORT's C
 * boundary (CreateKernelV2 / KernelComputeV2 of the OrtCustomOp layout, version 16 and up).
 *
 * Threads: each op splits its rows over `rtdenoise_ops_set_threads` threads of the calling
 * thread (ORT runs a custom op on the thread that called Run), default the environment
 * variable RTDENOISE_OPS_THREADS, else every core; runtime/bridge/native_cpp.py sets it
 * around each run as the numba path sets numba's count.
 */

#include <algorithm>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <initializer_list>
#include <new>
#include <string>
#include <thread>

#include "kernels.h"
#include "ort_abi.h"

#ifdef _WIN32
#define RTD_EXPORT extern "C" __declspec(dllexport)
#else
#define RTD_EXPORT extern "C" __attribute__((visibility("default")))
#endif

namespace {

using ort::Status;

const ort::ApiFn *api = nullptr;  // the OrtApi table
template <class F>
F fn(int index) {
    return reinterpret_cast<F>(api[index]);
}

thread_local int threads_of_this_thread = 0;  // 0: the default

int default_threads() {
    static const int value = [] {
        const char *env = std::getenv("RTDENOISE_OPS_THREADS");
        int n = env ? std::atoi(env) : 0;
        if (n < 1) n = static_cast<int>(std::thread::hardware_concurrency());
        return std::max(1, n);
    }();
    return value;
}

Status *make_status(int code, const std::string &message) {
    return fn<Status *(*)(int, const char *)>(ort::CREATE_STATUS)(code, message.c_str());
}

Status *op_error(const rtd::OpDef *def, const std::string &cause, int code = ort::INVALID_ARGUMENT) {
    // the spec's messages already start with the op's name (as the Python checks do)
    bool named = cause.compare(0, std::strlen(def->name), def->name) == 0;
    return make_status(code, "rtdenoise_ops: " + (named ? cause : std::string(def->name) + ": " + cause));
}

/* The cause held by an ORT status, the status released. */
std::string take_message(Status *status) {
    const char *text = fn<const char *(*)(const Status *)>(ort::GET_ERROR_MESSAGE)(status);
    std::string message = text ? text : "(no message)";
    fn<void (*)(Status *)>(ort::RELEASE_STATUS)(status);
    return message;
}

struct Op {
    ort::CustomOp base;  // first: ORT's pointer to it is a pointer to this
    const rtd::OpDef *def;
};

struct Kernel {
    const rtd::OpDef *def;
    int64_t attrs[rtd::MAX_ATTRS];
};

const rtd::OpDef *def_of(const ort::CustomOp *op) { return reinterpret_cast<const Op *>(op)->def; }

Status *create_kernel(const ort::CustomOp *op, const void *, const void *info, void **out) {
    const rtd::OpDef *def = def_of(op);
    *out = nullptr;
    Kernel *kernel = new (std::nothrow) Kernel{def, {}};
    if (!kernel) return op_error(def, "out of memory creating the kernel", ort::FAIL);
    for (int a = 0; a < def->n_attrs; ++a) {
        Status *status = fn<Status *(*)(const void *, const char *, int64_t *)>(
            ort::KERNEL_INFO_GET_ATTRIBUTE_INT64)(info, def->attrs[a], &kernel->attrs[a]);
        const int first_optional = def->n_attrs - def->n_optional;
        if (status && a >= first_optional) {  // an attribute newer than the node: its default
            take_message(status);
            kernel->attrs[a] = def->optional_defaults[a - first_optional];
        } else if (status) {
            std::string why = take_message(status);
            delete kernel;
            return op_error(def, std::string("the node has no int attribute '") + def->attrs[a] +
                                     "' (" + why + ")");
        }
    }
    *out = kernel;
    return nullptr;
}

void destroy_kernel(void *kernel) { delete static_cast<Kernel *>(kernel); }

/* Shape and data of one tensor; an error message, or "" when read. */
std::string read_tensor(void *value, rtd::Tensor &t) {
    void *info = nullptr;
    if (Status *s = fn<Status *(*)(const void *, void **)>(ort::GET_TENSOR_TYPE_AND_SHAPE)(value, &info))
        return "reading a tensor's shape: " + take_message(s);
    int element = 0;
    size_t count = 0;
    std::string error;
    if (Status *s = fn<Status *(*)(const void *, int *)>(ort::GET_TENSOR_ELEMENT_TYPE)(info, &element))
        error = "reading a tensor's type: " + take_message(s);
    else if (Status *s2 = fn<Status *(*)(const void *, size_t *)>(ort::GET_DIMENSIONS_COUNT)(info, &count))
        error = "reading a tensor's rank: " + take_message(s2);
    else if (element != ort::ELEMENT_FLOAT)
        error = "is not float32 (ONNX element type " + std::to_string(element) + ")";
    else if (count > static_cast<size_t>(rtd::MAX_RANK))
        error = "has more than 8 dimensions";
    else if (Status *s3 = fn<Status *(*)(const void *, int64_t *, size_t)>(ort::GET_DIMENSIONS)(
                 info, t.dims, count))
        error = "reading a tensor's dimensions: " + take_message(s3);
    fn<void (*)(void *)>(ort::RELEASE_TENSOR_TYPE_AND_SHAPE_INFO)(info);
    if (!error.empty()) return error;
    t.rank = static_cast<int>(count);
    void *data = nullptr;
    if (Status *s = fn<Status *(*)(void *, void **)>(ort::GET_TENSOR_MUTABLE_DATA)(value, &data))
        return "reading a tensor's data: " + take_message(s);
    t.data = static_cast<float *>(data);
    return "";
}

std::string shape_text(const rtd::Tensor &t) {
    std::string s = "(";
    for (int d = 0; d < t.rank; ++d) s += (d ? ", " : "") + std::to_string(t.dims[d]);
    return s + (t.rank == 1 ? ",)" : ")");
}

Status *compute(void *kernel_, void *context) {
    const Kernel *kernel = static_cast<const Kernel *>(kernel_);
    const rtd::OpDef *def = kernel->def;
    try {
        size_t n_in = 0, n_out = 0;
        if (Status *s = fn<Status *(*)(const void *, size_t *)>(ort::KERNEL_CONTEXT_GET_INPUT_COUNT)(context, &n_in))
            return op_error(def, "counting inputs: " + take_message(s), ort::FAIL);
        if (Status *s = fn<Status *(*)(const void *, size_t *)>(ort::KERNEL_CONTEXT_GET_OUTPUT_COUNT)(context, &n_out))
            return op_error(def, "counting outputs: " + take_message(s), ort::FAIL);
        if (static_cast<int>(n_in) != def->n_in || static_cast<int>(n_out) != def->n_out)
            return op_error(def, "takes " + std::to_string(def->n_in) + " inputs and " +
                                     std::to_string(def->n_out) + " outputs, got " +
                                     std::to_string(n_in) + " and " + std::to_string(n_out));
        rtd::Tensor in[rtd::MAX_IO], out[rtd::MAX_IO];
        rtd::Shape shapes[rtd::MAX_IO];
        bool empty = false;
        for (size_t i = 0; i < n_in; ++i) {
            void *value = nullptr;
            if (Status *s = fn<Status *(*)(const void *, size_t, void **)>(ort::KERNEL_CONTEXT_GET_INPUT)(context, i, &value))
                return op_error(def, "reading input " + std::string(def->in_names[i]) + ": " + take_message(s), ort::FAIL);
            if (!value) return op_error(def, std::string(def->in_names[i]) + " is missing");
            std::string error = read_tensor(value, in[i]);
            if (!error.empty()) return op_error(def, std::string(def->in_names[i]) + " " + error);
            if (in[i].rank != def->in_ranks[i])
                return op_error(def, std::string(def->in_names[i]) + " must be " +
                                         std::to_string(def->in_ranks[i]) + "-D, got shape " +
                                         shape_text(in[i]));
            empty = empty || in[i].size() == 0;
        }
        std::string error = def->shapes(in, kernel->attrs, shapes);
        if (!error.empty()) return op_error(def, error);
        for (size_t o = 0; o < n_out; ++o) {
            void *value = nullptr;
            if (Status *s = fn<Status *(*)(void *, size_t, const int64_t *, size_t, void **)>(
                    ort::KERNEL_CONTEXT_GET_OUTPUT)(context, o, shapes[o].dims,
                                                    static_cast<size_t>(shapes[o].rank), &value))
                return op_error(def, "allocating output " + std::to_string(o) + ": " + take_message(s), ort::FAIL);
            void *data = nullptr;
            if (Status *s = fn<Status *(*)(void *, void **)>(ort::GET_TENSOR_MUTABLE_DATA)(value, &data))
                return op_error(def, "reading output " + std::to_string(o) + ": " + take_message(s), ort::FAIL);
            out[o].data = static_cast<float *>(data);
            out[o].rank = shapes[o].rank;
            std::copy(shapes[o].dims, shapes[o].dims + rtd::MAX_RANK, out[o].dims);
            empty = empty || out[o].size() == 0;
        }
        if (empty) {  // an empty input or output: nothing to compute (as FastKernel.compute)
            for (size_t o = 0; o < n_out; ++o) std::fill(out[o].data, out[o].data + out[o].size(), 0.0f);
            return nullptr;
        }
        int threads = threads_of_this_thread > 0 ? threads_of_this_thread : default_threads();
        const rtd::FpMode mode(def->to_the_bit ? rtd::FpMode::current() : rtd::FpMode::flushed());
        def->run(in, out, kernel->attrs, threads);
        return nullptr;
    } catch (const std::bad_alloc &) {
        return op_error(def, "out of memory", ort::FAIL);
    } catch (const std::exception &exc) {
        return op_error(def, exc.what(), ort::FAIL);
    } catch (...) {
        return op_error(def, "unknown failure", ort::FAIL);
    }
}

const char *get_name(const ort::CustomOp *op) { return def_of(op)->name; }
const char *get_provider(const ort::CustomOp *) { return nullptr; }  // CPU
int element_float(const ort::CustomOp *, size_t) { return ort::ELEMENT_FLOAT; }
size_t input_count(const ort::CustomOp *op) { return static_cast<size_t>(def_of(op)->n_in); }
size_t output_count(const ort::CustomOp *op) { return static_cast<size_t>(def_of(op)->n_out); }
int required(const ort::CustomOp *, size_t) { return 0; }
int default_memory(const ort::CustomOp *, size_t) { return 0; }
int one(const ort::CustomOp *) { return 1; }
int last_version(const ort::CustomOp *) { return 0x7fffffff; }
size_t no_pairs(int **input_index, int **output_index) {
    *input_index = nullptr;
    *output_index = nullptr;
    return 0;
}
void release_pairs(int *, int *) {}
void *unused_create(const ort::CustomOp *, const void *, const void *) { return nullptr; }
void unused_compute(void *, void *) {}

Op ops[rtd::MAX_IO * 2];
int n_ops = 0;
std::string names;

void build_ops() {
    if (n_ops) return;
    const int capacity = static_cast<int>(sizeof ops / sizeof ops[0]);
    for (auto table : {rtd::op_table, rtd::affinity_op_table, rtd::crossreg_op_table,
                       rtd::crossreg_step_op_table, rtd::conv_grad_op_table}) {
        int count = 0;
        const rtd::OpDef *defs = table(&count);
        for (int t = 0; t < count && n_ops < capacity; ++t) {
            const int i = n_ops;
            Op &op = ops[i];
            std::memset(&op, 0, sizeof op);
            ort::CustomOp &c = op.base;
            c.version = ort::CUSTOM_OP_VERSION;
            c.CreateKernel = unused_create;  // ORT uses the V2 forms, which return a status
            c.GetName = get_name;
            c.GetExecutionProviderType = get_provider;
            c.GetInputType = element_float;
            c.GetInputTypeCount = input_count;
            c.GetOutputType = element_float;
            c.GetOutputTypeCount = output_count;
            c.KernelCompute = unused_compute;
            c.KernelDestroy = destroy_kernel;
            c.GetInputCharacteristic = required;
            c.GetOutputCharacteristic = required;
            c.GetInputMemoryType = default_memory;
            c.GetVariadicInputMinArity = one;
            c.GetVariadicInputHomogeneity = one;
            c.GetVariadicOutputMinArity = one;
            c.GetVariadicOutputHomogeneity = one;
            c.CreateKernelV2 = create_kernel;
            c.KernelComputeV2 = compute;
            c.GetStartVersion = one;
            c.GetEndVersion = last_version;
            c.GetMayInplace = no_pairs;
            c.ReleaseMayInplace = release_pairs;
            c.GetAliasMap = no_pairs;
            c.ReleaseAliasMap = release_pairs;
            op.def = &defs[t];
            names += (i ? "," : "") + std::string(defs[t].name);
            n_ops = i + 1;
        }
    }
}

/* The OrtApi positions used here are right if a status round-trips through them. */
bool api_positions_ok() {
    Status *status = make_status(ort::FAIL, "rtdenoise probe");
    if (!status) return false;
    bool ok = fn<int (*)(const Status *)>(ort::GET_ERROR_CODE)(status) == ort::FAIL &&
              std::strcmp(fn<const char *(*)(const Status *)>(ort::GET_ERROR_MESSAGE)(status),
                          "rtdenoise probe") == 0;
    fn<void (*)(Status *)>(ort::RELEASE_STATUS)(status);
    return ok;
}

}  // namespace

/* ---- what ONNX Runtime calls ---- */

RTD_EXPORT Status *RegisterCustomOps(void *options, const ort::ApiBase *base) {
    try {
        api = static_cast<const ort::ApiFn *>(base->GetApi(ort::API_VERSION));
        if (!api) return nullptr;  // cannot even say why: ORT then fails on the unknown ops
        if (!api_positions_ok()) return make_status(ort::FAIL, "rtdenoise_ops: unexpected OrtApi layout");
        build_ops();
        void *domain = nullptr;  // one per registration, kept for the process
        if (Status *s = fn<Status *(*)(const char *, void **)>(ort::CREATE_CUSTOM_OP_DOMAIN)("rtdenoise", &domain))
            return s;
        for (int i = 0; i < n_ops; ++i)
            if (Status *s = fn<Status *(*)(void *, void *)>(ort::CUSTOM_OP_DOMAIN_ADD)(domain, &ops[i].base))
                return s;
        return fn<Status *(*)(void *, void *)>(ort::ADD_CUSTOM_OP_DOMAIN)(options, domain);
    } catch (...) {
        return api ? make_status(ort::FAIL, "rtdenoise_ops: registration failed") : nullptr;
    }
}

/* ---- what a host may call (Python through ctypes) ---- */

/* The ops this library holds, comma-separated ("KernelApply,SoftmaxKernelApply,..."). */
RTD_EXPORT const char *rtdenoise_ops_names(void) {
    try {
        build_ops();
    } catch (...) {
        return "";
    }
    return names.c_str();
}

/* Threads of the ops run by the calling thread (ORT runs them on the thread that calls Run);
 * 0: the default (RTDENOISE_OPS_THREADS, else every core). Returns the previous setting. */
RTD_EXPORT int rtdenoise_ops_set_threads(int threads) {
    int before = threads_of_this_thread;
    threads_of_this_thread = threads > 0 ? threads : 0;
    return before;
}

/* 1: this library's ABI (the functions above); a later change of them bumps it. */
RTD_EXPORT int rtdenoise_ops_abi(void) { return 1; }

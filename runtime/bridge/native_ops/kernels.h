/* The ops of rtdenoise_ops: each op's spec (inputs, outputs, int attributes, the shape rule
 * and checks of rtdenoise/ops/<op>.py) and its forward kernel (the arithmetic of
 * runtime/kernels/<op>.py, loop for loop). No ONNX Runtime and no Python here: library.cpp
 * is the ORT glue. */
#pragma once

#include <cstdint>
#include <string>

namespace rtd {

constexpr int MAX_RANK = 8;
constexpr int MAX_IO = 16;
constexpr int MAX_ATTRS = 8;

struct Tensor {
    float *data = nullptr;  // ORT's buffer (inputs are only read)
    int rank = 0;
    int64_t dims[MAX_RANK] = {};
    int64_t size() const {
        int64_t s = 1;
        for (int d = 0; d < rank; ++d) s *= dims[d];
        return s;
    }
    int64_t dim(int d) const { return dims[d]; }
};

struct Shape {
    int rank = 0;
    int64_t dims[MAX_RANK] = {};
};

/* Output shapes of a call, or an error ("" = ok) that names the cause as the Python spec's
 * check does (the op's name is added by the caller). */
using ShapeFn = std::string (*)(const Tensor *in, const int64_t *attrs, Shape *out);
/* Fill the outputs (shapes as ShapeFn gave, every size > 0) from the inputs with `threads`
 * threads. */
using RunFn = void (*)(const Tensor *in, Tensor *out, const int64_t *attrs, int threads);

struct OpDef {
    const char *name;
    int n_in;
    int n_out;
    const int *in_ranks;   // n_in entries
    const char *const *in_names;  // n_in entries, as in the spec
    const char *const *attrs;  // n_attrs names
    int n_attrs;
    ShapeFn shapes;
    RunFn run;
    /* The last n_optional attributes may be omitted on a node (added after models were
     * shipped without them: the spec's optional_attrs); an omitted one takes
     * optional_defaults[i - (n_attrs - n_optional)]. */
    int n_optional = 0;
    const int64_t *optional_defaults = nullptr;
    /* Kept to the bit with the torch form (float32 step by step, no fastmath on the numba
     * side): runs with the caller's floating-point mode. Every other op runs with denormals
     * flushed to zero (FpMode::flushed). */
    bool to_the_bit = false;
};

/* The calling thread's SSE floating-point mode set to `mode` for the scope, and restored when
 * it ends (x86-64; elsewhere nothing). `flushed()` is the thread's mode with flush-to-zero and
 * denormals-are-zero set: an exponential weight below 2^-126 times a value gives a denormal,
 * and on Intel cores each denormal operand or result costs a microcode assist (measured: a
 * multiply-add loop 57x slower, CrossBilateralFilter at 320x240 372 -> 22 ms); flushed, a
 * result moves by less than 1.2e-38. The host's own mode is never left changed. */
class FpMode {
  public:
    explicit FpMode(unsigned mode);
    ~FpMode();
    FpMode(const FpMode &) = delete;
    FpMode &operator=(const FpMode &) = delete;
    static unsigned current();  // the calling thread's mode
    static unsigned flushed();  // current() with denormals flushed

  private:
    unsigned saved_ = 0;
};

const OpDef *op_table(int *count);           // kernels.cpp (and filters.cpp): afn, wskp, nbg
const OpDef *affinity_op_table(int *count);  // affinity.cpp: demo:affinity's ops
const OpDef *crossreg_op_table(int *count);  // crossreg.cpp: demo:crossreg's ops
const OpDef *crossreg_step_op_table(int *count);  // crossreg_step.cpp: crossreg's history warp
const OpDef *conv_grad_op_table(int *count);  // conv_grad.cpp: conv weight gradients (online backward)

/* Split [0, rows) into contiguous chunks run by up to `threads` threads (the caller's one of
 * them), at most one per GRAIN of `work` (about the multiply-adds of the call: a thread
 * started for less costs more than it saves); fn(begin, end). Falls back to fewer threads
 * if threads cannot be started; an exception of fn is rethrown on the caller's thread. Every
 * chunk runs in the caller's floating-point mode (FpMode). */
constexpr int64_t GRAIN = int64_t(1) << 16;
void parallel_rows(int64_t rows, int threads, int64_t work, void (*fn)(void *, int64_t, int64_t),
                   void *ctx);

template <class F>
void parallel_for(int64_t rows, int threads, int64_t work, F &&f) {
    parallel_rows(
        rows, threads, work,
        [](void *ctx, int64_t b, int64_t e) { (*static_cast<F *>(ctx))(b, e); },
        static_cast<void *>(&f));
}

}  // namespace rtd

/* The part of ONNX Runtime's C ABI that rtdenoise_ops uses, declared without ORT's headers
 * (the onnxruntime wheel ships none), as runtime/bridge/_ort_bridge.c does: version-1 entries
 * of the OrtApi function table (append-only, so their positions never change; checked by a
 * status round trip when the library registers) and the OrtCustomOp layout of API version 20
 * (ONNX Runtime 1.20, the oldest the package supports; later versions only add fields at the
 * end, which ORT reads only when the op's version says they exist).
 */
#pragma once

#include <cstddef>
#include <cstdint>

namespace ort {

using Status = void;                 // OrtStatus
using ApiFn = void (*)(void);        // an entry of the OrtApi table, cast to its type to call

enum ApiIndex : int {
    CREATE_STATUS = 0,
    GET_ERROR_CODE = 1,
    GET_ERROR_MESSAGE = 2,
    CREATE_CUSTOM_OP_DOMAIN = 26,
    CUSTOM_OP_DOMAIN_ADD = 27,
    ADD_CUSTOM_OP_DOMAIN = 28,
    GET_TENSOR_MUTABLE_DATA = 51,
    GET_TENSOR_ELEMENT_TYPE = 60,
    GET_DIMENSIONS_COUNT = 61,
    GET_DIMENSIONS = 62,
    GET_TENSOR_TYPE_AND_SHAPE = 65,
    KERNEL_INFO_GET_ATTRIBUTE_INT64 = 86,
    KERNEL_CONTEXT_GET_INPUT_COUNT = 88,
    KERNEL_CONTEXT_GET_OUTPUT_COUNT = 89,
    KERNEL_CONTEXT_GET_INPUT = 90,
    KERNEL_CONTEXT_GET_OUTPUT = 91,
    RELEASE_STATUS = 93,
    RELEASE_TENSOR_TYPE_AND_SHAPE_INFO = 99,
};

enum : int { FAIL = 1, INVALID_ARGUMENT = 2, ELEMENT_FLOAT = 1 };
enum : uint32_t { CUSTOM_OP_VERSION = 20, API_VERSION = 20 };

struct ApiBase {
    const void *(*GetApi)(uint32_t version);
    const char *(*GetVersionString)(void);
};

struct CustomOp;  // the fields of OrtCustomOp up to its version 20, then room
struct CustomOp {
    uint32_t version;
    void *(*CreateKernel)(const CustomOp *op, const void *api, const void *info);
    const char *(*GetName)(const CustomOp *op);
    const char *(*GetExecutionProviderType)(const CustomOp *op);
    int (*GetInputType)(const CustomOp *op, size_t index);
    size_t (*GetInputTypeCount)(const CustomOp *op);
    int (*GetOutputType)(const CustomOp *op, size_t index);
    size_t (*GetOutputTypeCount)(const CustomOp *op);
    void (*KernelCompute)(void *kernel, void *context);
    void (*KernelDestroy)(void *kernel);
    int (*GetInputCharacteristic)(const CustomOp *op, size_t index);  // version 8
    int (*GetOutputCharacteristic)(const CustomOp *op, size_t index);
    int (*GetInputMemoryType)(const CustomOp *op, size_t index);  // 11
    int (*GetVariadicInputMinArity)(const CustomOp *op);  // 14
    int (*GetVariadicInputHomogeneity)(const CustomOp *op);
    int (*GetVariadicOutputMinArity)(const CustomOp *op);
    int (*GetVariadicOutputHomogeneity)(const CustomOp *op);
    // 16: the status-returning forms, used by ORT when set
    Status *(*CreateKernelV2)(const CustomOp *op, const void *api, const void *info, void **kernel);
    Status *(*KernelComputeV2)(void *kernel, void *context);
    void *InferOutputShapeFn;  // 17; NULL: no shape inference
    int (*GetStartVersion)(const CustomOp *op);
    int (*GetEndVersion)(const CustomOp *op);
    size_t (*GetMayInplace)(int **input_index, int **output_index);  // 18
    void (*ReleaseMayInplace)(int *input_index, int *output_index);
    size_t (*GetAliasMap)(int **input_index, int **output_index);  // 20
    void (*ReleaseAliasMap)(int *input_index, int *output_index);
    void *reserved[16];  // NULL: room for fields a later ORT adds
};

}  // namespace ort

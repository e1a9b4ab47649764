/* A C host of an exported rtdenoise model: ONNX Runtime's C API and the native custom-op
 * library rtdenoise_ops, no Python. It knows nothing of the model beforehand: what it feeds
 * and reads back comes from the model file itself.
 *
 *     mkdir lib && ln -s <site-packages>/onnxruntime/capi/libonnxruntime.so.1.* lib/libonnxruntime.so.1
 *     ln -s libonnxruntime.so.1 lib/libonnxruntime.so
 *     cc -O2 -Wall -Wextra -I<site-packages>/rtdenoise/runtime/bridge/native_ops -o host host.c \
 *         -Llib -lonnxruntime -Wl,-rpath,$PWD/lib -ldl
 *     ./host MODEL.onnx LIBRARY FOLDER FRAMES H W
 *
 * (the onnxruntime wheel ships libonnxruntime.so.1.<minor>.<patch> without the links of its
 * soname, libonnxruntime.so.1; tests/test_host_c.py builds it that way and runs it).
 *
 * MODEL is an exported model (`denoise-export`), LIBRARY the custom-op library
 * (<site-packages>/rtdenoise/runtime/bridge/librtdenoise_ops.so), FRAMES the number of frames
 * and H W their size. Frame t's buffer <name> is <FOLDER>/f<t>.<name>.f32: the H x W frame,
 * raw float32 C x H x W (C order); the program writes each frame's `output`, cropped to the
 * frame (C x H x W), to <FOLDER>/out<t>.f32.
 *
 * It loads the model, registers the custom ops by calling the library's RegisterCustomOps
 * (what ORT's RegisterCustomOpsLibrary does; dlopen + dlsym here), then reads what
 * docs/contract.md ("Driving a model") says a host reads, from the model's custom metadata
 * (SessionGetModelMetadata, ModelMetadataLookupCustomMetadataMap) and the session's inputs and
 * outputs, with the small JSON reader below:
 *   - rtdenoise.contract: must be 1;
 *   - rtdenoise.inputs {"buffers": [...]}: the per-frame buffers, in order; each one's channel
 *     count C is that graph input's shape [1, C, H, W] (static in every exported model);
 *   - rtdenoise.pad_multiple: H and W are padded to HP and WP, its multiples, by repeating the
 *     last row and column;
 *   - rtdenoise.edge_margin (optional, 0 if absent): M edge rows and columns repeated on every
 *     side first (HP and WP are then multiples at least H + 2M and W + 2M), and the frame's
 *     output read back from row M, column M;
 *   - rtdenoise.state [{"name", "channels", "scale" (default 1), "size" (optional)}]: the
 *     inputs state.<name>, [1, channels, HP/scale, WP/scale] or [1, channels, h, w] for a
 *     fixed size [h, w], and the outputs state_next.<name> fed back;
 *   - `reset`, the scalar input, if the graph has it; `output`, the graph output.
 * Anything missing or malformed (a key, a value of the wrong type, a graph input the metadata
 * does not account for, an input of a kind this host does not feed such as per-sample
 * `samples`) is refused before the first frame with one line naming it, exit status 2.
 *
 * The frames run in order with the state fed back: `state.<name>` zero and `reset` = 1 on the
 * first frame, then each frame's `state_next.<name>` as the next frame's `state.<name>` and
 * `reset` = 0.
 *
 * Every input buffer of every frame first passes the input guard, the same rules as
 * runtime/guard.py (what `Denoiser.process` applies): the library's rtdenoise_guard_buffer
 * (rtdenoise_guard.h, found by dlsym in the same library) on the H x W frame, before it is
 * padded. As `Denoiser` does, a frame whose albedo, normal or depth is zero everywhere after
 * the guard (rtdenoise_guard_zero_guide: a missing render pass) runs with zero state and
 * reset = 1, and so does the next frame; so does the frame after one whose output had NaN/Inf
 * (replaced by 0). A frame the guard changed or restarted prints one line:
 *     frame <t>: nonfinite <pixels> clamped <pixels> outliers <pixels> unusable <names|-> reset <0|1>
 * (the counts of `Denoiser.last_guard`: NaN/Inf pixels of any buffer, clamped and outlier
 * pixels summed over the buffers), and the run ends with "<frames> frames".
 *
 * Exit status: 0 done; 1 a failure while running (ORT, a file, memory); 2 a bad command line
 * or a model this host cannot drive (the metadata or graph above), with the reason on stderr.
 *
 * ORT's headers are not in the onnxruntime wheel, so the part of the C API used here is
 * declared below as runtime/bridge/native_ops/ort_abi.h declares it: positions in the OrtApi
 * function table, which is append-only, so a position never changes once a version has it.
 * They are all among the first 125 entries, which the header of API version 13 already lists,
 * so GetApi(API_VERSION = 20) returning a table asserts that this ORT has them. Checked against
 * ORT's include/onnxruntime/core/session/onnxruntime_c_api.h (API versions 13 and 29),
 * counting the members of `struct OrtApi` from CreateStatus = 0.
 */

#include <dlfcn.h>
#include <errno.h>
#include <limits.h>
#include <math.h>
#include <stdarg.h>
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

enum { /* positions in the OrtApi table (the header's member order, from 0) */
    GET_ERROR_MESSAGE = 2, CREATE_ENV = 3, CREATE_SESSION = 7, RUN = 9,
    CREATE_SESSION_OPTIONS = 10,
    SESSION_GET_INPUT_COUNT = 30, SESSION_GET_OUTPUT_COUNT = 31,
    SESSION_GET_INPUT_TYPE_INFO = 33, SESSION_GET_OUTPUT_TYPE_INFO = 34,
    SESSION_GET_INPUT_NAME = 36, SESSION_GET_OUTPUT_NAME = 37,
    CREATE_TENSOR_WITH_DATA = 49, GET_TENSOR_MUTABLE_DATA = 51,
    CAST_TYPE_INFO_TO_TENSOR_INFO = 55, GET_TENSOR_ELEMENT_TYPE = 60,
    GET_DIMENSIONS_COUNT = 61, GET_DIMENSIONS = 62, GET_TENSOR_SHAPE_ELEMENT_COUNT = 64,
    GET_TENSOR_TYPE_AND_SHAPE = 65, CREATE_CPU_MEMORY_INFO = 69, ALLOCATOR_FREE = 76,
    GET_ALLOCATOR_WITH_DEFAULT_OPTIONS = 78, RELEASE_ENV = 92, RELEASE_STATUS = 93,
    RELEASE_MEMORY_INFO = 94, RELEASE_SESSION = 95, RELEASE_VALUE = 96, RELEASE_TYPE_INFO = 98,
    RELEASE_TENSOR_TYPE_AND_SHAPE_INFO = 99, RELEASE_SESSION_OPTIONS = 100,
    SESSION_GET_MODEL_METADATA = 111, MODEL_METADATA_LOOKUP_CUSTOM_METADATA_MAP = 116,
    RELEASE_MODEL_METADATA = 118,
};
enum { API_VERSION = 20, ELEMENT_FLOAT = 1, LOG_WARNING = 2, DEVICE_ALLOCATOR = 0 };
#define MAX_TENSORS 32  /* per kind: buffers, states, graph inputs, graph outputs */
#define MAX_RANK 8
#define MAX_SIDE 32768  /* H, W and state sizes: keeps every product within size_t */
#define EXIT_RUN 1      /* a failure while running */
#define EXIT_MODEL 2    /* a bad command line, or a model this host cannot drive */

static const ApiFn *api;
#define FN(index, type) ((type)api[index])
static const char *model_path = "model"; /* for messages */

/* Exit with ORT's message when `status` is a failure. */
static void check(OrtStatus *status, const char *what) {
    if (!status) return;
    fprintf(stderr, "%s: %s\n", what,
            FN(GET_ERROR_MESSAGE, const char *(*)(const OrtStatus *))(status));
    FN(RELEASE_STATUS, void (*)(OrtStatus *))(status);
    exit(EXIT_RUN);
}

/* Refuse the model: one line naming what is wrong, exit status 2. */
__attribute__((noreturn, format(printf, 1, 2))) static void refuse(const char *format, ...) {
    va_list args;
    va_start(args, format);
    fprintf(stderr, "%s: ", model_path);
    vfprintf(stderr, format, args);
    fputc('\n', stderr);
    va_end(args);
    exit(EXIT_MODEL);
}

static void *xmalloc(size_t size) {
    void *p = malloc(size ? size : 1);
    if (!p) fprintf(stderr, "out of memory\n"), exit(EXIT_RUN);
    return p;
}

static char *xstrdup(const char *s) {
    return strcpy(xmalloc(strlen(s) + 1), s);
}

/* ---- A small, strict JSON reader ---------------------------------------------------------
 *
 * Reads the part of JSON (RFC 8259) that the rtdenoise.* metadata values use: objects, arrays,
 * strings and integers, into a tree. Anything else is an error, not a guess: a number with a
 * fraction or an exponent, true / false / null, a key twice in one object, a control character
 * or a bad escape in a string, "\u0000" (names are C strings), nesting deeper than JSON_DEPTH,
 * text after the value. An error names the metadata key and the character offset and exits
 * with status 2. Bytes >= 0x80 in strings are kept as they are (ORT hands values over as
 * UTF-8); "\uXXXX" escapes, surrogate pairs included, become UTF-8.
 */

typedef enum { JSON_OBJECT, JSON_ARRAY, JSON_STRING, JSON_INTEGER } JsonType;

typedef struct Json {
    JsonType type;
    char *key;          /* a member of an object: its key; NULL otherwise */
    char *string;       /* JSON_STRING: the decoded text */
    long long integer;  /* JSON_INTEGER */
    struct Json *first; /* JSON_OBJECT, JSON_ARRAY: the first member or element */
    struct Json *next;  /* the next member or element of the same parent */
    size_t count;       /* JSON_OBJECT, JSON_ARRAY: the number of members or elements */
} Json;

typedef struct {
    const char *key;   /* the metadata key whose value is read, for messages */
    const char *text;  /* the value */
    const char *p;     /* the read position in it */
    int depth;         /* objects and arrays open around p */
} JsonReader;

enum { JSON_DEPTH = 16 };

__attribute__((noreturn)) static void json_error(const JsonReader *r, const char *what) {
    refuse("metadata %s is not valid JSON for this host: %s at character %ld", r->key, what,
           (long)(r->p - r->text));
}

static void json_skip_space(JsonReader *r) {
    while (*r->p == ' ' || *r->p == '\t' || *r->p == '\n' || *r->p == '\r') ++r->p;
}

static Json *json_new(JsonType type) {
    Json *v = xmalloc(sizeof *v);
    memset(v, 0, sizeof *v);
    v->type = type;
    return v;
}

static void json_free(Json *v) {
    while (v) {
        Json *next = v->next;
        json_free(v->first);
        free(v->key);
        free(v->string);
        free(v);
        v = next;
    }
}

/* Four hex digits at r->p (after "\u"). */
static unsigned json_hex4(JsonReader *r) {
    unsigned code = 0;
    for (int i = 0; i < 4; ++i, ++r->p) {
        const char c = *r->p;
        int digit = c >= '0' && c <= '9' ? c - '0'
                    : c >= 'a' && c <= 'f' ? c - 'a' + 10
                    : c >= 'A' && c <= 'F' ? c - 'A' + 10 : -1;
        if (digit < 0) json_error(r, "expected 4 hex digits after \\u");
        code = code * 16 + (unsigned)digit;
    }
    return code;
}

/* A string at r->p (on its opening quote): the decoded text, allocated. */
static char *json_string(JsonReader *r) {
    ++r->p; /* the opening quote */
    /* The decoded text is never longer than the source: an escape of n characters gives at
     * most n bytes ("\uXXXX": 6 -> at most 3; a pair, 12 -> 4). */
    const char *end = r->p;
    while (*end && *end != '"') end += (*end == '\\' && end[1]) ? 2 : 1;
    char *out = xmalloc((size_t)(end - r->p) + 1), *o = out;
    for (;;) {
        const unsigned char c = (unsigned char)*r->p;
        if (c == '"') break;
        if (c == '\0') json_error(r, "unterminated string");
        if (c < 0x20) json_error(r, "control character in a string");
        ++r->p;
        if (c != '\\') {
            *o++ = (char)c;
            continue;
        }
        const char e = *r->p++;
        switch (e) {
        case '"': *o++ = '"'; break;
        case '\\': *o++ = '\\'; break;
        case '/': *o++ = '/'; break;
        case 'b': *o++ = '\b'; break;
        case 'f': *o++ = '\f'; break;
        case 'n': *o++ = '\n'; break;
        case 'r': *o++ = '\r'; break;
        case 't': *o++ = '\t'; break;
        case 'u': {
            unsigned code = json_hex4(r);
            if (code >= 0xDC00 && code <= 0xDFFF) json_error(r, "lone low surrogate");
            if (code >= 0xD800 && code <= 0xDBFF) { /* a high surrogate: its low one follows */
                if (r->p[0] != '\\' || r->p[1] != 'u')
                    json_error(r, "high surrogate without its low surrogate");
                r->p += 2;
                const unsigned low = json_hex4(r);
                if (low < 0xDC00 || low > 0xDFFF)
                    json_error(r, "high surrogate without its low surrogate");
                code = 0x10000 + ((code - 0xD800) << 10) + (low - 0xDC00);
            }
            if (code == 0) json_error(r, "\\u0000 in a string");
            if (code < 0x80) {
                *o++ = (char)code;
            } else if (code < 0x800) {
                *o++ = (char)(0xC0 | code >> 6);
                *o++ = (char)(0x80 | (code & 0x3F));
            } else if (code < 0x10000) {
                *o++ = (char)(0xE0 | code >> 12);
                *o++ = (char)(0x80 | (code >> 6 & 0x3F));
                *o++ = (char)(0x80 | (code & 0x3F));
            } else {
                *o++ = (char)(0xF0 | code >> 18);
                *o++ = (char)(0x80 | (code >> 12 & 0x3F));
                *o++ = (char)(0x80 | (code >> 6 & 0x3F));
                *o++ = (char)(0x80 | (code & 0x3F));
            }
            break;
        }
        default: --r->p; json_error(r, "bad escape in a string");
        }
    }
    ++r->p; /* the closing quote */
    *o = '\0';
    return out;
}

/* An integer at r->p: -?(0|[1-9][0-9]*), within long long; no fraction, no exponent. */
static long long json_integer(JsonReader *r) {
    const int negative = *r->p == '-';
    if (negative) ++r->p;
    if (*r->p < '0' || *r->p > '9') json_error(r, "expected a digit");
    if (*r->p == '0' && r->p[1] >= '0' && r->p[1] <= '9') json_error(r, "leading zero");
    unsigned long long magnitude = 0;
    const unsigned long long limit = negative ? (unsigned long long)LLONG_MAX + 1 : LLONG_MAX;
    while (*r->p >= '0' && *r->p <= '9') {
        const unsigned digit = (unsigned)(*r->p - '0');
        if (magnitude > (limit - digit) / 10) json_error(r, "integer out of range");
        magnitude = magnitude * 10 + digit;
        ++r->p;
    }
    if (*r->p == '.' || *r->p == 'e' || *r->p == 'E')
        json_error(r, "a number that is not an integer (this host reads integers only)");
    if (!negative) return (long long)magnitude;
    return magnitude > (unsigned long long)LLONG_MAX ? LLONG_MIN : -(long long)magnitude;
}

static Json *json_value(JsonReader *r);

/* An object or an array at r->p (on its '{' or '['). */
static Json *json_container(JsonReader *r) {
    const int object = *r->p == '{';
    const char close = object ? '}' : ']';
    if (++r->depth > JSON_DEPTH) json_error(r, "nesting too deep");
    ++r->p;
    Json *v = json_new(object ? JSON_OBJECT : JSON_ARRAY), **tail = &v->first;
    json_skip_space(r);
    if (*r->p == close) {
        ++r->p, --r->depth;
        return v;
    }
    for (;;) {
        char *key = NULL;
        if (object) {
            json_skip_space(r);
            if (*r->p != '"') json_error(r, "expected a string key");
            const char *at = r->p;
            key = json_string(r);
            for (Json *m = v->first; m; m = m->next)
                if (strcmp(m->key, key) == 0) r->p = at, json_error(r, "a key twice in one object");
            json_skip_space(r);
            if (*r->p != ':') json_error(r, "expected ':'");
            ++r->p;
        }
        Json *item = json_value(r);
        item->key = key;
        *tail = item, tail = &item->next, ++v->count;
        json_skip_space(r);
        if (*r->p == ',') {
            ++r->p;
            continue;
        }
        if (*r->p != close) json_error(r, object ? "expected ',' or '}'" : "expected ',' or ']'");
        ++r->p, --r->depth;
        return v;
    }
}

static Json *json_value(JsonReader *r) {
    json_skip_space(r);
    const char c = *r->p;
    if (c == '{' || c == '[') return json_container(r);
    if (c == '"') {
        Json *v = json_new(JSON_STRING);
        v->string = json_string(r);
        return v;
    }
    if (c == '-' || (c >= '0' && c <= '9')) {
        Json *v = json_new(JSON_INTEGER);
        v->integer = json_integer(r);
        return v;
    }
    json_error(r, c ? "expected an object, an array, a string or an integer" : "unexpected end");
}

/* The whole of `text`, the value of metadata key `key`: one JSON value and nothing after. */
static Json *json_parse(const char *key, const char *text) {
    JsonReader r = {key, text, text, 0};
    Json *v = json_value(&r);
    json_skip_space(&r);
    if (*r.p) json_error(&r, "text after the value");
    return v;
}

static const char *json_type_name(const Json *v) {
    static const char *names[] = {"an object", "an array", "a string", "an integer"};
    return names[v->type];
}

/* Member `name` of object `obj` (whose path, for messages, is `path`), which must be of
 * `type`; NULL when absent and `optional`. */
static const Json *json_member(const Json *obj, const char *path, const char *name,
                               JsonType type, int optional) {
    const Json *m = obj->first;
    while (m && strcmp(m->key, name) != 0) m = m->next;
    if (!m) {
        if (optional) return NULL;
        refuse("metadata %s has no key \"%s\"", path, name);
    }
    if (m->type != type) {
        const Json want = {.type = type};
        refuse("metadata %s.%s must be %s, not %s", path, name, json_type_name(&want),
               json_type_name(m));
    }
    return m;
}

/* ---- The model: what the metadata and the session say ------------------------------------ */

typedef struct {
    char *name;
    int rank;                /* -1: not a tensor */
    int element_type;
    int64_t dims[MAX_RANK];  /* -1: a dynamic dimension */
} GraphTensor;

/* The session's inputs (outputs = 0) or outputs (1): names, element types and shapes. */
static int graph_tensors(void *session, void *allocator, int outputs, GraphTensor *list) {
    size_t count = 0;
    check(FN(outputs ? SESSION_GET_OUTPUT_COUNT : SESSION_GET_INPUT_COUNT,
             OrtStatus *(*)(const void *, size_t *))(session, &count),
          "SessionGetInputCount/SessionGetOutputCount");
    if (count > MAX_TENSORS)
        refuse("the graph has %zu %s, this host takes %d", count, outputs ? "outputs" : "inputs",
               MAX_TENSORS);
    for (size_t i = 0; i < count; ++i) {
        GraphTensor *t = &list[i];
        char *name = NULL;
        check(FN(outputs ? SESSION_GET_OUTPUT_NAME : SESSION_GET_INPUT_NAME,
                 OrtStatus *(*)(const void *, size_t, void *, char **))(session, i, allocator,
                                                                        &name),
              "SessionGetInputName/SessionGetOutputName");
        t->name = xstrdup(name);
        check(FN(ALLOCATOR_FREE, OrtStatus *(*)(void *, void *))(allocator, name), "AllocatorFree");
        void *type_info = NULL;
        const void *tensor_info = NULL;
        check(FN(outputs ? SESSION_GET_OUTPUT_TYPE_INFO : SESSION_GET_INPUT_TYPE_INFO,
                 OrtStatus *(*)(const void *, size_t, void **))(session, i, &type_info),
              "SessionGetInputTypeInfo/SessionGetOutputTypeInfo");
        check(FN(CAST_TYPE_INFO_TO_TENSOR_INFO, OrtStatus *(*)(const void *, const void **))(
                  type_info, &tensor_info), "CastTypeInfoToTensorInfo");
        t->rank = -1;
        if (tensor_info) { /* NULL: not a tensor (a sequence, a map) */
            size_t rank = 0;
            check(FN(GET_TENSOR_ELEMENT_TYPE, OrtStatus *(*)(const void *, int *))(
                      tensor_info, &t->element_type), "GetTensorElementType");
            check(FN(GET_DIMENSIONS_COUNT, OrtStatus *(*)(const void *, size_t *))(tensor_info,
                                                                                  &rank),
                  "GetDimensionsCount");
            if (rank > MAX_RANK) refuse("graph tensor '%s' has rank %zu", t->name, rank);
            check(FN(GET_DIMENSIONS, OrtStatus *(*)(const void *, int64_t *, size_t))(
                      tensor_info, t->dims, rank), "GetDimensions");
            t->rank = (int)rank;
        }
        FN(RELEASE_TYPE_INFO, void (*)(void *))(type_info);
        if (t->rank < 0 || t->element_type != ELEMENT_FLOAT)
            refuse("graph tensor '%s' is not a float32 tensor (the contract's only kind)",
                   t->name);
    }
    return (int)count;
}

static const GraphTensor *find_tensor(const GraphTensor *list, int count, const char *name) {
    for (int i = 0; i < count; ++i)
        if (strcmp(list[i].name, name) == 0) return &list[i];
    return NULL;
}

/* The value of custom metadata key `key`, allocated, or NULL if the model has none. */
static char *optional_metadata_value(void *metadata, void *allocator, const char *key) {
    char *value = NULL;
    check(FN(MODEL_METADATA_LOOKUP_CUSTOM_METADATA_MAP,
             OrtStatus *(*)(const void *, void *, const char *, char **))(metadata, allocator,
                                                                         key, &value),
          "ModelMetadataLookupCustomMetadataMap");
    if (!value) return NULL;
    char *copy = xstrdup(value);
    check(FN(ALLOCATOR_FREE, OrtStatus *(*)(void *, void *))(allocator, value), "AllocatorFree");
    return copy;
}

/* The value of custom metadata key `key`, allocated; the model must have it. */
static char *metadata_value(void *metadata, void *allocator, const char *key) {
    char *value = optional_metadata_value(metadata, allocator, key);
    if (!value)
        refuse("metadata key %s missing: not an rtdenoise model (docs/contract.md, \"Metadata\")",
               key);
    return value;
}

typedef struct {
    char *name;             /* the graph input's name */
    char *out;              /* a state: its state_next output */
    int rank;
    int64_t dims[4];
    size_t count;
    float *data;
    int64_t scale, size_h, size_w; /* a state: size_h > 0 for a fixed size, else HP/scale */
} Tensor;

typedef struct {
    int n_in, n_state, has_reset;
    Tensor in[MAX_TENSORS];        /* the buffers of rtdenoise.inputs, in order */
    Tensor state[MAX_TENSORS];     /* rtdenoise.state, in order */
    int64_t pad, margin, out_channels;
} Model;

/* Read rtdenoise.* and the session's inputs and outputs into `m` (shapes without H and W). */
static void read_model(void *session, Model *m) {
    void *allocator = NULL, *metadata = NULL; /* the default allocator is never released */
    check(FN(GET_ALLOCATOR_WITH_DEFAULT_OPTIONS, OrtStatus *(*)(void **))(&allocator),
          "GetAllocatorWithDefaultOptions");
    check(FN(SESSION_GET_MODEL_METADATA, OrtStatus *(*)(const void *, void **))(session,
                                                                               &metadata),
          "SessionGetModelMetadata");
    char *contract = metadata_value(metadata, allocator, "rtdenoise.contract");
    char *inputs = metadata_value(metadata, allocator, "rtdenoise.inputs");
    char *states = metadata_value(metadata, allocator, "rtdenoise.state");
    char *pad = metadata_value(metadata, allocator, "rtdenoise.pad_multiple");
    char *margin = optional_metadata_value(metadata, allocator, "rtdenoise.edge_margin");
    FN(RELEASE_MODEL_METADATA, void (*)(void *))(metadata);

    /* rtdenoise.contract and rtdenoise.pad_multiple: an integer each, as text */
    Json *v = json_parse("rtdenoise.contract", contract);
    if (v->type != JSON_INTEGER || v->integer != 1)
        refuse("metadata rtdenoise.contract is \"%s\", this host reads version 1", contract);
    json_free(v);
    v = json_parse("rtdenoise.pad_multiple", pad);
    if (v->type != JSON_INTEGER || v->integer < 1 || v->integer > 4096)
        refuse("metadata rtdenoise.pad_multiple is \"%s\", not an integer in 1..4096", pad);
    m->pad = v->integer;
    json_free(v);
    m->margin = 0;
    if (margin) { /* optional: an integer as text, 0..256 */
        v = json_parse("rtdenoise.edge_margin", margin);
        if (v->type != JSON_INTEGER || v->integer < 0 || v->integer > 256)
            refuse("metadata rtdenoise.edge_margin is \"%s\", not an integer in 0..256", margin);
        m->margin = v->integer;
        json_free(v);
        free(margin);
    }

    GraphTensor graph_in[MAX_TENSORS], graph_out[MAX_TENSORS];
    const int n_graph_in = graph_tensors(session, allocator, 0, graph_in);
    const int n_graph_out = graph_tensors(session, allocator, 1, graph_out);

    /* rtdenoise.inputs: {"buffers": [names...], ...}; each one's C from its graph input */
    Json *spec = json_parse("rtdenoise.inputs", inputs);
    if (spec->type != JSON_OBJECT)
        refuse("metadata rtdenoise.inputs must be an object, not %s", json_type_name(spec));
    const Json *buffers = json_member(spec, "rtdenoise.inputs", "buffers", JSON_ARRAY, 0);
    if (buffers->count < 1 || buffers->count > MAX_TENSORS)
        refuse("metadata rtdenoise.inputs.buffers lists %zu buffers (1..%d)", buffers->count,
               MAX_TENSORS);
    for (const Json *b = buffers->first; b; b = b->next) {
        const int i = m->n_in;
        if (b->type != JSON_STRING)
            refuse("metadata rtdenoise.inputs.buffers[%d] must be a string, not %s", i,
                   json_type_name(b));
        if (find_tensor(graph_in, n_graph_in, b->string) == NULL)
            refuse("metadata rtdenoise.inputs.buffers[%d]: '%s' is not a graph input", i,
                   b->string);
        for (int j = 0; j < i; ++j)
            if (strcmp(m->in[j].name, b->string) == 0)
                refuse("metadata rtdenoise.inputs.buffers lists '%s' twice", b->string);
        const GraphTensor *g = find_tensor(graph_in, n_graph_in, b->string);
        if (g->rank != 4)
            refuse("buffer '%s' has rank %d: this host feeds [1, C, H, W] buffers only%s",
                   b->string, g->rank, g->rank == 5 ? " (not per-sample data)" : "");
        if (g->dims[1] < 1 || g->dims[1] > 4096)
            refuse("buffer '%s': the graph input's channel count is not fixed (or above 4096)",
                   b->string);
        Tensor *t = &m->in[m->n_in++];
        t->name = xstrdup(b->string);
        t->rank = 4;
        t->dims[0] = 1, t->dims[1] = g->dims[1];
    }
    json_free(spec);

    /* rtdenoise.state: [{"name", "channels", "scale" (default 1), "size": [h, w] (optional)}] */
    Json *list = json_parse("rtdenoise.state", states);
    if (list->type != JSON_ARRAY)
        refuse("metadata rtdenoise.state must be an array, not %s", json_type_name(list));
    if (list->count > MAX_TENSORS)
        refuse("metadata rtdenoise.state lists %zu states (at most %d)", list->count, MAX_TENSORS);
    for (const Json *e = list->first; e; e = e->next) {
        const int s = m->n_state;
        char path[64];
        snprintf(path, sizeof path, "rtdenoise.state[%d]", s);
        if (e->type != JSON_OBJECT)
            refuse("metadata %s must be an object, not %s", path, json_type_name(e));
        const Json *name = json_member(e, path, "name", JSON_STRING, 0);
        const Json *channels = json_member(e, path, "channels", JSON_INTEGER, 0);
        const Json *scale = json_member(e, path, "scale", JSON_INTEGER, 1);
        const Json *size = json_member(e, path, "size", JSON_ARRAY, 1);
        if (!name->string[0]) refuse("metadata %s.name is empty", path);
        for (int j = 0; j < s; ++j)
            if (strcmp(m->state[j].name + strlen("state."), name->string) == 0)
                refuse("metadata rtdenoise.state lists '%s' twice", name->string);
        if (channels->integer < 1 || channels->integer > (1 << 24))
            refuse("metadata %s.channels must be in 1..%d, not %lld", path, 1 << 24,
                   channels->integer);
        Tensor *t = &m->state[m->n_state++];
        t->scale = scale ? scale->integer : 1;
        if (t->scale < 1 || m->pad % t->scale)
            refuse("metadata %s.scale %lld does not divide rtdenoise.pad_multiple %lld", path,
                   (long long)t->scale, (long long)m->pad);
        if (size) {
            const Json *h = size->first, *w = h ? h->next : NULL;
            if (size->count != 2 || h->type != JSON_INTEGER || w->type != JSON_INTEGER ||
                h->integer < 1 || h->integer > MAX_SIDE || w->integer < 1 ||
                w->integer > MAX_SIDE)
                refuse("metadata %s.size must be [h, w], integers in 1..%d", path, MAX_SIDE);
            t->size_h = h->integer, t->size_w = w->integer;
        }
        const size_t length = strlen(name->string) + sizeof "state_next.";
        t->name = xmalloc(length), t->out = xmalloc(length);
        snprintf(t->name, length, "state.%s", name->string);
        snprintf(t->out, length, "state_next.%s", name->string);
        t->rank = 4;
        t->dims[0] = 1, t->dims[1] = channels->integer;
        const GraphTensor *g = find_tensor(graph_in, n_graph_in, t->name);
        const GraphTensor *o = find_tensor(graph_out, n_graph_out, t->out);
        if (!g) refuse("metadata %s names state '%s', but the graph has no input %s", path,
                       name->string, t->name);
        if (!o) refuse("metadata %s names state '%s', but the graph has no output %s", path,
                       name->string, t->out);
        const GraphTensor *pair[2] = {g, o}; /* both [1, channels, h, w] */
        for (int x = 0; x < 2; ++x)
            if (pair[x]->rank != 4 || (pair[x]->dims[1] >= 0 && pair[x]->dims[1] != t->dims[1]))
                refuse("graph tensor %s is not [1, %lld, h, w] as metadata %s says",
                       pair[x]->name, (long long)t->dims[1], path);
    }
    json_free(list);

    /* reset, if the graph has it; any other graph input is one this host cannot feed */
    const GraphTensor *reset = find_tensor(graph_in, n_graph_in, "reset");
    m->has_reset = reset != NULL;
    if (reset && reset->rank != 0) refuse("graph input 'reset' is not a scalar");
    if (m->n_state && !reset) refuse("the model has state but no 'reset' input");
    for (int i = 0; i < n_graph_in; ++i) {
        int known = strcmp(graph_in[i].name, "reset") == 0;
        for (int j = 0; j < m->n_in; ++j) known |= strcmp(graph_in[i].name, m->in[j].name) == 0;
        for (int j = 0; j < m->n_state; ++j)
            known |= strcmp(graph_in[i].name, m->state[j].name) == 0;
        if (!known)
            refuse("graph input '%s' is neither in rtdenoise.inputs.buffers, 'reset' nor in "
                   "rtdenoise.state", graph_in[i].name);
    }
    const GraphTensor *output = find_tensor(graph_out, n_graph_out, "output");
    if (!output) refuse("the graph has no output 'output'");
    if (output->rank != 4 || output->dims[1] < 1)
        refuse("graph output 'output' is not [1, C, H, W] with a fixed C");
    m->out_channels = output->dims[1];

    for (int i = 0; i < n_graph_in; ++i) free(graph_in[i].name);
    for (int i = 0; i < n_graph_out; ++i) free(graph_out[i].name);
    free(contract), free(inputs), free(states), free(pad);
}

/* The library's guard functions (rtdenoise_guard.h), found by dlsym. */
typedef int (*GuardBufferFn)(const char *, const float *, float *, int64_t, int64_t, int64_t,
                             rtdenoise_guard_counts *, uint8_t *);
typedef int (*ZeroGuideFn)(const char *, const float *, int64_t);
typedef const char *(*GuardErrorFn)(int);

/* Give `t` its H x W dependent dims (HP x WP padded) and zeroed data. */
static void allocate(Tensor *t, int64_t h, int64_t w) {
    t->dims[2] = h, t->dims[3] = w;
    t->count = (size_t)t->dims[1] * (size_t)h * (size_t)w;
    t->data = xmalloc(t->count * sizeof(float));
    memset(t->data, 0, t->count * sizeof(float));
}

static int64_t clamp_index(int64_t i, int64_t n) { return i < 0 ? 0 : i < n ? i : n - 1; }

/* Repeat the edge rows and columns: C x H x W `src` -> the C x HP x WP tensor `t`, the frame
 * at row and column `margin` (the edge repeated above and left of it, and below and right up
 * to HP x WP). */
static void pad_edge(const float *src, int64_t h, int64_t w, int64_t margin, Tensor *t) {
    const int64_t c = t->dims[1], hp = t->dims[2], wp = t->dims[3];
    for (int64_t k = 0; k < c; ++k)
        for (int64_t y = 0; y < hp; ++y)
            for (int64_t x = 0; x < wp; ++x)
                t->data[(k * hp + y) * wp + x] =
                    src[(k * h + clamp_index(y - margin, h)) * w + clamp_index(x - margin, w)];
}

static void read_floats(const char *path, float *data, size_t count) {
    FILE *f = fopen(path, "rb");
    if (!f || fread(data, sizeof(float), count, f) != count) {
        fprintf(stderr, "%s: cannot read %zu floats\n", path, count);
        exit(EXIT_RUN);
    }
    fclose(f);
}

/* A whole decimal number in lo..hi, or exit with the usage error. */
static long parse_arg(const char *text, const char *what, long lo, long hi) {
    char *end = NULL;
    errno = 0;
    const long v = strtol(text, &end, 10);
    if (errno || end == text || *end || v < lo || v > hi) {
        fprintf(stderr, "%s must be an integer in %ld..%ld, not '%s'\n", what, lo, hi, text);
        exit(EXIT_MODEL);
    }
    return v;
}

/* The number of values of the tensor `value`, which ORT allocated. */
static size_t element_count(void *value) {
    void *info = NULL;
    size_t count = 0;
    check(FN(GET_TENSOR_TYPE_AND_SHAPE, OrtStatus *(*)(const void *, void **))(value, &info),
          "GetTensorTypeAndShape");
    check(FN(GET_TENSOR_SHAPE_ELEMENT_COUNT, OrtStatus *(*)(const void *, size_t *))(info, &count),
          "GetTensorShapeElementCount");
    FN(RELEASE_TENSOR_TYPE_AND_SHAPE_INFO, void (*)(void *))(info);
    return count;
}

int main(int argc, char **argv) {
    if (argc != 7) {
        fprintf(stderr, "usage: %s MODEL.onnx LIBRARY FOLDER FRAMES H W\n", argv[0]);
        return EXIT_MODEL;
    }
    model_path = argv[1];
    const char *library = argv[2], *folder = argv[3];
    const int frames = (int)parse_arg(argv[4], "FRAMES", 0, 1000000);
    const int64_t height = parse_arg(argv[5], "H", 1, MAX_SIDE);
    const int64_t width = parse_arg(argv[6], "W", 1, MAX_SIDE);

    const OrtApiBase *base = OrtGetApiBase();
    api = base->GetApi(API_VERSION);
    if (!api)
        return fprintf(stderr, "ONNX Runtime %s lacks API version %d\n", base->GetVersionString(),
                       API_VERSION), EXIT_RUN;
    void *env = NULL, *options = NULL, *session = NULL, *memory = NULL;
    check(FN(CREATE_ENV, OrtStatus *(*)(int, const char *, void **))(LOG_WARNING, "host_c", &env),
          "CreateEnv");
    check(FN(CREATE_SESSION_OPTIONS, OrtStatus *(*)(void **))(&options), "CreateSessionOptions");

    /* the custom ops: the library's own registration entry point */
    void *handle = dlopen(library, RTLD_NOW | RTLD_LOCAL);
    if (!handle) return fprintf(stderr, "%s\n", dlerror()), EXIT_RUN;
    OrtStatus *(*register_ops)(void *, const OrtApiBase *) =
        (OrtStatus * (*)(void *, const OrtApiBase *)) dlsym(handle, "RegisterCustomOps");
    if (!register_ops) return fprintf(stderr, "%s: no RegisterCustomOps\n", library), EXIT_RUN;
    check(register_ops(options, base), "RegisterCustomOps");
    GuardBufferFn guard_buffer = (GuardBufferFn)dlsym(handle, "rtdenoise_guard_buffer");
    ZeroGuideFn zero_guide = (ZeroGuideFn)dlsym(handle, "rtdenoise_guard_zero_guide");
    GuardErrorFn guard_error = (GuardErrorFn)dlsym(handle, "rtdenoise_guard_error");
    if (!guard_buffer || !zero_guide || !guard_error)
        return fprintf(stderr, "%s: no rtdenoise_guard_* functions\n", library), EXIT_RUN;

    check(FN(CREATE_SESSION, OrtStatus *(*)(void *, const char *, void *, void **))(
              env, model_path, options, &session), "CreateSession");
    check(FN(CREATE_CPU_MEMORY_INFO, OrtStatus *(*)(int, int, void **))(DEVICE_ALLOCATOR, 0, &memory),
          "CreateCpuMemoryInfo");

    /* everything about the model, from the model */
    static Model m;
    read_model(session, &m);
    const int64_t hp = (height + 2 * m.margin + m.pad - 1) / m.pad * m.pad;
    const int64_t wp = (width + 2 * m.margin + m.pad - 1) / m.pad * m.pad;
    size_t stage_count = 0; /* the largest C x H x W buffer, read and guarded before padding */
    for (int i = 0; i < m.n_in; ++i) {
        allocate(&m.in[i], hp, wp);
        const size_t count = (size_t)m.in[i].dims[1] * (size_t)height * (size_t)width;
        if (count > stage_count) stage_count = count;
    }
    for (int s = 0; s < m.n_state; ++s) {
        Tensor *t = &m.state[s];
        if (t->size_h) allocate(t, t->size_h, t->size_w);
        else allocate(t, hp / t->scale, wp / t->scale);
    }
    const size_t output_count = (size_t)m.out_channels * (size_t)hp * (size_t)wp;
    const size_t frame_count = (size_t)m.out_channels * (size_t)height * (size_t)width;
    float reset_value = 1.0f;
    float *stage = xmalloc(stage_count * sizeof(float));
    float *cropped = xmalloc(frame_count * sizeof(float)); /* the frame's output, C x H x W */
    uint8_t *nonfinite_mask = xmalloc((size_t)height * (size_t)width);

    const char *in_names[MAX_TENSORS * 2 + 1], *out_names[MAX_TENSORS + 1];
    void *in_values[MAX_TENSORS * 2 + 1], *out_values[MAX_TENSORS + 1];
    int restart = 1; /* the next frame starts a new history: the first one, as Denoiser's */
    for (int t = 0; t < frames; ++t) {
        int k = 0;
        char path[4096], unusable[256] = "";
        long long nonfinite = 0, clamped = 0, outliers = 0;
        memset(nonfinite_mask, 0, (size_t)height * (size_t)width);
        for (int i = 0; i < m.n_in; ++i) { /* the input guard, then the padding */
            const char *name = m.in[i].name;
            const int64_t planes = m.in[i].dims[1], count = planes * height * width;
            if (snprintf(path, sizeof path, "%s/f%d.%s.f32", folder, t, name) >= (int)sizeof path)
                return fprintf(stderr, "%s: path too long\n", folder), EXIT_RUN;
            read_floats(path, stage, (size_t)count);
            rtdenoise_guard_counts counts;
            int rc = guard_buffer(name, stage, stage, planes, height, width, &counts,
                                  nonfinite_mask);
            if (rc != RTDENOISE_GUARD_OK)
                return fprintf(stderr, "%s: %s\n", name, guard_error(rc)), EXIT_RUN;
            clamped += counts.clamped;
            outliers += counts.outliers;
            if (zero_guide(name, stage, count) == 1) /* a missing render pass */
                snprintf(unusable + strlen(unusable), sizeof unusable - strlen(unusable), "%s%s",
                         unusable[0] ? "," : "", name);
            pad_edge(stage, height, width, m.margin, &m.in[i]);
        }
        for (int64_t p = 0; p < height * width; ++p) nonfinite += nonfinite_mask[p];
        const int reset_now = restart || unusable[0];
        if (reset_now) /* a new history: zero state (the graph ignores it with reset = 1) */
            for (int s = 0; s < m.n_state; ++s)
                memset(m.state[s].data, 0, m.state[s].count * sizeof(float));
        if (nonfinite || clamped || outliers || unusable[0] || (reset_now && t > 0))
            printf("frame %d: nonfinite %lld clamped %lld outliers %lld unusable %s reset %d\n", t,
                   nonfinite, clamped, outliers, unusable[0] ? unusable : "-", reset_now);
        /* the inputs: buffers, reset (a scalar: no dims) if the graph has it, states */
        Tensor *fed[MAX_TENSORS * 2];
        int n_fed = 0;
        for (int i = 0; i < m.n_in; ++i) fed[n_fed++] = &m.in[i];
        for (int s = 0; s < m.n_state; ++s) fed[n_fed++] = &m.state[s];
        for (int i = 0; i < n_fed; ++i, ++k) {
            in_names[k] = fed[i]->name;
            check(FN(CREATE_TENSOR_WITH_DATA,
                     OrtStatus *(*)(void *, void *, size_t, const int64_t *, size_t, int, void **))(
                      memory, fed[i]->data, fed[i]->count * sizeof(float), fed[i]->dims,
                      (size_t)fed[i]->rank, ELEMENT_FLOAT, &in_values[k]),
                  "CreateTensorWithDataAsOrtValue");
        }
        if (m.has_reset) {
            reset_value = reset_now ? 1.0f : 0.0f;
            in_names[k] = "reset";
            check(FN(CREATE_TENSOR_WITH_DATA,
                     OrtStatus *(*)(void *, void *, size_t, const int64_t *, size_t, int, void **))(
                      memory, &reset_value, sizeof reset_value, NULL, 0, ELEMENT_FLOAT,
                      &in_values[k++]),
                  "CreateTensorWithDataAsOrtValue");
        }
        out_names[0] = "output";
        for (int s = 0; s < m.n_state; ++s) out_names[1 + s] = m.state[s].out;
        for (int o = 0; o <= m.n_state; ++o) out_values[o] = NULL;  /* ORT allocates them */
        check(FN(RUN, OrtStatus *(*)(void *, const void *, const char *const *, const void *const *,
                                     size_t, const char *const *, size_t, void **))(
                  session, NULL, in_names, (const void *const *)in_values, (size_t)k, out_names,
                  (size_t)m.n_state + 1, out_values), "Run");
        for (int o = 0; o <= m.n_state; ++o) {
            float *data = NULL;
            const size_t expected = o == 0 ? output_count : m.state[o - 1].count;
            if (element_count(out_values[o]) != expected)
                return fprintf(stderr, "%s: %zu values, not the %zu of its input\n", out_names[o],
                               element_count(out_values[o]), expected), EXIT_RUN;
            check(FN(GET_TENSOR_MUTABLE_DATA, OrtStatus *(*)(void *, void **))(out_values[o],
                                                                            (void **)&data),
                  "GetTensorMutableData");
            if (o == 0) { /* cropped; NaN/Inf in it: 0, and the next frame restarts */
                restart = unusable[0] != 0;
                float *v = cropped;
                for (int64_t c = 0; c < m.out_channels; ++c)
                    for (int64_t y = m.margin; y < m.margin + height; ++y)
                        for (int64_t x = m.margin; x < m.margin + width; ++x, ++v) {
                            *v = data[(c * hp + y) * wp + x];
                            if (!isfinite(*v)) *v = 0.0f, restart = 1;
                        }
                snprintf(path, sizeof path, "%s/out%d.f32", folder, t);
                FILE *f = fopen(path, "wb");
                if (!f || fwrite(cropped, sizeof(float), frame_count, f) != frame_count)
                    return fprintf(stderr, "%s: cannot write\n", path), EXIT_RUN;
                fclose(f);
            } else { /* the state the next frame reads */
                memcpy(m.state[o - 1].data, data, expected * sizeof(float));
            }
            FN(RELEASE_VALUE, void (*)(void *))(out_values[o]);
        }
        for (int i = 0; i < k; ++i) FN(RELEASE_VALUE, void (*)(void *))(in_values[i]);
    }
    for (int i = 0; i < m.n_in; ++i) free(m.in[i].name), free(m.in[i].data);
    for (int s = 0; s < m.n_state; ++s)
        free(m.state[s].name), free(m.state[s].out), free(m.state[s].data);
    free(stage);
    free(cropped);
    free(nonfinite_mask);
    FN(RELEASE_MEMORY_INFO, void (*)(void *))(memory);
    FN(RELEASE_SESSION, void (*)(void *))(session);
    FN(RELEASE_SESSION_OPTIONS, void (*)(void *))(options);
    FN(RELEASE_ENV, void (*)(void *))(env);
    printf("%d frames\n", frames);
    return 0;
}

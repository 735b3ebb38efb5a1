/*
 * bridge.h: what the FMI 2.0 and FMI 3.0 wrappers of mbdfmu FMUs share (included by
 * fmi2.c and fmi3.c, each compiled alone into the binary of an FMU of its version).
 *
 * The binary is the same for every FMU of a version: what a model is comes from its
 * resources folder (mbdfmu.json, mbdfmu_boot.py, the runtime package and the model module).
 *
 * Python is found at run time, never linked:
 *   - a process that already runs Python (fmpy, libcosimpy, ecospy, any Python host) is
 *     used as it is: dlsym(RTLD_DEFAULT, "Py_IsInitialized") finds it and it returns 1;
 *   - otherwise the libpython named by $MBDFMU_PYTHON_LIBRARY, or else the one recorded
 *     in mbdfmu.json at build time, is loaded with RTLD_GLOBAL (extension modules such as
 *     numpy's resolve their Python symbols in the global scope), initialized once with
 *     Py_InitializeEx(0) (no signal handlers) and its GIL released, so that any thread
 *     can call in. It is never finalized: numpy cannot be initialized twice in a process,
 *     and finalizing at unload is what crashed hosts at exit.
 * Every C-API function comes from dlsym into the table `py`, and only functions of the
 * stable ABI are used (Py_IncRef/Py_DecRef rather than the macros), so one binary works
 * with CPython 3.10 to 3.13.
 *
 * Each FMI call takes the GIL (PyGILState_Ensure), calls one method of the slave (the
 * protocol in docs/fmu_runtime.md: every method returns (status, payload) and never
 * raises), then hands the messages the slave queued to the host's logger (through the
 * instance's `emit`, which each wrapper sets for its version's logger). An exception
 * escaping the runtime means the runtime broke its contract: the wrapper logs it and
 * returns Fatal. FMI 2.0 and 3.0 number their statuses alike (OK 0 ... Fatal 4), so
 * statuses cross as plain ints.
 */
#ifndef MBDFMU_BRIDGE_H
#define MBDFMU_BRIDGE_H

#define _GNU_SOURCE
#include <dlfcn.h>
#include <math.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/types.h>
#include <wchar.h>

/* Statuses as FMI 2.0 and 3.0 both number them. */
#define ST_OK 0
#define ST_WARNING 1
#define ST_DISCARD 2
#define ST_ERROR 3
#define ST_FATAL 4
#define ST_PENDING 5

/* ---- the Python C API, resolved at run time ----------------------------------------- */

typedef struct _object PyObject;   /* opaque: never dereferenced here */
typedef ssize_t Py_ssize_t;
typedef int PyGILState_STATE;

#define PY_FUNCTIONS(X)                                                        \
    X(int, Py_IsInitialized, (void))                                           \
    X(void, Py_InitializeEx, (int))                                            \
    X(void *, PyEval_SaveThread, (void))                                       \
    X(PyGILState_STATE, PyGILState_Ensure, (void))                             \
    X(void, PyGILState_Release, (PyGILState_STATE))                            \
    X(void, Py_IncRef, (PyObject *))                                           \
    X(void, Py_DecRef, (PyObject *))                                           \
    X(PyObject *, Py_BuildValue, (const char *, ...))                          \
    X(PyObject *, PyImport_ImportModule, (const char *))                       \
    X(PyObject *, PyObject_GetAttrString, (PyObject *, const char *))          \
    X(PyObject *, PyObject_CallObject, (PyObject *, PyObject *))               \
    X(PyObject *, PyObject_Str, (PyObject *))                                  \
    X(PyObject *, PyDict_GetItemString, (PyObject *, const char *))            \
    X(PyObject *, PyTuple_New, (Py_ssize_t))                                   \
    X(int, PyTuple_SetItem, (PyObject *, Py_ssize_t, PyObject *))              \
    X(PyObject *, PyTuple_GetItem, (PyObject *, Py_ssize_t))                   \
    X(Py_ssize_t, PyTuple_Size, (PyObject *))                                  \
    X(Py_ssize_t, PyList_Size, (PyObject *))                                   \
    X(PyObject *, PyList_GetItem, (PyObject *, Py_ssize_t))                    \
    X(PyObject *, PyLong_FromLong, (long))                                     \
    X(PyObject *, PyLong_FromUnsignedLong, (unsigned long))                    \
    X(long, PyLong_AsLong, (PyObject *))                                       \
    X(PyObject *, PyFloat_FromDouble, (double))                                \
    X(double, PyFloat_AsDouble, (PyObject *))                                  \
    X(PyObject *, PyBytes_FromStringAndSize, (const char *, Py_ssize_t))       \
    X(int, PyBytes_AsStringAndSize, (PyObject *, char **, Py_ssize_t *))       \
    X(PyObject *, PyUnicode_AsUTF8String, (PyObject *))                        \
    X(void *, PyLong_AsVoidPtr, (PyObject *))                                  \
    X(PyObject *, PyErr_Occurred, (void))                                      \
    X(void, PyErr_Fetch, (PyObject **, PyObject **, PyObject **))              \
    X(void, PyErr_Clear, (void))

#define DECLARE(ret, name, args) ret (*name) args;
static struct { PY_FUNCTIONS(DECLARE) } py;   /* filled once per process, then read-only */
#undef DECLARE

static pthread_mutex_t python_lock = PTHREAD_MUTEX_INITIALIZER;
static int python_ready;            /* py is complete and Python is initialized */
static int python_started_here;     /* this library called Py_InitializeEx */

/* ---- instances and states ------------------------------------------------------------- */

#define INSTANCE_MAGIC 0x6d62646eu  /* "mbdn": tells our instances from stray pointers */
#define STATE_MAGIC 0x6d626473u     /* "mbds" */
#define MAX_NVR (1u << 24)          /* more value references than any FMU of ours has */
#define MESSAGE_SIZE 2048

typedef enum {
    M_REJECT, M_SET_DEBUG_LOGGING, M_SETUP_EXPERIMENT, M_ENTER_INIT, M_EXIT_INIT, M_TERMINATE,
    M_RESET, M_FREE, M_GET, M_SET, M_DO_STEP, M_CANCEL_STEP, M_GET_STATUS, M_GET_STATE,
    M_SET_STATE, M_SERIALIZE, M_DESERIALIZE, M_DIRECTIONAL, M_SET_INPUT_DER, M_GET_OUTPUT_DER,
    M_ENTER_INIT3, M_DO_STEP3, M_SYNC, M_TAKE_LOG, N_METHODS
} Method;

static const char *const METHOD_NAMES[N_METHODS] = {
    "fmi2_reject", "fmi2_set_debug_logging", "fmi2_setup_experiment",
    "fmi2_enter_initialization_mode", "fmi2_exit_initialization_mode", "fmi2_terminate",
    "fmi2_reset", "fmi2_free_instance", "fmi2_get", "fmi2_set", "fmi2_do_step",
    "fmi2_cancel_step", "fmi2_get_status", "fmi2_get_fmu_state", "fmi2_set_fmu_state",
    "fmi2_serialize_fmu_state", "fmi2_deserialize_fmu_state",
    "fmi2_get_directional_derivative", "fmi2_set_real_input_derivatives",
    "fmi2_get_real_output_derivatives", "fmi3_enter_initialization_mode", "fmi3_do_step",
    "fmi_sync", "take_log",
};

typedef struct Instance Instance;
/* Pass one message to the host's logger (each wrapper's own logger signature). */
typedef void (*Emit)(const Instance *in, int status, const char *category, const char *text);

struct Instance {
    unsigned magic;
    char *name;
    Emit emit;
    void *logger;                   /* the host's logger function (cast by `emit`) */
    void *environment;              /* the host's pointer passed back to it */
    PyObject *methods[N_METHODS];   /* bound methods of the slave, looked up once */
    PyObject *log_queue;            /* the slave's list of pending messages */
    char **strings;                 /* GetString results: valid until the next call */
    size_t n_strings;
    int fatal;                      /* the runtime broke its contract: only free is left */
    /* the slave's Real values, served by GetReal / GetFloat64 without Python while
     * *fast_valid (runtime/real_cache.py): set by the slave after a step, cleared by every
     * other call */
    const double *fast_values;
    const unsigned char *fast_mask;
    const unsigned char *fast_kept;   /* those still served after fast_set (may be NULL) */
    volatile int64_t *fast_valid;
    size_t fast_count;
    /* the slave's FastSteps block (runtime/real_cache.py): enabled, a step function and
     * its two context pointers; fmi2DoSteps it takes leave the slave behind
     * (fast_pending) until it catches up (M_SYNC) before any other call; fmi2SetReal taken
     * by its set function (fast_set) sends gets through Python until the next step, but
     * those of values the set leaves as they are (fast_kept) */
    int64_t *fast_step;
    int fast_pending;
    int fast_set;
    /* FMI 3.0: the independent variable's value reference (-1: none), whose value a step
     * taken here sets to t + h as the slave's step sets it */
    long fast_time;
};

/* runtime/real_cache.py FastSteps: 0 when it took the step and refreshed values. */
typedef int (*FastStepFunction)(const void *model, void *context, double t, double h,
                                double *values);
/* ... and 0 when it applied every value set (inputs the step function reads). */
typedef int (*FastSetFunction)(void *context, const unsigned int *vr, size_t nvr,
                               const double *value, double *values);

typedef struct {
    unsigned magic;
    PyObject *state;        /* the runtime's FmuState */
    PyObject *serialized;   /* bytes, kept between SerializedFMUstateSize and Serialize */
} StateHandle;

/* ---- logging -------------------------------------------------------------------------- */

/* printf-style message to the instance's logger (cut at MESSAGE_SIZE). */
__attribute__((format(printf, 4, 5)))
static void log_instance(const Instance *in, int status, const char *category,
                         const char *format, ...) {
    char text[MESSAGE_SIZE];
    va_list args;
    va_start(args, format);
    vsnprintf(text, sizeof text, format, args);
    va_end(args);
    if (in->emit) in->emit(in, status, category, text);
}

/* Text of the pending Python exception (cleared), into buf. Needs the GIL. */
static void exception_text(char *buf, size_t size) {
    PyObject *type = NULL, *value = NULL, *trace = NULL, *str = NULL, *bytes = NULL;
    char *data = NULL;
    Py_ssize_t n = 0;
    snprintf(buf, size, "unknown Python error");
    py.PyErr_Fetch(&type, &value, &trace);
    if (value && (str = py.PyObject_Str(value)) && (bytes = py.PyUnicode_AsUTF8String(str))
        && py.PyBytes_AsStringAndSize(bytes, &data, &n) == 0)
        snprintf(buf, size, "%.*s", (int)(n < (Py_ssize_t)size ? n : (Py_ssize_t)size - 1), data);
    py.PyErr_Clear();
    PyObject *refs[] = {type, value, trace, str, bytes};
    for (size_t i = 0; i < sizeof refs / sizeof *refs; i++)
        if (refs[i]) py.Py_DecRef(refs[i]);
}

/* Hand the slave's queued messages (status, category, text) to the host's logger. */
static void forward_log(Instance *in) {
    if (!in->log_queue || py.PyList_Size(in->log_queue) <= 0) return;
    PyObject *messages = py.PyObject_CallObject(in->methods[M_TAKE_LOG], NULL);
    if (!messages) { py.PyErr_Clear(); return; }
    for (Py_ssize_t i = 0; i < py.PyList_Size(messages); i++) {
        PyObject *m = py.PyList_GetItem(messages, i);   /* borrowed */
        PyObject *category = py.PyUnicode_AsUTF8String(py.PyTuple_GetItem(m, 1));
        PyObject *text = py.PyUnicode_AsUTF8String(py.PyTuple_GetItem(m, 2));
        char *c = NULL, *t = NULL;
        Py_ssize_t n;
        long status = py.PyLong_AsLong(py.PyTuple_GetItem(m, 0));
        if (category && text && py.PyBytes_AsStringAndSize(category, &c, &n) == 0
            && py.PyBytes_AsStringAndSize(text, &t, &n) == 0)
            in->emit(in, (int)status, c, t);
        if (category) py.Py_DecRef(category);
        if (text) py.Py_DecRef(text);
        py.PyErr_Clear();
    }
    py.Py_DecRef(messages);
}

/* The string value of "key" in a flat JSON object (escapes \" \\ \/ only), or 0. */
static int json_string(const char *json, const char *key, char *out, size_t size) {
    char pattern[64];
    snprintf(pattern, sizeof pattern, "\"%s\"", key);
    const char *p = strstr(json, pattern);
    if (!p) return 0;
    p += strlen(pattern);
    while (*p == ' ' || *p == '\n' || *p == '\t' || *p == '\r' || *p == ':') p++;
    if (*p++ != '"') return 0;          /* null or not a string */
    size_t n = 0;
    for (; *p && *p != '"'; p++) {
        if (*p == '\\') {
            p++;
            if (*p != '"' && *p != '\\' && *p != '/') return 0;
        }
        if (n + 1 >= size) return 0;
        out[n++] = *p;
    }
    out[n] = '\0';
    return *p == '"';
}

/* The whole of a small text file, NUL-terminated (malloc'd), or NULL. */
static char *read_file(const char *path) {
    FILE *f = fopen(path, "rb");
    if (!f) return NULL;
    char *text = NULL;
    long size = fseek(f, 0, SEEK_END) == 0 ? ftell(f) : -1;
    if (size >= 0 && size < (1 << 24) && fseek(f, 0, SEEK_SET) == 0 && (text = malloc(size + 1))) {
        if (fread(text, 1, (size_t)size, f) != (size_t)size) { free(text); text = NULL; }
        else text[size] = '\0';
    }
    fclose(f);
    return text;
}

/* Fill `py` from `handle`; the name of the first missing function, or NULL. */
static const char *resolve(void *handle) {
#define RESOLVE(ret, name, args) \
    if (!(*(void **)&py.name = dlsym(handle, #name))) return #name;
    PY_FUNCTIONS(RESOLVE)
#undef RESOLVE
    return NULL;
}

/* Tell an interpreter we start where its standard library is. Without it, CPython looks
 * for "python3" on PATH and may take another installation's library (Debian's /usr).
 * PYTHONHOME, when the host sets it, wins. Py_SetPythonHome is deprecated since 3.11 but
 * present up to 3.13; without it the interpreter searches as usual. */
static void set_home(void *handle, const char *home) {
    static wchar_t *wide;   /* Python keeps the pointer: never freed */
    void (*set)(const wchar_t *) = (void (*)(const wchar_t *))dlsym(handle, "Py_SetPythonHome");
    wchar_t *(*decode)(const char *, size_t *) =
        (wchar_t *(*)(const char *, size_t *))dlsym(handle, "Py_DecodeLocale");
    if (!*home || getenv("PYTHONHOME") || !set || !decode || wide) return;
    if ((wide = decode(home, NULL))) set(wide);
}

/* Make Python usable in this process (see the top of the file); on failure, a message in
 * `error` saying what is missing and how to fix it. Thread-safe: hosts may instantiate
 * from several threads. */
static int ensure_python(const char *resources, const char *function, char *error,
                         size_t size) {
    pthread_mutex_lock(&python_lock);
    if (python_ready) { pthread_mutex_unlock(&python_lock); return 1; }
    int (*is_initialized)(void) = (int (*)(void))dlsym(RTLD_DEFAULT, "Py_IsInitialized");
    void *handle = RTLD_DEFAULT;     /* NULL in glibc: `found` says whether we have one */
    int found = 1;
    char library[4096] = "", home[4096] = "", config_path[4200], version[64] = "3";
    snprintf(config_path, sizeof config_path, "%s/mbdfmu.json", resources);
    char *config = read_file(config_path);
    if (config) json_string(config, "python_version", version, sizeof version);
    if (!is_initialized || !is_initialized()) {
        const char *env = getenv("MBDFMU_PYTHON_LIBRARY"), *env_home = getenv("MBDFMU_PYTHON_HOME");
        if (env && *env) snprintf(library, sizeof library, "%s", env);
        else if (config && json_string(config, "python_library", library, sizeof library))
            json_string(config, "python_home", home, sizeof home);   /* the recorded pair */
        if (env_home && *env_home) snprintf(home, sizeof home, "%s", env_home);
        found = 0;
        if (!*library)
            snprintf(error, size, "%s: this FMU runs Python %s and no Python library was "
                     "recorded at build time: set MBDFMU_PYTHON_LIBRARY to the path of a "
                     "libpython3.X.so.1.0 (CPython 3.10+ with numpy)", function, version);
        else if ((handle = dlopen(library, RTLD_NOW | RTLD_GLOBAL)))
            found = 1;
        else
            snprintf(error, size, "%s: cannot load the Python library %s (%s): set "
                     "MBDFMU_PYTHON_LIBRARY to the libpython3.X.so.1.0 of a CPython 3.10+ with "
                     "numpy (the FMU was built with Python %s)", function, library, dlerror(),
                     version);
    }
    free(config);
    const char *missing = found ? resolve(handle) : "";
    if (found && missing)
        snprintf(error, size, "%s: the Python library %s lacks %s: set MBDFMU_PYTHON_LIBRARY "
                 "to a CPython 3.10+ libpython", function, *library ? library
                 : "of this process", missing);
    if (found && !missing) {
        if (!py.Py_IsInitialized()) {
            set_home(handle, home);
            py.Py_InitializeEx(0);
            py.PyEval_SaveThread();     /* release the GIL: every call takes it */
            python_started_here = 1;
        }
        python_ready = 1;
    }
    pthread_mutex_unlock(&python_lock);
    return python_ready;
}

/* ---- calling the slave ------------------------------------------------------------------- */

static Instance *as_instance(void *c) {
    Instance *in = (Instance *)c;
    return in && in->magic == INSTANCE_MAGIC ? in : NULL;
}

static void free_strings(Instance *in) {
    for (size_t i = 0; i < in->n_strings; i++) free(in->strings[i]);
    free(in->strings);
    in->strings = NULL;
    in->n_strings = 0;
}

/* Start of every call on an instance: the previous GetString results expire. */
static Instance *begin(void *c) {
    Instance *in = as_instance(c);
    if (in) free_strings(in);
    return in;
}

/* Call method m with args (a new reference, stolen; NULL means building it failed).
 * Returns the status; *payload (optional) receives a new reference to the second item.
 * Needs the GIL. */
static int call(Instance *in, Method m, PyObject *args, PyObject **payload) {
    char text[MESSAGE_SIZE / 2];
    if (payload) *payload = NULL;
    if (in->fatal) {
        if (args) py.Py_DecRef(args);
        log_instance(in, ST_FATAL, "logStatusFatal", "%s refused: the FMU's Python runtime "
                     "failed earlier; only FreeInstance is possible", METHOD_NAMES[m]);
        return ST_FATAL;
    }
    if (in->fast_pending) {         /* the slave catches up with the steps taken here */
        in->fast_pending = 0;
        in->fast_set = 0;
        int synced = call(in, M_SYNC, py.Py_BuildValue("()"), NULL);
        if (synced != ST_OK) {
            if (args) py.Py_DecRef(args);
            return synced;
        }
    }
    if (in->fast_valid && m != M_GET && m != M_SYNC) *in->fast_valid = 0;  /* may change */
    PyObject *result = args ? py.PyObject_CallObject(in->methods[m], args) : NULL;
    if (args) py.Py_DecRef(args);
    long status = -1;
    if (result && py.PyTuple_Size(result) == 2)
        status = py.PyLong_AsLong(py.PyTuple_GetItem(result, 0));
    if (status < ST_OK || status > ST_PENDING || py.PyErr_Occurred()) {
        exception_text(text, sizeof text);
        in->fatal = 1;
        if (result) py.Py_DecRef(result);
        forward_log(in);
        log_instance(in, ST_FATAL, "logStatusFatal", "the FMU's Python runtime broke its "
                     "protocol (a bug in mbdfmu): %s", text);
        return ST_FATAL;
    }
    if (payload) {
        *payload = py.PyTuple_GetItem(result, 1);
        py.Py_IncRef(*payload);
    }
    py.Py_DecRef(result);
    forward_log(in);
    return (int)status;
}

/* A call the wrapper refuses itself (NULL pointer, non-finite number, unsupported
 * function): the slave logs the reason and enters its Error state. Needs the GIL. */
static int reject(Instance *in, const char *function, const char *reason) {
    return call(in, M_REJECT, py.Py_BuildValue("(ss)", function, reason), NULL);
}

/* Python may have been finalized by a Python host that exits before freeing us. */
static int python_alive(void) {
    return python_ready && py.Py_IsInitialized();
}

/* The usual frame of an FMI call on an instance: valid instance, live Python, GIL held. */
#define ENTER(c)                                                   \
    Instance *in = begin(c);                                       \
    if (!in || !python_alive()) return ST_ERROR;                   \
    PyGILState_STATE gil = py.PyGILState_Ensure();                 \
    int status
#define LEAVE()                                                    \
    py.PyGILState_Release(gil);                                    \
    return status

/* The FMI functions that pass nothing but the instance. */
static int call_without_arguments(void *c, Method m) {
    ENTER(c);
    status = call(in, m, py.Py_BuildValue("()"), NULL);
    LEAVE();
}

/* A function this FMU does not provide (its capability flag is false): Error, logged. */
__attribute__((unused))
static int unsupported(void *c, const char *function, const char *reason) {
    ENTER(c);
    status = reject(in, function, reason);
    LEAVE();
}

/* A tuple of Python ints from value references (NULL on failure). */
static PyObject *vr_tuple(const unsigned int vr[], size_t n) {
    PyObject *t = py.PyTuple_New((Py_ssize_t)n);
    for (size_t i = 0; t && i < n; i++)
        py.PyTuple_SetItem(t, (Py_ssize_t)i, py.PyLong_FromUnsignedLong(vr[i]));
    return t && py.PyErr_Occurred() ? (py.Py_DecRef(t), NULL) : t;
}

/* nvr > 0 needs both arrays; also caps nvr. The reason, or NULL if fine. */
static const char *array_problem(size_t nvr, const void *vr, const void *values) {
    if (nvr > MAX_NVR) return "nvr is larger than any variable table";
    if (nvr > 0 && !vr) return "vr is NULL";
    if (nvr > 0 && !values) return "the value array is NULL";
    return NULL;
}

static PyObject *real_tuple(const double *x, size_t n) {
    PyObject *t = py.PyTuple_New((Py_ssize_t)n);
    for (size_t i = 0; t && i < n; i++)
        py.PyTuple_SetItem(t, (Py_ssize_t)i, py.PyFloat_FromDouble(x[i]));
    return t;
}

static PyObject *int_tuple(const int *x, size_t n) {
    PyObject *t = py.PyTuple_New((Py_ssize_t)n);
    for (size_t i = 0; t && i < n; i++)
        py.PyTuple_SetItem(t, (Py_ssize_t)i, py.PyLong_FromLong(x[i]));
    return t;
}

/* Copy n floats out of a Python tuple; 0 if it is not one of n numbers. Needs the GIL. */
static int copy_reals(PyObject *payload, double *out, size_t n) {
    if (py.PyTuple_Size(payload) != (Py_ssize_t)n) { py.PyErr_Clear(); return 0; }
    for (size_t i = 0; i < n; i++)
        out[i] = py.PyFloat_AsDouble(py.PyTuple_GetItem(payload, (Py_ssize_t)i));
    return !py.PyErr_Occurred();
}

/* The protocol was broken after a call returned: mark the instance, say why. */
static int protocol_error(Instance *in, const char *function) {
    char text[MESSAGE_SIZE / 2];
    exception_text(text, sizeof text);
    in->fatal = 1;
    log_instance(in, ST_FATAL, "logStatusFatal", "%s: the FMU's Python runtime returned "
                 "values of the wrong kind (a bug in mbdfmu): %s", function, text);
    return ST_FATAL;
}

/* ---- getting and setting values -------------------------------------------------------- */

/* How a value of an FMI type sits in the caller's array. K_NONE: a type this runtime has
 * no variables of (the slave refuses every value reference of it). */
typedef enum { K_REAL, K_INT32, K_INT_BOOL, K_C_BOOL, K_STRING, K_NONE } Kind;

/* Copy the slave's values into the caller's array; 0 if the payload is not n values of
 * the kind. Strings are copied into the instance (valid until its next call). */
static int copy_out(Instance *in, Kind kind, PyObject *payload, void *values, size_t n) {
    if (py.PyTuple_Size(payload) != (Py_ssize_t)n) return 0;
    if (kind == K_REAL) return copy_reals(payload, values, n);
    if (kind == K_STRING && !(in->strings = calloc(n ? n : 1, sizeof(char *)))) return 0;
    for (size_t i = 0; i < n; i++) {
        PyObject *item = py.PyTuple_GetItem(payload, (Py_ssize_t)i);
        if (kind == K_STRING) {
            char *data = NULL;
            Py_ssize_t size = 0;
            if (py.PyBytes_AsStringAndSize(item, &data, &size) != 0) return 0;
            if (!(in->strings[i] = malloc((size_t)size + 1))) return 0;
            memcpy(in->strings[i], data, (size_t)size + 1);
            in->n_strings = i + 1;
            ((const char **)values)[i] = in->strings[i];
        } else if (kind == K_INT32) {
            ((int32_t *)values)[i] = (int32_t)py.PyLong_AsLong(item);
        } else if (kind == K_INT_BOOL) {
            ((int *)values)[i] = py.PyLong_AsLong(item) ? 1 : 0;
        } else {
            ((bool *)values)[i] = py.PyLong_AsLong(item) ? true : false;
        }
    }
    return !py.PyErr_Occurred();
}

/* GetReal / GetFloat64 without Python: every vr a Real variable while the slave's values
 * are valid (see Instance), and after an input set here only those the set leaves as
 * they are; 0 when Python must answer. */
static int fast_get_real(void *c, const unsigned int vr[], size_t nvr, double value[]) {
    Instance *in = as_instance(c);
    if (!in || in->fatal || !in->fast_valid || !*in->fast_valid
        || (in->fast_set && !in->fast_kept)
        || !python_alive() || nvr > MAX_NVR || (nvr > 0 && (!vr || !value)))
        return 0;
    for (size_t i = 0; i < nvr; i++)
        if (vr[i] >= in->fast_count || !in->fast_mask[vr[i]]
            || (in->fast_set && !in->fast_kept[vr[i]]))
            return 0;
    free_strings(in);
    for (size_t i = 0; i < nvr; i++) value[i] = in->fast_values[vr[i]];
    return 1;
}

/* Get{type}: `function` names the FMI function in messages, `type` the slave's type name. */
static int get_values(void *c, const char *function, const char *type, Kind kind,
                      const unsigned int vr[], size_t nvr, void *values) {
    ENTER(c);
    PyObject *payload = NULL;
    const char *problem = array_problem(nvr, vr, values);
    if (problem) { status = reject(in, function, problem); LEAVE(); }
    status = call(in, M_GET, py.Py_BuildValue("(sN)", type, vr_tuple(vr, nvr)), &payload);
    /* (skipped entries come back as NaN, 0, false, "": copied too) */
    if (payload && kind != K_NONE && !copy_out(in, kind, payload, values, nvr))
        status = protocol_error(in, function);
    if (payload) py.Py_DecRef(payload);
    LEAVE();
}

/* The caller's values as a tuple (String: bytes); NULL with *problem set for a NULL
 * string. K_NONE passes None for each (the slave refuses them by value reference). */
static PyObject *values_in(Kind kind, const void *values, size_t n, const char **problem) {
    if (kind == K_REAL) return real_tuple(values, n);
    PyObject *t = py.PyTuple_New((Py_ssize_t)n);
    for (size_t i = 0; t && i < n; i++) {
        PyObject *item;
        if (kind == K_STRING) {
            const char *s = ((const char *const *)values)[i];
            if (!s) { *problem = "a string in value[] is NULL"; py.Py_DecRef(t); return NULL; }
            item = py.PyBytes_FromStringAndSize(s, (Py_ssize_t)strlen(s));
        } else if (kind == K_INT32) {
            item = py.PyLong_FromLong(((const int32_t *)values)[i]);
        } else if (kind == K_INT_BOOL) {
            item = py.PyLong_FromLong(((const int *)values)[i]);
        } else if (kind == K_C_BOOL) {
            item = py.PyLong_FromLong(((const bool *)values)[i] ? 1 : 0);
        } else {
            item = py.Py_BuildValue("()");
        }
        py.PyTuple_SetItem(t, (Py_ssize_t)i, item);
    }
    return t;
}

static int set_values(void *c, const char *function, const char *type, Kind kind,
                      const unsigned int vr[], size_t nvr, const void *values) {
    ENTER(c);
    PyObject *items = NULL;
    const char *problem = array_problem(nvr, vr, values);
    if (!problem) items = values_in(kind, values, nvr, &problem);
    if (problem) { status = reject(in, function, problem); LEAVE(); }
    status = call(in, M_SET, py.Py_BuildValue("(sNN)", type, vr_tuple(vr, nvr), items), NULL);
    LEAVE();
}

/* ---- instances ----------------------------------------------------------------------------- */

/* The slave's RealCache addresses (its attribute fast_real: values, mask, valid flag,
 * count); none (no fast path) when it has no such attribute. Needs the GIL. */
static void fast_real(Instance *in, PyObject *slave) {
    PyObject *t = py.PyObject_GetAttrString(slave, "fast_real");
    Py_ssize_t size = t ? py.PyTuple_Size(t) : -1;
    if (size == 4 || size == 5) {
        void *values = py.PyLong_AsVoidPtr(py.PyTuple_GetItem(t, 0));
        void *mask = py.PyLong_AsVoidPtr(py.PyTuple_GetItem(t, 1));
        void *valid = py.PyLong_AsVoidPtr(py.PyTuple_GetItem(t, 2));
        long count = py.PyLong_AsLong(py.PyTuple_GetItem(t, 3));
        void *kept = size == 5 ? py.PyLong_AsVoidPtr(py.PyTuple_GetItem(t, 4)) : NULL;
        if (!py.PyErr_Occurred() && values && mask && valid && count >= 0) {
            in->fast_values = values;
            in->fast_mask = mask;
            in->fast_valid = valid;
            in->fast_count = (size_t)count;
            in->fast_kept = kept;
        }
    }
    if (t) py.Py_DecRef(t);
    py.PyErr_Clear();
    if (!in->fast_valid) return;
    PyObject *time = py.PyObject_GetAttrString(slave, "fast_time");
    long vr = time ? py.PyLong_AsLong(time) : -1;
    if (time) py.Py_DecRef(time);
    if (py.PyErr_Occurred() || vr < 0 || (size_t)vr >= in->fast_count || !in->fast_mask[vr])
        vr = -1;
    py.PyErr_Clear();
    in->fast_time = vr;
    PyObject *block = py.PyObject_GetAttrString(slave, "fast_step");
    void *address = block ? py.PyLong_AsVoidPtr(block) : NULL;
    if (!py.PyErr_Occurred() && address) in->fast_step = address;
    if (block) py.Py_DecRef(block);
    py.PyErr_Clear();
}

/* fmi2DoStep / fmi3DoStep taken by the slave's FastSteps function without Python (the
 * Real values valid: nothing called since the last step but gets); 1 when it did. */
static int fast_do_step(void *c, double t, double h) {
    Instance *in = as_instance(c);
    if (!in || in->fatal || !in->fast_step || !in->fast_valid || !*in->fast_valid
        || !in->fast_step[0] || !isfinite(t) || !isfinite(h) || !(h > 0) || !python_alive())
        return 0;
    FastStepFunction step = (FastStepFunction)(intptr_t)in->fast_step[1];
    if (step((const void *)(intptr_t)in->fast_step[2], (void *)(intptr_t)in->fast_step[3], t, h,
             (double *)in->fast_values) != 0)
        return 0;
    if (in->fast_time >= 0) ((double *)in->fast_values)[in->fast_time] = t + h;
    free_strings(in);
    in->fast_pending = 1;
    in->fast_set = 0;
    in->fast_step[4]++;
    return 1;
}

/* fmi2SetReal / fmi3SetFloat64 taken by the slave's FastSteps set function without
 * Python (the fast steps armed, nothing called since the last step but gets, sets and
 * such steps); 1 when it did. The slave learns the values when it catches up; gets go
 * through Python until the next step (the values that follow inputs are the slave's to
 * compute). */
static int fast_set_real(void *c, const unsigned int vr[], size_t nvr, const double value[]) {
    Instance *in = as_instance(c);
    if (!in || in->fatal || !in->fast_step || !in->fast_valid || !*in->fast_valid
        || !in->fast_step[0] || !in->fast_step[5] || nvr > MAX_NVR || (nvr > 0 && (!vr || !value))
        || !python_alive())
        return 0;
    FastSetFunction set = (FastSetFunction)(intptr_t)in->fast_step[5];
    if (set((void *)(intptr_t)in->fast_step[3], vr, nvr, value, (double *)in->fast_values) != 0)
        return 0;
    free_strings(in);
    in->fast_pending = 1;
    in->fast_set = 1;
    return 1;
}

/* Build the slave through resources/mbdfmu_boot.py; NULL with `error` filled on failure.
 * `function` names the instantiating FMI function in messages. Needs the GIL. */
static Instance *create(const char *name, const char *guid, const char *resources,
                        int logging_on, const char *function, char *error, size_t size) {
    char boot_path[4200];
    Instance *in = calloc(1, sizeof *in);
    PyObject *runpy = NULL, *run_path = NULL, *globals = NULL, *result = NULL, *bytes = NULL;
    char *message = NULL;
    Py_ssize_t length = -1;
    snprintf(boot_path, sizeof boot_path, "%s/mbdfmu_boot.py", resources);
    if (in && (in->name = strdup(name))
        && (runpy = py.PyImport_ImportModule("runpy"))
        && (run_path = py.PyObject_GetAttrString(runpy, "run_path"))
        && (globals = py.PyObject_CallObject(run_path, py.Py_BuildValue("(s)", boot_path)))) {
        PyObject *boot = py.PyDict_GetItemString(globals, "boot");   /* borrowed */
        PyObject *args = py.Py_BuildValue("(sssii)", resources, name, guid, logging_on,
                                          python_started_here);
        result = boot && args ? py.PyObject_CallObject(boot, args) : NULL;
        if (args) py.Py_DecRef(args);
    }
    if (result && py.PyTuple_Size(result) == 2
        && (bytes = py.PyUnicode_AsUTF8String(py.PyTuple_GetItem(result, 1))))
        py.PyBytes_AsStringAndSize(bytes, &message, &length);
    if (length > 0)
        snprintf(error, size, "%s", message);
    else if (length < 0) {
        char text[MESSAGE_SIZE / 2];
        exception_text(text, sizeof text);
        snprintf(error, size, "%s: cannot run %.500s: %s", function, boot_path, text);
    } else {
        PyObject *slave = py.PyTuple_GetItem(result, 0);   /* borrowed */
        for (int m = 0; m < N_METHODS && length == 0; m++)
            if (!(in->methods[m] = py.PyObject_GetAttrString(slave, METHOD_NAMES[m])))
                length = -1;
        if (length == 0 && (in->log_queue = py.PyObject_GetAttrString(slave, "log_queue"))) {
            in->magic = INSTANCE_MAGIC;
            fast_real(in, slave);
        }
        else
            snprintf(error, size, "%s: the model's slave lacks a protocol method of this "
                     "wrapper (%s ...)", function, METHOD_NAMES[N_METHODS - 1]);
    }
    PyObject *refs[] = {runpy, run_path, globals, result, bytes};
    for (size_t i = 0; i < sizeof refs / sizeof *refs; i++)
        if (refs[i]) py.Py_DecRef(refs[i]);
    py.PyErr_Clear();
    if (in && in->magic != INSTANCE_MAGIC) {
        for (int m = 0; m < N_METHODS; m++)
            if (in->methods[m]) py.Py_DecRef(in->methods[m]);
        free(in->name);
        free(in);
        in = NULL;
    }
    return in;
}

/* Python ready, then the slave of the FMU in `resources`; NULL with `error` set. The
 * caller logs the error with its own logger. */
static Instance *instantiate(const char *name, const char *guid, const char *resources,
                             int logging_on, const char *function, Emit emit, void *logger,
                             void *environment, char *error, size_t size) {
    Instance *in = NULL;
    if (ensure_python(resources, function, error, size)) {
        PyGILState_STATE gil = py.PyGILState_Ensure();
        in = create(name, guid, resources, logging_on, function, error, size);
        if (in) {
            in->emit = emit;
            in->logger = logger;
            in->environment = environment;
            forward_log(in);
        }
        py.PyGILState_Release(gil);
    }
    return in;
}

static void free_instance(void *c) {
    Instance *in = begin(c);
    if (!in) return;
    if (python_alive()) {   /* else the host finalized Python: its objects are gone */
        PyGILState_STATE gil = py.PyGILState_Ensure();
        if (!in->fatal) call(in, M_FREE, py.Py_BuildValue("()"), NULL);
        for (int m = 0; m < N_METHODS; m++) py.Py_DecRef(in->methods[m]);
        py.Py_DecRef(in->log_queue);
        py.PyGILState_Release(gil);
    }
    in->magic = 0;
    free(in->name);
    free(in);
}

static int set_debug_logging(void *c, const char *function, int logging_on, size_t n,
                             const char *const categories[]) {
    ENTER(c);
    PyObject *names = NULL;
    const char *problem = array_problem(n, categories, categories);
    for (size_t i = 0; !problem && i < n; i++)
        if (!categories[i]) problem = "a category is NULL";
    if (problem) { status = reject(in, function, problem); LEAVE(); }
    names = py.PyTuple_New((Py_ssize_t)n);
    for (size_t i = 0; names && i < n; i++)
        py.PyTuple_SetItem(names, (Py_ssize_t)i, py.PyBytes_FromStringAndSize(
            categories[i], (Py_ssize_t)strlen(categories[i])));
    status = call(in, M_SET_DEBUG_LOGGING, py.Py_BuildValue("(iN)", logging_on, names), NULL);
    LEAVE();
}

/* SetupExperiment (FMI 2.0) or EnterInitializationMode (FMI 3.0, method m): the times and
 * tolerance, checked finite. */
static int experiment(void *c, Method m, const char *function, int tolerance_defined,
                      double tolerance, double start, int stop_defined, double stop) {
    ENTER(c);
    if (!isfinite(start) || (stop_defined && !isfinite(stop))
        || (tolerance_defined && !isfinite(tolerance)))
        status = reject(in, function, "startTime, stopTime and tolerance must be finite numbers");
    else
        status = call(in, m, py.Py_BuildValue("(iddid)", tolerance_defined, tolerance, start,
                      stop_defined, stop), NULL);
    LEAVE();
}

/* DoStep's arguments checked (the wrapper's own refusal), then method m (FMI 2.0: no
 * payload; FMI 3.0: (terminate, lastSuccessfulTime), whose fmi3DoStep tries
 * fast_do_step itself to set its outputs). */
static int do_step(void *c, Method m, const char *function, double t, double h,
                   int no_set_prior, PyObject **payload) {
    if (!payload && fast_do_step(c, t, h)) return ST_OK;
    ENTER(c);
    char reason[200];
    if (payload) *payload = NULL;
    if (!isfinite(t)) {
        snprintf(reason, sizeof reason, "currentCommunicationPoint = %g is not finite", t);
        status = reject(in, function, reason);
    } else if (!isfinite(h) || h <= 0) {
        snprintf(reason, sizeof reason, "communicationStepSize = %g must be positive and "
                 "finite", h);
        status = reject(in, function, reason);
    } else {
        status = call(in, m, py.Py_BuildValue("(ddi)", t, h, no_set_prior), payload);
    }
    LEAVE();
}

/* ---- FMU states ---------------------------------------------------------------------------- */

static StateHandle *as_state(void *s) {
    StateHandle *h = (StateHandle *)s;
    return h && h->magic == STATE_MAGIC ? h : NULL;
}

/* Put the runtime's state object (a new reference, stolen) into *state: into the handle
 * it points to when that is one of ours (the master may pass a handle back to be reused),
 * else into a new one. Needs the GIL. */
static int store_state(PyObject *object, void **state) {
    StateHandle *h = as_state(*state);
    if (!h && !(h = calloc(1, sizeof *h))) { py.Py_DecRef(object); return ST_FATAL; }
    if (h->state) py.Py_DecRef(h->state);
    if (h->serialized) py.Py_DecRef(h->serialized);
    h->magic = STATE_MAGIC;
    h->state = object;
    h->serialized = NULL;
    *state = h;
    return ST_OK;
}

/* `function` names the FMI function (fmi2GetFMUstate, fmi3GetFMUState) in messages. */
static int get_state(void *c, const char *function, void **state) {
    ENTER(c);
    PyObject *object = NULL;
    if (!state) { status = reject(in, function, "FMUstate is NULL"); LEAVE(); }
    status = call(in, M_GET_STATE, py.Py_BuildValue("()"), &object);
    if (status == ST_OK && object) status = store_state(object, state);
    else if (object) py.Py_DecRef(object);
    LEAVE();
}

static int set_state(void *c, const char *function, void *state) {
    ENTER(c);
    StateHandle *h = as_state(state);
    if (!h) status = reject(in, function, "FMUstate is NULL or not an FMU state");
    else status = call(in, M_SET_STATE, py.Py_BuildValue("(O)", h->state), NULL);
    LEAVE();
}

static int free_state(void *c, const char *function, void **state) {
    ENTER(c);
    StateHandle *h = state ? as_state(*state) : NULL;
    if (!state || (*state && !h)) {
        status = reject(in, function, "FMUstate is NULL or not an FMU state");
        LEAVE();
    }
    status = ST_OK;
    if (h) {
        py.Py_DecRef(h->state);
        if (h->serialized) py.Py_DecRef(h->serialized);
        h->magic = 0;
        free(h);
        *state = NULL;
    }
    LEAVE();
}

/* The handle's serialized bytes, made once; NULL (status in *status) on failure. */
static PyObject *serialized(Instance *in, StateHandle *h, int *status) {
    PyObject *bytes = NULL;
    if (h->serialized) return h->serialized;
    *status = call(in, M_SERIALIZE, py.Py_BuildValue("(O)", h->state), &bytes);
    if (*status == ST_OK && bytes) return h->serialized = bytes;
    if (bytes) py.Py_DecRef(bytes);
    return NULL;
}

/* The serialized bytes of state h as (data, n): 1, or 0 with *status and the reason set.
   `buffer` is the caller's buffer when it needs one (checked against NULL). */
static int serialized_data(Instance *in, const char *function, StateHandle *h,
                           const void *buffer, int *status, char **data, Py_ssize_t *n) {
    PyObject *bytes;
    if (!h || !buffer) {
        *status = reject(in, function, "FMUstate is not an FMU state, or a pointer is NULL");
        return 0;
    }
    if (!(bytes = serialized(in, h, status))) return 0;
    if (py.PyBytes_AsStringAndSize(bytes, data, n) == 0) return 1;
    *status = protocol_error(in, function);
    return 0;
}

static int serialized_size(void *c, const char *function, void *state, size_t *size) {
    ENTER(c) = ST_OK;
    char *data;
    Py_ssize_t n;
    if (serialized_data(in, function, as_state(state), size, &status, &data, &n))
        *size = (size_t)n;
    LEAVE();
}

static int serialize(void *c, const char *function, void *state, unsigned char buffer[],
                     size_t size) {
    ENTER(c) = ST_OK;
    char *data;
    Py_ssize_t n;
    if (serialized_data(in, function, as_state(state), buffer, &status, &data, &n)) {
        if ((size_t)n > size)
            status = reject(in, function, "size is smaller than the serialized state's size");
        else
            memcpy(buffer, data, (size_t)n);
    }
    LEAVE();
}

static int deserialize(void *c, const char *function, const unsigned char buffer[],
                       size_t size, void **state) {
    ENTER(c);
    PyObject *object = NULL;
    if (!state || (size > 0 && !buffer) || size > (size_t)1 << 30) {
        status = reject(in, function, "serializedState or FMUstate is NULL, or size exceeds "
                        "1 GiB");
        LEAVE();
    }
    status = call(in, M_DESERIALIZE, py.Py_BuildValue("(N)", py.PyBytes_FromStringAndSize(
                  buffer ? (const char *)buffer : "", (Py_ssize_t)size)), &object);
    if (status == ST_OK && object) status = store_state(object, state);
    else if (object) py.Py_DecRef(object);
    LEAVE();
}

/* ---- derivatives (hooks a model may implement) ------------------------------------------ */

static int directional_derivative(void *c, const char *function, const unsigned int unknowns[],
                                  size_t n_unknowns, const unsigned int knowns[],
                                  size_t n_knowns, const double seed[], double sensitivity[]) {
    ENTER(c);
    PyObject *payload = NULL;
    const char *problem = array_problem(n_unknowns, unknowns, sensitivity);
    if (!problem) problem = array_problem(n_knowns, knowns, seed);
    if (problem) { status = reject(in, function, problem); LEAVE(); }
    status = call(in, M_DIRECTIONAL, py.Py_BuildValue("(NNN)", vr_tuple(unknowns, n_unknowns),
                  vr_tuple(knowns, n_knowns), real_tuple(seed, n_knowns)), &payload);
    if (status <= ST_WARNING && payload && !copy_reals(payload, sensitivity, n_unknowns))
        status = protocol_error(in, function);
    if (payload) py.Py_DecRef(payload);
    LEAVE();
}

static int output_derivatives(void *c, const char *function, const unsigned int vr[],
                              size_t nvr, const int order[], double values[]) {
    ENTER(c);
    PyObject *payload = NULL;
    const char *problem = array_problem(nvr, vr, values);
    if (!problem && nvr > 0 && !order) problem = "order is NULL";
    if (problem) { status = reject(in, function, problem); LEAVE(); }
    status = call(in, M_GET_OUTPUT_DER, py.Py_BuildValue("(NN)", vr_tuple(vr, nvr),
                  int_tuple(order, nvr)), &payload);
    if (status <= ST_WARNING && payload && !copy_reals(payload, values, nvr))
        status = protocol_error(in, function);
    if (payload) py.Py_DecRef(payload);
    LEAVE();
}

#endif /* MBDFMU_BRIDGE_H */

/*
 * fmi2.c: the FMI 2.0 co-simulation API of every mbdfmu FMU, forwarding to a Python slave.
 *
 * The binary is the same for every FMU: what a model is comes from its resources folder
 * (mbdfmu.json, mbdfmu_boot.py, the runtime package and the model module).
 *
 * Python is found at run time, never linked:
 *   - a process that already runs Python (fmpy, libcosimpy, any Python host) is used as
 *     it is: dlsym(RTLD_DEFAULT, "Py_IsInitialized") finds it and it returns 1;
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
 * raises), then hands the messages the slave queued to the host's logger. An exception
 * escaping the runtime means the runtime broke its contract: the wrapper logs it and
 * returns fmi2Fatal.
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <math.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/types.h>
#include <wchar.h>

#include "fmi2Functions.h"

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
    M_TAKE_LOG, N_METHODS
} Method;

static const char *const METHOD_NAMES[N_METHODS] = {
    "fmi2_reject", "fmi2_set_debug_logging", "fmi2_setup_experiment",
    "fmi2_enter_initialization_mode", "fmi2_exit_initialization_mode", "fmi2_terminate",
    "fmi2_reset", "fmi2_free_instance", "fmi2_get", "fmi2_set", "fmi2_do_step",
    "fmi2_cancel_step", "fmi2_get_status", "fmi2_get_fmu_state", "fmi2_set_fmu_state",
    "fmi2_serialize_fmu_state", "fmi2_deserialize_fmu_state",
    "fmi2_get_directional_derivative", "fmi2_set_real_input_derivatives",
    "fmi2_get_real_output_derivatives", "take_log",
};

typedef struct {
    unsigned magic;
    char *name;
    fmi2CallbackLogger logger;
    fmi2ComponentEnvironment environment;
    PyObject *methods[N_METHODS];   /* bound methods of the slave, looked up once */
    PyObject *log_queue;            /* the slave's list of pending messages */
    char **strings;                 /* fmi2GetString results: valid until the next call */
    size_t n_strings;
    int fatal;                      /* the runtime broke its contract: only free is left */
    /* the slave's Real values, served by fmi2GetReal without Python while *fast_valid
     * (runtime/real_cache.py): set by the slave after a step, cleared by every call */
    const double *fast_values;
    const unsigned char *fast_mask;
    volatile int64_t *fast_valid;
    size_t fast_count;
} Instance;

typedef struct {
    unsigned magic;
    PyObject *state;        /* the runtime's FmuState */
    PyObject *serialized;   /* bytes, kept between SerializedFMUstateSize and Serialize */
} StateHandle;

/* ---- logging -------------------------------------------------------------------------- */

/* The host's logger takes a printf format: '%' in a message is doubled so that a host that
 * formats prints it as is (one that does not shows "%%"). */
static void log_text(const char *name, fmi2CallbackLogger logger, fmi2ComponentEnvironment env,
                     fmi2Status status, const char *category, const char *text) {
    char escaped[2 * MESSAGE_SIZE + 1];
    size_t j = 0;
    if (!logger) return;
    for (size_t i = 0; text[i] && j + 2 < sizeof escaped; i++) {
        if (text[i] == '%') escaped[j++] = '%';
        escaped[j++] = text[i];
    }
    escaped[j] = '\0';
    logger(env, name ? name : "", status, category, escaped);
}

/* printf-style message to the instance's logger (cut at MESSAGE_SIZE). */
__attribute__((format(printf, 4, 5)))
static void log_instance(const Instance *in, fmi2Status status, const char *category,
                         const char *format, ...) {
    char text[MESSAGE_SIZE];
    va_list args;
    va_start(args, format);
    vsnprintf(text, sizeof text, format, args);
    va_end(args);
    log_text(in->name, in->logger, in->environment, status, category, text);
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
            log_text(in->name, in->logger, in->environment, (fmi2Status)status, c, t);
        if (category) py.Py_DecRef(category);
        if (text) py.Py_DecRef(text);
        py.PyErr_Clear();
    }
    py.Py_DecRef(messages);
}

/* ---- finding and starting Python --------------------------------------------------------- */

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
static int ensure_python(const char *resources, char *error, size_t size) {
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
            snprintf(error, size, "fmi2Instantiate: this FMU runs Python %s and no Python "
                     "library was recorded at build time: set MBDFMU_PYTHON_LIBRARY to the "
                     "path of a libpython3.X.so.1.0 (CPython 3.10+ with numpy)", version);
        else if ((handle = dlopen(library, RTLD_NOW | RTLD_GLOBAL)))
            found = 1;
        else
            snprintf(error, size, "fmi2Instantiate: cannot load the Python library %s (%s): "
                     "set MBDFMU_PYTHON_LIBRARY to the libpython3.X.so.1.0 of a CPython 3.10+ "
                     "with numpy (the FMU was built with Python %s)", library, dlerror(), version);
    }
    free(config);
    const char *missing = found ? resolve(handle) : "";
    if (found && missing)
        snprintf(error, size, "fmi2Instantiate: the Python library %s lacks %s: set "
                 "MBDFMU_PYTHON_LIBRARY to a CPython 3.10+ libpython", *library ? library
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

/* fmuResourceLocation ("file:///p", "file:/p", "file://localhost/p", %-escaped) -> path. */
static int uri_to_path(const char *uri, char *path, size_t size) {
    const char *p;
    if (strncmp(uri, "file://localhost/", 17) == 0) p = uri + 16;
    else if (strncmp(uri, "file:///", 8) == 0) p = uri + 7;
    else if (strncmp(uri, "file:/", 6) == 0) p = uri + 5;
    else return 0;
    size_t n = 0;
    for (; *p; p++) {
        unsigned hex;
        if (*p == '%' && sscanf(p + 1, "%2x", &hex) == 1) { path[n] = (char)hex; p += 2; }
        else path[n] = *p;
        if (++n >= size) return 0;
    }
    while (n > 1 && path[n - 1] == '/') n--;    /* no trailing slash */
    path[n] = '\0';
    return 1;
}

/* ---- calling the slave ------------------------------------------------------------------- */

static Instance *as_instance(fmi2Component c) {
    Instance *in = (Instance *)c;
    return in && in->magic == INSTANCE_MAGIC ? in : NULL;
}

static void free_strings(Instance *in) {
    for (size_t i = 0; i < in->n_strings; i++) free(in->strings[i]);
    free(in->strings);
    in->strings = NULL;
    in->n_strings = 0;
}

/* Start of every call on an instance: the previous fmi2GetString results expire. */
static Instance *begin(fmi2Component c) {
    Instance *in = as_instance(c);
    if (in) free_strings(in);
    return in;
}

/* Call method m with args (a new reference, stolen; NULL means building it failed).
 * Returns the status; *payload (optional) receives a new reference to the second item.
 * Needs the GIL. */
static fmi2Status call(Instance *in, Method m, PyObject *args, PyObject **payload) {
    char text[MESSAGE_SIZE / 2];
    if (payload) *payload = NULL;
    if (in->fatal) {
        if (args) py.Py_DecRef(args);
        log_instance(in, fmi2Fatal, "logStatusFatal", "%s refused: the FMU's Python runtime "
                     "failed earlier; only fmi2FreeInstance is possible", METHOD_NAMES[m]);
        return fmi2Fatal;
    }
    if (in->fast_valid && m != M_GET) *in->fast_valid = 0;   /* anything may change now */
    PyObject *result = args ? py.PyObject_CallObject(in->methods[m], args) : NULL;
    if (args) py.Py_DecRef(args);
    long status = -1;
    if (result && py.PyTuple_Size(result) == 2)
        status = py.PyLong_AsLong(py.PyTuple_GetItem(result, 0));
    if (status < fmi2OK || status > fmi2Pending || py.PyErr_Occurred()) {
        exception_text(text, sizeof text);
        in->fatal = 1;
        if (result) py.Py_DecRef(result);
        forward_log(in);
        log_instance(in, fmi2Fatal, "logStatusFatal", "the FMU's Python runtime broke its "
                     "protocol (a bug in mbdfmu): %s", text);
        return fmi2Fatal;
    }
    if (payload) {
        *payload = py.PyTuple_GetItem(result, 1);
        py.Py_IncRef(*payload);
    }
    py.Py_DecRef(result);
    forward_log(in);
    return (fmi2Status)status;
}

/* A call the wrapper refuses itself (NULL pointer, non-finite number): the slave logs the
 * reason and enters its Error state, as for any fmi2Error. Needs the GIL. */
static fmi2Status reject(Instance *in, const char *function, const char *reason) {
    return call(in, M_REJECT, py.Py_BuildValue("(ss)", function, reason), NULL);
}

/* Python may have been finalized by a Python host that exits before freeing us. */
static int python_alive(void) {
    return python_ready && py.Py_IsInitialized();
}

/* The usual frame of an FMI call on an instance: valid instance, live Python, GIL held. */
#define ENTER(c)                                                   \
    Instance *in = begin(c);                                       \
    if (!in || !python_alive()) return fmi2Error;                  \
    PyGILState_STATE gil = py.PyGILState_Ensure();                 \
    fmi2Status status
#define LEAVE()                                                    \
    py.PyGILState_Release(gil);                                    \
    return status

/* A tuple of Python ints from value references (NULL on failure). */
static PyObject *vr_tuple(const fmi2ValueReference vr[], size_t n) {
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

static PyObject *real_tuple(const fmi2Real *x, size_t n) {
    PyObject *t = py.PyTuple_New((Py_ssize_t)n);
    for (size_t i = 0; t && i < n; i++)
        py.PyTuple_SetItem(t, (Py_ssize_t)i, py.PyFloat_FromDouble(x[i]));
    return t;
}

static PyObject *int_tuple(const fmi2Integer *x, size_t n) {
    PyObject *t = py.PyTuple_New((Py_ssize_t)n);
    for (size_t i = 0; t && i < n; i++)
        py.PyTuple_SetItem(t, (Py_ssize_t)i, py.PyLong_FromLong(x[i]));
    return t;
}

/* Copy n floats out of a Python tuple; 0 if it is not one of n numbers. Needs the GIL. */
static int copy_reals(PyObject *payload, fmi2Real *out, size_t n) {
    if (py.PyTuple_Size(payload) != (Py_ssize_t)n) { py.PyErr_Clear(); return 0; }
    for (size_t i = 0; i < n; i++)
        out[i] = py.PyFloat_AsDouble(py.PyTuple_GetItem(payload, (Py_ssize_t)i));
    return !py.PyErr_Occurred();
}

/* The protocol was broken after a call returned: mark the instance, say why. */
static fmi2Status protocol_error(Instance *in, const char *function) {
    char text[MESSAGE_SIZE / 2];
    exception_text(text, sizeof text);
    in->fatal = 1;
    log_instance(in, fmi2Fatal, "logStatusFatal", "%s: the FMU's Python runtime returned "
                 "values of the wrong kind (a bug in mbdfmu): %s", function, text);
    return fmi2Fatal;
}

/* ---- FMI functions: platform, instances, logging --------------------------------------------- */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

/* The slave's RealCache addresses (its attribute fast_real: values, mask, valid flag,
 * count); none (no fast path) when it has no such attribute. Needs the GIL. */
static void fast_real(Instance *in, PyObject *slave) {
    PyObject *t = py.PyObject_GetAttrString(slave, "fast_real");
    if (t && py.PyTuple_Size(t) == 4) {
        void *values = py.PyLong_AsVoidPtr(py.PyTuple_GetItem(t, 0));
        void *mask = py.PyLong_AsVoidPtr(py.PyTuple_GetItem(t, 1));
        void *valid = py.PyLong_AsVoidPtr(py.PyTuple_GetItem(t, 2));
        long count = py.PyLong_AsLong(py.PyTuple_GetItem(t, 3));
        if (!py.PyErr_Occurred() && values && mask && valid && count >= 0) {
            in->fast_values = values;
            in->fast_mask = mask;
            in->fast_valid = valid;
            in->fast_count = (size_t)count;
        }
    }
    if (t) py.Py_DecRef(t);
    py.PyErr_Clear();
}

/* fmi2GetReal without Python: every vr a Real variable while the slave's values are valid
 * (see Instance); 0 when Python must answer. */
static int fast_get_real(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         fmi2Real value[]) {
    Instance *in = as_instance(c);
    if (!in || in->fatal || !in->fast_valid || !*in->fast_valid || !python_alive()
        || nvr > MAX_NVR || (nvr > 0 && (!vr || !value)))
        return 0;
    for (size_t i = 0; i < nvr; i++)
        if (vr[i] >= in->fast_count || !in->fast_mask[vr[i]]) return 0;
    free_strings(in);
    for (size_t i = 0; i < nvr; i++) value[i] = in->fast_values[vr[i]];
    return 1;
}

/* Build the slave through resources/mbdfmu_boot.py; NULL with `error` filled on failure.
 * Needs the GIL. */
static Instance *create(const char *name, const char *guid, const char *resources,
                        int logging_on, char *error, size_t size) {
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
        snprintf(error, size, "fmi2Instantiate: cannot run %.500s: %s", boot_path, text);
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
            snprintf(error, size, "fmi2Instantiate: the model's slave lacks the protocol "
                     "method %s", METHOD_NAMES[N_METHODS - 1]);
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

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn) {
    fmi2CallbackLogger logger = functions ? functions->logger : NULL;
    fmi2ComponentEnvironment env = functions ? functions->componentEnvironment : NULL;
    char resources[4096], error[MESSAGE_SIZE] = "";
    Instance *in = NULL;
    (void)visible;
    if (!instanceName || !fmuGUID || !fmuResourceLocation)
        snprintf(error, sizeof error, "fmi2Instantiate: instanceName, fmuGUID and "
                 "fmuResourceLocation must not be NULL");
    else if (fmuType != fmi2CoSimulation)
        snprintf(error, sizeof error, "fmi2Instantiate: this FMU supports co-simulation only");
    else if (!uri_to_path(fmuResourceLocation, resources, sizeof resources))
        snprintf(error, sizeof error, "fmi2Instantiate: fmuResourceLocation \"%.1000s\" is not "
                 "a file: URI", fmuResourceLocation);
    else if (ensure_python(resources, error, sizeof error)) {
        PyGILState_STATE gil = py.PyGILState_Ensure();
        in = create(instanceName, fmuGUID, resources, loggingOn, error, sizeof error);
        if (in) {
            in->logger = logger;
            in->environment = env;
            forward_log(in);
        }
        py.PyGILState_Release(gil);
    }
    if (!in)
        log_text(instanceName, logger, env, fmi2Error, "logStatusError", error);
    return in;
}

void fmi2FreeInstance(fmi2Component c) {
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

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    ENTER(c);
    PyObject *names = NULL;
    const char *problem = array_problem(nCategories, categories, categories);
    for (size_t i = 0; !problem && i < nCategories; i++)
        if (!categories[i]) problem = "a category is NULL";
    if (problem) { status = reject(in, "fmi2SetDebugLogging", problem); LEAVE(); }
    names = py.PyTuple_New((Py_ssize_t)nCategories);
    for (size_t i = 0; names && i < nCategories; i++)
        py.PyTuple_SetItem(names, (Py_ssize_t)i, py.PyBytes_FromStringAndSize(
            categories[i], (Py_ssize_t)strlen(categories[i])));
    status = call(in, M_SET_DEBUG_LOGGING, py.Py_BuildValue("(iN)", loggingOn, names), NULL);
    LEAVE();
}

/* ---- FMI functions: the state machine ----------------------------------------------------- */

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined,
                               fmi2Real stopTime) {
    ENTER(c);
    if (!isfinite(startTime) || (stopTimeDefined && !isfinite(stopTime))
        || (toleranceDefined && !isfinite(tolerance)))
        status = reject(in, "fmi2SetupExperiment", "startTime, stopTime and tolerance must be "
                        "finite numbers");
    else
        status = call(in, M_SETUP_EXPERIMENT, py.Py_BuildValue("(iddid)", toleranceDefined,
                      tolerance, startTime, stopTimeDefined, stopTime), NULL);
    LEAVE();
}

/* The FMI functions that pass nothing but the instance. */
static fmi2Status call_without_arguments(fmi2Component c, Method m) {
    ENTER(c);
    status = call(in, m, py.Py_BuildValue("()"), NULL);
    LEAVE();
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) { return call_without_arguments(c, M_ENTER_INIT); }
fmi2Status fmi2ExitInitializationMode(fmi2Component c) { return call_without_arguments(c, M_EXIT_INIT); }
fmi2Status fmi2Terminate(fmi2Component c) { return call_without_arguments(c, M_TERMINATE); }
fmi2Status fmi2Reset(fmi2Component c) { return call_without_arguments(c, M_RESET); }

/* ---- FMI functions: getting and setting values --------------------------------------------- */

typedef enum { T_REAL, T_INTEGER, T_BOOLEAN, T_STRING } Type;
static const char *const TYPE_NAMES[] = {"Real", "Integer", "Boolean", "String"};

/* Copy the slave's values into the caller's array; 0 if the payload is not n values of
 * the type. Strings are copied into the instance (valid until its next call). */
static int copy_out(Instance *in, Type type, PyObject *payload, void *values, size_t n) {
    if (py.PyTuple_Size(payload) != (Py_ssize_t)n) return 0;
    if (type == T_REAL) return copy_reals(payload, values, n);
    if (type == T_STRING && !(in->strings = calloc(n ? n : 1, sizeof(char *)))) return 0;
    for (size_t i = 0; i < n; i++) {
        PyObject *item = py.PyTuple_GetItem(payload, (Py_ssize_t)i);
        if (type == T_STRING) {
            char *data = NULL;
            Py_ssize_t size = 0;
            if (py.PyBytes_AsStringAndSize(item, &data, &size) != 0) return 0;
            if (!(in->strings[i] = malloc((size_t)size + 1))) return 0;
            memcpy(in->strings[i], data, (size_t)size + 1);
            in->n_strings = i + 1;
            ((fmi2String *)values)[i] = in->strings[i];
        } else if (type == T_INTEGER) {
            ((fmi2Integer *)values)[i] = (fmi2Integer)py.PyLong_AsLong(item);
        } else {
            ((fmi2Boolean *)values)[i] = py.PyLong_AsLong(item) ? fmi2True : fmi2False;
        }
    }
    return !py.PyErr_Occurred();
}

static fmi2Status get_values(fmi2Component c, Type type, const fmi2ValueReference vr[],
                             size_t nvr, void *values) {
    ENTER(c);
    char function[32];
    PyObject *payload = NULL;
    snprintf(function, sizeof function, "fmi2Get%s", TYPE_NAMES[type]);
    const char *problem = array_problem(nvr, vr, values);
    if (problem) { status = reject(in, function, problem); LEAVE(); }
    status = call(in, M_GET, py.Py_BuildValue("(sN)", TYPE_NAMES[type], vr_tuple(vr, nvr)),
                  &payload);
    if (payload && !copy_out(in, type, payload, values, nvr))
        status = protocol_error(in, function);
    if (payload) py.Py_DecRef(payload);
    LEAVE();
}

/* The caller's values as a tuple (String: bytes); NULL with *problem set for a NULL string. */
static PyObject *values_in(Type type, const void *values, size_t n, const char **problem) {
    if (type == T_REAL) return real_tuple(values, n);
    if (type != T_STRING) return int_tuple(values, n);   /* fmi2Boolean is an int too */
    for (size_t i = 0; i < n; i++)
        if (!((const fmi2String *)values)[i]) { *problem = "a string in value[] is NULL"; return NULL; }
    PyObject *t = py.PyTuple_New((Py_ssize_t)n);
    for (size_t i = 0; t && i < n; i++) {
        const char *s = ((const fmi2String *)values)[i];
        py.PyTuple_SetItem(t, (Py_ssize_t)i, py.PyBytes_FromStringAndSize(s, (Py_ssize_t)strlen(s)));
    }
    return t;
}

static fmi2Status set_values(fmi2Component c, Type type, const fmi2ValueReference vr[],
                             size_t nvr, const void *values) {
    ENTER(c);
    char function[32];
    PyObject *items = NULL;
    snprintf(function, sizeof function, "fmi2Set%s", TYPE_NAMES[type]);
    const char *problem = array_problem(nvr, vr, values);
    if (!problem) items = values_in(type, values, nvr, &problem);
    if (problem) { status = reject(in, function, problem); LEAVE(); }
    status = call(in, M_SET, py.Py_BuildValue("(sNN)", TYPE_NAMES[type], vr_tuple(vr, nvr),
                  items), NULL);
    LEAVE();
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       fmi2Real value[]) {
    if (fast_get_real(c, vr, nvr, value)) return fmi2OK;
    return get_values(c, T_REAL, vr, nvr, value);
}
fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Integer value[]) { return get_values(c, T_INTEGER, vr, nvr, value); }
fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Boolean value[]) { return get_values(c, T_BOOLEAN, vr, nvr, value); }
fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         fmi2String value[]) { return get_values(c, T_STRING, vr, nvr, value); }
fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       const fmi2Real value[]) { return set_values(c, T_REAL, vr, nvr, value); }
fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Integer value[]) { return set_values(c, T_INTEGER, vr, nvr, value); }
fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Boolean value[]) { return set_values(c, T_BOOLEAN, vr, nvr, value); }
fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         const fmi2String value[]) { return set_values(c, T_STRING, vr, nvr, value); }

/* ---- FMI functions: FMU states ---------------------------------------------------------- */

static StateHandle *as_state(fmi2FMUstate s) {
    StateHandle *h = (StateHandle *)s;
    return h && h->magic == STATE_MAGIC ? h : NULL;
}

/* Put the runtime's state object (a new reference, stolen) into *state: into the handle
 * it points to when that is one of ours (FMI 2.0 lets the master pass a handle back to be
 * reused), else into a new one. Needs the GIL. */
static fmi2Status store_state(PyObject *object, fmi2FMUstate *state) {
    StateHandle *h = as_state(*state);
    if (!h && !(h = calloc(1, sizeof *h))) { py.Py_DecRef(object); return fmi2Fatal; }
    if (h->state) py.Py_DecRef(h->state);
    if (h->serialized) py.Py_DecRef(h->serialized);
    h->magic = STATE_MAGIC;
    h->state = object;
    h->serialized = NULL;
    *state = h;
    return fmi2OK;
}

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    ENTER(c);
    PyObject *object = NULL;
    if (!FMUstate) { status = reject(in, "fmi2GetFMUstate", "FMUstate is NULL"); LEAVE(); }
    status = call(in, M_GET_STATE, py.Py_BuildValue("()"), &object);
    if (status == fmi2OK && object) status = store_state(object, FMUstate);
    else if (object) py.Py_DecRef(object);
    LEAVE();
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    ENTER(c);
    StateHandle *h = as_state(FMUstate);
    if (!h) status = reject(in, "fmi2SetFMUstate", "FMUstate is NULL or not an FMU state");
    else status = call(in, M_SET_STATE, py.Py_BuildValue("(O)", h->state), NULL);
    LEAVE();
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    ENTER(c);
    StateHandle *h = FMUstate ? as_state(*FMUstate) : NULL;
    if (!FMUstate || (*FMUstate && !h)) {
        status = reject(in, "fmi2FreeFMUstate", "FMUstate is NULL or not an FMU state");
        LEAVE();
    }
    status = fmi2OK;
    if (h) {
        py.Py_DecRef(h->state);
        if (h->serialized) py.Py_DecRef(h->serialized);
        h->magic = 0;
        free(h);
        *FMUstate = NULL;
    }
    LEAVE();
}

/* The handle's serialized bytes, made once; NULL (status in *status) on failure. */
static PyObject *serialized(Instance *in, StateHandle *h, fmi2Status *status) {
    PyObject *bytes = NULL;
    if (h->serialized) return h->serialized;
    *status = call(in, M_SERIALIZE, py.Py_BuildValue("(O)", h->state), &bytes);
    if (*status == fmi2OK && bytes) return h->serialized = bytes;
    if (bytes) py.Py_DecRef(bytes);
    return NULL;
}

/* The serialized bytes of state h as (data, n): 1, or 0 with *status and the reason set.
   `buffer` is the caller's buffer when it needs one (checked against NULL). */
static int serialized_data(Instance *in, const char *function, StateHandle *h, const void *buffer,
                           fmi2Status *status, char **data, Py_ssize_t *n) {
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

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    ENTER(c) = fmi2OK;
    char *data;
    Py_ssize_t n;
    if (serialized_data(in, "fmi2SerializedFMUstateSize", as_state(FMUstate), size, &status,
                        &data, &n))
        *size = (size_t)n;
    LEAVE();
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[],
                                 size_t size) {
    ENTER(c) = fmi2OK;
    char *data;
    Py_ssize_t n;
    if (serialized_data(in, "fmi2SerializeFMUstate", as_state(FMUstate), serializedState,
                        &status, &data, &n)) {
        if ((size_t)n > size)
            status = reject(in, "fmi2SerializeFMUstate", "size is smaller than "
                            "fmi2SerializedFMUstateSize gave");
        else
            memcpy(serializedState, data, (size_t)n);
    }
    LEAVE();
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    ENTER(c);
    PyObject *object = NULL;
    if (!FMUstate || (size > 0 && !serializedState) || size > (size_t)1 << 30) {
        status = reject(in, "fmi2DeSerializeFMUstate", "serializedState or FMUstate is NULL, or "
                        "size exceeds 1 GiB");
        LEAVE();
    }
    status = call(in, M_DESERIALIZE, py.Py_BuildValue("(N)", py.PyBytes_FromStringAndSize(
                  serializedState ? serializedState : "", (Py_ssize_t)size)), &object);
    if (status == fmi2OK && object) status = store_state(object, FMUstate);
    else if (object) py.Py_DecRef(object);
    LEAVE();
}

/* ---- FMI functions: derivatives (hooks a model may implement) ------------------------------ */

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[],
                                        size_t nUnknown, const fmi2ValueReference vKnown_ref[],
                                        size_t nKnown, const fmi2Real dvKnown[],
                                        fmi2Real dvUnknown[]) {
    ENTER(c);
    PyObject *payload = NULL;
    const char *problem = array_problem(nUnknown, vUnknown_ref, dvUnknown);
    if (!problem) problem = array_problem(nKnown, vKnown_ref, dvKnown);
    if (problem) { status = reject(in, "fmi2GetDirectionalDerivative", problem); LEAVE(); }
    status = call(in, M_DIRECTIONAL, py.Py_BuildValue("(NNN)", vr_tuple(vUnknown_ref, nUnknown),
                  vr_tuple(vKnown_ref, nKnown), real_tuple(dvKnown, nKnown)), &payload);
    if (status <= fmi2Warning && payload && !copy_reals(payload, dvUnknown, nUnknown))
        status = protocol_error(in, "fmi2GetDirectionalDerivative");
    if (payload) py.Py_DecRef(payload);
    LEAVE();
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    ENTER(c);
    const char *problem = array_problem(nvr, vr, value);
    if (!problem && nvr > 0 && !order) problem = "order is NULL";
    if (problem) { status = reject(in, "fmi2SetRealInputDerivatives", problem); LEAVE(); }
    status = call(in, M_SET_INPUT_DER, py.Py_BuildValue("(NNN)", vr_tuple(vr, nvr),
                  int_tuple(order, nvr), real_tuple(value, nvr)), NULL);
    LEAVE();
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    ENTER(c);
    PyObject *payload = NULL;
    const char *problem = array_problem(nvr, vr, value);
    if (!problem && nvr > 0 && !order) problem = "order is NULL";
    if (problem) { status = reject(in, "fmi2GetRealOutputDerivatives", problem); LEAVE(); }
    status = call(in, M_GET_OUTPUT_DER, py.Py_BuildValue("(NN)", vr_tuple(vr, nvr),
                  int_tuple(order, nvr)), &payload);
    if (status <= fmi2Warning && payload && !copy_reals(payload, value, nvr))
        status = protocol_error(in, "fmi2GetRealOutputDerivatives");
    if (payload) py.Py_DecRef(payload);
    LEAVE();
}

/* ---- FMI functions: stepping and status ------------------------------------------------------- */

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint,
                      fmi2Real communicationStepSize, fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    ENTER(c);
    char reason[200];
    if (!isfinite(currentCommunicationPoint)) {
        snprintf(reason, sizeof reason, "currentCommunicationPoint = %g is not finite",
                 currentCommunicationPoint);
        status = reject(in, "fmi2DoStep", reason);
    } else if (!isfinite(communicationStepSize) || communicationStepSize <= 0) {
        snprintf(reason, sizeof reason, "communicationStepSize = %g must be positive and finite",
                 communicationStepSize);
        status = reject(in, "fmi2DoStep", reason);
    } else {
        status = call(in, M_DO_STEP, py.Py_BuildValue("(ddi)", currentCommunicationPoint,
                      communicationStepSize, noSetFMUStatePriorToCurrentPoint), NULL);
    }
    LEAVE();
}

/* canRunAsynchronuously is false, so there is never a step to cancel: fmi2Error. */
fmi2Status fmi2CancelStep(fmi2Component c) { return call_without_arguments(c, M_CANCEL_STEP); }

/* All five status functions: the slave answers fmi2LastSuccessfulTime (Real) and
 * fmi2Terminated (Boolean); other kinds cannot be retrieved (fmi2Discard). */
static fmi2Status get_status(fmi2Component c, const char *type, fmi2StatusKind kind, void *value) {
    ENTER(c);
    PyObject *payload = NULL;
    char function[40];
    snprintf(function, sizeof function, "fmi2Get%sStatus", type);
    if (!value) { status = reject(in, function, "value is NULL"); LEAVE(); }
    status = call(in, M_GET_STATUS, py.Py_BuildValue("(si)", type, (int)kind), &payload);
    if (status == fmi2OK && payload) {
        if (strcmp(type, "Real") == 0) *(fmi2Real *)value = py.PyFloat_AsDouble(payload);
        else *(fmi2Boolean *)value = py.PyLong_AsLong(payload) ? fmi2True : fmi2False;
        if (py.PyErr_Occurred()) status = protocol_error(in, function);
    }
    if (payload) py.Py_DecRef(payload);
    LEAVE();
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    return get_status(c, "", s, value);
}
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    return get_status(c, "Real", s, value);
}
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    return get_status(c, "Integer", s, value);
}
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    return get_status(c, "Boolean", s, value);
}
fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    return get_status(c, "String", s, value);
}

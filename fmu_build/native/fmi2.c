/*
 * fmi2.c: the FMI 2.0 co-simulation API of every mbdfmu FMI 2.0 FMU, forwarding to a
 * Python slave through bridge.h (how Python is found, the call protocol, states).
 */
#include "bridge.h"
#include "fmi2Functions.h"

/* The host's logger takes a printf format: '%' in a message is doubled so that a host that
 * formats prints it as is (one that does not shows "%%"). */
static void log_text(const char *name, fmi2CallbackLogger logger, fmi2ComponentEnvironment env,
                     int status, const char *category, const char *text) {
    char escaped[2 * MESSAGE_SIZE + 1];
    size_t j = 0;
    if (!logger) return;
    for (size_t i = 0; text[i] && j + 2 < sizeof escaped; i++) {
        if (text[i] == '%') escaped[j++] = '%';
        escaped[j++] = text[i];
    }
    escaped[j] = '\0';
    logger(env, name ? name : "", (fmi2Status)status, category, escaped);
}

static void emit2(const Instance *in, int status, const char *category, const char *text) {
    log_text(in->name, (fmi2CallbackLogger)in->logger, in->environment, status, category, text);
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

/* ---- platform, instances, logging ---------------------------------------------------------- */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

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
    else
        in = instantiate(instanceName, fmuGUID, resources, loggingOn, "fmi2Instantiate", emit2,
                         (void *)logger, env, error, sizeof error);
    if (!in)
        log_text(instanceName, logger, env, fmi2Error, "logStatusError", error);
    return in;
}

void fmi2FreeInstance(fmi2Component c) { free_instance(c); }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    return set_debug_logging(c, "fmi2SetDebugLogging", loggingOn, nCategories, categories);
}

/* ---- the state machine ---------------------------------------------------------------------- */

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined,
                               fmi2Real stopTime) {
    return experiment(c, M_SETUP_EXPERIMENT, "fmi2SetupExperiment", toleranceDefined, tolerance,
                      startTime, stopTimeDefined, stopTime);
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) { return call_without_arguments(c, M_ENTER_INIT); }
fmi2Status fmi2ExitInitializationMode(fmi2Component c) { return call_without_arguments(c, M_EXIT_INIT); }
fmi2Status fmi2Terminate(fmi2Component c) { return call_without_arguments(c, M_TERMINATE); }
fmi2Status fmi2Reset(fmi2Component c) { return call_without_arguments(c, M_RESET); }

/* ---- getting and setting values ------------------------------------------------------------ */

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       fmi2Real value[]) {
    if (fast_get_real(c, vr, nvr, value)) return fmi2OK;
    return get_values(c, "fmi2GetReal", "Real", K_REAL, vr, nvr, value);
}
fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Integer value[]) {
    return get_values(c, "fmi2GetInteger", "Integer", K_INT32, vr, nvr, value);
}
fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Boolean value[]) {
    return get_values(c, "fmi2GetBoolean", "Boolean", K_INT_BOOL, vr, nvr, value);
}
fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         fmi2String value[]) {
    return get_values(c, "fmi2GetString", "String", K_STRING, vr, nvr, value);
}
fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       const fmi2Real value[]) {
    if (fast_set_real(c, vr, nvr, value)) return fmi2OK;
    return set_values(c, "fmi2SetReal", "Real", K_REAL, vr, nvr, value);
}
fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Integer value[]) {
    return set_values(c, "fmi2SetInteger", "Integer", K_INT32, vr, nvr, value);
}
fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Boolean value[]) {
    return set_values(c, "fmi2SetBoolean", "Boolean", K_INT_BOOL, vr, nvr, value);
}
fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         const fmi2String value[]) {
    return set_values(c, "fmi2SetString", "String", K_STRING, vr, nvr, value);
}

/* ---- FMU states -------------------------------------------------------------------------------- */

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    return get_state(c, "fmi2GetFMUstate", FMUstate);
}
fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    return set_state(c, "fmi2SetFMUstate", FMUstate);
}
fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    return free_state(c, "fmi2FreeFMUstate", FMUstate);
}
fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    return serialized_size(c, "fmi2SerializedFMUstateSize", FMUstate, size);
}
fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate,
                                 fmi2Byte serializedState[], size_t size) {
    return serialize(c, "fmi2SerializeFMUstate", FMUstate, (unsigned char *)serializedState,
                     size);
}
fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    return deserialize(c, "fmi2DeSerializeFMUstate", (const unsigned char *)serializedState,
                       size, FMUstate);
}

/* ---- derivatives ---------------------------------------------------------------------------- */

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[],
                                        size_t nUnknown, const fmi2ValueReference vKnown_ref[],
                                        size_t nKnown, const fmi2Real dvKnown[],
                                        fmi2Real dvUnknown[]) {
    return directional_derivative(c, "fmi2GetDirectionalDerivative", vUnknown_ref, nUnknown,
                                  vKnown_ref, nKnown, dvKnown, dvUnknown);
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
    return output_derivatives(c, "fmi2GetRealOutputDerivatives", vr, nvr, order, value);
}

/* ---- stepping and status ----------------------------------------------------------------------- */

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint,
                      fmi2Real communicationStepSize, fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    return do_step(c, M_DO_STEP, "fmi2DoStep", currentCommunicationPoint, communicationStepSize,
                   noSetFMUStatePriorToCurrentPoint, NULL);
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

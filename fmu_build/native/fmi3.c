/*
 * fmi3.c: the FMI 3.0 co-simulation API of every mbdfmu FMI 3.0 FMU, forwarding to the
 * same Python slave as fmi2.c through bridge.h (docs/fmu_runtime.md).
 *
 * What FMI 3.0 adds or changes, and how it maps onto the slave:
 *   - fmi3InstantiateCoSimulation gets a resource *path* (not a URI); eventModeUsed and
 *     earlyReturnAllowed are accepted and unused (hasEventMode, mightReturnEarlyFromDoStep
 *     and providesIntermediateUpdate are false), the intermediate-update callback is never
 *     called;
 *   - fmi3EnterInitializationMode carries the experiment (FMI 2.0's fmi2SetupExperiment);
 *   - fmi3DoStep also returns eventHandlingNeeded (false), terminateSimulation,
 *     earlyReturn (false) and lastSuccessfulTime;
 *   - values are typed: Float64, Int32, Boolean and String hold this runtime's variables;
 *     every other type has none (a value reference of it is fmi3Error, an empty call OK);
 *   - Model Exchange, Scheduled Execution, clocks, Event Mode, Configuration Mode and
 *     adjoint derivatives are not provided: each such call is fmi3Error with the reason.
 * The slave answers in FMI 3.0's names (its config says fmi_version 3).
 */
#include "bridge.h"
#include "fmi3Functions.h"

static void emit3(const Instance *in, int status, const char *category, const char *text) {
    fmi3LogMessageCallback logger = (fmi3LogMessageCallback)in->logger;
    if (logger) logger(in->environment, (fmi3Status)status, category, text);
}

const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[]) {
    return set_debug_logging(instance, "fmi3SetDebugLogging", loggingOn, nCategories, categories);
}

/* ---- instances -------------------------------------------------------------------------------- */

fmi3Instance fmi3InstantiateCoSimulation(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3Boolean eventModeUsed,
    fmi3Boolean earlyReturnAllowed, const fmi3ValueReference requiredIntermediateVariables[],
    size_t nRequiredIntermediateVariables, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3IntermediateUpdateCallback intermediateUpdate) {
    char resources[4096], error[MESSAGE_SIZE] = "";
    Instance *in = NULL;
    (void)visible; (void)eventModeUsed; (void)earlyReturnAllowed;
    (void)requiredIntermediateVariables; (void)intermediateUpdate;
    if (!instanceName || !instantiationToken || !resourcePath)
        snprintf(error, sizeof error, "fmi3InstantiateCoSimulation: instanceName, "
                 "instantiationToken and resourcePath must not be NULL");
    else if (nRequiredIntermediateVariables > 0)
        snprintf(error, sizeof error, "fmi3InstantiateCoSimulation: this FMU has no "
                 "intermediate variables (providesIntermediateUpdate is false)");
    else if (snprintf(resources, sizeof resources, "%s", resourcePath) >= (int)sizeof resources
             || !*resources)
        snprintf(error, sizeof error, "fmi3InstantiateCoSimulation: resourcePath is empty or "
                 "too long");
    else {
        size_t n = strlen(resources);
        while (n > 1 && resources[n - 1] == '/') resources[--n] = '\0';   /* no trailing slash */
        in = instantiate(instanceName, instantiationToken, resources, loggingOn,
                         "fmi3InstantiateCoSimulation", emit3, (void *)logMessage,
                         instanceEnvironment, error, sizeof error);
    }
    if (!in && logMessage)
        logMessage(instanceEnvironment, fmi3Error, "logStatusError", error);
    return in;
}

/* Model Exchange and Scheduled Execution are not provided: no instance. */
fmi3Instance fmi3InstantiateModelExchange(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage) {
    (void)instanceName; (void)instantiationToken; (void)resourcePath; (void)visible;
    (void)loggingOn;
    if (logMessage)
        logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                   "fmi3InstantiateModelExchange: this FMU supports co-simulation only");
    return NULL;
}

fmi3Instance fmi3InstantiateScheduledExecution(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3ClockUpdateCallback clockUpdate,
    fmi3LockPreemptionCallback lockPreemption, fmi3UnlockPreemptionCallback unlockPreemption) {
    (void)instanceName; (void)instantiationToken; (void)resourcePath; (void)visible;
    (void)loggingOn; (void)clockUpdate; (void)lockPreemption; (void)unlockPreemption;
    if (logMessage)
        logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                   "fmi3InstantiateScheduledExecution: this FMU supports co-simulation only");
    return NULL;
}

void fmi3FreeInstance(fmi3Instance instance) { free_instance(instance); }

/* ---- the state machine ------------------------------------------------------------------------ */

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined,
                                       fmi3Float64 tolerance, fmi3Float64 startTime,
                                       fmi3Boolean stopTimeDefined, fmi3Float64 stopTime) {
    return experiment(instance, M_ENTER_INIT3, "fmi3EnterInitializationMode", toleranceDefined,
                      tolerance, startTime, stopTimeDefined, stopTime);
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance) {
    return call_without_arguments(instance, M_EXIT_INIT);
}
fmi3Status fmi3Terminate(fmi3Instance instance) { return call_without_arguments(instance, M_TERMINATE); }
fmi3Status fmi3Reset(fmi3Instance instance) { return call_without_arguments(instance, M_RESET); }

#define NO_EVENT_MODE "this FMU has no Event Mode (hasEventMode is false)"
fmi3Status fmi3EnterEventMode(fmi3Instance instance) {
    return unsupported(instance, "fmi3EnterEventMode", NO_EVENT_MODE);
}
fmi3Status fmi3EnterStepMode(fmi3Instance instance) {
    return unsupported(instance, "fmi3EnterStepMode", NO_EVENT_MODE);
}
fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance instance) {
    return unsupported(instance, "fmi3EvaluateDiscreteStates", NO_EVENT_MODE);
}
fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation,
                                    fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged,
                                    fmi3Boolean *nextEventTimeDefined, fmi3Float64 *nextEventTime) {
    (void)discreteStatesNeedUpdate; (void)terminateSimulation;
    (void)nominalsOfContinuousStatesChanged; (void)valuesOfContinuousStatesChanged;
    (void)nextEventTimeDefined; (void)nextEventTime;
    return unsupported(instance, "fmi3UpdateDiscreteStates", NO_EVENT_MODE);
}

#define NO_CONFIGURATION "this FMU has no structural parameters (no Configuration Mode)"
fmi3Status fmi3EnterConfigurationMode(fmi3Instance instance) {
    return unsupported(instance, "fmi3EnterConfigurationMode", NO_CONFIGURATION);
}
fmi3Status fmi3ExitConfigurationMode(fmi3Instance instance) {
    return unsupported(instance, "fmi3ExitConfigurationMode", NO_CONFIGURATION);
}

/* ---- getting and setting values --------------------------------------------------------------- */

/* Scalars only: nValues must equal nValueReferences. */
static int scalar_count(fmi3Instance instance, const char *function, size_t nvr, size_t n_values) {
    char reason[160];
    if (n_values == nvr) return fmi3OK;
    snprintf(reason, sizeof reason, "nValues = %zu differs from nValueReferences = %zu (this "
             "FMU has scalar variables only)", n_values, nvr);
    return unsupported(instance, function, reason);
}

#define GETTER(T, CTYPE, NAME, KIND)                                                        \
fmi3Status fmi3Get##T(fmi3Instance instance, const fmi3ValueReference valueReferences[],    \
                      size_t nValueReferences, CTYPE values[], size_t nValues) {            \
    if (nValues != nValueReferences)                                                        \
        return scalar_count(instance, "fmi3Get" #T, nValueReferences, nValues);             \
    return get_values(instance, "fmi3Get" #T, NAME, KIND, valueReferences, nValueReferences, \
                      values);                                                              \
}
#define SETTER(T, CTYPE, NAME, KIND)                                                        \
fmi3Status fmi3Set##T(fmi3Instance instance, const fmi3ValueReference valueReferences[],    \
                      size_t nValueReferences, const CTYPE values[], size_t nValues) {      \
    if (nValues != nValueReferences)                                                        \
        return scalar_count(instance, "fmi3Set" #T, nValueReferences, nValues);             \
    return set_values(instance, "fmi3Set" #T, NAME, KIND, valueReferences, nValueReferences, \
                      values);                                                              \
}
#define TYPE(T, CTYPE, KIND) GETTER(T, CTYPE, #T, KIND) SETTER(T, CTYPE, #T, KIND)

/* Float64 first tries the values the slave published after a step (no Python). */
fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, fmi3Float64 values[], size_t nValues) {
    if (nValues != nValueReferences)
        return scalar_count(instance, "fmi3GetFloat64", nValueReferences, nValues);
    if (fast_get_real(instance, valueReferences, nValueReferences, values)) return fmi3OK;
    return get_values(instance, "fmi3GetFloat64", "Float64", K_REAL, valueReferences,
                      nValueReferences, values);
}
/* ... and takes the inputs the wrapper's own steps read without Python (fmi2SetReal's). */
fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, const fmi3Float64 values[], size_t nValues) {
    if (nValues != nValueReferences)
        return scalar_count(instance, "fmi3SetFloat64", nValueReferences, nValues);
    if (fast_set_real(instance, valueReferences, nValueReferences, values)) return fmi3OK;
    return set_values(instance, "fmi3SetFloat64", "Float64", K_REAL, valueReferences,
                      nValueReferences, values);
}
TYPE(Int32, fmi3Int32, K_INT32)
TYPE(Boolean, fmi3Boolean, K_C_BOOL)
TYPE(String, fmi3String, K_STRING)
TYPE(Float32, fmi3Float32, K_NONE)
TYPE(Int8, fmi3Int8, K_NONE)
TYPE(UInt8, fmi3UInt8, K_NONE)
TYPE(Int16, fmi3Int16, K_NONE)
TYPE(UInt16, fmi3UInt16, K_NONE)
TYPE(UInt32, fmi3UInt32, K_NONE)
TYPE(Int64, fmi3Int64, K_NONE)
TYPE(UInt64, fmi3UInt64, K_NONE)

fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                         size_t nValueReferences, size_t valueSizes[], fmi3Binary values[],
                         size_t nValues) {
    (void)valueSizes;
    if (nValues != nValueReferences)
        return scalar_count(instance, "fmi3GetBinary", nValueReferences, nValues);
    return get_values(instance, "fmi3GetBinary", "Binary", K_NONE, valueReferences,
                      nValueReferences, values);
}

fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                         size_t nValueReferences, const size_t valueSizes[],
                         const fmi3Binary values[], size_t nValues) {
    (void)valueSizes;
    if (nValues != nValueReferences)
        return scalar_count(instance, "fmi3SetBinary", nValueReferences, nValues);
    return set_values(instance, "fmi3SetBinary", "Binary", K_NONE, valueReferences,
                      nValueReferences, values);
}

/* ---- clocks (none) ------------------------------------------------------------------------------ */

#define NO_CLOCKS "this FMU has no clocks"
fmi3Status fmi3GetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, fmi3Clock values[]) {
    (void)valueReferences; (void)nValueReferences; (void)values;
    return unsupported(instance, "fmi3GetClock", NO_CLOCKS);
}
fmi3Status fmi3SetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, const fmi3Clock values[]) {
    (void)valueReferences; (void)nValueReferences; (void)values;
    return unsupported(instance, "fmi3SetClock", NO_CLOCKS);
}
fmi3Status fmi3GetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                  size_t nValueReferences, fmi3Float64 intervals[],
                                  fmi3IntervalQualifier qualifiers[]) {
    (void)valueReferences; (void)nValueReferences; (void)intervals; (void)qualifiers;
    return unsupported(instance, "fmi3GetIntervalDecimal", NO_CLOCKS);
}
fmi3Status fmi3GetIntervalFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                   size_t nValueReferences, fmi3UInt64 counters[],
                                   fmi3UInt64 resolutions[], fmi3IntervalQualifier qualifiers[]) {
    (void)valueReferences; (void)nValueReferences; (void)counters; (void)resolutions;
    (void)qualifiers;
    return unsupported(instance, "fmi3GetIntervalFraction", NO_CLOCKS);
}
fmi3Status fmi3GetShiftDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                               size_t nValueReferences, fmi3Float64 shifts[]) {
    (void)valueReferences; (void)nValueReferences; (void)shifts;
    return unsupported(instance, "fmi3GetShiftDecimal", NO_CLOCKS);
}
fmi3Status fmi3GetShiftFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                size_t nValueReferences, fmi3UInt64 counters[],
                                fmi3UInt64 resolutions[]) {
    (void)valueReferences; (void)nValueReferences; (void)counters; (void)resolutions;
    return unsupported(instance, "fmi3GetShiftFraction", NO_CLOCKS);
}
fmi3Status fmi3SetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                  size_t nValueReferences, const fmi3Float64 intervals[]) {
    (void)valueReferences; (void)nValueReferences; (void)intervals;
    return unsupported(instance, "fmi3SetIntervalDecimal", NO_CLOCKS);
}
fmi3Status fmi3SetIntervalFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                   size_t nValueReferences, const fmi3UInt64 counters[],
                                   const fmi3UInt64 resolutions[]) {
    (void)valueReferences; (void)nValueReferences; (void)counters; (void)resolutions;
    return unsupported(instance, "fmi3SetIntervalFraction", NO_CLOCKS);
}
fmi3Status fmi3SetShiftDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                               size_t nValueReferences, const fmi3Float64 shifts[]) {
    (void)valueReferences; (void)nValueReferences; (void)shifts;
    return unsupported(instance, "fmi3SetShiftDecimal", NO_CLOCKS);
}
fmi3Status fmi3SetShiftFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                size_t nValueReferences, const fmi3UInt64 counters[],
                                const fmi3UInt64 resolutions[]) {
    (void)valueReferences; (void)nValueReferences; (void)counters; (void)resolutions;
    return unsupported(instance, "fmi3SetShiftFraction", NO_CLOCKS);
}
fmi3Status fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference clockReference,
                                      fmi3Float64 activationTime) {
    (void)clockReference; (void)activationTime;
    return unsupported(instance, "fmi3ActivateModelPartition", NO_CLOCKS);
}

/* ---- dependencies (declared in the model description only) ----------------------------------- */

#define NO_PER_ELEMENT "providesPerElementDependencies is false: the model description's " \
    "ModelStructure lists the dependencies"
fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance instance,
                                               fmi3ValueReference valueReference,
                                               size_t *nDependencies) {
    (void)valueReference; (void)nDependencies;
    return unsupported(instance, "fmi3GetNumberOfVariableDependencies", NO_PER_ELEMENT);
}
fmi3Status fmi3GetVariableDependencies(fmi3Instance instance, fmi3ValueReference dependent,
                                       size_t elementIndicesOfDependent[],
                                       fmi3ValueReference independents[],
                                       size_t elementIndicesOfIndependents[],
                                       fmi3DependencyKind dependencyKinds[], size_t nDependencies) {
    (void)dependent; (void)elementIndicesOfDependent; (void)independents;
    (void)elementIndicesOfIndependents; (void)dependencyKinds; (void)nDependencies;
    return unsupported(instance, "fmi3GetVariableDependencies", NO_PER_ELEMENT);
}

/* ---- FMU states -------------------------------------------------------------------------------- */

fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    return get_state(instance, "fmi3GetFMUState", FMUState);
}
fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState) {
    return set_state(instance, "fmi3SetFMUState", FMUState);
}
fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    return free_state(instance, "fmi3FreeFMUState", FMUState);
}
fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState FMUState, size_t *size) {
    return serialized_size(instance, "fmi3SerializedFMUStateSize", FMUState, size);
}
fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState,
                                 fmi3Byte serializedState[], size_t size) {
    return serialize(instance, "fmi3SerializeFMUState", FMUState, serializedState, size);
}
fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[],
                                   size_t size, fmi3FMUState *FMUState) {
    return deserialize(instance, "fmi3DeserializeFMUState", serializedState, size, FMUState);
}

/* ---- derivatives ------------------------------------------------------------------------------- */

fmi3Status fmi3GetDirectionalDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
                                        size_t nUnknowns, const fmi3ValueReference knowns[],
                                        size_t nKnowns, const fmi3Float64 seed[], size_t nSeed,
                                        fmi3Float64 sensitivity[], size_t nSensitivity) {
    if (nSeed != nKnowns || nSensitivity != nUnknowns) {
        return unsupported(instance, "fmi3GetDirectionalDerivative", "nSeed must equal nKnowns "
                           "and nSensitivity nUnknowns (this FMU has scalar variables only)");
    }
    return directional_derivative(instance, "fmi3GetDirectionalDerivative", unknowns, nUnknowns,
                                  knowns, nKnowns, seed, sensitivity);
}

fmi3Status fmi3GetAdjointDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
                                    size_t nUnknowns, const fmi3ValueReference knowns[],
                                    size_t nKnowns, const fmi3Float64 seed[], size_t nSeed,
                                    fmi3Float64 sensitivity[], size_t nSensitivity) {
    (void)unknowns; (void)nUnknowns; (void)knowns; (void)nKnowns; (void)seed; (void)nSeed;
    (void)sensitivity; (void)nSensitivity;
    return unsupported(instance, "fmi3GetAdjointDerivative", "providesAdjointDerivatives is "
                       "false: use fmi3GetDirectionalDerivative");
}

fmi3Status fmi3GetOutputDerivatives(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                    size_t nValueReferences, const fmi3Int32 orders[],
                                    fmi3Float64 values[], size_t nValues) {
    if (nValues != nValueReferences)
        return scalar_count(instance, "fmi3GetOutputDerivatives", nValueReferences, nValues);
    return output_derivatives(instance, "fmi3GetOutputDerivatives", valueReferences,
                              nValueReferences, orders, values);
}

/* ---- stepping ---------------------------------------------------------------------------------- */

fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint,
                      fmi3Float64 communicationStepSize,
                      fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation,
                      fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime) {
    PyObject *payload = NULL;
    Instance *in = as_instance(instance);
    if (!in || !python_alive()) return fmi3Error;
    if (!eventHandlingNeeded || !terminateSimulation || !earlyReturn || !lastSuccessfulTime)
        return unsupported(instance, "fmi3DoStep", "an output argument (eventHandlingNeeded, "
                           "terminateSimulation, earlyReturn, lastSuccessfulTime) is NULL");
    if (fast_do_step(instance, currentCommunicationPoint, communicationStepSize)) {
        /* the slave's step would end at t + h, OK, asking for nothing (as its payload) */
        *eventHandlingNeeded = *terminateSimulation = *earlyReturn = fmi3False;
        *lastSuccessfulTime = currentCommunicationPoint + communicationStepSize;
        return fmi3OK;
    }
    int status = do_step(instance, M_DO_STEP3, "fmi3DoStep", currentCommunicationPoint,
                         communicationStepSize, noSetFMUStatePriorToCurrentPoint, &payload);
    *eventHandlingNeeded = fmi3False;
    *earlyReturn = fmi3False;
    if (payload) {   /* (terminate, lastSuccessfulTime) */
        PyGILState_STATE gil = py.PyGILState_Ensure();
        if (py.PyTuple_Size(payload) == 2) {
            *terminateSimulation = py.PyLong_AsLong(py.PyTuple_GetItem(payload, 0)) ? fmi3True
                                                                                   : fmi3False;
            *lastSuccessfulTime = py.PyFloat_AsDouble(py.PyTuple_GetItem(payload, 1));
        }
        if (py.PyErr_Occurred() || py.PyTuple_Size(payload) != 2)
            status = protocol_error(in, "fmi3DoStep");
        py.Py_DecRef(payload);
        py.PyGILState_Release(gil);
    }
    return (fmi3Status)status;
}

/* ---- Model Exchange (not provided) ------------------------------------------------------------- */

#define NO_ME "this FMU supports co-simulation only"
fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance) {
    return unsupported(instance, "fmi3EnterContinuousTimeMode", NO_ME);
}
fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance,
                                       fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode,
                                       fmi3Boolean *terminateSimulation) {
    (void)noSetFMUStatePriorToCurrentPoint; (void)enterEventMode; (void)terminateSimulation;
    return unsupported(instance, "fmi3CompletedIntegratorStep", NO_ME);
}
fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time) {
    (void)time;
    return unsupported(instance, "fmi3SetTime", NO_ME);
}
fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    (void)continuousStates; (void)nContinuousStates;
    return unsupported(instance, "fmi3SetContinuousStates", NO_ME);
}
fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 derivatives[],
                                             size_t nContinuousStates) {
    (void)derivatives; (void)nContinuousStates;
    return unsupported(instance, "fmi3GetContinuousStateDerivatives", NO_ME);
}
fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 eventIndicators[],
                                  size_t nEventIndicators) {
    (void)eventIndicators; (void)nEventIndicators;
    return unsupported(instance, "fmi3GetEventIndicators", NO_ME);
}
fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    (void)continuousStates; (void)nContinuousStates;
    return unsupported(instance, "fmi3GetContinuousStates", NO_ME);
}
fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 nominals[],
                                             size_t nContinuousStates) {
    (void)nominals; (void)nContinuousStates;
    return unsupported(instance, "fmi3GetNominalsOfContinuousStates", NO_ME);
}
fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t *nEventIndicators) {
    (void)nEventIndicators;
    return unsupported(instance, "fmi3GetNumberOfEventIndicators", NO_ME);
}
fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t *nContinuousStates) {
    (void)nContinuousStates;
    return unsupported(instance, "fmi3GetNumberOfContinuousStates", NO_ME);
}

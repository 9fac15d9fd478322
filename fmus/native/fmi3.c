/* The FMI 3.0 co-simulation entry points of the native uplift FMUs, beside fmi2.c on the same
   runtime: the instance (instance.c), the model, its life cycle and step (model.c), the
   variables by element (variables.c), the FMU states with their checksummed format (state.c).

   What differs from FMI 2.0 is the interface, not the model:
   - the Float64 variables are arrays or scalars; each is a run of elements of the runtime's
     bank (resource record fmi3_float64: first element and length of the variable of value
     reference k; first = -1: the independent variable time), so fmi3GetFloat64 /
     fmi3SetFloat64 move whole arrays (nValues must be the sum of their lengths); the number N of interface nodes is the structural parameter N (UInt64,
     fixed at export: configuration mode is refused);
   - the stop time comes with fmi3EnterInitializationMode; fmi3DoStep reports the last
     successful time and never asks for event handling, termination or an early return;
   - no event mode (hasEventMode = false), no early return (canReturnEarlyAfterIntermediateUpdate
     = false), no intermediate update, no derivatives, no clocks: those calls are refused,
     logged; model exchange and scheduled execution are not instantiated.
   Every entry point opens with UP_GUARD(its name) and its allowed-state mask MASK_<name>
   (fmu.h); the refusals are fmi2.c's (a step at the wrong time, not finite or negative, past
   the stop time, of the wrong size, with a non-finite input or a wrong stamp: fmi3Error, the
   instance as it was; a step whose Newton iteration fails: fmi3Discard), every error logged
   (logStatusError), events when logging is on. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3Functions.h"
#include "fmu.h"

static void emit(UpInstance *I, int status, const char *category, const char *message)
{
    ((fmi3LogMessageCallback)I->logger)(I->env, (fmi3Status)status, category, message);
}

static const UpApi API = {"fmi3", "FMI 3.0", "fmi3EnterInitializationMode", emit};

#define UP_ERROR_STATUS fmi3Error
#define STATUS(rc) ((rc) ? fmi3Error : fmi3OK)

/* a call this FMU does not provide: fmi3Error, logged when the instance is one */
static fmi3Status unsupported(fmi3Instance c, const char *fn, const char *why)
{
    UpInstance *I = up_instance(c);
    if (I)
        up_log_error(I, "%s: %s", fn, why);
    return fmi3Error;
}

/* ---- inquiry, logging, life cycle ------------------------------------------------------------------ */
const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance c, fmi3Boolean loggingOn, size_t nCategories, const fmi3String categories[])
{
    UP_GUARD(fmi3SetDebugLogging);
    return STATUS(up_set_logging(I, "fmi3SetDebugLogging", loggingOn, nCategories, categories));
}

fmi3Instance fmi3InstantiateCoSimulation(fmi3String instanceName, fmi3String instantiationToken,
                                         fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                         fmi3Boolean eventModeUsed, fmi3Boolean earlyReturnAllowed,
                                         const fmi3ValueReference requiredIntermediateVariables[],
                                         size_t nRequiredIntermediateVariables,
                                         fmi3InstanceEnvironment instanceEnvironment,
                                         fmi3LogMessageCallback logMessage,
                                         fmi3IntermediateUpdateCallback intermediateUpdate)
{
    (void)visible, (void)earlyReturnAllowed, (void)requiredIntermediateVariables, (void)intermediateUpdate;
    const char *refusal = eventModeUsed ? "this FMU has no event mode (hasEventMode = false): instantiate it with "
                                          "eventModeUsed = false"
                          : nRequiredIntermediateVariables ? "this FMU provides no intermediate variables "
                                                             "(providesIntermediateUpdate = false)"
                                                           : NULL;
    return up_instantiate(&API, instanceName, instantiationToken, resourcePath, 0, (void (*)(void))logMessage,
                          instanceEnvironment, loggingOn, refusal);
}

static fmi3Instance not_co_simulation(fmi3InstanceEnvironment env, fmi3LogMessageCallback logMessage)
{
    if (logMessage)
        logMessage(env, fmi3Error, "logStatusError", "this FMU is for co-simulation only (fmi3InstantiateCoSimulation)");
    return NULL;
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment, fmi3LogMessageCallback logMessage)
{
    (void)instanceName, (void)instantiationToken, (void)resourcePath, (void)visible, (void)loggingOn;
    return not_co_simulation(instanceEnvironment, logMessage);
}

fmi3Instance fmi3InstantiateScheduledExecution(fmi3String instanceName, fmi3String instantiationToken,
                                               fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                               fmi3InstanceEnvironment instanceEnvironment,
                                               fmi3LogMessageCallback logMessage, fmi3ClockUpdateCallback clockUpdate,
                                               fmi3LockPreemptionCallback lockPreemption,
                                               fmi3UnlockPreemptionCallback unlockPreemption)
{
    (void)instanceName, (void)instantiationToken, (void)resourcePath, (void)visible, (void)loggingOn;
    (void)clockUpdate, (void)lockPreemption, (void)unlockPreemption;
    return not_co_simulation(instanceEnvironment, logMessage);
}

void fmi3FreeInstance(fmi3Instance c)
{
    UpInstance *I = up_instance(c);
    if (I)
        up_free_instance(I);
}

fmi3Status fmi3EnterInitializationMode(fmi3Instance c, fmi3Boolean toleranceDefined, fmi3Float64 tolerance,
                                       fmi3Float64 startTime, fmi3Boolean stopTimeDefined, fmi3Float64 stopTime)
{
    (void)toleranceDefined, (void)tolerance;
    UP_GUARD(fmi3EnterInitializationMode);
    if (up_setup_experiment(I, "fmi3EnterInitializationMode", stopTimeDefined, startTime, stopTime))
        return fmi3Error;
    return (fmi3Status)up_enter_initialisation(I);
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance c)
{
    UP_GUARD(fmi3ExitInitializationMode);
    return (fmi3Status)up_exit_initialisation(I);
}

fmi3Status fmi3EnterEventMode(fmi3Instance c)
{
    UP_GUARD(fmi3EnterEventMode);
    up_log_error(I, "fmi3EnterEventMode: this FMU has no event mode (hasEventMode = false)");
    return fmi3Error;
}

fmi3Status fmi3Terminate(fmi3Instance c)
{
    UP_GUARD(fmi3Terminate);
    I->state = UP_TERMINATED;                  /* from any state: a host ending a failed start too */
    return fmi3OK;
}

fmi3Status fmi3Reset(fmi3Instance c)
{
    UP_GUARD(fmi3Reset);
    up_reset(I);
    return fmi3OK;
}

/* ---- variables --------------------------------------------------------------------------------------- */
/* the run of elements (first, length) of the Float64 variable vr, or -1 logged */
static int float64_run(UpInstance *I, const char *fn, fmi3ValueReference vr, int64_t *first, int64_t *len)
{
    if ((int64_t)vr >= I->nvars3) {
        up_log_error(I, "%s: value reference %u: the Float64 variables of this FMU are 0..%lld", fn, vr,
                     (long long)I->nvars3 - 1);
        return -1;
    }
    *first = I->vars3[2 * vr];
    *len = I->vars3[2 * vr + 1];
    return 0;
}

/* the Float64 variables vr[0..nvr-1] exist, their lengths sum to nValues, and (setting) they are
   inputs; 0, or -1 logged */
static int float64_values(UpInstance *I, const char *fn, const fmi3ValueReference vr[], size_t nvr, const void *values,
                          size_t nValues, int setting)
{
    if (up_check_refs(I, fn, vr, nvr, values))
        return -1;
    size_t total = 0;
    for (size_t i = 0; i < nvr; i++) {
        int64_t first, len;
        if (float64_run(I, fn, vr[i], &first, &len))
            return -1;
        if (setting && (first < 0 || I->causality[first] != 0)) {
            up_log_error(I, "%s: value reference %u is an output: only inputs can be set", fn, vr[i]);
            return -1;
        }
        total += (size_t)len;
    }
    if (total != nValues) {
        up_log_error(I, "%s: nValues = %zu, the %zu variables have %zu values (an array gives all its elements)", fn,
                     nValues, nvr, total);
        return -1;
    }
    return 0;
}

fmi3Status fmi3GetFloat64(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Float64 values[],
                          size_t nValues)
{
    UP_GUARD(fmi3GetFloat64);
    if (float64_values(I, "fmi3GetFloat64", vr, nvr, values, nValues, 0))
        return fmi3Error;
    for (size_t i = 0, k = 0; i < nvr; i++) {
        int64_t first = I->vars3[2 * vr[i]], len = I->vars3[2 * vr[i] + 1];
        if (first >= 0)
            up_soil_read(I, first, len);
        memcpy(values + k, first < 0 ? I->time : I->bank + first, (size_t)len * sizeof(double));
        k += (size_t)len;
    }
    return fmi3OK;
}

fmi3Status fmi3SetFloat64(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3Float64 values[],
                          size_t nValues)
{
    UP_GUARD(fmi3SetFloat64);
    if (float64_values(I, "fmi3SetFloat64", vr, nvr, values, nValues, 1))
        return fmi3Error;
    for (size_t i = 0, k = 0; i < nvr; i++) {
        int64_t first = I->vars3[2 * vr[i]], len = I->vars3[2 * vr[i] + 1];
        memcpy(I->bank + first, values + k, (size_t)len * sizeof(double));
        k += (size_t)len;
    }
    return fmi3OK;
}

static int n_refs(UpInstance *I, const char *fn, const fmi3ValueReference vr[], size_t nvr, const void *values,
                  size_t nValues)
{
    if (up_check_refs(I, fn, vr, nvr, values))
        return -1;
    for (size_t i = 0; i < nvr; i++)
        if ((int64_t)vr[i] != I->vr3_N) {
            up_log_error(I, "%s: value reference %u: the only UInt64 variable of this FMU is N (%lld)", fn, vr[i],
                         (long long)I->vr3_N);
            return -1;
        }
    if (nValues != nvr) {
        up_log_error(I, "%s: nValues = %zu for %zu scalar variables", fn, nValues, nvr);
        return -1;
    }
    return 0;
}

fmi3Status fmi3GetUInt64(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3UInt64 values[],
                         size_t nValues)
{
    UP_GUARD(fmi3GetUInt64);
    if (n_refs(I, "fmi3GetUInt64", vr, nvr, values, nValues))
        return fmi3Error;
    for (size_t i = 0; i < nvr; i++)
        values[i] = (fmi3UInt64)I->N;
    return fmi3OK;
}

fmi3Status fmi3SetUInt64(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3UInt64 values[],
                         size_t nValues)
{
    UP_GUARD(fmi3SetUInt64);
    if (n_refs(I, "fmi3SetUInt64", vr, nvr, values, nValues))
        return fmi3Error;
    if (nvr == 0)
        return fmi3OK;
    up_log_error(I, "fmi3SetUInt64: N, the number of interface nodes, is fixed by the export (the scene's mesh): "
                 "export the FMU again for another mesh");
    return fmi3Error;
}

fmi3Status fmi3GetBoolean(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Boolean values[],
                          size_t nValues)
{
    UP_GUARD(fmi3GetBoolean);
    if (up_boolean_refs(I, "fmi3GetBoolean", vr, nvr, values, 0))
        return fmi3Error;
    if (nValues != nvr) {
        up_log_error(I, "fmi3GetBoolean: nValues = %zu for %zu scalar variables", nValues, nvr);
        return fmi3Error;
    }
    for (size_t i = 0; i < nvr; i++)
        values[i] = *I->internal_motion != 0.0;
    return fmi3OK;
}

fmi3Status fmi3SetBoolean(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3Boolean values[],
                          size_t nValues)
{
    UP_GUARD(fmi3SetBoolean);
    if (up_boolean_refs(I, "fmi3SetBoolean", vr, nvr, values, 1))
        return fmi3Error;
    if (nValues != nvr) {
        up_log_error(I, "fmi3SetBoolean: nValues = %zu for %zu scalar variables", nValues, nvr);
        return fmi3Error;
    }
    for (size_t i = 0; i < nvr; i++)
        *I->internal_motion = values[i] ? 1.0 : 0.0;
    return fmi3OK;
}

/* the types this FMU has no variables of: an empty get or set succeeds, any other is refused */
static fmi3Status no_variables(fmi3Instance c, const char *fn, const char *type, const fmi3ValueReference vr[],
                               size_t nvr, const void *values)
{
    UpInstance *I = up_guard(c, UP_ANY_STATE, fn);
    return !I ? fmi3Error : STATUS(up_no_variables(I, fn, type, vr, nvr, values));
}

#define NO_VARIABLES(T, type)                                                                                    \
    fmi3Status fmi3Get##T(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, type values[], size_t nValues) \
    {                                                                                                            \
        (void)nValues;                                                                                           \
        return no_variables(c, "fmi3Get" #T, #T, vr, nvr, values);                                               \
    }                                                                                                            \
    fmi3Status fmi3Set##T(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const type values[],         \
                          size_t nValues)                                                                        \
    {                                                                                                            \
        (void)nValues;                                                                                           \
        return no_variables(c, "fmi3Set" #T, #T, vr, nvr, values);                                               \
    }
NO_VARIABLES(Float32, fmi3Float32)
NO_VARIABLES(Int8, fmi3Int8)
NO_VARIABLES(UInt8, fmi3UInt8)
NO_VARIABLES(Int16, fmi3Int16)
NO_VARIABLES(UInt16, fmi3UInt16)
NO_VARIABLES(Int32, fmi3Int32)
NO_VARIABLES(UInt32, fmi3UInt32)
NO_VARIABLES(Int64, fmi3Int64)
NO_VARIABLES(String, fmi3String)

fmi3Status fmi3GetBinary(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, size_t valueSizes[],
                         fmi3Binary values[], size_t nValues)
{
    (void)valueSizes, (void)nValues;
    return no_variables(c, "fmi3GetBinary", "Binary", vr, nvr, values);
}

fmi3Status fmi3SetBinary(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const size_t valueSizes[],
                         const fmi3Binary values[], size_t nValues)
{
    (void)valueSizes, (void)nValues;
    return no_variables(c, "fmi3SetBinary", "Binary", vr, nvr, values);
}

fmi3Status fmi3GetClock(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Clock values[])
{
    return no_variables(c, "fmi3GetClock", "Clock", vr, nvr, values);
}

fmi3Status fmi3SetClock(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3Clock values[])
{
    return no_variables(c, "fmi3SetClock", "Clock", vr, nvr, values);
}

/* ---- FMU states ---------------------------------------------------------------------------------------- */
fmi3Status fmi3GetFMUState(fmi3Instance c, fmi3FMUState *s)
{
    UP_GUARD(fmi3GetFMUState);
    return STATUS(up_state_get(I, "fmi3GetFMUState", s));
}

fmi3Status fmi3SetFMUState(fmi3Instance c, fmi3FMUState s)
{
    UP_GUARD(fmi3SetFMUState);
    return STATUS(up_state_set(I, "fmi3SetFMUState", s));
}

fmi3Status fmi3FreeFMUState(fmi3Instance c, fmi3FMUState *s)
{
    UP_GUARD(fmi3FreeFMUState);
    return STATUS(up_state_free(I, "fmi3FreeFMUState", s));
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance c, fmi3FMUState s, size_t *size)
{
    UP_GUARD(fmi3SerializedFMUStateSize);
    return STATUS(up_state_size(I, "fmi3SerializedFMUStateSize", s, size));
}

fmi3Status fmi3SerializeFMUState(fmi3Instance c, fmi3FMUState s, fmi3Byte serializedState[], size_t size)
{
    UP_GUARD(fmi3SerializeFMUState);
    return STATUS(up_state_serialize(I, "fmi3SerializeFMUState", s, (unsigned char *)serializedState, size));
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance c, const fmi3Byte serializedState[], size_t size, fmi3FMUState *s)
{
    UP_GUARD(fmi3DeserializeFMUState);
    return STATUS(up_state_deserialize(I, "fmi3DeserializeFMUState", (const unsigned char *)serializedState, size, s));
}

/* ---- co-simulation -------------------------------------------------------------------------------------- */
fmi3Status fmi3DoStep(fmi3Instance c, fmi3Float64 currentCommunicationPoint, fmi3Float64 communicationStepSize,
                      fmi3Boolean noSetFMUStatePriorToCurrentPoint, fmi3Boolean *eventHandlingNeeded,
                      fmi3Boolean *terminateSimulation, fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime)
{
    (void)noSetFMUStatePriorToCurrentPoint;
    UP_GUARD(fmi3DoStep);
    if (!eventHandlingNeeded || !terminateSimulation || !earlyReturn || !lastSuccessfulTime) {
        up_log_error(I, "fmi3DoStep: NULL eventHandlingNeeded, terminateSimulation, earlyReturn or lastSuccessfulTime");
        return fmi3Error;
    }
    fmi3Status status = (fmi3Status)up_do_step(I, currentCommunicationPoint, communicationStepSize);
    *eventHandlingNeeded = *terminateSimulation = *earlyReturn = fmi3False;
    *lastSuccessfulTime = *I->time;
    return status;
}

fmi3Status fmi3GetOutputDerivatives(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3Int32 orders[],
                                    fmi3Float64 values[], size_t nValues)
{
    (void)vr, (void)orders, (void)values, (void)nValues;
    UP_GUARD(fmi3GetOutputDerivatives);
    if (nvr == 0)
        return fmi3OK;
    up_log_error(I, "fmi3GetOutputDerivatives: this FMU provides no output derivatives (maxOutputDerivativeOrder = 0)");
    return fmi3Error;
}

/* ---- what this FMU does not provide --------------------------------------------------------------------- */
#define NO_EVENT_MODE "this FMU has no event mode (hasEventMode = false)"
#define CO_SIMULATION "this FMU is for co-simulation only"

fmi3Status fmi3EnterStepMode(fmi3Instance c) { return unsupported(c, "fmi3EnterStepMode", NO_EVENT_MODE); }

fmi3Status fmi3EnterConfigurationMode(fmi3Instance c)
{
    return unsupported(c, "fmi3EnterConfigurationMode", "the structural parameter N is fixed by the export (export "
                       "the FMU again for another mesh)");
}

fmi3Status fmi3ExitConfigurationMode(fmi3Instance c)
{
    return unsupported(c, "fmi3ExitConfigurationMode", "configuration mode is never entered");
}

fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance c, fmi3ValueReference valueReference, size_t *nDependencies)
{
    (void)valueReference, (void)nDependencies;
    return unsupported(c, "fmi3GetNumberOfVariableDependencies", "not provided (the outputs have no direct "
                       "feedthrough: see ModelStructure)");
}

fmi3Status fmi3GetVariableDependencies(fmi3Instance c, fmi3ValueReference dependent, size_t elementIndicesOfDependent[],
                                       fmi3ValueReference independents[], size_t elementIndicesOfIndependents[],
                                       fmi3DependencyKind dependencyKinds[], size_t nDependencies)
{
    (void)dependent, (void)elementIndicesOfDependent, (void)independents, (void)elementIndicesOfIndependents;
    (void)dependencyKinds, (void)nDependencies;
    return unsupported(c, "fmi3GetVariableDependencies", "not provided (the outputs have no direct feedthrough: see "
                       "ModelStructure)");
}

fmi3Status fmi3GetDirectionalDerivative(fmi3Instance c, const fmi3ValueReference unknowns[], size_t nUnknowns,
                                        const fmi3ValueReference knowns[], size_t nKnowns, const fmi3Float64 seed[],
                                        size_t nSeed, fmi3Float64 sensitivity[], size_t nSensitivity)
{
    (void)unknowns, (void)nUnknowns, (void)knowns, (void)nKnowns, (void)seed, (void)nSeed, (void)sensitivity;
    (void)nSensitivity;
    return unsupported(c, "fmi3GetDirectionalDerivative", "not provided (providesDirectionalDerivatives = false)");
}

fmi3Status fmi3GetAdjointDerivative(fmi3Instance c, const fmi3ValueReference unknowns[], size_t nUnknowns,
                                    const fmi3ValueReference knowns[], size_t nKnowns, const fmi3Float64 seed[],
                                    size_t nSeed, fmi3Float64 sensitivity[], size_t nSensitivity)
{
    (void)unknowns, (void)nUnknowns, (void)knowns, (void)nKnowns, (void)seed, (void)nSeed, (void)sensitivity;
    (void)nSensitivity;
    return unsupported(c, "fmi3GetAdjointDerivative", "not provided (providesAdjointDerivatives = false)");
}

fmi3Status fmi3GetIntervalDecimal(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Float64 intervals[],
                                  fmi3IntervalQualifier qualifiers[])
{
    (void)vr, (void)nvr, (void)intervals, (void)qualifiers;
    return unsupported(c, "fmi3GetIntervalDecimal", "this FMU has no clocks");
}

fmi3Status fmi3GetIntervalFraction(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3UInt64 counters[],
                                   fmi3UInt64 resolutions[], fmi3IntervalQualifier qualifiers[])
{
    (void)vr, (void)nvr, (void)counters, (void)resolutions, (void)qualifiers;
    return unsupported(c, "fmi3GetIntervalFraction", "this FMU has no clocks");
}

fmi3Status fmi3GetShiftDecimal(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3Float64 shifts[])
{
    (void)vr, (void)nvr, (void)shifts;
    return unsupported(c, "fmi3GetShiftDecimal", "this FMU has no clocks");
}

fmi3Status fmi3GetShiftFraction(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, fmi3UInt64 counters[],
                                fmi3UInt64 resolutions[])
{
    (void)vr, (void)nvr, (void)counters, (void)resolutions;
    return unsupported(c, "fmi3GetShiftFraction", "this FMU has no clocks");
}

fmi3Status fmi3SetIntervalDecimal(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                                  const fmi3Float64 intervals[])
{
    (void)vr, (void)nvr, (void)intervals;
    return unsupported(c, "fmi3SetIntervalDecimal", "this FMU has no clocks");
}

fmi3Status fmi3SetIntervalFraction(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                                   const fmi3UInt64 counters[], const fmi3UInt64 resolutions[])
{
    (void)vr, (void)nvr, (void)counters, (void)resolutions;
    return unsupported(c, "fmi3SetIntervalFraction", "this FMU has no clocks");
}

fmi3Status fmi3SetShiftDecimal(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3Float64 shifts[])
{
    (void)vr, (void)nvr, (void)shifts;
    return unsupported(c, "fmi3SetShiftDecimal", "this FMU has no clocks");
}

fmi3Status fmi3SetShiftFraction(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr, const fmi3UInt64 counters[],
                                const fmi3UInt64 resolutions[])
{
    (void)vr, (void)nvr, (void)counters, (void)resolutions;
    return unsupported(c, "fmi3SetShiftFraction", "this FMU has no clocks");
}

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance c)
{
    return unsupported(c, "fmi3EvaluateDiscreteStates", NO_EVENT_MODE);
}

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance c, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation, fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged, fmi3Boolean *nextEventTimeDefined,
                                    fmi3Float64 *nextEventTime)
{
    (void)discreteStatesNeedUpdate, (void)terminateSimulation, (void)nominalsOfContinuousStatesChanged;
    (void)valuesOfContinuousStatesChanged, (void)nextEventTimeDefined, (void)nextEventTime;
    return unsupported(c, "fmi3UpdateDiscreteStates", NO_EVENT_MODE);
}

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance c)
{
    return unsupported(c, "fmi3EnterContinuousTimeMode", CO_SIMULATION);
}

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance c, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode, fmi3Boolean *terminateSimulation)
{
    (void)noSetFMUStatePriorToCurrentPoint, (void)enterEventMode, (void)terminateSimulation;
    return unsupported(c, "fmi3CompletedIntegratorStep", CO_SIMULATION);
}

fmi3Status fmi3SetTime(fmi3Instance c, fmi3Float64 time)
{
    (void)time;
    return unsupported(c, "fmi3SetTime", CO_SIMULATION);
}

fmi3Status fmi3SetContinuousStates(fmi3Instance c, const fmi3Float64 continuousStates[], size_t nContinuousStates)
{
    (void)continuousStates, (void)nContinuousStates;
    return unsupported(c, "fmi3SetContinuousStates", CO_SIMULATION);
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance c, fmi3Float64 derivatives[], size_t nContinuousStates)
{
    (void)derivatives, (void)nContinuousStates;
    return unsupported(c, "fmi3GetContinuousStateDerivatives", CO_SIMULATION);
}

fmi3Status fmi3GetEventIndicators(fmi3Instance c, fmi3Float64 eventIndicators[], size_t nEventIndicators)
{
    (void)eventIndicators, (void)nEventIndicators;
    return unsupported(c, "fmi3GetEventIndicators", CO_SIMULATION);
}

fmi3Status fmi3GetContinuousStates(fmi3Instance c, fmi3Float64 continuousStates[], size_t nContinuousStates)
{
    (void)continuousStates, (void)nContinuousStates;
    return unsupported(c, "fmi3GetContinuousStates", CO_SIMULATION);
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance c, fmi3Float64 nominals[], size_t nContinuousStates)
{
    (void)nominals, (void)nContinuousStates;
    return unsupported(c, "fmi3GetNominalsOfContinuousStates", CO_SIMULATION);
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance c, size_t *nEventIndicators)
{
    (void)nEventIndicators;
    return unsupported(c, "fmi3GetNumberOfEventIndicators", CO_SIMULATION);
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance c, size_t *nContinuousStates)
{
    (void)nContinuousStates;
    return unsupported(c, "fmi3GetNumberOfContinuousStates", CO_SIMULATION);
}

fmi3Status fmi3ActivateModelPartition(fmi3Instance c, fmi3ValueReference clockReference, fmi3Float64 activationTime)
{
    (void)clockReference, (void)activationTime;
    return unsupported(c, "fmi3ActivateModelPartition", CO_SIMULATION);
}

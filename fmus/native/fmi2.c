/* The FMI 2.0 co-simulation entry points of the native uplift FMUs, on the runtime the FMI 3.0
   layer (fmi3.c) shares: the instance (instance.c), the model, its life cycle and step
   (model.c), the variables (variables.c), the FMU states (state.c). Behaves as the Python FMUs
   (fmus/slave.py): the same refusals, with the messages of fmus/schema.py (uplift_messages.h).

   Every entry point opens with UP_GUARD(its name): the instance is checked and the call is
   allowed only in the states of its mask MASK_<name> (fmu.h, in the manner of the Modelica
   Reference-FMUs); a call in another state is refused with fmi2Error and a message naming the
   state, the instance unchanged. A call that cannot be right returns fmi2Error with the
   instance as it was: a step at the wrong time, not finite or negative, past the stop time of
   fmi2SetupExperiment, of the wrong size (the coupled FMU takes any multiple of dt, the pair
   exactly dt; a step shorter than UP_SLIVER dt is a no-op that returns OK, one within
   UP_STEP_RTOL of a whole number of dt is that number, more than UP_MAX_STEPS_PER_CALL steps
   are refused up front), with a non-finite input or a wrong time stamp. A step whose Newton
   iteration fails (after its halvings) returns fmi2Discard, the instance as it was. Errors go
   to the logger always (logStatusError); events (instantiation, steps) when logging is on
   (fmi2Instantiate's loggingOn, fmi2SetDebugLogging). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "fmu.h"

/* FMI2_FUNCTION_PREFIX prefixes the entry points too, also with FMI 2.0 headers whose
   fmi2FullName ignores it (fmpy's) */
#ifdef FMI2_FUNCTION_PREFIX
#undef fmi2FullName
#define fmi2FullName(name) UP_PASTE(FMI2_FUNCTION_PREFIX, name)
#endif

static void emit(UpInstance *I, int status, const char *category, const char *message)
{
    ((fmi2CallbackLogger)I->logger)(I->env, I->name, (fmi2Status)status, category, message);
}

static const UpApi API = {"fmi2", "FMI 2.0", "fmi2SetupExperiment", emit};

#define UP_ERROR_STATUS fmi2Error
#define STATUS(rc) ((rc) ? fmi2Error : fmi2OK)

/* ---- FMI 2.0: common functions ------------------------------------------------------------------- */
const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories, const fmi2String categories[])
{
    UP_GUARD(fmi2SetDebugLogging);
    return STATUS(up_set_logging(I, "fmi2SetDebugLogging", loggingOn != fmi2False, nCategories, categories));
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn)
{
    (void)visible;
    return up_instantiate(&API, instanceName, fmuGUID, fmuResourceLocation, 1,
                          functions ? (void (*)(void))functions->logger : NULL,
                          functions ? functions->componentEnvironment : NULL, loggingOn != fmi2False,
                          fmuType != fmi2CoSimulation ? "this FMU is for co-simulation only (fmuType = fmi2CoSimulation)"
                                                      : NULL);
}

void fmi2FreeInstance(fmi2Component c)
{
    UpInstance *I = up_instance(c);
    if (I)
        up_free_instance(I);
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime)
{
    (void)toleranceDefined, (void)tolerance;
    UP_GUARD(fmi2SetupExperiment);
    return STATUS(up_setup_experiment(I, "fmi2SetupExperiment", stopTimeDefined != fmi2False, startTime, stopTime));
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c)
{
    UP_GUARD(fmi2EnterInitializationMode);
    return (fmi2Status)up_enter_initialisation(I);
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c)
{
    UP_GUARD(fmi2ExitInitializationMode);
    return (fmi2Status)up_exit_initialisation(I);
}

fmi2Status fmi2Terminate(fmi2Component c)
{
    UP_GUARD(fmi2Terminate);
    I->state = UP_TERMINATED;                  /* from any state: a host ending a failed start too */
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c)
{
    UP_GUARD(fmi2Reset);
    up_reset(I);
    return fmi2OK;
}

/* ---- FMI 2.0: variables ----------------------------------------------------------------------------- */
fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[])
{
    UP_GUARD(fmi2GetReal);
    return STATUS(up_get_reals(I, "fmi2GetReal", vr, nvr, value));
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[])
{
    UP_GUARD(fmi2SetReal);
    return STATUS(up_set_reals(I, "fmi2SetReal", vr, nvr, value));
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[])
{
    UP_GUARD(fmi2GetBoolean);
    if (up_boolean_refs(I, "fmi2GetBoolean", vr, nvr, value, 0))
        return fmi2Error;
    for (size_t i = 0; i < nvr; i++)
        value[i] = *I->internal_motion != 0.0 ? fmi2True : fmi2False;
    return fmi2OK;
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Boolean value[])
{
    UP_GUARD(fmi2SetBoolean);
    if (up_boolean_refs(I, "fmi2SetBoolean", vr, nvr, value, 1))
        return fmi2Error;
    for (size_t i = 0; i < nvr; i++)
        *I->internal_motion = value[i] != fmi2False;
    return fmi2OK;
}

static fmi2Status no_variables(fmi2Component c, const char *fn, const char *type, const fmi2ValueReference vr[],
                               size_t nvr, const void *value)
{
    UpInstance *I = up_guard(c, UP_ANY_STATE, fn);
    return !I ? fmi2Error : STATUS(up_no_variables(I, fn, type, vr, nvr, value));
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[])
{
    return no_variables(c, "fmi2GetInteger", "Integer", vr, nvr, value);
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[])
{
    return no_variables(c, "fmi2SetInteger", "Integer", vr, nvr, value);
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String value[])
{
    return no_variables(c, "fmi2GetString", "String", vr, nvr, value);
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[])
{
    return no_variables(c, "fmi2SetString", "String", vr, nvr, value);
}

/* ---- FMI 2.0: FMU states ----------------------------------------------------------------------------- */
fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *s)
{
    UP_GUARD(fmi2GetFMUstate);
    return STATUS(up_state_get(I, "fmi2GetFMUstate", s));
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate s)
{
    UP_GUARD(fmi2SetFMUstate);
    return STATUS(up_state_set(I, "fmi2SetFMUstate", s));
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *s)
{
    UP_GUARD(fmi2FreeFMUstate);
    return STATUS(up_state_free(I, "fmi2FreeFMUstate", s));
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t *size)
{
    UP_GUARD(fmi2SerializedFMUstateSize);
    return STATUS(up_state_size(I, "fmi2SerializedFMUstateSize", s, size));
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte bytes[], size_t size)
{
    UP_GUARD(fmi2SerializeFMUstate);
    return STATUS(up_state_serialize(I, "fmi2SerializeFMUstate", s, (unsigned char *)bytes, size));
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte bytes[], size_t size, fmi2FMUstate *s)
{
    UP_GUARD(fmi2DeSerializeFMUstate);
    return STATUS(up_state_deserialize(I, "fmi2DeSerializeFMUstate", (const unsigned char *)bytes, size, s));
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[], size_t nUnknown,
                                        const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[])
{
    (void)vUnknown_ref, (void)nUnknown, (void)vKnown_ref, (void)nKnown, (void)dvKnown, (void)dvUnknown;
    UpInstance *I = up_instance(c);
    if (I)
        up_log_error(I, "fmi2GetDirectionalDerivative: not provided by this FMU (providesDirectionalDerivative = false)");
    return fmi2Error;
}

/* ---- FMI 2.0: co-simulation ----------------------------------------------------------------------------- */
fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[])
{
    (void)vr, (void)order, (void)value;
    UP_GUARD(fmi2SetRealInputDerivatives);
    if (nvr == 0)
        return fmi2OK;
    up_log_error(I, "fmi2SetRealInputDerivatives: this FMU does not interpolate inputs (canInterpolateInputs = false)");
    return fmi2Error;
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[])
{
    (void)vr, (void)order, (void)value;
    UP_GUARD(fmi2GetRealOutputDerivatives);
    if (nvr == 0)
        return fmi2OK;
    up_log_error(I, "fmi2GetRealOutputDerivatives: this FMU provides no output derivatives "
              "(maxOutputDerivativeOrder = 0)");
    return fmi2Error;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSetFMUStatePriorToCurrentPoint)
{
    (void)noSetFMUStatePriorToCurrentPoint;
    UP_GUARD(fmi2DoStep);
    return (fmi2Status)up_do_step(I, t, h);
}

fmi2Status fmi2CancelStep(fmi2Component c)
{
    UP_GUARD(fmi2CancelStep);
    up_log_error(I, "fmi2CancelStep: this FMU computes its steps synchronously, there is nothing to cancel");
    return fmi2Error;
}

static fmi2Status status_kind(fmi2Component c, fmi2StatusKind s, const char *fn, int allowed)
{
    UpInstance *I = up_guard(c, UP_ANY_STATE, fn);
    if (!I)
        return fmi2Error;
    if ((int)s != allowed) {
        up_log_error(I, "%s: status kind %d is not available (this FMU never returns fmi2Pending)", fn, (int)s);
        return fmi2Discard;
    }
    return fmi2OK;
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value)
{
    fmi2Status r = status_kind(c, s, "fmi2GetStatus", fmi2DoStepStatus);
    if (r == fmi2OK && value)
        *value = fmi2OK;
    return value || r != fmi2OK ? r : fmi2Error;
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value)
{
    fmi2Status r = status_kind(c, s, "fmi2GetRealStatus", fmi2LastSuccessfulTime);
    if (r == fmi2OK && value)
        *value = *((UpInstance *)c)->time;
    return value || r != fmi2OK ? r : fmi2Error;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value)
{
    (void)value;
    return status_kind(c, s, "fmi2GetIntegerStatus", -1);
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value)
{
    fmi2Status r = status_kind(c, s, "fmi2GetBooleanStatus", fmi2Terminated);
    if (r == fmi2OK && value)
        *value = fmi2False;
    return value || r != fmi2OK ? r : fmi2Error;
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value)
{
    (void)value;
    return status_kind(c, s, "fmi2GetStringStatus", -1);
}

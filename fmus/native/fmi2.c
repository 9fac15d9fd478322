/* The FMI 2.0 co-simulation entry points of the native uplift FMUs: the life cycle, the step,
   the status queries (the variables are in variables.c, the FMU states in state.c). Behaves as
   the Python FMUs (fmus/slave.py): the same refusals, with the messages of fmus/schema.py
   (uplift_messages.h).

   Every entry point opens with UP_GUARD(its name): the instance is checked and the call is
   allowed only in the states of its mask MASK_<name> (below, in the manner of the Modelica
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

#include "fmu.h"

/* ---- the guard of every entry point (the masks are in fmu.h) ------------------------------------ */
UpInstance *up_guard(fmi2Component c, int mask, const char *fn)
{
    UpInstance *I = up_instance(c);
    if (!I || (I->state & mask))
        return I;
    if (mask & UP_STEPPING)                   /* a call of the stepping phase, too early or too late */
        up_log_error(I, I->state == UP_TERMINATED ? UP_MSG_AFTER_TERMINATE : UP_MSG_BEFORE_INIT, fn);
    else
        up_log_error(I, UP_MSG_WRONG_STATE, fn,
                     I->state == UP_INSTANTIATED     ? "before fmi2EnterInitializationMode"
                     : I->state == UP_INITIALISATION ? "in initialisation mode"
                     : I->state == UP_STEPPING       ? "after initialisation (fmi2Reset first)"
                                                     : "after fmi2Terminate (fmi2Reset first)");
    return NULL;
}

/* ---- FMI 2.0: common functions ------------------------------------------------------------------- */
const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories, const fmi2String categories[])
{
    UP_GUARD(fmi2SetDebugLogging);
    if (nCategories > 0 && !categories) {
        up_log_error(I, "fmi2SetDebugLogging: categories is NULL with nCategories = %zu", nCategories);
        return fmi2Error;
    }
    for (size_t k = 0; k < nCategories; k++)
        if (!categories[k] || (strcmp(categories[k], "logEvents") && strcmp(categories[k], "logStatusError"))) {
            up_log_error(I, "fmi2SetDebugLogging: unknown log category %s (this FMU has logEvents and "
                         "logStatusError)", categories[k] ? categories[k] : "(null)");
            return fmi2Error;
        }
    I->logging = loggingOn != fmi2False;
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn)
{
    (void)visible;
    UpInstance *I = (UpInstance *)calloc(1, sizeof(UpInstance));
    if (!I)
        return NULL;
    I->magic = UP_INSTANCE_MAGIC;
    I->stop_time = INFINITY;
    snprintf(I->name, sizeof I->name, "%s", instanceName ? instanceName : "uplift");
    if (functions) {
        I->logger = functions->logger;
        I->env = functions->componentEnvironment;
    }
    I->logging = loggingOn != fmi2False;
    if (!instanceName || !*instanceName)
        snprintf(I->err, UP_MSG, "instanceName is empty: give the instance a name");
    else if (fmuType != fmi2CoSimulation)
        snprintf(I->err, UP_MSG, "this FMU is for co-simulation only (fmuType = fmi2CoSimulation)");
    else if (up_setup(I, fmuGUID, fmuResourceLocation) == 0) {
        I->state = UP_INSTANTIATED;
        up_log_event(I, "instantiated from %s: %d Real variables, dt = %g s", I->res.path, I->n_real, I->dt);
        return I;
    }
    up_log_error(I, "instantiation failed: %s", I->err);
    up_free_instance(I);
    return NULL;
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
    if (stopTimeDefined && !(stopTime >= startTime)) {
        char b1[32], b2[32];
        up_log_error(I, "fmi2SetupExperiment: stop time %s s before the start time %s s", up_num(stopTime, b1),
                     up_num(startTime, b2));
        return fmi2Error;
    }
    I->start_time = startTime;
    I->stop_time = stopTimeDefined ? stopTime : INFINITY;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c)
{
    UP_GUARD(fmi2EnterInitializationMode);
    if (up_initial_state(I)) {
        up_log_error(I, "initialisation failed: %s", I->err);
        return fmi2Error;
    }
    I->state = UP_INITIALISATION;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c)
{
    UP_GUARD(fmi2ExitInitializationMode);
    if (up_initial_state(I)) {                 /* inputs and parameters set during initialisation */
        up_log_error(I, "initialisation failed: %s", I->err);
        return fmi2Error;
    }
    I->state = UP_STEPPING;
    return fmi2OK;
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
    memset(I->block, 0, I->block_len * sizeof(double));
    *I->internal_motion = I->has_motion;
    I->start_time = 0.0;
    I->stop_time = INFINITY;
    I->state = UP_INSTANTIATED;
    return fmi2OK;
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

/* a call that cannot be right: fmi2Error, logged, the instance as it was */
static fmi2Status refuse(UpInstance *I, double t, const char *why)
{
    char b[32];
    up_log_error(I, UP_MSG_REFUSED, up_num(t, b), why);
    return fmi2Error;
}

/* The number of steps of dt in a communication step of h from t (0: a sliver, a no-op), or -1
   with the reason in why (fmus.schema: SLIVER, STEP_RTOL, TIME_TOL, MAX_STEPS_PER_CALL) */
static double steps_of(UpInstance *I, double t, double h, char *why)
{
    char b1[32], b2[32], b3[32];
    double dt = I->dt;
    if (!(isfinite(t) && fabs(t - *I->time) <= UP_TIME_TOL * dt)) {
        snprintf(why, UP_MSG, UP_MSG_WRONG_TIME, up_num(*I->time, b1));
        return -1;
    }
    if (!(isfinite(h) && h >= 0)) {
        snprintf(why, UP_MSG, UP_MSG_BAD_STEP, up_num(h, b1));
        return -1;
    }
    if (t + h > I->stop_time + UP_TIME_TOL * dt) {
        snprintf(why, UP_MSG, UP_MSG_PAST_STOP, up_num(h, b1), up_num(t + h, b2), up_num(I->stop_time, b3));
        return -1;
    }
    if (h < UP_SLIVER * dt)
        return 0;
    /* the coupled FMU takes any multiple of dt (steps of dt inside); the pair exactly dt, the
       step its coupling is exchanged at */
    int multistep = I->role == ROLE_COUPLED;
    double steps = multistep ? floor(h / dt + 0.5) : 1.0;
    if (steps > UP_MAX_STEPS_PER_CALL) {
        snprintf(b2, sizeof b2, "%d", UP_MAX_STEPS_PER_CALL);
        snprintf(why, UP_MSG, UP_MSG_TOO_MANY_STEPS, up_num(h, b1), b2, up_num(dt, b3));
        return -1;
    }
    if (!(steps >= 1 && fabs(h - steps * dt) <= UP_STEP_RTOL * h)) {
        snprintf(why, UP_MSG, UP_MSG_WRONG_STEP, up_num(h, b1), multistep ? "a multiple" : "exactly", up_num(dt, b2));
        return -1;
    }
    for (int k = 0; k < NSLOT; k++) {
        if (I->slot[k] < 0 || I->causality[I->slot[k]] != 0)
            continue;                                         /* the inputs only */
        const double *v = up_var(I, k);
        for (int i = 0; i < I->slot_len[k]; i++)
            if (!isfinite(v[i])) {
                char name[48];
                snprintf(why, UP_MSG, UP_MSG_NOT_FINITE, up_element_name(I, k, i, name), up_num(v[i], b1));
                return -1;
            }
    }
    return steps;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSetFMUStatePriorToCurrentPoint)
{
    (void)noSetFMUStatePriorToCurrentPoint;
    UP_GUARD(fmi2DoStep);
    char b1[32], why[UP_MSG];
    double steps = steps_of(I, t, h, why);
    if (steps < 0)
        return refuse(I, t, why);
    if (steps == 0) {                                         /* a sliver: nothing to compute */
        *I->time = t + h;
        return fmi2OK;
    }
    memcpy(I->backup, I->block, I->block_len * sizeof(double));
    int rc = 0;
    for (long i = 0; i < (long)steps && rc == 0; i++)
        rc = up_step(I, t + (double)i * I->dt);
    if (rc) {
        memcpy(I->block, I->backup, I->block_len * sizeof(double));     /* the instance as it was */
        if (rc == UP_REFUSED)
            return refuse(I, t, I->err);
        up_log_error(I, "step from t = %s s failed: %s", up_num(t, b1), I->err);
        return fmi2Discard;                                           /* no Newton convergence */
    }
    *I->time = t + h;
    up_log_event(I, "step from t = %s s: %ld step(s) of dt", up_num(t, b1), (long)steps);
    return fmi2OK;
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

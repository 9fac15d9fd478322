/* fmi2Get/Set of the variables: the Reals in one bank indexed by value reference, the Boolean
   parameter internal_motion; no Integer or String variables. */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmu.h"

int up_check_refs(UpInstance *I, const char *fn, const fmi2ValueReference vr[], size_t nvr, const void *value)
{
    if (nvr > 0 && (!vr || !value)) {
        up_log_error(I, "%s: NULL value reference or value array with nvr = %zu", fn, nvr);
        return -1;
    }
    return 0;
}

static int check_real_refs(UpInstance *I, const char *fn, const fmi2ValueReference vr[], size_t nvr, const void *value)
{
    if (up_check_refs(I, fn, vr, nvr, value))
        return -1;
    unsigned lo = 0, hi = 0;
    int bad = 0;
    for (size_t i = 0; i < nvr; i++)
        if (vr[i] >= (unsigned)I->n_real) {
            lo = bad ? (vr[i] < lo ? vr[i] : lo) : vr[i];
            hi = bad ? (vr[i] > hi ? vr[i] : hi) : vr[i];
            bad = 1;
        }
    if (bad) {
        up_log_error(I, "%s: value references %u..%u: the Real variables of this FMU are 0..%d", fn, lo, hi, I->n_real - 1);
        return -1;
    }
    return 0;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[])
{
    UP_GUARD(fmi2GetReal);
    if (check_real_refs(I, "fmi2GetReal", vr, nvr, value))
        return fmi2Error;
    for (size_t i = 0; i < nvr; i++)
        value[i] = I->bank[vr[i]];
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[])
{
    UP_GUARD(fmi2SetReal);
    if (check_real_refs(I, "fmi2SetReal", vr, nvr, value))
        return fmi2Error;
    for (size_t i = 0; i < nvr; i++)
        if (I->causality[vr[i]] != 0) {
            up_log_error(I, "fmi2SetReal: value reference %u is an output: only inputs can be set", vr[i]);
            return fmi2Error;
        }
    for (size_t i = 0; i < nvr; i++)
        I->bank[vr[i]] = value[i];
    return fmi2OK;
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[])
{
    UP_GUARD(fmi2GetBoolean);
    if (up_check_refs(I, "fmi2GetBoolean", vr, nvr, value))
        return fmi2Error;
    for (size_t i = 0; i < nvr; i++) {
        if ((int64_t)vr[i] != I->vr_internal_motion) {
            up_log_error(I, "fmi2GetBoolean: value reference %u: the only Boolean variable of this FMU is "
                      "internal_motion (%lld)", vr[i], (long long)I->vr_internal_motion);
            return fmi2Error;
        }
        value[i] = *I->internal_motion != 0.0 ? fmi2True : fmi2False;
    }
    return fmi2OK;
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Boolean value[])
{
    UP_GUARD(fmi2SetBoolean);
    if (up_check_refs(I, "fmi2SetBoolean", vr, nvr, value))
        return fmi2Error;
    for (size_t i = 0; i < nvr; i++) {
        if ((int64_t)vr[i] != I->vr_internal_motion) {
            up_log_error(I, "fmi2SetBoolean: value reference %u: the only Boolean variable of this FMU is "
                      "internal_motion (%lld)", vr[i], (long long)I->vr_internal_motion);
            return fmi2Error;
        }
        if (I->state != UP_INSTANTIATED && I->state != UP_INITIALISATION) {
            up_log_error(I, "fmi2SetBoolean: internal_motion is a fixed parameter: set it before "
                      "fmi2ExitInitializationMode");
            return fmi2Error;
        }
    }
    for (size_t i = 0; i < nvr; i++)
        *I->internal_motion = value[i] != fmi2False;
    return fmi2OK;
}

static fmi2Status no_variables(fmi2Component c, const char *fn, const char *type, const fmi2ValueReference vr[],
                               size_t nvr, const void *value)
{
    UpInstance *I = up_guard(c, UP_ANY_STATE, fn);
    if (!I)
        return fmi2Error;
    if (up_check_refs(I, fn, vr, nvr, value))
        return fmi2Error;
    if (nvr > 0) {
        up_log_error(I, "%s: value reference %u: this FMU has no %s variables", fn, vr[0], type);
        return fmi2Error;
    }
    return fmi2OK;
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


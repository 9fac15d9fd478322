/* The variables by element, for both FMI versions: the Reals in one bank indexed by element
   (value references 0 .. n_real - 1 of the FMI 2.0 model description; fmi3.c maps each FMI 3.0
   Float64 variable, an array or a scalar, to a run of elements), the Boolean parameter
   internal_motion. Every function returns 0, or -1 with the reason logged. */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmu.h"

int up_check_refs(UpInstance *I, const char *fn, const unsigned int vr[], size_t nvr, const void *value)
{
    if (nvr > 0 && (!vr || !value)) {
        up_log_error(I, "%s: NULL value reference or value array with nvr = %zu", fn, nvr);
        return -1;
    }
    return 0;
}

static int check_real_refs(UpInstance *I, const char *fn, const unsigned int vr[], size_t nvr, const void *value)
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

int up_get_reals(UpInstance *I, const char *fn, const unsigned int vr[], size_t nvr, double value[])
{
    if (check_real_refs(I, fn, vr, nvr, value))
        return -1;
    for (size_t i = 0; i < nvr && I->soil.stale && *I->soil.stale != 0.0; i++)
        up_soil_read(I, vr[i], 1);
    for (size_t i = 0; i < nvr; i++)
        value[i] = I->bank[vr[i]];
    return 0;
}

int up_set_reals(UpInstance *I, const char *fn, const unsigned int vr[], size_t nvr, const double value[])
{
    if (check_real_refs(I, fn, vr, nvr, value))
        return -1;
    for (size_t i = 0; i < nvr; i++)
        if (I->causality[vr[i]] != 0) {
            up_log_error(I, "%s: value reference %u is an output: only inputs can be set", fn, vr[i]);
            return -1;
        }
    for (size_t i = 0; i < nvr; i++)
        I->bank[vr[i]] = value[i];
    return 0;
}

/* the references of a get (setting = 0) or set of the Boolean internal_motion */
int up_boolean_refs(UpInstance *I, const char *fn, const unsigned int vr[], size_t nvr, const void *value,
                    int setting)
{
    if (up_check_refs(I, fn, vr, nvr, value))
        return -1;
    for (size_t i = 0; i < nvr; i++) {
        if ((int64_t)vr[i] != I->vr_internal_motion) {
            up_log_error(I, "%s: value reference %u: the only Boolean variable of this FMU is internal_motion "
                         "(%lld)", fn, vr[i], (long long)I->vr_internal_motion);
            return -1;
        }
        if (setting && I->state != UP_INSTANTIATED && I->state != UP_INITIALISATION) {
            up_log_error(I, "%s: internal_motion is a fixed parameter: set it before %sExitInitializationMode", fn,
                         I->api->api);
            return -1;
        }
    }
    return 0;
}

/* a get or set of a type this FMU has no variables of: only an empty one */
int up_no_variables(UpInstance *I, const char *fn, const char *type, const unsigned int vr[], size_t nvr,
                    const void *value)
{
    if (up_check_refs(I, fn, vr, nvr, value))
        return -1;
    if (nvr > 0) {
        up_log_error(I, "%s: value reference %u: this FMU has no %s variables", fn, vr[0], type);
        return -1;
    }
    return 0;
}

/* Instantiation of a native uplift FMU: the resource file (resources.c), the GUID, the layout
   of the variables (records vr.<slot> looked up by name, fmus/schema.py), the numerics and the
   state block; messages to the host's logger. */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmu.h"

const char *const up_slot_names[NSLOT] = UP_SLOT_NAMES;           /* uplift_schema.h */

/* ---- messages -------------------------------------------------------------------------------- */
static void emit(UpInstance *I, int status, const char *category, const char *fmt, va_list ap)
{
    char raw[UP_MSG + 256], msg[2 * (UP_MSG + 256)];
    vsnprintf(raw, sizeof raw, fmt, ap);
    size_t k = 0;
    for (const char *p = raw; *p && k + 2 < sizeof msg; p++) {   /* the message is a printf format */
        if (*p == '%')
            msg[k++] = '%';
        msg[k++] = *p;
    }
    msg[k] = '\0';
    if (I->logger)
        I->api->emit(I, status, category, msg);
}

void up_log_error(UpInstance *I, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    emit(I, UP_ERROR, "logStatusError", fmt, ap);
    va_end(ap);
}

void up_log_event(UpInstance *I, const char *fmt, ...)
{
    if (!I->logging)
        return;
    va_list ap;
    va_start(ap, fmt);
    emit(I, UP_OK, "logEvents", fmt, ap);
    va_end(ap);
}

/* the shortest decimal that reads back as v (as Python's repr): the fewest significant digits p
   that do, by bisection (if p digits read back, p + 1 do: the p-digit decimal is one of them) */
const char *up_num(double v, char *buf)
{
    int lo = 1, hi = 17;
    while (isfinite(v) && lo < hi) {
        int mid = (lo + hi) / 2;
        snprintf(buf, 32, "%.*g", mid, v);
        if (strtod(buf, NULL) == v)
            hi = mid;
        else
            lo = mid + 1;
    }
    snprintf(buf, 32, "%.*g", isfinite(v) ? lo : 1, v);
    return buf;
}

/* the name of element i of a slot's variables, as the model description has it (buf[48]) */
const char *up_element_name(const UpInstance *I, int slot, int i, char *buf)
{
    if (slot == S_AG)
        snprintf(buf, 48, "ag_%c", "xyz"[i % 3]);
    else if (I->slot_len[slot] == 1)
        snprintf(buf, 48, "%s", up_slot_names[slot]);
    else
        snprintf(buf, 48, "%s[%d]", up_slot_names[slot], i);
    return buf;
}

UpInstance *up_instance(void *c)
{
    UpInstance *I = (UpInstance *)c;
    return I && I->magic == UP_INSTANCE_MAGIC ? I : NULL;
}

/* ---- the guard of every entry point (the masks are in fmu.h) ------------------------------------ */
UpInstance *up_guard(void *c, int mask, const char *fn)
{
    UpInstance *I = up_instance(c);
    if (!I || (I->state & mask))
        return I;
    const char *api = I->api->api;
    char state[96];
    if (mask & UP_STEPPING) {                 /* a call of the stepping phase, too early or too late */
        if (I->state == UP_TERMINATED)
            up_log_error(I, UP_MSG_AFTER_TERMINATE, fn, api);
        else
            up_log_error(I, UP_MSG_BEFORE_INIT, fn, api);
        return NULL;
    }
    if (I->state == UP_INSTANTIATED)
        snprintf(state, sizeof state, "before %sEnterInitializationMode", api);
    else if (I->state == UP_INITIALISATION)
        snprintf(state, sizeof state, "in initialisation mode");
    else if (I->state == UP_STEPPING)
        snprintf(state, sizeof state, "after initialisation (%sReset first)", api);
    else
        snprintf(state, sizeof state, "after %sTerminate (%sReset first)", api, api);
    up_log_error(I, UP_MSG_WRONG_STATE, fn, state, I->api->standard);
    return NULL;
}

int up_set_logging(UpInstance *I, const char *fn, int on, size_t n, const char *const categories[])
{
    if (n > 0 && !categories) {
        up_log_error(I, "%s: categories is NULL with nCategories = %zu", fn, n);
        return -1;
    }
    for (size_t k = 0; k < n; k++)
        if (!categories[k] || (strcmp(categories[k], "logEvents") && strcmp(categories[k], "logStatusError"))) {
            up_log_error(I, "%s: unknown log category %s (this FMU has logEvents and logStatusError)", fn,
                         categories[k] ? categories[k] : "(null)");
            return -1;
        }
    I->logging = on;
    return 0;
}


/* ---- set up ------------------------------------------------------------------------------------ */
static uint64_t hash_text(const char *s)
{
    uint64_t h = 14695981039346656037ULL;
    for (; *s; s++) {
        h ^= (unsigned char)*s;
        h *= 1099511628211ULL;
    }
    return h;
}

/* resources folder URI (file:///path, file:/path, or a plain path; uri = 0: a path, as is) ->
   path of uplift.bin */
static int resource_path(const char *location, int uri, char *out, size_t size)
{
    const char *p = location;
    if (!uri) {
        size_t k = strlen(p);
        while (k > 0 && (p[k - 1] == '/' || p[k - 1] == '\\'))
            k--;
        if (k + 12 > size)
            return -1;
        memcpy(out, p, k);
        strcpy(out + k, "/uplift.bin");
        return 0;
    }
    if (strncmp(p, "file://", 7) == 0) {
        p += 7;
        if (strncmp(p, "localhost/", 10) == 0)
            p += 9;
    } else if (strncmp(p, "file:", 5) == 0) {
        p += 5;
    }
    if (p[0] == '/' && p[1] && p[2] == ':')      /* /C:/... on Windows */
        p++;
    size_t k = 0;
    for (; *p && k + 1 < size; p++) {
        if (*p == '%' && p[1] && p[2]) {
            char hex[3] = {p[1], p[2], 0};
            char *end;
            long v = strtol(hex, &end, 16);
            if (*end == 0) {
                out[k++] = (char)v;
                p += 2;
                continue;
            }
        }
        out[k++] = *p;
    }
    while (k > 0 && (out[k - 1] == '/' || out[k - 1] == '\\'))
        k--;
    const char *file = "/uplift.bin";
    if (k + strlen(file) + 1 > size)
        return -1;
    strcpy(out + k, file);
    return 0;
}

static int int_scalar(UpInstance *I, const char *name, double lo, double hi, int64_t *v)
{
    double x;
    if (up_res_scalar(&I->res, name, &x, I->err))
        return -1;
    if (!(x >= lo && x <= hi) || x != floor(x)) {
        snprintf(I->err, UP_MSG, "resource file %s: %s = %g must be an integer in [%g, %g]: export the FMU again",
                 I->res.path, name, x, lo, hi);
        return -1;
    }
    *v = (int64_t)x;
    return 0;
}

/* the layout of the Real variables: slots, their lengths, causalities */

/* the layout of the Real variables: the first value reference of each slot (record vr.<name>,
   -1 when the FMU has none), their lengths, the causalities */
static int read_layout(UpInstance *I)
{
    int64_t n_real, dims[1];
    if (int_scalar(I, "n_real", 1, 1e7, &n_real) || int_scalar(I, "vr_internal_motion", -1, 1e7, &I->vr_internal_motion))
        return -1;
    I->n_real = (int)n_real;
    dims[0] = n_real;
    if (!(I->causality = up_res_i64(&I->res, "causality", 1, dims, I->err)))
        return -1;
    int n = I->n, N = I->N;
    const int len[NSLOT] = UP_SLOT_LENGTHS(n, N, I->nnodes);
    for (int k = 0; k < NSLOT; k++) {
        char rec[40];
        snprintf(rec, sizeof rec, "vr.%s", up_slot_names[k]);
        if (int_scalar(I, rec, -1, (double)n_real - 1, &I->slot[k]))
            return -1;
        I->slot_len[k] = I->slot[k] < 0 ? 0 : len[k];
        if (I->slot[k] >= 0 && I->slot[k] + len[k] > n_real) {
            snprintf(I->err, UP_MSG, "resource file %s: the variables %s lie outside the %d Real variables: export "
                     "the FMU again", I->res.path, up_slot_names[k], I->n_real);
            return -1;
        }
    }
    static const int need[UP_N_ROLES][NSLOT] = UP_SLOT_NEEDED;
    for (int k = 0; k < NSLOT; k++)
        if (need[I->role][k] && I->slot[k] < 0) {
            snprintf(I->err, UP_MSG, "resource file %s: no variables %s: export the FMU again", I->res.path,
                     up_slot_names[k]);
            return -1;
        }
    for (int64_t k = 0; k < n_real; k++)
        if (I->causality[k] != 0 && I->causality[k] != 1) {
            snprintf(I->err, UP_MSG, "resource file %s: bad causality record: export the FMU again", I->res.path);
            return -1;
        }
    return 0;
}

static int setup(UpInstance *I, const char *guid, const char *location, int uri)
{
    char path[1024];
    if (!location || resource_path(location, uri, path, sizeof path)) {
        snprintf(I->err, UP_MSG, uri ? "fmuResourceLocation %s is not a file URI of the FMU's resources folder"
                                     : "resourcePath %s is not the path of the FMU's resources folder",
                 location ? location : "(null)");
        return -1;
    }
    if (up_res_load(&I->res, path, I->err))
        return -1;
    const UpRecord *g = up_res_find(&I->res, "guid");
    if (!g || g->kind != UP_TEXT || !guid || strlen(guid) != g->nbytes || memcmp(guid, g->data, g->nbytes) != 0) {
        snprintf(I->err, UP_MSG, "GUID %s does not match the resources (%s): the resources folder belongs to "
                 "another FMU; extract this FMU again", guid ? guid : "(null)", I->res.path);
        return -1;
    }
    I->guid_hash = hash_text(guid);
    int64_t role, n, N = 0, nnodes = 0;
    if (int_scalar(I, "role", 0, 2, &role) || int_scalar(I, "n_dof", 1, 1e6, &n)
        || up_res_scalar(&I->res, "dt", &I->dt, I->err))
        return -1;
    if (!(I->dt > 0) || !isfinite(I->dt)) {
        snprintf(I->err, UP_MSG, "resource file %s: dt must be > 0: export the FMU again", I->res.path);
        return -1;
    }
    I->role = (int)role;
    I->n = (int)n;
    I->has_stepper = I->role != ROLE_SOIL;
    if (I->has_stepper) {
        int64_t dims[2] = {-1, 3};
        if (int_scalar(I, "N", 0, 1e6, &N) || !(I->node_dofs = up_res_i64(&I->res, "node_dofs", 2, dims, I->err)))
            return -1;
        nnodes = dims[0];
        if (up_res_find(&I->res, "motion")) {
            dims[0] = -1;
            if (!(I->motion = up_res_f64(&I->res, "motion", 2, dims, I->err)))
                return -1;
            I->nt = dims[0];
            I->has_motion = I->nt > 0;
        }
    }
    I->N = I->has_stepper ? (int)N : I->n - 6;        /* the soil: n = 6 + N interface DOFs */
    I->nnodes = (int)nnodes;
    if (up_res_find(&I->res, "fmi3_float64")) {   /* FMI 3.0: the Float64 variables over the elements */
        int64_t dims[2] = {-1, 2};
        if (!(I->vars3 = up_res_i64(&I->res, "fmi3_float64", 2, dims, I->err))
            || int_scalar(I, "fmi3_vr_N", -1, 1e7, &I->vr3_N))
            return -1;
        I->nvars3 = dims[0];
    }
    int64_t levels = 0;                         /* the soil's matrices at each halving level */
    if (read_layout(I) || (I->has_stepper && int_scalar(I, "contact_max_subdiv", 0, UP_MAXLEV - 1, &levels)))
        return -1;
    if (up_soil_init(&I->soil, &I->res, I->n, (int)levels + 1, I->role == ROLE_SOIL ? 2 : I->role != ROLE_STRUCTURE,
                     I->err))
        return -1;
    if (I->has_stepper) {
        if (up_stepper_init(&I->st, &I->res, &I->soil, I->role == ROLE_STRUCTURE, I->err))
            return -1;
        for (int k = 0; k < 3 * I->nnodes; k++)
            if (I->node_dofs[k] < 0 || I->node_dofs[k] >= I->st.n) {
                snprintf(I->err, UP_MSG, "resource file %s: node_dofs out of range: export the FMU again", I->res.path);
                return -1;
            }
        I->st.err = I->err;
    } else {
        up_soil_level(&I->soil, 0, I->dt);
    }
    for (int64_t k = 0; k < I->nvars3; k++)
        if (I->vars3[2 * k] < -1 || I->vars3[2 * k + 1] < 1 || I->vars3[2 * k] + I->vars3[2 * k + 1] > I->n_real
            || (I->vars3[2 * k] == -1 && I->vars3[2 * k + 1] != 1)) {       /* -1: the time */
            snprintf(I->err, UP_MSG, "resource file %s: fmi3_float64 out of range: export the FMU again", I->res.path);
            return -1;
        }
    if (I->role == ROLE_STRUCTURE) {
        int64_t dims[2] = {n, n};
        if (!(I->Gx = up_res_f64(&I->res, "Gx", 2, dims, I->err)) || !(I->Gv = up_res_f64(&I->res, "Gv", 2, dims, I->err)))
            return -1;
        /* Gx symmetric (it is sum (a_k + 1) b_k R_k): packed, half the traffic of its product; Gv
           zero (the recursion's state does not see xdot): no product at all */
        if (!(I->Gxp = (double *)malloc(((size_t)n * (n + 1) / 2 + 1) * sizeof(double)))) {
            snprintf(I->err, UP_MSG, "out of memory for the history gains (%d DOFs)", (int)n);
            return -1;
        }
        if (!up_pack_sym(I->Gx, (int)n, I->Gxp)) {
            free(I->Gxp);
            I->Gxp = NULL;
        }
        I->Gv_zero = 1;
        for (size_t k = 0; k < (size_t)n * n; k++)
            I->Gv_zero &= I->Gv[k] == 0.0;
    }
    /* the state block: time, internal_motion, held_t, the variables, held inputs, stepper, soil */
    I->held_len = I->role == ROLE_SOIL ? 2 * I->n : I->role == ROLE_STRUCTURE ? I->n : 0;
    size_t st_len = I->has_stepper ? up_stepper_state_len(&I->st) : 0;
    size_t soil_len = I->role == ROLE_STRUCTURE ? 0 : up_soil_state_len(&I->soil);
    I->block_len = 3 + (size_t)I->n_real + (size_t)I->held_len + st_len + soil_len;
    int nsaves = I->has_stepper ? I->st.nlev : 0;
    I->block = (double *)calloc(I->block_len, sizeof(double));
    I->backup = (double *)calloc(I->block_len, sizeof(double));
    I->saves = (double *)calloc((size_t)nsaves * I->block_len + 1, sizeof(double));
    I->tmp = (double *)calloc(4 * (size_t)I->n + 8, sizeof(double));
    if (!I->block || !I->backup || !I->saves || !I->tmp) {
        snprintf(I->err, UP_MSG, "out of memory for the FMU state (%zu values)", I->block_len);
        return -1;
    }
    I->time = I->block;
    I->internal_motion = I->block + 1;
    I->held_t = I->block + 2;
    I->bank = I->block + 3;
    I->held = I->bank + I->n_real;
    double *rest = I->held + I->held_len;
    if (I->has_stepper) {
        up_stepper_bind(&I->st, rest, I->block, I->block_len, I->saves);
        rest += st_len;
    }
    if (soil_len)
        up_soil_bind(&I->soil, rest);
    *I->internal_motion = I->has_motion;
    if (I->has_stepper && up_stepper_prepare(&I->st, I->err))
        return -1;
    return 0;
}

UpInstance *up_instantiate(const UpApi *api, const char *name, const char *guid, const char *location, int uri,
                           void (*logger)(void), void *env, int logging, const char *refusal)
{
    UpInstance *I = (UpInstance *)calloc(1, sizeof(UpInstance));
    if (!I)
        return NULL;
    I->magic = UP_INSTANCE_MAGIC;
    I->api = api;
    I->stop_time = INFINITY;
    snprintf(I->name, sizeof I->name, "%s", name ? name : "uplift");
    I->logger = logger;
    I->env = env;
    I->logging = logging;
    if (!name || !*name)
        snprintf(I->err, UP_MSG, "instanceName is empty: give the instance a name");
    else if (refusal)
        snprintf(I->err, UP_MSG, "%s", refusal);
    else if (setup(I, guid, location, uri) == 0) {
        I->state = UP_INSTANTIATED;
        up_log_event(I, "instantiated from %s: %d Real variables, dt = %g s", I->res.path, I->n_real, I->dt);
        return I;
    }
    up_log_error(I, "instantiation failed: %s", I->err);
    up_free_instance(I);
    return NULL;
}

void up_free_instance(UpInstance *I)
{
    if (I->has_stepper)
        up_stepper_free(&I->st);
    up_soil_free(&I->soil);
    up_res_free(&I->res);
    free(I->Gxp);
    free(I->block);
    free(I->backup);
    free(I->saves);
    free(I->tmp);
    I->magic = 0;
    free(I);
}


/* FMI 2.0 co-simulation entry points of the native uplift FMUs: life cycle, variables, FMU
   state, the split coupling of the pair (fmus/common.py). Behaves as the Python FMUs
   (fmus/soil_fmu.py, structure_fmu.py, coupled_fmu.py): the same variables, the same answers,
   the same refusals with the same messages.

   Every entry point checks its instance and its arguments and reports what it refuses through
   the logger (category logStatusError), never a crash. A call that cannot be right returns
   fmi2Error with the instance as it was before the call: a step before initialisation or after
   fmi2Terminate, at the wrong time, of the wrong size (the coupled FMU takes any multiple of
   dt, the pair exactly dt), with a non-finite input or a wrong time stamp; an unknown value
   reference, a variable that cannot be set. A step whose Newton iteration fails (after its
   halvings) returns fmi2Discard, the instance as it was. The FMU state is one block of doubles
   (time, variables, held stamped inputs, stepper and soil state): fmi2GetFMUstate and
   fmi2SetFMUstate copy it, serialisation writes it with a header naming the model (GUID hash)
   and its length. */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "uplift.h"

#define MAGIC 0x75706c6966744e42ULL            /* "upliftNB" */
#define STATE_MAGIC 0x55504c4946545354ULL      /* "UPLIFTST" */

enum { ROLE_SOIL, ROLE_STRUCTURE, ROLE_COUPLED };
enum { INSTANTIATED, INITIALISATION, STEPPING, TERMINATED };
/* the named vectors of Real variables: first value reference in the resource record "slots" */
enum { S_X, S_XDOT, S_X_TIME, S_G, S_G_TIME, S_F, S_DISS, S_AG, S_P, S_GAP, S_NODES, S_ENERGY, S_NEWTON,
       S_MAX_UPLIFT, S_MAX_ROTATION, NSLOT };
static const char *SLOT_NAMES[NSLOT] = {"x", "xdot", "x_time", "g", "g_time", "f", "dissipated_energy", "ag",
                                        "P", "gap", "nodes", "energy", "newton_iters", "max_uplift",
                                        "max_raft_rotation"};

typedef struct {
    uint64_t magic;
    int role, phase, logging;
    char name[256];
    fmi2CallbackLogger logger;
    fmi2ComponentEnvironment env;
    UpRes res;
    UpSoil soil;
    UpStepper st;
    int has_stepper;
    int n, N, nnodes, n_real, slot_len[NSLOT];
    int64_t slot[NSLOT];
    const int64_t *causality;               /* (n_real): 0 input, 1 output */
    const int64_t *node_dofs;               /* (nnodes, 3) */
    const double *motion;                   /* (nt, 3) or NULL */
    int64_t nt, vr_internal_motion;
    int has_motion;
    const double *Gx, *Gv;                  /* (n, n), structure only */
    double dt, start_time;
    uint64_t guid_hash;
    /* the state block and its parts */
    double *block, *backup, *saves, *tmp;
    size_t block_len;
    double *time, *internal_motion, *held_t, *bank, *held;
    int held_len;
    char err[UP_MSG];
} Inst;

typedef struct {
    uint64_t magic, guid_hash;
    size_t len;
    double data[1];
} State;

/* ---- messages -------------------------------------------------------------------------------- */
static void log_error(Inst *I, const char *fmt, ...)
{
    char raw[UP_MSG + 256], msg[2 * (UP_MSG + 256)];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(raw, sizeof raw, fmt, ap);
    va_end(ap);
    size_t k = 0;
    for (const char *p = raw; *p && k + 2 < sizeof msg; p++) {   /* the message is a printf format */
        if (*p == '%')
            msg[k++] = '%';
        msg[k++] = *p;
    }
    msg[k] = '\0';
    if (I->logger)
        I->logger(I->env, I->name, fmi2Error, "logStatusError", msg);
}

/* the shortest decimal that reads back as v (as Python's repr) */
static const char *num(double v, char *buf)
{
    for (int p = 1; p <= 17; p++) {
        snprintf(buf, 32, "%.*g", p, v);
        if (strtod(buf, NULL) == v || !isfinite(v))
            break;
    }
    return buf;
}

static Inst *instance(fmi2Component c)
{
    Inst *I = (Inst *)c;
    return I && I->magic == MAGIC ? I : NULL;
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

/* resources folder URI (file:///path, file:/path, or a plain path) -> path of uplift.bin */
static int resource_path(const char *uri, char *out, size_t size)
{
    const char *p = uri;
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

static int int_scalar(Inst *I, const char *name, double lo, double hi, int64_t *v)
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
static int read_layout(Inst *I)
{
    int64_t n_real, dims[2] = {NSLOT, -1};
    if (int_scalar(I, "n_real", 1, 1e7, &n_real) || int_scalar(I, "vr_internal_motion", -1, 1e7, &I->vr_internal_motion))
        return -1;
    I->n_real = (int)n_real;
    const int64_t *slots = up_res_i64(&I->res, "slots", 1, dims, I->err);
    dims[0] = n_real;
    if (!slots || !(I->causality = up_res_i64(&I->res, "causality", 1, dims, I->err)))
        return -1;
    int n = I->n, N = I->N;
    const int len[NSLOT] = {n, n, 1, n, 1, n, 1, 3, N, N, 6 * I->nnodes, 7, 1, 1, 1};
    for (int k = 0; k < NSLOT; k++) {
        I->slot[k] = slots[k];
        I->slot_len[k] = slots[k] < 0 ? 0 : len[k];
        if (slots[k] >= 0 && slots[k] + len[k] > n_real) {
            snprintf(I->err, UP_MSG, "resource file %s: the variables %s lie outside the %d Real variables: export "
                     "the FMU again", I->res.path, SLOT_NAMES[k], I->n_real);
            return -1;
        }
    }
    static const int need[3][NSLOT] = {
        {1, 1, 1, 1, 1, 1, 1, 0, 0, 0, 0, 0, 0, 0, 0},
        {1, 1, 1, 1, 1, 0, 0, 1, 1, 1, 0, 1, 1, 1, 1},
        {1, 1, 0, 0, 0, 0, 0, 1, 1, 1, 0, 1, 1, 1, 1}};
    for (int k = 0; k < NSLOT; k++)
        if (need[I->role][k] && slots[k] < 0) {
            snprintf(I->err, UP_MSG, "resource file %s: no variables %s: export the FMU again", I->res.path,
                     SLOT_NAMES[k]);
            return -1;
        }
    for (int64_t k = 0; k < n_real; k++)
        if (I->causality[k] != 0 && I->causality[k] != 1) {
            snprintf(I->err, UP_MSG, "resource file %s: bad causality record: export the FMU again", I->res.path);
            return -1;
        }
    return 0;
}

static int setup(Inst *I, const char *guid, const char *uri)
{
    char path[1024];
    if (!uri || resource_path(uri, path, sizeof path)) {
        snprintf(I->err, UP_MSG, "fmuResourceLocation %s is not a file URI of the FMU's resources folder",
                 uri ? uri : "(null)");
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
    I->N = (int)N;
    I->nnodes = (int)nnodes;
    int64_t levels = 0;                         /* the soil's matrices at each halving level */
    if (read_layout(I) || (I->has_stepper && int_scalar(I, "contact_max_subdiv", 0, UP_MAXLEV - 1, &levels)))
        return -1;
    if (up_soil_init(&I->soil, &I->res, I->n, (int)levels + 1, I->role != ROLE_STRUCTURE, I->err))
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
    if (I->role == ROLE_STRUCTURE) {
        int64_t dims[2] = {n, n};
        if (!(I->Gx = up_res_f64(&I->res, "Gx", 2, dims, I->err)) || !(I->Gv = up_res_f64(&I->res, "Gv", 2, dims, I->err)))
            return -1;
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

static void free_instance(Inst *I)
{
    if (I->has_stepper)
        up_stepper_free(&I->st);
    up_soil_free(&I->soil);
    up_res_free(&I->res);
    free(I->block);
    free(I->backup);
    free(I->saves);
    free(I->tmp);
    I->magic = 0;
    free(I);
}

/* ---- publishing the outputs ------------------------------------------------------------------- */
static double *var(Inst *I, int slot) { return I->bank + I->slot[slot]; }

static void publish_stepper(Inst *I)
{
    UpStepper *st = &I->st;
    int n = I->n, N = I->N;
    memcpy(var(I, S_X), st->u + st->ni, (size_t)n * sizeof(double));
    memcpy(var(I, S_XDOT), st->v + st->ni, (size_t)n * sizeof(double));
    memcpy(var(I, S_P), st->P, (size_t)N * sizeof(double));
    double *gap = var(I, S_GAP);
    up_stepper_gap(st, gap);
    double *node = var(I, S_NODES);
    for (int k = 0; k < I->nnodes; k++)
        for (int c = 0; c < 3; c++) {
            int64_t d = I->node_dofs[3 * k + c];
            node[6 * k + c] = st->a[d] + st->ag[c];
            node[6 * k + 3 + c] = st->u[d];
        }
    up_stepper_energies(st, var(I, S_ENERGY));
    double gmax = 0.0, *up = var(I, S_MAX_UPLIFT), *rot = var(I, S_MAX_ROTATION);
    for (int i = 0; i < N; i++)
        gmax = i == 0 || gap[i] > gmax ? gap[i] : gmax;
    const double *q = st->u + st->ni;
    double r = hypot(q[3], q[4]);
    *up = *up >= gmax ? *up : gmax;
    *rot = *rot >= r ? *rot : r;
    if (I->slot[S_X_TIME] >= 0)
        *var(I, S_X_TIME) = *st->t;
}

/* g is written by the step (or at rest, zero) */
static void publish_soil(Inst *I, double t_next)
{
    *var(I, S_G_TIME) = t_next;
    memcpy(var(I, S_F), I->soil.f, (size_t)I->n * sizeof(double));
    *var(I, S_DISS) = *I->soil.work;
}

/* the model at rest at t = 0 with the current inputs and parameters; 0 or -1 with I->err */
static int initial_state(Inst *I)
{
    if (I->start_time != 0.0) {
        char b[32];
        snprintf(I->err, UP_MSG, "start time %s s: this FMU starts at t = 0 s, at rest, with the first sample "
                 "of its record", num(I->start_time, b));
        return -1;
    }
    *I->time = 0.0;
    *I->held_t = 0.0;
    memset(I->held, 0, (size_t)I->held_len * sizeof(double));
    if (!I->has_stepper) {
        up_soil_rest(&I->soil);
        up_soil_ahead(&I->soil, 0, var(I, S_G));
        publish_soil(I, 0.0);
        return 0;
    }
    double ag0[3];
    if (*I->internal_motion != 0.0) {
        if (!I->has_motion) {
            snprintf(I->err, UP_MSG, "internal_motion = true but this FMU was exported without a motion: set "
                     "internal_motion = false and drive the input ag");
            return -1;
        }
        memcpy(ag0, I->motion, sizeof ag0);
    } else {
        memcpy(ag0, var(I, S_AG), sizeof ag0);
        for (int c = 0; c < 3; c++)
            if (!isfinite(ag0[c])) {
                char b[32];
                snprintf(I->err, UP_MSG, "input ag[%d] = %s at initialisation: inputs must be finite (check what "
                         "is connected to it)", c, num(ag0[c], b));
                return -1;
            }
    }
    up_stepper_rest(&I->st, ag0);
    *var(I, S_MAX_UPLIFT) = *var(I, S_MAX_ROTATION) = 0.0;
    publish_stepper(I);
    return 0;
}

/* ---- the step ----------------------------------------------------------------------------------- */
/* the stamped input (values of length len, stamped by the partner's time): the values to use
   for the step from t, or NULL with I->err (see fmus.common.StampedInput) */
static const double *take(Inst *I, double t, double stamp, const double *values, int len, const char *name,
                          const char *stamp_name)
{
    double tol = 1e-6 * I->dt;
    if (fabs(stamp - t) <= tol)
        return values;
    if (fabs(stamp - (t + I->dt)) <= tol && fabs(*I->held_t - t) <= tol) {
        double *used = I->tmp + 2 * (size_t)I->n;
        memcpy(used, I->held, (size_t)len * sizeof(double));
        *I->held_t = stamp;
        memcpy(I->held, values, (size_t)len * sizeof(double));
        return used;
    }
    char b1[32], b2[32];
    snprintf(I->err, UP_MSG, "input %s is stamped %s = %s s at a step from t = %s s: it must be the partner's "
             "output at t or at t + dt (connect the partner's %s output to this input, with %s)", name, stamp_name,
             num(stamp, b1), num(t, b2), stamp_name, name);
    return NULL;
}

static void ag_next(Inst *I, double t)
{
    double *next = I->st.ag_next;
    if (*I->internal_motion == 0.0) {
        memcpy(next, var(I, S_AG), 3 * sizeof(double));
        return;
    }
    int64_t k = (int64_t)floor(t / I->dt + 0.5) + 1;
    for (int c = 0; c < 3; c++)
        next[c] = k < I->nt ? I->motion[3 * k + c] : 0.0;
}

enum { REFUSED = 1, FAILED = 2 };

/* one step of dt from t: 0, REFUSED (a wrong stamp) or FAILED (no Newton convergence), with I->err */
static int step(Inst *I, double t)
{
    int n = I->n;
    if (I->role == ROLE_SOIL) {
        double *xx = I->tmp;
        memcpy(xx, var(I, S_X), (size_t)n * sizeof(double));
        memcpy(xx + n, var(I, S_XDOT), (size_t)n * sizeof(double));
        const double *used = take(I, t, *var(I, S_X_TIME), xx, 2 * n, "x, xdot", "x_time");
        if (!used)
            return REFUSED;
        if (t > 0.5 * I->dt)                     /* at t = 0 the soil is at rest: nothing to commit */
            up_soil_step(&I->soil, 0, used, used + n, var(I, S_G));
        else
            up_soil_ahead(&I->soil, 0, var(I, S_G));
        publish_soil(I, t + I->dt);
        return 0;
    }
    UpStepper *st = &I->st;
    if (I->role == ROLE_STRUCTURE) {
        const double *g = take(I, t, *var(I, S_G_TIME), var(I, S_G), n, "g", "g_time");
        if (!g)
            return REFUSED;
        const double *x = st->u + st->ni, *xd = st->v + st->ni;
        for (int i = 0; i < n; i++)
            st->h_ext[i] = (g[i] + up_dot(I->Gx + (size_t)i * n, x, n)) + up_dot(I->Gv + (size_t)i * n, xd, n);
    }
    ag_next(I, t);
    if (up_stepper_step(st))
        return FAILED;
    *var(I, S_NEWTON) = st->last_iters;
    publish_stepper(I);
    return 0;
}

/* ---- FMI 2.0: common functions ------------------------------------------------------------------- */
const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories, const fmi2String categories[])
{
    Inst *I = instance(c);
    if (!I)
        return fmi2Error;
    if (nCategories > 0 && !categories) {
        log_error(I, "fmi2SetDebugLogging: categories is NULL with nCategories = %zu", nCategories);
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
    Inst *I = (Inst *)calloc(1, sizeof(Inst));
    if (!I)
        return NULL;
    I->magic = MAGIC;
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
    else if (setup(I, fmuGUID, fmuResourceLocation) == 0) {
        I->phase = INSTANTIATED;
        return I;
    }
    log_error(I, "instantiation failed: %s", I->err);
    free_instance(I);
    return NULL;
}

void fmi2FreeInstance(fmi2Component c)
{
    Inst *I = instance(c);
    if (I)
        free_instance(I);
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime)
{
    (void)toleranceDefined, (void)tolerance, (void)stopTimeDefined, (void)stopTime;
    Inst *I = instance(c);
    if (!I)
        return fmi2Error;
    if (I->phase != INSTANTIATED) {
        log_error(I, "fmi2SetupExperiment is allowed only after fmi2Instantiate (or fmi2Reset)");
        return fmi2Error;
    }
    I->start_time = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c)
{
    Inst *I = instance(c);
    if (!I)
        return fmi2Error;
    if (I->phase != INSTANTIATED) {
        log_error(I, "fmi2EnterInitializationMode is allowed only after fmi2Instantiate (or fmi2Reset)");
        return fmi2Error;
    }
    if (initial_state(I)) {
        log_error(I, "initialisation failed: %s", I->err);
        return fmi2Error;
    }
    I->phase = INITIALISATION;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c)
{
    Inst *I = instance(c);
    if (!I)
        return fmi2Error;
    if (I->phase != INITIALISATION) {
        log_error(I, "fmi2ExitInitializationMode is allowed only after fmi2EnterInitializationMode");
        return fmi2Error;
    }
    if (initial_state(I)) {                 /* inputs and parameters set during initialisation */
        log_error(I, "initialisation failed: %s", I->err);
        return fmi2Error;
    }
    I->phase = STEPPING;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c)
{
    Inst *I = instance(c);
    if (!I)
        return fmi2Error;
    I->phase = TERMINATED;                  /* from any state: a host ending a failed start too */
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c)
{
    Inst *I = instance(c);
    if (!I)
        return fmi2Error;
    memset(I->block, 0, I->block_len * sizeof(double));
    *I->internal_motion = I->has_motion;
    I->start_time = 0.0;
    I->phase = INSTANTIATED;
    return fmi2OK;
}

/* ---- variables ------------------------------------------------------------------------------------ */
static int check_refs(Inst *I, const char *fn, const fmi2ValueReference vr[], size_t nvr, const void *value)
{
    if (nvr > 0 && (!vr || !value)) {
        log_error(I, "%s: NULL value reference or value array with nvr = %zu", fn, nvr);
        return -1;
    }
    return 0;
}

static int check_real_refs(Inst *I, const char *fn, const fmi2ValueReference vr[], size_t nvr, const void *value)
{
    if (check_refs(I, fn, vr, nvr, value))
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
        log_error(I, "%s: value references %u..%u: the Real variables of this FMU are 0..%d", fn, lo, hi, I->n_real - 1);
        return -1;
    }
    return 0;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[])
{
    Inst *I = instance(c);
    if (!I)
        return fmi2Error;
    if (check_real_refs(I, "fmi2GetReal", vr, nvr, value))
        return fmi2Error;
    for (size_t i = 0; i < nvr; i++)
        value[i] = I->bank[vr[i]];
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[])
{
    Inst *I = instance(c);
    if (!I)
        return fmi2Error;
    if (check_real_refs(I, "fmi2SetReal", vr, nvr, value))
        return fmi2Error;
    if (I->phase == TERMINATED) {
        log_error(I, "fmi2SetReal after fmi2Terminate (instantiate the FMU again)");
        return fmi2Error;
    }
    for (size_t i = 0; i < nvr; i++)
        if (I->causality[vr[i]] != 0) {
            log_error(I, "fmi2SetReal: value reference %u is an output: only inputs can be set", vr[i]);
            return fmi2Error;
        }
    for (size_t i = 0; i < nvr; i++)
        I->bank[vr[i]] = value[i];
    return fmi2OK;
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[])
{
    Inst *I = instance(c);
    if (!I)
        return fmi2Error;
    if (check_refs(I, "fmi2GetBoolean", vr, nvr, value))
        return fmi2Error;
    for (size_t i = 0; i < nvr; i++) {
        if ((int64_t)vr[i] != I->vr_internal_motion) {
            log_error(I, "fmi2GetBoolean: value reference %u: the only Boolean variable of this FMU is "
                      "internal_motion (%lld)", vr[i], (long long)I->vr_internal_motion);
            return fmi2Error;
        }
        value[i] = *I->internal_motion != 0.0 ? fmi2True : fmi2False;
    }
    return fmi2OK;
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Boolean value[])
{
    Inst *I = instance(c);
    if (!I)
        return fmi2Error;
    if (check_refs(I, "fmi2SetBoolean", vr, nvr, value))
        return fmi2Error;
    for (size_t i = 0; i < nvr; i++) {
        if ((int64_t)vr[i] != I->vr_internal_motion) {
            log_error(I, "fmi2SetBoolean: value reference %u: the only Boolean variable of this FMU is "
                      "internal_motion (%lld)", vr[i], (long long)I->vr_internal_motion);
            return fmi2Error;
        }
        if (I->phase != INSTANTIATED && I->phase != INITIALISATION) {
            log_error(I, "fmi2SetBoolean: internal_motion is a fixed parameter: set it before "
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
    Inst *I = instance(c);
    if (!I)
        return fmi2Error;
    if (check_refs(I, fn, vr, nvr, value))
        return fmi2Error;
    if (nvr > 0) {
        log_error(I, "%s: value reference %u: this FMU has no %s variables", fn, vr[0], type);
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

/* ---- FMU state ---------------------------------------------------------------------------------------- */
static State *checked_state(Inst *I, fmi2FMUstate s, const char *fn)
{
    State *S = (State *)s;
    if (!S || S->magic != STATE_MAGIC || S->guid_hash != I->guid_hash || S->len != I->block_len) {
        log_error(I, "%s: not an FMU state of this FMU (get it with fmi2GetFMUstate or fmi2DeSerializeFMUstate)", fn);
        return NULL;
    }
    return S;
}

static State *new_state(Inst *I)
{
    State *S = (State *)malloc(sizeof(State) + I->block_len * sizeof(double));
    if (S) {
        S->magic = STATE_MAGIC;
        S->guid_hash = I->guid_hash;
        S->len = I->block_len;
    }
    return S;
}

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *s)
{
    Inst *I = instance(c);
    if (!I)
        return fmi2Error;
    if (!s) {
        log_error(I, "fmi2GetFMUstate: FMUstate pointer is NULL");
        return fmi2Error;
    }
    State *S = (State *)*s;
    if (S && !checked_state(I, S, "fmi2GetFMUstate"))
        return fmi2Error;
    if (!S && !(S = new_state(I))) {
        log_error(I, "fmi2GetFMUstate: out of memory");
        return fmi2Error;
    }
    memcpy(S->data, I->block, I->block_len * sizeof(double));
    *s = S;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate s)
{
    Inst *I = instance(c);
    if (!I)
        return fmi2Error;
    State *S = checked_state(I, s, "fmi2SetFMUstate");
    if (!S)
        return fmi2Error;
    memcpy(I->block, S->data, I->block_len * sizeof(double));
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *s)
{
    Inst *I = instance(c);
    if (!I)
        return fmi2Error;
    if (!s) {
        log_error(I, "fmi2FreeFMUstate: FMUstate pointer is NULL");
        return fmi2Error;
    }
    if (*s && !checked_state(I, *s, "fmi2FreeFMUstate"))
        return fmi2Error;
    if (*s)
        ((State *)*s)->magic = 0;
    free(*s);
    *s = NULL;
    return fmi2OK;
}

/* serialised: magic, GUID hash, length (uint64 each), then the block's doubles */
#define SER_HEADER 24

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t *size)
{
    Inst *I = instance(c);
    if (!I)
        return fmi2Error;
    if (!size || !checked_state(I, s, "fmi2SerializedFMUstateSize")) {
        if (!size)
            log_error(I, "fmi2SerializedFMUstateSize: size pointer is NULL");
        return fmi2Error;
    }
    *size = SER_HEADER + I->block_len * sizeof(double);
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte bytes[], size_t size)
{
    Inst *I = instance(c);
    if (!I)
        return fmi2Error;
    State *S = checked_state(I, s, "fmi2SerializeFMUstate");
    if (!S)
        return fmi2Error;
    if (!bytes || size != SER_HEADER + S->len * sizeof(double)) {
        log_error(I, "fmi2SerializeFMUstate: give a buffer of fmi2SerializedFMUstateSize bytes");
        return fmi2Error;
    }
    uint64_t head[3] = {STATE_MAGIC, S->guid_hash, (uint64_t)S->len};
    memcpy(bytes, head, SER_HEADER);
    memcpy(bytes + SER_HEADER, S->data, S->len * sizeof(double));
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte bytes[], size_t size, fmi2FMUstate *s)
{
    Inst *I = instance(c);
    if (!I)
        return fmi2Error;
    uint64_t head[3] = {0, 0, 0};
    if (bytes && size >= SER_HEADER)
        memcpy(head, bytes, SER_HEADER);
    if (!s || !bytes || size != SER_HEADER + I->block_len * sizeof(double) || head[0] != STATE_MAGIC
        || head[1] != I->guid_hash || head[2] != I->block_len) {
        log_error(I, "fmi2DeSerializeFMUstate: the %zu bytes are not a serialised state of this FMU", size);
        return fmi2Error;
    }
    State *S = new_state(I);
    if (!S) {
        log_error(I, "fmi2DeSerializeFMUstate: out of memory");
        return fmi2Error;
    }
    memcpy(S->data, bytes + SER_HEADER, S->len * sizeof(double));
    *s = S;
    return fmi2OK;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[], size_t nUnknown,
                                        const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[])
{
    (void)vUnknown_ref, (void)nUnknown, (void)vKnown_ref, (void)nKnown, (void)dvKnown, (void)dvUnknown;
    Inst *I = instance(c);
    if (I)
        log_error(I, "fmi2GetDirectionalDerivative: not provided by this FMU (providesDirectionalDerivative = false)");
    return fmi2Error;
}

/* ---- FMI 2.0: co-simulation ----------------------------------------------------------------------------- */
fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[])
{
    (void)vr, (void)order, (void)value;
    Inst *I = instance(c);
    if (!I)
        return fmi2Error;
    if (nvr == 0)
        return fmi2OK;
    log_error(I, "fmi2SetRealInputDerivatives: this FMU does not interpolate inputs (canInterpolateInputs = false)");
    return fmi2Error;
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[])
{
    (void)vr, (void)order, (void)value;
    Inst *I = instance(c);
    if (!I)
        return fmi2Error;
    if (nvr == 0)
        return fmi2OK;
    log_error(I, "fmi2GetRealOutputDerivatives: this FMU provides no output derivatives "
              "(maxOutputDerivativeOrder = 0)");
    return fmi2Error;
}

/* a call that cannot be right: fmi2Error, logged, the instance as it was */
static fmi2Status refuse(Inst *I, double t, const char *why)
{
    char b[32];
    log_error(I, "step from t = %s s refused: %s", num(t, b), why);
    return fmi2Error;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSetFMUStatePriorToCurrentPoint)
{
    (void)noSetFMUStatePriorToCurrentPoint;
    Inst *I = instance(c);
    if (!I)
        return fmi2Error;
    char b1[32], b2[32], why[UP_MSG];
    if (I->phase == INSTANTIATED || I->phase == INITIALISATION)
        return refuse(I, t, "doStep before initialisation (call fmi2ExitInitializationMode first)");
    if (I->phase == TERMINATED)
        return refuse(I, t, "doStep after fmi2Terminate (instantiate the FMU again)");
    if (!(isfinite(t) && fabs(t - *I->time) <= 1e-6 * I->dt)) {
        snprintf(why, sizeof why, "this FMU is at t = %s s: steps must follow one another (restore an FMU "
                 "state to go back)", num(*I->time, b1));
        return refuse(I, t, why);
    }
    /* the coupled FMU takes any multiple of dt (steps of dt inside); the pair exactly dt, the
       step its coupling is exchanged at */
    int multistep = I->role == ROLE_COUPLED;
    double steps = multistep && isfinite(h) ? floor(h / I->dt + 0.5) : 1.0;
    if (!(steps >= 1 && steps <= 1e9 && fabs(h - steps * I->dt) <= 1e-9 * h)) {
        snprintf(why, sizeof why, "communication step %s s: this FMU steps %s %s s per communication step "
                 "(export it again with the step you need)", num(h, b1), multistep ? "a multiple" : "exactly",
                 num(I->dt, b2));
        return refuse(I, t, why);
    }
    for (int k = 0; k < NSLOT; k++) {
        if (I->slot[k] < 0 || I->causality[I->slot[k]] != 0)
            continue;                                         /* the inputs only */
        const double *v = var(I, k);
        for (int i = 0; i < I->slot_len[k]; i++)
            if (!isfinite(v[i])) {
                snprintf(why, sizeof why, "input %s[%d] = %s: inputs must be finite (check what is connected "
                         "to it)", SLOT_NAMES[k], i, num(v[i], b1));
                return refuse(I, t, why);
            }
    }
    memcpy(I->backup, I->block, I->block_len * sizeof(double));
    int rc = 0;
    for (long i = 0; i < (long)steps && rc == 0; i++)
        rc = step(I, t + (double)i * I->dt);
    if (rc) {
        memcpy(I->block, I->backup, I->block_len * sizeof(double));     /* the instance as it was */
        if (rc == REFUSED)
            return refuse(I, t, I->err);
        log_error(I, "step from t = %s s failed: %s", num(t, b1), I->err);
        return fmi2Discard;                                           /* no Newton convergence */
    }
    *I->time = t + h;
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component c)
{
    Inst *I = instance(c);
    if (!I)
        return fmi2Error;
    log_error(I, "fmi2CancelStep: this FMU computes its steps synchronously, there is nothing to cancel");
    return fmi2Error;
}

static fmi2Status status_kind(fmi2Component c, fmi2StatusKind s, const char *fn, int allowed)
{
    Inst *I = instance(c);
    if (!I)
        return fmi2Error;
    if ((int)s != allowed) {
        log_error(I, "%s: status kind %d is not available (this FMU never returns fmi2Pending)", fn, (int)s);
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
        *value = *((Inst *)c)->time;
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

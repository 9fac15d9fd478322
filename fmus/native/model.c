/* The model at the FMI boundary: the initial state at t = 0, one step of dt from t (the soil,
   the structure with the split coupling's stamped inputs, or both: fmus/coupling.py), the
   outputs published into the variables; the life cycle and the communication step both FMI
   versions share (a step at the wrong time, not finite or negative, past the stop time, of the
   wrong size, with a non-finite input or a wrong stamp is refused; see fmi2.c). */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmu.h"

double *up_var(UpInstance *I, int slot) { return I->bank + I->slot[slot]; }

/* the gap and the running maxima of the uplift and the raft's rotation: after every step */
static void track_maxima(UpInstance *I)
{
    UpStepper *st = &I->st;
    double *gap = up_var(I, S_GAP), gmax = 0.0, *up = up_var(I, S_MAX_UPLIFT), *rot = up_var(I, S_MAX_RAFT_ROTATION);
    up_stepper_gap(st, gap);
    for (int i = 0; i < I->N; i++)
        gmax = i == 0 || gap[i] > gmax ? gap[i] : gmax;
    const double *q = st->u + st->ni;
    double r = hypot(q[3], q[4]);
    *up = *up >= gmax ? *up : gmax;
    *rot = *rot >= r ? *rot : r;
}

/* xs (n = 6 + N) <- the soil's DOFs [q, w] of the stepper's boundary block x: x itself for a rigid
   raft, x without the plate's deflections t ([q, t, w]) for a plate */
static void soil_part(const UpStepper *st, const double *x, double *xs, int n)
{
    memcpy(xs, x, 6 * sizeof(double));
    memcpy(xs + 6, x + 6 + st->nf, (size_t)(n - 6) * sizeof(double));
}

/* every output of the stepper: at the end of a communication step (its inner steps track the
   maxima only: the other outputs are overwritten before anyone reads them) */
static void publish_stepper(UpInstance *I)
{
    UpStepper *st = &I->st;
    int n = I->n, N = I->N;
    soil_part(st, st->u + st->ni, up_var(I, S_X), n);
    soil_part(st, st->v + st->ni, up_var(I, S_XDOT), n);
    memcpy(up_var(I, S_P), st->P, (size_t)N * sizeof(double));
    double *node = up_var(I, S_NODES);
    for (int k = 0; k < I->nnodes; k++)
        for (int c = 0; c < 3; c++) {
            int64_t d = I->node_dofs[3 * k + c];
            node[6 * k + c] = st->a[d] + st->ag[c];
            node[6 * k + 3 + c] = st->u[d];
        }
    up_stepper_energies(st, up_var(I, S_ENERGY));
    track_maxima(I);
    if (I->slot[S_X_TIME] >= 0)
        *up_var(I, S_X_TIME) = *st->t;
}

/* g is written by the step (or at rest, zero); f and dissipated_energy are computed when they are
   read (up_soil_read): a master that reads g only does not pay for them */
static void publish_soil(UpInstance *I, double t_next)
{
    *up_var(I, S_G_TIME) = t_next;
    *I->soil.stale = 1.0;
}

void up_soil_read(UpInstance *I, int64_t first, int64_t len)
{
    if (I->role != ROLE_SOIL || *I->soil.stale == 0.0)
        return;
    int64_t f = I->slot[S_F], e = I->slot[S_DISSIPATED_ENERGY];
    if ((first < f + I->n && f < first + len) || (first <= e && e < first + len))
        up_soil_outputs(&I->soil, 0, up_var(I, S_F), up_var(I, S_DISSIPATED_ENERGY));
}

/* the model at rest at t = 0 with the current inputs and parameters; 0 or -1 with I->err */
int up_initial_state(UpInstance *I)
{
    if (I->start_time != 0.0) {
        char b[32];
        snprintf(I->err, UP_MSG, UP_MSG_START_TIME, up_num(I->start_time, b));
        return -1;
    }
    *I->time = 0.0;
    *I->held_t = 0.0;
    memset(I->held, 0, (size_t)I->held_len * sizeof(double));
    if (!I->has_stepper) {
        up_soil_rest(&I->soil);
        up_soil_ahead(&I->soil, 0, up_var(I, S_G));
        publish_soil(I, 0.0);
        return 0;
    }
    double ag0[3];
    if (*I->internal_motion != 0.0) {
        if (!I->has_motion) {
            snprintf(I->err, UP_MSG, UP_MSG_NO_MOTION);
            return -1;
        }
        memcpy(ag0, I->motion, sizeof ag0);
    } else {
        memcpy(ag0, up_var(I, S_AG), sizeof ag0);
        for (int c = 0; c < 3; c++)
            if (!isfinite(ag0[c])) {
                char b[32], name[48];
                snprintf(I->err, UP_MSG, UP_MSG_NOT_FINITE, up_element_name(I, S_AG, c, name), up_num(ag0[c], b));
                return -1;
            }
    }
    up_stepper_rest(&I->st, ag0);
    *up_var(I, S_MAX_UPLIFT) = *up_var(I, S_MAX_RAFT_ROTATION) = 0.0;
    publish_stepper(I);
    return 0;
}

/* ---- the step ----------------------------------------------------------------------------------- */
/* the stamped input (values of length len, stamped by the partner's time): the values to use
   for the step from t, or NULL with I->err (see fmus.coupling.StampedInput) */
static const double *take(UpInstance *I, double t, double stamp, const double *values, int len, const char *name,
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
    snprintf(I->err, UP_MSG, UP_MSG_STAMP, name, stamp_name, up_num(stamp, b1), up_num(t, b2), stamp_name, name);
    return NULL;
}

static void ag_next(UpInstance *I, double t)
{
    double *next = I->st.ag_next;
    if (*I->internal_motion == 0.0) {
        memcpy(next, up_var(I, S_AG), 3 * sizeof(double));
        return;
    }
    int64_t k = (int64_t)floor(t / I->dt + 0.5) + 1;
    for (int c = 0; c < 3; c++)
        next[c] = k < I->nt ? I->motion[3 * k + c] : 0.0;
}


/* one step of dt from t, the last of its communication step or not (then the stepper's outputs
   but the maxima are not written): 0, UP_REFUSED (a wrong stamp) or UP_FAILED (no Newton
   convergence), with I->err */
int up_step(UpInstance *I, double t, int last)
{
    int n = I->n;
    if (I->role == ROLE_SOIL) {
        double *xx = I->tmp;
        memcpy(xx, up_var(I, S_X), (size_t)n * sizeof(double));
        memcpy(xx + n, up_var(I, S_XDOT), (size_t)n * sizeof(double));
        const double *used = take(I, t, *up_var(I, S_X_TIME), xx, 2 * n, "x, xdot", "x_time");
        if (!used)
            return UP_REFUSED;
        if (t > 0.5 * I->dt)                     /* at t = 0 the soil is at rest: nothing to commit */
            up_soil_step(&I->soil, 0, used, used + n, up_var(I, S_G));
        else
            up_soil_ahead(&I->soil, 0, up_var(I, S_G));
        publish_soil(I, t + I->dt);
        return 0;
    }
    UpStepper *st = &I->st;
    if (I->role == ROLE_STRUCTURE) {
        const double *g = take(I, t, *up_var(I, S_G_TIME), up_var(I, S_G), n, "g", "g_time");
        if (!g)
            return UP_REFUSED;
        const double *x = st->u + st->ni, *xd = st->v + st->ni;
        double *Gx = st->w_n[8], *Gv = st->w_n[9];          /* work of the stepper, free between steps */
        if (st->nf) {                                        /* a plate: the soil's DOFs [q, w] of [q, t, w] */
            soil_part(st, x, st->xs, n);
            soil_part(st, xd, st->vs, n);
            x = st->xs;
            xd = st->vs;
        }
        up_symv(I->Gx, I->Gxp, n, x, Gx);
        if (I->Gv_zero) {
            for (int i = 0; i < n; i++)
                st->h_ext[i] = g[i] + Gx[i];
        } else {
            up_matvec(I->Gv, n, n, xd, Gv);
            for (int i = 0; i < n; i++)
                st->h_ext[i] = (g[i] + Gx[i]) + Gv[i];
        }
    }
    ag_next(I, t);
    if (up_stepper_step(st))
        return UP_FAILED;
    *up_var(I, S_NEWTON_ITERS) = st->last_iters;
    if (last)
        publish_stepper(I);
    else
        track_maxima(I);
    return 0;
}


/* ---- the life cycle and the communication step (both FMI versions) -------------------------------- */
int up_setup_experiment(UpInstance *I, const char *fn, int stop_defined, double start, double stop)
{
    if (stop_defined && !(stop >= start)) {
        char b1[32], b2[32];
        up_log_error(I, "%s: stop time %s s before the start time %s s", fn, up_num(stop, b1), up_num(start, b2));
        return -1;
    }
    I->start_time = start;
    I->stop_time = stop_defined ? stop : INFINITY;
    return 0;
}

int up_enter_initialisation(UpInstance *I)
{
    if (up_initial_state(I)) {
        up_log_error(I, "initialisation failed: %s", I->err);
        return UP_ERROR;
    }
    I->state = UP_INITIALISATION;
    return UP_OK;
}

int up_exit_initialisation(UpInstance *I)
{
    if (up_initial_state(I)) {                 /* inputs and parameters set during initialisation */
        up_log_error(I, "initialisation failed: %s", I->err);
        return UP_ERROR;
    }
    I->state = UP_STEPPING;
    return UP_OK;
}

void up_reset(UpInstance *I)
{
    memset(I->block, 0, I->block_len * sizeof(double));
    *I->internal_motion = I->has_motion;
    I->start_time = 0.0;
    I->stop_time = INFINITY;
    I->state = UP_INSTANTIATED;
}

/* a call that cannot be right: UP_ERROR, logged, the instance as it was */
static int refuse(UpInstance *I, double t, const char *why)
{
    char b[32];
    up_log_error(I, UP_MSG_REFUSED, up_num(t, b), why);
    return UP_ERROR;
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
        snprintf(why, UP_MSG, UP_MSG_PAST_STOP, up_num(h, b1), up_num(t + h, b2), up_num(I->stop_time, b3),
                 I->api->setup);
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

/* the communication step from t of h: UP_OK; UP_ERROR for a call that cannot be right, UP_DISCARD
   for a step whose Newton iteration fails (after its halvings), the instance as it was, logged */
int up_do_step(UpInstance *I, double t, double h)
{
    char b1[32], why[UP_MSG];
    double steps = steps_of(I, t, h, why);
    if (steps < 0)
        return refuse(I, t, why);
    if (steps == 0) {                                         /* a sliver: nothing to compute */
        *I->time = t + h;
        return UP_OK;
    }
    /* the instance as it was if a step fails: a single step of the structure or the coupled
       model changes only the held input and the stepper's inputs (ag_next, h_ext) before its
       stepper step, which leaves the state as it found it when it fails: those are kept; the
       soil's step (always a single one) fails only when take() refuses its stamp, before it
       changes anything: its held input is kept all the same (its whole state block, 41 kB on the
       reactor, was copied before every step); several steps of the coupled model: the whole block */
    int whole = steps > 1;
    double *in = I->st.ag_next, *keep = I->backup + 1 + I->held_len;
    size_t in_len = whole || !I->has_stepper ? 0 : 3 + (size_t)I->st.nb;     /* ag_next and h_ext, consecutive */
    if (whole) {
        memcpy(I->backup, I->block, I->block_len * sizeof(double));
    } else {
        I->backup[0] = *I->held_t;
        memcpy(I->backup + 1, I->held, (size_t)I->held_len * sizeof(double));
        if (in_len)
            memcpy(keep, in, in_len * sizeof(double));
    }
    int rc = 0;
    for (long i = 0; i < (long)steps && rc == 0; i++)
        rc = up_step(I, t + (double)i * I->dt, i + 1 == (long)steps);
    if (rc) {
        if (whole) {
            memcpy(I->block, I->backup, I->block_len * sizeof(double));     /* the instance as it was */
        } else {
            *I->held_t = I->backup[0];
            memcpy(I->held, I->backup + 1, (size_t)I->held_len * sizeof(double));
            if (in_len)
                memcpy(in, keep, in_len * sizeof(double));
        }
        if (rc == UP_REFUSED)
            return refuse(I, t, I->err);
        up_log_error(I, "step from t = %s s failed: %s", up_num(t, b1), I->err);
        return UP_DISCARD;                                            /* no Newton convergence */
    }
    *I->time = t + h;
    if (I->logging)                                                   /* the number formatted only then */
        up_log_event(I, "step from t = %s s: %ld step(s) of dt", up_num(t, b1), (long)steps);
    return UP_OK;
}

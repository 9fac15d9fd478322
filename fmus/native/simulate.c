/* The in-process run: the stepper and the soil of the coupled FMU over a motion, in chunks of
   steps (no FMI layer, no call per step): the host reports progress and takes an interrupt
   between two chunks. The in-process routes load it with ctypes from a library compiled for
   the host (fmus/native_stepper.py); the native FMUs do not ship it.

   up_sim_open(res, size, ag0, err) -> handle
     res, size  the coupled FMU's resource records (fmus/native/README.md) in memory
     ag0        (3) ground acceleration at t = 0, m/s^2 (the state at rest)
     Parses the records, sets up the soil and the stepper at rest and prepares the system at dt:
     everything a run allocates. NULL when the records cannot be used (message in err).
   up_sim_width(handle) -> the length of a row: UP_ROW_WIDTH(N, nodes) = 6 + 3 N + 6 nodes + UP_N_ENERGY
   up_sim_steps(handle, ag, k0, k1, rows, iters, stats, err)
     computes samples k0 .. k1 - 1 (k0 the first sample not computed yet: 0, then the previous
     call's k1; sample 0 is the state at rest, sample k > 0 one step under ag[k])
     ag         (nt, 3) ground acceleration at k dt, m/s^2 (rows k0 .. k1 - 1 read)
     rows       (k1 - k0, width) out, row k - k0 for sample k, per sample (the parts of
                fmus.schema.ROW, at the offsets UP_ROW_* of uplift_schema.h): raft q (6), gap (N),
                total contact force P (N), soil w (N), per output node its absolute acceleration
                (3) and displacement (3), the energies (UP_N_ENERGY, in the order of
                fmus.schema.ENERGY_TERMS)
     iters      (k1 - k0) out, entry k - k0: Newton solves of the step to sample k
     stats      (3) out: samples computed so far (k1 unless a step failed), Jacobian
                factorisations, steps that were halved (over the whole run)
     Returns 0; 1 when a step's Newton iteration failed after its halvings (samples up to
     stats[0], the stepper's message in err; the run cannot go on); -1 when k0 is not the next
     sample (message in err). The samples are the same bits whatever the chunks.
   up_sim_steps_src(handle, ag, src, k0, k1, rows, iters, stats, err)
     up_sim_steps with a source in the contact equations: src (nt, N) N, row k the force W_k that
     the step to sample k adds to its contact equations (P - P0 + W the dynamic interface force,
     UpStepper.src; row 0 not read: sample 0 is the state at rest). The time-frequency route's
     defect correction marches its causal stand-in this way (orchestrator/timefreq/standin.py).
   up_sim_rewind(handle, ag0)
     the run back at rest under ag0 (3), its next sample 0 again, as up_sim_open leaves it, but
     with what the stepper built kept: the systems of each step size, the Newton bases and the
     capacitance matrices of the active sets seen (their numbers depend on the step size and the
     active set only: the samples are the same bits as a new handle's). The stand-in's marches,
     one per sweep of the defect correction, rewind one handle instead of opening a new one.
   up_sim_correction(handle, nt, mode) -> the mode set, or -1
     the next run of nt samples (after up_sim_open or up_sim_rewind) in the correction form of
     soil.c (up_soil_corr_mode): 1 its soil history and states recorded per sample, 2 its history
     as the last recorded run's plus the history of the change from that run's states in single
     precision (recorded in turn), 3 as 2 from a run at rest recorded (the whole history in single
     precision; returns 2), 0 neither. -1: not available (a soil history that is not packed
     symmetric, out of memory) or, for 2, no whole run of nt samples recorded without a halved
     step: the host asks for 3 or 1 then. The defect correction's marches (orchestrator/standin.py).
   up_sim_lean(handle, on)
     on 1: the run's next samples are a march of the defect correction, which reads the raft's q and
     the soil's w of each row only: the rows get those two parts (the others are left as they are),
     the works and energies are not summed, and the soil force's K0C x of each committed state is
     taken from the Newton iteration's S0 x instead of a product (UpStepper.lean: the samples then
     differ from a plain run's by the iterations' round-off carried from step to step); 0 (as
     up_sim_open leaves it): every part and the plain steps. Kept over up_sim_rewind.
   up_sim_close(handle)  frees the handle (NULL: nothing)
   up_simulate(res, size, ag, nt, rows, iters, stats, err)
     the whole motion in one call (open, the nt samples, close); returns 0, 1 or -1 as above. */
#include <stdlib.h>
#include <string.h>

#include "uplift.h"

struct UpSim {
    UpRes r;
    UpSoil soil;
    UpStepper st;
    double *block, *saves;
    const int64_t *node_dofs;
    int nnodes;
    int64_t next;               /* the first sample not computed yet */
    int64_t halved;             /* steps halved so far */
    int failed;
    int lean;                   /* up_sim_lean: the rows' raft and soil parts only */
    char err[UP_MSG];           /* the stepper's message */
};

static void record(const UpStepper *st, const int64_t *node_dofs, int nnodes, int lean, double *row)
{
    size_t N = (size_t)st->N, m = (size_t)nnodes;
    memcpy(row + UP_ROW_RAFT(N, m), st->u + st->ni, 6 * sizeof(double));
    if (lean) {
        memcpy(row + UP_ROW_SOIL_W(N, m), st->u + st->ns, N * sizeof(double));
        return;
    }
    up_stepper_gap(st, row + UP_ROW_GAP(N, m));
    memcpy(row + UP_ROW_CONTACT_FORCE(N, m), st->P, N * sizeof(double));
    memcpy(row + UP_ROW_SOIL_W(N, m), st->u + st->ns, N * sizeof(double));
    double *node = row + UP_ROW_NODES(N, m);
    for (int k = 0; k < nnodes; k++)
        for (int c = 0; c < 3; c++) {
            int64_t d = node_dofs[3 * k + c];
            node[6 * k + c] = st->a[d] + st->ag[c];
            node[6 * k + 3 + c] = st->u[d];
        }
    up_stepper_energies(st, row + UP_ROW_ENERGY(N, m));
}

UP_API void up_sim_close(UpSim *h)
{
    if (!h)
        return;
    free(h->block);
    free(h->saves);
    up_stepper_free(&h->st);
    up_soil_free(&h->soil);
    up_res_free(&h->r);
    free(h);
}

UP_API UpSim *up_sim_open(const unsigned char *res, uint64_t size, const double *ag0, char *err)
{
    UpSim *h = (UpSim *)calloc(1, sizeof *h);
    if (!h) {
        strcpy(err, "out of memory for the run");
        return NULL;
    }
    if (up_res_parse(&h->r, res, (size_t)size, "(in memory)", err)) {
        free(h);
        return NULL;
    }
    UpStepper *st = &h->st;
    double levels, n_dof;
    int64_t dims[2] = {-1, 3};
    h->node_dofs = up_res_i64(&h->r, "node_dofs", 2, dims, err);
    h->nnodes = (int)dims[0];
    if (!h->node_dofs || up_res_scalar(&h->r, "contact_max_subdiv", &levels, err)
        || up_res_scalar(&h->r, "n_dof", &n_dof, err))
        goto fail;
    if (!(levels >= 0 && levels < UP_MAXLEV) || !(n_dof >= 6 && n_dof <= 1e6)) {
        strcpy(err, "contact_max_subdiv or n_dof out of range");
        goto fail;
    }
    if (up_soil_init(&h->soil, &h->r, (int)n_dof, (int)levels + 1, 1, err))
        goto fail;
    if (up_stepper_init(st, &h->r, &h->soil, 0, err))
        goto fail;
    for (int k = 0; k < 3 * h->nnodes; k++)
        if (h->node_dofs[k] < 0 || h->node_dofs[k] >= st->n) {
            strcpy(err, "node_dofs out of range");
            goto fail;
        }
    st->err = h->err;
    size_t len = up_stepper_state_len(st) + up_soil_state_len(&h->soil);
    h->block = (double *)calloc(len, sizeof(double));
    h->saves = (double *)calloc((size_t)st->nlev * len, sizeof(double));
    if (!h->block || !h->saves) {
        strcpy(err, "out of memory for the stepper's state");
        goto fail;
    }
    up_stepper_bind(st, h->block, h->block, len, h->saves);
    up_soil_bind(&h->soil, h->block + up_stepper_state_len(st));
    up_stepper_rest(st, ag0);
    if (up_stepper_prepare(st, err))
        goto fail;
    return h;
fail:
    up_sim_close(h);
    return NULL;
}

UP_API int64_t up_sim_width(const UpSim *h)
{
    return UP_ROW_WIDTH((int64_t)h->st.N, (int64_t)h->nnodes);
}

static int steps(UpSim *h, const double *ag, const double *src, int64_t k0, int64_t k1, double *rows,
                 int64_t *iters, int64_t *stats, char *err)
{
    UpStepper *st = &h->st;
    size_t width = (size_t)up_sim_width(h);
    if (h->failed || k0 != h->next || k1 < k0) {
        strcpy(err, h->failed ? "the run stopped at a failed step" : "up_sim_steps: k0 is not the next sample");
        return -1;
    }
    int rc = 0;
    int64_t k = k0;
    for (; k < k1; k++) {
        if (k > 0) {
            memcpy(st->ag_next, ag + 3 * k, 3 * sizeof(double));
            st->src = src ? src + (size_t)k * (size_t)st->N : NULL;
            up_soil_corr_sample(&h->soil, k);
            int failed = up_stepper_step(st);
            st->src = NULL;
            if (failed) {
                memcpy(err, h->err, UP_MSG);
                h->failed = 1;
                rc = 1;
                break;
            }
            h->halved += st->last_halved;
        }
        iters[k - k0] = k > 0 ? st->last_iters : 0;
        record(st, h->node_dofs, h->nnodes, h->lean, rows + (size_t)(k - k0) * width);
    }
    h->next = k;
    stats[0] = k;
    stats[1] = st->n_factorisations;
    stats[2] = h->halved;
    return rc;
}

UP_API int up_sim_steps(UpSim *h, const double *ag, int64_t k0, int64_t k1, double *rows, int64_t *iters,
                        int64_t *stats, char *err)
{
    return steps(h, ag, NULL, k0, k1, rows, iters, stats, err);
}

UP_API int up_sim_steps_src(UpSim *h, const double *ag, const double *src, int64_t k0, int64_t k1, double *rows,
                            int64_t *iters, int64_t *stats, char *err)
{
    return steps(h, ag, src, k0, k1, rows, iters, stats, err);
}

UP_API void up_sim_rewind(UpSim *h, const double *ag0)
{
    up_stepper_rest(&h->st, ag0);
    h->next = 0;
    h->halved = 0;
    h->failed = 0;
    h->err[0] = '\0';
}

UP_API void up_sim_lean(UpSim *h, int on)
{
    h->lean = h->st.lean = on != 0;
}

UP_API int up_sim_correction(UpSim *h, int64_t nt, int mode)
{
    return up_soil_corr_mode(&h->soil, nt, mode);
}

UP_API int up_simulate(const unsigned char *res, uint64_t size, const double *ag, int64_t nt, double *rows,
                       int64_t *iters, int64_t *stats, char *err)
{
    stats[0] = stats[1] = stats[2] = 0;
    UpSim *h = up_sim_open(res, size, ag, err);
    if (!h)
        return -1;
    int rc = up_sim_steps(h, ag, 0, nt, rows, iters, stats, err);
    up_sim_close(h);
    return rc;
}

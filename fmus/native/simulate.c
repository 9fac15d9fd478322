/* The in-process run: the stepper and the soil of the coupled FMU over a whole motion, in one
   call (no FMI layer, no call per step). The in-process routes load it with ctypes from a
   library compiled for the host (fmus/native_host.py); the native FMUs do not ship it.

   up_simulate(res, size, ag, nt, rows, iters, stats, err)
     res, size  the coupled FMU's resource records (fmus/native/README.md) in memory
     ag         (nt, 3) ground acceleration at k dt, m/s^2
     rows       (nt, 6 + 3 N + 6 nodes + 7) out, per step: raft q (6), gap (N), total contact
                force P (N), soil w (N), per output node its absolute acceleration (3) and
                displacement (3), the energies (input, kinetic, strain, damping, soil, contact,
                contact_potential)
     iters      (nt) out: Newton solves per step
     stats      (3) out: steps computed (nt unless a step failed), Jacobian factorisations,
                steps that were halved
   Returns 0; 1 when a step's Newton iteration failed after its halvings (rows up to stats[0],
   the stepper's message in err); -1 when the records cannot be used (message in err). */
#include <stdlib.h>
#include <string.h>

#include "uplift.h"

static void record(const UpStepper *st, const int64_t *node_dofs, int nnodes, double *row)
{
    int N = st->N;
    memcpy(row, st->u + st->ni, 6 * sizeof(double));
    up_stepper_gap(st, row + 6);
    memcpy(row + 6 + N, st->P, (size_t)N * sizeof(double));
    memcpy(row + 6 + 2 * (size_t)N, st->u + st->ns, (size_t)N * sizeof(double));
    double *node = row + 6 + 3 * (size_t)N;
    for (int k = 0; k < nnodes; k++)
        for (int c = 0; c < 3; c++) {
            int64_t d = node_dofs[3 * k + c];
            node[6 * k + c] = st->a[d] + st->ag[c];
            node[6 * k + 3 + c] = st->u[d];
        }
    up_stepper_energies(st, node + 6 * (size_t)nnodes);
}

UP_API int up_simulate(const unsigned char *res, uint64_t size, const double *ag, int64_t nt, double *rows,
                       int64_t *iters, int64_t *stats, char *err)
{
    UpRes r;
    UpSoil soil;
    UpStepper st;
    double *block = NULL, *saves = NULL;
    int rc = -1;
    memset(&soil, 0, sizeof soil);
    memset(&st, 0, sizeof st);
    stats[0] = stats[1] = stats[2] = 0;
    if (up_res_parse(&r, res, (size_t)size, "(in memory)", err))
        return -1;
    double levels;
    int64_t dims[2] = {-1, 3};
    const int64_t *node_dofs = up_res_i64(&r, "node_dofs", 2, dims, err);
    int nnodes = (int)dims[0];
    double n_dof;
    if (!node_dofs || up_res_scalar(&r, "contact_max_subdiv", &levels, err) || up_res_scalar(&r, "n_dof", &n_dof, err))
        goto out;
    if (!(levels >= 0 && levels < UP_MAXLEV) || !(n_dof >= 6 && n_dof <= 1e6)) {
        strcpy(err, "contact_max_subdiv or n_dof out of range");
        goto out;
    }
    if (up_soil_init(&soil, &r, (int)n_dof, (int)levels + 1, 1, err))
        goto out;
    if (up_stepper_init(&st, &r, &soil, 0, err))
        goto out;
    for (int k = 0; k < 3 * nnodes; k++)
        if (node_dofs[k] < 0 || node_dofs[k] >= st.n) {
            strcpy(err, "node_dofs out of range");
            goto out;
        }
    st.err = err;
    size_t len = up_stepper_state_len(&st) + up_soil_state_len(&soil);
    block = (double *)calloc(len, sizeof(double));
    saves = (double *)calloc((size_t)st.nlev * len, sizeof(double));
    if (!block || !saves) {
        strcpy(err, "out of memory for the stepper's state");
        goto out;
    }
    up_stepper_bind(&st, block, block, len, saves);
    up_soil_bind(&soil, block + up_stepper_state_len(&st));
    up_stepper_rest(&st, ag);
    if (up_stepper_prepare(&st, err))
        goto out;
    size_t width = 6 + 3 * (size_t)st.N + 6 * (size_t)nnodes + 7;
    record(&st, node_dofs, nnodes, rows);
    iters[0] = 0;
    int64_t k = 1;
    rc = 0;
    for (; k < nt; k++) {
        memcpy(st.ag_next, ag + 3 * k, 3 * sizeof(double));
        if (up_stepper_step(&st)) {
            rc = 1;
            break;
        }
        iters[k] = st.last_iters;
        stats[2] += st.last_halved;
        record(&st, node_dofs, nnodes, rows + (size_t)k * width);
    }
    stats[0] = k;
    stats[1] = st.n_factorisations;
out:
    free(block);
    free(saves);
    up_stepper_free(&st);
    up_soil_free(&soil);
    up_res_free(&r);
    return rc;
}

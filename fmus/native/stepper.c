/* Newmark average acceleration (HHT-alpha option) with penalty contact and semi-smooth Newton:
   the discrete equations of structure/newmark.py (NewmarkStepper), step for step.

   u = [structure | q | w] (n = ns + N), relative to the static state under self-weight:
     M a + C v + K u + f_soil(x, xdot) + f_c(u) = -M r a_g(t),  x = [q, w] = u[ni:], ni = ns - 6
   f_soil = K0 x + C0 xdot + h on x, (K0, C0) = (D0(dt), E) of the soil model, h its history force
   (from the soil stepped here, or an input: the structure FMU); f_c = -B^T (P - P0) with the
   total contact force P_i = kp_i max(0, delta0_i - d_i), d = Bq3 q[2:5] - w.

   Per step size dt (one level per halving) the effective matrix
   A = diag(c0 M) + (1 + alpha)(K + c1 C) is condensed on x: A_II^-1 (from its LU),
   X = A_II^-1 A_IB, S0 = A_BB - A_BI X. Newton solves (S0 + (1 + alpha) B^T diag(kp active) B) dx
   = -g by Woodbury from two bases (below); an exact line search on the piecewise-quadratic
   incremental energy guards against cycling; a step whose Newton fails is halved recursively
   (ground motion interpolated, soil history of an external soil held) down to dt / 2**max_subdiv.
   A step writes the state only when it succeeds. When Ks, Cs (to round-off) and E are symmetric,
   the matrices a step multiplies are held symmetrised and packed (half the memory traffic, which
   bounds a step).

   Springs (a soil without memory: no pole, D and E zero between q and w and off the diagonal on
   w; the structure touches q only) make S0 a dense (6, 6) block on q plus a diagonal on w, and
   the contact couples each w_i to q[2:5] alone: a "diagonal soil" (UpStepper.diag). Its products
   with K0C and E take the two blocks, and a Newton solve eliminates the w_i node by node onto a
   (6, 6) system on q (newton_diag): O(N) a step instead of O(nb^2), and no bases. The same
   equations: the histories equal the dense path's to round-off. No allocation after
   up_stepper_init.

   A plate raft (structure/plate_raft.py, PlateStepper; resource record plate_nf): the boundary
   block is x = [q, t, w] (nb = 6 + nf + N), t the free plate vertices' deflections; the contact
   direction of node i is its trace on [q, t] (a few vertex weights, the held vertices' through
   q[2:5]) and -1 on w_i (UpStepper.bc_*), used wherever a rigid raft uses Bq3; the soil acts on
   [q, w] only: its matrices, history force and state vectors (fs, Kx, h) keep the soil's order
   (nsoil = 6 + N), gathered from x around each product (soil_gather, soil_dof). A plate's
   interior (the sticks and the free vertices' rotations) is condensed by a banded Cholesky with
   sparse couplings A_BI, A_IB when it is symmetric and narrow (plate_band_init, band_factor,
   band_solve): a step solves it twice by substitution instead of multiplying by A_II^-1 and X.
   The springs' node-by-node elimination is a rigid raft's only. Without plate_nf every line a rigid raft
   runs is the one it ran before the plate (the same bits).

   The reference is structure/newmark.py (NewmarkStepper: the readable Python stepper); this
   file and soil.c are what runs by default. A change to the physics is made there first, then
   here, step for step. The two are held equal by tests/fmu/test_native_stepper.py,
   test_native_springs.py and test_native_fmu.py: the same Newton counts and halved steps, every
   history to 1e-10 on a mild (bonded) scene and, where uplift amplifies round-off, to
   max(1e-10, 100 x its round-off spread) measured on the Python stepper (tests/helpers/roundoff.py,
   docs/verification.md). */
#ifdef UP_PROFILE
#define _POSIX_C_SOURCE 199309L
#endif
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "uplift.h"

enum { W_INPUT, W_DAMPING, W_SOIL, W_CONTACT };

/* A profiling build (-DUP_PROFILE, benchmarks/step_profile.py; never the FMUs' or the routes'
   build) times the parts of a step in process CPU seconds: up_profile(t, n) copies the
   totals and the call counts (inclusive: a solve's time holds its factorisation's). */
enum { P_HISTORY, P_S0, P_SOLVE, P_CAPACITANCE, P_BASE, P_SYSTEM, P_STEP, P_UPDATE, P_NPROF };
#ifdef UP_PROFILE
#include <time.h>
static double prof_t[P_NPROF];
static int64_t prof_n[P_NPROF];
static double prof_now(void)
{
    struct timespec t;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}
static double prof_stack[16];                              /* the open timers, nested */
static int prof_sp;
#define PROF_BEGIN(k) (prof_stack[prof_sp++] = prof_now())
#define PROF_END(k) (prof_t[k] += prof_now() - prof_stack[--prof_sp], prof_n[k]++)
UP_API void up_profile(double *t, int64_t *n, int reset)
{
    for (int k = 0; k < P_NPROF; k++) {
        t[k] = prof_t[k];
        n[k] = prof_n[k];
        if (reset)
            prof_t[k] = 0.0, prof_n[k] = 0;
    }
}
#else
#define PROF_BEGIN(k) (void)0
#define PROF_END(k) (void)0
#endif

static int scalar_in(const UpRes *r, const char *name, double lo, double hi, double *v, char *err)
{
    if (up_res_scalar(r, name, v, err))
        return -1;
    if (!(*v >= lo && *v <= hi)) {
        snprintf(err, UP_MSG, "resource file %s: %s = %g must lie in [%g, %g]: export the FMU again", r->path,
                 name, *v, lo, hi);
        return -1;
    }
    return 0;
}

static int finite_all(const double *a, size_t n)
{
    for (size_t i = 0; i < n; i++)
        if (!isfinite(a[i]))
            return 0;
    return 1;
}

/* 1 when the soil is springs: no pole, D and E zero (exactly) between q and w and off the diagonal
   on w */
static int diagonal_soil(const UpSoil *soil)
{
    int n = soil->n;
    if (soil->mr || soil->mc)
        return 0;
    for (int i = 0; i < n; i++)
        for (int j = 0; j < n; j++)
            if (i != j && (i >= 6 || j >= 6) && (soil->D[(size_t)i * n + j] != 0.0 || soil->E[(size_t)i * n + j] != 0.0))
                return 0;
    return 1;
}

/* c (36 + nb - 6) <- the (6, 6) block of A (nb, nb) on q, then its diagonal on w */
static void compact(const double *A, int nb, double *c)
{
    for (int i = 0; i < 6; i++)
        for (int j = 0; j < 6; j++)
            c[6 * i + j] = A[(size_t)i * nb + j];
    for (int i = 6; i < nb; i++)
        c[30 + i] = A[(size_t)i * nb + i];
}

/* A (n, n) symmetric to round-off: |A_ij - A_ji| <= 1e-13 max |A| (an assembled stiffness is
   symmetric but for the last bits of its products) */
static int symmetric(const double *A, int n)
{
    double big = 0.0, off = 0.0;
    for (int i = 0; i < n; i++)
        for (int j = 0; j < n; j++) {
            double a = fabs(A[(size_t)i * n + j]), d = fabs(A[(size_t)i * n + j] - A[(size_t)j * n + i]);
            big = a > big ? a : big;
            off = d > off ? d : off;
        }
    return off <= 1e-13 * big;
}

/* a plate raft's records: plate_nf (the free vertices: the deflections t of the boundary block
   [q, t, w]), plate_trace_col / plate_trace_val int64 / float64 (N, w) the trace of each node on
   [q, t] (column -1: none), compressed here; ns (read before) counts the plate's DOFs */
static int plate_init(UpStepper *s, const UpRes *r, char *err)
{
    double nf;
    int64_t dims[2] = {s->N, -1};
    if (scalar_in(r, "plate_nf", 0, 1e6, &nf, err))
        return -1;
    s->nf = (int)nf;
    s->ni = s->ns - 6 - s->nf;
    s->nb = 6 + s->nf + s->N;
    if (s->ni < 0) {
        snprintf(err, UP_MSG, "resource file %s: plate_nf = %d does not fit ns = %d: export the FMU again", r->path,
                 s->nf, s->ns);
        return -1;
    }
    const int64_t *col = up_res_i64(r, "plate_trace_col", 2, dims, err);
    const double *val = col ? up_res_f64(r, "plate_trace_val", 2, dims, err) : NULL;
    if (!val)
        return -1;
    int w = (int)dims[1];
    s->bc_ptr = (int *)calloc((size_t)s->N + 1, sizeof(int));
    s->bc_col = (int *)malloc(((size_t)s->N * w + 1) * sizeof(int));
    s->bc_val = (double *)malloc(((size_t)s->N * w + 1) * sizeof(double));
    if (!s->bc_ptr || !s->bc_col || !s->bc_val) {
        snprintf(err, UP_MSG, "out of memory for the plate's trace (%d nodes)", s->N);
        return -1;
    }
    int k = 0;
    for (int i = 0; i < s->N; i++) {
        for (int j = 0; j < w; j++) {
            int64_t c = col[(size_t)i * w + j];
            double v = val[(size_t)i * w + j];
            if (c < 0)
                continue;
            if (c >= 6 + s->nf || !isfinite(v)) {
                snprintf(err, UP_MSG, "resource file %s: plate_trace_col[%d] = %lld is not a DOF of [q, t] (or its "
                         "weight is not finite): export the FMU again", r->path, i, (long long)c);
                return -1;
            }
            s->bc_col[k] = (int)c;
            s->bc_val[k++] = v;
        }
        s->bc_ptr[i + 1] = k;
    }
    return 0;
}

/* the soil's DOF j (of [q, w]) in the boundary block ([q, t, w]) */
static inline int soil_dof(const UpStepper *s, int j)
{
    return j < 6 ? j : j + s->nf;
}

/* xs (nsoil) <- the soil's part [q, w] of x (nb) */
static void soil_gather(const UpStepper *s, const double *x, double *xs)
{
    memcpy(xs, x, 6 * sizeof(double));
    memcpy(xs + 6, x + 6 + s->nf, (size_t)s->N * sizeof(double));
}

/* ---- a plate's interior: A_II banded ------------------------------------------------------
   The interior of a plate raft is the sticks' DOFs and the free vertices' rotations: the two do
   not couple (the sticks hang on q) and each is sparse with a narrow band (a vertex couples to
   its cell neighbours'), so A_II = c0 M_I + (1 + al)(Ks + c1 Cs)_II is factorised by a banded
   Cholesky and a step's two interior solves (y = A_II^-1 rhs_I, then u_I = A_II^-1 (rhs_I -
   A_IB uB)) are banded substitutions with the sparse couplings A_BI, A_IB: about 2 (band + 1)
   ni values read twice instead of ni (ni + 1) / 2 of the packed inverse and the dense ni x nb
   X = A_II^-1 A_IB (X is still formed, once per level, for S0 = A_BB - A_BI X). Taken when the
   system is symmetric and 4 (band + 1) <= ni; a level whose A_II is not positive definite takes
   the dense path. */

/* the pattern (non-zeros of Ks or Cs) of the block rows r0.., cols c0.. (rows x cols) of the
   structure's matrices, as a sparse matrix of ones */
static int pattern_init(const UpStepper *s, UpSparse *S, int r0, int rows, int c0, int cols)
{
    double *P = (double *)calloc((size_t)rows * cols + 1, sizeof(double));
    if (!P)
        return -1;
    for (int i = 0; i < rows; i++)
        for (int j = 0; j < cols; j++) {
            int gi = r0 + i, gj = c0 + j;
            if (gi < s->ns && gj < s->ns
                && (s->Ks[(size_t)gi * s->ns + gj] != 0.0 || s->Cs[(size_t)gi * s->ns + gj] != 0.0))
                P[(size_t)i * cols + j] = 1.0;
        }
    int rc = up_sparse_init(S, P, rows, cols);
    free(P);
    return rc;
}

/* s->band (0: the dense path) and the coupling patterns; 0, or -1 out of memory */
static int plate_band_init(UpStepper *s)
{
    int ni = s->ni, ns = s->ns, b = 0;
    s->band = 0;
    if (!s->nf || !s->sym || ni < 8)
        return 0;
    for (int i = 0; i < ni; i++)
        for (int j = 0; j < i; j++)
            if ((s->Ks[(size_t)i * ns + j] != 0.0 || s->Cs[(size_t)i * ns + j] != 0.0) && i - j > b)
                b = i - j;
    if (4 * (b + 1) > ni)
        return 0;
    if (pattern_init(s, &s->bi_pat, ni, s->nb, 0, ni) || pattern_init(s, &s->ib_pat, 0, ni, ni, s->nb))
        return -1;
    s->band = b;
    return 0;
}

/* the level's values of A_BI, A_IB on their patterns, A_II's band and its Cholesky factor Lb;
   1 when A_II is positive definite (y->banded), else 0 */
static int band_factor(const UpStepper *s, UpSystem *y)
{
    int ni = s->ni, ns = s->ns, b = s->band;
    double al = s->alpha, c1 = y->c1;
    const UpSparse *P = &s->bi_pat, *Q = &s->ib_pat;
    for (int i = 0; i < P->rows; i++)
        for (int q = P->ptr[i]; q < P->ptr[i + 1]; q++) {
            size_t k = (size_t)(ni + i) * ns + P->col[q];
            y->bi_val[q] = (1 + al) * (s->Ks[k] + c1 * s->Cs[k]);
        }
    for (int i = 0; i < Q->rows; i++)
        for (int q = Q->ptr[i]; q < Q->ptr[i + 1]; q++) {
            size_t k = (size_t)i * ns + ni + Q->col[q];
            y->ib_val[q] = (1 + al) * (s->Ks[k] + c1 * s->Cs[k]);
        }
    double *L = y->Lb;
    for (int i = 0; i < ni; i++) {
        int j0 = i - b > 0 ? i - b : 0;
        double *li = L + (size_t)i * b + b;                  /* li[j]: L_ij (row i starts at i w) */
        for (int j = j0; j <= i; j++) {
            size_t k = (size_t)i * ns + j;
            double a = (1 + al) * (s->Ks[k] + c1 * s->Cs[k]) + (i == j ? y->c0 * s->M[i] : 0.0);
            const double *lj = L + (size_t)j * b + b;
            for (int m = j0; m < j; m++)                      /* L_jm = 0 below j - b <= j0 */
                a -= li[m] * lj[m];
            if (j < i) {
                li[j] = a / lj[j];
            } else {
                if (!(a > 0.0) || !isfinite(a))
                    return 0;
                li[i] = sqrt(a);
            }
        }
    }
    return 1;
}

/* x <- A_II^-1 x from the level's banded Cholesky factor (L L^T x = x) */
static void band_solve(const UpStepper *s, const UpSystem *y, double *x)
{
    int ni = s->ni, b = s->band;
    const double *L = y->Lb;
    for (int i = 0; i < ni; i++) {
        int j0 = i - b > 0 ? i - b : 0;
        const double *li = L + (size_t)i * b + b;
        double t = x[i];
        for (int j = j0; j < i; j++)
            t -= li[j] * x[j];
        x[i] = t / li[i];
    }
    for (int i = ni - 1; i >= 0; i--) {
        int j0 = i - b > 0 ? i - b : 0;
        const double *li = L + (size_t)i * b + b;
        double xi = x[i] / li[i];
        x[i] = xi;
        for (int j = j0; j < i; j++)
            x[j] -= li[j] * xi;
    }
}

static size_t k0c_blocks(UpStepper *s, UpSystem *y, const UpSoilLevel *sl);

int up_stepper_init(UpStepper *s, const UpRes *r, UpSoil *soil, int external, char *err)
{
    memset(s, 0, sizeof *s);
    double ns, N, enabled, max_iter, max_subdiv;
    if (scalar_in(r, "dt", 1e-300, 1e300, &s->sys[0].dt, err) || scalar_in(r, "ns", 6, 1e6, &ns, err) || scalar_in(r, "N", 0, 1e6, &N, err)
        || scalar_in(r, "alpha", -1.0 / 3.0 - 1e-12, 0.0, &s->alpha, err)
        || scalar_in(r, "contact_enabled", 0, 1, &enabled, err)
        || scalar_in(r, "contact_tol", 1e-300, 1.0, &s->tol, err)
        || scalar_in(r, "contact_max_iter", 1, 1e4, &max_iter, err)
        || scalar_in(r, "contact_max_subdiv", 0, UP_MAXLEV - 1, &max_subdiv, err))
        return -1;
    s->ns = (int)ns;
    s->N = (int)N;
    s->n = s->ns + s->N;
    s->ni = s->ns - 6;
    s->nb = 6 + s->N;
    s->nsoil = s->nb;
    if (up_res_find(r, "plate_nf") && plate_init(s, r, err))
        return -1;
    s->enabled = enabled != 0.0;
    s->max_iter = (int)max_iter;
    s->max_subdiv = (int)max_subdiv;
    s->nlev = s->max_subdiv + 1;
    s->beta = (1 - s->alpha) * (1 - s->alpha) / 4;
    s->gamma = 0.5 - s->alpha;
    s->soil = soil;
    s->external = external;
    if (soil->n != s->nsoil) {
        snprintf(err, UP_MSG, "resource file %s: the soil model has %d DOFs, the raft needs 6 + N = %d: "
                 "export the FMU again", r->path, soil->n, s->nsoil);
        return -1;
    }
    int n = s->n, ns_ = s->ns, Ni = s->N, nb = s->nb, ni = s->ni;
    int64_t dn[1] = {n}, dss[2] = {ns_, ns_}, dc[2] = {ns_, ns_}, dm[2] = {ns_, 3}, db[2] = {Ni, 3};
    int64_t dk[1] = {Ni}, dp[1] = {Ni}, dd[1] = {Ni};
    if (!(s->M = up_res_f64(r, "M", 1, dn, err)) || !(s->Ks = up_res_f64(r, "Ks", 2, dss, err))
        || !(s->Cs = up_res_f64(r, "Cs", 2, dc, err)) || !(s->Mr = up_res_f64(r, "Mr", 2, dm, err))
        || !(s->Bq3 = up_res_f64(r, "Bq3", 2, db, err)) || !(s->kp = up_res_f64(r, "kp", 1, dk, err))
        || !(s->P0 = up_res_f64(r, "P0", 1, dp, err)) || !(s->delta0 = up_res_f64(r, "delta0", 1, dd, err)))
        return -1;
    const double *arrays[] = {s->M, s->Ks, s->Cs, s->Mr, s->Bq3, s->kp, s->P0, s->delta0};
    const size_t sizes[] = {(size_t)n, (size_t)ns_ * ns_, (size_t)ns_ * ns_, (size_t)ns_ * 3, (size_t)Ni * 3,
                            (size_t)Ni, (size_t)Ni, (size_t)Ni};
    for (int k = 0; k < 8; k++)
        if (!finite_all(arrays[k], sizes[k])) {
            snprintf(err, UP_MSG, "resource file %s: the structure's matrices hold NaN or inf: export the "
                     "FMU again", r->path);
            return -1;
        }
    for (int i = 0; i < Ni; i++)
        if (!(s->kp[i] > 0)) {
            snprintf(err, UP_MSG, "resource file %s: contact penalty kp[%d] = %g must be > 0", r->path, i, s->kp[i]);
            return -1;
        }
    s->sym = symmetric(s->Ks, ns_) && symmetric(s->Cs, ns_) && soil->Ep != NULL;
    s->diag = !s->nf && diagonal_soil(soil);     /* a plate's contact couples w to t: the dense path */
    int ok = up_sparse_init(&s->Ks_sp, s->Ks, ns_, ns_) == 0 && up_sparse_init(&s->Cs_sp, s->Cs, ns_, ns_) == 0
             && plate_band_init(s) == 0;
    s->hk = !s->diag && !external && soil->hm_de_ranks && soil->Ep;
    if (s->hk) {
        size_t nt = (size_t)soil->mr + 2 * (size_t)soil->mc + 2;
        s->hk_off = (size_t *)malloc((nt * soil->hm_nblk + 1) * sizeof(size_t));
        ok = ok && s->hk_off;
        s->hk_len = ok ? k0c_blocks(s, NULL, NULL) : 0;
    }
    for (int l = 0; ok && l < s->nlev; l++) {
        UpSystem *y = &s->sys[l];
        y->AII = (double *)malloc(((size_t)ni * ni + 1) * sizeof(double));
        y->AIIp = (double *)malloc(((size_t)ni * (ni + 1) / 2 + 1) * sizeof(double));
        y->ABI = (double *)malloc(((size_t)nb * ni + 1) * sizeof(double));
        y->X = (double *)malloc(((size_t)ni * nb + 1) * sizeof(double));
        y->S0 = (double *)malloc((size_t)nb * nb * sizeof(double));
        y->Sq = (double *)malloc(((size_t)nb + 36) * sizeof(double));
        y->K0C = (double *)malloc((size_t)nb * nb * sizeof(double));
        y->K0Cp = (double *)malloc(((size_t)nb * (nb + 1) / 2 + 1) * sizeof(double));
        y->K0Cd = (double *)malloc(((size_t)nb + 30) * sizeof(double));
        y->S0d = (double *)malloc(((size_t)nb + 30) * sizeof(double));
        ok = y->AII && y->AIIp && y->ABI && y->X && y->S0 && y->Sq && y->K0C && y->K0Cp && y->K0Cd && y->S0d;
        if (ok && s->nf) {
            size_t nq = 6 + (size_t)s->nf;
            y->Sqt = (double *)malloc(nq * nq * sizeof(double));
            y->Sqtp = (double *)malloc(nq * (nq + 1) / 2 * sizeof(double));
            ok = y->Sqt && y->Sqtp;
        }
        if (ok && s->hk) {
            y->hk_rank = (int64_t *)malloc(((size_t)soil->hm_nblk + 1) * sizeof(int64_t));
            y->hk_data = (double *)malloc((s->hk_len + 1) * sizeof(double));
            ok = y->hk_rank && y->hk_data;
        }
        if (ok && s->band) {
            y->Lb = (double *)malloc(((size_t)ni * (s->band + 1) + 1) * sizeof(double));
            y->bi_val = (double *)malloc(((size_t)s->bi_pat.ptr[s->bi_pat.rows] + 1) * sizeof(double));
            y->ib_val = (double *)malloc(((size_t)s->ib_pat.ptr[s->ib_pat.rows] + 1) * sizeof(double));
            ok = y->Lb && y->bi_val && y->ib_val;
        }
        for (int c = 0; ok && c < 2; c++) {
            y->Jb[c] = (double *)malloc((size_t)nb * nb * sizeof(double));
            y->Jp[c] = (double *)malloc(((size_t)nb * (nb + 1) / 2 + 1) * sizeof(double));
            y->Jd[c] = (double *)malloc((size_t)nb * sizeof(double));
            y->Z[c] = (double *)malloc(((size_t)Ni * nb + 1) * sizeof(double));
            y->Jlu[c] = (double *)malloc((size_t)nb * nb * sizeof(double));
            y->Jpiv[c] = (int *)malloc((size_t)nb * sizeof(int));
            y->zdone[c] = (unsigned char *)calloc((size_t)Ni + 1, 1);
            ok = y->Jb[c] && y->Jp[c] && y->Jd[c] && y->Z[c] && y->Jlu[c] && y->Jpiv[c] && y->zdone[c];
        }
    }
    s->cache_lu = (double *)malloc(((size_t)UP_NCACHE * Ni * Ni + 1) * sizeof(double));
    s->cache_piv = (int *)malloc(((size_t)UP_NCACHE * Ni + 1) * sizeof(int));
    s->cache_nodes = (int *)malloc(((size_t)UP_NCACHE * Ni + 1) * sizeof(int));
    s->cache_lev = (int *)malloc(UP_NCACHE * sizeof(int));
    s->cache_base = (int *)calloc(UP_NCACHE, sizeof(int));
    s->cache_k = (int *)calloc(UP_NCACHE, sizeof(int));
    s->cache_act = (unsigned char *)calloc((size_t)UP_NCACHE * Ni + 1, 1);
    s->cache_used = (long *)calloc(UP_NCACHE, sizeof(long));
    ok = ok && s->cache_lu && s->cache_piv && s->cache_nodes && s->cache_lev && s->cache_base && s->cache_k
         && s->cache_act && s->cache_used;
    for (int k = 0; ok && k < UP_NCACHE; k++)
        s->cache_lev[k] = -1;
    for (int k = 0; ok && k < 10; k++)
        ok = (s->w_n[k] = (double *)calloc((size_t)n, sizeof(double))) != NULL;
    for (int k = 0; ok && k < 12; k++)
        ok = (s->w_nb[k] = (double *)calloc((size_t)nb, sizeof(double))) != NULL;
    for (int k = 0; ok && k < 6; k++)
        ok = (s->w_N[k] = (double *)calloc((size_t)Ni + 1, sizeof(double))) != NULL;
    if (ok) {
        size_t big = (size_t)(ni > nb ? ni : nb);
        s->lu = (double *)malloc((big * big + 1) * sizeof(double));
        s->rhs = (double *)malloc((big * big + 1) * sizeof(double));
        s->lu_piv = (int *)malloc((big + 1) * sizeof(int));
        s->hbuf = (double *)calloc((size_t)s->nlev * nb, sizeof(double));
        s->act = (unsigned char *)calloc((size_t)Ni + 1, 1);
        s->act_new = (unsigned char *)calloc((size_t)Ni + 1, 1);
        s->Ed = (double *)malloc(((size_t)nb + 30) * sizeof(double));
        s->xs = (double *)calloc((size_t)nb, sizeof(double));
        s->vs = (double *)calloc((size_t)nb, sizeof(double));
        ok = s->lu && s->rhs && s->lu_piv && s->hbuf && s->act && s->act_new && s->Ed && s->xs && s->vs;
    }
    if (ok)
        compact(soil->E, s->nsoil, s->Ed);
    if (!ok) {
        up_stepper_free(s);
        snprintf(err, UP_MSG, "out of memory for the structure (%d DOFs, %d step levels)", n, s->nlev);
        return -1;
    }
    return 0;
}

void up_stepper_free(UpStepper *s)
{
    for (int l = 0; l < UP_MAXLEV; l++) {
        UpSystem *y = &s->sys[l];
        free(y->AII);
        free(y->AIIp);
        free(y->ABI);
        free(y->X);
        free(y->S0);
        free(y->Sq);
        free(y->K0C);
        free(y->K0Cp);
        free(y->K0Cd);
        free(y->S0d);
        free(y->Sqt);
        free(y->Sqtp);
        free(y->Lb);
        free(y->hk_rank);
        free(y->hk_data);
        free(y->bi_val);
        free(y->ib_val);
        for (int c = 0; c < 2; c++) {
            free(y->Jb[c]);
            free(y->Jp[c]);
            free(y->Jd[c]);
            free(y->Z[c]);
            free(y->Jlu[c]);
            free(y->Jpiv[c]);
            free(y->zdone[c]);
        }
    }
    up_sparse_free(&s->Ks_sp);
    up_sparse_free(&s->Cs_sp);
    free(s->hk_off);
    up_sparse_free(&s->bi_pat);
    up_sparse_free(&s->ib_pat);
    free(s->cache_lu);
    free(s->cache_piv);
    free(s->cache_nodes);
    free(s->cache_base);
    free(s->cache_k);
    free(s->cache_lev);
    free(s->cache_act);
    free(s->cache_used);
    for (int k = 0; k < 10; k++)
        free(s->w_n[k]);
    for (int k = 0; k < 12; k++)
        free(s->w_nb[k]);
    for (int k = 0; k < 6; k++)
        free(s->w_N[k]);
    free(s->lu);
    free(s->rhs);
    free(s->lu_piv);
    free(s->hbuf);
    free(s->act);
    free(s->act_new);
    free(s->Ed);
    free(s->xs);
    free(s->vs);
    free(s->bc_ptr);
    free(s->bc_col);
    free(s->bc_val);
    memset(s, 0, sizeof *s);
}

size_t up_stepper_state_len(const UpStepper *s)
{
    return 1 + 5 * (size_t)s->n + (size_t)s->N + 4 * (size_t)s->nb + 11;
}

void up_stepper_bind(UpStepper *s, double *state, double *block, size_t block_len, double *saves)
{
    s->t = state;
    s->u = s->t + 1;
    s->v = s->u + s->n;
    s->a = s->v + s->n;
    s->P = s->a + s->n;
    s->fs = s->P + s->N;
    s->fc = s->fs + s->nb;
    s->R = s->fc + s->nb;
    s->F = s->R + s->n;
    s->ag = s->F + s->n;
    s->work = s->ag + 3;
    s->ag_next = s->work + 4;
    s->h_ext = s->ag_next + 3;
    s->Kx = s->h_ext + s->nb;
    s->kx_lev = s->Kx + s->nb;
    s->block = block;
    s->block_len = block_len;
    s->saves = saves;
}

/* F = -Mr ag on the structure DOFs (zero on w) */
static void load(const UpStepper *s, const double *ag, double *F)
{
    for (int i = 0; i < s->ns; i++) {
        const double *m = s->Mr + 3 * (size_t)i;
        F[i] = -(m[0] * ag[0] + m[1] * ag[1] + m[2] * ag[2]);
    }
    for (int i = s->ns; i < s->n; i++)
        F[i] = 0.0;
    if (s->src && s->nf) {            /* a plate: B^T W on [q, t, w] through its trace */
        double *Fx = F + s->ni, *Fw = F + s->ni + 6 + s->nf;
        for (int i = 0; i < s->N; i++) {
            double w = s->src[i];
            for (int k = s->bc_ptr[i]; k < s->bc_ptr[i + 1]; k++)
                Fx[s->bc_col[k]] += s->bc_val[k] * w;
            Fw[i] -= w;
        }
    } else if (s->src) {              /* the source W: P - P0 + W is the interface force, so B^T W a load */
        double *Fq = F + s->ni, *Fw = F + s->ni + 6;
        for (int i = 0; i < s->N; i++) {
            const double *b = s->Bq3 + 3 * (size_t)i;
            double w = s->src[i];
            Fq[2] += b[0] * w;
            Fq[3] += b[1] * w;
            Fq[4] += b[2] * w;
            Fw[i] -= w;
        }
    }
}

void up_stepper_rest(UpStepper *s, const double *ag0)
{
    memset(s->t, 0, up_stepper_state_len(s) * sizeof(double));
    memcpy(s->ag, ag0, 3 * sizeof(double));
    memcpy(s->ag_next, ag0, 3 * sizeof(double));
    load(s, ag0, s->F);
    for (int i = 0; i < s->n; i++)
        s->a[i] = s->M[i] > 0 ? s->F[i] / s->M[i] : 0.0;
    memcpy(s->P, s->P0, (size_t)s->N * sizeof(double));
    s->lean_steps = 0;
    if (!s->external)
        up_soil_rest(s->soil);
}

/* ---- K0C over the compressed history's partition -------------------------------------------
   When the soil's D and E are compressed with its history (hhistory.py: the same partition, the
   same tolerance), K0C = D0 + c1 E = D + c1 E + sum_b c_b H_b (c_b the level's b_k; a pair's
   b_k re for 2 Re R_k, im for -2 Im R_k) is held block by block over that partition: a block where
   every term is low-rank is the terms' factors stacked, U = [c_t U_t], V = [V_t] (exact: no
   truncation beyond the terms' own), when that is smaller than the block; any other block is K0C's
   own values (dense, from y->K0C). So the held K0C is the dense K0C the bases and S0 are built from,
   to round-off, and a product with it (up_hm_matvec) reads about the history block's share of n^2.
   The layout (which blocks are stacked, their ranks) is the same at every level: the size is
   counted once (y NULL) and each level's values are written into it. Returns the values' count. */
static size_t k0c_blocks(UpStepper *s, UpSystem *y, const UpSoilLevel *sl)
{
    const UpSoil *so = s->soil;
    int n = so->n, nblk = so->hm_nblk, nh = so->mr + 2 * so->mc, nt = nh + 2;
    const int64_t *perm = so->hm_perm;
    size_t len = 0, *off = s->hk_off;                    /* (nt, nblk): term t's values of block j */
    if (!y) {                                             /* the offsets, once */
        size_t o = 0;                                     /* history block by history block, then D, E */
        for (int t = 0; t < nt; t++) {
            if (t == nh)
                o = 0;
            const int64_t *rank = t < nh ? so->hm_ranks + (size_t)t * nblk : so->hm_de_ranks + (size_t)(t - nh) * nblk;
            for (int j = 0; j < nblk; j++) {
                const int64_t *bl = so->hm_blocks + 4 * (size_t)j;
                off[(size_t)t * nblk + j] = o;
                o += rank[j] < 0 ? (size_t)(bl[1] * bl[3]) : (size_t)(rank[j] * (bl[1] + bl[3]));
            }
        }
    }
    for (int j = 0; j < nblk; j++) {
        const int64_t *bl = so->hm_blocks + 4 * (size_t)j;
        int r0 = (int)bl[0], nr = (int)bl[1], c0 = (int)bl[2], nc = (int)bl[3];
        size_t dense = (size_t)nr * nc;
        int64_t rs = 0;
        int low = 1;
        for (int t = 0; low && t < nt; t++) {
            int64_t r = t < nh ? so->hm_ranks[(size_t)t * nblk + j] : so->hm_de_ranks[(size_t)(t - nh) * nblk + j];
            low = r >= 0;
            rs += r;
        }
        low = low && (size_t)rs * (nr + nc) < dense;
        if (y) {
            double *o = y->hk_data + len;
            y->hk_rank[j] = low ? rs : -1;
            if (!low) {
                for (int i = 0; i < nr; i++)
                    for (int l = 0; l < nc; l++)
                        o[(size_t)i * nc + l] = y->K0C[(size_t)perm[r0 + i] * n + perm[c0 + l]];
            } else {
                double *U = o, *V = o + (size_t)rs * nr;
                for (int t = 0; t < nt; t++) {             /* the history blocks, then D, then E */
                    const double *src = (t < nh ? so->hm_data : so->hm_de_data) + off[(size_t)t * nblk + j];
                    int64_t r = t < nh ? so->hm_ranks[(size_t)t * nblk + j] : so->hm_de_ranks[(size_t)(t - nh) * nblk + j];
                    double c;
                    if (t < so->mr)
                        c = sl->br[t];
                    else if (t < nh)
                        c = sl->bc[2 * ((t - so->mr) / 2) + (t - so->mr) % 2];
                    else
                        c = t == nh ? 1.0 : y->c1;
                    for (size_t q = 0; q < (size_t)r * nr; q++)
                        U[q] = c * src[q];
                    memcpy(V, src + (size_t)r * nr, (size_t)r * nc * sizeof(double));
                    U += (size_t)r * nr;
                    V += (size_t)r * nc;
                }
            }
        }
        len += low ? (size_t)rs * (nr + nc) : dense;
    }
    return len;
}

/* ---- the per-level system ------------------------------------------------------------------ */
static int base_at(UpStepper *s, UpSystem *y, int c);
static const UpSystem *system_build(UpStepper *s, int lev);
static const UpSystem *system_at(UpStepper *s, int lev)
{
    if (s->sys[lev].ready)
        return &s->sys[lev];
    PROF_BEGIN(P_SYSTEM);
    const UpSystem *y = system_build(s, lev);
    PROF_END(P_SYSTEM);
    return y;
}

static const UpSystem *system_build(UpStepper *s, int lev)
{
    UpSystem *y = &s->sys[lev];
    double dt = s->sys[0].dt;
    for (int l = 0; l < lev; l++)
        dt /= 2;                                          /* exact: a power of two */
    const UpSoilLevel *sl = up_soil_level(s->soil, lev, dt);
    double b = s->beta, g = s->gamma, al = s->alpha;
    y->dt = dt;
    y->c0 = 1 / (b * dt * dt);
    y->c1 = g / (b * dt);
    y->c2 = 1 / (b * dt);
    y->c3 = 1 / (2 * b) - 1;
    int ns = s->ns, ni = s->ni, nb = s->nb;
    /* the blocks of A = diag(c0 M) + (1 + al)(K + c1 C), K = Ks + K0 and C = Cs + E embedded;
       A_II factorised in the set-up's work (s->lu) */
    double *LU = s->lu;
    for (int i = 0; i < ni; i++)
        for (int j = 0; j < ni; j++) {
            double k = s->Ks[(size_t)i * ns + j], c = s->Cs[(size_t)i * ns + j];
            LU[(size_t)i * ni + j] = (1 + al) * (k + y->c1 * c) + (i == j ? y->c0 * s->M[i] : 0.0);
        }
    for (int i = 0; i < nb; i++)
        for (int j = 0; j < ni; j++) {
            int gi = ni + i;
            double k = gi < ns ? s->Ks[(size_t)gi * ns + j] : 0.0, c = gi < ns ? s->Cs[(size_t)gi * ns + j] : 0.0;
            y->ABI[(size_t)i * ni + j] = (1 + al) * (k + y->c1 * c);
        }
    double *S0 = y->S0;
    int nso = s->nsoil, nf = s->nf;
    for (int i = 0; i < nb; i++)
        for (int j = 0; j < nb; j++) {
            int gi = ni + i, gj = ni + j;
            int si = i < 6 ? i : i - nf, sj = j < 6 ? j : j - nf;    /* the soil's DOFs, when not a plate's t */
            int on = (i < 6 || i >= 6 + nf) && (j < 6 || j >= 6 + nf);
            double k = on ? sl->D0[(size_t)si * nso + sj] : 0.0, c = on ? s->soil->E[(size_t)si * nso + sj] : 0.0;
            if (gi < ns && gj < ns) {
                k += s->Ks[(size_t)gi * ns + gj];
                c += s->Cs[(size_t)gi * ns + gj];
            }
            S0[(size_t)i * nb + j] = (1 + al) * (k + y->c1 * c) + (i == j ? y->c0 * s->M[gi] : 0.0);
        }
    y->banded = s->band && band_factor(s, y);               /* a plate: A_II banded (band_solve) */
    if (ni > 0 && !y->banded && up_lu(LU, s->lu_piv, ni))
        return NULL;
    /* X = A_II^-1 A_IB, column by column; only the columns of the raft DOFs are not zero */
    memset(y->X, 0, (size_t)ni * nb * sizeof(double));
    double *col = s->w_n[0];
    for (int j = 0; j < nb && ni > 0; j++) {
        int gj = ni + j, any = 0;
        for (int i = 0; i < ni; i++) {
            double k = gj < ns ? s->Ks[(size_t)i * ns + gj] : 0.0, c = gj < ns ? s->Cs[(size_t)i * ns + gj] : 0.0;
            col[i] = (1 + al) * (k + y->c1 * c);
            any |= col[i] != 0.0;
        }
        if (!any)
            continue;
        if (y->banded)
            band_solve(s, y, col);
        else
            up_lu_solve(LU, s->lu_piv, ni, col);
        for (int i = 0; i < ni; i++)
            y->X[(size_t)i * nb + j] = col[i];
    }
    /* A_II^-1 itself: a step's solve is then one product (packed: half the memory traffic) */
    if (ni > 0 && !y->banded)
        up_inverse(LU, s->lu_piv, ni, y->AII, s->sym ? y->AIIp : NULL);
    y->abi_rows = y->x_cols = 0;
    for (int i = 0; i < nb; i++)
        for (int k = 0; k < ni; k++)
            if (y->ABI[(size_t)i * ni + k] != 0.0)
                y->abi_rows = i + 1;
    for (int i = 0; i < ni; i++)
        for (int j = 0; j < nb; j++)
            if (y->X[(size_t)i * nb + j] != 0.0 && j + 1 > y->x_cols)
                y->x_cols = j + 1;
    for (int i = 0; i < nb; i++)
        for (int k = 0; k < ni; k++) {
            double a = y->ABI[(size_t)i * ni + k];
            if (a == 0.0)
                continue;
            const double *xk = y->X + (size_t)k * nb;
            double *si = S0 + (size_t)i * nb;
            for (int j = 0; j < nb; j++)
                si[j] -= a * xk[j];
        }
    /* S0 = (1 + al) K0C + diag(c0 M_B) + Sq on q: the structure's part (its stiffness, damping
       and condensation) touches the raft's six DOFs only */
    double *Sq = y->Sq, *cM = y->Sq + 36;
    for (int i = 0; i < 6; i++)
        for (int j = 0; j < 6; j++) {
            int gi = ni + i, gj = ni + j;
            double v = (1 + al) * (s->Ks[(size_t)gi * ns + gj] + y->c1 * s->Cs[(size_t)gi * ns + gj]);
            for (int k = 0; k < ni; k++)
                v -= y->ABI[(size_t)i * ni + k] * y->X[(size_t)k * nb + j];
            Sq[6 * i + j] = v;
        }
    for (int i = 0; i < nb; i++)
        cM[i] = y->c0 * s->M[ni + i];
    if (s->sym) {                                         /* symmetric but for the round-off of A_BI X */
        for (int i = 0; i < nb; i++)
            for (int j = i + 1; j < nb; j++) {
                double m = 0.5 * (S0[(size_t)i * nb + j] + S0[(size_t)j * nb + i]);
                S0[(size_t)i * nb + j] = S0[(size_t)j * nb + i] = m;
            }
        for (int i = 0; i < 6; i++)
            for (int j = i + 1; j < 6; j++)
                Sq[6 * i + j] = Sq[6 * j + i] = 0.5 * (Sq[6 * i + j] + Sq[6 * j + i]);
    }
    /* on the soil's DOFs [q, w] (nsoil; a rigid raft: nb) */
    for (size_t i = 0; i < (size_t)nso * nso; i++)
        y->K0C[i] = sl->D0[i] + y->c1 * s->soil->E[i];
    up_pack_sym(y->K0C, nso, y->K0Cp);                    /* symmetric when E is (D0 is) */
    if (s->hk)
        k0c_blocks(s, y, sl);                             /* the same K0C over the history's partition */
    compact(y->K0C, nso, y->K0Cd);
    if (nf) {                                             /* a plate: S0's structural part on [q, t] */
        int nq = 6 + nf;
        for (int i = 0; i < nq; i++)
            for (int j = 0; j < nq; j++)
                y->Sqt[(size_t)i * nq + j] = (S0[(size_t)i * nb + j]
                                              - (i < 6 && j < 6 ? (1 + al) * y->K0C[(size_t)i * nso + j] : 0.0))
                                             - (i == j ? y->c0 * s->M[ni + i] : 0.0);
        if (s->sym) {
            for (int i = 0; i < nq; i++)
                for (int j = i + 1; j < nq; j++)
                    y->Sqt[(size_t)i * nq + j] = y->Sqt[(size_t)j * nq + i]
                        = 0.5 * (y->Sqt[(size_t)i * nq + j] + y->Sqt[(size_t)j * nq + i]);
            up_pack_sym(y->Sqt, nq, y->Sqtp);
        }
    }
    compact(S0, nb, y->S0d);
    y->base_ok[0] = y->base_ok[1] = 0;                    /* built when first needed (base) */
    y->ready = 1;
    return y;
}

/* y = A x for a soil matrix A (nsoil, nsoil) of the level (K0C, E) at x = [q, w] (nsoil: a plate's
   x gathered first, soil_gather): over the compressed history's partition when held so (hr, hd: its
   ranks and values, UpStepper.hk), dense (packed when P is not NULL), or from c, A compact (compact),
   for a diagonal soil */
static void soil_product(const UpStepper *s, const double *A, const double *P, const double *c, const int64_t *hr,
                         const double *hd, const double *x, double *y)
{
    if (s->hk && hr) {
        up_hm_matvec(s->soil, hr, hd, x, y);
        return;
    }
    if (!s->diag) {
        up_symv(A, P, s->nsoil, x, y);
        return;
    }
    for (int i = 0; i < 6; i++)
        y[i] = up_dot(c + 6 * i, x, 6);
    for (int i = 6; i < s->nsoil; i++)
        y[i] = c[30 + i] * x[i];
}

/* ---- contact ------------------------------------------------------------------------------- */
/* d = Bq3 x[2:5] - x[6:] for x = [q, w] */
static void relative(const UpStepper *s, const double *x, double *d)
{
    if (s->nf) {                                          /* a plate: d_i = trace_i . [q, t] - w_i */
        const double *w = x + 6 + s->nf;
        for (int i = 0; i < s->N; i++) {
            double t = 0.0;
            for (int k = s->bc_ptr[i]; k < s->bc_ptr[i + 1]; k++)
                t += s->bc_val[k] * x[s->bc_col[k]];
            d[i] = t - w[i];
        }
        return;
    }
    for (int i = 0; i < s->N; i++) {
        const double *b = s->Bq3 + 3 * (size_t)i;
        d[i] = (b[0] * x[2] + b[1] * x[3] + b[2] * x[4]) - x[6 + i];
    }
}

/* the contact force P_i of node i at the relative displacement d_i, and whether it is active:
   the penalty law, or the bonded spring around the static force P0 when contact is disabled */
static double node_force(const UpStepper *s, int i, double di, unsigned char *act)
{
    if (s->enabled) {
        double pen = s->delta0[i] - di;
        *act = pen > 0;
        return *act ? s->kp[i] * pen : 0.0;
    }
    *act = 1;
    return s->P0[i] - s->kp[i] * di;
}

/* P (N), active (N) and the contact internal force fc (nb) at x = [q, w] */
static void contact(const UpStepper *s, const double *x, double *P, unsigned char *act, double *fc)
{
    double *d = s->w_N[5], f2 = 0.0, f3 = 0.0, f4 = 0.0;    /* fc[2:5], summed in registers */
    relative(s, x, d);
    if (s->nf) {                                          /* a plate: fc = -Bc^T (P - P0) */
        memset(fc, 0, (size_t)s->nb * sizeof(double));
        for (int i = 0; i < s->N; i++) {
            P[i] = node_force(s, i, d[i], &act[i]);
            double dp = P[i] - s->P0[i];
            for (int k = s->bc_ptr[i]; k < s->bc_ptr[i + 1]; k++)
                fc[s->bc_col[k]] -= s->bc_val[k] * dp;
            fc[6 + s->nf + i] = dp;
        }
        return;
    }
    for (int i = 0; i < s->N; i++) {
        P[i] = node_force(s, i, d[i], &act[i]);
        double dp = P[i] - s->P0[i];
        const double *b = s->Bq3 + 3 * (size_t)i;
        f2 -= b[0] * dp;
        f3 -= b[1] * dp;
        f4 -= b[2] * dp;
        fc[6 + i] = dp;
    }
    fc[0] = fc[1] = fc[5] = 0.0;
    fc[2] = f2;
    fc[3] = f3;
    fc[4] = f4;
}

/* g = S0 x + (1 + al) fc(x) - r_hat, with the active set at x; Sx = S0 x given (S0 is linear: the
   Newton loop updates it from the line search's S0 dx, one product per iteration) */
static void residual(const UpStepper *s, const double *Sx, const double *x, const double *r_hat, double *g,
                     unsigned char *act)
{
    double *fc = s->w_nb[9], *P = s->w_N[4];
    contact(s, x, P, act, fc);
    for (int i = 0; i < s->nb; i++)
        g[i] = (Sx[i] + (1 + s->alpha) * fc[i]) - r_hat[i];
}

/* ---- the Newton matrix J(act) = S0 + sum over the active nodes of s_i b_i b_i^T ----------------
   s_i = (1 + al) kp_i, b_i the contact direction of node i (Bq3_i on q[2:5], -1 on w_i). Two
   bases per level, each inverted once when first needed: every contact closed (Jc) and every
   contact open (S0), with Z_i = base^-1 b_i solved for node i when it first enters a capacitance
   matrix (directions) and W_ij = b_i . Z_j. J(act) differs from the nearer base by
   the k = min(open, closed) nodes K: J = base + sigma U_K S_K U_K^T (sigma -1 from the closed
   base, +1 from the open one), so by Woodbury
       J^-1 r = y - Z_K C^-1 (U_K^T y),  y = base^-1 r,  C = sigma S_K^-1 + W_KK  (k, k).
   Only C is factorised per active set ((2/3) k^3 instead of (2/3) nb^3), kept per (level, active
   set) in the cache (least recently used replaced). Every number depends on the level and the
   active set only, never on what the cache held before: a replayed step is the same bit for bit. */
static double along(const UpStepper *s, int i, const double *x)
{
    if (s->nf) {
        double t = 0.0;
        for (int k = s->bc_ptr[i]; k < s->bc_ptr[i + 1]; k++)
            t += s->bc_val[k] * x[s->bc_col[k]];
        return t - x[6 + s->nf + i];
    }
    const double *b = s->Bq3 + 3 * (size_t)i;
    return ((b[0] * x[2] + b[1] * x[3]) + b[2] * x[4]) - x[6 + i];
}

/* ---- a large base's inverse ----------------------------------------------------------------
   From UP_INV4_MIN DOFs on, a base's inverse is formed from its LU by substitutions that update
   a block of INV4_ROWS rows of the result at once (block_update): each row of the substitutions'
   right-hand side is then read once per block instead of once per row (up_inverse reads the rows
   of its n^2 right-hand side, which do not fit in cache, once per row: the memory traffic, not
   the arithmetic, bounds it at these sizes). The forward substitution
   runs over the increasing rows of L (up_inverse's order), the backward one over the decreasing
   columns of U (the reverse of up_inverse's: a row's updates then all come from rows already
   final), so an entry's result differs from up_inverse's by round-off. Below UP_INV4_MIN (the
   reactor's bases among them) up_inverse, the same bits as before. */
#define UP_INV4_MIN 512
#if defined(__x86_64__) && defined(__GNUC__) && !defined(UP_BASELINE_ONLY)
#define INV4_DISPATCH 1
#define INV4_BODY static inline __attribute__((always_inline))
#else
#define INV4_BODY static inline
#endif

/* o_r[j] = (o_r[j] - a_r x[j]) - b_r y[j] for the four rows (j < k) */
INV4_BODY void upd4x2(double *restrict o0, double *restrict o1, double *restrict o2, double *restrict o3,
                      const double *restrict x, const double *restrict y, const double *a, const double *b, int k)
{
    double a0 = a[0], a1 = a[1], a2 = a[2], a3 = a[3], b0 = b[0], b1 = b[1], b2 = b[2], b3 = b[3];
    for (int j = 0; j < k; j++) {
        double xj = x[j], yj = y[j];
        o0[j] = (o0[j] - a0 * xj) - b0 * yj;
        o1[j] = (o1[j] - a1 * xj) - b1 * yj;
        o2[j] = (o2[j] - a2 * xj) - b2 * yj;
        o3[j] = (o3[j] - a3 * xj) - b3 * yj;
    }
}

INV4_BODY void upd4x1(double *restrict o0, double *restrict o1, double *restrict o2, double *restrict o3,
                      const double *restrict x, const double *a, int k)
{
    double a0 = a[0], a1 = a[1], a2 = a[2], a3 = a[3];
    for (int j = 0; j < k; j++) {
        double xj = x[j];
        o0[j] -= a0 * xj;
        o1[j] -= a1 * xj;
        o2[j] -= a2 * xj;
        o3[j] -= a3 * xj;
    }
}

INV4_BODY void upd1x2(double *restrict o, const double *restrict x, const double *restrict y, double a, double b,
                      int k)
{
    for (int j = 0; j < k; j++)
        o[j] = (o[j] - a * x[j]) - b * y[j];
}

/* o_r[j] -= c_r[p] B_p[j] (j < k) for the rows o_0 .. o_{nrow-1} of the result (nrow <= INV4_ROWS),
   over p in [p0, p1), increasing (up) or decreasing, each row's updates in that order: the columns
   in chunks of INV4_CHUNK and, per chunk, two rows of B at a time applied to every row of the
   block (four at a time), so that a chunk of B is read once for the block's rows and the block's
   chunk stays in cache through the pass over p */
#ifndef INV4_ROWS
#define INV4_ROWS 32
#endif
#ifndef INV4_CHUNK
#define INV4_CHUNK 1024
#endif
INV4_BODY void block_update(double *const *o, int nrow, const double *B, size_t ld, const double *const *c, int p0,
                            int p1, int k, int up)
{
    int m = p1 - p0;
    for (int j0 = 0; j0 < k; j0 += INV4_CHUNK) {
        int kk = k - j0 < INV4_CHUNK ? k - j0 : INV4_CHUNK, q = 0;
        for (; q + 2 <= m; q += 2) {
            int pa = up ? p0 + q : p1 - 1 - q, pb = up ? pa + 1 : pa - 1;
            const double *x = B + (size_t)pa * ld + j0, *y = B + (size_t)pb * ld + j0;
            int g = 0;
            for (; g + 4 <= nrow; g += 4) {
                double a[4] = {c[g][pa], c[g + 1][pa], c[g + 2][pa], c[g + 3][pa]};
                double b[4] = {c[g][pb], c[g + 1][pb], c[g + 2][pb], c[g + 3][pb]};
                upd4x2(o[g] + j0, o[g + 1] + j0, o[g + 2] + j0, o[g + 3] + j0, x, y, a, b, kk);
            }
            for (; g < nrow; g++)
                upd1x2(o[g] + j0, x, y, c[g][pa], c[g][pb], kk);
        }
        if (q < m) {
            int pa = up ? p0 + q : p1 - 1 - q;
            const double *x = B + (size_t)pa * ld + j0;
            int g = 0;
            for (; g + 4 <= nrow; g += 4) {
                double a[4] = {c[g][pa], c[g + 1][pa], c[g + 2][pa], c[g + 3][pa]};
                upd4x1(o[g] + j0, o[g + 1] + j0, o[g + 2] + j0, o[g + 3] + j0, x, a, kk);
            }
            for (; g < nrow; g++) {
                double a = c[g][pa], *og = o[g] + j0;
                for (int jj = 0; jj < kk; jj++)
                    og[jj] -= a * x[jj];
            }
        }
    }
}

/* o[j] -= c[p] B_p[j] (j < k) over p in [p0, p1), increasing (up) or decreasing */
INV4_BODY void row1_update(double *restrict o, const double *B, size_t ld, const double *c, int p0, int p1, int k,
                           int up)
{
    for (int q = 0; q < p1 - p0; q++) {
        int p = up ? p0 + q : p1 - 1 - q;
        const double *restrict b = B + (size_t)p * ld;
        double l = c[p];
        for (int j = 0; j < k; j++)
            o[j] -= l * b[j];
    }
}

/* inv (n, n) <- U^-1 L^-1 of the identity from the LU (unit L), then its columns swapped as the LU
   swapped the rows (inverse_k's result, to round-off) */
INV4_BODY void inverse4_k(const double *LU, const int *piv, int n, double *inv)
{
    size_t ld = (size_t)n;
    for (int i = 0; i < n; i++)
        for (int j = 0; j < n; j++)
            inv[(size_t)i * n + j] = i == j ? 1.0 : 0.0;
    /* forward: row i -= L_ip row p (p < i), on columns < i (L^-1 is lower triangular, unit), by
       blocks of rows: the rows above the block, then among its rows */
    double *o[INV4_ROWS];
    const double *c[INV4_ROWS];
    for (int i = 0; i < n; i += INV4_ROWS) {
        int nrow = n - i < INV4_ROWS ? n - i : INV4_ROWS;
        for (int r = 0; r < nrow; r++) {
            o[r] = inv + (size_t)(i + r) * ld;
            c[r] = LU + (size_t)(i + r) * ld;
        }
        block_update(o, nrow, inv, ld, c, 0, i, i, 1);
        for (int r = 1; r < nrow; r++)
            row1_update(o[r], inv, ld, c[r], i, i + r, i + r, 1);
    }
    /* backward: row i -= U_ip row p (p > i, decreasing), then / U_ii, by blocks of rows from the
       last: the rows below the block, then among its rows */
    for (int i = n - 1; i >= 0; i -= INV4_ROWS) {
        int nrow = i + 1 < INV4_ROWS ? i + 1 : INV4_ROWS;
        for (int r = 0; r < nrow; r++) {
            o[r] = inv + (size_t)(i - r) * ld;
            c[r] = LU + (size_t)(i - r) * ld;
        }
        block_update(o, nrow, inv, ld, c, i + 1, n, n, 0);
        for (int r = 0; r < nrow; r++) {
            row1_update(o[r], inv, ld, c[r], i - r + 1, i + 1, n, 0);
            double d = c[r][i - r];
            for (int j = 0; j < n; j++)
                o[r][j] /= d;
        }
    }
    for (int q = n - 1; q >= 0; q--)                      /* A^-1 = U^-1 L^-1 P: the swaps on the columns */
        if (piv[q] != q)
            for (int r = 0; r < n; r++) {
                double *row = inv + (size_t)r * n, t = row[q];
                row[q] = row[piv[q]];
                row[piv[q]] = t;
            }
}

#ifdef INV4_DISPATCH
__attribute__((target("avx512f"))) static void inverse4_avx512(const double *LU, const int *piv, int n, double *inv)
{
    inverse4_k(LU, piv, n, inv);
}
__attribute__((target("avx2"))) static void inverse4_avx2(const double *LU, const int *piv, int n, double *inv)
{
    inverse4_k(LU, piv, n, inv);
}
#endif

/* a base's inverse from its LU: up_inverse below UP_INV4_MIN, else inverse4 (then symmetrised and
   packed into P when P is not NULL, as up_inverse does) */
static void base_inverse(const double *LU, const int *piv, int n, double *inv, double *P)
{
    if (n < UP_INV4_MIN) {
        up_inverse(LU, piv, n, inv, P);
        return;
    }
#ifdef INV4_DISPATCH
    int level = up_vector_level();
    if (level == 2)
        inverse4_avx512(LU, piv, n, inv);
    else if (level == 1)
        inverse4_avx2(LU, piv, n, inv);
    else
        inverse4_k(LU, piv, n, inv);
#else
    inverse4_k(LU, piv, n, inv);
#endif
    if (P)
        up_symmetrise_pack(inv, n, P);
}

/* base c of level lev: its LU and inverse (the directions Z when first needed: directions);
   0, or -1 when singular */
static int base_at(UpStepper *s, UpSystem *y, int c)
{
    int N = s->N, nb = s->nb;
    double *J = y->Jlu[c], *Ji = y->Jb[c];
    memcpy(J, y->S0, (size_t)nb * nb * sizeof(double));
    for (int i = 0; c == 0 && s->nf && i < N; i++) {       /* a plate: s_i b_i b_i^T, b_i its trace and -1 on w_i */
        double si = (1 + s->alpha) * s->kp[i];
        int w = 6 + s->nf + i;
        for (int k = s->bc_ptr[i]; k < s->bc_ptr[i + 1]; k++) {
            int r = s->bc_col[k];
            double br = s->bc_val[k];
            for (int l = s->bc_ptr[i]; l < s->bc_ptr[i + 1]; l++)
                J[(size_t)r * nb + s->bc_col[l]] += br * (si * s->bc_val[l]);
            double cross = -(si * br);
            J[(size_t)w * nb + r] += cross;
            J[(size_t)r * nb + w] += cross;
        }
        J[(size_t)w * nb + w] += si;
    }
    for (int i = 0; c == 0 && !s->nf && i < N; i++) {
        double si = (1 + s->alpha) * s->kp[i];
        const double *b = s->Bq3 + 3 * (size_t)i;
        for (int r = 0; r < 3; r++) {
            for (int q = 0; q < 3; q++)
                J[(size_t)(2 + r) * nb + 2 + q] += b[r] * (si * b[q]);
            double cross = -(si * b[r]);
            J[(size_t)(6 + i) * nb + 2 + r] += cross;
            J[(size_t)(2 + r) * nb + 6 + i] += cross;
        }
        J[(size_t)(6 + i) * nb + 6 + i] += si;
    }
    /* scaled by powers of two (exact) to a unit diagonal, d_r ~ |J_rr|^-1/2: the inverse of the
       scaled base is symmetric to round-off of its own size, so its two triangles can be
       averaged and packed (unscaled, the penalty's large entries leave the small ones of the
       inverse with round-off of the large ones') */
    double *d = y->Jd[c];
    for (int r = 0; r < nb; r++) {
        double jr = fabs(J[(size_t)r * nb + r]);
        d[r] = jr > 0.0 && isfinite(jr) ? ldexp(1.0, -ilogb(jr) / 2) : 1.0;
    }
    for (int r = 0; r < nb; r++)
        for (int q = 0; q < nb; q++)
            J[(size_t)r * nb + q] *= d[r] * d[q];
    s->n_factorisations++;
    if (up_lu(J, y->Jpiv[c], nb))
        return -1;
    base_inverse(J, y->Jpiv[c], nb, Ji, s->sym ? y->Jp[c] : NULL);
    memset(y->zdone[c], 0, (size_t)N);                    /* no direction solved yet */
    return 0;
}

/* Z_i = base^-1 b_i for the nodes K[0 .. k) of base c whose direction is not solved yet (b_i =
   Bq3_i on q[2:5] and -1 on w_i): solved from the base's LU (a combination of the inverse's
   columns would lose digits: the penalty couples them strongly), all of them in one solve with
   many right-hand sides. Only the nodes that enter a capacitance matrix need their direction
   (the lifting part of the raft from the closed base): 2 nb^2 flops a node when first needed,
   instead of 2 nb^2 N for every node with the base. The solve treats each right-hand side
   alone, in the same operations whichever others it is solved with (up_lu_solve_many), so a
   direction has the same bits whenever, and with whichever nodes, it is solved: the numbers
   depend on the level and the node only. */
static void directions(UpStepper *s, UpSystem *y, int c, const int *K, int k)
{
    int nb = s->nb, m = 0;
    int *todo = (int *)s->lu_piv;                         /* the set-up's pivots: free here (nb >= k) */
    for (int a = 0; a < k; a++)
        if (!y->zdone[c][K[a]])
            todo[m++] = K[a];
    if (m == 0)
        return;
    double *B = s->rhs, *d = y->Jd[c];                    /* (nb, m): column j is b_todo[j] */
    memset(B, 0, (size_t)nb * m * sizeof(double));
    for (int j = 0; j < m; j++) {
        int i = todo[j];
        if (s->nf) {
            for (int q = s->bc_ptr[i]; q < s->bc_ptr[i + 1]; q++)
                B[(size_t)s->bc_col[q] * m + j] += s->bc_val[q];
            B[(size_t)(6 + s->nf + i) * m + j] = -1.0;
        } else {
            const double *b = s->Bq3 + 3 * (size_t)i;
            for (int r = 0; r < 3; r++)
                B[(size_t)(2 + r) * m + j] = b[r];
            B[(size_t)(6 + i) * m + j] = -1.0;
        }
    }
    for (int r = 0; r < nb; r++)
        for (int j = 0; j < m; j++)
            B[(size_t)r * m + j] *= d[r];
    up_lu_solve_many(y->Jlu[c], y->Jpiv[c], nb, B, m);
    for (int j = 0; j < m; j++) {
        double *z = y->Z[c] + (size_t)todo[j] * nb;
        for (int r = 0; r < nb; r++)
            z[r] = d[r] * B[(size_t)r * m + j];
        y->zdone[c][todo[j]] = 1;
    }
}

/* 1 when base c of the level is usable, built on first use (its numbers are the same whenever
   it is built); 0 when it is singular */
static int base(UpStepper *s, UpSystem *y, int c)
{
    if (y->base_ok[c] == 0) {
        PROF_BEGIN(P_BASE);
        y->base_ok[c] = base_at(s, y, c) == 0 ? 1 : -1;
        PROF_END(P_BASE);
    }
    return y->base_ok[c] > 0;
}

/* the cache slot of (lev, act): its base, nodes K and the LU of C; -1 when singular */
static int capacitance(UpStepper *s, int lev, const unsigned char *act)
{
    int N = s->N, nb = s->nb, slot = 0;
    UpSystem *y = &s->sys[lev];
    s->clock++;
    for (int k = 0; k < UP_NCACHE; k++) {
        if (s->cache_lev[k] == lev && memcmp(s->cache_act + (size_t)k * N, act, (size_t)N) == 0) {
            s->cache_used[k] = s->clock;
            return k;
        }
        if (s->cache_used[k] < s->cache_used[slot])
            slot = k;
    }
    int closed = 0;
    for (int i = 0; i < N; i++)
        closed += act[i] != 0;
    int c = closed < N - closed && base(s, y, 1) ? 1 : 0;     /* the nearer base: all open (1), all closed (0) */
    if (!base(s, y, c))
        return -1;
    int *K = s->cache_nodes + (size_t)slot * N, k = 0;
    for (int i = 0; i < N; i++)
        if ((act[i] != 0) == (c == 1))
            K[k++] = i;
    directions(s, y, c, K, k);
    double sigma = c == 1 ? 1.0 : -1.0, *C = s->cache_lu + (size_t)slot * N * N;
    for (int a = 0; a < k; a++)                           /* W_KK: b_a . Z_b */
        for (int b = 0; b < k; b++)
            C[(size_t)a * k + b] = along(s, K[a], y->Z[c] + (size_t)K[b] * nb)
                                   + (a == b ? sigma / ((1 + s->alpha) * s->kp[K[a]]) : 0.0);
    s->cache_lev[slot] = -1;
    if (k > 0) {
        s->n_factorisations++;
        if (up_lu(C, s->cache_piv + (size_t)slot * N, k))
            return -1;
    }
    s->cache_lev[slot] = lev;
    s->cache_used[slot] = s->clock;
    s->cache_base[slot] = c;
    s->cache_k[slot] = k;
    memcpy(s->cache_act + (size_t)slot * N, act, (size_t)N);
    return slot;
}

/* x <- J(act)^-1 x for a diagonal soil. Row w_i of J reads -s_i a_i Bq3_i . dq[2:5] + (S_i + s_i a_i) dw_i
   = x_{w_i} (S_i the diagonal of S0 there, a_i = act_i, s_i = (1 + al) kp_i), so dw_i eliminates onto q:
     (S0_qq + sum_active s_i S_i / d_i b_i b_i^T) dq = x_q + sum_active s_i / d_i b_i x_{w_i},  d_i = S_i + s_i,
   b_i = Bq3_i on q[2:5]; then dw_i = (x_{w_i} + s_i a_i b_i . dq) / (S_i + s_i a_i). 0, or -1 when singular */
static int newton_diag(UpStepper *s, int lev, const unsigned char *act, double *x)
{
    const double *S = s->sys[lev].S0d, *Sw = S + 36;
    double a[3][3] = {{0.0}}, r[3] = {0.0};              /* the sums on q[2:5] (upper triangle of a) */
    for (int i = 0; i < s->N; i++) {
        if (!act[i])
            continue;
        double si = (1 + s->alpha) * s->kp[i], d = Sw[i] + si, c = si * Sw[i] / d, e = si / d * x[6 + i];
        const double *b = s->Bq3 + 3 * (size_t)i;
        for (int p = 0; p < 3; p++) {
            double cp = c * b[p];
            for (int q = p; q < 3; q++)
                a[p][q] += cp * b[q];
            r[p] += e * b[p];
        }
    }
    double *A = s->lu;                                    /* S0 on q plus the sums on q[2:5] */
    memcpy(A, S, 36 * sizeof(double));
    for (int p = 0; p < 3; p++) {
        for (int q = 0; q < 3; q++)
            A[6 * (2 + p) + 2 + q] += p <= q ? a[p][q] : a[q][p];
        x[2 + p] += r[p];
    }
    s->n_factorisations++;
    if (up_lu(A, s->lu_piv, 6))
        return -1;
    up_lu_solve(A, s->lu_piv, 6, x);
    for (int i = 0; i < s->N; i++) {
        double si = act[i] ? (1 + s->alpha) * s->kp[i] : 0.0, d = Sw[i] + si;
        if (d == 0.0)
            return -1;
        const double *b = s->Bq3 + 3 * (size_t)i;
        x[6 + i] = (x[6 + i] + si * ((b[0] * x[2] + b[1] * x[3]) + b[2] * x[4])) / d;
    }
    return 0;
}

/* x <- J(act)^-1 x at level lev; 0, or -1 when J is singular */
static int newton_solve(UpStepper *s, int lev, const unsigned char *act, double *x)
{
    if (s->diag)
        return newton_diag(s, lev, act, x);
    PROF_BEGIN(P_CAPACITANCE);
    int slot = capacitance(s, lev, act);
    PROF_END(P_CAPACITANCE);
    if (slot < 0)
        return -1;
    const UpSystem *y = &s->sys[lev];
    int N = s->N, nb = s->nb, c = s->cache_base[slot], k = s->cache_k[slot];
    const int *K = s->cache_nodes + (size_t)slot * N;
    double *yb = s->w_nb[7];                              /* free during the Newton iteration */
    const double *d = y->Jd[c];
    for (int r = 0; r < nb; r++)
        x[r] *= d[r];
    up_symv(y->Jb[c], s->sym ? y->Jp[c] : NULL, nb, x, yb);      /* base^-1 = D (D base D)^-1 D */
    for (int r = 0; r < nb; r++)
        x[r] = d[r] * yb[r];
    if (k == 0)
        return 0;
    double *t = s->w_N[3];
    for (int a = 0; a < k; a++)
        t[a] = along(s, K[a], x);
    up_lu_solve(s->cache_lu + (size_t)slot * N * N, s->cache_piv + (size_t)slot * N, k, t);
    for (int a = 0; a < k; a++)
        up_axpy(-t[a], y->Z[c] + (size_t)K[a] * nb, nb, x);
    return 0;
}

/* exact line search on the incremental energy along dx: the step t in (0, 1] where
   dx . g(uB + t dx) = 0, a continuous, piecewise linear, non-decreasing function of t */
static double slope_at(const UpStepper *s, double a, double b, const double *dd, const double *pen, double t)
{
    double sum = 0.0;
    for (int i = 0; i < s->N; i++) {
        double m = pen[i] - t * dd[i];
        sum += (dd[i] * ((1 + s->alpha) * s->kp[i])) * (m > 0.0 ? m : 0.0);
    }
    return a + b * t - sum;
}

static double line_search(UpStepper *s, const double *uB, const double *dx, const double *g0, const double *Sdx)
{
    int N = s->N;
    double *d0 = s->w_N[0], *dd = s->w_N[1], *pen = s->w_N[2], *kinks = s->w_N[3];
    relative(s, uB, d0);
    relative(s, dx, dd);
    double lin = 0.0;
    for (int i = 0; i < N; i++) {
        pen[i] = s->delta0[i] - d0[i];
        lin += dd[i] * (s->kp[i] * (pen[i] > 0.0 ? pen[i] : 0.0));
    }
    double a = up_dot(dx, g0, s->nb) + (1 + s->alpha) * lin;
    double b = up_dot(dx, Sdx, s->nb);
    double f0 = slope_at(s, a, b, dd, pen, 0.0);
    if (slope_at(s, a, b, dd, pen, 1.0) <= 1e-12 * fabs(f0))
        return 1.0;
    int m = 0;
    for (int i = 0; i < N; i++) {
        if (dd[i] == 0.0)
            continue;
        double t = pen[i] / dd[i];
        if (t > 0 && t < 1 && isfinite(t)) {
            int j = m++;                                  /* insertion sort: few kinks */
            while (j > 0 && kinks[j - 1] > t) {
                kinks[j] = kinks[j - 1];
                j--;
            }
            kinks[j] = t;
        }
    }
    double lo = 0.0, flo = f0;
    if (flo >= 0)
        return 1.0;                                       /* not a descent direction: the Newton step */
    for (int k = 0; k <= m; k++) {
        double tk = k < m ? kinks[k] : 1.0, fk = slope_at(s, a, b, dd, pen, tk);
        if (fk >= 0)
            return fk > flo ? lo + (tk - lo) * (-flo) / (fk - flo) : tk;
        lo = tk;
        flo = fk;
    }
    return 1.0;
}

/* ---- one step ------------------------------------------------------------------------------ */
typedef struct {
    int node;
    double residual;
} Failure;

/* C v on u = [structure | x]: Cs on the structure block, E (the soil's C0) on x */
static void damp(const UpStepper *s, const double *v, double *out, double *Ev)
{
    up_sparse_matvec(&s->Cs_sp, v, out);
    for (int i = s->ns; i < s->n; i++)
        out[i] = 0.0;
    const double *vx = v + s->ni;
    if (s->nf) {                                          /* a plate: the soil's part [q, w] of x */
        soil_gather(s, vx, s->vs);
        vx = s->vs;
    }
    const UpSoil *so = s->soil;
    soil_product(s, so->E, so->Ep, s->Ed, so->hm_de_ranks ? so->hm_de_ranks + so->hm_nblk : NULL,
                 so->hm_de_data ? so->hm_de_data + so->hm_de_off : NULL, vx, Ev);    /* E v on x, kept for the soil force */
    for (int i = 0; i < s->nsoil; i++)
        out[s->ni + soil_dof(s, i)] += Ev[i];
}

static int advance(UpStepper *s, int lev, const double *ag_new, const double *h, int *iters, Failure *fail)
{
    const UpSystem *y = system_at(s, lev);
    int n = s->n, ns = s->ns, ni = s->ni, nb = s->nb, N = s->N;
    if (!y) {
        fail->node = -1;
        fail->residual = INFINITY;
        return -1;
    }
    double dt = y->dt, c0 = y->c0, c1 = y->c1, c2 = y->c2, c3 = y->c3;
    double al = s->alpha, b = s->beta, g = s->gamma;
    double *F_new = s->w_n[1], *a_hat = s->w_n[2], *v_hat = s->w_n[3], *rhs = s->w_n[4], *Cv = s->w_n[5];
    double *u_new = s->w_n[6], *v_new = s->w_n[7];
    const double *u = s->u, *v = s->v, *a = s->a;
    load(s, ag_new, F_new);
    for (int i = 0; i < n; i++) {
        a_hat[i] = (-c0 * u[i] - c2 * v[i]) - c3 * a[i];
        v_hat[i] = (-c1 * u[i] + (1 - g / b) * v[i]) + dt * (1 - g / (2 * b)) * a[i];
    }
    double *Ev = s->w_nb[10], *Sx = s->w_nb[11], *Sdx = s->w_nb[8];
    PROF_BEGIN(P_S0);
    damp(s, v_hat, Cv, Ev);
    PROF_END(P_S0);
    for (int i = 0; i < n; i++)
        rhs[i] = (((-s->M[i] * a_hat[i] - (1 + al) * Cv[i]) + al * s->R[i]) + (1 + al) * F_new[i]) - al * s->F[i];
    for (int i = 0; i < s->nsoil; i++)                   /* h on the soil's DOFs [q, w] */
        rhs[ni + soil_dof(s, i)] -= (1 + al) * h[i];
    /* condensation: y = A_II^-1 rhs_I, r_hat = rhs_B - A_BI y */
    double *yI = u_new, *r_hat = s->w_nb[0], *uB = s->w_nb[1], *gv = s->w_nb[2], *dx = s->w_nb[3];
    double *xn = s->w_nb[4], *gn = s->w_nb[5];
    if (y->banded) {                                     /* a plate, A_II banded: A_BI sparse */
        const UpSparse *P = &s->bi_pat;
        memcpy(yI, rhs, (size_t)ni * sizeof(double));
        band_solve(s, y, yI);
        for (int i = 0; i < nb; i++) {
            double t = 0.0;
            for (int q = P->ptr[i]; q < P->ptr[i + 1]; q++)
                t += y->bi_val[q] * yI[P->col[q]];
            r_hat[i] = rhs[ni + i] - t;
        }
    } else {
        if (ni > 0)
            up_symv(y->AII, s->sym ? y->AIIp : NULL, ni, rhs, yI);
        up_matvec(y->ABI, y->abi_rows, ni, yI, r_hat);
        for (int i = 0; i < nb; i++)
            r_hat[i] = rhs[ni + i] - (i < y->abi_rows ? r_hat[i] : 0.0);
    }
    *iters = 0;
    if (!s->enabled) {
        /* bonded: the contact is linear, x = J(all closed)^-1 r_hat */
        memset(s->act, 1, (size_t)N);
        memcpy(uB, r_hat, (size_t)nb * sizeof(double));
        if (newton_solve(s, lev, s->act, uB)) {
            fail->node = -1;
            fail->residual = INFINITY;
            return -1;
        }
    } else {
        memcpy(uB, u + ni, (size_t)nb * sizeof(double));
        double scale = up_norm(r_hat, nb), p0 = (1 + al) * up_norm(s->P0, N);
        scale = scale > p0 ? scale : p0;
        scale = scale > 1.0 ? scale : 1.0;
        double tol = s->tol * scale;
        /* S0 x = (1 + al) K0C x + c0 M_B x + Sq x[0:6], K0C x from the step that left x (the
           soil force's product) when it was at this level, else computed here (in fs_new's
           work, free until the iteration ends: the state is written only by a step that succeeds) */
        if (s->nf) {
            /* a plate: S0 x = (1 + al) K0C x on the soil's DOFs + c0 M_B x + Sqt x on [q, t] */
            const double *Kx = s->Kx, *cM = y->Sq + 36;
            if (*s->kx_lev != (double)lev) {
                soil_gather(s, uB, s->xs);
                soil_product(s, y->K0C, s->soil->Ep ? y->K0Cp : NULL, y->K0Cd, y->hk_rank, y->hk_data, s->xs, s->w_nb[6]);
                Kx = s->w_nb[6];
            }
            int nq = 6 + s->nf;
            double *St = s->w_nb[3];                      /* dx, free until the iteration */
            up_symv(y->Sqt, s->sym ? y->Sqtp : NULL, nq, uB, St);
            for (int i = 0; i < nb; i++)
                Sx[i] = (i < nq ? St[i] : 0.0) + cM[i] * uB[i];
            for (int i = 0; i < s->nsoil; i++)
                Sx[soil_dof(s, i)] += (1 + al) * Kx[i];
        } else {
            const double *Kx = s->Kx;
            if (*s->kx_lev != (double)lev) {
                PROF_BEGIN(P_S0);
                soil_product(s, y->K0C, s->soil->Ep ? y->K0Cp : NULL, y->K0Cd, y->hk_rank, y->hk_data, uB, s->w_nb[6]);
                PROF_END(P_S0);
                Kx = s->w_nb[6];
            }
            const double *Sq = y->Sq, *cM = y->Sq + 36;
            for (int i = 0; i < nb; i++)
                Sx[i] = (1 + al) * Kx[i] + cM[i] * uB[i];
            for (int i = 0; i < 6; i++)
                Sx[i] += up_dot(Sq + 6 * i, uB, 6);
        }
        residual(s, Sx, uB, r_hat, gv, s->act);
        int conv = 0;
        for (int it = 0; it < s->max_iter; it++) {
            for (int i = 0; i < nb; i++)
                dx[i] = gv[i];
            PROF_BEGIN(P_SOLVE);
            int singular = newton_solve(s, lev, s->act, dx);
            PROF_END(P_SOLVE);
            if (singular)
                break;
            for (int i = 0; i < nb; i++)
                dx[i] = -dx[i];
            ++*iters;
            /* S0 dx = J dx - sum_active s_i b_i (b_i . dx), J dx = -g: no product with S0 */
            for (int i = 0; i < nb; i++)
                Sdx[i] = -gv[i];
            for (int i = 0; s->nf && i < N; i++)         /* a plate: b_i its trace on [q, t], -1 on w_i */
                if (s->act[i]) {
                    double c = ((1 + al) * s->kp[i]) * along(s, i, dx);
                    for (int k = s->bc_ptr[i]; k < s->bc_ptr[i + 1]; k++)
                        Sdx[s->bc_col[k]] -= c * s->bc_val[k];
                    Sdx[6 + s->nf + i] += c;
                }
            double S2 = Sdx[2], S3 = Sdx[3], S4 = Sdx[4];   /* summed in registers */
            for (int i = 0; !s->nf && i < N; i++)
                if (s->act[i]) {
                    double c = ((1 + al) * s->kp[i]) * along(s, i, dx);
                    const double *b = s->Bq3 + 3 * (size_t)i;
                    S2 -= c * b[0];
                    S3 -= c * b[1];
                    S4 -= c * b[2];
                    Sdx[6 + i] += c;
                }
            Sdx[2] = S2;
            Sdx[3] = S3;
            Sdx[4] = S4;
            double t = line_search(s, uB, dx, gv, Sdx);
            for (int i = 0; i < nb; i++) {
                xn[i] = uB[i] + t * dx[i];
                Sx[i] += t * Sdx[i];
            }
            residual(s, Sx, xn, r_hat, gn, s->act_new);
            int same = memcmp(s->act, s->act_new, (size_t)N) == 0;
            memcpy(uB, xn, (size_t)nb * sizeof(double));
            memcpy(gv, gn, (size_t)nb * sizeof(double));
            memcpy(s->act, s->act_new, (size_t)N);
            if ((t == 1.0 && same) || up_norm(gv, nb) <= tol) {
                conv = 1;
                break;
            }
        }
        if (!conv || !finite_all(uB, (size_t)nb)) {
            int node = -1, finite = 1;
            double best = -1.0;
            const double *gw = gv + 6 + s->nf;           /* the residual on w */
            for (int i = 0; i < N; i++) {
                double r = fabs(gw[i]);
                if (!isfinite(r))
                    finite = 0;
                else if (r > best)
                    best = r;
            }
            for (int i = 0; i < N && node < 0; i++)      /* the first within round-off of the largest (ties) */
                if (fabs(gw[i]) >= best * (1 - 1e-9))
                    node = i;
            fail->node = finite ? (N ? node : 0) : -1;
            fail->residual = up_norm(gv, nb);
            return -1;
        }
    }
    /* u_new = [y - X uB, uB]; a banded plate: [A_II^-1 (rhs_I - A_IB uB), uB] */
    if (y->banded) {
        const UpSparse *Q = &s->ib_pat;
        for (int i = 0; i < ni; i++) {
            double t = 0.0;
            for (int q = Q->ptr[i]; q < Q->ptr[i + 1]; q++)
                t += y->ib_val[q] * uB[Q->col[q]];
            u_new[i] = rhs[i] - t;
        }
        band_solve(s, y, u_new);
    } else {
        double *XuB = s->w_n[8];
        up_matvec_ld(y->X, ni, y->x_cols, nb, uB, XuB);
        for (int i = 0; i < ni; i++)
            u_new[i] = yI[i] - XuB[i];
    }
    memcpy(u_new + ni, uB, (size_t)nb * sizeof(double));
    if (!finite_all(u_new, (size_t)n)) {
        fail->node = -1;
        fail->residual = INFINITY;
        return -1;
    }
    double *a_new = rhs, *R_new = Cv, *fs_new = s->w_nb[6], *fc_new = s->w_nb[7], *P_new = s->w_N[4];
    for (int i = 0; i < n; i++) {
        v_new[i] = c1 * u_new[i] + v_hat[i];
        a_new[i] = c0 * u_new[i] + a_hat[i];
    }
    contact(s, u_new + ni, P_new, s->act_new, fc_new);
    const double *x_new = u_new + ni, *xd_new = v_new + ni;
    /* the soil force K0 x + C0 xdot + h = (D0 + c1 E) x + E v_hat + h (xdot = c1 x + v_hat) */
    double *Kx_new = s->w_nb[3];                          /* dx, free after the Newton iteration */
    const double *xs_new = x_new, *xds_new = xd_new;      /* the soil's part [q, w] */
    if (s->nf) {
        soil_gather(s, x_new, s->xs);
        soil_gather(s, xd_new, s->vs);
        xs_new = s->xs;
        xds_new = s->vs;
    }
    PROF_BEGIN(P_S0);
    if (s->lean && s->enabled && !s->nf && ++s->lean_steps % UP_LEAN_ANCHOR != 0) {
        /* a march (UpStepper.lean): K0C x from the Newton iteration's S0 x at x (Sx = (1 + al) K0C x +
           c0 M_B x + Sq x[0:6], kept up to date by its steps), no product; the next step's S0 x starts
           from it, so the iterations' round-off is carried from step to step, up to the next product
           (every UP_LEAN_ANCHOR-th step) */
        const double *Sq = y->Sq, *cM = y->Sq + 36;
        for (int i = 0; i < nb; i++) {
            double t = Sx[i];
            if (i < 6)
                t -= up_dot(Sq + 6 * i, x_new, 6);
            Kx_new[i] = (t - cM[i] * x_new[i]) / (1 + al);
        }
    } else {
        soil_product(s, y->K0C, s->soil->Ep ? y->K0Cp : NULL, y->K0Cd, y->hk_rank, y->hk_data, xs_new, Kx_new);
    }
    PROF_END(P_S0);
    for (int i = 0; i < s->nsoil; i++)
        fs_new[i] = (Kx_new[i] + Ev[i]) + h[i];
    if (al != 0.0) {
        /* R = Ks u + Cs v, plus fs + fc on x: the internal force the HHT average needs */
        double *Cv_new = s->w_n[9];
        up_sparse_matvec(&s->Ks_sp, u_new, R_new);
        up_sparse_matvec(&s->Cs_sp, v_new, Cv_new);
        for (int i = 0; i < ns; i++)
            R_new[i] += Cv_new[i];
        for (int i = ns; i < n; i++)
            R_new[i] = 0.0;
        if (s->nf) {
            for (int i = 0; i < nb; i++)
                R_new[ni + i] += fc_new[i];
            for (int i = 0; i < s->nsoil; i++)
                R_new[ni + soil_dof(s, i)] += fs_new[i];
        } else {
            for (int i = 0; i < nb; i++)
                R_new[ni + i] += fs_new[i] + fc_new[i];
        }
    } else {
        memset(R_new, 0, (size_t)n * sizeof(double));           /* not used by the average acceleration rule */
    }
    /* works: sums of du . (f_n + f_{n+1}) / 2 (not in a march: UpStepper.lean) */
    if (!s->lean) {
        double w_in = 0.0, w_damp = 0.0, w_soil = 0.0, w_contact = 0.0;
        double *vm = s->w_n[0];
        for (int i = 0; i < ns; i++)
            vm[i] = 0.5 * (v[i] + v_new[i]);
        for (int i = 0; i < n; i++)
            w_in += (u_new[i] - u[i]) * (0.5 * (s->F[i] + F_new[i]));
        double *Cvm = s->w_n[8];
        up_sparse_matvec(&s->Cs_sp, vm, Cvm);
        for (int i = 0; i < ns; i++)
            w_damp += (u_new[i] - u[i]) * Cvm[i];
        if (s->nf) {
            for (int i = 0; i < s->nsoil; i++) {
                int k = ni + soil_dof(s, i);
                w_soil += (u_new[k] - u[k]) * (0.5 * (s->fs[i] + fs_new[i]));
            }
            for (int i = 0; i < nb; i++)
                w_contact += (u_new[ni + i] - u[ni + i]) * (0.5 * (s->fc[i] + fc_new[i]));
        } else {
            for (int i = 0; i < nb; i++) {
                double du = u_new[ni + i] - u[ni + i];
                w_soil += du * (0.5 * (s->fs[i] + fs_new[i]));
                w_contact += du * (0.5 * (s->fc[i] + fc_new[i]));
            }
        }
        s->work[W_INPUT] += w_in;
        s->work[W_DAMPING] += w_damp;
        s->work[W_SOIL] += w_soil;
        s->work[W_CONTACT] += w_contact;
    }
    memcpy(s->u, u_new, (size_t)n * sizeof(double));
    memcpy(s->v, v_new, (size_t)n * sizeof(double));
    memcpy(s->a, a_new, (size_t)n * sizeof(double));
    memcpy(s->P, P_new, (size_t)N * sizeof(double));
    memcpy(s->fs, fs_new, (size_t)s->nsoil * sizeof(double));
    memcpy(s->fc, fc_new, (size_t)nb * sizeof(double));
    memcpy(s->Kx, Kx_new, (size_t)s->nsoil * sizeof(double));
    *s->kx_lev = lev;
    memcpy(s->R, R_new, (size_t)n * sizeof(double));
    memcpy(s->F, F_new, (size_t)n * sizeof(double));
    *s->t += dt;
    memcpy(s->ag, ag_new, 3 * sizeof(double));
    if (!s->external) {
        PROF_BEGIN(P_HISTORY);
        up_soil_commit(s->soil, lev, xs_new, xds_new, fs_new);
        PROF_END(P_HISTORY);
    }
    return 0;
}

/* one (sub)step of size dt / 2**depth, halved on a Newton failure. advance writes the state
   only when it succeeds, so the state is copied (to depth's slot of saves) only before a halving,
   and a span that fails leaves the state as it found it. */
static int span(UpStepper *s, int depth, const double *ag0, const double *ag1, const double *h_in, int *iters)
{
    const double *h = h_in;
    if (!s->external) {
        double *hd = s->hbuf + (size_t)depth * s->nb;
        system_at(s, depth);                              /* the soil's coefficients at this dt */
        PROF_BEGIN(P_HISTORY);
        up_soil_history(s->soil, depth, hd);
        PROF_END(P_HISTORY);
        h = hd;
    }
    int it = 0;
    Failure fail = {-1, INFINITY};
    if (advance(s, depth, ag1, h, &it, &fail) == 0) {
        *iters += it;
        return 0;
    }
    double dt = s->sys[depth].ready ? s->sys[depth].dt : s->sys[0].dt;
    if (depth >= s->max_subdiv) {
        snprintf(s->err, UP_MSG, "Newton contact iteration failed at t = %.6g s (step %.3g s after %d halvings), "
                 "interface node %d, residual %.3e N; raise contact.max_subdiv, reduce dt, or check the penalty",
                 *s->t + dt, dt, depth, fail.node, fail.residual);
        return -1;
    }
    s->last_halved = 1;
    double *saved = s->saves + (size_t)depth * s->block_len;
    memcpy(saved, s->block, s->block_len * sizeof(double));
    double agm[3];
    for (int k = 0; k < 3; k++)
        agm[k] = 0.5 * (ag0[k] + ag1[k]);
    if (span(s, depth + 1, ag0, agm, h_in, iters) == 0 && span(s, depth + 1, agm, ag1, h_in, iters) == 0)
        return 0;
    memcpy(s->block, saved, s->block_len * sizeof(double));
    return -1;
}

int up_stepper_prepare(UpStepper *s, char *err)
{
    if (system_at(s, 0))
        return 0;
    snprintf(err, UP_MSG, "the structure's interior effective matrix is singular at dt = %g s: a DOF of the "
             "structure has neither mass nor stiffness (check the model)", s->sys[0].dt);
    return -1;
}

int up_stepper_step(UpStepper *s)
{
    double ag0[3], ag1[3];
    memcpy(ag0, s->ag, sizeof ag0);
    memcpy(ag1, s->ag_next, sizeof ag1);
    int iters = 0;
    s->last_iters = 0;
    s->last_halved = 0;
    PROF_BEGIN(P_STEP);
    int failed = span(s, 0, ag0, ag1, s->external ? s->h_ext : NULL, &iters);
    PROF_END(P_STEP);
    if (failed)
        return -1;                                        /* the state as it was */
    s->last_iters = iters;
    return 0;
}

/* ---- outputs ------------------------------------------------------------------------------- */
void up_stepper_gap(const UpStepper *s, double *gap)
{
    relative(s, s->u + s->ni, gap);
    for (int i = 0; i < s->N; i++) {
        double g = gap[i] - s->delta0[i];
        gap[i] = s->enabled && g > 0.0 ? g : 0.0;
    }
}

void up_stepper_energies(const UpStepper *s, double *e)
{
    int n = s->n, ns = s->ns, N = s->N;
    double kin = 0.0, strain = 0.0, pot = 0.0;
    for (int i = 0; i < n; i++)
        kin += s->v[i] * (s->M[i] * s->v[i]);
    double *Ku = s->w_n[9];
    up_sparse_matvec(&s->Ks_sp, s->u, Ku);
    for (int i = 0; i < ns; i++)
        strain += s->u[i] * Ku[i];
    double *d = s->w_N[5];
    relative(s, s->u + s->ni, d);
    for (int i = 0; i < N; i++) {
        if (s->enabled) {
            double pen = s->delta0[i] - d[i], pen0 = s->delta0[i];
            pen = pen > 0.0 ? pen : 0.0;
            pen0 = pen0 > 0.0 ? pen0 : 0.0;
            pot += 0.5 * s->kp[i] * (pen * pen - pen0 * pen0) + s->P0[i] * d[i];
        } else {
            pot += 0.5 * s->kp[i] * d[i] * d[i];
        }
    }
    e[UP_E_INPUT] = s->work[W_INPUT];
    e[UP_E_KINETIC] = 0.5 * kin;
    e[UP_E_STRAIN] = 0.5 * strain;
    e[UP_E_DAMPING] = s->work[W_DAMPING];
    e[UP_E_SOIL] = s->work[W_SOIL];
    e[UP_E_CONTACT] = s->work[W_CONTACT];
    e[UP_E_CONTACT_POTENTIAL] = pot;
}

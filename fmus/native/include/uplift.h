/* The native uplift FMU runtime: declarations shared by its C files.

   One runtime serves the three FMUs (soil, structure, coupled); the role, the model data and
   the layout of the variables come from resources/uplift.bin, written by fmus/native_build.py
   (format: fmus/native/README.md). C standard library only (libc, libm); one instance
   allocates all its memory in fmi2Instantiate, fmi2DoStep allocates nothing.

   Numerics (the same discrete equations as the Python FMUs, so the results agree to
   round-off):
     soil.c     the trapezoidal recursive convolution of the rational soil model
                (soil_impedance/convolution.py, RecursiveConvolutionSoil)
     stepper.c  Newmark / HHT-alpha with interior DOFs condensed, penalty contact, semi-smooth
                Newton with an exact line search and recursive step halving
                (structure/newmark.py, NewmarkStepper)
     linalg.c   dense LU with partial pivoting, matrix-vector products
     resources.c the binary resource file
     instance.c, model.c, variables.c, state.c   the FMI side both versions share (include/fmu.h)
     fmi2.c, fmi3.c                              the FMI 2.0 and FMI 3.0 entry points

   Units: SI throughout (m, rad, s, N, J). Matrices are dense, row-major. */
#ifndef UPLIFT_H
#define UPLIFT_H

#include <stddef.h>
#include <stdint.h>

#include "uplift_schema.h"   /* the roles, energy terms, slots and row layout of fmus/schema.py */

/* Symbols. Everything the runtime's files share is named up_*; entry points are the FMI 2.0
   (fmi2.c) or the FMI 3.0 (fmi3.c) functions. A tool that compiles several FMUs' sources into
   one binary defines FMI2_FUNCTION_PREFIX or FMI3_FUNCTION_PREFIX (as the FMI headers ask of
   source-code FMUs, e.g. UpliftSoil_): the FMI functions and every up_* symbol then carry that
   prefix, so that two runtimes linked together do not collide. */
#if defined(FMI2_FUNCTION_PREFIX)
#define UP_PREFIX FMI2_FUNCTION_PREFIX
#elif defined(FMI3_FUNCTION_PREFIX)
#define UP_PREFIX FMI3_FUNCTION_PREFIX
#endif
#define UP_PASTE_(a, b) a##b
#define UP_PASTE(a, b) UP_PASTE_(a, b)
#ifdef UP_PREFIX
#define UP_SYM(name) UP_PASTE(UP_PREFIX, name)
#define up_check_refs UP_SYM(up_check_refs)
#define up_dot UP_SYM(up_dot)
#define up_element_name UP_SYM(up_element_name)
#define up_boolean_refs UP_SYM(up_boolean_refs)
#define up_do_step UP_SYM(up_do_step)
#define up_enter_initialisation UP_SYM(up_enter_initialisation)
#define up_exit_initialisation UP_SYM(up_exit_initialisation)
#define up_free_instance UP_SYM(up_free_instance)
#define up_get_reals UP_SYM(up_get_reals)
#define up_guard UP_SYM(up_guard)
#define up_hm_matvec UP_SYM(up_hm_matvec)
#define up_initial_state UP_SYM(up_initial_state)
#define up_instance UP_SYM(up_instance)
#define up_instantiate UP_SYM(up_instantiate)
#define up_log_error UP_SYM(up_log_error)
#define up_log_event UP_SYM(up_log_event)
#define up_lu UP_SYM(up_lu)
#define up_lu_solve UP_SYM(up_lu_solve)
#define up_inverse UP_SYM(up_inverse)
#define up_lu_solve_many UP_SYM(up_lu_solve_many)
#define up_vector_level UP_SYM(up_vector_level)
#define up_matvec UP_SYM(up_matvec)
#define up_gemv_t UP_SYM(up_gemv_t)
#define up_spmv_add UP_SYM(up_spmv_add)
#define up_pack_sym UP_SYM(up_pack_sym)
#define up_symv UP_SYM(up_symv)
#define up_symmetrise_pack UP_SYM(up_symmetrise_pack)
#define up_matvec_add UP_SYM(up_matvec_add)
#define up_matvec_ld UP_SYM(up_matvec_ld)
#define up_sparse_init UP_SYM(up_sparse_init)
#define up_sparse_free UP_SYM(up_sparse_free)
#define up_sparse_matvec UP_SYM(up_sparse_matvec)
#define up_axpy UP_SYM(up_axpy)
#define up_norm UP_SYM(up_norm)
#define up_no_variables UP_SYM(up_no_variables)
#define up_num UP_SYM(up_num)
#define up_res_f64 UP_SYM(up_res_f64)
#define up_res_find UP_SYM(up_res_find)
#define up_res_free UP_SYM(up_res_free)
#define up_res_i64 UP_SYM(up_res_i64)
#define up_res_load UP_SYM(up_res_load)
#define up_res_parse UP_SYM(up_res_parse)
#define up_res_scalar UP_SYM(up_res_scalar)
#define up_reset UP_SYM(up_reset)
#define up_set_logging UP_SYM(up_set_logging)
#define up_set_reals UP_SYM(up_set_reals)
#define up_setup_experiment UP_SYM(up_setup_experiment)
#define up_sim_close UP_SYM(up_sim_close)
#define up_sim_open UP_SYM(up_sim_open)
#define up_sim_steps UP_SYM(up_sim_steps)
#define up_sim_width UP_SYM(up_sim_width)
#define up_simulate UP_SYM(up_simulate)
#define up_slot_names UP_SYM(up_slot_names)
#define up_soil_ahead UP_SYM(up_soil_ahead)
#define up_soil_bind UP_SYM(up_soil_bind)
#define up_soil_commit UP_SYM(up_soil_commit)
#define up_soil_corr_broken UP_SYM(up_soil_corr_broken)
#define up_soil_corr_mode UP_SYM(up_soil_corr_mode)
#define up_soil_corr_sample UP_SYM(up_soil_corr_sample)
#define up_soil_force UP_SYM(up_soil_force)
#define up_soil_free UP_SYM(up_soil_free)
#define up_soil_history UP_SYM(up_soil_history)
#define up_soil_init UP_SYM(up_soil_init)
#define up_soil_level UP_SYM(up_soil_level)
#define up_soil_read UP_SYM(up_soil_read)
#define up_soil_rest UP_SYM(up_soil_rest)
#define up_soil_state_len UP_SYM(up_soil_state_len)
#define up_soil_outputs UP_SYM(up_soil_outputs)
#define up_soil_step UP_SYM(up_soil_step)
#define up_state_deserialize UP_SYM(up_state_deserialize)
#define up_state_free UP_SYM(up_state_free)
#define up_state_get UP_SYM(up_state_get)
#define up_state_serialize UP_SYM(up_state_serialize)
#define up_state_set UP_SYM(up_state_set)
#define up_state_size UP_SYM(up_state_size)
#define up_step UP_SYM(up_step)
#define up_stepper_bind UP_SYM(up_stepper_bind)
#define up_stepper_energies UP_SYM(up_stepper_energies)
#define up_stepper_free UP_SYM(up_stepper_free)
#define up_stepper_gap UP_SYM(up_stepper_gap)
#define up_stepper_init UP_SYM(up_stepper_init)
#define up_stepper_prepare UP_SYM(up_stepper_prepare)
#define up_stepper_rest UP_SYM(up_stepper_rest)
#define up_stepper_state_len UP_SYM(up_stepper_state_len)
#define up_stepper_step UP_SYM(up_stepper_step)
#define up_var UP_SYM(up_var)
#endif


/* what a library built for an in-process host exports (simulate.c); the FMUs export the FMI
   functions only */
#if defined(_WIN32)
#define UP_API __declspec(dllexport)
#else
#define UP_API __attribute__((visibility("default")))
#endif

#define UP_MSG 1024           /* length of an error message buffer */
#define UP_MAXLEV 31          /* step-halving levels: dt / 2**k, k = 0 .. max_subdiv <= 30 */
#define UP_NCACHE 16          /* Newton matrices kept (per level and active set) */
#define UP_LEAN_ANCHOR 8      /* a lean run's K0C x by its product at every 8th step: the Newton iterations'
                                 round-off carried between them (stepper.c, advance) */

/* ---- resources.c: the binary resource file ------------------------------------------------ */
enum { UP_F64 = 1, UP_I64 = 2, UP_TEXT = 3 };

typedef struct {
    char name[33];
    int kind, ndim;
    int64_t dims[4];
    uint64_t nbytes;
    const void *data;
} UpRecord;

typedef struct {
    unsigned char *buf;
    int count;
    UpRecord *rec;
    char path[512];
} UpRes;

int up_res_load(UpRes *r, const char *path, char *err);
/* the same from size bytes in memory (copied); name stands for the path in messages */
int up_res_parse(UpRes *r, const unsigned char *data, size_t size, const char *name, char *err);
void up_res_free(UpRes *r);
const UpRecord *up_res_find(const UpRes *r, const char *name);
/* the float64 (int64) record ``name`` with ndim dimensions; dims[k] >= 0 are checked, -1 any
   (the record's are written back); NULL and a message naming the record when absent or wrong */
const double *up_res_f64(const UpRes *r, const char *name, int ndim, int64_t *dims, char *err);
const int64_t *up_res_i64(const UpRes *r, const char *name, int ndim, int64_t *dims, char *err);
int up_res_scalar(const UpRes *r, const char *name, double *value, char *err);

/* a sparse matrix, compressed rows (the structure's stiffness and damping: mostly zeros) */
typedef struct {
    int rows;
    int *ptr, *col;
    double *val;
} UpSparse;

/* ---- linalg.c --------------------------------------------------------------------------------- */
int up_lu(double *A, int *piv, int n);                  /* in place; 0, or k + 1 on a zero pivot */
void up_lu_solve(const double *LU, const int *piv, int n, double *b);   /* b <- A^-1 b */
void up_lu_solve_many(const double *LU, const int *piv, int n, double *B, int k);  /* B (n, k) <- A^-1 B */
/* inv <- A^-1 from its LU; with P, inv symmetrised and packed into P */
void up_inverse(const double *LU, const int *piv, int n, double *inv, double *P);
void up_matvec(const double *A, int rows, int cols, const double *x, double *y);        /* y = A x */
void up_matvec_ld(const double *A, int rows, int cols, int lda, const double *x, double *y);  /* rows of stride lda */
int up_sparse_init(UpSparse *S, const double *A, int rows, int cols);   /* from dense A; -1 out of memory */
void up_sparse_free(UpSparse *S);
void up_sparse_matvec(const UpSparse *S, const double *x, double *y);   /* y = S x */
/* y = At^T x for At (rows, cols): y (cols) accumulates x_j times row j of At, in the order of j */
void up_gemv_t(const double *At, int rows, int cols, const double *x, double *y);
/* y += P x for a symmetric (n, n) P packed by rows of its upper triangle (n (n + 1) / 2 values) */
void up_spmv_add(const double *P, int n, const double *x, double *y);
int up_pack_sym(const double *A, int n, double *P);       /* P <- A packed; 1 when A is symmetric */
void up_symmetrise_pack(double *A, int n, double *P);    /* A <- (A + A^T) / 2, then packed into P */
void up_symv(const double *A, const double *P, int n, const double *x, double *y);  /* y = A x, P if not NULL */
void up_axpy(double a, const double *x, int n, double *y);                      /* y += a x */
void up_matvec_add(const double *A, int rows, int cols, const double *x, double s, double *y); /* y += s A x */
double up_dot(const double *a, const double *b, int n);
int up_vector_level(void);        /* the kernels' width on this CPU: 2 AVX-512, 1 AVX2, 0 the baseline */
double up_norm(const double *a, int n);

/* ---- soil.c: recursive convolution --------------------------------------------------------- */
typedef struct {
    int ready;
    double dt;
    double *ar, *br;          /* (mr) real-pole coefficients */
    double *ac, *bc;          /* (mc) complex, as (re, im) pairs */
    double *D0;               /* (n, n) D + sum b_k R_k, symmetrised */
    double *D0p;              /* D0 packed (up_pack_sym) */
} UpSoilLevel;

typedef struct {
    int n, mr, mc;
    size_t L;                 /* (mr + 2 mc) n: length of the stacked pole states */
    const double *pr, *pc;    /* (mr), (mc, 2) poles: real, and one (re, im) per conjugate pair */
    const double *Rr, *Rc;    /* (mr, n, n), (mc, n, n, 2) residues */
    const double *D, *E;      /* (n, n) */
    double *Ep;               /* E packed when it is symmetric (as a fit makes it), else NULL */
    double *H;                /* (L, n): H transposed (pole-major), h = H g; NULL when the soil is not stepped */
    double *Hs;               /* the same when every residue is symmetric (reciprocity): the L / n blocks
                                 of H (R_k; 2 Re R_k, -2 Im R_k) packed (up_spmv_add); H is then NULL */
    double *g, *fbuf;         /* (L), (5 n) work */
    double *part;             /* (L) work: the packed history product's parts, block by block */
    int flip;                 /* the order the blocks were read in last (no effect on the product) */
    double *Gx, *Gxp;         /* (n, n) history gain at level 0 and packed (NULL if not symmetric): a soil
                                 stepped alone (up_soil_init's stepped = 2) only */
    /* the compressed history (soil_impedance/hhistory.py; records hm_*), when the resource file has
       it: H's blocks as hierarchical matrices over one partition, in the permuted order hm_perm (n);
       hm_blocks (hm_nblk, 4): row start, rows, column start, columns of the upper blocks (off the
       diagonal: used for their mirror too); hm_ranks (L / n, hm_nblk): -1 dense, else the rank r of
       U (r, rows), V (r, columns), the block U^T V; hm_data the values in that order. H and Hs are
       then NULL */
    const int64_t *hm_perm, *hm_blocks, *hm_ranks;
    const double *hm_data;
    int hm_nblk;
    double *hm_x, *hm_y, *hm_t; /* (n) work: the permuted input, the permuted product, U x or V x */
    /* the model's D and E over the same partition (records hm_de_*), when compressed with the history:
       hm_de_ranks (2, hm_nblk) as hm_ranks, hm_de_data D's values then E's (from hm_de_data + hm_de_off);
       the stepper's products with E and D0 + c1 E then run over the blocks (up_hm_matvec). NULL: dense */
    const int64_t *hm_de_ranks;
    const double *hm_de_data;
    size_t hm_de_off;
    UpSoilLevel lev[UP_MAXLEV];
    /* state, inside the instance's state block. f: the force committed last, work: the work done on
       the soil (a soil stepped alone: f unused, work that of the force's part E u' + h; gq, gp the
       histories published (real poles with packed blocks: gq the history of the next commit, soil.c
       real_packed), ev = E u', hn = h of the commit, stale = 1 when its outputs are not computed yet:
       up_soil_outputs) */
    double *yr, *yc, *u, *ud, *f, *work, *gq, *gp, *ev, *hn, *stale;
    /* the correction form of a sequence of marches (up_soil_corr_mode; NULL until asked for) */
    struct UpSoilCorr *corr;
} UpSoil;

/* stepped: 0 the history is given (a structure FMU), 1 stepped by the stepper, 2 stepped alone (a soil
   FMU: up_soil_step) */
int up_soil_init(UpSoil *s, const UpRes *r, int n, int nlev, int stepped, char *err);
void up_soil_free(UpSoil *s);
size_t up_soil_state_len(const UpSoil *s);
void up_soil_bind(UpSoil *s, double *state);             /* state pointers into a block */
void up_soil_rest(UpSoil *s);
const UpSoilLevel *up_soil_level(UpSoil *s, int lev, double dt);
void up_soil_history(UpSoil *s, int lev, double *h);     /* h_n (n) */
void up_soil_force(UpSoil *s, int lev, const double *x, const double *xd, const double *h, double *f);
void up_soil_commit(UpSoil *s, int lev, const double *x, const double *xd, const double *f);
void up_soil_ahead(UpSoil *s, int lev, double *g);       /* history of the step after next, zero state next */
void up_soil_step(UpSoil *s, int lev, const double *x, const double *xd, double *g);  /* commit x, then g */
/* y = A x (n) for a symmetric A held over the compressed history's partition: ranks (hm_nblk) and data laid
   out as one history block of hm_data (a dense block row-major, a low-rank one U then V) */
void up_hm_matvec(UpSoil *s, const int64_t *ranks, const double *data, const double *x, double *y);
/* a soil stepped alone: its force f (n) and the work done on it, of the state committed last */
void up_soil_outputs(UpSoil *s, int lev, double *f, double *work);
/* the correction form of repeated runs from rest (the time-frequency route's marches): mode 0 off,
   1 the run's history and states recorded per sample, 2 the history as the last recorded run's plus
   the change from it in single precision (recorded in turn), 3 as 2 from a run at rest (returns 2);
   nt samples; returns the mode set, or -1
   (a history that is not packed symmetric, no record of nt samples for mode 2, out of memory) */
int up_soil_corr_mode(UpSoil *s, int64_t nt, int mode);
void up_soil_corr_sample(UpSoil *s, int64_t k);          /* the sample the next step computes */
int up_soil_corr_broken(const UpSoil *s);                /* 1: a step of this run was halved */

/* ---- stepper.c: Newmark-contact stepper ---------------------------------------------------- */
typedef struct {
    int ready;
    double dt, c0, c1, c2, c3;
    double *AII;              /* (ni, ni) A_II^-1 (from its LU: up_inverse) */
    double *AIIp;             /* the same packed, when the system is symmetric (UpStepper.sym) */
    double *ABI;              /* (nb, ni); rows abi_rows and on are zero (w couples to no interior DOF) */
    double *X;                /* (ni, nb) A_II^-1 A_IB; columns x_cols and on are zero */
    int abi_rows, x_cols;
    double *S0;               /* (nb, nb) Schur complement on x = [q, w]; symmetrised when sym */
    double *Sq;               /* (6, 6) then (nb): S0 - (1 + al) K0C - diag(c0 M_B) (on q only), then c0 M_B */
    double *K0C;              /* (nb, nb) D0 + c1 E: the soil force's part in x at this step size */
    double *K0Cp;             /* the same packed (used when E is symmetric: then K0C is) */
    double *K0Cd, *S0d;       /* (36 + N) K0C and S0 compact, for a diagonal soil (UpStepper.diag): their
                                 (6, 6) block on q, then their diagonal on w */
    /* the Newton matrix's two bases (stepper.c): every contact closed [0], every one open [1] */
    double *Jd[2];            /* (nb) their scaling, powers of two: d_r ~ |J_rr|^-1/2 */
    double *Jb[2];            /* (nb, nb) the inverses of the scaled bases, D J D (symmetrised when sym) */
    double *Jp[2];            /* the same packed, when sym */
    double *Jlu[2];           /* (nb, nb) the LU of the scaled bases (pivots Jpiv): the directions' solves */
    int *Jpiv[2];
    double *Z[2];             /* (N, nb) row i: base^-1 b_i, b_i node i's contact direction, solved when node i
                                 first enters a capacitance matrix (zdone[i] = 1 then; stepper.c: directions) */
    unsigned char *zdone[2];
    int base_ok[2];           /* 1 built, -1 singular, 0 not built yet (built when first needed) */
    /* a plate (UpStepper.nf > 0): the structure's part of S0 on [q, t] (6 + nf square: S0 less
       (1 + al) K0C on q and diag(c0 M_B) there), and packed when sym; NULL for a rigid raft */
    double *Sqt, *Sqtp;
    /* a plate whose A_II is banded (UpStepper.band > 0) and positive definite at this level: its
       Cholesky factor Lb (ni, band + 1; row i holds L_ij, j = i - band .. i), and the values of
       A_BI and A_IB on their patterns (UpStepper.bi_pat, ib_pat); AII, AIIp are then unused and a
       step's interior solves are two banded substitutions (banded = 1), else the dense path */
    double *Lb, *bi_val, *ib_val;
    int banded;
    /* K0C over the compressed history's partition (UpStepper.hk): per block (hk_rank) dense, or the
       factors of D, E and the history blocks stacked with the level's coefficients (stepper.c: k0c_blocks) */
    int64_t *hk_rank;
    double *hk_data;
} UpSystem;

typedef struct {
    int n, ns, ni, N, nb, nlev;
    double alpha, beta, gamma, tol;
    int enabled, max_iter, max_subdiv;
    int sym;                  /* 1: Ks, Cs (to round-off) and the soil's E symmetric: the system's matrices
                                 are held symmetrised and packed (half the memory traffic) */
    int diag;                 /* 1: the soil is springs (no pole, D and E zero between q and w and off the
                                 diagonal on w): S0 is a (6, 6) block on q and a diagonal on w, the products
                                 with K0C and E take the two blocks, Newton eliminates w node by node */
    double *Ed;               /* (36 + N) E compact (UpSystem.K0Cd), when diag */
    const double *M, *Ks, *Cs, *Mr, *Bq3, *kp, *P0, *delta0;   /* (n), (ns, ns) x2, (ns, 3), (N, 3), (N) x3 */
    UpSparse Ks_sp, Cs_sp;    /* Ks, Cs compressed (their products per step) */
    UpSoil *soil;             /* dt-dependent soil matrices; stepped unless external */
    int external;             /* 1: the history h is an input (h_ext), the soil is not stepped */
    const double *src;        /* (N) or NULL: a source W added to the contact equations of the next step,
                                 P - P0 + W the dynamic interface force (a load B^T W on [q, w]; held over
                                 a halved step's two halves): the time-frequency route's defect correction */
    UpSystem sys[UP_MAXLEV];
    /* per (level, active set): the base, the k nodes where J differs from it and the LU of the
       (k, k) capacitance matrix; least recently used replaced */
    double *cache_lu;
    int *cache_piv, *cache_lev, *cache_nodes, *cache_base, *cache_k;
    unsigned char *cache_act;
    long *cache_used;
    long clock;
    /* state, inside the instance's state block */
    double *t, *u, *v, *a, *P, *fs, *fc, *R, *F, *ag, *work, *ag_next, *h_ext;
    double *Kx, *kx_lev;      /* K0C x for the state's x = u[ni:], and the level it was computed at */
    /* work */
    double *w_n[10], *w_nb[12], *w_N[6], *hbuf;
    double *lu, *rhs;         /* (max(ni, nb)^2) x2: the set-up's LU factorisations and their solves */
    int *lu_piv;
    unsigned char *act, *act_new;
    double *saves;            /* (nlev + 1) copies of the instance's state block */
    double *block;
    size_t block_len;
    int last_iters;
    int last_halved;          /* 1 when the last step was halved */
    long n_factorisations;    /* LU factorisations of Newton matrices so far (bases and capacitances) */
    char *err;                /* message of a failed step */
    /* a plate raft (structure/plate_raft.py, PlateStepper; record nf): the boundary block is
       x = [q, t, w] (nb = 6 + nf + N), t the free plate vertices' deflections, the soil on
       [q, w] only (nsoil = 6 + N; its vectors fs, Kx, h held in the soil's order); the contact
       d_i = sum_k bc_val[k] x[bc_col[k]] (k in bc_ptr[i] .. bc_ptr[i + 1]: the trace on [q, t])
       - w_i. A rigid raft: nf = 0, nsoil = nb, no bc_* (d = Bq3 q[2:5] - w) */
    int nf, nsoil;
    int *bc_ptr, *bc_col;
    double *bc_val;
    double *xs, *vs;          /* (nsoil) work: x and xdot in the soil's order */
    int band;                 /* a plate, sym: the half bandwidth of A_II (the sticks' and the plate
                                 rotations' blocks: sparse and banded) when two banded solves cost less
                                 than one dense product with A_II^-1, else 0 (the dense path) */
    UpSparse bi_pat, ib_pat;  /* the patterns of A_BI (nb, ni) and A_IB (ni, nb): Ks's or Cs's non-zeros */
    int hk;                   /* 1: the soil's D and E are compressed with its history (UpSoil.hm_de_ranks)
                                 and E is symmetric: the products with E and K0C run over the blocks */
    size_t hk_len;            /* the values of a level's K0C blocks (UpSystem.hk_data) */
    size_t *hk_off;           /* (m_r + 2 m_c + 2, hm_nblk): where each term's values of a block start (the
                                 history blocks' in hm_data, D's and E's in hm_de_data) */
    int lean;                 /* 1: a march of the time-frequency route's defect correction (simulate.c,
                                 up_sim_lean): the works not summed, and K0C x of the committed state taken
                                 from the Newton iteration's S0 x (a rigid raft in contact) instead of a
                                 product but at every UP_LEAN_ANCHOR-th step; 0 (the default): every
                                 route's steps */
    long lean_steps;          /* steps since rest (up_stepper_rest) of a lean run */
} UpStepper;

int up_stepper_init(UpStepper *s, const UpRes *r, UpSoil *soil, int external, char *err);
void up_stepper_free(UpStepper *s);
size_t up_stepper_state_len(const UpStepper *s);
void up_stepper_bind(UpStepper *s, double *state, double *block, size_t block_len, double *saves);
void up_stepper_rest(UpStepper *s, const double *ag0);
int up_stepper_prepare(UpStepper *s, char *err);        /* the system at dt, before the first step */
int up_stepper_step(UpStepper *s);                       /* 0, or -1 with s->err */
void up_stepper_gap(const UpStepper *s, double *gap);
void up_stepper_energies(const UpStepper *s, double *e); /* (UP_N_ENERGY): e[UP_E_INPUT], ... */

/* ---- simulate.c: a run in chunks of steps, or in one call, for in-process hosts ------------- */
typedef struct UpSim UpSim;                              /* a run: records, soil, stepper, state */
UP_API UpSim *up_sim_open(const unsigned char *res, uint64_t size, const double *ag0, char *err);
UP_API int64_t up_sim_width(const UpSim *h);
UP_API int up_sim_steps(UpSim *h, const double *ag, int64_t k0, int64_t k1, double *rows, int64_t *iters,
                        int64_t *stats, char *err);
UP_API int up_sim_steps_src(UpSim *h, const double *ag, const double *src, int64_t k0, int64_t k1, double *rows,
                            int64_t *iters, int64_t *stats, char *err);
UP_API void up_sim_rewind(UpSim *h, const double *ag0);
UP_API int up_sim_correction(UpSim *h, int64_t nt, int mode);  /* soil.c's correction form, next run */
UP_API void up_sim_close(UpSim *h);
UP_API int up_simulate(const unsigned char *res, uint64_t size, const double *ag, int64_t nt, double *rows,
                       int64_t *iters, int64_t *stats, char *err);

#endif

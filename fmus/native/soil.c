/* The trapezoidal recursive convolution of the rational soil model
   K(s) = D + s E + sum_k R_k / (s - p_k), as soil_impedance/convolution.py (RecursiveConvolutionSoil):

     y_{k,n} = a_k y_{k,n-1} + b_k (u_n + u_{n-1}),  a_k = (1 + p_k dt/2)/(1 - p_k dt/2),
                                                     b_k = (dt/2)/(1 - p_k dt/2)
     f_n = D0 u_n + E u'_n + h_n,  D0 = D + sum_k b_k R_k,  h_n = sum_k R_k (a_k y_{k,n-1} + b_k u_{n-1})

   Complex poles are carried once per conjugate pair (the partner gives the complex conjugate):
   h = H g with H (n, L) stacking R_k of the real poles and [2 Re R_k, -2 Im R_k] of the pairs,
   g the stacked a_k y_k + b_k u (pairs as (re, im)). The residues of a fitted model are
   symmetric (reciprocity): H is then held as its L / n symmetric blocks, packed (half the
   memory traffic of the product, which is what bounds it); otherwise pole-major, as its
   transpose Ht (L, n), h accumulating g_j times row j of Ht (up_gemv_t). Either way the loops
   vectorise with no reassociation (the same sums in the same order at every width). The coefficients and D0 depend on dt:
   one set per step-halving level, computed when first needed.

   A soil stepped alone (the soil FMU, up_soil_step) publishes g_{n+2}, the history of the step after
   next without the part driven by the state committed next (fmus/coupling.py). Its own history for
   the commit of u_n is then what it published two steps before plus that part, h_n = g_n + Gx u_{n-1}
   with the constant gain Gx = sum_k R_k b_k (a_k + 1): one product over H per step, as the stepper.
   With real poles only (packed blocks), h_{n+1} and g_{n+2} come from the same block products
   P_k = R_k (a_k y_k + b_k u_n) after the commit of u_n: h_{n+1} = sum P_k, g_{n+2} = sum a_k P_k, and
   Gx u is not needed (real_packed, next_histories).
   Its outputs, the force f_n = (D0 u_n + E u'_n) + h_n and the work done on it, are not needed by
   the step itself: the step keeps E u'_n and h_n, and accumulates the work of the force's part
   E u' + h, sum du . ((E u' + h)_n + (E u' + h)_{n-1}) / 2. The part D0 u telescopes (D0 is
   symmetric): sum du_n . D0 (u_n + u_{n-1}) / 2 = u_n . D0 u_n / 2 from rest. So D0 u_n, the force
   and the total work are computed only when read (up_soil_outputs): two n x n products a step
   instead of three; the force bit for bit as when it was computed every step, the work to round-off.

   On a large interface H is held compressed (records hm_*: soil_impedance/hhistory.py): its blocks
   as hierarchical matrices, dense near blocks and low-rank far blocks over one cluster tree of the
   nodes; the residues of the resource file are then those of the compressed model (D0 and the
   history gain from them), so the product is that model's to round-off. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "uplift.h"

/* a run in correction form (up_soil_corr_mode, at the end of this file) */
struct UpSoilCorr {
    int mode, broken;
    int64_t nt, k, recorded;  /* samples; the sample of the step under way; nt when the records hold a run */
    float *Hs32;              /* the packed blocks in single precision */
    float *g32, *part32;      /* (L) the change's stacked input, each block's product */
    double *hrec, *urec;      /* (nt, n) per sample: the history the step used, the state it committed */
    double *dy, *du, *gd, *dx; /* (L) the change's pole states, (n) its last committed state, (L) its input,
                                 (n) work */
};

/* entry (i, j) of history block b (a real pole's R_k; a pair's 2 Re R_k, then -2 Im R_k) */
static double block_entry(const UpSoil *s, int b, int i, int j)
{
    size_t n = (size_t)s->n;
    if (b < s->mr)
        return s->Rr[((size_t)b * n + i) * n + j];
    int k = (b - s->mr) / 2, im = (b - s->mr) % 2;
    double v = s->Rc[(((size_t)k * n + i) * n + j) * 2 + im];
    return im ? -2.0 * v : 2.0 * v;
}

/* the model's D and E compressed over the history's partition (records hm_de_ranks (2, nblk), hm_de_data:
   hhistory.py's CompressedHistory.instant), when the resource file has them: read and checked as the
   history's blocks; 0 when absent or read, -1 with a message when malformed */
static int compressed_instant(UpSoil *s, const UpRes *r, char *err)
{
    if (!up_res_find(r, "hm_de_ranks"))
        return 0;
    int64_t dr[2] = {2, s->hm_nblk}, dd[1] = {-1};
    if (!(s->hm_de_ranks = up_res_i64(r, "hm_de_ranks", 2, dr, err))
        || !(s->hm_de_data = up_res_f64(r, "hm_de_data", 1, dd, err)))
        return -1;
    uint64_t total = 0;
    int ok = 1;
    for (int k = 0; ok && k < 2; k++) {
        if (k == 1)
            s->hm_de_off = (size_t)total;
        for (int j = 0; ok && j < s->hm_nblk; j++) {
            const int64_t *b = s->hm_blocks + 4 * (size_t)j;
            int64_t rk = s->hm_de_ranks[(size_t)k * s->hm_nblk + j];
            ok = rk >= -1 && rk <= s->n;
            total += rk < 0 ? (uint64_t)(b[1] * b[3]) : (uint64_t)(rk * (b[1] + b[3]));
        }
    }
    if (!ok || total != (uint64_t)dd[0]) {
        snprintf(err, UP_MSG, "resource file %s: the compressed D and E of the soil (records hm_de_*) are "
                 "inconsistent: export the FMU again with this version of uplift", r->path);
        return -1;
    }
    return 0;
}

/* the compressed history of the resource file (records hm_*), when it has one: read and checked
   (a permutation, blocks inside the matrix and upper, ranks and values of the blocks' sizes); 0 when
   absent or read, -1 with a message when malformed or out of memory */
static int compressed_history(UpSoil *s, const UpRes *r, char *err)
{
    if (!up_res_find(r, "hm_perm"))
        return 0;
    int n = s->n, nb = s->mr + 2 * s->mc;
    int64_t dp[1] = {n}, db[2] = {-1, 4}, dr[2] = {nb, -1}, dd[1] = {-1};
    if (!(s->hm_perm = up_res_i64(r, "hm_perm", 1, dp, err)) || !(s->hm_blocks = up_res_i64(r, "hm_blocks", 2, db, err)))
        return -1;
    dr[1] = db[0];
    if (!(s->hm_ranks = up_res_i64(r, "hm_ranks", 2, dr, err)) || !(s->hm_data = up_res_f64(r, "hm_data", 1, dd, err)))
        return -1;
    s->hm_nblk = (int)db[0];
    s->hm_x = (double *)calloc(3 * (size_t)n + 1, sizeof(double));
    if (!s->hm_x) {
        snprintf(err, UP_MSG, "out of memory for the compressed soil history (%d DOFs)", n);
        return -1;
    }
    s->hm_y = s->hm_x + n;
    s->hm_t = s->hm_y + n;
    int ok = 1;
    unsigned char *seen = (unsigned char *)calloc((size_t)n + 1, 1);
    for (int p = 0; ok && seen && p < n; p++) {
        int64_t q = s->hm_perm[p];
        ok = q >= 0 && q < n && !seen[q];
        if (ok)
            seen[q] = 1;
    }
    free(seen);
    uint64_t total = 0;
    for (int j = 0; ok && j < s->hm_nblk; j++) {
        const int64_t *b = s->hm_blocks + 4 * (size_t)j;
        ok = b[0] >= 0 && b[1] > 0 && b[2] >= b[0] && b[3] > 0 && b[0] + b[1] <= n && b[2] + b[3] <= n
             && (b[0] != b[2] || b[1] == b[3]);
        for (int k = 0; ok && k < nb; k++) {
            int64_t rk = s->hm_ranks[(size_t)k * s->hm_nblk + j];
            ok = rk >= -1 && rk <= n;
            total += rk < 0 ? (uint64_t)(b[1] * b[3]) : (uint64_t)(rk * (b[1] + b[3]));
        }
    }
    if (!ok || total != (uint64_t)dd[0]) {
        snprintf(err, UP_MSG, "resource file %s: the compressed soil history (records hm_*) is inconsistent: "
                 "export the FMU again with this version of uplift", r->path);
        return -1;
    }
    return compressed_instant(s, r, err);
}

/* the history matrix: none when compressed (compressed_history); packed symmetric blocks when every
   residue is symmetric (as the fit makes them), else H transposed; 0 when out of memory */
static int history_matrix(UpSoil *s)
{
    int n = s->n, nb = s->mr + 2 * s->mc, sym = 1;
    if (s->hm_perm)
        return 1;
    for (int b = 0; sym && b < nb; b++)
        for (int i = 0; sym && i < n; i++)
            for (int j = i + 1; sym && j < n; j++)
                sym = block_entry(s, b, i, j) == block_entry(s, b, j, i);
    if (sym) {
        size_t packed = (size_t)n * (n + 1) / 2, q = 0;
        if (!(s->Hs = (double *)malloc((nb ? nb * packed : 1) * sizeof(double))))
            return 0;
        for (int b = 0; b < nb; b++)
            for (int i = 0; i < n; i++)
                for (int j = i; j < n; j++)
                    s->Hs[q++] = block_entry(s, b, i, j);
        return 1;
    }
    if (!(s->H = (double *)malloc((s->L ? s->L : 1) * (size_t)n * sizeof(double))))
        return 0;
    for (int b = 0; b < nb; b++)                          /* Ht[c][i] = H[i][c] */
        for (int j = 0; j < n; j++) {
            size_t c = b < s->mr ? (size_t)b * n + j
                                 : (size_t)s->mr * n + ((size_t)((b - s->mr) / 2) * n + j) * 2 + (b - s->mr) % 2;
            for (int i = 0; i < n; i++)
                s->H[c * n + i] = block_entry(s, b, i, j);
        }
    return 1;
}

/* the stacked input of block b into v (n): g's entries of that block (a pair's re or im parts) */
static const double *block_input(const UpSoil *s, const double *g, int b, double *v)
{
    int n = s->n;
    if (b < s->mr)
        return g + (size_t)b * n;
    const double *gc = g + (size_t)s->mr * n + (size_t)((b - s->mr) / 2) * n * 2 + (b - s->mr) % 2;
    for (int j = 0; j < n; j++)
        v[j] = gc[2 * j];
    return v;
}

/* The compressed product's loops: along contiguous rows, with no reduction or with eight fixed
   partial sums (folded in a fixed order), so that the compiler vectorises them without
   reassociating anything: the same result at every vector width. On x86-64 with GCC or clang,
   AVX2 and AVX-512 versions of the product beside the baseline, the widest the CPU has called
   (up_vector_level, linalg.c's test), as linalg.c's kernels. */
#if defined(__x86_64__) && defined(__GNUC__) && !defined(UP_BASELINE_ONLY)
#define HM_DISPATCH 1
#define HM_BODY static inline __attribute__((always_inline))
#else
#define HM_BODY static inline
#endif

HM_BODY double hm_fold8(const double *s)
{
    return ((s[0] + s[1]) + (s[2] + s[3])) + ((s[4] + s[5]) + (s[6] + s[7]));
}

/* y[i] += A_i . x for the rows of A (rows, cols), eight partial sums each; four rows in one pass
   (x loaded once per four rows) */
HM_BODY void hm_rows_dot(const double *restrict A, int rows, int cols, const double *restrict x, double *restrict y)
{
    int i = 0;
    for (; i + 4 <= rows; i += 4) {
        const double *restrict a0 = A + (size_t)i * cols, *restrict a1 = a0 + cols, *restrict a2 = a1 + cols,
                     *restrict a3 = a2 + cols;
        double s0[8] = {0.0}, s1[8] = {0.0}, s2[8] = {0.0}, s3[8] = {0.0};
        int j = 0;
        for (; j + 8 <= cols; j += 8)
            for (int k = 0; k < 8; k++) {
                double xv = x[j + k];
                s0[k] += a0[j + k] * xv;
                s1[k] += a1[j + k] * xv;
                s2[k] += a2[j + k] * xv;
                s3[k] += a3[j + k] * xv;
            }
        for (int k = 0; j < cols; j++, k++) {
            s0[k] += a0[j] * x[j];
            s1[k] += a1[j] * x[j];
            s2[k] += a2[j] * x[j];
            s3[k] += a3[j] * x[j];
        }
        y[i] += hm_fold8(s0);
        y[i + 1] += hm_fold8(s1);
        y[i + 2] += hm_fold8(s2);
        y[i + 3] += hm_fold8(s3);
    }
    for (; i < rows; i++) {
        const double *restrict a = A + (size_t)i * cols;
        double s[8] = {0.0};
        int j = 0;
        for (; j + 8 <= cols; j += 8)
            for (int k = 0; k < 8; k++)
                s[k] += a[j + k] * x[j + k];
        for (int k = 0; j < cols; j++, k++)
            s[k] += a[j] * x[j];
        y[i] += hm_fold8(s);
    }
}

/* y += A^T t for A (rows, cols): t_i times row i, in the order of the rows, four rows in one pass
   (y loaded and stored once per four rows) */
HM_BODY void hm_rows_axpy(const double *restrict A, int rows, int cols, const double *restrict t, double *restrict y)
{
    int i = 0;
    for (; i + 4 <= rows; i += 4) {
        const double *restrict a0 = A + (size_t)i * cols, *restrict a1 = a0 + cols, *restrict a2 = a1 + cols,
                     *restrict a3 = a2 + cols;
        double t0 = t[i], t1 = t[i + 1], t2 = t[i + 2], t3 = t[i + 3];
        for (int j = 0; j < cols; j++)
            y[j] = (((y[j] + t0 * a0[j]) + t1 * a1[j]) + t2 * a2[j]) + t3 * a3[j];
    }
    for (; i < rows; i++) {
        const double *restrict a = A + (size_t)i * cols;
        double ti = t[i];
        for (int j = 0; j < cols; j++)
            y[j] += ti * a[j];
    }
}

/* a block off the diagonal and its mirror in one pass over A (rows, cols): yr += A xc (eight
   partial sums per row) and yc += A^T xr (in the order of the rows); four rows at a time, so that
   xc is loaded and yc loaded and stored once per four rows; yr and yc are disjoint */
HM_BODY void hm_pair(const double *restrict A, int rows, int cols, const double *restrict xc, const double *restrict xr,
                     double *restrict yr, double *restrict yc)
{
    int i = 0;
    for (; i + 4 <= rows; i += 4) {
        const double *restrict a0 = A + (size_t)i * cols, *restrict a1 = a0 + cols, *restrict a2 = a1 + cols,
                     *restrict a3 = a2 + cols;
        double x0 = xr[i], x1 = xr[i + 1], x2 = xr[i + 2], x3 = xr[i + 3];
        double s0[8] = {0.0}, s1[8] = {0.0}, s2[8] = {0.0}, s3[8] = {0.0};
        int j = 0;
        for (; j + 8 <= cols; j += 8)
            for (int k = 0; k < 8; k++) {
                double v0 = a0[j + k], v1 = a1[j + k], v2 = a2[j + k], v3 = a3[j + k], xv = xc[j + k];
                s0[k] += v0 * xv;
                s1[k] += v1 * xv;
                s2[k] += v2 * xv;
                s3[k] += v3 * xv;
                yc[j + k] = (((yc[j + k] + x0 * v0) + x1 * v1) + x2 * v2) + x3 * v3;
            }
        for (int k = 0; j < cols; j++, k++) {
            double v0 = a0[j], v1 = a1[j], v2 = a2[j], v3 = a3[j], xv = xc[j];
            s0[k] += v0 * xv;
            s1[k] += v1 * xv;
            s2[k] += v2 * xv;
            s3[k] += v3 * xv;
            yc[j] = (((yc[j] + x0 * v0) + x1 * v1) + x2 * v2) + x3 * v3;
        }
        yr[i] += hm_fold8(s0);
        yr[i + 1] += hm_fold8(s1);
        yr[i + 2] += hm_fold8(s2);
        yr[i + 3] += hm_fold8(s3);
    }
    for (; i < rows; i++) {
        const double *restrict a = A + (size_t)i * cols;
        double s[8] = {0.0}, xi = xr[i];
        int j = 0;
        for (; j + 8 <= cols; j += 8)
            for (int k = 0; k < 8; k++) {
                double v = a[j + k];
                s[k] += v * xc[j + k];
                yc[j + k] += xi * v;
            }
        for (int k = 0; j < cols; j++, k++) {
            s[k] += a[j] * xc[j];
            yc[j] += xi * a[j];
        }
        yr[i] += hm_fold8(s);
    }
}

/* h = H g through the compressed history: per history block (in order) its input permuted, then
   each block of the partition (in order): a dense block A adds A x to its rows and, off the
   diagonal, A^T x to its columns (one pass); a low-rank one U^T V adds U^T (V x) and, always off
   the diagonal, V^T (U x). The permuted product scattered back at the end */
/* y += A x over the permuted order for one matrix of the partition (its ranks, its values d): each
   block in order, a dense one A (and its mirror off the diagonal, one pass), a low-rank one U^T V (and
   V^T U); t (n) work. The values past A's */
HM_BODY const double *hm_blocks_add(const UpSoil *s, const int64_t *rank, const double *d, const double *x,
                                    double *y, double *t)
{
    for (int j = 0; j < s->hm_nblk; j++) {
        const int64_t *bl = s->hm_blocks + 4 * (size_t)j;
        int r0 = (int)bl[0], nr = (int)bl[1], c0 = (int)bl[2], nc = (int)bl[3], r = (int)rank[j];
        if (r < 0) {
            if (r0 == c0)
                hm_rows_dot(d, nr, nc, x + c0, y + r0);
            else
                hm_pair(d, nr, nc, x + c0, x + r0, y + r0, y + c0);
            d += (size_t)nr * nc;
        } else {
            const double *U = d, *V = d + (size_t)r * nr;
            memset(t, 0, (size_t)r * sizeof(double));
            hm_rows_dot(V, r, nc, x + c0, t);
            hm_rows_axpy(U, r, nr, t, y + r0);
            memset(t, 0, (size_t)r * sizeof(double));
            hm_rows_dot(U, r, nr, x + r0, t);
            hm_rows_axpy(V, r, nc, t, y + c0);
            d += (size_t)r * (nr + nc);
        }
    }
    return d;
}

HM_BODY void compressed_product_k(UpSoil *s, const double *g, double *h)
{
    int n = s->n, nb = s->mr + 2 * s->mc, nblk = s->hm_nblk;
    double *x = s->hm_x, *y = s->hm_y, *t = s->hm_t, *v = s->fbuf + 3 * (size_t)n;
    const int64_t *perm = s->hm_perm;
    const double *d = s->hm_data;
    memset(y, 0, (size_t)n * sizeof(double));
    for (int b = 0; b < nb; b++) {
        const double *gb = block_input(s, g, b, v);
        for (int p = 0; p < n; p++)
            x[p] = gb[perm[p]];
        d = hm_blocks_add(s, s->hm_ranks + (size_t)b * nblk, d, x, y, t);
    }
    for (int p = 0; p < n; p++)
        h[perm[p]] = y[p];
}

/* y = A x for one symmetric matrix over the partition (up_hm_matvec): x permuted, the blocks, y
   scattered back */
HM_BODY void hm_matvec_k(UpSoil *s, const int64_t *rank, const double *d, const double *xin, double *out)
{
    int n = s->n;
    double *x = s->hm_x, *y = s->hm_y, *t = s->hm_t;
    const int64_t *perm = s->hm_perm;
    for (int p = 0; p < n; p++)
        x[p] = xin[perm[p]];
    memset(y, 0, (size_t)n * sizeof(double));
    hm_blocks_add(s, rank, d, x, y, t);
    for (int p = 0; p < n; p++)
        out[perm[p]] = y[p];
}

#ifdef HM_DISPATCH
__attribute__((target("avx512f"))) static void hm_matvec_avx512(UpSoil *s, const int64_t *rank, const double *d,
                                                                 const double *x, double *y)
{
    hm_matvec_k(s, rank, d, x, y);
}
__attribute__((target("avx2"))) static void hm_matvec_avx2(UpSoil *s, const int64_t *rank, const double *d,
                                                            const double *x, double *y)
{
    hm_matvec_k(s, rank, d, x, y);
}
#endif

void up_hm_matvec(UpSoil *s, const int64_t *rank, const double *d, const double *x, double *y)
{
#ifdef HM_DISPATCH
    int level = up_vector_level();
    if (level == 2) {
        hm_matvec_avx512(s, rank, d, x, y);
        return;
    }
    if (level == 1) {
        hm_matvec_avx2(s, rank, d, x, y);
        return;
    }
#endif
    hm_matvec_k(s, rank, d, x, y);
}

#ifdef HM_DISPATCH
__attribute__((target("avx512f"))) static void compressed_product_avx512(UpSoil *s, const double *g, double *h)
{
    compressed_product_k(s, g, h);
}
__attribute__((target("avx2"))) static void compressed_product_avx2(UpSoil *s, const double *g, double *h)
{
    compressed_product_k(s, g, h);
}
#endif

static void compressed_product(UpSoil *s, const double *g, double *h)
{
#ifdef HM_DISPATCH
    int level = up_vector_level();
    if (level == 2) {
        compressed_product_avx512(s, g, h);
        return;
    }
    if (level == 1) {
        compressed_product_avx2(s, g, h);
        return;
    }
#endif
    compressed_product_k(s, g, h);
}

/* h = H g. Packed: each block's product into its own part of s->part, the parts summed in the
   blocks' order, so the result does not depend on the order the blocks are read in; that order
   alternates from one product to the next, so the blocks read last (still in cache) are read
   first the next time (the packed blocks of the reactor, ~2 MB, do not fit in L2) */
static void history_product(UpSoil *s, const double *g, double *h)
{
    int n = s->n;
    if (s->hm_perm) {
        compressed_product(s, g, h);
        return;
    }
    if (!s->Hs) {
        up_gemv_t(s->H, (int)s->L, n, g, h);
        return;
    }
    size_t packed = (size_t)n * (n + 1) / 2;
    double *v = s->fbuf + 3 * (size_t)n;
    int nb = s->mr + 2 * s->mc;
    s->flip = !s->flip;
    memset(s->part, 0, s->L * sizeof(double));
    for (int q = 0; q < nb; q++) {
        int b = s->flip ? nb - 1 - q : q;
        up_spmv_add(s->Hs + (size_t)b * packed, n, block_input(s, g, b, v), s->part + (size_t)b * n);
    }
    memset(h, 0, (size_t)n * sizeof(double));
    for (int b = 0; b < nb; b++)
        up_axpy(1.0, s->part + (size_t)b * n, n, h);
}

int up_soil_init(UpSoil *s, const UpRes *r, int n, int nlev, int stepped, char *err)
{
    memset(s, 0, sizeof *s);
    s->n = n;
    int64_t d1[1] = {-1}, d2[2] = {-1, 2}, dr[3] = {-1, n, n}, dc[4] = {-1, n, n, 2}, dn[2] = {n, n};
    if (!(s->pr = up_res_f64(r, "poles_real", 1, d1, err)) || !(s->pc = up_res_f64(r, "poles_pair", 2, d2, err)))
        return -1;
    s->mr = (int)d1[0];
    s->mc = (int)d2[0];
    dr[0] = s->mr;
    dc[0] = s->mc;
    if (!(s->Rr = up_res_f64(r, "residues_real", 3, dr, err)) || !(s->Rc = up_res_f64(r, "residues_pair", 4, dc, err))
        || !(s->D = up_res_f64(r, "D", 2, dn, err)))
        return -1;
    dn[0] = dn[1] = n;
    if (!(s->E = up_res_f64(r, "E", 2, dn, err)))
        return -1;
    for (int k = 0; k < s->mr + s->mc; k++) {
        double re = k < s->mr ? s->pr[k] : s->pc[2 * (k - s->mr)];
        double im = k < s->mr ? 0.0 : s->pc[2 * (k - s->mr) + 1];
        if (!(re < 0.0) || !isfinite(re) || !isfinite(im)) {
            snprintf(err, UP_MSG, "soil pole %d = %g%+gi is not stable (Re p < 0): the rational soil model "
                     "of resource file %s is not usable; fit it again", k, re, im, r->path);
            return -1;
        }
    }
    int mr = s->mr, mc = s->mc;
    s->L = (size_t)(mr + 2 * mc) * (size_t)n;
    s->fbuf = (double *)calloc(5 * (size_t)n + 1, sizeof(double));
    int ok = s->fbuf != NULL;
    if (stepped && ok) {
        s->g = (double *)calloc(s->L + 1, sizeof(double));
        s->part = (double *)calloc(s->L + 1, sizeof(double));
        if (compressed_history(s, r, err) < 0) {
            up_soil_free(s);
            return -1;
        }
        ok = s->g && s->part && history_matrix(s);
    }
    if (stepped == 2 && ok) {
        s->Gx = (double *)malloc((size_t)n * n * sizeof(double) + 1);
        s->Gxp = (double *)malloc(((size_t)n * (n + 1) / 2 + 1) * sizeof(double));
        ok = s->Gx && s->Gxp;
    }
    for (int l = 0; ok && l < nlev; l++) {
        UpSoilLevel *lv = &s->lev[l];
        lv->ar = (double *)calloc((size_t)(2 * mr + 4 * mc) + 1, sizeof(double));
        lv->D0 = (double *)malloc((size_t)n * n * sizeof(double));
        lv->D0p = (double *)malloc(((size_t)n * (n + 1) / 2 + 1) * sizeof(double));
        ok = lv->ar && lv->D0 && lv->D0p;
        if (ok) {
            lv->br = lv->ar + mr;
            lv->ac = lv->br + mr;
            lv->bc = lv->ac + 2 * mc;
        }
    }
    if (ok && (s->Ep = (double *)malloc(((size_t)n * (n + 1) / 2 + 1) * sizeof(double))) != NULL
        && !up_pack_sym(s->E, n, s->Ep)) {
        free(s->Ep);                                      /* not symmetric: the dense products */
        s->Ep = NULL;
    }
    if (!ok) {
        up_soil_free(s);
        snprintf(err, UP_MSG, "out of memory for the soil model (%d DOFs, %d poles)", n, mr + 2 * mc);
        return -1;
    }
    return 0;
}

static void corr_free(struct UpSoilCorr *c);

void up_soil_free(UpSoil *s)
{
    corr_free(s->corr);
    free(s->H);
    free(s->Hs);
    free(s->Ep);
    free(s->g);
    free(s->part);
    free(s->Gx);
    free(s->Gxp);
    free(s->fbuf);
    free(s->hm_x);
    for (int l = 0; l < UP_MAXLEV; l++) {
        free(s->lev[l].ar);
        free(s->lev[l].D0);
        free(s->lev[l].D0p);
    }
    memset(s, 0, sizeof *s);
}

size_t up_soil_state_len(const UpSoil *s)
{
    return s->L + (s->Gx ? 7 : 3) * (size_t)s->n + (s->Gx ? 2 : 1);
}

void up_soil_bind(UpSoil *s, double *state)
{
    s->yr = state;
    s->yc = s->yr + (size_t)s->mr * s->n;
    s->u = s->yr + s->L;
    s->ud = s->u + s->n;
    s->f = s->ud + s->n;
    s->work = s->f + s->n;
    s->gq = s->Gx ? s->work + 1 : NULL;
    s->gp = s->Gx ? s->gq + s->n : NULL;
    s->ev = s->Gx ? s->gp + s->n : NULL;
    s->hn = s->Gx ? s->ev + s->n : NULL;
    s->stale = s->Gx ? s->hn + s->n : NULL;
}

void up_soil_rest(UpSoil *s)
{
    memset(s->yr, 0, up_soil_state_len(s) * sizeof(double));
}

/* s->Gx = sum_k R_k b_k (a_k + 1) at the level's dt (a pair: 2 Re), and packed when symmetric: the part
   of the history of the step after next driven by the state committed next */
static void history_gain(UpSoil *s, const UpSoilLevel *lv)
{
    size_t nn = (size_t)s->n * s->n;
    double *G = s->Gx;
    memset(G, 0, nn * sizeof(double));
    for (int k = 0; k < s->mr; k++) {
        const double *R = s->Rr + (size_t)k * nn;
        double c = lv->br[k] * (lv->ar[k] + 1.0);
        for (size_t i = 0; i < nn; i++)
            G[i] += c * R[i];
    }
    for (int k = 0; k < s->mc; k++) {
        const double *R = s->Rc + (size_t)k * nn * 2;
        double are = lv->ac[2 * k] + 1.0, aim = lv->ac[2 * k + 1], bre = lv->bc[2 * k], bim = lv->bc[2 * k + 1];
        double cre = bre * are - bim * aim, cim = bre * aim + bim * are;         /* c = b (a + 1) */
        for (size_t i = 0; i < nn; i++)
            G[i] += 2.0 * (cre * R[2 * i] - cim * R[2 * i + 1]);
    }
    if (!up_pack_sym(G, s->n, s->Gxp)) {
        free(s->Gxp);                                     /* not symmetric: the dense product */
        s->Gxp = NULL;
    }
}

const UpSoilLevel *up_soil_level(UpSoil *s, int lev, double dt)
{
    UpSoilLevel *lv = &s->lev[lev];
    if (lv->ready)
        return lv;
    int n = s->n, mr = s->mr, mc = s->mc;
    for (int k = 0; k < mr; k++) {
        double den = 1.0 - 0.5 * dt * s->pr[k];
        lv->ar[k] = (1.0 + 0.5 * dt * s->pr[k]) / den;
        lv->br[k] = 0.5 * dt / den;
    }
    for (int k = 0; k < mc; k++) {
        double pre = s->pc[2 * k], pim = s->pc[2 * k + 1];
        double dre = 1.0 - 0.5 * dt * pre, dim = -0.5 * dt * pim;     /* den = 1 - p dt/2 */
        double nre = 1.0 + 0.5 * dt * pre, nim = 0.5 * dt * pim;      /* num = 1 + p dt/2 */
        double q = dre * dre + dim * dim;
        lv->ac[2 * k] = (nre * dre + nim * dim) / q;
        lv->ac[2 * k + 1] = (nim * dre - nre * dim) / q;
        lv->bc[2 * k] = 0.5 * dt * dre / q;
        lv->bc[2 * k + 1] = -0.5 * dt * dim / q;
    }
    double *D0 = lv->D0;
    memcpy(D0, s->D, (size_t)n * n * sizeof(double));
    for (int k = 0; k < mr; k++) {
        const double *R = s->Rr + (size_t)k * n * n;
        for (size_t i = 0; i < (size_t)n * n; i++)
            D0[i] += lv->br[k] * R[i];
    }
    for (int k = 0; k < mc; k++) {
        const double *R = s->Rc + (size_t)k * n * n * 2;
        double bre = lv->bc[2 * k], bim = lv->bc[2 * k + 1];
        for (size_t i = 0; i < (size_t)n * n; i++)
            D0[i] += 2.0 * (bre * R[2 * i] - bim * R[2 * i + 1]);
    }
    for (int i = 0; i < n; i++)
        for (int j = i + 1; j < n; j++) {
            double m = 0.5 * (D0[(size_t)i * n + j] + D0[(size_t)j * n + i]);
            D0[(size_t)i * n + j] = D0[(size_t)j * n + i] = m;
        }
    up_pack_sym(D0, n, lv->D0p);
    if (lev == 0 && s->Gx)
        history_gain(s, lv);
    lv->dt = dt;
    lv->ready = 1;
    return lv;
}

/* g = [a y + b u] stacked, from the pole states y and the input u given */
static void stack(const UpSoil *s, const UpSoilLevel *lv, const double *yr, const double *yc, const double *u,
                  double *g)
{
    int n = s->n;
    for (int k = 0; k < s->mr; k++)
        for (int j = 0; j < n; j++)
            g[(size_t)k * n + j] = lv->ar[k] * yr[(size_t)k * n + j] + lv->br[k] * u[j];
    double *gc = g + (size_t)s->mr * n;
    for (int k = 0; k < s->mc; k++) {
        double are = lv->ac[2 * k], aim = lv->ac[2 * k + 1], bre = lv->bc[2 * k], bim = lv->bc[2 * k + 1];
        for (int j = 0; j < n; j++) {
            size_t q = ((size_t)k * n + j) * 2;
            double yre = yc[q], yim = yc[q + 1];
            gc[q] = (are * yre - aim * yim) + bre * u[j];
            gc[q + 1] = (are * yim + aim * yre) + bim * u[j];
        }
    }
}

static void corr_history(UpSoil *s, int lev, double *h);
static void corr_commit(UpSoil *s, int lev, const double *x);

void up_soil_history(UpSoil *s, int lev, double *h)
{
    if (s->corr && s->corr->mode) {                   /* a run in correction form (below) */
        corr_history(s, lev, h);
        return;
    }
    stack(s, &s->lev[lev], s->yr, s->yc, s->u, s->g);
    history_product(s, s->g, h);
}

void up_soil_force(UpSoil *s, int lev, const double *x, const double *xd, const double *h, double *f)
{
    const UpSoilLevel *lv = &s->lev[lev];
    int n = s->n;
    double *Dx = s->fbuf + 3 * (size_t)n, *Ev = Dx + n;
    up_symv(lv->D0, lv->D0p, n, x, Dx);
    up_symv(s->E, s->Ep, n, xd, Ev);
    for (int i = 0; i < n; i++)
        f[i] = (Dx[i] + Ev[i]) + h[i];
}

/* y <- a y + b (x + u), the pole states after committing x on u (pair states as (re, im)) */
static void advance_states(const UpSoil *s, const UpSoilLevel *lv, const double *x, const double *u, double *yr,
                           double *yc)
{
    int n = s->n;
    for (int k = 0; k < s->mr; k++)
        for (int j = 0; j < n; j++) {
            double *y = &yr[(size_t)k * n + j];
            *y = lv->ar[k] * *y + lv->br[k] * (x[j] + u[j]);
        }
    for (int k = 0; k < s->mc; k++) {
        double are = lv->ac[2 * k], aim = lv->ac[2 * k + 1], bre = lv->bc[2 * k], bim = lv->bc[2 * k + 1];
        for (int j = 0; j < n; j++) {
            double *y = &yc[((size_t)k * n + j) * 2];
            double wj = x[j] + u[j], yre = y[0], yim = y[1];
            y[0] = (are * yre - aim * yim) + bre * wj;
            y[1] = (are * yim + aim * yre) + bim * wj;
        }
    }
}

void up_soil_commit(UpSoil *s, int lev, const double *x, const double *xd, const double *f)
{
    int n = s->n;
    double w = 0.0;
    for (int i = 0; i < n; i++)
        w += (x[i] - s->u[i]) * (0.5 * (f[i] + s->f[i]));
    *s->work += w;
    if (s->corr && s->corr->mode)
        corr_commit(s, lev, x);
    advance_states(s, &s->lev[lev], x, s->u, s->yr, s->yc);
    memcpy(s->u, x, (size_t)n * sizeof(double));
    memcpy(s->ud, xd, (size_t)n * sizeof(double));
    memcpy(s->f, f, (size_t)n * sizeof(double));
}

/* g = a y' with y' = a y + b u: the stacked history input of the step after next when a zero state
   is committed next (the pole states after that commit, then their history with a zero input), in
   one pass over the pole states y (the same operations as advance_states then stack with zero
   states: the terms b 0 are left out, an exact zero added) */
static void stack_ahead(const UpSoil *s, const UpSoilLevel *lv, const double *yr, const double *yc,
                        const double *u, double *g)
{
    int n = s->n;
    for (int k = 0; k < s->mr; k++)
        for (int j = 0; j < n; j++) {
            size_t q = (size_t)k * n + j;
            g[q] = lv->ar[k] * (lv->ar[k] * yr[q] + lv->br[k] * u[j]);
        }
    double *gc = g + (size_t)s->mr * n;
    for (int k = 0; k < s->mc; k++) {
        double are = lv->ac[2 * k], aim = lv->ac[2 * k + 1], bre = lv->bc[2 * k], bim = lv->bc[2 * k + 1];
        for (int j = 0; j < n; j++) {
            size_t q = ((size_t)k * n + j) * 2;
            double yre = yc[q], yim = yc[q + 1];
            double are1 = (are * yre - aim * yim) + bre * u[j], aim1 = (are * yim + aim * yre) + bim * u[j];
            gc[q] = are * are1 - aim * aim1;
            gc[q + 1] = are * aim1 + aim * are1;
        }
    }
}

void up_soil_ahead(UpSoil *s, int lev, double *g)
{
    /* committing a zero state: y' = a y + b u, then the history of y' with u' = 0 */
    stack_ahead(s, &s->lev[lev], s->yr, s->yc, s->u, s->g);
    history_product(s, s->g, g);
}

/* A soil stepped alone whose poles are all real and whose history is held as packed blocks (a fit's
   reciprocal residues, not compressed): see up_soil_step */
static int real_packed(const UpSoil *s)
{
    return s->Hs && !s->hm_perm && s->mc == 0;
}

/* real_packed: from the pole states and input of the commit just made, the history of the next commit
   h = sum_k P_k and the history published for the step after next g = sum_k a_k P_k, with P_k = R_k
   (a_k y_k + b_k u) the block products (each into its part, the parts summed in the blocks' order) */
static void next_histories(UpSoil *s, int lev, double *h, double *g)
{
    const UpSoilLevel *lv = &s->lev[lev];
    int n = s->n, nb = s->mr;
    size_t packed = (size_t)n * (n + 1) / 2;
    stack(s, lv, s->yr, s->yc, s->u, s->g);
    s->flip = !s->flip;
    memset(s->part, 0, s->L * sizeof(double));
    for (int q = 0; q < nb; q++) {
        int b = s->flip ? nb - 1 - q : q;
        up_spmv_add(s->Hs + (size_t)b * packed, n, s->g + (size_t)b * n, s->part + (size_t)b * n);
    }
    memset(h, 0, (size_t)n * sizeof(double));
    memset(g, 0, (size_t)n * sizeof(double));
    for (int b = 0; b < nb; b++) {
        up_axpy(1.0, s->part + (size_t)b * n, n, h);
        up_axpy(lv->ar[b], s->part + (size_t)b * n, n, g);
    }
}

void up_soil_step(UpSoil *s, int lev, const double *x, const double *xd, double *g)
{
    /* h_n for the commit of x = u_n: g_n + Gx u_{n-1} (gq: g_n, published two steps before); then E x'_n,
       the work of E x' + h over the step; then g_{n+2} (gp, published). D0 x, the force and the total
       work wait until they are read (up_soil_outputs). With real poles only and packed blocks
       (real_packed), the commit before left h_n itself in gq, from the block products that gave the
       g it published (next_histories): no product with Gx, one packed n x n product a step less; the
       history published differs from the other way's by round-off (a_k R_k v against R_k (a_k v)) */
    int n = s->n, real = real_packed(s);
    double *h = s->fbuf + n, *ev = s->fbuf + 2 * (size_t)n;
    if (real) {
        memcpy(h, s->gq, (size_t)n * sizeof(double));
    } else {
        up_symv(s->Gx, s->Gxp, n, s->u, h);
        for (int i = 0; i < n; i++)
            h[i] = s->gq[i] + h[i];
    }
    up_symv(s->E, s->Ep, n, xd, ev);
    double w = 0.0;
    for (int i = 0; i < n; i++)
        w += (x[i] - s->u[i]) * (0.5 * ((ev[i] + h[i]) + (s->ev[i] + s->hn[i])));
    *s->work += w;
    advance_states(s, &s->lev[lev], x, s->u, s->yr, s->yc);
    memcpy(s->u, x, (size_t)n * sizeof(double));
    memcpy(s->ud, xd, (size_t)n * sizeof(double));
    memcpy(s->ev, ev, (size_t)n * sizeof(double));
    memcpy(s->hn, h, (size_t)n * sizeof(double));
    *s->stale = 1.0;
    if (real) {
        next_histories(s, lev, s->gq, s->gp);
    } else {
        memcpy(s->gq, s->gp, (size_t)n * sizeof(double));
        up_soil_ahead(s, lev, s->gp);
    }
    memcpy(g, s->gp, (size_t)n * sizeof(double));
}

void up_soil_outputs(UpSoil *s, int lev, double *f, double *work)
{
    /* f = (D0 u + E u') + h as up_soil_force; the work: that of E u' + h plus u . D0 u / 2 */
    int n = s->n;
    double *Dx = s->fbuf + 3 * (size_t)n;
    up_symv(s->lev[lev].D0, s->lev[lev].D0p, n, s->u, Dx);
    double e = 0.0;
    for (int i = 0; i < n; i++) {
        f[i] = (Dx[i] + s->ev[i]) + s->hn[i];
        e += s->u[i] * Dx[i];
    }
    *work = *s->work + 0.5 * e;
    *s->stale = 0.0;
}

/* ---- the correction form of repeated runs (the time-frequency route's marches) ---------------

   The defect correction (orchestrator/timefreq/march.py) marches the same causal stand-in again
   and again from rest, each march with another source; from one march to the next the contact
   history x changes less and less (by the residual's size). In the correction form a march takes
   its history as the last march's (recorded per sample, float64) plus the history of the change
   dx = x - x_last, through single-precision copies of the packed blocks (half the memory traffic
   of the product, which bounds a step): h_k = h_last_k + H32 g(dy, du), dy the pole states of dx
   (float64, the same recursion as the soil's own). Its rounding error is relative to the change,
   not to x; what is summed is recorded in turn, so the history a march steps is the first march's
   plus the single-precision histories of every change since. The first march is either float64
   recording itself (mode 1) or the change from a run at rest (mode 3: its whole history in single
   precision, an error of ~1e-7 of it that every later march inherits unchanged: a fixed offset of
   the stand-in, which the defect correction's source absorbs). The marches' fixed point is the
   route's whole-range residual's (float64): the form changes what the sweeps cost, not the answer.
   Only at the full step (level 0): a halved step marks the run broken (its later steps take the
   float64 product of the soil's own states, and the run is not a record: the host's next run
   starts again in mode 3 or 1). */


/* y += P x for a symmetric (n, n) P packed by rows, in single precision: up_spmv_add_k's loops and
   sums (the same order at every vector width) on floats */
HM_BODY void spmv32_add_k(const float *restrict P, int n, const float *restrict x, float *restrict y)
{
    int i = 0;
    for (; i + 4 <= n; i += 4) {
        int len = n - i;
        const float *r0 = P, *r1 = r0 + len, *r2 = r1 + len - 1, *r3 = r2 + len - 2;
        float x0 = x[i], x1 = x[i + 1], x2 = x[i + 2], x3 = x[i + 3];
        float d0 = ((r0[0] * x0 + r0[1] * x1) + r0[2] * x2) + r0[3] * x3;
        float d1 = (r1[0] * x1 + r1[1] * x2) + r1[2] * x3;
        float d2 = r2[0] * x2 + r2[1] * x3;
        float d3 = r3[0] * x3;
        float y1 = y[i + 1] + x0 * r0[1];
        float y2 = (y[i + 2] + x0 * r0[2]) + x1 * r1[1];
        float y3 = ((y[i + 3] + x0 * r0[3]) + x1 * r1[2]) + x2 * r2[1];
        const float *restrict a0 = r0 + 4, *restrict a1 = r1 + 3, *restrict a2 = r2 + 2, *restrict a3 = r3 + 1;
        const float *restrict xr = x + i + 4;
        float *restrict yr = y + i + 4;
        float s0[8] = {0.0f}, s1[8] = {0.0f}, s2[8] = {0.0f}, s3[8] = {0.0f};
        int m = len - 4, j = 0;
        for (; j + 8 <= m; j += 8)
            for (int k = 0; k < 8; k++) {
                float xv = xr[j + k], v0 = a0[j + k], v1 = a1[j + k], v2 = a2[j + k], v3 = a3[j + k];
                s0[k] += v0 * xv;
                s1[k] += v1 * xv;
                s2[k] += v2 * xv;
                s3[k] += v3 * xv;
                float t = yr[j + k];
                t += x0 * v0;
                t += x1 * v1;
                t += x2 * v2;
                t += x3 * v3;
                yr[j + k] = t;
            }
        for (; j < m; j++) {
            float xv = xr[j], v0 = a0[j], v1 = a1[j], v2 = a2[j], v3 = a3[j];
            s0[0] += v0 * xv;
            s1[0] += v1 * xv;
            s2[0] += v2 * xv;
            s3[0] += v3 * xv;
            float t = yr[j];
            t += x0 * v0;
            t += x1 * v1;
            t += x2 * v2;
            t += x3 * v3;
            yr[j] = t;
        }
        y[i] += d0 + (((s0[0] + s0[1]) + (s0[2] + s0[3])) + ((s0[4] + s0[5]) + (s0[6] + s0[7])));
        y[i + 1] = y1 + (d1 + (((s1[0] + s1[1]) + (s1[2] + s1[3])) + ((s1[4] + s1[5]) + (s1[6] + s1[7]))));
        y[i + 2] = y2 + (d2 + (((s2[0] + s2[1]) + (s2[2] + s2[3])) + ((s2[4] + s2[5]) + (s2[6] + s2[7]))));
        y[i + 3] = y3 + (d3 + (((s3[0] + s3[1]) + (s3[2] + s3[3])) + ((s3[4] + s3[5]) + (s3[6] + s3[7]))));
        P = r3 + len - 3;
    }
    for (; i < n; i++) {
        int len = n - i;
        float xi = x[i], d = 0.0f;
        for (int j = 0; j < len; j++)
            d += P[j] * x[i + j];
        y[i] += d;
        for (int j = 1; j < len; j++)
            y[i + j] += xi * P[j];
        P += len;
    }
}

#ifdef HM_DISPATCH
__attribute__((target("avx512f"))) static void spmv32_add_avx512(const float *P, int n, const float *x, float *y)
{
    spmv32_add_k(P, n, x, y);
}
__attribute__((target("avx2"))) static void spmv32_add_avx2(const float *P, int n, const float *x, float *y)
{
    spmv32_add_k(P, n, x, y);
}
#endif

static void spmv32_add(const float *P, int n, const float *x, float *y)
{
#ifdef HM_DISPATCH
    int level = up_vector_level();
    if (level == 2) {
        spmv32_add_avx512(P, n, x, y);
        return;
    }
    if (level == 1) {
        spmv32_add_avx2(P, n, x, y);
        return;
    }
#endif
    spmv32_add_k(P, n, x, y);
}

static void corr_free(struct UpSoilCorr *c)
{
    if (!c)
        return;
    free(c->Hs32);
    free(c->g32);
    free(c->hrec);
    free(c->dy);
    free(c);
}

int up_soil_corr_mode(UpSoil *s, int64_t nt, int mode)
{
    struct UpSoilCorr *c = s->corr;
    if (mode == 0) {
        if (c)
            c->mode = 0;
        return 0;
    }
    if (!s->Hs || s->hm_perm || nt < 1 || mode < 0 || mode > 3)
        return -1;                                    /* not packed symmetric: no correction form */
    int n = s->n, nb = s->mr + 2 * s->mc;
    size_t packed = (size_t)n * (n + 1) / 2;
    if (!c) {
        if (!(c = (struct UpSoilCorr *)calloc(1, sizeof *c)))
            return -1;
        c->Hs32 = (float *)malloc((nb * packed + 1) * sizeof(float));
        c->g32 = (float *)malloc((2 * s->L + 1) * sizeof(float));
        c->dy = (double *)malloc((2 * s->L + 2 * (size_t)n + 1) * sizeof(double));
        if (!c->Hs32 || !c->g32 || !c->dy) {
            corr_free(c);
            return -1;
        }
        for (size_t q = 0; q < nb * packed; q++)
            c->Hs32[q] = (float)s->Hs[q];
        c->part32 = c->g32 + s->L;
        c->gd = c->dy + s->L;
        c->du = c->gd + s->L;
        c->dx = c->du + n;
        s->corr = c;
    }
    if (c->nt != nt) {
        free(c->hrec);
        c->hrec = (double *)malloc((2 * (size_t)nt * n + 1) * sizeof(double));
        if (!c->hrec) {
            c->nt = c->recorded = 0;
            c->mode = 0;
            return -1;
        }
        c->urec = c->hrec + (size_t)nt * n;
        c->nt = nt;
        c->recorded = 0;
    }
    if (mode == 2 && c->recorded != nt)
        return -1;                                    /* no whole run recorded to correct */
    if (mode == 3) {                                  /* the change from a run at rest: x itself */
        memset(c->hrec, 0, 2 * (size_t)nt * n * sizeof(double));
        mode = 2;
    }
    c->mode = mode;
    c->broken = 0;
    c->k = 0;
    c->recorded = 0;                                  /* the records are this run's from now on */
    memset(c->dy, 0, s->L * sizeof(double));
    memset(c->du, 0, (size_t)n * sizeof(double));
    return mode;
}

void up_soil_corr_sample(UpSoil *s, int64_t k)
{
    struct UpSoilCorr *c = s->corr;
    if (!c || !c->mode)
        return;
    c->k = k;
}

int up_soil_corr_broken(const UpSoil *s)
{
    return s->corr && s->corr->mode && s->corr->broken;
}

/* the history h (n) of the step to sample c->k: the last run's plus H32 g(dy, du) (mode 2), recorded */
static void corr_history(UpSoil *s, int lev, double *h)
{
    struct UpSoilCorr *c = s->corr;
    int n = s->n, nb = s->mr + 2 * s->mc;
    int in = lev == 0 && c->k > 0 && c->k < c->nt;
    if (!in)
        c->broken = 1;
    if (c->mode == 1 || c->broken) {
        stack(s, &s->lev[lev], s->yr, s->yc, s->u, s->g);
        history_product(s, s->g, h);
    } else {
        size_t packed = (size_t)n * (n + 1) / 2;
        const double *hl = c->hrec + (size_t)c->k * n;
        stack(s, &s->lev[0], c->dy, c->dy + (size_t)s->mr * n, c->du, c->gd);
        for (int b = 0; b < nb; b++) {                /* each block's input as floats, in g32's block order */
            const double *gb = block_input(s, c->gd, b, s->fbuf + 3 * (size_t)n);
            float *xb = c->g32 + (size_t)b * n;
            for (int j = 0; j < n; j++)
                xb[j] = (float)gb[j];
        }
        memset(c->part32, 0, s->L * sizeof(float));
        for (int b = 0; b < nb; b++)
            spmv32_add(c->Hs32 + (size_t)b * packed, n, c->g32 + (size_t)b * n, c->part32 + (size_t)b * n);
        for (int i = 0; i < n; i++) {
            double d = 0.0;
            for (int b = 0; b < nb; b++)
                d += (double)c->part32[(size_t)b * n + i];
            h[i] = hl[i] + d;
        }
    }
    if (in)
        memcpy(c->hrec + (size_t)c->k * n, h, (size_t)n * sizeof(double));
}

/* before the soil's commit of x (s->u still the last state): the change's states advanced (mode 2),
   x recorded */
static void corr_commit(UpSoil *s, int lev, const double *x)
{
    struct UpSoilCorr *c = s->corr;
    int n = s->n;
    if (lev != 0 || c->k <= 0 || c->k >= c->nt) {
        c->broken = 1;
        return;
    }
    double *ul = c->urec + (size_t)c->k * n;
    if (c->mode == 2 && !c->broken) {
        double *dx = c->dx;
        for (int i = 0; i < n; i++)
            dx[i] = x[i] - ul[i];
        advance_states(s, &s->lev[0], dx, c->du, c->dy, c->dy + (size_t)s->mr * n);
        memcpy(c->du, dx, (size_t)n * sizeof(double));
    }
    memcpy(ul, x, (size_t)n * sizeof(double));
    if (c->k == c->nt - 1 && !c->broken)
        c->recorded = c->nt;                          /* a whole run recorded, no step halved */
}

/* Dense linear algebra at the sizes of the model (a few hundred unknowns): LU with partial
   pivoting (as LAPACK getrf: row interchanges recorded as swaps), solves, products. Row-major;
   the inner loops run along rows, contiguous in memory. */
#include <math.h>
#include <stdlib.h>

#include "uplift.h"

/* Right-looking LU by panels of LU_BLOCK columns: the panel is factorised column by column
   (pivot search, full-row swaps), then the rows of U to its right and the trailing block are
   updated panel-wise, so a trailing row stays in cache while the panel's rows are applied to
   it. Every entry sees the same operations in the same order as the column-by-column
   algorithm (the same result, bit for bit); only the memory traffic changes. */
#define LU_BLOCK 32

/* The hot loops (the history product, the LU's trailing update) run along contiguous rows with
   no reduction, or with eight fixed partial sums, so the compiler vectorises them without
   reassociating anything: the result is the same at every vector width. Baseline x86-64 code
   (SSE2) for every machine; on x86-64 with GCC or clang (zig cc), AVX2 and AVX-512 versions of
   each kernel too, and the widest one the CPU and the OS support is called (cpuid, xgetbv: our
   own test, as the compiler runtime's is not reliable everywhere: zig's reports no feature, so
   target_clones ran the baseline). */
#if defined(__x86_64__) && defined(__GNUC__) && !defined(UP_BASELINE_ONLY)
#define UP_DISPATCH 1
#include <cpuid.h>
#define UP_BODY static inline __attribute__((always_inline))
#else
#define UP_BODY static inline
#endif

#ifdef UP_DISPATCH
/* 2: AVX-512F, 1: AVX2, 0: SSE2 only (each with its register state enabled by the OS) */
static int cpu_detect(void)
{
    unsigned a, b, c, d, lo, hi;
    if (!__get_cpuid(1, &a, &b, &c, &d) || !(c & (1u << 27)) || !(c & (1u << 28)))   /* OSXSAVE, AVX */
        return 0;
    __asm__ volatile("xgetbv" : "=a"(lo), "=d"(hi) : "c"(0));
    if ((lo & 6u) != 6u || __get_cpuid_max(0, NULL) < 7)                              /* XMM, YMM state */
        return 0;
    __cpuid_count(7, 0, a, b, c, d);
    if (!(b & (1u << 5)))                                                             /* AVX2 */
        return 0;
    return (b & (1u << 16)) && (lo & 0xE6u) == 0xE6u ? 2 : 1;     /* AVX-512F, opmask and ZMM state */
}

#ifndef UP_MAX_LEVEL
#define UP_MAX_LEVEL 2      /* -DUP_MAX_LEVEL=1: at most AVX2 (the tests compare every width) */
#endif

/* detected on first use; threads that race here write the same value */
static int cpu_level(void)
{
    static int level = -1;
    if (level < 0) {
        int l = cpu_detect();
        level = l < UP_MAX_LEVEL ? l : UP_MAX_LEVEL;
    }
    return level;
}

/* the kernel name##_k (UP_BODY, inlined into each) compiled for AVX-512, AVX2 and the baseline,
   and the function name calling the one for this CPU */
#define UP_KERNEL(name, params, args)                                                              \
    __attribute__((target("avx512f"))) static void name##_avx512 params { name##_k args; }         \
    __attribute__((target("avx2"))) static void name##_avx2 params { name##_k args; }              \
    static void name##_sse2 params { name##_k args; }                                              \
    void name params                                                                               \
    {                                                                                              \
        int level = cpu_level();                                                                   \
        if (level == 2)                                                                            \
            name##_avx512 args;                                                                    \
        else if (level == 1)                                                                       \
            name##_avx2 args;                                                                      \
        else                                                                                       \
            name##_sse2 args;                                                                      \
    }
/* the same, the dispatching function static (this file's own) */
#define UP_KERNEL_STATIC(name, params, args)                                                       \
    __attribute__((target("avx512f"))) static void name##_avx512 params { name##_k args; }         \
    __attribute__((target("avx2"))) static void name##_avx2 params { name##_k args; }              \
    static void name##_sse2 params { name##_k args; }                                              \
    static void name params                                                                        \
    {                                                                                              \
        int level = cpu_level();                                                                   \
        if (level == 2)                                                                            \
            name##_avx512 args;                                                                    \
        else if (level == 1)                                                                       \
            name##_avx2 args;                                                                      \
        else                                                                                       \
            name##_sse2 args;                                                                      \
    }
#define UP_KERNEL_INT(name, params, args)                                                          \
    __attribute__((target("avx512f"))) static int name##_avx512 params { return name##_k args; }  \
    __attribute__((target("avx2"))) static int name##_avx2 params { return name##_k args; }       \
    static int name##_sse2 params { return name##_k args; }                                       \
    int name params                                                                                \
    {                                                                                              \
        int level = cpu_level();                                                                   \
        return level == 2 ? name##_avx512 args : level == 1 ? name##_avx2 args : name##_sse2 args; \
    }
#else
#define UP_KERNEL(name, params, args) void name params { name##_k args; }
#define UP_KERNEL_INT(name, params, args) int name params { return name##_k args; }
#define UP_KERNEL_STATIC(name, params, args) static void name params { name##_k args; }
#endif

/* the vector width the kernels run at: 2 AVX-512, 1 AVX2, 0 the baseline (SSE2 on x86-64) */
int up_vector_level(void)
{
#ifdef UP_DISPATCH
    return cpu_level();
#else
    return 0;
#endif
}

/* eight partial sums folded, the same at every width */
UP_BODY double fold8(const double *s)
{
    return ((s[0] + s[1]) + (s[2] + s[3])) + ((s[4] + s[5]) + (s[6] + s[7]));
}

/* bi[j] -= sum_p coef[p] B[p ld + j] (j < k) for p0 <= p < p1, the rows of B four at a time and
   in their order along the k entries (no reduction): an entry stays in a register through four
   updates. The LU's trailing update and the substitutions of many right-hand sides. */
UP_BODY void rows_update(double *restrict bi, const double *B, int ld, const double *coef, int p0, int p1, int k)
{
    int p = p0;
    for (; p + 4 <= p1; p += 4) {
        const double *restrict b0 = B + (size_t)p * ld, *restrict b1 = b0 + ld, *restrict b2 = b1 + ld,
                     *restrict b3 = b2 + ld;
        double l0 = coef[p], l1 = coef[p + 1], l2 = coef[p + 2], l3 = coef[p + 3];
        for (int j = 0; j < k; j++) {
            double t = bi[j];
            t -= l0 * b0[j];
            t -= l1 * b1[j];
            t -= l2 * b2[j];
            t -= l3 * b3[j];
            bi[j] = t;
        }
    }
    for (; p < p1; p++) {
        const double *restrict bp = B + (size_t)p * ld;
        double l = coef[p];
        for (int j = 0; j < k; j++)
            bi[j] -= l * bp[j];
    }
}

/* a . b with eight partial sums: independent chains in vector registers (two of four, or one of
   eight lanes), the same sums at every width; inlined into the loops that call it */
UP_BODY double dot(const double *restrict a, const double *restrict b, int n)
{
    double s[8] = {0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0};
    int i = 0;
    for (; i + 8 <= n; i += 8)
        for (int k = 0; k < 8; k++)
            s[k] += a[i + k] * b[i + k];
    for (; i < n; i++)
        s[0] += a[i] * b[i];
    return fold8(s);
}

UP_BODY int up_lu_k(double *A, int *piv, int n)
{
    for (int k0 = 0; k0 < n; k0 += LU_BLOCK) {
        int k1 = k0 + LU_BLOCK < n ? k0 + LU_BLOCK : n;
        for (int k = k0; k < k1; k++) {
            int p = k;
            double best = fabs(A[(size_t)k * n + k]);
            for (int i = k + 1; i < n; i++) {
                double v = fabs(A[(size_t)i * n + k]);
                if (v > best) {
                    best = v;
                    p = i;
                }
            }
            piv[k] = p;
            if (!(best > 0.0) || !isfinite(best))
                return k + 1;
            if (p != k) {
                double *rk = A + (size_t)k * n, *rp = A + (size_t)p * n;
                for (int j = 0; j < n; j++) {
                    double t = rk[j];
                    rk[j] = rp[j];
                    rp[j] = t;
                }
            }
            const double *rk = A + (size_t)k * n;
            double inv = 1.0 / rk[k];
            for (int i = k + 1; i < n; i++) {
                double *ri = A + (size_t)i * n;
                double l = ri[k] * inv;
                ri[k] = l;
                if (l != 0.0)
                    for (int j = k + 1; j < k1; j++)
                        ri[j] -= l * rk[j];
            }
        }
        /* the rows of U right of the panel, then the trailing block, by the panel's rows (four
           at a time: an entry stays in a register through four updates, in their order) */
        for (int i = k0 + 1; i < n; i++) {
            double *restrict ri = A + (size_t)i * n;
            rows_update(ri + k1, A + k1, n, ri, k0, i < k1 ? i : k1, n - k1);
        }
    }
    return 0;
}
UP_KERNEL_INT(up_lu, (double *A, int *piv, int n), (A, piv, n))

UP_BODY void up_lu_solve_k(const double *LU, const int *piv, int n, double *b)
{
    for (int k = 0; k < n; k++)
        if (piv[k] != k) {
            double t = b[k];
            b[k] = b[piv[k]];
            b[piv[k]] = t;
        }
    for (int i = 1; i < n; i++)
        b[i] -= dot(LU + (size_t)i * n, b, i);
    for (int i = n - 1; i >= 0; i--) {
        const double *ri = LU + (size_t)i * n;
        b[i] = (b[i] - dot(ri + i + 1, b + i + 1, n - i - 1)) / ri[i];
    }
}
UP_KERNEL(up_lu_solve, (const double *LU, const int *piv, int n, double *b), (LU, piv, n, b))

/* B (n, k) <- L^-1 B, L the unit lower triangle of LU. ident: B is the identity, whose row i keeps
   its entries from column i on (L^-1 is lower triangular: the updates there subtract exact zeros,
   which leave every bit as it is), so only its first i columns are updated. */
UP_BODY void forward_many(const double *LU, int n, double *B, int k, int ident)
{
    for (int i = 1; i < n; i++)
        rows_update(B + (size_t)i * k, B, k, LU + (size_t)i * n, 0, i, ident ? i : k);
}

UP_BODY void backward_many(const double *LU, int n, double *B, int k)
{
    for (int i = n - 1; i >= 0; i--) {
        double *bi = B + (size_t)i * k, d = LU[(size_t)i * n + i];
        rows_update(bi, B, k, LU + (size_t)i * n, i + 1, n, k);
        for (int j = 0; j < k; j++)
            bi[j] /= d;
    }
}

UP_BODY void up_lu_solve_many_k(const double *LU, const int *piv, int n, double *B, int k)
{
    for (int i = 0; i < n; i++)
        if (piv[i] != i) {
            double *a = B + (size_t)i * k, *b = B + (size_t)piv[i] * k;
            for (int j = 0; j < k; j++) {
                double t = a[j];
                a[j] = b[j];
                b[j] = t;
            }
        }
    forward_many(LU, n, B, k, 0);
    backward_many(LU, n, B, k);
}
UP_KERNEL(up_lu_solve_many, (const double *LU, const int *piv, int n, double *B, int k), (LU, piv, n, B, k))

/* inv <- A^-1 (n, n) from the LU of A (up_lu). With P not NULL (A symmetric), inv is made
   symmetric, (inv + inv^T) / 2, and packed into P (up_pack_sym): the round-off of the solves is
   the only asymmetry. */
UP_BODY void inverse_k(const double *LU, const int *piv, int n, double *inv)
{
    for (int i = 0; i < n; i++)
        for (int j = 0; j < n; j++)
            inv[(size_t)i * n + j] = i == j ? 1.0 : 0.0;
    forward_many(LU, n, inv, n, 1);
    backward_many(LU, n, inv, n);
    for (int i = n - 1; i >= 0; i--)                      /* A^-1 = U^-1 L^-1 P: the swaps on the columns */
        if (piv[i] != i)
            for (int r = 0; r < n; r++) {
                double *row = inv + (size_t)r * n, t = row[i];
                row[i] = row[piv[i]];
                row[piv[i]] = t;
            }
}
UP_KERNEL_STATIC(inverse, (const double *LU, const int *piv, int n, double *inv), (LU, piv, n, inv))

/* inv <- A^-1 (n, n) from the LU of A (up_lu): U^-1 L^-1 of the identity, its columns then swapped
   as the LU swapped the rows. Each column of U^-1 L^-1 is solved alone, in the operations
   up_lu_solve_many takes on it, so inv is the same bits as up_lu_solve_many of the identity (its
   rows swapped first), at 5/6 of its work. With P not NULL (A symmetric), inv is made
   symmetric, (inv + inv^T) / 2, and packed into P (up_pack_sym): the round-off of the solves is
   the only asymmetry. */
void up_inverse(const double *LU, const int *piv, int n, double *inv, double *P)
{
    inverse(LU, piv, n, inv);
    if (P)
        up_symmetrise_pack(inv, n, P);
}

/* A <- (A + A^T) / 2 (n, n), then packed into P (up_pack_sym): an inverse whose only asymmetry is
   the round-off of its solves */
void up_symmetrise_pack(double *A, int n, double *P)
{
    for (int i = 0; i < n; i++)
        for (int j = i + 1; j < n; j++) {
            double m = 0.5 * (A[(size_t)i * n + j] + A[(size_t)j * n + i]);
            A[(size_t)i * n + j] = A[(size_t)j * n + i] = m;
        }
    up_pack_sym(A, n, P);
}

UP_BODY void up_matvec_k(const double *A, int rows, int cols, const double *x, double *y)
{
    for (int i = 0; i < rows; i++)
        y[i] = dot(A + (size_t)i * cols, x, cols);
}
UP_KERNEL(up_matvec, (const double *A, int rows, int cols, const double *x, double *y), (A, rows, cols, x, y))

UP_BODY void up_matvec_ld_k(const double *A, int rows, int cols, int lda, const double *x, double *y)
{
    for (int i = 0; i < rows; i++)
        y[i] = dot(A + (size_t)i * lda, x, cols);
}
UP_KERNEL(up_matvec_ld, (const double *A, int rows, int cols, int lda, const double *x, double *y),
          (A, rows, cols, lda, x, y))

int up_sparse_init(UpSparse *S, const double *A, int rows, int cols)
{
    int nnz = 0;
    for (size_t i = 0; i < (size_t)rows * cols; i++)
        nnz += A[i] != 0.0;
    S->rows = rows;
    S->ptr = (int *)malloc(((size_t)rows + 1) * sizeof(int));
    S->col = (int *)malloc(((size_t)nnz + 1) * sizeof(int));
    S->val = (double *)malloc(((size_t)nnz + 1) * sizeof(double));
    if (!S->ptr || !S->col || !S->val)
        return -1;
    int q = 0;
    for (int i = 0; i < rows; i++) {
        S->ptr[i] = q;
        for (int j = 0; j < cols; j++)
            if (A[(size_t)i * cols + j] != 0.0) {
                S->col[q] = j;
                S->val[q++] = A[(size_t)i * cols + j];
            }
    }
    S->ptr[rows] = q;
    return 0;
}

void up_sparse_free(UpSparse *S)
{
    free(S->ptr);
    free(S->col);
    free(S->val);
    S->ptr = S->col = NULL;
    S->val = NULL;
}

void up_sparse_matvec(const UpSparse *S, const double *x, double *y)
{
    for (int i = 0; i < S->rows; i++) {
        double t = 0.0;
        for (int q = S->ptr[i]; q < S->ptr[i + 1]; q++)
            t += S->val[q] * x[S->col[q]];
        y[i] = t;
    }
}

/* y = At^T x, row by row of At (four at a time: y_i stays in a register through four updates,
   in their order); the inner loop runs along a row, with no reduction, so it vectorises at any
   width with the same result */
UP_BODY void up_gemv_t_k(const double *restrict At, int rows, int cols, const double *restrict x, double *restrict y)
{
    for (int i = 0; i < cols; i++)
        y[i] = 0.0;
    int j = 0;
    for (; j + 4 <= rows; j += 4) {
        const double *restrict r0 = At + (size_t)j * cols, *restrict r1 = r0 + cols, *restrict r2 = r1 + cols,
                     *restrict r3 = r2 + cols;
        double x0 = x[j], x1 = x[j + 1], x2 = x[j + 2], x3 = x[j + 3];
        for (int i = 0; i < cols; i++) {
            double t = y[i];
            t += x0 * r0[i];
            t += x1 * r1[i];
            t += x2 * r2[i];
            t += x3 * r3[i];
            y[i] = t;
        }
    }
    for (; j < rows; j++) {
        const double *restrict r = At + (size_t)j * cols;
        double xj = x[j];
        for (int i = 0; i < cols; i++)
            y[i] += xj * r[i];
    }
}
UP_KERNEL(up_gemv_t, (const double *restrict At, int rows, int cols, const double *restrict x, double *restrict y),
          (At, rows, cols, x, y))

/* y += P x for a symmetric (n, n) matrix held packed: its upper triangle row by row (row i:
   the n - i entries from the diagonal). Each entry is read once and used twice: in the dot
   product of its row (y_i) and in the update of the rows below (y_j += P_ij x_i, j > i), so
   the memory traffic is half a full product's. Four rows in one pass: the 4 x 4 block on the
   diagonal first, then the columns right of it, where each column's four entries update y_j
   in the order of the rows and feed the four rows' dot products (eight partial sums each,
   lanes by the column's offset from the block's edge): four independent sums in flight and
   y_j loaded and stored once per four rows; the remainder rows one by one. The same sums in
   the same order at every vector width. */
UP_BODY void up_spmv_add_k(const double *restrict P, int n, const double *restrict x, double *restrict y)
{
    int i = 0;
    for (; i + 4 <= n; i += 4) {
        int len = n - i;
        const double *r0 = P, *r1 = r0 + len, *r2 = r1 + len - 1, *r3 = r2 + len - 2;  /* r_a[0]: (i+a, i+a) */
        double x0 = x[i], x1 = x[i + 1], x2 = x[i + 2], x3 = x[i + 3];
        double d0 = ((r0[0] * x0 + r0[1] * x1) + r0[2] * x2) + r0[3] * x3;
        double d1 = (r1[0] * x1 + r1[1] * x2) + r1[2] * x3;
        double d2 = r2[0] * x2 + r2[1] * x3;
        double d3 = r3[0] * x3;
        double y1 = y[i + 1] + x0 * r0[1];
        double y2 = (y[i + 2] + x0 * r0[2]) + x1 * r1[1];
        double y3 = ((y[i + 3] + x0 * r0[3]) + x1 * r1[2]) + x2 * r2[1];
        const double *restrict a0 = r0 + 4, *restrict a1 = r1 + 3, *restrict a2 = r2 + 2, *restrict a3 = r3 + 1;
        const double *restrict xr = x + i + 4;
        double *restrict yr = y + i + 4;
        double s0[8] = {0.0}, s1[8] = {0.0}, s2[8] = {0.0}, s3[8] = {0.0};
        int m = len - 4, j = 0;
        for (; j + 8 <= m; j += 8)
            for (int k = 0; k < 8; k++) {
                double xv = xr[j + k], v0 = a0[j + k], v1 = a1[j + k], v2 = a2[j + k], v3 = a3[j + k];
                s0[k] += v0 * xv;
                s1[k] += v1 * xv;
                s2[k] += v2 * xv;
                s3[k] += v3 * xv;
                double t = yr[j + k];
                t += x0 * v0;
                t += x1 * v1;
                t += x2 * v2;
                t += x3 * v3;
                yr[j + k] = t;
            }
        for (; j < m; j++) {
            double xv = xr[j], v0 = a0[j], v1 = a1[j], v2 = a2[j], v3 = a3[j];
            s0[0] += v0 * xv;
            s1[0] += v1 * xv;
            s2[0] += v2 * xv;
            s3[0] += v3 * xv;
            double t = yr[j];
            t += x0 * v0;
            t += x1 * v1;
            t += x2 * v2;
            t += x3 * v3;
            yr[j] = t;
        }
        y[i] += d0 + fold8(s0);
        y[i + 1] = y1 + (d1 + fold8(s1));
        y[i + 2] = y2 + (d2 + fold8(s2));
        y[i + 3] = y3 + (d3 + fold8(s3));
        P = r3 + len - 3;
    }
    for (; i < n; i++) {
        int len = n - i;
        double xi = x[i];
        y[i] += dot(P, x + i, len);
        for (int j = 1; j < len; j++)
            y[i + j] += xi * P[j];
        P += len;
    }
}
UP_KERNEL(up_spmv_add, (const double *restrict P, int n, const double *restrict x, double *restrict y), (P, n, x, y))

/* P <- the upper triangle of A (n, n) packed by rows; 1 when A is symmetric (bit for bit) */
int up_pack_sym(const double *A, int n, double *P)
{
    size_t q = 0;
    for (int i = 0; i < n; i++)
        for (int j = i; j < n; j++) {
            if (A[(size_t)i * n + j] != A[(size_t)j * n + i])
                return 0;
            P[q++] = A[(size_t)i * n + j];
        }
    return 1;
}

/* y = A x: from P (A packed, half the memory traffic) when P is not NULL, else from A */
void up_symv(const double *A, const double *P, int n, const double *x, double *y)
{
    if (!P) {
        up_matvec(A, n, n, x, y);
        return;
    }
    for (int i = 0; i < n; i++)
        y[i] = 0.0;
    up_spmv_add(P, n, x, y);
}

UP_BODY void up_matvec_add_k(const double *A, int rows, int cols, const double *x, double s, double *y)
{
    for (int i = 0; i < rows; i++)
        y[i] += s * dot(A + (size_t)i * cols, x, cols);
}
UP_KERNEL(up_matvec_add, (const double *A, int rows, int cols, const double *x, double s, double *y),
          (A, rows, cols, x, s, y))

UP_BODY void up_axpy_k(double a, const double *restrict x, int n, double *restrict y)
{
    for (int i = 0; i < n; i++)
        y[i] += a * x[i];
}
UP_KERNEL(up_axpy, (double a, const double *restrict x, int n, double *restrict y), (a, x, n, y))

double up_dot(const double *a, const double *b, int n)
{
    return dot(a, b, n);
}

double up_norm(const double *a, int n)
{
    return sqrt(up_dot(a, a, n));
}

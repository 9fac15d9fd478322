/* Dense linear algebra at the sizes of the model (a few hundred unknowns): LU with partial
   pivoting (as LAPACK getrf: row interchanges recorded as swaps), solves, products. Row-major;
   the inner loops run along rows, contiguous in memory. */
#include <math.h>

#include "uplift.h"

/* Right-looking LU by panels of LU_BLOCK columns: the panel is factorised column by column
   (pivot search, full-row swaps), then the rows of U to its right and the trailing block are
   updated panel-wise, so a trailing row stays in cache while the panel's rows are applied to
   it. Every entry sees the same operations in the same order as the column-by-column
   algorithm (the same result, bit for bit); only the memory traffic changes. */
#define LU_BLOCK 32

int up_lu(double *A, int *piv, int n)
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
            int last = i < k1 ? i : k1, p = k0;
            for (; p + 4 <= last; p += 4) {
                const double *restrict r0 = A + (size_t)p * n, *restrict r1 = r0 + n, *restrict r2 = r1 + n,
                             *restrict r3 = r2 + n;
                double l0 = ri[p], l1 = ri[p + 1], l2 = ri[p + 2], l3 = ri[p + 3];
                for (int j = k1; j < n; j++) {
                    double r = ri[j];
                    r -= l0 * r0[j];
                    r -= l1 * r1[j];
                    r -= l2 * r2[j];
                    r -= l3 * r3[j];
                    ri[j] = r;
                }
            }
            for (; p < last; p++) {
                double l = ri[p];
                const double *rp = A + (size_t)p * n;
                for (int j = k1; j < n; j++)
                    ri[j] -= l * rp[j];
            }
        }
    }
    return 0;
}

void up_lu_solve(const double *LU, const int *piv, int n, double *b)
{
    for (int k = 0; k < n; k++)
        if (piv[k] != k) {
            double t = b[k];
            b[k] = b[piv[k]];
            b[piv[k]] = t;
        }
    for (int i = 1; i < n; i++) {
        const double *ri = LU + (size_t)i * n;
        double s = b[i];
        for (int j = 0; j < i; j++)
            s -= ri[j] * b[j];
        b[i] = s;
    }
    for (int i = n - 1; i >= 0; i--) {
        const double *ri = LU + (size_t)i * n;
        double s = b[i];
        for (int j = i + 1; j < n; j++)
            s -= ri[j] * b[j];
        b[i] = s / ri[i];
    }
}

void up_matvec(const double *A, int rows, int cols, const double *x, double *y)
{
    for (int i = 0; i < rows; i++)
        y[i] = up_dot(A + (size_t)i * cols, x, cols);
}

void up_matvec2(const double *A, int rows, int cols, const double *x1, const double *x2, double *y1, double *y2)
{
    for (int i = 0; i < rows; i++) {
        const double *a = A + (size_t)i * cols;
        double s0 = 0.0, s1 = 0.0, t0 = 0.0, t1 = 0.0;
        int j = 0;
        for (; j + 2 <= cols; j += 2) {
            s0 += a[j] * x1[j];
            s1 += a[j + 1] * x1[j + 1];
            t0 += a[j] * x2[j];
            t1 += a[j + 1] * x2[j + 1];
        }
        for (; j < cols; j++) {
            s0 += a[j] * x1[j];
            t0 += a[j] * x2[j];
        }
        y1[i] = s0 + s1;
        y2[i] = t0 + t1;
    }
}

void up_matvec_add(const double *A, int rows, int cols, const double *x, double s, double *y)
{
    for (int i = 0; i < rows; i++)
        y[i] += s * up_dot(A + (size_t)i * cols, x, cols);
}

double up_dot(const double *a, const double *b, int n)
{
    /* four partial sums: independent chains the compiler can keep in vector registers */
    double s0 = 0.0, s1 = 0.0, s2 = 0.0, s3 = 0.0;
    int i = 0;
    for (; i + 4 <= n; i += 4) {
        s0 += a[i] * b[i];
        s1 += a[i + 1] * b[i + 1];
        s2 += a[i + 2] * b[i + 2];
        s3 += a[i + 3] * b[i + 3];
    }
    for (; i < n; i++)
        s0 += a[i] * b[i];
    return (s0 + s1) + (s2 + s3);
}

double up_norm(const double *a, int n)
{
    return sqrt(up_dot(a, a, n));
}

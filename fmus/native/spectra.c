/* Response spectra of acceleration histories by the Nigam-Jennings recurrence: the loop of
   orchestrator/spectra.py's response_spectra (the floor spectra of every results file), the
   same operations in the same order, one oscillator at a time; compiled without contraction
   (-ffp-contract=off), its numbers are those of the numpy loop bit for bit
   (tests/orchestration/test_spectra_native.py). In the in-process library only (not part of the
   FMUs): orchestrator/spectra.py calls it when a run has loaded that library.

   up_response_spectra(nt, m, P, acc, coef, umax, amax)
     acc    (nt, m) the m histories (columns), m/s^2, nt >= 2
     coef   (10, P) per oscillator: the recurrence a11 a12 a21 a22 b0u b1u b0v b1v
            (spectra._coefficients) and the weights cv = 2 zeta omega, cu = omega^2 of the
            absolute acceleration cv v + cu u
     umax   (m, P) out: max over the steps of |u|, m
     amax   (m, P) out: max over the steps of |cv v + cu u|, m/s^2
     A NaN in a history gives NaN maxima for its oscillators, as numpy's maximum does. */
#include <math.h>
#include <stdint.h>

#include "uplift.h"

UP_API void up_response_spectra(int64_t nt, int64_t m, int64_t np_, const double *acc, const double *coef,
                                double *umax, double *amax);

/* the running maximum of numpy's maximum: a NaN stays */
static double up_nanmax(double m, double a)
{
    return (m == m && !(a <= m)) ? a : m;
}

UP_API void up_response_spectra(int64_t nt, int64_t m, int64_t np_, const double *acc, const double *coef,
                                double *umax, double *amax)
{
    for (int64_t j = 0; j < m; j++) {
        for (int64_t k = 0; k < np_; k++) {
            const double a11 = coef[k], a12 = coef[np_ + k], a21 = coef[2 * np_ + k], a22 = coef[3 * np_ + k];
            const double b0u = coef[4 * np_ + k], b1u = coef[5 * np_ + k];
            const double b0v = coef[6 * np_ + k], b1v = coef[7 * np_ + k];
            const double cv = coef[8 * np_ + k], cu = coef[9 * np_ + k];
            double u = 0.0, v = 0.0, um = 0.0, am = 0.0;
            for (int64_t n = 0; n + 1 < nt; n++) {
                const double p0 = -acc[n * m + j], p1 = -acc[(n + 1) * m + j];
                const double un = ((a11 * u + a12 * v) + b0u * p0) + b1u * p1;
                const double vn = ((a22 * v + a21 * u) + b0v * p0) + b1v * p1;
                u = un;
                v = vn;
                um = up_nanmax(um, fabs(u));
                am = up_nanmax(am, fabs(cv * v + cu * u));
            }
            umax[j * np_ + k] = um;
            amax[j * np_ + k] = am;
        }
    }
}

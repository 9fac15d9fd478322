/* Timing of the native soil's history product (fmus/native/soil.c, up_soil_history) alone, for
   benchmarks/soil_step.py --hmatrix: reads a resource file of soil records (dense, or with the
   compressed history's records hm_*), steps the pole states with a fixed input a few times so
   that they are not zero, then times `reps` products. Prints: seconds per product, then the
   product's n values (%.17g) of the last one.

       cc -std=c99 -O3 -ffp-contract=off -Ifmus/native/include benchmarks/soil_history.c \
          fmus/native/soil.c fmus/native/linalg.c fmus/native/resources.c -lm -o soil_history
       ./soil_history model.bin reps */
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include "uplift.h"

static double now(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec + 1e-9 * t.tv_nsec;
}

int main(int argc, char **argv)
{
    char err[UP_MSG];
    UpRes r;
    UpSoil s;
    double dt, nd;
    if (argc < 3 || up_res_load(&r, argv[1], err) || up_res_scalar(&r, "dt", &dt, err)
        || up_res_scalar(&r, "n_dof", &nd, err)) {
        fprintf(stderr, "usage: soil_history model.bin reps (%s)\n", argc < 3 ? "" : err);
        return 2;
    }
    int n = (int)nd, reps = atoi(argv[2]);
    if (up_soil_init(&s, &r, n, 1, 1, err)) {
        fprintf(stderr, "%s\n", err);
        return 1;
    }
    double *state = (double *)calloc(up_soil_state_len(&s) + 1, sizeof(double));
    double *x = (double *)malloc(n * sizeof(double)), *h = (double *)malloc(n * sizeof(double));
    up_soil_bind(&s, state);
    up_soil_rest(&s);
    up_soil_level(&s, 0, dt);
    for (int k = 0; k < 5; k++) {                    /* a deterministic input: pole states not zero */
        for (int i = 0; i < n; i++)
            x[i] = 1e-3 * ((i * 7919 + k * 104729) % 1000 - 500) / 500.0;
        up_soil_history(&s, 0, h);
        up_soil_commit(&s, 0, x, x, h);
    }
    double best = 1e300;
    for (int round = 0; round < 3; round++) {
        double t0 = now();
        for (int k = 0; k < reps; k++)
            up_soil_history(&s, 0, h);
        double t = (now() - t0) / reps;
        best = t < best ? t : best;
    }
    printf("%.9g\n", best);
    for (int i = 0; i < n; i++)
        printf("%.17g\n", h[i]);
    up_soil_free(&s);
    up_res_free(&r);
    free(state);
    free(x);
    free(h);
    return 0;
}

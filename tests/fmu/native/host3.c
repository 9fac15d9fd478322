/* A plain C host for the native uplift FMI 3.0 FMUs (no Python in the process): loads the
   FMU's shared library with dlopen, runs it through the FMI 3.0 calls and prints what it reads.
   Used by tests/fmu/test_fmi3.py; the FMI 3.0 counterpart of host.c (POSIX: dlopen).

   cc -O2 -rdynamic -I<fmpy>/c-code host3.c -o host3 -ldl -lm   (-rdynamic: the counting malloc)

   host3 run DIR LIB TOKEN DT STEPS VR...  the FMU unzipped in DIR, its library LIB: instantiate,
                                           initialise, STEPS steps of DT (the bundled motion),
                                           then print "vr value" for each scalar Float64 VR, the
                                           allocations made inside fmi3DoStep and whether a
                                           Python symbol is loaded
   host3 hostile DIR LIB TOKEN DT VR_IN VR_OUT NOUT VR_N VR_BOOL STAMPED
                                           hostile calls, each printing "case status" (fmi3Status,
                                           or 1/0 for a yes/no case), log messages as "log: ...";
                                           VR_IN a scalar input (STAMPED 1: a time stamp), VR_OUT
                                           an output array of NOUT values, VR_N the structural
                                           parameter N, VR_BOOL internal_motion or -1 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3FunctionTypes.h"
#include "host_common.h"

/* ---- the FMI functions: declared (FN) and loaded (LOAD) from the one list ------------------- */
#define FUNCTIONS(X) X(fmi3InstantiateCoSimulation) X(fmi3InstantiateModelExchange) X(fmi3FreeInstance) \
    X(fmi3EnterInitializationMode) X(fmi3ExitInitializationMode) X(fmi3Terminate) X(fmi3DoStep) X(fmi3GetFloat64) \
    X(fmi3SetFloat64) X(fmi3GetUInt64) X(fmi3SetUInt64) X(fmi3SetBoolean) X(fmi3GetFMUState) X(fmi3SetFMUState) \
    X(fmi3FreeFMUState) X(fmi3SerializedFMUStateSize) X(fmi3SerializeFMUState) X(fmi3DeserializeFMUState) \
    X(fmi3Reset) X(fmi3EnterEventMode) X(fmi3EnterConfigurationMode)
FUNCTIONS(FN)

static void load(const char *path)
{
    open_library(path);
    FUNCTIONS(LOAD)
}

static void logger(fmi3InstanceEnvironment env, fmi3Status status, fmi3String category, fmi3String message)
{
    (void)env, (void)category;
    printf("log: [%d] %s\n", (int)status, message);
}

static fmi3Instance instantiate_in(const char *dir, const char *folder, const char *token, int event_mode)
{
    char path[4096];
    snprintf(path, sizeof path, "%s/%s/", dir, folder);
    return fmi3InstantiateCoSimulation("host", token, path, fmi3False, fmi3True, event_mode, fmi3False, NULL, 0, NULL,
                                       logger, NULL);
}

static fmi3Instance instantiate(const char *dir, const char *token)
{
    return instantiate_in(dir, "resources", token, 0);
}

static int initialise(fmi3Instance c)
{
    return fmi3EnterInitializationMode(c, fmi3False, 0.0, 0.0, fmi3False, 0.0) | fmi3ExitInitializationMode(c);
}

static int step(fmi3Instance c, double t, double dt)
{
    fmi3Boolean event, terminate, early;
    double last;
    return fmi3DoStep(c, t, dt, fmi3True, &event, &terminate, &early, &last);
}

static double get(fmi3Instance c, fmi3ValueReference vr)
{
    double v = NAN;
    fmi3GetFloat64(c, &vr, 1, &v, 1);
    return v;
}

static int run(const char *dir, const char *token, double dt, long steps, int nvr, char **vrs)
{
    fmi3Instance c = instantiate(dir, token);
    if (!c)
        return 4;
    if (initialise(c) != fmi3OK)
        return 5;
    counting = 1;
    for (long k = 0; k < steps; k++)
        if (step(c, k * dt, dt) != fmi3OK) {
            counting = 0;
            printf("step %ld failed\n", k);
            return 6;
        }
    counting = 0;
    for (int i = 0; i < nvr; i++) {
        fmi3ValueReference vr = (fmi3ValueReference)strtoul(vrs[i], NULL, 10);
        printf("%u %.17g\n", vr, get(c, vr));
    }
    printf("allocations in doStep %ld\n", allocations);
    printf("python symbols %d\n", dlsym(RTLD_DEFAULT, "Py_Initialize") != NULL);
    fmi3Terminate(c);
    fmi3FreeInstance(c);
    return 0;
}

#define CASE(name, call) printf("%s %d\n", name, (int)(call))

static int hostile(const char *dir, const char *token, double dt, fmi3ValueReference in, fmi3ValueReference out,
                   size_t nout, fmi3ValueReference vr_n, long vb, int stamped)
{
    CASE("wrong-token", instantiate(dir, "{not-this-one}") != NULL);
    CASE("wrong-folder", instantiate_in(dir, "nowhere", token, 0) != NULL);
    CASE("event-mode", instantiate_in(dir, "resources", token, 1) != NULL);
    CASE("model-exchange", fmi3InstantiateModelExchange("host", token, dir, 0, 1, NULL, logger) != NULL);
    CASE("null-token", instantiate(dir, NULL) != NULL);
    fmi3Instance c = instantiate(dir, token);
    if (!c)
        return 4;
    double v = 0.0, nan = NAN, big = 7 * dt, vals[4096];
    fmi3UInt64 n = 0, n2 = 5;
    fmi3ValueReference bad = 1000000;
    fmi3Boolean f = fmi3False;
    CASE("null-instance-step", step(NULL, 0.0, dt));
    CASE("null-instance-get", fmi3GetFloat64(NULL, &out, 1, vals, nout));
    CASE("before-init", step(c, 0.0, dt));
    CASE("bad-vr", fmi3GetFloat64(c, &bad, 1, &v, 1));
    CASE("null-values", fmi3GetFloat64(c, &out, 1, NULL, nout));
    CASE("short-array", fmi3GetFloat64(c, &out, 1, vals, nout - 1));
    CASE("get-array", fmi3GetFloat64(c, &out, 1, vals, nout));
    CASE("set-output", fmi3SetFloat64(c, &out, 1, vals, nout));
    CASE("get-N", fmi3GetUInt64(c, &vr_n, 1, &n, 1));
    printf("N = %llu\n", (unsigned long long)n);
    CASE("set-N", fmi3SetUInt64(c, &vr_n, 1, &n2, 1));
    CASE("configuration-mode", fmi3EnterConfigurationMode(c));
    CASE("init", initialise(c));
    CASE("event-mode-call", fmi3EnterEventMode(c));
    if (vb >= 0) {
        fmi3ValueReference b = (fmi3ValueReference)vb;
        CASE("set-parameter-after-init", fmi3SetBoolean(c, &b, 1, &f, 1));
    }
    CASE("nan", fmi3SetFloat64(c, &in, 1, &nan, 1) | step(c, 0.0, dt));
    CASE("nan-after", fmi3SetFloat64(c, &in, 1, &v, 1) | step(c, 0.0, dt));
    CASE("skipped-time", step(c, 5 * dt, dt));
    CASE("negative-time", step(c, -dt, dt));
    CASE("nan-time", step(c, nan, dt));
    CASE("wrong-step", step(c, dt, 1.5 * dt));                          /* no multiple of dt */
    if (stamped) {                   /* VR_IN is a time stamp: x_time or g_time */
        double now = dt;
        CASE("stamp", fmi3SetFloat64(c, &in, 1, &big, 1) | step(c, dt, dt));
        CASE("stamp-after", fmi3SetFloat64(c, &in, 1, &now, 1) | step(c, dt, dt));
    }
    fmi3Boolean event, terminate, early;
    double t = NAN;
    fmi3DoStep(c, stamped ? 2 * dt : dt, 0.0, fmi3True, &event, &terminate, &early, &t);   /* a no-op: the time */
    long k0 = lround(t / dt);
    /* roll back through a serialised state: the replay is bit-identical */
    fmi3FMUState s = NULL, s2 = NULL;
    size_t size = 0;
    CASE("get-state", fmi3GetFMUState(c, &s) | fmi3SerializedFMUStateSize(c, s, &size));
    fmi3Byte *bytes = malloc(size);
    CASE("serialize", fmi3SerializeFMUState(c, s, bytes, size));
    double first[10], again[10];
    for (int k = 0; k < 10; k++) {
        double tk = (k0 + k) * dt;
        fmi3SetFloat64(c, &in, 1, &tk, 1);
        step(c, tk, dt);
        fmi3GetFloat64(c, &out, 1, vals, nout);
        first[k] = vals[nout - 1];
    }
    CASE("deserialize", fmi3DeserializeFMUState(c, bytes, size, &s2) | fmi3SetFMUState(c, s2));
    for (int k = 0; k < 10; k++) {
        double tk = (k0 + k) * dt;
        fmi3SetFloat64(c, &in, 1, &tk, 1);
        step(c, tk, dt);
        fmi3GetFloat64(c, &out, 1, vals, nout);
        again[k] = vals[nout - 1];
    }
    CASE("replay-differs", memcmp(first, again, sizeof first) != 0);
    bytes[0] ^= 1;
    fmi3FMUState s3 = NULL;
    CASE("deserialize-damaged", fmi3DeserializeFMUState(c, bytes, size, &s3));
    CASE("deserialize-short", fmi3DeserializeFMUState(c, bytes, size / 2, &s3));
    CASE("set-null-state", fmi3SetFMUState(c, NULL));
    CASE("free-states", fmi3FreeFMUState(c, &s) | fmi3FreeFMUState(c, &s2));
    free(bytes);
    CASE("terminate", fmi3Terminate(c));
    CASE("after-terminate", step(c, (k0 + 10) * dt, dt));
    CASE("reset", fmi3Reset(c) | initialise(c) | step(c, 0.0, dt));
    fmi3FreeInstance(c);
    fmi3FreeInstance(NULL);
    printf("survived 1\n");
    return 0;
}

int main(int argc, char **argv)
{
    if (argc >= 7 && strcmp(argv[1], "run") == 0) {
        load(argv[3]);
        int rc = run(argv[2], argv[4], atof(argv[5]), atol(argv[6]), argc - 7, argv + 7);
        dlclose(lib);
        return rc;
    }
    if (argc == 12 && strcmp(argv[1], "hostile") == 0) {
        load(argv[3]);
        int rc = hostile(argv[2], argv[4], atof(argv[5]), (fmi3ValueReference)atol(argv[6]),
                         (fmi3ValueReference)atol(argv[7]), (size_t)atol(argv[8]), (fmi3ValueReference)atol(argv[9]),
                         atol(argv[10]), atoi(argv[11]));
        dlclose(lib);
        return rc;
    }
    fprintf(stderr, "usage: host3 run DIR LIB TOKEN DT STEPS VR... | host3 hostile DIR LIB TOKEN DT VR_IN VR_OUT "
            "NOUT VR_N VR_BOOL STAMPED\n");
    return 1;
}

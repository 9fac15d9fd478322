/* A plain C host for the native uplift FMUs (no Python in the process): loads the FMU's
   shared library with dlopen, runs it through the FMI 2.0 calls and prints what it reads.
   Used by tests/fmu/test_native_fmu.py; an example of what a tool does with the FMU (POSIX: dlopen).

   cc -O2 -rdynamic -I<fmpy>/c-code host.c -o host -ldl -lm   (-rdynamic: the counting malloc)

   host run DIR LIB GUID DT STEPS VR...   the FMU unzipped in DIR, its library LIB: instantiate,
                                          initialise, STEPS steps of DT (the bundled motion),
                                          then print "vr value" for each Real VR, the
                                          allocations made inside fmi2DoStep and whether a
                                          Python symbol is loaded
   host hostile DIR LIB GUID DT VR_IN VR_OUT VR_BOOL STAMPED
                                          hostile calls, each printing "case status" (fmi2Status,
                                          or 1/0 for a yes/no case), log messages as "log: ...";
                                          VR_IN an input (STAMPED 1: a time stamp, x_time or
                                          g_time), VR_OUT an output, VR_BOOL internal_motion or -1 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2FunctionTypes.h"
#include "host_common.h"

/* ---- the FMI functions: declared (FN) and loaded (LOAD) from the one list ------------------- */
#define FUNCTIONS(X) X(fmi2Instantiate) X(fmi2FreeInstance) X(fmi2SetupExperiment) X(fmi2EnterInitializationMode) \
    X(fmi2ExitInitializationMode) X(fmi2Terminate) X(fmi2DoStep) X(fmi2GetReal) X(fmi2SetReal) X(fmi2SetBoolean) \
    X(fmi2GetFMUstate) X(fmi2SetFMUstate) X(fmi2FreeFMUstate) X(fmi2SerializedFMUstateSize) \
    X(fmi2SerializeFMUstate) X(fmi2DeSerializeFMUstate) X(fmi2GetRealStatus) X(fmi2Reset)
FUNCTIONS(FN)

static void load(const char *path)
{
    open_library(path);
    FUNCTIONS(LOAD)
}

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                   fmi2String message, ...)
{
    (void)env, (void)name, (void)category;
    printf("log: [%d] %s\n", (int)status, message);
}

static const fmi2CallbackFunctions callbacks = {logger, calloc, free, NULL, NULL};

static fmi2Component instantiate(const char *dir, const char *guid)
{
    char uri[4096];
    snprintf(uri, sizeof uri, "file://%s/resources", dir);
    return fmi2Instantiate("host", fmi2CoSimulation, guid, uri, &callbacks, fmi2False, fmi2True);
}

static int initialise(fmi2Component c)
{
    int s = fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0);
    s |= fmi2EnterInitializationMode(c);
    return s | fmi2ExitInitializationMode(c);
}

static double get(fmi2Component c, fmi2ValueReference vr)
{
    double v = NAN;
    fmi2GetReal(c, &vr, 1, &v);
    return v;
}

static int run(const char *dir, const char *guid, double dt, long steps, int nvr, char **vrs)
{
    fmi2Component c = instantiate(dir, guid);
    if (!c)
        return 4;
    if (initialise(c) != fmi2OK)
        return 5;
    counting = 1;
    for (long k = 0; k < steps; k++)
        if (fmi2DoStep(c, k * dt, dt, fmi2True) != fmi2OK) {
            counting = 0;
            printf("step %ld failed\n", k);
            return 6;
        }
    counting = 0;
    for (int i = 0; i < nvr; i++) {
        fmi2ValueReference vr = (fmi2ValueReference)strtoul(vrs[i], NULL, 10);
        printf("%u %.17g\n", vr, get(c, vr));
    }
    printf("allocations in doStep %ld\n", allocations);
    printf("python symbols %d\n", dlsym(RTLD_DEFAULT, "Py_Initialize") != NULL);
    fmi2Terminate(c);
    fmi2FreeInstance(c);
    return 0;
}

#define CASE(name, call) printf("%s %d\n", name, (int)(call))

static int hostile(const char *dir, const char *guid, double dt, fmi2ValueReference in, fmi2ValueReference out,
                   long vb, int stamped)
{
    char uri[4096];
    snprintf(uri, sizeof uri, "file://%s/nowhere", dir);
    CASE("wrong-guid", instantiate(dir, "{not-this-one}") != NULL);
    CASE("wrong-folder", fmi2Instantiate("host", fmi2CoSimulation, guid, uri, &callbacks, 0, 1) != NULL);
    CASE("model-exchange", fmi2Instantiate("host", fmi2ModelExchange, guid, uri, &callbacks, 0, 1) != NULL);
    CASE("null-guid", instantiate(dir, NULL) != NULL);
    fmi2Component c = instantiate(dir, guid);
    if (!c)
        return 4;
    double v = 0.0, nan = NAN, big = 7 * dt;
    fmi2ValueReference bad = 1000000;
    fmi2Boolean f = fmi2False;
    CASE("null-instance-step", fmi2DoStep(NULL, 0.0, dt, 1));
    CASE("null-instance-get", fmi2GetReal(NULL, &out, 1, &v));
    CASE("before-init", fmi2DoStep(c, 0.0, dt, 1));
    CASE("bad-vr", fmi2GetReal(c, &bad, 1, &v));
    CASE("null-values", fmi2GetReal(c, &out, 1, NULL));
    CASE("set-output", fmi2SetReal(c, &out, 1, &v));
    CASE("init", initialise(c));
    if (vb >= 0) {
        fmi2ValueReference b = (fmi2ValueReference)vb;
        CASE("set-parameter-after-init", fmi2SetBoolean(c, &b, 1, &f));
    }
    CASE("nan", fmi2SetReal(c, &in, 1, &nan) | fmi2DoStep(c, 0.0, dt, 1));
    CASE("nan-after", fmi2SetReal(c, &in, 1, &v) | fmi2DoStep(c, 0.0, dt, 1));
    CASE("skipped-time", fmi2DoStep(c, 5 * dt, dt, 1));
    CASE("negative-time", fmi2DoStep(c, -dt, dt, 1));
    CASE("nan-time", fmi2DoStep(c, nan, dt, 1));
    CASE("wrong-step", fmi2DoStep(c, dt, 1.5 * dt, 1));                 /* no multiple of dt */
    if (stamped) {                   /* VR_IN is a time stamp: x_time or g_time */
        double now = dt;
        CASE("stamp", fmi2SetReal(c, &in, 1, &big) | fmi2DoStep(c, dt, dt, 1));
        CASE("stamp-after", fmi2SetReal(c, &in, 1, &now) | fmi2DoStep(c, dt, dt, 1));
    }
    double t = 0.0;
    fmi2GetRealStatus(c, fmi2LastSuccessfulTime, &t);
    long k0 = lround(t / dt);
    /* roll back through a serialised state: the replay is bit-identical */
    fmi2FMUstate s = NULL, s2 = NULL;
    size_t size = 0;
    CASE("get-state", fmi2GetFMUstate(c, &s) | fmi2SerializedFMUstateSize(c, s, &size));
    char *bytes = malloc(size);
    CASE("serialize", fmi2SerializeFMUstate(c, s, bytes, size));
    double first[10], again[10];
    for (int k = 0; k < 10; k++) {
        double tk = (k0 + k) * dt;
        fmi2SetReal(c, &in, 1, &tk);
        fmi2DoStep(c, tk, dt, 1);
        first[k] = get(c, out);
    }
    CASE("deserialize", fmi2DeSerializeFMUstate(c, bytes, size, &s2) | fmi2SetFMUstate(c, s2));
    for (int k = 0; k < 10; k++) {
        double tk = (k0 + k) * dt;
        fmi2SetReal(c, &in, 1, &tk);
        fmi2DoStep(c, tk, dt, 1);
        again[k] = get(c, out);
    }
    CASE("replay-differs", memcmp(first, again, sizeof first) != 0);
    bytes[0] ^= 1;
    fmi2FMUstate s3 = NULL;
    CASE("deserialize-damaged", fmi2DeSerializeFMUstate(c, bytes, size, &s3));
    CASE("deserialize-short", fmi2DeSerializeFMUstate(c, bytes, size / 2, &s3));
    CASE("set-null-state", fmi2SetFMUstate(c, NULL));
    CASE("free-states", fmi2FreeFMUstate(c, &s) | fmi2FreeFMUstate(c, &s2));
    free(bytes);
    CASE("terminate", fmi2Terminate(c));
    CASE("after-terminate", fmi2DoStep(c, (k0 + 10) * dt, dt, 1));
    CASE("reset", fmi2Reset(c) | initialise(c) | fmi2DoStep(c, 0.0, dt, 1));
    fmi2FreeInstance(c);
    fmi2FreeInstance(NULL);
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
    if (argc == 10 && strcmp(argv[1], "hostile") == 0) {
        load(argv[3]);
        int rc = hostile(argv[2], argv[4], atof(argv[5]), (fmi2ValueReference)atol(argv[6]),
                         (fmi2ValueReference)atol(argv[7]), atol(argv[8]), atoi(argv[9]));
        dlclose(lib);
        return rc;
    }
    fprintf(stderr, "usage: host run DIR LIB GUID DT STEPS VR... | host hostile DIR LIB GUID DT VR_IN VR_OUT "
            "VR_BOOL STAMPED\n");
    return 1;
}

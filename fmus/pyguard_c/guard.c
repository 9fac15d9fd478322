/* The guard of the Python uplift FMUs: the FMI 2.0 library a python FMU ships as
   binaries/<platform>/<modelIdentifier>.<so|dll> (fmus/pyguard.py compiles it with ziglang's C
   compiler, as the native runtime). It checks every argument of every call and forwards the
   legal ones to pythonfmu's own library (pythonfmu-export.<so|dll>, shipped beside it and
   loaded from the guard's own folder at the first instantiation); pythonfmu's library trusts
   its arguments (a NULL or foreign pointer, a missing resource folder: a crash).

   What it refuses, each with fmi2Error (fmi2Instantiate: NULL) and the reason in the log, the
   instance as it was (the answers of fmus/native/fmi2.c, with the messages of fmus/schema.py):
   - a NULL or foreign instance (no magic tag; nothing can be logged: there is no logger);
   - fmi2Instantiate with another fmuType than co-simulation, no or an empty instance name, a
     GUID other than the one of the resources' variable table (resources/uplift_guard.txt,
     written at export from the model description), a resource location that is not a readable
     folder of this FMU's resources (file URI or plain path; decoded here, pythonfmu gets the
     path), an interpreter where pythonfmu's library cannot be loaded (no libpython);
   - a call in a state the FMI 2.0 co-simulation state machine does not allow it in (the masks
     of fmus/native/include/fmu.h);
   - NULL value-reference, value, size, status or state-pointer arguments;
   - a value reference that is not a variable of that type; setting a variable whose causality,
     variability and initial do not allow it in the current state (FMI 2.0, section 4.2.4):
     outputs never, a fixed parameter before fmi2ExitInitializationMode only, inputs until
     fmi2Terminate;
   - an FMU state pointer that this instance did not return (it is looked up in the instance's
     list of its live states, never dereferenced first), and serialised bytes that are not an
     uplift state (magic, version, length, CRC-32: fmus/fmu_state.py's header; the identity of
     the FMU is checked by the Python FMU when the state is set);
   - derivatives, cancelling a step (this FMU provides neither).
   Logging: pythonfmu drops every message, its errors too, while logging is off; the guard keeps
   pythonfmu's logging on and passes on its warnings and errors always, its other messages when
   the host's loggingOn (fmi2Instantiate, fmi2SetDebugLogging) and categories allow them.
   pythonfmu's results are not touched: a legal call is forwarded as it is. */
#if defined(_WIN32)
#define WIN32_LEAN_AND_MEAN
#include <windows.h>
#else
#define _GNU_SOURCE
#include <dlfcn.h>
#include <pthread.h>
#endif
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "uplift_crc32.h"
#include "uplift_messages.h"

#define GUARD_MAGIC 0x555047554152444bULL      /* "UPGUARDK" */
#define STATE_MAGIC 0x5550475354415445ULL      /* "UPGSTATE" */
#define TABLE_FILE "uplift_guard.txt"
#define TABLE_HEADER "uplift-pyguard 1"
#define MAX_VR 10000000u
#define MSG 1024
#if defined(_WIN32)
#define INNER_NAME L"pythonfmu-export.dll"
#elif defined(__APPLE__)
#define INNER_NAME "pythonfmu-export.dylib"
#else
#define INNER_NAME "pythonfmu-export.so"
#endif

enum { INSTANTIATED = 1, INITIALISATION = 2, STEPPING = 4, TERMINATED = 8 };
#define ANY_STATE (INSTANTIATED | INITIALISATION | STEPPING | TERMINATED)
/* causality, variability, initial: the codes of the table (fmus.pyguard.guard_table) */
enum { C_PARAMETER, C_CALCULATED, C_INPUT, C_OUTPUT, C_LOCAL, C_INDEPENDENT };
enum { V_CONSTANT, V_FIXED, V_TUNABLE, V_DISCRETE, V_CONTINUOUS };
enum { I_EXACT, I_APPROX, I_CALCULATED };
enum { T_REAL, T_INTEGER, T_BOOLEAN, T_STRING, NTYPE };
static const char *const TYPE_NAMES[NTYPE] = {"Real", "Integer", "Boolean", "String"};
static const char *const CAUSALITY[] = {"a parameter", "a calculated parameter", "an input", "an output", "a local",
                                        "the independent variable"};

/* ---- pythonfmu's library ------------------------------------------------------------------------ */
#define INNER(X) X(fmi2Instantiate) X(fmi2FreeInstance) X(fmi2SetupExperiment) \
    X(fmi2EnterInitializationMode) X(fmi2ExitInitializationMode) X(fmi2Terminate) X(fmi2Reset)           \
    X(fmi2GetReal) X(fmi2GetInteger) X(fmi2GetBoolean) X(fmi2GetString) X(fmi2SetReal) X(fmi2SetInteger) \
    X(fmi2SetBoolean) X(fmi2SetString) X(fmi2GetFMUstate) X(fmi2SetFMUstate) X(fmi2FreeFMUstate)          \
    X(fmi2SerializedFMUstateSize) X(fmi2SerializeFMUstate) X(fmi2DeSerializeFMUstate) X(fmi2DoStep)      \
    X(fmi2GetStatus) X(fmi2GetRealStatus) X(fmi2GetIntegerStatus) X(fmi2GetBooleanStatus)                \
    X(fmi2GetStringStatus)
#define SLOT(name) name##TYPE *name;
static struct { INNER(SLOT) } in;
static char load_error[MSG];

#if defined(_WIN32)
static void *symbol(void *lib, const char *name) { return (void *)GetProcAddress((HMODULE)lib, name); }

static void *open_inner(void)
{
    HMODULE self = NULL;
    wchar_t path[4096];
    if (!GetModuleHandleExW(GET_MODULE_HANDLE_EX_FLAG_FROM_ADDRESS | GET_MODULE_HANDLE_EX_FLAG_UNCHANGED_REFCOUNT,
                            (LPCWSTR)(void *)&open_inner, &self)) {
        snprintf(load_error, MSG, "the guard cannot find its own folder (error %lu)", GetLastError());
        return NULL;
    }
    DWORD n = GetModuleFileNameW(self, path, 4096);
    if (n == 0 || n >= 4096 - 32) {
        snprintf(load_error, MSG, "the guard's own path is too long");
        return NULL;
    }
    while (n > 0 && path[n - 1] != L'\\' && path[n - 1] != L'/')
        n--;
    wcscpy(path + n, INNER_NAME);
    HMODULE lib = LoadLibraryExW(path, NULL, LOAD_WITH_ALTERED_SEARCH_PATH);
    if (!lib)
        snprintf(load_error, MSG, "pythonfmu's library %ls cannot be loaded (error %lu): the host needs Python "
                 "(see resources/requirements.txt)", path, GetLastError());
    return lib;
}
#else
static void *symbol(void *lib, const char *name) { return dlsym(lib, name); }

static void *open_inner(void)
{
    Dl_info info;
    char path[4096];
    if (!dladdr((void *)&open_inner, &info) || !info.dli_fname || strlen(info.dli_fname) >= sizeof path - 32) {
        snprintf(load_error, MSG, "the guard cannot find its own folder");
        return NULL;
    }
    strcpy(path, info.dli_fname);
    char *slash = strrchr(path, '/');
    strcpy(slash ? slash + 1 : path, INNER_NAME);
    void *lib = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (!lib)
        snprintf(load_error, MSG, "pythonfmu's library cannot be loaded (%s): the host must have libpython loaded "
                 "globally (a Python host, or LD_PRELOAD=libpython3.x.so)", dlerror());
    return lib;
}
#endif

static int inner_ok;

static void load_inner(void)
{
    void *lib = open_inner();
    if (!lib)
        return;
#define GET(name)                                                                                   \
    if (!(in.name = (name##TYPE *)symbol(lib, #name))) {                                            \
        snprintf(load_error, MSG, "pythonfmu's library has no %s: export the FMU again", #name);    \
        return;                                                                                     \
    }
    INNER(GET)
    inner_ok = 1;
}

#if defined(_WIN32)
static INIT_ONCE once = INIT_ONCE_STATIC_INIT;
static BOOL CALLBACK load_once(PINIT_ONCE o, PVOID p, PVOID *c)
{
    (void)o, (void)p, (void)c;
    load_inner();
    return TRUE;
}
static int inner_loaded(void) { InitOnceExecuteOnce(&once, load_once, NULL, NULL); return inner_ok; }
#else
static pthread_once_t once = PTHREAD_ONCE_INIT;
static int inner_loaded(void) { pthread_once(&once, load_inner); return inner_ok; }
#endif

/* ---- the instance ------------------------------------------------------------------------------- */
typedef struct { int n; unsigned char *code; } Vars;    /* code[vr]: NONE, or causality | variability << 3 | initial << 6 */
#define NONE 0xFF

typedef struct GState {
    uint64_t magic;
    struct GState *next;
    fmi2FMUstate inner;
} GState;

typedef struct {
    uint64_t magic;
    fmi2Component inner;
    int state;
    char name[128];
    fmi2CallbackLogger logger;
    fmi2ComponentEnvironment env;
    fmi2CallbackFunctions mine;                /* given to pythonfmu, which keeps the pointer */
    int logging;                               /* the host's loggingOn and categories (pythonfmu's */
    size_t ncat;                               /* own logging stays on: it would drop its errors) */
    char **cats;
    Vars vars[NTYPE];
    GState *states;
} Guard;

/* the message to the host's logger, whole (pythonfmu's may hold a traceback), each % doubled:
   the logger takes a printf format */
static void emit(Guard *G, fmi2Status status, const char *category, const char *text)
{
    if (!G->logger)
        return;
    char small[2 * MSG + 16], *msg = small;
    size_t n = 2 * strlen(text) + 1, size = sizeof small, k = 0;
    if (n > size && (msg = (char *)malloc(n)) != NULL)
        size = n;
    else if (n > size)
        msg = small;                          /* out of memory: the message cut */
    for (const char *p = text; *p && k + 2 < size; p++) {
        if (*p == '%')
            msg[k++] = '%';
        msg[k++] = *p;
    }
    msg[k] = '\0';
    G->logger(G->env, G->name, status, category, msg);
    if (msg != small)
        free(msg);
}

static void error(Guard *G, const char *fmt, ...)
{
    char text[MSG];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(text, sizeof text, fmt, ap);
    va_end(ap);
    emit(G, fmi2Error, "logStatusError", text);
}

/* pythonfmu's messages to the host, through the guard (the host's logger may be NULL) */
static void forward_log(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                        fmi2String message, ...)
{
    Guard *G = (Guard *)env;
    (void)name;
    if (!G)
        return;
    int shown = status >= fmi2Warning;          /* warnings and errors always, as the native FMUs */
    if (!shown && G->logging) {
        shown = G->ncat == 0;
        for (size_t k = 0; !shown && k < G->ncat; k++)
            shown = category && strcmp(category, G->cats[k]) == 0;
    }
    if (shown)
        emit(G, status, category, message ? message : "");
}

static void free_categories(Guard *G)
{
    for (size_t k = 0; k < G->ncat; k++)
        free(G->cats[k]);
    free(G->cats);
    G->cats = NULL;
    G->ncat = 0;
}

static void free_guard(Guard *G)
{
    free_categories(G);
    for (int t = 0; t < NTYPE; t++)
        free(G->vars[t].code);
    G->magic = 0;
    free(G);
}

static Guard *instance(fmi2Component c) { return c && ((Guard *)c)->magic == GUARD_MAGIC ? (Guard *)c : NULL; }

static Guard *guard(fmi2Component c, int mask, const char *fn)
{
    Guard *G = instance(c);
    if (!G || (G->state & mask))
        return G;
    if (mask == STEPPING && G->state == TERMINATED)
        error(G, UP_MSG_AFTER_TERMINATE, fn, "fmi2");
    else if (mask == STEPPING)
        error(G, UP_MSG_BEFORE_INIT, fn, "fmi2");
    else {
        const char *state = G->state == INSTANTIATED ? "before fmi2EnterInitializationMode"
                          : G->state == INITIALISATION ? "in initialisation mode"
                          : G->state == STEPPING ? "after initialisation (fmi2Reset first)"
                                                 : "after fmi2Terminate (fmi2Reset first)";
        error(G, UP_MSG_WRONG_STATE, fn, state, "FMI 2.0");
    }
    return NULL;
}

#define GUARD(fn, mask)                    \
    Guard *G = guard(c, mask, #fn);        \
    if (!G)                                \
        return fmi2Error;

/* ---- instantiation ------------------------------------------------------------------------------- */
/* resources folder URI (file:///path, file:/path, file://localhost/path) or plain path -> path */
static int resource_folder(const char *p, char *out, size_t size)
{
    if (strncmp(p, "file://", 7) == 0) {
        p += 7;
        if (strncmp(p, "localhost/", 10) == 0)
            p += 9;
        if (*p != '/')
            return -1;                           /* file://host/...: another machine */
    } else if (strncmp(p, "file:", 5) == 0) {
        p += 5;
    } else if (strstr(p, "://")) {
        return -1;                               /* http:// ...: not a file */
    }
#if defined(_WIN32)
    if (p[0] == '/' && p[1] && p[2] == ':')      /* /C:/... */
        p++;
#endif
    size_t k = 0;
    for (; *p; p++) {
        if (k + 1 >= size)
            return -1;
        if (*p == '%') {
            char hex[3] = {p[1], p[1] ? p[2] : 0, 0};
            char *end;
            long v = strtol(hex, &end, 16);
            if (!hex[0] || !hex[1] || *end || v == 0)
                return -1;
            out[k++] = (char)v;
            p += 2;
            continue;
        }
        out[k++] = *p;
    }
    while (k > 1 && (out[k - 1] == '/' || out[k - 1] == '\\'))
        k--;
    out[k] = '\0';
    return k ? 0 : -1;
}

static FILE *open_in(const char *folder, const char *file, char *path, size_t size)
{
    if ((size_t)snprintf(path, size, "%s/%s", folder, file) >= size)
        return NULL;
    return fopen(path, "rb");
}

/* resources/uplift_guard.txt: the GUID and, per variable, its type, value reference and codes */
static int read_table(Guard *G, const char *folder, const char *guid, char *err)
{
    char path[4200], line[512], word[16], want[256];
    FILE *f = open_in(folder, TABLE_FILE, path, sizeof path);
    if (!f) {
        snprintf(err, MSG, "fmuResourceLocation %s: %s cannot be opened: give the file URI of this FMU's "
                 "resources folder (extract the FMU again)", folder, TABLE_FILE);
        return -1;
    }
    int rc = -1;
    if (!fgets(line, sizeof line, f) || strncmp(line, TABLE_HEADER, strlen(TABLE_HEADER)) != 0
        || !fgets(line, sizeof line, f) || sscanf(line, "guid %255s", want) != 1) {
        snprintf(err, MSG, "%s is not a variable table of the uplift guard: export the FMU again", path);
        goto done;
    }
    if (!guid || strcmp(guid, want) != 0) {
        snprintf(err, MSG, "GUID %s does not match the resources (%s): the resources folder belongs to another FMU; "
                 "extract this FMU again", guid ? guid : "(null)", path);
        goto done;
    }
    int count[NTYPE] = {0};
    if (!fgets(line, sizeof line, f) || sscanf(line, "sizes %d %d %d %d", count, count + 1, count + 2, count + 3) != 4)
        goto bad;
    for (int t = 0; t < NTYPE; t++) {
        if (count[t] < 0 || (unsigned)count[t] > MAX_VR)
            goto bad;
        G->vars[t].n = count[t];
        G->vars[t].code = (unsigned char *)malloc((size_t)count[t] + 1);
        if (!G->vars[t].code) {
            snprintf(err, MSG, "out of memory for the variable table");
            goto done;
        }
        memset(G->vars[t].code, NONE, (size_t)count[t] + 1);
    }
    while (fgets(line, sizeof line, f)) {
        unsigned vr;
        int cau, var, ini, t;
        if (sscanf(line, "%15s %u %d %d %d", word, &vr, &cau, &var, &ini) != 5)
            goto bad;
        for (t = 0; t < NTYPE && strcmp(word, TYPE_NAMES[t]); t++)
            ;
        if (t == NTYPE || vr >= (unsigned)G->vars[t].n || cau < 0 || cau > C_INDEPENDENT || var < 0
            || var > V_CONTINUOUS || ini < 0 || ini > I_CALCULATED)
            goto bad;
        G->vars[t].code[vr] = (unsigned char)(cau | var << 3 | ini << 6);
    }
    rc = 0;
    goto done;
bad:
    snprintf(err, MSG, "%s: a line is not a variable of the uplift guard: export the FMU again", path);
done:
    fclose(f);
    return rc;
}

/* the Python module pythonfmu imports (slavemodule.txt names it) must be there: pythonfmu calls a
   NULL class otherwise */
static int check_module(const char *folder, char *err)
{
    char path[4200], module[256], script[300];
    FILE *f = open_in(folder, "slavemodule.txt", path, sizeof path);
    int ok = f && fgets(module, sizeof module, f) != NULL;
    if (f)
        fclose(f);
    if (ok) {
        module[strcspn(module, "\r\n")] = '\0';
        snprintf(script, sizeof script, "%s.py", module);
        f = *module ? open_in(folder, script, path, sizeof path) : NULL;
        ok = f != NULL;
        if (f)
            fclose(f);
    }
    if (!ok)
        snprintf(err, MSG, "%s cannot be opened: the resources folder %s is not complete (extract the FMU again)",
                 path, folder);
    return ok ? 0 : -1;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn)
{
    Guard *G = (Guard *)calloc(1, sizeof(Guard));
    if (!G)
        return NULL;
    G->magic = GUARD_MAGIC;
    snprintf(G->name, sizeof G->name, "%s", instanceName ? instanceName : "uplift");
    G->logger = functions ? functions->logger : NULL;
    G->env = functions ? functions->componentEnvironment : NULL;
    G->mine.logger = forward_log;
    G->mine.allocateMemory = calloc;
    G->mine.freeMemory = free;
    G->mine.componentEnvironment = G;
    G->logging = loggingOn != fmi2False;
    char err[MSG] = "", folder[4096];
    if (!instanceName || !*instanceName)
        snprintf(err, MSG, "instanceName is empty: give the instance a name");
    else if (fmuType != fmi2CoSimulation)
        snprintf(err, MSG, "this FMU is for co-simulation only (fmuType = fmi2CoSimulation)");
    else if (!fmuResourceLocation || resource_folder(fmuResourceLocation, folder, sizeof folder))
        snprintf(err, MSG, "fmuResourceLocation %s is not a file URI of the FMU's resources folder",
                 fmuResourceLocation ? fmuResourceLocation : "(null)");
    else if (read_table(G, folder, fmuGUID, err) || check_module(folder, err))
        ;
    else if (!inner_loaded())
        snprintf(err, MSG, "%s", load_error);
    else if (!(G->inner = in.fmi2Instantiate(instanceName, fmuType, fmuGUID, folder, &G->mine, visible, fmi2True)))
        snprintf(err, MSG, "the Python FMU could not be created (pythonfmu's message above)");
    if (*err) {
        error(G, "instantiation failed: %s", err);
        free_guard(G);
        return NULL;
    }
    G->state = INSTANTIATED;
    return G;
}

static void free_state(Guard *G, GState *S)
{
    GState **p = &G->states;
    while (*p && *p != S)
        p = &(*p)->next;
    if (*p)
        *p = S->next;
    fmi2FMUstate inner = S->inner;
    in.fmi2FreeFMUstate(G->inner, &inner);
    S->magic = 0;
    free(S);
}

void fmi2FreeInstance(fmi2Component c)
{
    Guard *G = instance(c);
    if (!G)
        return;
    while (G->states)
        free_state(G, G->states);
    in.fmi2FreeInstance(G->inner);
    free_guard(G);
}

/* ---- common functions ----------------------------------------------------------------------------- */
const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories, const fmi2String categories[])
{
    GUARD(fmi2SetDebugLogging, ANY_STATE)
    if (nCategories > 0 && !categories) {
        error(G, "fmi2SetDebugLogging: categories is NULL with nCategories = %zu", nCategories);
        return fmi2Error;
    }
    for (size_t k = 0; k < nCategories; k++)
        if (!categories[k]) {
            error(G, "fmi2SetDebugLogging: category %zu is NULL", k);
            return fmi2Error;
        }
    char **cats = nCategories ? (char **)calloc(nCategories, sizeof(char *)) : NULL;
    for (size_t k = 0; k < nCategories && cats; k++)
        if (!(cats[k] = (char *)malloc(strlen(categories[k]) + 1))) {
            while (k > 0)
                free(cats[--k]);
            free(cats);
            cats = NULL;
        } else {
            strcpy(cats[k], categories[k]);
        }
    if (nCategories && !cats) {
        error(G, "fmi2SetDebugLogging: out of memory");
        return fmi2Error;
    }
    free_categories(G);              /* pythonfmu's own logging stays on: forward_log filters */
    G->logging = loggingOn != fmi2False;
    G->cats = cats;
    G->ncat = nCategories;
    return fmi2OK;
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime)
{
    GUARD(fmi2SetupExperiment, INSTANTIATED)
    return in.fmi2SetupExperiment(G->inner, toleranceDefined, tolerance, startTime, stopTimeDefined, stopTime);
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c)
{
    GUARD(fmi2EnterInitializationMode, INSTANTIATED)
    fmi2Status s = in.fmi2EnterInitializationMode(G->inner);
    if (s <= fmi2Warning)
        G->state = INITIALISATION;
    return s;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c)
{
    GUARD(fmi2ExitInitializationMode, INITIALISATION)
    fmi2Status s = in.fmi2ExitInitializationMode(G->inner);
    if (s <= fmi2Warning)
        G->state = STEPPING;
    return s;
}

fmi2Status fmi2Terminate(fmi2Component c)
{
    GUARD(fmi2Terminate, ANY_STATE)
    fmi2Status s = in.fmi2Terminate(G->inner);
    G->state = TERMINATED;                 /* from any state: a host ending a failed start too */
    return s;
}

fmi2Status fmi2Reset(fmi2Component c)
{
    GUARD(fmi2Reset, ANY_STATE)
    fmi2Status s = in.fmi2Reset(G->inner);
    if (s <= fmi2Warning)
        G->state = INSTANTIATED;
    return s;
}

/* ---- variables ----------------------------------------------------------------------------------- */
/* may a variable of these codes be set in state? (FMI 2.0, section 4.2.4) */
static int settable(int code, int state)
{
    int cau = code & 7, var = (code >> 3) & 7, ini = (code >> 6) & 3;
    if (var == V_CONSTANT || cau == C_OUTPUT || cau == C_CALCULATED || cau == C_INDEPENDENT)
        return 0;
    if (state == INSTANTIATED)
        return ini == I_EXACT || ini == I_APPROX;
    if (state == INITIALISATION)
        return ini == I_EXACT || cau == C_INPUT;
    if (state == STEPPING)
        return cau == C_INPUT || (cau == C_PARAMETER && var == V_TUNABLE);
    return 0;
}

static int check_refs(Guard *G, const char *fn, int type, const fmi2ValueReference vr[], size_t nvr,
                      const void *value, int setting)
{
    if (nvr == 0)
        return 0;
    if (!vr || !value) {
        error(G, "%s: NULL value reference or value array with nvr = %zu", fn, nvr);
        return -1;
    }
    const Vars *V = &G->vars[type];
    unsigned lo = 0, hi = 0;
    int bad = 0;
    for (size_t i = 0; i < nvr; i++)
        if (vr[i] >= (unsigned)V->n || V->code[vr[i]] == NONE) {
            lo = bad ? (vr[i] < lo ? vr[i] : lo) : vr[i];
            hi = bad ? (vr[i] > hi ? vr[i] : hi) : vr[i];
            bad = 1;
        }
    if (bad) {
        if (V->n == 0)
            error(G, "%s: value reference %u: this FMU has no %s variables", fn, lo, TYPE_NAMES[type]);
        else
            error(G, "%s: value references %u..%u: not %s variables of this FMU (its %s value references are "
                  "below %d)", fn, lo, hi, TYPE_NAMES[type], TYPE_NAMES[type], V->n);
        return -1;
    }
    for (size_t i = 0; setting && i < nvr; i++) {
        int code = V->code[vr[i]];
        if (settable(code, G->state))
            continue;
        int cau = code & 7, var = (code >> 3) & 7;
        if (cau == C_OUTPUT)
            error(G, "%s: value reference %u is an output: only inputs can be set", fn, vr[i]);
        else if (G->state == TERMINATED)
            error(G, "%s: value reference %u: no variable can be set after fmi2Terminate (fmi2Reset first)", fn,
                  vr[i]);
        else if (cau == C_PARAMETER && var == V_FIXED)
            error(G, "%s: value reference %u is a fixed parameter: set it before fmi2ExitInitializationMode", fn,
                  vr[i]);
        else
            error(G, "%s: value reference %u is %s: it cannot be set %s (FMI 2.0, section 4.2.4)", fn, vr[i],
                  CAUSALITY[cau], G->state == STEPPING ? "after initialisation" : "now");
        return -1;
    }
    return 0;
}

#define GETTER(fn, T, type)                                                                   \
    fmi2Status fn(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, T value[])      \
    {                                                                                         \
        GUARD(fn, ANY_STATE)                                                                  \
        if (check_refs(G, #fn, type, vr, nvr, value, 0))                                      \
            return fmi2Error;                                                                 \
        return nvr == 0 ? fmi2OK : in.fn(G->inner, vr, nvr, value);                           \
    }
#define SETTER(fn, T, type)                                                                   \
    fmi2Status fn(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const T value[]) \
    {                                                                                         \
        GUARD(fn, ANY_STATE)                                                                  \
        if (check_refs(G, #fn, type, vr, nvr, value, 1))                                      \
            return fmi2Error;                                                                 \
        return nvr == 0 ? fmi2OK : in.fn(G->inner, vr, nvr, value);                           \
    }
GETTER(fmi2GetReal, fmi2Real, T_REAL)
GETTER(fmi2GetInteger, fmi2Integer, T_INTEGER)
GETTER(fmi2GetBoolean, fmi2Boolean, T_BOOLEAN)
GETTER(fmi2GetString, fmi2String, T_STRING)
SETTER(fmi2SetReal, fmi2Real, T_REAL)
SETTER(fmi2SetInteger, fmi2Integer, T_INTEGER)
SETTER(fmi2SetBoolean, fmi2Boolean, T_BOOLEAN)
SETTER(fmi2SetString, fmi2String, T_STRING)

/* ---- FMU states: wrappers owned by the instance ---------------------------------------------------- */
static GState *owned(Guard *G, fmi2FMUstate s, const char *fn)
{
    for (GState *S = G->states; S; S = S->next)
        if ((void *)S == (void *)s && S->magic == STATE_MAGIC)
            return S;
    error(G, "%s: not an FMU state of this FMU (get it from this instance: get the FMU state, or deserialise one)",
          fn);
    return NULL;
}

/* the new inner state into *s: the wrapper *s if it is one of this instance's, else a new one */
static fmi2Status wrap(Guard *G, fmi2FMUstate *s, fmi2FMUstate inner, const char *fn)
{
    GState *S = *s ? owned(G, *s, fn) : NULL;
    if (S) {
        fmi2FMUstate old = S->inner;
        in.fmi2FreeFMUstate(G->inner, &old);
    } else if (!(S = (GState *)calloc(1, sizeof(GState)))) {
        error(G, "%s: out of memory", fn);
        in.fmi2FreeFMUstate(G->inner, &inner);
        return fmi2Error;
    } else {
        S->magic = STATE_MAGIC;
        S->next = G->states;
        G->states = S;
    }
    S->inner = inner;
    *s = S;
    return fmi2OK;
}

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *s)
{
    GUARD(fmi2GetFMUstate, ANY_STATE)
    if (!s) {
        error(G, "fmi2GetFMUstate: FMUstate pointer is NULL");
        return fmi2Error;
    }
    if (*s && !owned(G, *s, "fmi2GetFMUstate"))
        return fmi2Error;
    fmi2FMUstate inner = NULL;
    fmi2Status r = in.fmi2GetFMUstate(G->inner, &inner);
    if (r > fmi2Warning || !inner)
        return r > fmi2Warning ? r : fmi2Error;
    fmi2Status w = wrap(G, s, inner, "fmi2GetFMUstate");
    return w != fmi2OK ? w : r;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate s)
{
    GUARD(fmi2SetFMUstate, ANY_STATE)
    GState *S = owned(G, s, "fmi2SetFMUstate");
    return S ? in.fmi2SetFMUstate(G->inner, S->inner) : fmi2Error;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *s)
{
    GUARD(fmi2FreeFMUstate, ANY_STATE)
    if (!s) {
        error(G, "fmi2FreeFMUstate: FMUstate pointer is NULL");
        return fmi2Error;
    }
    if (!*s)
        return fmi2OK;
    GState *S = owned(G, *s, "fmi2FreeFMUstate");
    if (!S)
        return fmi2Error;
    free_state(G, S);
    *s = NULL;
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t *size)
{
    GUARD(fmi2SerializedFMUstateSize, ANY_STATE)
    if (!size) {
        error(G, "fmi2SerializedFMUstateSize: size pointer is NULL");
        return fmi2Error;
    }
    GState *S = owned(G, s, "fmi2SerializedFMUstateSize");
    return S ? in.fmi2SerializedFMUstateSize(G->inner, S->inner, size) : fmi2Error;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte bytes[], size_t size)
{
    GUARD(fmi2SerializeFMUstate, ANY_STATE)
    GState *S = owned(G, s, "fmi2SerializeFMUstate");
    if (!S)
        return fmi2Error;
    size_t need = 0;
    fmi2Status r = in.fmi2SerializedFMUstateSize(G->inner, S->inner, &need);
    if (r > fmi2Warning)
        return r;
    if (!bytes || size < need) {       /* pythonfmu copies size bytes from a buffer of need */
        error(G, "fmi2SerializeFMUstate: a buffer of %zu bytes at %p: this state needs %zu "
              "(fmi2SerializedFMUstateSize)", size, (void *)bytes, need);
        return fmi2Error;
    }
    return in.fmi2SerializeFMUstate(G->inner, S->inner, bytes, need);
}

static uint64_t le(const unsigned char *p, int n)
{
    uint64_t v = 0;
    for (int i = n - 1; i >= 0; i--)
        v = v << 8 | p[i];
    return v;
}

/* fmus/fmu_state.py's header: magic UPLIFTPS, version u32, CRC-32 of the rest u32, identity u64,
   payload length u64 */
static const char *state_problem(const unsigned char *b, size_t size, char *buf)
{
    if (size < 8 || memcmp(b, "UPLIFTPS", 8) != 0)
        return UP_MSG_STATE_MAGIC;
    if (size < 32 || le(b + 24, 8) != size - 32)
        return UP_MSG_STATE_SIZE;
    if (le(b + 8, 4) != UP_STATE_VERSION) {
        char got[16], want[16];
        snprintf(got, sizeof got, "%u", (unsigned)le(b + 8, 4));
        snprintf(want, sizeof want, "%d", UP_STATE_VERSION);
        snprintf(buf, 96, UP_MSG_STATE_VERSION, got, want);
        return buf;
    }
    if (le(b + 12, 4) != up_crc32(b + 16, size - 16))
        return UP_MSG_STATE_CHECKSUM;
    return NULL;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte bytes[], size_t size, fmi2FMUstate *s)
{
    GUARD(fmi2DeSerializeFMUstate, ANY_STATE)
    if (!s || (!bytes && size > 0)) {
        error(G, "fmi2DeSerializeFMUstate: %s is NULL", s ? "the byte array" : "the FMUstate pointer");
        return fmi2Error;
    }
    if (*s && !owned(G, *s, "fmi2DeSerializeFMUstate"))
        return fmi2Error;
    char buf[96];
    const char *why = state_problem((const unsigned char *)bytes, size, buf);
    if (why) {
        char size_text[32];
        snprintf(size_text, sizeof size_text, "%zu", size);
        error(G, "fmi2DeSerializeFMUstate: " UP_MSG_BAD_STATE, size_text, why);
        return fmi2Error;
    }
    fmi2FMUstate inner = NULL;
    fmi2Status r = in.fmi2DeSerializeFMUstate(G->inner, bytes, size, &inner);
    if (r > fmi2Warning || !inner)
        return r > fmi2Warning ? r : fmi2Error;
    fmi2Status w = wrap(G, s, inner, "fmi2DeSerializeFMUstate");
    return w != fmi2OK ? w : r;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[], size_t nUnknown,
                                        const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[])
{
    (void)vUnknown_ref, (void)nUnknown, (void)vKnown_ref, (void)nKnown, (void)dvKnown, (void)dvUnknown;
    GUARD(fmi2GetDirectionalDerivative, ANY_STATE)
    error(G, "fmi2GetDirectionalDerivative: not provided by this FMU (providesDirectionalDerivative = false)");
    return fmi2Error;
}

/* ---- co-simulation ---------------------------------------------------------------------------------- */
fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[])
{
    (void)vr, (void)order, (void)value;
    GUARD(fmi2SetRealInputDerivatives, ANY_STATE)
    if (nvr == 0)
        return fmi2OK;
    error(G, "fmi2SetRealInputDerivatives: this FMU does not interpolate inputs (canInterpolateInputs = false)");
    return fmi2Error;
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[])
{
    (void)vr, (void)order, (void)value;
    GUARD(fmi2GetRealOutputDerivatives, ANY_STATE)
    if (nvr == 0)
        return fmi2OK;
    error(G, "fmi2GetRealOutputDerivatives: this FMU provides no output derivatives (maxOutputDerivativeOrder = 0)");
    return fmi2Error;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSetFMUStatePriorToCurrentPoint)
{
    GUARD(fmi2DoStep, STEPPING)
    return in.fmi2DoStep(G->inner, t, h, noSetFMUStatePriorToCurrentPoint);
}

fmi2Status fmi2CancelStep(fmi2Component c)
{
    GUARD(fmi2CancelStep, STEPPING)
    error(G, "fmi2CancelStep: this FMU computes its steps synchronously, there is nothing to cancel");
    return fmi2Error;
}

#define STATUS(fn, T)                                                        \
    fmi2Status fn(fmi2Component c, const fmi2StatusKind s, T *value)         \
    {                                                                        \
        GUARD(fn, ANY_STATE)                                                 \
        if (!value) {                                                        \
            error(G, "%s: value pointer is NULL", #fn);                      \
            return fmi2Error;                                                \
        }                                                                    \
        return in.fn(G->inner, s, value);                                    \
    }
STATUS(fmi2GetStatus, fmi2Status)
STATUS(fmi2GetRealStatus, fmi2Real)
STATUS(fmi2GetIntegerStatus, fmi2Integer)
STATUS(fmi2GetBooleanStatus, fmi2Boolean)
STATUS(fmi2GetStringStatus, fmi2String)

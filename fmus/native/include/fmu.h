/* The instance of a native uplift FMU and what the runtime's FMI files share, with no FMI
   header: the entry layers fmi2.c (FMI 2.0) and fmi3.c (FMI 3.0) include theirs and call
     instance.c   instantiation: the resource file, the layout of the variables, the state block
     model.c      the model at the FMI boundary: initial state, the communication step, the outputs
     variables.c  get/set of the variables by element
     state.c      FMU states: get, set, serialise (versioned, identified, CRC-32 checked)
   An entry point opens with UP_GUARD(its name): the instance, if it is one and the call is
   allowed in its state (the mask MASK_<name> below, one per entry point of both versions),
   else the entry point returns its error status with the reason logged. The status codes are the
   values fmi2Status and fmi3Status share. The refusal messages shared with the Python FMUs are
   in uplift_messages.h (generated from fmus/schema.py). */
#ifndef UPLIFT_FMU_H
#define UPLIFT_FMU_H

#include "uplift.h"
#include "uplift_messages.h"

enum { UP_OK = 0, UP_WARNING = 1, UP_DISCARD = 2, UP_ERROR = 3 };

/* the FMI states of an instance, one bit each (the masks are unions of them) */
enum { UP_INSTANTIATED = 1 << 0, UP_INITIALISATION = 1 << 1, UP_STEPPING = 1 << 2, UP_TERMINATED = 1 << 3 };
#define UP_ANY_STATE (UP_INSTANTIATED | UP_INITIALISATION | UP_STEPPING | UP_TERMINATED)

/* the named vectors of Real variables (the roles ROLE_*, the slots S_* and NSLOT are in
   uplift_schema.h, generated from fmus.schema.SLOTS): first value reference in the resource
   records vr.<name>, looked up by name at instantiation */
extern const char *const up_slot_names[NSLOT];

typedef struct UpInstance UpInstance;

/* what an entry layer gives the instance: its version's names and its logger */
typedef struct {
    const char *api;           /* "fmi2", "fmi3": the prefix of the entry points */
    const char *standard;      /* "FMI 2.0", "FMI 3.0" */
    const char *setup;         /* the call that takes the stop time */
    void (*emit)(UpInstance *I, int status, const char *category, const char *message);
} UpApi;

struct UpInstance {
    uint64_t magic;
    int role, state, logging;
    char name[256];
    const UpApi *api;
    void (*logger)(void);                   /* the host's logger, called through api->emit */
    void *env;
    UpRes res;
    UpSoil soil;
    UpStepper st;
    int has_stepper;
    int n, N, nnodes, n_real, slot_len[NSLOT];
    int64_t slot[NSLOT];
    const int64_t *causality;               /* (n_real): 0 input, 1 output */
    const int64_t *node_dofs;               /* (nnodes, 3) */
    const double *motion;                   /* (nt, 3) or NULL */
    int64_t nt, vr_internal_motion;
    int has_motion;
    const int64_t *vars3;                   /* FMI 3.0: (nvars3, 2) first element (-1: the time), length of each
                                               Float64 variable */
    int64_t nvars3, vr3_N;
    const double *Gx, *Gv;                  /* (n, n), structure only */
    double *Gxp;                            /* Gx packed when it is symmetric, else NULL */
    int Gv_zero;                            /* 1 when Gv is zero (no product) */
    double dt, start_time, stop_time;       /* stop_time: +inf unless the host defines it */
    uint64_t guid_hash;
    /* the state block and its parts */
    double *block, *backup, *saves, *tmp;
    size_t block_len;
    double *time, *internal_motion, *held_t, *bank, *held;
    int held_len;
    char err[UP_MSG];
};

#define UP_INSTANCE_MAGIC 0x75706c6966744e42ULL       /* "upliftNB" */

/* instance.c */
UpInstance *up_instance(void *c);                             /* NULL unless a live instance */
/* a new instance (NULL: out of memory, or a bad name or setup, logged); location: the resources
   folder, a file URI (FMI 2.0) or a path (FMI 3.0, uri = 0) */
UpInstance *up_instantiate(const UpApi *api, const char *name, const char *guid, const char *location, int uri,
                           void (*logger)(void), void *env, int logging, const char *refusal);
void up_free_instance(UpInstance *I);
void up_log_error(UpInstance *I, const char *fmt, ...);       /* logStatusError, always */
void up_log_event(UpInstance *I, const char *fmt, ...);       /* logEvents, when logging is on */
const char *up_num(double v, char *buf);                      /* shortest round-trip decimal, buf[32] */
const char *up_element_name(const UpInstance *I, int slot, int i, char *buf);   /* "x[3]", "ag_x", buf[48] */
UpInstance *up_guard(void *c, int mask, const char *fn);
int up_set_logging(UpInstance *I, const char *fn, int on, size_t n, const char *const categories[]);
/* UP_ERROR_STATUS: the entry layer's error status (fmi2Error, fmi3Error) */
#define UP_GUARD(fn)                                    \
    UpInstance *I = up_guard(c, MASK_##fn, #fn);        \
    if (!I)                                             \
    return UP_ERROR_STATUS

/* model.c */
enum { UP_REFUSED = 1, UP_FAILED = 2 };
double *up_var(UpInstance *I, int slot);
/* before the bank's elements first .. first + len - 1 are read: the soil's outputs f and
   dissipated_energy computed if they are among them and not yet computed since the last step */
void up_soil_read(UpInstance *I, int64_t first, int64_t len);
int up_initial_state(UpInstance *I);                          /* 0, or -1 with I->err */
int up_step(UpInstance *I, double t, int last);  /* 0, UP_REFUSED or UP_FAILED with I->err; outputs if last */
int up_setup_experiment(UpInstance *I, const char *fn, int stop_defined, double start, double stop);  /* 0 / -1 */
int up_enter_initialisation(UpInstance *I);                   /* UP_OK or UP_ERROR, logged */
int up_exit_initialisation(UpInstance *I);
void up_reset(UpInstance *I);
int up_do_step(UpInstance *I, double t, double h);           /* UP_OK, UP_DISCARD or UP_ERROR, logged */

/* variables.c: the Real variables by element (value references 0 .. n_real - 1), the Boolean */
int up_check_refs(UpInstance *I, const char *fn, const unsigned int vr[], size_t nvr, const void *value);
int up_get_reals(UpInstance *I, const char *fn, const unsigned int vr[], size_t nvr, double value[]);
int up_set_reals(UpInstance *I, const char *fn, const unsigned int vr[], size_t nvr, const double value[]);
int up_boolean_refs(UpInstance *I, const char *fn, const unsigned int vr[], size_t nvr, const void *value,
                    int setting);
int up_no_variables(UpInstance *I, const char *fn, const char *type, const unsigned int vr[], size_t nvr,
                    const void *value);

/* state.c: FMU states (0, or -1 with the reason logged) */
int up_state_get(UpInstance *I, const char *fn, void **s);
int up_state_set(UpInstance *I, const char *fn, void *s);
int up_state_free(UpInstance *I, const char *fn, void **s);
int up_state_size(UpInstance *I, const char *fn, void *s, size_t *size);
int up_state_serialize(UpInstance *I, const char *fn, void *s, unsigned char *bytes, size_t size);
int up_state_deserialize(UpInstance *I, const char *fn, const unsigned char *bytes, size_t size, void **s);

/* the states each entry point is allowed in (the co-simulation state machines; queries and FMU
   states in every state; Terminate also ends a failed start) */
#define MASK_fmi2SetDebugLogging UP_ANY_STATE
#define MASK_fmi2SetupExperiment UP_INSTANTIATED
#define MASK_fmi2EnterInitializationMode UP_INSTANTIATED
#define MASK_fmi2ExitInitializationMode UP_INITIALISATION
#define MASK_fmi2Terminate UP_ANY_STATE
#define MASK_fmi2Reset UP_ANY_STATE
#define MASK_fmi2GetReal UP_ANY_STATE
#define MASK_fmi2SetReal (UP_INSTANTIATED | UP_INITIALISATION | UP_STEPPING)
#define MASK_fmi2GetBoolean UP_ANY_STATE
#define MASK_fmi2SetBoolean UP_ANY_STATE          /* internal_motion: fixed, checked by variability */
#define MASK_fmi2GetFMUstate UP_ANY_STATE
#define MASK_fmi2SetFMUstate UP_ANY_STATE
#define MASK_fmi2FreeFMUstate UP_ANY_STATE
#define MASK_fmi2SerializedFMUstateSize UP_ANY_STATE
#define MASK_fmi2SerializeFMUstate UP_ANY_STATE
#define MASK_fmi2DeSerializeFMUstate UP_ANY_STATE
#define MASK_fmi2SetRealInputDerivatives UP_ANY_STATE
#define MASK_fmi2GetRealOutputDerivatives UP_ANY_STATE
#define MASK_fmi2DoStep UP_STEPPING
#define MASK_fmi2CancelStep UP_STEPPING

#define MASK_fmi3SetDebugLogging UP_ANY_STATE
#define MASK_fmi3EnterInitializationMode UP_INSTANTIATED
#define MASK_fmi3ExitInitializationMode UP_INITIALISATION
#define MASK_fmi3EnterEventMode UP_STEPPING        /* refused: the FMU has no event mode */
#define MASK_fmi3EnterStepMode 0                   /* event mode only, never entered */
#define MASK_fmi3EnterConfigurationMode (UP_INSTANTIATED | UP_STEPPING)   /* refused: N is fixed */
#define MASK_fmi3ExitConfigurationMode 0
#define MASK_fmi3Terminate UP_ANY_STATE
#define MASK_fmi3Reset UP_ANY_STATE
#define MASK_fmi3GetFloat64 UP_ANY_STATE
#define MASK_fmi3SetFloat64 (UP_INSTANTIATED | UP_INITIALISATION | UP_STEPPING)
#define MASK_fmi3GetUInt64 UP_ANY_STATE
#define MASK_fmi3SetUInt64 UP_ANY_STATE           /* N: a structural parameter, refused */
#define MASK_fmi3GetBoolean UP_ANY_STATE
#define MASK_fmi3SetBoolean UP_ANY_STATE          /* internal_motion: fixed, checked by variability */
#define MASK_fmi3GetFMUState UP_ANY_STATE
#define MASK_fmi3SetFMUState UP_ANY_STATE
#define MASK_fmi3FreeFMUState UP_ANY_STATE
#define MASK_fmi3SerializedFMUStateSize UP_ANY_STATE
#define MASK_fmi3SerializeFMUState UP_ANY_STATE
#define MASK_fmi3DeserializeFMUState UP_ANY_STATE
#define MASK_fmi3GetOutputDerivatives UP_ANY_STATE
#define MASK_fmi3DoStep UP_STEPPING

#endif

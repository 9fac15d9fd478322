/* The instance of a native uplift FMU and what the runtime's FMI files share:
     instance.c   instantiation: the resource file, the layout of the variables, the state block
     model.c      the model at the FMI boundary: initial state, one step of dt, the outputs
     variables.c  fmi2Get/Set of the variables
     state.c      FMU states: get, set, serialise (versioned, identified, CRC-32 checked)
     fmi2.c       the FMI 2.0 entry points of the life cycle and the step; the allowed-state
                  mask of every entry point, checked by one guard (up_guard)
   The refusal messages shared with the Python FMUs are in uplift_messages.h (generated from
   fmus/schema.py). */
#ifndef UPLIFT_FMU_H
#define UPLIFT_FMU_H

#include "fmi2Functions.h"
#include "uplift.h"
#include "uplift_messages.h"

/* FMI2_FUNCTION_PREFIX prefixes the entry points too, also with FMI 2.0 headers whose
   fmi2FullName ignores it (fmpy's) */
#ifdef FMI2_FUNCTION_PREFIX
#undef fmi2FullName
#define fmi2FullName(name) UP_PASTE(FMI2_FUNCTION_PREFIX, name)
#endif

enum { ROLE_SOIL, ROLE_STRUCTURE, ROLE_COUPLED };

/* the FMI states of an instance, one bit each (the masks of fmi2.c are unions of them) */
enum { UP_INSTANTIATED = 1 << 0, UP_INITIALISATION = 1 << 1, UP_STEPPING = 1 << 2, UP_TERMINATED = 1 << 3 };
#define UP_ANY_STATE (UP_INSTANTIATED | UP_INITIALISATION | UP_STEPPING | UP_TERMINATED)

/* the named vectors of Real variables: first value reference in the resource records vr.<name>
   (fmus.schema.SLOTS, looked up by name at instantiation) */
enum { S_X, S_XDOT, S_X_TIME, S_G, S_G_TIME, S_F, S_DISS, S_AG, S_P, S_GAP, S_NODES, S_ENERGY, S_NEWTON,
       S_MAX_UPLIFT, S_MAX_ROTATION, NSLOT };
extern const char *const up_slot_names[NSLOT];

typedef struct {
    uint64_t magic;
    int role, state, logging;
    char name[256];
    fmi2CallbackLogger logger;
    fmi2ComponentEnvironment env;
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
    const double *Gx, *Gv;                  /* (n, n), structure only */
    double dt, start_time, stop_time;       /* stop_time: +inf unless fmi2SetupExperiment defines it */
    uint64_t guid_hash;
    /* the state block and its parts */
    double *block, *backup, *saves, *tmp;
    size_t block_len;
    double *time, *internal_motion, *held_t, *bank, *held;
    int held_len;
    char err[UP_MSG];
} UpInstance;

#define UP_INSTANCE_MAGIC 0x75706c6966744e42ULL       /* "upliftNB" */

/* instance.c */
UpInstance *up_instance(fmi2Component c);                    /* NULL unless a live instance */
int up_setup(UpInstance *I, const char *guid, const char *uri);
void up_free_instance(UpInstance *I);
void up_log_error(UpInstance *I, const char *fmt, ...);       /* logStatusError, always */
void up_log_event(UpInstance *I, const char *fmt, ...);       /* logEvents, when logging is on */
const char *up_num(double v, char *buf);                      /* shortest round-trip decimal, buf[32] */
const char *up_element_name(const UpInstance *I, int slot, int i, char *buf);   /* "x[3]", "ag_x", buf[48] */

/* model.c */
enum { UP_REFUSED = 1, UP_FAILED = 2 };
double *up_var(UpInstance *I, int slot);
int up_initial_state(UpInstance *I);                          /* 0, or -1 with I->err */
int up_step(UpInstance *I, double t);                         /* 0, UP_REFUSED or UP_FAILED with I->err */

/* fmi2.c: the guard opening every entry point: the instance, if it is one and the call is
   allowed in its state (mask: MASK_<entry point>), else NULL with the reason logged */
UpInstance *up_guard(fmi2Component c, int mask, const char *fn);
#define UP_GUARD(fn)                                    \
    UpInstance *I = up_guard(c, MASK_##fn, #fn);        \
    if (!I)                                             \
    return fmi2Error

/* the states each entry point is allowed in (FMI 2.0, co-simulation state machine; queries and
   FMU states in every state; fmi2Terminate also ends a failed start) */
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

/* variables.c */
int up_check_refs(UpInstance *I, const char *fn, const fmi2ValueReference vr[], size_t nvr, const void *value);

/* state.c */
uint32_t up_crc32(const unsigned char *p, size_t n);

#endif

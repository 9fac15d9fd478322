/* Generated from fmus/schema.py by fmus.schema.c_messages_header(): do not edit.
   The refusals both kinds of FMU make (printf formats, fields as %s in the order of
   the Python template) and the limits of the FMI boundary. */
#ifndef UPLIFT_MESSAGES_H
#define UPLIFT_MESSAGES_H

#define UP_MSG_REFUSED "step from t = %s s refused: %s"
#define UP_MSG_BEFORE_INIT "%s before initialisation (call %sExitInitializationMode first)"
#define UP_MSG_WRONG_STATE "%s is not allowed %s (%s co-simulation state machine)"
#define UP_MSG_AFTER_TERMINATE "%s after %sTerminate (instantiate the FMU again)"
#define UP_MSG_WRONG_TIME "this FMU is at t = %s s: steps must follow one another (restore an FMU state to go back)"
#define UP_MSG_BAD_STEP "communication step %s s: a step must be finite and positive"
#define UP_MSG_WRONG_STEP "communication step %s s: this FMU steps %s %s s per communication step (export it again with the step you need)"
#define UP_MSG_TOO_MANY_STEPS "communication step %s s: more than %s steps of %s s in one communication step (call doStep more often)"
#define UP_MSG_PAST_STOP "communication step %s s ends at %s s, past the stop time %s s given to %s"
#define UP_MSG_NOT_FINITE "input %s = %s: inputs must be finite (check what is connected to it)"
#define UP_MSG_STAMP "input %s is stamped %s = %s s at a step from t = %s s: it must be the partner's output at t or at t + dt (connect the partner's %s output to this input, with %s)"
#define UP_MSG_START_TIME "start time %s s: this FMU starts at t = 0 s, at rest, with the first sample of its record"
#define UP_MSG_NO_MOTION "internal_motion = true but this FMU was exported without a motion: set internal_motion = false and drive the inputs ag_x, ag_y, ag_z"
#define UP_MSG_BAD_STATE "the %s bytes are not a serialised state of this FMU: %s"
#define UP_MSG_STATE_MAGIC "not an uplift FMU state"
#define UP_MSG_STATE_VERSION "format version %s, this FMU reads version %s"
#define UP_MSG_STATE_IDENTITY "a state of another FMU (GUID hash %s, this FMU %s)"
#define UP_MSG_STATE_SIZE "size or length mismatch"
#define UP_MSG_STATE_CHECKSUM "checksum mismatch (the bytes changed since they were written)"

#define UP_SLIVER 1e-06
#define UP_STEP_RTOL 1e-09
#define UP_TIME_TOL 1e-06
#define UP_MAX_STEPS_PER_CALL 100000
#define UP_STATE_VERSION 2

#endif

"""The life cycle of the Python FMUs (pythonfmu slaves): the checked calls, the steps and the
FMU state, shared by fmus/soil_fmu.py, structure_fmu.py and coupled_fmu.py."""
from __future__ import annotations

import json
import math
import sys
import traceback

import numpy as np

from fmus.real_variables import add_units
from fmus.coupling import StepRefused
from fmus.fmu_state import StateRefused, copy_state, identity, state_from_bytes, state_to_bytes
from fmus.resources import PREFIX, REQUIREMENTS_FILE, adopt_resources
from fmus.schema import MAX_STEPS_PER_CALL, SLIVER, STEP_RTOL, TIME_TOL, message


def survive_fatal(slave) -> None:
    """Call before raising out of a method pythonfmu's wrapper calls. The wrapper answers an
    exception with fmi2Fatal and releases the Python object, its class and its log queue,
    and releases them again when the host frees the instance: one reference more to each
    keeps the counts right, so the instance still answers a host that calls again and a later
    fmi2FreeInstance does not corrupt the interpreter (a crash at the next garbage collection)."""
    import ctypes
    for obj in (slave, type(slave), slave.log_queue):
        ctypes.pythonapi.Py_IncRef(ctypes.py_object(obj))


def forget_repeated_path(folder: str) -> None:
    """pythonfmu puts the resources folder at the front of sys.path at every instantiation and
    never takes it out (one entry more per instance, for ever, in a host that instantiates
    often): keep its first entry only."""
    if sys.path.count(folder) > 1:
        first = sys.path.index(folder)
        sys.path[:] = [p for i, p in enumerate(sys.path) if p != folder or i == first]


class BankedSlave:
    """Mixin for the pythonfmu slaves: Real variables in one numpy bank (one gather or scatter
    per FMI call), a checked life cycle and the FMU state serialised as npz bytes. The slave
    names its engine attribute (``engine``: the stepper or the soil object, None until built),
    its input slots (``inputs``: names of input vectors checked finite before a step) and
    defines ``_build`` and ``_step(t)``.

    Failures, as pythonfmu lets a Python FMU report them (a Python method either succeeds, or
    returns False from ``do_step``: fmi2Discard, or raises: fmi2Fatal with the exception in the
    log): a model that cannot be built is logged with the cause and the fix by
    ``enter_initialization_mode``, then ``exit_initialization_mode`` raises; a step that cannot
    be right (wrong time or step size, a non-finite input, a wrong stamp, called before a
    successful initialisation or after ``terminate``, not finite or negative, past the stop time
    given to ``setup_experiment``, more than MAX_STEPS_PER_CALL steps of dt) raises
    ``StepRefused`` with the reason (fmus.schema.MESSAGES)
    (fmi2Fatal: a host such as fmpy's simulate_fmu stops on it, where it would end a run silently
    on fmi2Discard); a step that fails (no Newton convergence) is logged and discarded. Either
    way the instance is left as it was and still answers (``survive_fatal``); an unknown value
    reference in a getter or setter is fmi2Fatal too, with the range in the message, and so is
    a serialised state that fails its checks (fmus.fmu_state). A step shorter than SLIVER dt
    is a no-op that succeeds (a host's time accumulated by repeated addition ends with one).
    """

    engine = "stepper"
    inputs: tuple = ()
    #: a communication step may be a multiple of dt (steps of dt inside); False: exactly dt (the
    #: pair, whose coupling is exchanged every dt)
    multistep = False
    #: the build key (parameters and inputs) the model was built with, and last tried with
    _built_with = _tried_with = None

    def _init_life_cycle(self, dt: float) -> None:
        from pythonfmu.default_experiment import DefaultExperiment
        adopt_resources(self.resources)
        forget_repeated_path(str(self.resources))
        self.default_experiment = DefaultExperiment(0.0, self.settings.get("stop_time"), float(dt))
        self.dt = float(dt)
        self.time = 0.0
        self.stop_time = None
        self.phase = "instantiated"
        self.last_error = ""
        self.identity = identity(f"{type(self).__name__}\0{json.dumps(self.settings, sort_keys=True)}\0"
                                 f"{PREFIX}")

    def to_xml(self, model_options=None):
        root = super().to_xml(model_options or {})
        add_units(root, getattr(self, "units", {}))
        return root

    def get_real(self, vrs):
        return self.bank.values[self._index(vrs)].tolist()

    def set_real(self, vrs, values):
        self.bank.values[self._index(vrs)] = values

    def _index(self, vrs):
        try:
            return self.bank.index(vrs)
        except IndexError:
            survive_fatal(self)
            raise

    def setup_experiment(self, start_time, stop_time, tolerance):
        self.start_time = start_time
        self.stop_time = None if stop_time is None else float(stop_time)

    def enter_initialization_mode(self):
        self._try_build()

    def exit_initialization_mode(self):
        if self._tried_with != self._build_key():       # a parameter or input set in between
            self._try_build()
        if self._built_with is None:
            # the reason was logged when the build failed; a build that failed is not tried again
            # with the same inputs: a message logged in the call that raises turns pythonfmu's
            # report of the exception into "unknown error"
            survive_fatal(self)
            raise RuntimeError(self.last_error)
        self.time, self.phase = 0.0, "stepping"

    def _build_key(self):
        return getattr(self, "internal_motion", None), self.bank.values.tobytes()

    def _try_build(self):
        """Build the model, or log why not (the message reaches the host here: pythonfmu drops
        the message of an exception, so exit_initialization_mode only raises after this)."""
        self._built_with = None
        self._tried_with = self._build_key()
        start = getattr(self, "start_time", 0.0) or 0.0
        try:
            if start != 0.0:
                raise ValueError(message("start_time", start=repr(start)))
            self._build()
        except Exception as exc:                        # the FMU boundary: logged with the fix
            self._fail("initialisation failed", exc)
            return
        self._built_with = self._build_key()

    def terminate(self):
        self.phase = "terminated"

    def do_step(self, current_time, step_size):
        saved = None
        try:
            n = self._check_step(current_time, step_size)
            if n == 0:                               # a sliver: nothing to compute
                self.time = current_time + step_size
                return True
            saved = self._get_fmu_state()
            for i in range(n):
                self._step(current_time + i * self.dt)
        except StepRefused as exc:               # a call that cannot be right: fmi2Fatal, with
            if saved is not None:                # this message in pythonfmu's log line
                self._set_fmu_state(saved)
            self.last_error = message("refused", t=repr(current_time), why=exc)
            survive_fatal(self)
            raise StepRefused(self.last_error) from None
        except Exception as exc:                 # the step failed (Newton): logged, discarded
            self._set_fmu_state(saved)
            self._fail(f"step from t = {current_time!r} s failed", exc)
            return False
        self.time = current_time + step_size
        return True

    def _check_step(self, t, step_size) -> int:
        """The number of steps of dt in the communication step (0: a sliver), or StepRefused."""
        if self.phase != "stepping":
            key = {"instantiated": "before_init", "terminated": "after_terminate"}[self.phase]
            raise StepRefused(message(key, call="doStep"))
        dt = self.dt
        if not (math.isfinite(t) and abs(t - self.time) <= TIME_TOL * dt):
            raise StepRefused(message("wrong_time", time=repr(self.time)))
        if not (math.isfinite(step_size) and step_size >= 0):
            raise StepRefused(message("bad_step", h=repr(step_size)))
        if self.stop_time is not None and t + step_size > self.stop_time + TIME_TOL * dt:
            raise StepRefused(message("past_stop", h=repr(step_size), end=repr(t + step_size),
                                      stop=repr(self.stop_time)))
        if step_size < SLIVER * dt:
            return 0
        n = round(step_size / dt) if self.multistep else 1
        if n > MAX_STEPS_PER_CALL:
            raise StepRefused(message("too_many_steps", h=repr(step_size), limit=MAX_STEPS_PER_CALL, dt=repr(dt)))
        if n < 1 or abs(step_size - n * dt) > STEP_RTOL * step_size:
            raise StepRefused(message("wrong_step", h=repr(step_size), allowed="a multiple" if self.multistep
                                      else "exactly", dt=repr(dt)))
        v = self.bank.values
        for name in self.inputs:
            bad = np.flatnonzero(~np.isfinite(v[self.sl[name]]))
            if bad.size:
                vr = self.sl[name].start + int(bad[0])
                raise StepRefused(message("not_finite", name=self.vars[vr].name, value=repr(v[vr])))
        return n

    def _fail(self, what, exc):
        from pythonfmu.enums import Fmi2Status
        self.last_error = f"{what}: {type(exc).__name__}: {exc}"
        if isinstance(exc, ImportError):
            self.last_error += (f" (the host Python lacks a package this FMU needs: "
                                f"pip install -r {self.resources}/{REQUIREMENTS_FILE})")
        self.log(self.last_error + "\n" + traceback.format_exc(), Fmi2Status.error)

    # ---- FMU state: time, variables, pending stamped inputs and the engine's own state ------
    # pythonfmu calls the (de)serialiser on the class, not on the instance: the state carries the
    # FMU's identity, a buffer that fails its checks deserialises to a refusal (never an
    # exception there: pythonfmu's wrapper would release an instance it cannot name), and
    # setting either kind of bad state is refused with the reason in the log, the instance as it was.
    def _get_fmu_state(self):
        state = {"identity": self.identity, "time": self.time, "bank": self.bank.values.copy(),
                 "held": {k: s.get_state() for k, s in self.stamped.items()}}
        if getattr(self, self.engine) is not None:
            state["engine"] = copy_state(self._engine_state())
        return state

    def _set_fmu_state(self, state):
        why = state.get("refused")
        if why is None and state.get("identity") != self.identity:
            why = message("state_identity", got=f"{int(state.get('identity', 0)):016x}", expected=f"{self.identity:016x}")
        if why is not None:              # the reason in the exception only: a message logged
            self.last_error = f"fmi2SetFMUstate: {why}"      # before raising turns pythonfmu's
            survive_fatal(self)                               # report of it into "unknown error"
            raise StateRefused(self.last_error)
        self.time = float(state["time"])
        self.bank.values[:] = state["bank"]
        for k, s in self.stamped.items():
            s.set_state(state["held"][k])
        if "engine" in state and getattr(self, self.engine) is not None:
            self._restore_engine(copy_state(state["engine"]))

    @staticmethod
    def _fmu_state_to_bytes(state):
        return state_to_bytes(state, int(state["identity"]))

    @staticmethod
    def _fmu_state_from_bytes(data):
        try:
            return state_from_bytes(data)
        except StateRefused as exc:
            return {"refused": str(exc)}

"""What the FMU adapters share: the resources they read, the soil they rebuild, the split
coupling that makes the pair exact under any master, a flat bank of Real variables, FMU-state
serialisation and the guarded life cycle.

No numerics here: the adapters call ``structure.NewmarkStepper`` and the soil object built
from the resources, exactly as the in-process (monolithic) route does.

Resources (inside ``resources/`` of each FMU, written by ``fmus.build``)::

    uplift_<role>.json    settings: dt, the soil factory, the structure spec, contact, outputs
    uplift_soil_model.npz the rational soil model (poles, residues, D, E, dofs)
    uplift_mesh.npz       xy (N, 2) m, area (N,) m^2 of the interface nodes (structure, coupled)
    uplift_soil_instantaneous.npz  K0, C0 at the FMU's dt, K_static of the soil and the history
                          gains Gx, Gv (structure only: it folds them in without the soil)
    uplift_motion.npz     acc (nt, 3) m/s^2, dt s: the bundled ground motion (structure, coupled)
    requirements.txt      what the host Python needs (pythonfmu FMUs run in the host's Python)

A soil is "any object following the soil protocol" (structure.soil_interface) that a factory
``"module:callable"`` builds as ``factory(model, dt, **kwargs)`` from the RationalModel in the
resources (the default factory is ``soil_impedance.convolution:RecursiveConvolutionSoil``).

The split coupling (docs/formulation.md). The force on the soil at step k is
f_k = K0 x_k + C0 xdot_k + h_k with h_k depending on the past only. For a linear soil,
h_{k+1} = g_{k+1} + Gx x_k + Gv xdot_k where g_{k+1} depends on the states up to k − 1 only:
the soil FMU publishes g (``history_ahead``), the structure FMU adds the part driven by its
own latest state with the constant gains (``history_gains``, measured at export). A parallel
(Jacobi) master hands the structure the soil's g one step after the soil computed it, which is
exactly when it is needed, so the pair is exact under Jacobi; the time stamps x_time and
g_time (``StampedInput``) make it exact under either sequential (Gauss-Seidel) order too.
"""
from __future__ import annotations

import importlib
import io
import json
import sys
import traceback
from pathlib import Path

import numpy as np

DEFAULT_SOIL_FACTORY = "soil_impedance.convolution:RecursiveConvolutionSoil"
SOIL_MODEL_FILE = "uplift_soil_model.npz"
SOIL_INSTANT_FILE = "uplift_soil_instantaneous.npz"
MESH_FILE = "uplift_mesh.npz"
MOTION_FILE = "uplift_motion.npz"
REQUIREMENTS_FILE = "requirements.txt"
#: what the host Python needs, written to resources/requirements.txt (pip format)
REQUIREMENTS = ("numpy>=1.24", "scipy>=1.10", 'tomli>=2.0; python_version < "3.11"')


# ---- resources --------------------------------------------------------------------------------
def read_settings(resources, role: str) -> dict:
    return json.loads((Path(resources) / f"uplift_{role}.json").read_text())


def save_rational(path, model) -> None:
    """Write a RationalModel to npz (no pickles)."""
    np.savez(path, poles=model.poles, residues=model.residues, D=model.D, E=model.E,
             dofs=np.array(model.dofs, dtype=str),
             provenance=np.array(json.dumps(model.provenance, default=str)))


def load_rational(path):
    from soil_impedance.rational import RationalModel
    with np.load(path, allow_pickle=False) as z:
        return RationalModel(z["poles"], z["residues"], z["D"], z["E"], [str(d) for d in z["dofs"]],
                             json.loads(str(z["provenance"])))


#: the private package of the code inside an FMU (fmus.build.bundle), "" in the project: a
#: factory named "soil_impedance.convolution:..." or a bundled module loads the bundled copy
PREFIX = __name__[:-len("fmus.common")]


def adopt_resources(resources) -> None:
    """Inside an FMU, point the bundled package at this instance's resources (its ``adopt``,
    see fmus.build.PACKAGE_INIT); nothing in the project itself."""
    if PREFIX:
        sys.modules[PREFIX.rstrip(".")].adopt(str(resources))


def import_object(spec: str):
    """``"package.module:attr"`` -> the object (a soil factory): the bundled module inside an
    FMU, else the host's."""
    module, _, attr = spec.partition(":")
    if not attr:
        raise ValueError(f"soil factory {spec!r} must read 'module:callable'")
    try:
        obj = importlib.import_module(PREFIX + module)
    except ModuleNotFoundError:
        if not PREFIX:
            raise
        obj = importlib.import_module(module)
    for part in attr.split("."):
        obj = getattr(obj, part)
    return obj


def make_soil(resources, settings: dict):
    """The soil object of the resources: factory(RationalModel, dt, **kwargs)."""
    soil = settings["soil"]
    model = load_rational(Path(resources) / SOIL_MODEL_FILE)
    return soil_from_model(model, settings["dt"], soil["factory"], soil.get("kwargs", {}))


def soil_from_model(model, dt: float, factory: str = DEFAULT_SOIL_FACTORY, kwargs: dict | None = None):
    """The soil object ``factory(model, dt, **kwargs)`` (the recursive convolution's
    constructor tests passivity unless ``checked=True``: the exported FMUs pass it, the
    exporter having tested it once)."""
    return import_object(factory)(model, float(dt), **dict(kwargs or {}))


# ---- the split coupling ------------------------------------------------------------------
def history_gains(soil, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(Gx, Gv), each (n, n): how the history force of the step after next depends on the next
    committed state, h_{k+2} = g_{k+2} + Gx x_{k+1} + Gv xdot_{k+1}. Constant for a linear soil
    at a fixed dt; measured on a soil at rest (where g = 0) by committing unit states, 2n
    commits, once at export. The soil is left at rest."""
    n = soil.n_dof
    soil.instantaneous(dt)
    rest = soil.get_state()
    zero, e = np.zeros(n), np.zeros(n)
    Gx, Gv = np.empty((n, n)), np.empty((n, n))
    for i in range(n):
        e[i] = 1.0
        for G, state in ((Gx, (e, zero)), (Gv, (zero, e))):
            soil.set_state(rest)
            soil.commit(*state)
            G[:, i] = soil.history()
        e[i] = 0.0
    soil.set_state(rest)
    return Gx, Gv


def history_ahead(soil) -> np.ndarray:
    """g_{k+2} (n,), N: the history force of the step after next with a zero state committed
    next, i.e. the part of h_{k+2} that does not depend on x_{k+1}, xdot_{k+1}. The soil is
    left as it was."""
    saved = soil.get_state()
    zero = np.zeros(soil.n_dof)
    soil.commit(zero, zero)
    g = soil.history()
    soil.set_state(saved)
    return g


class StepRefused(ValueError):
    """A call the FMU refuses (wrong time, step size or state, non-finite input, a wrong stamp):
    the call fails with this message, the instance is left as it was."""


class StampedInput:
    """An input vector sent with the time it belongs to (the partner FMU's own time), so that
    one FMU is exact under any master.

    At a step from t, a parallel (Jacobi) master hands over the partner's outputs at t; a
    sequential (Gauss-Seidel) master that stepped the partner first hands over its outputs at
    t + dt. The stamp tells which: values of t are used now; values of t + dt are held for the
    next step and the values held from the previous step (those of t) are used now. Both FMUs
    start at rest, so the values held at t = 0 are ``rest``. Any other stamp is a wiring error.
    """

    def __init__(self, name: str, stamp_name: str, rest):
        self.name, self.stamp_name = name, stamp_name
        self.held_t, self.held = 0.0, np.array(rest, float)

    def take(self, t: float, dt: float, stamp: float, values) -> np.ndarray:
        stamp, tol = float(stamp), 1e-6 * dt
        if abs(stamp - t) <= tol:
            return values
        if abs(stamp - (t + dt)) <= tol and abs(self.held_t - t) <= tol:
            used, self.held_t, self.held = self.held, float(stamp), np.array(values, float)
            return used
        raise StepRefused(
            f"input {self.name} is stamped {self.stamp_name} = {stamp!r} s at a step from t = {t!r} s: "
            f"it must be the partner's output at t or at t + dt (connect the partner's "
            f"{self.stamp_name} output to this input, with {self.name})")

    def get_state(self) -> dict:
        return {"t": self.held_t, "values": self.held.copy()}

    def set_state(self, state: dict) -> None:
        self.held_t, self.held = float(state["t"]), np.array(state["values"], float)


# ---- a flat bank of Real variables ----------------------------------------------------------
class RealBank:
    """All Real variables of an FMU in one float64 vector indexed by value reference.

    pythonfmu calls ``get_real(vrs)`` / ``set_real(vrs, values)`` once per FMI call with a
    fresh Python list of value references; with the bank these are one numpy gather / scatter
    instead of one Python getter per scalar (a 247-DOF interface would otherwise cost ~1000
    Python calls per step). ``index(vrs)`` memoises the list -> index conversion, since a host
    asks for the same lists every step.
    """

    MAX_INDICES = 64                    # memoised value-reference lists (a host uses a few)

    def __init__(self):
        self.values = np.zeros(0)
        self.slots = {}                 # name -> slice or index into values
        self._indices = {}              # (len, first, last) -> (the list, its index)

    def grow(self, n: int) -> None:
        self.values = np.concatenate([self.values, np.zeros(n)])

    def index(self, vrs):
        """Index into ``values`` of the value references ``vrs`` (a list): a slice when they are
        consecutive, else an int array. Memoised; a hit is checked against the whole list
        (one C-level list comparison), so it is exact."""
        if type(vrs) is not list:       # pythonfmu passes lists; anything else is made one
            vrs = [int(v) for v in vrs]
        key = (len(vrs), vrs[0], vrs[-1]) if vrs else ()
        hit = self._indices.get(key)
        if hit is not None and hit[0] == vrs:
            return hit[1]
        idx = np.asarray(vrs, int)
        if idx.size and not 0 <= idx.min() <= idx.max() < self.values.size:
            raise IndexError(f"value references {idx.min()}..{idx.max()}: the Real variables of "
                             f"this FMU are 0..{self.values.size - 1}")
        if idx.size and np.array_equal(idx, np.arange(idx[0], idx[0] + idx.size)):
            idx = slice(int(idx[0]), int(idx[0]) + idx.size)
        if len(self._indices) >= self.MAX_INDICES:
            self._indices.clear()
        self._indices[key] = (list(vrs), idx)
        return idx


def register_vector(fmu, name: str, n: int, causality, variability=None, start=0.0,
                    description: str = "", unit=None):
    """Register Real variables ``name[0]..name[n-1]`` (or the scalar ``name`` when n is None)
    backed by fmu.bank; returns the slice of the bank holding them. Value references are
    allocated in order, so the bank index of a Real variable is its value reference. ``unit``:
    one unit for all, or one per element (see UNITS; written by ``BankedSlave.to_xml``)."""
    from pythonfmu import Real
    from pythonfmu.enums import Fmi2Variability

    bank = fmu.bank
    first = len(fmu.vars)
    if first != bank.values.size:
        raise RuntimeError("register all Real variables through register_vector, before any other")
    count = 1 if n is None else n
    bank.grow(count)
    bank.values[first:first + count] = start
    units = fmu.__dict__.setdefault("units", {})
    for i in range(count):
        vr = first + i
        vname = name if n is None else f"{name}[{i}]"
        kw = dict(causality=causality, description=description,
                  getter=(lambda vr=vr: float(bank.values[vr])))
        if variability is not None:
            kw["variability"] = variability
        if variability != Fmi2Variability.constant:
            kw["setter"] = lambda v, vr=vr: bank.values.__setitem__(vr, v)
        fmu.register_variable(Real(vname, **kw), nested=False)
        if unit is not None:
            units[vname] = unit if isinstance(unit, str) else unit[i]
    sl = slice(first, first + count)
    bank.slots[name] = sl
    return sl


#: the SI units the FMUs use, as exponents of the SI base units (FMI 2.0 BaseUnit)
UNITS = {"1": {}, "s": {"s": 1}, "m": {"m": 1}, "rad": {"rad": 1}, "m/s": {"m": 1, "s": -1},
         "rad/s": {"rad": 1, "s": -1}, "m/s2": {"m": 1, "s": -2}, "N": {"kg": 1, "m": 1, "s": -2},
         "N.m": {"kg": 1, "m": 2, "s": -2}, "J": {"kg": 1, "m": 2, "s": -2}}


def interface_units(n: int, translation: str, rotation: str) -> tuple:
    """Units of an interface vector [q, w] (n = 6 + N): q = (ux, uy, uz, rx, ry, rz), w."""
    return (translation,) * 3 + (rotation,) * 3 + (translation,) * (n - 6)


def add_units(root, units: dict) -> None:
    """Write ``unit`` on the Real variables named in ``units`` and the UnitDefinitions they use
    into a modelDescription element tree (UnitDefinitions placed after CoSimulation, as FMI 2.0
    orders the elements)."""
    import xml.etree.ElementTree as ET

    used = []
    for sv in root.iter("ScalarVariable"):
        unit = units.get(sv.get("name"))
        if unit is not None:
            sv.find("Real").set("unit", unit)
            used.append(unit)
    if not used:
        return
    defs = ET.Element("UnitDefinitions")
    for unit in dict.fromkeys(used):
        ET.SubElement(ET.SubElement(defs, "Unit", name=unit), "BaseUnit",
                      {k: str(v) for k, v in UNITS[unit].items()})
    after = [i for i, el in enumerate(root) if el.tag in ("CoSimulation", "ModelExchange")]
    root.insert(after[-1] + 1 if after else 0, defs)


# ---- FMU state ----------------------------------------------------------------------------------
def flatten(tree: dict, prefix: str = "") -> dict:
    """Nested dict of arrays / numbers -> {"a/b": ndarray} (for npz, no pickles)."""
    out = {}
    for key, value in tree.items():
        k = f"{prefix}{key}"
        if isinstance(value, dict):
            out[f"{k}/"] = np.zeros(0)          # marks an (possibly empty) sub-dict
            out.update(flatten(value, f"{k}/"))
        else:
            out[k] = np.asarray(value)
    return out


def unflatten(flat: dict) -> dict:
    tree: dict = {}
    for key in sorted(flat, key=len):
        parts = key.split("/")
        node = tree
        for p in parts[:-1]:
            node = node.setdefault(p, {})
        if parts[-1]:
            v = flat[key]
            node[parts[-1]] = v.item() if v.ndim == 0 and v.dtype.kind in "fiub" else v
    return tree


def state_to_bytes(state: dict) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **flatten(state))
    return buf.getvalue()


def state_from_bytes(data: bytes) -> dict:
    with np.load(io.BytesIO(bytes(data)), allow_pickle=False) as z:
        return unflatten({k: z[k] for k in z.files})


def copy_state(state: dict) -> dict:
    return {k: copy_state(v) if isinstance(v, dict) else np.array(v, copy=True) if isinstance(v, np.ndarray)
            else v for k, v in state.items()}


# ---- the life cycle ------------------------------------------------------------------------
def survive_fatal(slave) -> None:
    """Call before raising out of a method pythonfmu's wrapper calls. The wrapper answers an
    exception with fmi2Fatal and releases the Python object, its class and its log queue,
    and releases them again when the host frees the instance: one reference more to each
    keeps the counts right, so the instance still answers a host that calls again and a later
    fmi2FreeInstance does not corrupt the interpreter (a crash at the next garbage collection)."""
    import ctypes
    for obj in (slave, type(slave), slave.log_queue):
        ctypes.pythonapi.Py_IncRef(ctypes.py_object(obj))


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
    successful initialisation or after ``terminate``) raises ``StepRefused`` with the reason
    (fmi2Fatal: a host such as fmpy's simulate_fmu stops on it, where it would end a run silently
    on fmi2Discard); a step that fails (no Newton convergence) is logged and discarded. Either
    way the instance is left as it was and still answers (``survive_fatal``); an unknown value
    reference in a getter or setter is fmi2Fatal too, with the range in the message.
    """

    engine = "stepper"
    inputs: tuple = ()
    #: a communication step may be a multiple of dt (steps of dt inside); False: exactly dt (the
    #: pair, whose coupling is exchanged every dt)
    multistep = False

    def _init_life_cycle(self, dt: float) -> None:
        from pythonfmu.default_experiment import DefaultExperiment
        adopt_resources(self.resources)
        self.default_experiment = DefaultExperiment(0.0, self.settings.get("stop_time"), float(dt))
        self.dt = float(dt)
        self.time = 0.0
        self.phase = "instantiated"
        self.last_error = ""

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

    def enter_initialization_mode(self):
        self._try_build()

    def exit_initialization_mode(self):
        if self._built_with != self._build_key():       # a parameter or input set in between
            self._try_build()
        if self._built_with is None:
            survive_fatal(self)
            raise RuntimeError(self.last_error)
        self.time, self.phase = 0.0, "stepping"

    def _build_key(self):
        return getattr(self, "internal_motion", None), self.bank.values.tobytes()

    def _try_build(self):
        """Build the model, or log why not (the message reaches the host here: pythonfmu drops
        the message of an exception, so exit_initialization_mode only raises after this)."""
        self._built_with = None
        start = getattr(self, "start_time", 0.0) or 0.0
        try:
            if start != 0.0:
                raise ValueError(f"start time {start!r} s: this FMU starts at t = 0 s, at rest, "
                                 "with the first sample of its record")
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
            saved = self._get_fmu_state()
            for i in range(n):
                self._step(current_time + i * self.dt)
        except StepRefused as exc:               # a call that cannot be right: fmi2Fatal, with
            if saved is not None:                # this message in pythonfmu's log line
                self._set_fmu_state(saved)
            self.last_error = f"step from t = {current_time!r} s refused: {exc}"
            survive_fatal(self)
            raise StepRefused(self.last_error) from None
        except Exception as exc:                 # the step failed (Newton): logged, discarded
            self._set_fmu_state(saved)
            self._fail(f"step from t = {current_time!r} s failed", exc)
            return False
        self.time = current_time + step_size
        return True

    def _check_step(self, t, step_size):
        if self.phase != "stepping":
            why = {"instantiated": "before initialisation (call fmi2ExitInitializationMode first)",
                   "terminated": "after fmi2Terminate (instantiate the FMU again)"}[self.phase]
            raise StepRefused(f"doStep {why}")
        if not (np.isfinite(t) and abs(t - self.time) <= 1e-6 * self.dt):
            raise StepRefused(f"this FMU is at t = {self.time!r} s: steps must follow one another "
                              "(restore an FMU state to go back)")
        n = round(step_size / self.dt) if self.multistep and np.isfinite(step_size) else 1
        if n < 1 or abs(step_size - n * self.dt) > 1e-9 * step_size:
            allowed = "a multiple" if self.multistep else "exactly"
            raise StepRefused(f"communication step {step_size!r} s: this FMU steps {allowed} {self.dt!r} s "
                              "per communication step (export it again with the step you need)")
        v = self.bank.values
        for name in self.inputs:
            bad = np.flatnonzero(~np.isfinite(v[self.sl[name]]))
            if bad.size:
                raise StepRefused(f"input {name}[{bad[0]}] = {v[self.sl[name]][bad[0]]!r}: inputs must be "
                                  "finite (check what is connected to it)")
        return n

    def _fail(self, what, exc):
        from pythonfmu.enums import Fmi2Status
        self.last_error = f"{what}: {type(exc).__name__}: {exc}"
        if isinstance(exc, ImportError):
            self.last_error += (f" (the host Python lacks a package this FMU needs: "
                                f"pip install -r {self.resources}/{REQUIREMENTS_FILE})")
        self.log(self.last_error + "\n" + traceback.format_exc(), Fmi2Status.error)

    # ---- FMU state: time, variables, pending stamped inputs and the engine's own state ------
    def _get_fmu_state(self):
        state = {"time": self.time, "bank": self.bank.values.copy(),
                 "held": {k: s.get_state() for k, s in self.stamped.items()}}
        if getattr(self, self.engine) is not None:
            state["engine"] = copy_state(self._engine_state())
        return state

    def _set_fmu_state(self, state):
        self.time = float(state["time"])
        self.bank.values[:] = state["bank"]
        for k, s in self.stamped.items():
            s.set_state(state["held"][k])
        if "engine" in state and getattr(self, self.engine) is not None:
            self._restore_engine(copy_state(state["engine"]))

    @staticmethod
    def _fmu_state_to_bytes(state):
        return state_to_bytes(state)

    @staticmethod
    def _fmu_state_from_bytes(data):
        return state_from_bytes(data)

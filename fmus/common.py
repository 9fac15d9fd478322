"""What both FMU adapters share: the resources they read, the soil they rebuild, a flat bank
of Real variables, FMU-state serialisation and the guarded ``do_step``.

No numerics here: the adapters call ``structure.NewmarkStepper`` and the soil object built
from the resources, exactly as the in-process (monolithic) route does.

Resources (inside ``resources/`` of each FMU, written by ``fmus.build``)::

    uplift_<role>.json    settings: dt, the soil factory, the structure spec, contact, outputs
    uplift_soil_model.npz the rational soil model (poles, residues, D, E, dofs)
    uplift_mesh.npz       xy (N, 2) m, area (N,) m^2 of the interface nodes (structure only)
    uplift_soil_instantaneous.npz  K0, C0 at the FMU's dt and K_static of the soil (structure
                          only: the structure folds them in without constructing the soil)
    uplift_motion.npz     acc (nt, 3) m/s^2, dt s: the bundled ground motion (structure only)

A soil is "any object following the soil protocol" (structure.soil_interface) that a factory
``"module:callable"`` builds as ``factory(model, dt, **kwargs)`` from the RationalModel in the
resources (the default factory is ``soil_impedance.convolution:RecursiveConvolutionSoil``).
"""
from __future__ import annotations

import importlib
import io
import json
import traceback
from pathlib import Path

import numpy as np

DEFAULT_SOIL_FACTORY = "soil_impedance.convolution:RecursiveConvolutionSoil"
SOIL_MODEL_FILE = "uplift_soil_model.npz"
SOIL_INSTANT_FILE = "uplift_soil_instantaneous.npz"
MESH_FILE = "uplift_mesh.npz"
MOTION_FILE = "uplift_motion.npz"


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


def import_object(spec: str):
    """``"package.module:attr"`` -> the object (a soil factory)."""
    module, _, attr = spec.partition(":")
    if not attr:
        raise ValueError(f"soil factory {spec!r} must read 'module:callable'")
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
    """The soil object ``factory(model, dt, **kwargs)`` (one construction per call: the
    recursive convolution's constructor checks passivity, ~15-30 s for 247 DOFs)."""
    return import_object(factory)(model, float(dt), **dict(kwargs or {}))


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
                    description: str = "", indexed: bool = True):
    """Register Real variables ``name[0]..name[n-1]`` (or the scalar ``name`` when n is None)
    backed by fmu.bank; returns the slice of the bank holding them. Value references are
    allocated in order, so the bank index of a Real variable is its value reference."""
    from pythonfmu import Real
    from pythonfmu.enums import Fmi2Variability

    bank = fmu.bank
    first = len(fmu.vars)
    if first != bank.values.size:
        raise RuntimeError("register all Real variables through register_vector, before any other")
    count = 1 if n is None else n
    bank.grow(count)
    bank.values[first:first + count] = start
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
    sl = slice(first, first + count)
    bank.slots[name] = sl
    return sl


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


# ---- guarded step -------------------------------------------------------------------------------
def guarded(fmu, what: str, fn, *args) -> bool:
    """Run fn(*args); on any exception log it through the FMU logger (status error) and return
    False, so the host sees a failed step (fmi2Error) instead of a crash."""
    from pythonfmu.enums import Fmi2Status
    try:
        fn(*args)
        return True
    except Exception as exc:                  # the FMU boundary: any error is logged, never raised
        fmu.last_error = f"{what}: {type(exc).__name__}: {exc}"
        fmu.log(fmu.last_error + "\n" + traceback.format_exc(), Fmi2Status.error)
        return False


def check_step(dt: float, step_size: float) -> None:
    if abs(step_size - dt) > 1e-9 * dt:
        raise ValueError(f"communication step {step_size!r} s: this FMU runs a fixed step of {dt!r} s "
                         "(export it again with the step you need)")


# ---- what both FMUs share ----------------------------------------------------------------------
class BankedSlave:
    """Mixin for the two pythonfmu slaves: Real variables in one numpy bank (one gather or
    scatter per FMI call), a guarded life cycle (an exception is logged and the call fails, the
    host never crashes) and the FMU state serialised as npz bytes. The slave names its engine
    attribute (``engine``: the stepper or the soil object, None until built) and defines
    ``_build`` and ``_step``."""

    engine = "stepper"

    def get_real(self, vrs):
        return self.bank.values[self.bank.index(vrs)].tolist()

    def set_real(self, vrs, values):
        self.bank.values[self.bank.index(vrs)] = values

    def enter_initialization_mode(self):
        guarded(self, "initialisation", self._build)

    def do_step(self, current_time, step_size):
        if getattr(self, self.engine) is None:
            self.log("do_step before a successful initialisation: " + self.last_error)
            return False
        return guarded(self, f"step at t = {current_time:.6g} s", self._step, current_time, step_size)

    @staticmethod
    def _fmu_state_to_bytes(state):
        return state_to_bytes(state)

    @staticmethod
    def _fmu_state_from_bytes(data):
        return state_from_bytes(data)


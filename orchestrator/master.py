"""Master algorithms over the two FMUs (fmpy), fixed communication step.

Schedules for one step t_k -> t_{k+1} (S: structure FMU, G: soil FMU). The soil publishes g,
its history force for the structure's next step without the part driven by the structure's
latest state, which the structure adds itself (fmus/coupling.py); both stamp what they send
(x_time, g_time), so every schedule is exact (equal to the monolithic route to round-off):

``gauss-seidel`` (default)
    S <- g, g_time, a_g(t_{k+1}) (ag_x, ag_y, ag_z);  S.doStep;  G <- x, xdot, x_time at t_{k+1};  G.doStep
``soil-first``
    G <- x, xdot, x_time at t_k;  G.doStep;  S <- g, g_time (new), a_g(t_{k+1});  S.doStep
``jacobi``
    both FMUs step from the outputs at t_k (what a parallel engine such as libcosim's
    fixed-step algorithm or fmpy's SSP runner does)

``cosimulate(structure_fmu, soil_fmu, ag, dt)`` returns the RouteResult every route returns.

Per step the master makes six FMI calls and no copy: the structure's outputs go into one row
of a preallocated (nt, m) array (unpacked at the end), the soil reads its inputs x, xdot,
x_time from that row (they lead it), the soil's g and g_time go into one row of the structure's
input array whose ag_x, ag_y, ag_z columns hold the motion already, and the structure reads
that row (``FmuSlave.mover``: raw fmi2GetReal / fmi2SetReal on addresses).
"""
from __future__ import annotations

import ctypes
import functools
import os
import tempfile
import time as _time
import zipfile
from pathlib import Path
from types import SimpleNamespace
from xml.parsers import expat

import numpy as np
from fmpy import read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave, defaultCallbacks, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE
from fmpy.fmi3 import FMU3Slave, fmi3Boolean

from fmus.schema import AG, ENERGY_TERMS, vector3
from structure.results import RouteResult, RunNotes, Status
from uplift_common.errors import ComputationError

SCHEDULES = ("gauss-seidel", "soil-first", "jacobi")
FMI2_TYPES = ("Real", "Integer", "Boolean", "String", "Enumeration")
#: the generation tool of the native FMUs (fmus/native_build.py), which log their errors whatever
#: the debug logging and an event per step only with it on
NATIVE_TOOL = "uplift native"
FMI2_WARNING = 1                    # fmi2Status (fmi3Status) above which a call failed (discard, error, fatal)
#: the master reports progress about this many times a run (and after the last step), not every step
PROGRESS_CALLS = 100


class CosimError(ComputationError):
    """A co-simulation that cannot go on; the message names the FMU, the time and its log."""


class FmuSlave:
    """One co-simulation FMU instance over fmpy, FMI 2.0 or FMI 3.0, with vector access by name.

    ``FmuSlave(path, name)`` extracts and instantiates; ``get("x")`` returns the Real vector
    ``x[0..n-1]`` (or the scalar ``x``) as an ndarray, ``set("g", values)`` sets one. An FMI 3.0
    FMU's arrays are read under the same names: ``x`` is its arrays x_raft_u, x_raft_r, x_w
    (fmus.schema.INTERFACE_PARTS) end to end, as the FMI 2.0 x[0..n-1]. One ctypes call per
    call of get/set/do_step, on the raw fmi2GetReal / fmi2SetReal / fmi2DoStep (fmi3GetFloat64
    ...) with value-reference and value arrays built once per list of names (fmpy's
    ``getReal``/``setReal`` build both per call). The instance owns its fmpy slave: fmpy's
    ``freeInstance`` unloads the shared library, so never re-instantiate it; open a new
    FmuSlave instead.
    """

    def __init__(self, path, name: str | None = None, parameters: dict | None = None):
        self.path = Path(path)
        self._tmp = tempfile.TemporaryDirectory(prefix=f"uplift_{name or self.path.stem}_")
        self.dir = extract_fmu(self.path, self._tmp.name)
        self.md = model_description(Path(self.dir) / "modelDescription.xml")
        self.version = 3 if self.md.fmiVersion.startswith("3") else 2
        self.name = name or self.md.modelName
        self.log: list[str] = []
        cls = FMU3Slave if self.version == 3 else FMU2Slave
        self.fmu = cls(guid=self.md.guid, unzipDirectory=self.dir,
                       modelIdentifier=self.md.coSimulation.modelIdentifier, instanceName=self.name)
        dll = self.fmu.dll                 # the functions fmpy typed (argtypes, restype) at load
        if self.version == 3:
            self._instantiate(loggingOn=True, logMessage=self._logger3())
            self._get_real, self._set_real, self._do_step = dll.fmi3GetFloat64, dll.fmi3SetFloat64, dll.fmi3DoStep
            self._flags = (fmi3Boolean(), fmi3Boolean(), fmi3Boolean(), ctypes.c_double())
            self._flag_refs = [ctypes.byref(f) for f in self._flags]
        else:
            self._instantiate(callbacks=self._callbacks(), loggingOn=True)
            self._get_real, self._set_real, self._do_step = dll.fmi2GetReal, dll.fmi2SetReal, dll.fmi2DoStep
            self._flag_refs = ()
        self._component = self.fmu.component
        if (self.md.generationTool or "").startswith(NATIVE_TOOL):
            self.fmu.setDebugLogging(False, [])     # no event (a callback into Python) per step
        self.vars = {v.name: v for v in self.md.modelVariables}
        self._by_vr = {v.valueReference: v for v in self.md.modelVariables}
        self._vr, self._len = {}, {}
        for v in self.md.modelVariables:
            base = v.name.split("[")[0] if self.version == 2 else vector3(v.name)
            self._vr.setdefault(base, []).append(v.valueReference)
            self._len[base] = self._len.get(base, 0) + self._length(v)
        self._arrays = {}
        self.t = 0.0
        if parameters:
            self.set_parameters(parameters)

    def _instantiate(self, **kw) -> None:
        """fmpy's instantiate, whose failure (a bare Exception) becomes a CosimError with the FMU's
        own message (a native FMU's damaged resource file: its checksum, which extract_fmu leaves
        to it)."""
        try:
            self.fmu.instantiate(**kw)
        except Exception as exc:
            raise CosimError(f"FMU {self.name!r}: instantiation failed ({exc}): {self._reason()}") from None

    def _length(self, v) -> int:
        """Number of values of a variable (FMI 3.0: the product of its dimensions)."""
        out = 1
        for d in getattr(v, "dimensions", None) or ():
            out *= int(d.start) if d.start is not None else int(self._by_vr[d.valueReference].start)
        return out

    def _callbacks(self):
        def logger(env, instance, status, category, message):
            text = message.decode("utf-8", "replace") if message else ""
            self.log.append(text)

        cb = fmi2CallbackFunctions()
        cb.logger = fmi2CallbackLoggerTYPE(logger)
        cb.allocateMemory = defaultCallbacks.allocateMemory
        cb.freeMemory = defaultCallbacks.freeMemory
        self._cb = cb                     # keep the ctypes callbacks alive
        return cb

    def _logger3(self):
        def logger(env, status, category, message):
            self.log.append(message.decode("utf-8", "replace") if message else "")
        return logger

    def size(self, name: str) -> int:
        """Number of values of the vector ``name`` (what get(name) returns)."""
        self.vrs(name)
        return self._len[name]

    def vrs(self, name: str) -> list:
        if name not in self._vr:
            raise KeyError(f"FMU {self.name!r} has no variable {name!r}; it has "
                           f"{', '.join(sorted(self._vr))}")
        return self._vr[name]

    def _buffers(self, names):
        key = tuple(names)
        if key not in self._arrays:
            vr = np.concatenate([np.asarray(self.vrs(n), np.uint32) for n in names])
            val = np.zeros(sum(self.size(n) for n in names))
            extra = (val.size,) if self.version == 3 else ()       # FMI 3.0: nValues
            self._arrays[key] = (vr, val, (vr.ctypes.data_as(ctypes.POINTER(ctypes.c_uint)), vr.size,
                                           val.ctypes.data_as(ctypes.POINTER(ctypes.c_double))) + extra)
        return self._arrays[key]

    def mover(self, names, setting: bool = False):
        """``move(address)`` -> FMI status: one raw fmi2GetReal (setting: fmi2SetReal; FMI 3.0:
        fmi3GetFloat64 / fmi3SetFloat64) of the named vectors, concatenated, from or to the float64
        values at ``address`` (an int: a row of the caller's array, ``size`` values). The
        value-reference array is built once; the call takes plain integers (no ctypes object per
        call). The caller checks the status (``failed`` when above FMI2_WARNING)."""
        vr = np.concatenate([np.asarray(self.vrs(nm), np.uint32) for nm in names])
        nval = sum(self.size(nm) for nm in names)
        fn = self._set_real if setting else self._get_real
        extra = (ctypes.c_size_t,) if self.version == 3 else ()
        proto = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_size_t, ctypes.c_void_p,
                                 *extra)
        raw = proto(ctypes.cast(fn, ctypes.c_void_p).value)
        comp, ptr, nvr = self.fmu.component, vr.ctypes.data, vr.size
        if self.version == 3:
            def move(address, _vr=vr):               # _vr: the references live as long as the mover
                return raw(comp, ptr, nvr, address, nval)
        else:
            move = functools.partial(raw, comp, ptr, nvr)   # no Python frame per call
            move.vr = vr                                    # the references live as long as the mover
        move.size = nval
        move.what = f"{'setting' if setting else 'getting'} {', '.join(names)}"
        move.function = fn.__name__
        return move

    def failed(self, move) -> None:
        """Raise the CosimError of a failed ``mover`` call."""
        self._failed(move.what, move.function)

    def get(self, *names) -> np.ndarray:
        """Real values of the named vectors, concatenated (the FMU's buffer for this list of
        names, overwritten by the next get of the same names: copy to keep it)."""
        vr, val, args = self._buffers(names)
        if self._get_real(self.fmu.component, *args) > FMI2_WARNING:
            self._failed(f"getting {', '.join(names)}", self._get_real.__name__)
        return val

    def set(self, *names_then_values) -> None:
        """``set("g", g)`` or several vectors in one call: ``set("x", "xdot", values)``."""
        *names, values = names_then_values
        vr, val, args = self._buffers(tuple(names))
        val[:] = values
        if self._set_real(self.fmu.component, *args) > FMI2_WARNING:
            self._failed(f"setting {', '.join(names)}", self._set_real.__name__)

    def set_parameters(self, parameters: dict) -> None:
        for key, value in parameters.items():
            v = self.vars[key]
            if v.type == "Boolean":
                self.fmu.setBoolean([v.valueReference], [bool(value)])
            elif v.type == "Integer":
                self.fmu.setInteger([v.valueReference], [int(value)])
            elif self.version == 3:
                self.fmu.setFloat64([v.valueReference], [float(value)])
            else:
                self.fmu.setReal([v.valueReference], [float(value)])

    def get_integer(self, name: str) -> int:
        return int(self.fmu.getInteger([self.vars[name].valueReference])[0])

    def initialize(self, start_time: float = 0.0, stop_time: float | None = None) -> None:
        """Set up (with the stop time, when given), enter and exit initialisation mode."""
        if self.version == 3:
            self._call("initialisation", self.fmu.enterInitializationMode, startTime=start_time, stopTime=stop_time)
        else:
            self._call("initialisation", self.fmu.setupExperiment, startTime=start_time, stopTime=stop_time)
            self._call("initialisation", self.fmu.enterInitializationMode)
        self._call("initialisation", self.fmu.exitInitializationMode)
        self.t = start_time

    def do_step(self, t: float, dt: float) -> None:
        if self._do_step(self._component, t, dt, 1, *self._flag_refs) > FMI2_WARNING:
            self._failed(f"step at t = {t:.6g} s", self._do_step.__name__)
        self.t = t + dt

    def _failed(self, what, function):
        raise CosimError(f"FMU {self.name!r}: {what} failed ({function}): {self._reason()}")

    def _call(self, what, fn, **kw):
        try:
            fn(**kw)
        except FMICallException as exc:
            raise CosimError(f"FMU {self.name!r}: {what} failed ({exc}): {self._reason()}") from None

    def _reason(self) -> str:
        """The FMU's own last message, first line (pythonfmu logs a fatal error as a line of its
        own followed by the exception, or by "unknown error" when it lost it)."""
        for message in reversed(self.log):
            text = message.strip()
            if text.startswith("Fatal py exception"):
                text = text.partition("\n")[2].strip()
                if text == "unknown error":
                    continue
            if text:
                return text.splitlines()[0]
        return "(no log message)"

    # ---- FMU state ------------------------------------------------------------------------
    def get_state(self):
        return self.fmu.getFMUState() if self.version == 3 else self.fmu.getFMUstate()

    def set_state(self, state) -> None:
        (self.fmu.setFMUState if self.version == 3 else self.fmu.setFMUstate)(state)

    def serialize(self, state) -> bytes:
        return (self.fmu.serializeFMUState if self.version == 3 else self.fmu.serializeFMUstate)(state)

    def deserialize(self, data: bytes):
        return (self.fmu.deserializeFMUState if self.version == 3 else self.fmu.deSerializeFMUstate)(data)

    def close(self) -> None:
        if self.fmu is not None:
            try:
                self.fmu.terminate()
            finally:
                self.fmu.freeInstance()
                self.fmu = None
                self._tmp.cleanup()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def needed_member(name: str) -> bool:
    """Whether an FMU's archive member is extracted to run it: everything but the sources and the
    documentation (an importer runs the binaries with the resources and the model description)."""
    return not name.startswith(("sources/", "documentation/"))


#: the native runtime's resource file (fmus/native_build.py: stored, not deflated) and the magic it
#: starts with: the runtime checks the file's own CRC-32, size and extents when it loads it
#: (fmus/native/resources.c), so extract_fmu copies it out of the archive without zipfile's CRC pass
NATIVE_RESOURCE, NATIVE_MAGIC = "resources/uplift.bin", b"UPLIFTNB"


def extract_fmu(path, folder) -> str:
    """Extract the members of the FMU ``path`` an importer needs (``needed_member``) into
    ``folder``, with fmpy.extract's checks of the member names; returns ``folder`` as a str.

    The native runtime's stored resource file (NATIVE_RESOURCE, starting with NATIVE_MAGIC: a few
    MB, read and checked by the runtime at every instantiation) is copied by the kernel
    (os.copy_file_range where there is one) without zipfile's CRC-32, which the runtime's own check
    repeats: 7-10 ms -> 3-5 ms CPU an FMU of the reactor. Every other member, or a resource file of
    another kind, goes through zipfile (its CRC checked)."""
    folder = Path(folder)
    with zipfile.ZipFile(path) as zf:
        infos = zf.infolist()
        for info in infos:
            name = info.filename
            if "\\" in name or ":" in name or name.startswith("/"):
                raise CosimError(f"{path}: illegal member name {name!r} (forward slashes, no drive letter, no "
                                 "leading slash): export the FMU again")
        for info in infos:
            if needed_member(info.filename) and not (info.filename == NATIVE_RESOURCE and _copy_stored(path, info, folder)):
                zf.extract(info, folder)
    return str(folder)


def _copy_stored(path, info, folder: Path) -> bool:
    """Copy the stored, unencrypted member ``info`` of the archive ``path`` to its place in
    ``folder`` when its data start with NATIVE_MAGIC; False (nothing written) otherwise."""
    if info.compress_type != zipfile.ZIP_STORED or info.flag_bits & 1:
        return False
    with open(path, "rb") as src:
        src.seek(info.header_offset)
        head = src.read(30)                               # the local file header
        if head[:4] != b"PK\x03\x04":
            return False
        start = info.header_offset + 30 + int.from_bytes(head[26:28], "little") + int.from_bytes(head[28:30], "little")
        src.seek(start)
        if src.read(len(NATIVE_MAGIC)) != NATIVE_MAGIC:
            return False
        dest = folder / info.filename
        dest.parent.mkdir(parents=True, exist_ok=True)
        with open(dest, "wb") as dst:
            left, pos = info.file_size, start
            copy = getattr(os, "copy_file_range", None)
            while left > 0 and copy is not None:
                done = copy(src.fileno(), dst.fileno(), left, pos)
                if done <= 0:
                    break
                left, pos = left - done, pos + done
            if left > 0:                                  # no copy_file_range here (or it stopped)
                src.seek(pos)
                dst.seek(info.file_size - left)
                dst.write(src.read(left))
        if dest.stat().st_size != info.file_size:
            raise CosimError(f"{path}: {info.filename} could not be extracted ({dest.stat().st_size} of "
                             f"{info.file_size} bytes written)")
    return True


class _Done(Exception):
    """The model variables are read: the rest of the model description is not parsed."""


def model_description(xml: Path):
    """The model description in ``xml`` as the master uses it: fmiVersion, guid, modelName,
    generationTool, coSimulation.modelIdentifier and modelVariables (name, valueReference, type,
    causality; ``dimensions`` None). FMI 2.0 read here in one pass of expat up to the
    ModelStructure (no tree built); FMI 3.0 (array dimensions) by fmpy. Neither is checked
    against the schema (fmpy's reader builds a full object per variable and validates: most of
    the set-up of a pair with a thousand variables); the export's tests run
    fmpy.validation.validate_fmu on every kind and version."""
    root, cosim, variables, current = {}, {}, [], []

    def start(tag, attrs):
        if not root:
            root.update(attrs)
            if not root.get("fmiVersion", "").startswith("2"):
                raise _Done
        elif tag == "ScalarVariable":
            current[:] = [attrs]
            variables.append(SimpleNamespace(name=attrs.get("name"), valueReference=int(attrs.get("valueReference")),
                                             type=None, causality=attrs.get("causality", "local"), dimensions=None))
        elif current and tag in FMI2_TYPES:
            variables[-1].type = tag
            current.clear()
        elif tag == "CoSimulation":
            cosim.update(attrs)
        elif tag == "ModelStructure":
            raise _Done

    def end(tag):
        if tag == "ScalarVariable":
            current.clear()

    parser = expat.ParserCreate()
    parser.StartElementHandler, parser.EndElementHandler = start, end
    try:
        with open(xml, "rb") as f:
            parser.ParseFile(f)
    except _Done:
        pass
    if not root.get("fmiVersion", "").startswith("2"):
        return read_model_description(str(xml), validate=False)
    if not cosim:
        raise CosimError(f"{xml}: not a co-simulation FMU (no CoSimulation element)")
    return SimpleNamespace(fmiVersion=root.get("fmiVersion"), guid=root.get("guid"), modelName=root.get("modelName"),
                           generationTool=root.get("generationTool"), modelVariables=variables,
                           coSimulation=SimpleNamespace(modelIdentifier=cosim.get("modelIdentifier")))


def output_nodes(structure: FmuSlave) -> list:
    return sorted(n[4:] for n in structure._vr if n.startswith("acc_"))


class Timer:
    """Wall and CPU (process) time per part of a co-simulation step, s: ``add(part)`` books
    the time since the previous ``add`` or ``mark`` to ``part``; ``rest(part, since)`` books to
    ``part`` what the other parts do not hold of the time since ``since`` (a ``now()``);
    ``Timer.share`` (the master's loop) builds one from parts timed by the wall clock alone."""

    def __init__(self):
        self.parts = {"structure step": 0.0, "soil step": 0.0, "transfers": 0.0}
        self.cpu = dict(self.parts)
        self.mark()

    def mark(self):
        self._wall, self._cpu = _time.perf_counter(), _time.process_time()

    def add(self, part):
        wall, cpu = _time.perf_counter(), _time.process_time()
        self.parts[part] = self.parts.get(part, 0.0) + wall - self._wall
        self.cpu[part] = self.cpu.get(part, 0.0) + cpu - self._cpu
        self._wall, self._cpu = wall, cpu

    @staticmethod
    def now():
        return _time.perf_counter(), _time.process_time()

    def rest(self, part, since):
        wall, cpu = self.now()
        others = [p for p in self.parts if p != part and p != "initialisation"]
        self.parts[part] = max(0.0, wall - since[0] - sum(self.parts[p] for p in others))
        self.cpu[part] = max(0.0, cpu - since[1] - sum(self.cpu[p] for p in others))

    @classmethod
    def share(cls, since, walls: dict, rest: str) -> Timer:
        """A Timer of the loop begun at ``since`` (a ``now()``) whose parts ``walls`` ({part: wall
        s}) were timed with the wall clock alone: ``rest`` gets the loop's wall time the others do
        not hold, and the loop's CPU time (read here and at ``since`` only) is shared out over the
        parts in proportion to their wall times. The process CPU clock is a system call (~2 us):
        read around every FMU step it cost 4 % of a co-simulation of the reactor."""
        wall, cpu = cls.now()
        total, cpu_total = wall - since[0], max(0.0, cpu - since[1])
        timer = cls()
        timer.parts.update(walls)
        timer.parts[rest] = max(0.0, total - sum(walls.values()))
        scale = cpu_total / total if total > 0 else 0.0
        timer.cpu = {part: scale * w for part, w in timer.parts.items()}
        return timer


def cosimulate(structure_fmu, soil_fmu, ag, dt: float, schedule: str = "gauss-seidel",
               route: str = "cosim", progress=None, parameters: dict | None = None):
    """Co-simulate the exported pair over the ground acceleration ``ag`` (nt, 3) m/s^2 at
    step ``dt`` (the FMUs' fixed step) with ``schedule`` in SCHEDULES. The motion goes in
    through the structure's inputs ``ag_x``, ``ag_y``, ``ag_z`` (``internal_motion = false``).

    structure_fmu, soil_fmu : paths of .fmu files (or open FmuSlaves, left open)
    Returns a RouteResult (route name ``route``; ``info["schedule"]``; ``notes.timings`` and
    ``info["timing_cpu"]`` the wall and CPU time per part: initialisation (FMU extraction,
    instantiation, initialisation), structure step, soil step, transfers (FMI get/set and
    recording)). A failed FMU call ends the run: ``converged = False``, the results up to the
    last completed step and ``message`` with the FMU's log.
    """
    if schedule not in SCHEDULES:
        raise ValueError(f"schedule = {schedule!r}: use one of {', '.join(SCHEDULES)}")
    start = _time.perf_counter(), _time.process_time()
    ag = np.asarray(ag, float)
    if ag.ndim != 2 or ag.shape[1] != 3 or ag.shape[0] < 1:
        raise ValueError(f"ground acceleration ag must have shape (nt, 3) (x, y, z in m/s2 at t = k dt), "
                         f"got {ag.shape}")
    if not np.all(np.isfinite(ag)):
        raise ValueError(f"ground acceleration ag contains NaN or inf (first at step "
                         f"{int(np.argmin(np.isfinite(ag).all(axis=1)))}): clean or resample the record")
    own = []
    S = structure_fmu if isinstance(structure_fmu, FmuSlave) else None
    G = soil_fmu if isinstance(soil_fmu, FmuSlave) else None
    try:
        if S is None:
            S = FmuSlave(structure_fmu, "structure")
            own.append(S)
        if G is None:
            G = FmuSlave(soil_fmu, "soil")
            own.append(G)
        params = {"internal_motion": False, **(parameters or {})}
        S.set_parameters(params)
        S.set(*AG, ag[0])
        S.initialize()
        G.initialize()
        return _run(S, G, ag, dt, schedule, route, progress, start)
    finally:
        for f in own:
            f.close()


def _run(S, G, ag, dt, schedule, route, progress, start):
    nodes = output_nodes(S)
    nt = ag.shape[0]
    names = ("x", "xdot", "x_time", "P", "gap") + tuple(f"{k}_{nm}" for nm in nodes for k in ("acc", "disp")) + \
        tuple(f"energy.{e}" for e in ENERGY_TERMS) + ("newton_iters",)
    # every structure output at every step, one row each (x, xdot, x_time lead: the soil's inputs)
    get_y, set_x = S.mover(names), G.mover(("x", "xdot", "x_time"), setting=True)
    get_g, set_s = G.mover(("g", "g_time")), S.mover(("g", "g_time", *AG), setting=True)
    Y = np.empty((nt, get_y.size))
    U = np.empty((nt, set_s.size))               # row k: the structure's inputs of the step to t_k
    U[:, get_g.size:] = ag
    y0, ys, u0, us = Y.ctypes.data, Y.strides[0], U.ctypes.data, U.strides[0]
    if get_y(y0) > FMI2_WARNING:
        S.failed(get_y)
    init_wall, init_cpu = _time.perf_counter() - start[0], _time.process_time() - start[1]
    pc, W = _time.perf_counter, FMI2_WARNING
    s_step, g_step = S.do_step, G.do_step      # looked up once (a caller may have replaced one)
    soil_row = 1 if schedule == "jacobi" else 0  # the soil takes row k - soil_row (jacobi: the outputs at t)
    every = max(1, nt // PROGRESS_CALLS)
    # only the wall clock is read in the loop, around the two doSteps (perf_counter: no system call);
    # the process CPU clock (a system call, ~2 us) at its two ends: see Timer.share
    ws = wg = 0.0                                # wall s in the structure's and the soil's doStep

    def structure_half(t, k):                   # S <- g, row k of U; S.doStep; its outputs into row k of Y
        uk = u0 + k * us
        if get_g(uk) > W:
            G.failed(get_g)
        if set_s(uk) > W:
            S.failed(set_s)
        a = pc()
        s_step(t, dt)
        wall = pc() - a
        if get_y(y0 + k * ys) > W:
            S.failed(get_y)
        return wall

    def soil_half(t, row):                      # G <- x, row `row` of Y; G.doStep
        if set_x(y0 + row * ys) > W:
            G.failed(set_x)
        a = pc()
        g_step(t, dt)
        return pc() - a

    loop = _time.perf_counter(), _time.process_time()
    done, message = 1, ""                        # rows of Y filled
    try:
        for k in range(1, nt):
            t = (k - 1) * dt
            if schedule == "soil-first":         # G <- x at t; G.doStep; S <- g (new); S.doStep
                wg += soil_half(t, k - 1)
                ws += structure_half(t, k)
            else:                                # S <- g; S.doStep; G <- x (at t + dt, jacobi: at t); G.doStep
                ws += structure_half(t, k)
                wg += soil_half(t, k - soil_row)
            done = k + 1
            if progress is not None and (done % every == 0 or done == nt):
                progress(done, nt)
    except CosimError as exc:
        message = str(exc)
    timer = Timer.share(loop, {"structure step": ws, "soil step": wg}, "transfers")
    timer.parts["initialisation"], timer.cpu["initialisation"] = init_wall, init_cpu
    cols = _columns(Y[:done], names, [S.size(nm) for nm in names])
    x = cols["x"]
    headline = S.get("max_uplift", "max_raft_rotation")
    return RouteResult(
        route=route, time=dt * np.arange(done), raft=x[:, :6], gap=cols["gap"], contact_force=cols["P"],
        soil_w=x[:, 6:], acc={nm: cols[f"acc_{nm}"] for nm in nodes}, disp={nm: cols[f"disp_{nm}"] for nm in nodes},
        energy={e: cols[f"energy.{e}"][:, 0] for e in ENERGY_TERMS}, newton_iters=cols["newton_iters"][:, 0],
        status=Status.STOPPED if message else Status.CONVERGED, message=message,
        wall_s=_time.perf_counter() - start[0],
        notes=RunNotes(timings=timer.parts),
        info=dict(dt=dt, schedule=schedule, P0=cols["P"][0], timing_cpu=dict(timer.cpu),
                  fmu_max_uplift=float(headline[0]), fmu_max_raft_rotation=float(headline[1])))


def _columns(Y, names, sizes) -> dict:
    """{name: (nt, size)} columns of the rows Y (nt, m) of the structure's outputs ``names``."""
    offs = np.concatenate([[0], np.cumsum(sizes)])
    return {nm: Y[:, offs[i]:offs[i + 1]] for i, nm in enumerate(names)}

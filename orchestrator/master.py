"""Master algorithms over the two FMUs (fmpy), fixed communication step.

Schedules for one step t_k -> t_{k+1} (S: structure FMU, G: soil FMU):

``gauss-seidel`` (default; the impedance split of DESIGN.md §6)
    S <- h_{k+1} (G's output), a_g(t_{k+1});  S.doStep -> x, xdot at t_{k+1}
    G <- x_{k+1}, xdot_{k+1};                 G.doStep -> commits them, h_{k+2}
    h depends on the past only and S folds the soil's instantaneous terms into its implicit
    matrix, so this equals the monolithic route to round-off.
``jacobi``
    both FMUs step from the outputs at t_k (what a parallel engine such as libcosim's
    fixed-step algorithm does): the soil history reaching the structure is one step late,
    an O(dt) coupling error.
``total-force``
    plain explicit coupling: S folds nothing and receives the soil's total force f_k of the
    previous step as a load. Kept only to show why it is not the default: on stiff soils it
    diverges (tests/test_cosim_coupling.py measures the growth).

``cosimulate(structure_fmu, soil_fmu, ag, dt)`` returns the RouteResult every route returns.
"""
from __future__ import annotations

import ctypes
import tempfile
import time as _time
from pathlib import Path

import numpy as np

SCHEDULES = ("gauss-seidel", "jacobi", "total-force")
ENERGY_TERMS = ("input", "kinetic", "strain", "damping", "soil", "contact", "contact_potential")


class CosimError(RuntimeError):
    """A co-simulation that cannot go on; the message names the FMU, the time and its log."""


class FmuSlave:
    """One co-simulation FMU instance over fmpy, with vector access by variable name.

    ``FmuSlave(path, name)`` extracts and instantiates; ``get("x")`` returns the Real vector
    ``x[0..n-1]`` (or the scalar ``x``) as an ndarray, ``set("h", values)`` sets one. One
    ctypes call per vector. The instance owns its fmpy FMU2Slave: fmpy's ``freeInstance``
    unloads the shared library, so never re-instantiate it; open a new FmuSlave instead.
    """

    def __init__(self, path, name: str | None = None, parameters: dict | None = None):
        from fmpy import extract, read_model_description
        from fmpy.fmi2 import FMU2Slave

        self.path = Path(path)
        self.md = read_model_description(str(self.path))
        self.name = name or self.md.modelName
        self._tmp = tempfile.TemporaryDirectory(prefix=f"uplift_{self.name}_")
        self.dir = extract(str(self.path), self._tmp.name)
        self.log: list[str] = []
        self.fmu = FMU2Slave(guid=self.md.guid, unzipDirectory=self.dir,
                             modelIdentifier=self.md.coSimulation.modelIdentifier, instanceName=self.name)
        self.fmu.instantiate(callbacks=self._callbacks(), loggingOn=True)
        self.vars = {v.name: v for v in self.md.modelVariables}
        self._vr = {}
        for v in self.md.modelVariables:
            base = v.name.split("[")[0]
            self._vr.setdefault(base, []).append(v.valueReference)
        self._arrays = {}
        self.t = 0.0
        if parameters:
            self.set_parameters(parameters)

    def _callbacks(self):
        from fmpy.fmi2 import (defaultCallbacks, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)

        def logger(env, instance, status, category, message):
            text = message.decode("utf-8", "replace") if message else ""
            self.log.append(text)

        cb = fmi2CallbackFunctions()
        cb.logger = fmi2CallbackLoggerTYPE(logger)
        cb.allocateMemory = defaultCallbacks.allocateMemory
        cb.freeMemory = defaultCallbacks.freeMemory
        self._cb = cb                     # keep the ctypes callbacks alive
        return cb

    def vrs(self, name: str) -> list:
        if name not in self._vr:
            raise KeyError(f"FMU {self.name!r} has no variable {name!r}; it has "
                           f"{', '.join(sorted(self._vr))}")
        return self._vr[name]

    def _buffers(self, names):
        key = tuple(names)
        if key not in self._arrays:
            vr = np.concatenate([np.asarray(self.vrs(n), np.uint32) for n in names])
            val = np.zeros(vr.size)
            self._arrays[key] = (vr, val, vr.ctypes.data_as(ctypes.POINTER(ctypes.c_uint)),
                                 val.ctypes.data_as(ctypes.POINTER(ctypes.c_double)))
        return self._arrays[key]

    def get(self, *names) -> np.ndarray:
        """Real values of the named vectors, concatenated (a view: copy to keep it)."""
        vr, val, pvr, pval = self._buffers(names)
        self.fmu.fmi2GetReal(self.fmu.component, pvr, vr.size, pval)
        return val

    def set(self, *names_then_values) -> None:
        """``set("h", h)`` or several vectors in one call: ``set("x", "xdot", values)``."""
        *names, values = names_then_values
        vr, val, pvr, pval = self._buffers(tuple(names))
        val[:] = values
        self.fmu.fmi2SetReal(self.fmu.component, pvr, vr.size, pval)

    def set_parameters(self, parameters: dict) -> None:
        for key, value in parameters.items():
            v = self.vars[key]
            if v.type == "Boolean":
                self.fmu.setBoolean([v.valueReference], [bool(value)])
            elif v.type == "Integer":
                self.fmu.setInteger([v.valueReference], [int(value)])
            else:
                self.fmu.setReal([v.valueReference], [float(value)])

    def get_integer(self, name: str) -> int:
        return int(self.fmu.getInteger([self.vars[name].valueReference])[0])

    def initialize(self, start_time: float = 0.0) -> None:
        self._call("initialisation", self.fmu.setupExperiment, startTime=start_time)
        self._call("initialisation", self.fmu.enterInitializationMode)
        self._call("initialisation", self.fmu.exitInitializationMode)
        self.t = start_time

    def do_step(self, t: float, dt: float) -> None:
        self._call(f"step at t = {t:.6g} s", self.fmu.doStep, currentCommunicationPoint=t,
                   communicationStepSize=dt)
        self.t = t + dt

    def _call(self, what, fn, **kw):
        from fmpy.fmi1 import FMICallException
        try:
            fn(**kw)
        except FMICallException as exc:
            tail = self.log[-1].strip() if self.log else "(no log message)"
            raise CosimError(f"FMU {self.name!r}: {what} failed ({exc}): {tail}") from None

    # ---- FMU state ------------------------------------------------------------------------
    def get_state(self):
        return self.fmu.getFMUstate()

    def set_state(self, state) -> None:
        self.fmu.setFMUstate(state)

    def serialize(self, state) -> bytes:
        return self.fmu.serializeFMUstate(state)

    def deserialize(self, data: bytes):
        return self.fmu.deSerializeFMUstate(data)

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


def output_nodes(structure: FmuSlave) -> list:
    return sorted(n[4:] for n in structure._vr if n.startswith("acc_"))


class Timer:
    """Wall time per part of a co-simulation step, s."""

    def __init__(self):
        self.parts = {"structure step": 0.0, "soil step": 0.0, "transfers": 0.0}

    def add(self, part, t0):
        t1 = _time.perf_counter()
        self.parts[part] += t1 - t0
        return t1


def cosimulate(structure_fmu, soil_fmu, ag, dt: float, schedule: str = "gauss-seidel",
               route: str = "td-cosim", progress=None, parameters: dict | None = None):
    """Co-simulate the exported pair over the ground acceleration ``ag`` (nt, 3) m/s^2 at
    step ``dt`` (the FMUs' fixed step) with ``schedule`` in SCHEDULES. The motion goes in
    through the structure's ``ag`` inputs (``internal_motion = false``).

    structure_fmu, soil_fmu : paths of .fmu files (or open FmuSlaves, left open)
    Returns a RouteResult (route name ``route``; ``info["schedule"]``, ``info["timing"]``
    the wall time per part). A failed FMU step ends the run: ``converged = False`` and the
    results so far, ``message`` with the FMU's log.
    """
    if schedule not in SCHEDULES:
        raise ValueError(f"schedule = {schedule!r}: use one of {', '.join(SCHEDULES)}")
    t_start = _time.perf_counter()
    ag = np.asarray(ag, float)
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
        params = {"internal_motion": False, "impedance_split": schedule != "total-force", **(parameters or {})}
        S.set_parameters(params)
        S.set("ag", ag[0])
        S.initialize()
        G.initialize()
        return _run(S, G, ag, dt, schedule, route, progress, t_start)
    finally:
        for f in own:
            f.close()


def _run(S, G, ag, dt, schedule, route, progress, t_start):
    from structure.results import RouteResult

    nodes = output_nodes(S)
    nt = ag.shape[0]
    n = len(S.vrs("x"))
    N = len(S.vrs("gap"))
    names = ["x", "xdot", "P", "gap"] + [f"{k}_{nm}" for nm in nodes for k in ("acc", "disp")] + \
            [f"energy.{e}" for e in ENERGY_TERMS] + ["newton_iters"]
    sizes = [len(S.vrs(nm)) for nm in names]
    offs = np.concatenate([[0], np.cumsum(sizes)])
    part = {nm: slice(offs[i], offs[i + 1]) for i, nm in enumerate(names)}
    res = RouteResult(route, dt * np.arange(nt), np.zeros((nt, 6)), np.zeros((nt, N)), np.zeros((nt, N)),
                      np.zeros((nt, N)), {nm: np.zeros((nt, 3)) for nm in nodes},
                      {nm: np.zeros((nt, 3)) for nm in nodes}, {e: np.zeros(nt) for e in ENERGY_TERMS},
                      np.zeros(nt, int), True, "", 0.0, None, {"dt": dt, "schedule": schedule})

    def record(k):
        y = S.get(*names)
        x = y[part["x"]]
        res.raft[k] = x[:6]
        res.soil_w[k] = x[6:]
        res.gap[k] = y[part["gap"]]
        res.contact_force[k] = y[part["P"]]
        for nm in nodes:
            res.acc[nm][k] = y[part[f"acc_{nm}"]]
            res.disp[nm][k] = y[part[f"disp_{nm}"]]
        for e in ENERGY_TERMS:
            res.energy[e][k] = y[part[f"energy.{e}"]][0]
        res.newton_iters[k] = int(y[part["newton_iters"]][0])
        return y

    y = record(0)
    res.info["P0"] = res.contact_force[0].copy()
    timer = Timer()
    timer.parts["initialisation"] = _time.perf_counter() - t_start
    feed, feed_to = ("f" if schedule == "total-force" else "h"), "h"
    xs = slice(0, 2 * n)                        # x and xdot are contiguous in `names`
    try:
        for k in range(1, nt):
            t = (k - 1) * dt
            t0 = _time.perf_counter()
            if schedule == "jacobi":
                x_old = y[xs].copy()
                S.set("h", "ag", np.concatenate([G.get("h"), ag[k]]))
                G.set("x", "xdot", x_old)
                t0 = timer.add("transfers", t0)
                S.do_step(t, dt)
                t0 = timer.add("structure step", t0)
                G.do_step(t, dt)
                t0 = timer.add("soil step", t0)
                y = record(k)
            else:
                S.set(feed_to, "ag", np.concatenate([G.get(feed), ag[k]]))
                t0 = timer.add("transfers", t0)
                S.do_step(t, dt)
                t0 = timer.add("structure step", t0)
                y = record(k)
                G.set("x", "xdot", y[xs])
                t0 = timer.add("transfers", t0)
                G.do_step(t, dt)
                t0 = timer.add("soil step", t0)
            timer.add("transfers", t0)
            if progress is not None:
                progress(k, nt)
    except CosimError as exc:
        res = res.truncated(k)
        res.converged, res.message = False, str(exc)
    res.wall_s = _time.perf_counter() - t_start
    res.info["timing"] = dict(timer.parts)
    return res

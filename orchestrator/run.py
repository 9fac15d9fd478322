"""Running a scene: its motion, one impedance sweep and one soil fit shared by every route,
then each route of the registry (orchestrator.routes), into one result per route.

``run_scene(scene)`` returns ``({route: RouteResult}, Motion)``. Every route returns a
result: converged, stopped (the histories so far and the reason) or refused (the reason).
What the run reuses or skips (cache hits, interface reductions) is in each result's notes.

Many runs of one scene under different motions (an ensemble of records,
``orchestrator.ensemble``) share what does not depend on the motion: ``prepare_run(scene)``
computes it once (the sweep, the fit, the time-step checks' proxy springs) as a ``SharedRun``
that ``run_scene(..., shared=...)`` takes instead of recomputing it.
"""
from __future__ import annotations

import hashlib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
from soil_impedance.cache import read_entry, write_entry
from uplift_common.code import code_digest
from uplift_common.files import atomic_output, stamp_checksum

from structure import ConvergenceError, simulate
from structure.results import RouteResult, Status
from structure.spec import winkler_from_moduli
from structure.winkler import modes_on_soil, springs_from_rigid_impedance

from orchestrator.exit_codes import STOPPED, USER_INPUT
from orchestrator.impedance import cached_scene_fit, scene_fit, scene_impedance, scene_static
from orchestrator.motion import Motion, make_motion
from orchestrator.routes import RunContext, get_route
from orchestrator.scene import SceneError
from orchestrator.settings import compute_threads

#: fewest steps per period of the first soil-structure mode a run accepts: on the reactor,
#: 12.7 steps move the max uplift by < 1 %, 5.1 steps by +12 % (winkler) and +104 % (monolithic)
#: (benchmarks/stress.py)
MIN_STEPS_PER_PERIOD = 10


#: step doubling: relative change of max uplift, when dt is halved, above which the time-stepped
#: routes carry a warning; the estimate runs on the strongest DT_CHECK_WINDOW_S of the record
DT_TOLERANCE = 0.05
DT_CHECK_WINDOW_S = 10.0
#: uplift below this (m) is no uplift for the step-doubling estimate (round-off of the penalty)
UPLIFT_FLOOR = 1e-6


def proxy_springs(scene, bem: bool, cache_dir=None):
    """Winkler springs standing for the scene's soil in the time-step checks: the BEM static
    rigid impedance shared with the rocking stiffness exact, or ``[soil].winkler``'s moduli for a
    run that gives them and needs no BEM table (``bem`` False)."""
    if scene.winkler.explicit and not bem:
        return winkler_from_moduli(scene.winkler.moduli, scene.mesh.xy, scene.mesh.area)
    K0 = np.real(scene_static(scene, "rigid", cache_dir))
    return springs_from_rigid_impedance(K0, scene.mesh.xy, scene.mesh.area, match="rocking")


def strongest_window(motion, length_s: float = DT_CHECK_WINDOW_S):
    """(Motion, t0): the ``length_s`` of the record with the largest Arias intensity (the whole
    record if shorter)."""
    n = int(round(length_s / motion.dt)) + 1
    if motion.acc.shape[0] <= n:
        return motion, 0.0
    energy = np.concatenate([[0.0], np.cumsum((motion.acc ** 2).sum(axis=1))])
    k = int(np.argmax(energy[n:] - energy[:-n]))
    return Motion(motion.dt, motion.acc[k:k + n], motion.label), k * motion.dt


def step_doubling(scene, model, soil, motion, cache_dir=None, keep: bool = True) -> dict:
    """Max uplift of the structure on the proxy springs ``soil`` (Newmark + the scene's contact)
    at the motion's step and at half of it, on the record's strongest window: the time-step
    error estimate of the uplift routes. Returns a JSON-able dict (relative_change None when
    neither run lifts off). cache_dir: the run's cache folder (where the native stepper's library
    is kept, and the two answers: a warm run does not step them again, ``_dt_check_run``; None:
    a temporary folder of the process, nothing kept); keep False: the answers are not kept (a
    motion no other run steps, such as an ensemble cell's)."""
    window, t0 = strongest_window(motion)
    coarse, fine = (_dt_check_run(scene, model, soil, m, cache_dir, keep)
                    for m in (window, window.resampled(window.dt / 2)))
    change = None if max(coarse, fine) < UPLIFT_FLOOR else abs(coarse - fine) / max(fine, UPLIFT_FLOOR)
    return {"dt": motion.dt, "window_s": [t0, t0 + window.duration], "max_uplift_m": coarse,
            "max_uplift_half_dt_m": fine, "relative_change": change, "tolerance": DT_TOLERANCE}


def _dt_check_run(scene, model, soil, motion, cache_dir=None, keep: bool = True) -> float:
    """Max uplift (m) of the structure on the proxy springs under ``motion``, NaN when Newton
    fails: through the native stepper where it is available (the monolithic route's C runtime:
    the same answer to round-off, several times faster), else ``simulate``. With a cache folder (and keep)
    the native answer is kept there (``dtcheck-<key>.h5``, checksummed, verified on read) under
    the key of everything the C runtime reads (``_native_run_key``): read back, never stepped
    again, by a run of the same structure, springs, contact, motion and step."""
    from fmus.native_stepper import cache_folder, encode_run, library, native_max_uplift, springs_soil   # when it checks
    from structure import NewmarkStepper
    lib = library(cache_folder(cache_dir))
    if lib is None:
        try:
            return simulate(model, soil, motion.acc, motion.dt, contact=scene.contact, route="dt-check").max_uplift()
        except ConvergenceError:
            return float("nan")
    st = NewmarkStepper(model, springs_soil(soil, motion.dt), motion.dt, contact=scene.contact,
                        external_soil=True, ag0=motion.acc[0])
    blob = encode_run(st)
    path = None if cache_dir is None or not keep else \
        Path(cache_dir) / f"dtcheck-{_native_run_key(lib, blob, motion.acc)[:24]}.h5"
    if path is not None:
        hit = read_entry(path, lambda h: float(h.attrs["max_uplift_m"]))
        if hit is not None:
            return hit
    value = native_max_uplift(st, motion.acc, lib, blob)
    if path is not None:
        _keep(path, value)
    return value


#: what the native answer of a check also depends on besides its inputs: the Python side that
#: encodes them for the C runtime and the measure taken of its histories
DT_CHECK_CODE = ("fmus.native_stepper", "fmus.native_build", "orchestrator.run")


def _native_run_key(lib, blob: bytes, acc) -> str:
    """SHA-256 of what a native run reads: the compiled library (its file name is the digest of
    its C sources, compiler, flags and platform), the encoded model (``blob``, ``encode_run``: the
    structure's matrices, static state, soil springs, penalty and contact settings, the step), the ground
    acceleration, and the sources of the Python side (``DT_CHECK_CODE``)."""
    h = hashlib.sha256(Path(lib._name).name.encode() + b"\0")
    h.update(code_digest(*DT_CHECK_CODE).encode())
    h.update(blob)
    a = np.ascontiguousarray(acc, "<f8")
    h.update(f"{a.shape}".encode() + memoryview(a).cast("B"))
    return h.hexdigest()


def _keep(path, value: float) -> None:
    """Store a check's answer (atomic, checksummed; a failure only warns: ``write_entry``)."""
    def writer(p):
        with atomic_output(p) as tmp, h5py.File(tmp, "w") as h:
            h.attrs["max_uplift_m"] = value
            stamp_checksum(h)
    write_entry(path, writer)


def step_doubling_warning(check: dict) -> str | None:
    """The warning of a step-doubling check beyond its tolerance (None within it)."""
    change = check["relative_change"]
    if change is None or change <= check["tolerance"]:
        return None
    t0, t1 = check["window_s"]
    return (f"analysis.dt = {check['dt']:g} s does not resolve the contact dynamics: halving it moves the max "
            f"uplift of a Winkler stand-in of this scene by {100 * change:.0f} % ({1e3 * check['max_uplift_m']:.3g} "
            f"-> {1e3 * check['max_uplift_half_dt_m']:.3g} mm, record {t0:.1f}-{t1:.1f} s; tolerance "
            f"{100 * check['tolerance']:g} %): rerun with dt <= {check['dt'] / 2:g} s and compare")


def check_time_step(model, soil, dt: float) -> float:
    """Refuse a step that does not resolve the first soil-structure mode (of the structure
    ``model`` on the springs ``soil``, see ``proxy_springs``); returns its frequency."""
    f1 = float(modes_on_soil(model, soil).freq[0])
    if dt * f1 * MIN_STEPS_PER_PERIOD > 1.0 + 1e-9:
        raise SceneError(f"analysis.dt = {dt:g} s gives {1 / (dt * f1):.1f} steps per period of the first "
                         f"soil-structure mode ({f1:.3g} Hz): not resolved (at least {MIN_STEPS_PER_PERIOD} "
                         f"needed); use dt <= {1 / (MIN_STEPS_PER_PERIOD * f1):.3g} s")
    return f1


@dataclass(frozen=True)
class SharedRun:
    """What the runs of one scene share whatever their motion, computed once by ``prepare_run``.

    routes : the route names it was prepared for; tables : {"rigid"|"gap": ImpedanceTable} (empty
    when the routes need only the fit and it was found in the cache);
    sweep : the sweep's stats (``computed``, ``from_cache``); springs : the proxy springs of the
    time-step checks (``proxy_springs``); fit : the FitResult of the gap table, or None when no
    route needs it; dt_check : a step-doubling check (``step_doubling``) standing for every run,
    or None: each run checks its own motion (as a single run does).
    """
    routes: tuple
    tables: Mapping
    sweep: Mapping
    springs: object
    fit: object = None
    dt_check: Mapping | None = None


def _chosen_routes(scene, routes):
    """(scene with ``routes``, [Route]); a scene without [structure] for routes that need one raises."""
    if routes:
        scene = scene.with_routes(routes)
    chosen = [get_route(n) for n in scene.analysis.routes]
    if scene.structure is None and any(r.needs_structure for r in chosen):
        raise SceneError(f"scene {scene.name!r} has no [structure]: the routes "
                         f"{', '.join(r.name for r in chosen if r.needs_structure)} need one "
                         "(add [structure] model = \"reactor\", or inline nodes/beams/masses/raft)")
    return scene, chosen


def _tables_read(scene, chosen) -> tuple:
    """The impedance tables the routes read (their union, in route order)."""
    return tuple(dict.fromkeys(t for r in chosen for t in r.tables(scene)))


def _cached_fit(scene, chosen, outputs, cache_dir):
    """The run's rational fit read from the cache, found by its table's inputs (no table is
    read), when a route needs it; else (or on a miss) None."""
    return cached_scene_fit(scene, cache_dir) if outputs and any(r.needs_fit for r in chosen) else None


def _reads_tables(scene, chosen) -> bool:
    """Whether a route reads an impedance table itself (not only through the rational fit)."""
    return any(r.tables(scene) and not r.needs_fit for r in chosen)


def prepare_run(scene, routes=None, cache_dir=None, sweep_progress=None, fit_progress=None) -> SharedRun:
    """The parts of ``run_scene`` that do not depend on the motion, for many runs of ``scene``
    with ``routes`` (default: the scene's): the time-step check (raises as ``run_scene`` does),
    one impedance sweep and, when a route needs it, one rational fit (built here, not on
    demand: a fit that fails raises instead of refusing the route; a fit found in the cache
    leaves the tables unread when no route reads them itself). Progress callbacks as in
    ``run_scene``."""
    scene, chosen = _chosen_routes(scene, routes)
    outputs = _tables_read(scene, chosen)
    with compute_threads():
        springs = proxy_springs(scene, bool(outputs), cache_dir)
        check_time_step(scene.model(), springs, scene.analysis.dt)
        sweep, tables = {}, {}
        fit = _cached_fit(scene, chosen, outputs, cache_dir)
        if outputs and (fit is None or _reads_tables(scene, chosen)):
            tables = scene_impedance(scene, outputs, cache_dir=cache_dir, progress=sweep_progress, stats=sweep)
        if fit is None and "gap" in tables and any(r.needs_fit for r in chosen):
            fit = scene_fit(scene, cache_dir=cache_dir, table=tables["gap"], fit_progress=fit_progress)
    return SharedRun(routes=tuple(scene.analysis.routes), tables=tables, sweep=sweep, springs=springs, fit=fit)


def run_scene(scene, routes=None, cache_dir=None, progress=None, sweep_progress=None, options=None,
              motion=None, fit_progress=None, shared: SharedRun | None = None):
    """Run routes of a scene. Returns (``{route: RouteResult}``, Motion).

    routes : names (default: the scene's ``[analysis].routes``); options : {route: {option:
    value}} (route options such as the TF padding, see ``Route.options``); motion : a Motion
    replacing the scene's (resampled to ``[analysis].dt``); shared : a ``prepare_run`` of this
    scene for these routes (or more): its sweep, fit and proxy springs are used, not recomputed.
    ``progress`` follows each route (label: the route's name), ``sweep_progress`` the BEM
    sweep, done once for all routes (one factorisation per frequency for every table),
    ``fit_progress`` the rational fit (label: its stage); all three follow the progress
    protocol ``progress(done, total, label)`` (orchestrator.progress). A route that stops keeps its results so far (status STOPPED,
    ``message`` says why) and the other routes still run; a route that cannot run on this
    scene is REFUSED with the reason. Bad input found before any route runs raises.
    """
    scene, chosen = _chosen_routes(scene, routes)
    if shared is not None and not set(scene.analysis.routes) <= set(shared.routes):
        raise ValueError(f"run_scene: shared was prepared for the routes {', '.join(shared.routes)}, "
                         f"not {', '.join(scene.analysis.routes)}: call prepare_run with every route")
    dt = scene.analysis.dt
    motion = make_motion(scene.motion, dt) if motion is None else motion.resampled(dt)
    with compute_threads():
        ctx = RunContext(scene=scene, motion=motion, cache_dir=cache_dir)
        outputs = _tables_read(scene, chosen)
        springs = shared.springs if shared is not None else proxy_springs(scene, bool(outputs), cache_dir)
        check_time_step(ctx.model(), springs, dt)
        dt_notes = {}
        if scene.contact.enabled and any(r.time_stepped for r in chosen):
            dt_check = shared.dt_check if shared is not None and shared.dt_check is not None else \
                step_doubling(scene, ctx.model(), springs, motion, cache_dir, keep=shared is None)
            warning = step_doubling_warning(dt_check)
            dt_notes = {"warnings": [warning] if warning else [], "info": {"dt_check": dt_check}}
        sweep = {}
        if shared is not None:
            ctx.tables, sweep = shared.tables, shared.sweep
            if shared.fit is not None:
                ctx.shared["fit"] = shared.fit
        elif outputs:
            ctx.tables = SweptTables(outputs, lambda: scene_impedance(scene, outputs, cache_dir=cache_dir,
                                                                      progress=sweep_progress, stats=sweep))
            fit = _cached_fit(scene, chosen, outputs, cache_dir)
            if fit is not None:
                ctx.shared["fit"] = fit
            if fit is None or _reads_tables(scene, chosen):
                ctx.tables.load()           # before the routes (one sweep for all; its errors raise here)
        if "gap" in ctx.tables and "fit" not in ctx.shared:
            ctx.fit_builder = lambda: scene_fit(scene, cache_dir=cache_dir, table=ctx.tables["gap"],
                                                fit_progress=fit_progress)
        results = {}
        for route in chosen:
            res = _run_route(route, ctx.for_route(route, (options or {}).get(route.name)),
                             _labelled(progress, route.name))
            if route.time_stepped:
                res = res.with_notes(**dt_notes)
            if route.needs_fit and "fit" in ctx.shared and not ctx.fit().report.tol_reached:
                res = res.with_notes(warnings=[f"rational soil fit: {ctx.fit().report.message}"])
            ran = {} if res.status is Status.REFUSED else {"components": list(motion.components)}
            results[route.name] = res.with_notes(skipped=_shared_skips(scene, route, sweep, ctx), info=ran)
    return results, motion


class SweptTables(Mapping):
    """The run's impedance tables ``{output: ImpedanceTable}``, swept (or read from the cache) all
    at once by ``load()``: before the routes when one of them reads a table, else (its routes
    need only the rational fit, found in the cache by the table's inputs) on first use, if any."""

    def __init__(self, outputs, sweep):
        self._outputs, self._sweep, self._tables = tuple(outputs), sweep, None

    def load(self) -> dict:
        if self._tables is None:
            self._tables = self._sweep()
        return self._tables

    def __getitem__(self, output):
        if output not in self._outputs:
            raise KeyError(output)
        return self.load()[output]

    def __contains__(self, output):
        return output in self._outputs

    def __iter__(self):
        return iter(self._outputs)

    def __len__(self):
        return len(self._outputs)


def _run_route(route, ctx, bar) -> RouteResult:
    """The route's result; a stop or a refusal becomes a result with the reason."""
    try:
        return route.run(ctx, bar)
    except USER_INPUT as exc:
        return RouteResult.refused(route.name, str(exc))
    except STOPPED as exc:
        result = getattr(exc, "result", None)      # ConvergenceError carries the histories so far
        return result if result is not None else RouteResult(
            route=route.name, time=np.zeros(0), status=Status.STOPPED, message=f"{type(exc).__name__}: {exc}")


def _shared_skips(scene, route, sweep, ctx) -> list:
    """What the run's shared parts did not compute for this route (only what really happened:
    cache hits are those of this run)."""
    out = []
    tables = route.tables(scene)
    if tables and sweep.get("from_cache"):
        out.append("impedance sweep read from cache")
    elif tables and not sweep and route.needs_fit and "fit" in ctx.shared and ctx.fit().report.cached:
        out.append("impedance table not read: the route needs only the rational fit, found in the cache "
                   "by the table's inputs")
    elif tables and sweep.get("computed") and scene.profile.is_homogeneous and scene.frequencies_hz[0] == 0.0:
        out.append("homogeneous half-space: K(0) from the closed-form static kernels "
                   "(no wavenumber integral at 0 Hz)")
    if "gap" in tables:
        n = scene.mesh.n
        out.append(f"rigid raft: soil interface reduced from 3N = {3 * n} to 6 + N = {6 + n} DOFs")
    if route.needs_fit and "fit" in ctx.shared and ctx.fit().report.cached:
        out.append("rational fit read from cache")
    return out


def _labelled(progress, label: str):
    """progress(done, total) with ``label`` for a route (None for None)."""
    if progress is None:
        return None
    return lambda done, total, _label="": progress(done, total, label)

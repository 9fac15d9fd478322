"""Running a scene: its motion, one impedance sweep and one soil fit shared by every route,
then each route of the registry (orchestrator.routes), into one result per route.

``run_scene(scene)`` returns ``({route: RouteResult}, Motion)``. Every route returns a
result: converged, stopped (the histories so far and the reason) or refused (the reason).
What the run reuses or skips (cache hits, interface reductions) is in each result's notes.

One sequence, in two parts. ``prepare_run(scene)`` does what does not depend on the motion
(the routes, the memory guard, the structure model, the proxy springs and the time-step check,
the cached fit, the sweep) and returns a ``SharedRun``, which makes the fit when a route first
needs it.
``run_scene`` prepares its own run (or takes ``shared=``, a ``prepare_run`` made once for many
runs of one scene under different motions: an ensemble of records, ``orchestrator.ensemble``,
which ``settle``s it first, the fit made once for every cell) and runs the per-motion part: the
motion, its step-doubling check, the routes.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import platform
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from soil_impedance.cache import feed, read_entry, write_entry
from uplift_common.code import code_digest
from uplift_common.files import hdf5_output, stamp_checksum

from structure import ConvergenceError, simulate
from structure.results import RouteResult, Status
from structure.spec import winkler_from_moduli
from structure.soil_interface import WinklerSoil
from structure.winkler import modes_on_soil, springs_from_rigid_impedance

from orchestrator.exit_codes import STOPPED, USER_INPUT
from orchestrator.impedance import cached_scene_fit, scene_fit, scene_impedance, scene_static
from orchestrator.memory_guard import check_run_memory, check_stepping_memory
from orchestrator.motion import Motion, make_motion
from orchestrator.oncurve import scene_key
from orchestrator.routes import RouteInputError, RunContext, get_route
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
    the key of the stepper's inputs (``_dt_check_key``: the structure, the springs' matrices, the
    contact settings, the motion and its step, the code and the C runtime): read back, never
    stepped (nor its stepper built) again, by a run of the same structure, springs, contact,
    motion and step."""
    from fmus.native_stepper import cache_folder, encode_run, library, native_max_uplift, springs_soil   # when it checks
    from structure import NewmarkStepper
    lib = library(cache_folder(cache_dir))
    if lib is None:
        try:
            return simulate(model, soil, motion.acc, motion.dt, contact=scene.contact, route="dt-check").max_uplift()
        except ConvergenceError:
            return float("nan")
    path = None if cache_dir is None or not keep else \
        Path(cache_dir) / f"dtcheck-{_dt_check_key(lib, model, soil, scene.contact, motion)[:24]}.h5"
    if path is not None:
        hit = read_entry(path, lambda h: float(h.attrs["max_uplift_m"]))
        if hit is not None:
            return hit
    st = NewmarkStepper(model, springs_soil(soil, motion.dt), motion.dt, contact=scene.contact,
                        external_soil=True, ag0=motion.acc[0])
    value = native_max_uplift(st, motion.acc, lib, encode_run(st))
    if path is not None:
        _keep(path, value)
    return value


#: what the native answer of a check also depends on besides its inputs: the code that builds the
#: stepper from them (the structure's matrices, the static state, the springs as a soil without
#: memory), the Python side that encodes them for the C runtime, and the measure taken of its histories
DT_CHECK_CODE = ("structure", "soil_impedance.convolution", "soil_impedance.rational", "fmus.native_stepper",
                 "fmus.native_build", "orchestrator.run")


def _dt_check_key(lib, model, soil, contact, motion) -> str:
    """SHA-256 of what a check's native run is made of, taken before its stepper is built (a
    warm run builds none): the compiled library (its file name is the digest of its C sources,
    compiler, flags and platform), ``DT_CHECK_CODE``'s sources, the structure model (every field,
    its arrays' bytes: ``soil_impedance.cache.feed``), the springs as the stepper reads them
    (``_springs_inputs``: a WinklerSoil's constants, else its instantaneous stiffness and damping
    matrices at the motion's step), the contact settings, the step and the
    ground acceleration."""
    h = hashlib.sha256(Path(lib._name).name.encode() + b"\0")
    h.update(code_digest(*DT_CHECK_CODE).encode())
    for part in (model, _springs_inputs(soil, motion.dt), contact, float(motion.dt), np.asarray(motion.acc, float)):
        feed(h, part)
    return h.hexdigest()


def _springs_inputs(soil, dt: float):
    """What the matrices of the proxy springs ``soil`` are made of, for a cache key: a WinklerSoil's
    nodes and constants (its sparse matrices are assembled from them by the structure's code, which
    every such key digests: a warm run assembles nothing), else its instantaneous (K, C) at ``dt``
    as dense arrays."""
    if isinstance(soil, WinklerSoil):
        return ("winkler", soil.xy, soil.kv, soil.kx, soil.ky, soil.cv, soil.cx, soil.cy)
    K, C = soil.instantaneous(dt)
    dense = lambda a: np.asarray(a.toarray() if hasattr(a, "toarray") else a, float)
    return dense(K), dense(C)


#: what a synthetic motion depends on besides its [motion] keys and the step: the code that makes
#: it (the spectral matching, the response spectra, g) and numpy (its random generator and its
#: elementary functions), the machine's kind
MOTION_CODE = ("orchestrator.motion", "orchestrator.spectra", "structure.model")


def scene_motion(config, dt: float, cache_dir=None) -> Motion:
    """``make_motion(config, dt)``: a synthetic motion (``config.kind == "synthetic"``) is kept in
    the cache folder (``motion-<key>.h5``, checksummed, verified on read) under the key of its
    inputs (``_motion_key``: every [motion] key, the step, ``MOTION_CODE``'s sources, numpy's
    version, the machine's kind): a warm run reads its bits back instead of matching the spectrum
    again (the same numbers to the bit, a function of the inputs only); a record is read as
    before, and nothing is kept without a cache folder."""
    if cache_dir is None or config.kind != "synthetic":
        return make_motion(config, dt)
    path = Path(cache_dir) / f"motion-{_motion_key(config, dt)[:24]}.h5"
    hit = read_entry(path, _read_motion)
    if hit is not None:
        return hit
    motion = make_motion(config, dt)

    def writer(p):
        with hdf5_output(p) as h:
            h.create_dataset("acc", data=motion.acc)
            h.attrs.update(dt=motion.dt, label=motion.label, components=" ".join(motion.components))
            stamp_checksum(h)
    write_entry(path, writer)
    return motion


def _motion_key(config, dt: float) -> str:
    """SHA-256 of what ``make_motion(config, dt)`` of a synthetic motion reads: the [motion] keys
    (every field of the MotionConfig, exactly: ``repr``), the step, and ``MOTION_CODE``."""
    fields = {f.name: repr(getattr(config, f.name)) for f in dataclasses.fields(config) if f.init}
    h = hashlib.sha256(json.dumps({"motion": fields, "dt": repr(float(dt)), "numpy": np.__version__,
                                   "machine": platform.machine()}, sort_keys=True).encode())
    h.update(code_digest(*MOTION_CODE).encode())
    return h.hexdigest()


def _read_motion(h) -> Motion:
    acc = h["acc"][()]
    if acc.ndim != 2 or acc.shape[1] != 3:
        raise ValueError(f"acc of shape {acc.shape}, not (nt, 3)")
    return Motion(float(h.attrs["dt"]), acc, str(h.attrs["label"]), tuple(str(h.attrs["components"]).split()))


def _keep(path, value: float) -> None:
    """Store a check's answer (atomic, checksummed; a failure only warns: ``write_entry``)."""
    def writer(p):
        with hdf5_output(p) as h:
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


def check_time_step(model, soil, dt: float, cache_dir=None) -> float:
    """Refuse a step that does not resolve the first soil-structure mode (of the structure
    ``model`` on the springs ``soil``, see ``proxy_springs``: ``first_frequency``, kept in the
    cache folder ``cache_dir``); returns its frequency."""
    f1 = first_frequency(model, soil, cache_dir)
    if dt * f1 * MIN_STEPS_PER_PERIOD > 1.0 + 1e-9:
        raise SceneError(f"analysis.dt = {dt:g} s gives {1 / (dt * f1):.1f} steps per period of the first "
                         f"soil-structure mode ({f1:.3g} Hz): not resolved (at least {MIN_STEPS_PER_PERIOD} "
                         f"needed); use dt <= {1 / (MIN_STEPS_PER_PERIOD * f1):.3g} s")
    return f1


#: what the first soil-structure frequency depends on besides the structure and the springs: the
#: code that assembles their matrices and solves the modes, and the one that keys it
MODES_CODE = ("structure", "orchestrator.run")


def first_frequency(model, soil, cache_dir=None) -> float:
    """The first frequency (Hz) of the structure ``model`` on the springs ``soil``
    (``structure.winkler.modes_on_soil``). With a cache folder and Winkler springs it is kept there
    (``modes-<key>.h5``, checksummed, verified on read) under the key of its inputs (the structure
    model, every field; the springs' nodes and constants, ``_springs_inputs``; ``MODES_CODE``): a
    warm run reads it back instead of assembling the matrices and solving the eigenproblem (scipy
    is not imported)."""
    if cache_dir is None or not isinstance(soil, WinklerSoil):
        return float(modes_on_soil(model, soil).freq[0])
    h = hashlib.sha256(code_digest(*MODES_CODE).encode())
    for part in (model, _springs_inputs(soil, 1.0)):
        feed(h, part)
    path = Path(cache_dir) / f"modes-{h.hexdigest()[:24]}.h5"
    hit = read_entry(path, lambda f: float(f.attrs["f1_hz"]))
    if hit is not None:
        return hit
    f1 = float(modes_on_soil(model, soil).freq[0])

    def writer(p):
        with hdf5_output(p) as f:
            f.attrs["f1_hz"] = f1
            stamp_checksum(f)
    write_entry(path, writer)
    return f1


@dataclass(eq=False)
class SharedRun:
    """What the runs of one scene share whatever their motion, made once by ``prepare_run``: by
    ``run_scene`` for its own run, or once for many (an ensemble's cells, on other processes:
    the object is pickled, without its progress callback).

    scene : the scene with the routes it was prepared for (its motion is not read); routes :
    their names; model : the structure model (``scene.model()``), shared by every route;
    springs : the proxy springs of the time-step checks (``proxy_springs``); tables :
    {"rigid"|"gap": ImpedanceTable}, the union of the routes' tables, swept (or read from the
    cache) once; empty when the routes need only the rational fit and it was found in the cache
    (the tables are then not read); sweep : the sweep's stats (``computed``, ``from_cache``;
    empty without a sweep); fit : the FitResult of the gap table, found in the cache by
    ``prepare_run`` or fitted by ``soil_fit`` when a route first needs it, else None; fit_error :
    the error of that fit when it failed (kept: the fit is tried once, and every route that needs
    it is refused or stopped with the reason); dt_check : a step-doubling check (``step_doubling``)
    standing for every run, or None: each run checks its own motion (as a single run does);
    scene_key : ``oncurve.scene_key`` of the scene (what a pushover of it depends on; each
    route's ``info`` carries it: ``uplift report`` draws the run on that pushover); made :
    {route: what its ``Route.settle`` made in advance} (``settle``; empty for a single run);
    stepping_checked : the fit whose poles the stepping's memory was checked with (``stepping_fit``).
    """
    scene: object
    routes: tuple
    model: object
    springs: object
    tables: Mapping
    sweep: Mapping
    cache_dir: object = None
    fit: object = None
    fit_error: Exception | None = None
    dt_check: Mapping | None = None
    fit_progress: Callable | None = None
    scene_key: str = ""
    made: dict = dataclasses.field(default_factory=dict)
    stepping_checked: object = None

    def soil_fit(self):
        """The rational fit of the gap table (``fit``): made here on first need (``scene_fit`` on
        the swept table, ``fit_progress`` following it), at most once, its error kept and raised
        again at every call."""
        if self.fit is None and self.fit_error is None:
            if "gap" not in self.tables:
                raise RouteInputError("this run has no rational soil fit: the route must declare needs_fit")
            try:
                with compute_threads():
                    self.fit = scene_fit(self.scene, cache_dir=self.cache_dir, table=self.tables["gap"],
                                         fit_progress=self.fit_progress)
            except (*USER_INPUT, *STOPPED) as exc:
                self.fit_error = exc
        if self.fit_error is not None:
            raise self.fit_error.with_traceback(None)
        return self.fit

    def stepping_fit(self):
        """``soil_fit`` for a route that steps it: the memory guard's stepping stage checked again
        with the fit's poles first (before the fit only their bound was known: RunMemoryError,
        exit 2, the route refused with the estimate), once per fit."""
        fit = self.soil_fit()
        if self.stepping_checked is not fit:
            check_stepping_memory(self.scene, fit.model.poles.size, self.routes, self.cache_dir is not None)
            self.stepping_checked = fit
        return fit

    def settle(self) -> SharedRun:
        """Make now what a route would make on first need (the fit, when a route needs it; its
        error kept, not raised; and what each route's ``settle`` makes in advance): before copies
        of this object are sent to other processes (an ensemble's workers), so that it is made
        once for all of them. Returns self."""
        if any(get_route(r).needs_fit for r in self.routes) and "gap" in self.tables:
            try:
                self.soil_fit()
            except (*USER_INPUT, *STOPPED):
                pass                                 # kept in fit_error, raised in each route that needs it
        for name in self.routes:
            route = get_route(name)
            if route.settle is not None and name not in self.made:
                route.settle(self)
        return self

    def __getstate__(self):
        return {**self.__dict__, "fit_progress": None}      # a callback of this process stays here


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


def prepare_run(scene, routes=None, cache_dir=None, sweep_progress=None, fit_progress=None,
                memory_checked: bool = False) -> SharedRun:
    """What the runs of ``scene`` with ``routes`` (default: the scene's) share whatever their
    motion: the only place that chooses the routes (a scene without [structure] for routes that
    need one raises), refuses a run whose estimated peak memory exceeds the machine's
    (``orchestrator.memory_guard.check_run_memory``: RunMemoryError, exit 2), makes the proxy springs
    and checks the time step (raises), finds the cached fit and sweeps: once for all routes, and not at all when the routes need only the
    fit and it was found in the cache by the table's inputs (the sweep's errors raise here).
    The fit itself is made on first need (``SharedRun.soil_fit``; ``settle`` makes it now).
    ``sweep_progress`` follows the sweep, ``fit_progress`` the fit (progress protocol);
    ``memory_checked``: the caller has just made that memory check of this scene and these
    routes (``run_scene``, before the motion), not made again."""
    scene, chosen = _chosen_routes(scene, routes)
    outputs = tuple(dict.fromkeys(t for r in chosen for t in r.tables(scene)))    # their union, in route order
    if not memory_checked:
        check_run_memory(scene, cached=cache_dir is not None)   # every stage's peak, before anything large
    with compute_threads():
        springs = proxy_springs(scene, bool(outputs), cache_dir)
        model = scene.model()
        check_time_step(model, springs, scene.analysis.dt, cache_dir)
        fit = cached_scene_fit(scene, cache_dir) if outputs and any(r.needs_fit for r in chosen) else None
        reads_tables = any(r.tables(scene) and not r.needs_fit for r in chosen)   # not only through the fit
        sweep, tables = {}, {}
        if outputs and (fit is None or reads_tables):
            tables = scene_impedance(scene, outputs, cache_dir=cache_dir, progress=sweep_progress, stats=sweep)
    return SharedRun(scene=scene, routes=tuple(scene.analysis.routes), model=model, springs=springs, tables=tables,
                     sweep=sweep, cache_dir=cache_dir, fit=fit, fit_progress=fit_progress, scene_key=scene_key(scene))


def run_scene(scene, routes=None, cache_dir=None, progress=None, sweep_progress=None, options=None,
              motion=None, fit_progress=None, shared: SharedRun | None = None):
    """Run routes of a scene. Returns (``{route: RouteResult}``, Motion).

    routes : names (default: the scene's ``[analysis].routes``); options : {route: {option:
    value}} (route options such as the TF padding, see ``Route.options``); motion : a Motion
    replacing the scene's (resampled to ``[analysis].dt``); shared : a ``prepare_run`` of this
    scene (whatever its motion) for these routes (or more), used instead of preparing the run
    here: the run is then its per-motion part only (the motion, its step-doubling check, the routes).
    ``progress`` follows each route (label: the route's name), ``sweep_progress`` the BEM
    sweep, done once for all routes (one factorisation per frequency for every table),
    ``fit_progress`` the rational fit (label: its stage); all three follow the progress
    protocol ``progress(done, total, label)`` (orchestrator.progress). A route that stops keeps its results so far (status STOPPED,
    ``message`` says why) and the other routes still run; a route that cannot run on this
    scene is REFUSED with the reason (so is every route that needs a fit that failed, once). Bad input found before any route runs raises.
    """
    scene, chosen = _chosen_routes(scene, routes)
    if shared is not None and not set(scene.analysis.routes) <= set(shared.routes):
        raise ValueError(f"run_scene: shared was prepared for the routes {', '.join(shared.routes)}, "
                         f"not {', '.join(scene.analysis.routes)}: call prepare_run with every route")
    if shared is not None and scene.analysis.dt != shared.scene.analysis.dt:
        raise ValueError(f"run_scene: shared was prepared for analysis.dt = {shared.scene.analysis.dt:g} s, "
                         f"not {scene.analysis.dt:g} s (its time-step check): call prepare_run on this scene")
    dt = scene.analysis.dt
    if shared is None:
        check_run_memory(scene, cached=cache_dir is not None)   # before the motion (prepare_run need not again)
    motion = scene_motion(scene.motion, dt, cache_dir) if motion is None else motion.resampled(dt)   # before any computation
    run = shared if shared is not None else prepare_run(scene, cache_dir=cache_dir, sweep_progress=sweep_progress,
                                                        fit_progress=fit_progress, memory_checked=True)
    with compute_threads():
        check = _Beside(dict, threaded=False)      # the notes of the step-doubling check, if any
        if scene.contact.enabled and any(r.time_stepped for r in chosen):
            check = _Beside(lambda: _dt_notes(run.dt_check), threaded=False) if run.dt_check is not None else \
                _Beside(lambda: _dt_notes(step_doubling(scene, run.model, run.springs, motion, cache_dir,
                                                        keep=shared is None)))
        ctx = RunContext(scene=scene, motion=motion, prepared=run, cache_dir=cache_dir)
        results = {}
        for route in chosen:
            bar = _labelled(progress, route.name)
            res = _run_route(route, ctx.for_route(route, (options or {}).get(route.name)),
                             check.starting(bar) if route.time_stepped else bar)
            if route.time_stepped:
                res = res.with_notes(**check.value())
            if route.needs_fit and run.fit is not None and not run.fit.report.tol_reached:
                res = res.with_notes(warnings=[f"rational soil fit: {run.fit.report.message}"])
            ran = {} if res.status is Status.REFUSED else {"components": list(motion.components),
                                                           "scene_key": run.scene_key}
            results[route.name] = res.with_notes(skipped=_shared_skips(scene, route, run), info=ran)
    return results, motion


def _dt_notes(dt_check: dict) -> dict:
    """The notes of a step-doubling check (``step_doubling``): its warning and its dict
    (``info["dt_check"]``)."""
    warning = step_doubling_warning(dt_check)
    return {"warnings": [warning] if warning else [], "info": {"dt_check": dt_check}}


class _Beside:
    """``call()`` computed once, beside a time-stepped route (``threaded``): started in a thread
    at the route's first progress report (``starting``), when its stepping runs in the C runtime
    without the interpreter's lock, so that a warm run's step-doubling check (its cache reads and
    keys) costs no wall time; computed in the caller's thread when the route reports no progress
    (or not ``threaded``). The value is the same either way (a function of what ``call`` reads,
    which nothing changes meanwhile); ``value()`` waits for it and returns it, or raises its
    exception."""

    def __init__(self, call: Callable[[], object], threaded: bool = True):
        self._call, self._threaded = call, threaded
        self._thread = None
        self._out = None                          # (value, None) or (None, exception)

    def _run(self):
        try:
            self._out = (self._call(), None)
        except BaseException as exc:              # raised again in the caller's thread, by value()
            self._out = (None, exc)

    def starting(self, bar):
        """``bar`` (a progress callback or None) that also starts the computation, at its first
        call, in a thread."""
        if not self._threaded:
            return bar

        def tick(*args):
            if self._thread is None and self._out is None:
                self._thread = threading.Thread(target=self._run, name="uplift-beside")
                self._thread.start()
            if bar is not None:
                bar(*args)
        return tick

    def value(self):
        if self._thread is not None:
            self._thread.join()
        elif self._out is None:
            self._run()
        value, exc = self._out
        if exc is not None:
            raise exc
        return value


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


def _shared_skips(scene, route, run: SharedRun) -> list:
    """What the run's prepared parts did not compute for this route (only what really happened:
    cache hits are those of this run)."""
    out = []
    tables, sweep, fit = route.tables(scene), run.sweep, run.fit
    cached_fit = route.needs_fit and fit is not None and fit.report.cached
    if tables and sweep.get("from_cache"):
        out.append("impedance sweep read from cache")
    elif tables and not sweep and cached_fit:
        out.append("impedance table not read: the route needs only the rational fit, found in the cache "
                   "by the table's inputs")
    elif tables and sweep.get("computed") and scene.profile.is_homogeneous and scene.frequencies_hz[0] == 0.0:
        out.append("homogeneous half-space: K(0) from the closed-form static kernels "
                   "(no wavenumber integral at 0 Hz)")
    out += list(sweep.get("thinning", ()))
    if "gap" in tables:
        n = scene.mesh.n
        what = "rigid raft" if scene.raft is None else "plate raft, rigid in its plane"
        out.append(f"{what}: soil interface reduced from 3N = {3 * n} to 6 + N = {6 + n} DOFs")
    if cached_fit:
        out.append("rational fit read from cache")
    return out


def _labelled(progress, label: str):
    """progress(done, total) with ``label`` for a route (None for None)."""
    if progress is None:
        return None
    return lambda done, total, _label="": progress(done, total, label)

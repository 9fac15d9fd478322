"""The route registry's core: what a route declares and what it receives.

A route is one way of computing the uplift response of a scene (winkler, monolithic, cosim,
linear, timefreq). Each lives in its own module of ``orchestrator/routes/`` and registers one
``Route``: its name, a one-line summary, the impedance tables and soil fit it needs, its bench
knobs, and ``run(context, progress) -> RouteResult``. ``run_scene``, ``uplift run --route``,
``uplift compare``, ``uplift report`` and ``uplift bench`` all read the registry: adding a
route is adding one module (and its name to ``BUILTIN``), or calling ``register`` from user code.

The built-in routes are known by name (``BUILTIN``) and each one's module is imported when that
route is first asked for (``get_route``): importing or listing the registry costs nothing, so
the scene validates route names and the command line lists them without loading what the
routes import (the BEM, the fit, the FMUs), and a run loads only the routes it runs.
Route modules import the leaves (soil_impedance, structure, fmus), the motion, the
time-frequency package and this module, never the scene, run or CLI modules.
"""
from __future__ import annotations

import dataclasses
import importlib
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from uplift_common.errors import UserInputError


#: scene-level knobs ``uplift bench`` knows how to apply (see orchestrator.bench.knob_scene)
SCENE_KNOBS = ("dt", "fit_tol", "element_size", "penalty")


class RouteInputError(UserInputError):
    """A route cannot run on this scene; the message says what to change (exit 2)."""


@dataclass(frozen=True)
class Route:
    """One route of the registry.

    name : str, as in ``[analysis].routes`` and ``--route``
    summary : one line: what the route computes (help, reports)
    run : callable(ctx: RunContext, progress) -> RouteResult; progress is callable(done, total) or None
          (the progress protocol, orchestrator.progress).
          A computation that stops returns a result with status STOPPED and the reason; bad input
          raises RouteInputError (run_scene turns it into a REFUSED result)
    tables : callable(scene) -> tuple of impedance tables read ("rigid", "gap"); run_scene sweeps
             the union of every route's tables once
    needs_fit : reads the rational soil model (``ctx.fit()``, shared by every route of a run)
    needs_structure : refuses scenes without [structure] (checked before anything is computed)
    time_stepped : its answer depends on the analysis step (the run's step-doubling check applies)
    options : route options ``run`` reads from ``ctx.options`` (e.g. "pad_s"), settable by the bench
    bench, quick : {scene: {knob: values, coarse to fine}} swept by ``uplift bench`` (quick: --quick);
                   knobs are SCENE_KNOBS or ``options``
    reference_rank : ``uplift compare`` takes the present route of highest rank among those with
                     uplift as its default reference: the most exact present (timefreq 3, built on
                     the BEM table itself; monolithic 2; cosim 1, equal to it to round-off)
    uplift : the raft may lift off (False: bonded, e.g. linear; never a reference of uplift
             quantities, and its own max uplift is not compared)
    settle : callable(shared: orchestrator.run.SharedRun) or None: what ``run`` would make on
             first need that does not depend on the motion (e.g. timefreq's constrained fit),
             made once by ``SharedRun.settle`` before an ensemble's workers receive the run; it
             keeps it in ``shared.made[name]`` (``run`` reads ``ctx.prepared.made``); its errors
             are the route's to report in each run (settle must not raise them)
    """
    name: str
    summary: str
    run: Callable
    tables: Callable = lambda scene: ("gap",)
    needs_fit: bool = False
    needs_structure: bool = True
    time_stepped: bool = True
    options: tuple[str, ...] = ()
    bench: Mapping[str, Mapping[str, tuple]] = field(default_factory=dict)
    quick: Mapping[str, Mapping[str, tuple]] = field(default_factory=dict)
    reference_rank: int = 0
    uplift: bool = True
    settle: Callable | None = None

    def __post_init__(self):
        unknown = {k for knobs in (*self.bench.values(), *self.quick.values()) for k in knobs} \
            - set(SCENE_KNOBS) - set(self.options)
        if unknown:
            raise ValueError(f"route {self.name!r}: bench knobs {sorted(unknown)} are neither scene knobs "
                             f"{SCENE_KNOBS} nor route options {self.options}")


#: the built-in routes, in the registry's order: each is the module ``orchestrator.routes.<name>``,
#: which registers it when imported
BUILTIN = ("monolithic", "cosim", "linear", "timefreq", "winkler")
_REGISTRY: dict[str, Route] = {}
#: built-in routes whose module was imported (each registered itself) or that were unregistered
_LOADED: set = set()
_REMOVED: set = set()
_LOADING: list = []
_LOCK = threading.RLock()


def _load(name: str) -> None:
    """Import the module of the built-in route ``name`` once (it registers itself): a route's
    module, and what it imports (the BEM, the fit, the FMUs), loads when that route is first
    asked for, not when the registry is read (``uplift --help`` lists the names only). Another
    thread asking meanwhile waits for the import to finish (the route is then registered)."""
    if name not in BUILTIN or name in _LOADED:
        return
    with _LOCK:
        if name in _LOADED or name in _LOADING:
            return
        _LOADING.append(name)
        try:
            importlib.import_module(f"orchestrator.routes.{name}")
        finally:
            _LOADING.remove(name)
        _LOADED.add(name)


def register(route: Route) -> Route:
    """Add ``route`` to the registry (replacing a route of the same name); returns it."""
    if route.name in BUILTIN and route.name not in _LOADING:
        _load(route.name)           # user code replacing a built-in: the built-in registers first, then is replaced
    _REMOVED.discard(route.name)
    _REGISTRY[route.name] = route
    return route


def unregister(name: str) -> None:
    with _LOCK:
        _REGISTRY.pop(name, None)
        if name in BUILTIN:
            _LOADED.add(name)                             # not imported again: it stays out
            _REMOVED.add(name)


def route_names() -> tuple[str, ...]:
    """Names of the registered routes, in registration order (the built-in ones first, in
    ``BUILTIN``'s order): read without importing any route's module."""
    return tuple(n for n in BUILTIN if n not in _REMOVED) + tuple(n for n in _REGISTRY if n not in BUILTIN)


def get_route(name: str) -> Route:
    """The registered route ``name`` (a built-in one's module imported on first use)."""
    if name not in _REMOVED:
        _load(name)
    try:
        return _REGISTRY[name]
    except KeyError:
        raise RouteInputError(f"unknown route {name!r}; available: {', '.join(route_names())}") from None


def has_uplift(name: str) -> bool:
    """Whether route ``name`` lets the raft lift off (a name not registered: assumed so)."""
    return name not in route_names() or get_route(name).uplift


def default_reference(names) -> str:
    """The reference route among ``names``: the most exact one present, i.e. of the routes with
    uplift the registered one of highest reference_rank (timefreq, else monolithic, else
    cosim), else the first with uplift; a route without uplift (linear) only when no other is
    there."""
    names = list(names)
    if not names:
        raise ValueError("no routes to choose a reference among")
    lifting = [n for n in names if has_uplift(n)]
    known = route_names()
    ranked = [(get_route(n).reference_rank, -i) for i, n in enumerate(lifting) if n in known]
    best = max(ranked, default=(0, 0))
    return lifting[-best[1]] if best[0] > 0 else (lifting or names)[0]


def route_model(ctx):
    """The structure a route runs: the run's model, on the scene's plate raft when it has one
    (``Scene.plate_model``: a PlateRaftModel)."""
    model = ctx.model()
    if getattr(ctx.scene, "raft", None) is not None:
        model = ctx.scene.plate_model(model)
    return model


@dataclass
class RunContext:
    """What a route receives: the scene, its motion at the analysis step, and what the run
    prepared once for every route (and, in an ensemble, for every motion): the structure model,
    the impedance tables and the soil fit.

    scene : the validated Scene; motion : orchestrator.motion.Motion at scene.analysis.dt
    prepared : the run's prepared parts (``orchestrator.run.SharedRun``): ``model``, ``tables``
        and ``soil_fit()``
    cache_dir : impedance/fit cache folder or None
    options : {option: value} for this route (bench knobs such as pad_s)
    stepped : the route steps the fit in time (its memory checked with the fit's poles: ``fit``)
    """
    scene: object
    motion: object
    prepared: object
    cache_dir: object = None
    options: Mapping = field(default_factory=dict)
    stepped: bool = False

    @property
    def tables(self) -> Mapping:
        """{"rigid"|"gap": ImpedanceTable}: those the run's routes declared, swept once for all
        (none when the routes need only the fit and it was found in the cache: a route that
        declares ``needs_fit`` reads its table through ``fit()`` only)."""
        return self.prepared.tables

    def model(self):
        """The structure model (built once per run)."""
        return self.prepared.model

    def fit(self):
        """The FitResult of the scene's gap table (read from the cache or fitted once per run; a
        fit that failed raises its error again; for a time-stepped route, the stepping's memory
        checked with the fit's poles: ``SharedRun.stepping_fit``)."""
        return self.prepared.stepping_fit() if self.stepped else self.prepared.soil_fit()

    def for_route(self, route: Route, options: Mapping | None = None) -> RunContext:
        """The context a route's ``run`` receives: this run's prepared parts and the route's options."""
        unknown = set(options or {}) - set(route.options)
        if unknown:
            raise RouteInputError(f"route {route.name!r} has no option {sorted(unknown)[0]!r}; "
                                  f"options: {', '.join(route.options) or 'none'}")
        return dataclasses.replace(self, options=dict(options or {}), stepped=route.time_stepped)

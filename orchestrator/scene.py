"""Scenes: one TOML file describing soil, foundation, impedance sweep, structure, contact,
motion, analysis and outputs, one section per part, parsed once into a frozen ``Scene``.

Every key of every section is checked when the scene is loaded, here and nowhere else: an
unknown section or key is an error (a typo must not be ignored silently, the message suggests
the key meant), numbers must be numbers (not strings, not booleans), finite and in range,
integers must be integers, and the sections must agree with each other (output nodes exist in
the structure, a record file exists and reads, the routes have the soil they need). Every error
is a SceneError whose message starts with the scene file (or name) and names the key at fault
and what would fix it; errors of the parts (StructureError, MotionError, SoilError, MeshError)
are re-raised as SceneError with that prefix.

The configuration dataclasses (MotionConfig, AnalysisConfig, OutputConfig, WinklerConfig and
Scene itself, which checks the sections against each other) check their values when
constructed: ``dataclasses.replace`` on them goes through the same checks. Relative paths are
relative to the scene file. Built-in scenes ship as package data (``orchestrator/scenes/*.toml``)
and are loaded by name: ``load_scene("reactor")``.
"""
from __future__ import annotations

import copy
import csv
import sys
from dataclasses import dataclass, field, fields, replace
from functools import partial
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from orchestrator.motion import (DIRECTIONS, FORMATS, SPECTRA, SYNTHETIC_DT, UNITS, VERTICAL_RATIO, G, Motion,
                                 MotionError, check_components, read_components, read_record)
from orchestrator.routes import get_route, route_names
from soil_impedance.mesh import InterfaceMesh, MeshError, circle_mesh, read_nodes_csv, rectangle_mesh
from soil_impedance.profile import DAMPING_MODELS, Layer, Material, SoilError, SoilProfile
from structure.contact import ContactSettings
from structure.errors import StructureError
from structure.model import StructureModel
from structure.plate_raft import PLATE_RANGES, PlateProperties, PlateRaftModel, plate_cells
from structure.spec import (WINKLER_MODULI, StructureSpec, build_model, check_choice, check_keys, check_number,
                            contact_from_spec, parse_structure, show, winkler_moduli)
from uplift_common.ranges import MAX_LAYERS, check_count, check_plausible

if TYPE_CHECKING:       # the parsers of optional sections load with them (_design_spectra, _soil_design, _foundation)
    from orchestrator.design_spectra import DesignSpectraConfig
    from orchestrator.soil_cases import SoilCases, StrainCompatibleConfig
    from soil_impedance.mesh_file import MeshSource

# the error, the built-in names, the TOML reader and the PGA limit live in a module the command
# line loads without this one (numpy, the mesh, the structure): re-exported here
from orchestrator.scene_base import MAX_PGA_G, SceneError, builtin_scenes, tomllib

#: the sweep's solvers, the fast solver's default tolerance and its range (soil_impedance.solvers: not
#: the fast solver's module, which imports scipy.fft, which a run that does not sweep never uses)
from soil_impedance.solvers import DEFAULT_TOL as SOLVER_TOL, SOLVERS, TOL_RANGE as SOLVER_TOL_RANGE


_check_keys = partial(check_keys, error=SceneError)
_number = partial(check_number, error=SceneError)
_choice = partial(check_choice, error=SceneError)
_plausible = partial(check_plausible, error=SceneError)

SECTIONS = ("soil", "foundation", "impedance", "structure", "contact", "motion", "analysis", "output")
#: most time steps a run may take (motion duration over the analysis step; a synthetic motion
#: is generated at SYNTHETIC_DT): 1000 s at 5 ms. Results hold (steps, nodes) arrays
MAX_STEPS = 200_000
#: most impedance frequencies (one BEM solve each)
MAX_FREQUENCIES = 10_000
#: default tolerance of the rational soil fit ([analysis].fit_tol). A causal model cannot follow
#: hysteretic damping ξ closer than about ξ over the band (docs/formulation.md, Causality): scenes on
#: damped hysteretic soil set a looser one, e.g. 0.04 on 3 % rock
FIT_TOL = 0.01
#: default time budget of the timefreq route, s ([analysis].timefreq_max_s)
TIMEFREQ_MAX_S = 600.0


# ---- section configurations -------------------------------------------------------------------

@dataclass(frozen=True)
class MotionConfig:
    """[motion]: a synthetic spectrum-compatible record or recorded accelerograms, on one axis
    (``direction``) or on several at once (``components``).

    direction : "x" | "y" | "z", one component (the default, "x", when components is not given);
    None when ``components`` is given (the two are exclusive).
    components : synthetic: a non-empty subset of "x", "y", "z" (independent components, see
    orchestrator.motion.synthetic_components), kept as a tuple of axes in x, y, z order;
    record: {axis: file} (absolute paths, resolved against the scene folder by the loader),
    kept as a tuple of (axis, Path) pairs in x, y, z order.
    kind "synthetic": spectrum, pga_g (> 0, g: the peak of each horizontal), duration_s (> 0,
    s), seed (an integer >= 0), vertical_ratio (the vertical's peak over pga_g, in (0, 2],
    default 2/3; only with "z" among the components). kind "record": file (with direction) or
    components, format "two-column" | "peer-at2", units "g" | "m/s2", scale (a finite nonzero
    factor, on every component). ``record`` is the Motion read at construction (at the
    records' own step)."""

    kind: str = "synthetic"
    direction: str | None = None
    spectrum: str = "RG1.60"
    pga_g: float = 0.25
    duration_s: float = 10.0
    seed: int = 1
    file: Path | None = None
    format: str = "two-column"
    units: str = "g"
    scale: float = 1.0
    components: tuple | None = None
    vertical_ratio: float | None = None
    record: Motion | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self):
        _choice("motion.kind", self.kind, ("synthetic", "record"))
        self._check_axes()
        if self.kind == "synthetic":
            _choice("motion.spectrum", self.spectrum, SPECTRA)
            _set(self, "pga_g", _number("motion.pga_g", self.pga_g, 0.0, expect="a peak ground acceleration > 0 g"))
            _set(self, "duration_s", _number("motion.duration_s", self.duration_s, 0.0))
            _number("motion.seed", self.seed, 0, lo_open=False, integer=True, expect="an integer >= 0")
            return
        _choice("motion.format", self.format, FORMATS)
        _choice("motion.units", self.units, UNITS)
        if not _number("motion.scale", self.scale, expect="a finite nonzero factor"):
            raise SceneError(f"motion.scale = {show(self.scale)} must be a finite nonzero factor")
        _plausible("motion.scale", self.scale, "scale")
        _set(self, "scale", float(self.scale))
        if self.components is None:
            if self.file is None:
                raise SceneError('motion.file is missing for kind = "record": give the record file '
                                 "(a path relative to the scene file), or components = { x = ..., y = ..., z = ... }")
            _set(self, "file", _record_path("motion.file", self.file))
        where = "motion.file" if self.components is None else "motion.components"
        try:
            if self.components is None:
                _set(self, "record", read_record(self.file, self.format, self.units, self.scale, self.direction))
            else:
                _set(self, "record", read_components(self.components, self.format, self.units, self.scale))
        except MotionError as exc:
            raise SceneError(str(exc) if str(exc).startswith(where) else f"{where}: {exc}") from None

    def _check_axes(self):
        """direction or components (exclusive), normalised; vertical_ratio with a synthetic z only."""
        if self.components is None:
            _set(self, "direction", "x" if self.direction is None else self.direction)
            _choice("motion.direction", self.direction, DIRECTIONS)
        elif self.direction is not None:
            raise SceneError("motion: give direction (one component, with file for a record) or components "
                             "(several at once), not both")
        elif self.kind == "synthetic":
            if isinstance(self.components, dict):
                raise SceneError(f"motion.components = {show(self.components)}: a synthetic motion takes a list "
                                 'of axes, e.g. components = ["x", "y", "z"] (files are for kind = "record")')
            _set(self, "components", _checked(check_components, self.components))
        else:
            pairs = self.components
            if isinstance(pairs, dict):
                pairs = tuple(pairs.items())
            elif not (isinstance(pairs, (list, tuple)) and all(isinstance(p, (list, tuple)) and len(p) == 2
                                                                 for p in pairs)):
                raise SceneError(f"motion.components = {show(self.components)}: a record takes one file per "
                                 'component, e.g. components = { x = "H1.AT2", y = "H2.AT2", z = "UP.AT2" }')
            files = dict(pairs)
            axes = _checked(check_components, list(files))
            if self.file is not None:
                raise SceneError("motion: give file (with direction) or components = { x = ..., ... }, not both")
            _set(self, "components", tuple((a, _record_path(f"motion.components.{a}", files[a])) for a in axes))
        if self.vertical_ratio is not None:
            if self.kind != "synthetic" or "z" not in self.axes or self.direction is not None:
                raise SceneError("motion.vertical_ratio scales the synthetic vertical component: it goes with "
                                 'kind = "synthetic" and "z" in components (with direction = "z", pga_g is the '
                                 "vertical peak); remove it")
            _set(self, "vertical_ratio", _number("motion.vertical_ratio", self.vertical_ratio, 0.0, 2.0,
                                                 expect="the vertical peak over pga_g, in (0, 2], e.g. 0.667"))
        elif self.kind == "synthetic" and self.direction is None and "z" in self.axes:
            _set(self, "vertical_ratio", VERTICAL_RATIO)

    @property
    def axes(self) -> tuple[str, ...]:
        """The components that carry a motion, in x, y, z order."""
        if self.direction is not None:
            return (self.direction,)
        return tuple(c if isinstance(c, str) else c[0] for c in self.components)

    @property
    def files(self) -> tuple:
        """Record files as (axis, Path) pairs (empty for a synthetic motion)."""
        if self.kind != "record":
            return ()
        return ((self.direction, self.file),) if self.direction is not None else self.components

    @property
    def length_s(self) -> float:
        """Duration of the motion, s."""
        return self.duration_s if self.kind == "synthetic" else self.record.duration


def _checked(check, value):
    """check(value), its MotionError as a SceneError."""
    try:
        return check(value)
    except MotionError as exc:
        raise SceneError(str(exc)) from None


def _record_path(where: str, path) -> Path:
    """An absolute path to an existing record file (the loader resolves relative ones)."""
    if not isinstance(path, (str, Path)) or not Path(path).is_absolute():
        raise SceneError(f"{where} = {show(path)} must be an absolute path here "
                         "(the scene loader resolves it against the scene folder)")
    if not Path(path).is_file():
        raise SceneError(f"{where} = {str(path)!r}: no such file (paths are relative to the scene file)")
    return Path(path)


@dataclass(frozen=True)
class AnalysisConfig:
    """[analysis]: routes (names from orchestrator.routes.route_names(), each once), dt (s, in
    (0, 0.05]), fit_tol (relative error of the rational soil fit, in (0, 1), see FIT_TOL),
    timefreq_max_s (time budget of the timefreq route, s; past it the best iterate is kept, flagged),
    max_pga_g (the largest peak ground acceleration a motion may have, g; see MAX_PGA_G),
    hht_alpha (the time-stepped routes' HHT-alpha, in [-1/3, 0]: 0 the average acceleration rule,
    the default; below 0 it damps the frequencies near the step's Nyquist frequency, the stiff
    penalty contact's: see ``HHT_ROUTES`` and docs/formulation.md, 'Flexible raft')."""

    routes: tuple[str, ...] = ("winkler",)
    dt: float = 0.005
    fit_tol: float = FIT_TOL
    timefreq_max_s: float = TIMEFREQ_MAX_S
    max_pga_g: float = MAX_PGA_G
    hht_alpha: float = 0.0

    def __post_init__(self):
        _set(self, "routes", check_routes(self.routes))
        _set(self, "dt", _number("analysis.dt", self.dt, 0.0, 0.05, expect=(
            "a step in (0, 0.05] s: the contact and the structure's modes up to ~30 Hz need a few "
            "steps per period")))
        _set(self, "fit_tol", _number("analysis.fit_tol", self.fit_tol, 0.0, 1.0, hi_open=True,
                                      expect="a relative fit error in (0, 1), e.g. 0.04"))
        _set(self, "timefreq_max_s", _number("analysis.timefreq_max_s", self.timefreq_max_s, 0.0,
                                             expect="a positive number of seconds, e.g. 600"))
        _set(self, "max_pga_g", _number("analysis.max_pga_g", self.max_pga_g, 0.0,
                                        expect=f"a peak ground acceleration limit > 0 g, e.g. {MAX_PGA_G:g}"))
        _set(self, "hht_alpha", _number("analysis.hht_alpha", self.hht_alpha, -1.0 / 3.0, 0.0, lo_open=False,
                                        expect="an HHT alpha in [-1/3, 0]: 0 (the default, no numerical "
                                               "damping) or e.g. -0.05"))
        other = [r for r in self.routes if r not in HHT_ROUTES]
        if self.hht_alpha != 0 and other:
            raise SceneError(f"analysis.hht_alpha = {self.hht_alpha:g} is a time step's rule of the routes "
                             f"{', '.join(HHT_ROUTES)}; route{'s' if len(other) > 1 else ''} {', '.join(other)} "
                             f"solve{'' if len(other) > 1 else 's'} the equations without it: set hht_alpha = 0 or "
                             "drop them from analysis.routes")


@dataclass(frozen=True)
class OutputConfig:
    """[output]: nodes, the names of the structure nodes whose responses are kept (None: every
    named node); checked against the structure by Scene. raft_points: {name: (x, y) m} points of
    a plate raft (about its centre) whose accelerations and floor spectra are kept beside the
    nodes' (the nearest plate vertex; Scene checks that the raft is a plate)."""

    nodes: tuple[str, ...] | None = None
    raft_points: dict | None = None

    def __post_init__(self):
        if self.raft_points is not None:
            _set(self, "raft_points", _raft_points(self.raft_points))
        if self.nodes is None:
            return
        nodes = self.nodes
        if (not isinstance(nodes, (list, tuple)) or not nodes
                or not all(isinstance(n, str) and n for n in nodes)):
            raise SceneError(f"output.nodes = {show(nodes)} must be a non-empty list of structure node "
                             "names, e.g. [\"top\"] (omit it for every named node)")
        twice = sorted({n for n in nodes if nodes.count(n) > 1})
        if twice:
            raise SceneError(f"output.nodes lists {twice[0]!r} twice")
        _set(self, "nodes", tuple(nodes))


WINKLER_CHOICES = {"springs": ("rigid", "nodal"), "match": ("rocking", "vertical"), "damping": ("rccg", "dashpots")}


@dataclass(frozen=True)
class WinklerConfig:
    """[soil] winkler: the winkler route's spring mattress. Either subgrade moduli given
    explicitly, ``moduli`` = (kv, kh, cv, ch) (N/m^3, N s/m^3 per unit area; the structure keeps
    its own damping; no BEM needed), or how to calibrate them on the BEM: springs "rigid" (the
    rigid static impedance shared by area) | "nodal" (the nodal static diagonal), match
    "rocking" | "vertical" (which rigid stiffness is exact), damping "rccg" (composite modal) |
    "dashpots" (the rigid impedance's dashpots at the first soil-structure frequency)."""

    springs: str = "rigid"
    match: str = "rocking"
    damping: str = "rccg"
    moduli: tuple[float, float, float, float] | None = None

    def __post_init__(self):
        for key, choices in WINKLER_CHOICES.items():
            _choice(f"soil.winkler.{key}", getattr(self, key), choices)
        if self.moduli is not None:
            if not isinstance(self.moduli, (list, tuple)) or len(self.moduli) != 4:
                raise SceneError(f"soil.winkler moduli = {show(self.moduli)} must be (kv, kh, cv, ch)")
            try:
                _set(self, "moduli", winkler_moduli(dict(zip(WINKLER_MODULI, self.moduli, strict=True))))
            except StructureError as exc:
                raise SceneError(str(exc)) from None

    @property
    def explicit(self) -> bool:
        """True when the moduli are given (no BEM calibration)."""
        return self.moduli is not None


def _set(obj, name, value):
    object.__setattr__(obj, name, value)


def check_routes(routes, where: str = "analysis.routes") -> tuple:
    """Route names as a tuple: a non-empty list of known routes (orchestrator.routes), each once."""
    names = route_names()
    if not isinstance(routes, (list, tuple)) or not routes:
        raise SceneError(f"{where} = {show(routes)} must be a non-empty list of routes, e.g. [\"winkler\"]; "
                         f"available: {', '.join(names)}")
    for r in routes:
        if not isinstance(r, str) or r not in names:
            raise SceneError(f"{where}: unknown route {show(r)}; available: {', '.join(names)}")
        if routes.count(r) > 1:
            raise SceneError(f"{where} lists {r!r} twice")
    return tuple(routes)


# ---- the scene --------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class Scene:
    """A validated scene (see the module docstring).

    profile is None only when [soil] winkler gives explicit moduli and no half-space is given
    (then only the winkler route runs); structure is None when the scene has no [structure]
    (the routes refuse it). Construction checks the sections against each other."""

    name: str
    base_dir: Path
    profile: SoilProfile | None
    mesh: InterfaceMesh
    contact_kind: str                       # "welded" or "relaxed" (soil-raft interface of the BEM)
    frequencies_hz: np.ndarray
    structure: StructureSpec | None = None
    contact: ContactSettings = field(default_factory=ContactSettings)
    motion: MotionConfig = field(default_factory=MotionConfig)
    analysis: AnalysisConfig = field(default_factory=AnalysisConfig)
    output: OutputConfig = field(default_factory=OutputConfig)
    winkler: WinklerConfig = field(default_factory=WinklerConfig)
    #: the parsed TOML the scene was built from, the command line's overrides applied (see
    #: ``orchestrator.scene_file.scene_toml``); ``with_routes`` keeps it in step, a plain
    #: ``dataclasses.replace`` does not
    source: dict | None = field(default=None, repr=False)
    #: the command line's overrides, in the order applied: ({"option": "--pga", "value": 0.5,
    #: "key": "motion.pga_g", "was": 0.25, "now": 0.5}, ...); for a record, --pga sets motion.scale
    overrides: tuple = ()
    #: [soil] cases (the Cv rule or named profiles, orchestrator.soil_cases), None: one soil
    soil_cases: SoilCases | None = None
    #: [soil] strain_compatible (the equivalent-linear free-field analysis), None: the soil as given
    strain_compatible: StrainCompatibleConfig | None = None
    #: [output] design_spectra (broadened, enveloped floor spectra, orchestrator.design_spectra)
    design_spectra: DesignSpectraConfig | None = None
    #: where a [foundation] mesh = FILE was read from (the file, its SHA-256, the group, the
    #: raft centre in its coordinates: ``soil_impedance.mesh_file.MeshSource``); None otherwise
    mesh_source: MeshSource | None = None
    #: [impedance] frequency_tol: sweep a thinned subset of the frequencies, interpolating the rest
    #: where held-out frequencies show an error within it (soil_impedance.frequencies); None: all
    frequency_tol: float | None = None
    #: [foundation] raft = { kind = "plate", ... }: the plate raft (structure.plate_raft); None: rigid
    raft: PlateProperties | None = None
    #: [impedance] solver and solver_tol: the BEM sweep's solver ("auto", "dense", "fast") and the
    #: fast solver's relative residual (soil_impedance.fastsolve; auto: dense below 500 nodes)
    solver: str = "auto"
    solver_tol: float = SOLVER_TOL

    def __post_init__(self):
        if self.raft is not None:
            other = [r for r in self.analysis.routes if r not in PLATE_ROUTES]
            if other:
                raise SceneError(
                    f"foundation.raft.kind = \"plate\" runs on the route{'s' if len(PLATE_ROUTES) > 1 else ''} "
                    f"{', '.join(PLATE_ROUTES)} only (the time-stepped routes on either stepper, the frequency-domain routes); "
                    f"route{'s' if len(other) > 1 else ''} {', '.join(other)} cannot carry a plate yet (a rigid "
                    "raft only: the Winkler route's springs): drop them from "
                    "analysis.routes, or use raft.kind = \"rigid\"")
        f = np.array(self.frequencies_hz, float)
        f.setflags(write=False)
        _set(self, "frequencies_hz", f)
        _choice("impedance.solver", self.solver, SOLVERS)
        _number("impedance.solver_tol", self.solver_tol, *SOLVER_TOL_RANGE, lo_open=False)
        routes = self.analysis.routes
        if self.profile is None:
            need = [r for r in routes if get_route(r).tables(self)]      # routes that read a BEM table
            if need:
                raise SceneError(
                    "soil.halfspace is missing: routes " + ", ".join(need) + " need the BEM soil (layers over "
                    "a half-space), e.g. halfspace = { vs = 500.0, nu = 0.33, rho = 2000.0 }"
                    + ("" if self.winkler.explicit else
                       "; a winkler-only run may give [soil] winkler = { kv, kh } moduli instead"))
        if self.output.raft_points is not None:
            if self.raft is None:
                raise SceneError("output.raft_points: the points of a plate raft; this scene's raft is rigid (its "
                                 "motion is the raft node's: add \"raft\" to output.nodes instead, or make it a plate "
                                 "with foundation.raft.kind = \"plate\")")
            other = [r for r in self.analysis.routes if r not in RAFT_POINT_ROUTES]
            if other:
                raise SceneError(f"output.raft_points is computed by the route{'s' if len(RAFT_POINT_ROUTES) > 1 else ''} "
                                 f"{', '.join(RAFT_POINT_ROUTES)} only; route{'s' if len(other) > 1 else ''} "
                                 f"{', '.join(other)} give{'' if len(other) > 1 else 's'} no plate accelerations: drop "
                                 "them from analysis.routes or remove output.raft_points")
            clash = sorted(set(self.output.raft_points) & set(self.structure.node_names if self.structure else ()))
            if clash:
                raise SceneError(f"output.raft_points: {clash[0]!r} is the name of a structure node; name the point "
                                 "otherwise")
        if self.raft is not None and self.raft.damping > 0:
            undamped = [r for r in self.analysis.routes if r in UNDAMPED_PLATE_ROUTES]
            if undamped:
                raise SceneError(f"foundation.raft.damping: the route{'s' if len(undamped) > 1 else ''} "
                                 f"{', '.join(undamped)} condense{'' if len(undamped) > 1 else 's'} the plate without "
                                 "its own damping: set damping.ratio = 0 for them, or drop them from analysis.routes")
        if self.output.nodes is not None:
            if self.structure is None:
                raise SceneError("output.nodes names structure nodes but the scene has no [structure]")
            known = self.structure.node_names
            for n in self.output.nodes:
                if n not in known:
                    raise SceneError(f"output.nodes: {n!r} is not a named structure node; "
                                     f"named nodes: {', '.join(known)}")
        self._check_steps()
        self._check_intensity()

    def _check_intensity(self):
        """Refuse a motion whose peak ground acceleration exceeds [analysis].max_pga_g."""
        m, limit = self.motion, self.analysis.max_pga_g
        if m.kind == "synthetic":
            vertical = m.vertical_ratio if m.vertical_ratio is not None else 1.0      # set with a z component
            peak = m.pga_g * max(1.0, vertical)
            what = (f"motion.pga_g = {m.pga_g:g}" if peak == m.pga_g else
                    f"motion.pga_g = {m.pga_g:g} with vertical_ratio = {vertical:g} peaks at {peak:.4g} g, which")
        else:
            peak = float(np.max(m.record.pga)) / G
            what = f"motion.scale = {m.scale:g} makes the record peak at {peak:.4g} g, which"
        if peak > limit * (1 + 1e-9):          # a record scaled to the limit exactly passes
            raise SceneError(f"{what} exceeds the intensity limit analysis.max_pga_g = {limit:g} g: check the "
                             "value (g, not m/s2?), or raise the limit (--max-pga on the command line)")

    def _check_steps(self):
        m, dt = self.motion, self.analysis.dt
        length = m.length_s
        if m.kind == "synthetic" and length < 20 * max(dt, SYNTHETIC_DT):
            raise SceneError(f"motion.duration_s = {length:g} s is too short: at least 20 steps of "
                             f"max(analysis.dt, {SYNTHETIC_DT:g} s), i.e. >= {20 * max(dt, SYNTHETIC_DT):g} s")
        if m.kind == "record" and length < 20 * dt:
            raise SceneError(f"motion.file: the record lasts {length:g} s, under 20 steps of analysis.dt = "
                             f"{dt:g} s; use a longer record or a smaller dt")
        steps = length / (min(dt, SYNTHETIC_DT) if m.kind == "synthetic" else dt)
        if steps > MAX_STEPS:
            what = "motion.duration_s = " if m.kind == "synthetic" else "motion.file: the record lasts "
            raise SceneError(f"{what}{length:g} s makes {steps:.3g} time steps; at most MAX_STEPS = "
                             f"{MAX_STEPS}: shorten the motion or raise analysis.dt")

    def model(self) -> StructureModel:
        """The StructureModel of [structure] on the scene's interface nodes (built at each call)."""
        if self.structure is None:
            raise SceneError(f"scene {self.name!r} has no [structure] section; add one, e.g. "
                             '[structure] model = "reactor"')
        return build_model(self.structure, self.mesh.xy, self.mesh.area)

    def check_rigid_raft(self, what: str, instead: str = "") -> None:
        """Refuse a plate raft in ``what`` (a command that models a rigid raft only, for now);
        ``instead``: what does carry a plate, said as the other fix."""
        if self.raft is not None:
            raise SceneError(f"{what} models a rigid raft only (for now); scene {self.name!r} has foundation.raft.kind "
                             "= \"plate\": set it to \"rigid\" (or remove foundation.raft) for this command"
                             + (f", or {instead}" if instead else ""))

    def plate_model(self, model: StructureModel | None = None):
        """The PlateRaftModel of a plate raft (``raft`` not None) on the interface's cells: the
        stick model (``model``, default ``self.model()``) with its raft master's mass and inertia
        replaced by the plate's own (rho t A per vertex)."""
        if self.raft is None:
            raise SceneError(f"scene {self.name!r} has a rigid raft: foundation.raft.kind = \"plate\" makes a plate")
        model = model or self.model()
        stick = replace(model, raft=replace(model.raft, m=0.0, inertia=(0.0, 0.0, 0.0)))
        points, cells, trace = plate_cells(self.mesh.xy, self.mesh.cell, self.mesh.cells)
        try:
            return PlateRaftModel(stick, self.raft, points, cells, trace)
        except StructureError as exc:
            raise SceneError(f"foundation.{exc}") from None

    def with_routes(self, routes, where: str = "--route") -> Scene:
        """The scene with other routes (e.g. the command line's, named ``where`` in messages),
        checked like [analysis].routes and against the soil the scene has."""
        source = None if self.source is None else \
            {**self.source, "analysis": {**self.source.get("analysis", {}), "routes": list(routes)}}
        return replace(self, analysis=replace(self.analysis, routes=check_routes(routes, where)), source=source)


def is_design(scene) -> bool:
    """True when the scene asks for soil cases, strain-compatible soil or design spectra (its run
    is ``orchestrator.design``'s)."""
    return any(x is not None for x in (scene.soil_cases, scene.strain_compatible, scene.design_spectra))


def load_scene(spec: str | Path, max_pga_g: float | None = None, pga_g: float | None = None,
               dt: float | None = None, duration_s: float | None = None) -> Scene:
    """Load a scene from a TOML path or a built-in name (see ``builtin_scenes()``). The command
    line's overrides, when given, replace keys of the scene (recorded in ``Scene.overrides``,
    checked like the keys, a refusal naming the option): ``max_pga_g`` (g) its
    [analysis].max_pga_g (--max-pga), ``dt`` (s) its [analysis].dt (--dt), ``duration_s`` (s) the
    [motion].duration_s of a synthetic motion (--duration; a record is refused: it lasts as long
    as its file), ``pga_g`` (g) the [motion].pga_g of a synthetic motion, or the [motion].scale
    that makes a record's stronger horizontal (its vertical, without one) peak at ``pga_g`` (--pga)."""
    path = Path(spec)
    builtins = ", ".join(builtin_scenes())
    if path.is_file():
        try:
            raw = path.read_bytes()
        except OSError as exc:
            raise SceneError(f"scene file {str(path)!r} cannot be read: {exc.strerror}") from None
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            line = raw[:exc.start].count(b"\n") + 1
            raise SceneError(f"scene file {str(path)!r}, line {line}: byte {raw[exc.start]:#04x} is not "
                             "UTF-8 text; save the scene as UTF-8") from None
        base, name, origin = path.resolve().parent, path.stem, f"scene file {str(path)!r}"
    elif str(spec) in builtin_scenes():
        res = resources.files("orchestrator.scenes") / f"{spec}.toml"
        text, base, name = res.read_text(), Path(str(res)).parent, str(spec)
        origin = f"scene {name!r}"
    elif path.is_dir():
        raise SceneError(f"scene {str(path)!r} is a directory; give a .toml file or a built-in scene "
                         f"name ({builtins})")
    elif path.suffix == ".toml" or path.exists():
        raise SceneError(f"scene file {str(path)!r} does not exist; give a path to a .toml file "
                         f"or a built-in scene name ({builtins})")
    else:
        raise SceneError(f"unknown scene {str(spec)!r}: not a file and not a built-in scene ({builtins})")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"{origin} is not valid TOML: {exc}") from None
    overrides = []
    if max_pga_g is not None:
        if not isinstance(data.get("analysis", {}), dict):
            raise SceneError(f"{origin}: [analysis] must be a table of keys (a section)")
        was = data.get("analysis", {}).get("max_pga_g", MAX_PGA_G)
        data["analysis"] = {**data.get("analysis", {}), "max_pga_g": max_pga_g}
        overrides.append({"option": "--max-pga", "value": max_pga_g, "key": "analysis.max_pga_g", "was": was, "now": max_pga_g})
    scene = _scene(data, base, name, origin)
    for option, value in (("--dt", dt), ("--duration", duration_s), ("--pga", pga_g)):
        if value is not None:
            scene = _override(scene, option, value, origin, overrides)
    return replace(scene, overrides=tuple(overrides)) if overrides else scene


#: the command line's overrides of ``uplift run``: option -> (section, key) of the scene
OVERRIDES = {"--dt": ("analysis", "dt"), "--duration": ("motion", "duration_s"), "--pga": ("motion", "pga_g")}


def _override(scene: Scene, option: str, value: float, origin: str, done: list) -> Scene:
    """``scene`` with the key of ``option`` (OVERRIDES) set to ``value``, rebuilt from its
    source and checked; appends the record of the change to ``done``."""
    section, key = OVERRIDES[option]
    config, given = getattr(scene, section), value
    if section == "motion" and config.kind == "record":
        if option == "--duration":
            raise SceneError(f"{origin}: --duration {value:g} sets [motion].duration_s of a synthetic motion; this "
                             f"scene's motion is a record, which lasts as long as its file ({config.length_s:g} s): "
                             "drop --duration (or cut the record file)")
        peaks = dict(zip("xyz", config.record.pga))
        horizontal = [peaks[a] for a in ("x", "y") if a in config.axes]
        peak = max(horizontal) if horizontal else peaks["z"]          # m/s², already scaled
        if not peak > 0:
            raise SceneError(f"{origin}: --pga {value:g}: the record is zero everywhere and cannot be scaled "
                             "to a peak; check [motion] file, or drop --pga")
        key, value = "scale", config.scale * value * G / peak
    data = copy.deepcopy(scene.source)
    table = data.get(section, {})
    was = table.get(key, getattr(config, key))
    data[section] = {**table, key: value}
    try:
        new = _scene(data, scene.base_dir, scene.name, origin)
    except SceneError as exc:
        text = str(exc).removeprefix(f"{origin}: ")
        raise SceneError(f"{origin}: {option} {given:g}: {text}") from None
    done.append({"option": option, "value": given, "key": f"{section}.{key}", "was": was, "now": value})
    return new


def scene_from_dict(data: dict, base_dir: Path | str = ".", name: str = "scene") -> Scene:
    """Validate a scene given as nested dicts (the parsed TOML); relative paths are relative to
    base_dir."""
    return _scene(data, Path(base_dir), name, f"scene {name!r}")


def _scene(data, base_dir: Path, name: str, origin: str) -> Scene:
    try:
        _check_keys(data, SECTIONS, "scene", what="section")
        soil = _section(data, "soil", 'halfspace = { vs = ..., nu = ..., rho = ... }')
        _check_keys(soil, ("layers", "halfspace", "damping_model", "winkler", "cases", "strain_compatible"), "soil")
        winkler = _winkler(soil.get("winkler"))
        model = _choice("soil.damping_model", soil.get("damping_model", "hysteretic"), DAMPING_MODELS,
                        hint="hysteretic: G (1 + 2i damping) at every frequency, the default; causal: "
                             "constant Q with a 0.05 Hz cut-off, vs given at 1 Hz")
        needed = "halfspace" in soil or "layers" in soil or not winkler.explicit
        profile = _profile(soil, model) if needed else None
        cases, strain_compatible = _soil_design(soil, model, profile)
        foundation = _section(data, "foundation", 'shape = "circle", radius = ..., element_size = ...')
        mesh, contact_kind, mesh_source = _foundation(foundation, base_dir)
        raft = _raft(foundation.get("raft", {}), mesh)
        freqs = _frequencies(_table(data, "impedance"))
        solver, solver_tol = _solver(_table(data, "impedance"))
        frequency_tol = _frequency_tol(_table(data, "impedance"))
        structure = parse_structure(data["structure"]) if "structure" in data else None
        contact = contact_from_spec(_table(data, "contact"))
        motion = _motion(_table(data, "motion"), base_dir)
        analysis = _config(AnalysisConfig, _table(data, "analysis"), "analysis")
        output_table = _table(data, "output")
        design_spectra = _design_spectra(output_table["design_spectra"]) if "design_spectra" in output_table \
            else None
        output = _config(OutputConfig, {k: v for k, v in output_table.items() if k != "design_spectra"}, "output")
        _check_design_spectra(design_spectra, structure, output, analysis)
        return Scene(name=name, base_dir=base_dir, profile=profile, mesh=mesh, contact_kind=contact_kind,
                     frequencies_hz=freqs, structure=structure, contact=contact, motion=motion,
                     analysis=analysis, output=output, winkler=winkler, source=copy.deepcopy(data),
                     soil_cases=cases, strain_compatible=strain_compatible, design_spectra=design_spectra,
                     mesh_source=mesh_source, raft=raft, solver=solver, solver_tol=solver_tol,
                     frequency_tol=frequency_tol)
    except _scene_errors() as exc:
        raise SceneError(f"{origin}: {exc}") from None


#: the errors of the parsers a scene loads only when it has their sections ([soil] cases and
#: strain_compatible, [output] design_spectra): (module, class)
_SECTION_ERRORS = (("orchestrator.soil_cases", "SoilCaseError"), ("orchestrator.design_spectra", "SpectraConfigError"))


def _scene_errors() -> tuple:
    """The error types a scene's parsing reports with its origin: this module's and those of the
    section parsers loaded (one that was not loaded raised nothing)."""
    loaded = tuple(getattr(sys.modules[m], name) for m, name in _SECTION_ERRORS if m in sys.modules)
    return (SceneError, StructureError, MotionError, SoilError, MeshError, *loaded)


def _design_spectra(table):
    """[output] design_spectra (``orchestrator.design_spectra``, loaded here: a scene without it never loads it)."""
    from orchestrator.design_spectra import parse_design_spectra     # start-up cost: only a scene with the section
    return parse_design_spectra(table)


def _table(data: dict, section: str) -> dict:
    table = data.get(section, {})
    if not isinstance(table, dict):
        raise SceneError(f"[{section}] must be a table of keys (a section), got {section} = {show(table)}")
    return table


def _section(data: dict, section: str, hint: str) -> dict:
    if section not in data:
        raise SceneError(f"the scene has no [{section}] section; add one, e.g. [{section}] {hint}")
    return _table(data, section)


def _config(cls, table: dict, section: str):
    """cls(**table) after the key check (the dataclass fields are the section's keys)."""
    _check_keys(table, tuple(f.name for f in fields(cls) if f.init), section)
    return cls(**table)


MOTION_KEYS = {"synthetic": ("kind", "direction", "components", "spectrum", "pga_g", "vertical_ratio",
                             "duration_s", "seed"),
               "record": ("kind", "direction", "file", "components", "format", "units", "scale")}


def _motion(table: dict, base_dir: Path) -> MotionConfig:
    kind = _choice("motion.kind", table.get("kind", "synthetic"), tuple(MOTION_KEYS))
    _check_keys(table, MOTION_KEYS[kind], "motion")
    if "components" in table and "direction" in table:
        raise SceneError("motion: give direction (one component) or components (several at once), not both; "
                         'e.g. components = ["x", "y", "z"] alone')
    resolve = lambda where, f: _resolve(where, f, base_dir)
    if "file" in table:
        table = {**table, "file": resolve("motion.file", table["file"])}
    comps = table.get("components")
    if kind == "record" and isinstance(comps, dict):
        table = {**table, "components": {a: resolve(f"motion.components.{a}", f) for a, f in comps.items()}}
    return MotionConfig(**table)


def _resolve(where: str, file, base_dir: Path) -> Path:
    """A record path of the scene, resolved against the scene folder."""
    if not isinstance(file, str) or not file:
        raise SceneError(f"{where} = {show(file)} must be a path (a string, relative to the scene file)")
    return (base_dir / file).resolve()


def _winkler(table) -> WinklerConfig:
    if table is None:
        return WinklerConfig()
    _check_keys(table, tuple(WINKLER_CHOICES) + WINKLER_MODULI, "soil.winkler")
    given = set(table) & set(WINKLER_MODULI)
    if not given:
        return WinklerConfig(**table)
    if set(table) - given:
        raise SceneError("soil.winkler: give either subgrade moduli { kv, kh, cv, ch } or a BEM calibration "
                         "{ springs, match, damping }, not both")
    return WinklerConfig(moduli=winkler_moduli(table))


MATERIAL_KEYS = ("vs", "vp", "nu", "rho", "damping")
#: the plausible range (uplift_common.ranges.PLAUSIBLE) of each key of a soil material
SOIL_RANGES = {"vs": "vs", "vp": "vp", "rho": "rho", "thickness": "thickness"}     # damping: Material's [0, 0.5)
#: ... of each length of [foundation]
FOUNDATION_RANGES = {"radius": "radius", "lx": "length", "ly": "length", "element_size": "element_size"}


def _material(table, where: str, cls=Material, extra=(), damping_model="hysteretic"):
    _check_keys(table, MATERIAL_KEYS + tuple(extra), where)
    for key in ("vs", "rho") + tuple(extra):
        if key not in table:
            raise SceneError(f"{where}.{key} is missing (give vs in m/s, rho in kg/m^3"
                             + (", thickness in m)" if extra else ")"))
    values = {k: _number(f"{where}.{k}", v) for k, v in table.items()}
    for k, v in values.items():
        if k in SOIL_RANGES:
            _plausible(f"{where}.{k}", v, SOIL_RANGES[k])
    return cls(name=where, damping_model=damping_model, **values)


def _profile(soil: dict, model: str) -> SoilProfile:
    if "halfspace" not in soil:
        raise SceneError("soil.halfspace is missing: the profile needs a half-space below its layers, "
                         "e.g. halfspace = { vs = 500.0, nu = 0.33, rho = 2000.0 }")
    layers = soil.get("layers", [])
    if not isinstance(layers, list):
        raise SceneError("soil.layers must be a list of tables { thickness, vs, nu or vp, rho, damping }")
    check_count("soil.layers", len(layers), MAX_LAYERS, "layers", SceneError)
    out = tuple(_material(t, f"soil.layers[{i}]", cls=Layer, extra=("thickness",), damping_model=model)
                for i, t in enumerate(layers))
    return SoilProfile(out, _material(soil["halfspace"], "soil.halfspace", damping_model=model))


def _soil_design(soil: dict, model: str, profile: SoilProfile | None):
    """(SoilCases or None, StrainCompatibleConfig or None) of [soil] cases and strain_compatible
    (orchestrator.soil_cases): both need the BEM profile; named case profiles are parsed like the
    scene's own (same damping model), strain_compatible goes with the Cv rule or with no cases."""
    if "cases" not in soil and "strain_compatible" not in soil:
        return None, None
    if profile is None:
        raise SceneError("soil.cases and soil.strain_compatible need the BEM soil: give soil.halfspace "
                         "(and soil.layers)")

    from orchestrator.soil_cases import parse_cases, parse_strain_compatible   # only a scene with these sections

    def case_profile(table, where):
        try:
            return _profile(table, model)
        except (SceneError, SoilError) as exc:
            raise SceneError(f"{where}: {exc}") from None
    cases = parse_cases(soil["cases"], case_profile) if "cases" in soil else None
    sc = None
    if "strain_compatible" in soil:
        if cases is not None and cases.cv is None:
            raise SceneError("soil.strain_compatible goes with cases = { cv = ... } (the cases are built on the "
                             "strain-compatible profile) or with no cases, not with named profiles: remove one")
        sc = parse_strain_compatible(soil["strain_compatible"], len(profile.layers))
    return cases, sc


def _check_design_spectra(config, structure, output, analysis) -> None:
    """[output] design_spectra's nodes among the nodes whose histories are kept ([output].nodes,
    or every named node) and its routes among [analysis].routes."""
    if config is None:
        return
    if structure is None:
        raise SceneError("output.design_spectra needs a [structure] (floor spectra of its nodes)")
    kept = output.nodes or structure.node_names
    for node in config.nodes or ():
        if node not in kept:
            raise SceneError(f"output.design_spectra.nodes: {node!r} is not among the nodes kept "
                             f"(output.nodes: {', '.join(kept)}); add it to output.nodes or remove it")
    for route in config.routes or ():
        if route not in analysis.routes:
            raise SceneError(f"output.design_spectra.routes: {route!r} is not run (analysis.routes: "
                             f"{', '.join(analysis.routes)}); add it there or remove it")


FOUNDATION_KEYS = {"circle": ("radius", "element_size"), "rectangle": ("lx", "ly", "element_size"),
                   "nodes": ("file",), "mesh": ("mesh", "mesh_group", "centre")}
#: the keys each shape cannot do without (the others are optional)
FOUNDATION_REQUIRED = {"circle": ("radius", "element_size"), "rectangle": ("lx", "ly", "element_size"),
                       "nodes": ("file",), "mesh": ("mesh",)}


def _foundation(table: dict, base_dir: Path):
    """(InterfaceMesh, contact kind, MeshSource or None) of [foundation]. ``mesh = FILE`` (a
    finite-element mesh, soil_impedance.mesh_file) implies shape = "mesh"."""
    shape = table.get("shape", "mesh" if "mesh" in table else "circle")
    shape = _choice("foundation.shape", shape, tuple(FOUNDATION_KEYS))
    keys = FOUNDATION_KEYS[shape]
    if shape != "mesh" and "mesh" in table:
        raise SceneError(f'foundation.mesh is the file of a finite-element raft: it goes with shape = "mesh" (or no '
                         f'shape), not shape = {shape!r}; remove one of the two')
    _check_keys(table, ("shape", "contact") + keys + ("raft",), "foundation", required=FOUNDATION_REQUIRED[shape])
    for key in set(keys) & set(FOUNDATION_RANGES):
        if key in table:
            _plausible(f"foundation.{key}", table[key], FOUNDATION_RANGES[key])
    contact = _choice("foundation.contact", table.get("contact", "welded"), ("welded", "relaxed"),
                      hint="welded: all traction components, the default; relaxed: no shear under normal loads")
    if shape == "circle":
        return circle_mesh(table["radius"], table["element_size"]), contact, None
    if shape == "rectangle":
        return rectangle_mesh(table["lx"], table["ly"], table["element_size"]), contact, None
    if shape == "mesh":
        file, group = table["mesh"], table.get("mesh_group")
        if not isinstance(file, str) or not file:
            raise SceneError(f"foundation.mesh = {show(file)} must be a path (a string, relative to the scene file)")
        if group is not None and (not isinstance(group, str) or not group):
            raise SceneError(f"foundation.mesh_group = {show(group)} must be the name of a group of the mesh file "
                             '(a string, e.g. "base"); omit it to take every 2-D cell')
        from soil_impedance.mesh_file import read_mesh_source     # only a scene with a mesh file
        mesh, source = read_mesh_source(base_dir / file, group, table.get("centre"))
        return mesh, contact, source
    file = table["file"]
    if not isinstance(file, str) or not file:
        raise SceneError(f"foundation.file = {show(file)} must be a path (a string, relative to the scene file)")
    try:
        return read_nodes_csv(base_dir / file), contact, None
    except (UnicodeDecodeError, OSError, csv.Error) as exc:
        raise SceneError(f"foundation.file = {file!r}: cannot read it as a UTF-8 CSV x,y,area: {exc}") from None


#: the routes that step with analysis.hht_alpha (the Newmark steppers, native and Python, and the
#: FMUs' pair); the frequency-domain routes have no time step's rule and refuse a non-zero alpha
HHT_ROUTES = ("monolithic", "cosim", "winkler")
#: the routes that run a plate raft (foundation.raft.kind = "plate")
PLATE_ROUTES = ("monolithic", "cosim", "linear", "timefreq")
#: the keys of foundation.raft = { kind = "plate", ... } (rigid_radius, damping optional)
PLATE_KEYS = ("kind", "thickness", "E", "nu", "rho", "rigid_radius", "rigid_centre", "damping")
#: the routes that give [output] raft_points (the Python stepper's plate vertices)
RAFT_POINT_ROUTES = ("monolithic",)
#: the routes whose plate has no damping of its own (the frequency-domain condensation)
UNDAMPED_PLATE_ROUTES = ("linear", "timefreq")
#: foundation.raft.damping = { ratio, frequency_hz }: the default frequency, Hz
PLATE_DAMPING_HZ = 10.0


def _raft_points(points) -> dict:
    """output.raft_points = { name = [x, y], ... } (m about the raft centre) as {name: (x, y)}."""
    eg = "e.g. raft_points = { edge = [18.0, 0.0] } (m about the raft centre)"
    if not isinstance(points, dict) or not points:
        raise SceneError(f"output.raft_points = {show(points)} must be a table of named points, {eg}")
    out = {}
    for name, xy in points.items():
        if (not isinstance(xy, (list, tuple)) or len(xy) != 2
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) for v in xy)):
            raise SceneError(f"output.raft_points.{name} = {show(xy)} must be [x, y] in m, {eg}")
        out[str(name)] = (float(xy[0]), float(xy[1]))
    return out


def _plate_damping(table) -> dict:
    """foundation.raft.damping = { ratio, frequency_hz }: {damping, damping_hz} of PlateProperties."""
    eg = f"e.g. damping = {{ ratio = 0.02, frequency_hz = {PLATE_DAMPING_HZ:g} }}"
    if not isinstance(table, dict):
        raise SceneError(f"foundation.raft.damping = {show(table)} must be a table, {eg} (stiffness proportional: "
                         "the ratio at that frequency)")
    _check_keys(table, ("ratio", "frequency_hz"), "foundation.raft.damping", required=("ratio",))
    ratio = _number("foundation.raft.damping.ratio", table["ratio"], 0.0, 1.0, lo_open=False, hi_open=True,
                    expect=f"a damping ratio in [0, 1), {eg}")
    hz = _number("foundation.raft.damping.frequency_hz", table.get("frequency_hz", PLATE_DAMPING_HZ), 0.0, 1e3,
                 expect=f"a frequency in (0, 1000] Hz, {eg}")
    return {"damping": ratio, "damping_hz": hz}


def _raft(table, mesh: InterfaceMesh) -> PlateProperties | None:
    """foundation.raft: None for kind = "rigid" (the default), else the PlateProperties (SI);
    rigid_radius defaults to half the raft's radius (``mesh.radius``)."""
    if not isinstance(table, dict):
        raise SceneError(f"foundation.raft = {show(table)} must be a table, e.g. raft = {{ kind = \"plate\", "
                         "thickness = 4.0, E = 30e9, nu = 0.2, rho = 2500.0 }")
    kind = _choice("foundation.raft.kind", table.get("kind", "rigid"), ("rigid", "plate"),
                   hint="rigid: the raft's rigid-body DOFs only, the default; plate: a DKT plate on the interface's "
                        "cells")
    if kind == "rigid":
        _check_keys(table, ("kind",), "foundation.raft")
        return None
    _check_keys(table, PLATE_KEYS, "foundation.raft", required=("thickness", "E", "nu", "rho"))
    values = {}
    for key, (lo, hi) in PLATE_RANGES.items():
        values[key] = _number(f"foundation.raft.{key}", table[key], lo, hi, lo_open=False,
                              expect=f"a number in [{lo:g}, {hi:g}] ({dict(thickness='m', E='Pa', nu='-', rho='kg/m^3')[key]})")
    radius = 0.5 * mesh.radius
    if "rigid_radius" in table:
        radius = _number("foundation.raft.rigid_radius", table["rigid_radius"], 0.0,
                         expect="a positive length in m (the plate vertices within it of the raft centre move with "
                                "the stick base)")
    if mesh.cell is None and mesh.cells is None:
        raise SceneError("foundation.raft.kind = \"plate\" needs the interface's cells: a circle or a rectangle of "
                         "square cells, or a mesh file (foundation.mesh); this foundation has none "
                         f"(shape {mesh.kind!r})")
    if "damping" in table:
        values.update(_plate_damping(table["damping"]))
    if "rigid_centre" in table:
        c = table["rigid_centre"]
        if (not isinstance(c, (list, tuple)) or len(c) != 2
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) for v in c)):
            raise SceneError(f"foundation.raft.rigid_centre = {show(c)} must be [x, y] in m about the raft centre (the "
                             "centre of the held region, the stick base), e.g. rigid_centre = [0.0, 0.0]")
        values.update(rigid_x=float(c[0]), rigid_y=float(c[1]))
    return PlateProperties(rigid_radius=radius, **values)



def _solver(table: dict) -> tuple[str, float]:
    """[impedance] solver ("auto": dense below 500 interface nodes or on a mesh file, else the fast
    solver of grid meshes) and solver_tol (its relative residual)."""
    solver = _choice("impedance.solver", table.get("solver", "auto"), SOLVERS,
                     hint="auto: the fast solver on a circle or rectangle grid of 500 nodes or more, else dense; "
                          "dense: one LU per frequency; fast: FFT products and GMRES (grid meshes)")
    lo, hi = SOLVER_TOL_RANGE
    tol = _number("impedance.solver_tol", table.get("solver_tol", SOLVER_TOL), lo, hi, lo_open=False,
                  expect=f"a relative residual in [{lo:g}, {hi:g}] (default {SOLVER_TOL:g})")
    return solver, float(tol)


def _frequency_tol(table: dict) -> float | None:
    """[impedance] frequency_tol (relative interpolation error allowed where frequencies are thinned), or None."""
    if "frequency_tol" not in table:
        return None
    return _number("impedance.frequency_tol", table["frequency_tol"], 0.0, 0.5,
                   expect="a relative error in (0, 0.5], e.g. 1e-3 (or leave it out: every frequency swept)")


def _frequencies(table: dict) -> np.ndarray:
    _check_keys(table, ("frequencies_hz", "range_hz", "frequency_tol", "solver", "solver_tol"), "impedance")
    if "frequencies_hz" in table and "range_hz" in table:
        raise SceneError("impedance: give frequencies_hz or range_hz, not both")
    if "range_hz" in table:
        r = table["range_hz"]
        if not isinstance(r, list) or len(r) != 3:
            raise SceneError(f"impedance.range_hz = {show(r)} must be [fmin, fmax, count] (count an integer)")
        fmin = _number("impedance.range_hz[0]", r[0], 0.0, lo_open=False, expect="a frequency fmin >= 0 Hz")
        fmax = _number("impedance.range_hz[1]", r[1], fmin, expect=f"a frequency fmax > fmin = {fmin:g} Hz")
        _plausible("impedance.range_hz[1]", fmax, "frequency")
        count = _number("impedance.range_hz[2]", r[2], 2, MAX_FREQUENCIES, lo_open=False, integer=True,
                        expect=f"an integer count in [2, {MAX_FREQUENCIES}]")
        return np.linspace(fmin, fmax, count)
    freqs = table.get("frequencies_hz", [0.0, 2.0, 4.0])
    if not isinstance(freqs, list) or not 1 <= len(freqs) <= MAX_FREQUENCIES:
        raise SceneError(f"impedance.frequencies_hz = {show(freqs)} must be a non-empty list of numbers in Hz "
                         f"(at most {MAX_FREQUENCIES})")
    f = np.array([_plausible(f"impedance.frequencies_hz[{i}]", _number(f"impedance.frequencies_hz[{i}]", v, 0.0,
                                                                         lo_open=False), "frequency")
                  for i, v in enumerate(freqs)])
    if np.any(np.diff(f) <= 0):
        raise SceneError(f"impedance.frequencies_hz = {show(freqs)} must be >= 0 and strictly increasing")
    return f

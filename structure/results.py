"""One result type for every route (time-domain and frequency-domain routes fill it alike).

A RouteResult is immutable: it is built once, by keyword, when a route has finished (or
stopped), and its arrays are read-only. Routes that add to a result make a new one
(``with_notes``, ``dataclasses.replace``).
"""
from __future__ import annotations

import dataclasses
import enum
from dataclasses import dataclass, field
from types import MappingProxyType
from collections.abc import Mapping

import numpy as np


class Status(str, enum.Enum):
    """How a route ended."""

    CONVERGED = "converged"   # the whole record was computed to the route's tolerance
    STOPPED = "stopped"       # a computation stopped (Newton failure, budget, divergence): histories so far
    REFUSED = "refused"       # the route could not run on this input (message says why): no histories


@dataclass(frozen=True)
class RunNotes:
    """What every reader of a result uses, besides the histories.

    skipped : what the run did not compute and why (cache hits, closed contact, ...)
    warnings : what the user should know before trusting the numbers
    precheck : what the linear contact pre-check found (structure.ContactSettings.precheck)
    timings : {part: wall s}, e.g. setup, solve, build
    """
    skipped: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()
    precheck: str = ""
    timings: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self):
        object.__setattr__(self, "skipped", tuple(str(s) for s in self.skipped))
        object.__setattr__(self, "warnings", tuple(str(s) for s in self.warnings))
        object.__setattr__(self, "timings", MappingProxyType({str(k): float(v) for k, v in self.timings.items()}))

    def as_dict(self) -> dict:
        return {"skipped": list(self.skipped), "warnings": list(self.warnings), "precheck": self.precheck,
                "timings": dict(self.timings)}


def _frozen(a, dtype=float):
    a = np.array(a, dtype=dtype)        # a private copy: the result never aliases a caller's buffer
    a.flags.writeable = False
    return a


@dataclass(frozen=True, kw_only=True)
class RouteResult:
    """Time histories of one run. nt time samples, N interface nodes. Build it by keyword.

    route : str                         the route's name, e.g. "winkler", "monolithic", "timefreq"
    time : (nt,) s
    raft : (nt, 6) raft DOFs q (ux, uy, uz m; rx, ry, rz rad), dynamic (relative to the
           static state and to the free field)
    gap : (nt, N) m, uplift g_i >= 0
    contact_force : (nt, N) N, total compressive contact force P_i = P0_i + p_i
    soil_w : (nt, N) m, dynamic soil vertical displacement under each node
    acc : {name: (nt, 3)} absolute accelerations (relative + ground), m/s^2
    disp : {name: (nt, 3)} displacements relative to the free field, m
    energy : {input, kinetic, strain, damping, soil, contact: (nt,)} J, cumulative works
             and stored energies (input = kinetic + strain + damping + soil + contact, exact
             for alpha = 0); "soil" and "contact" are works done on the soil and on the
             penalty springs; optional "contact_potential": the physical penalty energy
             (contact_potential - contact > 0 would be energy created by contact switching)
    newton_iters : (nt,) int, linear solves per step (0 for linear routes)
    status : Status; message : str (why it stopped or was refused; "" when converged)
    wall_s : float, s; xy : (N, 2) m interface nodes
    notes : RunNotes (skipped, warnings, precheck, timings)
    info : route-specific details (static settlement, P0, penalty, solver history, ...), JSON-able
    plate_deflection : (nt, N) m, a plate raft's deflection at the interface nodes (dynamic, as
                       raft); plate_vertex_deflection : (nt, m) m, at its vertices; plate_vertices
                       (m, 2) m about the raft centre (None for a rigid raft)
    plate_moment : (nt, n_base, 3) N m/m, a plate raft's bending moments [Mx, My, Mxy] per unit
                   length (static + dynamic; positive: top fibre in tension) in the cells around
                   the stick base, the interface nodes plate_moment_cells (n_base,);
                   plate_moment_peak : (N, 3) N m/m, the largest |Mx|, |My|, |Mxy| of each cell
                   over the run; plate_vertex_held : (m,) bool, the vertices of the held region
    """
    route: str
    time: np.ndarray
    raft: np.ndarray | None = None
    gap: np.ndarray | None = None
    contact_force: np.ndarray | None = None
    soil_w: np.ndarray | None = None
    acc: Mapping[str, np.ndarray] = field(default_factory=dict)
    disp: Mapping[str, np.ndarray] = field(default_factory=dict)
    energy: Mapping[str, np.ndarray] = field(default_factory=dict)
    newton_iters: np.ndarray | None = None
    status: Status = Status.CONVERGED
    message: str = ""
    wall_s: float = 0.0
    xy: np.ndarray | None = None
    notes: RunNotes = field(default_factory=RunNotes)
    info: Mapping = field(default_factory=dict)
    plate_deflection: np.ndarray | None = None
    plate_vertex_deflection: np.ndarray | None = None
    plate_vertices: np.ndarray | None = None
    plate_moment: np.ndarray | None = None
    plate_moment_peak: np.ndarray | None = None
    plate_moment_cells: np.ndarray | None = None
    plate_vertex_held: np.ndarray | None = None

    def __post_init__(self):
        put = lambda name, value: object.__setattr__(self, name, value)
        time = _frozen(self.time)
        nt = time.shape[0]
        put("time", time)
        N = 0 if self.gap is None else np.shape(self.gap)[1]
        for name, width in (("raft", 6), ("gap", N), ("contact_force", N), ("soil_w", N)):
            value = getattr(self, name)
            put(name, _frozen(np.zeros((nt, width)) if value is None else value))
            if getattr(self, name).shape[0] != nt:
                raise ValueError(f"RouteResult.{name} has {getattr(self, name).shape[0]} samples, time has {nt}")
        for name in ("acc", "disp", "energy"):
            put(name, MappingProxyType({str(k): _frozen(v) for k, v in getattr(self, name).items()}))
        put("newton_iters", _frozen(np.zeros(nt, int) if self.newton_iters is None else self.newton_iters, int))
        put("xy", None if self.xy is None else _frozen(self.xy))
        for name in ("plate_deflection", "plate_vertex_deflection", "plate_vertices", "plate_moment",
                     "plate_moment_peak"):
            put(name, None if getattr(self, name) is None else _frozen(getattr(self, name)))
        for name, kind in (("plate_moment_cells", int), ("plate_vertex_held", bool)):
            put(name, None if getattr(self, name) is None else _frozen(getattr(self, name), kind))
        put("status", Status(self.status))
        put("message", str(self.message))
        put("wall_s", float(self.wall_s))
        if not isinstance(self.notes, RunNotes):
            put("notes", RunNotes(**dict(self.notes)))
        put("info", MappingProxyType(dict(self.info)))
        if self.status is not Status.CONVERGED and not self.message:
            raise ValueError(f"a {self.status.value} RouteResult needs a message saying why")

    @classmethod
    def refused(cls, route: str, message: str, notes: RunNotes | None = None) -> RouteResult:
        """A route that could not run on this input: no histories, the reason in ``message``."""
        return cls(route=route, time=np.zeros(0), status=Status.REFUSED, message=message,
                   notes=notes or RunNotes())

    @property
    def converged(self) -> bool:
        return self.status is Status.CONVERGED

    @property
    def nt(self) -> int:
        return self.time.shape[0]

    def replace(self, **changes) -> RouteResult:
        """A copy with ``changes`` (keyword fields of the dataclass)."""
        return dataclasses.replace(self, **changes)

    def with_notes(self, skipped=(), warnings=(), precheck: str | None = None, timings=None,
                   info=None) -> RouteResult:
        """A copy with items added to its notes (and keys to its info)."""
        n = self.notes
        notes = RunNotes(skipped=n.skipped + tuple(skipped), warnings=n.warnings + tuple(warnings),
                         precheck=n.precheck if precheck is None else precheck,
                         timings={**n.timings, **(timings or {})})
        return self.with_checked(notes=notes, info=MappingProxyType({**self.info, **(info or {})}))

    def with_checked(self, **changes) -> RouteResult:
        """A copy with ``changes``, each already in the form ``__post_init__`` gives its field (a
        RunNotes, a read-only mapping, a float ``wall_s``...): the histories, private read-only
        arrays, are shared with this result, not copied again (``replace`` copies them all)."""
        new = object.__new__(type(self))
        new.__dict__.update(self.__dict__)
        new.__dict__.update(changes)
        return new

    def truncated(self, nt: int, status: Status = Status.STOPPED, message: str = "", wall_s=None,
                  info=None) -> RouteResult:
        """The first nt samples (results up to a failure), with the reason."""
        cut = lambda m: {k: v[:nt] for k, v in m.items()}
        plate = {k: getattr(self, k)[:nt] for k in ("plate_deflection", "plate_vertex_deflection", "plate_moment")
                 if getattr(self, k) is not None}
        return dataclasses.replace(
            self, time=self.time[:nt], raft=self.raft[:nt], gap=self.gap[:nt],
            contact_force=self.contact_force[:nt], soil_w=self.soil_w[:nt], acc=cut(self.acc),
            disp=cut(self.disp), energy=cut(self.energy), newton_iters=self.newton_iters[:nt],
            status=status, message=message or self.message,
            wall_s=self.wall_s if wall_s is None else wall_s, info={**self.info, **(info or {})}, **plate)

    def max_uplift(self) -> float:
        return float(self.gap.max()) if self.gap.size else 0.0

    def uplift_area_fraction(self, area) -> np.ndarray:
        """(nt,) fraction of the interface area (area (N,) m^2) that has lifted."""
        area = np.asarray(area, float)
        return (self.gap > 0) @ area / area.sum()

    def energy_balance_error(self) -> float:
        """max_t |W_input - (kinetic + strain + damping + soil + contact)| / max_t |W_input|: the
        discrete energy balance (round-off for alpha = 0; NaN for routes that keep no energies)."""
        e = self.energy
        if not e or "input" not in e:
            return float("nan")
        out = e["kinetic"] + e["strain"] + e["damping"] + e["soil"] + e["contact"]
        return float(np.abs(e["input"] - out).max() / max(np.abs(e["input"]).max(), 1e-300))

    def uplift_fraction(self) -> np.ndarray:
        """(nt,) fraction of the interface nodes with a gap > 0."""
        return (self.gap > 0).mean(axis=1)

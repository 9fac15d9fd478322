"""One result type for every route (time-domain and frequency-domain routes fill it alike)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class RouteResult:
    """Time histories of one run. nt time samples, N interface nodes.

    route : str                         e.g. "td-winkler", "td-monolithic", "tf"
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
    converged : bool; message : str; wall_s : float, s
    xy : (N, 2) m interface nodes; info : dict (static settlement, P0, penalty, ...)
    """
    route: str
    time: np.ndarray
    raft: np.ndarray
    gap: np.ndarray
    contact_force: np.ndarray
    soil_w: np.ndarray
    acc: dict = field(default_factory=dict)
    disp: dict = field(default_factory=dict)
    energy: dict = field(default_factory=dict)
    newton_iters: np.ndarray | None = None
    converged: bool = True
    message: str = ""
    wall_s: float = 0.0
    xy: np.ndarray | None = None
    info: dict = field(default_factory=dict)

    @property
    def nt(self) -> int:
        return self.time.shape[0]

    def truncated(self, nt: int) -> "RouteResult":
        """The first nt samples (used to hand back results up to a failure)."""
        cut = lambda a: None if a is None else a[:nt]
        return RouteResult(self.route, self.time[:nt], self.raft[:nt], self.gap[:nt],
                           self.contact_force[:nt], self.soil_w[:nt],
                           {k: v[:nt] for k, v in self.acc.items()},
                           {k: v[:nt] for k, v in self.disp.items()},
                           {k: v[:nt] for k, v in self.energy.items()}, cut(self.newton_iters),
                           self.converged, self.message, self.wall_s, self.xy, dict(self.info))

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

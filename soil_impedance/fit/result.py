"""What a fit returns: the model and its ``FitReport`` (``FitResult``)."""
from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np

from ..rational import RationalModel


@dataclass(frozen=True)
class FitReport:
    """What ``fit_table`` measured (all errors relative Frobenius on DOF-scaled matrices).

    order : int                       number of poles (a conjugate pair counts two)
    max_rel_error : float             max over f ≥ f_causal of e(f), after enforcement
    rel_error : ndarray (F,)          e(f) against the table, per table frequency
    freq_hz : ndarray (F,)            the table frequencies
    max_rel_error_fit : float         the same before passivity enforcement
    max_rel_error_unscaled : float    relative Frobenius error in SI units
    low_freq_error : float            max e(f) for f < f_causal (hysteretic → causal), 0 if none
    f_causal_hz : float
    block_errors : dict               per DOF block ("rigid", "rigid-w", "w"): max over the band of
                                      ‖Δ_block‖_F/‖K_block‖_F ("own") and /‖K‖_F ("total")
    passive, passivity_margin : bool, float      see ``passivity.PassivityReport``
    passivity : dict                  the full PassivityReport.to_dict()
    order_history : list              [(order, max_rel_error)] tried during order selection; gap tables
                                      with the rigid criterion: [(order, max_rel_error, rigid_error)]
    settings : dict                   ``FitOptions.settings()`` (node_xy as node_xy_sha) + rigid_corrected
    wall_s : float                    fit + enforcement wall time, s (the load time on a cache hit): a
                                      measurement only, nothing else in the result depends on it
    cached : bool
    tol_reached : bool                max_rel_error <= tol (and, for gap tables, every rigid_errors
                                      re and im <= tol: the order-selection criterion)
    message : str                     why tol was missed and which tol is reachable ("" if reached)
    error_floor : float               a-priori hysteretic floor estimate ≈ 1.1 ξ (0: not hysteretic)
    stop_reason : str                 why the order search stopped
    enforcement_attempts : list       [(order, passive, criterion after, iterations)] per enforcement
                                      (a failed one: criterion nan)
    rigid_errors : dict               gap tables: errors of the rigid-raft impedance Pᵀ K P per rigid DOF
                                      (``rigid_errors``), max over f ≥ f_causal, after enforcement
                                      ({} for other tables or without node coordinates)
    """

    order: int
    max_rel_error: float
    rel_error: np.ndarray
    freq_hz: np.ndarray
    max_rel_error_fit: float
    max_rel_error_unscaled: float
    low_freq_error: float
    f_causal_hz: float
    block_errors: dict
    passive: bool
    passivity_margin: float
    passivity: dict
    order_history: list
    settings: dict
    wall_s: float
    cached: bool = False
    tol_reached: bool = True
    message: str = ""
    error_floor: float = 0.0
    stop_reason: str = ""
    enforcement_attempts: list = field(default_factory=list)
    rigid_errors: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        d = {k: getattr(self, k) for k in self.__dataclass_fields__}
        d["rel_error"] = [float(x) for x in self.rel_error]
        d["freq_hz"] = [float(x) for x in self.freq_hz]
        return json.loads(json.dumps(d, default=float))

    def summary(self) -> dict:
        """The ``uplift fit --json`` object."""
        return {"order": int(self.order), "max_rel_error": float(self.max_rel_error),
                "passive": bool(self.passive), "passivity_margin": float(self.passivity_margin),
                "wall_s": float(self.wall_s)}

    @classmethod
    def from_dict(cls, d) -> FitReport:
        d = dict(d)
        d["rel_error"] = np.asarray(d["rel_error"], float)
        d["freq_hz"] = np.asarray(d["freq_hz"], float)
        d["order_history"] = [tuple(x) for x in d["order_history"]]
        return cls(**d)


@dataclass(frozen=True, eq=False)
class FitResult:
    model: RationalModel
    report: FitReport

    def plot(self, table, path):
        from ..fit_plot import plot_fit
        return plot_fit(self, table, path)

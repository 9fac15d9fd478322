"""Set-up shared by the frequency-domain routes, and their RouteResult.

``prepare`` builds the grid (padding rule, window), the soil bands, the condensed operator,
the static preload (same ``solve_static`` and penalty rule as the Newmark stepper) and the
blocked contact force f(t). ``result`` turns a contact history (d, P) into the common
RouteResult: raft q and the output nodes by back-substitution in the frequency domain.

Renormalised contact unknown (paper eq. 15, kept with the stepper's finite penalty kp):
per node z(t) with the penetration e = delta0 - d = z^- + eps z^+ and the total contact force
P = k z^+, eps = k / kp, k (N/m) the auxiliary stiffness (the soil's local static stiffness
K(0)[w_i, w_i]). z < 0 is the gap (-z), z > 0 is P / k. P = kp max(0, e): the stepper's law.
At rest z = z0 (z0 = P0 / k in contact, delta0 if statically open).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from structure.contact import ContactSettings, penalty_stiffness
from structure.preload import solve_static
from structure.results import RouteResult

from orchestrator.tf_grid import Grid, pad_rule_s
from orchestrator.tf_operator import InterfaceOperator, ModalStructure
from orchestrator.tf_soil import soil_bands


@dataclass(eq=False)
class ContactProblem:
    """Everything the solvers need. Arrays per node are (N,); histories (N, nt)."""
    model: object
    grid: Grid
    op: InterfaceOperator
    ag: np.ndarray              # (nt, 3) m/s^2
    ag_hat: np.ndarray          # (3, F)
    f: np.ndarray               # (N, nt) N, blocked dynamic contact force for the full motion
    static: object              # StaticState
    contact: ContactSettings
    kp: np.ndarray
    k: np.ndarray
    info: dict = field(default_factory=dict)

    @property
    def eps(self):
        return self.k / self.kp

    @property
    def z0(self):
        d0 = self.static.delta0
        return np.where(d0 > 0, d0 / self.eps, d0)

    @property
    def P0(self):
        return self.static.P0

    def phi(self, z):
        """Penetration e(z) = z^- + eps z^+ (N, nt)."""
        return np.minimum(z, 0.0) + self.eps[:, None] * np.maximum(z, 0.0)


def prepare(model, soil, ag, dt, contact=None, damping=None, pad_s=None, wrap_tol=1e-4,
            bilinear=False, nfft=None, static=None, aux_factor=1.0, window=True) -> ContactProblem:
    """ContactProblem for ground acceleration ag (nt, 3) m/s^2 at step dt (s).

    soil : ImpedanceTable | WinklerSoil | RationalModel | RecursiveConvolutionSoil
    pad_s : zero padding, s (None: the rule of tf_grid, max(1 s, 3 tau_1) with the window,
    max(1 s, ln(1/wrap_tol) tau_1) without); wrap_tol : attenuation of what wraps around;
    window : exponential window (eta = ln(1/wrap_tol) / (nfft dt)) or none (eta = 0, longer
    pad; no amplification of a non-causal soil's acausal part, see tf_grid);
    bilinear : s -> trapezoidal s_d;
    aux_factor : the auxiliary stiffness k = aux_factor x the soil's local K(0)[w_i, w_i].
    """
    t0 = time.perf_counter()
    ag = np.asarray(ag, float)
    if ag.ndim != 2 or ag.shape[1] != 3 or not np.all(np.isfinite(ag)):
        raise ValueError(f"ground acceleration must be a finite (nt, 3) array, got shape {ag.shape}")
    contact = contact or ContactSettings()
    st = ModalStructure(model, damping)
    rule = pad_rule_s(st.decay_rates, n_tau=3.0 if window else np.log(1.0 / wrap_tol))
    pad = rule if pad_s is None else float(pad_s)
    grid = Grid.build(ag.shape[0], dt, pad_s=pad, wrap_tol=wrap_tol if window else 1.0,
                      bilinear=bilinear, nfft=nfft, eta_pad_s=min(pad, rule))
    bands = soil_bands(soil, grid)
    op = InterfaceOperator(model, bands, grid, structure=st)
    N = model.n_interface
    kp = penalty_stiffness(contact, bands.K0, N)
    static = static or solve_static(model, bands, kp, unilateral=contact.enabled)
    kloc = np.diag(bands.K0)[6:6 + N].copy()
    k = aux_factor * np.where(kloc > 0, kloc, kp * 1e-4)
    k = np.minimum(k, kp)
    ag_hat = grid.to_freq(ag.T)
    f = grid.to_time(op.blocked_force(ag_hat))
    info = dict(nfft=grid.nfft, eta=grid.eta, pad_s=(grid.nfft - grid.nt) * dt, pad_rule_s=rule,
                wrap_tol=wrap_tol, window=window, bilinear=bilinear, soil=bands.label, n_freq=grid.n_freq,
                setup_s=time.perf_counter() - t0,
                condensation="exact: all fixed-base modes + rigid raft, per frequency")
    return ContactProblem(model, grid, op, ag, ag_hat, f, static, contact, kp, k, info)


def result(prob: ContactProblem, route: str, d, P, gap, output_nodes=None, converged=True,
           message="", wall_s=0.0, info=None) -> RouteResult:
    """RouteResult from the contact history: d (N, nt) m dynamic relative displacement (raft
    trace minus soil w), P (N, nt) N total contact force, gap (N, nt) m."""
    g, op, model = prob.grid, prob.op, prob.model
    d_hat = g.to_freq(d)
    q_hat = op.raft(prob.ag_hat, d_hat)
    q = g.to_time(q_hat)
    w = prob.op.Bq @ q - d
    names = [n.name for n in model.nodes if n.name] if output_nodes is None else list(output_nodes)
    acc, disp = {}, {}
    s2 = op.s * op.s
    for nm in names:
        dofs = model.dofs(model.node_by_name(nm).id)[:3]
        u_hat = op.st.node_response(dofs, op.s, q_hat, prob.ag_hat)
        disp[nm] = g.to_time(u_hat).T
        acc[nm] = g.to_time(s2 * u_hat + prob.ag_hat).T      # absolute: no feedthrough
    nt = g.nt
    inf = dict(settlement=prob.static.settlement, P0=prob.P0.copy(), penalty=prob.kp.copy(),
               delta0=prob.static.delta0.copy(), dt=g.dt, alpha=0.0,
               contact_enabled=prob.contact.enabled, aux_stiffness=prob.k.copy())
    inf.update(prob.info)
    inf.update(info or {})
    return RouteResult(route, g.dt * np.arange(nt), q.T.copy(), np.asarray(gap).T.copy(),
                       np.asarray(P).T.copy(), w.T.copy(), acc, disp, {}, np.zeros(nt, int),
                       converged, message, wall_s, np.array(model.raft.xy), inf)

"""The contact problem shared by the frequency-domain routes: set-up, residual, result.

``prepare`` builds the grid (padding rule, window), the soil bands, the condensed operator,
the static preload (same ``solve_static`` and penalty rule as the Newmark stepper) and the
blocked contact force f(t). ``route_result`` turns a contact history (d, P) into the common
RouteResult: raft q and the output nodes by back-substitution in the frequency domain.

Renormalised contact unknown (paper eq. 15, kept with the stepper's finite penalty kp):
per node z(t) with the penetration e = delta0 - d = z^- + eps z^+ and the total contact force
P = k z^+, eps = k / kp, k (N/m) the auxiliary stiffness (the soil's local static stiffness
K(0)[w_i, w_i]). z < 0 is the gap (-z), z > 0 is P / k. P = kp max(0, e): the stepper's law.
At rest z = z0 (z0 = P0 / k in contact, delta0 if statically open).

With z = z0 + y and the dynamic contact force p = k z^+ - P0, the condensed system p = S * d
- lam f (d = -(phi(z) - phi(z0)), lam the motion scale) is the whole-range residual over
[0, T], (N, nt), in N (``ContactEquation``; paper eq. 16):

    g(y) = S * [phi(z0 + y) - phi(z0)] + k (z0 + y)^+ - P0 + lam f = 0

S* applied per frequency (operator) between windowed FFTs (grid). Its generalized
(semi-smooth) Jacobian is J v = S * [(I^- + eps I^+) v] + k I^+ v with I^+ = [z > 0] the
active (closed) set, time-varying (paper eq. 18 with eps -> 0). Every solver (march,
newton_krylov, paper) drives |g| / |lam f| below its tolerance and returns an ``Outcome``.
"""
from __future__ import annotations

import enum
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from structure.contact import ContactSettings, penalty_stiffness
from structure.preload import solve_static
from structure.results import RouteResult, Status

from orchestrator.timefreq.grid import Grid, pad_rule_s
from orchestrator.timefreq.flexible import PLATE_PAD_S, is_plate, plate_static, structure_of
from orchestrator.timefreq.operator import InterfaceOperator, WorkerPool
from orchestrator.timefreq.soil import soil_bands


class SolverStatus(str, enum.Enum):
    """How a whole-range solver ended."""

    CONVERGED = "converged"           # |g| / |lam f| <= tol
    NOT_CONVERGED = "not converged"   # iterations spent, or no progress left
    DIVERGED = "diverged"             # the iterates blew up (a march: the soil's causal part is not passive)
    STOPPED = "stopped"               # the time budget ran out


@dataclass(frozen=True, eq=False)
class Outcome:
    """What a whole-range solver returns.

    y : (N, nt) the renormalised unknown (its best iterate when it did not converge)
    status : SolverStatus
    history : one record per sweep or iteration (the solver's own small frozen dataclass,
              each with ``residual`` and ``wall_s``)
    reason : why it diverged or stopped ("" otherwise)
    extra : solver-specific, JSON-able (Newton-Krylov's continuation ladder, ...)
    residual : |g(y)| / |lam f| of y as the solver measured it (None: not measured)
    """
    y: np.ndarray
    status: SolverStatus
    history: tuple = ()
    reason: str = ""
    extra: Mapping = field(default_factory=dict)
    residual: float | None = None

    @property
    def converged(self) -> bool:
        return self.status is SolverStatus.CONVERGED


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


def prepare(model, soil, ag, dt, *, grid, contact=None, damping=None, static=None,
            aux_factor=1.0, pool: WorkerPool | None = None, cache_dir=None) -> ContactProblem:
    """ContactProblem for ground acceleration ag (nt, 3) m/s^2 at step dt (s).

    soil : ImpedanceTable | WinklerSoil | RationalModel | RecursiveConvolutionSoil
    grid : GridOptions with bilinear and window set (``GridOptions.resolved``)
    static : StaticState (default: solve_static with the soil's K(0) and the penalty rule)
    aux_factor : the auxiliary stiffness k = aux_factor x the soil's local K(0)[w_i, w_i]
    pool : WorkerPool of the operator (default: none)
    cache_dir : folder where a table's set-up is kept (setup_cache: the band's rows, the far
        field's split), None: made every time
    """
    t0 = time.perf_counter()
    if grid.bilinear is None or grid.window is None:
        raise ValueError("prepare needs GridOptions with bilinear and window set: pass grid.resolved(...)")
    ag = np.asarray(ag, float)
    if ag.ndim != 2 or ag.shape[1] != 3 or not np.all(np.isfinite(ag)):
        raise ValueError(f"ground acceleration must be a finite (nt, 3) array, got shape {ag.shape}")
    contact = contact or ContactSettings()
    st = structure_of(model, damping)
    wrap_tol, window = grid.wrap_tol, grid.window
    rule = pad_rule_s(st.decay_rates, n_tau=3.0 if window else np.log(1.0 / wrap_tol))
    pad = rule if grid.pad_s is None else float(grid.pad_s)
    if grid.pad_s is None and is_plate(model):
        pad = max(pad, PLATE_PAD_S)         # a lifted plate rings undamped (flexible.PLATE_PAD_S)
    g = Grid.build(ag.shape[0], dt, pad_s=pad, wrap_tol=wrap_tol if window else 1.0,
                   bilinear=grid.bilinear, nfft=grid.nfft, eta_pad_s=min(pad, rule))
    bands = soil_bands(soil, g)
    op = InterfaceOperator(model, bands, g, structure=st, pool=pool, cache_dir=cache_dir)
    N = model.n_interface
    kp = penalty_stiffness(contact, bands.K0, N)
    if static is None:
        static = plate_static(model, bands.K0, kp, unilateral=contact.enabled) if is_plate(model) else \
            solve_static(model, bands, kp, unilateral=contact.enabled)
    kloc = np.diag(bands.K0)[6:6 + N].copy()
    k = aux_factor * np.where(kloc > 0, kloc, kp * 1e-4)
    k = np.minimum(k, kp)
    ag_hat = g.to_freq(ag.T)
    f = g.to_time(op.blocked_force(ag_hat))
    info = dict(nfft=g.nfft, eta=g.eta, pad_s=(g.nfft - g.nt) * dt, pad_rule_s=rule,
                wrap_tol=wrap_tol, window=window, bilinear=grid.bilinear, soil=bands.label, n_freq=g.n_freq,
                setup_s=time.perf_counter() - t0,
                condensation="exact: all fixed-base modes + rigid raft, per frequency" if not is_plate(model) else
                "exact: the sticks' fixed-base modes + the plate's rotations on [q, t] (the held raft and the "
                f"{model.nf} free vertices' deflections), per frequency")
    return ContactProblem(model, g, op, ag, ag_hat, f, static, contact, kp, k, info)


class ContactEquation:
    """g(y) and J v of one ContactProblem at motion scale lam (module notes)."""

    def __init__(self, prob, lam: float = 1.0, apply=None):
        """apply: S X for X (N, F) complex, another route to op.apply_S (the march's split,
        AffineSplit.apply), or None (op.apply_S)."""
        self.p, self.lam = prob, float(lam)
        self.apply = apply or prob.op.apply_S
        self.g = prob.grid
        self.z0 = prob.z0
        self.phi0 = prob.phi(self.z0[:, None])
        self.k = prob.k[:, None]
        self.eps = prob.eps[:, None]
        self.n_res = 0
        self.n_jv = 0

    @property
    def scale(self) -> float:
        """|lam f|, N: the residual's relative measure."""
        return max(np.linalg.norm(self.lam * self.p.f), 1e-300)

    def S(self, x):
        """S * x for x (N, nt) causal."""
        return self.g.to_time(self.apply(self.g.to_freq(x)))

    def residual(self, y):
        """g(y) (N, nt), N: S * [phi(z0 + y) - phi(z0)] + k (z0 + y)^+ - P0 + lam f, its
        elementwise parts in place on two work arrays (the same operations in the same order as
        the expression, so the same bits)."""
        self.n_res += 1
        z = self.z0[:, None] + y
        zp = np.maximum(z, 0.0)
        x = np.minimum(z, 0.0, out=z)                    # phi(z) = z^- + eps z^+
        x += self.eps * zp
        x -= self.phi0
        g = self.S(x)
        zp *= self.k
        g += zp
        g -= self.p.P0[:, None]
        g += self.lam_f
        return g

    @cached_property
    def lam_f(self):
        """lam f (N, nt), N: the residual's load, formed once."""
        return self.lam * self.p.f

    def jvp(self, y, v):
        self.n_jv += 1
        closed = (self.z0[:, None] + y) > 0
        return self.S(np.where(closed, self.eps * v, v)) + np.where(closed, self.k * v, 0.0)


def route_result(prob: ContactProblem, route: str, d, P, gap, *, output_nodes=None,
                 status: Status = Status.CONVERGED, message: str = "", started: float | None = None,
                 info=None) -> RouteResult:
    """RouteResult from the contact history: d (N, nt) m dynamic relative displacement (raft
    trace minus soil w), P (N, nt) N total contact force, gap (N, nt) m. started: the
    perf_counter time the route began (wall_s is measured to the end of this assembly)."""
    g, op, model = prob.grid, prob.op, prob.model
    d_hat = g.to_freq(d)
    q_hat = op.raft(prob.ag_hat, d_hat)                      # a plate: r = [q, t]
    q = g.to_time(q_hat)
    w = prob.op.Bq @ q - d
    plate = {}
    if is_plate(model):
        W = (op.st.vertex_trace @ q).T                       # (nt, m) the plate's vertex deflections
        plate = dict(plate_vertex_deflection=W, plate_deflection=W @ model.trace.T.toarray(),
                     plate_vertices=np.array(model.points))
        q = q[:6]
    stick = model.stick if is_plate(model) else model        # the node_response's numbering
    names = [n.name for n in model.nodes if n.name] if output_nodes is None else list(output_nodes)
    acc, disp = {}, {}
    s2 = op.s * op.s
    for nm in names:
        dofs = stick.dofs(model.node_by_name(nm).id)[:3]
        u_hat = op.st.node_response(dofs, op.s, q_hat, prob.ag_hat)
        disp[nm] = g.to_time(u_hat).T
        acc[nm] = g.to_time(s2 * u_hat + prob.ag_hat).T      # absolute: no feedthrough
    nt = g.nt
    inf = dict(settlement=prob.static.settlement, P0=prob.P0.copy(), penalty=prob.kp.copy(),
               delta0=prob.static.delta0.copy(), dt=g.dt, alpha=0.0,
               contact_enabled=prob.contact.enabled, aux_stiffness=prob.k.copy())
    inf.update(prob.info)
    inf.update(info or {})
    wall = 0.0 if started is None else time.perf_counter() - started
    return RouteResult(route=route, time=g.dt * np.arange(nt), raft=q.T, gap=np.asarray(gap).T,
                       contact_force=np.asarray(P).T, soil_w=w.T, acc=acc, disp=disp,
                       newton_iters=np.zeros(nt, int), status=status, message=message, wall_s=wall,
                       xy=np.array(model.raft.xy), info=inf, **plate)

"""Static unilateral contact of a rigid raft on a soil given by its static stiffness, solved
exactly (no penalty), and the rotation-controlled static pushover built on it.

Unknowns x = [q, w] (6 + N): q the raft's rigid DOFs (ux, uy, uz, rx, ry, rz about the raft
centre), w the soil's vertical displacement under each interface node; K (6+N, 6+N) the soil's
static stiffness on x (the BEM's static gap table, or Winkler springs: ``WinklerSoil.static_stiffness``).
At node i, with the raft trace t_i = uz + rx y_i - ry x_i (docs/conventions.md):

    gap d_i = t_i - w_i >= 0,   contact force P_i >= 0,   d_i P_i = 0,
    raft:  (K x)_q - Bq^T P = F + M a      soil:  (K x)_w + P = 0,

F (6,) the loads on the raft (the structure's weight brought to the raft centre), a (6,) the
unit rocking vector of the pushover and M the moment that holds the prescribed rotation
a . q = theta (its reaction; without a prescribed rotation, M = 0). This is the minimum of the
convex energy 1/2 x^T K x - F . q over d >= 0, solved by the primal-dual active-set method
(closed nodes: d_i = 0, open nodes: P_i = 0; each iteration one dense solve of the
closed-set problem; finite and exact for this piecewise-linear problem, warm-started from the
previous step's set along a pushover; a set seen twice switches to one flip at a time).

In full contact the solution is linear in theta, so the lift-off onset (the first node whose
force reaches zero) is solved directly from two closed-set solutions (``liftoff_onset``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from .errors import ConvergenceError, StructureError
from .model import vertical_trace


def rocking_vector(angle_rad: float) -> np.ndarray:
    """a (6,): the unit rotation that rocks the raft in the horizontal direction
    n = (cos angle, sin angle): a . q = theta gives the trace -theta (n . r), the edge at +n
    pressed down and the edge at -n lifted (angle 0: ry = theta, rocking in the x-z plane)."""
    a = np.zeros(6)
    a[3], a[4] = -np.sin(angle_rad), np.cos(angle_rad)
    return a


@dataclass(frozen=True, eq=False)
class ContactState:
    """x (6+N,) [q, w], m and rad; P (N,) N contact forces (>= 0); gap (N,) m (>= 0);
    closed (N,) bool, the nodes in contact; moment N m, the reaction of the prescribed rotation
    (0 without one); iterations of the active-set method."""
    x: np.ndarray
    P: np.ndarray
    gap: np.ndarray
    closed: np.ndarray
    moment: float
    iterations: int


class _Problem:
    """The data of one raft: K, Bq, loads and the prescribed rotation (or none)."""

    def __init__(self, K, xy, load, rocking=None):
        K = np.asarray(K.toarray() if hasattr(K, "toarray") else K)
        if np.iscomplexobj(K):
            K = K.real
        self.K = 0.5 * (K + K.T)
        self.n = self.K.shape[0] - 6
        xy = np.asarray(xy, float)
        if xy.shape != (self.n, 2):
            raise StructureError(f"node coordinates {xy.shape} do not match the stiffness ({self.n} soil DOFs)")
        self.Bq = vertical_trace(xy)
        self.F = np.zeros(6 + self.n)
        self.F[:6] = np.asarray(load, float)
        if rocking is None:
            self.a, self.Z = np.zeros(6), np.eye(6)
        else:
            a = np.asarray(rocking, float)
            self.a = a / np.linalg.norm(a)
            self.Z = sla.null_space(self.a[None, :])          # (6, 5) orthonormal, a . Z = 0
        self.scale = np.abs(np.diag(self.K)[6:]).max(initial=1.0)

    def solve_set(self, closed, theta):
        """x, P for the set ``closed`` (d = 0 there, P = 0 elsewhere) at rotation theta."""
        n, k = self.n, self.Z.shape[1]
        op = np.flatnonzero(~closed)
        L = np.zeros((6 + n, k + op.size))
        L[:6, :k] = self.Z
        L[6 + np.flatnonzero(closed), :k] = self.Bq[closed] @ self.Z
        L[6 + op, k + np.arange(op.size)] = 1.0
        x0 = np.zeros(6 + n)
        x0[:6] = theta * self.a
        x0[6:][closed] = theta * (self.Bq[closed] @ self.a)
        H = L.T @ self.K @ L
        rhs = L.T @ (self.F - self.K @ x0)
        try:
            c, low = sla.cho_factor(H)
            y = sla.cho_solve((c, low), rhs)
        except (np.linalg.LinAlgError, ValueError):
            raise StructureError(
                "static contact problem is singular with " f"{int(closed.sum())} of {n} nodes closed: the raft is not "
                "held in every direction (the soil stiffness lacks horizontal or torsional terms, or too "
                "few nodes are in contact)") from None
        x = x0 + L @ y
        Kx = self.K @ x
        P = -Kx[6:]
        P[~closed] = 0.0
        d = self.Bq @ x[:6] - x[6:]
        d[closed] = 0.0
        moment = float(self.a @ (Kx[:6] - self.Bq.T @ P - self.F[:6]))
        return x, P, d, moment

    def solve(self, theta, closed=None, max_iter=None):
        n = self.n
        closed = np.ones(n, bool) if closed is None else np.array(closed, bool)
        max_iter = max_iter or 4 * n + 20
        seen, single = set(), False
        for it in range(1, max_iter + 1):
            if not closed.any():
                raise StructureError("static contact: no node is in contact; the loads lift the raft off the "
                                     "soil (is the vertical load downward?)")
            x, P, d, moment = self.solve_set(closed, theta)
            tol_p = 1e-11 * max(np.abs(P).max(initial=0.0), np.abs(self.F[:3]).max(), 1e-300)
            tol_d = 1e-11 * max(np.abs(x).max(initial=0.0), 1e-300)
            # violations in metres: a tensile force over the local soil stiffness, a penetration
            tension, penetration = P + tol_p < 0, d + tol_d < 0
            viol = np.where(closed, np.where(tension, -P / self.scale, 0.0), np.where(penetration, -d, 0.0))
            if not viol.any():
                return ContactState(x, np.maximum(P, 0.0), np.maximum(d, 0.0), closed, moment, it)
            key = closed.tobytes()
            single = single or key in seen
            seen.add(key)
            if single:                               # a cycle: flip the worst node only
                closed = closed.copy()
                j = int(np.argmax(viol))
                closed[j] = not closed[j]
            else:
                closed = np.where(closed, ~tension, penetration)
        raise ConvergenceError(f"static contact active set did not settle in {max_iter} iterations at "
                               f"rotation {theta:.6g} rad", 0.0, int(np.argmax(viol)), float(viol.max()))


def solve_contact(K, xy, load, rocking=None, theta: float = 0.0, closed=None) -> ContactState:
    """Exact static unilateral contact (see the module docstring). K (6+N, 6+N) N/m static
    stiffness on [q, w]; xy (N, 2) m; load (6,) N and N m on the raft; rocking (6,) the
    rotation prescribed to ``theta`` rad (None: all six raft DOFs free); closed (N,) bool the
    starting set (default: all in contact)."""
    return _Problem(K, xy, load, rocking).solve(theta, closed)


@dataclass(frozen=True, eq=False)
class Onset:
    """Lift-off onset: rotation rad, moment N m (the prescribed rotation's reaction), node (the
    first to reach P = 0; ``nodes`` all those that reach it together to 1e-9), vertical N
    (the total contact force), eccentricity m = moment / vertical; stiffness N m/rad the rocking
    stiffness dM/dtheta in full contact. at_rest: True when a node is already open (or in
    tension in full contact) at zero rotation: no linear onset (rotation 0)."""
    rotation: float
    moment: float
    node: int
    nodes: tuple
    vertical: float
    stiffness: float
    at_rest: bool

    @property
    def eccentricity(self) -> float:
        return self.moment / self.vertical


def _onset(prob: _Problem) -> Onset:
    allc = np.ones(prob.n, bool)
    _, P0, _, M0 = prob.solve_set(allc, 0.0)
    _, P1, _, M1 = prob.solve_set(allc, 1.0)
    dP, dM, vertical = P1 - P0, M1 - M0, float(P0.sum())
    if (P0 <= 0).any():
        j = int(np.argmin(P0))
        return Onset(0.0, float(M0), j, (j,), vertical, float(dM), True)
    with np.errstate(divide="ignore"):
        t = np.where(dP < 0, P0 / np.where(dP < 0, -dP, 1.0), np.inf)
    j = int(np.argmin(t))
    if not np.isfinite(t[j]):
        raise StructureError("no node loses contact under this rotation: the rocking vector moves no node")
    nodes = tuple(int(i) for i in np.flatnonzero(t <= t[j] * (1 + 1e-9)))
    return Onset(float(t[j]), float(M0 + t[j] * dM), j, nodes, vertical, float(dM), False)


def liftoff_onset(K, xy, load, rocking) -> Onset:
    """The rotation and moment at which the first node's contact force reaches zero: in full
    contact x, P and M are linear in theta (two closed-set solves), P_i(theta) = 0 solved per
    node, the smallest positive root kept."""
    return _onset(_Problem(K, xy, load, rocking))


@dataclass(frozen=True, eq=False)
class PushoverCurve:
    """Per step k (n,): rotation rad, moment N m, settlement m (raft centre, positive down),
    contact_ratio (area in contact / total), max_gap m, iterations; per step and node (n, N):
    force N, pressure Pa (force / tributary area), gap m; q (n, 6) the raft DOFs;
    vertical N the total vertical load; onset the exact lift-off onset."""
    rotation: np.ndarray
    moment: np.ndarray
    settlement: np.ndarray
    contact_ratio: np.ndarray
    max_gap: np.ndarray
    iterations: np.ndarray
    force: np.ndarray
    pressure: np.ndarray
    gap: np.ndarray
    q: np.ndarray
    vertical: float
    onset: Onset


def pushover(K, xy, area, load, rocking, rotations, progress=None, onset: Onset | None = None) -> PushoverCurve:
    """The rotation-controlled static pushover: for each rotation theta of ``rotations`` (rad,
    in order) the exact unilateral equilibrium with a . q = theta prescribed (a = ``rocking``,
    e.g. ``rocking_vector(angle)``), the other raft DOFs and the soil free, under ``load``
    (6,) on the raft. Each step starts from the previous step's contact set. progress(done, total,
    label) after each step, if given; onset: ``liftoff_onset`` of the same problem, if known."""
    prob = _Problem(K, xy, load, rocking)
    area = np.asarray(area, float)
    rotations = np.asarray(rotations, float)
    onset = _onset(prob) if onset is None else onset
    states, closed = [], None
    for k, th in enumerate(rotations):
        s = prob.solve(float(th), closed)
        states.append(s)
        closed = s.closed
        if progress is not None:
            progress(k + 1, rotations.size, f"{th:.3g} rad")
    force = np.array([s.P for s in states])
    q = np.array([s.x[:6] for s in states])
    in_contact = np.array([s.closed for s in states])
    return PushoverCurve(
        rotation=rotations, moment=np.array([s.moment for s in states]), settlement=-q[:, 2],
        contact_ratio=(in_contact * area).sum(axis=1) / area.sum(), max_gap=np.array([s.gap.max() for s in states]),
        iterations=np.array([s.iterations for s in states]), force=force, pressure=force / area,
        gap=np.array([s.gap for s in states]), q=q, vertical=onset.vertical, onset=onset)

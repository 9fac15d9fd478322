"""Newmark average acceleration (HHT-alpha option) with semi-smooth Newton on the contact.

Equation of motion in the frame of the free field (relative displacements u, dynamic
perturbation of the static state under self-weight), u = [structure | q | w]:

    M a + C v + K u + f_soil(x, xdot) + f_c(u) = F(t) = -M r a_g(t)

f_soil = K0 x + C0 xdot + h acts on the interface block x = [q, w] (see soil_interface),
f_c = -B^T (P - P0) is the contact (see contact). HHT: the internal and external forces are
evaluated at t_{n+1+alpha} = (1 + alpha) (.)_{n+1} - alpha (.)_n, alpha in [-1/3, 0],
beta = (1 - alpha)^2 / 4, gamma = 1/2 - alpha; alpha = 0 is the average acceleration rule
(second order, no numerical damping, exact discrete energy balance).

Solution: the effective matrix is condensed on the interface block once per step size
(sparse LU of the structural block A_II, dense Schur complement S0 on x). Each Newton
iteration solves (S0 + (1+alpha) B^T diag(kp active) B) dx = -g with a dense LU that is
cached per active set, so a step whose active set does not change costs one
back-substitution. A backtracking line search on |g|^2 guards against active-set cycling;
if Newton fails, the step is halved recursively (ground motion interpolated linearly, the
soil history held) down to dt / 2**max_subdiv, then ConvergenceError is raised.

Closed contact (contact disabled, or ``simulate``'s linear pre-check): the problem is linear;
one factorisation of the whole effective matrix with every penalty spring closed
(``_ClosedSolver``: the soil DOFs condensed exactly when they are uncoupled, else sparse LU),
one solve per step, no Newton; ``simulate`` then records outputs and energies over the whole
history at once (``_closed_run``, ``_closed_result``).
"""
from __future__ import annotations

import time as _time
from collections import OrderedDict

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ._blas import single_threaded_blas
from .contact import ContactSettings, contact_force, gap, penalty_stiffness
from .damping import damping_matrix
from .errors import ConvergenceError, StructureError
from .model import StructureModel
from .preload import StaticState, embed, interface_operator, solve_static
from types import SimpleNamespace

from .results import RouteResult, RunNotes, Status


class _NewtonFailure(Exception):
    def __init__(self, node, residual):
        self.node, self.residual = node, residual


class _ClosedSolver:
    """u = A^-1 rhs for the effective matrix A (n, n) with every contact spring closed, split
    as [[Ass, Asw], [Aws, Aww]] on the ns structure DOFs and the N soil DOFs w.

    When Aww is diagonal (springs and dashpots under each node in series with the penalty:
    Winkler soils) w is condensed exactly: S = Ass - Asw Aww^-1 Aws (ns, ns) is factorised
    densely (a stick model has few DOFs), and a solve is a few vector operations; w couples
    to the raft rows only, so Asw and Aws are kept on their bounding blocks. Otherwise (a soil
    coupling the nodes, e.g. the BEM's recursive convolution) a sparse LU of A."""

    def __init__(self, A, ns: int):
        A = sp.csr_matrix(A)
        self.n, self.ns = A.shape[0], ns
        Aww = A[ns:, ns:]
        dw = Aww.diagonal()
        self.lu = None
        if ns == 0 or (Aww - sp.diags(dw)).count_nonzero() or not np.all(dw != 0):
            self.lu = spla.splu(A.tocsc())
            return
        Asw, Aws = A[:ns, ns:], A[ns:, :ns]
        r, c = Asw.nonzero()[0], Aws.nonzero()[1]
        self.r = slice(r.min(), r.max() + 1) if r.size else slice(0, 0)
        self.c = slice(c.min(), c.max() + 1) if c.size else slice(0, 0)
        self.dw = dw
        self.Asw = Asw[self.r].toarray()                       # (rows of Asw, N)
        self.G = Aws[:, self.c].toarray() / dw[:, None]        # Aww^-1 Aws on its columns
        S = A[:ns, :ns].toarray()
        S[:, self.c] -= Asw.toarray() @ self.G
        self.S_lu = sla.lu_factor(S, check_finite=False)
        self.Sinv = sla.lu_solve(self.S_lu, np.eye(ns), check_finite=False)

    def solve(self, rhs):
        """A^-1 rhs (rhs (n,) may be overwritten)."""
        if self.lu is not None:
            return self.lu.solve(rhs)
        ns = self.ns
        t = rhs[ns:] / self.dw
        rs = rhs[:ns]
        rs[self.r] -= self.Asw @ t
        u = np.empty(self.n)
        us = u[:ns]
        np.matmul(self.Sinv, rs, out=us)
        np.subtract(t, self.G @ us[self.c], out=u[ns:])
        return u


class NewmarkStepper:
    """One implicit time step at a time; the FMU calls ``step()`` exactly as ``simulate`` does.

    Parameters
    ----------
    model : StructureModel
    soil : SoilInterface            provides (K0, C0) and, unless external_soil, h
    dt : float, s                   communication / time step
    contact : ContactSettings       unilateral contact (enabled=False: bonded, linear)
    damping : None | float | Damping | ndarray   structural damping (see damping_matrix)
    alpha : float                   HHT parameter in [-1/3, 0]
    static : StaticState or None    preload (computed if None)
    external_soil : bool            True: h is set by ``set_soil_history`` before each step
                                    and the soil object is not advanced (co-simulation)
    ag0 : (3,) m/s^2                ground acceleration at t = 0

    State after each step: t, u, v, a (n_dof,), P (N,) total contact forces.
    """

    def __init__(self, model: StructureModel, soil, dt: float, contact: ContactSettings | None = None,
                 damping=None, alpha: float = 0.0, static: StaticState | None = None,
                 external_soil: bool = False, ag0=(0.0, 0.0, 0.0)):
        with single_threaded_blas():
            self._init(model, soil, dt, contact, damping, alpha, static, external_soil, ag0)

    def _init(self, model, soil, dt, contact, damping, alpha, static, external_soil, ag0):
        if not dt > 0:
            raise StructureError(f"time step dt = {dt!r} must be > 0")
        if not -1.0 / 3.0 - 1e-12 <= alpha <= 0.0:
            raise StructureError(f"HHT alpha = {alpha!r} must lie in [-1/3, 0]")
        if soil.n_dof != 6 + model.n_interface:
            raise StructureError(f"soil has {soil.n_dof} interface DOFs, the raft needs 6 + N = "
                                 f"{6 + model.n_interface}")
        self.model, self.soil, self.dt = model, soil, float(dt)
        self.contact = contact or ContactSettings()
        self.alpha = float(alpha)
        self.beta = (1 - alpha) ** 2 / 4
        self.gamma = 0.5 - alpha
        self.external_soil = external_soil
        ns, N = model.n_struct, model.n_interface
        self.ns, self.N, self.n = ns, N, model.n_dof
        self.ni = ns - 6
        self.nb = 6 + N
        self.kp = penalty_stiffness(self.contact, soil.static_stiffness(), N)
        self.static = static or solve_static(model, soil, self.kp, unilateral=self.contact.enabled)
        self.P0 = self.static.P0.copy()
        self.delta0 = self.static.delta0.copy()
        self.M = np.concatenate([model.mass, np.zeros(N)])
        self.Ks = embed(model, model.stiffness, sp.csr_matrix((self.nb, self.nb)))
        self.Cs = embed(model, sp.csr_matrix(damping_matrix(model, damping)), sp.csr_matrix((self.nb, self.nb)))
        r = np.zeros((self.n, 3))
        r[:ns] = model.influence
        self.Mr = self.M[:, None] * r
        Bq = model.raft.vertical_trace()
        self.Bq3 = Bq[:, 2:5]                      # (N, 3) on q[2:5] = uz, rx, ry
        self._systems = {}
        self._lu_cache = OrderedDict()
        self.n_factorisations = 0
        self._h_ext = np.zeros(self.nb)
        # state
        self.t = 0.0
        self.u = np.zeros(self.n)
        self.v = np.zeros(self.n)
        ag0 = np.asarray(ag0, float)
        self.ag = ag0.copy()
        self.F = -self.Mr @ ag0
        self.a = np.where(self.M > 0, self.F / np.where(self.M > 0, self.M, 1.0), 0.0)
        self.P = self.P0.copy()
        self.fs = np.zeros(self.nb)     # force on the soil at t
        self.fc = np.zeros(self.nb)     # contact internal force (dynamic) at t
        self.R = np.zeros(self.n)       # total internal force at t
        self.work = dict(input=0.0, damping=0.0, soil=0.0, contact=0.0)
        self._ag_next = ag0.copy()
        self.last_iters = 0
        self.last_substeps = 1          # sub-steps used by the last step (1: not subdivided)
        self._nsub = 0

    # ---- inputs ----------------------------------------------------------------------
    def set_ground_acceleration(self, ag_next) -> None:
        """a_g(t + dt) (3,), m/s^2, for the next step."""
        self._ag_next = np.asarray(ag_next, float).reshape(3)

    def set_soil_history(self, h) -> None:
        """Soil history force h (6+N,), N, for the next step (external soil only)."""
        self._h_ext = np.asarray(h, float).reshape(self.nb)

    # ---- outputs ---------------------------------------------------------------------
    @property
    def x(self) -> np.ndarray:
        """Interface displacements [q, w] (6+N,)."""
        return self.u[self.ni:]

    @property
    def xdot(self) -> np.ndarray:
        return self.v[self.ni:]

    def relative_vertical(self, u=None) -> np.ndarray:
        u = self.u if u is None else u
        q = u[self.ni:self.ni + 6]
        return self.Bq3 @ q[2:5] - u[self.ns:]

    def gap(self) -> np.ndarray:
        """(N,) m; zero when contact is disabled (bonded raft: see P < 0 for tension)."""
        if not self.contact.enabled:
            return np.zeros(self.N)
        return gap(self.relative_vertical(), self.delta0)

    # ---- per-dt system ------------------------------------------------------------------
    def _coeffs(self, dt):
        b, g = self.beta, self.gamma
        return 1 / (b * dt * dt), g / (b * dt), 1 / (b * dt), 1 / (2 * b) - 1

    def _system(self, dt):
        key = round(dt / self.dt, 12)
        if key in self._systems:
            return self._systems[key]
        K0, C0 = self.soil.instantaneous(dt)
        K0e = embed(self.model, sp.csr_matrix((self.ns, self.ns)), K0)
        C0e = embed(self.model, sp.csr_matrix((self.ns, self.ns)), C0)
        c0, c1, _, _ = self._coeffs(dt)
        Ktot = (self.Ks + K0e).tocsr()
        Ctot = (self.Cs + C0e).tocsr()
        A = (sp.diags(c0 * self.M) + (1 + self.alpha) * (Ktot + c1 * Ctot)).tocsc()
        ni = self.ni
        AII = A[:ni, :ni].tocsc()
        AIB = A[:ni, ni:].tocsc()
        ABI = A[ni:, :ni].tocsr()
        lu = spla.splu(AII) if ni else None
        X = lu.solve(AIB.toarray()) if ni else np.zeros((0, self.nb))
        S0 = A[ni:, ni:].toarray() - ABI @ X
        sysd = dict(dt=dt, K0=sp.csr_matrix(K0), C0=sp.csr_matrix(C0), Ktot=Ktot, Ctot=Ctot, lu=lu,
                    X=X, ABI=ABI, S0=S0, key=key, A=A)
        self._systems[key] = sysd
        return sysd

    def _closed_lu(self, sysd):
        """Solver of the whole effective matrix with every contact spring closed: the linear
        problem (contact disabled, or closed everywhere), one factorisation per step size."""
        lu = sysd.get("lu_closed")
        if lu is None:
            B = interface_operator(self.model)
            Kc = B.T @ sp.diags(self.kp) @ B
            lu = sysd["lu_closed"] = _ClosedSolver(sysd["A"] + (1 + self.alpha) * Kc, self.ns)
            self.n_factorisations += 1
        return lu

    def _jacobian_lu(self, sysd, active):
        key = (sysd["key"], active.tobytes())
        lu = self._lu_cache.get(key)
        if lu is not None:
            self._lu_cache.move_to_end(key)
            return lu
        J = sysd["S0"].copy()
        s = (1 + self.alpha) * self.kp * active
        B3 = self.Bq3
        J[2:5, 2:5] += B3.T @ (s[:, None] * B3)
        cross = -(s[:, None] * B3)                 # (N, 3)
        J[6:, 2:5] += cross
        J[2:5, 6:] += cross.T
        J[np.arange(6, self.nb), np.arange(6, self.nb)] += s
        lu = sla.lu_factor(J, check_finite=False)
        self.n_factorisations += 1
        self._lu_cache[key] = lu
        if len(self._lu_cache) > 16:
            self._lu_cache.popitem(last=False)
        return lu

    def _line_search(self, uB, dx, g0, S0, al):
        """Exact line search on the (convex, piecewise-quadratic) incremental energy along dx:
        the step t in (0, 1] where dx . g(uB + t dx) = 0. dx . g(t) is continuous, piecewise
        linear and non-decreasing in t (kinks where a node opens or closes), so the root is
        found exactly by scanning the kinks. Returns 1 when the full step is not past it."""
        d0 = self.Bq3 @ uB[2:5] - uB[6:]
        dd = self.Bq3 @ dx[2:5] - dx[6:]
        pen = self.delta0 - d0
        a = dx @ g0 + (1 + al) * (dd @ (self.kp * np.maximum(pen, 0.0)))  # linear part at t = 0
        b = dx @ (S0 @ dx)
        ka = (1 + al) * self.kp

        def slope(t):
            return a + b * t - (dd * ka) @ np.maximum(pen - t * dd, 0.0)

        if slope(1.0) <= 1e-12 * abs(slope(0.0)):
            return 1.0
        with np.errstate(divide="ignore", invalid="ignore"):
            kinks = pen / dd
        kinks = np.sort(kinks[(kinks > 0) & (kinks < 1) & np.isfinite(kinks)])
        lo, flo = 0.0, slope(0.0)
        if flo >= 0:
            return 1.0                      # not a descent direction: take the Newton step
        for tk in np.append(kinks, 1.0):
            fk = slope(tk)
            if fk >= 0:
                return lo + (tk - lo) * (-flo) / (fk - flo) if fk > flo else tk
            lo, flo = tk, fk
        return 1.0

    def _contact(self, uB):
        """(P, active, fc (nb,)) for interface displacements uB = [q, w]."""
        d = self.Bq3 @ uB[2:5] - uB[6:]
        if self.contact.enabled:
            P, act = contact_force(d, self.delta0, self.kp)
        else:
            P, act = self.P0 - self.kp * d, np.ones(self.N, bool)
        dp = P - self.P0
        fc = np.zeros(self.nb)
        fc[2:5] = -self.Bq3.T @ dp
        fc[6:] = dp
        return P, act, fc

    # ---- one step ------------------------------------------------------------------------
    def _advance(self, dt, ag_new, h):
        c0, c1, c2, c3 = self._coeffs(dt)
        al, b, g = self.alpha, self.beta, self.gamma
        sysd = self._system(dt)
        u, v, a = self.u, self.v, self.a
        F_new = -self.Mr @ ag_new
        a_hat = -c0 * u - c2 * v - c3 * a
        v_hat = -c1 * u + (1 - g / b) * v + dt * (1 - g / (2 * b)) * a
        rhs = -self.M * a_hat - (1 + al) * (sysd["Ctot"] @ v_hat) + al * self.R + (1 + al) * F_new - al * self.F
        rhs[self.ni:] -= (1 + al) * h
        ni = self.ni
        iters = 0
        if not self.contact.enabled:
            # bonded: f_c = B^T kp B uB is linear, one factorisation for the whole run
            u_new = self._closed_lu(sysd).solve(rhs)
        else:
            y = sysd["lu"].solve(rhs[:ni]) if ni else rhs[:0]
            r_hat = rhs[ni:] - sysd["ABI"] @ y
            S0 = sysd["S0"]
            uB = u[ni:].copy()
            scale = max(np.linalg.norm(r_hat), (1 + al) * np.linalg.norm(self.P0), 1.0)
            tol = self.contact.tol * scale

            def resid(x):
                P, act, fc = self._contact(x)
                return S0 @ x + (1 + al) * fc - r_hat, act

            gv, act = resid(uB)
            conv = False
            for _ in range(self.contact.max_iter):
                lu = self._jacobian_lu(sysd, act)
                dx = -sla.lu_solve(lu, gv, check_finite=False)
                iters += 1
                t = self._line_search(uB, dx, gv, S0, al)
                xn = uB + t * dx
                gn, actn = resid(xn)
                same = np.array_equal(actn, act)
                uB, gv, act = xn, gn, actn
                if (t == 1.0 and same) or np.linalg.norm(gv) <= tol:
                    conv = True
                    break
            if not conv or not np.all(np.isfinite(uB)):
                rn = np.abs(gv[6:]) if self.N else np.zeros(1)
                # the first node within round-off of the largest residual (ties of symmetric nodes)
                node = int(np.flatnonzero(rn >= rn.max() * (1 - 1e-9))[0]) if np.all(np.isfinite(rn)) else -1
                raise _NewtonFailure(node, float(np.linalg.norm(gv)))
            u_new = np.empty(self.n)
            u_new[ni:] = uB
            u_new[:ni] = y - sysd["X"] @ uB if ni else y
        if not np.all(np.isfinite(u_new)):
            raise _NewtonFailure(-1, np.inf)
        v_new = c1 * u_new + v_hat
        a_new = c0 * u_new + a_hat
        P, act, fc = self._contact(u_new[ni:])
        x_new, xd_new = u_new[ni:], v_new[ni:]
        fs = sysd["K0"] @ x_new + sysd["C0"] @ xd_new + h
        R = sysd["Ktot"] @ u_new + sysd["Ctot"] @ v_new
        R[ni:] += h + fc
        du = u_new - u
        w = self.work
        w["input"] += du @ (0.5 * (self.F + F_new))
        w["damping"] += du @ (self.Cs @ (0.5 * (v + v_new)))
        w["soil"] += du[ni:] @ (0.5 * (self.fs + fs))
        w["contact"] += du[ni:] @ (0.5 * (self.fc + fc))
        self.u, self.v, self.a = u_new, v_new, a_new
        self.P, self.fs, self.fc, self.R, self.F = P, fs, fc, R, F_new
        self.t += dt
        self.ag = np.asarray(ag_new, float)
        if not self.external_soil:
            self.soil.commit(x_new.copy(), xd_new.copy())
        return iters

    def _span(self, dt, ag0, ag1, h, depth):
        saved = self.get_state()
        try:
            if not self.external_soil:
                self.soil.instantaneous(dt)
                h = self.soil.history()
            n = self._advance(dt, ag1, h)
            self._nsub += 1
            return n
        except _NewtonFailure as fail:
            self.set_state(saved)
            if depth >= self.contact.max_subdiv:
                raise ConvergenceError(
                    f"Newton contact iteration failed at t = {self.t + dt:.6g} s (step {dt:.3g} s "
                    f"after {depth} halvings), interface node {fail.node}, residual {fail.residual:.3e} N; "
                    "raise contact.max_subdiv, reduce dt, or check the penalty", self.t + dt,
                    fail.node, fail.residual) from None
            agm = 0.5 * (ag0 + ag1)
            n1 = self._span(dt / 2, ag0, agm, h, depth + 1)
            return n1 + self._span(dt / 2, agm, ag1, h, depth + 1)

    def step(self) -> int:
        """Advance from t to t + dt with a_g(t + dt) from ``set_ground_acceleration`` (and h from
        ``set_soil_history`` when the soil is external). Returns the Newton solves used."""
        h = self._h_ext if self.external_soil else None
        saved = self.get_state()
        self._nsub = 0
        try:
            with single_threaded_blas():
                self.last_iters = self._span(self.dt, self.ag.copy(), self._ag_next.copy(), h, 0)
        except ConvergenceError:
            self.set_state(saved)       # leave the stepper at the last accepted step
            raise
        self.last_substeps = self._nsub
        return self.last_iters

    # ---- state ---------------------------------------------------------------------------
    def get_state(self) -> dict:
        s = {k: getattr(self, k).copy() for k in ("u", "v", "a", "P", "fs", "fc", "R", "F", "ag")}
        s["t"] = self.t
        s["work"] = dict(self.work)
        if not self.external_soil:
            s["soil"] = self.soil.get_state()
        return s

    def set_state(self, s: dict) -> None:
        for k in ("u", "v", "a", "P", "fs", "fc", "R", "F", "ag"):
            setattr(self, k, np.array(s[k], copy=True))
        self.t = s["t"]
        self.work = dict(s["work"])
        if not self.external_soil and "soil" in s:
            self.soil.set_state(s["soil"])

    # ---- energies --------------------------------------------------------------------------
    def energies(self) -> dict:
        """Cumulative works and stored energies at t, J."""
        e = dict(self.work)
        e["kinetic"] = 0.5 * self.v @ (self.M * self.v)
        e["strain"] = 0.5 * self.u @ (self.Ks @ self.u)
        d = self.relative_vertical()
        pen = np.maximum(0.0, self.delta0 - d)
        pen0 = np.maximum(0.0, self.delta0)
        e["contact_potential"] = float(np.sum(0.5 * self.kp * (pen**2 - pen0**2) + self.P0 * d)) \
            if self.contact.enabled else float(np.sum(0.5 * self.kp * d * d))
        return e


def simulate(model: StructureModel, soil, ag, dt: float, contact: ContactSettings | None = None,
             damping=None, alpha: float = 0.0, output_nodes=None, progress=None,
             route: str = "newmark", static: StaticState | None = None) -> RouteResult:
    """Time history of the structure on ``soil`` under ground acceleration ``ag``.

    ag : (nt, 3) m/s^2 at t_k = k dt (x, y, z); output_nodes : node names (default: all
    named nodes); progress : callable(k, nt) or None. Returns a RouteResult; on a Newton
    failure raises ConvergenceError with ``.result`` holding the samples computed so far.

    What is skipped (``info["skipped"]``, ``info["precheck"]``): with the contact disabled,
    or enabled with ``contact.precheck`` and the raft in full contact at rest, the run is the
    closed-contact linear recursion (``_closed_run``: one factorisation, one solve per
    step, outputs and energies computed at the end over the whole history). With the contact
    enabled that run stops at the first step where a node would go into tension (the gap
    opens), the soil is rolled back and the nonlinear stepper runs from t = 0, so a run with
    uplift is exactly what ``precheck=False`` gives. Without tension the closed solution is
    the unilateral one (the penalty law is linear while closed); it equals the Newton path to
    round-off amplified by the penalty's conditioning (~1e-10 relative, as between any two
    linear solvers of this system).
    """
    with single_threaded_blas():
        return _simulate(model, soil, ag, dt, contact, damping, alpha, output_nodes, progress,
                         route, static)


def _closed_run(st: NewmarkStepper, ag, stop_on_tension: bool, progress=None):
    """The whole run with every contact spring closed (linear): one factorisation, one solve
    per step, the soil advanced through its protocol. Returns (Z, H): Z (nt, 3, n) the states
    [u, v, a] and H (nt, 6+N) the soil history force of each step; or, when
    ``stop_on_tension``, the index k of the first step where a node goes into tension (checked
    every 50 steps at most: the run goes on at most that far past it; the soil is then left
    advanced, the stepper itself is not changed).

    The update is the stepper's (``_advance`` with the contact closed) written on the
    predictors p = -a_hat, q = -v_hat for speed: A u' = M p + (1+al) (C q + F' - h) - al F + al R,
    v' = c1 u' - q, a' = c0 u' - p (tests/test_skip.py checks it against ``step()``)."""
    nt, dt, al = ag.shape[0], st.dt, st.alpha
    sysd = st._system(dt)
    lu = st._closed_lu(sysd)
    c0, c1, c2, c3 = st._coeffs(dt)
    b, g = st.beta, st.gamma
    W = np.array([[c0, c2, c3], [c1, -(1 - g / b), -dt * (1 - g / (2 * b))]])
    e = np.array([[1.0], [c1], [c0]])
    M, ni, ns = st.M, st.ni, st.ns
    Ktot, Ctot, B3, delta0 = sysd["Ktot"], sysd["Ctot"], st.Bq3, st.delta0
    Cq = _MatVec(Ctot)
    F = -ag @ st.Mr.T
    Fk = (1 + al) * F
    Fk[1:] -= al * F[:-1]
    Z = np.vstack([st.u, st.v, st.a])
    Zh = np.empty((nt, 3, st.n))
    H = np.zeros((nt, st.nb))
    Zh[0] = Z
    R = st.R
    soil = st.soil
    soil.instantaneous(dt)
    every, k0 = max(1, min(50, nt // 100)), 1
    for k in range(1, nt):
        h = soil.history()
        p, q = W @ Z
        rhs = M * p
        Cq.add_to(rhs, q, 1 + al)
        if al:
            rhs += al * R
        rhs[ni:] -= (1 + al) * h if al else h
        rhs += Fk[k]
        u = lu.solve(rhs)
        Z = e * u
        Z[1] -= q
        Z[2] -= p
        soil.commit(u[ni:].copy(), Z[1, ni:].copy())
        if al:
            R = Ktot @ u + Ctot @ Z[1]
            R[ni:] += h + st._contact(u[ni:])[2]
        Zh[k] = Z
        H[k] = h
        if k % every == 0 or k == nt - 1:
            # tension (d > delta0) checked in blocks of steps: the run restarts from t = 0 anyway
            if stop_on_tension:
                blk = Zh[k0:k + 1, 0]
                tens = np.flatnonzero(((blk[:, ni + 2:ni + 5] @ B3.T - blk[:, ns:]) > delta0).any(axis=1))
                if tens.size:
                    return k0 + int(tens[0])
                k0 = k + 1
            if progress is not None:
                progress(k, nt)
    return Zh, H


def _rows_times(S, Z, r, c):
    """(nt, |r|): rows r of S z_k for every row z_k of Z (nt, n), S sparse and zero outside
    rows r and columns c: a dense block product when S is dense there, else sparse."""
    Sb = S[r][:, c]
    Zc = Z[:, c]
    if Sb.nnz >= 0.1 * r.size * c.size:
        return Zc @ Sb.toarray().T
    return (Sb @ np.ascontiguousarray(Zc.T)).T


def _work(dY, S, Z):
    """(nt - 1,) dy_k . S (z_k + z_{k+1}) / 2 for dY (nt - 1, n), Z (nt, n) and a sparse S
    (n, n): the work increments of the force S z, on the rows and columns S touches."""
    rows, cols = S.nonzero()
    if rows.size == 0:
        return np.zeros(dY.shape[0])
    r = np.unique(rows)
    Q = _rows_times(S, Z, r, np.unique(cols))
    return np.einsum("ij,ij->i", dY[:, r], 0.5 * (Q[:-1] + Q[1:]))


def _quad(Y, S):
    """(nt,) y_k . S y_k / 2 for Y (nt, n) and a sparse S (n, n)."""
    rows, cols = S.nonzero()
    r = np.unique(rows)
    return 0.5 * np.einsum("ij,ij->i", Y[:, r], _rows_times(S, Y, r, np.unique(cols)))


class _MatVec:
    """y = S x for a constant sparse S, fast in a time loop: a dense product on the bounding
    block of its nonzeros when S is dense there (the modal damping of a stick model), else
    scipy's sparse product."""

    def __init__(self, S):
        S = sp.csr_matrix(S)
        rows, cols = S.nonzero()
        if rows.size == 0:
            self.mode = "zero"
            return
        self.r = slice(rows.min(), rows.max() + 1)
        self.c = slice(cols.min(), cols.max() + 1)
        block = S[self.r, self.c]
        self.mode = "dense" if block.nnz >= 0.1 * block.shape[0] * block.shape[1] else "sparse"
        self.S = block.toarray() if self.mode == "dense" else S

    def add_to(self, y, x, scale=1.0):
        """y += scale * S x."""
        if self.mode == "dense":
            y[self.r] += self.S @ x[self.c] if scale == 1.0 else scale * (self.S @ x[self.c])
        elif self.mode == "sparse":
            y += self.S @ x if scale == 1.0 else scale * (self.S @ x)


def _closed_result(st: NewmarkStepper, res: SimpleNamespace, ag, Zh, H, dofs) -> None:
    """Fill the history buffers ``res`` from a closed run's histories: the stepper's step-by-step records and
    energy works, vectorised over time."""
    sysd = st._system(st.dt)
    ni, ns = st.ni, st.ns
    U, V, A = Zh[:, 0], Zh[:, 1], Zh[:, 2]
    res.raft[:] = U[:, ni:ni + 6]
    res.soil_w[:] = U[:, ns:]
    d = res.raft[:, 2:5] @ st.Bq3.T - res.soil_w
    if st.contact.enabled:
        P = contact_force(d, st.delta0, st.kp)[0]
        res.gap[:] = gap(d, st.delta0)
    else:
        P = st.P0 - st.kp * d
    P[0] = st.P0                                   # the static state, as the stepper records it
    res.contact_force[:] = P
    for nm, dd in dofs.items():
        res.acc[nm][:] = A[:, dd] + ag
        res.disp[nm][:] = U[:, dd]
    # works: sums over the steps of du . (f_n + f_{n+1}) / 2, as NewmarkStepper._advance
    dU = np.diff(U, axis=0)
    dX = dU[:, ni:]
    dp = P - st.P0
    dp[0] = 0.0                                    # the stepper starts from zero forces
    works = {"input": -np.einsum("ij,ij->i", dU @ st.Mr, 0.5 * (ag[:-1] + ag[1:])),
             "damping": _work(dU, st.Cs, V),
             # fs = K0 x + C0 xdot + h (zero at t = 0, where x = xdot = h = 0)
             "soil": _work(dX, sysd["K0"], U[:, ni:]) + _work(dX, sysd["C0"], V[:, ni:]),
             # fc = -B^T dp on x, B x = d: dx . fc = -dd . dp
             "contact": -np.einsum("ij,ij->i", np.diff(d, axis=0), 0.5 * (dp[:-1] + dp[1:]))}
    if H.any():
        works["soil"] += np.einsum("ij,ij->i", dX, 0.5 * (H[:-1] + H[1:]))
    for key, w in works.items():
        res.energy[key][0] = 0.0
        np.cumsum(w, out=res.energy[key][1:])
    res.energy["kinetic"][:] = 0.5 * np.einsum("ij,ij->i", V, V * st.M)
    res.energy["strain"][:] = _quad(U, st.Ks)
    if st.contact.enabled:
        pen = np.maximum(0.0, st.delta0 - d)
        pen0 = np.maximum(0.0, st.delta0)
        res.energy["contact_potential"][:] = (0.5 * st.kp * (pen**2 - pen0**2) + st.P0 * d).sum(axis=1)
    else:
        res.energy["contact_potential"][:] = (0.5 * st.kp * d * d).sum(axis=1)


def _simulate(model, soil, ag, dt, contact, damping, alpha, output_nodes, progress, route, static):
    t0 = _time.perf_counter()
    ag = np.asarray(ag, float)
    if ag.ndim != 2 or ag.shape[1] != 3:
        raise StructureError(f"ground acceleration must have shape (nt, 3), got {ag.shape}")
    if not np.all(np.isfinite(ag)):
        raise StructureError("ground acceleration contains NaN or inf")
    st = NewmarkStepper(model, soil, dt, contact=contact, damping=damping, alpha=alpha,
                        static=static, ag0=ag[0])
    names = [n.name for n in model.nodes if n.name] if output_nodes is None else list(output_nodes)
    dofs = {nm: model.dofs(model.node_by_name(nm).id)[:3] for nm in names}
    nt, N = ag.shape[0], model.n_interface
    res = SimpleNamespace(      # history buffers, filled in place, frozen into a RouteResult at the end
        raft=np.zeros((nt, 6)), gap=np.zeros((nt, N)), contact_force=np.zeros((nt, N)), soil_w=np.zeros((nt, N)),
        acc={nm: np.zeros((nt, 3)) for nm in names}, disp={nm: np.zeros((nt, 3)) for nm in names},
        energy={k: np.zeros(nt) for k in ("input", "kinetic", "strain", "damping", "soil", "contact",
                                          "contact_potential")},
        newton_iters=np.zeros(nt, int))
    info = dict(settlement=st.static.settlement, P0=st.P0.copy(), penalty=st.kp.copy(),
                delta0=st.delta0.copy(), dt=dt, alpha=alpha, contact_enabled=st.contact.enabled)
    skipped = []
    enabled = st.contact.enabled
    if not enabled:
        closed, note = True, "not needed: contact disabled (bonded raft, linear)"
    elif not st.contact.precheck:
        closed, note = False, "off (contact.precheck = false): nonlinear contact iterations forced"
    elif not np.all(st.P0 > 0):
        closed, note = False, (f"not run: {int(np.sum(st.P0 <= 0))} interface nodes are not in contact at "
                               "rest, the closed-contact problem is not the unilateral one")
    else:
        closed, note = True, ""
    if closed:
        soil0 = st.soil.get_state()
        out = _closed_run(st, ag, enabled, progress)
        if isinstance(out, int):
            st.soil.set_state(soil0)
            closed = False
            note = f"tension at t = {out * dt:.6g} s (step {out}): the contact opens, nonlinear run from t = 0"
        elif not (np.isfinite(out[0][-1]).all() and np.isfinite(out[1][-1]).all()):
            # a linear recursion that overflows stays non-finite to the end
            st.soil.set_state(soil0)          # let the stepper report where it breaks down
            closed = False
            note = "the closed-contact run is not finite: nonlinear run from t = 0"
        else:
            _closed_result(st, res, ag, *out, dofs)
            note = note or "no tension: the closed-contact (linear) solution is the unilateral one"
            skipped.append(
                "contact disabled: one linear solve per step, no Newton" if not enabled else
                "no tension in the linear pre-check: nonlinear contact iterations skipped")
    failure, n_subdivided = (None, 0) if closed else _nonlinear(st, res, ag, dofs, progress)
    info.update(factorisations=st.n_factorisations, subdivided_steps=n_subdivided)
    out = RouteResult(route=route, time=dt * np.arange(nt), **vars(res), wall_s=_time.perf_counter() - t0,
                      xy=np.array(model.raft.xy), notes=RunNotes(skipped=skipped, precheck=note), info=info)
    if failure is not None:
        exc, k = failure
        exc.result = out.truncated(k, Status.STOPPED, str(exc))
        raise exc
    return out


def _nonlinear(st: NewmarkStepper, res: SimpleNamespace, ag, dofs, progress):
    """The step-by-step run (Newton on the contact), recorded into the buffers ``res``.
    Returns (failure, subdivided steps): failure is None or (ConvergenceError, first step not
    computed)."""
    ni, nt = st.ni, ag.shape[0]

    def record(k):
        res.raft[k] = st.u[ni:ni + 6]
        res.gap[k] = st.gap()
        res.contact_force[k] = st.P
        res.soil_w[k] = st.u[st.ns:]
        for nm, d in dofs.items():
            res.acc[nm][k] = st.a[d] + st.ag
            res.disp[nm][k] = st.u[d]
        for key, val in st.energies().items():
            res.energy[key][k] = val

    record(0)
    n_subdivided = 0
    for k in range(1, nt):
        st.set_ground_acceleration(ag[k])
        try:
            res.newton_iters[k] = st.step()
            n_subdivided += st.last_substeps > 1
        except ConvergenceError as exc:
            return (exc, k), n_subdivided
        record(k)
        if progress is not None:
            progress(k, nt)
    return None, n_subdivided

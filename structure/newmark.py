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
(``closed.ClosedSolver``: the soil DOFs condensed exactly when they are uncoupled, else sparse
LU), one solve per step, no Newton. ``march_closed`` runs the whole record that way and
``closed_histories`` records its outputs and energies over the whole history at once; the
driver ``simulate`` (driver.py) chooses between that and ``step()``.

The reference stepper. ``fmus/native/stepper.c`` (with ``soil.c``) steps the same discrete
equations in C and is what runs by default (the monolithic and winkler routes in process, the
native FMUs); this module is the readable reference it follows step for step: a change to the
physics is made here first, then there. The two are held equal by tests/fmu/test_native_stepper.py,
test_native_springs.py and test_native_fmu.py: the same Newton counts and halved steps, every
history to 1e-10 on a mild (bonded) scene and, where uplift amplifies round-off, to
max(1e-10, 100 x its round-off spread) measured on this stepper (tests/helpers/roundoff.py,
docs/verification.md "Two steppers of the same physics").
"""
from __future__ import annotations

from collections import OrderedDict

import numpy as np
from uplift_common.lazy import lazy_module

from uplift_common.blas import single_threaded_blas
from .closed_contact import ClosedSolver, MatVec, quad, work
from .contact import ContactSettings, contact_force, gap, penalty_stiffness
from .damping import damping_matrix
from .errors import ConvergenceError, StructureError
from .model import StructureModel
from .preload import StaticState, embed, interface_operator, solve_static

# scipy loads on first use (uplift_common.lazy): a warm run reads what it would compute
sla = lazy_module("scipy.linalg")
sp = lazy_module("scipy.sparse")
spla = lazy_module("scipy.sparse.linalg")


class _NewtonFailure(Exception):
    def __init__(self, node, residual):
        self.node, self.residual = node, residual



#: the energy terms of ``NewmarkStepper.energies()`` and of every history's ``energy``, in output order, J
ENERGY_TERMS = ("input", "kinetic", "strain", "damping", "soil", "contact", "contact_potential")


class NewmarkStepper:
    """One implicit time step at a time; the FMU calls ``step()`` exactly as ``simulate`` does.

    Public: ``step()``, and for a linear run ``march_closed`` and ``closed_histories``; inputs
    ``set_ground_acceleration``, ``set_soil_history``; outputs ``x``, ``xdot``, ``gap()``,
    ``energies()``; ``get_state`` / ``set_state``.

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
        self._scheme(model, soil, dt, contact, alpha)
        self.soil = soil
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
        self._start(ag0)

    def _scheme(self, model, soil, dt, contact, alpha) -> None:
        """Check the step, the HHT alpha and the soil's size; set the model, the step, the contact
        settings and the scheme's parameters (alpha, beta, gamma)."""
        if not dt > 0:
            raise StructureError(f"time step dt = {dt!r} must be > 0")
        if not -1.0 / 3.0 - 1e-12 <= alpha <= 0.0:
            raise StructureError(f"HHT alpha = {alpha!r} must lie in [-1/3, 0]")
        if soil.n_dof != 6 + model.n_interface:
            raise StructureError(f"soil has {soil.n_dof} interface DOFs, the raft needs 6 + N = "
                                 f"{6 + model.n_interface}")
        self.model, self.dt = model, float(dt)
        self.contact = contact or ContactSettings()
        self.alpha = float(alpha)
        self.beta = (1 - alpha) ** 2 / 4
        self.gamma = 0.5 - alpha

    def _start(self, ag0) -> None:
        """Empty caches and the state at rest at t = 0 under a_g(0) = ``ag0`` (M, Mr, P0 and the
        sizes set)."""
        self._systems = {}
        self._lu_cache = OrderedDict()
        self.n_factorisations = 0
        self._h_ext = np.zeros(self.nb)
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

    def next_inputs(self) -> tuple:
        """Copies of the inputs set for the next step: (a_g(t + dt) (3,) m/s^2, h (6+N,) N); an
        FMU keeps them in its state."""
        return self._ag_next.copy(), self._h_ext.copy()

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
        K0e = self._embed_soil(K0)
        C0e = self._embed_soil(C0)
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

    # ---- the raft's vertical trace (hooks: structure.plate_raft's PlateStepper overrides them) --
    def _embed_soil(self, K0):
        """The soil's (6+N, 6+N) matrix on the whole (n_dof, n_dof) system."""
        return embed(self.model, sp.csr_matrix((self.ns, self.ns)), K0)

    def _interface_operator(self):
        """B (N, n_dof): d = B u."""
        return interface_operator(self.model)

    def _trace(self, uB):
        """d (N,) = raft trace - w for the interface block uB = [q, w] (or an increment of it)."""
        return self.Bq3 @ uB[2:5] - uB[6:]

    def _relative_block(self, U):
        """d (k, N) for a block of whole states U (k, n_dof)."""
        ni = self.ni
        return U[:, ni + 2:ni + 5] @ self.Bq3.T - U[:, self.ns:]

    def _relative_history(self, out, U):
        """d (nt, N) from the recorded raft and soil_w histories (U (nt, n_dof) the states)."""
        return out["raft"][:, 2:5] @ self.Bq3.T - out["soil_w"]

    def _closed_lu(self, sysd):
        """Solver of the whole effective matrix with every contact spring closed: the linear
        problem (contact disabled, or closed everywhere), one factorisation per step size."""
        lu = sysd.get("lu_closed")
        if lu is None:
            B = self._interface_operator()
            Kc = B.T @ sp.diags(self.kp) @ B
            lu = sysd["lu_closed"] = ClosedSolver(sysd["A"] + (1 + self.alpha) * Kc, self.ns)
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
        d0 = self._trace(uB)
        dd = self._trace(dx)
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

    # ---- a linear run at once --------------------------------------------------------------
    def march_closed(self, ag, stop_on_tension: bool = False, progress=None):
        """The whole run with every contact spring closed (linear): one factorisation, one solve
        per step, the soil advanced through its protocol (not with an external soil). Returns
        (Z, H): Z (nt, 3, n) the states [u, v, a] and H (nt, 6+N) the soil history force of each
        step; or, when ``stop_on_tension``, the index k of the first step where a node goes into
        tension (checked every 50 steps at most: the run goes on at most that far past it; the
        soil is then left advanced, the stepper itself is not changed).

        ag : (nt, 3) m/s^2 at t_k = k dt, ag[0] the stepper's a_g(0); progress : callable(done,
        total) or None, with done = k + 1 samples of total = nt. Starts from the stepper's state at t = 0.

        The update is ``step()``'s with the contact closed, written on the predictors
        p = -a_hat, q = -v_hat for speed: A u' = M p + (1+al) (C q + F' - h) - al F + al R,
        v' = c1 u' - q, a' = c0 u' - p (tests/structural/test_skip.py checks it against ``step()``)."""
        with single_threaded_blas():
            return self._march_closed(ag, stop_on_tension, progress)

    def _march_closed(self, ag, stop_on_tension, progress):
        nt, dt, al = ag.shape[0], self.dt, self.alpha
        sysd = self._system(dt)
        lu = self._closed_lu(sysd)
        c0, c1, c2, c3 = self._coeffs(dt)
        b, g = self.beta, self.gamma
        W = np.array([[c0, c2, c3], [c1, -(1 - g / b), -dt * (1 - g / (2 * b))]])
        e = np.array([[1.0], [c1], [c0]])
        M, ni = self.M, self.ni
        Ktot, Ctot, delta0 = sysd["Ktot"], sysd["Ctot"], self.delta0
        Cq = MatVec(Ctot)
        F = -ag @ self.Mr.T
        Fk = (1 + al) * F
        Fk[1:] -= al * F[:-1]
        Z = np.vstack([self.u, self.v, self.a])
        Zh = np.empty((nt, 3, self.n))
        H = np.zeros((nt, self.nb))
        Zh[0] = Z
        R = self.R
        soil = self.soil
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
                R[ni:] += h + self._contact(u[ni:])[2]
            Zh[k] = Z
            H[k] = h
            if k % every == 0 or k == nt - 1:
                # tension (d > delta0) checked in blocks of steps: the run restarts from t = 0 anyway
                if stop_on_tension:
                    blk = Zh[k0:k + 1, 0]
                    tens = np.flatnonzero((self._relative_block(blk) > delta0).any(axis=1))
                    if tens.size:
                        return k0 + int(tens[0])
                    k0 = k + 1
                if progress is not None:
                    progress(k + 1, nt)
        return Zh, H

    def closed_histories(self, ag, Zh, H, dofs) -> dict:
        """The records of a ``march_closed`` run (Zh, H), as ``step()`` would leave them step by
        step, vectorised over time: raft (nt, 6) m and rad, soil_w, gap, contact_force (nt, N)
        m and N, acc and disp {node: (nt, 3)} m/s^2 (absolute) and m for the DOFs ``dofs``
        {node: (3,) indices}, energy {term: (nt,)} J (the terms of ``energies()``)."""
        nt, N = ag.shape[0], self.N
        out = dict(gap=np.zeros((nt, N)), acc={}, disp={}, energy={k: np.zeros(nt) for k in ENERGY_TERMS})
        sysd = self._system(self.dt)
        ni, ns = self.ni, self.ns
        U, V, A = Zh[:, 0], Zh[:, 1], Zh[:, 2]
        out["raft"] = U[:, ni:ni + 6].copy()
        out["soil_w"] = U[:, ns:].copy()
        d = self._relative_history(out, U)
        if self.contact.enabled:
            P = contact_force(d, self.delta0, self.kp)[0]
            out["gap"][:] = gap(d, self.delta0)
        else:
            P = self.P0 - self.kp * d
        P[0] = self.P0                                   # the static state, as the stepper records it
        out["contact_force"] = P
        for nm, dd in dofs.items():
            out["acc"][nm] = A[:, dd] + ag
            out["disp"][nm] = U[:, dd].copy()
        # works: sums over the steps of du . (f_n + f_{n+1}) / 2, as ``step()``
        dU = np.diff(U, axis=0)
        dX = dU[:, ni:]
        dp = P - self.P0
        dp[0] = 0.0                                    # the stepper starts from zero forces
        works = {"input": -np.einsum("ij,ij->i", dU @ self.Mr, 0.5 * (ag[:-1] + ag[1:])),
                 "damping": work(dU, self.Cs, V),
                 # fs = K0 x + C0 xdot + h (zero at t = 0, where x = xdot = h = 0)
                 "soil": work(dX, sysd["K0"], U[:, ni:]) + work(dX, sysd["C0"], V[:, ni:]),
                 # fc = -B^T dp on x, B x = d: dx . fc = -dd . dp
                 "contact": -np.einsum("ij,ij->i", np.diff(d, axis=0), 0.5 * (dp[:-1] + dp[1:]))}
        if H.any():
            works["soil"] += np.einsum("ij,ij->i", dX, 0.5 * (H[:-1] + H[1:]))
        for key, w in works.items():
            out["energy"][key][0] = 0.0
            np.cumsum(w, out=out["energy"][key][1:])
        out["energy"]["kinetic"][:] = 0.5 * np.einsum("ij,ij->i", V, V * self.M)
        out["energy"]["strain"][:] = quad(U, self.Ks)
        if self.contact.enabled:
            pen = np.maximum(0.0, self.delta0 - d)
            pen0 = np.maximum(0.0, self.delta0)
            out["energy"]["contact_potential"][:] = (0.5 * self.kp * (pen**2 - pen0**2) + self.P0 * d).sum(axis=1)
        else:
            out["energy"]["contact_potential"][:] = (0.5 * self.kp * d * d).sum(axis=1)
        return out

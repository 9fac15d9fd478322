"""Solvers of the contact equation over the whole time range (paper §3).

With the renormalised unknown z = z0 + y (tf_problem), the penetration e = phi(z) and the
dynamic contact force p = k z^+ - P0, the condensed system p = S * d - lam f (d = -(phi(z) -
phi(z0)), lam the motion scale) is the residual over [0, T], (N, nt), in N:

    g(y) = S * [phi(z0 + y) - phi(z0)] + k (z0 + y)^+ - P0 + lam f = 0        (paper eq. 16)

S* is applied per frequency (tf_operator) between windowed FFTs (tf_grid). Its generalized
(semi-smooth) Jacobian is J v = S * [(I^- + eps I^+) v] + k I^+ v with I^+ = [z > 0] the
active (closed) set, time-varying (paper eq. 18 with eps -> 0).

* ``paper_scheme``: y <- y - rho G^-1 g(y), G the order-0 stochastic linearisation of J:
  I^+- replaced by their time averages, globally or per window (restriction R_n, eq. 20).
* ``newton_krylov``: semi-smooth Newton, J dy = -g solved by right-preconditioned FGMRES
  to an Eisenstat-Walker forcing term, with the active-set preconditioner
  (``masked_preconditioner``: S_OO^-1 per frequency on the nodes O that open, masked to the
  open (node, time) entries; its product with J0 = J without the eps terms comes free),
  backtracking line search on |g| over an advancing time horizon, and load continuation
  (ramping lam) when Newton stalls. Known limit (benchmarks/timefreq.py --map): on the
  21-node Winkler raft it fails from 0.4 g (from 0.6 g when started from a causal march):
  the linearisation with the active set frozen holds over no full step once contact switches
  thousands of times, whereas the Newmark stepper solves the same discrete equations in
  <= 3 Newton iterations a step. tf_march.defect_correction (the route's default) marches
  them step by step.

G per frequency: columns of never-open nodes are k e_j (times 1 + O(eps)), so G is block
lower-triangular: only the m x m block of the nodes that open is factorised per frequency.
"""
from __future__ import annotations

import time

import numpy as np


class ContactEquation:
    """g(y), J v and the averaged preconditioner of one ContactProblem at motion scale lam."""

    def __init__(self, prob, lam: float = 1.0):
        self.p, self.lam = prob, float(lam)
        self.g = prob.grid
        self.z0 = prob.z0
        self.phi0 = prob.phi(self.z0[:, None])
        self.k = prob.k[:, None]
        self.eps = prob.eps[:, None]
        self.n_res = 0
        self.n_jv = 0

    def S(self, x):
        """S * x for x (N, nt) causal."""
        return self.g.to_time(self.p.op.apply_S(self.g.to_freq(x)))

    def residual(self, y):
        self.n_res += 1
        z = self.z0[:, None] + y
        return self.S(self.p.phi(z) - self.phi0) + self.k * np.maximum(z, 0.0) \
            - self.p.P0[:, None] + self.lam * self.p.f

    def jvp(self, y, v):
        self.n_jv += 1
        closed = (self.z0[:, None] + y) > 0
        return self.S(np.where(closed, self.eps * v, v)) + np.where(closed, self.k * v, 0.0)

    def averaged(self, y, windows=1):
        """AveragedOperator (list over windows) of the active set at y."""
        closed = (self.z0[:, None] + y) > 0
        nt = y.shape[1]
        edges = np.linspace(0, nt, windows + 1).round().astype(int)
        return [AveragedOperator(self, 1.0 - closed[:, a:b].mean(axis=1), a, b)
                for a, b in zip(edges[:-1], edges[1:])]


class AveragedOperator:
    """G = S (Dm + eps Dp) + k Dp, Dm/Dp the time-averaged open/closed fractions (N,) on one
    window [a, b); ``solve(r)`` = G^-1 (R r), R the restriction to the window."""

    def __init__(self, eq: ContactEquation, open_frac, a, b):
        self.eq, self.a, self.b = eq, a, b
        self.Dm = open_frac
        self.Dp = 1.0 - open_frac
        op = eq.p.op
        self.O = np.flatnonzero(open_frac > 0)
        self.C = np.flatnonzero(open_frac <= 0)
        k, eps = eq.p.k, eq.p.eps
        self.kO, self.kC = k[self.O], k[self.C]
        self.colO = self.Dm[self.O] + eps[self.O] * self.Dp[self.O]
        if self.O.size:
            G = op.S_sub(self.O, self.O) * self.colO[None, None, :]
            G[:, np.arange(self.O.size), np.arange(self.O.size)] += self.kO * self.Dp[self.O]
            self.Ginv = np.linalg.inv(G)

    @property
    def n_open(self) -> int:
        return int(self.O.size)

    def solve(self, r):
        eq = self.eq
        if self.a > 0 or self.b < r.shape[1]:
            rr = np.zeros_like(r)
            rr[:, self.a:self.b] = r[:, self.a:self.b]
            r = rr
        if not self.O.size:
            return r / eq.k
        g = eq.g
        R = g.to_freq(r)                                     # (N, F)
        xO = np.einsum("fij,jf->if", self.Ginv, R[self.O])   # (m, F)
        full = np.zeros_like(R)
        full[self.O] = xO * self.colO[:, None]
        SX = eq.p.op.apply_S(full)
        X = np.empty_like(R)
        X[self.O] = xO
        X[self.C] = (R[self.C] - SX[self.C]) / self.kC[:, None]
        return g.to_time(X)


def precondition(ops, r):
    out = ops[0].solve(r)
    for o in ops[1:]:
        out += o.solve(r)
    return out


def fgmres(matvec, b, precond, rtol, restart=40, maxiter=200):
    """Right-preconditioned flexible GMRES from x = 0. Returns (x, iterations, relres).

    matvec None: precond(v) returns (z, A z) (a preconditioner that yields the product with
    its result for free, see ``masked_preconditioner``) and precond.matvec(x) is A x."""
    shape = b.shape
    bn = np.linalg.norm(b)
    if bn == 0:
        return np.zeros(shape), 0, 0.0
    x = np.zeros(b.size)
    r = b.ravel().copy()
    total = 0
    rel = 1.0
    while total < maxiter:
        beta = np.linalg.norm(r)
        V = [r / beta]
        Z = []
        H = np.zeros((restart + 1, restart))
        cs, sn = np.zeros(restart), np.zeros(restart)
        e = np.zeros(restart + 1)
        e[0] = beta
        j = 0
        for j in range(restart):
            if matvec is None:
                zj, w = precond(V[j].reshape(shape))
                zj, w = zj.ravel(), w.ravel()
            else:
                zj = precond(V[j].reshape(shape)).ravel()
                w = matvec(zj.reshape(shape)).ravel()
            Z.append(zj)
            total += 1
            for i in range(j + 1):
                H[i, j] = V[i] @ w
                w -= H[i, j] * V[i]
            H[j + 1, j] = np.linalg.norm(w)
            for i in range(j):
                t = cs[i] * H[i, j] + sn[i] * H[i + 1, j]
                H[i + 1, j] = -sn[i] * H[i, j] + cs[i] * H[i + 1, j]
                H[i, j] = t
            den = np.hypot(H[j, j], H[j + 1, j])
            cs[j], sn[j] = (H[j, j] / den, H[j + 1, j] / den) if den > 0 else (1.0, 0.0)
            H[j, j] = den
            e[j + 1] = -sn[j] * e[j]
            e[j] = cs[j] * e[j]
            rel = abs(e[j + 1]) / bn
            if rel <= rtol or total >= maxiter or H[j + 1, j] == 0:
                break
            V.append(w / H[j + 1, j])
        m = j + 1
        c = np.linalg.solve(np.triu(H[:m, :m]), e[:m])
        for ci, zi in zip(c, Z):
            x += ci * zi
        if rel <= rtol or total >= maxiter:
            break
        r = b.ravel() - _product(matvec, precond, x, shape)
    return x.reshape(shape), total, rel


def _product(matvec, precond, x, shape):
    """A x at a restart (matvec None: the combined preconditioner's own precond.matvec)."""
    if matvec is not None:
        return matvec(x.reshape(shape)).ravel()
    return precond.matvec(x.reshape(shape)).ravel()


def _scale(eq):
    return max(np.linalg.norm(eq.lam * eq.p.f), 1e-300)


def newton_krylov(prob, tol=1e-10, max_iter=200, y0=None, lam=1.0, windows=1, gmres_restart=80,
                  gmres_maxiter=300, history=None, horizon_s=None, exact_jacobian=False,
                  forcing_max=0.1, deadline=None):
    """Semi-smooth Newton-Krylov at motion scale lam, advancing a time horizon.

    Causality: g on [0, t) depends on y on [0, t) only. Each iteration finds the first time
    t_b where the cumulative residual exceeds the tolerance (the prefix before it is solved),
    and takes a Newton step for the prefix [0, t_b + H) only (J and the preconditioner masked
    to it), with a backtracking line search on the prefix residual. H (initially horizon_s;
    default 0.5 s from y = 0, the whole range from a given y0, whose residual is spread over
    it) doubles after a full step and halves after a cut one. deadline (perf_counter time):
    stop there with the last iterate (converged False, history[-1]["stopped"]).

    Inner solves: FGMRES to the Eisenstat-Walker forcing term on the full range (choice 2:
    0.9 (|g_k| / |g_k-1|)^2 with its safeguard, at most forcing_max, at least what the last
    step needs, 0.25 tol |f| / |g|, and 1e-6); 1e-3 while the horizon advances or after a cut
    step. The Jacobian is J0 (``masked_preconditioner``: eps terms
    dropped, O(|S|/kp) ~ 1e-4 relative, so Newton still converges, at worst linearly with
    that factor, to the exact residual g) whose product comes with the preconditioner for
    free: one S application per GMRES iteration instead of two. J itself
    (``ContactEquation.jvp``) while the horizon advances (where contact first opens and steps
    are often cut), for forcing terms below 1e-2 (the last iterations, where J0's error
    would make Newton linear) and with exact_jacobian=True. Returns (y, converged, history).

    Known limit (benchmarks/timefreq.py --map): on the 21-node Winkler raft it fails from
    0.4 g from zero and from 0.6 g even when started from one causal march (0.3 % from the
    solution): GMRES stalls once contact switches often, and with the linearised march as
    preconditioner (tried: 1-2 GMRES iterations) the full semi-smooth steps still diverge,
    the frozen active set holding for no step over thousands of switches. tf_march's
    defect correction is the robust solver."""
    eq = ContactEquation(prob, lam)
    nt = prob.f.shape[1]
    y = np.zeros_like(prob.f) if y0 is None else y0.copy()
    g = eq.residual(y)
    scale = _scale(eq)
    hist = [] if history is None else history
    if horizon_s is None:
        horizon_s = 0.5 if y0 is None else np.inf
    H = int(min(nt, max(4, round(min(horizon_s, 2 * nt * prob.grid.dt) / prob.grid.dt))))
    Hmin = 4
    forcing, gp_prev = forcing_max, None
    for it in range(1, max_iter + 1):
        gn = np.linalg.norm(g)
        if gn <= tol * scale:
            return y, True, hist
        t0 = time.perf_counter()
        cum = np.sqrt(np.cumsum(np.einsum("it,it->t", g, g)))
        tb = int(np.searchsorted(cum, 0.5 * tol * scale))
        hi = min(nt, tb + H)
        mask = np.zeros(nt, bool)
        mask[:hi] = True
        prec = masked_preconditioner(eq, y, windows, time_mask=mask)
        gp = np.where(mask, g, 0.0)
        gpn = np.linalg.norm(gp)
        if hi < nt or (hist and hist[-1]["step"] < 1.0):
            forcing = 1e-3                          # advancing horizon, or after a cut step
        elif gp_prev is not None:
            ew = 0.9 * (gpn / gp_prev) ** 2
            safe = 0.9 * forcing ** 2
            forcing = min(forcing_max, max(ew, safe) if safe > 0.1 else ew)
        forcing = max(forcing, 0.25 * tol * scale / gn, 1e-6)
        if exact_jacobian or hi < nt or forcing < 1e-2:
            dy, nit, rel = fgmres(lambda v: np.where(mask, eq.jvp(y, v), 0.0), -gp, prec, forcing,
                                  gmres_restart, gmres_maxiter)
        else:
            pm = prec.with_product
            pm.matvec = prec.matvec
            dy, nit, rel = fgmres(None, -gp, pm, forcing, gmres_restart, gmres_maxiter)
        t = 1.0
        best = None
        for _ in range(8):
            yt = y + t * dy
            gt = eq.residual(yt)
            gtn = np.linalg.norm(np.where(mask, gt, 0.0))
            if best is None or gtn < best[2]:
                best = (yt, gt, gtn, t)
            if gtn <= (1 - 1e-4 * t) * gpn:
                break
            t *= 0.5
        yt, gt, gtn, t = best
        if not np.all(np.isfinite(gt)):
            return y, False, hist
        if gtn < gpn:
            y, g = yt, gt
        gp_prev = gpn if hi == nt else None
        H = min(2 * H, nt) if t == 1.0 else max(H // 2, Hmin)
        hist.append(dict(lam=lam, iter=it, residual=float(np.linalg.norm(g) / scale),
                         horizon_s=hi * prob.grid.dt, gmres=int(nit), gmres_relres=float(rel),
                         forcing=float(forcing),
                         step=float(t), n_open=int(prec.n_open), wall_s=time.perf_counter() - t0))
        if deadline is not None and time.perf_counter() > deadline:
            hist[-1]["stopped"] = "time budget"
            return y, bool(np.linalg.norm(g) <= tol * scale), hist
        if gtn >= gpn and H == Hmin and len(hist) > 1 and hist[-2]["step"] < 1 and hist[-2]["horizon_s"] <= hi * prob.grid.dt:
            return y, False, hist
    return y, np.linalg.norm(g) <= tol * scale, hist


def newton_continuation(prob, tol=1e-10, max_iter=200, windows=1, y0=None, min_dlam=1 / 64,
                        **kw):
    """Newton-Krylov at lam = 1 from y0 (None: zero); if it fails, load continuation: lam
    ramped from zero with an adaptive step (doubled on success, halved on failure), each
    solve started from the last converged one. A deadline (kw) stops it with the last iterate.
    Returns (y, converged, history, ladder of the converged lam)."""
    hist = []
    y, ok, _ = newton_krylov(prob, tol, max_iter, y0=y0, lam=1.0, windows=windows, history=hist, **kw)
    if ok or (hist and hist[-1].get("stopped")):
        return y, ok, hist, [1.0] if ok else []
    lam_done, y_done, dl = 0.0, np.zeros_like(prob.f), 0.25
    ladder = []
    while lam_done < 1.0:
        lam = min(1.0, lam_done + dl)
        y, ok, _ = newton_krylov(prob, tol, max_iter, y0=y_done, lam=lam, windows=windows,
                                 history=hist, **{"horizon_s": 0.5, **kw})
        if hist and hist[-1].get("stopped"):
            return y, ok and lam == 1.0, hist, ladder + [lam] if ok else ladder
        if ok:
            lam_done, y_done = lam, y
            ladder.append(lam)
            dl = min(2 * dl, 0.5)
        else:
            dl *= 0.5
            if dl < min_dlam:
                return y_done, False, hist, ladder
    return y_done, True, hist, ladder


def paper_scheme(prob, rho=1.0, windows=1, tol=1e-6, max_iter=200, y0=None, lam=1.0,
                 diverge=1e3):
    """The paper's quasi-Newton (eq. 17-20): y <- y - rho G_n^-1 g(y), G_n the order-0
    stochastic linearisation (averages over ``windows`` windows). Returns (y, converged,
    history)."""
    eq = ContactEquation(prob, lam)
    y = np.zeros_like(prob.f) if y0 is None else y0.copy()
    g = eq.residual(y)
    scale = _scale(eq)
    g0 = np.linalg.norm(g)
    hist = []
    for it in range(1, max_iter + 1):
        gn = np.linalg.norm(g)
        if gn <= tol * scale:
            return y, True, hist
        if not np.isfinite(gn) or gn > diverge * g0:
            return y, False, hist
        t0 = time.perf_counter()
        ops = eq.averaged(y, windows)
        y = y - rho * precondition(ops, g)
        g = eq.residual(y)
        hist.append(dict(iter=it, residual=float(np.linalg.norm(g) / scale),
                         n_open=int(max(o.n_open for o in ops)), wall_s=time.perf_counter() - t0))
    return y, np.linalg.norm(g) <= tol * scale, hist


class MaskedOperator:
    """Active-set preconditioner: J ~ [[k, S_co], [0, S_oo]] on the (closed, open) entries of
    the (node, time) grid (eps terms dropped), with S_oo^-1 ~ I^- S_OO^-1 I^-: the frequency-
    domain inverse of S on the nodes O that open in the window [a, b), applied to the masked
    residual and masked again. Exact when the open set is constant on the window."""

    def __init__(self, eq: ContactEquation, open_mask, a, b):
        self.eq, self.a, self.b = eq, a, b
        self.mask = np.zeros_like(open_mask)
        self.mask[:, a:b] = open_mask[:, a:b]
        self.O = np.flatnonzero(self.mask.any(axis=1))
        if self.O.size:
            key = self.O.tobytes()
            cache = eq.__dict__.setdefault("_sinv_cache", {})
            if key not in cache:                 # factorised once per open node set
                if len(cache) > 4:
                    cache.pop(next(iter(cache)))
                cache[key] = eq.p.op.sub_inverse(self.O)
                eq.n_factor = getattr(eq, "n_factor", 0) + 1
            self.Sinv = cache[key]

    @property
    def n_open(self) -> int:
        return int(self.O.size)

    def open_part(self, r):
        if not self.O.size:
            return np.zeros_like(r)
        g = self.eq.g
        R = g.to_freq(np.where(self.mask[self.O], r[self.O], 0.0))
        xo = g.to_time(self.Sinv.apply(R))
        out = np.zeros_like(r)
        out[self.O] = np.where(self.mask[self.O], xo, 0.0)
        return out


def masked_preconditioner(eq, y, windows=1, time_mask=None):
    """r -> x for the active-set preconditioner (MaskedOperator per window).

    ``apply.with_product(r)`` returns (x, J0 x) with J0 v = S * [I^- v] + k I^+ v, the
    Jacobian without its eps terms (closed nodes as rigid supports; J - J0 = S * [eps I^+ v]
    is O(|S| / kp) ~ 1e-4 relative): J0 x = S xo on the open entries and r on the closed ones,
    so the product costs nothing beyond the preconditioner's own S * xo. time_mask (nt,)
    bool restricts both to a time prefix (Newton's horizon). ``apply.matvec`` is J0."""
    z = eq.z0[:, None] + y
    open_mask = z <= 0
    nt = y.shape[1]
    tm = np.ones(nt, bool) if time_mask is None else time_mask
    edges = np.linspace(0, nt, windows + 1).round().astype(int)
    ops = [MaskedOperator(eq, open_mask, a, b) for a, b in zip(edges[:-1], edges[1:])]

    def parts(r):
        if not open_mask.any():
            return np.zeros_like(r), np.zeros_like(r)
        xo = ops[0].open_part(r)
        for o in ops[1:]:
            xo += o.open_part(r)
        xo = np.where(tm, xo, 0.0)          # beyond the horizon it would wrap around into S xo
        return xo, eq.S(xo)

    def apply(r):
        return with_product(r)[0]

    def with_product(r):
        xo, Sxo = parts(r)
        x = np.where(tm, xo + np.where(open_mask, 0.0, (r - Sxo) / eq.k), 0.0)
        return x, np.where(tm, np.where(open_mask, Sxo, r), 0.0)

    def matvec(v):
        return np.where(tm, eq.S(np.where(open_mask, v, 0.0)) + np.where(open_mask, 0.0, eq.k * v), 0.0)

    apply.with_product = with_product
    apply.matvec = matvec
    apply.n_open = max(o.n_open for o in ops)
    return apply

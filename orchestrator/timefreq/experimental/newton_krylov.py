"""EXPERIMENTAL: semi-smooth Newton-Krylov on the whole-range contact equation (method
"newton-krylov"; the route's default is the march, orchestrator/timefreq/march.py).

Newton on g(y) = 0 (problem.ContactEquation): J dy = -g solved by right-preconditioned FGMRES
to an Eisenstat-Walker forcing term, with the active-set preconditioner
(``masked_preconditioner``: S_OO^-1 per frequency on the nodes O that open, masked to the open
(node, time) entries; its product with J0 = J without the eps terms comes free), backtracking
line search on |g| over an advancing time horizon, and load continuation (ramping lam) when
Newton stalls. It is the solver of the continuous grid, where the march's instantaneous kernel
is indefinite.

Measured failure points (benchmarks/timefreq.py --map): on the 21-node Winkler raft it fails
from 0.4 g started from zero and from 0.6 g started from one causal march (0.3 % from the
solution): GMRES stalls once contact switches often, and with the linearised march as
preconditioner (tried: 1-2 GMRES iterations) the full semi-smooth steps still diverge, the
frozen active set holding for no step over thousands of switches, whereas the Newmark stepper
solves the same discrete equations in <= 3 Newton iterations a step. march.defect_correction
marches them step by step.
"""
from __future__ import annotations

import time
from itertools import pairwise
from dataclasses import dataclass

import numpy as np

from orchestrator.timefreq.problem import ContactEquation, Outcome, SolverStatus


@dataclass(frozen=True)
class NewtonIteration:
    """One Newton step: lam the motion scale, iter (from 1, per solve), residual |g| / |lam f|
    after it, horizon_s the time prefix solved, gmres / gmres_relres the inner solve, forcing
    its tolerance, step the line search's step length, n_open the preconditioner's open nodes,
    wall_s."""
    lam: float
    iter: int
    residual: float
    horizon_s: float
    gmres: int
    gmres_relres: float
    forcing: float
    step: float
    n_open: int
    wall_s: float


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
        for ci, zi in zip(c, Z, strict=True):
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


def newton_krylov(prob, tol=1e-10, max_iter=200, y0=None, lam=1.0, windows=1, gmres_restart=80,
                  gmres_maxiter=300, history=None, horizon_s=None, exact_jacobian=False,
                  forcing_max=0.1, deadline=None) -> Outcome:
    """Semi-smooth Newton-Krylov at motion scale lam, advancing a time horizon.

    Causality: g on [0, t) depends on y on [0, t) only. Each iteration finds the first time
    t_b where the cumulative residual exceeds the tolerance (the prefix before it is solved),
    and takes a Newton step for the prefix [0, t_b + H) only (J and the preconditioner masked
    to it), with a backtracking line search on the prefix residual. H (initially horizon_s;
    default 0.5 s from y = 0, the whole range from a given y0, whose residual is spread over
    it) doubles after a full step and halves after a cut one. deadline (perf_counter time):
    stop there with the last iterate (STOPPED). history: a list the NewtonIteration records are
    appended to (shared by the solves of a continuation; the step control reads its last ones).

    Inner solves: FGMRES to the Eisenstat-Walker forcing term on the full range (choice 2:
    0.9 (|g_k| / |g_k-1|)^2 with its safeguard, at most forcing_max, at least what the last
    step needs, 0.25 tol |f| / |g|, and 1e-6); 1e-3 while the horizon advances or after a cut
    step. The Jacobian is J0 (``masked_preconditioner``: eps terms
    dropped, O(|S|/kp) ~ 1e-4 relative, so Newton still converges, at worst linearly with
    that factor, to the exact residual g) whose product comes with the preconditioner for
    free: one S application per GMRES iteration instead of two. J itself
    (``ContactEquation.jvp``) while the horizon advances (where contact first opens and steps
    are often cut), for forcing terms below 1e-2 (the last iterations, where J0's error
    would make Newton linear) and with exact_jacobian=True. Returns an Outcome (history: the
    whole list, earlier solves included). Known limit: the module notes."""
    eq = ContactEquation(prob, lam)
    nt = prob.f.shape[1]
    y = np.zeros_like(prob.f) if y0 is None else y0.copy()
    g = eq.residual(y)
    scale = eq.scale
    hist = [] if history is None else history
    if horizon_s is None:
        horizon_s = 0.5 if y0 is None else np.inf
    n_h = int(min(nt, max(4, round(min(horizon_s, 2 * nt * prob.grid.dt) / prob.grid.dt))))
    h_min = 4
    cache = {}                    # S_OO^-1 per open node set (masked_preconditioner)
    forcing, gp_prev = forcing_max, None
    for it in range(1, max_iter + 1):
        gn = np.linalg.norm(g)
        if gn <= tol * scale:
            return Outcome(y, SolverStatus.CONVERGED, tuple(hist))
        t0 = time.perf_counter()
        cum = np.sqrt(np.cumsum(np.einsum("it,it->t", g, g)))
        tb = int(np.searchsorted(cum, 0.5 * tol * scale))
        hi = min(nt, tb + n_h)
        mask = np.zeros(nt, bool)
        mask[:hi] = True
        prec = masked_preconditioner(eq, y, windows, time_mask=mask, cache=cache)
        gp = np.where(mask, g, 0.0)
        gpn = np.linalg.norm(gp)
        if hi < nt or (hist and hist[-1].step < 1.0):
            forcing = 1e-3                          # advancing horizon, or after a cut step
        elif gp_prev is not None:
            ew = 0.9 * (gpn / gp_prev) ** 2
            safe = 0.9 * forcing ** 2
            forcing = min(forcing_max, max(ew, safe) if safe > 0.1 else ew)
        forcing = max(forcing, 0.25 * tol * scale / gn, 1e-6)
        if exact_jacobian or hi < nt or forcing < 1e-2:
            dy, nit, rel = fgmres(lambda v, y=y, mask=mask: np.where(mask, eq.jvp(y, v), 0.0), -gp, prec, forcing,
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
            return Outcome(y, SolverStatus.DIVERGED, tuple(hist), "the residual is no longer finite")
        if gtn < gpn:
            y, g = yt, gt
        gp_prev = gpn if hi == nt else None
        n_h = min(2 * n_h, nt) if t == 1.0 else max(n_h // 2, h_min)
        hist.append(NewtonIteration(lam=lam, iter=it, residual=float(np.linalg.norm(g) / scale),
                                    horizon_s=hi * prob.grid.dt, gmres=int(nit), gmres_relres=float(rel),
                                    forcing=float(forcing), step=float(t), n_open=int(prec.n_open),
                                    wall_s=time.perf_counter() - t0))
        if deadline is not None and time.perf_counter() > deadline:
            return Outcome(y, SolverStatus.STOPPED, tuple(hist), "time budget")
        if gtn >= gpn and n_h == h_min and len(hist) > 1 and hist[-2].step < 1 \
                and hist[-2].horizon_s <= hi * prob.grid.dt:
            return Outcome(y, SolverStatus.NOT_CONVERGED, tuple(hist), "the line search stalled")
    converged = np.linalg.norm(g) <= tol * scale
    return Outcome(y, SolverStatus.CONVERGED if converged else SolverStatus.NOT_CONVERGED, tuple(hist))


def newton_continuation(prob, tol=1e-10, max_iter=200, windows=1, y0=None, min_dlam=1 / 64,
                        **kw) -> Outcome:
    """Newton-Krylov at lam = 1 from y0 (None: zero); if it fails, load continuation: lam
    ramped from zero with an adaptive step (doubled on success, halved on failure), each
    solve started from the last converged one. A deadline (kw) stops it with the last iterate.
    Returns an Outcome (extra["continuation"]: the ladder of the converged lam)."""
    hist = []

    def ended(y, status, ladder, reason=""):
        return Outcome(y, status, tuple(hist), reason, {"continuation": ladder})

    out = newton_krylov(prob, tol, max_iter, y0=y0, lam=1.0, windows=windows, history=hist, **kw)
    if out.status in (SolverStatus.CONVERGED, SolverStatus.STOPPED):
        return ended(out.y, out.status, [1.0] if out.converged else [], out.reason)
    lam_done, y_done, dl = 0.0, np.zeros_like(prob.f), 0.25
    ladder = []
    while lam_done < 1.0:
        lam = min(1.0, lam_done + dl)
        out = newton_krylov(prob, tol, max_iter, y0=y_done, lam=lam, windows=windows,
                            history=hist, **{"horizon_s": 0.5, **kw})
        if out.status is SolverStatus.STOPPED:
            return ended(out.y, out.status, ladder, out.reason)
        if out.converged:
            lam_done, y_done = lam, out.y
            ladder.append(lam)
            dl = min(2 * dl, 0.5)
        else:
            dl *= 0.5
            if dl < min_dlam:
                return ended(y_done, SolverStatus.NOT_CONVERGED, ladder,
                             f"load continuation stalled at lam = {lam_done:g} (step below {min_dlam:g})")
    return ended(y_done, SolverStatus.CONVERGED, ladder)


class MaskedOperator:
    """Active-set preconditioner: J ~ [[k, S_co], [0, S_oo]] on the (closed, open) entries of
    the (node, time) grid (eps terms dropped), with S_oo^-1 ~ I^- S_OO^-1 I^-: the frequency-
    domain inverse of S on the nodes O that open in the window [a, b), applied to the masked
    residual and masked again. Exact when the open set is constant on the window. cache: {open
    node set: SubInverse}, shared by the operators of one solve."""

    def __init__(self, eq: ContactEquation, open_mask, a, b, cache: dict):
        self.eq, self.a, self.b = eq, a, b
        self.mask = np.zeros_like(open_mask)
        self.mask[:, a:b] = open_mask[:, a:b]
        self.O = np.flatnonzero(self.mask.any(axis=1))
        if self.O.size:
            key = self.O.tobytes()
            if key not in cache:                 # factorised once per open node set
                if len(cache) > 4:
                    cache.pop(next(iter(cache)))
                cache[key] = eq.p.op.sub_inverse(self.O)
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


def masked_preconditioner(eq, y, windows=1, time_mask=None, cache=None):
    """r -> x for the active-set preconditioner (MaskedOperator per window).

    ``apply.with_product(r)`` returns (x, J0 x) with J0 v = S * [I^- v] + k I^+ v, the
    Jacobian without its eps terms (closed nodes as rigid supports; J - J0 = S * [eps I^+ v]
    is O(|S| / kp) ~ 1e-4 relative): J0 x = S xo on the open entries and r on the closed ones,
    so the product costs nothing beyond the preconditioner's own S * xo. time_mask (nt,)
    bool restricts both to a time prefix (Newton's horizon). ``apply.matvec`` is J0. cache:
    see MaskedOperator (default: a new one)."""
    z = eq.z0[:, None] + y
    open_mask = z <= 0
    nt = y.shape[1]
    tm = np.ones(nt, bool) if time_mask is None else time_mask
    edges = np.linspace(0, nt, windows + 1).round().astype(int)
    cache = {} if cache is None else cache
    ops = [MaskedOperator(eq, open_mask, a, b, cache) for a, b in pairwise(edges)]

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

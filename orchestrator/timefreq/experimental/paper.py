"""EXPERIMENTAL: the paper's quasi-Newton scheme (§3, eq. 17-20; method "paper"; the route's
default is the march, orchestrator/timefreq/march.py).

y <- y - rho G^-1 g(y) on the whole-range residual g (problem.ContactEquation), G the order-0
stochastic linearisation of the Jacobian J: the active-set indicators I^+- replaced by their
time averages, globally or per window (restriction R_n, eq. 20). G per frequency: columns of
never-open nodes are k e_j (times 1 + O(eps)), so G is block lower-triangular: only the m x m
block of the nodes that open is factorised per frequency.

Measured failure points (benchmarks/timefreq.py --map, 21-node Winkler raft): it fails from
0.2 g with the paper's auxiliary stiffness (k = the local static soil stiffness, diverging on
the soil's high-frequency dashpots) and from 0.3 g with k = 30 K(0), the only setting found
to converge, slowly (linearly).
"""
from __future__ import annotations

import time
from itertools import pairwise
from dataclasses import dataclass

import numpy as np

from orchestrator.timefreq.problem import ContactEquation, Outcome, SolverStatus


@dataclass(frozen=True)
class PaperIteration:
    """One iteration: iter (from 1), residual |g| / |lam f| after it, n_open the most nodes
    that open in a window, wall_s."""
    iter: int
    residual: float
    n_open: int
    wall_s: float


def averaged_operators(eq: ContactEquation, y, windows=1):
    """AveragedOperator (list over windows) of the active set at y."""
    closed = (eq.z0[:, None] + y) > 0
    nt = y.shape[1]
    edges = np.linspace(0, nt, windows + 1).round().astype(int)
    return [AveragedOperator(eq, 1.0 - closed[:, a:b].mean(axis=1), a, b)
            for a, b in pairwise(edges)]


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
    """sum over the windows of G_n^-1 (R_n r)."""
    out = ops[0].solve(r)
    for o in ops[1:]:
        out += o.solve(r)
    return out


def paper_scheme(prob, rho=1.0, windows=1, tol=1e-6, max_iter=200, y0=None, lam=1.0,
                 diverge=1e3) -> Outcome:
    """The paper's quasi-Newton (eq. 17-20): y <- y - rho G_n^-1 g(y), G_n the order-0
    stochastic linearisation (averages over ``windows`` windows). DIVERGED once |g| passes
    ``diverge`` x its initial value. Returns an Outcome (history: PaperIteration)."""
    eq = ContactEquation(prob, lam)
    y = np.zeros_like(prob.f) if y0 is None else y0.copy()
    g = eq.residual(y)
    scale = eq.scale
    g0 = np.linalg.norm(g)
    hist = []
    for it in range(1, max_iter + 1):
        gn = np.linalg.norm(g)
        if gn <= tol * scale:
            return Outcome(y, SolverStatus.CONVERGED, tuple(hist))
        if not np.isfinite(gn) or gn > diverge * g0:
            return Outcome(y, SolverStatus.DIVERGED, tuple(hist),
                           f"the residual grew past {diverge:g} x its initial value")
        t0 = time.perf_counter()
        ops = averaged_operators(eq, y, windows)
        y = y - rho * precondition(ops, g)
        g = eq.residual(y)
        hist.append(PaperIteration(iter=it, residual=float(np.linalg.norm(g) / scale),
                                   n_open=int(max(o.n_open for o in ops)), wall_s=time.perf_counter() - t0))
    converged = np.linalg.norm(g) <= tol * scale
    return Outcome(y, SolverStatus.CONVERGED if converged else SolverStatus.NOT_CONVERGED, tuple(hist))

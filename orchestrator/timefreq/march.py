"""Causal time marching of the contact equation: the robust solver of the TF reference.

The interface stiffness S (operator) applied between the grid's windowed FFTs is the
discrete convolution p_n = sum_k h_k d_{n-k} with the kernel h_k = to_time(S)_k: the inverse
FFT of S at the grid's frequencies, window undone (grid). For lags k < nt it is S's causal
kernel (up to its alias wrap_tol h_{k + nfft}); on the periodic grid, where the whole-range
residual g (problem.ContactEquation) lives, every n < m also sees wrap_tol h_{nfft + n - m} d_m from later
times (the wrap-around), and a soil that is not causal on the grid adds its kernel's negative
lags (a BEM table continued by springs and dashpots above its last frequency: 10 % of the
rocking impedance at 4 Hz for the hysteretic reactor table, measured by truncating them).

A march solves the causal equations step by step, as the Newmark stepper does:

    kp max(0, delta0 - d_n) - P0 = h_0 d_n + H_n - lam f_n,   H_n = sum_{k>=1} h_k d_{n-k}

with a semi-smooth Newton on the N contact conditions of step n (full steps, the LU of
h_0 + kp I^+ cached per active set; damped on the step's convex energy if an active set comes
back), so no global iteration has to cross thousands of contact switches at once. The history
H_n is split at blocks of B steps: the near field (the same block) directly with the kernel
head h_1..h_{B-1} (step by step inside the innermost of nested sub-blocks (SUB), by one
matrix product from each finished sub-block to the rest of its parent), the far field
(earlier blocks) with one application of S per block, on the grid. Cost of a march: (nt / B) S
applications + nt B N^2 / 2 multiply-adds + one (N x N) LU per new active set.

``defect_correction`` feeds what the periodic grid adds back as a source, march after march,
to the whole-range residual's tolerance. h_0 must be positive definite (a step then has one
solution): true on the bilinear grid (the trapezoidal dashpot 2C/dt), not on the continuous
one, where h_0 is a band-limited dashpot with negative eigenvalues.
"""
from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla
from numpy.lib.stride_tricks import as_strided

from structure.contact import contact_force
from uplift_common.errors import ComputationError

from orchestrator.timefreq.farfield import AffineSplit, generic_far_field
from orchestrator.timefreq.problem import ContactEquation, Outcome, SolverStatus
from orchestrator.timefreq.soil import AffineBand, dense

#: |d| (m) past which a march has diverged (a soil whose causal part is not passive on the grid)
DIVERGED_M = 100.0

#: steps per block: the near field costs nt B N^2 / 2 multiply-adds, the far field nt / B
#: applications of S (on the reactor, N = 241, per sweep in CPU s with float64 marches: 64 with
#: (16, 4) 1.50, 80 with (20, 5) 1.51, 96 with (24, 6) 1.28 to 1.41, 112 with (28, 7) 1.37, 128
#: with (32, 8) 1.35; with single-precision corrections, whose near field costs half: 96 with
#: (24, 6) 0.79 to 0.84, with (24, 8) 0.77 to 0.87, 120 with (40, 8) 0.81 to 0.84, 128 with
#: (32, 8) 0.72 to 0.81, with (32, 8, 4) 0.78 to 0.82, 144 with (36, 9) 0.78 to 0.81)
BLOCK = 128
#: the near field's nested sub-blocks, outermost first (CausalSweep.run): step by step inside
#: the innermost, one matrix product from each finished sub-block to the rest of its parent;
#: SUB = (BLOCK,) is the plain step-by-step near field (the same sums in another order)
SUB = (32, 8)
#: the march's look-ahead (CausalSweep): the kernel's first negative lags held at the step's d;
#: on the reactor's table at 0.25 g the sweeps to a residual of 1e-6 go from 5 to 4 with 2
#: (residual after sweep 1: 1.3e-2 without, 4.8e-3 with 2, 3.8e-3 with 3 or more)
AHEAD = 2
#: defect_correction's marches in correction form with single-precision products (CausalSweep):
#: the history of the change from the previous march in float32, the previous march's history
#: and the step solves in float64; the fixed point stays the float64 residual's
SINGLE = True


def kernel_head(op, grid, n_lags: int, fold: bool = False, chunk: int = 8):
    """S's discrete kernel at its first lags, (n_lags, N, N) real (kernel_lags without the
    look-ahead lags)."""
    return kernel_lags(op, grid, n_lags, 0, fold, chunk)[0]


def kernel_lags(op, grid, n_lags: int, n_ahead: int = 0, fold: bool = False, chunk: int = 8):
    """S's discrete kernel at its first lags and first negative lags: (head (n_lags, N, N),
    ahead (n_ahead, N, N)) real, head = h_0 .. h_{n_lags-1}, ahead = h_{-1} .. h_{-n_ahead}
    (read at the end of the windowed period). With ``fold`` the head is the folded kernel
    h_c[k] = h_k - h_{-k} (k >= 1), h_c[0] = h_0 + 2 sum_{k>=1} h_{-k}, the negative lags -1
    .. -(nfft - nt) (the padding): the causal kernel with the same Im S(w) (the damping, so
    passive when S is) and the same static value. Truncating the negative lags instead
    changes Im S and can leave a non-passive causal part: the reactor's table (continued by
    springs and dashpots above 25 Hz) made the truncated march without look-ahead diverge from
    0.6 g, the folded one converges.

    Every step is linear per matrix entry: an affine band's K_ww = A + s B (a table's
    continuation above its last frequency, a Winkler soil) contributes A (x) a_k + B (x) b_k,
    a and b the kernels of the scalar series 1 and s on the band's frequencies, so only the
    dense bands and the rank-6 structure term go through an FFT per entry. ``chunk`` columns of
    S at a time, (N, chunk, F) complex arrays: ~35 MB each on the reactor at 8; at 24 (~100 MB
    each, fresh memory paged in per chunk) the reactor's head cost ~3.6 CPU s against ~2.8 (the
    same bits). A symmetric S (op.symmetric: a reciprocal soil) has a symmetric kernel: only
    the rows up to each chunk's last column are transformed (half the FFTs), the rest mirrored."""
    N, nt, nf = op.N, grid.nt, grid.nfft
    rows = np.arange(N)
    k = np.arange(1, nf - nt + 1)
    ka = np.arange(1, n_ahead + 1)

    def lags(X):                   # (..., F) -> the (folded) kernel (..., n_lags + n_ahead)
        hw = np.fft.irfft(X, n=nf, axis=-1)                                  # windowed period
        h = hw[..., :n_lags] * np.exp(grid.eta * grid.dt * np.arange(n_lags))
        a = hw[..., nf - ka] * np.exp(-grid.eta * grid.dt * ka)              # h_{-1} .. h_{-n_ahead}
        if fold:
            hn = hw[..., nf - k] * np.exp(-grid.eta * grid.dt * k)           # h_{-1}, h_{-2}, ...
            h[..., 1:] -= hn[..., :n_lags - 1]
            h[..., 0] += 2.0 * hn.sum(axis=-1)
        return np.concatenate([h, a], axis=-1)

    affine = [b for b in op.soil.bands if isinstance(b, AffineBand)]
    series = np.zeros((2 * len(affine), op.s.size), complex)
    for j, band in enumerate(affine):
        series[2 * j, band.idx] = 1.0
        series[2 * j + 1, band.idx] = op.s[band.idx]
    ab = lags(series) if affine else None                          # (2 m, n_lags + n_ahead)
    sym = op.symmetric()
    out = np.empty((n_lags + n_ahead, N, N))
    for c0 in range(0, N, chunk):
        cols = rows[c0:c0 + chunk]
        r = rows[:cols[-1] + 1] if sym else rows                  # a symmetric S: the upper triangle
        Sc = op.S_sub(r, cols, affine=False).transpose(1, 2, 0)              # (r, c, F), a view
        h = lags(Sc)                                                         # (r, c, lags)
        for j, band in enumerate(affine):
            A, B = (dense(M[r][:, cols]) if hasattr(M, "tocsr") else M[np.ix_(r, cols)] for M in band.ww())
            h += A[:, :, None] * ab[2 * j] + B[:, :, None] * ab[2 * j + 1]
        c1 = c0 + cols.size
        out[:, :r.size, c0:c1] = h.transpose(2, 0, 1)
        if sym and c0:
            out[:, c0:c1, :c0] = h[:c0].transpose(2, 1, 0)
    return out[:n_lags], out[n_lags:]


def _spd(M) -> bool:
    """M symmetric positive definite (a Cholesky factorisation succeeds)."""
    if np.abs(M - M.T).max() > 1e-12 * np.abs(M).max():
        return False
    try:
        np.linalg.cholesky(M)
    except np.linalg.LinAlgError:
        return False
    return True


class MarchDiverged(ComputationError, FloatingPointError):
    """A march whose contact displacements pass DIVERGED_M: the causal part of the soil on
    the grid is not passive (the kernel of a table that is not causal, truncated to its
    positive lags), and once the raft lifts off widely nothing holds it back."""

    def __init__(self, t, n_open):
        self.t, self.n_open = t, n_open
        super().__init__(f"the march diverged at t = {t:.3g} s ({n_open} nodes open)")


class StepSolver:
    """Step n's contact conditions r(d) = kp max(0, delta0 - d) - P0 - h_0 d - c = 0
    (c = H_n - lam f_n), -r the gradient of the strictly convex energy
    E(d) = d.h_0 d / 2 + (c + P0).d + kp |max(0, delta0 - d)|^2 / 2 when h_0 is symmetric
    positive definite. Semi-smooth Newton (Jacobian -(h_0 + kp I^+), LU cached per active set)
    with full steps, as the stepper's active-set iteration; if an active set comes back (a
    cycle), backtracking on E (on |r|^2 for a non-symmetric h_0)."""

    def __init__(self, h0, kp, delta0, P0, max_iter=50, cache=256):
        self.h0, self.kp, self.delta0, self.P0 = h0, kp, delta0, P0
        self.max_iter, self.cache_size = max_iter, cache
        self.lu: dict = {}
        self.n_factor = 0
        self.symmetric = np.abs(h0 - h0.T).max() <= 1e-12 * np.abs(h0).max()
        self.scale = float(np.abs(P0).max() + np.abs(h0).max() * np.abs(delta0).max()) or 1.0
        self._getrs = sla.get_lapack_funcs(("getrs",), (np.asarray(h0, float),))[0]

    def _lu_solve(self, lu, b):
        """scipy.linalg.lu_solve(lu, b) without its checks and wrappers (the same LAPACK getrs
        call, so the same bits, at a fraction of the ~50 us overhead it adds to each step)."""
        x, info = self._getrs(lu[0], lu[1], b)
        if info:
            raise ValueError(f"getrs: illegal value in argument {-info}")
        return x

    def residual(self, d, c):
        return contact_force(d, self.delta0, self.kp)[0] - self.P0 - self.h0 @ d - c

    def _merit(self, d, c, r):
        if self.symmetric:
            pen = np.maximum(0.0, self.delta0 - d)
            return 0.5 * d @ (self.h0 @ d) + (c + self.P0) @ d + 0.5 * self.kp @ (pen * pen)
        return r @ r

    def _factor(self, active):
        key = active.tobytes()
        lu = self.lu.get(key)
        if lu is None:
            J = self.h0.copy()
            J[np.diag_indices_from(J)] += self.kp * active
            lu = sla.lu_factor(J, check_finite=False)
            if len(self.lu) >= self.cache_size:
                self.lu.pop(next(iter(self.lu)))
            self.lu[key] = lu
            self.n_factor += 1
        return lu

    def solve(self, d, c, tol=1e-13):
        """d (N,) from the initial iterate d; returns (d, linear solves).

        Full semi-smooth Newton steps are the active-set iteration: solve
        (h_0 + kp I_A) d = kp I_A delta0 - P0 - c for the active set A of the last iterate
        until A repeats, exact then (no residual to evaluate). A set seen before is a cycle:
        the damped Newton below takes over."""
        active = self.delta0 - d > 0
        seen = set()
        for it in range(1, self.max_iter + 1):
            seen.add(active.tobytes())
            d = self._lu_solve(self._factor(active), self.kp * active * self.delta0 - self.P0 - c)
            new = self.delta0 - d > 0
            if np.array_equal(new, active):
                return d, it
            if new.tobytes() in seen:
                n, it0 = self._damped(d, c, tol)
                return n, it + it0
            active = new
        return self._damped(d, c, tol)

    def _damped(self, d, c, tol):
        """Semi-smooth Newton with Armijo backtracking on the energy (|r|^2 if h_0 is not
        symmetric) once an active set comes back."""
        r = self.residual(d, c)
        rn = np.linalg.norm(r)
        stop = tol * (self.scale * np.sqrt(d.size) + np.linalg.norm(c))
        for it in range(1, self.max_iter + 1):
            if rn <= stop:
                return d, it - 1
            dd = self._lu_solve(self._factor(self.delta0 - d > 0), r)
            m0 = self._merit(d, c, r)             # descent: dd = -J^-1 grad
            slope = -(r @ dd) if self.symmetric else -2.0 * (r @ r)
            t = 1.0
            while True:
                dn = d + t * dd
                rt = self.residual(dn, c)
                if self._merit(dn, c, rt) <= m0 + 1e-4 * t * slope or t < 1e-8:
                    break
                t *= 0.5
            d, r = dn, rt
            rn = np.linalg.norm(r)
        if rn <= 1e3 * stop:
            return d, self.max_iter
        raise FloatingPointError(f"the step's contact conditions did not converge (|r| = {rn:.3e} N)")


class CausalSweep:
    """The march's kernel head and step solver, kept from one sweep to the next (the LUs of
    h_0 + kp I^+ too).

    ahead : the look-ahead, the kernel's first negative lags h_{-1} .. h_{-ahead} added to h_0
    (the truncated kernel only): a table's non-causal part sum_{k>=1} h_{-k} d_{n+k} taken
    with the future d_{n+k} held at d_n instead of left to the defect correction, which then
    carries only h_{-k} (d_{n+k} - d_n) and what lies further. The march stays causal; the
    fixed point (the whole-range residual's) is the same. Skipped (self.ahead 0) if h_0 +
    sum h_{-k} is not symmetric positive definite like h_0.

    single : the march in correction form, its products in single precision (the truncated
    kernel with the split far field only). Each march keeps what it summed, X (its steps) and
    its history Hc_n = sum_{k>=1} h_k x_{n-k} (float64), and the next march sums only the
    change: c_n = c0_n + Hc_n + sum_{k>=1} h_k (x - X)_{n-k}, that last sum in float32 (the
    near field's products and the far field's dense band: float32 GEMMs and cspmv, about twice
    as fast as float64's). Its rounding error is relative to the change, which shrinks from one
    sweep to the next, and what the first march's rounding left in Hc is the same in every later
    march: the whole-range residual (float64) removes both, so the fixed point is the float64
    one (a plain float32 march instead has a rounding error of ~1e-7 of x in every march, and
    the residual stalled at ~5e-6 on the reactor)."""

    def __init__(self, prob, block: int = BLOCK, fold: bool = False, sub=SUB, ahead: int = AHEAD,
                 single: bool = False):
        t0 = time.perf_counter()
        self.prob, self.fold = prob, fold
        N, nt = prob.f.shape
        self.B = B = int(max(2, min(block, nt)))
        n_ahead = 0 if fold else int(max(0, min(ahead, prob.grid.nfft - nt)))
        split = None if fold else AffineSplit(prob.op, prob.grid)
        split = split if split is not None and split.usable else None
        # correction form in single precision: the split far field (AffineSplit) only
        self.single = bool(single) and split is not None
        self.dtype = np.float32 if self.single else float
        if self.single:                   # h_0 and the look-ahead in float64, the rest in float32
            (h0,), lags_ahead = split.kernel(1, n_ahead)
            head = split.kernel(B, 0, np.float32)[0]
        else:
            head, lags_ahead = split.kernel(B, n_ahead) if split is not None else \
                kernel_lags(prob.op, prob.grid, B, n_ahead, fold)
            h0 = head[0]
        self.far = split if split is not None else generic_far_field(prob.op, prob.grid)
        self.ahead = 0
        if n_ahead:
            h0a = h0 + lags_ahead.sum(axis=0)
            if _spd(h0a) or not _spd(h0):
                h0, self.ahead = h0a, n_ahead
        # the near field's nested sub-blocks (outermost first), each within [1, B]
        self.sizes = tuple(int(max(1, min(q, B))) for q in (sub if isinstance(sub, (tuple, list)) else (sub,)))
        leaf = self.sizes[-1] if self.sizes else B
        self.prev = None                   # (X, Hc) of the last march finished (single)
        # [h_1^T .. h_{B-1}^T] side by side (N, (B - 1) N): a finished sub-block's steps (rows of
        # x^T) times it give every later lag's contribution as rows (the cross products)
        self.hT = np.ascontiguousarray(head[1:].transpose(2, 0, 1).reshape(N, (B - 1) * N), self.dtype)
        # [h_1 .. h_{leaf-1}] side by side: the step-by-step products inside the innermost sub-block
        self.hflat = np.ascontiguousarray(head[1:leaf].transpose(1, 0, 2).reshape(N, (leaf - 1) * N), self.dtype)
        self.step = StepSolver(h0, prob.kp, prob.static.delta0, prob.P0)
        self.head_s = time.perf_counter() - t0

    def run(self, c0, progress=None, deadline=None):
        """The contact history x (N, nt): step n solves its contact conditions with
        c_n = c0_n + sum_{k>=1} h_k x_{n-k}, the near field (same block of B steps) from the
        kernel head, the far field (earlier blocks) by one S application per block on the
        grid. The near field in nested sub-blocks (``sizes``, outermost first): inside the
        innermost one step by step (h_1 .. h_{leaf-1}, small enough to stay in cache), and from
        each finished sub-block to the rest of its parent at once (``_cross``: one matrix
        product, the head read once per sub-block, not once per step). Returns (x, steps done,
        linear solves)."""
        g, op = self.prob.grid, self.prob.op
        N, nt = c0.shape
        nf = g.nfft
        B = self.B
        # (the nested sub-blocks are methods, not closures: a recursive closure is a reference
        # cycle that would hold this sweep's head and far field until the garbage collector runs)
        m = _MarchState(xT=np.zeros((nt, N)), near=np.zeros((nt, N), self.dtype), H=np.array(c0, float),
                        x=np.zeros(N))
        if self.single:                  # the products on the change from the last march
            prev, self.prev = self.prev, None
            m.src, m.C = np.zeros((nt, N), np.float32), np.empty((nt, N))
            m.base = np.zeros((nt, N)) if prev is None else prev[0]
            if prev is not None:
                m.H += prev[1].T
        else:
            m.src = m.xT
        xT, H = m.xT, m.H
        far_kw = {"single": True} if self.single else {}
        for a in range(0, nt, B):
            b = min(a + B, nt)
            self._level(m, a, b, 0)
            if b < nt and not self.fold:      # far field of this block, on the grid
                self.far(np.ascontiguousarray(m.src[a:b].T), a, b, H, **far_kw)
            elif b < nt:     # folded: sum_m (h_{n-m} - h_{m-n}) x_m, the second term from a
                X = np.zeros((2, N, nf))            # time-reversed copy at the period's end
                X[0, :, a:b] = xT[a:b].T
                X[1][:, (nf - np.arange(a, b)) % nf] = xT[a:b].T
                Y = g.to_time(op.apply_S(g.to_freq(X)), n=nf)
                H[:, b:] += Y[0][:, b:nt] - Y[1][:, nf - np.arange(b, nt)]
            if progress is not None:
                progress(b, nt)
            if not np.abs(xT[b - 1]).max() < DIVERGED_M:          # NaN included
                raise MarchDiverged((b - 1) * g.dt, int(np.sum(xT[b - 1] > self.step.delta0)))
            if deadline is not None and time.perf_counter() > deadline and b < nt:
                return np.ascontiguousarray(xT.T), b, m.solves
        if self.single:
            m.C -= c0.T                       # what the march summed: its history Hc
            self.prev = (xT, m.C)
        return np.ascontiguousarray(xT.T), nt, m.solves

    def _level(self, m, a, b, lev):
        """Steps [a, b) of a march (m: _MarchState) in sub-blocks of sizes[lev]."""
        while lev < len(self.sizes) and self.sizes[lev] >= b - a:
            lev += 1                           # (a level that does not split [a, b))
        if lev == len(self.sizes):
            return self._steps(m, a, b)
        q = self.sizes[lev]
        for s0 in range(a, b, q):
            s1 = min(s0 + q, b)
            self._level(m, s0, s1, lev + 1)
            if s1 < b:
                self._cross(m.src, m.near, s0, s1, b)

    def _steps(self, m, a, b):
        """The innermost sub-block [a, b), step by step: h_1..h_{n-a} on x_{n-1}..x_a."""
        N, hflat = m.x.size, self.hflat
        for n in range(a, b):
            c = m.H[:, n] + m.near[n]
            if n > a:
                c += hflat[:, :(n - a) * N] @ m.src[a:n][::-1].ravel()
            m.x, it = self.step.solve(m.x, c)
            m.xT[n] = m.x
            if self.single:
                m.C[n] = c
                m.src[n] = m.x - m.base[n]
            m.solves += it

    def _cross(self, xT, near, s0, s1, b):
        """near[t] += sum_{s0 <= s < s1} (h_{t-s} x_s)^T for the later steps t in [s1, b): one
        product of the finished steps with the head up to lag L = b - 1 - s0, Y (q, L N), row i
        (step s0 + i) holding every lag's contribution; target t takes lag t - s0 - i of row i,
        a diagonal of Y's blocks read as one strided view and summed over the q rows."""
        N, q, L = xT.shape[1], s1 - s0, b - 1 - s0
        Y = xT[s0:s1] @ self.hT[:, :L * N]
        # row i, target s1 + j: lag q + j - i at columns (q - 1 + j - i) N
        V = as_strided(Y[:, (q - 1) * N:], shape=(q, b - s1, N), strides=(Y.strides[0] - N * Y.itemsize,
                                                                            N * Y.itemsize, Y.itemsize))
        near[s1:b] += V.sum(axis=0)


def march(prob, lam: float = 1.0, block: int = BLOCK, progress=None, deadline: float | None = None,
          sweep: CausalSweep | None = None, source=None, ahead: int = 0):
    """Marched contact history of a ContactProblem at motion scale lam.

    Returns (d (N, nt) m, info dict); d is the dynamic relative displacement (raft trace minus
    soil, the unknown of problem.route_result); source (N, nt) N: a known force added to the
    equations (defect_correction); ahead: the look-ahead of a new sweep (CausalSweep; 0: the
    causal equations alone). info: newton (linear solves of the steps), factors
    (LUs), block, head_s, wall_s, steps (completed; < nt when the deadline (perf_counter
    time) stopped it: d is then zero beyond)."""
    t0 = time.perf_counter()
    sw = sweep or CausalSweep(prob, block, ahead=ahead)
    c0 = -lam * prob.f if source is None else -lam * prob.f - source
    d, done, solves = sw.run(c0, progress, deadline)
    info = dict(newton=int(solves), factors=int(sw.step.n_factor), block=sw.B, head_s=sw.head_s,
                wall_s=time.perf_counter() - t0, steps=int(done))
    return d, info


def y_from_d(prob, d):
    """The renormalised unknown y = z - z0 (problem) of a contact history d (N, nt)."""
    e = prob.static.delta0[:, None] - d
    np.divide(e, prob.eps[:, None], out=e, where=e > 0)        # z: e / eps where in contact (in place)
    e -= prob.z0[:, None]
    return e


@dataclass
class _MarchState:
    """A march in progress: xT (nt, N) the contact history so far, one step per row; near
    (nt, N) the near field, the same layout; H (N, nt) the source and the far field; x (N,) the
    last step's solution; solves, the linear solves so far; src (nt, N) what the history
    products read: xT, or in correction form (CausalSweep.single) the change x - base from the
    last march's steps base, in float32, with C (nt, N) each step's c (float64)."""
    xT: np.ndarray
    near: np.ndarray
    H: np.ndarray
    x: np.ndarray
    solves: int = 0
    src: np.ndarray | None = None
    base: np.ndarray | None = None
    C: np.ndarray | None = None


@dataclass(frozen=True)
class MarchSweep:
    """One sweep of ``defect_correction``.

    sweep : from 1; residual : |g| / |f| after it (NaN: the march did not finish); wall_s : s
    kernel : "truncated" | "folded" (kernel_head) | "stand-in" (a marcher's); diverged : the march passed DIVERGED_M (on
    the truncated kernel with fold "auto": the solve starts again on the folded one)
    newton, factors : the march's linear solves and LU factorisations; anderson : past
    residuals mixed into the next source
    """
    sweep: int
    residual: float
    wall_s: float
    kernel: str
    diverged: bool = False
    newton: int = 0
    factors: int = 0
    anderson: int = 0


def defect_correction(prob, lam=1.0, tol=1e-10, max_sweeps=60, depth=5, block=BLOCK, monitor=None,
                      deadline=None, fold=False, sub=SUB, stand_in=None, ahead=AHEAD, single=SINGLE) -> Outcome:
    """The whole-range equation g(y) = 0 (problem.ContactEquation) by marches.

    g = C + W: C the causal equations the march solves exactly, W(y) what the periodic grid
    adds (the wrap-around from later to earlier times, and a table's non-causal part). Sweep k
    solves C(y_k) = -W_{k-1} (the march with the source W_{k-1}); then g(y_k) = W(y_k) -
    W_{k-1}, so W_k = W_{k-1} + g(y_k) costs one residual. The fixed point W = W(y(W)) is
    accelerated by Anderson mixing of depth ``depth`` (a multisecant quasi-Newton method,
    GMRES on the linearised map, Walker & Ni 2011), restarted when the residual grows.
    fold : True, False or "auto": march on the folded kernel (kernel_head), for a soil that
    is not causal on the grid (a table): its causal part then keeps S's damping, so the march
    stays stable, and W carries the rest. Without it and without the look-ahead the reactor's
    table diverged from 0.6 g (the truncated kernel is not passive: with the raft lifted almost
    everywhere the free soil's response grew as e^{10 t}); with the look-ahead it converges
    there on the truncated kernel (7 sweeps, against 1 diverged + 5 folded). "auto" marches
    on the truncated kernel (cheaper: one S application per block instead of a pair: on the
    reactor at 0.25 g one more sweep, each cheaper, and less time in all) and starts again
    folded if a march diverges (a ``MarchSweep`` with ``diverged`` on the truncated kernel,
    then sweeps on the folded one).
    Measured (benchmarks/timefreq.py --map, --map-reactor): the 21-node Winkler raft (causal
    soil, no fold) from 0.1 to 1.0 g in <= 6 sweeps to 1e-10 (the wrap-around only).
    monitor : callable(sweep, residual) after each sweep; deadline : perf_counter time past which the best
    iterate is returned, STOPPED; block, sub : CausalSweep's blocks and near-field sub-blocks
    (an int or nested sizes, outermost first).
    stand_in : a ContactProblem on the same grid and static state whose causal kernel the march
    steps instead of prob's (a causal soil standing in for the table, e.g. its rational fit);
    or a marcher, any object with ``march(lam, source, deadline) -> (d (N, nt), info)`` (info:
    newton, factors, steps; MarchDiverged when it cannot go on) that solves a causal stand-in's
    contact equations with the source added (the native stepper on the table's constrained fit:
    orchestrator/standin.py). The residual, and so the fixed point, stay prob's: a stand-in
    changes the sweeps (their count: the linear rate rho(S_x^-1 (S - S_x))), not the answer.
    ahead : the truncated kernel's look-ahead (CausalSweep; 0: the plain causal kernel); it
    changes the sweeps, not the fixed point.
    single : the marches in correction form with single-precision products (CausalSweep); it
    changes the sweeps' cost, not the fixed point.

    Returns an Outcome (history: one MarchSweep per sweep)."""
    marcher = stand_in if hasattr(stand_in, "march") else None
    marched = prob if stand_in is None or marcher is not None else stand_in
    if marcher is None:
        sweep = CausalSweep(marched, block, fold is True, sub, ahead, single)
        split = sweep.far if stand_in is None and isinstance(sweep.far, AffineSplit) else None
    else:
        # the residual's split alone (no kernel head: the march is the stand-in's), built in a
        # thread beside the first march (a native marcher releases the interpreter's lock; on the
        # reactor the split is ~1 CPU s, a native march ~0.3): the same split, whatever the timing
        sweep, split, built = None, None, {}

        def build():
            try:
                built["split"] = AffineSplit(prob.op, prob.grid)
            except BaseException as exc:     # raised again in the solve's thread
                built["error"] = exc
        builder = threading.Thread(target=build, name="uplift-split", daemon=True)
        builder.start()
    eq = None

    def equation():
        nonlocal eq, split
        if eq is None:
            if marcher is not None:
                builder.join()
                if "error" in built:
                    raise built["error"]
                split = built["split"] if built["split"].usable else None
            # the residual's S through the split when it is prob's (a table's K then not formed)
            eq = ContactEquation(prob, lam, split.apply if split is not None else None)
        return eq
    hist = []
    W = np.zeros_like(prob.f)
    mix = _Anderson(depth)                # Anderson: past maps G(W) = W + g and residuals g
    best = None
    y = np.zeros_like(prob.f)

    def kernel():
        return "stand-in" if marcher is not None else "folded" if sweep.fold else "truncated"

    def ended(status, reason=""):
        return Outcome(best[1] if best else y, status, tuple(hist), reason,
                       residual=best[0] if best else None)

    for k in range(1, max_sweeps + 1):
        t0 = time.perf_counter()
        try:
            with np.errstate(over="ignore", invalid="ignore"):
                if marcher is not None:
                    d, info = marcher.march(lam, W, deadline)
                else:
                    d, info = march(prob, lam, sweep=sweep, source=W, deadline=deadline)
        except MarchDiverged as exc:
            hist.append(MarchSweep(k, math.nan, time.perf_counter() - t0, kernel(), diverged=True))
            if fold == "auto" and marcher is None and not sweep.fold:      # start again on the folded kernel
                sweep = CausalSweep(marched, block, True, sub)
                W, mix, best = np.zeros_like(prob.f), _Anderson(depth), None
                continue
            return ended(SolverStatus.DIVERGED, str(exc))
        if info["steps"] < prob.grid.nt:
            hist.append(MarchSweep(k, math.nan, time.perf_counter() - t0, kernel()))
            return ended(SolverStatus.STOPPED, "time budget")
        y = y_from_d(prob, d)
        g = equation().residual(y)
        r = float(np.linalg.norm(g) / eq.scale)
        hist.append(MarchSweep(k, r, time.perf_counter() - t0, kernel(), newton=info["newton"],
                               factors=info["factors"], anderson=mix.size))
        if monitor is not None:
            monitor(k, r)
        if best is None or r < best[0]:
            best = (r, y)
        elif r > 2 * best[0]:
            mix = _Anderson(depth)         # the mixing went astray: restart from this iterate
        if r <= tol:
            return Outcome(y, SolverStatus.CONVERGED, tuple(hist), residual=r)
        if deadline is not None and time.perf_counter() > deadline:
            return ended(SolverStatus.STOPPED, "time budget")
        W = mix.next(W, g)
    return ended(SolverStatus.NOT_CONVERGED)            # a sweep at tol returned above


class _Anderson:
    """defect_correction's Anderson mixing of depth ``depth``: ``next(W, g)`` -> the next source
    from the last ``depth + 1`` maps G = W + g and residuals g (the plain step W + g for the
    first). The differences of successive maps and residuals are kept as they come (each formed
    once, not again at every sweep: the same numbers in the same order as forming them all
    from the kept maps); ``size``: the residuals kept. The mixing coefficients solve the least
    squares problem min |g - dF gam| by its normal equations on dF's columns scaled to unit norm
    (an m x m system, m <= depth, from dot products of the kept differences: no stacked copies),
    directions of the scaled Gram matrix below 1e-13 of its largest cut (columns dependent to
    ~3e-7): on the reactor a solve's mixing takes 0.06 s CPU against 0.1-0.15 s with the
    differences formed again and stacked at every sweep and the SVD of the tall dF (lstsq, ~0.1 s
    of it), the residuals the same to 5 digits and max uplift 3e-13 relative apart (the
    coefficients change the sweeps, not the fixed point)."""

    def __init__(self, depth: int):
        self.depth, self.size = int(depth), 0
        self.G = self.F = None
        self.dG, self.dF = [], []

    def next(self, W, g):
        G, F = W + g, g
        if self.F is not None:
            self.dG.append(G - self.G)
            self.dF.append(F - self.F)
            self.dG, self.dF = self.dG[-self.depth:], self.dF[-self.depth:]
        self.G, self.F = G, F
        self.size = min(self.size + 1, self.depth + 1)
        if not self.dF:
            return G
        # the Gram matrix and dF^T g by dot products of the kept differences (no stacked copies)
        dF = [d.ravel() for d in self.dF]
        m = len(dF)
        Gram = np.empty((m, m))
        for a in range(m):
            for b in range(a, m):
                Gram[a, b] = Gram[b, a] = dF[a] @ dF[b]
        scale = np.sqrt(np.diag(Gram))
        scale = np.where(scale > 0.0, scale, 1.0)
        rhs = np.array([d @ F.ravel() for d in dF]) / scale
        gam = np.linalg.lstsq(Gram / np.outer(scale, scale), rhs, rcond=1e-13)[0] / scale
        out = G.copy()
        for c, d in zip(gam, self.dG):
            out -= c * d
        return out

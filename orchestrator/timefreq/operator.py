"""The structure-soil system condensed on the contact: d -> contact force, per frequency.

Unknowns in the frequency domain (Laplace variable s, see grid): raft q (6), soil w (N),
and the fixed-base modal coordinates eta of the structure. The structure is condensed on q
exactly with *all* its fixed-base modes (massless DOFs are condensed statically in the modes,
exact for the lumped masses; the damping must be diagonal in the modes: modal or Rayleigh):

    u_struct = T q + Phi eta,   (s^2 + c_j s + w_j^2) eta_j = -L_j (a_g + s^2 q)   (L = Phi^T M T)
    A_q(s) q = s^2 M_T q - s^4 L^T D^-1 L q,    load b(s) a_g = -(M_T - s^2 L^T D^-1 L)[:, :3] a_g

In the contact coordinates x = [q, w] -> [q, d], d = Bq q - w (raft vertical trace minus soil
w, the contact's relative displacement), with P = [I; Bq] and the soil K(s) on [q, w]:

    Z_qq q - Vl d = b a_g,       -Vr q + K_ww d = p
    Z_qq = A_q + P^T K P,  Vr = K[w, :] P,  Vl = P^T K[:, w]

so the contact force p (dynamic, on the raft +Bq^T p, on the soil -p) and d satisfy
p = S d - f with the interface dynamic stiffness S = K_ww - Vr Z_qq^-1 Vl (N x N) and the
blocked force f = Vr Z_qq^-1 b a_g. Z_qq is the raft bonded to the soil (regular at s -> 0);
S is applied as K_ww (the soil's bands) minus a rank-6 term; it is never formed for all N.

The per-frequency work (batched products and inverses, numpy/BLAS calls that release the GIL)
may run on a ``WorkerPool``: each frequency is computed alone, whatever the split, so the
result does not depend on the thread count.
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from functools import cached_property
from itertools import pairwise

import numpy as np
from scipy.linalg import LinAlgError, eigh

from structure import damping_matrix, fixed_base_modes

from orchestrator.timefreq.setup_cache import band_rows
from orchestrator.timefreq.soil import AffineBand, MatrixBand, Scratch, dense

#: frequencies per chunk below which a band is not split between threads
MIN_CHUNK = 8


class WorkerPool:
    """``threads`` workers for the operator's per-frequency tasks, the calling thread being one
    of them (threads = 1: everything inline, no thread started). Its threads live until
    ``close()``: use it as a context manager around one solve.

    The solves default to options.THREADS; a bare operator (pool None) runs inline. The answer
    is the same to the last bit for any thread count (each frequency is computed alone)."""

    def __init__(self, threads: int = 1):
        if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 1:
            raise ValueError(f"threads = {threads!r} must be a positive integer (worker threads, 1: none)")
        self.threads = int(threads)
        self._executor = ThreadPoolExecutor(self.threads - 1) if self.threads > 1 else None
        self._closed = False

    def __enter__(self) -> WorkerPool:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Stop the worker threads (waits for running tasks)."""
        if self._executor is not None:
            self._executor.shutdown(wait=True)
        self._closed = True

    def chunks(self, n: int) -> list:
        """Slices splitting range(n) into one part per thread (fewer if the parts would be
        shorter than MIN_CHUNK)."""
        parts = max(1, min(self.threads, n // MIN_CHUNK))
        edges = [n * i // parts for i in range(parts + 1)]
        return [slice(a, b) for a, b in pairwise(edges)]

    def run(self, tasks) -> list:
        """Results of the callables ``tasks``, the first on the calling thread."""
        if self._closed:
            raise RuntimeError("the worker pool is closed: the operator was used after its solve ended")
        if len(tasks) == 1 or self._executor is None:
            return [t() for t in tasks]
        futs = [self._executor.submit(t) for t in tasks[1:]]
        first = tasks[0]()
        return [first] + [f.result() for f in futs]


def _span(idx):
    """The frequency indices idx as a slice when they are a contiguous range (a band of a
    table or of a Winkler soil), else unchanged."""
    if idx.size and idx[-1] - idx[0] + 1 == idx.size and (idx.size == 1 or np.all(np.diff(idx) == 1)):
        return slice(int(idx[0]), int(idx[-1]) + 1)
    return idx


class ModalStructure:
    """Fixed-base modal data of a StructureModel: w (m,) rad/s, c (m,) 1/s (= 2 xi w), Phi
    (n_struct, m), L (m, 6), M_T (6, 6) rigid-body mass about the raft centre."""

    def __init__(self, model, damping=None):
        modes = fixed_base_modes(model)
        Phi = modes.shapes
        C = damping_matrix(model, damping)
        Cm = Phi.T @ C @ Phi
        c = np.diag(Cm).copy()
        off = np.abs(Cm - np.diag(c)).max() if c.size else 0.0
        if off > 1e-8 * max(np.abs(c).max(), 1e-30):
            raise ValueError("the structural damping is not diagonal in the fixed-base modes (an explicit "
                             "damping matrix?): the frequency-domain routes need modal or Rayleigh damping")
        T = model.rigid_transform
        KT = model.stiffness @ T
        if np.abs(KT).max() > 1e-9 * max(abs(model.stiffness).max(), 1.0):
            raise ValueError("the structure has springs to the ground (K T != 0): the frequency-domain "
                             "condensation assumes the structure is supported by the raft only")
        m = model.mass
        self.w = modes.omega
        self.c = c
        self.Phi = Phi
        self.T = T
        self.L = Phi.T @ (m[:, None] * T)
        self.MT = T.T @ (m[:, None] * T)

    @property
    def decay_rates(self) -> np.ndarray:
        return 0.5 * self.c

    def blocks(self, s):
        """A_q (F, 6, 6) and b (F, 6, 3) at the Laplace variables s (F,)."""
        s2 = s * s
        Dinv = 1.0 / (s2[:, None] + self.c * s[:, None] + self.w**2)        # (F, m)
        LL = np.einsum("fj,ja,jb->fab", Dinv, self.L, self.L)               # (F, 6, 6)
        A = s2[:, None, None] * self.MT - (s2 * s2)[:, None, None] * LL
        b = -(self.MT[:, :3] - s2[:, None, None] * LL[:, :, :3])
        return A, b

    def node_response(self, dofs, s, q, ag):
        """Relative displacement (3, F) at the global DOFs ``dofs`` (3,) for raft q (6, F) and
        ground acceleration ag (3, F)."""
        s2 = s * s
        Dinv = 1.0 / (s2[:, None] + self.c * s[:, None] + self.w**2)        # (F, m)
        force = self.L[:, :3] @ ag + self.L @ (s2[None, :] * q)             # (m, F)
        eta = -Dinv.T * force
        return self.T[dofs] @ q + self.Phi[dofs] @ eta


class InterfaceOperator:
    """S(s), f(s) and the back-substitution of the condensed system on one Grid.

    Parameters
    ----------
    model : StructureModel, or a PlateRaftModel (its raft coordinates [q, t]: flexible)
    soil : SoilBands                 K(s) on [q, w] (soil.soil_bands)
    grid : Grid
    damping : None | float | Damping structural damping (see structure.damping_matrix)
    structure : ModalStructure       the model's modal data if already built (a plate: its
                                     PlateStructure, required: flexible.structure_of)
    pool : WorkerPool                threads for the per-frequency work (default: none)
    cache_dir : folder or None       where the set-up is kept (setup_cache: a table's band rows
                                     here, the far field's split, farfield.AffineSplit); None: not kept
    """

    def __init__(self, model, soil, grid, damping=None, structure: ModalStructure | None = None,
                 pool: WorkerPool | None = None, cache_dir=None):
        if soil.n != 6 + model.n_interface:
            raise ValueError(f"the soil has {soil.n} DOFs, the raft needs 6 + N = {6 + model.n_interface}")
        self.model, self.soil, self.grid = model, soil, grid
        self.cache_dir = cache_dir
        self.pool = pool or WorkerPool(1)
        if structure is None and hasattr(model, "plate"):
            raise ValueError("a plate raft's operator needs its PlateStructure: pass structure="
                             "orchestrator.timefreq.flexible.structure_of(model, damping)")
        self.st = structure or ModalStructure(model, damping)
        self.N = model.n_interface
        s = grid.s
        self.s = s
        # the raft coordinates' trace: a rigid raft's Bq (N, 6), a plate's B (N, 6 + nf) (flexible)
        Bq = self.st.trace if hasattr(self.st, "trace") else model.raft.vertical_trace()
        self.Bq = Bq
        self.nr = nr = Bq.shape[1]
        F = s.size
        A, b = self.st.blocks(s)
        self.b = b
        self.Vr = np.empty((F, self.N, nr), complex)
        self.Vl = np.empty((F, nr, self.N), complex)
        Zqq = A.copy()
        for band in soil.bands:
            i = _span(band.idx)
            out = (self.Vr[i], self.Vl[i]) if isinstance(i, slice) else None   # views: written in place
            Vr, Vl, KPP = band_rows(band, s[i], Bq, out, table=getattr(soil, "table", None), cache_dir=cache_dir)
            if out is None:
                self.Vr[i], self.Vl[i] = Vr, Vl
            Zqq[i] += KPP
        self.Zqq = Zqq
        self.Zinv = np.linalg.inv(Zqq)
        self.n_apply = 0

    @cached_property
    def ZV(self):
        """Zqq^-1 Vl (F, 6, N), for the users of S's rank-6 term as a product of two (formed when
        first asked for: applying S does not need it)."""
        return self.Zinv @ self.Vl

    # ---- the interface stiffness -----------------------------------------------------------
    def apply_S(self, X):
        """X (N, F) or (r, N, F) complex -> S X, same shape (r vectors share one pass over the
        bands, which are read from memory once)."""
        self.n_apply += 1
        X3 = X if X.ndim == 3 else X[None]
        Xf = np.ascontiguousarray(np.transpose(X3, (2, 1, 0)))             # (F, N, r)
        Y = np.empty_like(Xf)

        def band_task(band, sel):
            def run():
                i = _span(band.idx if sel is None else band.idx[sel])     # a slice: views, no copies
                Y[i] = self._apply(band, i, Xf[i], sel)
            return run

        tasks = []
        for band in self.soil.bands:
            if isinstance(band, MatrixBand) and len(self.soil.bands) == 1:
                band.form()                 # here, once, if formed on demand (not by every thread)
                tasks += [band_task(band, h) for h in self.pool.chunks(band.idx.size)]
            else:
                tasks.append(band_task(band, None))
        self.pool.run(tasks)
        Y = np.transpose(Y, (2, 1, 0))
        return Y if X.ndim == 3 else Y[0]

    def _apply(self, band, i, X, sel=None):
        """S X for X (m, N, r) on the frequencies i (a slice or indices) of ``band`` (its part
        sel; None: all of it)."""
        Y = band.apply_ww(X, self.s[i]) if sel is None else band.apply_ww(X, self.s[i], sel)
        Y -= self.Vr[i] @ (self.Zinv[i] @ (self.Vl[i] @ X))
        return Y

    def groups(self, size: int) -> list:
        """[(band, sel)]: every band's frequencies in groups of at most ``size`` (an affine band:
        one group), for a solve that takes the frequencies a group at a time (``pieces``)."""
        return [(band, sel) for band in self.soil.bands for sel in band.groups(size)]

    def pieces(self, groups):
        """For each (band, sel) of ``groups``: (i, apply, matrix) on its frequencies i (a slice
        or indices, m of them), apply(X (m, N, r)) = S X and matrix(j) = S (m_j, N, N) on the
        group's frequencies j (a slice), the band's matrices formed once per group (a table's
        spline band: into one work array, reused by the next group: use a piece before asking
        for the next). A generator: one per thread."""
        scratch = Scratch()
        allN = np.arange(self.N)
        for band, sel in groups:
            piece = band.piece(sel, scratch)
            i = _span(piece.idx)

            def matrix(j, piece=piece, i=i):
                k = np.arange(self.s.size)[i][j]
                S = piece.sub_ww(allN, allN, self.s[i], j)
                S -= self.Vr[k] @ (self.Zinv[k] @ self.Vl[k])
                return S
            yield i, (lambda X, piece=piece, i=i: self._apply(piece, i, X)), matrix

    def symmetric(self, rtol: float = 1e-12) -> bool:
        """S(s) = S(s)^T at every frequency to rtol of its largest entry (a reciprocal soil:
        symmetric bands, Vr = Vl^T, Zqq symmetric), checked once; a table's band on its own
        matrices when they are exactly symmetric (its matrices at the grid are not formed)."""
        if not hasattr(self, "_symmetric"):
            def sym(M):              # (..., n, n): one matrix at a time (in cache), exact first
                M = dense(M) if hasattr(M, "toarray") else M
                M3 = M.reshape((-1,) + M.shape[-2:])
                if all(np.array_equal(m, m.T) for m in M3):
                    return True
                tol = rtol * np.abs(M3).max(initial=0.0)
                return all(np.abs(m - m.T).max(initial=0.0) <= tol for m in M3)
            bands = all((band.symmetric_by_construction() or sym(band.ww())) if isinstance(band, MatrixBand)
                        else all(sym(M) for M in band.ww()) for band in self.soil.bands)
            # Vr against Vl^T a few frequencies at a time (no (F, N, 6) temporaries to page in)
            gap = max((np.abs(self.Vr[i:i + 64] - self.Vl[i:i + 64].swapaxes(1, 2)).max(initial=0.0)
                       for i in range(0, self.Vr.shape[0], 64)), default=0.0)
            rank6 = gap <= rtol * np.abs(self.Vr).max(initial=0.0)
            self._symmetric = bool(bands and rank6 and sym(self.Zqq))
        return self._symmetric

    def sub_inverse(self, O):
        """SubInverse: S[O, O]^-1 per frequency, applied to (m, F) arrays."""
        return SubInverse(self, np.asarray(O))

    def S_sub(self, rows, cols, affine: bool = True):
        """S[rows, cols] (F, m_r, m_c); affine False: without the affine bands' K_ww (A + s B,
        whose kernel march.kernel_head forms from two scalar series instead)."""
        F = self.s.size
        out = np.empty((F, rows.size, cols.size), complex)
        for band in self.soil.bands:
            if affine or not isinstance(band, AffineBand):
                out[band.idx] = band.sub_ww(rows, cols, self.s[band.idx])
            else:
                out[band.idx] = 0.0
        out -= self.Vr[:, rows] @ (self.Zinv @ self.Vl[:, :, cols])
        return out

    def blocked_force(self, ag_hat):
        """f (N, F) for ground acceleration ag_hat (3, F)."""
        t = self.Zinv @ (self.b @ ag_hat.T[:, :, None])
        return (self.Vr @ t)[:, :, 0].T

    def raft(self, ag_hat, d_hat):
        """q (6, F) from the ground motion (3, F) and the contact displacement d (N, F) (a plate:
        its raft coordinates r = [q, t], (6 + nf, F))."""
        rhs = self.b @ ag_hat.T[:, :, None] + self.Vl @ np.ascontiguousarray(d_hat.T)[:, :, None]
        return (self.Zinv @ rhs)[:, :, 0].T


class SubInverse:
    """S[O, O](s)^-1 on every frequency. Dense bands: batched inverses (the operator's pool). Affine
    bands (K_ww = A + s B, A and B real symmetric, B positive definite): K_OO^-1 = V (L + s)^-1
    V^T from one generalized eigendecomposition A V = B V L (V^T B V = I) for all the band's
    frequencies, and the structure's rank-6 term by the Woodbury identity
    S_OO^-1 = K^-1 + K^-1 Vr (Zqq - Vl K^-1 Vr)^-1 Vl K^-1 (Vr, Vl restricted to O)."""

    def __init__(self, op, O):
        self.O, self.parts, self.pool = O, [], op.pool
        m = O.size
        for band in op.soil.bands:
            idx = band.idx
            s = op.s[idx]
            if isinstance(band, AffineBand):
                Aw, Bw = band.ww()
                A = dense(Aw)[np.ix_(O, O)]
                B = dense(Bw)[np.ix_(O, O)]
                try:
                    if np.abs(A - A.T).max() > 1e-12 * np.abs(A).max() or \
                            np.abs(B - B.T).max() > 1e-12 * max(np.abs(B).max(), 1e-300):
                        raise LinAlgError("not symmetric")
                    lam, V = eigh(A, B)
                except (LinAlgError, ValueError):
                    pass
                else:
                    d = 1.0 / (lam[:, None] + s[None, :])                    # (m, Fb)
                    Vr = op.Vr[idx][:, O, :]                                 # (Fb, m, 6)
                    Y6 = self._kinv(V, d, np.ascontiguousarray(Vr.transpose(1, 0, 2)), op.nr)
                    Y6 = np.ascontiguousarray(Y6.transpose(1, 0, 2))         # (Fb, m, 6)
                    Vl = np.ascontiguousarray(op.Vl[idx][:, :, O])           # (Fb, 6, m)
                    Minv = np.linalg.inv(op.Zqq[idx] - Vl @ Y6)
                    self.parts.append(("eig", idx, (V, d, Y6, Minv @ Vl)))
                    continue
            G = np.empty((idx.size, m, m), complex)
            band.form()                     # here, once, if formed on demand (not by every thread)
            ZV = op.ZV

            def inv(sel, band=band, idx=idx, s=s, G=G):
                i = idx[sel]
                Gs = band.sub_ww(O, O, s, sel) - op.Vr[i][:, O] @ (ZV[i][:, :, O])
                G[sel] = np.linalg.inv(Gs)
            self.pool.run([lambda h=h: inv(h) for h in self.pool.chunks(idx.size)])
            self.parts.append(("dense", idx, G))

    @staticmethod
    def _kinv(V, d, X, r):
        """V diag(d) V^T X for X (m, Fb, r) complex -> (m, Fb, r)."""
        m, Fb = d.shape
        Xr = np.ascontiguousarray(X).view(float).reshape(m, -1)
        T = (V.T @ Xr).view(complex).reshape(m, Fb, r) * d[:, :, None]
        return (V @ np.ascontiguousarray(T).view(float).reshape(m, -1)).view(complex).reshape(m, Fb, r)

    def apply(self, R):
        """R (m, F) -> S_OO^-1 R per frequency."""
        out = np.empty_like(R)

        def task(kind, idx, data):
            def run():
                Ri = R[:, idx]
                if kind == "dense":
                    out[:, idx] = (data @ np.ascontiguousarray(Ri.T)[:, :, None])[:, :, 0].T
                else:
                    V, d, Y6, MVl = data
                    u = self._kinv(V, d, Ri[:, :, None], 1)[:, :, 0]         # (m, Fb)
                    t = MVl @ np.ascontiguousarray(u.T)[:, :, None]          # (Fb, 6, 1)
                    out[:, idx] = u + (Y6 @ t)[:, :, 0].T
            return run

        tasks = []
        for kind, idx, data in self.parts:
            if kind == "dense" and len(self.parts) == 1:
                tasks += [task(kind, idx[h], data[h]) for h in self.pool.chunks(idx.size)]
            else:
                tasks.append(task(kind, idx, data))
        self.pool.run(tasks)
        return out

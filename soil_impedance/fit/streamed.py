"""The fit of a table read in blocks (``blocked.BlockedTable``): ``StreamedProblem``, the same least
squares as ``target.Problem`` without holding the table (docs/formulation.md, "The fit's memory").

``Problem`` holds the table, its scaled copy S K S, the causal target, the upper-triangle columns X and
the model's response: five to seven arrays of the table's size (F (6+N)² complex: 0.6 GB each at 600
nodes and 101 frequencies). ``StreamedProblem`` holds the frequencies, the DOF scaling S, the hysteretic
offset H0 (n²), per-frequency norms, the rigid-raft projections Pᵀ K P (F × 6 × 6) and the compressed
columns Y (F × ≤ 24), and reads the table block by block (``BLOCK`` × ``BLOCK`` entries across all
frequencies, upper triangle) for each pass:

* construction: two passes (the row maxima and diagonals that give S; then the target's norms, the
  rigid-raft projections and the R factor of the columns, by a tall-skinny QR of the stacked blocks, on
  one BLAS thread: ``uplift_common.blas.single_threaded_blas``, see below);
* the compressed columns from that R: [Re X; Im X] = Rᵀ Qᵀ, so the SVD of Rᵀ gives the singular values
  and the combinations Y = X V of ``vectfit.compress`` without forming V (same singular values, the
  combinations up to their signs, which vector fitting does not see);
* per fitted order: one pass for the residues (one QR of the fixed-pole basis, applied to each block;
  a second one when E must be projected on the PSD cone) and one for the per-frequency error;
* per model (criterion, report): one pass evaluating the model on each block.

What stays whole: the model's coefficients, (m + 2) (6+N)² doubles (the residues of a dense history are
that size), and its passivity test and enforcement (``passivity``: they work on the coefficients, never
on the table; at m · (6+N) above ``passivity.MAX_PENCIL`` the test is the certified sweep, whose working
set is the G(ν) of up to 64 frequencies, capped at ``passivity.CHUNK_BYTES``). The results equal
``Problem``'s up to round-off: the sums run in another order (per block), the compressed columns come
from a QR instead of an SVD.
"""
from __future__ import annotations

import numpy as np

from uplift_common.blas import single_threaded_blas

from ..rational import FitError, RationalModel
from ..vectfit import real_basis, vector_fit, initial_poles, canonical_poles
from .options import POLE_CAP, RIGID, WEIGHTINGS
from .target import causal_cutoff, entry_weighted_coefficients, hysteretic_part

#: block edge (entries) of the streamed passes when the file is not chunked by frequency (else its chunk
#: edge, at most ``blocked.CHUNK`` = 128: aligned reads): a block is F × BLOCK² complex (26 MB at 101 frequencies)
BLOCK = 128
#: columns kept by the compression (as ``vectfit.compress``)
MAX_COLUMNS, COMPRESS_RTOL = 24, 1e-8


class _Frequencies:
    """Ks[k] (scaled, (n, n)) read on demand for ``hysteretic_part`` and ``causal_cutoff``."""

    def __init__(self, table, S):
        self.table, self.S, self._got = table, S, {}

    def __getitem__(self, k):
        if k not in self._got:
            K = self.table.frequency(int(k))
            self._got[k] = K * self.S[:, None] * self.S[None, :]
        return self._got[k]


class StreamedProblem:
    """``target.Problem`` of a ``BlockedTable``: the same attributes f, S, idx, f_c, w_ref, s, band,
    w_rel, w, Y, weighting, table, and the passes the fit needs (``coefficients``, ``order_error``,
    ``response_errors``, ``model``, ``report_errors``). P : the rigid-raft projection (n, 6) of a gap
    table, or None: its projections of the table and of the causal target are taken in the first pass.
    """

    streamed = True

    def __init__(self, table, weighting, f_causal_hz, P=None, block=None):
        if weighting not in WEIGHTINGS:
            raise FitError(f"weighting {weighting!r} unknown: use one of {WEIGHTINGS}")
        f = table.frequencies_hz
        if f.size < 4:
            raise FitError(f"table has {f.size} frequencies: a rational fit needs at least 4 (recompute the sweep)")
        block = block or getattr(table, "chunk", None) or BLOCK        # the file's chunks: aligned reads
        if block < len(RIGID):
            raise FitError(f"block = {block}: at least {len(RIGID)} (the rigid DOFs in one block)")
        self.table, self.f, self.block, self.weighting = table, f, int(block), weighting
        n = table.n_dof
        F = f.size
        # pass 1: row maxima and diagonals (table_scaling)
        rowmax, diag = np.zeros(n), np.empty((F, n), complex)
        for r, c in table.blocks(self.block):
            K = table.block(r, c)
            a = np.abs(K).max(axis=0)
            rowmax[r] = np.maximum(rowmax[r], a.max(axis=1))
            rowmax[c] = np.maximum(rowmax[c], a.max(axis=0))
            if r == c:
                diag[:, r] = np.einsum("fii->fi", K)
        self.idx = np.nonzero(rowmax > 0)[0]
        if self.idx.size == 0:
            raise FitError("table is identically zero: nothing to fit")
        active = rowmax > 0
        d = np.abs(diag[0].real)
        fallback = np.max(np.abs(diag), axis=0)
        d = np.where(d > 1e-9 * fallback, d, fallback)
        # a DOF whose row is zero (a gap table's horizontal rows) gets S = 0: its entries are zero in
        # every pass, as Problem leaves it out; Sd is S with 1 there (a safe divisor)
        self.S = np.where(active, 1.0 / np.sqrt(np.where(active, d, 1.0)), 0.0)
        self.Sd = np.where(active, self.S, 1.0)
        self.Ks = _Frequencies(table, self.S)                 # Ks[k] on demand (a few frequencies)
        self.f_c = causal_cutoff(table, self.Ks, f_causal_hz)
        self.H0 = hysteretic_part(f, self.Ks) if self.f_c > 0 else None
        self.w_ref = 2 * np.pi * f[-1]
        self.s = 1j * 2 * np.pi * f / self.w_ref
        self.band = f >= self.f_c
        self.P = P
        # pass 2: norms, projections, the R factor of the stacked columns [Re X; Im X]
        t2, k2, u2 = np.zeros(F), np.zeros(F), np.zeros(F)
        xmax = 0.0
        R = np.zeros((0, 2 * F))
        if P is not None:
            self.rigid_raw = np.zeros((F, 6, 6), complex)       # Pᵀ K P
            self.rigid_target = np.zeros((F, 6, 6), complex)    # Pᵀ (causal target, SI) P
        # the tall-skinny QRs, per block (BLOCK² + 2F) × 2F, on one BLAS thread: thin panels, where a second
        # thread buys little and, on a loaded 2-core machine, spins waiting for a busy core. The set-up of the
        # 2506-DOF mat's table took 4.5-8 CPU min on two OpenBLAS threads, 70 % of it these QRs (34 s on one
        # idle thread); at 1207 DOFs and 21 frequencies the QRs took 7.4 CPU s (15.5 s wall) on two threads and
        # 0.7 CPU s (3.1 s wall) on one. R then differs from a two-thread run's by round-off (2.8e-14 of its
        # largest entry there; the norms and rigid-raft projections, no QR, are the same bits)
        with single_threaded_blas():
            for r, c, K, Ks, T, sel in self._passes(raw=True):
                wgt = 1.0 if r == c else 2.0
                t2 += wgt * _sq(T)
                k2 += wgt * _sq(Ks)
                u2 += wgt * _sq(K)
                X = T[:, sel[0], sel[1]] * sel[2]
                xmax = max(xmax, float(np.abs(X).max()))
                R = np.linalg.qr(np.vstack([R, np.concatenate([X.real, X.imag]).T]), mode="r")
                if P is not None:
                    Tu = T / self.Sd[r, None] / self.Sd[None, c]
                    for out, A in ((self.rigid_raw, K), (self.rigid_target, Tu)):
                        out += _project(P[r], A, P[c])
                        if r != c:
                            out += _project(P[c], A.transpose(0, 2, 1), P[r])
        self.R = R                                            # [Re X; Im X] [Re X; Im X]ᵀ = Rᵀ R (``search_orders``)
        self.norm_target, self.norm_Ks, self.norm_K = np.sqrt(t2), np.sqrt(k2), np.sqrt(u2)
        self.w_rel = 1.0 / np.maximum(self.norm_target, 1e-300)
        self.w = self.w_rel if weighting != "uniform" else np.full(F, 1.0 / xmax)
        self.Y = self._compress(R)

    # ---- the passes ----------------------------------------------------------------------------
    def _passes(self, raw=False):
        """Per upper-triangle block: (rows, cols, K or None, Ks, target, (i, j, ew)): the block's raw, scaled
        and causal-target matrices (F, r, c) and its upper-triangle entries (local indices, weights √2
        off the diagonal, as ``Problem``'s columns)."""
        S, f = self.S, self.f
        low = f < self.f_c
        fade = ((1 - f[low] / self.f_c) ** 2) if self.f_c > 0 else None
        for r, c in self.table.blocks(self.block):
            K = self.table.block(r, c)
            Ks = K * S[r, None] * S[None, c]
            if not raw:
                del K
                K = None
            T = Ks
            if self.f_c > 0:
                T = Ks.copy()
                T[low] = T[low] - 1j * fade[:, None, None] * self.H0[None, r, c]
            yield r, c, K, Ks, T, self._entries(r, c)

    def _entries(self, r, c):
        nr, nc = r.stop - r.start, c.stop - c.start
        if r != c:
            i, j = np.divmod(np.arange(nr * nc), nc)
            return i, j, np.full(i.size, np.sqrt(2.0))
        i, j = np.triu_indices(nr)
        return i, j, np.where(i == j, 1.0, np.sqrt(2.0))

    def _compress(self, R):
        """``vectfit.compress`` of the columns whose stacked [Re X; Im X] (2F × M) is Rᵀ Qᵀ."""
        F = self.f.size
        D = np.concatenate([self.w_rel, self.w_rel])
        u, sv, _ = np.linalg.svd(R.T * D[:, None] if R.shape[0] else np.zeros((2 * F, 0)), full_matrices=False)
        q = int(min(MAX_COLUMNS, np.sum(sv > COMPRESS_RTOL * sv[0])))
        Z = (u[:, :q] * sv[:q]) / D[:, None]                  # [Re; Im] of X V, unweighted
        return Z[:F] + 1j * Z[F:]

    def _basis_solver(self, poles, linear):
        A = real_basis(self.s, poles, const=True, linear=linear) * self.w[:, None]
        Ar = np.concatenate([A.real, A.imag])
        col = np.linalg.norm(Ar, axis=0)
        col[col == 0] = 1.0
        Q, Rr = np.linalg.qr(Ar / col)
        return np.linalg.lstsq(Rr, Q.T, rcond=None)[0] / col[:, None]    # the basis' least-squares inverse, once per order

    def _solve_block(self, solver, poles, X, linear):
        """Coefficients (nb, q) of the columns X (F, q): ``Problem._solve`` on one block."""
        if self.weighting != "entry":
            WX = self.w[:, None] * X
            return solver @ np.concatenate([WX.real, WX.imag])
        return entry_weighted_coefficients(self.s, X, poles, linear)

    def coefficients(self, poles, error=False):
        """The coefficient matrices (nb, n, n) (symmetric; ``Problem.coefficients`` as matrices: its
        columns divided by their √2 weights), E projected on the PSD cone unless a Cholesky factorisation
        on the active DOFs proves it positive definite (an eigendecomposition of the whole E finds
        round-off negative eigenvalues, -1e-15, on a gap table's zero rows: a second pass for nothing). ``error``: also
        ``order_error(poles, C)``, summed in the same pass as the coefficients (each block is read once
        per order, not once more for the error; the same sums in the same order: the same value)."""
        n, m = self.table.n_dof, poles.size
        C = np.zeros((m + 2, n, n))
        solver = self._basis_solver(poles, True)
        B = real_basis(self.s, poles) if error else None
        num = np.zeros(self.f.size)
        for r, c, _, _, T, (i, j, ew) in self._passes():
            X = _columns(T, r, c, i, j)
            cb = self._solve_block(solver, poles, X * ew, True) / ew
            _put(C, slice(None), r, c, i, j, cb)
            if error:                                          # cb: the values just put in C
                num += _sq((B @ cb - X) * ew)
        act = np.nonzero(self.S > 0)[0]
        lam, vec = (None, None) if _definite(C[-1][np.ix_(act, act)]) else np.linalg.eigh(C[-1])
        if lam is not None and lam[0] < 0:
            Ep = (vec * np.maximum(lam, 0)) @ vec.T
            C[-1] = np.triu(Ep) + np.triu(Ep, 1).T          # Problem keeps the upper triangle
            solver = self._basis_solver(poles, False)
            num = np.zeros(self.f.size)
            for r, c, _, _, T, (i, j, ew) in self._passes():
                ep = Ep[r.start + i, c.start + j] * ew
                X = _columns(T, r, c, i, j)
                cb = self._solve_block(solver, poles, X * ew - self.s[:, None] * ep[None], False) / ew
                _put(C, slice(None, -1), r, c, i, j, cb)
                if error:                                      # C's column: cb and the projected E's entries
                    num += _sq((B @ np.concatenate([cb, C[-1:, r.start + i, c.start + j]]) - X) * ew)
        if not error:
            return C
        err = np.sqrt(num) / np.maximum(self.norm_target, 1e-300)
        return C, float(err[self.band].max())

    def search_orders(self, n_pairs, n_iter, provenance=None, first=1):
        """Orders of the order search at once, ``first`` to ``n_pairs`` pole pairs, in one or two passes
        over the table instead of one or two per order: per order (poles, max band error, the rigid-raft
        model Pᵀ K P (6 × 6 ``RationalModel`` of the order's model before its rigid-raft correction, or
        None without P)), the poles, errors and rigid-raft models of ``fit_order_streamed`` and
        ``model`` up to round-off; no coefficients are formed (``coefficients`` fits them for an order).

        The residues are linear in the table: an order's coefficients are Z X̃ (Z = the basis'
        least-squares inverse with the row weights, (nb, 2F); X̃ = [Re X; Im X], (2F, M) the target's
        columns), so

        * its error needs only X̃ X̃ᵀ = Rᵀ R (``__init__``'s tall-skinny QR): the residuals are
          M X̃ with M = B̃ Z − I, their per-frequency sums of squares the rows of (M Rᵀ)²: no pass;
        * its rigid-raft model needs only Pᵀ K_target P (``rigid_target``): Pᵀ C_b P = Σ Z_bf Pᵀ X̃_f P;
        * its E (one row of Z applied to every entry) is the one thing read from the table: one pass
          gives every order's E, (n_pairs, n, n) doubles. An E with a negative eigenvalue is projected
          on the PSD cone (Ep = E − E₋, E₋ its negative eigenpairs; a Cholesky factorisation proves
          the others PSD without an eigensolution) and its order re-solved without the s column on
          X̃ − s̃ epᵀ: the residual's sums of squares are those of M' (Rᵀ R − g s̃ᵀ − s̃ gᵀ + ‖ep‖² s̃ s̃ᵀ) M'ᵀ
          with g = X̃ ep = Rᵀ R z_E − X̃ e₋: a second pass, for every such order at once, sums X̃ e₋.

        Not for the "entry" weighting (each column its own weights): ``fit_order_streamed`` per order."""
        import scipy.linalg
        if self.weighting == "entry":
            raise FitError("search_orders: the entry weighting fits each column alone: use fit_order_streamed")
        n, F = self.table.n_dof, self.f.size
        wt = np.concatenate([self.w, self.w])
        st = np.concatenate([self.s.real, self.s.imag])       # s̃, the E column of the stacked basis
        RT = self.R.T
        orders = []
        for pairs in range(first, n_pairs + 1):
            poles = order_poles(self, pairs, n_iter)
            B = real_basis(self.s, poles)
            orders.append((poles, np.concatenate([B.real, B.imag]), self._basis_solver(poles, True) * wt))
        # pass: every order's E
        zE = np.array([Z[-1] for _, _, Z in orders])              # (K, 2F)
        E = np.zeros((len(orders), n, n))
        for r, c, _, _, T, (i, j, _) in self._passes():
            X = _columns(T, r, c, i, j)
            _put(E, slice(None), r, c, i, j, zE @ np.concatenate([X.real, X.imag]))
        act = np.nonzero(self.S > 0)[0]
        Ps = np.where(self.S[:, None] > 0, self.P / self.Sd[:, None], 0.0) if self.P is not None else None
        RTs = None if Ps is None else np.concatenate([self.rigid_target.real, self.rigid_target.imag])
        neg = {}                                                    # order: (‖e₋‖², Pᵀ E₋ P); E[k] becomes E₋
        for k in range(len(orders)):
            Ea = E[k][np.ix_(act, act)]
            if _definite(Ea):
                continue                                            # positive definite: as fitted
            lam, V = scipy.linalg.eigh(Ea, subset_by_value=(-np.inf, 0.0))
            keep = lam < 0
            if not keep.any():
                continue
            lam, V = lam[keep], V[:, keep]
            PV = None if Ps is None else Ps[act].T @ V
            neg[k] = (float(np.sum(lam ** 2)), None if Ps is None else (PV * lam) @ PV.T)   # ‖e₋‖², Pᵀ E₋ P
            del Ea
            E[k] = 0.0
            E[k][np.ix_(act, act)] = (V * lam) @ V.T
        gneg = {k: np.zeros(2 * F) for k in neg}
        if neg:                                                     # pass: X̃ e₋ of the projected orders
            for r, c, _, _, T, (i, j, ew) in self._passes():
                X = _columns(T, r, c, i, j) * (ew * ew)
                for k in neg:
                    en = E[k][r, c].reshape(-1) if r != c else E[k][r.start + i, c.start + j]
                    g = X @ en
                    gneg[k] += np.concatenate([g.real, g.imag])
        del E
        self.projected = [first - 1 + k for k in sorted(neg)]       # the orders (0-based) whose E was projected
        out = []
        for k, (poles, Bt, Z) in enumerate(orders):
            m = poles.size
            M = Bt @ Z - np.eye(2 * F)
            e2 = np.sum((M @ RT) ** 2, axis=1)                      # residuals M X̃ of the order as fitted
            rigid = None if Ps is None else np.tensordot(Z, RTs, axes=1)
            if k in neg:
                # E projected: the residues re-solved on X̃ − s̃ epᵀ, ep = e − e₋, are Z' (X̃ − s̃ eᵀ) + Z' s̃ e₋ᵀ,
                # and Z' (X̃ − s̃ eᵀ) are the order's own (least squares with e fixed at its optimum): the
                # residuals are M X̃ + (M' s̃) e₋ᵀ, no difference of large terms
                ne2, PEP = neg[k]
                Zs = (self._basis_solver(poles, False) * wt) @ st
                Ms = Bt[:, :-1] @ Zs - st
                e2 = e2 + 2 * Ms * (M @ gneg[k]) + ne2 * Ms ** 2
                if rigid is not None:
                    rigid[:m + 1] += Zs[:, None, None] * PEP[None]
                    rigid[m + 1] -= PEP
            err = np.sqrt(np.maximum(e2[:F] + e2[F:], 0.0)) / np.maximum(self.norm_target, 1e-300)
            if rigid is not None:
                rigid[:m] *= self.w_ref
                rigid[m + 1] /= self.w_ref
                rigid = RationalModel.from_coefficients(poles * self.w_ref, 0.5 * (rigid + rigid.transpose(0, 2, 1)),
                                                        RIGID, provenance)
            out.append((poles, float(err[self.band].max()), rigid))
        return out

    def order_error(self, poles, C) -> float:
        """Max over the band of the relative Frobenius error of the fit ``C`` to the target
        (``target.fit_order``'s: the upper triangle, √2 weights)."""
        B = real_basis(self.s, poles)
        num = np.zeros(self.f.size)
        for r, c, _, _, T, (i, j, ew) in self._passes():
            res = (B @ C[:, r.start + i, c.start + j] - T[:, i, j]) * ew
            num += _sq(res)
        err = np.sqrt(num) / np.maximum(self.norm_target, 1e-300)
        return float(err[self.band].max())

    def model(self, poles, C, provenance):
        """Unscaled, full-size RationalModel (``Problem.model``)."""
        m = poles.size
        mats = C.copy()
        mats[:m] *= self.w_ref
        mats[m + 1] /= self.w_ref
        mats /= self.Sd[None, :, None]
        mats /= self.Sd[None, None, :]
        mats = 0.5 * (mats + mats.transpose(0, 2, 1))
        off = self.S == 0
        mats[:, off] = 0.0
        mats[:, :, off] = 0.0
        return RationalModel.from_coefficients(poles * self.w_ref, mats, self.table.dofs, provenance)

    # ---- the model against the table -----------------------------------------------------------
    def _model_passes(self, model):
        s = 2j * np.pi * self.f
        inv = 1.0 / (s[:, None] - model.poles[None, :])
        for r, c, K, Ks, _, _ in self._passes(raw=True):
            Km = model.D[None, r, c] + s[:, None, None] * model.E[None, r, c] \
                + (inv @ model.residues[:, r, c].reshape(inv.shape[1], -1)).reshape(s.size, r.stop - r.start, c.stop - c.start)
            yield r, c, K, Ks, Km

    def response_errors(self, model) -> np.ndarray:
        """Per frequency, the relative Frobenius error of the scaled model against S K S (F,)."""
        num = np.zeros(self.f.size)
        for r, c, _, Ks, Km in self._model_passes(model):
            num += (1.0 if r == c else 2.0) * _sq(Km * self.S[r, None] * self.S[None, c] - Ks)
        return np.sqrt(num) / np.where(self.norm_Ks > 0, self.norm_Ks, 1.0)

    def report_errors(self, model):
        """(scaled errors (F,), unscaled errors (F,), {dof block: (err² (F,), own² (F,))}) for the report
        (``pipeline._report``'s e_t, e_un and its blocks rigid / rigid-w / w of ``target.dof_blocks``)."""
        F = self.f.size
        num, un = np.zeros(F), np.zeros(F)
        parts = {k: [np.zeros(F), np.zeros(F)] for k in ("rigid", "rigid-w", "w")}
        nr = len(RIGID)
        gap = list(self.table.dofs[:nr]) == list(RIGID) and self.table.n_dof > nr
        for r, c, K, Ks, Km in self._model_passes(model):
            D = Km * self.S[r, None] * self.S[None, c] - Ks
            dd, oo = np.abs(D) ** 2, np.abs(Ks) ** 2
            wgt = 1.0 if r == c else 2.0
            num += wgt * dd.reshape(F, -1).sum(axis=1)
            un += wgt * _sq(Km - K)
            if not gap:
                continue
            gi = np.arange(r.start, r.stop)[:, None]
            gj = np.arange(c.start, c.stop)[None, :]
            masks = {"rigid": (gi < nr) & (gj < nr), "rigid-w": (gi < nr) & (gj >= nr),
                     "w": (gi >= nr) & (gj >= nr)}
            for k, mk in masks.items():
                if mk.any():
                    mult = 2.0 if (k == "w" and r != c) else 1.0
                    parts[k][0] += mult * dd[:, mk].sum(axis=1)
                    parts[k][1] += mult * oo[:, mk].sum(axis=1)
        e_t = np.sqrt(num) / np.where(self.norm_Ks > 0, self.norm_Ks, 1.0)
        e_un = np.sqrt(un) / np.where(self.norm_K > 0, self.norm_K, 1.0)
        return e_t, e_un, (parts if gap else None)

    def hysteretic_floor(self) -> float:
        """``target.hysteretic_floor`` from the frequencies it reads."""
        if self.f_c <= 0:
            return 0.0
        return float(1.1 * 0.5 * np.linalg.norm(self.H0) / max(np.linalg.norm(self.Ks[0].real), 1e-300))


def _definite(A) -> bool:
    """True when a Cholesky factorisation proves the symmetric A positive definite (its E kept as fitted)."""
    try:
        np.linalg.cholesky(A)
    except np.linalg.LinAlgError:
        return False
    return True


def _columns(T, r, c, i, j) -> np.ndarray:
    """T[:, i, j] (F, entries): an off-diagonal block's entries are all of it, row-major (a view)."""
    return T.reshape(T.shape[0], -1) if r != c else T[:, i, j]


def _put(C, rows, r, c, i, j, cb) -> None:
    """C[rows] at a block's upper-triangle entries (local i, j, as ``_entries``) and at their mirror
    images: an off-diagonal block (every entry, row-major) by slices, a diagonal one by indices."""
    if r != c:
        blk = cb.reshape(cb.shape[0], r.stop - r.start, c.stop - c.start)
        C[rows, r, c] = blk
        C[rows, c, r] = blk.transpose(0, 2, 1)
        return
    C[rows, r.start + i, c.start + j] = cb
    C[rows, c.start + j, r.start + i] = cb


def _project(Pa, A, Pb) -> np.ndarray:
    """Pa^T A_f Pb per frequency (F, 6, 6) of a complex block A (F, r, c) and real Pa (r, 6), Pb (c, 6):
    real products on the real and imaginary parts (BLAS; a complex einsum over the block is ~30x slower)."""
    return (Pa.T @ A.real @ Pb) + 1j * (Pa.T @ A.imag @ Pb)


def _sq(A) -> np.ndarray:
    """Per frequency, the sum of |A|² over the block (F,)."""
    return (A.real ** 2 + A.imag ** 2).reshape(A.shape[0], -1).sum(axis=1)


def order_poles(prob: StreamedProblem, n_pairs, n_iter) -> np.ndarray:
    """The poles of the order of ``n_pairs`` pole pairs (``target.fit_order``'s): vector fitting of the
    compressed columns, poles above ``POLE_CAP`` dropped."""
    poles = vector_fit(prob.s, prob.Y, prob.w_rel, initial_poles(n_pairs, 1.0), n_iter=n_iter)
    keep = np.abs(poles) <= POLE_CAP
    return canonical_poles(poles[keep])


def fit_order_streamed(prob: StreamedProblem, n_pairs, n_iter):
    """``target.fit_order`` on a ``StreamedProblem``."""
    poles = order_poles(prob, n_pairs, n_iter)
    C, err = prob.coefficients(poles, error=True)
    return poles, C, err

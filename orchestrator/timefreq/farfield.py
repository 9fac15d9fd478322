"""The march's far field: what a finished block of contact displacements adds to the later steps.

The generic way (``generic_far_field``) is one application of S on the grid: the block's d
zero-padded, windowed FFT, S per frequency, inverse FFT. On a table that reads the dense band
(~250 MB on the reactor) and multiplies the affine band's A and B with the block's spectrum on
every frequency above the table (858 frequencies on the reactor, ~40 % of the application).

``AffineSplit`` computes the same sum with the soil's springs and dashpots K_inf = A + s B (the
affine band's) taken on *all* frequencies: S = K_inf + D - R6_hi, where D = S - K_inf on the
dense band's frequencies (K_ww - Vr Zqq^-1 Vl - A - s B, the rank-6 structure term folded in;
zero above) and R6_hi the rank-6 term above the table, Vr Zqq^-1 Vl with Vr and Vl affine in s
there (products with 6 or 12 columns, no band-sized arrays). On the bilinear grid K_inf's
periodic kernel is closed form: A at lag 0 only, and s_d = (2/dt)(z - 1)/(z + 1) has h_0 =
(2/dt)(1 + r)/(1 - r) and h_k = (4/dt)(-1)^k / (1 - r) for 0 < k < nfft, r = (-1)^nfft
e^{-eta nfft dt} (the alternating tail of the trapezoidal rule's velocity, wrapped around the
period). So K_inf's far field from a block [a, b) is the rank-one update (-1)^n c B sum_m
(-1)^m d_m for n >= b, N^2 multiply-adds, and only D and R6_hi go through the FFTs. A
symmetric S keeps D's upper triangles packed (BLAS packed storage, read by zspmv: half the
bytes). The same sums in another order: equal to round-off. The kernel head comes from the
same split (``AffineSplit.kernel``).
"""
from __future__ import annotations

from functools import cached_property

import numpy as np
from scipy.linalg.blas import cspmv, zspmv

from orchestrator.timefreq.operator import _span
from orchestrator.timefreq.setup_cache import entry_path, read_mapped, setup_key, write_mapped
from orchestrator.timefreq.soil import AffineBand, MatrixBand, dense, upper_pairs

#: |h_k - c (-1)^k| <= ALTERNATING_RTOL |c| over the lags 1 .. nt-1 for the closed form to be used
ALTERNATING_RTOL = 1e-10


def generic_far_field(op, grid):
    """far(x_block, a, b, H): H[:, b:] += (S * x_block)[:, b:] for the block x[:, a:b] (N, b - a),
    by one application of S on the grid."""
    N, nt = op.N, grid.nt

    def far(xb, a, b, H):
        X = np.zeros((N, nt))
        X[:, a:b] = xb
        H[:, b:] += grid.to_time(op.apply_S(grid.to_freq(X)))[:, b:]
    return far


class AffineSplit:
    """The far field with the affine band taken on all frequencies (module notes). ``usable``
    tells whether the soil and grid allow it: one AffineBand, the other bands dense, the
    bilinear grid (checked on s's kernel itself).

    The dense bands' D and whether S is symmetric (its packing) are kept in the operator's cache
    folder (``op.cache_dir``; setup_cache, ``tf-split``), keyed on the table's data, the bands,
    the grid's s, the raft's trace and Zqq^-1: a second split of the same inputs maps them
    (``read_mapped``: the same bits, read-only) instead of making them again."""

    def __init__(self, op, grid):
        self.op, self.grid = op, grid
        bands = op.soil.bands
        affine = [b for b in bands if isinstance(b, AffineBand)]
        # a plate raft's structure term has rank 6 + nf (op.nr): the generic far field
        self.usable = grid.bilinear and len(affine) == 1 and op.nr == 6 and \
            all(isinstance(b, (AffineBand, MatrixBand)) for b in bands)
        if not self.usable:
            return
        nt = grid.nt
        sig = grid.to_time(op.s, n=nt)                      # the kernel of s on the grid
        alt = (-1.0) ** np.arange(nt)
        c = -sig[1] if nt > 1 else 0.0
        if nt > 1 and not np.abs(sig[1:] - c * alt[1:]).max() <= ALTERNATING_RTOL * abs(c):   # NaN: no
            self.usable = False
            return
        self.c, self.alt = c, alt
        band = affine[0]
        self.hi = _span(band.idx)
        self.s_hi = op.s[band.idx]
        Aw, Bw = band.ww()
        self.Aw, self.Bw = Aw, Bw
        (VrA, VlA, _), (VrB, VlB, _) = band.rows_P_parts(op.Bq)
        self.VrAB, self.VlAB = np.hstack([VrA, VrB]), np.vstack([VlA, VlB])  # (N, 12), (12, N)
        self.Zinv_hi = op.Zinv[self.hi]
        N = op.N
        matrix = [b for b in bands if isinstance(b, MatrixBand)]
        path = entry_path(getattr(op, "cache_dir", None), "split", setup_key(
            "split", getattr(op.soil, "table", None), [(type(b).__name__, b.idx, getattr(b, "W", None)) for b in bands],
            op.s, np.asarray(op.Bq, float), op.Zinv))
        kept = read_mapped(path, [f"D{k}" for k in range(len(matrix))], attrs=("packed",))
        if kept is not None:
            self.packed = bool(kept[1]["packed"])
            self.upper = upper_pairs(N) if self.packed else None
            shapes = [(b.idx.size, N * (N + 1) // 2) if self.packed else (b.idx.size, N, N) for b in matrix]
            if [D.shape for D in kept[0]] == shapes:
                self.dense = list(zip((b.idx for b in matrix), kept[0]))
                return
        Ad, Bd = dense(Aw), dense(Bw)
        # a symmetric S: D's upper triangles packed column by column (BLAS 'U' packed storage:
        # half the bytes per application, read by zspmv; the head's DFT on half the entries)
        self.packed = op.symmetric()
        self.upper = upper_pairs(N) if self.packed else None
        self.dense = [(b.idx, self._dense_part(op, b, Ad, Bd, self.upper)) for b in matrix]
        write_mapped(path, {f"D{k}": D for k, (_, D) in enumerate(self.dense)}, {"packed": self.packed})

    @staticmethod
    def _dense_part(op, band, A, B, upper=None, chunk=16):
        """S - (A + s B) on a dense band's frequencies: K_ww - Vr Zqq^-1 Vl - A - s B, (Fb, N, N)
        complex, or with ``upper`` (row and column indices of the upper triangle, column by
        column) its packed upper triangles (Fb, N (N + 1) / 2): A and B gathered on them, K_ww's
        from the band's packed_ww (the whole band in one call, written into D itself), the
        rank-6 term's by ``packed_product`` (the (m, N, N) product is not formed: 0.26 -> 0.06 s
        on the reactor); the rest ``chunk`` frequencies at a time (no band-sized temporaries)."""
        idx, s = band.idx, op.s[band.idx]
        N = A.shape[0]
        if upper is None:
            K = band.ww()
            D = np.empty((idx.size, N, N), complex)
            R = np.empty((min(chunk, idx.size), N, N), complex)
        else:
            at = upper[0] * N + upper[1]                             # the upper triangle in an (N, N) array
            A, B = A.ravel()[at], B.ravel()[at]
            D = np.empty((idx.size, at.size), complex)
        # the chunk's temporaries allocated once (fresh band-sized memory per chunk is paged in
        # by the kernel each time: ~0.4 s of system time on the reactor)
        tmp = np.empty((min(chunk, idx.size),) + D.shape[1:], complex)
        if upper is not None:
            # K_ww's upper triangles on the whole band at once (a table's: one product of the
            # spline's weights with its packed matrices, which are then read once instead of once
            # per chunk: 0.31-0.62 -> 0.18-0.20 s CPU on the reactor; equal to round-off)
            band.packed_ww(slice(None), D)
        for j0 in range(0, idx.size, chunk):
            j = slice(j0, j0 + chunk)
            f = idx[j]
            m = f.size
            Dj, tj = D[j], tmp[:m]
            if upper is None:
                np.subtract(K[j], np.matmul(op.Vr[f], op.ZV[f], out=R[:m]), out=Dj)   # minus the rank-6 term
            else:
                Dj -= packed_product(op.Vr[f], op.ZV[f], tj)
            Dj -= A
            np.multiply(s[j].reshape((-1,) + (1,) * (Dj.ndim - 1)), B, out=tj)
            Dj -= tj
        return D

    def kernel(self, n_lags: int, n_ahead: int = 0, dtype=float):
        """S's grid kernel (kernel_lags without fold, to round-off) from the split: (head
        (n_lags, N, N), ahead (n_ahead, N, N)), h_0 .. h_{n_lags-1} and h_{-1} .. h_{-n_ahead}.
        A at lag 0 and B times s's scalar kernel; D by a direct inverse DFT restricted to the
        dense bands' frequencies (one GEMM over all N^2 entries); the rank-6 term above the
        table from its affine parts and three 6 x 6 kernels of Zqq^-1, s Zqq^-1, s^2 Zqq^-1.
        dtype np.float32: the products and the result in single precision (D's complex64 copy:
        the head of a march in correction form, CausalSweep.single)."""
        op, g = self.op, self.grid
        nf, F = g.nfft, op.s.size
        k = np.arange(n_lags)
        ka = np.arange(1, n_ahead + 1)
        n = np.concatenate([k, nf - ka])                                    # grid indices
        w = np.exp(g.eta * g.dt * np.concatenate([k, -ka]))                 # the window undone
        f = np.arange(F)
        c = np.where((f == 0) | (2 * f == nf), 1.0, 2.0) / nf                # irfft's weights
        E = c[:, None] * np.exp(2j * np.pi * np.outer(f, n) / nf) * w       # (F, L): h = Re(E^T X)
        cast = lambda a: np.asarray(a, dtype)                               # (float64: no copy)
        L = n.size
        N = op.N
        if self.packed:                                   # each (i, j)'s place in the packed triangle
            i, j = self.upper
            pos = np.empty((N, N), np.intp)
            pos[i, j] = pos[j, i] = np.arange(i.size)
        # every term added in place, lag by lag (no (L, N, N) temporaries: fresh memory is paged
        # in by the kernel, ~0.2 s of system time for each on the reactor)
        out = None
        for idx, D in self.dense32 if np.dtype(dtype) == np.float32 else self.dense:
            h = np.real(np.tensordot(E[idx].astype(D.dtype), D, axes=(0, 0)))
            if self.packed:
                h = np.take(h, pos.ravel(), axis=1).reshape(L, N, N)      # a new array
            if out is None:
                out = h if self.packed else np.array(h)
            else:
                out += h
        if out is None:
            out = np.zeros((L, N, N), dtype)
        sig = cast(np.real(E.T @ op.s))                                     # s's kernel (L,)
        e0 = cast(np.real(E.sum(axis=0)))                                   # delta_0, to round-off
        Eh, sh = E[self.hi], self.s_hi
        Z = [np.real(np.tensordot(Eh, self.Zinv_hi * sh[:, None, None] ** j, axes=(0, 0))) for j in range(3)]
        VM = cast(self.VrAB @ np.block([[Z[0], Z[1]], [Z[1], Z[2]]]))      # (L, N, 12)
        Ad, Bd, Vl = cast(dense(self.Aw)), cast(dense(self.Bw)), cast(self.VlAB)
        for lag in range(L):
            o = out[lag]
            o += sig[lag] * Bd
            o += e0[lag] * Ad
            o -= VM[lag] @ Vl
        return out[:n_lags], out[n_lags:]

    def apply(self, X):
        """S X for X (N, F) complex, through the split: K_inf X + (S - K_inf) X (the same sums as
        the far field's; op.apply_S's to round-off, without the dense band's K, which a table's
        band then never forms)."""
        self.op.n_apply += 1
        Y = np.empty_like(X)
        self._beyond_inf(X, Y)
        # A and B are real: their products on X's floats (real GEMMs, A and B not cast to complex:
        # 0.053 -> 0.030 s per application on the reactor; equal to round-off)
        if all(np.issubdtype(M.dtype, np.floating) for M in (self.Aw, self.Bw)):
            Xf = _real_view(X)
            Y += np.ascontiguousarray(self.Aw @ Xf).view(complex)
            Y += self.op.s * np.ascontiguousarray(self.Bw @ Xf).view(complex)
        else:
            Y += self.Aw @ X
            Y += self.op.s * (self.Bw @ X)
        return Y

    @cached_property
    def dense32(self):
        """The dense bands' D in single precision (complex64), for the far field of a march's
        change (CausalSweep.single): half the bytes read per application."""
        return [(idx, D.astype(np.complex64)) for idx, D in self.dense]

    def _beyond_inf(self, X, Y, single: bool = False):
        """Y (N, F) = (S - K_inf) X for X (N, F): D X on the dense bands' frequencies (with
        ``single``, in single precision: D's complex64 copy, cspmv), minus the rank-6 term
        above the table."""
        op = self.op
        # above the table: the rank-6 term from its affine parts, S + R6 = A + s B there
        Xh = _real_view(X[:, self.hi])                                       # (N, 2 F_hi)
        U = (self.VlAB @ Xh).view(complex)                                   # [VlA; VlB] X: (12, F_hi)
        u = U[:6] + U[6:] * self.s_hi
        t = np.matmul(self.Zinv_hi, u.T[:, :, None])[:, :, 0].T              # (6, F_hi)
        T = np.concatenate([t, t * self.s_hi])                               # (12, F_hi)
        Y[:, self.hi] = -(self.VrAB @ _real_view(T)).view(complex)

        spmv = cspmv if single else zspmv

        def dense_task(idx, D, h):
            def run():
                i = _span(idx[h])
                Xl = np.ascontiguousarray(X[:, i].T, D.dtype)                # (Fc, N)
                if self.packed:
                    n, Dh = Xl.shape[1], D[h]
                    Y[:, i] = np.array([spmv(n, 1.0, Dh[j], Xl[j]) for j in range(Xl.shape[0])]).T
                else:
                    Y[:, i] = (D[h] @ Xl[:, :, None])[:, :, 0].T
            return run
        tasks = []
        for idx, D in self.dense32 if single else self.dense:
            tasks += [dense_task(idx, D, h) for h in op.pool.chunks(idx.size)]
        if tasks:
            op.pool.run(tasks)

    def __call__(self, xb, a, b, H, single: bool = False):
        """H[:, b:] += (S * x_block)[:, b:] for the block x[:, a:b] (N, b - a); ``single``: the
        dense band's products in single precision (``_beyond_inf``)."""
        op, g = self.op, self.grid
        op.n_apply += 1
        N, nt = xb.shape[0], g.nt
        # to_freq and to_time on the plans' own buffers: no band-sized copies or fresh arrays
        fwd, inv = g.plans(N)
        x = fwd.input_array
        x[:] = 0.0
        np.multiply(xb, np.exp(-g.eta * g.dt * np.arange(a, b)), out=x[:, a:b])
        X = fwd()                                                            # (N, F)
        self._beyond_inf(X, inv.input_array, single)
        y = inv()[:, b:nt]                                                   # (N, nt - b)
        y *= np.exp(g.eta * g.dt * np.arange(b, nt))                         # the window undone
        gamma = xb @ self.alt[a:b]                                           # sum_m (-1)^m d_m
        y += (self.c * (self.Bw @ gamma))[:, None] * self.alt[None, b:]
        H[:, b:] += y


def packed_product(U, V, out, width: int = 32):
    """The upper triangles of U V for U (m, N, k) and V (m, k, N) (the rank-6 term: k = 6), packed
    column by column (``upper_pairs``' order) into out (m, N (N + 1) / 2): ``width`` columns at
    a time, each from rows 0 .. c1 - 1 only (U V itself, m N^2 entries, is not formed nor
    gathered from)."""
    N = U.shape[1]
    for c0 in range(0, N, width):
        c1 = min(c0 + width, N)
        P = U[:, :c1] @ V[:, :, c0:c1]                                     # (m, c1, c1 - c0)
        for j in range(c0, c1):
            p = j * (j + 1) // 2
            out[:, p:p + j + 1] = P[:, :j + 1, j - c0]
    return out


def _real_view(Z):
    """A complex (m, n) array as float (m, 2 n) (no copy if C-contiguous)."""
    Z = np.ascontiguousarray(Z)
    return Z.view(float).reshape(Z.shape[0], 2 * Z.shape[1])

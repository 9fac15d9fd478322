"""Soil impedance K(s) on x = [q, w] (6 + N DOFs) at the grid's complex frequencies.

A soil is held as frequency bands, each either dense (one (n, n) matrix per frequency:
``MatrixBand``) or affine (K = A + s B with constant A, B): a band is applied to many
frequencies at once. A table's dense band (``SplineBand``) is formed on demand: whole for a
solver that applies it again and again, or a group of frequencies at a time (``piece``) for
one that takes the frequencies group by group (the linear route's bonded solve), never
holding the whole band (Fb (6 + N)^2 complex numbers).

Sources (``soil_bands``):

* ImpedanceTable (the BEM "gap" table): for f <= f_max, the table's cubic spline in f
  (the same not-a-knot spline as ``ImpedanceTable.at``) continued to the complex frequency
  f_c = s / (2 pi i) (continuous grid: f - i eta / 2 pi; bilinear grid: the warped s_d, what
  a trapezoidal recursion of the exact table would see) by its second-order Taylor series
  about Re f_c (spline derivatives; error O(|Im f_c|^3 K''')); the bands split on Re f_c.
  Above f_max: the spring-dashpot continuation K = Re K(f_max) + s Im K(f_max) / w_max
  (continuous at f_max; the high-frequency impedance of a surface foundation tends to a
  dashpot). Its static stiffness is Re K(0) (the table must start at 0 Hz).
  Hysteretic tables (material damping as complex moduli, Im K(0+) = 2 xi K_0 != 0) are first
  made causal at low frequency by the rational fit's own rule (``soil_impedance.fit.
  causal_target``: the offset Im K(0+) faded out below f_causal, 5 % of f_max): the sign(w)
  jump of a hysteretic Im K at w = 0 is a non-causal kernel ~ 2 xi K_0 / (pi t) for t < 0,
  which the window's undoing e^{+eta t} amplifies by up to 1/wrap_tol at the end of the
  record (measured on the reactor's linear route: the raft rotation drifted to 1.7e-5 rad in
  the last second, 12x the causal value, and moved with the padding).
* WinklerSoil: K + s C, exact (also for the bilinear map: the stepper sees K x + C xdot).
* RationalModel: K(s) exactly (bilinear grids: K(s_d), what a trapezoidal recursion gives).
* RecursiveConvolutionSoil: the recursion's own z-transform
  D + s_d E + sum_k R_k b_k (z + 1)/(z - a_k) at z = e^{s dt} (equals K(s_d) to round-off).
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np
from scipy.interpolate import CubicSpline

from soil_impedance.convolution import bilinear_coefficients
from soil_impedance.fit import causal_cutoff, causal_target
from soil_impedance.rational import RationalModel
from soil_impedance.table import ImpedanceTable
from structure.soil_interface import WinklerSoil


class MatrixBand:
    """A band held as one matrix per frequency, K (Fb, n, n) at the grid frequencies idx (Fb,):
    given (DenseBand) or formed from a table's spline (SplineBand). Subclasses provide idx, K."""

    def full(self, s):
        return self.K

    def apply_ww(self, X, s, sel=slice(None)):
        """X (Fb, N, r) -> K_ww X (s (Fb,) unused); sel: the band's frequencies X stands for
        (a part of the band, for the worker pool's chunks)."""
        return np.matmul(self.ww()[sel], X)

    def ww(self):
        """K_ww (Fb, N, N), the soil block: a view (its rows are contiguous, which is all the
        batched products need: a copy would cost the time of several of them, and the memory)."""
        return self.K[:, 6:, 6:]

    def sub_ww(self, rows, cols, s, sel=slice(None)):
        """K_ww[rows, cols] (Fb, m_r, m_c) at the band's frequencies sel (s unused)."""
        return self.K[sel][:, 6 + rows[:, None], 6 + cols[None, :]]

    def rows_P(self, s, Bq, out=None):
        """(K[w, :] P (Fb, N, 6), P^T K[:, w] (Fb, 6, N), P^T K P (Fb, 6, 6)), P = [I; Bq]; out:
        two arrays to write the first two in (None: new ones)."""
        return _written(rows_P(self.K, Bq), out)

    def packed_ww(self, sel: slice, out):
        """K_ww's upper triangles (``upper_pairs``: BLAS 'U' packed storage) at the band's
        frequencies sel (a slice), written into out (m, N (N + 1) / 2) complex."""
        m, n = out.shape[0], self.K.shape[-1]
        return np.take(self.K[sel].reshape(m, n * n), _upper_in(n), axis=1, out=out)

    def symmetric_by_construction(self) -> bool:
        """K_ww symmetric at every frequency because the band's data are, exactly (False: not
        known without forming K)."""
        return False

    def form(self) -> np.ndarray:
        """K, formed now if it is formed on demand (SplineBand)."""
        return self.K

    def groups(self, size: int) -> list:
        """The band's frequencies as slices of at most ``size`` (see ``piece``)."""
        n = self.idx.size
        return [slice(a, min(a + size, n)) for a in range(0, n, size)]

    def piece(self, sel: slice, scratch=None):
        """The band on its frequencies sel (a slice): a DenseBand of views (scratch unused)."""
        return DenseBand(self.idx[sel], self.K[sel])


@dataclass(frozen=True, eq=False)
class DenseBand(MatrixBand):
    """K (Fb, n, n) complex at the grid frequencies idx (Fb,)."""
    idx: np.ndarray
    K: np.ndarray


@dataclass(frozen=True, eq=False)
class SplineBand(MatrixBand):
    """A table's spline at the grid frequencies idx (Fb,), K = sum_j W[:, j] T_j + c H (T (F_tab,
    n, n) the table's matrices, not copied; W (Fb, F_tab) the spline's weights, real, or complex
    with the Taylor terms of a complex frequency; c (Fb,) and H (n, n) real: a rank-one
    correction in frequency, the causal fade, or None). K is formed when first asked for
    (the whole band: Fb n^2 complex, 260 MB on the reactor); ``piece`` forms a few
    frequencies only, and ``rows_P`` and ``packed_ww`` none (they are linear in K: formed on
    the table's matrices, F_tab of them, and combined with the weights)."""
    idx: np.ndarray
    W: np.ndarray
    T: np.ndarray
    c: np.ndarray | None = None
    H: np.ndarray | None = None

    @cached_property
    def K(self):
        """(Fb, n, n) complex, formed on first use and kept."""
        return self.block(slice(None), np.empty((self.idx.size,) + self.T.shape[1:], complex))

    def block(self, sel: slice, out):
        """K at the band's frequencies sel (a slice), written into out (m, n, n) complex."""
        self._combine(sel, self.T.reshape(self.T.shape[0], -1), self.H.reshape(-1) if self.c is not None else None,
                      out.reshape(out.shape[0], -1))
        return out

    def _combine(self, sel: slice, T, H, out):
        """out (m, p) = W[sel] T + c[sel] H for entries of the table's matrices T (F_tab, p)
        complex and of H (p,) (None without c): ``block`` on whole matrices, ``packed_ww`` on
        their upper triangles."""
        W = self.W[sel]
        if np.isrealobj(W):         # a real product on the complex data's floats: half the work
            np.matmul(W, T.view(float), out=out.view(float))
        else:
            np.matmul(W, T, out=out)
        if H is not None:
            for k, ck in enumerate(self.c[sel]):    # one frequency at a time: no (m, p) temporary
                out[k] += ck * H
        return out

    def piece(self, sel: slice, scratch=None):
        """The band on its frequencies sel (a slice) as a DenseBand: views of K once formed,
        else its matrices formed alone, in ``scratch`` (a Scratch: reused by the next piece)."""
        if "K" in self.__dict__ or scratch is None:
            return super().piece(sel)
        m = len(range(*sel.indices(self.idx.size)))
        return DenseBand(self.idx[sel], self.block(sel, scratch.array((m,) + self.T.shape[1:], complex)))

    @cached_property
    def _T_upper(self):
        """(T_ww's upper triangles (F_tab, P), H_ww's (P,) or None): ``packed_ww``'s data."""
        n = self.T.shape[-1]
        at = _upper_in(n)
        return self.T.reshape(-1, n * n)[:, at], None if self.c is None else self.H.reshape(-1)[at]

    def packed_ww(self, sel: slice, out):
        """As MatrixBand.packed_ww, from the table's packed matrices and the weights: K is not
        formed (the same sums over the table's matrices, half the entries)."""
        return self._combine(sel, *self._T_upper, out)

    def symmetric_by_construction(self) -> bool:
        """K = sum_j W[:, j] T_j + c H is symmetric when every T_j and H is (their soil blocks
        K_ww, exactly): checked on the table's F_tab matrices, K not formed."""
        sym = lambda M: np.array_equal(M, M.T)
        return all(sym(T[6:, 6:]) for T in self.T) and (self.c is None or sym(self.H[6:, 6:]))

    def rows_P(self, s, Bq, out=None):
        """As MatrixBand.rows_P, on the table's matrices and combined with the weights (s unused)."""
        F_tab = self.T.shape[0]
        Fb = self.idx.size
        res = []
        parts = zip(rows_P(self.T, Bq), rows_P(self.H[None], Bq) if self.c is not None else (None,) * 3)
        for part, hpart in parts:
            M = (self.W @ part.reshape(F_tab, -1)).reshape((Fb,) + part.shape[1:])
            if hpart is not None:
                M += self.c[:, None, None] * hpart
            res.append(M)
        return _written(tuple(res), out)


class Scratch:
    """One work array, reused (grown when too small): the pieces a thread forms one after
    another share it."""

    def __init__(self):
        self._a = None

    def array(self, shape, dtype):
        size = int(np.prod(shape))
        if self._a is None or self._a.size < size or self._a.dtype != dtype:
            self._a = np.empty(size, dtype)
        return self._a[:size].reshape(shape)


def _written(parts, out):
    """parts = (Vr, Vl, KPP), Vr and Vl copied into out = (Vr, Vl) when given."""
    if out is None:
        return parts
    out[0][...], out[1][...] = parts[0], parts[1]
    return out[0], out[1], parts[2]


def upper_pairs(N: int):
    """(rows, columns) of an (N, N) matrix's upper triangle, column by column: the order of BLAS
    'U' packed storage (N (N + 1) / 2 entries)."""
    return (np.concatenate([np.arange(j + 1) for j in range(N)]), np.repeat(np.arange(N), np.arange(1, N + 1)))


def _upper_in(n: int):
    """Flat indices in an (n, n) K of its soil block K_ww's (K[6:, 6:]) upper triangle, in
    ``upper_pairs(n - 6)``'s order."""
    i, j = upper_pairs(n - 6)
    return (6 + i) * n + 6 + j


def rows_P(K, Bq):
    """(K[w, :] P (F, N, r), P^T K[:, w] (F, r, N), P^T K P (F, r, r)) of K (F, n, n), P = [I; Bq]
    for a rigid raft's trace Bq (N, 6) (r = 6), P = [[I, 0]; Bq] for a plate's Bq (N, r) on its
    raft coordinates [q, t] (``plate_rows_P``)."""
    if Bq.shape[1] != 6:
        return plate_rows_P(K[:, :6, :6], K[:, :6, 6:], K[:, 6:, :6], K[:, 6:, 6:], Bq)
    Vr = K[:, 6:, :6] + K[:, 6:, 6:] @ Bq
    Vl = K[:, :6, 6:] + np.swapaxes(Bq, 0, 1) @ K[:, 6:, 6:]
    KPP = K[:, :6, :6] + K[:, :6, 6:] @ Bq + np.swapaxes(Bq, 0, 1) @ Vr
    return Vr, Vl, KPP


def plate_rows_P(Kqq, Kqw, Kwq, Kww, B):
    """rows_P's blocks for a plate raft (``structure.plate_raft``): the raft coordinates r = [q,
    t] (6 + nf: the rigid DOFs and the free vertices' deflections), the soil's x = [q, w] = P r
    + [0; -d] with P = [[I, 0]; B], B (N, 6 + nf) the trace of r at the nodes. The soil's
    blocks (..., 6, 6), (..., 6, N), (..., N, 6), (..., N, N); the results (..., N, r),
    (..., r, N), (..., r, r), the soil acting on q and (through w) on the trace only."""
    Bt = B.T
    Vr = Kww @ B
    Vr[..., :6] += Kwq
    Vl = Bt @ Kww
    Vl[..., :6, :] += Kqw
    KPP = Bt @ Vr
    KPP[..., :6, :] += Kqw @ B
    KPP[..., :6, :6] += Kqq
    return Vr, Vl, KPP


@dataclass(frozen=True, eq=False)
class AffineBand:
    """K = A + s B (A, B real (n, n), dense or sparse) at the grid frequencies idx."""
    idx: np.ndarray
    A: object
    B: object

    def full(self, s):
        A, B = dense(self.A), dense(self.B)
        return A[None] + s[:, None, None] * B[None]

    def apply_ww(self, X, s):
        """X (Fb, N, r) -> K_ww X at the Laplace variables s (Fb,)."""
        Aw, Bw = self.ww()
        Fb, N, r = X.shape
        Xt = np.ascontiguousarray(np.moveaxis(X, 0, 1)).reshape(N, Fb * r)      # (N, Fb r)
        Y = _real_apply(Aw, Xt) + _real_apply(Bw, Xt * np.repeat(s, r)[None, :])
        return np.moveaxis(Y.reshape(N, Fb, r), 1, 0)

    def ww(self):
        """(A_ww, B_ww), the soil blocks (dense or sparse as given, cached)."""
        if not hasattr(self, "_cache"):
            A, B = self.A, self.B
            object.__setattr__(self, "_cache", (_sub(A, slice(6, None), slice(6, None)),
                                                _sub(B, slice(6, None), slice(6, None))))
        return self._cache

    def sub_ww(self, rows, cols, s, sel=slice(None)):
        """K_ww[rows, cols] (Fb, m_r, m_c) at the band's frequencies sel (s: the band's)."""
        Aw, Bw = self.ww()
        a = dense(Aw[rows][:, cols]) if hasattr(Aw, "tocsr") else Aw[np.ix_(rows, cols)]
        b = dense(Bw[rows][:, cols]) if hasattr(Bw, "tocsr") else Bw[np.ix_(rows, cols)]
        return a[None] + s[sel][:, None, None] * b[None]

    def rows_P(self, s, Bq, out=None):
        """As MatrixBand.rows_P at the Laplace variables s (Fb,): A's parts + s B's, written in
        out (two arrays, the first two parts) when given (no band-sized temporaries)."""
        ss = s[:, None, None]
        res = []
        for k, (a, b) in enumerate(zip(*self.rows_P_parts(Bq))):
            M = np.multiply(ss, b, out=None if out is None or k >= len(out) else out[k])
            M += a
            res.append(M)
        return tuple(res)

    def form(self) -> None:
        """Nothing is formed on demand."""

    def groups(self, size: int) -> list:
        """One group: the whole band (it is applied to all its frequencies at once)."""
        return [slice(None)]

    def piece(self, sel: slice, scratch=None):
        """The band itself (its one group)."""
        return self

    def rows_P_parts(self, Bq):
        """rows_P's three blocks as A's and B's parts, real: ((K[w, :] P, P^T K[:, w], P^T K P)
        of A, the same of B); rows_P(s) = A's + s B's."""
        out = []
        for M in (dense(self.A), dense(self.B)):
            if Bq.shape[1] != 6:
                out.append(plate_rows_P(M[:6, :6], M[:6, 6:], M[6:, :6], M[6:, 6:], Bq))
                continue
            Vr = M[6:, :6] + M[6:, 6:] @ Bq
            Vl = M[:6, 6:] + Bq.T @ M[6:, 6:]
            KPP = M[:6, :6] + M[:6, 6:] @ Bq + Bq.T @ Vr
            out.append((Vr, Vl, KPP))
        return tuple(out)


def dense(M):
    """M as a dense float array (from a scipy sparse matrix or an array)."""
    return M.toarray() if hasattr(M, "toarray") else np.asarray(M, float)


def _sub(M, r, c):
    if hasattr(M, "tocsr"):
        return M.tocsr()[r][:, c].tocsr()
    return np.ascontiguousarray(np.asarray(M, float)[r, c])


def _real_apply(M, X):
    """M (N, N) real (dense or sparse) times complex X (N, m) without complexifying M."""
    Xr = X.view(float).reshape(X.shape[0], 2 * X.shape[1]) if X.flags.c_contiguous else \
        np.ascontiguousarray(X).view(float).reshape(X.shape[0], 2 * X.shape[1])
    Y = M @ Xr
    return np.ascontiguousarray(Y).view(complex)


@dataclass(frozen=True, eq=False)
class SoilBands:
    """The soil on the whole grid: bands partition the F frequencies; K0 (n, n) real, the
    static stiffness (for the preload and the penalty rule); label says where it came from;
    table the ImpedanceTable the bands were made from (None: another soil), whose data digest
    keys the set-up's cache entries (setup_cache)."""
    bands: tuple
    K0: np.ndarray
    n: int
    label: str
    table: object = None

    def static_stiffness(self):
        return self.K0


def soil_bands(soil, grid) -> SoilBands:
    """SoilBands of an ImpedanceTable, WinklerSoil, RationalModel or RecursiveConvolutionSoil."""
    s = grid.s
    F = s.size
    allf = np.arange(F)
    if isinstance(soil, ImpedanceTable):
        return _table_bands(soil, grid)
    if isinstance(soil, WinklerSoil):
        K, C = soil.instantaneous(grid.dt)
        return SoilBands((AffineBand(allf, K, C),), dense(soil.static_stiffness()), soil.n_dof,
                         "winkler springs and dashpots K + s C")
    if isinstance(soil, RationalModel):
        K0 = soil(np.zeros(1))[0].real
        return SoilBands((DenseBand(allf, soil(s)),), 0.5 * (K0 + K0.T), soil.n,
                         "rational model K(s)" + (" at the bilinear s_d" if grid.bilinear else ""))
    if hasattr(soil, "model") and isinstance(soil.model, RationalModel):
        return _recursion_bands(soil, grid)
    raise TypeError(f"cannot use a {type(soil).__name__} as a frequency-domain soil: give an "
                    "ImpedanceTable, WinklerSoil, RationalModel or RecursiveConvolutionSoil")


def _recursion_bands(soil, grid):
    model = soil.model
    if not grid.bilinear or abs(soil.dt - grid.dt) > 1e-12 * grid.dt:
        raise ValueError("a RecursiveConvolutionSoil is a discrete-time model: use it on a bilinear "
                         f"grid with the same dt (soil dt = {soil.dt}, grid dt = {grid.dt}, "
                         f"bilinear = {grid.bilinear})")
    z = grid.z
    a, b = bilinear_coefficients(model.poles, grid.dt)
    sb = grid.s
    g = b * (z[:, None] + 1) / (z[:, None] - a)
    K = model.D + sb[:, None, None] * model.E + np.einsum("fk,kij->fij", g, model.residues)
    return SoilBands((DenseBand(np.arange(z.size), K),), np.asarray(soil.static_stiffness(), float),
                     model.n, "recursive convolution z-transform")


def _table_bands(table, grid) -> SoilBands:
    f_tab = table.frequencies_hz
    if f_tab[0] != 0.0:
        raise ValueError(f"the impedance table starts at {f_tab[0]:g} Hz: the frequency-domain routes "
                         "need K(0) (static preload, penalty): include 0 Hz in the sweep")
    # complex frequency of each grid point: f_c = s / (2 pi i) (continuous: f - i eta / 2 pi;
    # bilinear: the warped s_d); the spline is continued from Re f_c by its Taylor series
    # the bands split on the real frequency a grid point stands for (grid.warped_hz: near a
    # bilinear grid's Nyquist s_d is nearly real and Re f_c is no frequency)
    fcx = grid.s / (2j * np.pi)
    fq = fcx.real
    fmax = f_tab[-1]
    lo = np.flatnonzero(grid.warped_hz <= fmax * (1 + 1e-12))
    hi = np.flatnonzero(grid.warped_hz > fmax * (1 + 1e-12))
    K = np.ascontiguousarray(table.matrices)
    n = K.shape[1]
    f_causal = causal_cutoff(table, K)
    # the causal fade is K - 1j g H0 (H0 = Im K(0), real): linear in the data, the spline of
    # the faded table is the table's spline plus the spline of g times H0 (no faded copy)
    g = _causal_fade(f_tab, f_causal) if f_causal > 0 else None
    H0 = np.ascontiguousarray(K[0].imag) if g is not None else None
    if f_tab.size >= 4:
        # the spline is linear in the data: its weights (lo, F_tab) at Re f_c, combined with
        # the Taylor terms (real on the imaginary axis: no window), times the table: the
        # spline of all n^2 entries would build 4 x F_tab x n^2 coefficients
        sp = CubicSpline(f_tab, np.eye(f_tab.size), axis=0)
        fc = fq[lo]
        W = sp(fc)
        dz = (1j * fcx[lo].imag)[:, None]
        if np.any(dz):
            W = W + dz * sp(fc, 1) + 0.5 * dz * dz * sp(fc, 2)
        band = SplineBand(lo, W, K, None if g is None else -1j * (W @ g), H0)
    else:
        Kt = K if g is None else K - 1j * g[:, None, None] * H0
        band = DenseBand(lo, replace(table, matrices=Kt).at(fq[lo]))
    bands = [band]
    if hi.size:
        wmax = 2 * np.pi * fmax
        top = K[-1] if g is None or g[-1] == 0 else K[-1] - 1j * g[-1] * H0
        bands.append(AffineBand(hi, np.ascontiguousarray(top.real), np.ascontiguousarray(top.imag / wmax)))
    K0 = K[0].real
    causal = f", hysteretic offset faded below {f_causal:g} Hz" if f_causal > 0 else ""
    return SoilBands(tuple(bands), 0.5 * (K0 + K0.T), n,
                     f"BEM table to {fmax:g} Hz (spline at f - i eta/2pi{causal}), spring-dashpot above", table)


def _causal_fade(f, f_causal):
    """g (F,): ``causal_target``'s fade as weights, causal_target(f, K, f_causal) = K - 1j g Im
    K(0) for a table from 0 Hz (its rule is linear in the data: read on a 1 x 1 table)."""
    probe = np.zeros((f.size, 1, 1), complex)
    probe[0] = 1j
    return (probe - causal_target(f, probe, f_causal))[:, 0, 0].imag


def causal_table(table):
    """(matrices (F, n, n), f_causal Hz): the table with its hysteretic offset Im K(0+) faded
    out below f_causal (the rational fit's rule, soil_impedance.fit; f_causal = 0 and the
    matrices unchanged for a table without hysteretic damping)."""
    f = table.frequencies_hz
    f_c = causal_cutoff(table, table.matrices)
    return causal_target(f, table.matrices, f_c), f_c

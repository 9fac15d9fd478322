"""The table in fit form: DOF scaling, the causal target, the least-squares problem of the
residues (``Problem``) and the fit of one order (``fit_order``).

The fit works on S K S, S = diag(|Re K_ii(f_0)|)^{-1/2}, in normalised frequency ν = ω/ω_ref,
ω_ref = 2π f_max, on the upper triangle (off-diagonal entries weighted √2: the Frobenius norm);
below f_causal a hysteretic table's offset Im K(0⁺) is faded out of the target
(docs/formulation.md, "Causality").
"""
from __future__ import annotations

from functools import cached_property

import numpy as np

from ..rational import FitError, RationalModel
from ..vectfit import canonical_poles, compress, fit_coefficients, initial_poles, real_basis, vector_fit
from .options import POLE_CAP, RIGID, WEIGHTINGS


def table_scaling(table):
    """(active DOF indices, S) for the table: nonzero rows, S_i = |Re K_ii(f_0)|^{-1/2}."""
    K = table.matrices
    rowmax = np.max(np.abs(K), axis=(0, 2))
    idx = np.nonzero(rowmax > 0)[0]
    d = np.abs(K[0].real.diagonal())[idx]
    fallback = np.max(np.abs(np.einsum("fii->fi", K)), axis=0)[idx]
    d = np.where(d > 1e-9 * fallback, d, fallback)
    return idx, 1.0 / np.sqrt(d)


def causal_cutoff(table, Ks, f_causal_hz="auto", fraction=0.05) -> float:
    """f_causal (Hz) for the causal target: ``f_causal_hz`` when given; else 0 for a table of
    causal materials or without hysteretic damping (|H0| <= 1e-3 |K(f_0)|), otherwise the first
    table frequency >= ``fraction`` f_max."""
    f = table.frequencies_hz
    if f_causal_hz != "auto":
        return float(f_causal_hz)
    if causal_materials(table):
        return 0.0
    im0 = np.linalg.norm(hysteretic_part(f, Ks))
    if im0 <= 1e-3 * np.linalg.norm(Ks[0]):
        return 0.0
    return float(f[np.nonzero(f >= fraction * f[-1])[0][0]])


def causal_materials(table) -> bool:
    """True when the table's provenance lists its soil materials, all with the causal model."""
    profile = table.provenance.get("profile")
    if not isinstance(profile, dict) or "halfspace" not in profile:
        return False
    mats = list(profile.get("layers") or []) + [profile["halfspace"]]
    return all(isinstance(m, dict) and m.get("damping_model") == "causal" for m in mats)


def hysteretic_part(f, Ks) -> np.ndarray:
    """Im K extrapolated to f = 0 (linear through the two lowest positive frequencies)."""
    if f[0] == 0:
        return Ks[0].imag.copy()
    pos = np.nonzero(f > 0)[0]
    if pos.size < 2:
        return np.zeros(Ks.shape[1:])
    i1, i2 = pos[:2]
    return Ks[i1].imag - f[i1] * (Ks[i2].imag - Ks[i1].imag) / (f[i2] - f[i1])


def causal_target(f, Ks, f_c):
    """Ks with the hysteretic offset H0 = Im K(0⁺) faded out below f_c:
    Im K_target(f) = Im K(f) − H0·(1 − f/f_c)² for f < f_c (C¹ at f_c, linear in f at 0)."""
    if f_c <= 0:
        return Ks
    H0 = hysteretic_part(f, Ks)
    out = Ks.copy()
    low = f < f_c
    out[low] = out[low] - 1j * ((1 - f[low] / f_c) ** 2)[:, None, None] * H0[None]
    return out


def dof_blocks(dofs):
    rigid = np.array([d in RIGID for d in dofs])
    if rigid.all() or not rigid.any():
        return {"all": (np.arange(len(dofs)), np.arange(len(dofs)))}
    r, w = np.nonzero(rigid)[0], np.nonzero(~rigid)[0]
    return {"rigid": (r, r), "rigid-w": (r, w), "w": (w, w)}


def rel_errors(Km, Kt):
    """Per-frequency relative Frobenius error, shape (F,)."""
    num = np.linalg.norm((Km - Kt).reshape(Kt.shape[0], -1), axis=1)
    den = np.linalg.norm(Kt.reshape(Kt.shape[0], -1), axis=1)
    return num / np.where(den > 0, den, 1.0)


def entry_weighted_coefficients(s, X, poles, linear):
    """Coefficients (nb, q) of the columns X (F, q) at s = 2πif with the "entry" weighting: each
    column fitted alone, weighted by 1 / max(|X|, 1e-3 max|X| of its column) (relative error)."""
    mag = np.abs(X)
    we = 1.0 / np.maximum(mag, 1e-3 * mag.max(axis=0, keepdims=True) + 1e-300)
    A = real_basis(s, poles, const=True, linear=linear)
    out = np.empty((A.shape[1], X.shape[1]))
    for j in range(X.shape[1]):
        Aw = A * we[:, j:j + 1]
        out[:, j] = np.linalg.lstsq(np.concatenate([Aw.real, Aw.imag]),
                                    np.concatenate([(we[:, j] * X[:, j]).real, (we[:, j] * X[:, j]).imag]),
                                    rcond=None)[0]
    return out


class Problem:
    """The table in fit form: upper-triangle entries of S K S, weights, normalised s."""

    def __init__(self, table, weighting, f_causal_hz):
        if weighting not in WEIGHTINGS:
            raise FitError(f"weighting {weighting!r} unknown: use one of {WEIGHTINGS}")
        f = table.frequencies_hz
        if f.size < 4:
            raise FitError(f"table has {f.size} frequencies: a rational fit needs at least 4 (recompute the sweep)")
        self.table, self.f = table, f
        self.idx, self.S = table_scaling(table)
        if self.idx.size == 0:
            raise FitError("table is identically zero: nothing to fit")
        K = table.matrices[:, self.idx][:, :, self.idx]
        self.Ks = K * self.S[None, :, None] * self.S[None, None, :]
        self.f_c = causal_cutoff(table, self.Ks, f_causal_hz)
        self.target = causal_target(f, self.Ks, self.f_c)
        self.w_ref = 2 * np.pi * f[-1]
        self.s = 1j * 2 * np.pi * f / self.w_ref
        na = self.idx.size
        self.iu = np.triu_indices(na)
        self.ew = np.where(self.iu[0] == self.iu[1], 1.0, np.sqrt(2.0))
        self.X = self.target[:, self.iu[0], self.iu[1]] * self.ew      # (F, M)
        self.w_rel = 1.0 / np.maximum(np.linalg.norm(self.target.reshape(f.size, -1), axis=1), 1e-300)
        self.weighting = weighting
        self.w = self.w_rel if weighting != "uniform" else np.full(f.size, 1.0 / np.abs(self.X).max())
        self.band = f >= self.f_c
        self.Y = compress(self.X, self.w_rel)

    def coefficients(self, poles):
        """(nb, M) coefficients with E projected on the PSD cone."""
        C = self._solve(poles, self.X, linear=True)
        E = self._matrix(C[-1])
        lam, vec = np.linalg.eigh(E)
        if lam[0] < 0:
            Ep = (vec * np.maximum(lam, 0)) @ vec.T
            ep = Ep[self.iu] * self.ew
            C = np.vstack([self._solve(poles, self.X - self.s[:, None] * ep[None], linear=False), ep[None]])
        return C

    def _solve(self, poles, X, linear):
        if self.weighting != "entry":
            return fit_coefficients(self.s, X, self.w, poles, const=True, linear=linear)
        return entry_weighted_coefficients(self.s, X, poles, linear)

    def _matrix(self, v):
        na = self.idx.size
        M = np.zeros((na, na))
        M[self.iu] = v / self.ew
        return M + np.triu(M, 1).T

    def model(self, poles, C, provenance) -> RationalModel:
        """Unscaled, full-size RationalModel."""
        m = poles.size
        n = self.table.n_dof
        mats = np.stack([self._matrix(c) for c in C])
        mats[:m] *= self.w_ref
        mats[m + 1] /= self.w_ref
        mats = mats / self.S[None, :, None] / self.S[None, None, :]
        mats = 0.5 * (mats + mats.transpose(0, 2, 1))
        full = np.zeros((m + 2, n, n))
        full[np.ix_(range(m + 2), self.idx, self.idx)] = mats
        return RationalModel.from_coefficients(poles * self.w_ref, full, self.table.dofs, provenance)

    @cached_property
    def unscaled_target(self):
        """The causal target in SI units, full size (F, n, n) (zero rows stay zero)."""
        out = np.zeros(self.table.matrices.shape, complex)
        T = self.target / self.S[None, :, None] / self.S[None, None, :]
        out[np.ix_(range(self.f.size), self.idx, self.idx)] = T
        return out

    def scaled_response(self, model):
        K = model.frequency_response(self.f)[:, self.idx][:, :, self.idx]
        return K * self.S[None, :, None] * self.S[None, None, :]


def fit_order(prob, n_pairs, n_iter):
    if getattr(prob, "streamed", False):                  # a table read in blocks (fit.streamed)
        from .streamed import fit_order_streamed
        return fit_order_streamed(prob, n_pairs, n_iter)
    poles = vector_fit(prob.s, prob.Y, prob.w_rel, initial_poles(n_pairs, 1.0), n_iter=n_iter)
    keep = np.abs(poles) <= POLE_CAP
    poles = canonical_poles(poles[keep])
    C = prob.coefficients(poles)
    res = real_basis(prob.s, poles) @ C - prob.X       # rows: Frobenius norms (√2 weights)
    err = np.linalg.norm(res, axis=1) / np.maximum(np.linalg.norm(prob.X, axis=1), 1e-300)
    return poles, C, float(err[prob.band].max())


def hysteretic_floor(prob) -> float:
    """A-priori estimate of the band error floor of a causal fit: ≈ 1.1 ξ with the loss factor
    2ξ = ‖H0‖_F/‖Re K(f_0)‖_F (scaled), H0 = Im K(0⁺); 0 when the table is not hysteretic."""
    if getattr(prob, "streamed", False):
        return prob.hysteretic_floor()
    if prob.f_c <= 0:
        return 0.0
    H0 = hysteretic_part(prob.f, prob.Ks)
    return float(1.1 * 0.5 * np.linalg.norm(H0) / max(np.linalg.norm(prob.Ks[0].real), 1e-300))

"""Pole-free time-domain soil forces: the independent cross-check of the recursive convolution.

``convolve(K, u, dt)`` returns f (nt, n) = the soil force for displacements u (nt, n) from rest,
by one of two routes, neither of which uses poles or residues:

* ``method="cq"`` (default for a callable K(s), e.g. a RationalModel or a closed form):
  convolution quadrature with BDF2 (Lubich 1988; Code_Aster's Laplace-time method).
  f_n = Σ_{j≤n} W_j u_{n−j} with K(δ(ζ)/dt) = Σ_j W_j ζ^j, δ(ζ) = (1−ζ) + (1−ζ)^2/2. The weights
  come from K on the circle |ζ| = ρ by FFT (L = 2 nt points, ρ^{nt} = eps^{1/3}: weight error
  ~ eps^{2/3} relative). Second order in dt; A-stable; needs K(s) for Re s > 0.
* ``method="fft"`` (the only route for an ImpedanceTable; also for a callable, with K(iω)):
  the frequency-domain product, f = IDFT(K(iω_k) DFT(u zero-padded to ``pad`` × nt)), i.e. a
  direct (circular, padded) discrete convolution with the band-limited impulse response
  IDFT K(iω_k). Spectrally accurate for smooth band-limited input once the response has
  decayed inside the padding (wrap-around otherwise). For a table: K is interpolated
  (``ImpedanceTable.at``) on the FFT grid; above the table's last frequency it is continued
  by its spring-plus-dashpot asymptote Re K(f_max) + i (f / f_max) Im K(f_max); below
  ``f_causal`` (default: the table's first nonzero frequency) Im K is ramped linearly to 0 at
  f = 0 (a hysteretic table has Im K(0+) ≠ 0: the ramp removes the non-causal step at ω = 0,
  K(0) = Re K(0) is the static stiffness). What remains of the hysteretic non-causality is
  measured by ``impulse_response(...)[1]`` (the kernel's acausal energy fraction).
"""
from __future__ import annotations

import numpy as np
from scipy import fft as sfft


def _as_2d(u):
    u = np.asarray(u, float)
    if u.ndim == 1:
        u = u[:, None]
    if u.ndim != 2:
        raise ValueError(f"displacements u must have shape (nt, n), got {u.shape}")
    return u


def _is_table(K):
    return hasattr(K, "frequencies_hz") and hasattr(K, "matrices")


def bdf2_delta(zeta):
    """BDF2 generating function δ(ζ) = (1 − ζ) + (1 − ζ)^2 / 2."""
    return (1 - zeta) + 0.5 * (1 - zeta) ** 2


def cq_weights(K, dt: float, nt: int, n: int | None = None) -> np.ndarray:
    """BDF2 convolution-quadrature weights W (nt, n, n), real, of a callable K(s) -> (..., n, n).

    K(δ(ζ)/dt) = Σ_j W_j ζ^j; W_j = ρ^{−j} (1/L) Σ_l K(δ(ρ e^{2πil/L})/dt) e^{−2πijl/L}."""
    L = 2 * nt
    rho = np.finfo(float).eps ** (1.0 / (3 * nt))
    l = np.arange(L // 2 + 1)                     # K(conj s) = conj K(s): half the circle
    zeta = rho * np.exp(2j * np.pi * l / L)
    s = bdf2_delta(zeta) / dt
    Kl = np.asarray(K(s), complex)
    if Kl.ndim == 1:
        Kl = Kl[:, None, None]
    W = sfft.irfft(np.conj(Kl), n=L, axis=0)[:nt]   # (1/L) Σ_l K_l e^{-2πijl/L}, real
    return W * rho ** (-np.arange(nt))[:, None, None]


def _causal_product(W, u):
    """f_n = Σ_{j≤n} W_j u_{n−j} for W (nt, n, n), u (nt, n), via FFT."""
    nt = u.shape[0]
    L = sfft.next_fast_len(2 * nt, real=True)
    Wf = sfft.rfft(W, n=L, axis=0)
    uf = sfft.rfft(u, n=L, axis=0)
    return sfft.irfft(np.einsum("kij,kj->ki", Wf, uf), n=L, axis=0)[:nt]


def table_response(table, freq_hz, f_causal: float | None = None) -> np.ndarray:
    """K (F, n, n) of a table on an arbitrary grid freq_hz >= 0, Hz: interpolated inside the
    table, dashpot asymptote above it, Im ramped to 0 below f_causal (see module doc)."""
    f = np.asarray(freq_hz, float)
    ft, Kt = table.frequencies_hz, table.matrices
    inside = (f >= ft[0]) & (f <= ft[-1])
    out = np.empty(f.shape + Kt.shape[1:], complex)
    if inside.any():
        out[inside] = table.at(f[inside])
    hi = f > ft[-1]
    if hi.any():
        out[hi] = Kt[-1].real + 1j * (f[hi] / ft[-1])[:, None, None] * Kt[-1].imag
    lo = f < ft[0]
    if lo.any():
        out[lo] = Kt[0].real + 1j * (f[lo] / max(ft[0], 1e-300))[:, None, None] * Kt[0].imag
    fc = (ft[ft > 0][0] if np.any(ft > 0) else 0.0) if f_causal is None else float(f_causal)
    ramp = f < fc
    if ramp.any():
        Kc = table.at(fc) if ft[0] <= fc <= ft[-1] else out[np.argmin(np.abs(f - fc))]
        out[ramp] = out[ramp].real + 1j * (f[ramp] / fc)[:, None, None] * Kc.imag
    out[f == 0] = out[f == 0].real
    return out


def _fft_K(K, dt, L, f_causal):
    freq = np.arange(L // 2 + 1) / (L * dt)
    if _is_table(K):
        return table_response(K, freq, f_causal)
    Kw = np.asarray(K(2j * np.pi * freq), complex)
    Kw = Kw[:, None, None] if Kw.ndim == 1 else Kw
    Kw[0] = Kw[0].real
    return Kw


def impulse_response(K, dt: float, nt: int, pad: int = 4, f_causal: float | None = None):
    """Discrete kernel k_j (L, n, n) = IDFT K(iω_k) on L = pad·nt samples (k_j for j ≥ L/2 is
    the acausal part, t = (j − L) dt < 0), and its acausal fraction: Σ_{j≥L/2}|r_j|^2 / Σ|r_j|^2
    of the kernel r of the remainder K − (K_∞ + iω C_∞) after removing the spring-dashpot
    asymptote at the top frequency ω_top (K_∞ = Re K(ω_top), C_∞ = Im K(ω_top)/ω_top; causal
    in continuous time but band-limited it is not, so it is left out of the measure)."""
    L = sfft.next_fast_len(pad * nt, real=True)
    Kw = _fft_K(K, dt, L, f_causal)
    k = sfft.irfft(Kw, n=L, axis=0)
    ftop = min(K.frequencies_hz[-1], 0.5 / dt) if _is_table(K) else 0.5 / dt
    top = min(int(round(ftop * L * dt)), Kw.shape[0] - 1)
    w = np.arange(Kw.shape[0]) / top
    rem = Kw - Kw[top].real - 1j * w[:, None, None] * Kw[top].imag
    rem[top:] = 0.0
    r = sfft.irfft(rem, n=L, axis=0)
    e = (r**2).sum(axis=(1, 2))
    return k, float(e[L // 2:].sum() / max(e.sum(), 1e-300))


def convolve(K, u, dt: float, method: str | None = None, pad: int = 4,
             f_causal: float | None = None) -> np.ndarray:
    """Soil force f (nt, n), N, for displacements u (nt, n), m, at t_j = j dt from rest.

    K : callable K(s) (array of complex s -> (..., n, n)), e.g. a RationalModel, or an
        ImpedanceTable (frequencies in Hz, e^{+iωt}).
    method : "cq" (BDF2 convolution quadrature; callable only; default for a callable) or
        "fft" (frequency-domain product with zero padding to pad·nt; default for a table).
    """
    u = _as_2d(u)
    nt = u.shape[0]
    if method is None:
        method = "fft" if _is_table(K) else "cq"
    if method == "cq":
        if _is_table(K):
            raise ValueError("method='cq' needs K(s) off the imaginary axis; a table only has "
                             "K(iω): use method='fft' (or a fitted RationalModel)")
        return _causal_product(cq_weights(K, dt, nt), u)
    if method != "fft":
        raise ValueError(f"method = {method!r} must be 'cq' or 'fft'")
    L = sfft.next_fast_len(pad * nt, real=True)
    Kw = _fft_K(K, dt, L, f_causal)
    uf = sfft.rfft(u, n=L, axis=0)
    return sfft.irfft(np.einsum("kij,kj->ki", Kw, uf), n=L, axis=0)[:nt]

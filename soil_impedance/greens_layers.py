"""Surface flexibility of a layered half-space in the wavenumber domain (stiffness-matrix method).

Exact layer stiffness matrices (Kausel & Roësset 1981) for one horizontal wavenumber k,
condensed from the half-space up to the free surface. A plane-strain field along the
wavenumber direction, ~ e^{-ikx} e^{+iωt}, depth ζ = -z downward, in-plane displacements
(U along k, W downward) and anti-plane V.

Numerical robustness (this is the point of the module):

* every wave is referenced to the interface it decays away from (down-going waves to the top
  of a layer, up-going to its bottom), so no exponential ever grows: k h may be huge;
* the P and SV down-going solutions coincide as ω → 0 (ν_p, ν_s → k). The second basis
  vector is the divided difference (SV - P)/(ks² - kp²), evaluated with expm1-type functions,
  so the same formulas are exact at ω = 0 (static, solutions e^{-kζ}, ζ e^{-kζ}) and lose no
  digits at 0.01 Hz;
* principal square roots ν = sqrt(k² - kj²) give Re ν >= 0 on the real axis and on contours
  above it (radiating branch for e^{+iωt}).

Output (per wavenumber, complex, m³/N: the Hankel-transform kernels of the surface
point-load Green's functions, see ``greens``):

    Fzz : vertical displacement / vertical traction
    Fb  : i * (radial displacement along k / downward traction)   (static: (1-2ν)/(2Gk))
    Fkk : horizontal displacement along k / traction along k      (P-SV)
    Ftt : horizontal displacement ⟂ k / traction ⟂ k              (SH)
"""
from __future__ import annotations

import numpy as np


def material_constants(material, omega):
    """(G*, ks², γ²) of a Material: complex shear modulus, S wavenumber², (Vs/Vp)²."""
    G = material.complex_shear_modulus(omega)
    ks2 = omega ** 2 * material.rho / G
    nu = material.poisson
    g2 = (1.0 - 2.0 * nu) / (2.0 * (1.0 - nu))
    return G, ks2, g2


def _phi1(x):
    """expm1(x)/x, exact at x = 0 (complex arrays)."""
    x = np.asarray(x, dtype=complex)
    small = np.abs(x) < 1e-4
    xs = np.where(small, 1.0, x)
    return np.where(small, 1.0 + x / 2.0 + x * x / 6.0, np.expm1(xs) / xs)


def _down_basis(k, G, ks2, g2, zeta):
    """Two down-going P-SV solutions at depth ``zeta`` below their reference plane.

    Returns disp, trac : ndarrays shape (n_k, 2, 2): [component (U, W or τx, τζ), basis].
    Basis 0: P wave scaled by 1/κ; basis 1: (SV - P)/(ks² - kp²) scaled by κ, with
    κ = sqrt(|k|² + |ks²|) so both columns are O(1) (conditioning only).
    """
    kp2 = g2 * ks2
    nup = np.sqrt(k * k - kp2)
    nus = np.sqrt(k * k - ks2)
    g = 1.0 / (1.0 - g2)
    Ep = np.exp(-nup * zeta)
    Es = np.exp(-nus * zeta)
    sig = nus + nup
    delta = (kp2 - ks2) / sig
    X = Ep * zeta * _phi1(-delta * zeta) / sig
    kap = np.sqrt(np.abs(k) ** 2 + abs(ks2))
    disp = np.empty(k.shape + (2, 2), dtype=complex)
    trac = np.empty_like(disp)
    disp[..., 0, 0] = -1j * k * Ep / kap
    disp[..., 1, 0] = -nup * Ep / kap
    trac[..., 0, 0] = 2j * k * G * nup * Ep / kap
    trac[..., 1, 0] = G * (2 * k * k - ks2) * Ep / kap
    disp[..., 0, 1] = -1j * kap * (-g / (nus + k) * Es + k * X)
    disp[..., 1, 1] = -kap * (g * g2 / (k + nup) * Es + nup * X)
    trac[..., 0, 1] = 1j * G * kap * (g * (2 * k * g2 / (k + nup) - 1.0) * Es + 2 * k * nup * X)
    trac[..., 1, 1] = G * kap * (-g * ks2 / (nus + k) ** 2 * Es + (2 * k * k - ks2) * X)
    return disp, trac


def _psv_layer_stiffness(k, G, ks2, g2, h):
    """4x4 P-SV stiffness of a layer, dofs (U_top, W_top, U_bot, W_bot); shape (n_k, 4, 4)."""
    d0, t0 = _down_basis(k, G, ks2, g2, 0.0)
    dh, th = _down_basis(k, G, ks2, g2, h)
    # up-going waves referenced to the bottom are mirror images: (U, W) -> (U, -W) and
    # (τx, τζ) -> (-τx, τζ), i.e. tractions take the factor -mirror
    mirror = np.array([[1.0], [-1.0]])
    Dm = np.empty(k.shape + (4, 4), dtype=complex)
    Sm = np.empty_like(Dm)
    Dm[..., 0:2, 0:2] = d0
    Dm[..., 2:4, 0:2] = dh
    Dm[..., 0:2, 2:4] = dh * mirror
    Dm[..., 2:4, 2:4] = d0 * mirror
    # external tractions on the layer faces: -τ on top (normal up), +τ at the bottom
    Sm[..., 0:2, 0:2] = -t0
    Sm[..., 2:4, 0:2] = th
    Sm[..., 0:2, 2:4] = th * mirror
    Sm[..., 2:4, 2:4] = -t0 * mirror
    # K = Sm Dm^-1  <=>  Dm^T K^T = Sm^T
    return np.swapaxes(np.linalg.solve(np.swapaxes(Dm, -1, -2), np.swapaxes(Sm, -1, -2)), -1, -2)


def _psv_halfspace_stiffness(k, G, ks2, g2):
    d0, t0 = _down_basis(k, G, ks2, g2, 0.0)
    return np.swapaxes(np.linalg.solve(np.swapaxes(d0, -1, -2), np.swapaxes(-t0, -1, -2)), -1, -2)


def _sh_layer_stiffness(k, G, ks2, h):
    """SH layer stiffness entries (K11 = K22, K12 = K21), overflow-free."""
    nus = np.sqrt(k * k - ks2)
    x = nus * h
    e = np.exp(-x)
    one_m_e2 = -np.expm1(-2.0 * x)
    small = np.abs(x) < 1e-6
    # G ν coth(νh) -> G/h,  G ν / sinh(νh) -> G/h for νh -> 0
    k11 = np.where(small, G / h, G * nus * (1.0 + e * e) / np.where(small, 1.0, one_m_e2))
    k12 = np.where(small, -G / h, -G * nus * 2.0 * e / np.where(small, 1.0, one_m_e2))
    return k11, k12


def surface_flexibility(profile, omega, k):
    """Surface flexibility kernels (Fzz, Fb, Fkk, Ftt) of a layered profile.

    Parameters
    ----------
    profile : SoilProfile
    omega : float, rad/s (>= 0)
    k : ndarray, shape (n,), 1/m, complex allowed (Re k > 0, contour above the real axis)

    Returns
    -------
    Fzz, Fb, Fkk, Ftt : ndarrays shape (n,), m³/N: Hankel kernels of the surface point-load
    Green's functions (see ``greens``).
    """
    k = np.asarray(k, dtype=complex)
    hs = profile.halfspace
    G, ks2, g2 = material_constants(hs, omega)
    K = _psv_halfspace_stiffness(k, G, ks2, g2)
    Ksh = G * np.sqrt(k * k - ks2)
    for layer in reversed(profile.layers):
        G, ks2, g2 = material_constants(layer, omega)
        KL = _psv_layer_stiffness(k, G, ks2, g2, layer.thickness)
        M = KL[..., 2:4, 2:4] + K
        K = KL[..., 0:2, 0:2] - KL[..., 0:2, 2:4] @ np.linalg.solve(M, KL[..., 2:4, 0:2])
        k11, k12 = _sh_layer_stiffness(k, G, ks2, layer.thickness)
        Ksh = k11 - k12 * k12 / (k11 + Ksh)
    F = np.linalg.inv(K)
    return F[..., 1, 1], 1j * F[..., 0, 1], F[..., 0, 0], 1.0 / Ksh


def static_flexibility(material, k, omega=None):
    """Static homogeneous half-space kernels (Fzz, Fb, Fkk, Ftt) of ``material`` with its
    complex G*(omega) (omega in rad/s; None: hysteretic materials only)."""
    k = np.asarray(k, dtype=complex)
    G = material.complex_shear_modulus(omega)
    nu = material.poisson
    return ((1.0 - nu) / (G * k), (1.0 - 2.0 * nu) / (2.0 * G * k),
            (1.0 - nu) / (G * k), 1.0 / (G * k))

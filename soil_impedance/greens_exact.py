"""Independent exact kernel for the homogeneous half-space (Lamb's problem), for checks.

Closed-form surface flexibility in the wavenumber domain (Rayleigh function
R(k) = (2k² - ks²)² - 4k² ν_p ν_s), e^{+iωt}, same kernel names as ``greens_layers``:

    Fzz = -ks² ν_p / (G R),   Fkk = -ks² ν_s / (G R),
    Fb  = -k (2k² - ks² - 2 ν_p ν_s) / (G R),   Ftt = 1 / (G ν_s).

Shares no code with the production path: its own kernel formulas, its own path (a half
ellipse above the real axis to k_e, then the real axis) and adaptive quadrature
(dense composite Simpson) instead of Gauss panels and closed-form tails. Slow-ish
(~1 s); meant for tests at a handful of radii.
"""
from __future__ import annotations

import numpy as np
from scipy import special


def lamb_flexibility(material, omega, k):
    """(Fzz, Fb, Fkk, Ftt) of a homogeneous half-space, k complex array (Re ν >= 0 branch)."""
    k = np.asarray(k, dtype=complex)
    G = material.complex_shear_modulus(omega)
    nu = material.poisson
    ks2 = omega ** 2 * material.rho / G
    kp2 = ks2 * (1 - 2 * nu) / (2 * (1 - nu))
    nup, nus = np.sqrt(k * k - kp2), np.sqrt(k * k - ks2)
    R = (2 * k * k - ks2) ** 2 - 4 * k * k * nup * nus
    return (-ks2 * nup / (G * R), -k * (2 * k * k - ks2 - 2 * nup * nus) / (G * R),
            -ks2 * nus / (G * R), 1.0 / (G * nus))


def _integrand(kernel, material, omega, r, k, dk):
    """Regular-part integrands, shape (4, n_r, n_k), static half-space kernel removed."""
    G = material.complex_shear_modulus(omega)
    nu = material.poisson
    f0 = np.array([(1 - nu) / G, (1 - 2 * nu) / (2 * G), (1 - nu) / G, 1 / G])[:, None]
    F = np.array(kernel(omega, k)) - f0 / k
    x = np.outer(r, k)
    j0, j1 = special.jv(0, x), special.jv(1, x)
    j1x = np.where(np.abs(x) < 1e-8, 0.5, j1 / np.where(x == 0, 1.0, x))
    wk = k * dk / (2 * np.pi)
    return np.stack([F[0] * j0, F[1] * j1, F[2] * (j0 - j1x) + F[3] * j1x,
                     F[3] * (j0 - j1x) + F[2] * j1x]) * wk


def _simpson(n):
    w = np.ones(n)
    w[1:-1:2], w[2:-1:2] = 4.0, 2.0
    return w / 3.0


def exact_regular_halfspace(material, omega, r, **kw):
    """Regular part (A, B, C, D) of the homogeneous half-space at radii r (m), omega > 0."""
    return reference_regular(material, lambda w, k: lamb_flexibility(material, w, k), omega, r,
                             vs_min=material.vs, **kw)


def reference_regular(material, kernel, omega, r, vs_min, h1=np.inf, k_end_factor=3.0,
                      k_max_factor=400.0, n_ellipse=20001, per_period=60):
    """Regular part (A, B, C, D) at radii r (m), omega > 0, of any k-domain ``kernel(ω, k)``
    returning (Fzz, Fb, Fkk, Ftt), minus the static half-space of ``material`` (the top).
    For layered media pass ``kernel = lambda w, k: surface_flexibility(profile, w, k)``,
    vs_min and h1 (top layer thickness): K >= 60/h1.

    Path: half ellipse 0 -> k_e (k_e = k_end_factor ω/vs_min, height min(k_e/2, 2/r_max)),
    composite Simpson in the angle; then [k_e, K], K = max(k_max_factor ks, 60/h1), Simpson with
    ``per_period`` points per period of J0(k r_max); plus the analytic tail c/K of the
    r = 0 kernels (c: k^-3 coefficient read at K).
    """
    r = np.atleast_1d(np.asarray(r, dtype=float))
    ks = omega / material.vs
    k_e, K = k_end_factor * omega / vs_min, max(k_max_factor * ks, 60.0 / h1)
    r_max = max(r.max(), 1.0)
    h = min(0.01 * k_e, 2.0 / r_max)  # hug the axis: first-quadrant poles exist (see greens_rule)
    phi = np.linspace(0.0, np.pi, n_ellipse)
    phi[0] = 1e-9  # k -> 0: the integrand has a finite limit
    z = k_e / 2 * (1 - np.cos(phi)) + 1j * h * np.sin(phi)
    dz = (k_e / 2 * np.sin(phi) + 1j * h * np.cos(phi)) * _simpson(n_ellipse) * (phi[1] - phi[0])
    out = _integrand(kernel, material, omega, r, z, dz).sum(axis=-1)
    n = int(np.ceil((K - k_e) * r_max / (2 * np.pi) * per_period)) // 2 * 2 + 1
    kr = np.linspace(k_e, K, n)
    for chunk in np.array_split(np.arange(n), max(1, n // 4000)):
        w = _simpson(n)[chunk] * (kr[1] - kr[0])
        out = out + _integrand(kernel, material, omega, r, kr[chunk] + 0j, w).sum(axis=-1)
    G = material.complex_shear_modulus(omega)
    nu = material.poisson
    Fk = np.array(kernel(omega, np.array([K], dtype=complex)))[:, 0]
    c = (Fk - np.array([(1 - nu) / G, 0, (1 - nu) / G, 1 / G]) / K) * K ** 3
    at0 = r == 0
    out[0, at0] += c[0] / K / (2 * np.pi)
    out[2, at0] += 0.5 * (c[2] + c[3]) / K / (2 * np.pi)
    out[3, at0] += 0.5 * (c[2] + c[3]) / K / (2 * np.pi)
    return tuple(out)

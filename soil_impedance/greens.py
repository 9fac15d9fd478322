"""Surface Green's functions of a layered viscoelastic half-space (docs/formulation.md).

A unit point force on the soil surface at the origin, direction j; surface displacement at
(x, y) = r (cos θ, sin θ), in radial form (complex, functions of r only):

* vertical load (j = z):    u_z = A(r),  u_r = B(r)      (u_x = B cos θ, u_y = B sin θ)
* horizontal load (j = x):  u_r = C(r) cos θ,  u_θ = -D(r) sin θ,  u_z = E(r) cos θ, E = -B
                            (u_x = C cos²θ + D sin²θ,  u_y = (C - D) sin θ cos θ)

Conventions: SI, z up, e^{+iωt}, complex moduli G*(ω) of ``Material.complex_shear_modulus``
(hysteretic or causal damping, same ν); every kernel at ω uses G*(ω).

Method (production, ``regular_green``)
-------------------------------------
Exact layer stiffness matrices (Kausel-Roësset) in the wavenumber domain
(``greens_layers``), Hankel transforms

    A = 1/2π ∫ Fzz k J0(kr) dk,     B = 1/2π ∫ Fb k J1(kr) dk,
    C = 1/2π ∫ [Fkk (J0 - J1/kr) + Ftt J1/kr] k dk,   D = same with Fkk <-> Ftt,

with the **static top half-space kernel subtracted in the k domain** (so the integrand is
bounded at k -> 0 and decays at k -> ∞), and the leading dynamic tail c/k³ of the top
material subtracted too through (2c/a²)(1/k - 1/sqrt(k² + a²)), whose transforms are
closed forms. The path runs above the real k axis up to k_c (Rayleigh/Love poles of
undamped media), then along it (``greens_rule``). Why this and not the thin-layer method:
the BEM needs the regular part at r = 0 and at r ~ a patch size, and at ω = 0; TLM+PML
gives neither (its near field is that of the discretised medium, and PML needs ω > 0).
This kernel is exact for any layer thickness and at every frequency including 0; its only
error is quadrature, controlled by ``GreenRule`` and tested by refinement.

Independent checks (tests): ``greens_exact`` (Lamb's closed-form half-space kernel,
adaptive quadrature), a transfer-matrix (expm) layer stiffness, and static limits.
"""
from __future__ import annotations

import numpy as np

from .greens_layers import material_constants, static_flexibility, surface_flexibility
from .greens_rule import GreenRule, KGrid

__all__ = ["static_radial", "regular_green", "GreenRule", "KGrid", "radial_kernels"]

_TWO_PI = 2.0 * np.pi


def static_radial(material, r, omega=None):
    """Static half-space (Boussinesq/Cerruti) surface kernels with the complex G*(ω) of ``material``.

    Parameters
    ----------
    material : Material
    r : array_like, m, r > 0
    omega : float, rad/s: the frequency of G* (None: hysteretic materials only)

    Returns
    -------
    A, B, C, D : complex ndarrays shaped like r, m/N
    """
    r = np.asarray(r, dtype=float)
    G = material.complex_shear_modulus(omega)
    nu = material.poisson
    base = 1.0 / (2.0 * np.pi * G * r)
    return (1.0 - nu) * base, 0.5 * (1.0 - 2.0 * nu) * base, base + 0j * r, (1.0 - nu) * base


def _bessel(x, real):
    """J0, J1, J1(x)/x for x (n_r, n_k); exact limits at x = 0."""
    from scipy import special      # start-up cost: only a BEM sweep loads it (a cached run does not)
    if real:
        x = x.real
        j0, j1 = special.j0(x), special.j1(x)
    else:
        j0, j1 = special.jv(0, x), special.jv(1, x)
    small = np.abs(x) < 1e-4
    j1x = np.where(small, 0.5 - x * x / 16.0, j1 / np.where(small, 1.0, x))
    return j0, j1, j1x


def _tail_coefficients(material, omega, rule):
    """c_j with F_j - F0_j ~ c_j / k³ (k -> ∞) for the half-space of ``material``."""
    from .profile import SoilProfile

    _, ks2, _ = material_constants(material, omega)
    ks = np.sqrt(abs(ks2))
    ka = np.array([rule.asym_probe * ks], dtype=complex)
    F = surface_flexibility(SoilProfile((), material), omega, ka)
    F0 = static_flexibility(material, ka, omega)
    c = [((f - f0) * ka ** 3)[0] for f, f0 in zip(F, F0)]
    return c


def _tail(k, c, a):
    """Subtracted k-domain tail (2c/a²)(1/k - 1/sqrt(k²+a²)) ~ c/k³."""
    return 2.0 * c / a ** 2 * (1.0 / k - 1.0 / np.sqrt(k * k + a * a))


def _tail_transforms(r, c, a):
    """(1/2π) × Hankel transforms of ``_tail``: kernels k J0, J1/r (= k J1/(kr)) and k J1."""
    x = a * r
    small = x < 0.1
    xs = np.where(small, 1.0, x)
    t0 = np.where(small, 1.0 - x / 2 + x ** 2 / 6 - x ** 3 / 24 + x ** 4 / 120,
                  -np.expm1(-xs) / xs)
    t1 = np.where(small, 0.5 - x / 6 + x ** 2 / 24 - x ** 3 / 120 + x ** 4 / 720,
                  (xs + np.expm1(-xs)) / xs ** 2)
    # kernel k J1: 1/r - ∫ k J1/sqrt(k²+a²) dk = 1/r - (a/2)(I0 K1 - I1 K0)(ar/2)
    from scipy import special      # start-up cost (as in _bessel)
    y = 0.5 * np.where(x < 1e-4, 1.0, x)
    q = special.i0e(y) * special.k1e(y) - special.i1e(y) * special.k0e(y)
    tb = np.where(x < 1e-4, 0.0, 1.0 / (2.0 * y) - 0.5 * q)
    scale = 2.0 * c / a / _TWO_PI
    return scale * t0, scale * t1, scale * tb


def radial_kernels(F, grid: KGrid, r):
    """Hankel transforms of k-domain kernels F = (Fzz, Fb, Fkk, Ftt) on ``grid`` at radii r.

    Returns (A, B, C, D), complex ndarrays shape (n_r,), with the 1/2π factor.
    """
    Fzz, Fb, Fkk, Ftt = F
    k, w = grid.nodes, grid.weights
    wk = w * k / _TWO_PI
    out = [np.zeros(r.shape, dtype=complex) for _ in range(4)]
    nc = grid.n_contour
    for sl, real in ((slice(0, nc), False), (slice(nc, None), True)):
        if sl.start == sl.stop:
            continue
        j0, j1, j1x = _bessel(np.outer(r, k[sl]), real)
        wks = wk[sl]
        out[0] += j0 @ (Fzz[sl] * wks)
        out[1] += j1 @ (Fb[sl] * wks)
        fk, ft = Fkk[sl] * wks, Ftt[sl] * wks
        jk = j1x @ fk
        jt = j1x @ ft
        out[2] += j0 @ fk - jk + jt
        out[3] += j0 @ ft - jt + jk
    return tuple(out)


def regular_green(profile, omega, r, rule=None):
    """Regular part of the layered dynamic surface Green's functions.

    Full dynamic layered solution minus ``static_radial(profile.top, r, omega)``; finite at r = 0
    (C(0) = D(0); B(0) = 0).

    Parameters
    ----------
    profile : SoilProfile
    omega : float, rad/s, >= 0 (0: static layered minus static top half-space)
    r : array_like, m, >= 0, any shape
    rule : GreenRule or None (default rule)

    Returns
    -------
    A, B, C, D : complex ndarrays shaped like r, m/N
    """
    rule = GreenRule() if rule is None else rule
    omega = float(omega)
    r = np.asarray(r, dtype=float)
    if omega < 0 or not np.isfinite(omega):
        raise ValueError(f"omega = {omega!r} rad/s must be finite and >= 0")
    if r.size and (np.min(r) < 0 or not np.all(np.isfinite(r))):
        raise ValueError("r must be finite and >= 0 (m)")
    shape = r.shape
    rf = r.ravel()
    if omega == 0.0 and profile.is_homogeneous:
        return tuple(np.zeros(shape, dtype=complex) for _ in range(4))
    grid = rule.discretize(profile, omega, rf.max() if rf.size else 0.0)
    k = grid.nodes
    F = surface_flexibility(profile, omega, k)
    F0 = static_flexibility(profile.top, k, omega)
    dF = [f - f0 for f, f0 in zip(F, F0)]
    tails = None
    if omega > 0:
        c, a = _tail_coefficients(profile.top, omega, rule), grid.tail_a
        for j in range(4):
            dF[j] = dF[j] - _tail(k, c[j], a)
        tails = [_tail_transforms(rf, c[j], a) for j in range(4)]
    A, B, C, D = radial_kernels(dF, grid, rf)
    if tails is not None:
        (a0, _, _), (_, _, b0), (k0, k1, _), (t0, t1, _) = tails
        A = A + a0
        B = B + b0
        C = C + k0 - k1 + t1
        D = D + t0 - t1 + k1
    return tuple(v.reshape(shape) for v in (A, B, C, D))

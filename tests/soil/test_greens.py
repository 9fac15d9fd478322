"""Surface Green's functions of layered half-spaces (soil_impedance.greens*).

Error measure: |g - g_ref| / |g_full_static(max(r, 1 m))| where g_full_static is the static
half-space value of the same component (the size of the full Green's function at r).
"""
import math
from dataclasses import replace

import numpy as np
import pytest
import scipy.linalg as sl

from soil_impedance.greens import GreenRule, radial_kernels, regular_green, static_radial
from soil_impedance.greens_exact import (exact_regular_halfspace, lamb_flexibility,
                                         reference_regular)
from soil_impedance.greens_layers import (_psv_layer_stiffness, material_constants,
                                          static_flexibility, surface_flexibility)
from soil_impedance.greens_rule import KGrid
from soil_impedance.profile import Layer, Material, SoilProfile

HS = Material(vs=500.0, rho=2000.0, nu=0.3, damping=0.0)
SOFT = Layer(vs=300.0, rho=1900.0, nu=0.35, damping=0.05, thickness=5.0)
MID = Layer(vs=600.0, rho=2000.0, nu=0.3, damping=0.03, thickness=15.0)
ROCK = Material(vs=1500.0, rho=2300.0, nu=0.25, damping=0.01)
R = np.array([0.0, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 40.0])


def scale(material, r):
    """|static half-space kernels| at max(r, 1 m), shape (4, n_r)."""
    return np.abs(np.array(static_radial(material, np.maximum(r, 1.0))))


def err(g, ref, material, r):
    return np.max(np.abs(np.array(g) - np.array(ref)) / scale(material, r), axis=1)


# --- static half-space -----------------------------------------------------------------

def test_static_radial_closed_forms_and_sign():
    m = Material(vs=400.0, rho=1800.0, nu=0.25)
    G = m.shear_modulus
    A, B, C, D = static_radial(m, np.array([2.0]))
    assert np.allclose([A[0], B[0], C[0], D[0]],
                       [0.75 / (4 * math.pi * G), 0.5 / (8 * math.pi * G),
                        1 / (4 * math.pi * G), 0.75 / (4 * math.pi * G)], rtol=1e-14)
    # an upward pull moves nearby surface points up and outward
    assert A[0].real > 0 and B[0].real > 0
    # complex modulus
    md = replace(m, damping=0.05)
    assert np.isclose(static_radial(md, 1.0)[0], static_radial(m, 1.0)[0] / (1 + 0.1j))


def test_static_kernel_k_domain_integrates_to_closed_forms():
    """Hankel transforms of the k-domain static kernels (with e^{-εk}) -> Boussinesq/Cerruti."""
    m = Material(vs=400.0, rho=1800.0, nu=0.25, damping=0.02)
    eps, r = 0.01, np.array([1.0, 3.0, 10.0])
    edges = np.linspace(0.0, 3000.0, 60001)
    x, w = np.polynomial.legendre.leggauss(8)
    mid, half = 0.5 * (edges[1:] + edges[:-1]), 0.5 * np.diff(edges)
    k = (mid[:, None] + half[:, None] * x).ravel()
    wt = (half[:, None] * w).ravel()
    grid = KGrid(k + 0j, wt * np.exp(-eps * k) + 0j, 0, 0.0, 0.0, 3000.0, 0.05)
    got = np.array(radial_kernels(static_flexibility(m, k), grid, r))
    # closed forms of the regularised transforms: ∫J0 e^{-εk} = 1/ρ, ∫J1 e^{-εk} = (1-ε/ρ)/r,
    # ∫J1(kr)/(kr) e^{-εk} = (ρ-ε)/r², ρ = sqrt(r²+ε²); then ε -> 0 gives static_radial
    rho = np.hypot(r, eps)
    i0, i1, i1x = 1 / rho, (1 - eps / rho) / r, (rho - eps) / r ** 2
    c = [f * 1.0 for f in static_flexibility(m, np.ones(1))]
    ref = np.array([c[0] * i0, c[1] * i1, c[2] * (i0 - i1x) + c[3] * i1x,
                    c[3] * (i0 - i1x) + c[2] * i1x]) / (2 * math.pi)
    assert np.max(np.abs(got - ref) / np.abs(ref)) < 1e-6
    closed = np.array(static_radial(m, r))
    assert np.max(np.abs(ref - closed) / np.abs(closed)) < 1.1 * eps / r[0]  # ε -> 0 limit


def test_layer_kernels_match_lamb_and_static():
    """Stiffness-matrix kernels vs Lamb's closed form (independent formulas), incl. ω = 0."""
    p = SoilProfile((), replace(HS, damping=0.03))
    k = np.array([1e-4, 0.05, 0.2 + 0.01j, 0.3, 3.0, 30.0], dtype=complex)
    for omega in (10.0, 80.0, 600.0):  # |k/ks| < 1e3: Lamb's R(k) loses (k/ks)² digits
        a = np.array(surface_flexibility(p, omega, k))
        b = np.array(lamb_flexibility(p.top, omega, k))
        assert np.max(np.abs(a / b - 1)) < 1e-8
    a = np.array(surface_flexibility(p, 0.0, k))
    b = np.array(static_flexibility(p.top, k))
    assert np.max(np.abs(a / b - 1)) < 1e-12


def _layer_stiffness_expm(mat, omega, k, h):
    """Independent P-SV layer stiffness from the transfer matrix expm(A h) (small k h only)."""
    G = mat.complex_shear_modulus()
    nu = mat.poisson
    lam, M = 2 * G * nu / (1 - 2 * nu), 2 * G * (1 - nu) / (1 - 2 * nu)
    rw2 = mat.rho * omega ** 2
    A = np.zeros((4, 4), complex)  # y = (U, W, τx, τζ), depth ζ, e^{-ikx}
    A[0, 1], A[0, 2] = 1j * k, 1 / G
    A[1, 0], A[1, 3] = 1j * lam * k / M, 1 / M
    A[2, 0] = -rw2 + 1j * k * (-1j * k * M + 1j * lam * lam * k / M)
    A[2, 3] = 1j * k * lam / M
    A[3, 1], A[3, 2] = -rw2, 1j * k
    T = sl.expm(A * h)
    T11, T12, T21, T22 = T[:2, :2], T[:2, 2:], T[2:, :2], T[2:, 2:]
    iT12 = np.linalg.inv(T12)
    return np.block([[iT12 @ T11, -iT12], [T21 - T22 @ iT12 @ T11, T22 @ iT12]])


@pytest.mark.parametrize("omega", [0.0, 1e-3, 20.0, 150.0])
def test_layer_stiffness_vs_transfer_matrix(omega):
    for k in (0.05, 0.3, 0.9 + 0.05j):
        G, ks2, g2 = material_constants(SOFT, omega)
        K1 = _psv_layer_stiffness(np.array([k], complex), G, ks2, g2, 4.0)[0]
        K2 = _layer_stiffness_expm(SOFT, omega, k, 4.0)
        assert np.max(np.abs(K1 - K2)) / np.max(np.abs(K2)) < 1e-9


# --- homogeneous half-space ------------------------------------------------------------

def test_homogeneous_static_is_zero_and_low_frequency_vanishes():
    p = SoilProfile((), HS)
    assert all(np.all(g == 0) for g in regular_green(p, 0.0, R))
    e = [np.max(err(regular_green(p, 2 * math.pi * f, R), np.zeros((4, R.size)), HS, R))
         for f in (0.01, 0.1, 1.0)]
    # relative size ~ ks r (0.006 at 0.01 Hz, r = 40 m), linear in ω (leading term -iω·const)
    assert e[0] < 1e-2 and 8 < e[1] / e[0] < 12


@pytest.mark.parametrize("a0,damping", [(0.5, 0.0), (1.0, 0.0), (2.0, 0.0), (1.0, 0.05)])
def test_homogeneous_vs_exact_lamb(a0, damping):
    """Production kernel vs independent Lamb kernel, R = 10 m, Vs = 500 m/s. Tol 1e-3
    (measured ~1e-5)."""
    m = replace(HS, damping=damping)
    omega = a0 * m.vs / 10.0
    g = regular_green(SoilProfile((), m), omega, R)
    ref = exact_regular_halfspace(m, omega, R)
    assert np.max(err(g, ref, m, R)) < 1e-3
    assert abs(g[2][0] - g[3][0]) < 1e-12 * abs(g[2][0]) and g[1][0] == 0


def test_identical_layers_equal_homogeneous():
    m = replace(HS, damping=0.02)
    lay = Layer(vs=m.vs, rho=m.rho, nu=m.nu, damping=m.damping, thickness=3.0)
    for omega in (0.0, 30.0, 150.0):
        a = np.array(regular_green(SoilProfile((lay, lay, lay), m), omega, R))
        b = np.array(regular_green(SoilProfile((), m), omega, R))
        assert np.max(np.abs(a - b) / scale(m, R)) < 1e-9


# --- layered ---------------------------------------------------------------------------

def test_soft_layer_on_rock_static():
    """Static: stiffer material below => smaller displacements: regular A(0), C(0) < 0;
    thin layer (h/r <= 0.01) => regular part = static(rock) - static(top)."""
    p = SoilProfile((SOFT,), ROCK)
    A, B, C, D = regular_green(p, 0.0, R)
    assert A[0].real < 0 and C[0].real < 0 and D[0].real < 0
    thin = SoilProfile((replace(SOFT, thickness=0.01),), ROCK)
    r = np.array([1.0, 5.0, 20.0])
    g = regular_green(thin, 0.0, r)
    ref = np.array(static_radial(ROCK, r)) - np.array(static_radial(SOFT, r))
    assert np.max(err(g, ref, SOFT, r)) < 1e-2


def test_thick_damped_layer_equals_its_halfspace():
    """A 1 km damped layer hides the rock (waves die out, e^{-2kh} ~ 0): tol 1e-4."""
    top = replace(SOFT, thickness=1000.0)
    omega = 2 * math.pi * 10.0
    a = np.array(regular_green(SoilProfile((top,), ROCK), omega, R))
    b = np.array(regular_green(SoilProfile((), Material(vs=300.0, rho=1900.0, nu=0.35,
                                                        damping=0.05)), omega, R))
    assert np.max(np.abs(a - b) / scale(SOFT, R)) < 1e-4


@pytest.mark.parametrize("f", [2.0, 25.0])
def test_undamped_layered_vs_independent_quadrature(f):
    """Rayleigh/Love poles on the real axis: production (polygon contour, Gauss panels, k^-3
    tail subtraction) vs reference (half ellipse, dense Simpson, no subtraction) on the same
    kernel (itself checked against expm above). Tol 1e-3 (measured <1e-4)."""
    layers = (replace(SOFT, damping=0.0), replace(MID, damping=0.0))
    p = SoilProfile(layers, replace(ROCK, damping=0.0))
    r = np.array([0.0, 1.0, 5.0, 20.0, 60.0])
    omega = 2 * math.pi * f
    ref = reference_regular(layers[0], lambda w, k: surface_flexibility(p, w, k), omega, r,
                            vs_min=300.0, h1=5.0)
    assert np.max(err(regular_green(p, omega, r), ref, SOFT, r)) < 1e-3


@pytest.mark.parametrize("f", [8.5, 9.5])
def test_thickness_resonance_pole_above_axis(f):
    """10 m of Vs 200 on Vs 2000 rock near the P thickness resonance (9.4 Hz) has a pole at
    k ≈ 0.01 + 0.1i /m: a contour passing above it was 10x wrong (found via BEM passivity).
    Tol 1e-3 vs the independent quadrature (measured <2e-4); radiation: Im A(0) < 0."""
    top = Layer(vs=200.0, rho=1800.0, nu=0.3, damping=0.0, thickness=10.0)
    p = SoilProfile((top,), Material(vs=2000.0, rho=2400.0, nu=0.25))
    r = np.array([0.0, 0.5, 1.0, 2.0, 5.0, 10.0])
    omega = 2 * math.pi * f
    g = regular_green(p, omega, r)
    ref = reference_regular(top, lambda w, k: surface_flexibility(p, w, k), omega, r,
                            vs_min=200.0, h1=10.0)
    assert np.max(err(g, ref, top, r)) < 1e-3
    assert g[0][0].imag < 0 and g[2][0].imag < 0


def test_low_frequency_continuous_with_static_layered():
    p = SoilProfile((SOFT, MID), ROCK)
    g0 = regular_green(p, 0.0, R)
    g1 = regular_green(p, 2 * math.pi * 0.01, R)
    assert np.max(err(g1, g0, SOFT, R)) < 1e-3
    assert np.all(np.isfinite(np.array(g1)))


# --- rule ------------------------------------------------------------------------------

def test_rule_scales_with_frequency_as_documented():
    p = SoilProfile((SOFT, MID), ROCK)
    rule = GreenRule()
    g1, g2 = rule.discretize(p, 20.0, 60.0), rule.discretize(p, 40.0, 60.0)
    assert math.isclose(g1.k_c, rule.kc_factor * 20.0 / 300.0)
    assert math.isclose(g2.k_c, 2 * g1.k_c)
    ks_top = 40.0 * math.sqrt(SOFT.rho / abs(SOFT.complex_shear_modulus()))
    assert math.isclose(g2.k_max, max(rule.kmax_ks * ks_top, rule.kmax_depth / 5.0,
                                      2 * g2.k_c))
    assert g2.height <= rule.bessel_growth / 60.0 + 1e-15
    assert np.all(g1.nodes[:g1.n_contour].imag > 0) and np.all(g1.nodes[g1.n_contour:].imag == 0)
    s = rule.discretize(p, 0.0, 60.0)
    assert s.n_contour == 0 and s.k_c == 0
    assert math.isclose(rule.refined(2).discretize(p, 20.0, 60.0).panel_width,
                        g1.panel_width / 2)


@pytest.mark.parametrize("f", [0.0, 2.0, 10.0, 25.0])
@pytest.mark.parametrize("damped", [True, False])
def test_rule_refinement_converged(f, damped):
    """Refining the rule (panels /2, K_max x2) changes the result by < 1e-3 (measured
    <~3e-5) at r in [0, 60] m."""
    layers = (SOFT, MID) if damped else (replace(SOFT, damping=0.0), replace(MID, damping=0.0))
    p = SoilProfile(layers, ROCK if damped else replace(ROCK, damping=0.0))
    r = np.linspace(0.0, 60.0, 121)
    a = regular_green(p, 2 * math.pi * f, r)
    b = regular_green(p, 2 * math.pi * f, r, GreenRule().refined(2))
    assert np.max(err(a, b, SOFT, r)) < 1e-3


@pytest.mark.parametrize("f", [1.0, 25.0])
def test_path_independence_inverted_profile(f):
    """Cauchy: a higher contour (b x2, Bessel growth e^4) and a farther tail branch point give
    the same integral (the tail's branch point ia must stay above the path). Tol 1e-4."""
    p = SoilProfile((replace(MID, thickness=10.0), replace(SOFT, nu=0.45)), ROCK)
    r = np.linspace(0.0, 60.0, 61)
    a = regular_green(p, 2 * math.pi * f, r)
    b = regular_green(p, 2 * math.pi * f, r, GreenRule(height=0.5, bessel_growth=4.0,
                                                       tail_clearance=6.0, asym_scale=2.0))
    assert np.max(err(a, b, MID, r)) < 1e-4


def test_shapes_and_validation():
    p = SoilProfile((SOFT,), ROCK)
    r = np.array([[0.0, 1.0], [2.0, 3.0]])
    out = regular_green(p, 10.0, r)
    assert all(o.shape == (2, 2) and o.dtype == complex for o in out)
    with pytest.raises(ValueError):
        regular_green(p, -1.0, r)
    with pytest.raises(ValueError):
        regular_green(p, 1.0, np.array([-1.0]))

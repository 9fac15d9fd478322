"""Causal constant-Q soil damping (``damping_model = "causal"``, soil_impedance.profile).

Checks: the modulus satisfies the Kramers-Kronig relation (and the hysteretic and anti-causal
models fail it), its limits (real static value, loss factor -> 2ξ, vs at the reference
frequency), and the BEM with the causal material: statics scale with G0, and at any ω the disk
impedance is that of the hysteretic material having the same complex G*(ω) (every kernel of the
BEM uses G*(ω)); the layered Green's functions against Lamb's exact kernel with the causal G*.
"""
import math

import numpy as np
import pytest
from scipy import integrate

from soil_impedance import Material, SoilError, SoilProfile, SurfaceBem, circle_mesh, rigid_transform
from soil_impedance.greens import regular_green
from soil_impedance.greens_exact import exact_regular_halfspace
from soil_impedance.profile import CAUSAL_CUTOFF_HZ, CAUSAL_REFERENCE_HZ, causal_factor

W1 = 2 * math.pi * CAUSAL_CUTOFF_HZ
XI = 0.05


def _mat(model="causal", damping=XI, **kw):
    kw = {"vs": 200.0, "rho": 2000.0, "nu": 0.3, **kw}
    return Material(damping=damping, damping_model=model, **kw)


def _kk_imag(G, omega):
    """Im G(ω) from Re G by the once-subtracted Kramers-Kronig relation of a causal modulus
    (e^{+iωt}: G analytic for Im ω < 0, i.e. Re s > 0):

        Im G(ω) = (2ω/π) ∫_0^∞ (Re G(ω') − Re G(ω)) / (ω'² − ω²) dω'

    (principal value; the subtraction removes the pole, ∫_0^∞ dω'/(ω'² − ω²) = 0 in PV).
    Integrated in u = ln(ω'/ω) over |u| < 60 (the integrand decays like e^{−(1−2γ)|u|})."""
    re0 = G(omega).real

    def f(u):
        if abs(u) < 1e-7:   # removable singularity: d Re G/dω' / (2ω) · ω'
            h = 1e-6 * omega
            return (G(omega + h).real - G(omega - h).real) / (2 * h) / (2 * omega) * omega
        w = omega * math.exp(u)
        return (G(w).real - re0) / (w * w - omega * omega) * w

    parts = [integrate.quad(f, a, b, limit=400, epsabs=0, epsrel=1e-11)[0]
             for a, b in ((-60, -5), (-5, 0), (0, 5), (5, 60))]
    return 2 * omega / math.pi * sum(parts)


@pytest.mark.parametrize("omega", [0.1 * W1, W1, 20 * W1, 2000 * W1])
def test_causal_modulus_satisfies_kramers_kronig(omega):
    m = _mat()
    G = m.complex_shear_modulus
    assert np.isclose(_kk_imag(G, omega), G(omega).imag, rtol=1e-9)
    # the relation has teeth: the hysteretic model (Re constant) and the anti-causal mirror fail it
    hyst = _mat("hysteretic").complex_shear_modulus
    assert abs(_kk_imag(hyst, omega)) < 1e-9 * abs(hyst(omega).imag)
    anti = lambda w: np.conj(G(w))
    assert np.isclose(_kk_imag(anti, omega), -anti(omega).imag, rtol=1e-9)


def test_causal_modulus_analytic_in_right_half_plane():
    """G0 (1 + s/ω1)^{2γ} is analytic for Re s > −ω1: its Cauchy integral on a circle of the
    right half s-plane reproduces it inside, and the circle integral of G itself vanishes."""
    s0, rad = 3.0 * W1 + 5.0j * W1, 2.5 * W1
    theta = np.linspace(0, 2 * np.pi, 4001)[:-1]
    s = s0 + rad * np.exp(1j * theta)
    g = causal_factor(s / 1j, W1, XI)            # ω = s / i: the factor is a function of iω
    ds = 1j * rad * np.exp(1j * theta) * (2 * np.pi / theta.size)
    assert abs(np.sum(g * ds)) < 1e-12 * rad
    z = s0 + 0.7 * rad * np.exp(0.3j)
    cauchy = np.sum(g / (s - z) * ds) / (2j * np.pi)
    assert np.isclose(cauchy, causal_factor(z / 1j, W1, XI), rtol=1e-12)
    assert np.allclose(causal_factor(-np.array([0.3, 7.0]), W1, XI),
                       np.conj(causal_factor(np.array([0.3, 7.0]), W1, XI)), rtol=1e-15)   # real response


def test_causal_modulus_limits_and_normalisation():
    m = _mat()
    G_ref = m.rho * m.vs ** 2
    g0 = m.complex_shear_modulus(0.0)
    assert g0.imag == 0.0 and 0.8 * G_ref < g0.real < G_ref
    # vs holds at the reference frequency
    assert np.isclose(m.complex_shear_modulus(2 * math.pi * CAUSAL_REFERENCE_HZ).real, G_ref, rtol=1e-14)
    # loss factor -> 2ξ well above ω1, ~ (2γ ω/ω1) below it (viscous), half at ω1
    w = np.array([1e-3, 1.0, 1e2, 1e4]) * W1
    g = m.complex_shear_modulus(w)
    loss = g.imag / g.real
    gamma = math.atan(2 * XI) / math.pi
    assert np.isclose(loss[0], 2 * gamma * 1e-3, rtol=1e-3)
    assert np.isclose(loss[1], math.tan(gamma * math.pi / 2), rtol=1e-12)
    assert abs(loss[2] / (2 * XI) - 1) < 1e-2 and abs(loss[3] / (2 * XI) - 1) < 1e-4
    # dispersion: Re G grows by (4ξ/π)(1 + O(ξ²)) per e-fold far above ω1
    slope = math.log(g[3].real / g[2].real) / math.log(100.0)
    assert np.isclose(slope, 2 * gamma, rtol=1e-3) and np.isclose(slope, 4 * XI / math.pi, rtol=5e-3)
    # no damping: the causal model is the elastic one
    e = _mat(damping=0.0).complex_shear_modulus(np.array([0.0, 3.0, 300.0]))
    assert np.all(e == G_ref)


def test_causal_modulus_needs_frequency_and_model_validated():
    with pytest.raises(SoilError, match="needs omega"):
        _mat().complex_shear_modulus()
    with pytest.raises(SoilError, match="damping_model = 'viscous'.*'hysteretic', 'causal'"):
        _mat("viscous")
    # the hysteretic model ignores ω and broadcasts
    h = _mat("hysteretic")
    assert np.all(h.complex_shear_modulus(np.zeros(3)) == h.complex_shear_modulus())
    assert SoilProfile((), _mat()).is_homogeneous
    from soil_impedance import Layer
    lay = Layer(vs=200.0, rho=2000.0, nu=0.3, damping=XI, thickness=2.0)   # hysteretic layer
    assert not SoilProfile((lay,), _mat()).is_homogeneous


MESH = circle_mesh(6.0, 2.0)


def _rigid(material, omega):
    bem = SurfaceBem(SoilProfile((), material), MESH)
    T = rigid_transform(MESH)
    return T.T @ bem.solve(omega, T)


def test_disk_statics_scale_with_static_modulus():
    """Homogeneous statics: K is proportional to G*, so K_causal(0) = K_hyst(0) G0 / (ρvs²(1+2iξ))."""
    c, h = _mat(), _mat("hysteretic")
    ratio = c.complex_shear_modulus(0.0) / h.complex_shear_modulus()
    Kc, Kh = _rigid(c, 0.0), _rigid(h, 0.0)
    assert np.abs(Kc.imag).max() < 1e-12 * np.abs(Kc).max()
    assert np.allclose(Kc, Kh * ratio, rtol=1e-12, atol=1e-12 * np.abs(Kh).max())
    # the Winkler springs' calibration: the relaxed K(0) brought to the moduli rho vs^2
    k_ref = SoilProfile((), c).static_to_reference
    assert k_ref > 1.05 and SoilProfile((), h).static_to_reference == 1.0
    assert np.allclose(k_ref * Kc, Kh.real, rtol=1e-12, atol=1e-12 * np.abs(Kh).max())


@pytest.mark.parametrize("f_hz", [0.2, 6.0])
def test_disk_dynamic_equals_hysteretic_with_same_modulus(f_hz):
    """At ω the causal material is the hysteretic one with Re G = Re G*(ω), 2ξ' = Im/Re G*(ω)
    (same ρ, ν): its BEM impedance must be the same (every kernel uses G*(ω), the static singular
    part included); it differs from the nominal hysteretic table by the dispersion."""
    omega = 2 * math.pi * f_hz
    c = _mat()
    g = c.complex_shear_modulus(omega)
    eq = _mat("hysteretic", damping=g.imag / (2 * g.real), vs=math.sqrt(g.real / c.rho))
    assert np.isclose(eq.complex_shear_modulus(), g, rtol=1e-14)
    Kc, Ke, Kh = _rigid(c, omega), _rigid(eq, omega), _rigid(_mat("hysteretic"), omega)
    scale = np.abs(Kc).max()
    assert np.abs(Kc - Ke).max() < 1e-10 * scale
    assert np.abs(Kc - Kh).max() > 1e-2 * scale


def test_green_causal_against_lamb_exact_kernel():
    """Production layered kernel vs Lamb's closed-form kernel (independent path), causal G*(ω)."""
    m = _mat()
    omega, r = 2 * math.pi * 8.0, np.array([0.0, 3.0, 15.0])
    got = np.array(regular_green(SoilProfile((), m), omega, r))
    ref = np.array(exact_regular_halfspace(m, omega, r))
    scale = np.abs(ref).max()
    assert np.abs(got - ref).max() < 2e-4 * scale   # measured 4.5e-5
    hyst = np.array(regular_green(SoilProfile((), _mat("hysteretic")), omega, r))
    assert np.abs(hyst - ref).max() > 0.05 * scale

"""Strain-compatible soil (orchestrator.site_response): the iterated properties against pystrata
run directly here (per layer G/Gmax and damping within 1 %), and the peak strain of a linear
layer on a rigid base against the closed-form transfer function."""
import math

import numpy as np
import pytest

from helpers import tower
from helpers.motions import broadband
from scipy.constants import g as G     # pystrata's g (the project's G is 9.81)
from orchestrator.soil_cases import parse_strain_compatible
from soil_impedance.profile import Layer, Material, SoilProfile

ps = pytest.importorskip("pystrata")          # 5-10 s to import, once per process (the tests themselves < 2 s)
from orchestrator.site_response import SiteResponseError, strain_compatible  # noqa: E402  (after the skip)

#: two soft layers over rock (a site where the strains matter)
SOFT = SoilProfile((Layer(vs=180.0, rho=1800.0, nu=0.35, damping=0.02, thickness=6.0, name="l0"),
                    Layer(vs=320.0, rho=1950.0, nu=0.3, damping=0.015, thickness=14.0, name="l1")),
                   Material(vs=900.0, rho=2300.0, nu=0.25, damping=0.01, name="hs"))
MOTION = broadband(0.15, duration=6.0, dt=0.005, seed=5)


@pytest.mark.parametrize("wave_field", ["outcrop", "within"])
def test_iterated_properties_match_pystrata_run_directly(wave_field):
    cfg = parse_strain_compatible({"curves": [{"model": "darendeli", "pi": 20.0, "ocr": 1.5, "k0": 0.6},
                                              "darendeli"], "input": wave_field}, 2)
    got = strain_compatible(SOFT, MOTION, 0.005, cfg)
    # the same analysis typed out with the library: dry overburden at mid-layer, mean stress
    # sigma_v (1 + 2 k0) / 3 in kPa, unit weights in kN/m^3, Darendeli with the layer's damping as Dmin
    g1, g2 = 1800.0 * G / 1000, 1950.0 * G / 1000
    s1, s2 = g1 * 3.0 * (1 + 1.2) / 3, (g1 * 6.0 + g2 * 7.0) * (1 + 1.0) / 3
    column = ps.site.Profile([
        ps.site.Layer(ps.site.DarendeliSoilType(g1, plas_index=20.0, ocr=1.5, stress_mean=s1, damping_min=0.02),
                      6.0, 180.0),
        ps.site.Layer(ps.site.DarendeliSoilType(g2, plas_index=0.0, ocr=1.0, stress_mean=s2, damping_min=0.015),
                      14.0, 320.0),
        ps.site.Layer(ps.site.SoilType("rock", 2300.0 * G / 1000, None, 0.01), 0, 900.0)])
    calc = ps.propagation.EquivalentLinearCalculator(strain_ratio=0.65, tolerance=0.01, max_iterations=15)
    calc(ps.motion.TimeSeriesMotion("m", "", 0.005, MOTION[:, 0] / G), column,
         column.location(wave_field, index=-1))
    ref_g = np.array([layer.shear_mod_reduc for layer in column[:-1]])
    ref_d = np.array([layer.damping for layer in column[:-1]])
    np.testing.assert_allclose(got.g_ratio, ref_g, rtol=0.01)
    np.testing.assert_allclose(got.damping, ref_d, rtol=0.01)
    assert got.converged and 1 <= got.iterations <= 15 and got.component == "x"
    assert np.all(got.g_ratio < 0.95) and np.all(got.damping > [0.02, 0.015])     # the soil did soften
    # the BEM profile: vs from G/Gmax at constant density, damping the iterated one, the rock as given
    for layer, base, g, d in zip(got.profile.layers, SOFT.layers, got.g_ratio, got.damping):
        assert layer.shear_modulus == pytest.approx(g * base.shear_modulus, rel=1e-12) and layer.damping == d
    assert got.profile.halfspace == SOFT.halfspace


def test_linear_layer_on_rigid_base_peak_strain_is_the_closed_form():
    """A linear layer (no curves) under a motion given *within* at its base: the base is then
    effectively rigid (the half-space below does not matter), and the strain at mid-depth per
    unit base acceleration is k* sin(k* H / 2) / (omega^2 cos(k* H)) with k* = omega / vs*,
    vs* = vs sqrt(sqrt(1 - 4 D^2) + 2i D) (pystrata's complex modulus). Peak of its time history,
    computed here with a longer FFT than the library's, against the reported peak strain."""
    H, vs, D = 15.0, 250.0, 0.05
    profile = SoilProfile((Layer(vs=vs, rho=1900.0, nu=0.3, damping=D, thickness=H, name="l"),),
                          Material(vs=1200.0, rho=2400.0, nu=0.3, damping=0.01, name="hs"))
    acc = np.vstack([MOTION, np.zeros((2000, 3))])                     # a quiet tail: no wrap-around
    got = strain_compatible(profile, acc, 0.005, parse_strain_compatible({"curves": "linear", "input": "within"}, 1))
    n = 4 * 2 ** math.ceil(math.log2(acc.shape[0]))
    w = 2 * np.pi * np.fft.rfftfreq(n, 0.005)
    k = w[1:] / (vs * np.sqrt(np.sqrt(1 - 4 * D ** 2) + 2j * D))
    tf = np.zeros(w.size, complex)
    tf[1:] = k * np.sin(k * H / 2) / (w[1:] ** 2 * np.cos(k * H))
    strain = np.fft.irfft(tf * np.fft.rfft(acc[:, 0], n), n)
    assert got.strain_max[0] == pytest.approx(np.abs(strain).max(), rel=2e-3)      # measured 1e-4 (outcrop: -12 %)
    assert got.strain_eff[0] == pytest.approx(0.65 * got.strain_max[0], rel=1e-9)
    assert got.g_ratio[0] == 1.0 and got.damping[0] == D and got.iterations == 1


def test_table_curves_and_cases_on_the_strain_compatible_profile():
    """User tables give G/Gmax and damping read on the table at the effective strain (log-linear);
    the Cv cases are built on the strain-compatible profile."""
    from orchestrator.design import design_cases
    from orchestrator.motion import make_motion
    from orchestrator.scene import scene_from_dict
    strains = [1e-6, 1e-5, 1e-4, 1e-3, 1e-2]
    table = {"model": "table", "strain": strains, "g_ratio": [1.0, 0.98, 0.8, 0.4, 0.1],
             "damping": [0.01, 0.015, 0.04, 0.1, 0.18]}
    data = tower(soil={"layers": [{"thickness": 10.0, "vs": 200.0, "nu": 0.3, "rho": 1900.0, "damping": 0.01}],
                       "halfspace": {"vs": 800.0, "nu": 0.3, "rho": 2200.0, "damping": 0.01}, "winkler": None,
                       "cases": {"cv": 0.5}, "strain_compatible": {"curves": [table]}},
                 motion={"pga_g": 0.3, "duration_s": 4.0})
    scene = scene_from_dict(data)
    cases, site = design_cases(scene, make_motion(scene.motion, scene.analysis.dt))
    e = site.strain_eff[0]
    assert 1e-5 < e < 1e-2
    assert site.g_ratio[0] == pytest.approx(np.interp(np.log(e), np.log(strains), table["g_ratio"]), rel=0.01)
    assert site.damping[0] == pytest.approx(np.interp(np.log(e), np.log(strains), table["damping"]), rel=0.01)
    cases = dict(cases)
    assert cases["be"].profile == site.profile
    assert cases["ub"].profile.layers[0].shear_modulus == pytest.approx(1.5 * site.profile.layers[0].shear_modulus,
                                                                        rel=1e-14)


def test_a_vertical_motion_alone_is_refused():
    cfg = parse_strain_compatible({"curves": "linear"}, 2)
    acc = np.zeros((100, 3))
    acc[:, 2] = 1.0
    with pytest.raises(SiteResponseError, match="no horizontal component"):
        strain_compatible(SOFT, acc, 0.01, cfg)


def test_without_pystrata_the_message_says_how_to_install_it(monkeypatch):
    import sys
    monkeypatch.setitem(sys.modules, "pystrata", None)            # as if it were not installed
    with pytest.raises(SiteResponseError, match=r"needs pystrata .*pip install 'uplift-ssi\[site\]'"):
        strain_compatible(SOFT, MOTION, 0.005, parse_strain_compatible({"curves": "linear"}, 2))

"""Nigam-Jennings spectra: exact for piecewise-linear input (checked against a tight ODE solve
and a closed form), and peak broadening."""
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from orchestrator.spectra import broaden, response_spectra, response_spectrum


def test_matches_ode_for_piecewise_linear_input():
    dt = 0.02
    t = np.arange(0, 4, dt)
    a = np.sin(2 * np.pi * 1.3 * t) * np.exp(-t) + 0.3 * t * (t < 2)
    periods = np.array([0.1, 0.5, 1.0, 3.0])
    s = response_spectrum(a, dt, periods, 0.05)
    for T, sd in zip(periods, s.sd):
        w = 2 * np.pi / T
        sol = solve_ivp(lambda tt, y: [y[1], -np.interp(tt, t, a) - 2 * 0.05 * w * y[1] - w * w * y[0]],
                        (0, t[-1]), [0, 0], t_eval=t, rtol=1e-11, atol=1e-13, max_step=dt / 8)
        # the recurrence is exact; the reference only has its tolerance
        assert sd == pytest.approx(np.abs(sol.y[0]).max(), rel=1e-6)


def test_step_input_closed_form():
    # constant a_g = -1 from t = 0 (linear between samples): undamped peak u = 2/ω² at t = π/ω
    dt, T = 0.001, 0.5
    a = -np.ones(2001)
    a[0] = 0.0  # ramp over the first step: peak 2/ω² · |sin(ω dt/2)/(ω dt/2)| ~ 2/ω² (1 - 1e-5)
    s = response_spectrum(a, dt, [T], 0.0)
    w = 2 * np.pi / T
    assert s.sd[0] == pytest.approx(2 / w ** 2, rel=1e-4)
    assert s.psa[0] == pytest.approx(2.0, rel=1e-4)


def test_broadening_spreads_peak_by_15_percent():
    f = np.geomspace(1, 10, 400)
    v = np.exp(-((f - 4.0) / 0.05) ** 2)
    b = broaden(f, v, 0.15)
    plateau = f[b > 0.999 * v.max()]
    assert plateau.min() == pytest.approx(4.0 * 0.85, rel=0.01)
    assert plateau.max() == pytest.approx(4.0 * 1.15, rel=0.01)
    assert np.all(b >= v)


def test_many_histories_in_one_pass_are_each_history_alone():
    # the ensemble's floor spectra: every column's numbers are those of its own spectrum, bit for bit
    acc = np.random.default_rng(3).standard_normal((801, 5))
    periods = 1 / np.geomspace(0.5, 40.0, 30)
    for col, s in zip(acc.T, response_spectra(acc, 0.005, periods)):
        one = response_spectrum(col, 0.005, periods)
        assert all(np.array_equal(getattr(s, k), getattr(one, k)) for k in ("sd", "psv", "psa", "sa"))

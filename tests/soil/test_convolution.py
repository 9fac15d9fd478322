"""Recursive convolution of a rational soil model (soil_impedance.convolution).

Exactness claims tested here: the recursion's z-transform is K(s_b), s_b = (2i/dt) tan(ωdt/2),
to round-off (1e-12); the steady-state harmonic response equals it (1e-9, limited by the
decay of the start-up transient); it differs from K(iω) by O((ωdt)^2) (order fitted);
K_d(z = 1) = K(0) exactly (constant input). Invariants: work on a passive soil never
negative over 10^5 random steps, bounded response; rollback bit-identical.
"""
import warnings

import numpy as np
import pytest

from helpers import oscillator_model, random_passive_model
from soil_impedance.convolution import RecursiveConvolutionSoil, bilinear_coefficients, bilinear_s, recursion_transfer
from soil_impedance.passivity import check_passive
from soil_impedance.poles_free import convolve
from soil_impedance.rational import FitError

MODEL = random_passive_model(3, n_pairs=3, n_real=2, seed=1)   # poles 0.4 to 20 Hz


def harmonic_amplitude(soil, U, freq, dt, periods):
    """Complex amplitude F of f_n = Re(F e^{iωt_n}) after `periods` periods of u = Re(U e^{iωt})
    (xdot given exactly on the trapezoidal sequence: Re(s_b U e^{iωt}))."""
    P = int(round(1 / (freq * dt)))
    w = 2 * np.pi * freq
    sb = bilinear_s(freq, dt)
    t = dt * np.arange(1, P * periods + 1)
    ph = np.exp(1j * w * t)
    f = np.array([soil.step((U * e).real, (sb * U * e).real) for e in ph])
    return 2 / P * (f[-P:] * np.conj(ph[-P:])[:, None]).sum(axis=0)


def test_z_transform_is_the_bilinear_model():
    f = np.array([0.0, 0.37, 2.0, 9.5, 30.0])
    for dt in (0.002, 0.01, 0.03):
        Kd = recursion_transfer(MODEL, dt, f)
        Kb = MODEL(bilinear_s(f, dt))
        assert np.abs(Kd - Kb).max() <= 1e-12 * np.abs(Kb).max()
    # z = 1 (f = 0) is s = 0: the static stiffness exactly
    assert np.allclose(recursion_transfer(MODEL, 0.01, [0.0])[0], MODEL(np.zeros(1))[0], rtol=0, atol=1e-13)


@pytest.mark.parametrize("freq", [0.5, 2.0, 10.0])
def test_steady_state_harmonic_response_is_K_bilinear(freq):
    dt = 1 / (freq * 40)                     # 40 steps per period: ωdt = 0.157
    rng = np.random.default_rng(0)
    U = rng.standard_normal(3) + 1j * rng.standard_normal(3)
    soil = RecursiveConvolutionSoil(MODEL, dt)
    # run until the slowest pole transient (|a| closest to 1) has decayed below 1e-12
    a = np.abs((1 + MODEL.poles * dt / 2) / (1 - MODEL.poles * dt / 2)).max()
    periods = int(np.ceil(np.log(1e-12) / np.log(a) / 40)) + 1
    F = harmonic_amplitude(soil, U, freq, dt, periods)
    Fd = soil.transfer(freq)[0] @ U
    assert np.abs(F - Fd).max() <= 1e-9 * np.abs(Fd).max()


def test_frequency_warping_is_second_order():
    """|K_d(e^{iωdt}) − K(iω)| = O((ωdt)^2): the fitted order in dt is 2."""
    freq = np.array([0.6, 3.0, 12.0])
    dts = np.array([0.004, 0.002, 0.001])
    err = [np.abs(recursion_transfer(MODEL, dt, freq) - MODEL.frequency_response(freq)).max()
           / np.abs(MODEL.frequency_response(freq)).max() for dt in dts]
    rate = np.polyfit(np.log(dts), np.log(err), 1)[0]
    assert 1.95 < rate < 2.05, (rate, err)
    # and it is the frequency warping ω -> (2/dt) tan(ωdt/2) = ω (1 + (ωdt)^2/12 + ...):
    dt, w = dts[-1], 2 * np.pi * freq
    dw = w**3 * dt**2 / 12
    h = 1e-4 * w
    dK = (MODEL(1j * (w + h)) - MODEL(1j * (w - h))) / (2 * h)[:, None, None]
    pred = MODEL(1j * w) + dw[:, None, None] * dK
    Kd = recursion_transfer(MODEL, dt, freq)
    assert np.abs(Kd - pred).max() < 0.05 * np.abs(Kd - MODEL(1j * w)).max()


def test_constant_input_gives_static_force():
    soil = RecursiveConvolutionSoil(MODEL, 0.01)
    u = np.array([1.0, -2.0, 0.5])
    for _ in range(4000):
        f = soil.step(u, np.zeros(3))      # xdot = 0: the trapezoidal rate of a step would ring
    assert np.allclose(f, soil.static_stiffness() @ u, rtol=1e-10, atol=0)


def trapezoidal_signal(nt, n, dt, seed):
    """A random band-limited velocity v (AR(1) noise) and u integrated from it by the trapezoidal
    rule (as Newmark does), detrended consistently (u - c t, v - c): bounded, trapezoid-exact."""
    rng = np.random.default_rng(seed)
    e = rng.standard_normal((nt, n))
    v = np.empty((nt, n))
    v[0] = 0.0
    for k in range(1, nt):
        v[k] = 0.99 * v[k - 1] + e[k]
    u = np.concatenate([np.zeros((1, n)), np.cumsum(0.5 * dt * (v[1:] + v[:-1]), axis=0)])
    c = u[-1] / (dt * (nt - 1))
    t = dt * np.arange(nt)
    return u - t[:, None] * c, v - c


def test_random_input_1e5_steps_work_nonnegative_and_bounded():
    model = random_passive_model(4, n_pairs=3, n_real=1, seed=5)
    dt, nt = 0.005, 100_000
    soil = RecursiveConvolutionSoil(model, dt)
    u, v = trapezoidal_signal(nt, 4, dt, seed=2)
    W = np.empty(nt)
    fmax = np.empty(nt)
    for k in range(1, nt):
        fmax[k] = np.abs(soil.step(u[k], v[k])).max()
        W[k] = soil.dissipated_energy()
    W[0], fmax[0] = 0.0, 0.0
    # round-off scale of the work sum: |K| |u|^2 per step
    tol = 1e-13 * np.abs(soil.static_stiffness()).max() * (np.abs(u).max() ** 2) * nt
    assert W.min() >= -tol, W.min()
    assert W[-1] > 0
    # no growth: a rigorous bound of the stable recursion, and late peaks like early ones
    a, b = bilinear_coefficients(model.poles, dt)
    Rn = np.abs(model.residues).sum(axis=2).max(axis=1)
    bound = ((np.abs(model.D).sum(1).max() + (Rn * np.abs(b) * 2 / (1 - np.abs(a))).sum())
             * np.abs(u).max() + np.abs(model.E).sum(1).max() * np.abs(v).max())
    assert np.all(np.isfinite(fmax)) and fmax.max() <= bound
    tenth = nt // 10
    assert fmax[-tenth:].max() < 3 * fmax[tenth:2 * tenth].max()


def _nonpassive():
    W = np.eye(2)
    return oscillator_model(np.eye(2), 0.001 * np.eye(2), terms=[(1.0, 0.2, 1.0 / (2 * np.pi) ** 2, -0.5 * W)])


def test_nonpassive_model_is_refused_or_forced_with_warning():
    bad = _nonpassive()
    with pytest.raises(FitError, match="not passive"):
        RecursiveConvolutionSoil(bad, 0.01)
    with pytest.warns(Warning, match="not passive"):
        soil = RecursiveConvolutionSoil(bad, 0.01, force=True)
    # and it really is harmful: driven at its resonance (1 Hz) the soil does negative work
    dt = 0.01
    for k in range(1, 2001):
        soil.step(np.array([1.0, 0.0]) * np.sin(2 * np.pi * k * dt))
    assert soil.dissipated_energy() < 0


def test_exact_tests_find_the_closed_form_violation_band():
    """K = I (1 + k) + 0.001 s I − 0.5 k² I/(m s² + c s + k) (k = 1, c = 0.2, m = 1/(2π)²) has
    G(ω) = ω (0.001 − 0.5 k² c/((k − m ω²)² + c² ω²)): negative below the root ω_c of
    (k − m ω²)² + c² ω² = 500 k² c (ω_c = 2π·3.1925 Hz). Both exact tests find the band [0, ω_c];
    the passive MODEL has none (the sweep brackets the edge between two of its nodes)."""
    bad = _nonpassive()
    k, c, m = 1.0, 0.2, 1.0 / (2 * np.pi) ** 2
    y = np.roots([m * m, c * c - 2 * k * m, k * k - 500 * k * k * c])      # y = ω²
    f_c = np.sqrt(y[y > 0].max()) / (2 * np.pi)
    for method in ("hamiltonian", "sweep"):
        rep = check_passive(bad, method=method)
        assert not rep.passive and len(rep.bands_hz) == 1 and rep.bands_hz[0][0] == 0.0
        hi = rep.bands_hz[0][1]
        assert hi == pytest.approx(f_c, rel=1e-9) if method == "hamiltonian" else f_c <= hi < 1.1 * f_c
        assert check_passive(MODEL, method=method).passive


def test_passive_model_is_accepted_silently():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        RecursiveConvolutionSoil(MODEL, 0.01)


def test_save_restore_replays_bit_identically():
    soil = RecursiveConvolutionSoil(MODEL, 0.01)
    rng = np.random.default_rng(3)
    u = rng.standard_normal((600, 3))
    for k in range(300):
        soil.step(u[k])
    s = soil.get_state()
    run1 = [soil.step(u[k]) for k in range(300, 600)]
    e1 = soil.dissipated_energy()
    soil.instantaneous(0.004)                 # a different dt before the rollback
    soil.step(u[0])
    soil.set_state(s)
    run2 = [soil.step(u[k]) for k in range(300, 600)]
    assert np.array_equal(np.array(run1), np.array(run2))
    assert soil.dissipated_energy() == e1
    s["u"][:] = 1e9                            # the saved state is a copy
    assert np.all(np.abs(soil.get_state()["u"]) < 1e9)


def test_change_of_dt_mid_run():
    """dt -> dt/4 -> dt is the variable-step trapezoidal rule of the state-space model: equal
    (1e-12) to an independent pole-by-pole complex implementation, and more accurate than the
    uniform coarse run inside the fine window (against the exact response, FFT route)."""
    T, tp, dt = 4.0, 1.0, 0.02

    def u_of(t):
        t = np.atleast_1d(t)
        return (np.where(t < tp, np.sin(np.pi * t / tp) ** 4, 0.0))[:, None] * np.array([1.0, -0.5, 0.3])

    n1 = int(round(0.5 / dt))
    mixed = [dt] * n1 + [dt / 4] * (4 * 4 * n1) + [dt] * (3 * n1)
    coarse = [dt] * (8 * n1)
    times = {"mixed": np.cumsum(mixed), "coarse": np.cumsum(coarse)}
    out = {}
    for name, sched in (("mixed", mixed), ("coarse", coarse)):
        soil = RecursiveConvolutionSoil(MODEL, dt)
        f = []
        for h, t in zip(sched, times[name]):
            soil.instantaneous(h)
            f.append(soil.step(u_of(t)[0]))
        out[name] = np.array(f)
    # independent implementation: every pole on its own, complex states, same rule
    p, R = MODEL.poles, MODEL.residues
    y = np.zeros((p.size, 3), complex)
    u_prev, v_prev = np.zeros(3), np.zeros(3)
    f_ind = []
    for h, t in zip(mixed, times["mixed"]):
        u = u_of(t)[0]
        v = 2 / h * (u - u_prev) - v_prev
        a, b = bilinear_coefficients(p, h)
        y = a[:, None] * y + b[:, None] * (u + u_prev)
        f_ind.append(MODEL.D @ u + MODEL.E @ v + np.einsum("kij,kj->i", R, y).real)
        u_prev, v_prev = u, v
    scale = np.abs(out["coarse"]).max()
    assert np.abs(out["mixed"] - np.array(f_ind)).max() <= 1e-12 * scale
    # accuracy against the exact response
    h_ref = dt / 16
    f_ref = convolve(MODEL, u_of(h_ref * np.arange(int(round(T / h_ref)) + 1)), h_ref,
                     method="fft", pad=8)

    def err(name, lo, hi):
        t = times[name]
        sel = (t > lo) & (t < hi)
        idx = np.rint(t[sel] / h_ref).astype(int)
        return np.abs(out[name][sel] - f_ref[idx]).max() / scale

    fine_window = (0.5 + 2 * dt, 1.5)
    assert err("mixed", *fine_window) < 0.5 * err("coarse", *fine_window)   # 0.38 measured: the
    # coarse first 0.5 s leaves its error in the pole states
    assert err("mixed", 0, 4) <= err("coarse", 0, 4) < 2e-3


def test_the_history_matrix_is_built_at_the_first_product_only():
    """The dense history matrix H (as large as the residues) is not held until the first history
    product (a native run never asks for it: it builds its own from the model); the product then
    equals the sum over the poles written out, sum_k Re-part of R_k g_k (independent of H's layout)."""
    dt = 0.01
    soil = RecursiveConvolutionSoil(MODEL, dt)
    assert soil._H is None
    rng = np.random.default_rng(3)
    for _ in range(3):
        soil.step(rng.standard_normal(3), rng.standard_normal(3))
    assert soil._H is not None and soil._H.shape == (3, MODEL.order * 3)
    # h = sum over real poles R g + over pairs 2 Re(R g), with g the states the product used
    h = soil.history()
    pr, Rr, pc, Rc = MODEL.pole_split
    want = np.einsum("kij,kj->i", Rr, soil._gr) + 2 * np.einsum("kij,kj->i", Rc, soil._gc).real
    assert np.abs(h - want).max() <= 1e-12 * np.abs(want).max()

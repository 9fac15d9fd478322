"""Transient cross-check of the recursive convolution against the pole-free routes
(soil_impedance.poles_free): BDF2 convolution quadrature and the FFT product with a table.

Reference: the FFT route with the exact K(iω) on a fine grid (spectral for this smooth,
compactly supported input; checked against itself at half the step, 1e-10). Claims: recursion
and CQ both converge at order 2 (fitted slope 1.9-2.1) and so does their difference; CQ
weights of a polynomial K are the BDF2 stencil (1e-9); a finely sampled table reproduces the
exact response (1e-4); a 1 % fit error shows up in the time domain at most at its own size.
"""
import numpy as np

from helpers import random_passive_model
from soil_impedance.convolution import RecursiveConvolutionSoil
from soil_impedance.poles_free import convolve, cq_weights, impulse_response
from soil_impedance.rational import RationalModel
from soil_impedance.table import ImpedanceTable

MODEL = random_passive_model(3, n_pairs=3, n_real=2, seed=1)
T, TP = 4.0, 1.0
DIR = np.array([1.0, -0.5, 0.3])


def u_of(t):
    return np.where(t < TP, np.sin(np.pi * t / TP) ** 4, 0.0)[:, None] * DIR


def grid(dt):
    return dt * np.arange(int(round(T / dt)) + 1)


def recursion(model, dt):
    u = u_of(grid(dt))
    soil = RecursiveConvolutionSoil(model, dt)
    return np.vstack([np.zeros(model.n), [soil.step(x) for x in u[1:]]])


H_REF = 0.02 / 32
F_REF = convolve(MODEL, u_of(grid(H_REF)), H_REF, method="fft", pad=8)
SCALE = np.abs(F_REF).max()


def on_ref(f, dt):
    return np.abs(f - F_REF[:: int(round(dt / H_REF))]).max() / SCALE


def test_reference_is_converged():
    f2 = convolve(MODEL, u_of(grid(H_REF / 2)), H_REF / 2, method="fft", pad=8)
    assert np.abs(f2[::2] - F_REF).max() < 1e-10 * SCALE


def test_recursion_and_cq_converge_to_each_other_at_order_2():
    dts = np.array([0.02, 0.01, 0.005])
    e_rec, e_cq, e_diff = [], [], []
    for dt in dts:
        fr = recursion(MODEL, dt)
        fc = convolve(MODEL, u_of(grid(dt)), dt, method="cq")
        e_rec.append(on_ref(fr, dt))
        e_cq.append(on_ref(fc, dt))
        e_diff.append(np.abs(fr - fc).max() / SCALE)
    for e in (e_rec, e_cq, e_diff):
        rate = np.polyfit(np.log(dts), np.log(e), 1)[0]
        assert 1.9 < rate < 2.1, (rate, e)
    assert e_rec[-1] < 5e-5 and e_cq[-1] < 2e-4        # measured 3.4e-5, 1.4e-4


def test_cq_weights_of_spring_and_dashpot_are_the_bdf2_stencil():
    D = np.array([[2.0, 0.3], [0.3, 1.0]])
    E = np.array([[0.5, 0.1], [0.1, 0.2]])
    dt, nt = 0.01, 64
    W = cq_weights(lambda s: D + s[:, None, None] * E, dt, nt)
    expect = np.zeros_like(W)
    expect[0] = D + 1.5 * E / dt
    expect[1] = -2.0 * E / dt
    expect[2] = 0.5 * E / dt
    assert np.abs(W - expect).max() < 1e-9 * np.abs(expect).max()


def test_table_route_reproduces_the_exact_response():
    fq = np.linspace(0.0, 100.0, 8001)          # df = 0.0125 Hz, well inside the 0.2 Hz
    table = ImpedanceTable(fq, MODEL.frequency_response(fq), ["a", "b", "c"])  # resonance widths
    f = convolve(table, u_of(grid(H_REF)), H_REF)
    assert np.abs(f - F_REF).max() < 1e-4 * SCALE            # measured 6e-6
    _, acausal = impulse_response(table, H_REF, grid(H_REF).size)
    assert acausal < 1e-2      # causal model: only band-limitation leakage (measured 1.9e-3)


def test_fit_error_bounds_the_time_domain_error():
    """A 'fitted' model (the true one with residues and D perturbed by ~1 %) against the true
    table: the transient error is of the size of the frequency-domain fit error, not more."""
    rng = np.random.default_rng(4)
    pert = 1 + 0.01 * rng.standard_normal(MODEL.order)
    # conjugate pairs get conjugate factors (real factors keep the model real)
    for k in range(MODEL.order):
        if MODEL.poles[k].imag < 0:
            j = np.argmin(np.abs(MODEL.poles - np.conj(MODEL.poles[k])))
            pert[k] = pert[j]
    fitted = RationalModel(MODEL.poles, MODEL.residues * pert[:, None, None], MODEL.D * 1.005,
                           MODEL.E, provenance={"source": "perturbed"})
    fq = np.linspace(0.0, 100.0, 8001)
    Kt = MODEL.frequency_response(fq)
    fit_err = (np.linalg.norm(fitted.frequency_response(fq) - Kt, axis=(1, 2))
               / np.linalg.norm(Kt, axis=(1, 2))).max()
    table = ImpedanceTable(fq, Kt, ["a", "b", "c"])
    dt = 0.0025
    f_true = convolve(table, u_of(grid(dt)), dt)
    f_fit = recursion(fitted, dt)
    e_time = np.abs(f_fit - f_true).max() / np.abs(f_true).max()
    e_disc = on_ref(recursion(MODEL, dt), dt)         # the recursion's own error at this dt
    assert e_time <= fit_err + e_disc, (e_time, fit_err, e_disc)
    assert e_time > 0.1 * fit_err                       # and the cross-check does see it


def test_hysteretic_table_kernel_is_acausal_and_measured():
    """Constant hysteretic damping K = k (1 + 2 i ξ sgn ω) is not causal: the table route
    says so (acausal kernel fraction) instead of hiding it."""
    fq = np.linspace(0.0, 50.0, 501)
    K = np.ones((fq.size, 1, 1)) * (1 + 2j * 0.05)
    K[0] = 1.0
    _, acausal = impulse_response(ImpedanceTable(fq, K, ["uz"]), 0.005, 4000)
    assert acausal > 0.3       # odd (Hilbert) kernel 1/(πt): half its energy before t = 0

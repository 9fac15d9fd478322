"""The recursive-convolution soil in the structure's NewmarkStepper (reactor model, 241 nodes).

1. A rational model with D, E only (no poles) equal to the Winkler springs and dashpots gives
   the Winkler run to round-off, with uplift (1e-9 relative on raft motion and gaps).
2. With poles (oscillators on the Winkler pattern, passive): the stepper's soil work equals
   the soil's own dissipated_energy() to round-off, it is never negative, the stepper's energy
   balance closes, and forced sub-stepping (instantaneous(dt/2^k)) runs through.
"""
import numpy as np

from helpers import oscillator_model
from soil_impedance.convolution import RecursiveConvolutionSoil
from soil_impedance.rational import RationalModel
from structure import ContactSettings, simulate
from structure.broadband import broadband_accelerogram
from helpers import FINE_RAFT

MODEL, soil = FINE_RAFT.model, FINE_RAFT.soil

DT = 0.005


def accelerogram(T, pga, seed=7):
    ag = np.zeros((int(round(T / DT)) + 1, 3))
    ag[:, 0] = broadband_accelerogram(T, DT, pga, seed=seed)
    return ag


def winkler_matrices():
    w = soil(damped=True)
    K, C = w.instantaneous(DT)
    return w, K.toarray(), C.toarray()


def test_spring_dashpot_model_equals_winkler_with_uplift():
    w, K, C = winkler_matrices()
    model = RationalModel(np.zeros(0, complex), np.zeros((0,) + K.shape, complex), K, C)
    ag = accelerogram(2.0, 0.8 * 9.81)      # 2 s: the raft lifts in 187 of its 400 steps (35 mm)
    r_ref = simulate(MODEL, w, ag, DT)
    r = simulate(MODEL, RecursiveConvolutionSoil(model, DT), ag, DT)
    assert r_ref.max_uplift() > 1e-3
    scale = np.abs(r_ref.raft).max(axis=0)
    assert np.all(np.abs(r.raft - r_ref.raft).max(axis=0) <= 1e-9 * scale)
    assert np.abs(r.gap - r_ref.gap).max() <= 1e-9 * r_ref.gap.max()


def _pole_model():
    """Winkler springs/dashpots plus two oscillator pairs (2 and 6 Hz) on the spring pattern."""
    _, K, C = winkler_matrices()
    kref = 1.0
    terms = [(0.3 * kref, 2 * 0.2 * np.sqrt(0.3 * kref * 0.3 * kref / (2 * np.pi * f) ** 2),
              0.3 * kref / (2 * np.pi * f) ** 2, K) for f in (2.0, 6.0)]
    return oscillator_model(K, C, terms)


def test_pole_model_energy_and_substeps():
    model = _pole_model()
    ag = accelerogram(2.0, 1.5 * 9.81)
    sl = RecursiveConvolutionSoil(model, DT)
    few = ContactSettings(max_iter=2, max_subdiv=8)      # forces halvings at contact changes
    r = simulate(MODEL, sl, ag, DT, contact=few)
    assert r.info["subdivided_steps"] > 0 and r.max_uplift() > 1e-3
    Ws = r.energy["soil"]
    assert abs(Ws[-1] - sl.dissipated_energy()) <= 1e-9 * np.abs(Ws).max()
    assert Ws.min() >= -1e-12 * np.abs(Ws).max()
    assert r.energy_balance_error() < 1e-6

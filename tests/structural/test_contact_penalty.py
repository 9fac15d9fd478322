"""Penalty "auto" (kp = 1e4 x local soil static stiffness) is converged: x10 moves results < 0.1 %."""
import numpy as np

from structure import ContactSettings, simulate
from structure.broadband import broadband_accelerogram
from structure.contact import AUTO_FACTOR
from helpers import FINE_RAFT

MODEL, soil = FINE_RAFT.model, FINE_RAFT.soil


def test_penalty_times_ten_moves_results_less_than_0_1_percent():
    dt = 0.005
    ag = np.zeros((1201, 3))
    ag[:, 0] = broadband_accelerogram(6.0, dt, 0.25 * 9.81, seed=1)
    s = soil()
    r1 = simulate(MODEL, s, ag, dt, contact=ContactSettings(penalty="auto"))
    r10 = simulate(MODEL, s, ag, dt, contact=ContactSettings(penalty=10 * AUTO_FACTOR * s.kv))
    assert np.allclose(r1.info["penalty"], AUTO_FACTOR * s.kv)
    assert r1.max_uplift() > 5e-4
    metrics = lambda r: np.array([r.max_uplift(), np.abs(r.raft[:, 4]).max(),
                                  np.abs(r.acc["top_outer"][:, 0]).max(),
                                  np.abs(r.acc["internals_37m"][:, 0]).max(),
                                  r.contact_force.sum(axis=1).max(), r.info["settlement"]])
    m1, m10 = metrics(r1), metrics(r10)
    rel = np.abs(m10 - m1) / np.abs(m10)
    assert np.all(rel < 1e-3), rel
    # whole histories too (normalised by their peaks)
    hist = np.abs(r1.raft[:, 4] - r10.raft[:, 4]).max() / np.abs(r10.raft[:, 4]).max()
    assert hist < 1e-3, hist

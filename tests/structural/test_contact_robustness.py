"""Robustness: PGA 0.1 g to 2 g on the reactor on Winkler soil completes (sub-stepping where
needed) or stops with a ConvergenceError that names time, node and residual; no NaN."""
import numpy as np
import pytest

from structure import ContactSettings, ConvergenceError, simulate
from structure.broadband import broadband_accelerogram
from helpers import FINE_RAFT

MODEL, soil = FINE_RAFT.model, FINE_RAFT.soil


@pytest.mark.parametrize("pga_g", [0.1, 0.5, 1.0, 2.0])
def test_reactor_pga_sweep_completes_or_fails_clearly(pga_g):
    dt = 0.005
    ag = np.zeros((1401, 3))
    ag[:, 0] = broadband_accelerogram(7.0, dt, pga_g * 9.81, seed=2)
    ag[:, 2] = 0.66 * broadband_accelerogram(7.0, dt, pga_g * 9.81, seed=12)
    try:
        r = simulate(MODEL, soil(), ag, dt)
    except ConvergenceError as exc:
        assert "t =" in str(exc) and "node" in str(exc) and np.isfinite(exc.time)
        r = exc.result
        assert r is not None and not r.converged
    for a in (r.raft, r.gap, r.contact_force, r.soil_w, *r.acc.values(), *r.energy.values()):
        assert np.all(np.isfinite(a))
    assert np.all(r.gap >= 0) and np.all(r.contact_force >= 0)
    if r.converged:
        assert r.nt == ag.shape[0]
        if pga_g <= 0.1:
            assert r.max_uplift() == 0.0          # 0.1 g does not lift the raft
        if pga_g >= 1.0:
            assert r.max_uplift() > 1e-3


def test_convergence_error_carries_time_node_residual_and_partial_results():
    dt = 0.005
    ag = np.zeros((801, 3))
    ag[:, 0] = broadband_accelerogram(4.0, dt, 1.0 * 9.81, seed=2)
    strict = ContactSettings(max_iter=1, max_subdiv=0)   # one Newton solve, no sub-stepping
    with pytest.raises(ConvergenceError) as ei:
        simulate(MODEL, soil(), ag, dt, contact=strict)
    exc = ei.value
    assert exc.time > 0 and exc.node >= 0 and exc.residual > 0
    assert f"interface node {exc.node}" in str(exc)
    r = exc.result
    assert not r.converged and 0 < r.nt < ag.shape[0] and r.time[-1] < exc.time
    assert np.all(np.isfinite(r.raft))

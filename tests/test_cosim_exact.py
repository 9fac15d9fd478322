"""Co-simulation with the impedance split equals the monolithic route to round-off.

Small scene (reactor stick on a 21-node raft over rock), a strong pulse that lifts the raft,
and a soil with a nonzero history force (Winkler springs and dashpots plus two Maxwell
relaxation terms, run by the recursive convolution). Gauss-Seidel (structure, then soil) with
the soil's instantaneous terms folded into the structure must reproduce simulate() with the
soil object in process to 1e-10 relative; the Jacobi schedule (history one step late) must
not, and its difference is reported (it also guards the test itself: a soil whose history
never reached the structure would make Jacobi equal Gauss-Seidel).
"""
import numpy as np
import pytest

from cosim_cases import pulse_motion, small_scene, soil_model
from orchestrator.routes.cosim import run_cosim
from orchestrator.routes.monolithic import run_monolithic

SCENE = small_scene()
MODEL = soil_model(SCENE)
MOTION = pulse_motion()


def rel(a, b):
    return np.abs(a - b).max() / np.abs(b).max()


@pytest.fixture(scope="module")
def mono():
    res = run_monolithic(SCENE, MOTION, MODEL)
    assert res.converged and res.info["subdivided_steps"] == 0
    return res


def test_case_has_uplift_and_soil_memory(mono):
    from soil_impedance.convolution import RecursiveConvolutionSoil
    assert mono.max_uplift() > 1e-2                      # 34 mm: a real uplift episode
    assert mono.uplift_fraction().max() > 0.3
    soil = RecursiveConvolutionSoil(MODEL, MOTION.dt)
    soil.commit(np.ones(MODEL.n) * 1e-3, np.zeros(MODEL.n))
    assert np.abs(soil.history()).max() > 1e3            # the history channel carries force


@pytest.mark.parametrize("factory", ["soil_impedance.convolution:RecursiveConvolutionSoil",
                                     "soil_double:TrapezoidRationalSoil"])
def test_gauss_seidel_split_equals_monolithic(mono, factory):
    ref = mono if factory.startswith("soil_impedance") else run_monolithic(SCENE, MOTION, MODEL, soil_factory=factory)
    cos = run_cosim(SCENE, MOTION, MODEL, soil_factory=factory)
    assert cos.converged and cos.nt == ref.nt
    assert rel(cos.raft, ref.raft) <= 1e-10
    assert rel(cos.gap, ref.gap) <= 1e-10
    assert rel(cos.contact_force, ref.contact_force) <= 1e-10
    assert rel(cos.soil_w, ref.soil_w) <= 1e-10
    for node in ref.acc:
        assert rel(cos.acc[node], ref.acc[node]) <= 1e-10
    for term in ("input", "kinetic", "soil", "contact"):
        assert rel(cos.energy[term], ref.energy[term]) <= 1e-10
    assert np.array_equal(cos.newton_iters, ref.newton_iters)


def test_jacobi_is_one_step_late(mono):
    jac = run_cosim(SCENE, MOTION, MODEL, schedule="jacobi")
    d = rel(jac.raft, mono.raft)
    print(f"Jacobi vs monolithic (= Gauss-Seidel): raft {d:.3e} relative, "
          f"max uplift {jac.max_uplift():.5f} vs {mono.max_uplift():.5f} m")
    assert 1e-4 < d < 0.1                                  # O(dt) coupling error, not round-off

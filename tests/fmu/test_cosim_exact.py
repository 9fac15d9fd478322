"""Co-simulation with the impedance split equals the monolithic route to round-off.

Small scene (reactor stick on a 21-node raft over rock), a strong pulse along x, y and z at
once that lifts the raft and rocks it about both axes, and a soil with a nonzero history force (Winkler springs and dashpots plus two Maxwell
relaxation terms, run by the recursive convolution). With the split coupling (the soil
publishes its history force without the part of the structure's latest state, the structure
adds that part with the gains measured at export) every schedule, Gauss-Seidel in either
order and Jacobi, must reproduce simulate() with the soil object in process to 1e-10
relative. A structure fed the soil's g without its own part is off by O(1): the history
channel matters, so the equality is not trivial.
"""
import numpy as np
import pytest

from helpers import pulse_motion, random_passive_model, rel, rocks_about_both_axes, small_scene, soil_model
from orchestrator.routes.cosim import run_cosim
from orchestrator.routes.monolithic import run_monolithic

SCENE = small_scene()
MODEL = soil_model(SCENE)
MOTION = pulse_motion(y=0.5)                 # x, y and z at once


@pytest.fixture(scope="module")
def mono():
    res = run_monolithic(SCENE, MOTION, MODEL)
    assert res.converged and res.info["subdivided_steps"] == 0
    return res


def test_case_has_uplift_and_soil_memory(mono):
    from soil_impedance.convolution import RecursiveConvolutionSoil
    assert mono.max_uplift() > 1e-2                      # 52 mm: a real uplift episode
    assert MOTION.components == ("x", "y", "z") and rocks_about_both_axes(mono)
    assert mono.uplift_fraction().max() > 0.3
    soil = RecursiveConvolutionSoil(MODEL, MOTION.dt)
    soil.commit(np.ones(MODEL.n) * 1e-3, np.zeros(MODEL.n))
    assert np.abs(soil.history()).max() > 1e3            # the history channel carries force


@pytest.mark.parametrize("factory, schedule", [
    ("soil_impedance.convolution:RecursiveConvolutionSoil", "gauss-seidel"),
    ("soil_impedance.convolution:RecursiveConvolutionSoil", "soil-first"),
    ("soil_impedance.convolution:RecursiveConvolutionSoil", "jacobi"),
    ("helpers.soil_double:TrapezoidRationalSoil", "jacobi")])
def test_every_schedule_equals_monolithic(mono, factory, schedule):
    ref = mono if factory.startswith("soil_impedance") else run_monolithic(SCENE, MOTION, MODEL, soil_factory=factory)
    cos = run_cosim(SCENE, MOTION, MODEL, soil_factory=factory, schedule=schedule)
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
    assert cos.info["fmu_max_uplift"] == pytest.approx(ref.max_uplift(), rel=1e-10)
    rot = np.hypot(ref.raft[:, 3], ref.raft[:, 4]).max()
    assert cos.info["fmu_max_raft_rotation"] == pytest.approx(rot, rel=1e-10)


def test_closed_form_gains_equal_the_measured_ones():
    """The recursive convolution's history gains in closed form (RecursiveConvolutionSoil.
    history_gains, what export uses) against the gains measured by 2n unit commits
    (coupling.measured_gains): 1e-13 of the largest entry, real poles and pairs alike."""
    from fmus.coupling import history_gains, measured_gains
    from soil_impedance.convolution import RecursiveConvolutionSoil
    model = random_passive_model(9, n_pairs=3, n_real=2, seed=4)
    assert model.pole_split[0].size and model.pole_split[2].size
    soil = RecursiveConvolutionSoil(model, MOTION.dt)
    Gx, Gv = history_gains(soil, MOTION.dt)
    Mx, Mv = measured_gains(soil, MOTION.dt)
    assert np.abs(Gx - Mx).max() <= 1e-13 * np.abs(Mx).max() and not Mv.any() and not Gv.any()
    assert np.array_equal(Gx, Gx.T)


def test_history_gains_split_the_history_exactly():
    """h_{k+2} = g_{k+2} + Gx x_{k+1} + Gv xdot_{k+1} on a random run of the soil, and the
    structure's own part is not negligible (without it the coupling would be one step late)."""
    from fmus.coupling import history_ahead, history_gains
    from soil_impedance.convolution import RecursiveConvolutionSoil
    soil = RecursiveConvolutionSoil(MODEL, MOTION.dt)
    Gx, Gv = history_gains(soil, MOTION.dt)
    rng = np.random.default_rng(0)
    worst, part = 0.0, 0.0
    for _ in range(20):
        soil.commit(rng.normal(size=MODEL.n) * 1e-3, rng.normal(size=MODEL.n) * 1e-2)
        g = history_ahead(soil)
        x, xd = rng.normal(size=MODEL.n) * 1e-3, rng.normal(size=MODEL.n) * 1e-2
        soil.commit(x, xd)
        h = soil.history()
        worst = max(worst, np.abs(h - (g + Gx @ x + Gv @ xd)).max() / np.abs(h).max())
        part = max(part, np.abs(Gx @ x).max() / np.abs(h).max())
    assert worst <= 1e-12
    assert part > 0.1
    assert np.array_equal(Gx, Gx.T) and not Gv.any()        # reciprocal, no xdot: what the native FMU exploits

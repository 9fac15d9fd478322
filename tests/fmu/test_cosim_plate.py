"""A plate raft in co-simulation: the Python pair (the structure FMU steps
structure.plate_raft.PlateStepper with the soil's history from the soil FMU) equals the monolithic
plate route on the same (Python) stepper to round-off under Gauss-Seidel and Jacobi, run by the
cosim route (kind="python") and from the ``uplift export --kind python`` files (which pass fmpy's
validation); the coupled FMU too. The native pair and FMUs of a plate: tests/fmu/test_native_plate.py.

Scene: the reactor sticks on a 2 m concrete plate (61 interface nodes, 80 plate vertices, the
held region within 10 m of the centre) over the rock's springs and dashpots with two Maxwell
terms (a soil with memory), a pulse along x, y and z that lifts most of the raft. "Round-off":
each history within max(1e-10, 100 x its round-off spread), the spread measured on the
monolithic route under the motion scaled by 1 + k 1e-14 (tests/helpers/roundoff.py); the Newton
counts identical. The rigid raft of the same mass differs by O(1) (the plate bends), so the
equality is not that of a rigid raft.
"""
import dataclasses

import numpy as np
import pytest

from helpers import pulse_motion, rel, rocks_about_both_axes, soil_model
from helpers.roundoff import assert_within_spread, roundoff_spread
from helpers.winkler import NU, R, RHO
from orchestrator.routes.cosim import run_cosim
from orchestrator.routes.monolithic import run_monolithic
from orchestrator.scene import scene_from_dict
from structure.plate_raft import rigid_equivalent

PLATE = {"kind": "plate", "thickness": 2.0, "E": 30e9, "nu": 0.2, "rho": 2500.0}
SCENE = scene_from_dict({
    "soil": {"halfspace": {"vs": 1600.0, "nu": NU, "rho": RHO}},
    "foundation": {"shape": "circle", "radius": R, "element_size": 4.6, "raft": PLATE},
    "structure": {"model": "reactor", "damping": {"modal": 0.07}},
    "contact": {"enabled": True},
    "analysis": {"dt": 0.005, "routes": ["monolithic", "cosim"]},
    "output": {"nodes": ["top_outer", "internals_37m"]},
}, name="plate")
MODEL = soil_model(SCENE)
MOTION = pulse_motion(0.005, 1.0, pga=6.0, tp=0.5, y=0.5)


@pytest.fixture(scope="module")
def mono():
    res = run_monolithic(SCENE, MOTION, MODEL, stepper="python")     # the Python pair's own stepper
    assert res.converged and res.info["subdivided_steps"] == 0
    return res


@pytest.fixture(scope="module")
def spread(mono):
    return roundoff_spread(lambda ag: run_monolithic(SCENE, dataclasses.replace(MOTION, acc=ag), MODEL,
                                                     stepper="python"), MOTION.acc, base=mono)


def test_case_lifts_rocks_and_bends(mono):
    pm = SCENE.plate_model()
    assert SCENE.mesh.n == 61 and pm.n_vertices == 80 and pm.nf > 40
    assert mono.max_uplift() > 1e-2 and mono.uplift_fraction().max() > 0.3 and rocks_about_both_axes(mono)
    # the rigid raft of the same masses on the same soil is O(1) away: the plate bends
    from fmus.resources import soil_from_model
    from structure import simulate
    rigid = simulate(rigid_equivalent(pm), soil_from_model(MODEL, MOTION.dt), MOTION.acc, MOTION.dt,
                     contact=SCENE.contact, output_nodes=SCENE.output.nodes)
    assert rel(rigid.gap, mono.gap) > 0.05 and rel(rigid.contact_force, mono.contact_force) > 0.05


def assert_equal_runs(cos, ref, spread):
    assert cos.converged and cos.nt == ref.nt
    checks = assert_within_spread(cos, ref, spread)
    assert np.array_equal(cos.newton_iters, ref.newton_iters)
    assert cos.info["fmu_max_uplift"] == pytest.approx(ref.max_uplift(), rel=1e-9)
    return checks


@pytest.mark.parametrize("schedule", ["gauss-seidel", "jacobi"])
def test_cosim_python_pair_equals_monolithic(mono, spread, schedule):
    cos = run_cosim(SCENE, MOTION, MODEL, schedule=schedule, kind="python")
    checks = assert_equal_runs(cos, mono, spread)
    assert max(d for d, _ in checks.values()) < 1e-9          # measured 6.3e-11 (acc), the rest below
    assert cos.info["fmu_kind"] == "python" and not cos.notes.warnings


@pytest.mark.slow            # 8 s: an export of three FMUs, the pair and the coupled FMU run
def test_exported_python_fmus_of_a_plate_validate_and_equal_monolithic(mono, spread, tmp_path):
    from fmpy.validation import validate_fmu
    from orchestrator.export import export_scene
    from orchestrator.master import FmuSlave, cosimulate
    exp = export_scene(SCENE, tmp_path / "fmus", MODEL, motion=MOTION, kind="python")
    for fmu in (exp.structure, exp.soil, exp.coupled):
        assert validate_fmu(str(fmu)) == [], fmu
    # every Python FMU of one export opened before any is freed (tests/fmu/test_native_fmu.py, PY_RUNS)
    S, G, C = FmuSlave(exp.structure, "structure"), FmuSlave(exp.soil, "soil"), FmuSlave(exp.coupled, "coupled")
    try:
        cos = cosimulate(S, G, MOTION.acc, MOTION.dt, schedule="jacobi")
        assert_equal_runs(cos, mono, spread)
        # the coupled FMU (the plate and the soil in one FMU, its bundled motion) steps the monolithic route
        C.initialize()
        rows = [C.get("x", "gap").copy()]
        for k in range(1, MOTION.acc.shape[0]):
            C.do_step((k - 1) * MOTION.dt, MOTION.dt)
            rows.append(C.get("x", "gap").copy())
    finally:
        for f in (S, G, C):
            f.close()
    rows = np.array(rows)
    n = SCENE.mesh.n + 6
    assert rel(rows[:, :6], mono.raft) <= spread.tol("raft")
    assert rel(rows[:, 6:n], mono.soil_w) <= spread.tol("soil_w")
    assert rel(rows[:, n:], mono.gap) <= spread.tol("gap")


def test_plate_stepper_with_an_external_soil_is_the_in_process_stepper_bit_for_bit():
    """PlateStepper(external_soil=True) fed h = soil.history() on [q, w] and committing its x,
    xdot to that soil is the in-process stepper, every state bit for bit; its inputs survive
    get_state / next_inputs and a restart (what the structure FMU keeps in its state)."""
    from fmus.resources import soil_from_model
    from structure.plate_raft import PlateStepper
    pm, dt, acc = SCENE.plate_model(), MOTION.dt, MOTION.acc[:161]
    inner = PlateStepper(pm, soil_from_model(MODEL, dt), dt, contact=SCENE.contact, ag0=acc[0])
    soil = soil_from_model(MODEL, dt)
    outer = PlateStepper(pm, soil, dt, contact=SCENE.contact, external_soil=True, ag0=acc[0])

    def outer_step(k):
        soil.instantaneous(dt)
        outer.set_ground_acceleration(acc[k])
        outer.set_soil_history(soil.history())
        outer.step()
        soil.commit(outer.x.copy(), outer.xdot.copy())

    for k in range(1, 121):
        inner.set_ground_acceleration(acc[k])
        inner.step()
        outer_step(k)
        assert np.array_equal(outer.u, inner.u) and np.array_equal(outer.P, inner.P), k
    assert inner.gap().max() > 1e-3 and outer.x.shape == (6 + SCENE.mesh.n,)
    # the state with the next inputs: the same next 40 steps after a restart
    saved, soil_saved, (ag_next, h_next) = outer.get_state(), soil.get_state(), outer.next_inputs()
    assert "soil" not in saved and h_next.shape == (6 + SCENE.mesh.n,) and np.abs(h_next).max() > 0
    for k in range(121, 161):
        outer_step(k)
    first = outer.u.copy()
    outer.set_state(saved)
    soil.set_state(soil_saved)
    outer.set_ground_acceleration(ag_next)
    outer.set_soil_history(h_next)
    assert np.array_equal(outer.next_inputs()[1], h_next)
    for k in range(121, 161):
        outer_step(k)
    assert np.array_equal(outer.u, first) and np.abs(first).max() > 0

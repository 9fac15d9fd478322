"""The thin plate that blows up: the penalty contact feeding energy in, seen by the stepper's
energy balance, the warning of the monolithic route, and the HHT alpha of ``analysis.hht_alpha``.

Scene: the reactor's sticks on a 1 m concrete plate (61 interface nodes, 4.6 m cells) over the rock's
springs and dashpots with two Maxwell terms, under the reactor scene's synthetic 10 s motion (no
BEM: the motion generator alone). With the trapezoidal rule (alpha 0) the edge cells open and
reclose on alternate steps (the penalty's omega dt is in the hundreds under a plate vertex), the
energy balance closes (input = kinetic + strain + damping + soil + contact to 1e-9 of the
largest term: the energy is the contact's work, not an error of the balance) and the contact's
work falls below its stored potential by 1.9e4 x the input work: max uplift 39 m. HHT alpha = -1/3
damps that chatter: max uplift 7.8 cm, the contact's excess 0.17 x the input (still above
CONTACT_ENERGY_SHARE: the warning stays). Each run 0.3 to 0.5 s native.
"""
import dataclasses

import numpy as np
import pytest

from helpers import pulse_motion, rel, soil_model
from helpers.roundoff import assert_within_spread, roundoff_spread
from helpers.winkler import NU, R, RHO
from fmus import native_stepper
from orchestrator.export import fmu_data
from orchestrator.motion import make_motion
from orchestrator.routes.monolithic import CONTACT_ENERGY_SHARE, run_monolithic
from orchestrator.scene import SceneError, load_scene, scene_from_dict

PLATE = {"kind": "plate", "thickness": 1.0, "E": 30e9, "nu": 0.2, "rho": 2500.0}
DATA = {
    "soil": {"halfspace": {"vs": 1600.0, "nu": NU, "rho": RHO}},
    "foundation": {"shape": "circle", "radius": R, "element_size": 4.6, "raft": PLATE},
    "structure": {"model": "reactor", "damping": {"modal": 0.07}},
    "contact": {"enabled": True},
    "analysis": {"dt": 0.005, "routes": ["monolithic"]},
    "output": {"nodes": ["top_outer"]},
}


def scene(alpha=0.0, **raft):
    return scene_from_dict({**DATA, "foundation": {**DATA["foundation"], "raft": {**PLATE, **raft}},
                            "analysis": {**DATA["analysis"], "hht_alpha": alpha}}, name="thin")


SCENE = scene()
MODEL = soil_model(SCENE)
MOTION = make_motion(load_scene("reactor").motion, 0.005)

needs_native = pytest.mark.skipif(native_stepper.library() is None, reason="no C compiler for the native stepper")


def fed(res) -> float:
    """The contact's largest excess of stored potential over its work, over the largest input work."""
    e = res.energy
    return float((e["contact_potential"] - e["contact"]).max() / np.abs(e["input"]).max())


@needs_native
def test_the_thin_plate_s_contact_feeds_energy_in_and_the_run_says_so():
    res = run_monolithic(SCENE, MOTION, MODEL)
    e = res.energy
    assert res.info["stepper"] == "native" and res.info["alpha"] == 0.0
    # the balance closes: the energy comes in through the contact's work
    stored = e["kinetic"] + e["strain"] + e["damping"] + e["soil"] + e["contact"]
    big = max(np.abs(e[k]).max() for k in e)
    assert np.abs(e["input"] - stored).max() < 1e-9 * big
    assert fed(res) > 1e3 and res.max_uplift() > 1.0                      # measured 1.9e4, 39 m
    warning = [w for w in res.notes.warnings if "the contact fed" in w]
    assert len(warning) == 1 and "analysis.hht_alpha" in warning[0] and "HHT alpha 0" in warning[0]
    # HHT alpha = -1/3 damps the alternate-step chatter: bounded, the contact's excess 1e5 times smaller
    damped = run_monolithic(scene(-1.0 / 3.0), MOTION, MODEL)
    assert damped.info["alpha"] == pytest.approx(-1.0 / 3.0) and damped.converged
    assert damped.max_uplift() < 0.2 and fed(damped) < 1e-4 * fed(res)    # measured 7.8 cm, 0.17


def test_a_run_whose_contact_returns_what_it_stored_has_no_warning():
    """The pulse on a 2 m plate (tests/fmu/test_native_plate.py's scene): the contact's excess
    1 % of the input, under CONTACT_ENERGY_SHARE: no warning."""
    sc = scene(thickness=2.0)
    res = run_monolithic(sc, pulse_motion(0.005, 1.0, pga=4.0, tp=0.5, y=0.5), MODEL)
    assert res.max_uplift() > 1e-2 and 0 < fed(res) < CONTACT_ENERGY_SHARE        # measured 0.010
    assert not [w for w in res.notes.warnings if "the contact fed" in w]
    # at rest (no input work) there is nothing to weigh the contact's energy against: no warning
    still = run_monolithic(sc, dataclasses.replace(MOTION, acc=np.zeros((50, 3))), MODEL)
    assert np.abs(still.energy["input"]).max() == 0 and not still.notes.warnings


@needs_native
def test_hht_alpha_reaches_both_steppers_and_the_fmus():
    """analysis.hht_alpha: the native run equals the Python one within the round-off criterion
    (tests/helpers/roundoff.py), and differs from the alpha = 0 run by far more; the FMUs' data
    carry it."""
    sc = dataclasses.replace(scene(-0.1, thickness=2.0), contact=dataclasses.replace(SCENE.contact, precheck=False))
    motion = pulse_motion(0.005, 1.0, pga=4.0, tp=0.5, y=0.5)
    go = lambda stepper, ag=motion.acc: run_monolithic(sc, dataclasses.replace(motion, acc=ag), MODEL,
                                                       stepper=stepper)
    ref, fast = go("python"), go("native")
    assert ref.info["alpha"] == fast.info["alpha"] == -0.1 and fast.info["stepper"] == "native"
    spread = roundoff_spread(lambda ag: go("python", ag), motion.acc, base=ref)
    checks = assert_within_spread(fast, ref, spread)
    trapezoidal = run_monolithic(scene(0.0, thickness=2.0), motion, MODEL)
    assert np.abs(trapezoidal.gap - fast.gap).max() > 1e3 * checks["gap"][1] * np.abs(fast.gap).max()
    assert fmu_data(sc, MODEL, 0.005).alpha == -0.1 and fmu_data(SCENE, MODEL, 0.005).alpha == 0.0


@pytest.mark.parametrize("alpha, routes, message", [
    (-0.5, ["monolithic"], r"analysis.hht_alpha = -0.5 must be an HHT alpha in \[-1/3, 0\]"),
    (0.1, ["monolithic"], r"analysis.hht_alpha = 0.1 must be"),
    (-0.05, ["monolithic", "timefreq"], "route timefreq solves the equations without it: set hht_alpha = 0"),
])
def test_bad_hht_alpha_is_refused_with_the_key(alpha, routes, message):
    with pytest.raises(SceneError, match=message):
        scene_from_dict({**DATA, "analysis": {**DATA["analysis"], "routes": routes, "hht_alpha": alpha}}, name="x")


@needs_native
@pytest.mark.slow            # the FMU runtime compiled for this machine (once per process)
def test_the_cosim_pair_steps_with_the_scene_s_hht_alpha():
    """The native pair under the cosim route equals the monolithic run at alpha = -0.1 to
    round-off (measured 6.7e-11 on the gap), 4.7 % away from the alpha = 0 run."""
    from orchestrator.routes.cosim import run_cosim
    sc = scene(-0.1, thickness=2.0)
    motion = pulse_motion(0.005, 1.0, pga=4.0, tp=0.5, y=0.5)
    mono = run_monolithic(sc, motion, MODEL)
    cos = run_cosim(sc, motion, MODEL, schedule="jacobi")
    zero = run_monolithic(scene(0.0, thickness=2.0), motion, MODEL)
    assert cos.info["fmu_kind"] == "native" and not cos.notes.warnings
    assert rel(cos.gap, mono.gap) < 1e-9 and rel(cos.raft, mono.raft) < 1e-9
    assert rel(zero.gap, mono.gap) > 1e-2

"""The native stepper on springs (a soil without memory: the step-doubling check's proxy): its
"diagonal soil" path (fmus/native/stepper.c: S0 a 6x6 block on the raft plus a diagonal on the
soil nodes, each Newton solve eliminating the soil nodes one by one) against two references,

- the Python stepper (structure.simulate) on the same WinklerSoil (sparse springs and dashpots);
- the native stepper's dense path on the same springs: a coupling of 1e-30 of the largest spring
  between two soil nodes (far below round-off: the same equations) makes the soil dense;

with uplift (rocking about both axes), with step halving (Newton held to 2 iterations) and with
the HHT-alpha rule: every history within its round-off spread (tests/helpers/roundoff.py:
max(1e-10, 100 x the spread of the Python stepper's run under the motion scaled by 1 + k 1e-14;
the penalty and step halving amplify round-off: with halving the contact forces of the dense
path and of the Python stepper differ by 2e-8, their spread is 2e-9); with the contact bonded
(the linear path, the mild scene): every history to a fixed 1e-10 of its largest value. That the diagonal path ran is read
from the factorisation count: one 6x6 factorisation per Newton solve, where the dense path
factorises per active set.

About 5 s on an idle machine, with the spreads' 4 x 3 perturbed runs of the Python stepper
(6 s of them on 2 busy cores).
"""
import dataclasses

import numpy as np
import pytest

from helpers import pulse_motion, rel, small_scene
from helpers.cases import winkler
from helpers.roundoff import assert_within_spread, roundoff_spread
from fmus import native_stepper
from soil_impedance.convolution import RecursiveConvolutionSoil
from structure import NewmarkStepper, simulate

SCENE = small_scene()
MOTION = pulse_motion(T=1.0, y=0.5)                # the raft rocks about both axes
DT = MOTION.dt
NODES = SCENE.output.nodes

pytestmark = pytest.mark.skipif(native_stepper.library() is None, reason="no C compiler for the native stepper")

CASES = {                                       # name: (contact settings, HHT alpha)
    "uplift": (dict(precheck=False), 0.0),
    "halving": (dict(precheck=False, max_iter=2), 0.0),
    "hht": (dict(precheck=False), -0.1),
    "bonded": (dict(enabled=False), 0.0),
}


def native(model, contact, alpha):
    st = NewmarkStepper(SCENE.model(), RecursiveConvolutionSoil(model, DT, checked=True), DT, contact=contact,
                        alpha=alpha, external_soil=True, ag0=MOTION.acc[0])
    return native_stepper.simulate_native(st, MOTION.acc, NODES)


def assert_same_histories(res, ref, spread=None):
    """Every history of ``res`` within the round-off ``spread`` of ``ref`` (None: a fixed 1e-10)."""
    assert res.time.shape == ref.time.shape
    if spread is not None:
        assert_within_spread(res, ref, spread)
        return
    for name in ("raft", "gap", "contact_force", "soil_w"):
        assert rel(getattr(res, name), getattr(ref, name)) <= 1e-10, name
    for nm in NODES:
        assert rel(res.disp[nm], ref.disp[nm]) <= 1e-10 and rel(res.acc[nm], ref.acc[nm]) <= 1e-10, nm
    for key in ref.energy:
        assert rel(res.energy[key], ref.energy[key]) <= 1e-10, key


@pytest.mark.parametrize("case", list(CASES))
def test_springs_equal_the_dense_path_and_the_python_stepper(case):
    settings, alpha = CASES[case]
    contact = dataclasses.replace(SCENE.contact, **settings)
    springs = winkler(SCENE)                                   # springs and dashpots: D and E diagonal on w
    model = native_stepper.springs_soil(springs, DT).model
    assert model.poles.size == 0 and np.abs(model.E).max() > 0
    D = model.D.copy()
    D[6, 7] = D[7, 6] = 1e-30 * np.abs(D).max()
    dense_model = dataclasses.replace(model, D=D)

    fast = native(model, contact, alpha)
    dense = native(dense_model, contact, alpha)

    def run(ag):
        return simulate(SCENE.model(), springs, ag, DT, contact=contact, alpha=alpha, output_nodes=NODES)
    ref = run(MOTION.acc)
    spread = roundoff_spread(run, MOTION.acc, base=ref) if contact.enabled else None    # bonded: mild, 1e-10
    assert_same_histories(fast, ref, spread)
    assert_same_histories(fast, dense, spread)
    assert_same_histories(dense, ref, spread)
    if contact.enabled:
        assert ref.max_uplift() > 1e-3                         # the raft lifts off
    halved = ref.info["subdivided_steps"]
    assert fast.info["subdivided_steps"] == dense.info["subdivided_steps"] == halved
    assert (halved > 0) == (case == "halving")
    assert np.array_equal(fast.newton_iters, dense.newton_iters)
    solves = fast.newton_iters.sum() if contact.enabled else fast.nt - 1
    if case != "halving":                                      # (a halved step's failed solves count too)
        assert fast.info["factorisations"] == solves > dense.info["factorisations"]


def test_the_step_doubling_check_runs_the_diagonal_path():
    """The check's proxy springs (the BEM static rigid impedance shared by area): taken as a
    diagonal soil, with the same max uplift as the Python stepper."""
    from orchestrator.run import proxy_springs
    springs = proxy_springs(SCENE, True)
    contact = dataclasses.replace(SCENE.contact, precheck=False)
    fast = native(native_stepper.springs_soil(springs, DT).model, contact, 0.0)

    def run(ag):
        return simulate(SCENE.model(), springs, ag, DT, contact=contact, output_nodes=NODES)
    ref = run(MOTION.acc)
    assert ref.max_uplift() > 1e-3
    assert fast.max_uplift() == pytest.approx(ref.max_uplift(), rel=1e-10, abs=0.0)
    assert_same_histories(fast, ref, roundoff_spread(run, MOTION.acc, base=ref))
    assert fast.info["factorisations"] == fast.newton_iters.sum()

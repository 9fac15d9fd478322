"""The stand-in's poles chosen from the frequency domain (orchestrator/standin.py: ``Probe``,
``choose_poles``, ``pole_choice``), on the small reactor on the reactor's layered rock (21 nodes,
6 poles), swept and fitted once for the module."""
import numpy as np
import pytest

from helpers import small_reactor
from orchestrator.timefreq import GridOptions, prepare
from soil_impedance.fit.continuation import ContinuationBasis, continuation_fit, continuation_model

#: the reactor scene's soil (causal damping): the layered rock (as test_timefreq's)
LAYERED = {"damping_model": "causal",
           "layers": [{"thickness": 8.0, "vs": 1350.0, "nu": 0.3, "rho": 2400.0, "damping": 0.03}],
           "halfspace": {"vs": 1600.0, "nu": 0.3, "rho": 2500.0, "damping": 0.03}}


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    """(scene, model, motion, gap table, fit, problem) of the small reactor lifting under 0.5 g for 2 s."""
    from orchestrator.impedance import scene_fit, scene_impedance
    from orchestrator.motion import make_motion
    from orchestrator.scene import scene_from_dict
    from structure.spec import build_model

    tmp = tmp_path_factory.mktemp("poles")
    scene = scene_from_dict(small_reactor(soil=LAYERED, motion={"pga_g": 0.5, "duration_s": 2.0}), name="poles")
    model = build_model(scene.structure, scene.mesh.xy, scene.mesh.area)
    table = scene_impedance(scene, ("gap",), cache_dir=tmp)["gap"]
    fit = scene_fit(scene, cache_dir=tmp, table=table)
    motion = make_motion(scene.motion, scene.analysis.dt)
    prob = prepare(model, table, motion.acc, motion.dt, grid=GridOptions().resolved(bilinear=True, window=True),
                   contact=scene.contact)
    return scene, model, motion, table, fit, prob


def test_the_basis_gives_each_subsets_constrained_fit(case):
    """ContinuationBasis.residues (one projection, then a small least squares per subset) equals
    continuation_model's own least squares on the subset's poles (the whole table each time)."""
    table, fit = case[3], case[4]
    basis = ContinuationBasis(table, fit.model.poles)
    assert len(basis.units) == fit.model.order
    for kept in [tuple(range(len(basis.units))), (1, 2, 3), (0, 4), (len(basis.units) - 1,)]:
        poles, R = basis.residues(kept)
        model, _ = continuation_model(table, basis.unit_poles(kept))
        assert np.array_equal(poles, model.poles)
        assert np.abs(R - model.residues).max() < 1e-10 * np.abs(model.residues).max()


@pytest.mark.filterwarnings("ignore:rational soil model is not passive")
def test_the_probe_condenses_the_stand_in_as_the_route_does(case):
    """Probe.stand_in (the recursion's z-transform condensed on the structure at the sampled
    frequencies) equals the route's own operator on the RecursiveConvolutionSoil of the same
    model (InterfaceOperator.S_sub; the model need not be passive here: force), and Probe's table
    stiffness the route's operator on the table."""
    from orchestrator.standin import Probe
    from orchestrator.timefreq import InterfaceOperator, soil_bands
    from soil_impedance.convolution import RecursiveConvolutionSoil

    table, fit, prob = case[3], case[4], case[5]
    probe = Probe(prob)
    basis = ContinuationBasis(table, fit.model.poles)
    model, _ = continuation_model(table, basis.unit_poles((0, 2, 3)))
    Sx = probe.stand_in(model.D, model.E, model.poles, model.residues)
    op = InterfaceOperator(case[1], soil_bands(RecursiveConvolutionSoil(model, prob.grid.dt, force=True), prob.grid), prob.grid,
                           structure=prob.op.st)
    allN = np.arange(prob.op.N)
    ref = op.S_sub(allN, allN)[probe.ks]
    assert np.abs(Sx - ref).max() < 1e-9 * np.abs(ref).max()
    St = prob.op.S_sub(allN, allN)[probe.ks]
    assert np.abs(probe.S - St).max() < 1e-9 * np.abs(St).max()


def test_the_predicted_worst_rate_estimates_the_spectral_radius(case):
    """``worst`` (the last of N_POWER power steps from two vectors at each sampled frequency) is
    within 30 % of the largest spectral radius of T = (S_x - S) S_x^-1 over those frequencies
    (its eigenvalues, computed here; measured within 2 %); ``rate`` is a rate (0 < rate < 1)."""
    from orchestrator.standin import Probe

    table, fit, prob = case[3], case[4], case[5]
    probe = Probe(prob)
    basis = ContinuationBasis(table, fit.model.poles)
    for kept in [tuple(range(len(basis.units))), (1, 2), (0, 3, 5)]:
        rate, worst = probe.predict(basis, kept)
        Sx = probe.stand_in(basis.A, basis.B, *basis.residues(kept))
        rho = max(np.abs(np.linalg.eigvals((Sx[i] - probe.S[i]) @ np.linalg.inv(Sx[i]))).max()
                  for i in range(probe.ks.size))
        assert 0.7 * rho <= worst <= 1.3 * rho, (kept, worst, rho)
        assert 0 < rate < 1.0


def test_the_chosen_poles_are_fewer_passive_within_the_bounds_and_the_same_from_the_cache(case, tmp_path):
    """choose_poles keeps fewer poles than the fit's on this scene; their constrained fit is
    passive and its predicted rates meet the bounds; the same inputs choose the same poles, and
    pole_choice writes them once (tf-poles-*.h5) and reads the same choice back."""
    import orchestrator.standin as standin

    table, fit, prob = case[3], case[4], case[5]
    choice = standin.choose_poles(prob, table, fit.model.poles)
    assert not choice.fallback and 0 < len(choice.kept) < choice.units == fit.model.order
    assert choice.rate <= standin.RATE_BOUND and choice.worst <= standin.WORST_BOUND
    kept = ContinuationBasis.kept_poles(fit.model.poles, choice.kept)
    assert continuation_fit(table, kept).passive
    assert standin.choose_poles(prob, table, fit.model.poles) == choice
    first = standin.pole_choice(prob, table, fit.model.poles, cache_dir=tmp_path)
    assert len(list(tmp_path.glob("tf-poles-*.h5"))) == 1
    assert first == choice == standin.pole_choice(prob, table, fit.model.poles, cache_dir=tmp_path)


def test_without_a_subset_the_route_marches_all_the_poles_and_says_so(case, monkeypatch):
    """No subset meets the bounds (RATE_BOUND set below any rate): the route marches today's
    stand-in on all the fit's poles, converges to the same max uplift as on the chosen poles and
    as the march on the table's own kernel (1e-6, the route's tolerance), and its info says so
    (stand_in_fallback, stand_in_poles, the reason's text); the chosen poles' sweeps are no more."""
    import orchestrator.standin as standin
    from orchestrator.routes.timefreq import run_timefreq

    scene, model, motion, table, fit, _ = case
    kw = dict(contact=scene.contact, output_nodes=scene.output.nodes)
    chosen = run_timefreq(motion, model, table, fit=fit, **kw)
    today = run_timefreq(motion, model, table, **kw)
    monkeypatch.setattr(standin, "RATE_BOUND", -1.0)
    every = run_timefreq(motion, model, table, fit=fit, **kw)
    assert chosen.info["march"] == every.info["march"] == "stand-in"
    assert not chosen.info["stand_in_fallback"] and len(chosen.info["stand_in_poles"]) < fit.model.order
    assert every.info["stand_in_fallback"] and every.info["stand_in_poles"] == list(range(fit.model.order))
    assert f"all {fit.model.order} poles (no subset" in every.info["stand_in"]
    assert chosen.info["iterations"] <= every.info["iterations"]
    assert today.max_uplift() > 1e-3
    for res in (chosen, every):
        assert res.converged and abs(res.max_uplift() / today.max_uplift() - 1) < 1e-6


def test_a_failed_prediction_marches_all_the_poles(case, monkeypatch):
    """A prediction that cannot be made (a singular system at a sampled frequency: LinAlgError)
    leaves the route on today's stand-in, all the poles, said in its info."""
    import orchestrator.standin as standin
    from orchestrator.routes.timefreq import run_timefreq

    def singular(self, basis, kept):
        raise np.linalg.LinAlgError("Singular matrix")
    scene, model, motion, table, fit, _ = case
    monkeypatch.setattr(standin.Probe, "predict", singular)
    res = run_timefreq(motion, model, table, fit=fit, contact=scene.contact, output_nodes=scene.output.nodes)
    assert res.converged and res.info["march"] == "stand-in"
    assert res.info["stand_in_fallback"] and res.info["stand_in_poles"] == list(range(fit.model.order))

"""The stand-in's poles chosen from the frequency domain, once per scene (orchestrator/standin.py:
``Probe``, ``choose_poles``, ``pole_choice``, ``scene_stand_in``), on the small reactor on the
reactor's layered rock (21 nodes, 6 poles), swept and fitted once for the module.

On this scene no subset of fewer poles meets the rule's bounds and is passive (its six poles
are kept: the fallback; 8 sweeps at 0.7 g, as with the five poles the record-dependent rule kept,
docs/native.md). The tests of a kept subset widen the bounds (``WIDE``) so that one is."""
import numpy as np
import pytest

from helpers import small_reactor
from orchestrator.timefreq import GridOptions, prepare
from soil_impedance.fit.continuation import ContinuationBasis, continuation_fit, continuation_model

#: the reactor scene's soil (causal damping): the layered rock (as test_timefreq's)
LAYERED = {"damping_model": "causal",
           "layers": [{"thickness": 8.0, "vs": 1350.0, "nu": 0.3, "rho": 2400.0, "damping": 0.03}],
           "halfspace": {"vs": 1600.0, "nu": 0.3, "rho": 2500.0, "damping": 0.03}}
#: bounds under which a subset of this scene's poles is kept (rate 0.10, worst 0.32 for the one kept)
WIDE = {"RATE_BOUND": 0.15, "WORST_BOUND": 0.35}


def _problem(scene, model, table, motion):
    return prepare(model, table, motion.acc, motion.dt, grid=GridOptions().resolved(bilinear=True, window=True),
                   contact=scene.contact)


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
    return scene, model, motion, table, fit, _problem(scene, model, table, motion)


@pytest.fixture
def wide(monkeypatch):
    import orchestrator.standin as standin
    for name, value in WIDE.items():
        monkeypatch.setattr(standin, name, value)


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


def test_the_probe_grid_is_a_grid_the_route_reads(case):
    """A ProbeGrid at a route grid's own frequencies and window rate gives that grid's z and s, and
    the Probe's table stiffness on it (the route's bands and operator) is the route's operator's
    (InterfaceOperator.S_sub) there: the probe's frequencies are read as the route reads its grid's."""
    from orchestrator.standin import Probe, ProbeGrid

    model, table, prob = case[1], case[3], case[5]
    g = prob.grid
    ks = np.array([1, 7, 40, g.n_freq // 3, g.n_freq - 3])
    pg = ProbeGrid(g.dt, g.freq_hz[ks], g.eta)
    assert np.allclose(pg.z, g.z[ks], rtol=1e-13, atol=0) and np.allclose(pg.s, g.s[ks], rtol=1e-12, atol=0)
    probe = Probe(model, table, g.dt, prob.op.st, grid=pg)
    allN = np.arange(prob.op.N)
    ref = prob.op.S_sub(allN, allN)[ks]
    assert np.abs(probe.S - ref).max() < 1e-10 * np.abs(ref).max()


@pytest.mark.filterwarnings("ignore:rational soil model is not passive")
def test_the_probe_condenses_the_stand_in_as_the_route_does(case):
    """Probe.stand_in (the recursion's z-transform condensed on the structure at the probe's
    frequencies) equals the route's own operator on the RecursiveConvolutionSoil of the same model
    (InterfaceOperator.S_sub on the probe's grid; the model need not be passive here: force); and
    Probe.subset_stand_in (a subset's stand-in from the parts of every column, made once) equals
    Probe.stand_in of the subset's residues (ContinuationBasis.residues), on the fit's real poles
    and on poles with complex pairs."""
    from orchestrator.standin import Probe
    from orchestrator.timefreq import InterfaceOperator, soil_bands
    from soil_impedance.convolution import RecursiveConvolutionSoil

    model, table, fit, prob = case[1], case[3], case[4], case[5]
    probe = Probe(model, table, prob.grid.dt, prob.op.st)
    basis = ContinuationBasis(table, fit.model.poles)
    rational, _ = continuation_model(table, basis.unit_poles((0, 2, 3)))
    Sx = probe.stand_in(rational.D, rational.E, rational.poles, rational.residues)
    op = InterfaceOperator(model, soil_bands(RecursiveConvolutionSoil(rational, prob.grid.dt, force=True), probe.grid),
                           probe.grid, structure=prob.op.st)
    allN = np.arange(prob.op.N)
    ref = op.S_sub(allN, allN)
    assert np.abs(Sx - ref).max() < 1e-9 * np.abs(ref).max()
    for kept in [(0, 2, 3), tuple(range(len(basis.units))), (1, 4)]:
        direct = probe.stand_in(basis.A, basis.B, *basis.residues(kept))
        assert np.abs(probe.subset_stand_in(basis, kept) - direct).max() < 1e-10 * np.abs(direct).max(), kept
    paired = ContinuationBasis(table, [-800.0, -150 + 300j, -150 - 300j, -40.0, -10 + 20j, -10 - 20j, -1.5])
    assert len(paired.units) == 5                           # complex pairs: two columns a unit
    for kept in [(1, 3), (0, 1, 2, 3, 4), (2, 4)]:
        direct = probe.stand_in(paired.A, paired.B, *paired.residues(kept))
        assert np.abs(probe.subset_stand_in(paired, kept) - direct).max() < 1e-10 * np.abs(direct).max(), kept


def test_the_predicted_worst_rate_estimates_the_spectral_radius(case):
    """``worst`` (the last of N_POWER power steps from the directions' forces and a fixed vector at
    each probe frequency) is within 30 % of the largest spectral radius of T = (S_x - S) S_x^-1
    over those frequencies (its eigenvalues, computed here); ``rate`` is a rate (0 < rate < 1)."""
    from orchestrator.standin import Probe

    model, table, fit, prob = case[1], case[3], case[4], case[5]
    probe = Probe(model, table, prob.grid.dt, prob.op.st)
    basis = ContinuationBasis(table, fit.model.poles)
    for kept in [tuple(range(len(basis.units))), (1, 2), (0, 3, 5)]:
        rate, worst = probe.predict(basis, kept)
        Sx = probe.stand_in(basis.A, basis.B, *basis.residues(kept))
        rho = max(np.abs(np.linalg.eigvals((Sx[i] - probe.S[i]) @ np.linalg.inv(Sx[i]))).max()
                  for i in range(probe.grid.n_freq))
        assert 0.7 * rho <= worst <= 1.3 * rho, (kept, worst, rho)
        assert 0 < rate < 1.0


def test_the_design_spectrum_falls_as_the_synthetic_motions_do():
    """design_psd (the probe's forcing) against the mean power spectrum of two RG 1.60 synthetic
    motions (orchestrator.motion), band by band from 0.2 to 25 Hz relative to the 2.5-5 Hz band:
    within a factor 1.5 (measured 0.84-1.16 over four 20 s motions), while the motions' bands fall
    about 100-fold from there to 16-25 Hz, where a flat spectrum (round five's record-free rule)
    would put as much as at 2.5-5 Hz."""
    from orchestrator.motion import synthetic_motion
    from orchestrator.standin import design_psd

    dt = 0.005
    power = np.mean([np.abs(np.fft.rfft(synthetic_motion(pga_g=0.25, duration_s=20.0, dt=dt, seed=seed).acc[:, 0])) ** 2
                     for seed in (1, 2)], axis=0)
    f = np.fft.rfftfreq(4001, dt)
    bands = [(0.2, 0.5), (0.5, 1.0), (1.0, 2.5), (2.5, 5.0), (5.0, 9.0), (9.0, 16.0), (16.0, 25.0)]
    measured = np.array([power[(f >= lo) & (f < hi)].mean() for lo, hi in bands])
    shape = np.array([design_psd(f[(f >= lo) & (f < hi)]).mean() for lo, hi in bands])
    ratio = (measured / measured[3]) / (shape / shape[3])
    assert np.all((ratio > 1 / 1.5) & (ratio < 1.5)), ratio
    assert measured[3] / measured[-1] > 30


@pytest.mark.usefixtures("wide")
def test_the_choice_is_the_scenes_not_the_records(case, tmp_path):
    """Two records of the scene (other seed, level and length: another grid) choose the same poles
    from one cache entry (tf-poles-*.h5, whose key has no record), fewer than the fit's, whose
    constrained fit is passive and whose predicted rates meet the bounds; of the constrained fits
    tested for passivity only the kept one is written (standin-*.h5: one entry)."""
    import dataclasses

    import orchestrator.standin as standin
    from orchestrator.motion import make_motion

    scene, model, motion, table, fit, prob = case
    other = make_motion(dataclasses.replace(scene.motion, seed=7, pga_g=0.3, duration_s=3.0), scene.analysis.dt)
    prob2 = _problem(scene, model, table, other)
    assert prob2.grid.nfft != prob.grid.nfft
    first = standin.scene_stand_in(prob.model, table, fit.model, prob.grid.dt, structure=prob.op.st, cache_dir=tmp_path)
    second = standin.scene_stand_in(prob2.model, table, fit.model, prob2.grid.dt, structure=prob2.op.st,
                                    cache_dir=tmp_path)
    assert first == second and first.key == second.key and second.fit.cached
    assert not first.fallback and 0 < len(first.kept) < first.units == fit.model.order
    assert first.rate <= standin.RATE_BOUND and first.worst <= standin.WORST_BOUND
    assert first.tested > 1                                  # subsets rejected before the kept one
    assert len(list(tmp_path.glob("tf-poles-*.h5"))) == 1 and len(list(tmp_path.glob("standin-*.h5"))) == 1
    kept = ContinuationBasis.kept_poles(fit.model.poles, first.kept)
    assert continuation_fit(table, kept).passive
    assert np.array_equal(second.fit.model.poles, kept)


def test_without_a_subset_the_route_marches_all_the_poles_and_says_so(case, monkeypatch):
    """The fallback: on this scene no subset meets the bounds and is passive (RATE_BOUND also set
    below any rate, so that it stays so), and the route marches today's stand-in on all the fit's
    poles and says so (stand_in_fallback, stand_in_poles, the reason's text); with a subset kept
    (WIDE bounds) the route converges to the same max uplift as on all the poles and as the march
    on the table's own kernel (1e-6, the route's tolerance), in no more sweeps."""
    import orchestrator.standin as standin
    from orchestrator.routes.timefreq import run_timefreq

    scene, model, motion, table, fit, _ = case
    kw = dict(contact=scene.contact, output_nodes=scene.output.nodes)
    today = run_timefreq(motion, model, table, **kw)
    monkeypatch.setattr(standin, "RATE_BOUND", -1.0)
    every = run_timefreq(motion, model, table, fit=fit, **kw)
    for name, value in WIDE.items():
        monkeypatch.setattr(standin, name, value)
    chosen = run_timefreq(motion, model, table, fit=fit, **kw)
    assert chosen.info["march"] == every.info["march"] == "stand-in"
    assert not chosen.info["stand_in_fallback"] and len(chosen.info["stand_in_poles"]) < fit.model.order
    assert every.info["stand_in_fallback"] and every.info["stand_in_poles"] == list(range(fit.model.order))
    assert f"all {fit.model.order} poles (no subset" in every.info["stand_in"]
    assert chosen.info["iterations"] <= every.info["iterations"]
    assert today.max_uplift() > 1e-3
    for res in (chosen, every):
        assert res.converged and abs(res.max_uplift() / today.max_uplift() - 1) < 1e-6


def test_a_failed_prediction_marches_all_the_poles(case, monkeypatch, tmp_path):
    """A prediction that cannot be made (a singular system at a probe frequency: LinAlgError)
    leaves the route on today's stand-in, all the poles, said in its info; that choice is not kept."""
    import orchestrator.standin as standin
    from helpers.native import seed_native
    from orchestrator.routes.timefreq import run_timefreq

    def singular(self, basis, kept):
        raise np.linalg.LinAlgError("Singular matrix")
    scene, model, motion, table, fit, _ = case
    monkeypatch.setattr(standin.Probe, "predict", singular)
    res = run_timefreq(motion, model, table, fit=fit, contact=scene.contact, output_nodes=scene.output.nodes,
                       cache_dir=seed_native(tmp_path))
    assert res.converged and res.info["march"] == "stand-in"
    assert res.info["stand_in_fallback"] and res.info["stand_in_poles"] == list(range(fit.model.order))
    assert not list(tmp_path.glob("tf-poles-*.h5"))

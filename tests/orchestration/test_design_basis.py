"""Design-basis deliverables (docs/design_basis.md): soil cases by the Cv rule (moduli exactly as
the rule says; each case's BEM the same, bit for bit, as a scene typed by hand), peak broadening
and envelopes of floor spectra, the results file per case, the commands on it."""
import json
import math

import h5py
import numpy as np
import pytest

from helpers import tower, write_scene
from orchestrator.cli import main
from orchestrator.design import case_envelope, read_design, run_design, write_design
from orchestrator.motion import G
from orchestrator.design_spectra import DesignSpectraConfig, broadened, design_spectra, envelope, raw_spectra
from orchestrator.results_file import read_cases, read_results, summary
from orchestrator.scene import SceneError, load_scene, scene_from_dict
from orchestrator.scene_file import scene_toml
from orchestrator.spectra import floor_spectra
from soil_impedance import impedance_sweep
from soil_impedance.sweep import table_key
from structure.results import RouteResult, Status

LAYERED = {"layers": [{"thickness": 4.0, "vs": 300.0, "nu": 0.3, "rho": 1900.0, "damping": 0.04}],
           "halfspace": {"vs": 600.0, "vp": 1200.0, "rho": 2100.0, "damping": 0.02}}


def design_scene(**soil):
    """The tower on a layered soil (BEM-calibrated Winkler springs: each case its own), a coarse
    raft, three frequencies, with [soil] ``soil`` added."""
    return tower(soil={**LAYERED, "winkler": None, **soil}, foundation={"element_size": 5.0},
                 impedance={"range_hz": [0.0, 8.0, 3]}, motion={"duration_s": 2.0})


def cases_of(data):
    from orchestrator.design import design_cases
    from orchestrator.motion import make_motion
    scene = scene_from_dict(data)
    return dict(design_cases(scene, make_motion(scene.motion, scene.analysis.dt))[0])


def test_cv_rule_gives_lower_and_upper_bound_moduli_exactly():
    cases = cases_of(design_scene(cases={"cv": 0.5}))
    assert list(cases) == ["be", "lb", "ub"]
    be = cases["be"].profile
    for name, factor in (("lb", 1 / 1.5), ("ub", 1.5)):
        p = cases[name].profile
        for m, m0 in zip((*p.layers, p.halfspace), (*be.layers, be.halfspace)):
            assert m.shear_modulus / m0.shear_modulus == pytest.approx(factor, rel=1e-14)
            assert (m.rho, m.damping, m.damping_model) == (m0.rho, m0.damping, m0.damping_model)
            assert m.poisson == pytest.approx(m0.poisson, rel=1e-14)      # vp scaled with vs
        assert p.layers[0].thickness == be.layers[0].thickness
    assert be == scene_from_dict(design_scene()).profile                  # BE: the soil as typed


def test_each_case_is_bit_for_bit_a_scene_typed_by_hand():
    """The LB case's sweep key and impedance are those of a scene whose [soil] says the same numbers."""
    lb = cases_of(design_scene(cases={"cv": 0.5}))["lb"]
    hand = design_scene()
    hand["soil"]["layers"][0].update(vs=300.0 / math.sqrt(1.5))
    hand["soil"]["halfspace"].update(vs=600.0 / math.sqrt(1.5), vp=1200.0 / math.sqrt(1.5))
    typed = scene_from_dict(hand)
    key = lambda s: table_key(s.profile, s.mesh, s.frequencies_hz, s.contact_kind, "rigid")
    assert key(lb) == key(typed)
    freqs = np.array([2.0])
    a = impedance_sweep(lb.profile, lb.mesh, freqs, outputs=("rigid",))["rigid"].matrices
    b = impedance_sweep(typed.profile, typed.mesh, freqs, outputs=("rigid",))["rigid"].matrices
    assert np.array_equal(a, b)
    base = scene_from_dict(design_scene())
    c = impedance_sweep(base.profile, base.mesh, freqs, outputs=("rigid",))["rigid"].matrices
    assert abs(a[0, 0, 0].real / c[0, 0, 0].real - 1 / 1.5) < 0.1            # softer soil, softer raft


def test_case_scene_toml_runs_the_case_alone(tmp_path):
    ub = cases_of(design_scene(cases={"cv": 0.5}))["ub"]
    path = tmp_path / "ub.toml"
    path.write_text(scene_toml(ub))
    again = load_scene(path)
    assert again.profile == ub.profile and again.soil_cases is None


@pytest.mark.parametrize("soil, msg", [
    ({"cases": {"cv": 0.2}}, "soil.cases.cv = 0.2 must be a coefficient of variation"),
    ({"cases": {}}, "soil.cases: give cv"),
    ({"cases": {"cv": 0.5, "profiles": []}}, "soil.cases: give cv"),
    ({"cases": {"profiles": [{"name": "a b", "halfspace": LAYERED["halfspace"]}]}}, "must be a short name"),
    ({"cases": {"profiles": [{"name": "soft", "halfspace": {"vs": -1.0, "nu": 0.3, "rho": 2000.0}}]}},
     "soil.cases.profiles[0]"),
    ({"strain_compatible": {"curves": ["darendeli", "linear"]}}, "one curve per layer (1)"),
    ({"strain_compatible": {"curves": [{"model": "table", "strain": [1e-4, 1e-5], "g_ratio": [1, 0.5],
                                        "damping": [0.01, 0.05]}]}}, "strictly increasing"),
    ({"strain_compatible": {"strain_ratio": 1.5}}, "strain_ratio = 1.5"),
    ({"strain_compatible": {"input": "surface"}}, 'soil.strain_compatible.input = \'surface\': use one of'),
])
def test_bad_design_keys_are_one_line_errors_naming_the_key(soil, msg):
    with pytest.raises(SceneError) as err:
        scene_from_dict(design_scene(**soil))
    assert msg in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize("spectra, msg", [
    ({"nodes": ["roof"]}, "output.design_spectra.nodes: 'roof' is not among the nodes kept"),
    ({"routes": ["monolithic"]}, "output.design_spectra.routes: 'monolithic' is not run"),
    ({"damping": [0.05, 0.7]}, "output.design_spectra.damping[1] = 0.7 must be a damping ratio in (0, 0.5)"),
    ({"broadening": 0.6}, "output.design_spectra.broadening = 0.6"),
    ({"directions": ["x", "up"]}, "output.design_spectra.directions"),
    ({"range_hz": [10.0, 1.0, 50]}, "output.design_spectra.range_hz[1] = 1.0 must be a frequency > 10 Hz"),
    ({"widen": 0.15}, "unknown key output.design_spectra.widen"),
])
def test_bad_design_spectra_keys_are_one_line_errors_naming_the_key(spectra, msg):
    data = design_scene()
    data["output"]["design_spectra"] = spectra
    with pytest.raises(SceneError) as err:
        scene_from_dict(data)
    assert msg in str(err.value) and "\n" not in str(err.value)


def test_named_profiles_are_cases_in_order():
    soft = {"name": "soft", "layers": [{**LAYERED["layers"][0], "vs": 250.0}], "halfspace": LAYERED["halfspace"]}
    stiff = {"name": "stiff", "halfspace": {**LAYERED["halfspace"], "vs": 900.0, "vp": None}}
    stiff["halfspace"] = {k: v for k, v in stiff["halfspace"].items() if v is not None} | {"nu": 0.3}
    cases = cases_of(design_scene(cases={"profiles": [soft, stiff]}))
    assert list(cases) == ["soft", "stiff"]
    assert cases["soft"].profile.layers[0].vs == 250.0 and not cases["stiff"].profile.layers


# ---- broadening and envelopes -------------------------------------------------------------------

def test_broadening_of_a_narrow_peak_covers_plus_minus_15_percent():
    f = np.geomspace(0.5, 50.0, 600)
    f0 = f[300]
    raw = 0.2 + np.where(f == f0, 1.0, 0.0) + 0.05 * np.exp(-((f - 20.0) / 3.0) ** 2)
    b = broadened(f, raw, 0.15)
    inside = (f >= 0.85 * f0) & (f <= 1.15 * f0)
    assert np.all(b[inside] == raw.max())
    assert np.all(b[~inside] < raw.max())
    assert np.all(b >= raw)
    # at every f: the max of the raw spectrum over [f / 1.15, f / 0.85] (the rule as stated)
    rule = np.array([raw[(f >= x / 1.15 * (1 - 1e-12)) & (f <= x / 0.85 * (1 + 1e-12))].max() for x in f])
    assert np.array_equal(b, rule)


def test_broadened_never_below_raw_and_envelope_never_below_any_case():
    rng = np.random.default_rng(4)
    f = np.geomspace(0.5, 40.0, 150)
    raw = rng.random((3, 2, 150))
    raw[1, 1] = np.nan                                    # a direction at round-off stays NaN
    b = broadened(f, raw, 0.15)
    assert np.all(b[np.isfinite(raw)] >= raw[np.isfinite(raw)]) and np.isnan(b[1, 1]).all()
    env = envelope(b, axis=0)
    assert np.all(env >= np.nan_to_num(b, nan=-np.inf))
    assert np.isfinite(env).all()
    strided = np.asfortranarray(raw)                      # any memory layout (a selection of directions)
    assert np.array_equal(broadened(f, strided, 0.15), b, equal_nan=True)


def _floor(route, amp, f_hz, nt=400, dt=0.01):
    t = dt * np.arange(nt)
    acc = {"top": np.column_stack([amp * np.sin(2 * np.pi * f_hz * t) * np.exp(-0.3 * t), 0 * t, 0 * t])}
    return RouteResult(route=route, time=t, raft=np.zeros((nt, 6)), gap=np.zeros((nt, 2)),
                       contact_force=np.ones((nt, 2)), acc=acc, status=Status.CONVERGED)


def test_design_spectra_of_cases_are_their_raw_spectra_broadened_and_enveloped():
    cases = {"be": {"winkler": _floor("winkler", 1.0, 3.0)}, "lb": {"winkler": _floor("winkler", 0.8, 2.4)},
             "ub": {"winkler": _floor("winkler", 0.7, 3.7)}}
    cfg = DesignSpectraConfig(damping=(0.02, 0.05), range_hz=(0.5, 20.0, 80))
    ds = design_spectra(cases, cfg, ["top"], ("x",))
    assert ds.raw.shape == (3, 1, 1, 1, 2, 80) and ds.envelope.shape == (1, 1, 1, 2, 80)
    # the 5 % raw spectrum is the floor spectrum of the results file at the same frequencies
    same = floor_spectra(cases["lb"]["winkler"].acc, 0.01, ["top"], cfg.frequencies_hz, 0.05)[0, 0]
    assert np.array_equal(ds.raw[1, 0, 0, 0, 1], same)
    assert np.all(ds.raw[:, :, :, :, 0] > ds.raw[:, :, :, :, 1])          # less damping, larger spectrum
    assert np.all(ds.envelope[None] >= ds.broadened) and np.all(ds.broadened >= ds.raw)
    # the envelope takes each case where it governs: the three peaks sit near 2.4, 3 and 3.7 Hz
    peak_f = [cfg.frequencies_hz[np.argmax(ds.raw[c, 0, 0, 0, 1])] for c in range(3)]
    for c, fp in enumerate(peak_f):
        assert ds.envelope[0, 0, 0, 1, list(cfg.frequencies_hz).index(fp)] >= ds.raw[c, 0, 0, 0, 1].max()


def test_raw_spectra_of_a_harmonic_floor_motion_match_the_steady_state_closed_form():
    """A long harmonic floor acceleration at f: the oscillator at f with damping z peaks near
    a / (2 z) (resonance, steady state), independent of the spectrum code's own tests."""
    dt, f, a = 0.005, 4.0, 1.0
    t = dt * np.arange(int(60 / dt))
    acc = {"n": np.column_stack([a * np.sin(2 * np.pi * f * t), 0 * t, 0 * t])}
    psa = raw_spectra(acc, dt, ["n"], ["x"], [0.05], [f])[0, 0, 0, 0]
    assert psa == pytest.approx(a / (2 * 0.05), rel=0.01)


# ---- the design run, its file and the commands ---------------------------------------------------

#: the design run's tests: a few seconds each, plus the native stepper's compilation (about 40 s)
#: on the first time-stepped run of the process
@pytest.fixture(scope="module")
def design_file(tmp_path_factory):
    data = design_scene(cases={"cv": 0.5})
    data["output"]["design_spectra"] = {"damping": [0.05, 0.02], "range_hz": [0.5, 20.0, 40]}
    scene = scene_from_dict(data, name="tiny")
    run = run_design(scene)
    path = tmp_path_factory.mktemp("design") / "tiny.h5"
    write_design(path, run)
    return path, run, data


@pytest.mark.slow
def test_design_file_holds_every_case_and_reads_back(design_file):
    path, run, _ = design_file
    assert read_cases(path) == ["be", "lb", "ub"]
    top = read_results(path)
    for case in ("be", "lb", "ub"):
        back = read_results(path, case)
        res = run.cases[case]["winkler"]
        assert np.array_equal(back["winkler"].gap, res.gap)
        assert np.array_equal(back["winkler"].acc["top"], res.acc["top"])
    assert np.array_equal(top["winkler"].gap, run.cases["be"]["winkler"].gap)     # the first case on top
    ups = [summary(run.cases[c]["winkler"])["max_uplift_m"] for c in ("lb", "be", "ub")]
    assert len(set(ups)) == 3                                       # the soil moves the answer
    design = read_design(path)
    assert design["rule"] == {"cv": 0.5} and design["site_response"] is None
    ds = design["spectra"]
    assert ds.cases == ("be", "lb", "ub") and ds.damping == (0.05, 0.02)
    assert np.array_equal(ds.envelope, run.spectra.envelope, equal_nan=True)
    with h5py.File(path, "r") as f:
        profile = json.loads(f["cases/lb"].attrs["profile"])
    assert profile["layers"][0]["vs"] == 300.0 / math.sqrt(1.5)


def test_design_file_opens_in_xarray(design_file):
    xr = pytest.importorskip("xarray")
    path = design_file[0]
    with xr.open_dataset(path, group="design/spectra", engine="h5netcdf") as ds:
        assert ds["envelope"].dims == ("envelope_route", "output", "direction", "damping", "frequency")
    with xr.open_dataset(path, group="cases/ub/routes/winkler", engine="h5netcdf") as ds:
        assert float(ds.attrs["max_uplift_m"]) == summary(design_file[1].cases["ub"]["winkler"])["max_uplift_m"]


def test_envelope_over_cases_takes_the_governing_case(design_file):
    run = design_file[1]
    env = case_envelope(run.cases)["envelope"]["winkler"]
    ups = {c: summary(r["winkler"])["max_uplift_m"] for c, r in run.cases.items()}
    assert env["max_uplift_m"] == max(ups.values()) and ups[env["max_uplift_case"]] == env["max_uplift_m"]


@pytest.mark.slow
def test_commands_on_a_design_scene(design_file, tmp_path, capsys):
    data = design_file[2]
    scene = write_scene(tmp_path / "d.toml", data)
    out = tmp_path / "d.h5"
    assert main(["run", scene, "-o", str(out), "--json", "--no-cache", "--design-dir", str(tmp_path / "tables")]) == 0
    got = json.loads(capsys.readouterr().out)
    assert set(got["cases"]) == {"be", "lb", "ub"} and "winkler" in got["envelope"]
    csv = tmp_path / "tables" / "fs_winkler_top_x_5pct.csv"
    table = np.loadtxt(csv, delimiter=",")
    assert table.shape == (40, 8) and np.all(table[:, 1] >= table[:, 2:].max(axis=1) - 1e-12 * table[:, 1])
    assert (tmp_path / "tables" / "design_top_x.png").is_file()
    assert main(["compare", str(out), "--json"]) == 0
    cmp = json.loads(capsys.readouterr().out)
    assert set(cmp["cases"]) == {"be", "lb", "ub"}
    assert main(["report", str(out), "-o", str(tmp_path / "rep")]) == 0
    page = (tmp_path / "rep" / "report.html").read_text()
    assert "Design basis: soil cases" in page and "Envelope over the soil cases" in page


# ---- ensembles: one per case, fractile spectra broadened and enveloped ---------------------------

def _ensemble(peak_hz, scale, pgas=(0.1, 0.2)):
    xr = pytest.importorskip("xarray")
    f = np.geomspace(0.5, 40.0, 120)
    shape = (3, len(pgas), 1, 1, 3, f.size)
    q = np.full(shape, np.nan)
    for k, quant in enumerate((0.16, 0.5, 0.84)):
        for a, pga in enumerate(pgas):
            q[k, a, 0, 0, 0] = scale * pga * (1 + quant) * (1 + 4 * np.exp(-np.log(f / peak_hz) ** 2 / 0.002))
    return xr.Dataset({"floor_spectrum_fractile": (("quantile", "pga", "route", "node", "direction", "frequency"), q)},
                      coords={"quantile": [0.16, 0.5, 0.84], "pga": list(pgas), "route": ["monolithic"],
                              "node": ["top"], "direction": ["x", "y", "z"], "frequency": f})


def test_fractile_spectra_of_case_ensembles_are_broadened_and_enveloped(tmp_path):
    from orchestrator.ensemble import EnsembleError, fractile_design_spectra, write_fractile_tables
    sets = {"be": _ensemble(3.0, 1.0), "lb": _ensemble(2.5, 0.9), "ub": _ensemble(3.6, 1.1)}
    d = fractile_design_spectra(sets, quantile=0.84, ratio=0.15)
    assert d["raw"].shape == (3, 2, 1, 1, 3, 120)
    np.testing.assert_array_equal(d["raw"][2], sets["ub"]["floor_spectrum_fractile"].sel(quantile=0.84).values)
    finite = np.isfinite(d["raw"])
    env = np.broadcast_to(d["envelope"][None], d["raw"].shape)
    assert np.all(d["broadened"][finite] >= d["raw"][finite]) and np.all(env[finite] >= d["broadened"][finite])
    f = d["frequency"]
    k = int(np.argmax(d["raw"][0, 1, 0, 0, 0]))                  # be's narrow peak at 3 Hz, 0.2 g
    inside = (f >= 0.85 * f[k]) & (f <= 1.15 * f[k])
    assert np.all(d["broadened"][0, 1, 0, 0, 0][inside] == d["raw"][0, 1, 0, 0, 0, k])
    paths = write_fractile_tables(d, tmp_path)
    assert [p.name for p in paths] == ["ens_0.1g_monolithic_top_x_p84.csv", "ens_0.2g_monolithic_top_x_p84.csv"]
    table = np.loadtxt(paths[1], delimiter=",")
    np.testing.assert_allclose(table[:, 1], d["envelope"][1, 0, 0, 0] / G, rtol=1e-6)
    with pytest.raises(EnsembleError, match="differ in their pga"):
        fractile_design_spectra({"be": sets["be"], "lb": _ensemble(2.5, 0.9, pgas=(0.1, 0.3))})


def test_an_ensemble_of_a_scene_with_cases_runs_one_case(tmp_path, capsys):
    from orchestrator.cli import OptionError, _ensemble_case
    from orchestrator.ensemble import EnsembleError, plan_ensemble
    scene = scene_from_dict(design_scene(cases={"cv": 0.5}), name="tiny")
    with pytest.raises(OptionError, match="give --case NAME"):
        _ensemble_case(scene, None)
    with pytest.raises(OptionError, match="has the soil cases be, lb, ub"):
        _ensemble_case(scene, "mid")
    lb = _ensemble_case(scene, "lb")
    assert lb.name == "tiny_lb" and lb.profile == cases_of(design_scene(cases={"cv": 0.5}))["lb"].profile
    assert plan_ensemble(lb, [0.1]).cells                              # a case is a scene of one soil
    with pytest.raises(EnsembleError, match="an ensemble runs one soil"):
        plan_ensemble(scene, [0.1])


def test_the_reactor_design_example_loads_with_every_deliverable():
    from helpers import ROOT
    scene = load_scene(ROOT / "examples" / "reactor_design.toml")
    assert scene.soil_cases.cv == 0.5 and scene.strain_compatible.curves[0].model == "darendeli"
    assert scene.design_spectra.damping == (0.02, 0.05) and scene.design_spectra.envelope_routes
    assert scene.profile == load_scene("reactor").profile                  # the built-in reactor's soil


def test_design_spectra_of_one_soil_without_a_bem_profile():
    """[output] design_spectra alone, on Winkler moduli (no BEM soil): one case, "be", whose
    envelope is its broadened spectrum."""
    data = tower(soil={"halfspace": None}, output={"design_spectra": {"damping": [0.05], "range_hz": [0.5, 20.0, 30]}})
    run = run_design(scene_from_dict(data))
    assert list(run.cases) == ["be"] and run.scenes["be"].profile is None
    ds = run.spectra
    assert np.array_equal(ds.envelope, ds.broadened[0], equal_nan=True)

"""Three components of motion at once: the [motion] contract, the motion, every route, the summaries.

The small scene is tests/orchestration/test_run.py's tower on a square 10 m raft (4 x 4 nodes: symmetric under
a quarter turn about z) over the BEM half-space; its impedance tables are cached after the first run.
"""
import json

import numpy as np
import pytest

from orchestrator.cli import main
from orchestrator.motion import (G, VERTICAL_RATIO, Motion, MotionError, read_components, synthetic_components,
                                 synthetic_motion)
from orchestrator.results_file import read_motion, read_results, summary
from orchestrator.run import run_scene
from orchestrator.scene import SceneError, scene_from_dict
from structure import ContactSettings, simulate
from structure.broadband import broadband_accelerogram
from helpers import changed, tower, write_scene

DT = 0.01
SOIL = {"halfspace": {"vs": 500.0, "nu": 0.3, "rho": 2000.0}}
BASE = {
    "soil": SOIL,
    "foundation": {"shape": "rectangle", "lx": 10.0, "ly": 10.0, "element_size": 2.5},
    "impedance": {"range_hz": [0.0, 20.0, 11]},
    "structure": {"nodes": [{"id": 1, "xyz": [0, 0, 0]}, {"id": 2, "xyz": [0, 0, 20], "name": "top"}],
                  "beams": [{"nodes": [1, 2], "E": 3e10, "G": 1.25e10, "A": 10.0, "Iy": 20.0, "Iz": 20.0,
                             "J": 40.0}],
                  "masses": [{"node": 2, "m": 2.0e6, "inertia": [0, 0, 0]}],
                  "raft": {"node": 1, "m": 1.0e6, "inertia": [1e7, 1e7, 2e7]}, "damping": {"modal": 0.05}},
    "contact": {"enabled": True},
    "analysis": {"routes": ["linear"], "dt": DT},
    "output": {"nodes": ["top"]},
}


def _write(path, t, a_g):
    np.savetxt(path, np.column_stack([t, a_g]), header="time (s), acceleration (g)")
    return path.name


@pytest.fixture(scope="module")
def records(tmp_path_factory):
    """A folder with a broadband record (3 s, 0.3 g), a longer copy, a copy at another step, and
    a vertical pulse downward of 1.5 g (0.3 s long at t = 0.5 s)."""
    d = tmp_path_factory.mktemp("records")
    a = broadband_accelerogram(3.0, DT, 0.3 * G, seed=4) / G
    t = DT * np.arange(a.size)
    pulse = np.where((t > 0.5) & (t < 0.8), -1.5 * np.sin(np.pi * (t - 0.5) / 0.3), 0.0)
    _write(d / "rec.txt", t, a)
    _write(d / "long.txt", DT * np.arange(a.size + 5), np.concatenate([a, np.zeros(5)]))
    _write(d / "fine.txt", 0.5 * t, a)
    _write(d / "pulse.txt", t, pulse)
    return d


def _scene(folder, motion, **changes):
    return scene_from_dict({**BASE, **changes, "motion": motion}, base_dir=folder)


def _run(folder, motion, **changes):
    results, used = run_scene(_scene(folder, motion, **changes))
    return results, used


# ---- the motion -----------------------------------------------------------------------------------

def test_synthetic_components_are_independent_baseline_corrected_and_scaled():
    """Each component: its own generator (child k of SeedSequence(seed)), so asking for fewer
    components does not change the others; horizontals peak at pga_g, z at 2/3 of it (exactly, at
    the generation step); final ground velocity and displacement zero (baseline correction)."""
    m = synthetic_components(0.3, 4.0, 0.005, seed=5)
    assert m.components == ("x", "y", "z")
    assert np.allclose(m.pga, [0.3 * G, 0.3 * G, VERTICAL_RATIO * 0.3 * G], rtol=1e-12)
    alone = synthetic_components(0.3, 4.0, 0.005, seed=5, components=["y"])
    assert alone.components == ("y",) and np.array_equal(alone.acc[:, 1], m.acc[:, 1])
    assert not alone.acc[:, [0, 2]].any()
    # statistically independent components: correlation of x with y and z well below 1
    corr = np.corrcoef(m.acc.T)
    assert abs(corr[0, 1]) < 0.2 and abs(corr[0, 2]) < 0.2 and abs(corr[1, 2]) < 0.2, corr
    for k in range(3):
        v = np.concatenate([[0.0], np.cumsum(0.5 * (m.acc[1:, k] + m.acc[:-1, k]) * 0.005)])
        disp = np.trapezoid(v, dx=0.005) if hasattr(np, "trapezoid") else np.trapz(v, dx=0.005)
        assert abs(v[-1]) < 1e-10 * np.abs(v).max() and abs(disp) < 1e-10 * np.abs(v).max() * 4.0
    # the legacy one-direction motion is untouched (same seed, same record as before)
    assert np.array_equal(synthetic_motion(0.3, 4.0, 0.005, seed=5, direction="y").acc[:, 1],
                          synthetic_motion(0.3, 4.0, 0.005, seed=5).acc[:, 0])
    # vertical_ratio scales the vertical only: the same record, peak pga_g x vertical_ratio
    full = synthetic_components(0.3, 4.0, 0.005, seed=5, components=["z"], vertical_ratio=1.0)
    assert full.pga[2] == pytest.approx(0.3 * G, rel=1e-12)
    assert np.allclose(VERTICAL_RATIO * full.acc[:, 2], m.acc[:, 2], rtol=0, atol=1e-12 * G)


def test_record_components_read_per_axis(records):
    one = read_components({"x": records / "rec.txt"})
    both = read_components({"y": records / "rec.txt", "x": records / "rec.txt"}, scale=2.0)
    assert both.components == ("x", "y") and one.components == ("x",)
    assert np.array_equal(both.acc[:, 0], 2.0 * one.acc[:, 0]) and np.array_equal(both.acc[:, 1], both.acc[:, 0])
    assert not both.acc[:, 2].any()
    with pytest.raises(MotionError, match=r"differ in their lengths.*long\.txt.*306 samples"):
        read_components({"x": records / "rec.txt", "z": records / "long.txt"})
    with pytest.raises(MotionError, match=r"differ in their time steps.*fine\.txt.*dt = 0\.005"):
        read_components({"x": records / "rec.txt", "y": records / "fine.txt"})


def test_scene_contract(records):
    """direction keeps meaning one component; components gives several; they exclude each other."""
    legacy = _scene(records, {"kind": "record", "direction": "y", "file": "rec.txt"}).motion
    new = _scene(records, {"kind": "record", "components": {"y": "rec.txt"}}).motion
    assert legacy.axes == new.axes == ("y",) and legacy.direction == "y" and new.direction is None
    assert np.array_equal(legacy.record.acc, new.record.acc)
    syn = _scene(records, {"kind": "synthetic", "components": ["z", "x"], "duration_s": 3.0}).motion
    assert syn.components == ("x", "z") and syn.vertical_ratio == pytest.approx(2 / 3)
    assert _scene(records, {"kind": "synthetic", "duration_s": 3.0}).motion.direction == "x"
    for bad, msg in [({"kind": "synthetic", "components": []}, "non-empty subset"),
                     ({"kind": "synthetic", "components": ["x", "x"]}, "lists 'x' twice"),
                     ({"kind": "synthetic", "components": {"x": "rec.txt"}}, "takes a list of axes"),
                     ({"kind": "synthetic", "direction": "x", "vertical_ratio": 0.5}, "vertical_ratio"),
                     ({"kind": "synthetic", "components": ["x", "z"], "vertical_ratio": 3.0}, "vertical_ratio"),
                     ({"kind": "record", "components": ["x"]}, "one file per component"),
                     ({"kind": "record", "components": {"x": "nope.txt"}}, "motion.components.x"),
                     ({"kind": "record", "components": {"x": "rec.txt"}, "file": "rec.txt"}, "not both")]:
        with pytest.raises(SceneError, match=msg):
            _scene(records, bad)


@pytest.mark.parametrize("motion, message", [
    ('direction = "x"\ncomponents = ["x", "y"]', "give direction (one component) or components"),
    ('kind = "record"\ncomponents = { x = "rec.txt", z = "long.txt" }', "long.txt': 306 samples"),
    ('kind = "record"\ncomponents = { x = "rec.txt", y = "fine.txt" }', "fine.txt': 301 samples at dt = 0.005"),
    ('kind = "record"\ncomponents = { x = "rec.txt", w = "rec.txt" }', "unknown component 'w'"),
    ('kind = "record"\ncomponents = { x = "rec.txt" }\nvertical_ratio = 0.5', "unknown key motion.vertical_ratio"),
])
def test_scene_errors_exit_2_naming_the_file(records, tmp_path, capsys, motion, message):
    path = records / "bad.toml"
    write_scene(path, SCENE, "[motion]\n" + motion + "\n")
    assert main(["run", str(path), "-o", str(tmp_path / "r.h5")]) == 2
    err = capsys.readouterr().err
    assert str(path) in err and message in err, err
    assert not (tmp_path / "r.h5").exists()


SCENE = tower(contact=None, motion=None, output=None)


# ---- the routes -----------------------------------------------------------------------------------

def test_linear_x_and_y_at_once_rock_sqrt2_times_one_alone(records):
    """Linear route, raft symmetric under a quarter turn: the response to y is the response to x
    turned by 90°, so x and y of the same record at once rock with (−ry, ry) and their magnitude
    is √2 times one alone at every instant (1e-6); the per-axis peaks are those of one alone."""
    peaks = {}
    for comps in ({"x": "rec.txt"}, {"y": "rec.txt"}, {"x": "rec.txt", "y": "rec.txt"}):
        res, motion = _run(records, {"kind": "record", "components": comps})
        s = summary(res["linear"])
        assert s["components"] == sorted(comps) == list(motion.components)
        peaks["".join(sorted(comps))] = s
    x, y, xy = peaks["x"], peaks["y"], peaks["xy"]
    assert x["max_raft_rotation_rad"] > 1e-4
    assert xy["max_raft_rotation_rad"] == pytest.approx(np.sqrt(2) * x["max_raft_rotation_rad"], rel=1e-6)
    assert y["max_raft_rotation_rad"] == pytest.approx(x["max_raft_rotation_rad"], rel=1e-6)
    assert xy["max_raft_rotation_axes_rad"]["x"] == pytest.approx(x["max_raft_rotation_rad"], rel=1e-6)
    assert xy["max_raft_rotation_axes_rad"]["y"] == pytest.approx(x["max_raft_rotation_rad"], rel=1e-6)
    assert x["max_raft_rotation_axes_rad"]["x"] < 1e-10 * x["max_raft_rotation_rad"]


def test_linear_vertical_alone_does_not_rock_and_components_superpose(records):
    """z alone on the symmetric stick: rotation at round-off (< 1e-10 of x's); the linear route
    with x, y and z at once is the sum of the three one-component runs (1e-10)."""
    comps = {"x": "rec.txt", "y": "rec.txt", "z": "rec.txt"}
    res, motion = _run(records, {"kind": "record", "components": comps})
    every = res["linear"]
    alone = {}
    for k, a in enumerate("xyz"):
        single = Motion(motion.dt, np.where(np.arange(3) == k, motion.acc, 0.0), a)
        alone[a] = run_scene(_scene(records, {"kind": "record", "components": comps}), motion=single)[0]["linear"]
    rock = lambda r: np.hypot(r.raft[:, 3], r.raft[:, 4]).max()
    assert rock(alone["z"]) < 1e-10 * rock(alone["x"])
    assert np.abs(alone["z"].raft[:, 2]).max() > 1e-4                  # it moves vertically, without rocking
    total = sum(alone[a].raft for a in "xyz")
    assert np.abs(every.raft - total).max() <= 1e-10 * np.abs(every.raft).max()
    acc = sum(alone[a].acc["top"] for a in "xyz")
    assert np.abs(every.acc["top"] - acc).max() <= 1e-10 * np.abs(every.acc["top"]).max()


@pytest.mark.parametrize("routes, soil", [(["winkler"], {**SOIL, "winkler": {"kv": 5.0e7, "kh": 4.0e7}}),
                                          (["monolithic"], SOIL)])
def test_downward_vertical_pulse_stronger_than_g_lifts_the_whole_raft_without_rocking(records, routes, soil):
    """The ground falling faster than gravity (1.5 g downward) throws the building up: every
    interface node lifts at once (uplift fraction 1, none before the pulse), and the raft does not
    rock (its edges' rocking displacement < 1e-9 of the uplift)."""
    res, _ = _run(records, {"kind": "record", "components": {"z": "pulse.txt"}}, soil=soil,
                  analysis={"routes": routes, "dt": DT})
    r = res[routes[0]]
    assert r.converged, r.message
    frac = r.uplift_fraction()
    assert frac[: int(0.5 / DT)].max() == 0.0 and frac.max() == 1.0
    assert r.max_uplift() > 0.01
    assert 5.0 * np.hypot(r.raft[:, 3], r.raft[:, 4]).max() < 1e-9 * r.max_uplift()
    assert summary(r)["components"] == ["z"]


def test_every_route_takes_three_components(records, tmp_path, capsys):
    """winkler, monolithic, cosim, linear and timefreq on x, y and z at once through `uplift run`:
    all converge and say so; the co-simulation equals the monolithic route (1e-8, measured ~1e-13);
    the TF reference on the BEM table and the monolithic route on its fit agree on the max uplift
    to the fit error (< 5 %); the results file keeps the components."""
    routes = ["winkler", "monolithic", "cosim", "linear", "timefreq"]
    path = tmp_path / "three.toml"
    write_scene(path, changed(SCENE, soil={"winkler": None}, analysis={"routes": routes},
                              impedance={"range_hz": [0.0, 20.0, 11]}, contact={"enabled": True},
                              motion={"kind": "synthetic", "components": ["x", "y", "z"], "pga_g": 0.3,
                                      "duration_s": 3.0, "seed": 2}))
    out = tmp_path / "r.h5"
    assert main(["run", str(path), "-o", str(out), "--json"]) == 0
    summ = json.loads(capsys.readouterr().out)
    assert summ["motion"]["components"] == ["x", "y", "z"]
    assert summ["motion"]["pga_g"]["x"] == pytest.approx(0.3, rel=1e-12)
    for r in routes:
        s = summ["routes"][r]
        assert s["converged"] and s["components"] == ["x", "y", "z"], (r, s["message"])
        axes = s["max_raft_rotation_axes_rad"]
        assert min(axes.values()) > 0.2 * max(axes.values())           # rocking about both axes
    res = read_results(out)
    mono, cosim = res["monolithic"], res["cosim"]
    assert mono.max_uplift() > 0
    assert np.abs(cosim.raft - mono.raft).max() <= 1e-8 * np.abs(mono.raft).max()
    assert np.abs(cosim.gap - mono.gap).max() <= 1e-8 * mono.gap.max()
    assert abs(res["timefreq"].max_uplift() / mono.max_uplift() - 1) < 0.05
    assert read_motion(out)[2].components == ("x", "y", "z")


def test_timefreq_load_takes_three_components_exactly():
    """The TF route's load vector with x, y and z at once: with the trapezoidal map on a
    frequency-independent soil it equals the Newmark route with uplift to the solver tolerance
    (< 1e-8, measured ~1e-10)."""
    from orchestrator.timefreq import GridOptions, solve
    from helpers import COARSE_RAFT, rel
    from helpers import broadband as motion
    MODEL, soil = COARSE_RAFT.model, COARSE_RAFT.soil
    ag = motion(0.3)
    ag[:, 1] = motion(0.3, seed=7)[:, 0]
    ag[:, 2] = motion(0.2, seed=11)[:, 0]
    uplift = ContactSettings(enabled=True)
    td = simulate(MODEL, soil(), ag, 0.005, contact=uplift)
    assert td.max_uplift() > 1e-3 and np.abs(td.raft[:, 3]).max() > 0.3 * np.abs(td.raft[:, 4]).max()
    tf = solve(MODEL, soil(), ag, 0.005, contact=uplift, grid=GridOptions(bilinear=True, wrap_tol=1e-10, pad_s=20.0))
    assert tf.converged, tf.message
    assert rel(tf.gap, td.gap) < 1e-8 and rel(tf.raft[:, :5], td.raft[:, :5]) < 1e-8
    for name in td.acc:
        assert rel(tf.acc[name], td.acc[name]) < 1e-8, name


def test_report_names_the_components_and_rocking_axes(tmp_path, capsys):
    """The report says which components ran and gives both rocking peaks; a refused route is
    listed without figures (it has no histories)."""
    from orchestrator.results_file import write_results
    from structure.results import RouteResult
    from helpers import route_result

    nt = 300
    t = 0.01 * np.arange(nt)
    run = route_result("monolithic")
    raft = np.array(run.raft)
    raft[:, 3] = 2e-4 * np.cos(2 * np.pi * t)
    results = {"monolithic": run.replace(raft=raft).with_notes(info={"components": ["x", "y", "z"]}),
               "cosim": RouteResult.refused("cosim", "refused for the test")}
    motion = Motion(0.01, np.column_stack([np.sin(t), np.cos(t), 0.5 * np.sin(3 * t)]), "triplet")
    path = write_results(tmp_path / "r.h5", results, motion, "tiny")
    assert main(["report", str(path), "-o", str(tmp_path / "rep")]) == 0
    page = (tmp_path / "rep" / "report.html").read_text()
    assert "components x, y, z" in page and "<td>x, y, z</td>" in page
    assert f"<td>{2e-4:.4e}</td>" in page and f"<td>{1e-4:.4e}</td>" in page      # max |rx|, max |ry|
    assert f"<td>{np.hypot(raft[:, 3], raft[:, 4]).max():.4e}</td>" in page
    assert sorted(p.name for p in (tmp_path / "rep").glob("*.png")) == ["monolithic_floor_spectra.png",
                                                                       "monolithic_raft.png"]

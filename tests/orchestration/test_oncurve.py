"""Runs on the static pushover curve (orchestrator/oncurve.py, ``uplift report``'s section): the
overturning moment of a results file's contact forces is the pushover's moment, zero at rest; a
run of tiny motion lies on the curve's initial slope; the report draws the routes on the curve
of the same scene and refuses the pushover of another scene."""
import re

import numpy as np
import pytest

from helpers import tower, write_scene
from helpers.native import seed_native
from orchestrator.cli import main
from orchestrator.oncurve import Curve, oncurve_figure, overturning_moment, route_point, scene_key
from orchestrator.plots import pyplot
from orchestrator.pushover import scene_pushover
from orchestrator.report import results_curves
from orchestrator.results_file import read_results, read_scene_record, write_results
from orchestrator.run import run_scene
from orchestrator.scene import scene_from_dict

#: the tower with enough frequencies for the rational fit (monolithic), a bonded route beside
SCENE = tower(impedance={"range_hz": [0.0, 10.0, 6]}, analysis={"routes": ["winkler", "monolithic", "linear"]})


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """One cache for the module (the sweep and the rational fit made once, the C runtime compiled
    once for the tests copied in), also the commands'."""
    path = seed_native(tmp_path_factory.mktemp("cache"))
    env = pytest.MonkeyPatch()
    env.setenv("UPLIFT_CACHE", str(path))
    yield path
    env.undo()


@pytest.fixture(scope="module")
def quiet(tmp_path_factory, cache):
    """The tower under a 0.001 g motion (nothing lifts), written and read back, and its curves."""
    scene = scene_from_dict(tower(impedance={"range_hz": [0.0, 10.0, 6]}, motion={"pga_g": 0.001},
                                  analysis={"routes": ["winkler", "monolithic"]}), name="tower")
    results, motion = run_scene(scene, cache_dir=cache)
    path = write_results(tmp_path_factory.mktemp("quiet") / "run.h5", results, motion, scene.name)
    curves = {soil: Curve.from_run(scene_pushover(scene, soil=soil, steps=10)) for soil in ("bem", "winkler")}
    return scene, read_results(path), curves


def test_moment_is_the_pushovers_and_zero_at_rest(quiet):
    """overturning_moment applied to the pushover's own contact forces gives its moment (the
    reaction of the prescribed rotation) to round-off; on the results file's total contact forces
    at t = 0 (the static state of the symmetric tower) it is zero, as the curve's at theta = 0."""
    scene, results, curves = quiet
    for soil in ("bem", "winkler"):
        run = scene_pushover(scene, soil=soil, steps=10)
        M = overturning_moment(run.curve.force, run.xy, run.load) @ np.array([0.0, 1.0])   # direction x: a = ry
        scale = run.curve.vertical * 5.0                                                # N x half the raft
        assert np.abs(M - run.curve.moment).max() < 1e-9 * scale
        assert abs(run.curve.moment[0]) < 1e-9 * scale
    for route, res in results.items():
        assert res.info["scene_key"] == scene_key(scene)
        M0 = np.hypot(*overturning_moment(res.contact_force[:1], scene.mesh.xy, curves["bem"].load)[0])
        assert 1e-9 * curves["bem"].vertical * 5.0 > M0, route          # measured ~1e-5 N m on 1.5e8 N m
        assert res.contact_force[0].sum() == pytest.approx(curves["bem"].vertical, rel=1e-9)


def test_tiny_motion_lies_on_the_initial_slope(quiet):
    """Nothing lifts at 0.001 g: the largest |M| over the largest rotation is the full-contact
    rocking stiffness. The winkler route on its own springs: within 5e-4 (measured 1.0e-4, the
    penalty in series: kp = 1e4 x the soil's); the monolithic route on the fitted BEM soil:
    within 5 % (measured 2.7 % below: the dynamic rocking stiffness at the tower's
    soil-structure frequency, a0 ~ 0.2, and the soil's damping shifting the two maxima in time)."""
    _, results, curves = quiet
    for route, soil, tol in (("winkler", "winkler", 5e-4), ("monolithic", "bem", 0.05)):
        p = route_point(results[route], curves[soil])
        assert p["min_contact_ratio"] == 1.0 and p["max_moment_Nm"] < 0.1 * curves[soil].onset_moment
        ratio = p["max_moment_Nm"] / p["max_rotation_rad"] / curves[soil].stiffness
        assert abs(ratio - 1) < tol, (route, ratio)
        assert p["moment_over_static"] == pytest.approx(ratio, rel=1e-3)     # the curve is straight there


@pytest.fixture(scope="module")
def strong(tmp_path_factory, cache):
    """`uplift run` of the tower at 0.3 g (winkler, monolithic, linear), and a pushover file of it."""
    tmp = tmp_path_factory.mktemp("strong")
    scene = write_scene(tmp / "tower.toml", SCENE)
    assert main(["run", scene, "-o", str(tmp / "run.h5")]) == 0
    assert main(["pushover", scene, "-o", str(tmp / "pu.h5"), "--soil", "winkler"]) == 0
    return tmp, scene


def test_report_draws_the_routes_on_the_curve(strong, capsys):
    tmp, scene = strong
    out = tmp / "rep"
    assert main(["report", str(tmp / "run.h5"), "-o", str(out), "--pushover", scene]) == 0
    page = (out / "report.html").read_text()
    assert "On the static pushover curve" in page and (out / "on_the_curve.png").is_file()
    assert "alt='on_the_curve'" in page and "static preload included" in page
    rows = {r[0]: r for r in re.findall(r"<tr><td>(\w+)</td><td>(bem|winkler)</td>((?:<td>[^<]*</td>)+)</tr>", page)}
    assert rows["winkler"][1] == "winkler" and rows["monolithic"][1] == "bem" and rows["linear"][1] == "bem"
    assert "no uplift (bonded)" in rows["linear"][2] and "no uplift" not in rows["monolithic"][2]
    # the winkler curve read from the pushover file: the one computed from the scene
    results = read_results(tmp / "run.h5")
    what = f"results file {tmp / 'run.h5'}"
    read, _ = results_curves(results, "tower", None, [str(tmp / "pu.h5")], what)
    made, _ = results_curves(results, "tower", None, [scene], what)
    assert set(read) == {"winkler"} and set(made) == {"bem", "winkler"}
    assert read["winkler"].source == str(tmp / "pu.h5") and made["winkler"].source.startswith("computed")
    for name in ("rotation", "moment", "contact_ratio", "load", "xy", "area"):
        np.testing.assert_allclose(getattr(read["winkler"], name), getattr(made["winkler"], name), rtol=1e-12)


def test_pushover_of_another_scene_is_refused(strong, capsys):
    tmp, _ = strong
    other = write_scene(tmp / "wider.toml", tower(impedance={"range_hz": [0.0, 10.0, 6]}, foundation={"lx": 12.0}))
    assert main(["pushover", other, "-o", str(tmp / "wider.h5")]) == 0
    capsys.readouterr()
    for given in (str(tmp / "wider.h5"), other):
        assert main(["report", str(tmp / "run.h5"), "-o", str(tmp / "rep3"), "--pushover", given]) == 2
        err = capsys.readouterr().err
        assert "not of the scene of results file" in err or "not the scene of results file" in err
        assert "mesh, soil, structure or springs differ" in err
    assert not (tmp / "rep3" / "report.html").exists()


def test_figure_has_units_and_marks_the_bonded_route(strong):
    tmp, scene = strong
    results = read_results(tmp / "run.h5")
    sc = scene_from_dict(SCENE, name="tower")
    curves = {soil: Curve.from_run(scene_pushover(sc, soil=soil, steps=10)) for soil in ("bem", "winkler")}
    points = [route_point(res, curves["winkler" if r == "winkler" else "bem"], uplift=r != "linear")
              for r, res in results.items()]
    fig = oncurve_figure(curves, points, "tower")
    try:
        for ax in fig.axes:
            for label in (ax.get_xlabel(), ax.get_ylabel()):
                assert re.search(r"\((mrad|MN m|% of the raft area)\)$", label), label
        lines = {ln.get_label(): ln for ln in fig.axes[0].lines}
        assert lines["linear (bem): no uplift (bonded)"].get_markerfacecolor() == "none"
        markers = {ln.get_marker() for name, ln in lines.items() if name.split()[0] in results}
        assert len(markers) == len(results)                               # told apart by more than colour
    finally:
        pyplot().close(fig)


def test_report_without_pushover_uses_the_scene_the_file_stores(strong):
    """A results file stores the scene as it ran (``scene_toml``): without --pushover, the report
    pushes that scene over (the tower is no built-in scene), the curve equal to the one of the
    scene's own TOML file."""
    tmp, scene = strong
    out = tmp / "rep_stored"
    assert main(["report", str(tmp / "run.h5"), "-o", str(out)]) == 0
    page = (out / "report.html").read_text()
    assert (out / "on_the_curve.png").is_file() and "Not drawn" not in page
    results = read_results(tmp / "run.h5")
    what = f"results file {tmp / 'run.h5'}"
    stored, _ = results_curves(results, "tower", None, [], what, read_scene_record(tmp / "run.h5")["scene_toml"])
    given, _ = results_curves(results, "tower", None, [scene], what)
    for soil in ("winkler", "bem"):
        np.testing.assert_array_equal(stored[soil].moment, given[soil].moment)

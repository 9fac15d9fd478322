"""``uplift pushover`` (orchestrator/pushover.py): the rigid disk on the BEM half-space lifts
off near e = R/3 (the rigid circular punch), the exact contact agrees with the stepper's penalty
preload, the file is checksummed and read back, and the command's inputs are checked."""
import json

import numpy as np
import pytest

from helpers import tower, write_scene
from orchestrator.cli import main
from orchestrator.pushover import read_pushover, scene_pushover
from orchestrator.routes.winkler import static_springs, winkler_soil
from orchestrator.scene import scene_from_dict
from orchestrator.impedance import scene_impedance, scene_static
from structure.contact import penalty_stiffness
from structure.preload import solve_static
from structure.model import vertical_trace

DISK = {"soil": {"layers": [], "halfspace": {"vs": 500.0, "nu": 1 / 3, "rho": 2000.0}},
        "foundation": {"shape": "circle", "radius": 10.0, "element_size": 1.25}}


@pytest.mark.parametrize("h, measured", [(1.25, 0.041), (0.8, 0.011)])
def test_rigid_disk_on_the_halfspace_lifts_off_near_r_over_3(h, measured):
    """Rigid punch: p = (N/(2 pi R^2) + 3 M x/(2 pi R^4)) / sqrt(1 - r^2/R^2), zero at the edge
    when e = R/3. The BEM's piecewise-constant tractions on the staircase disk converge as O(h),
    irregularly in h: |3 e/R - 1| <= 0.5 h/R (measured 0.043, 0.008, 0.041, 0.021, 0.011 at
    h = 2.5, 1.5, 1.25, 1.0, 0.8 m on R = 10 m); the two meshes here pin the measured values."""
    scene = scene_from_dict({**DISK, "foundation": {**DISK["foundation"], "element_size": h}}, name="disk")
    run = scene_pushover(scene, soil="bem", steps=4, vertical_load=1.0e7)
    err = abs(3 * run.curve.onset.eccentricity / 10.0 - 1)
    assert err <= 0.5 * h / 10.0
    assert err == pytest.approx(measured, abs=0.001)
    assert run.curve.contact_ratio[0] == 1.0 and run.curve.contact_ratio[-1] < 0.6


def test_exact_contact_matches_the_penalty_preload():
    """At zero rotation the exact contact gives the settlement of the stepper's static preload
    (penalty kp = 1e4 x the local soil stiffness, in series with it): within 2e-4 (measured 1e-4),
    on the tower's Winkler springs with the weight of its structure brought to the raft."""
    scene = scene_from_dict(tower(), name="tower")
    run = scene_pushover(scene, soil="winkler", steps=2)
    model = scene.model()
    soil, _ = static_springs(scene)
    pre = solve_static(model, soil, penalty_stiffness(scene.contact, soil.static_stiffness(), model.n_interface))
    assert run.weight_N == pytest.approx(-model.gravity_load().sum(), rel=1e-12) == 3.0e6 * 9.81
    assert run.curve.settlement[0] == pytest.approx(pre.settlement, rel=2e-4)
    assert run.curve.force[0] == pytest.approx(pre.P0, rel=2e-4)


def test_static_springs_are_the_routes():
    """static_springs calibrates the springs as the winkler route does (BEM rigid K(0) shared by
    area, rocking matched), to round-off."""
    scene = scene_from_dict(tower(soil={"winkler": {"springs": "rigid"}}, impedance={"range_hz": [0.0, 5.0, 2]}),
                            name="tower")
    table = scene_impedance(scene, ("rigid",))["rigid"]
    route, _, _ = winkler_soil(scene, scene.model(), table)
    springs, label = static_springs(scene)
    assert np.allclose(springs.kv, route.kv, rtol=1e-12) and "rocking matched" in label


def test_command_writes_a_checksummed_file_and_a_figure(tmp_path, capsys):
    scene = tmp_path / "tower.toml"
    write_scene(scene, tower())
    out, fig = tmp_path / "p.h5", tmp_path / "p.png"
    assert main(["pushover", str(scene), "-o", str(out), "--soil", "winkler", "--direction", "y", "--steps", "10",
                 "--plot", str(fig), "--json", "--no-cache"]) == 0
    summ = json.loads(capsys.readouterr().out)
    data = read_pushover(out)
    on = summ["onset"]
    assert data["attrs"]["onset_moment_Nm"] == on["moment_Nm"] and data["attrs"]["direction_deg"] == 90.0
    assert data["rotation"].size == len(summ["steps"]["rotation_rad"]) == 12          # 11 points + the onset
    assert data["force"].shape == (12, 16) and data["pressure"][0] == pytest.approx(data["force"][0] / 6.25)
    # rocking about x: the edge y = -3.75 m lifts first; e on a 4 x 4 grid is (B + h)/6
    assert data["y"][on["node"]] == -3.75 and on["eccentricity_m"] == pytest.approx(12.5 / 6, rel=1e-10)
    assert json.loads(data["attrs"]["provenance"])["winkler"]["moduli"][0] == 5.0e7
    assert fig.stat().st_size > 10_000
    assert main(["pushover", str(scene), "-o", str(out), "--soil", "winkler", "--steps", "3", "--no-cache"]) == 0
    text = capsys.readouterr().out
    assert "lift-off onset" in text and "eccentricity e = M/N = 2.08333 m" in text


@pytest.mark.parametrize("args, message", [
    (["--direction", "north"], "--direction 'north'"),
    (["--vertical-load=-1e9"], "is not downward"),
])
def test_command_refuses_bad_inputs(tmp_path, capsys, args, message):
    scene = tmp_path / "tower.toml"
    write_scene(scene, tower())
    assert main(["pushover", str(scene), "-o", str(tmp_path / "p.h5"), "--soil", "winkler", *args]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "p.h5").exists()


def test_a_scene_without_structure_needs_a_vertical_load(tmp_path, capsys):
    scene = tmp_path / "disk.toml"
    write_scene(scene, {**DISK, "foundation": {**DISK["foundation"], "element_size": 5.0}})
    assert main(["pushover", str(scene), "-o", str(tmp_path / "p.h5"), "--no-cache"]) == 2
    assert "--vertical-load" in capsys.readouterr().err


@pytest.mark.parametrize("soil", ["bem", "winkler"])
def test_slope_before_liftoff_is_the_static_rocking_stiffness(soil):
    """Before lift-off the raft is bonded: M / theta is the static rocking stiffness of the same
    soil with the other five rigid-raft DOFs free, 1 / (K_rigid^-1)_yy about y, where K_rigid is
    the rigid 6 x 6 static table (BEM; scaled as the pushover scales it) or the springs' rigid
    stiffness (Winkler: sum k_i T_i^T T_i): to 1e-6."""
    scene = scene_from_dict(tower(soil={"winkler": {"springs": "rigid"}}, impedance={"range_hz": [0.0, 5.0, 2]}),
                            name="tower")
    run = scene_pushover(scene, soil=soil, steps=40)        # 20 x the onset rotation: two steps before it
    c = run.curve
    bonded = (c.rotation > 0) & (c.rotation <= c.onset.rotation * (1 + 1e-12))
    assert bonded.sum() >= 2
    if soil == "bem":
        K6 = run.stiffness_factor * np.real(scene_static(scene, "rigid"))
    else:
        springs, _ = static_springs(scene)
        K = springs.static_stiffness().toarray()             # (6 + N): raft DOFs, then the soil under each node
        n = scene.mesh.n
        T = np.vstack([np.eye(6), vertical_trace(scene.mesh.xy)])         # w = B q: bonded
        K6 = T.T @ K @ T
        assert K.shape == (6 + n, 6 + n)
    k_rocking = 1.0 / np.linalg.inv(K6)[4, 4]                  # about y: --direction x
    np.testing.assert_allclose(c.moment[bonded] / c.rotation[bonded], k_rocking, rtol=1e-6)
    assert c.onset.stiffness == pytest.approx(k_rocking, rel=1e-6)

"""A plate raft's results through the scene, the monolithic route, the results file and the report:
contact pressures and the maps at peak uplift, the bending moments, the raft points' floor spectra
([output] raft_points), the plate's damping key; the refusals of what cannot carry them."""
import copy

import h5py
import numpy as np
import pytest

from helpers import pulse_motion, soil_model, write_scene
from helpers.plates import PLATE_SCENE as SCENE
from orchestrator.cli import main
from orchestrator.oncurve import scene_key
from orchestrator.report import write_report
from orchestrator.results_file import read_results, write_results
from orchestrator.routes.monolithic import run_monolithic
from orchestrator.scene import SceneError, scene_from_dict
from orchestrator.scene_file import scene_toml
from structure.model import G_ACC

POINTS = {"edge": [18.0, 0.0], "mid": [-10.0, 5.0]}


def plate_scene(raft=None, routes=("monolithic",), **output):
    data = copy.deepcopy(SCENE)
    data["foundation"]["raft"].update(raft or {})
    data["analysis"]["routes"] = list(routes)
    data["output"].update(output)
    return data


def test_pressures_moments_maps_and_raft_point_spectra_are_written_and_drawn(tmp_path):
    sc = scene_from_dict(plate_scene(raft={"damping": {"ratio": 0.05}}, raft_points=POINTS), name="plate")
    assert sc.raft.damping == 0.05 and sc.raft.damping_hz == 10.0             # the default frequency
    assert sc.output.raft_points == {"edge": (18.0, 0.0), "mid": (-10.0, 5.0)}
    pm = sc.plate_model()
    motion = pulse_motion(0.005, 1.0)
    res = run_monolithic(sc, motion, soil_model(sc))
    assert res.converged and res.max_uplift() > 1e-3 and res.info["stepper"] == "native"
    assert res.info["raft"]["damping_ratio"] == 0.05 and set(res.info["raft_points"]) == set(POINTS)
    assert {"edge", "mid", "top_outer"} <= set(res.acc)
    res = res.replace(info={**res.info, "scene_key": scene_key(sc)})          # as `uplift run` keeps it
    path = write_results(tmp_path / "r.h5", {"monolithic": res}, motion=motion, scene_name="plate",
                         scene_toml=scene_toml(sc), mesh=sc.mesh)
    with h5py.File(path) as f:
        g = f["routes/monolithic"]
        p = g["contact_pressure"][()]
        assert g["contact_pressure"].attrs["units"] == "Pa" and p.shape == res.gap.shape
        # at rest the pressures carry the weight of sticks and plate (independent: the masses)
        assert abs(p[0] @ sc.mesh.area / (G_ACC * pm.total_mass) - 1) < 1e-10     # measured 2.3e-12
        assert np.allclose(p * sc.mesh.area, res.contact_force, rtol=1e-14, atol=0)
        k = int(np.argmax(res.gap.max(axis=1)))
        assert g["uplift_map"].attrs["time_s"] == g.attrs["max_uplift_time_s"] == res.time[k]
        assert g["uplift_map"][()].max() == g.attrs["max_uplift_m"]
        assert np.array_equal(g["contact_pressure_map"][()], p[k])
        assert np.all(g["contact_pressure_map"][()][g["uplift_map"][()] > 0] == 0)    # no pressure where lifted
        assert g["plate_moment"].attrs["units"] == "N m m-1"
        assert g["plate_moment"].shape == (motion.acc.shape[0], pm.base_cells.size, 3)
        assert np.array_equal(g["base_cell"][()], pm.base_cells)
        assert [m.decode() for m in g["moment"][()]] == ["Mx", "My", "Mxy"]
        assert np.array_equal(g["plate_vertex_held"][()].astype(bool), pm.slaved)
        outputs = [o.decode() for o in g["output"][()]]
        assert "edge" in outputs and np.isfinite(g["floor_spectrum_peak"][outputs.index("edge"), 2])
    back = read_results(path)["monolithic"]
    for name in ("plate_moment", "plate_moment_peak", "plate_moment_cells", "plate_vertex_held"):
        assert np.array_equal(getattr(back, name), getattr(res, name)), name
    assert np.array_equal(back.acc["edge"], res.acc["edge"])
    report = tmp_path / "report"
    html = write_report(path, report).read_text()
    assert (report / "monolithic_plate_maps.png").is_file() and "The plate raft" in html
    assert "held region" in html


@pytest.mark.parametrize("data, message", [
    (plate_scene(raft_points={"e": [18.0, 0.0]}, routes=("monolithic", "cosim")),
     "output.raft_points is computed by the route monolithic only; route cosim"),
    (plate_scene(raft={"damping": {"ratio": 0.02}}, routes=("monolithic", "timefreq")),
     "foundation.raft.damping: the route timefreq condenses the plate without its own damping"),
    (plate_scene(raft={"damping": {"ratio": 1.5}}), "foundation.raft.damping.ratio = 1.5"),
    (plate_scene(raft={"damping": 0.02}), "foundation.raft.damping = 0.02 must be a table"),
    (plate_scene(raft={"damping": {"ratio": 0.02, "hz": 5}}), "hz"),
    (plate_scene(raft_points={"e": [18.0]}), "output.raft_points.e"),
    (plate_scene(raft_points={"raft": [1.0, 0.0]}), "'raft' is the name of a structure node"),
])
def test_bad_plate_result_keys_are_refused_with_the_key(data, message):
    with pytest.raises(SceneError, match=message):
        scene_from_dict(data, name="plate")


def test_raft_points_of_a_rigid_raft_are_refused_in_one_line(tmp_path, capsys):
    data = plate_scene(raft_points={"e": [18.0, 0.0]})
    data["foundation"]["raft"] = {"kind": "rigid"}
    with pytest.raises(SceneError, match="output.raft_points: the points of a plate raft; this scene's raft is rigid"):
        scene_from_dict(data)
    assert main(["run", write_scene(tmp_path, data), "-o", str(tmp_path / "out.h5")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "output.raft_points" in err[0], err

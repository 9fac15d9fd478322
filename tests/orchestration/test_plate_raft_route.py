"""A plate raft (``[foundation] raft = { kind = "plate", ... }``) through the scene, the monolithic
route (the Python stepper; the native one: tests/fmu/test_native_plate.py) and the results file; the scene's refusals of what cannot carry it."""
import copy
import dataclasses

import h5py
import numpy as np
import pytest

from helpers import pulse_motion, soil_model, write_scene
from helpers.plates import PLATE, PLATE_SCENE
from helpers.winkler import R
from fmus.resources import DEFAULT_SOIL_FACTORY, soil_from_model
from orchestrator.cli import main
from orchestrator.pushover import scene_pushover
from orchestrator.oncurve import scene_key
from orchestrator.report import write_report
from orchestrator.results_file import read_results, write_results
from orchestrator.routes.monolithic import run_monolithic
from orchestrator.scene import SceneError, load_scene, scene_from_dict
from orchestrator.scene_file import scene_toml
from structure import simulate
from structure.model import vertical_trace
from structure.plate_raft import PlateProperties, PlateRaftModel

SCENE = PLATE_SCENE


def scene(**foundation):
    data = copy.deepcopy(SCENE)
    data["foundation"].update(foundation)
    for k in [k for k, v in data["foundation"].items() if v is None]:
        del data["foundation"][k]
    return data


def test_a_plate_raft_runs_on_the_monolithic_route_and_its_deflections_are_written(tmp_path):
    sc = scene_from_dict(scene(), name="plate")
    assert sc.raft.rigid_radius == 0.5 * R                            # the default: half the raft's radius
    pm = sc.plate_model()
    assert isinstance(pm, PlateRaftModel) and pm.stick.raft.m == 0.0   # the plate is the raft's mass
    model, motion = soil_model(sc), pulse_motion(0.005, 1.2)
    res = run_monolithic(sc, motion, model, stepper="python")
    assert res.converged and res.info["stepper"] == "python" and not res.notes.warnings
    assert res.max_uplift() > 1e-3
    raft = res.info["raft"]
    assert raft["kind"] == "plate" and raft["free_vertices"] == pm.nf and raft["dropped_mass_coupling_m"] < 1e-12
    assert np.isclose(raft["plate_mass_kg"], 2500.0 * 2.0 * sc.mesh.area.sum(), rtol=1e-12)
    # the route is structure.simulate on the scene's plate model and the same soil, exactly
    ref = simulate(pm, soil_from_model(model, 0.005, DEFAULT_SOIL_FACTORY), motion.acc, 0.005,
                   contact=sc.contact, output_nodes=sc.output.nodes)
    assert np.array_equal(res.plate_vertex_deflection, ref.plate_vertex_deflection)
    assert np.array_equal(res.gap, ref.gap)
    # the trace at the nodes is the cell average of the vertices (1/4 on the grid's squares)
    assert np.allclose(res.plate_deflection, res.plate_vertex_deflection @ pm.trace.T.toarray(), rtol=0, atol=1e-15)
    path = write_results(tmp_path / "r.h5", {"monolithic": res}, motion=motion, scene_name="plate", mesh=sc.mesh)
    back = read_results(path)["monolithic"]
    assert np.array_equal(back.plate_deflection, res.plate_deflection)
    assert np.array_equal(back.plate_vertex_deflection, res.plate_vertex_deflection)
    assert np.array_equal(back.plate_vertices, pm.points)
    with h5py.File(path) as f:
        g = f["routes/monolithic"]
        assert g["plate_deflection"].attrs["units"] == "m" and g["plate_vertex_deflection"].attrs["units"] == "m"
        assert g["plate_vertex_deflection"].shape == (motion.acc.shape[0], pm.n_vertices)
        assert g["gap"].shape == (motion.acc.shape[0], sc.mesh.n)            # the uplift per node, as before
    # the report draws the run (the uplift map on the cells) and says why it has no pushover curve
    keyed = dataclasses.replace(res, info={**res.info, "scene_key": scene_key(sc)})      # as `uplift run` keeps it
    path = write_results(tmp_path / "s.h5", {"monolithic": keyed}, motion=motion, scene_name="plate",
                         scene_toml=scene_toml(sc), mesh=sc.mesh)
    html = write_report(path, tmp_path / "report").read_text()
    assert "has a plate raft: the static pushover models a rigid raft only" in html
    assert (tmp_path / "report" / "raft_uplift.png").is_file()


@pytest.mark.parametrize("change, message", [
    (dict(raft={**PLATE, "thickness": -1.0}), "foundation.raft.thickness = -1"),
    (dict(raft={**PLATE, "nu": 0.7}), "foundation.raft.nu"),
    (dict(raft={k: v for k, v in PLATE.items() if k != "E"}), "E"),
    (dict(raft={**PLATE, "rigid_radius": 0.5}), "rigid_radius = 0.5 m holds"),
    (dict(raft={"kind": "rigid", "thickness": 1.0}), "thickness"),
    (dict(raft={**PLATE, "kind": "shell"}), "foundation.raft.kind"),
    (dict(raft=3.0), "foundation.raft = 3"),
])
def test_bad_plate_keys_are_refused_with_the_key(change, message):
    with pytest.raises(SceneError, match=message):
        sc = scene_from_dict(scene(**change), name="plate")
        sc.plate_model()


def test_routes_and_foundations_that_cannot_carry_a_plate_are_refused(tmp_path, capsys):
    data = scene()
    data["analysis"]["routes"] = ["monolithic", "winkler", "cosim"]
    with pytest.raises(SceneError, match="route winkler cannot carry a plate yet"):
        scene_from_dict(data)
    data["analysis"]["routes"] = ["monolithic", "cosim", "linear", "timefreq"]     # these carry a plate
    assert scene_from_dict(data).raft is not None
    (tmp_path / "n.csv").write_text("x,y,area\n-2,-2,4\n2,-2,4\n2,2,4\n-2,2,4\n")
    with pytest.raises(SceneError, match="needs the interface's cells"):
        scene_from_dict(scene(shape="nodes", radius=None, element_size=None, file="n.csv"), base_dir=tmp_path)
    assert scene_from_dict(scene(raft={"kind": "rigid"})).raft is None
    plate = scene_from_dict(scene(), name="plate")
    with pytest.raises(SceneError, match="the static pushover models a rigid raft only"):
        scene_pushover(plate)
    # the command line: exit 2, one line naming the key
    data["analysis"]["routes"] = ["monolithic", "linear", "winkler"]
    assert main(["run", write_scene(tmp_path, data), "-o", str(tmp_path / "out.h5")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "foundation.raft.kind" in err[0], err


def test_a_plate_on_a_mesh_file_s_cells_off_centre_held_region_is_said():
    """The built-in l_raft scene (a gmsh L: triangles and quadrilaterals) as a plate: the plate on
    the file's cells, its trace exact for rigid motions; the held region is off the raft centre, so
    the route says what the lumped mass leaves out."""
    sc = load_scene("l_raft").with_routes(["monolithic"])
    plate = dataclasses.replace(sc, raft=PlateProperties(1.0, 30e9, 0.2, 2500.0, 0.5 * sc.mesh.radius))
    pm = plate.plate_model()
    q = np.array([0.0, 0.0, 1e-3, 2e-4, -3e-4, 0.0])
    assert np.abs(pm.trace @ (vertical_trace(pm.points) @ q) - vertical_trace(sc.mesh.xy) @ q).max() < 1e-15
    assert pm.mass_coupling > 0.1
    res = run_monolithic(plate, pulse_motion(0.005, 0.4), soil_model(sc))
    assert res.converged and res.plate_vertex_deflection.shape[1] == pm.n_vertices
    assert any("mass centre" in w and "left out" in w for w in res.notes.warnings), res.notes.warnings


def test_the_run_notes_say_the_soil_reduction_of_a_plate():
    """The gap table's reduction (3N to 6 + N) holds for a plate too (rigid in its plane, the N
    vertical DOFs under it); the run's notes do not call the raft rigid."""
    import types

    from orchestrator.routes.base import get_route
    from orchestrator.run import _shared_skips
    run = types.SimpleNamespace(sweep={}, fit=None)
    plate, rigid = scene_from_dict(scene(), name="plate"), scene_from_dict(scene(raft=None), name="rigid")
    n = plate.mesh.n
    said = f"soil interface reduced from 3N = {3 * n} to 6 + N = {6 + n} DOFs"
    assert f"plate raft, rigid in its plane: {said}" in _shared_skips(plate, get_route("monolithic"), run)
    assert f"rigid raft: {said}" in _shared_skips(rigid, get_route("monolithic"), run)

"""A raft read from a finite-element mesh file, end to end: the scene keys, the provenance in
the results file and every cache key (a changed file of the same name is not reused), the
built-in scene ``l_raft`` (a gmsh L-shaped raft, 44 cells) through every route, the native
pair and coupled FMU on its interface nodes, the report's uplift map.

Route comparisons (they hold whatever the BEM integrates on the cells, since both sides read the
same table): cosim and the native coupled FMU equal the monolithic route to round-off; timefreq
(the BEM table) within 0.5 % of monolithic (its rational fit) on max uplift (measured +0.09 %
at the scene's 0.4 g, max uplift 10.4 mm; -0.19 % at 0.2 g, +1.6 % at 0.3 g, the latter from
the table's 25 Hz band: +0.15 % with the table to 100 Hz (constant tractions), see docs/raft.md).
"""
import hashlib
import json
import shutil

import meshio
import numpy as np
import pytest

from helpers import DATA, rel, route_result, tower, write_scene
from helpers.native import seed_native
from orchestrator.cli import main
from orchestrator.impedance import scene_impedance
from orchestrator.oncurve import scene_key
from orchestrator.plots import uplift_map_figures
from orchestrator.results_file import read_interface, read_results, read_scene_record
from orchestrator.scene import SceneError, load_scene
from soil_impedance.sweep import table_key

L_RAFT = DATA / "meshes" / "l_raft.msh"
MESH_FOUNDATION = {"shape": None, "lx": None, "ly": None, "element_size": None, "mesh": "raft.msh"}


def _scene(tmp_path, **foundation):
    return write_scene(tmp_path / "scene.toml", tower(foundation={**MESH_FOUNDATION, **foundation},
                                                      impedance={"frequencies_hz": [0.0, 4.0]}))


def test_shape_mesh_is_implied_or_explicit_and_not_mixed(tmp_path):
    shutil.copy(L_RAFT, tmp_path / "raft.msh")
    implied = load_scene(_scene(tmp_path))
    explicit = load_scene(_scene(tmp_path, shape="mesh"))
    assert implied.mesh.kind == explicit.mesh.kind == "cells" and implied.mesh.n == 44
    assert np.array_equal(implied.mesh.cells, explicit.mesh.cells)
    assert implied.mesh_source.sha256 == hashlib.sha256(L_RAFT.read_bytes()).hexdigest()
    with pytest.raises(SceneError, match='foundation.mesh is the file of a finite-element raft: it goes with shape = '
                                         '"mesh" .*not shape = \'circle\''):
        load_scene(_scene(tmp_path, shape="circle", radius=10.0, element_size=2.0))
    with pytest.raises(SceneError, match="unknown key foundation.element_size"):
        load_scene(_scene(tmp_path, element_size=2.0))
    with pytest.raises(SceneError, match="foundation.mesh_group = 3 must be the name of a group"):
        load_scene(_scene(tmp_path, mesh_group=3))


def test_a_changed_mesh_file_of_the_same_name_is_not_reused(tmp_path):
    """The file's content reaches the run's scene key and the sweep's key: the same file read
    twice hits the cache, the file rewritten under the same name (the raft 10 % larger) misses it."""
    shutil.copy(L_RAFT, tmp_path / "raft.msh")
    path, cache = _scene(tmp_path), tmp_path / "cache"
    first = load_scene(path)
    stats = {}
    scene_impedance(first, cache_dir=cache, stats=stats)
    assert stats == {"computed": 2, "from_cache": False}
    again = load_scene(path)
    scene_impedance(again, cache_dir=cache, stats=stats)
    assert stats["from_cache"] and scene_key(again) == scene_key(first)
    m = meshio.read(L_RAFT)
    meshio.write(tmp_path / "raft.msh", meshio.Mesh(1.1 * m.points, m.cells, cell_data={
        k: m.cell_data[k] for k in ("gmsh:physical", "gmsh:geometrical")}), file_format="gmsh22")
    changed = load_scene(path)
    assert changed.mesh.total_area == pytest.approx(1.21 * 675.0)
    assert scene_key(changed) != scene_key(first)
    keys = [table_key(s.profile, s.mesh, s.frequencies_hz, s.contact_kind, "gap") for s in (first, changed)]
    assert keys[0] != keys[1]
    scene_impedance(changed, cache_dir=cache, stats=stats)
    assert stats == {"computed": 2, "from_cache": False}


def test_an_ensemble_cell_key_follows_the_mesh_content_not_its_path(tmp_path):
    """The same mesh in two folders: one cell key (the folder is not an input); the file
    changed: another."""
    from orchestrator.ensemble.plan import cell_key
    keys = []
    for folder in ("a", "b"):
        (tmp_path / folder).mkdir()
        shutil.copy(L_RAFT, tmp_path / folder / "raft.msh")
        keys.append(cell_key(load_scene(_scene(tmp_path / folder)), "winkler", 0.3))
    m = meshio.read(L_RAFT)
    meshio.write(tmp_path / "b" / "raft.msh", meshio.Mesh(m.points * [1.0, 1.05, 1.0], m.cells, cell_data={
        k: m.cell_data[k] for k in ("gmsh:physical", "gmsh:geometrical")}), file_format="gmsh22")
    keys.append(cell_key(load_scene(_scene(tmp_path / "b")), "winkler", 0.3))
    assert keys[0] == keys[1] != keys[2]


def test_the_results_file_keeps_the_mesh_and_where_it_came_from(tmp_path, capsys):
    """winkler with explicit moduli: no BEM, a second. The interface polygons are the cells, the
    file's SHA-256 and the centre are there, the scene as it ran names the mesh by absolute path
    and loads back into the same interface."""
    shutil.copy(L_RAFT, tmp_path / "raft.msh")
    path, out = _scene(tmp_path, centre=[12.0, 12.0]), tmp_path / "r.h5"
    assert main(["run", path, "-o", str(out)]) == 0
    scene = load_scene(path)
    got = read_interface(out)
    assert got["kind"] == "cells" and np.array_equal(got["polygon"], scene.mesh.cells)
    assert np.array_equal(got["area"], scene.mesh.area) and np.array_equal(got["xy"], scene.mesh.xy)
    src = got["mesh_source"]
    assert src["sha256"] == hashlib.sha256(L_RAFT.read_bytes()).hexdigest() and src["centre"] == [12.0, 12.0]
    assert src["path"] == str((tmp_path / "raft.msh").resolve()) and src["group"] is None
    toml = read_scene_record(out)["scene_toml"]
    assert f'mesh = "{(tmp_path / "raft.msh").resolve()}"' in toml
    back = tmp_path / "back.toml"
    back.write_text(toml)
    assert np.array_equal(load_scene(back).mesh.cells, scene.mesh.cells)
    assert np.array_equal(read_results(out)["winkler"].xy, scene.mesh.xy)


def test_uplift_map_colours_each_patch_by_its_gap_at_the_peak():
    """The figure's patches carry the gap (mm) of each node at the instant of the route's peak
    uplift (those in contact masked: grey); one colour scale over the routes from 0 to the
    largest; the centre marked at (0, 0)."""
    a, b = route_result("winkler"), route_result("monolithic", gap_scale=2.0)
    h = 0.5 * np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]])
    polygons = a.xy[:, None, :] + h[None]
    (name, fig), = uplift_map_figures({"winkler": a, "monolithic": b}, polygons, "toy")
    assert name == "raft_uplift"
    axes = [ax for ax in fig.axes if ax.lines]                 # the panels (not the colour bar)
    assert len(axes) == 2
    for ax, res in zip(axes, (a, b)):
        coll = ax.collections[0]
        k = int(np.argmax(res.gap.max(axis=1)))
        shown = coll.get_array()
        assert np.allclose(np.ma.filled(shown, 0.0), 1e3 * res.gap[k])
        assert np.array_equal(np.ma.getmaskarray(shown), res.gap[k] <= 0)          # in contact: grey
        assert coll.get_clim() == pytest.approx((0.0, 1e3 * b.gap.max()))
        assert np.allclose(ax.lines[0].get_xydata(), [[0.0, 0.0]])
    import matplotlib.pyplot as plt
    plt.close(fig)


@pytest.mark.slow
def test_the_l_raft_through_every_route_the_fmus_and_the_report(tmp_path, capsys, monkeypatch):
    """The built-in l_raft (44 cells, 26 frequencies, 1.5 s at 0.4 g): about a minute on 2
    cores, most of it the Python FMUs' build of the cosim route and the BEM sweep."""
    from orchestrator.export import export_scene
    from orchestrator.master import FmuSlave, cosimulate
    from orchestrator.motion import make_motion
    from orchestrator.report import write_report

    cache, out = seed_native(tmp_path / "cache", fmu=True), tmp_path / "r.h5"     # the C runtimes compiled once
    monkeypatch.setenv("UPLIFT_CACHE", str(cache))
    assert main(["run", "l_raft", "-o", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)["routes"]
    res = read_results(out)
    assert set(res) == {"winkler", "monolithic", "cosim", "linear", "timefreq"}
    assert all(r.converged for r in res.values()), {k: r.message for k, r in res.items()}
    mono = res["monolithic"]
    assert mono.gap.shape[1] == 44 and mono.max_uplift() > 5e-3 and res["winkler"].max_uplift() > 1e-3
    assert np.abs(res["cosim"].raft - mono.raft).max() <= 1e-10 * np.abs(mono.raft).max()
    assert abs(res["timefreq"].max_uplift() / mono.max_uplift() - 1) < 0.005, summary["timefreq"]["max_uplift_m"]
    assert res["linear"].max_uplift() == 0.0

    scene = load_scene("l_raft")
    nat = export_scene(scene, tmp_path / "fmus", kind="native", cache_dir=cache)
    pair = cosimulate(nat.structure, nat.soil, make_motion(scene.motion, scene.analysis.dt).acc, scene.analysis.dt,
                      schedule="gauss-seidel")                     # the native pair under the project's master
    assert pair.gap.shape == mono.gap.shape and rel(pair.raft, mono.raft) <= 1e-10 and rel(pair.gap, mono.gap) <= 1e-10
    rows = []
    with FmuSlave(nat.coupled, "coupled") as c:
        assert len(c.vrs("gap")) == 44
        c.initialize()
        rows.append(c.get("x", "max_uplift").copy())
        for k in range(1, mono.nt):
            c.do_step((k - 1) * scene.analysis.dt, scene.analysis.dt)
            rows.append(c.get("x", "max_uplift").copy())
    got = np.array(rows)
    assert rel(got[:, :6], mono.raft) <= 1e-10
    assert got[-1, -1] == pytest.approx(mono.max_uplift(), rel=1e-10)

    page = write_report(out, tmp_path / "report")
    assert (tmp_path / "report" / "raft_uplift.png").stat().st_size > 10_000
    assert "Uplift over the raft" in page.read_text(encoding="utf-8")

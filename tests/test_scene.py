"""Scene loading: built-ins load, and every invalid field gives its own clear message."""
import copy

import numpy as np
import pytest

from orchestrator.scene import SceneError, builtin_scenes, load_scene, scene_from_dict

BASE = {
    "soil": {"layers": [{"thickness": 5.0, "vs": 300.0, "nu": 0.33, "rho": 1900.0, "damping": 0.05}],
             "halfspace": {"vs": 500.0, "nu": 0.3333, "rho": 2000.0, "damping": 0.0}},
    "foundation": {"shape": "circle", "radius": 10.0, "element_size": 2.0, "contact": "welded"},
    "impedance": {"frequencies_hz": [0.01, 2.0, 4.0]},
}


def test_builtin_scenes_load():
    assert {"disk-halfspace", "reactor"} <= set(builtin_scenes())
    disk = load_scene("disk-halfspace")
    assert disk.profile.is_homogeneous and disk.mesh.kind == "circle"
    assert disk.profile.halfspace.vs == 500.0 and disk.profile.halfspace.rho == 2000.0
    assert disk.profile.halfspace.poisson == pytest.approx(1 / 3)
    reactor = load_scene("reactor")
    assert reactor.mesh.n == 241


def test_base_scene_and_range():
    s = scene_from_dict(BASE)
    assert len(s.profile.layers) == 1 and np.allclose(s.frequencies_hz, [0.01, 2.0, 4.0])
    d = copy.deepcopy(BASE)
    d["impedance"] = {"range_hz": [0.0, 25.0, 6]}
    assert np.allclose(scene_from_dict(d).frequencies_hz, [0, 5, 10, 15, 20, 25])


def test_relative_node_file(tmp_path):
    (tmp_path / "nodes.csv").write_text("x,y,area\n0,0,1\n1,0,1\n0,1,1\n")
    (tmp_path / "s.toml").write_text(
        '[soil]\nhalfspace = { vs = 500.0, nu = 0.3, rho = 2000.0 }\n'
        '[foundation]\nshape = "nodes"\nfile = "nodes.csv"\n')
    s = load_scene(tmp_path / "s.toml")
    assert s.mesh.n == 3 and s.mesh.cell is None


def _with(path, value):
    d = copy.deepcopy(BASE)
    node = d
    for key in path[:-1]:
        node = node[key]
    if value is KeyError:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return d


@pytest.mark.parametrize("path, value, expected", [
    (("soil", "layers", 0, "thickness"), -1.0, "soil.layers[0]: thickness = -1.0"),
    (("soil", "layers", 0, "nu"), 0.5, "Poisson ratio nu = 0.5 must lie in (0, 0.5)"),
    (("soil", "halfspace", "vs"), 0.0, "soil.halfspace: vs = 0.0"),
    (("soil", "layers", 0, "damping"), 0.6, "damping = 0.6 must lie in [0, 0.5)"),
    (("soil", "halfspace", "vp"), 600.0, "below vs*sqrt(2)"),
    (("soil", "halfspace"), KeyError, "soil.halfspace is missing"),
    (("soil", "layers", 0, "thicknes"), 3.0, "unknown key soil.layers[0].thicknes: did you mean 'thickness'"),
    (("foundation", "radius"), -2.0, "foundation.radius = -2.0"),
    (("foundation", "element_size"), 50.0, "exceeds the radius"),
    (("foundation", "shape"), "hexagon", 'foundation.shape = \'hexagon\''),
    (("foundation", "contact"), "glued", "foundation.contact = 'glued'"),
    (("foundation", "radius"), KeyError, "foundation.radius is missing"),
    (("impedance", "frequencies_hz"), [2.0, 1.0], "strictly increasing"),
    (("impedance", "frequencies_hz"), [0.0, float("nan")], "must be a non-empty list of numbers"),
    (("impedance", "frequency_hz"), [1.0], "unknown key impedance.frequency_hz"),
    (("foundaton",), {}, "unknown section scene.foundaton: did you mean 'foundation'"),
])
def test_invalid_fields(path, value, expected):
    with pytest.raises(SceneError) as err:
        scene_from_dict(_with(path, value))
    assert expected in str(err.value)


def test_damping_model_key():
    """[soil].damping_model applies to every material; it is part of the impedance cache key."""
    from soil_impedance.sweep import provenance
    from soil_impedance.table import content_hash
    hyst = scene_from_dict(BASE)
    causal = scene_from_dict(_with(("soil", "damping_model"), "causal"))
    assert hyst.profile.halfspace.damping_model == "hysteretic"
    assert {m.damping_model for m in causal.profile.layers + (causal.profile.halfspace,)} == {"causal"}
    keys = [content_hash(provenance(s.profile, s.mesh, "welded", None, "rigid"), s.frequencies_hz)
            for s in (hyst, causal)]
    assert keys[0] != keys[1]
    for bad in ("Causal", 1.0):
        with pytest.raises(SceneError, match=r"soil.damping_model = .*use one of \"hysteretic\", \"causal\""):
            scene_from_dict(_with(("soil", "damping_model"), bad))


def test_missing_files(tmp_path):
    with pytest.raises(SceneError, match="unknown scene 'nope'"):
        load_scene("nope")
    with pytest.raises(SceneError, match="does not exist"):
        load_scene(tmp_path / "absent.toml")
    d = copy.deepcopy(BASE)
    d["foundation"] = {"shape": "nodes", "file": "missing.csv"}
    with pytest.raises(SceneError, match="no such file"):
        scene_from_dict(d, base_dir=tmp_path)


def test_range_needs_three_values():
    d = copy.deepcopy(BASE)
    d["impedance"] = {"range_hz": [0.0, 25.0]}
    with pytest.raises(SceneError, match=r"must be \[fmin, fmax, count\]"):
        scene_from_dict(d)

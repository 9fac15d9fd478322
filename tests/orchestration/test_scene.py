"""Scene loading: built-ins load into typed frozen configs, and every invalid field gives its own
clear message."""
import copy
import dataclasses

import numpy as np
import pytest

from helpers import edited
from orchestrator.scene import (AnalysisConfig, MotionConfig, OutputConfig, SceneError, WinklerConfig, builtin_scenes,
                                load_scene, scene_from_dict)
from structure.contact import ContactSettings

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
    assert disk.structure is None and disk.contact == ContactSettings()
    assert (disk.motion, disk.analysis, disk.output, disk.winkler) == (MotionConfig(), AnalysisConfig(),
                                                                      OutputConfig(), WinklerConfig())
    reactor = load_scene("reactor")
    assert reactor.mesh.n == 241
    assert reactor.structure.model == "reactor" and reactor.structure.damping.ratio == 0.07
    assert reactor.output.nodes == ("top_outer", "top_inner", "internals_37m")
    assert reactor.analysis == AnalysisConfig(routes=("winkler", "monolithic", "linear"), dt=0.005)
    assert reactor.motion == MotionConfig(kind="synthetic", pga_g=0.25, duration_s=10.0, seed=1, direction="x")
    assert reactor.contact == ContactSettings(enabled=True, penalty="auto")
    assert reactor.profile.halfspace.damping_model == "causal" and not reactor.winkler.explicit
    model = reactor.model()
    assert model.n_interface == 241 and model.node_by_name("top_outer").xyz == (0.0, 0.0, 62.0)
    with pytest.raises(SceneError, match=r"scene 'disk-halfspace' has no \[structure\] section"):
        disk.model()


def test_scene_and_configs_are_frozen():
    s = load_scene("reactor")
    for obj, attr in ((s, "motion"), (s, "name"), (s.motion, "pga_g"), (s.analysis, "dt"), (s.output, "nodes"),
                      (s.winkler, "springs"), (s.contact, "enabled"), (s.structure, "nodes")):
        with pytest.raises(dataclasses.FrozenInstanceError):
            setattr(obj, attr, getattr(obj, attr))
    with pytest.raises(ValueError):
        s.frequencies_hz[0] = 1.0
    assert isinstance(s.analysis.routes, tuple) and isinstance(s.structure.nodes, tuple)


def test_replace_validates_again():
    """A config that exists is valid: dataclasses.replace goes through the same checks."""
    s = load_scene("reactor")
    with pytest.raises(SceneError, match=r"motion\.pga_g = -1\.0 must be a peak ground acceleration > 0 g"):
        dataclasses.replace(s.motion, pga_g=-1.0)
    with pytest.raises(SceneError, match=r"output\.nodes: 'roof' is not a named structure node; named nodes: raft, "):
        dataclasses.replace(s, output=OutputConfig(("roof",)))
    with pytest.raises(SceneError, match="unknown route 'fem'"):
        s.with_routes(["fem"])
    assert s.with_routes(["timefreq"]).analysis.routes == ("timefreq",)
    assert dataclasses.replace(s.motion, pga_g=0.6).pga_g == 0.6


WINKLER_ONLY = {
    "soil": {"winkler": {"kv": 5.0e7, "kh": 4.0e7}},
    "foundation": {"shape": "rectangle", "lx": 10.0, "ly": 10.0, "element_size": 2.5},
    "structure": {"nodes": [{"id": 1, "xyz": [0, 0, 0]}, {"id": 2, "xyz": [0, 0, 20], "name": "top"}],
                  "beams": [{"nodes": [1, 2], "E": 3e10, "G": 1.25e10, "A": 10.0, "Iy": 20.0, "Iz": 20.0, "J": 40.0}],
                  "raft": {"node": 1, "m": 1.0e6}},
    "analysis": {"routes": ["winkler"], "dt": 0.01},
}


def test_explicit_winkler_needs_no_halfspace_unless_a_bem_route_runs():
    s = scene_from_dict(WINKLER_ONLY)
    assert s.profile is None and s.winkler.explicit and s.winkler.moduli == (5.0e7, 4.0e7, 0.0, 0.0)
    for routes in (["winkler", "monolithic"], ["linear"]):
        d = copy.deepcopy(WINKLER_ONLY)
        d["analysis"]["routes"] = routes
        with pytest.raises(SceneError, match=r"scene 'scene': soil.halfspace is missing: routes "
                                             + ", ".join(r for r in routes if r != "winkler") + " need the BEM"):
            scene_from_dict(d)
    with pytest.raises(SceneError, match=r"soil\.halfspace is missing: routes monolithic need"):
        s.with_routes(["monolithic"])
    d = copy.deepcopy(WINKLER_ONLY)
    d["soil"]["winkler"] = {"springs": "nodal"}          # a calibration on the BEM needs the soil
    with pytest.raises(SceneError, match=r"soil\.halfspace is missing"):
        scene_from_dict(d)


def test_record_motion_is_resolved_and_read_at_load(tmp_path):
    (tmp_path / "rec").mkdir()
    (tmp_path / "rec" / "a.txt").write_text("".join(f"{0.01 * k:.2f} {0.1 * (k % 3)}\n" for k in range(200)))
    d = copy.deepcopy(WINKLER_ONLY)
    d["motion"] = {"kind": "record", "file": "rec/a.txt", "units": "m/s2", "scale": 2.0, "direction": "y"}
    s = scene_from_dict(d, base_dir=tmp_path)
    assert s.motion.file == (tmp_path / "rec" / "a.txt").resolve() and s.motion.file.is_absolute()
    assert s.motion.record.dt == pytest.approx(0.01) and s.motion.record.acc[2, 1] == pytest.approx(0.4)


def test_base_scene_and_range():
    s = scene_from_dict(BASE)
    assert len(s.profile.layers) == 1 and np.allclose(s.frequencies_hz, [0.01, 2.0, 4.0])
    d = copy.deepcopy(BASE)
    d["impedance"] = {"range_hz": [0.0, 25.0, 6]}
    assert np.allclose(scene_from_dict(d).frequencies_hz, [0, 5, 10, 15, 20, 25])


def test_relative_node_file(tmp_path):
    (tmp_path / "nodes.csv").write_text("x,y,area\n-1,-1,1\n1,-1,1\n0,1,1\n")
    (tmp_path / "s.toml").write_text(
        '[soil]\nhalfspace = { vs = 500.0, nu = 0.3, rho = 2000.0 }\n'
        '[foundation]\nshape = "nodes"\nfile = "nodes.csv"\n')
    s = load_scene(tmp_path / "s.toml")
    assert s.mesh.n == 3 and s.mesh.cell is None


def _with(path, value):
    return edited(BASE, path, value)


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
    (("impedance", "frequencies_hz"), [0.0, float("nan")], "impedance.frequencies_hz[1] = nan must be a finite number"),
    (("impedance", "frequencies_hz"), [], "must be a non-empty list of numbers"),
    (("impedance", "frequency_hz"), [1.0], "unknown key impedance.frequency_hz"),
    (("foundaton",), {}, "unknown section scene.foundaton: did you mean 'foundation'"),
])
def test_invalid_fields(path, value, expected):
    with pytest.raises(SceneError) as err:
        scene_from_dict(_with(path, value), name="base")
    assert str(err.value).startswith("scene 'base': ") and expected in str(err.value), str(err.value)


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

"""Scene-table validation: each invalid field gets its own message naming the key."""
import copy

import numpy as np
import pytest

from soil_impedance.mesh import circle_mesh
from structure import StructureError
from structure.spec import contact_from_spec, model_from_spec, winkler_from_spec

MESH = circle_mesh(10.0, 2.0)
BASE = {
    "nodes": [{"id": 1, "xyz": [0, 0, 0]}, {"id": 2, "xyz": [0, 0, 20], "name": "top"}],
    "beams": [{"nodes": [1, 2], "E": 3e10, "G": 1.25e10, "A": 40.0, "Iy": 900.0, "Iz": 900.0,
               "J": 1800.0}],
    "masses": [{"node": 2, "m": 2.0e6, "inertia": [0, 0, 0]}],
    "raft": {"node": 1, "m": 5.0e6, "inertia": [1e8, 1e8, 2e8]},
    "damping": {"modal": 0.07},
}


def edit(path, value):
    s = copy.deepcopy(BASE)
    obj = s
    for k in path[:-1]:
        obj = obj[k]
    if value is KeyError:
        del obj[path[-1]]
    else:
        obj[path[-1]] = value
    return s


def test_valid_inline_and_reactor():
    m = model_from_spec(BASE, MESH.xy, MESH.area)
    assert m.n_struct == 12 and m.n_interface == MESH.n and m.damping.ratio == 0.07
    r = model_from_spec({"model": "reactor", "damping": {"rayleigh": [0.1, 0.001]}}, MESH.xy, MESH.area)
    assert r.damping.kind == "rayleigh" and r.node_by_name("top_inner").xyz[2] == 56.0


@pytest.mark.parametrize("path, value, message", [
    (("beams", 0, "E"), -3, "structure.beams[0].E = -3 must be > 0"),
    (("beams", 0, "Iy"), "big", "structure.beams[0].Iy = 'big' must be a finite number"),
    (("beams", 0, "nodes"), [1, 9], "structure.beams[0].nodes[1] = 9 is not a node id"),
    (("beams", 0, "nodes"), [1, 1], "structure.beams[0].nodes = [1, 1] has zero length"),
    (("beams", 0, "colour"), 1, "structure.beams[0].colour is not a known key"),
    (("beams", 0, "J"), KeyError, "structure.beams[0].J is missing"),
    (("nodes", 1, "id"), 1, "structure.nodes[1].id = 1 is used twice"),
    (("nodes", 1, "xyz"), [0, 0], "structure.nodes[1].xyz = [0, 0] must be a list of 3 numbers"),
    (("masses", 0, "m"), -1.0, "structure.masses[0].m = -1.0 must be >= 0"),
    (("masses", 0, "inertia"), [0, -1, 0], "structure.masses[0].inertia[1] = -1 must be >= 0"),
    (("raft", "node"), 2, "structure.raft.node = 2 is at z = 20"),
    (("damping",), {"modal": 7}, "structure.damping.modal = 7.0 must be < 1"),
    (("damping",), {"viscous": 0.1}, "structure.damping.viscous is not a known key"),
    (("damping",), {"rayleigh": [0.1]}, "structure.damping.rayleigh = [0.1] must be a list of 2 numbers"),
    (("extra",), 1, "structure.extra is not a known key"),
    (("model",), "reactor", "structure.beams cannot be combined with structure.model"),
])
def test_invalid_structure_fields(path, value, message):
    with pytest.raises(StructureError) as ei:
        model_from_spec(edit(path, value), MESH.xy, MESH.area)
    assert message in str(ei.value), str(ei.value)


def test_unknown_builtin_model():
    with pytest.raises(StructureError, match="structure.model = 'plant' is not a built-in model"):
        model_from_spec({"model": "plant"}, MESH.xy, MESH.area)


def test_disconnected_node_is_named():
    s = edit(("nodes",), BASE["nodes"] + [{"id": 3, "xyz": [5, 0, 5]}])
    with pytest.raises(StructureError, match="node 3 is not connected"):
        model_from_spec(s, MESH.xy, MESH.area)


@pytest.mark.parametrize("spec, message", [
    ({"kv": -2e8, "kh": 1.5e8}, "soil.winkler.kv = -200000000.0 must be > 0"),
    ({"kv": 2e8}, "soil.winkler.kh is missing"),
    ({"kv": 2e8, "kh": 1e8, "cv": -1.0}, "soil.winkler.cv = -1.0 must be >= 0"),
    ({"kv": 2e8, "kh": 1e8, "kr": 1.0}, "soil.winkler.kr is not a known key"),
])
def test_invalid_winkler_fields(spec, message):
    with pytest.raises(StructureError) as ei:
        winkler_from_spec(spec, MESH.xy, MESH.area)
    assert message in str(ei.value), str(ei.value)


def test_winkler_from_spec_per_node_values():
    s = winkler_from_spec({"winkler": {"kv": 2.0e8, "kh": 1.5e8, "cv": 3.0, "ch": 4.0}}, MESH.xy, MESH.area)
    assert np.allclose(s.kv, 2.0e8 * MESH.area) and np.allclose(s.cx, 4.0 * MESH.area)


@pytest.mark.parametrize("spec, message", [
    ({"enabled": "yes"}, "contact.enabled = 'yes' must be true or false"),
    ({"penalty": "big"}, "contact.penalty = 'big' must be \"auto\""),
    ({"penalty": -1.0}, "contact.penalty = -1.0 must be > 0"),
    ({"friction": 0.5}, "contact.friction is not a known key"),
    ({"auto_factor": 0.0}, "contact.auto_factor = 0.0 must be > 0"),
])
def test_invalid_contact_fields(spec, message):
    with pytest.raises(StructureError) as ei:
        contact_from_spec(spec)
    assert message in str(ei.value), str(ei.value)


def test_contact_from_spec_values():
    c = contact_from_spec({"enabled": False, "penalty": 1e12})
    assert not c.enabled and c.penalty == 1e12
    assert contact_from_spec(None).penalty == "auto"


def test_auto_penalty_factor_scales_the_local_soil_stiffness():
    from structure.contact import AUTO_FACTOR, penalty_stiffness
    K0 = np.diag([1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 2.0e8, 3.0e8])
    kp = penalty_stiffness(contact_from_spec({"auto_factor": 250.0}), K0, 2)
    np.testing.assert_array_equal(kp, [5.0e10, 7.5e10])
    assert contact_from_spec({}).auto_factor == AUTO_FACTOR

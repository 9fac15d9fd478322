"""Scene-table validation: each invalid field gets its own message naming the key; the validated
spec is frozen, reads back from its table and builds the same model."""
import copy

import numpy as np
import pytest

from helpers import edited
from soil_impedance.mesh import circle_mesh
from structure import StructureError
from structure.spec import (StructureSpec, build_model, contact_from_spec, contact_table, model_from_spec,
                            parse_structure, winkler_from_moduli, winkler_from_spec)

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
    return edited(BASE, path, value)


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
    (("beams", 0, "colour"), 1, "unknown key structure.beams[0].colour: allowed: nodes, E, G"),
    (("beams", 0, "J"), KeyError, "structure.beams[0].J is missing"),
    (("nodes", 1, "id"), 1, "structure.nodes[1].id = 1 is used twice"),
    (("nodes", 1, "xyz"), [0, 0], "structure.nodes[1].xyz = [0, 0] must be a list of 3 numbers"),
    (("masses", 0, "m"), -1.0, "structure.masses[0].m = -1.0 must be >= 0"),
    (("masses", 0, "inertia"), [0, -1, 0], "structure.masses[0].inertia[1] = -1 must be >= 0"),
    (("raft", "node"), 2, "structure.raft.node = 2 is at z = 20"),
    (("damping",), {"modal": 7}, "structure.damping.modal = 7 must be a ratio in [0, 1)"),
    (("damping",), {"viscous": 0.1}, "unknown key structure.damping.viscous"),
    (("damping",), {"rayleigh": [0.1]}, "structure.damping.rayleigh = [0.1] must be a list of 2 numbers"),
    (("extra",), 1, "unknown key structure.extra"),
    (("mases",), [], "unknown key structure.mases: did you mean 'masses'?"),
    (("masses",), 5, "structure.masses = 5 must be a list of tables"),
    (("nodes", 0), 5, "structure.nodes[0] must be a table"),
    (("nodes", 0, "id"), 1.5, "structure.nodes[0].id = 1.5 must be an integer node id"),
    (("nodes", 0, "id"), True, "structure.nodes[0].id = True must be an integer node id"),
    (("beams", 0, "E"), float("inf"), "structure.beams[0].E = inf must be a finite number"),
    (("beams", 0, "A"), True, "structure.beams[0].A = True must be a finite number"),
    (("beams", 0, "nodes"), "12", "structure.beams[0].nodes = '12' must be a list of 2 node ids"),
    (("raft",), [1], "structure.raft must be a table"),
    (("raft", "inertias"), [0, 0, 0], "unknown key structure.raft.inertias: did you mean 'inertia'"),
    (("model",), "reactor", "structure.beams cannot be combined with structure.model"),
])
def test_invalid_structure_fields(path, value, message):
    with pytest.raises(StructureError) as ei:
        model_from_spec(edit(path, value), MESH.xy, MESH.area)
    assert message in str(ei.value), str(ei.value)


@pytest.mark.parametrize("table, message", [
    ({"model": "reactor", "dampng": {"modal": 0.05}}, "unknown key structure.dampng: did you mean 'damping'"),
    ({"model": 3}, "structure.model = 3 is not a built-in model"),
    ("reactor", "structure must be a table"),
])
def test_invalid_builtin_forms(table, message):
    with pytest.raises(StructureError) as ei:
        parse_structure(table)
    assert message in str(ei.value), str(ei.value)


def test_unknown_builtin_model():
    with pytest.raises(StructureError, match=r"structure\.model = 'plant' is not a built-in model"):
        model_from_spec({"model": "plant"}, MESH.xy, MESH.area)


def test_disconnected_node_is_named():
    s = edit(("nodes",), BASE["nodes"] + [{"id": 3, "xyz": [5, 0, 5]}])
    with pytest.raises(StructureError, match="node 3 is not connected"):
        model_from_spec(s, MESH.xy, MESH.area)


@pytest.mark.parametrize("spec, message", [
    ({"kv": -2e8, "kh": 1.5e8}, "soil.winkler.kv = -200000000.0 must be > 0"),
    ({"kv": 2e8}, "soil.winkler.kh is missing"),
    ({"kv": 2e8, "kh": 1e8, "cv": -1.0}, "soil.winkler.cv = -1.0 must be >= 0"),
    ({"kv": 2e8, "kh": 1e8, "kr": 1.0}, "unknown key soil.winkler.kr"),
    ({"kv": "2e8", "kh": 1e8}, "soil.winkler.kv = '2e8' must be a finite number"),
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
    ({"friction": 0.5}, "unknown key contact.friction"),
    ({"penalti": 1e9}, "unknown key contact.penalti: did you mean 'penalty'?"),
    ({"auto_factor": True}, "contact.auto_factor = True must be a finite number"),
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


def _same_model(a, b):
    assert (a.stiffness != b.stiffness).nnz == 0 and np.array_equal(a.mass, b.mass)
    assert a.nodes == b.nodes and a.damping == b.damping and np.array_equal(a.raft.xy, b.raft.xy)


@pytest.mark.parametrize("table", [
    BASE, {"model": "reactor"}, {"model": "reactor", "damping": {"rayleigh": [0.1, 1e-3]}},
    edit(("springs",), [{"node": 2, "k": [1e9] * 6}, {"node": 1, "node2": 2, "k": [0] * 6}]),
])
def test_spec_is_frozen_and_reads_back_from_its_table(table):
    """parse -> as_table -> parse gives an equal spec (what the FMU carries), the same model."""
    import dataclasses
    import json
    spec = parse_structure(copy.deepcopy(table))
    assert isinstance(spec, StructureSpec)
    again = parse_structure(json.loads(json.dumps(spec.as_table())))
    assert again == spec
    _same_model(build_model(again, MESH.xy, MESH.area), model_from_spec(table, MESH.xy, MESH.area))
    with pytest.raises(dataclasses.FrozenInstanceError):
        spec.model = "other"
    with pytest.raises(dataclasses.FrozenInstanceError):
        spec.raft.m = 0.0


def test_spec_names_and_builtin_provenance():
    r = parse_structure({"model": "reactor"})
    assert r.model == "reactor" and r.node_names == ("raft", "top_outer", "top_inner", "internals_37m")
    assert parse_structure(BASE).model is None and parse_structure(BASE).node_names == ("top",)


def test_winkler_from_moduli_is_winkler_from_spec():
    a = winkler_from_moduli((2.0e8, 1.5e8, 3.0, 0.0), MESH.xy, MESH.area)
    b = winkler_from_spec({"kv": 2.0e8, "kh": 1.5e8, "cv": 3.0}, MESH.xy, MESH.area)
    assert np.array_equal(a.kv, b.kv) and np.array_equal(a.kx, b.kx) and np.array_equal(a.cv, b.cv)
    with pytest.raises(StructureError, match="must be the 4 numbers"):
        winkler_from_moduli((2.0e8, 1.5e8), MESH.xy, MESH.area)


@pytest.mark.parametrize("table", [{}, {"enabled": False, "penalty": 1e12}, {"auto_factor": 250.0, "precheck": False}])
def test_contact_table_reads_back(table):
    c = contact_from_spec(table)
    assert contact_from_spec(contact_table(c)) == c

"""Scene tables -> structure objects, with validation that names the key at fault.

[structure]  -> model_from_spec(spec, xy, area)        (model = "reactor" or inline tables)
[soil] winkler = {...} -> winkler_from_spec(spec, xy, area)
[contact]    -> contact_from_spec(spec)
Unknown keys are errors. Messages read like "structure.beams[0].E = -3 must be > 0".
"""
from __future__ import annotations

import math
import tomllib
from importlib import resources

import numpy as np

from .contact import AUTO_FACTOR, ContactSettings
from .errors import StructureError
from .model import Beam, Damping, Mass, Node, Raft, Spring, StructureModel
from .soil_interface import WinklerSoil

BUILTIN_MODELS = ("reactor",)


def _keys(path, table, required, optional=()):
    if not isinstance(table, dict):
        raise StructureError(f"{path} must be a table, got {type(table).__name__}")
    unknown = sorted(set(table) - set(required) - set(optional))
    if unknown:
        raise StructureError(f"{path}.{unknown[0]} is not a known key; allowed: "
                             f"{', '.join(sorted(set(required) | set(optional)))}")
    for k in required:
        if k not in table:
            raise StructureError(f"{path}.{k} is missing")


def _num(path, v, lo=None, strict=True):
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise StructureError(f"{path} = {v!r} must be a finite number")
    if lo is not None and (v <= lo if strict else v < lo):
        raise StructureError(f"{path} = {v!r} must be {'>' if strict else '>='} {lo}")
    return float(v)


def _vec(path, v, n, lo=None, strict=False):
    if not isinstance(v, (list, tuple)) or len(v) != n:
        raise StructureError(f"{path} = {v!r} must be a list of {n} numbers")
    return tuple(_num(f"{path}[{i}]", x, lo, strict) for i, x in enumerate(v))


def _int(path, v):
    if isinstance(v, bool) or not isinstance(v, int):
        raise StructureError(f"{path} = {v!r} must be an integer node id")
    return v


def builtin_spec(name: str) -> dict:
    """The [structure] table of a built-in model (structure/data/<name>.toml)."""
    if name not in BUILTIN_MODELS:
        raise StructureError(f"structure.model = {name!r} is not a built-in model; "
                             f"choose one of {BUILTIN_MODELS} or give nodes/beams inline")
    text = resources.files("structure.data").joinpath(f"{name}.toml").read_text()
    return tomllib.loads(text)["structure"]


def _damping(path, d):
    if d is None:
        return Damping()
    _keys(path, d, (), ("modal", "rayleigh"))
    if len(d) != 1:
        raise StructureError(f"{path} must have exactly one of 'modal' or 'rayleigh'")
    if "modal" in d:
        r = _num(f"{path}.modal", d["modal"], 0.0, strict=False)
        if r >= 1:
            raise StructureError(f"{path}.modal = {r} must be < 1 (a ratio, 0.07 for 7 %)")
        return Damping("modal", ratio=r)
    a0, a1 = _vec(f"{path}.rayleigh", d["rayleigh"], 2, 0.0)
    return Damping("rayleigh", a0=a0, a1=a1)


def model_from_spec(spec: dict, xy, area) -> StructureModel:
    """StructureModel from a scene's [structure] table; xy (N, 2) m, area (N,) m^2 of the
    interface nodes about the raft centre. model = "reactor" loads the built-in model; it
    may be combined with ``damping`` only (to override the built-in damping)."""
    p = "structure"
    if not isinstance(spec, dict):
        raise StructureError(f"{p} must be a table")
    if "model" in spec:
        extra = sorted(set(spec) - {"model", "damping"})
        if extra:
            raise StructureError(f"{p}.{extra[0]} cannot be combined with {p}.model (a built-in "
                                 f"model); only {p}.damping may override it")
        if not isinstance(spec["model"], str):
            raise StructureError(f"{p}.model = {spec['model']!r} must be a string")
        base = dict(builtin_spec(spec["model"]))
        base.pop("model", None)
        if "damping" in spec:
            base["damping"] = spec["damping"]
        spec = base
    _keys(p, spec, ("nodes", "beams", "raft"), ("masses", "springs", "damping"))
    nodes, ids = [], set()
    if not isinstance(spec["nodes"], list) or not spec["nodes"]:
        raise StructureError(f"{p}.nodes must be a non-empty list of {{ id, xyz, name }} tables")
    for i, n in enumerate(spec["nodes"]):
        q = f"{p}.nodes[{i}]"
        _keys(q, n, ("id", "xyz"), ("name",))
        nid = _int(f"{q}.id", n["id"])
        if nid in ids:
            raise StructureError(f"{q}.id = {nid} is used twice: node ids must be unique")
        ids.add(nid)
        name = n.get("name")
        if name is not None and (not isinstance(name, str) or not name):
            raise StructureError(f"{q}.name = {name!r} must be a non-empty string")
        nodes.append(Node(nid, _vec(f"{q}.xyz", n["xyz"], 3), name))
    names = [n.name for n in nodes if n.name]
    if len(set(names)) != len(names):
        raise StructureError(f"{p}.nodes: names must be unique, got {names}")

    def ref(q, v):
        v = _int(q, v)
        if v not in ids:
            raise StructureError(f"{q} = {v} is not a node id; known ids: {sorted(ids)}")
        return v

    beams = []
    if not isinstance(spec["beams"], list):
        raise StructureError(f"{p}.beams must be a list of tables")
    xyz = {n.id: n.xyz for n in nodes}
    for i, b in enumerate(spec["beams"]):
        q = f"{p}.beams[{i}]"
        _keys(q, b, ("nodes", "E", "G", "A", "Iy", "Iz", "J"), ("Asy", "Asz", "rho"))
        if not isinstance(b["nodes"], list) or len(b["nodes"]) != 2:
            raise StructureError(f"{q}.nodes = {b['nodes']!r} must be a list of 2 node ids")
        n1, n2 = ref(f"{q}.nodes[0]", b["nodes"][0]), ref(f"{q}.nodes[1]", b["nodes"][1])
        if np.allclose(xyz[n1], xyz[n2]):
            raise StructureError(f"{q}.nodes = {[n1, n2]} has zero length")
        vals = {k: _num(f"{q}.{k}", b[k], 0.0) for k in ("E", "G", "A", "Iy", "Iz", "J")}
        for k in ("Asy", "Asz"):
            vals[k] = _num(f"{q}.{k}", b[k], 0.0) if k in b else None
        vals["rho"] = _num(f"{q}.rho", b["rho"], 0.0, strict=False) if "rho" in b else 0.0
        beams.append(Beam((n1, n2), **vals))
    masses = []
    for i, m in enumerate(spec.get("masses", [])):
        q = f"{p}.masses[{i}]"
        _keys(q, m, ("node", "m"), ("inertia",))
        masses.append(Mass(ref(f"{q}.node", m["node"]), _num(f"{q}.m", m["m"], 0.0, strict=False),
                           _vec(f"{q}.inertia", m.get("inertia", [0, 0, 0]), 3, 0.0)))
    springs = []
    for i, s in enumerate(spec.get("springs", [])):
        q = f"{p}.springs[{i}]"
        _keys(q, s, ("node", "k"), ("node2",))
        n2 = ref(f"{q}.node2", s["node2"]) if "node2" in s else None
        springs.append(Spring(ref(f"{q}.node", s["node"]), _vec(f"{q}.k", s["k"], 6, 0.0), n2))
    r = spec["raft"]
    q = f"{p}.raft"
    _keys(q, r, ("node",), ("m", "inertia"))
    rn = ref(f"{q}.node", r["node"])
    if abs(xyz[rn][2]) > 1e-9:
        raise StructureError(f"{q}.node = {rn} is at z = {xyz[rn][2]}: the raft master node must "
                             "lie on z = 0 at the raft centre")
    xy = np.asarray(xy, float)
    try:
        raft = Raft(rn, xy, area, _num(f"{q}.m", r.get("m", 0.0), 0.0, strict=False),
                    _vec(f"{q}.inertia", r.get("inertia", [0, 0, 0]), 3, 0.0))
    except StructureError as exc:
        raise StructureError(f"{q}: {exc}") from None
    model = StructureModel(tuple(nodes), tuple(beams), tuple(masses), raft, tuple(springs),
                           _damping(f"{p}.damping", spec.get("damping")))
    connected = {rn}
    edges = [b.nodes for b in beams] + [(s.node, s.node2) for s in springs if s.node2 is not None]
    grow = True
    while grow:
        grow = False
        for a, b in edges:
            if (a in connected) != (b in connected):
                connected |= {a, b}
                grow = True
    grounded = {s.node for s in springs if s.node2 is None}
    loose = sorted(ids - connected - grounded)
    if loose:
        raise StructureError(f"{p}.nodes: node {loose[0]} is not connected to the raft node {rn} "
                             "by beams or springs")
    return model


def winkler_from_spec(spec: dict, xy, area) -> WinklerSoil:
    """WinklerSoil from [soil] winkler = { kv, kh, cv, ch } (subgrade moduli N/m^3 and dashpots
    N s/m^3, multiplied by each node's tributary area). ``spec`` is the winkler table (a
    {"winkler": {...}} wrapper is accepted too)."""
    p = "soil.winkler"
    if isinstance(spec, dict) and set(spec) == {"winkler"}:
        spec = spec["winkler"]
    _keys(p, spec, ("kv", "kh"), ("cv", "ch"))
    kv = _num(f"{p}.kv", spec["kv"], 0.0)
    kh = _num(f"{p}.kh", spec["kh"], 0.0, strict=False)
    cv = _num(f"{p}.cv", spec.get("cv", 0.0), 0.0, strict=False)
    ch = _num(f"{p}.ch", spec.get("ch", 0.0), 0.0, strict=False)
    area = np.asarray(area, float)
    return WinklerSoil(xy, kv * area, kh * area, cv * area, ch * area)


def contact_from_spec(spec: dict | None) -> ContactSettings:
    """ContactSettings from [contact] { enabled = true, penalty = "auto" | N/m per node,
    auto_factor = 1e4, precheck = true } (auto_factor: the "auto" penalty over the soil's local
    static stiffness) (precheck = false forces the nonlinear contact iterations even when a
    linear pre-check would show that the contact never opens; see ContactSettings)."""
    p = "contact"
    if spec is None:
        return ContactSettings()
    _keys(p, spec, (), ("enabled", "penalty", "precheck", "auto_factor"))
    en, pre = spec.get("enabled", True), spec.get("precheck", True)
    for key, value in (("enabled", en), ("precheck", pre)):
        if not isinstance(value, bool):
            raise StructureError(f"{p}.{key} = {value!r} must be true or false")
    pen = spec.get("penalty", "auto")
    if isinstance(pen, str):
        if pen != "auto":
            raise StructureError(f"{p}.penalty = {pen!r} must be \"auto\" or a stiffness in N/m per node")
    else:
        pen = _num(f"{p}.penalty", pen, 0.0)
    factor = _num(f"{p}.auto_factor", spec.get("auto_factor", AUTO_FACTOR), 0.0)
    return ContactSettings(enabled=en, penalty=pen, auto_factor=factor, precheck=pre)

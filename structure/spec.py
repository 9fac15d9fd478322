"""Scene tables -> structure objects, with validation that names the key at fault.

[structure]  -> parse_structure(table) -> StructureSpec (validated, frozen: model = "reactor" or
                inline nodes / beams / masses / springs / raft / damping; spec.as_table() gives the
                table back), then build_model(spec, xy, area) -> StructureModel on the interface
                nodes; model_from_spec(table, xy, area) does both
[soil] winkler = { kv, kh, cv, ch } -> winkler_moduli(table) -> (kv, kh, cv, ch), then
                winkler_from_moduli(moduli, xy, area) -> WinklerSoil; winkler_from_spec does both
[contact]    -> contact_from_spec(table) -> ContactSettings (contact_table: back to the table)

check_keys, check_number and check_choice are the table checks of every scene section (the
orchestrator's scene loader uses them with its own error class): unknown keys are errors with a
did-you-mean hint, numbers are int or float (not bool), finite and in range. Messages read like
"structure.beams[0].E = -3 must be > 0" and "unknown key structure.beams[0].colour: allowed: ...".
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from importlib import resources

import numpy as np

from .contact import AUTO_FACTOR, ContactSettings
from .errors import StructureError
from uplift_common.ranges import MAX_STRUCTURE_ELEMENTS, MAX_STRUCTURE_NODES, check_count, check_plausible
from .model import Beam, Damping, Mass, Node, Raft, Spring, StructureModel
from .soil_interface import WinklerSoil

BUILTIN_MODELS = ("reactor",)
#: the plausible range (uplift_common.ranges.PLAUSIBLE) of each number of a beam
BEAM_RANGES = {"E": "modulus", "G": "modulus", "A": "area", "Asy": "area", "Asz": "area", "Iy": "second_moment",
               "Iz": "second_moment", "J": "second_moment", "rho": "beam_density"}
STRUCTURE_KEYS = ("nodes", "beams", "raft", "masses", "springs", "damping")
WINKLER_MODULI = ("kv", "kh", "cv", "ch")
CONTACT_KEYS = ("auto_factor", "enabled", "penalty", "precheck")


# ---- table checks shared by every scene section ----------------------------------------------

def show(value) -> str:
    """repr of a value, cut to a readable length for messages."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def check_keys(table, allowed, where: str, what: str = "key", *, required=(), error=StructureError):
    """Refuse a non-table, a key not in ``allowed`` (with a did-you-mean hint) and a missing
    ``required`` key; ``where`` is the table's dotted path (``structure.beams[0]``)."""
    if not isinstance(table, dict):
        raise error(f"{where} must be a table {{ key = value, ... }}, got {show(table)}")
    for key in table:
        if key not in allowed:
            close = [a for a in allowed if a.lower() == str(key).lower() or _near(a, str(key))]
            hint = f"did you mean {close[0]!r}? " if close else ""
            raise error(f"unknown {what} {where}.{key}: {hint}allowed: {', '.join(allowed)}")
    for key in required:
        if key not in table:
            raise error(f"{where}.{key} is missing")


def _near(a: str, b: str) -> bool:
    """One edit apart (a typo)."""
    if abs(len(a) - len(b)) > 1:
        return False
    if len(a) == len(b):
        return sum(x != y for x, y in zip(a, b, strict=True)) <= 1 or sorted(a) == sorted(b)
    s, l = sorted((a, b), key=len)
    return any(l[:i] + l[i + 1:] == s for i in range(len(l)))


def check_number(where: str, v, lo=None, hi=None, *, lo_open=True, hi_open=False, integer=False,
                 expect: str | None = None, error=StructureError):
    """v as a float (an int when ``integer``): an int or float, not a bool, finite, in the range
    given by lo / hi (open or closed ends). ``expect`` replaces the range in the message."""
    ok_type = isinstance(v, int) if integer else isinstance(v, (int, float)) and _finite(v)
    if isinstance(v, bool) or not ok_type:
        raise error(f"{where} = {show(v)} must be {expect or ('an integer' if integer else 'a finite number')}")
    if (lo is not None and (v <= lo if lo_open else v < lo)) or (hi is not None and (v >= hi if hi_open else v > hi)):
        if expect:
            raise error(f"{where} = {show(v)} must be {expect}")
        if lo is not None and hi is not None:
            rng = f"lie in {'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"
        elif lo is not None:
            rng = f"be {'>' if lo_open else '>='} {lo:g}"
        else:
            rng = f"be {'<' if hi_open else '<='} {hi:g}"
        raise error(f"{where} = {show(v)} must {rng}")
    return v if integer else float(v)


def _finite(v) -> bool:
    try:
        return math.isfinite(v)
    except OverflowError:       # an int beyond the float range
        return False


def check_choice(where: str, v, choices, hint: str = "", error=StructureError):
    """v if it is one of the strings ``choices``; the message lists them (and ``hint``)."""
    if not isinstance(v, str) or v not in choices:
        listed = ", ".join(f'"{c}"' for c in choices)
        raise error(f"{where} = {show(v)}: use one of {listed}" + (f" ({hint})" if hint else ""))
    return v


def _list(where: str, v, what: str):
    if not isinstance(v, (list, tuple)):
        raise StructureError(f"{where} = {show(v)} must be a list of {what}")
    return v


def _vec(where, v, n, lo=None, quantity=None):
    """A list of ``n`` numbers >= lo, each in the plausible range of ``quantity`` (if given)."""
    if not isinstance(v, (list, tuple)) or len(v) != n:
        raise StructureError(f"{where} = {show(v)} must be a list of {n} numbers")
    out = tuple(check_number(f"{where}[{i}]", x, lo, lo_open=False) for i, x in enumerate(v))
    for i, x in enumerate(out if quantity else ()):
        _plausible(f"{where}[{i}]", x, quantity)
    return out


def _plausible(where, v, quantity):
    """v, refused (StructureError) outside the plausible range of ``quantity`` (uplift_common.ranges)."""
    return check_plausible(where, v, quantity, StructureError)


def _count(where, items, most, what):
    """Refuse a list longer than ``most`` before parsing its items (a file of absurd size)."""
    if isinstance(items, (list, tuple)):
        check_count(where, len(items), most, what, StructureError)
    return items


def _id(where, v):
    return check_number(where, v, integer=True, expect="an integer node id")


# ---- [structure] -----------------------------------------------------------------------------

@dataclass(frozen=True)
class RaftSpec:
    """The raft master node (at the raft centre, z = 0), raft mass kg and rotary inertias
    (Ixx, Iyy, Izz) kg m^2; its interface points are the scene's foundation mesh (build_model)."""
    node: int
    m: float = 0.0
    inertia: tuple = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class StructureSpec:
    """A validated [structure] table: nodes, beams, masses, springs (records of structure.model),
    the raft and the damping; ``model`` names the built-in model it was loaded from (None: inline).
    Node ids are unique, every reference is a known node, every node is connected to the raft."""
    nodes: tuple
    beams: tuple
    raft: RaftSpec
    masses: tuple = ()
    springs: tuple = ()
    damping: Damping = field(default_factory=Damping)
    model: str | None = None

    @property
    def node_names(self) -> tuple:
        """Names of the named nodes (the ones results can be asked for)."""
        return tuple(n.name for n in self.nodes if n.name)

    def as_table(self, inline: bool = False) -> dict:
        """The [structure] table (plain lists, numbers and strings: TOML/JSON-ready) that
        parse_structure reads back into an equal spec; ``inline``: a built-in model written
        out node by node (for a reader without the built-in data, an exported FMU)."""
        damping = _damping_table(self.damping)
        if self.model is not None and not inline:
            return {"model": self.model, **({"damping": damping} if damping else {})}
        drop_none = lambda d: {k: v for k, v in d.items() if v is not None}
        return {
            "nodes": [drop_none({"id": n.id, "xyz": list(n.xyz), "name": n.name}) for n in self.nodes],
            "beams": [drop_none({"nodes": list(b.nodes), "E": b.E, "G": b.G, "A": b.A, "Iy": b.Iy, "Iz": b.Iz,
                                 "J": b.J, "Asy": b.Asy, "Asz": b.Asz, "rho": b.rho}) for b in self.beams],
            "masses": [{"node": m.node, "m": m.m, "inertia": list(m.inertia)} for m in self.masses],
            "springs": [drop_none({"node": s.node, "k": list(s.k), "node2": s.node2}) for s in self.springs],
            "raft": {"node": self.raft.node, "m": self.raft.m, "inertia": list(self.raft.inertia)},
            **({"damping": damping} if damping else {}),
        }


def _damping_table(d: Damping) -> dict:
    if d.kind == "modal":
        return {"modal": d.ratio}
    if d.kind == "rayleigh":
        return {"rayleigh": [d.a0, d.a1]}
    return {}


def builtin_spec(name: str) -> dict:
    """The [structure] table of a built-in model (structure/data/<name>.toml)."""
    if not isinstance(name, str) or name not in BUILTIN_MODELS:
        raise StructureError(f"structure.model = {show(name)} is not a built-in model; "
                             f"choose one of {BUILTIN_MODELS} or give nodes/beams inline")
    try:        # imported here: a host Python 3.10 running an FMU needs tomli only for this
        import tomllib
    except ModuleNotFoundError:  # Python < 3.11
        import tomli as tomllib
    text = resources.files(f"{__package__}.data").joinpath(f"{name}.toml").read_text()
    return tomllib.loads(text)["structure"]


def _damping(path, d):
    if d is None:
        return Damping()
    check_keys(d, ("modal", "rayleigh"), path)
    if len(d) != 1:
        raise StructureError(f"{path} must have exactly one of 'modal' or 'rayleigh'")
    if "modal" in d:
        r = check_number(f"{path}.modal", d["modal"], 0.0, 1.0, lo_open=False, hi_open=True,
                         expect="a ratio in [0, 1), e.g. 0.07 for 7 %")
        return Damping("modal", ratio=r)
    a0, a1 = _vec(f"{path}.rayleigh", d["rayleigh"], 2, 0.0)
    _plausible(f"{path}.rayleigh[0]", a0, "rayleigh_a0")
    _plausible(f"{path}.rayleigh[1]", a1, "rayleigh_a1")
    return Damping("rayleigh", a0=a0, a1=a1)


def parse_structure(table: dict) -> StructureSpec:
    """The validated StructureSpec of a scene's [structure] table. model = "reactor" loads the
    built-in model; it may be combined with ``damping`` only (to override the built-in damping)."""
    p = "structure"
    if not isinstance(table, dict):
        raise StructureError(f"{p} must be a table, got {show(table)}")
    model = None
    if "model" in table:
        inline = sorted(set(table) & set(STRUCTURE_KEYS) - {"damping"})
        if inline:
            raise StructureError(f"{p}.{inline[0]} cannot be combined with {p}.model (a built-in "
                                 f"model); only {p}.damping may override it")
        check_keys(table, ("model", "damping"), p)
        model = table["model"]
        base = dict(builtin_spec(model))
        base.pop("model", None)
        if "damping" in table:
            base["damping"] = table["damping"]
        table = base
    check_keys(table, STRUCTURE_KEYS, p, required=("nodes", "beams", "raft"))
    nodes, ids = [], set()
    if not isinstance(table["nodes"], list) or not table["nodes"]:
        raise StructureError(f"{p}.nodes must be a non-empty list of {{ id, xyz, name }} tables")
    _count(f"{p}.nodes", table["nodes"], MAX_STRUCTURE_NODES, "nodes")
    for key in ("beams", "masses", "springs"):
        _count(f"{p}.{key}", table.get(key), MAX_STRUCTURE_ELEMENTS, key)
    for i, n in enumerate(table["nodes"]):
        q = f"{p}.nodes[{i}]"
        check_keys(n, ("id", "xyz", "name"), q, required=("id", "xyz"))
        nid = _id(f"{q}.id", n["id"])
        if nid in ids:
            raise StructureError(f"{q}.id = {nid} is used twice: node ids must be unique")
        ids.add(nid)
        name = n.get("name")
        if name is not None and (not isinstance(name, str) or not name):
            raise StructureError(f"{q}.name = {show(name)} must be a non-empty string")
        nodes.append(Node(nid, _vec(f"{q}.xyz", n["xyz"], 3, quantity="coordinate"), name))
    names = [n.name for n in nodes if n.name]
    if len(set(names)) != len(names):
        raise StructureError(f"{p}.nodes: names must be unique, got {names}")

    def ref(q, v):
        v = _id(q, v)
        if v not in ids:
            raise StructureError(f"{q} = {v} is not a node id; known ids: {sorted(ids)}")
        return v

    xyz = {n.id: n.xyz for n in nodes}
    beams = []
    for i, b in enumerate(_list(f"{p}.beams", table["beams"], "tables")):
        q = f"{p}.beams[{i}]"
        check_keys(b, ("nodes", "E", "G", "A", "Iy", "Iz", "J", "Asy", "Asz", "rho"), q,
                   required=("nodes", "E", "G", "A", "Iy", "Iz", "J"))
        if not isinstance(b["nodes"], list) or len(b["nodes"]) != 2:
            raise StructureError(f"{q}.nodes = {show(b['nodes'])} must be a list of 2 node ids")
        n1, n2 = ref(f"{q}.nodes[0]", b["nodes"][0]), ref(f"{q}.nodes[1]", b["nodes"][1])
        if np.allclose(xyz[n1], xyz[n2]):
            raise StructureError(f"{q}.nodes = {[n1, n2]} has zero length")
        vals = {k: check_number(f"{q}.{k}", b[k], 0.0) for k in ("E", "G", "A", "Iy", "Iz", "J")}
        for k in ("Asy", "Asz"):
            vals[k] = check_number(f"{q}.{k}", b[k], 0.0) if k in b else None
        vals["rho"] = check_number(f"{q}.rho", b["rho"], 0.0, lo_open=False) if "rho" in b else 0.0
        for k, v in vals.items():
            if v is not None:
                _plausible(f"{q}.{k}", v, BEAM_RANGES[k])
        beams.append(Beam((n1, n2), **vals))
    masses = []
    for i, m in enumerate(_list(f"{p}.masses", table.get("masses", []), "tables")):
        q = f"{p}.masses[{i}]"
        check_keys(m, ("node", "m", "inertia"), q, required=("node", "m"))
        masses.append(Mass(ref(f"{q}.node", m["node"]),
                           _plausible(f"{q}.m", check_number(f"{q}.m", m["m"], 0.0, lo_open=False), "mass"),
                           _vec(f"{q}.inertia", m.get("inertia", [0.0, 0.0, 0.0]), 3, 0.0, "rotary_inertia")))
    springs = []
    for i, s in enumerate(_list(f"{p}.springs", table.get("springs", []), "tables")):
        q = f"{p}.springs[{i}]"
        check_keys(s, ("node", "k", "node2"), q, required=("node", "k"))
        n2 = ref(f"{q}.node2", s["node2"]) if "node2" in s else None
        springs.append(Spring(ref(f"{q}.node", s["node"]), _vec(f"{q}.k", s["k"], 6, 0.0, "stiffness"), n2))
    q = f"{p}.raft"
    r = table["raft"]
    check_keys(r, ("node", "m", "inertia"), q, required=("node",))
    rn = ref(f"{q}.node", r["node"])
    if abs(xyz[rn][2]) > 1e-9:
        raise StructureError(f"{q}.node = {rn} is at z = {xyz[rn][2]:g}: the raft master node must "
                             "lie on z = 0 at the raft centre")
    raft = RaftSpec(rn, _plausible(f"{q}.m", check_number(f"{q}.m", r.get("m", 0.0), 0.0, lo_open=False), "mass"),
                    _vec(f"{q}.inertia", r.get("inertia", [0.0, 0.0, 0.0]), 3, 0.0, "rotary_inertia"))
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
    return StructureSpec(tuple(nodes), tuple(beams), raft, tuple(masses), tuple(springs),
                         _damping(f"{p}.damping", table.get("damping")), model)


def build_model(spec: StructureSpec, xy, area) -> StructureModel:
    """StructureModel of a validated spec on the interface nodes xy (N, 2) m, area (N,) m^2
    (about the raft centre)."""
    try:
        raft = Raft(spec.raft.node, np.asarray(xy, float), area, spec.raft.m, spec.raft.inertia)
    except StructureError as exc:
        raise StructureError(f"structure.raft: {exc}") from None
    return StructureModel(spec.nodes, spec.beams, spec.masses, raft, spec.springs, spec.damping)


def model_from_spec(table: dict, xy, area) -> StructureModel:
    """StructureModel from a scene's [structure] table: build_model(parse_structure(table), xy, area)."""
    return build_model(parse_structure(table), xy, area)


# ---- [soil] winkler, [contact] ----------------------------------------------------------------

def winkler_moduli(table: dict, where: str = "soil.winkler") -> tuple:
    """(kv, kh, cv, ch) from { kv, kh, cv = 0, ch = 0 }: subgrade moduli N/m^3 (kv > 0, kh >= 0)
    and dashpots N s/m^3 (>= 0) per unit area."""
    check_keys(table, WINKLER_MODULI, where, required=("kv", "kh"))
    return tuple(_plausible(f"{where}.{k}", check_number(f"{where}.{k}", table.get(k, 0.0), 0.0, lo_open=k == "kv"),
                            "subgrade_modulus" if k in ("kv", "kh") else "subgrade_damping")
                 for k in WINKLER_MODULI)


def winkler_from_moduli(moduli, xy, area) -> WinklerSoil:
    """WinklerSoil from subgrade moduli (kv, kh, cv, ch) (N/m^3, N s/m^3; see winkler_moduli),
    multiplied by each node's tributary area (N,) m^2 at xy (N, 2) m."""
    if not isinstance(moduli, (list, tuple)) or len(moduli) != 4:
        raise StructureError(f"Winkler moduli = {show(moduli)} must be the 4 numbers (kv, kh, cv, ch)")
    kv, kh, cv, ch = winkler_moduli(dict(zip(WINKLER_MODULI, moduli, strict=True)))
    area = np.asarray(area, float)
    return WinklerSoil(xy, kv * area, kh * area, cv * area, ch * area)


def winkler_from_spec(table: dict, xy, area) -> WinklerSoil:
    """WinklerSoil from [soil] winkler = { kv, kh, cv, ch } (a {"winkler": {...}} wrapper is
    accepted too): winkler_from_moduli(winkler_moduli(table), xy, area)."""
    if isinstance(table, dict) and set(table) == {"winkler"}:
        table = table["winkler"]
    return winkler_from_moduli(winkler_moduli(table), xy, area)


def contact_from_spec(table: dict | None) -> ContactSettings:
    """ContactSettings from [contact] { enabled = true, penalty = "auto" | N/m per node,
    auto_factor = 1e4, precheck = true } (auto_factor: the "auto" penalty over the soil's local
    static stiffness) (precheck = false forces the nonlinear contact iterations even when a
    linear pre-check would show that the contact never opens; see ContactSettings)."""
    p = "contact"
    if table is None:
        return ContactSettings()
    check_keys(table, CONTACT_KEYS, p)
    en, pre = table.get("enabled", True), table.get("precheck", True)
    for key, value in (("enabled", en), ("precheck", pre)):
        if not isinstance(value, bool):
            raise StructureError(f"{p}.{key} = {show(value)} must be true or false")
    pen = table.get("penalty", "auto")
    if isinstance(pen, str):
        if pen != "auto":
            raise StructureError(f"{p}.penalty = {show(pen)} must be \"auto\" or a stiffness in N/m per node")
    else:
        pen = _plausible(f"{p}.penalty", check_number(f"{p}.penalty", pen, 0.0), "penalty")
    factor = _plausible(f"{p}.auto_factor", check_number(f"{p}.auto_factor", table.get("auto_factor", AUTO_FACTOR), 0.0),
                        "penalty_factor")
    return ContactSettings(enabled=en, penalty=pen, auto_factor=factor, precheck=pre)


def contact_table(settings: ContactSettings) -> dict:
    """The [contact] table of settings (contact_from_spec reads it back; the Newton tolerances,
    which are not scene keys, keep their defaults)."""
    return {"enabled": settings.enabled, "penalty": settings.penalty, "auto_factor": settings.auto_factor,
            "precheck": settings.precheck}

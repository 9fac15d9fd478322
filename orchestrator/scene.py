"""Scenes: one TOML file describing soil, foundation, impedance sweep, structure, contact,
motion, analysis and outputs, one section per part.

Every section is validated when the scene is loaded: an unknown key is an error (a typo must
not be ignored silently) and each message names the key at fault and what would fix it.
Relative paths are relative to the scene file. Built-in scenes ship as package data
(``orchestrator/scenes/*.toml``) and are loaded by name: ``load_scene("disk-halfspace")``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

try:
    import tomllib
except ModuleNotFoundError:  # Python < 3.11
    import tomli as tomllib

import numpy as np

from soil_impedance.mesh import InterfaceMesh, MeshError, circle_mesh, read_nodes_csv, rectangle_mesh
from soil_impedance.profile import DAMPING_MODELS, Layer, Material, SoilError, SoilProfile


class SceneError(ValueError):
    """An invalid scene; the message names the key at fault and how to fix it."""


SECTIONS = ("soil", "foundation", "impedance", "structure", "contact", "motion", "analysis", "output")


@dataclass(frozen=True, eq=False)
class Scene:
    """A validated scene. Sections owned by later stages are kept as plain tables
    (already checked for unknown keys where this module knows them)."""

    name: str
    base_dir: Path
    profile: SoilProfile
    mesh: InterfaceMesh
    contact_kind: str                       # "welded" or "relaxed" (soil-raft interface of the BEM)
    frequencies_hz: np.ndarray
    sections: dict = field(default_factory=dict)   # raw tables: structure, contact, motion, analysis, output, soil.winkler

    def section(self, name: str) -> dict:
        return self.sections.get(name, {})


def builtin_scenes() -> list[str]:
    return sorted(p.name[:-5] for p in resources.files("orchestrator.scenes").iterdir()
                  if p.name.endswith(".toml"))


def load_scene(spec: str | Path) -> Scene:
    """Load a scene from a TOML path or a built-in name (see ``builtin_scenes()``)."""
    path = Path(spec)
    if path.suffix == ".toml" or path.exists():
        if not path.is_file():
            raise SceneError(f"scene file {str(path)!r} does not exist; give a path to a .toml file "
                             f"or a built-in scene name ({', '.join(builtin_scenes())})")
        text, base, name = path.read_text(), path.resolve().parent, path.stem
    else:
        if str(spec) not in builtin_scenes():
            raise SceneError(f"unknown scene {str(spec)!r}: not a file and not a built-in scene "
                             f"({', '.join(builtin_scenes())})")
        res = resources.files("orchestrator.scenes") / f"{spec}.toml"
        text, base, name = res.read_text(), Path(str(res)).parent, str(spec)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"scene {name!r} is not valid TOML: {exc}") from None
    return scene_from_dict(data, base_dir=base, name=name)


def scene_from_dict(data: dict, base_dir: Path | str = ".", name: str = "scene") -> Scene:
    """Validate a scene given as nested dicts (the parsed TOML)."""
    _check_keys(data, SECTIONS, "scene", what="section")
    base_dir = Path(base_dir)
    try:
        soil = dict(data.get("soil") or _missing("soil", "halfspace = { vs = ..., nu = ..., rho = ... }"))
        _check_keys(soil, ("layers", "halfspace", "winkler", "damping_model"), "soil")
        profile = _profile(soil)
        foundation = dict(data.get("foundation") or _missing("foundation", 'shape = "circle", radius = ..., element_size = ...'))
        mesh, contact_kind = _foundation(foundation, base_dir)
    except (SoilError, MeshError) as exc:
        raise SceneError(str(exc)) from None
    freqs = _frequencies(dict(data.get("impedance", {})))
    sections = {k: dict(data.get(k, {})) for k in ("structure", "contact", "motion", "analysis", "output")}
    if "winkler" in soil:
        sections["winkler"] = soil["winkler"]
    return Scene(name=name, base_dir=base_dir, profile=profile, mesh=mesh, contact_kind=contact_kind,
                 frequencies_hz=freqs, sections=sections)


def _missing(section: str, hint: str):
    raise SceneError(f"the scene has no [{section}] section; add one, e.g. [{section}] {hint}")


def _check_keys(table: dict, allowed, where: str, what: str = "key"):
    if not isinstance(table, dict):
        raise SceneError(f"{where} must be a table, got {table!r}")
    for key in table:
        if key not in allowed:
            close = [a for a in allowed if a.lower() == key.lower() or _near(a, key)]
            hint = f"did you mean {close[0]!r}? " if close else ""
            raise SceneError(f"unknown {what} {where}.{key}: {hint}allowed: {', '.join(allowed)}")


def _near(a: str, b: str) -> bool:
    """One edit apart (a typo)."""
    if abs(len(a) - len(b)) > 1:
        return False
    if len(a) == len(b):
        return sum(x != y for x, y in zip(a, b)) <= 1 or sorted(a) == sorted(b)
    s, l = sorted((a, b), key=len)
    return any(l[:i] + l[i + 1:] == s for i in range(len(l)))


MATERIAL_KEYS = ("vs", "vp", "nu", "rho", "damping")


def _material(table, where: str, cls=Material, extra=(), damping_model="hysteretic"):
    _check_keys(table, MATERIAL_KEYS + tuple(extra), where)
    for key in ("vs", "rho"):
        if key not in table:
            raise SceneError(f"{where}.{key} is missing (give vs in m/s and rho in kg/m^3)")
    for key, value in table.items():
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            raise SceneError(f"{where}.{key} = {value!r} must be a number")
    return cls(name=where, damping_model=damping_model, **{k: float(v) for k, v in table.items()})


def _profile(soil: dict) -> SoilProfile:
    if "halfspace" not in soil:
        raise SceneError("soil.halfspace is missing: the profile needs a half-space below its layers, "
                         "e.g. halfspace = { vs = 500.0, nu = 0.33, rho = 2000.0 }")
    model = soil.get("damping_model", "hysteretic")
    if model not in DAMPING_MODELS:
        raise SceneError(f"soil.damping_model = {model!r}: use one of "
                         + ", ".join(f'"{m}"' for m in DAMPING_MODELS)
                         + " (hysteretic: G (1 + 2i damping) at every frequency, the default; causal: "
                         "constant Q with a 0.05 Hz cut-off, vs given at 1 Hz)")
    layers = soil.get("layers", [])
    if not isinstance(layers, list):
        raise SceneError("soil.layers must be a list of tables { thickness, vs, nu or vp, rho, damping }")
    out = []
    for i, t in enumerate(layers):
        where = f"soil.layers[{i}]"
        if "thickness" not in t:
            raise SceneError(f"{where}.thickness is missing (layer thickness in m)")
        out.append(_material(t, where, cls=Layer, extra=("thickness",), damping_model=model))
    return SoilProfile(tuple(out), _material(soil["halfspace"], "soil.halfspace", damping_model=model))


def _foundation(table: dict, base_dir: Path):
    shape = table.get("shape", "circle")
    keys = {"circle": ("radius", "element_size"), "rectangle": ("lx", "ly", "element_size"),
            "nodes": ("file",)}
    if shape not in keys:
        raise SceneError(f"foundation.shape = {shape!r}: use \"circle\", \"rectangle\" or \"nodes\"")
    _check_keys(table, ("shape", "contact") + keys[shape], "foundation")
    contact = table.get("contact", "welded")
    if contact not in ("welded", "relaxed"):
        raise SceneError(f"foundation.contact = {contact!r}: use \"welded\" (default, all traction "
                         "components) or \"relaxed\" (no shear under normal loads)")
    for key in keys[shape]:
        if key not in table:
            raise SceneError(f"foundation.{key} is missing for shape = {shape!r} (needs {', '.join(keys[shape])})")
    if shape == "circle":
        mesh = circle_mesh(table["radius"], table["element_size"])
    elif shape == "rectangle":
        mesh = rectangle_mesh(table["lx"], table["ly"], table["element_size"])
    else:
        mesh = read_nodes_csv(base_dir / table["file"])
    return mesh, contact


def _frequencies(table: dict) -> np.ndarray:
    _check_keys(table, ("frequencies_hz", "range_hz"), "impedance")
    if "frequencies_hz" in table and "range_hz" in table:
        raise SceneError("impedance: give frequencies_hz or range_hz, not both")
    if "range_hz" in table:
        r = table["range_hz"]
        if (not isinstance(r, list) or len(r) != 3 or not all(isinstance(v, (int, float)) for v in r)
                or int(r[2]) != r[2]):
            raise SceneError(f"impedance.range_hz = {r!r} must be [fmin, fmax, count] (count an integer)")
        fmin, fmax, count = float(r[0]), float(r[1]), int(r[2])
        if not (0 <= fmin < fmax) or count < 2:
            raise SceneError(f"impedance.range_hz = {r!r} needs 0 <= fmin < fmax and count >= 2")
        return np.linspace(fmin, fmax, count)
    freqs = table.get("frequencies_hz", [0.0, 2.0, 4.0])
    if not isinstance(freqs, list) or not freqs or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in freqs):
        raise SceneError(f"impedance.frequencies_hz = {freqs!r} must be a non-empty list of numbers in Hz")
    f = np.asarray(freqs, float)
    if np.any(f < 0) or np.any(np.diff(f) <= 0):
        raise SceneError(f"impedance.frequencies_hz = {freqs!r} must be >= 0 and strictly increasing")
    return f

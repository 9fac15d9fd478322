"""Scenes for tests as dicts: the small tower (``tower``), changed section by section, and
written as TOML (``write_scene``) for the command line."""
from __future__ import annotations

import copy
from pathlib import Path

from orchestrator.scene_file import dumps

#: a 20 m stick (one beam, a 2000 t top mass) on a 10 m square raft over Winkler springs (or the
#: half-space), a 3 s synthetic motion at 0.3 g, the winkler route at 10 ms: runs in about a second
TOWER = {
    "soil": {"halfspace": {"vs": 500.0, "nu": 0.3, "rho": 2000.0}, "winkler": {"kv": 5.0e7, "kh": 4.0e7}},
    "foundation": {"shape": "rectangle", "lx": 10.0, "ly": 10.0, "element_size": 2.5},
    "structure": {
        "nodes": [{"id": 1, "xyz": [0, 0, 0]}, {"id": 2, "xyz": [0, 0, 20], "name": "top"}],
        "beams": [{"nodes": [1, 2], "E": 3e10, "G": 1.25e10, "A": 10.0, "Iy": 20.0, "Iz": 20.0, "J": 40.0}],
        "masses": [{"node": 2, "m": 2.0e6, "inertia": [0, 0, 0]}],
        "raft": {"node": 1, "m": 1.0e6, "inertia": [1e7, 1e7, 2e7]},
        "damping": {"modal": 0.05},
    },
    "contact": {"enabled": True},
    "motion": {"kind": "synthetic", "pga_g": 0.3, "duration_s": 3.0, "seed": 2},
    "analysis": {"routes": ["winkler"], "dt": 0.01},
    "output": {"nodes": ["top"]},
}


def tower(**sections) -> dict:
    """The small tower scene with ``sections`` changed: a dict updates that section key by key
    (a key set to None is removed), None removes the section. E.g.
    ``tower(soil={"halfspace": None}, motion={"pga_g": 0.2}, output=None)``."""
    return changed(TOWER, **sections)


def changed(scene: dict, **sections) -> dict:
    """A deep copy of ``scene`` with ``sections`` changed as ``tower`` does."""
    out = copy.deepcopy(scene)
    for name, change in sections.items():
        if change is None:
            out.pop(name, None)
            continue
        section = out.setdefault(name, {})
        for key, value in change.items():
            if value is None:
                section.pop(key, None)
            else:
                section[key] = copy.deepcopy(value)
    return out


def edited(data: dict, path, value) -> dict:
    """A deep copy of the nested dicts and lists ``data`` with the entry at ``path`` (keys and
    indices) set to ``value``, or removed when ``value`` is KeyError."""
    out = copy.deepcopy(data)
    node = out
    for key in path[:-1]:
        node = node[key]
    if value is KeyError:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return out


def toml_text(scene: dict) -> str:
    """``scene`` ({section: {key: value}}) as TOML, as ``uplift scene`` writes it (one [section]
    table each, values inline, floats exact)."""
    return dumps(scene)


def write_scene(path, scene: dict, extra: str = "") -> str:
    """Write ``scene`` as TOML to ``path`` (a file, or a folder: ``scene.toml`` in it), with the
    TOML text ``extra`` appended; returns the file's path as a string (for the command line)."""
    path = Path(path)
    if path.is_dir():
        path = path / "scene.toml"
    path.write_text(toml_text(scene) + extra)
    return str(path)


#: the reactor on a coarse raft (21 nodes) over rock, a 1.5 s synthetic motion at 0.3 g, the
#: monolithic route at 5 ms (the ensemble tests' scene)
SMALL_REACTOR = {
    "soil": {"halfspace": {"vs": 1600.0, "nu": 0.3, "rho": 2500.0}},
    "foundation": {"shape": "circle", "radius": 20.0, "element_size": 8.0},
    "impedance": {"range_hz": [0.0, 25.0, 26]},
    "structure": {"model": "reactor", "damping": {"modal": 0.07}},
    "contact": {"enabled": True},
    "motion": {"kind": "synthetic", "pga_g": 0.3, "duration_s": 1.5, "seed": 3},
    "analysis": {"routes": ["monolithic"], "dt": 0.005},
    "output": {"nodes": ["top_outer", "internals_37m"]},
}


def small_reactor(**sections) -> dict:
    """SMALL_REACTOR with ``sections`` changed as ``tower`` does."""
    return changed(SMALL_REACTOR, **sections)


def export_tower(**sections) -> dict:
    """The tower on an undamped half-space (ν = 1/3), 6 frequencies to 10 Hz, bonded, 1 s at
    0.2 g, the scene's default routes: the export and cross-check tests' scene."""
    return changed(tower(soil={"halfspace": {"vs": 500.0, "nu": 1 / 3, "rho": 2000.0, "damping": 0.0},
                               "winkler": None},
                         foundation={"element_size": 5.0}, impedance={"range_hz": [0.0, 10.0, 6]},
                         contact=None, motion={"pga_g": 0.2, "duration_s": 1.0, "seed": None},
                         analysis={"routes": None}), **sections)

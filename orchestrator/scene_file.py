"""Scenes as TOML text: the commented copy of a built-in scene (``uplift scene NAME``) and the
scene of a run as it ran (stored in the results file by ``uplift run``).

A built-in scene (``orchestrator/scenes/NAME.toml``) is written as it is shipped, comments
included (they say what each key means and its unit), under a header naming the command that
wrote it. The copy runs from any folder: the files it names (a foundation's nodes CSV or mesh
file, record files) are copied beside the written file (``builtin_scene_text(name, folder)`` says which),
or, printed to stdout, named by absolute path.

``scene_toml(scene)`` writes a loaded scene back as TOML (its ``Scene.source``: the keys as read,
the command line's overrides applied, file paths made absolute), without comments but with a
header listing the overrides: ``load_scene`` of that text gives the scene that ran.
"""
from __future__ import annotations

import copy
import json
import math
import re
from importlib import resources
from pathlib import Path

from orchestrator.scene_base import SceneError, builtin_scenes, tomllib

#: the keys of a scene that name a file (relative to the scene file): (section, key); a record's
#: ``components`` is a table {axis: file}; ``foundation.mesh`` a finite-element raft mesh
PATH_KEYS = (("foundation", "file"), ("foundation", "mesh"), ("motion", "file"), ("motion", "components"))


def _paths(data: dict) -> list:
    """The file names a parsed scene refers to, as written (strings)."""
    out = []
    for section, key in PATH_KEYS:
        value = data.get(section, {}).get(key) if isinstance(data.get(section), dict) else None
        if isinstance(value, str):
            out.append(value)
        elif isinstance(value, dict):
            out.extend(v for v in value.values() if isinstance(v, str))
    return list(dict.fromkeys(out))


def builtin_scene_text(name: str, folder: Path | None = None) -> tuple[str, dict]:
    """(text, companions) of the built-in scene ``name`` written as a file in ``folder`` (None:
    printed, no folder): the shipped TOML with its comments under a header; companions
    {file name in folder: source Path} are the files it names, to copy into ``folder`` (the text
    then names them by those names); without a folder the text names them by absolute path."""
    if name not in builtin_scenes():
        hint = (f"; {name!r} is a file: it is already a scene, `uplift run {name}` runs it" if Path(name).is_file()
                else "")
        raise SceneError(f"unknown built-in scene {name!r}: `uplift scene` writes one of {', '.join(builtin_scenes())}"
                         + hint)
    res = resources.files("orchestrator.scenes") / f"{name}.toml"
    text, base = res.read_text(encoding="utf-8"), Path(str(res)).parent
    renamed, companions = {}, {}
    for rel in _paths(tomllib.loads(text)):
        source = (base / rel).resolve()
        if folder is None:
            renamed[rel] = str(source)
            continue
        stem, suffix, k = Path(rel).stem, Path(rel).suffix, 1
        target = Path(rel).name
        while target in companions:                    # two files of one name in different folders
            k += 1
            target = f"{stem}_{k}{suffix}"
        companions[target] = source
        renamed[rel] = target
    header = (f"# Written by `uplift scene {name}`: the built-in scene {name!r} as shipped; every command gives\n"
              f"# the same on this file as on the name (`uplift run FILE` equals `uplift run {name}`).\n")
    if companions:
        header += f"# The files it names were copied beside it: {', '.join(companions)}.\n"
    return header + _rename_strings(text, renamed), companions


def _rename_strings(text: str, renamed: dict) -> str:
    """``text`` with every TOML string whose value is a key of ``renamed`` replaced by a string
    of the new value (comments and layout kept)."""
    if not renamed:
        return text

    def swap(match):
        try:
            value = tomllib.loads(f"v = {match.group(0)}")["v"]
        except tomllib.TOMLDecodeError:
            return match.group(0)
        return _string(renamed[value]) if value in renamed else match.group(0)
    return re.sub(r'"(?:[^"\\\n]|\\.)*"|\'[^\'\n]*\'', swap, text)


# ---- a scene as TOML ------------------------------------------------------------------------------

def scene_toml(scene) -> str:
    """The scene as TOML text that ``load_scene`` reads back into the same scene: its source
    (the keys as read, the overrides applied) with file paths made absolute, under a header that
    names the scene and lists the command line's overrides."""
    if scene.source is None:
        raise ValueError(f"scene {scene.name!r} was not loaded from TOML (Scene.source is None)")
    data = copy.deepcopy(scene.source)
    for section, key in PATH_KEYS:
        table = data.get(section)
        if isinstance(table, dict) and isinstance(table.get(key), str):
            table[key] = str((scene.base_dir / table[key]).resolve())
        elif isinstance(table, dict) and isinstance(table.get(key), dict):
            table[key] = {a: str((scene.base_dir / f).resolve()) for a, f in table[key].items()}
    lines = [f"# scene {scene.name!r} as it ran (file paths made absolute)"]
    lines += [f"# override: {o['option']} {o['value']:g} sets {o['key']} = {_value(o['now'])} (was {_value(o['was'])})"
              for o in scene.overrides]
    return "\n".join(lines) + "\n\n" + dumps(data)


def dumps(data: dict) -> str:
    """TOML text of a scene's parsed data: one [section] per table of the top level, every value
    inline (arrays, inline tables); floats written exactly (``repr``: read back bit for bit)."""
    out = []
    for section, table in data.items():
        if not isinstance(table, dict):
            raise ValueError(f"{section}: the top level of a scene holds sections (tables) only")
        out.append(f"[{_key(section)}]")
        out.extend(f"{_key(k)} = {_value(v)}" for k, v in table.items())
        out.append("")
    return "\n".join(out)


def _key(key: str) -> str:
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else _string(key)


def _string(text: str) -> str:
    """A TOML basic string (JSON's escapes are TOML's; DEL must be escaped too)."""
    return json.dumps(text).replace("\x7f", "\\u007f")


def _value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(v) if math.isfinite(v) else ("nan" if math.isnan(v) else ("inf" if v > 0 else "-inf"))
    if isinstance(v, str):
        return _string(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{_key(k)} = {_value(x)}" for k, x in v.items()) + " }" if v else "{}"
    raise ValueError(f"cannot write {v!r} ({type(v).__name__}) as TOML")

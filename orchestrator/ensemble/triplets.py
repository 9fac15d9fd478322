"""The components of a record folder (one record, e.g. a PEER triplet): told by a
``components.toml`` in the folder, else recognised from PEER's file names.

``components.toml`` maps components to file names in the folder (any non-empty subset of x,
y, z; it wins over the names, and the folder's other files are ignored)::

    x = "RSN6_IMPVALL.I_I-ELC270.AT2"
    y = "RSN6_IMPVALL.I_I-ELC180.AT2"
    z = "RSN6_IMPVALL.I_I-ELC-UP.AT2"

Without it every record file of the folder (a suffix of ``RECORD_SUFFIXES``; PEER's ``.VT2``
and ``.DT2`` velocities and displacements and its search-result tables are not records) is
one component, told by the end of its name without the suffix (case-insensitive; ``-``
``_`` ``.`` are separators, required before a one-letter code):

- vertical, z: ``UP``, ``DWN``, ``DOWN``, ``UD``, ``VER``, ``VERT``, ``-V``, ``-Z``
  (``RSN9_BORREGO_B-ELC-UP``, ``RSN1_HELENA.A_A-HMCDWN``, ``RSN1485_CHICHI_TCU045-V``,
  K-NET/KiK-net ``...UD``); the values are used as they are in the file, z positive up;
- horizontals by name: ``H1``, ``EW``, ``-E``, ``-L``, ``-L1`` on x and ``H2``, ``NS``,
  ``-N``, ``-T``, ``-T1`` on y (east on x, north on y: x, y, z right-handed; longitudinal on
  x, transverse on y);
- horizontals by azimuth (degrees clockwise from north): three digits, ``000`` to ``360``
  (``RSN6_IMPVALL.I_I-ELC180``, ``RSN766_LOMAP_G02090``), or a quadrant bearing ``N10W``,
  ``S80E``. Two azimuths must be at right angles: x is the one 90° clockwise of the other
  (``090`` on x and ``000`` on y, as east and north); one alone goes on x.

A folder resolves when each of its record files names one component and no component is
named twice (the two horizontals both by name or both by azimuth). Otherwise it is refused
(EnsembleError) with the folder, the file at fault and the fix: a ``components.toml``, or
the files given one by one (each a one-component record).
"""
from __future__ import annotations

import re
from pathlib import Path

try:
    import tomllib
except ModuleNotFoundError:  # Python < 3.11
    import tomli as tomllib

from uplift_common.errors import UserInputError
from orchestrator.motion import DIRECTIONS

#: the file of a record folder that tells its components (it wins over the file names)
COMPONENTS_FILE = "components.toml"
#: how the components of a folder were told without it
PEER_NAMES = "PEER names"
#: PEER component codes at the end of a file's stem (upper-cased): (pattern, component)
PEER_CODES = (
    (re.compile(r"(UP|DWN|DOWN|UD|VERT?|[-_.][VZ])$"), "z"),
    (re.compile(r"(H1|EW|[-_.](E|L1?))$"), "x"),
    (re.compile(r"(H2|NS|[-_.](N|T1?))$"), "y"),
)
_AZIMUTH = re.compile(r"(\d{3})$")
_BEARING = re.compile(r"([NS])(\d{1,2})([EW])$")


class EnsembleError(UserInputError):
    """Bad input to an ensemble (a record, a PGA, a seed, the cluster); the message names it."""


def peer_component(name: str):
    """The component a PEER file name codes (the name without its suffix): "x", "y", "z", an
    azimuth of a horizontal (degrees clockwise from north, in [0, 360)) or None."""
    stem = Path(name).stem.upper()
    for pattern, component in PEER_CODES:
        if pattern.search(stem):
            return component
    m = _BEARING.search(stem)
    if m:
        angle = int(m.group(2))
        if angle <= 90:
            base, sign = (0, 1) if m.group(1) == "N" else (180, -1)
            return float((base + sign * (angle if m.group(3) == "E" else -angle)) % 360)
    m = _AZIMUTH.search(stem)
    if m and int(m.group(1)) <= 360:
        return float(int(m.group(1)) % 360)
    return None


def folder_components(folder: Path, suffixes) -> tuple[dict, str]:
    """({axis: absolute Path} in x, y, z order, how they were told: "components.toml" or "PEER
    names") of the record folder ``folder``; ``suffixes``: the suffixes of record files (lower
    case). A folder that cannot be told raises EnsembleError naming it and the fix."""
    folder = Path(folder)
    if (folder / COMPONENTS_FILE).is_file():
        return _from_toml(folder), COMPONENTS_FILE
    files = sorted(f.resolve() for f in folder.iterdir() if f.is_file() and f.suffix.lower() in suffixes)
    if not files:
        raise EnsembleError(f"--records {str(folder)!r}: no record files in this folder (suffixes: "
                           f"{', '.join(suffixes)}); a folder holds the components of one record")
    named, azimuths = {}, {}
    for f in files:
        code = peer_component(f.name)
        if code is None:
            _refuse(folder, f"cannot tell the component of {f.name!r} from its name (PEER's end in e.g. "
                            "H1, H2, UP, -000, -090, -UP, -E, -N, -V)")
        if isinstance(code, float):
            azimuths[f] = code
        else:
            named.setdefault(code, []).append(f)
    for axis, fs in named.items():
        if len(fs) > 1:
            _refuse(folder, f"{' and '.join(repr(f.name) for f in fs)} both name the component {axis}")
    if azimuths and ({"x", "y"} & set(named)):
        _refuse(folder, f"horizontals named both by azimuth ({', '.join(f.name for f in azimuths)}) and by "
                        f"name ({', '.join(f.name for a in ('x', 'y') for f in named.get(a, ()))})")
    out = {axis: fs[0] for axis, fs in named.items()}
    out.update(_by_azimuth(folder, azimuths))
    return {a: out[a] for a in DIRECTIONS if a in out}, PEER_NAMES


def _by_azimuth(folder: Path, azimuths: dict) -> dict:
    """x and y of horizontals named by azimuth: one alone on x; two at right angles with x the
    one 90 degrees clockwise of y (as east and north)."""
    if len(azimuths) > 2:
        _refuse(folder, f"{len(azimuths)} horizontals by azimuth ({', '.join(f.name for f in azimuths)})")
    if len(azimuths) < 2:
        return dict(zip("x", azimuths))
    (f1, a1), (f2, a2) = azimuths.items()
    if abs((a1 - a2) % 360 - 90) < 1e-9:
        return {"x": f1, "y": f2}
    if abs((a2 - a1) % 360 - 90) < 1e-9:
        return {"x": f2, "y": f1}
    _refuse(folder, f"the horizontals {f1.name!r} ({a1:g} deg) and {f2.name!r} ({a2:g} deg) are not at "
                    "right angles")


def _refuse(folder: Path, why: str):
    raise EnsembleError(f"--records {str(folder)!r}: {why}: the folder's components cannot be told. Write "
                       f"{COMPONENTS_FILE} in it (x = \"FILE\", y = \"FILE\", z = \"FILE\": file names in the "
                       "folder, any of the three), or give the files themselves to run each as a one-component "
                       "record on [motion].direction")


def _from_toml(folder: Path) -> dict:
    path = folder / COMPONENTS_FILE
    try:
        table = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise EnsembleError(f"{path}: cannot read it as TOML: {exc} (e.g. x = \"H1.AT2\", z = \"UP.AT2\")") from None
    unknown = sorted(set(table) - set(DIRECTIONS))
    if unknown or not table:
        raise EnsembleError(f"{path}: {'unknown key ' + repr(unknown[0]) if unknown else 'no component'}; its keys are "
                           "the components x, y, z (horizontal, horizontal, vertical up), each a file name in the "
                           "folder, e.g. x = \"H1.AT2\"")
    out = {}
    for axis in DIRECTIONS:
        if axis not in table:
            continue
        name = table[axis]
        if not isinstance(name, str) or not name:
            raise EnsembleError(f"{path}: {axis} = {name!r} must be a file name in the folder (a string)")
        f = (folder / name).resolve()
        if not f.is_file():
            raise EnsembleError(f"{path}: {axis} = {name!r}: no such file in {str(folder)!r}")
        if f in out.values():
            raise EnsembleError(f"{path}: {name!r} is given for two components")
        out[axis] = f
    return out

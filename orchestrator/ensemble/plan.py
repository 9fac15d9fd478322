"""Planning an ensemble: the inputs checked (PGAs, record files, seeds), the cells (record x
PGA x route) and the hash of each cell's inputs (its key in the cell store)."""
from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from uplift_common.code import PACKAGES, code_digest

from orchestrator.motion import DIRECTIONS, G, MotionError, read_components
from orchestrator.scene import MotionConfig, Scene, SceneError

from . import DT_CHECKS                 # the step-doubling check: once on the strongest motion, or each cell its own
from .triplets import EnsembleError, folder_components

#: record files taken from a folder, by suffix (case-insensitive): their format (None: the
#: scene's [motion].format when it is a record, else two-column)
RECORD_SUFFIXES = {".at2": "peer-at2", ".txt": None, ".dat": None}


@dataclass(frozen=True)
class Record:
    """One motion of the ensemble before scaling: record files (read once: their format, units,
    SHA-256 and peaks, m/s²), one file on the scene's direction or the components of a folder
    (``triplets``: one record, e.g. a PEER triplet); or, without files, a seed of the scene's
    synthetic motion.

    files : ((axis, Path), ...) in x, y, z order; checksums : the files' SHA-256, same order;
    peaks : the files' peaks as read (m/s², unscaled), same order; folder : True when the files
    are the components of one record (``[motion] components``), False for one file
    (``[motion] direction``); told : how a folder's components were told ("components.toml",
    "PEER names"; "" otherwise)."""
    label: str
    files: tuple = ()
    format: str = "two-column"
    units: str = "g"
    checksums: tuple = ()
    peaks: tuple = ()
    seed: int | None = None
    folder: bool = False
    told: str = ""

    @property
    def axes(self) -> tuple:
        return tuple(a for a, _ in self.files)

    @property
    def sha256(self) -> str:
        """The file's SHA-256, or for the components of a folder that of their (axis, SHA-256)."""
        if not self.folder:
            return self.checksums[0] if self.checksums else ""
        text = ";".join(f"{a}={c}" for a, c in zip(self.axes, self.checksums))
        return hashlib.sha256(text.encode()).hexdigest()

    @property
    def reference_peak(self) -> float:
        """The peak scaled to the PGA (m/s²): the stronger horizontal's, or the vertical's
        without a horizontal (a one-file record: its own)."""
        peaks = dict(zip(self.axes, self.peaks))
        horizontal = [peaks[a] for a in ("x", "y") if a in peaks]
        return max(horizontal) if horizontal else peaks["z"]

    def scale(self, pga_g: float) -> float:
        """The factor on every file's values that makes the reference peak ``pga_g`` (g)."""
        return pga_g * G / self.reference_peak

    def motion_config(self, base: MotionConfig, pga_g: float) -> MotionConfig:
        """The ``[motion]`` of this record at ``pga_g``: the scene's synthetic motion at that PGA
        and seed, or the files, each scaled by ``scale(pga_g)``."""
        if not self.files:
            return dataclasses.replace(base, pga_g=pga_g, seed=self.seed)
        common = dict(kind="record", format=self.format, units=self.units, scale=self.scale(pga_g))
        if self.folder:
            return MotionConfig(components=self.files, **common)
        (axis, file), = self.files
        return MotionConfig(direction=axis, file=file, **common)


@dataclass(frozen=True)
class Cell:
    """One run: record ``index[0]`` at pga ``index[1]`` on route ``index[2]``; ``scene`` is the
    scene with the cell's motion (what ``uplift run`` would load), ``key`` the hash of its inputs."""
    index: tuple
    label: str
    scene: Scene
    route: str
    key: str


@dataclass(frozen=True)
class Plan:
    """The ensemble: the scene (with its routes), the records, the PGAs (g, increasing), the
    routes, the output nodes, the dt check, the cells (records x pgas x routes) and the
    components of motion every cell runs (axes in x, y, z order)."""
    scene: Scene
    records: tuple
    pgas: tuple
    routes: tuple
    nodes: tuple
    dt_check: str
    cells: tuple
    components: tuple


# ---- planning: the inputs checked, the cells and their keys -----------------------------------

def plan_ensemble(scene: Scene, pgas, records=None, seeds=None, dt_check: str = "strongest") -> Plan:
    """The cells of ``scene`` (its routes) under ``records`` (files or folders, see
    ``record_sources``) or ``seeds`` of its synthetic motion, each at every PGA of ``pgas`` (g).
    Without either: the scene's own motion. Bad input raises EnsembleError naming it."""
    if dt_check not in DT_CHECKS:
        raise EnsembleError(f"dt_check = {dt_check!r}: use one of {', '.join(DT_CHECKS)}")
    if scene.soil_cases is not None or scene.strain_compatible is not None:
        raise EnsembleError(f"scene {scene.name!r} has [soil] cases or strain_compatible: an ensemble runs one soil; "
                            "run one ensemble per case on its scene (`uplift run` stores each case's scene in the "
                            "results file, /cases/<case> attribute scene_toml; docs/design_basis.md)")
    limit = scene.analysis.max_pga_g
    pgas = _pgas(pgas, limit)
    base = scene.motion
    if records is not None and seeds is not None:
        raise EnsembleError("give --records or --seeds, not both (--seeds varies the scene's synthetic motion)")
    if seeds is not None and base.kind != "synthetic":
        raise EnsembleError(f"--seeds: the [motion] of scene {scene.name!r} is a record, not synthetic; "
                            "give the records with --records")
    if records is not None:
        entries = _file_records(record_sources(records, base.direction), base)
    elif base.kind == "record":
        label = " + ".join(f.name for _, f in base.files)
        entries = _file_records([(label, dict(base.files), base.direction is None, "")], base)
    else:
        entries = _seed_records(seeds, base)
    components = _components(entries, base)
    nodes = tuple(scene.output.nodes or (scene.structure.node_names if scene.structure is not None else ()))
    routes = tuple(scene.analysis.routes)
    cells = []
    for i, rec in enumerate(entries):
        what = f"--records {rec.label!r}" if rec.files else f"--seeds {rec.seed}"
        for j, pga in enumerate(pgas):
            if rec.files:
                _check_intensity(rec, pga, limit, what)
            try:
                cell_scene = dataclasses.replace(scene, motion=rec.motion_config(base, pga))
            except SceneError as exc:
                raise EnsembleError(f"{what}: {exc}") from None
            for k, route in enumerate(routes):
                cells.append(Cell(index=(i, j, k), label=f"{rec.label} {pga:g} g [{route}]", scene=cell_scene,
                                  route=route, key=cell_key(cell_scene, route, pga, rec.sha256, dt_check)))
    return Plan(scene=scene, records=tuple(entries), pgas=pgas, routes=routes, nodes=nodes, dt_check=dt_check,
                cells=tuple(cells), components=components)


def _pgas(pgas, limit: float) -> tuple:
    values = []
    for p in pgas if pgas is not None else ():
        try:
            v = float(p)
        except (TypeError, ValueError):
            raise EnsembleError(f"--pga {p!r} is not a number (peak ground acceleration in g)") from None
        if not (np.isfinite(v) and v > 0):
            raise EnsembleError(f"--pga {p!r} must be a peak ground acceleration > 0 g, e.g. 0.25")
        if v > limit:
            raise EnsembleError(f"--pga {p!r} exceeds the intensity limit analysis.max_pga_g = {limit:g} g: check "
                                "the value (g, not m/s2?), or raise the limit with --max-pga")
        if v in values:
            raise EnsembleError(f"--pga {p!r} is given twice")
        values.append(v)
    if not values:
        raise EnsembleError("--pga: give at least one peak ground acceleration (g), e.g. --pga 0.1 0.25")
    return tuple(sorted(values))


def record_sources(paths, direction: str | None) -> list:
    """The records of ``paths``, as (label, {axis: file}, folder, told): a folder is one record,
    its components told by ``triplets.folder_components`` (labelled by the folder's name); a
    file is a one-component record on ``direction`` (the scene's [motion].direction; None
    refuses it), labelled by its name. Folders and files are not mixed; each file once."""
    out = []
    for p in map(Path, paths):
        if p.is_dir():
            files, told = folder_components(p, RECORD_SUFFIXES)
            out.append((p.resolve().name, files, True, told))
        elif p.is_file():
            if direction is None:
                raise EnsembleError(f"--records {str(p)!r}: a file is a one-component record on [motion].direction, "
                                    "and the scene's [motion] has components: give folders instead, one record "
                                    "(e.g. a PEER triplet) each")
            out.append((p.name, {direction: p.resolve()}, False, ""))
        else:
            raise EnsembleError(f"--records {str(p)!r}: no such file or folder")
    if not out:
        raise EnsembleError("--records: give at least one record folder or file")
    if len({folder for _, _, folder, _ in out}) > 1:
        raise EnsembleError("--records: give folders (one record each, its components x, y, z) or files (one "
                            "component each, on [motion].direction), not both")
    seen, labels = set(), set()
    for label, files, _, _ in out:
        for f in files.values():
            if f in seen:
                raise EnsembleError(f"--records: {str(f)!r} is given twice")
            seen.add(f)
        if label in labels:
            raise EnsembleError(f"--records: two records named {label!r}: rename one (the name labels the record)")
        labels.add(label)
    return out


def _file_records(sources, base: MotionConfig) -> list:
    """Records of the sources (``record_sources``): format by suffix (.AT2: PEER) else the
    scene's record format, units the scene's for a record scene else g; the files read once for
    the peaks and the checksums."""
    scene_fmt = base.format if base.kind == "record" else "two-column"
    units = base.units if base.kind == "record" else "g"
    out = []
    for label, files, folder, told in sources:
        where = f"--records {label!r}"
        formats = {f.name: RECORD_SUFFIXES.get(f.suffix.lower()) or scene_fmt for f in files.values()}
        if len(set(formats.values())) > 1:
            raise EnsembleError(f"{where}: its files are of different formats ("
                                + ", ".join(f"{n}: {fmt}" for n, fmt in formats.items())
                                + "): the components of a record share one format")
        fmt, = set(formats.values())
        try:
            motion = read_components(files, fmt, units, 1.0)
        except MotionError as exc:
            raise EnsembleError(f"{where}: {str(exc).removeprefix('motion.components: ')}") from None
        axes = motion.components
        rec = Record(label=label, files=tuple((a, files[a]) for a in axes), format=fmt,
                     units=units, checksums=tuple(hashlib.sha256(files[a].read_bytes()).hexdigest() for a in axes),
                     peaks=tuple(float(motion.pga[DIRECTIONS.index(a)]) for a in axes), folder=folder, told=told)
        if not rec.reference_peak > 0:
            which = "record is" if len(axes) == 1 else ("horizontals are" if {"x", "y"} & set(axes) else "vertical is")
            raise EnsembleError(f"{where}: the {which} zero everywhere: it cannot be scaled to a PGA")
        out.append(rec)
    return out


def _components(entries, base: MotionConfig) -> tuple:
    """The components every record runs (records of other components are refused)."""
    if not entries[0].files:
        return base.axes
    first = entries[0]
    for rec in entries[1:]:
        if rec.axes != first.axes:
            raise EnsembleError(f"--records: {first.label!r} has the components {', '.join(first.axes)} and "
                                f"{rec.label!r} {', '.join(rec.axes)}: every record of an ensemble runs the same "
                                "components (a components.toml in a folder may leave one out)")
    return first.axes


def _check_intensity(rec: Record, pga: float, limit: float, what: str) -> None:
    """Refuse a record whose scaled components (the vertical too) peak above ``limit`` (g)."""
    s = rec.scale(pga)
    for (axis, f), peak in zip(rec.files, rec.peaks):
        if peak * s / G > limit * (1 + 1e-9):
            raise EnsembleError(f"{what} at --pga {pga:g}: scaled by {s:.4g} (its reference peak to {pga:g} g), "
                                f"its component {axis} ({f.name}) peaks at {peak * s / G:.4g} g, above the intensity "
                                f"limit analysis.max_pga_g = {limit:g} g: lower the PGA, or raise the limit with "
                                "--max-pga")


def _seed_records(seeds, base: MotionConfig) -> list:
    seeds = [base.seed] if seeds is None else list(seeds)
    if not seeds:
        raise EnsembleError("--seeds: give at least one seed (an integer >= 0)")
    out = []
    for s in seeds:
        if isinstance(s, bool) or not isinstance(s, (int, np.integer)) or s < 0:
            raise EnsembleError(f"--seeds {s!r}: a seed is an integer >= 0")
        if int(s) in [r.seed for r in out]:
            raise EnsembleError(f"--seeds {s!r} is given twice")
        out.append(Record(label=f"seed {int(s)}", seed=int(s)))
    return out


def _canonical(obj):
    """A JSON-able image of a configuration, the same for the same content in any process:
    dataclasses by field, arrays by dtype, shape and SHA-256."""
    if dataclasses.is_dataclass(obj):
        return {f.name: _canonical(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, np.ndarray):
        a = np.ascontiguousarray(obj)
        return {"dtype": a.dtype.str, "shape": list(a.shape), "sha256": hashlib.sha256(a.tobytes()).hexdigest()}
    if isinstance(obj, (list, tuple)):
        return [_canonical(x) for x in obj]
    if isinstance(obj, dict):
        return {str(k): _canonical(v) for k, v in obj.items()}
    if isinstance(obj, np.generic):
        return obj.item()
    if obj is None or isinstance(obj, (str, int, float, bool)):
        return obj
    return repr(obj) if not isinstance(obj, Path) else str(obj)


def code_version() -> str:
    """SHA-256 of every package's sources, Python and the C runtime's (``uplift_common.code``):
    changed code, the C stepper's included, does not reuse the cells of the old one."""
    return code_digest(*PACKAGES)


def cell_key(scene: Scene, route: str, pga_g: float, record_sha256: str = "", dt_check: str = "strongest") -> str:
    """SHA-256 of a cell's inputs: the scene's content (not its name or folder, nor the TOML it
    was read from and the command line's overrides, which its configurations already hold; the
    record by its files' checksum ``Record.sha256`` and its components, not its paths), the route,
    the PGA, the dt check and the code."""
    image = _canonical(scene)
    for key in ("name", "base_dir", "source", "overrides", "mesh_source"):   # a mesh file's content is scene.mesh
        image.pop(key, None)
    image["analysis"].pop("routes")
    components = list(scene.motion.axes) if scene.motion.components is not None else None
    image["motion"].update(file=record_sha256, components=components, record=None)
    text = json.dumps({"scene": image, "route": route, "pga_g": pga_g, "dt_check": dt_check, "code": code_version()},
                      sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()

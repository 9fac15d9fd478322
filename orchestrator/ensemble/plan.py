"""Planning an ensemble: the inputs checked (PGAs, record files, seeds), the cells (record x
PGA x route) and the hash of each cell's inputs (its key in the cell store)."""
from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from orchestrator.errors import EnsembleError
from orchestrator.motion import G, MotionError, read_record
from orchestrator.scene import MotionConfig, Scene, SceneError

#: record files taken from a folder, by suffix (case-insensitive): their format (None: the
#: scene's [motion].format when it is a record, else two-column)
RECORD_SUFFIXES = {".at2": "peer-at2", ".txt": None, ".dat": None}
#: the step-doubling check: once on the strongest motion, or each cell its own
DT_CHECKS = ("strongest", "each")


@dataclass(frozen=True)
class Record:
    """One motion of the ensemble before scaling: a record file (read once: its format, units,
    SHA-256 and peak, m/s²) or, without files, a seed of the scene's synthetic motion."""
    label: str
    file: Path | None = None
    format: str = "two-column"
    units: str = "g"
    sha256: str = ""
    peak: float = 0.0
    seed: int | None = None

    def scale(self, pga_g: float) -> float:
        """The factor on the file's values that makes its peak ``pga_g`` (g)."""
        return pga_g * G / self.peak

    def motion_config(self, base: MotionConfig, pga_g: float) -> MotionConfig:
        """The ``[motion]`` of this record at ``pga_g``: the scene's synthetic motion at that PGA
        and seed, or the file scaled to that peak (the scene's direction)."""
        if self.file is None:
            return dataclasses.replace(base, pga_g=pga_g, seed=self.seed)
        return MotionConfig(kind="record", direction=base.direction, file=self.file, format=self.format,
                            units=self.units, scale=self.scale(pga_g))


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
    routes, the output nodes, the dt check, and the cells (records x pgas x routes)."""
    scene: Scene
    records: tuple
    pgas: tuple
    routes: tuple
    nodes: tuple
    dt_check: str
    cells: tuple


# ---- planning: the inputs checked, the cells and their keys -----------------------------------

def plan_ensemble(scene: Scene, pgas, records=None, seeds=None, dt_check: str = "strongest") -> Plan:
    """The cells of ``scene`` (its routes) under ``records`` (files or folders, see
    ``record_files``) or ``seeds`` of its synthetic motion, each at every PGA of ``pgas`` (g).
    Without either: the scene's own motion. Bad input raises EnsembleError naming it."""
    if dt_check not in DT_CHECKS:
        raise EnsembleError(f"dt_check = {dt_check!r}: use one of {', '.join(DT_CHECKS)}")
    pgas = _pgas(pgas, scene.analysis.max_pga_g)
    base = scene.motion
    if records is not None and seeds is not None:
        raise EnsembleError("give --records or --seeds, not both (--seeds varies the scene's synthetic motion)")
    if seeds is not None and base.kind != "synthetic":
        raise EnsembleError(f"--seeds: the [motion] of scene {scene.name!r} is a record, not synthetic; "
                            "give the records with --records")
    if records is None and base.kind == "record":
        records = [base.file]
    entries = _file_records(records, base) if records is not None else _seed_records(seeds, base)
    nodes = tuple(scene.output.nodes or (scene.structure.node_names if scene.structure is not None else ()))
    routes = tuple(scene.analysis.routes)
    cells = []
    for i, rec in enumerate(entries):
        for j, pga in enumerate(pgas):
            try:
                cell_scene = dataclasses.replace(scene, motion=rec.motion_config(base, pga))
            except SceneError as exc:
                what = f"--records {rec.file}" if rec.file is not None else f"--seeds {rec.seed}"
                raise EnsembleError(f"{what}: {exc}") from None
            for k, route in enumerate(routes):
                cells.append(Cell(index=(i, j, k), label=f"{rec.label} {pga:g} g [{route}]", scene=cell_scene,
                                  route=route, key=cell_key(cell_scene, route, pga, rec.sha256, dt_check)))
    return Plan(scene=scene, records=tuple(entries), pgas=pgas, routes=routes, nodes=nodes, dt_check=dt_check,
                cells=tuple(cells))


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


def record_files(paths) -> list:
    """The record files of ``paths``: files as given, folders expanded to their files whose
    suffix is in RECORD_SUFFIXES (sorted by name); each file once."""
    out = []
    for p in map(Path, paths):
        if p.is_dir():
            found = sorted(f for f in p.iterdir() if f.is_file() and f.suffix.lower() in RECORD_SUFFIXES)
            if not found:
                raise EnsembleError(f"--records {str(p)!r}: no record files in this folder (suffixes: "
                                    f"{', '.join(RECORD_SUFFIXES)})")
            out += found
        elif p.is_file():
            out.append(p)
        else:
            raise EnsembleError(f"--records {str(p)!r}: no such file or folder")
    resolved = [f.resolve() for f in out]
    for f in resolved:
        if resolved.count(f) > 1:
            raise EnsembleError(f"--records: {str(f)!r} is given twice")
    return resolved


def _file_records(paths, base: MotionConfig) -> list:
    """Records of the files: format by suffix (.AT2: PEER) else the scene's record format, units
    the scene's for a record scene else g; read once for the peak and the checksum."""
    scene_fmt = base.format if base.kind == "record" else "two-column"
    units = base.units if base.kind == "record" else "g"
    out, labels = [], {}
    for f in record_files(paths):
        fmt = RECORD_SUFFIXES.get(f.suffix.lower()) or scene_fmt
        try:
            peak = float(read_record(f, fmt, units, 1.0, base.direction).pga.max())
        except MotionError as exc:
            raise EnsembleError(f"--records: {exc}") from None
        if not peak > 0:
            raise EnsembleError(f"--records {str(f)!r}: the record is zero everywhere: it cannot be scaled to a PGA")
        if f.name in labels:
            raise EnsembleError(f"--records: two records named {f.name!r} ({labels[f.name]} and {f.parent}): "
                                "rename one (the name labels the record)")
        labels[f.name] = f.parent
        out.append(Record(label=f.name, file=f, format=fmt, units=units,
                          sha256=hashlib.sha256(f.read_bytes()).hexdigest(), peak=peak))
    return out


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


@functools.lru_cache(maxsize=1)
def code_digest() -> str:
    """SHA-256 of the package's Python sources (soil_impedance, structure, fmus, orchestrator),
    read once per process: changed code does not reuse the cells of the old one."""
    root = Path(__file__).resolve().parents[2]
    h = hashlib.sha256()
    for package in ("soil_impedance", "structure", "fmus", "orchestrator"):
        for path in sorted((root / package).rglob("*.py")):
            h.update(path.relative_to(root).as_posix().encode() + b"\0" + path.read_bytes())
    return h.hexdigest()


def cell_key(scene: Scene, route: str, pga_g: float, record_sha256: str = "", dt_check: str = "strongest") -> str:
    """SHA-256 of a cell's inputs: the scene's content (not its name or folder; the record by
    its file's checksum, not its path), the route, the PGA, the dt check and the code."""
    image = _canonical(scene)
    for key in ("name", "base_dir"):
        image.pop(key)
    image["analysis"].pop("routes")
    image["motion"].update(file=record_sha256, record=None)
    text = json.dumps({"scene": image, "route": route, "pga_g": pga_g, "dt_check": dt_check, "code": code_digest()},
                      sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()

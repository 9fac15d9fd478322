"""Ensembles of records: one scene run under many motions at several PGAs, on dask.distributed,
reduced to one ``xarray.Dataset`` with the fractiles over the records.

A design or fragility study runs a set of recorded (or spectrum-matched) motions, each scaled
to each intensity level, and reads fractiles over the records. Here a *cell* is one (record,
pga, route): exactly ``uplift run`` of the scene with that motion, i.e. the record file scaled
so that its peak is the PGA (``[motion]`` kind = "record", scale = pga / peak of the file) or,
without record files, the scene's synthetic motion at that PGA and seed. A cell keeps what the
run's summary gives (``orchestrator.results.summary``: max uplift, max raft rotation, minimum
contact ratio, wall time, status) and the floor response spectra of the scene's output nodes.

What the cells share is computed once per ensemble, on the calling process, and scattered to
the workers once (``orchestrator.run.prepare_run``): the BEM sweep, the rational fit and the
proxy springs of the time-step checks. The step-doubling check of the time step
(``run.step_doubling``, a warning) runs by default once, on the ensemble's strongest motion
(largest Arias intensity over its strongest window, at the largest PGA), and stands for every
cell; ``dt_check="each"`` checks every cell's own motion as ``uplift run`` does (it costs about
one monolithic run more per cell). A cell's numbers do not depend on it.

Cells run on a dask.distributed cluster: a LocalCluster of N worker processes, one thread
each, dask's statistical profiler off and glibc's heap trimming (LOCAL_WORKER_CONFIG), or an
existing cluster given by its scheduler address (its workers need this package and should run
one thread each with the profiler off: ``DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED=False dask
worker ADDRESS --nthreads 1``). A cell runs
under the thread discipline of a single run (one BLAS thread, ``$UPLIFT_THREADS``) and depends
on its inputs only, not on the number of workers or the order of completion. A cell whose task
fails (its worker killed more often than the scheduler allows, an exception) is recorded as
"failed" with the reason; the others complete.

Resuming: with an output file, every completed cell is written as it finishes to the folder
``<output>.cells/`` (one small HDF5 file per cell, atomic, checksummed), named by a hash of its
inputs (the scene's content, the record file's SHA-256, the PGA, the route, the dt check, the
package's sources); the output file is assembled from them at the end. A rerun with the same
output keeps the cells whose inputs match and computes the others (failed ones included).

The dataset (``write_ensemble``: netCDF4 through h5netcdf, ``xarray.open_dataset(path,
engine="h5netcdf")``) has the dimensions record, pga (g), route, node, direction (x, y, z),
frequency (Hz) and quantile (0.16, 0.5, 0.84). Per cell: ``max_uplift`` (m),
``max_raft_rotation`` (rad, sqrt(rx² + ry²)), ``min_contact_ratio`` (share of the interface
nodes in contact, gap = 0, its minimum over time), ``floor_spectrum`` (5 % damped
pseudo-acceleration, m/s², at FREQUENCIES_HZ; NaN in a direction of round-off response),
``wall_time`` (the route's, s), ``cell_time`` (the whole cell on its worker, s), ``status``
(converged | stopped | refused | failed), ``message``, ``warnings``. Per PGA and route: ``<name>_fractile`` over the records, from the
converged cells only (numpy's linear quantiles), and ``converged_records``. Per record: the
file and its SHA-256 and the scale factor of each PGA, or the seed.
"""
from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import logging
import os
import time
import warnings
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from soil_impedance.cache import atomic_output, read_entry, stamp_checksum
from structure.results import Status

from orchestrator.motion import G, MotionError, make_motion, read_record
from orchestrator.results import ResultsFileError, check_output_path, summary
from orchestrator.routes import get_route
from orchestrator.run import prepare_run, run_scene, step_doubling, strongest_window
from orchestrator.scene import MotionConfig, Scene, SceneError, load_scene
from orchestrator.settings import compute_threads, thread_count
from orchestrator.spectra import response_spectrum

#: floor response spectra: frequencies (Hz) and damping ratio (those of a single run's figures)
FREQUENCIES_HZ = np.geomspace(0.5, 40.0, 120)
DAMPING = 0.05
#: a direction whose floor acceleration stays below this share of the node's peak is round-off
#: (e.g. y under an x motion of a symmetric structure): its spectrum is NaN, not computed (the
#: rule of orchestrator.compare)
ROUNDOFF = 1e-6
#: fractiles over the records of each PGA: 16th percentile, median, 84th percentile
QUANTILES = (0.16, 0.5, 0.84)
DIRECTIONS = ("x", "y", "z")
#: record files taken from a folder, by suffix (case-insensitive): their format (None: the
#: scene's [motion].format when it is a record, else two-column)
RECORD_SUFFIXES = {".at2": "peer-at2", ".txt": None, ".dat": None}
#: the step-doubling check: once on the strongest motion, or each cell its own
DT_CHECKS = ("strongest", "each")
#: seconds to wait for an existing scheduler (and for its first worker)
CONNECT_TIMEOUT_S = 10.0
#: dask settings of the local workers, each measured on the reactor's monolithic run (CPU time
#: of the task's thread against the same run in process, paired runs): no statistical profiler
#: (it samples the running task's stack every 10 ms: +10-15 %), and glibc's own heap trimming
#: rather than dask's MALLOC_TRIM_THRESHOLD_ = 64 KiB (the stepper's temporaries then go back
#: to the system and fault in again: median +11 % over 8 pairs, against -3 % without it)
LOCAL_WORKER_CONFIG = {"distributed.worker.profile.enabled": False,
                       "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}
#: root attribute ``uplift_file`` of an ensemble file (``is_ensemble_file``)
KIND = "ensemble"
FAILED = "failed"
#: per-cell numbers: name -> (units, long name)
CELL_VARIABLES = {
    "max_uplift": ("m", "largest uplift of an interface node over the record"),
    "max_raft_rotation": ("rad", "largest raft rotation sqrt(rx^2 + ry^2) over the record"),
    "min_contact_ratio": ("1", "smallest share of the interface nodes in contact (gap = 0) over the record"),
    "wall_time": ("s", "wall time of the route (as uplift run reports it)"),
    "cell_time": ("s", "wall time of the whole cell on its worker (motion, checks, route, spectra)"),
}
#: the cell numbers that get fractiles over the records (with the floor spectra)
FRACTILE_VARIABLES = ("max_uplift", "max_raft_rotation", "min_contact_ratio", "floor_spectrum")
TEXT_VARIABLES = ("status", "message", "warnings")


class EnsembleError(ValueError):
    """Bad input to an ensemble (a record, a PGA, a seed, the cluster); the message names it."""


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
    pgas = _pgas(pgas)
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


def _pgas(pgas) -> tuple:
    values = []
    for p in pgas if pgas is not None else ():
        try:
            v = float(p)
        except (TypeError, ValueError):
            raise EnsembleError(f"--pga {p!r} is not a number (peak ground acceleration in g)") from None
        if not (np.isfinite(v) and v > 0):
            raise EnsembleError(f"--pga {p!r} must be a peak ground acceleration > 0 g, e.g. 0.25")
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
    root = Path(__file__).resolve().parents[1]
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


# ---- one cell ---------------------------------------------------------------------------------

def run_cell(scene: Scene, route: str, shared, nodes, cache_dir=None) -> dict:
    """The values of one cell (``cell_values``): ``run_scene`` of the cell's scene on ``route``
    with the ensemble's shared parts (a ``run.SharedRun``). Runs on a worker."""
    t0 = time.perf_counter()
    results, _ = run_scene(scene, [route], cache_dir=cache_dir, shared=shared)
    values = cell_values(results[route], nodes)
    values["cell_time"] = time.perf_counter() - t0
    return values


def cell_values(res, nodes) -> dict:
    """A RouteResult reduced to the cell's values: the summary's max uplift (m), max raft
    rotation (rad), min contact fraction, wall time (s), status, message and warnings (NaN
    numbers for a refused route), and the floor spectra (len(nodes), 3, F) at FREQUENCIES_HZ
    (NaN where the route gives no acceleration and in round-off directions, see ROUNDOFF)."""
    s = summary(res)
    spectra = np.full((len(nodes), len(DIRECTIONS), FREQUENCIES_HZ.size), np.nan)
    if res.nt > 1:
        dt = float(res.time[1] - res.time[0])
        for i, node in enumerate(nodes):
            acc = res.acc.get(node, np.zeros((0, 3)))
            for j in np.flatnonzero(np.abs(acc).max(axis=0, initial=0.0) > ROUNDOFF * np.abs(acc).max(initial=0.0)):
                spectra[i, j] = response_spectrum(acc[:, j], dt, 1 / FREQUENCIES_HZ, DAMPING).psa
    number = (lambda v: np.nan) if res.status is Status.REFUSED else float
    return {"status": s["status"], "message": s["message"], "warnings": "\n".join(s["warnings"]),
            "max_uplift": number(s["max_uplift_m"]), "max_raft_rotation": number(s["max_raft_rotation_rad"]),
            "min_contact_ratio": number(s["min_contact_fraction"]), "wall_time": float(s["wall_s"]),
            "floor_spectrum": spectra}


class CellStore:
    """The completed cells of an ensemble written to ``output``: one HDF5 file per cell in
    ``<output>.cells/``, named by its key, written atomically with a checksum (a damaged file
    is moved aside with a warning and the cell recomputed)."""

    def __init__(self, output):
        self.folder = Path(f"{output}.cells")
        if self.folder.exists() and not self.folder.is_dir():
            raise ResultsFileError(f"{self.folder} is a file: the completed runs of -o {output} are kept in a "
                                   "folder of that name; move the file or choose another -o")

    def _path(self, key: str) -> Path:
        return self.folder / f"{key[:32]}.h5"

    def read(self, key: str) -> dict | None:
        def reader(f):
            if f.attrs["key"] != key:
                raise ValueError(f"holds the cell {f.attrs['key'][:12]}, not {key[:12]}")
            out = {name: f[name][()] for name in f}
            out.update({k: v.item() if isinstance(v, np.generic) else str(v) for k, v in f.attrs.items()
                        if k not in ("key", "sha256")})
            missing = {*CELL_VARIABLES, *TEXT_VARIABLES, "floor_spectrum"} - set(out)
            if missing:
                raise ValueError(f"lacks {', '.join(sorted(missing))} (written by another version)")
            return out
        return read_entry(self._path(key), reader)

    def write(self, key: str, values: dict) -> None:
        self.folder.mkdir(exist_ok=True)
        with atomic_output(self._path(key)) as tmp, h5py.File(tmp, "w") as f:
            f.attrs["key"] = key
            for name, value in values.items():
                if isinstance(value, np.ndarray):
                    f.create_dataset(name, data=value)
                else:
                    f.attrs[name] = value
            stamp_checksum(f)


# ---- the ensemble -----------------------------------------------------------------------------

def run_ensemble(scene, pgas, records=None, seeds=None, routes=None, output=None, workers: int | None = None,
                 scheduler: str | None = None, cache_dir=None, dt_check: str = "strongest", progress=None,
                 sweep_progress=None, fit_progress=None, log=None):
    """Run ``scene`` (a Scene, a TOML path or a built-in name) on ``routes`` (default: the
    scene's) under ``records`` (record files or folders) or ``seeds`` of its synthetic motion,
    each at every PGA of ``pgas`` (g); returns the ``xarray.Dataset`` of the module docstring
    and, with ``output``, writes it there (resuming from ``<output>.cells/``).

    workers : worker processes of a LocalCluster (default: the usable cores, at most one per
    cell); scheduler : the address of an existing dask scheduler instead (e.g.
    "tcp://10.0.0.5:8786"); dt_check : "strongest" or "each" (module docstring);
    progress(done, total, label) follows the cells, sweep_progress and fit_progress the set-up
    (as in ``run_scene``); log(message) receives notes for the user. Bad input raises before
    any computation (EnsembleError, SceneError, ResultsFileError: all ValueErrors).
    """
    t0 = time.perf_counter()
    scene = scene if isinstance(scene, Scene) else load_scene(scene)
    if routes:
        scene = scene.with_routes(routes)
    if workers is not None and scheduler is not None:
        raise EnsembleError("give --workers (a local cluster) or --scheduler (an existing one), not both")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise EnsembleError(f"--workers {workers!r}: a number of worker processes >= 1")
    out = check_output_path(output) if output is not None else None
    plan = plan_ensemble(scene, pgas, records, seeds, dt_check)
    store = CellStore(out) if out is not None else None
    values = {}
    for cell in plan.cells if store is not None else ():
        found = store.read(cell.key)
        if found is not None:
            values[cell.key] = found
    todo = [c for c in plan.cells if c.key not in values]
    failures, times, n_workers, check = {}, dict.fromkeys(("cluster_s", "setup_s", "dt_check_s"), 0.0), 0, None
    if todo:
        t = time.perf_counter()
        with _client(workers, scheduler, len(todo), log) as client:
            n_workers = len(client.scheduler_info()["workers"])
            t1 = time.perf_counter()
            shared = prepare_run(plan.scene, cache_dir=cache_dir, sweep_progress=sweep_progress,
                                 fit_progress=fit_progress)
            t2 = time.perf_counter()
            if dt_check == "strongest":
                with compute_threads():
                    check = strongest_check(plan, shared)
                shared = dataclasses.replace(shared, dt_check=check)
            times.update(cluster_s=t1 - t, setup_s=t2 - t1, dt_check_s=time.perf_counter() - t2)
            done, failures = _run_cells(client, todo, shared, plan.nodes, cache_dir, store, progress)
        values.update(done)
    attrs = {**times, "wall_s": time.perf_counter() - t0, "workers": n_workers,
             "computed": len(todo) - len(failures), "reused": len(plan.cells) - len(todo),
             "dt_check": dt_check, "dt_check_result": json.dumps(check)}
    ds = assemble(plan, values, failures, attrs)
    if out is not None:
        write_ensemble(ds, out)
    return ds


def strongest_check(plan: Plan, shared):
    """The step-doubling check (``run.step_doubling``) on the ensemble's strongest motion: at the
    largest PGA, the record with the largest Arias intensity over its strongest window; None
    when no route of the plan is time-stepped with contact. The record and PGA are added."""
    scene = plan.scene
    if not (scene.contact.enabled and any(get_route(r).time_stepped for r in plan.routes)):
        return None
    dt = scene.analysis.dt
    top = [c for c in plan.cells if c.index[1] == len(plan.pgas) - 1 and c.index[2] == 0]
    motions = [make_motion(c.scene.motion, dt) for c in top]
    arias = [float((strongest_window(m)[0].acc ** 2).sum()) for m in motions]
    k = int(np.argmax(arias))
    check = step_doubling(scene, scene.model(), shared.springs, motions[k])
    return {**check, "record": plan.records[top[k].index[0]].label, "pga_g": plan.pgas[-1]}


def default_workers() -> int:
    """The cores this process may use."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


@contextmanager
def _client(workers, scheduler, n_cells: int, log):
    """A dask Client: on an existing scheduler, or on a LocalCluster of worker processes with
    one thread each and the BLAS thread count of this process (closed on exit)."""
    import dask  # heavy import (~1 s): only ensembles pay it
    from dask.distributed import Client, LocalCluster  # (same)
    if scheduler is not None:
        try:
            client = Client(scheduler, timeout=CONNECT_TIMEOUT_S)
        except (OSError, TimeoutError, ValueError) as exc:
            raise EnsembleError(f"--scheduler {scheduler!r}: cannot connect ({exc}); give the address of a "
                                "running dask scheduler, e.g. tcp://10.0.0.5:8786") from None
        with client:
            try:
                client.wait_for_workers(1, timeout=CONNECT_TIMEOUT_S)
            except (OSError, TimeoutError) as exc:
                raise EnsembleError(f"--scheduler {scheduler!r}: no worker joined within "
                                    f"{CONNECT_TIMEOUT_S:g} s ({exc}); start workers with "
                                    f"`dask worker {scheduler} --nthreads 1`") from None
            threads = set(client.nthreads().values())
            if log is not None and threads != {1}:
                log(f"workers of {scheduler} run {max(threads)} threads each: cells running side by side share "
                    "a process (BLAS thread limits, memory); start them with --nthreads 1")
            yield client
        return
    n = str(thread_count())
    env = {"UPLIFT_THREADS": n, "OMP_NUM_THREADS": n, "OPENBLAS_NUM_THREADS": n, "MKL_NUM_THREADS": n}
    with dask.config.set(LOCAL_WORKER_CONFIG), \
            LocalCluster(n_workers=workers or min(default_workers(), n_cells), threads_per_worker=1, processes=True,
                         dashboard_address=None, silence_logs=logging.ERROR, env=env) as cluster, \
            Client(cluster) as client:
        yield client


def _run_cells(client, cells, shared, nodes, cache_dir, store, progress):
    """Run ``cells`` on the cluster, ``shared`` scattered once to every worker; each result is
    stored as it arrives. Returns ({key: values}, {key: reason} of the cells that failed)."""
    from dask.distributed import as_completed  # heavy import, see _client
    shared_future = client.scatter(shared, broadcast=True)
    futures = {client.submit(run_cell, c.scene, c.route, shared_future, nodes, cache_dir, pure=False): c
               for c in cells}
    done, failures = {}, {}
    for n, future in enumerate(as_completed(futures), start=1):
        cell = futures[future]
        try:
            values = future.result()
        except Exception as exc:
            failures[cell.key] = f"{type(exc).__name__}: {exc}"
        else:
            done[cell.key] = values
            if store is not None:
                store.write(cell.key, values)
        future.release()
        if progress is not None:
            progress(n, len(cells), cell.label + (" FAILED" if cell.key in failures else ""))
    return done, failures


# ---- the dataset ------------------------------------------------------------------------------

def assemble(plan: Plan, values: dict, failures: dict, attrs: dict):
    """The ensemble's xarray.Dataset (module docstring) from the cells' values ({key: values};
    a cell without values is "failed", with its reason from ``failures``)."""
    import xarray as xr  # start-up cost (~0.5 s, pandas): only ensembles pay it
    shape = (len(plan.records), len(plan.pgas), len(plan.routes))
    numbers = {name: np.full(shape, np.nan) for name in CELL_VARIABLES}
    text = {name: np.full(shape, "", dtype=object) for name in TEXT_VARIABLES}
    spectra = np.full(shape + (len(plan.nodes), len(DIRECTIONS), FREQUENCIES_HZ.size), np.nan)
    for cell in plan.cells:
        v = values.get(cell.key)
        if v is None:
            text["status"][cell.index] = FAILED
            text["message"][cell.index] = failures.get(cell.key, "not run")
            continue
        for name in CELL_VARIABLES:
            numbers[name][cell.index] = v[name]
        for name in TEXT_VARIABLES:
            text[name][cell.index] = v[name]
        spectra[cell.index] = v["floor_spectrum"]
    cell_dims = ("record", "pga", "route")
    ds = xr.Dataset(coords={
        "record": ("record", [r.label for r in plan.records]),
        "pga": ("pga", np.array(plan.pgas), {"units": "g", "long_name": "peak ground acceleration"}),
        "route": ("route", list(plan.routes)),
        "node": ("node", list(plan.nodes)),
        "direction": ("direction", list(DIRECTIONS)),
        "frequency": ("frequency", FREQUENCIES_HZ, {"units": "Hz"}),
        "quantile": ("quantile", np.array(QUANTILES), {"long_name": "fractile over the records"})})
    for name, (units, long_name) in CELL_VARIABLES.items():
        ds[name] = (cell_dims, numbers[name], {"units": units, "long_name": long_name})
    ds["floor_spectrum"] = (cell_dims + ("node", "direction", "frequency"), spectra,
                            {"units": "m s-2", "long_name": f"{100 * DAMPING:g} % damped pseudo-acceleration "
                                                            "response spectrum of the floor acceleration"})
    for name in TEXT_VARIABLES:
        ds[name] = (cell_dims, text[name].astype(str))
    converged = text["status"] == Status.CONVERGED.value
    ds["converged_records"] = (("pga", "route"), converged.sum(axis=0),
                               {"long_name": "converged cells over the records (those of the fractiles)"})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)        # all-NaN slices: no converged record
        for name in FRACTILE_VARIABLES:
            a = ds[name].values
            mask = converged.reshape(converged.shape + (1,) * (a.ndim - 3))
            q = np.nanquantile(np.where(mask, a, np.nan), QUANTILES, axis=0)
            ds[f"{name}_fractile"] = (("quantile",) + ds[name].dims[1:], q,
                                      {**ds[name].attrs, "long_name": f"fractile over the records of {name}"})
    files = [r for r in plan.records if r.file is not None]
    if files:
        ds["record_file"] = ("record", [str(r.file) for r in plan.records])
        ds["record_sha256"] = ("record", [r.sha256 for r in plan.records])
        ds["record_scale"] = (("record", "pga"), np.array([[r.scale(p) for p in plan.pgas] for r in plan.records]),
                              {"long_name": "factor on the record file's values ([motion] scale)"})
    else:
        ds["seed"] = ("record", np.array([r.seed for r in plan.records]))
    s = plan.scene
    ds.attrs.update(uplift_file=KIND, scene=s.name, created=time.strftime("%Y-%m-%dT%H:%M:%S"),
                    dt=s.analysis.dt, motion_direction=s.motion.direction, damping=DAMPING, **attrs)
    return ds


def write_ensemble(ds, path) -> Path:
    """Write the dataset to ``path`` (netCDF4 through h5netcdf), atomically."""
    path = check_output_path(path)
    with atomic_output(path) as tmp:
        ds.to_netcdf(tmp, engine="h5netcdf")
    return path


def is_ensemble_file(path) -> bool:
    """True if ``path`` is a file written by ``write_ensemble``."""
    try:
        with h5py.File(path, "r") as f:
            kind = f.attrs.get("uplift_file")
    except OSError:
        return False
    return (kind.decode() if isinstance(kind, bytes) else kind) == KIND


def read_ensemble(path):
    """The dataset of an ensemble file (loaded, the file closed); ResultsFileError when it is
    missing or not one."""
    import xarray as xr  # start-up cost, see assemble
    if not is_ensemble_file(path):
        raise ResultsFileError(f"{path} is not an ensemble file of `uplift ensemble` (run `uplift ensemble SCENE "
                               "--pga G ... -o FILE` to make one)")
    with xr.open_dataset(path, engine="h5netcdf") as ds:
        return ds.load()


def ensemble_summary(ds) -> dict:
    """The JSON summary of ``uplift ensemble --json``: cell counts (runs, converged, stopped,
    refused, failed, computed, reused), wall_s, cluster_s (starting or joining the cluster),
    setup_s (sweep and fit), dt_check_s (the step-doubling check on the strongest motion); per
    PGA and route the median and 84th percentile of the max uplift (m; None without a converged
    record); the cells that did not converge with their reason."""
    status = ds["status"].values
    counts = {s: int((status == s).sum()) for s in ("converged", "stopped", "refused", FAILED)}
    finite = lambda v: float(v) if np.isfinite(v) else None
    fr = ds["max_uplift_fractile"]
    per_pga = {f"{p:g}": {route: {"median_max_uplift_m": finite(fr.sel(quantile=0.5, pga=p, route=route)),
                                   "p84_max_uplift_m": finite(fr.sel(quantile=0.84, pga=p, route=route)),
                                   "converged_records": int(ds["converged_records"].sel(pga=p, route=route))}
                           for route in ds["route"].values}
               for p in ds["pga"].values}
    others = [{"record": str(ds["record"].values[i]), "pga_g": float(ds["pga"].values[j]),
               "route": str(ds["route"].values[k]), "status": str(status[i, j, k]),
               "message": str(ds["message"].values[i, j, k])}
              for i, j, k in zip(*np.nonzero(status != "converged"))]
    a = ds.attrs
    return {"scene": a["scene"], "runs": int(status.size), **counts, "computed": int(a["computed"]),
            "reused": int(a["reused"]), "workers": int(a["workers"]), "wall_s": float(a["wall_s"]),
            "cluster_s": float(a["cluster_s"]), "setup_s": float(a["setup_s"]),
            "dt_check_s": float(a["dt_check_s"]), "pga": per_pga, "not_converged": others}

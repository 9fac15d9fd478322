"""One HDF5 layout for every route's results, and the per-route summary.

Layout (open it with h5py; every array is in SI units)::

    /                       attrs: scene, created, sha256 (checksum of the file's content),
                                   scene_toml (the scene as it ran, TOML: ``load_scene`` reads it),
                                   overrides (JSON: the command line's --pga, --dt, --duration,
                                   --max-pga, each {option, value, key, was, now})
    /motion/acc (nt, 3)     ground acceleration, m/s²; attrs: dt, label, components ("x,y,z")
    /routes/<route>/        attrs: status (converged | stopped | refused), message, wall_s,
                                   notes (JSON: skipped, warnings, precheck, timings), info (JSON)
        time (nt,)  raft (nt, 6)  gap (nt, N)  contact_force (nt, N)  soil_w (nt, N)
        xy (N, 2)  newton_iters (nt,)
        acc/<node> (nt, 3)  disp/<node> (nt, 3)  energy/<term> (nt,)

A route that stopped early is written with what it computed, status "stopped" and its
``message`` (the reason). The file is written atomically: an existing file at the same path
stays intact until the new one is complete.
"""
from __future__ import annotations

import json
import os
import time
from pathlib import Path

import h5py
import numpy as np

from uplift_common.files import ChangedFileError, OutputPathError, atomic_output, output_target, require_checksum, stamp_checksum
from structure.results import RouteResult, RunNotes, Status

from orchestrator.motion import G, Motion
from uplift_common.errors import UserInputError

ARRAYS = ("time", "raft", "gap", "contact_force", "soil_w", "newton_iters", "xy")
GROUPS = ("acc", "disp", "energy")
REMEDY = "run `uplift run SCENE -o FILE` again to make a good one"


class ResultsFileError(UserInputError):
    """A results file that is missing, unreadable or not of this layout, or an output path that
    cannot be written (exit 2 in the CLI)."""


def check_output_path(path) -> Path:
    """Refuse, before any computation, an output file the run could not write: its folder
    missing or not writable, the path a folder, or anything else that is not a regular file (a
    device, a FIFO: a rename would replace it). A symlink is followed: the target is checked
    and written, the link survives. Returns ``path``."""
    path = Path(path)
    if path.is_dir():
        raise ResultsFileError(f"output {str(path)!r} is a folder: give a file name, e.g. {path / 'results.h5'}")
    try:
        target = output_target(path)
    except OutputPathError as exc:
        raise ResultsFileError(str(exc)) from None
    folder = target.parent if str(target.parent) else Path(".")
    if not folder.is_dir():
        raise ResultsFileError(f"output folder {str(folder)!r} does not exist: create it or choose another -o path")
    if not os.access(folder, os.W_OK):
        raise ResultsFileError(f"output folder {str(folder)!r} is not writable: choose another -o path")
    return path


def check_output_folder(path, names=(), option: str = "-o") -> Path:
    """Refuse, before any computation, an output folder that cannot take the files ``names``:
    ``path`` (or a folder on its way) a file, not writable, or one of ``names`` inside it
    present and not a regular file (a symlink to one is followed). Returns ``path``."""
    path = Path(path)
    parts = [*reversed(path.absolute().parents), path.absolute()]
    for p in parts:
        if p.exists() or p.is_symlink():
            if not p.is_dir():
                where = "is" if p == path.absolute() else f"lies under {str(p)!r}, which is"
                raise ResultsFileError(f"{option} {str(path)!r} {where} not a folder: give a folder "
                                       "(it is created if it does not exist)")
            existing = p
    if not os.access(existing, os.W_OK):
        raise ResultsFileError(f"{option} {str(path)!r}: folder {str(existing)!r} is not writable; choose another "
                               "folder")
    for name in names:
        try:
            output_target(path / name)
        except OutputPathError as exc:
            raise ResultsFileError(f"{option} {str(path)!r}: {exc}") from None
    return path


def write_results(path, results: dict, motion=None, scene_name: str = "", scene_toml: str = "",
                  overrides=()) -> Path:
    """Write ``{route: RouteResult}`` (and the motion, the scene as TOML, the overrides of the
    command line) to one HDF5 file, atomically."""
    path = check_output_path(path)
    with atomic_output(path) as tmp, h5py.File(tmp, "w") as f:
        f.attrs["scene"] = scene_name
        f.attrs["scene_toml"] = scene_toml
        f.attrs["overrides"] = json.dumps(list(overrides))
        f.attrs["created"] = time.strftime("%Y-%m-%dT%H:%M:%S")
        if motion is not None:
            m = f.create_group("motion")
            m.create_dataset("acc", data=motion.acc)
            m.attrs["dt"], m.attrs["label"] = motion.dt, motion.label
            m.attrs["components"] = ",".join(motion.components)
        routes = f.create_group("routes")
        for name, res in results.items():
            g = routes.create_group(name)
            for key in ARRAYS:
                value = getattr(res, key)
                if value is not None:
                    g.create_dataset(key, data=value)
            for key in GROUPS:
                sub = g.create_group(key)
                for item, arr in getattr(res, key).items():
                    sub.create_dataset(item, data=arr)
            g.attrs["route"] = res.route
            g.attrs["status"] = res.status.value
            g.attrs["message"] = res.message
            g.attrs["wall_s"] = res.wall_s
            g.attrs["notes"] = json.dumps(res.notes.as_dict())
            g.attrs["info"] = json.dumps(dict(res.info), default=_jsonable)
        stamp_checksum(f)
    return path


def _jsonable(obj):
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.floating, np.integer, np.bool_)):
        return obj.item()
    if hasattr(obj, "items"):
        return dict(obj)
    return str(obj)


def read_results(path) -> dict:
    """Read a results file back as ``{route: RouteResult}``; a missing, unreadable or foreign
    file raises ResultsFileError naming it."""
    path = Path(path)
    if not path.is_file():
        raise ResultsFileError(f"results file {str(path)!r} does not exist: run `uplift run SCENE -o FILE` first")
    try:
        with h5py.File(path, "r") as f:
            require_checksum(f, path, REMEDY)
            if "routes" not in f or not len(f["routes"]):
                raise ResultsFileError(f"{path} holds no routes (/routes/<route>): not a results file of "
                                       "`uplift run`; run `uplift run SCENE -o FILE` to make one")
            return {route: _read_route(route, g) for route, g in f["routes"].items()}
    except (ResultsFileError, ChangedFileError):
        raise
    except OSError as exc:   # h5py: not an HDF5 file, truncated file
        raise ResultsFileError(f"{path} is not a readable HDF5 results file ({exc}); "
                               "run `uplift run SCENE -o FILE` to make one") from None
    except (KeyError, TypeError, ValueError) as exc:
        raise ResultsFileError(f"{path} does not have the results layout of `uplift run` ({exc}); "
                               "see orchestrator/results_file.py") from None


def _read_route(route, g) -> RouteResult:
    kw = {key: g[key][()] for key in ARRAYS if key in g}
    kw.update({key: {k: v[()] for k, v in g[key].items()} for key in GROUPS if key in g})
    a = g.attrs
    return RouteResult(route=str(a.get("route", route)), status=Status(str(a["status"])),
                       message=str(a.get("message", "")), wall_s=float(a.get("wall_s", 0.0)),
                       notes=RunNotes(**json.loads(a.get("notes", "{}"))), info=json.loads(a.get("info", "{}")),
                       **kw)


def read_motion(path):
    """(scene name, created, Motion or None) of a results file (its checksum verified)."""
    with h5py.File(path, "r") as f:
        require_checksum(f, path, REMEDY)
        motion = None
        if "motion" in f:
            m = f["motion"]
            axes = tuple(a for a in str(m.attrs.get("components", "")).split(",") if a)
            motion = Motion(float(m.attrs["dt"]), m["acc"][()], str(m.attrs.get("label", "motion")), axes)
        return str(f.attrs.get("scene", "")), str(f.attrs.get("created", "")), motion


def read_scene_record(path) -> dict:
    """{"scene": name, "scene_toml": the scene as it ran ("" in a file written without it),
    "overrides": [the command line's overrides]} of a results file (its checksum verified)."""
    with h5py.File(path, "r") as f:
        require_checksum(f, path, REMEDY)
        return {"scene": str(f.attrs.get("scene", "")), "scene_toml": str(f.attrs.get("scene_toml", "")),
                "overrides": json.loads(f.attrs.get("overrides", "[]"))}


def summary(res) -> dict:
    """The per-route summary of ``uplift run --json`` (see the CLI docs). ``components``: the
    motion's components the route ran (``run_scene`` records them in the result's info; empty
    for a refused route); ``max_raft_rotation_rad``: the peak rocking magnitude
    sqrt(rx² + ry²), with the per-axis peaks |rx|, |ry| in ``max_raft_rotation_axes_rad``."""
    gap = np.asarray(res.gap)
    if gap.size:
        k = np.unravel_index(np.argmax(gap), gap.shape)
        max_uplift, t_uplift = float(gap[k]), float(res.time[k[0]])
        min_contact = float((gap <= 0).mean(axis=1).min())
    else:
        max_uplift, t_uplift, min_contact = 0.0, 0.0, 1.0
    rot = np.hypot(res.raft[:, 3], res.raft[:, 4])
    peak = lambda a: float(np.abs(a).max()) if a.size else 0.0
    return {
        "status": res.status.value,
        "message": res.message,
        "components": list(res.info.get("components", ())),
        "max_uplift_m": max_uplift,
        "max_uplift_time_s": t_uplift,
        "max_raft_rotation_rad": peak(rot),
        "max_raft_rotation_axes_rad": {"x": peak(res.raft[:, 3]), "y": peak(res.raft[:, 4])},
        "min_contact_fraction": min_contact,
        "peak_acc_g": {name: float(np.abs(a).max() / G) if a.size else 0.0 for name, a in res.acc.items()},
        "wall_s": float(res.wall_s),
        "converged": bool(res.converged),
        **res.notes.as_dict(),
    }

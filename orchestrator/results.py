"""One HDF5 layout for every route's results, and the per-route summary.

Layout (open it with h5py; every array is in SI units)::

    /                       attrs: scene, created, uplift_version
    /motion/acc (nt, 3)     ground acceleration, m/s²; attrs: dt, label
    /routes/<route>/        attrs: converged, message, wall_s, info (JSON)
        time (nt,)  raft (nt, 6)  gap (nt, N)  contact_force (nt, N)  soil_w (nt, N)
        xy (N, 2)  newton_iters (nt,)
        acc/<node> (nt, 3)  disp/<node> (nt, 3)  energy/<term> (nt,)

A route that stopped early is written with what it computed and ``converged = False`` and
its ``message`` (the reason).
"""
from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import numpy as np

G = 9.81


def write_results(path, results: dict, motion=None, scene_name: str = "") -> Path:
    """Write ``{route: RouteResult}`` (and the motion) to one HDF5 file."""
    import h5py

    path = Path(path)
    with h5py.File(path, "w") as f:
        f.attrs["scene"] = scene_name
        f.attrs["created"] = time.strftime("%Y-%m-%dT%H:%M:%S")
        if motion is not None:
            m = f.create_group("motion")
            m.create_dataset("acc", data=motion.acc)
            m.attrs["dt"], m.attrs["label"] = motion.dt, motion.label
        routes = f.create_group("routes")
        for name, res in results.items():
            g = routes.create_group(name)
            for fld in dataclasses.fields(res):
                value = getattr(res, fld.name)
                if isinstance(value, dict) and fld.name != "info":
                    sub = g.create_group(fld.name)
                    for key, arr in value.items():
                        sub.create_dataset(key, data=np.asarray(arr))
                elif isinstance(value, np.ndarray):
                    g.create_dataset(fld.name, data=value)
                elif fld.name == "info":
                    g.attrs["info"] = json.dumps(value, default=_jsonable)
                elif value is not None:
                    g.attrs[fld.name] = value
    return path


def _jsonable(obj):
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.floating, np.integer, np.bool_)):
        return obj.item()
    return str(obj)


def read_results(path) -> dict:
    """Read a results file back as ``{route: RouteResult}``."""
    import h5py
    from structure.results import RouteResult

    out = {}
    names = {f.name for f in dataclasses.fields(RouteResult)}
    with h5py.File(path, "r") as f:
        for route, g in f["routes"].items():
            kw = {}
            for key, item in g.items():
                if key in names:
                    kw[key] = {k: v[()] for k, v in item.items()} if isinstance(item, h5py.Group) else item[()]
            for key, value in g.attrs.items():
                if key == "info":
                    kw["info"] = json.loads(value)
                elif key in names:
                    kw[key] = value.item() if isinstance(value, np.generic) else value
            out[route] = RouteResult(**kw)
    return out


def summary(res) -> dict:
    """The per-route summary of ``uplift run --json`` (see the CLI docs)."""
    gap = np.asarray(res.gap)
    if gap.size:
        k = np.unravel_index(np.argmax(gap), gap.shape)
        max_uplift, t_uplift = float(gap[k]), float(res.time[k[0]])
        contact = (gap <= 0).mean(axis=1)
        min_contact = float(contact.min())
    else:
        max_uplift, t_uplift, min_contact = 0.0, 0.0, 1.0
    rot = np.hypot(res.raft[:, 3], res.raft[:, 4])
    return {
        "max_uplift_m": max_uplift,
        "max_uplift_time_s": t_uplift,
        "max_raft_rotation_rad": float(rot.max()) if rot.size else 0.0,
        "min_contact_fraction": min_contact,
        "peak_acc_g": {name: float(np.abs(a).max() / G) for name, a in res.acc.items()},
        "wall_s": float(res.wall_s),
        "converged": bool(res.converged),
        # what the run did not compute and why (cache hits, closed contact, ...), and what the
        # linear contact pre-check found (structure.ContactSettings.precheck)
        "skipped": [str(s) for s in res.info.get("skipped", [])],
        "precheck": str(res.info.get("precheck", "")),
        "warnings": [str(w) for w in res.info.get("warnings", [])],
    }

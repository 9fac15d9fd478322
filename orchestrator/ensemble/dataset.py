"""The ensemble's dataset: assembled from the cells, with the fractiles over the records;
written (netCDF4 through h5netcdf, atomically, with a checksum of its data), read back
(verified) and summarised."""
from __future__ import annotations

import io
import time
import warnings
from pathlib import Path

import h5py
import numpy as np

from uplift_common.files import CHECKSUM_ATTR, require_checksum, stamp_file, write_image
from structure.results import Status

from orchestrator.motion import G
from orchestrator.oncurve import scene_key
from orchestrator.results_file import ResultsFileError, check_output_path

from .plan import Plan
from .store import CELL_VARIABLES, DAMPING, DIRECTIONS, FAILED, FREQUENCIES_HZ, ONCURVE_VARIABLES, TEXT_VARIABLES

#: fractiles over the records of each PGA: 16th percentile, median, 84th percentile
QUANTILES = (0.16, 0.5, 0.84)
#: root attribute ``uplift_file`` of an ensemble file (``is_ensemble_file``)
KIND = "ensemble"
#: the cell numbers that get fractiles over the records (with the floor spectra)
FRACTILE_VARIABLES = ("max_uplift", "max_raft_rotation", "min_contact_ratio", "floor_spectrum")


def assemble(plan: Plan, values: dict, failures: dict, attrs: dict):
    """The ensemble's xarray.Dataset (the package docstring) from the cells' values ({key: values};
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
            numbers[name][cell.index] = v.get(name, np.nan) if name in ONCURVE_VARIABLES else v[name]
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
    if plan.records[0].files:
        def per_axis(r, values, empty):          # by direction, ``empty`` where the record has none
            by_axis = dict(zip(r.axes, values))
            return [by_axis.get(d, empty) for d in DIRECTIONS]
        ds["record_file"] = (("record", "direction"), [per_axis(r, [str(f) for _, f in r.files], "")
                                                       for r in plan.records])
        ds["record_sha256"] = (("record", "direction"), [per_axis(r, r.checksums, "") for r in plan.records])
        ds["record_peak"] = (("record", "direction"), np.array([per_axis(r, r.peaks, np.nan) for r in plan.records]) / G,
                             {"units": "g", "long_name": "peak of the record file as read, before scaling"})
        ds["record_scale"] = (("record", "pga"), np.array([[r.scale(p) for p in plan.pgas] for r in plan.records]),
                              {"long_name": "factor on the record files' values ([motion] scale): the stronger "
                                            "horizontal (without one, the vertical) to the PGA"})
    else:
        ds["seed"] = ("record", np.array([r.seed for r in plan.records]))
    s = plan.scene
    ds.attrs.update(uplift_file=KIND, scene=s.name, scene_key=scene_key(s), created=time.strftime("%Y-%m-%dT%H:%M:%S"),
                    dt=s.analysis.dt, components=" ".join(plan.components), damping=DAMPING, **attrs)
    if not plan.records[0].files and "z" in plan.components and s.motion.vertical_ratio is not None:
        ds.attrs["vertical_ratio"] = s.motion.vertical_ratio
    return ds


def ensemble_components(ds) -> tuple:
    """The components of motion an ensemble ran, in x, y, z order: its ``components``
    attribute ("x y z"), or the ``motion_direction`` of a file written before it."""
    text = ds.attrs.get("components", ds.attrs.get("motion_direction", "x"))
    return tuple(a for a in DIRECTIONS if a in str(text).split())


def write_ensemble(ds, path) -> Path:
    """Write the dataset to ``path`` (netCDF4 through h5netcdf), atomically, with the checksum of
    its content (``uplift_common.files``; a later append re-stamps it with
    ``uplift_common.files.atomic_update``)."""
    path = check_output_path(path)
    import dask                      # start-up cost: the ensemble's writer only
    buf = io.BytesIO()               # written in memory, then to the disk in one write (hdf5_output's reason)
    # the local scheduler's lock: under a distributed client xarray would take a cluster-wide lock
    # named by the target, which a BytesIO cannot give
    with dask.config.set(scheduler="synchronous"):
        ds.to_netcdf(buf, engine="h5netcdf")
    stamp_file(buf)
    write_image(path, buf.getbuffer())
    return path


def is_ensemble_file(path) -> bool:
    """True if ``path`` is a file written by ``write_ensemble``."""
    try:
        with h5py.File(path, "r") as f:
            kind = f.attrs.get("uplift_file")
    except OSError:
        return False
    return (kind.decode() if isinstance(kind, bytes) else kind) == KIND


def read_ensemble(path, group: str | None = None):
    """The dataset of an ensemble file (loaded, the file closed; ``group``: a group appended to
    it); ResultsFileError when it is missing or not one, ChangedFileError when it changed since
    it was written."""
    import xarray as xr  # start-up cost, see assemble
    if not is_ensemble_file(path):
        raise ResultsFileError(f"{path} is not an ensemble file of `uplift ensemble` (run `uplift ensemble SCENE "
                               "--pga G ... -o FILE` to make one)")
    with h5py.File(path, "r") as f:
        require_checksum(f, path, "run `uplift ensemble` again with another -o to make a good one")
    with xr.open_dataset(path, engine="h5netcdf", group=group) as ds:
        ds = ds.load()
    ds.attrs.pop(CHECKSUM_ATTR, None)          # the file's, not the data's: it changes with an append
    return ds


def ensemble_summary(ds) -> dict:
    """The JSON summary of ``uplift ensemble --json``: cell counts (runs, converged, stopped,
    refused, failed, computed, reused), workers and workers_note (why fewer than asked), wall_s,
    cluster_s (starting or joining the cluster),
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
    return {"scene": a["scene"], "components": list(ensemble_components(ds)), "runs": int(status.size), **counts, "computed": int(a["computed"]),
            "reused": int(a["reused"]), "workers": int(a["workers"]), "workers_note": str(a.get("workers_note", "")),
            "wall_s": float(a["wall_s"]),
            "cluster_s": float(a["cluster_s"]), "setup_s": float(a["setup_s"]),
            "dt_check_s": float(a["dt_check_s"]), "pga": per_pga, "not_converged": others}

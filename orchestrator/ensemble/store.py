"""One cell of an ensemble: its run on a worker, the values it keeps, and the store of the
completed cells beside the output file (for resuming)."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from soil_impedance.cache import read_entry
from uplift_common.files import hdf5_output, stamp_checksum
from structure.results import Status

from orchestrator.oncurve import raft_load, run_extremes
from orchestrator.results_file import ResultsFileError, summary
from orchestrator.run import run_scene
from orchestrator.scene import Scene
from orchestrator.spectra import FLOOR_DAMPING, FLOOR_FREQUENCIES_HZ, ROUNDOFF, floor_spectra

#: floor response spectra: frequencies (Hz), damping ratio and round-off rule (a direction whose
#: floor acceleration stays below ROUNDOFF of the node's peak has a NaN spectrum): those of a
#: single run's results file and figures (orchestrator.spectra)
FREQUENCIES_HZ, DAMPING, ROUNDOFF = FLOOR_FREQUENCIES_HZ, FLOOR_DAMPING, ROUNDOFF
DIRECTIONS = ("x", "y", "z")
FAILED = "failed"
#: per-cell numbers: name -> (units, long name) (ONCURVE_VARIABLES: NaN in the values of a cell
#: made without them, e.g. by ``cell_values`` without the raft's loads)
CELL_VARIABLES = {
    "max_uplift": ("m", "largest uplift of an interface node over the record"),
    "max_raft_rotation": ("rad", "largest raft rotation sqrt(rx^2 + ry^2) over the record"),
    "min_contact_ratio": ("1", "smallest share of the interface nodes in contact (gap = 0) over the record"),
    "max_overturning_moment": ("N m", "largest overturning moment |M| about the raft centre of the total contact "
                                      "forces beyond the weight's (orchestrator.oncurve, as the pushover's)"),
    "min_contact_area_ratio": ("1", "smallest area in contact (gap = 0) / raft area over the record (the "
                                    "pushover's contact ratio)"),
    "wall_time": ("s", "wall time of the route (as uplift run reports it)"),
    "cell_time": ("s", "wall time of the whole cell on its worker (motion, checks, route, spectra)"),
}
TEXT_VARIABLES = ("status", "message", "warnings")
#: the cell numbers that place a cell on the static pushover curve (orchestrator.oncurve)
ONCURVE_VARIABLES = ("max_overturning_moment", "min_contact_area_ratio")


def run_cell(scene: Scene, route: str, shared, nodes, cache_dir=None) -> dict:
    """The values of one cell (``cell_values``): ``run_scene`` of the cell's scene on ``route``
    with the ensemble's shared parts (a ``run.SharedRun``, settled: its fit, or the fit's error, made
    on the calling process). Runs on a worker."""
    t0 = time.perf_counter()
    results, _ = run_scene(scene, [route], cache_dir=cache_dir, shared=shared)
    values = cell_values(results[route], nodes, raft=(scene.mesh.xy, scene.mesh.area, raft_load(shared.model)))
    values["cell_time"] = time.perf_counter() - t0
    return values


def cell_values(res, nodes, raft=None) -> dict:
    """A RouteResult reduced to the cell's values: the summary's max uplift (m), max raft
    rotation (rad), min contact fraction, wall time (s), status, message and warnings (NaN
    numbers for a refused route), and the floor spectra (len(nodes), 3, F) at FREQUENCIES_HZ
    (NaN where the route gives no acceleration and in round-off directions, see ROUNDOFF);
    with ``raft`` = (xy (N, 2) m, area (N,) m2, loads (6,) N, N m: the weight at the raft
    centre) the values that place the cell on the pushover curve (ONCURVE_VARIABLES,
    ``orchestrator.oncurve.run_extremes``: max |M| N m, min contact area ratio), else NaN."""
    s = summary(res)
    spectra = np.full((len(nodes), len(DIRECTIONS), FREQUENCIES_HZ.size), np.nan)
    if res.nt > 1:
        spectra = floor_spectra(res.acc, float(res.time[1] - res.time[0]), nodes)
    number = (lambda v: np.nan) if res.status is Status.REFUSED else float
    on = dict.fromkeys(ONCURVE_VARIABLES, np.nan)
    if raft is not None and res.nt > 0:
        ext = run_extremes(res, *raft)
        on = {"max_overturning_moment": ext["max_moment_Nm"], "min_contact_area_ratio": ext["min_contact_ratio"]}
    return {**on, "status": s["status"], "message": s["message"], "warnings": "\n".join(s["warnings"]),
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
        with hdf5_output(self._path(key)) as f:
            f.attrs["key"] = key
            for name, value in values.items():
                if isinstance(value, np.ndarray):
                    f.create_dataset(name, data=value)
                else:
                    f.attrs[name] = value
            stamp_checksum(f)

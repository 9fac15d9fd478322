"""Fit files: a model and its report in one HDF5 file, checksummed, written atomically."""
from __future__ import annotations

import json
import time
from pathlib import Path

from ..rational import FitError, read_model, write_model
from .result import FitReport, FitResult


def save_fit(result: FitResult, path) -> None:
    """Model (``rational.write_model`` layout) + the report as JSON attribute ``fit_report`` + the
    content checksum (``uplift_common.files.stamp_checksum``), written atomically (``uplift_common.files.atomic_output``)."""

    from uplift_common.files import hdf5_output, stamp_checksum
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with hdf5_output(path) as h:
        write_model(h, result.model)
        h.attrs["fit_report"] = json.dumps(result.report.to_dict())
        stamp_checksum(h)


def load_fit(path) -> FitResult:
    """Read a FitResult written by ``save_fit`` (report.cached = True, wall_s = load time); FitError
    naming the file when it is not one, or when it changed since it was written (its checksum)."""
    import h5py

    from uplift_common.files import ChangedFileError, require_checksum
    try:
        h = h5py.File(path, "r")
    except OSError as exc:
        raise FitError(f"{path}: cannot open as an HDF5 fit ({exc})") from None
    with h:
        try:
            require_checksum(h, path, "refit the table")
        except ChangedFileError as exc:
            raise FitError(str(exc)) from None
        return read_fit(h, path)


def read_fit(h, path, data=None, trust_digest: bool = False) -> FitResult:
    """The FitResult in the open h5py File ``h`` (``save_fit``); data, trust_digest: as
    ``rational.read_model`` (a verified cache entry's datasets as its checksum read them, and its
    stored model digest)."""
    t0 = time.perf_counter()
    model = read_model(h, path, data, trust_digest)
    if "fit_report" not in h.attrs:
        raise FitError(f"{path}: a rational model without a fit report: refit the table")
    d = json.loads(h.attrs["fit_report"])
    d.update(cached=True, wall_s=time.perf_counter() - t0)
    return FitResult(model, FitReport.from_dict(d))

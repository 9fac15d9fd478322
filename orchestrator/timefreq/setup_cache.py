"""The time-frequency solve's set-up kept in the cache folder: what a second solve of the same
table on the same grid and structure (another record, another seed, another motion scale)
would make again, bit for bit.

Two entries, each an HDF5 file written atomically with its checksum and verified on read
(``soil_impedance.cache``: a damaged one is moved aside with a CacheWarning and recomputed):

* ``tf-rows-<key>.h5``: a table's spline band's rows (K[w, :] P, P^T K[:, w] (Fb, N, 6), P^T K P
  (Fb, 6, 6); ``soil.SplineBand.rows_P``: products over the table's matrices combined with the
  spline's weights), read by the operator (``InterfaceOperator``). Key: the table's data, the
  spline's weights (the grid's frequencies) and the raft's trace Bq (12.5 MB on the reactor:
  the operator's set-up 0.16 -> 0.11 s CPU).
* ``tf-split-<key>.h5``: the far field's split's dense part (``farfield.AffineSplit``: D = S -
  (A + s B) on the table's frequencies, packed upper triangles when S is symmetric; on the
  reactor 125 MB, made from the spline band's packed matrices and the structure's rank-6 term:
  0.45-0.6 s CPU against 0.17-0.19 s to read and verify, most of it the SHA-256). Key: the table's data, every band's
  frequencies and the spline's weights, the grid's s, Bq and Zqq^-1 on every frequency (the
  structure's condensed impedance: the modes, the damping and the raft).

Both keys start from the digest of the code that makes the values (``SETUP_CODE``) and the
table's ``data_digest`` (the SHA-256 of its matrices and DOF labels, which a table read from a
file has from its own verification). A soil that is not a table has no entry (None keys).
"""
from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from soil_impedance.cache import feed, read_entry, write_entry
from uplift_common.code import code_digest
from uplift_common.files import hdf5_output, stamp_checksum

from orchestrator.timefreq.soil import SplineBand, _written

#: the code the entries' values depend on (the bands, the operator's rows, the split; the table's
#: spline and causal fade)
SETUP_CODE = ("orchestrator.timefreq.setup_cache", "orchestrator.timefreq.soil", "orchestrator.timefreq.operator",
              "orchestrator.timefreq.farfield", "orchestrator.timefreq.grid", "soil_impedance.table",
              "soil_impedance.fit")


def setup_key(kind: str, table, *parts) -> str | None:
    """SHA-256 (hex) of ``SETUP_CODE``, ``kind``, the table's data and frequencies and ``parts``
    (``soil_impedance.cache.feed``); None without a table or when a part has no digest."""
    if table is None or not hasattr(table, "data_digest"):
        return None
    h = hashlib.sha256(code_digest(*SETUP_CODE).encode())
    try:
        for part in (kind, table.data_digest, np.asarray(table.frequencies_hz, float), *parts):
            feed(h, part)
    except TypeError:
        return None
    return h.hexdigest()


def entry_path(cache_dir, kind: str, key: str | None) -> Path | None:
    """The entry's file in ``cache_dir`` (None: no cache folder or no key)."""
    if cache_dir is None or key is None:
        return None
    return Path(cache_dir) / f"tf-{kind}-{key[:24]}.h5"


def read_arrays(path, names, shapes=None, attrs=()) -> tuple | None:
    """([the complex arrays ``names``], {attr: value} of ``attrs``) from the entry ``path``, or None
    (absent, or damaged: CacheWarning, moved aside). shapes: the shape each array must have
    (None: any); a mismatch is damage. Each array is stored as one float dataset of its real and
    imaginary parts side by side (``write_arrays``), read and verified straight into the complex
    array (no copy of it made, no strided one)."""
    if path is None:
        return None

    def into(ds):                   # the complex array whose floats the dataset is
        if ds.dtype != np.float64 or ds.ndim < 1 or ds.shape[-1] != 2:
            return None
        return np.empty(ds.shape[:-1], complex).view(float).reshape(ds.shape)

    def reader(f, data):
        out = []
        for k, name in enumerate(names):
            a = data[f"/{name}"]
            if a.dtype != np.float64 or a.ndim < 1 or a.shape[-1] != 2 or not a.flags.c_contiguous:
                raise ValueError(f"array {name!r}: expected float64 (..., 2), got {a.dtype} {a.shape}")
            a = a.view(complex)[..., 0]
            if shapes is not None and a.shape != tuple(shapes[k]):
                raise ValueError(f"array {name!r} has shape {a.shape}, expected {tuple(shapes[k])}")
            out.append(a)
        return out, {a: f.attrs[a] for a in attrs}
    return read_entry(path, reader, keep=True, into=into)


def write_arrays(path, arrays: dict, attrs=None) -> None:
    """Store the complex ``arrays`` ({name: array}: each as one float dataset (..., 2), its real and
    imaginary parts side by side, as in memory) and ``attrs`` as the entry ``path`` (atomic,
    checksummed; a failure only warns)."""
    if path is None:
        return
    def writer(p):
        with hdf5_output(p) as f:
            for name, a in arrays.items():
                a = np.ascontiguousarray(a, complex)
                f.create_dataset(name, data=a.view(float).reshape(a.shape + (2,)))
            for k, v in (attrs or {}).items():
                f.attrs[k] = v
            stamp_checksum(f)
    write_entry(path, writer)


def band_rows(band, s, Bq, out, *, table, cache_dir):
    """``band.rows_P(s, Bq, out)``, a table's spline band's from the cache (``tf-rows``) when its
    entry is there, else computed and stored; any other band, or without a cache folder or a
    table, computed."""
    if not isinstance(band, SplineBand) or cache_dir is None or table is None:
        return band.rows_P(s, Bq, out)
    path = entry_path(cache_dir, "rows", setup_key("rows", table, band.idx, band.W, band.c, np.asarray(Bq, float)))
    Fb, N, r = band.idx.size, Bq.shape[0], Bq.shape[1]
    hit = read_arrays(path, ("Vr", "Vl", "KPP"), ((Fb, N, r), (Fb, r, N), (Fb, r, r)))
    if hit is not None:
        return _written(tuple(hit[0]), out)
    Vr, Vl, KPP = band.rows_P(s, Bq, out)
    write_arrays(path, {"Vr": Vr, "Vl": Vl, "KPP": KPP})
    return Vr, Vl, KPP

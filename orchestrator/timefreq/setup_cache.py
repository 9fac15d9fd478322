"""The time-frequency solve's set-up kept in the cache folder: what a second solve of the same
table on the same grid and structure (another record, another seed, another motion scale)
would make again, bit for bit.

Two entries, each an HDF5 file written atomically with its checksum, each array checked on read
by its CRC-32 (``read_mapped``: a damaged entry is moved aside with a CacheWarning and recomputed,
as ``soil_impedance.cache``'s):

* ``tf-rows-<key>.h5``: a table's spline band's rows (K[w, :] P, P^T K[:, w] (Fb, N, 6), P^T K P
  (Fb, 6, 6); ``soil.SplineBand.rows_P``: products over the table's matrices combined with the
  spline's weights), read by the operator (``InterfaceOperator``). Key: the table's data, the
  spline's weights (the grid's frequencies) and the raft's trace Bq (12.5 MB on the reactor:
  the operator's set-up 0.16 -> 0.11 s CPU). Read memory-mapped as the split (below).
* ``tf-split-<key>.h5``: the far field's split's dense part (``farfield.AffineSplit``: D = S -
  (A + s B) on the table's frequencies, packed upper triangles when S is symmetric; on the
  reactor 125 MB, made from the spline band's packed matrices and the structure's rank-6 term:
  0.45-0.6 s CPU). Key: the table's data, every band's frequencies and the spline's weights, the
  grid's s, Bq and Zqq^-1 on every frequency (the structure's condensed impedance: the modes, the
  damping and the raft). Read memory-mapped (``read_mapped``, ``write_mapped``): each array one
  contiguous dataset checked by the CRC-32 of its bytes, not copied (0.05 s on the reactor
  against 0.17-0.19 s for the SHA-256 verified read into memory), and kept for the next solve
  of the process while the file stays the same (``_MAPPED``).

Both keys start from the digest of the code that makes the values (``SETUP_CODE``) and the
table's ``data_digest`` (the SHA-256 of its matrices and DOF labels, which a table read from a
file has from its own verification). A soil that is not a table has no entry (None keys).
"""
from __future__ import annotations

import hashlib
import os
import zlib
from pathlib import Path

import h5py
import numpy as np

from soil_impedance.cache import discard_entry, feed, read_entry, write_entry
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


def write_arrays(path, arrays: dict, attrs=None, crc: bool = False) -> None:
    """Store the complex ``arrays`` ({name: array}: each as one float dataset (..., 2), its real and
    imaginary parts side by side, as in memory) and ``attrs`` as the entry ``path`` (atomic,
    checksummed; a failure only warns); ``crc``: each dataset with the CRC-32 of its bytes as its
    attribute ``CRC_ATTR`` (``write_mapped``)."""
    if path is None:
        return
    def writer(p):
        with hdf5_output(p) as f:
            for name, a in arrays.items():
                a = np.ascontiguousarray(a, complex)
                ds = f.create_dataset(name, data=a.view(float).reshape(a.shape + (2,)))
                if crc:
                    ds.attrs[CRC_ATTR] = np.uint32(zlib.crc32(a))
            for k, v in (attrs or {}).items():
                f.attrs[k] = v
            stamp_checksum(f)
    write_entry(path, writer)


#: the dataset attribute holding the CRC-32 of a mapped entry's array (``write_mapped``)
CRC_ATTR = "crc32"
#: the entries last read by ``read_mapped`` in this process (at most ``KEEP_MAPPED``, the oldest
#: dropped first): {path: (its stat signature, what was read)}
_MAPPED: dict = {}
KEEP_MAPPED = 4


def write_mapped(path, arrays: dict, attrs=None) -> None:
    """Store the complex ``arrays`` as the entry ``path`` for ``read_mapped``: as ``write_arrays``
    (each array one float dataset (..., 2), atomic, the file's SHA-256 stamped as every entry's),
    each dataset contiguous with the CRC-32 of its bytes as its attribute ``CRC_ATTR``."""
    write_arrays(path, arrays, attrs, crc=True)


def _signature(st) -> tuple:
    """What says that a file is still the one read: its inode, device, size and times."""
    return st.st_ino, st.st_dev, st.st_size, st.st_mtime_ns, st.st_ctime_ns


def read_mapped(path, names, shapes=None, attrs=()) -> tuple | None:
    """([the complex arrays ``names``], {attr: value} of ``attrs``) of the entry ``path`` written by
    ``write_mapped``, or None (absent, or damaged: CacheWarning, moved aside, as ``read_arrays``).

    Each array is the file's bytes memory-mapped read-only (no copy), checked by the CRC-32 of
    those bytes against its dataset's ``CRC_ATTR``, its type (little-endian float64 pairs) and
    its shape (``shapes``, None: any) checked too: a change of any byte read, the checksums'
    included, is found (a CRC-32 finds every change of up to 32 consecutive bits), and bytes that
    are not read (HDF5's own bookkeeping) cannot change what is read without failing a check.
    The last entries read stay mapped for the process (``_MAPPED``): read again while the file's
    inode, size and times are the same, it is not checked again (an entry is replaced by a rename,
    never rewritten in place; a rewrite in place changes its times)."""
    if path is None:
        return None
    try:
        before = os.stat(path)
    except (FileNotFoundError, NotADirectoryError):
        return None
    key = str(path)
    kept = _MAPPED.get(key)
    if kept is not None and kept[0] == _signature(before):
        return kept[1]
    try:
        with h5py.File(path, "r") as f:
            spans = []
            for k, name in enumerate(names):
                ds = f[name]
                if ds.dtype != np.dtype("<f8") or ds.ndim < 2 or ds.shape[-1] != 2:
                    raise ValueError(f"array {name!r}: expected little-endian float64 (..., 2), got {ds.dtype} {ds.shape}")
                shape = ds.shape[:-1]
                if shapes is not None and shape != tuple(shapes[k]):
                    raise ValueError(f"array {name!r} has shape {shape}, expected {tuple(shapes[k])}")
                offset = ds.id.get_offset()
                if offset is None or ds.id.get_storage_size() != 8 * ds.size or CRC_ATTR not in ds.attrs:
                    raise ValueError(f"array {name!r} is not stored contiguously with its {CRC_ATTR!r}")
                spans.append((name, offset, shape, int(ds.attrs[CRC_ATTR])))
            extra = {a: f.attrs[a] for a in attrs}
        out = []
        for name, offset, shape, crc in spans:
            a = np.memmap(path, "<c16", "r", offset=offset, shape=shape)
            if zlib.crc32(a) != crc:
                raise ValueError(f"array {name!r}: its bytes do not match their CRC-32")
            out.append(a.view(np.ndarray))
    except Exception as exc:
        discard_entry(path, f"{type(exc).__name__}: {exc}", before, stacklevel=3)
        return None
    _MAPPED.pop(key, None)
    while len(_MAPPED) >= KEEP_MAPPED:
        _MAPPED.pop(next(iter(_MAPPED)))
    _MAPPED[key] = (_signature(before), (out, extra))
    return out, extra


def band_rows(band, s, Bq, out, *, table, cache_dir):
    """``band.rows_P(s, Bq, out)``, a table's spline band's from the cache (``tf-rows``) when its
    entry is there, else computed and stored; any other band, or without a cache folder or a
    table, computed."""
    if not isinstance(band, SplineBand) or cache_dir is None or table is None:
        return band.rows_P(s, Bq, out)
    path = entry_path(cache_dir, "rows", setup_key("rows", table, band.idx, band.W, band.c, np.asarray(Bq, float)))
    Fb, N, r = band.idx.size, Bq.shape[0], Bq.shape[1]
    hit = read_mapped(path, ("Vr", "Vl", "KPP"), ((Fb, N, r), (Fb, r, N), (Fb, r, r)))
    if hit is not None:
        return _written(tuple(hit[0]), out)
    Vr, Vl, KPP = band.rows_P(s, Bq, out)
    write_mapped(path, {"Vr": Vr, "Vl": Vl, "KPP": KPP})
    return Vr, Vl, KPP

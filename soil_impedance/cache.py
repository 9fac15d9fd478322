"""Crash-safe and concurrency-safe output files, and verified HDF5 cache entries.

Why: two processes writing the same file name interleave their writes, and a process killed
mid-write leaves a truncated file; either blocks (or silently corrupts) every later run. Here
every file is written under a unique temporary name in the target folder and renamed onto the
target only once complete (``os.replace`` is atomic on one file system): a reader sees the old
file or the new one, never a mix, and concurrent writers each succeed (the last one wins).

HDF5 files also carry a SHA-256 checksum of their whole content (root attribute ``"sha256"``),
so a flipped bit or a half-written entry is detected on read. A damaged *cache entry* is
discarded with a ``CacheWarning`` and recomputed by the caller (``read_entry``); a damaged file
the user gave is the caller's to report as an error.

Usage::

    with atomic_output(path) as tmp:
        with h5py.File(tmp, "w") as f:
            ...                              # write datasets and attributes
            stamp_checksum(f)
    value = read_entry(path, reader)         # reader(f: h5py.File) -> value; None: recompute
"""
from __future__ import annotations

import contextlib
import hashlib
import os
import tempfile
import warnings
from pathlib import Path

import h5py
import numpy as np

CHECKSUM_ATTR = "sha256"
_CHUNK_BYTES = 1 << 26          # datasets are hashed in slabs of about 64 MiB along axis 0
_UMASK = os.umask(0o022)
os.umask(_UMASK)


def default_cache_dir() -> Path:
    """The project's cache folder (impedance tables, fits, the host's compiled runtime):
    $UPLIFT_CACHE, else ~/.cache/uplift."""
    env = os.environ.get("UPLIFT_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "uplift"


class CacheWarning(UserWarning):
    """A damaged cache entry was discarded; the result is recomputed."""


class OutputFolderError(FileNotFoundError, ValueError):
    """The folder of an output file does not exist (the caller decides whether to create it)."""


@contextlib.contextmanager
def atomic_output(path):
    """Yield a unique temporary ``Path`` next to ``path``; the caller writes it completely.

    On normal exit the temporary file is flushed to disk (fsync), renamed onto ``path``
    (``os.replace``, atomic) and the folder entry is synced; on an exception it is removed and
    the exception re-raised. The old file at ``path`` stays intact until the new one is
    complete, and concurrent writers never share a temporary name (pid + random suffix).
    Raises ``OutputFolderError`` (a FileNotFoundError and ValueError) if the folder is missing.
    """
    path = Path(path)
    folder = path.parent
    if not folder.is_dir():
        raise OutputFolderError(f"cannot write {path}: folder {folder} does not exist "
                                "(create it first or choose another path)")
    fd, name = tempfile.mkstemp(dir=folder, prefix=f".{path.name}.{os.getpid()}.", suffix=".tmp")
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        os.chmod(tmp, 0o666 & ~_UMASK)          # mkstemp makes 0600; keep the usual mode
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise
    _fsync_folder(folder)


def _fsync_folder(folder) -> None:
    """Make the rename durable (best effort: not every platform can open a folder)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _update_value(h, value) -> None:
    """Feed an attribute or dataset value (dtype, shape, bytes) into hash ``h``."""
    a = np.asarray(value)
    h.update(f"{a.shape}".encode())
    if a.dtype.kind in "OSU":                   # strings (fixed or variable length), objects
        h.update(b"str")
        for x in a.reshape(-1):
            b = x.encode() if isinstance(x, str) else bytes(x)
            h.update(len(b).to_bytes(8, "little") + b)
    else:
        h.update(a.dtype.str.encode())
        h.update(np.ascontiguousarray(a).tobytes())


def _update_dataset(h, ds) -> None:
    h.update(f"dataset {ds.dtype.str} {ds.shape}".encode())
    if ds.shape is None:                        # null dataspace
        return
    if ds.ndim == 0 or ds.size == 0:
        _update_value(h, ds[()])
        return
    row = max(1, ds.dtype.itemsize * ds.size // ds.shape[0])
    step = max(1, _CHUNK_BYTES // row)
    for i in range(0, ds.shape[0], step):
        _update_value(h, ds[i:i + step])


def _update_attrs(h, obj, skip=()) -> None:
    for key in sorted(obj.attrs):
        if key not in skip:
            h.update(b"attr " + key.encode() + b"\0")
            _update_value(h, obj.attrs[key])


def _checksum(f: h5py.File) -> str:
    """SHA-256 (hex) of every group, dataset and attribute of ``f`` in name order, except the
    root checksum attribute."""
    h = hashlib.sha256()
    _update_attrs(h, f, skip=(CHECKSUM_ATTR,))
    names = []
    f.visit(names.append)
    for name in sorted(names):
        obj = f[name]
        h.update(b"\0object " + name.encode() + b"\0")
        if isinstance(obj, h5py.Dataset):
            _update_dataset(h, obj)
        else:
            h.update(b"group")
        _update_attrs(h, obj)
    return h.hexdigest()


def stamp_checksum(f: h5py.File) -> str:
    """Compute the SHA-256 of the whole content of the open, writable file ``f`` (every dataset:
    name, dtype, shape, bytes; every attribute: name, value; in a deterministic order), store it
    as root attribute ``"sha256"`` and return it. Call it last, after every write."""
    f.flush()
    digest = _checksum(f)
    f.attrs[CHECKSUM_ATTR] = digest
    return digest


def verify_checksum(f: h5py.File) -> bool:
    """True if the root ``"sha256"`` attribute matches the content of ``f``; False when it is
    missing, different, or part of the file cannot be read."""
    stored = f.attrs.get(CHECKSUM_ATTR)
    if stored is None:
        return False
    if isinstance(stored, bytes):
        stored = stored.decode(errors="replace")
    try:
        return str(stored) == _checksum(f)
    except (OSError, KeyError, RuntimeError, ValueError):
        return False


def read_entry(path, reader):
    """Read the cache entry at ``path`` with ``reader(f: h5py.File)``; None means recompute.

    None if the file is absent (or its folder is not one). If it cannot be opened, fails checksum verification, or
    ``reader`` raises (any Exception, including the user-input error types: ``reader`` may
    reject a stale or nonsensical entry that way), warn ``CacheWarning`` naming the file and
    the cause, move the file aside to ``<name>.damaged`` (one kept per entry, for inspection)
    and return None: a damaged cache entry never stops a run.
    """
    path = Path(path)
    try:
        before = os.stat(path)
    except (FileNotFoundError, NotADirectoryError):
        return None
    try:
        with h5py.File(path, "r") as f:
            if not verify_checksum(f):
                raise ValueError("checksum attribute 'sha256' missing or not matching the content")
            return reader(f)
    except Exception as exc:
        cause = f"{type(exc).__name__}: {exc}"
    aside = path.with_name(path.name + ".damaged")
    try:
        now = os.stat(path)
        if (now.st_ino, now.st_dev, now.st_mtime_ns) == (before.st_ino, before.st_dev,
                                                          before.st_mtime_ns):
            os.replace(path, aside)             # else another process already rewrote it
            where = f"moved to {aside.name}"
        else:
            where = "already replaced by another process"
    except OSError as exc:
        where = f"could not move it aside ({exc})"
    warnings.warn(CacheWarning(f"damaged cache entry {path} ({cause}); {where}; recomputing"),
                  stacklevel=2)
    return None

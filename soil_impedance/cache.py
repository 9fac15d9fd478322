"""Verified HDF5 cache entries (impedance tables, fits, ensemble cells).

A cache entry is an HDF5 file written atomically with a checksum of its content
(``uplift_common.files``: ``atomic_output``, ``stamp_checksum``). A damaged entry (a flipped
bit, a half-written file, a stale layout) is discarded with a ``CacheWarning`` and recomputed
by the caller (``read_entry``); a damaged file the user gave is the caller's to report as an
error (``uplift_common.files.require_checksum``).

Usage::

    value = read_entry(path, reader)         # reader(f: h5py.File) -> value; None: recompute
    write_entry(path, writer)                # writer(path) writes it; a failure only warns
"""
from __future__ import annotations

import dataclasses
import functools
import os
import warnings
from pathlib import Path

import h5py
import numpy as np

from uplift_common.cache_folder import default_cache_dir  # noqa: F401  (named here for its users)
from uplift_common.files import ComplexPairs, OutputWriteError, verify_checksum


class CacheWarning(UserWarning):
    """A damaged cache entry was discarded; the result is recomputed."""


def read_entry(path, reader, keep: bool = False, pairs: bool = True, into=None, chunks: bool = True):
    """Read the cache entry at ``path`` with ``reader(f: h5py.File)``; None means recompute.
    keep: call ``reader(f, data)`` instead, ``data`` the entry's datasets as the checksum
    verification read them (``{"/name": ndarray}``, a scalar as a numpy scalar): a large entry
    is read and hashed once, a complex array stored as ``<name>_real`` and ``<name>_imag``
    straight into one complex array, kept as its two parts (``uplift_common.files.ComplexPairs``;
    pairs False: an entry without such pairs, its plain datasets read by the checksum's
    low-level reading); ``into``: another such rule in its place (``uplift_common.files.checksum``'s:
    ds -> an array to read ds into, or None).

    None if the file is absent (or its folder is not one). If it cannot be opened, fails checksum verification, or
    ``reader`` raises (any Exception, including the user-input error types: ``reader`` may
    reject a stale or nonsensical entry that way), warn ``CacheWarning`` naming the file and
    the cause, move the file aside to ``<name>.damaged`` (one kept per entry, for inspection)
    and return None: a damaged cache entry never stops a run. chunks=False: the chunks of a
    chunk-digested dataset are not checked here (``verify_checksum``): the reader checks each one
    as it reads it, and a damaged one found later is discarded by ``discard_entry``.
    """
    path = Path(path)
    try:
        before = os.stat(path)
    except (FileNotFoundError, NotADirectoryError):
        return None
    try:
        with h5py.File(path, "r") as f:
            data = {} if keep else None
            rule = (into or (ComplexPairs() if pairs else None)) if keep else None
            if not verify_checksum(f, data, rule, chunks):
                raise ValueError("checksum attribute 'sha256' missing or not matching the content")
            return reader(f) if data is None else reader(f, data)
    except Exception as exc:
        cause = f"{type(exc).__name__}: {exc}"
    discard_entry(path, cause, before, stacklevel=3)
    return None


def discard_entry(path, cause: str, before=None, stacklevel: int = 2) -> None:
    """Move the damaged cache entry ``path`` aside (``<name>.damaged``) with a ``CacheWarning`` naming
    it and ``cause``, unless it is no longer the file of ``os.stat`` result ``before`` (another
    process already rewrote it; None: whatever is there now)."""
    path = Path(path)
    aside = path.with_name(path.name + ".damaged")
    try:
        now = os.stat(path)
        if before is None or (now.st_ino, now.st_dev, now.st_mtime_ns) == (before.st_ino, before.st_dev,
                                                                           before.st_mtime_ns):
            os.replace(path, aside)             # else another process already rewrote it
            where = f"moved to {aside.name}"
        else:
            where = "already replaced by another process"
    except OSError as exc:
        where = f"could not move it aside ({exc})"
    warnings.warn(CacheWarning(f"damaged cache entry {path} ({cause}); {where}; recomputing"),
                  stacklevel=stacklevel)


def write_entry(path, writer) -> None:
    """Store a cache entry: ``writer(path)`` writes it (atomically, with its checksum), its
    folder made first. A failure (disk full, read-only folder) only warns (CacheWarning): the
    run goes on without the entry."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        writer(path)
    except (OSError, OutputWriteError) as exc:
        why = exc.reason if isinstance(exc, OutputWriteError) else exc
        warnings.warn(CacheWarning(f"could not write cache entry {path} ({why}); continuing without it"),
                      stacklevel=3)


#: the scalar types fed by their ``repr`` (exact types: a subclass takes the general path)
_SCALARS = {float: "float", int: "int", bool: "bool", str: "str", complex: "complex", type(None): "NoneType"}


@functools.cache
def _dataclass_parts(cls) -> tuple:
    """(opening bytes, ((field name, its bytes), ...)) that ``feed`` writes for a dataclass type."""
    return (f"<{cls.__module__}.{cls.__qualname__}".encode(),
            tuple((f.name, f" {f.name}=".encode()) for f in dataclasses.fields(cls)))


def feed(h, value) -> None:
    """Feed ``value`` into hash ``h`` unambiguously, for a cache key of a value's inputs (each item
    typed and delimited): dataclasses (their type and every field), tuples and lists, dicts (sorted), numpy arrays (dtype, shape,
    bytes) and scalars (exact ``repr``); any other type raises TypeError (a key must not miss an input)."""
    name = _SCALARS.get(type(value))
    if name is not None:                        # the most frequent case first (a model's numbers)
        h.update(f"({name} {value!r})".encode())
    elif dataclasses.is_dataclass(value) and not isinstance(value, type):
        opening, fields = _dataclass_parts(type(value))
        h.update(opening)
        for field, text in fields:
            h.update(text)
            feed(h, getattr(value, field))
        h.update(b">")
    elif isinstance(value, (tuple, list)):
        h.update(f"[{len(value)}".encode())
        for item in value:
            h.update(b",")
            feed(h, item)
        h.update(b"]")
    elif isinstance(value, dict):
        h.update(f"{{{len(value)}".encode())
        for key in sorted(value, key=repr):
            feed(h, key)
            h.update(b":")
            feed(h, value[key])
        h.update(b"}")
    elif isinstance(value, np.ndarray):
        a = np.ascontiguousarray(value)
        if a.dtype.kind not in "biufc":
            raise TypeError(f"_feed: no digest for an array of dtype {a.dtype}")
        h.update(f"(array {a.dtype.str} {a.shape})".encode())
        h.update(memoryview(a.reshape(-1)).cast("B"))
    elif value is None or isinstance(value, (bool, int, float, complex, str, np.generic)):
        h.update(f"({type(value).__name__} {value!r})".encode())
    else:
        raise TypeError(f"_feed: no digest for a {type(value).__name__}")

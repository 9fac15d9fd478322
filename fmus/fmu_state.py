"""The FMU state of the Python kind as bytes: a nested dict of arrays and numbers written as an
npz archive (no pickles) behind a header naming the format version, the FMU (a hash of its
GUID) and a checksum of the whole buffer, so that a damaged or foreign buffer is refused
before anything is read from it (``StateRefused``).

Layout (little-endian): magic ``UPLIFTPS`` (8 bytes), format version uint32, CRC-32 (zlib) of
everything after the first 16 bytes uint32, identity uint64 (first 8 bytes of the sha256 of
the FMU's GUID), payload length uint64, then the npz payload.
"""
from __future__ import annotations

import hashlib
import io
import struct
import zlib

import numpy as np

from fmus.schema import STATE_VERSION, message
from uplift_common.errors import UserInputError

MAGIC = b"UPLIFTPS"
HEADER = struct.Struct("<8sIIQQ")


class StateRefused(UserInputError):
    """A serialised state this FMU does not take (the message says why); nothing was changed."""


def identity(guid: str) -> int:
    """The 64-bit identity of an FMU in its serialised states."""
    return int.from_bytes(hashlib.sha256(guid.encode()).digest()[:8], "little")


def flatten(tree: dict, prefix: str = "") -> dict:
    """Nested dict of arrays / numbers -> {"a/b": ndarray} (for npz, no pickles)."""
    out = {}
    for key, value in tree.items():
        k = f"{prefix}{key}"
        if isinstance(value, dict):
            out[f"{k}/"] = np.zeros(0)          # marks an (possibly empty) sub-dict
            out.update(flatten(value, f"{k}/"))
        else:
            out[k] = np.asarray(value)
    return out


def unflatten(flat: dict) -> dict:
    tree: dict = {}
    for key in sorted(flat, key=len):
        parts = key.split("/")
        node = tree
        for p in parts[:-1]:
            node = node.setdefault(p, {})
        if parts[-1]:
            v = flat[key]
            node[parts[-1]] = v.item() if v.ndim == 0 and v.dtype.kind in "fiub" else v
    return tree


def state_to_bytes(state: dict, ident: int) -> bytes:
    """The serialised state (header, then the npz payload) of the FMU of identity ``ident``."""
    buf = io.BytesIO()
    np.savez(buf, **flatten(state))
    payload = buf.getvalue()
    tail = struct.pack("<QQ", ident, len(payload)) + payload
    return MAGIC + struct.pack("<II", STATE_VERSION, zlib.crc32(tail)) + tail


def state_from_bytes(data: bytes, ident: int | None = None) -> dict:
    """The state of a buffer of state_to_bytes, checked (magic, version, checksum, length and,
    when given, the identity) before it is read; StateRefused otherwise."""
    data = bytes(data)
    why = _check(data, ident)
    if why is None:
        try:
            with np.load(io.BytesIO(data[HEADER.size:]), allow_pickle=False) as z:
                return unflatten({k: z[k] for k in z.files})
        except Exception as exc:                   # a checked buffer that does not read: not ours
            why = f"unreadable payload ({type(exc).__name__})"
    raise StateRefused(message("bad_state", size=len(data), why=why))


def _check(data: bytes, ident: int | None):
    """None, or why ``data`` is not a serialised state of the FMU ``ident``."""
    if len(data) < HEADER.size or data[:8] != MAGIC:
        return message("state_magic")
    _, version, crc, got, length = HEADER.unpack_from(data)
    if version != STATE_VERSION:
        return message("state_version", version=version, expected=STATE_VERSION)
    if zlib.crc32(data[16:]) != crc:
        return message("state_checksum")
    if ident is not None and got != ident:
        return message("state_identity", got=f"{got:016x}", expected=f"{ident:016x}")
    if length != len(data) - HEADER.size:
        return message("state_size")
    return None


def copy_state(state: dict) -> dict:
    return {k: copy_state(v) if isinstance(v, dict) else np.array(v, copy=True) if isinstance(v, np.ndarray)
            else v for k, v in state.items()}

"""The cache folder: where it is, what it holds, and its clean-up (``uplift cache``). Standard
library only: the command line finds the folder without loading numpy or h5py.

Every cache entry is keyed on what it is made of and on the digest of the code that makes it, so a
new version of the code, a changed scene or another record makes new entries and leaves the old
ones unread: the folder only grows (the mat's gap table alone is 9.5 GiB). This module lists the
entries by kind and removes those not used for a while (least recently used first is what a
person wants from a cache: the entries a run still reads are kept).

An entry is a file named ``<kind>-<key>.<ext>`` or ``<kind>_<key>.<ext>`` (the key at least 8
hexadecimal digits) in the folder or in its ``native/`` folder (the compiled runtimes), and the
``.damaged`` copy of a discarded one. Nothing else is listed or removed: hidden files (the
locks, the temporaries of writes under way, which ``uplift_common.files.sweep_orphans`` removes
once their process is gone) and files of other names are left alone, so a cache folder pointed at
a folder holding other files ($UPLIFT_CACHE) loses none of them.

An entry's last use is the later of its last read and its write (``st_atime``, ``st_mtime``):
reading a file updates its access time on Linux's default mounts (``relatime``: once a day at
most, enough for a pruning counted in days); on a file system mounted ``noatime`` it is the
entry's write time. Removing an entry another run is reading is safe: the reader keeps its open
file, and a later run recomputes the entry.
"""
from __future__ import annotations

import os
import re
import time
from dataclasses import dataclass
from pathlib import Path

#: a cache entry's file name: kind, key (hexadecimal), extension, and ``.damaged`` for a discarded one
ENTRY_NAME = re.compile(r"^(?P<kind>[a-z][a-z0-9_-]*?)[-_](?P<key>[0-9a-f]{8,})\.(?P<ext>[a-z0-9]+)"
                        r"(?P<damaged>\.damaged)?$")
#: the sub-folders that hold entries besides the folder itself (the compiled native runtimes)
SUBFOLDERS = ("native",)
DAY_S = 86400.0


def default_cache_dir() -> Path:
    """The project's cache folder (impedance tables, fits, the host's compiled runtime):
    $UPLIFT_CACHE, else ~/.cache/uplift."""
    env = os.environ.get("UPLIFT_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "uplift"


def size_text(n: int) -> str:
    """``n`` bytes as text: bytes, KiB, MiB or GiB, one decimal."""
    for unit in ("bytes", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n:.0f} {unit}" if unit == "bytes" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} TiB"


@dataclass(frozen=True)
class CacheEntry:
    """One file of the cache: path, kind (``impedance_gap``, ``fit``, ``native/uplift-fmu2``, ...;
    ``damaged`` for a discarded entry kept for inspection), bytes, last_used (seconds since the
    epoch: the later of its last read and its write)."""
    path: Path
    kind: str
    bytes: int
    last_used: float


def cache_entries(folder) -> list[CacheEntry]:
    """The entries of the cache ``folder`` (module docstring), sorted by kind then path; [] when
    the folder does not exist."""
    folder = Path(folder)
    out = []
    for sub in ("", *SUBFOLDERS):
        where = folder / sub if sub else folder
        try:
            names = os.listdir(where)
        except (FileNotFoundError, NotADirectoryError):
            continue
        for name in names:
            m = ENTRY_NAME.match(name)
            if m is None:
                continue
            path = where / name
            try:
                st = os.stat(path, follow_symlinks=False)
            except FileNotFoundError:                     # removed meanwhile (another process)
                continue
            if not os.path.isfile(path) or os.path.islink(path):
                continue
            kind = "damaged" if m["damaged"] else (f"{sub}/{m['kind']}" if sub else m["kind"])
            out.append(CacheEntry(path, kind, st.st_size, max(st.st_atime, st.st_mtime)))
    return sorted(out, key=lambda e: (e.kind, str(e.path)))


def prune_cache(folder, older_than_days: float, now: float | None = None) -> list[CacheEntry]:
    """Remove the entries of ``folder`` last used more than ``older_than_days`` days before
    ``now`` (default: the clock; 0 removes every entry); return those removed."""
    if not older_than_days >= 0:
        raise ValueError(f"older_than_days must be >= 0, not {older_than_days!r}")
    limit = (time.time() if now is None else now) - older_than_days * DAY_S
    removed = []
    for entry in cache_entries(folder):
        if entry.last_used <= limit or older_than_days == 0:
            try:
                os.unlink(entry.path)
            except FileNotFoundError:                     # removed meanwhile
                continue
            removed.append(entry)
    return removed


def usage(entries) -> dict[str, dict]:
    """{kind: {"entries": count, "bytes": their size, "last_used": the least recently used one's}},
    the largest kind first: what ``uplift cache`` reports."""
    kinds: dict[str, dict] = {}
    for e in entries:
        k = kinds.setdefault(e.kind, {"entries": 0, "bytes": 0, "last_used": e.last_used})
        k["entries"] += 1
        k["bytes"] += e.bytes
        k["last_used"] = min(k["last_used"], e.last_used)
    return dict(sorted(kinds.items(), key=lambda kv: -kv[1]["bytes"]))


def usage_lines(entries, now: float | None = None) -> list[str]:
    """One line per kind of ``usage`` (entries, size, the least recently used entry's age in days)
    and a total: what ``uplift cache`` prints."""
    now = time.time() if now is None else now
    lines = [f"{'kind':24s} {'entries':>7s} {'size':>10s}  {'oldest use':>10s}"]
    for kind, k in usage(entries).items():
        age = (now - k["last_used"]) / DAY_S
        lines.append(f"{kind:24s} {k['entries']:7d} {size_text(k['bytes']):>10s}  {age:7.1f} d")
    lines.append(f"{'total':24s} {len(entries):7d} {size_text(sum(e.bytes for e in entries)):>10s}")
    return lines

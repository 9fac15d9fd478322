"""The digest of the code a cached value depends on: one function for every cache of the project.

A cached value (an impedance table, a rational fit, a step-doubling answer, an ensemble cell) is
keyed by its inputs and by the code that computed it, so that changed code never reuses an
answer of the old code. ``code_digest(*names)`` hashes the project's own source files named by
import path, without importing them:

- a module, ``"soil_impedance.bem"``: its ``.py`` file;
- a folder, ``"soil_impedance.fit"`` or ``"fmus.native"`` (a package, or the C runtime's
  sources that are package data): every source under it (``SOURCE_SUFFIXES``: Python and C),
  in sorted order, each with its path, so a renamed or moved file changes the digest too.

A name that resolves to nothing raises ``MissingSourceError`` naming it: a renamed file fails the
tests that digest every cache's sources (tests/integration/test_code_digest.py), never a run
that silently skips it. The files are read once per process: a digest once per set of names, a
name's files listed and each file read once whatever the sets that name it (a warm run keys
seven caches on overlapping sets: the structure's package is in three).
"""
from __future__ import annotations

import functools
import hashlib
import importlib.util
from pathlib import Path

from uplift_common.errors import ComputationError

#: the files a folder contributes: Python modules and the C runtime's sources and headers
SOURCE_SUFFIXES = (".py", ".c", ".h")
#: every package of the project (a digest of all of them: ``code_digest(*PACKAGES)``)
PACKAGES = ("uplift_common", "soil_impedance", "structure", "fmus", "orchestrator")


class MissingSourceError(ComputationError):
    """A source file a cache is keyed on is not in the installed package (a file renamed without
    updating the cache's list, or a damaged installation)."""


@functools.cache
def _package_root(top: str) -> Path:
    spec = importlib.util.find_spec(top)
    if spec is None or not spec.submodule_search_locations:
        raise MissingSourceError(f"code digest: no package {top!r} is installed (reinstall the project)")
    return Path(next(iter(spec.submodule_search_locations))).resolve()


def source_files(name: str) -> list[Path]:
    """The source files ``name`` (a dotted module or folder name) stands for, sorted."""
    return list(_source_files(name))


@functools.cache
def _source_files(name: str) -> tuple:
    top, *rest = name.split(".")
    root = _package_root(top)
    path = root.joinpath(*rest)
    if path.is_dir():
        files = sorted(p for p in path.rglob("*") if p.suffix in SOURCE_SUFFIXES and p.is_file()
                       and "__pycache__" not in p.parts)
        if files:
            return tuple(files)
    elif path.with_suffix(".py").is_file():
        return (path.with_suffix(".py"),)
    raise MissingSourceError(f"code digest: {name!r} names no source file (looked for {path.with_suffix('.py')} "
                             f"and for sources under {path}/): a file was renamed or removed; update the list "
                             "of sources that names it")


@functools.cache
def code_digest(*names: str) -> str:
    """SHA-256 (hex) of the source files of ``names`` (see the module docstring), each file with
    its path relative to its package's parent folder."""
    h = hashlib.sha256()
    seen = set()
    for name in names:
        base = _package_root(name.split(".")[0]).parent
        for path in _source_files(name):
            if path in seen:
                continue
            seen.add(path)
            h.update(_entry(path, base))
    return h.hexdigest()


@functools.cache
def _entry(path: Path, base: Path) -> bytes:
    """What a source file adds to a digest: its path relative to ``base`` and its bytes."""
    return path.relative_to(base).as_posix().encode() + b"\0" + path.read_bytes() + b"\0"

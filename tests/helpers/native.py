"""The C runtime compiled once for the tests: ``seed_native(cache_dir)`` puts the libraries of
the native stepper (and of the native FMUs) into a fresh cache folder, so that a test keyed on
its own cache folder does not compile them again (``from helpers.native import seed_native``).

The libraries are named by the content hash of their sources, compiler and flags
(fmus.native_stepper._digest): a copy under that name is what a build there would write, and a
change to fmus/native gives another name, built anew. The copies come from the project's cache
folder as it was when the tests started ($UPLIFT_CACHE, else ~/.cache/uplift; a test that points
$UPLIFT_CACHE elsewhere does not move it), built there once per content hash (about 20 CPU s
each, the whole of a small test's time)."""
from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

from fmus import native_stepper
from fmus.native_build import SOURCES, NativeBuildError
from soil_impedance.cache import default_cache_dir

#: where the libraries are built once: the cache folder of the test session's environment
SHARED = native_stepper.cache_folder(default_cache_dir())


def _shared(stem: str, sources) -> Path:
    """The library ``stem`` of ``sources`` in SHARED, compiled there if it is not yet; the build
    under a file lock, so that the test processes started together (pytest-xdist's workers)
    compile it once, the others waiting for it, instead of each compiling the same bytes."""
    try:
        import fcntl
    except ImportError:                              # (Windows: no lock, at worst a build each)
        return native_stepper._compiled(SHARED, stem, sources)
    SHARED.mkdir(parents=True, exist_ok=True)
    with open(SHARED / f".{stem}.lock", "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            return native_stepper._compiled(SHARED, stem, sources)
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def _copy_into(target: Path, fmu: bool) -> bool:
    """The host library (and with ``fmu`` the FMI 2.0 runtime) copied from SHARED into the folder
    ``target``; False (nothing more copied) when it cannot be built here."""
    wanted = [("uplift-host", native_stepper.HOST_SOURCES)] + ([("uplift-fmu2", SOURCES)] if fmu else [])
    for stem, sources in wanted:
        try:
            built = _shared(stem, sources)
        except (NativeBuildError, OSError, subprocess.SubprocessError, ValueError):
            return False
        target.mkdir(parents=True, exist_ok=True)
        if not (target / built.name).exists():
            shutil.copy2(built, target / built.name)
    return True


def seed_native(cache_dir, fmu: bool = False) -> Path:
    """``cache_dir`` (made if needed) holding the host library of the native stepper (and with
    ``fmu`` the FMI 2.0 runtime of the native FMUs) as a build into it would; returns it. Nothing
    is copied when the library cannot be built here (the tests then see no compiler, as before)."""
    cache_dir = Path(cache_dir)
    _copy_into(native_stepper.cache_folder(cache_dir), fmu)
    return cache_dir


def seed_process_folder() -> Path:
    """The test process's own folder of the C runtime (where a run with no cache folder,
    ``cache_dir=None``, builds it: fmus.native_stepper's temporary folder of the process, removed
    at exit) made now and holding both libraries as builds into it would; returns it. Called by
    tests/conftest.py before the test modules are collected: several of them ask
    ``native_stepper.library()`` at import (a skip mark), and every test process (each xdist
    worker) compiled the host library there (~20 CPU s), and the FMU runtime at its first
    co-simulation without a cache folder. The library a process loads is the same either way
    (one content hash); the compile itself stays tested where a test asks for it (a fresh cache
    folder, --no-cache in a child process, a changed source)."""
    folder = native_stepper._folder(None)
    _copy_into(folder, fmu=True)
    return folder

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


def seed_native(cache_dir, fmu: bool = False) -> Path:
    """``cache_dir`` (made if needed) holding the host library of the native stepper (and with
    ``fmu`` the FMI 2.0 runtime of the native FMUs) as a build into it would; returns it. Nothing
    is copied when the library cannot be built here (the tests then see no compiler, as before)."""
    cache_dir = Path(cache_dir)
    target = native_stepper.cache_folder(cache_dir)
    wanted = [("uplift-host", native_stepper.HOST_SOURCES)] + ([("uplift-fmu2", SOURCES)] if fmu else [])
    for stem, sources in wanted:
        try:
            built = native_stepper._compiled(SHARED, stem, sources)
        except (NativeBuildError, OSError, subprocess.SubprocessError, ValueError):
            return cache_dir
        target.mkdir(parents=True, exist_ok=True)
        if not (target / built.name).exists():
            shutil.copy2(built, target / built.name)
    return cache_dir

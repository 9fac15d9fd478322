"""One digest of the code for every cache (uplift_common.code): each cache's list of sources names
files that exist, a renamed file fails with its name, and the digest follows the C runtime too, so
a resumed ensemble recomputes the cells of a changed stepper."""
import importlib
import json
import os
import shutil
import subprocess
import sys

import pytest

from uplift_common.code import PACKAGES, MissingSourceError, code_digest, source_files
from helpers import ROOT, small_reactor, write_scene
from helpers.native import seed_native

#: every list of sources a cache is keyed on: (module, attribute)
CACHE_SOURCES = [("soil_impedance.sweep", "CODE"), ("soil_impedance.sweep", "FAST_CODE"), ("soil_impedance.fit.options", "CODE"),
                 ("orchestrator.run", "DT_CHECK_CODE"), ("orchestrator.run", "MOTION_CODE"), ("uplift_common.code", "PACKAGES"),
                 ("orchestrator.timefreq.setup_cache", "SETUP_CODE")]


@pytest.mark.parametrize("module, attribute", CACHE_SOURCES)
def test_every_cache_names_sources_that_exist(module, attribute):
    names = getattr(importlib.import_module(module), attribute)
    assert all(source_files(n) for n in names)
    assert len(code_digest(*names)) == 64


def test_the_project_digest_covers_the_c_runtime():
    files = {p.relative_to(ROOT).as_posix() for p in source_files("fmus")}
    assert {"fmus/native/stepper.c", "fmus/native/soil.c", "fmus/native/include/fmu.h", "fmus/schema.py"} <= files
    assert not any("__pycache__" in f for f in files)


def _copy(tmp_path):
    """The packages copied to ``tmp_path`` (what a child process with it on PYTHONPATH imports)."""
    for package in PACKAGES:
        shutil.copytree(ROOT / package, tmp_path / package, ignore=shutil.ignore_patterns("__pycache__"))
    return {**os.environ, "PYTHONPATH": str(tmp_path)}


def test_a_renamed_source_fails_with_its_name(tmp_path):
    """The fit's cache key digests soil_impedance/passivity.py; renamed in a copy, the digest (what
    the test above runs on the tree) raises naming it and the fix, not a bare FileNotFoundError."""
    env = _copy(tmp_path)
    (tmp_path / "soil_impedance" / "passivity.py").rename(tmp_path / "soil_impedance" / "passive.py")
    code = "from soil_impedance.fit.options import code_version; code_version()"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=tmp_path)
    assert proc.returncode != 0
    assert "MissingSourceError" in proc.stderr and "'soil_impedance.passivity' names no source file" in proc.stderr
    assert str(tmp_path / "soil_impedance" / "passivity.py") in proc.stderr
    with pytest.raises(MissingSourceError, match="soil_impedance.no_such_module"):
        code_digest("soil_impedance.no_such_module")


@pytest.mark.slow
def test_a_changed_c_source_recomputes_a_resumed_ensemble(tmp_path):
    """An ensemble in a copy of the packages; rerun as it is, its cells are reused; rerun after a
    change to the C stepper (fmus/native/stepper.c), every cell is computed again. The copy's
    C runtime is the tree's (the same content hash): compiled once for the tests, copied into
    its cache; the changed one is compiled there."""
    env = {**_copy(tmp_path), "UPLIFT_CACHE": str(seed_native(tmp_path / "cache"))}
    scene = tmp_path / "small.toml"
    write_scene(scene, small_reactor(analysis={"routes": ["winkler"]}))
    args = [sys.executable, "-m", "orchestrator.cli", "ensemble", str(scene), "--pga", "0.4", "--seeds", "1", "2",
            "--workers", "1", "-o", str(tmp_path / "ens.h5"), "--json"]

    def ensemble():
        proc = subprocess.run(args, capture_output=True, text=True, env=env, cwd=tmp_path)
        assert proc.returncode == 0, proc.stderr
        out = json.loads(proc.stdout)
        return out["computed"], out["reused"]

    assert ensemble() == (2, 0)
    assert ensemble() == (0, 2)
    stepper = tmp_path / "fmus" / "native" / "stepper.c"
    stepper.write_text(stepper.read_text() + "\n/* a change to the C runtime */\n")
    assert ensemble() == (2, 0)

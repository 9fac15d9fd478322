"""Fixtures shared by test modules."""
import os

# Two xdist workers on two cores: OpenBLAS's own threads on top only add contention (a BLAS-heavy
# test of 11 s ran 83 s beside another); .ci/run sets the same. Set before numpy loads; the CLI
# subprocesses of the tests inherit it.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import pytest

from helpers import EXPORT_MOTION, small_scene, soil_model


@pytest.fixture(scope="session")
def exported(tmp_path_factory):
    """small_scene() exported once for the session as pythonfmu FMUs (structure.fmu, soil.fmu,
    coupled.fmu, system.ssd, system.ssp) with EXPORT_MOTION (the native kind: test_native_fmu.py)."""
    from orchestrator.export import export_scene
    scene = small_scene()
    return export_scene(scene, tmp_path_factory.mktemp("export"), soil_model(scene), motion=EXPORT_MOTION,
                        kind="python")


@pytest.fixture(scope="session")
def exported_native(tmp_path_factory):
    """The same export as ``exported`` as native FMUs (linux64, win64, darwin64 binaries)."""
    from orchestrator.export import export_scene
    scene = small_scene()
    return export_scene(scene, tmp_path_factory.mktemp("export_native"), soil_model(scene), motion=EXPORT_MOTION,
                        kind="native")

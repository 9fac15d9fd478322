"""Fixtures shared by test modules."""
import os

# Two xdist workers on two cores: OpenBLAS's own threads on top only add contention (a BLAS-heavy
# test of 11 s ran 83 s beside another); .ci/run sets the same. Set before numpy loads; the CLI
# subprocesses of the tests inherit it.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import pytest

from helpers import EXPORT_MOTION, small_scene, soil_model
from helpers.native import seed_process_folder

# The C runtime compiled once for the test session (helpers/native.py) and copied into this
# process's folder for runs without a cache folder, before the test modules are collected: each
# test process (each xdist worker) compiled it there itself (~20 CPU s each).
seed_process_folder()


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


@pytest.fixture(scope="session")
def scheduler():
    """The address of a running dask scheduler with one worker process of one thread (the
    local cluster of ``uplift ensemble --workers 1``, with its worker settings), started once for
    the session: the ensembles whose test is about their cells and their files, not about
    starting and stopping a local cluster, run on it (``--scheduler``) instead of paying a
    cluster's start, its worker's imports and its shutdown each. The tests of the local cluster
    itself (test_ensemble's two workers, a killed worker, Ctrl-C as it starts) keep their own."""
    import logging

    import dask
    from dask.distributed import LocalCluster

    from orchestrator.ensemble.cluster import LOCAL_WORKER_CONFIG
    with dask.config.set(LOCAL_WORKER_CONFIG):
        cluster = LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None,
                               silence_logs=logging.CRITICAL)
    with cluster:
        yield cluster.scheduler_address

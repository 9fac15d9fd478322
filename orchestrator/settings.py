"""What the command line and the routes share: the cache folder, thread control (the exit codes
are in ``orchestrator.exit_codes``).

Threads. The project's dense matrices are small (a few hundred wide: Newton matrices, the
TF operator's bands, the fit's least squares) and a 2-core machine is often shared:
threaded BLAS there is no faster idle and several times slower beside a busy process
(threads spin-wait for busy cores). Every computation
started by the orchestrator therefore runs under ``compute_threads()``: BLAS/OpenMP pools at
``$UPLIFT_THREADS`` threads (default 1). Results do not depend on it beyond round-off.
"""
from __future__ import annotations

import os
import threading
from contextlib import contextmanager

from uplift_common.cache_folder import default_cache_dir  # noqa: F401  (the command line's: no h5py loaded)

#: the kinds of FMU ``uplift export`` writes (orchestrator.export; named here so the command line
#: lists them without loading the FMU stack)
FMU_KINDS = ("python", "native")


def thread_count() -> int:
    """BLAS threads for computations: $UPLIFT_THREADS (a positive integer), default 1."""
    raw = os.environ.get("UPLIFT_THREADS", "1")
    try:
        n = int(raw)
    except ValueError:
        n = 0
    if n < 1:
        raise ValueError(f"UPLIFT_THREADS = {raw!r} must be a positive integer (BLAS threads; default 1)")
    return n


#: the variables a BLAS or OpenMP pool reads its size from when its library loads
THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


_inside = threading.local()         # .limits: the limits of the compute_threads blocks this thread is in


@contextmanager
def compute_threads(n: int | None = None):
    """Run the block with BLAS and OpenMP thread pools limited to ``n`` (default
    ``thread_count()``); the previous limits come back on exit. The pools loaded before the block
    are limited by threadpoolctl; one loaded inside it (scipy's BLAS, imported on first use) reads
    its size from the environment when it loads, so the block sets those variables to ``n`` too:
    without them that pool would start at the machine's cores and the round-off would follow.
    A block inside another of the same ``n`` in the same thread (the command line's around a
    run's own) changes nothing: the outer one holds the limits and the variables until it ends."""
    n = n or thread_count()
    limits = _inside.__dict__.setdefault("limits", [])
    if limits and limits[-1] == n:
        limits.append(n)
        try:
            yield
        finally:
            limits.pop()
        return
    from threadpoolctl import threadpool_limits     # start-up cost: only a command that computes
    saved = {k: os.environ.get(k) for k in THREAD_VARIABLES}
    os.environ.update({k: str(n) for k in THREAD_VARIABLES})
    limits.append(n)
    try:
        with threadpool_limits(limits=n):
            yield
    finally:
        limits.pop()
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v

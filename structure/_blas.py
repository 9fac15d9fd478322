"""Run small dense LAPACK calls single-threaded.

The Newton matrices are a few hundred wide: multithreaded BLAS is no faster there and, on a
loaded machine, is 10-100x slower (threads spin-wait for busy cores). The orchestrator runs
every computation with one BLAS thread already (orchestrator.settings.compute_threads); this
guard gives callers of ``structure.simulate`` and of the stepper (the FMUs) the same behaviour.
"""
from __future__ import annotations

import functools


@functools.lru_cache(maxsize=1)
def _controller():
    # listing the loaded libraries costs ~1 ms; limiting through a listed controller ~40 us.
    # Imported here, on the first stepper made, not with this module: a warm run makes none
    import scipy.linalg  # noqa: F401  (scipy's BLAS loaded before the controller lists the libraries)
    from threadpoolctl import ThreadpoolController
    return ThreadpoolController()


def single_threaded_blas():
    """Context manager: BLAS pools at one thread inside, restored on exit."""
    return _controller().limit(limits=1, user_api="blas")

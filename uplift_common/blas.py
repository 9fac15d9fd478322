"""Run dense LAPACK calls on one BLAS thread.

Where the matrices are small or thin, multithreaded BLAS is no faster and, on a loaded machine,
10-100x slower (threads spin-wait for busy cores): the structure's Newton matrices, a few hundred
wide (``structure.simulate`` and the stepper of the FMUs), and the streamed fit's tall-skinny QRs
(soil_impedance/fit/streamed.py). The orchestrator runs every computation with one BLAS thread
already (orchestrator.settings.compute_threads); this guard gives other callers the same behaviour.
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

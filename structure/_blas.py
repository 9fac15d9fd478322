"""Run small dense LAPACK calls single-threaded.

The Newton matrices are a few hundred wide: multithreaded OpenBLAS is no faster there and,
on a loaded machine, is 10-100x slower (threads spin-wait for busy cores). This context
manager sets every loaded OpenBLAS to one thread and restores the previous count; it is a
no-op when no OpenBLAS is found (MKL, Accelerate...). stdlib ctypes only.
"""
from __future__ import annotations

import ctypes
from contextlib import contextmanager

_NAMES = [("scipy_openblas_get_num_threads64_", "scipy_openblas_set_num_threads64_"),
          ("scipy_openblas_get_num_threads", "scipy_openblas_set_num_threads"),
          ("openblas_get_num_threads64_", "openblas_set_num_threads64_"),
          ("openblas_get_num_threads", "openblas_set_num_threads")]
_handles = None


def _find():
    global _handles
    if _handles is not None:
        return _handles
    _handles = []
    try:
        paths = {ln.split()[-1] for ln in open("/proc/self/maps") if "openblas" in ln.lower()}
    except OSError:
        paths = set()
    for p in sorted(paths):
        try:
            lib = ctypes.CDLL(p)
        except OSError:
            continue
        for g, s in _NAMES:
            if hasattr(lib, g) and hasattr(lib, s):
                get, put = getattr(lib, g), getattr(lib, s)
                get.restype = ctypes.c_int
                _handles.append((get, put))
                break
    return _handles


@contextmanager
def single_threaded_blas():
    hs = _find()
    old = [get() for get, _ in hs]
    for _, put in hs:
        put(1)
    try:
        yield
    finally:
        for (_, put), n in zip(hs, old):
            put(n)

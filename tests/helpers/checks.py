"""Comparisons of arrays for tests."""
import numpy as np


def rel(a, b) -> float:
    """max |a - b| / max |b|: the error of ``a`` relative to the reference ``b`` (any shapes
    that broadcast)."""
    a, b = np.asarray(a), np.asarray(b)
    return float(np.abs(a - b).max() / np.abs(b).max())

"""Comparisons of arrays for tests."""
import numpy as np


def rel(a, b) -> float:
    """max |a - b| / max |b|: the error of ``a`` relative to the reference ``b`` (any shapes
    that broadcast; 0 for two zero arrays)."""
    a, b = np.asarray(a), np.asarray(b)
    return float(np.abs(a - b).max() / max(np.abs(b).max(), 1e-300))

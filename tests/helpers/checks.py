"""Comparisons of arrays for tests."""
import numpy as np


def rel(a, b) -> float:
    """max |a - b| / max |b|: the error of ``a`` relative to the reference ``b`` (any shapes
    that broadcast; 0 for two zero arrays)."""
    a, b = np.asarray(a), np.asarray(b)
    return float(np.abs(a - b).max() / max(np.abs(b).max(), 1e-300))


def assert_pair_rolls_back(s, g, step, warm: int = 80, steps: int = 10):
    """Two initialised FMU slaves ``s``, ``g`` stepped by ``step(s, g, k)`` (-> output array)
    ``warm`` steps (into the uplift phase), saved through serialised states, stepped ``steps``
    more, restored and stepped again: the replay equals the first run bit for bit."""
    for k in range(1, warm + 1):
        step(s, g, k)
    saved = [f.serialize(f.get_state()) for f in (s, g)]
    first = [step(s, g, k) for k in range(warm + 1, warm + steps + 1)]
    for f, blob in zip((s, g), saved):
        f.set_state(f.deserialize(blob))
    replay = [step(s, g, k) for k in range(warm + 1, warm + steps + 1)]
    assert np.abs(first[-1][:6]).max() > 0
    for a, b in zip(first, replay):
        assert np.array_equal(a, b)

"""The response spectra's loop in C (fmus/native/spectra.c), taken when a run has loaded the native
runtime, gives the numpy loop's numbers bit for bit (the floor spectra of a results file do not
depend on which route ran first), NaN where numpy gives NaN; without the library the numpy loop
runs, and nothing is compiled for it."""
import numpy as np
import pytest

from fmus import native_stepper
from helpers.native import seed_native
from orchestrator import spectra
from orchestrator.spectra import FLOOR_FREQUENCIES_HZ, floor_spectra, response_spectra


@pytest.fixture(scope="module")
def loaded(tmp_path_factory):
    lib = native_stepper.library(native_stepper.cache_folder(seed_native(tmp_path_factory.mktemp("native"))))
    if lib is None:
        pytest.skip("no C compiler for the native runtime")
    return lib


def _histories(nt=700, m=5, seed=4):
    """m ground-motion-like histories (nt, m), m/s²: filtered noise of a few m/s², one column of zeros."""
    rng = np.random.default_rng(seed)
    acc = np.cumsum(rng.standard_normal((nt, m)), axis=0)
    acc -= np.linspace(0, 1, nt)[:, None] * acc[-1]
    acc[:, 2] = 0.0
    return acc


def _numpy(monkeypatch, *args, **kw):
    with monkeypatch.context() as m:
        m.setattr(spectra, "_native", lambda: None)
        return response_spectra(*args, **kw)


@pytest.mark.parametrize("damping", [0.0, 0.05, 0.3])
def test_the_c_loop_gives_the_numpy_loops_bits(loaded, monkeypatch, damping):
    assert spectra._native() is not None                        # the C loop is the one taken below
    acc, dt, periods = _histories(), 0.01, 1 / FLOOR_FREQUENCIES_HZ
    native, numpy = response_spectra(acc, dt, periods, damping), _numpy(monkeypatch, acc, dt, periods, damping)
    assert len(native) == len(numpy) == acc.shape[1]
    for a, b in zip(native, numpy):
        for field in ("sd", "psv", "psa", "sa"):
            assert np.array_equal(getattr(a, field), getattr(b, field)), field
    assert native[0].sd.max() > 0 and np.all(native[2].sd == 0)


def test_a_nan_gives_the_numpy_loops_nan(loaded, monkeypatch):
    acc = _histories(nt=400, m=3)
    acc[300, 1] = np.nan                                         # after the first chunk of 256 steps
    native, numpy = response_spectra(acc, 0.02, [0.1, 1.0]), _numpy(monkeypatch, acc, 0.02, [0.1, 1.0])
    for a, b in zip(native, numpy):
        assert np.array_equal(a.sd, b.sd, equal_nan=True) and np.array_equal(a.sa, b.sa, equal_nan=True)
    assert np.all(np.isnan(native[1].sd)) and np.all(np.isfinite(native[0].sd))


def test_floor_spectra_are_the_same_with_and_without_the_library(loaded, monkeypatch):
    acc = _histories(nt=501, m=6)
    nodes = {"top": acc[:, :3], "mid": acc[:, 3:] * 1e-9}
    native = floor_spectra(nodes, 0.005)
    with monkeypatch.context() as m:
        m.setattr(native_stepper, "loaded_library", lambda: None)
        assert spectra._native() is None
        numpy = floor_spectra(nodes, 0.005)
    assert np.array_equal(native, numpy, equal_nan=True) and np.isfinite(native).sum() == 5 * 120

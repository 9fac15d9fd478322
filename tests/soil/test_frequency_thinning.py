"""Fewer frequencies where the impedance is smooth (soil_impedance.frequencies.thinned_sweep): held-out
frequencies are swept and measured, never guessed; the thinning is recorded in the table's provenance."""
import numpy as np
import pytest

from soil_impedance import circle_mesh, impedance_sweep
from soil_impedance.frequencies import ThinningError, thinned_sweep


@pytest.fixture(scope="module")
def case():
    """Disk R = 10 m, 29 nodes, causal 3 % half-space (vs 500 m/s), 0..25 Hz at 41 frequencies: the whole sweep."""
    from soil_impedance import Material, SoilProfile
    prof = SoilProfile((), Material(vs=500.0, rho=2000.0, nu=0.3, damping=0.03, damping_model="causal"))
    mesh = circle_mesh(10, 3.3)
    f = np.linspace(0, 25, 41)
    calls = []

    def sweep(fs):
        calls.append(np.array(fs))
        return impedance_sweep(prof, mesh, fs, outputs=("rigid", "gap"))
    return sweep, f, sweep(f), calls


def _rel(a, b):
    return np.linalg.norm(a - b, axis=(1, 2)) / np.linalg.norm(b, axis=(1, 2))


def test_thinning_sweeps_fewer_frequencies_and_its_measured_error_bounds_the_true_one(case):
    """tol = 1e-3: fewer than the 41 frequencies are swept; the swept ones are exact (bit-identical to the
    whole sweep: same BEM per frequency); the true interpolation error at every other grid frequency
    (against the whole sweep) is within tol; the report and the provenance say what was done."""
    sweep, f, full, calls = case
    del calls[:]
    tables, rep = thinned_sweep(sweep, f, tol=1e-3, step=4)
    swept = np.isin(f, rep.swept_hz)
    assert 11 <= swept.sum() < f.size and len(rep.held_out) >= 10
    assert all(np.all(np.isin(c, f)) for c in calls) and sum(c.size for c in calls) == swept.sum()
    for o in ("rigid", "gap"):
        t = tables[o]
        assert np.array_equal(t.frequencies_hz, f)
        assert np.array_equal(t.matrices[swept], full[o].matrices[swept])
        err = _rel(t.matrices[~swept], full[o].matrices[~swept])
        assert err.max() <= 1e-3, o
        assert t.provenance["frequency_thinning"]["n_swept"] == swept.sum() and t.hash != full[o].hash
    assert 0 < rep.accepted_error <= 1e-3 and "of 41 frequencies swept" in rep.lines()[0]
    only, rep2 = thinned_sweep(sweep, f, tol=1e-3, step=4, mode="swept")
    assert np.array_equal(only["gap"].frequencies_hz, f[swept]) and rep2.swept_hz == rep.swept_hz


def test_a_tolerance_no_interpolation_meets_sweeps_everything(case):
    sweep, f, full, _ = case
    tables, rep = thinned_sweep(sweep, f, tol=1e-14, step=2)
    assert len(rep.swept_hz) == f.size
    assert np.array_equal(tables["gap"].matrices, full["gap"].matrices)


@pytest.mark.parametrize("kw, match", [({"tol": 0}, "frequency_tol"), ({"tol": 1e-3, "step": 1}, "step"),
                                       ({"tol": 1e-3, "mode": "some"}, "mode")])
def test_bad_thinning_requests_name_the_key(case, kw, match):
    with pytest.raises(ThinningError, match=match):
        thinned_sweep(case[0], case[1], **kw)

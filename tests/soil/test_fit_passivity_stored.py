"""Passivity verified once per fit and stored with it: the fit cache entry (checksummed) carries
the steppers' passivity test, a run that reads the fit does not test again, and a model whose
content differs from what was tested is tested again."""
import pickle

import numpy as np
import pytest

import soil_impedance.passivity as passivity
from soil_impedance import ImpedanceTable
from soil_impedance.convolution import RecursiveConvolutionSoil
from soil_impedance.fit import fit_table
from soil_impedance.rational import FitError

from helpers import oscillator_model


@pytest.fixture(scope="module")
def table():
    """A two-DOF table of a known passive oscillator model (fast to fit)."""
    model = oscillator_model(np.diag([2.0, 1.0]), E=np.diag([0.1, 0.05]), terms=[(30.0, 2.0, 1.0, np.diag([0.5, 0.2]))])
    f = np.linspace(0.0, 2.0, 41)
    return ImpedanceTable(f, model(2j * np.pi * f), ["uz", "rx"], {"case": "oscillator"})


def _no_test(monkeypatch):
    """Make the exact test fail loudly, and forget this process's reports."""
    monkeypatch.setattr(passivity, "_assess", lambda *a, **k: (_ for _ in ()).throw(AssertionError("tested again")))
    passivity._REPORTS.clear()


def test_fit_stores_the_steppers_test_and_a_cached_fit_is_not_tested_again(table, tmp_path, monkeypatch):
    passivity._REPORTS.clear()
    first = fit_table(table, tol=0.01, cache_dir=tmp_path)
    rec = first.model.provenance[passivity.VERIFIED]
    assert rec["digest"] == first.model.digest and rec["report"]["passive"]
    reference = passivity.check_passive(first.model)          # (this process's cache: the fit's own test)
    _no_test(monkeypatch)
    again = fit_table(table, tol=0.01, cache_dir=tmp_path)     # read from the checksummed entry
    assert again.report.cached and again.model.digest == first.model.digest
    rep = passivity.check_passive(again.model)
    assert rep == reference
    RecursiveConvolutionSoil(again.model, 0.01)                # the stepper's guard reads the stored test
    # a worker process gets the model by pickling: the record travels with it
    passivity._REPORTS.clear()
    RecursiveConvolutionSoil(pickle.loads(pickle.dumps(again.model)), 0.01)


def test_a_changed_model_or_other_settings_are_tested_again(table, monkeypatch):
    fit = fit_table(table, tol=0.01)
    changed = fit.model.__class__(fit.model.poles, fit.model.residues, fit.model.D * 1.5, fit.model.E,
                                  fit.model.dofs, dict(fit.model.provenance))
    _no_test(monkeypatch)
    with pytest.raises(AssertionError, match="tested again"):
        passivity.check_passive(changed)                       # digest differs from the stored one
    with pytest.raises(AssertionError, match="tested again"):
        passivity.check_passive(fit.model, n_grid=100)         # settings differ
    passivity.check_passive(fit.model)


def test_a_malformed_stored_report_is_a_fit_error():
    with pytest.raises(FitError, match="malformed passivity report"):
        passivity.PassivityReport.from_dict({"passive": True})


def _counting(monkeypatch):
    """Count the passivity tests run (``_assess`` calls: the enforcement's and ``check_passive``'s)."""
    calls = []
    real = passivity._assess

    def counted(*a, **k):
        calls.append(k.get("violations_only", False))
        return real(*a, **k)
    monkeypatch.setattr(passivity, "_assess", counted)
    passivity._REPORTS.clear()
    return calls, real


@pytest.mark.parametrize("method, repeats", [("auto", 0), ("hamiltonian", 0), ("sweep", 1)])
def test_the_enforcements_passing_test_is_the_stored_one_not_run_again(table, monkeypatch, method, repeats):
    """The enforcement's last test (passive as fitted: the same model, the same grid and method as the
    steppers' "auto" for this size, or "auto" itself) is the report stored with the fit: the test runs
    once, and the stored report equals a fresh test of the stored model, field by field. The sweep is
    not what "auto" runs at this size (the exact test is): then the steppers' test runs once more."""
    calls, real = _counting(monkeypatch)
    got = fit_table(table, tol=0.01, passivity_method=method)
    assert got.model.provenance["passivity_iterations"] == 0
    assert calls.count(True) == 1 and calls.count(False) == repeats, calls   # the enforcement's (+ repeat)
    stored = passivity.PassivityReport.from_dict(got.model.provenance[passivity.VERIFIED]["report"])
    fresh = passivity._report(got.model.scaled, real(got.model.scaled))  # the test run again, directly
    assert stored.to_dict() == fresh.to_dict() and stored.passive


def test_a_model_changed_by_the_enforcement_is_tested_again_when_its_scaling_moved(monkeypatch):
    """After corrections the model is rebuilt from its scaled coefficients and scaled again (K(0) moved):
    the enforcement's test is kept for it only when the new scaled model is the tested one bit for bit,
    and whichever way, ``check_passive`` gives what a fresh test of the model gives."""
    from soil_impedance.rational import RationalModel
    w0, zeta = 2 * np.pi * 1.0, 0.02
    p = -zeta * w0 + 1j * w0 * np.sqrt(1 - zeta ** 2)
    r = 3.0 * w0 ** 2 / (p - np.conj(p))                            # a negative damping peak at 1 Hz
    V = np.diag([1.0, 0.0])
    bad = RationalModel(np.array([p, np.conj(p)]), np.array([r * V, np.conj(r) * V]), np.diag([2.0, 1.0]),
                        np.diag([0.01, 0.005]), ["uz", "rx"], {"f_max_hz": 2.0})
    assert not passivity.check_passive(bad).passive
    calls, real = _counting(monkeypatch)
    fixed, rep, it = passivity.enforce_passivity(bad, np.linspace(0, 2, 41))
    assert it >= 1 and rep.passive
    again = passivity.check_passive(fixed)
    fresh = passivity._report(fixed.scaled, real(fixed.scaled))
    assert again.to_dict() == fresh.to_dict()

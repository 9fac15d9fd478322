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

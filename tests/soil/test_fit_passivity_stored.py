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


def test_a_cached_fit_keeps_its_stored_digest_and_a_user_s_fit_file_is_hashed(table, tmp_path):
    """The fit entry stores the model's digest (``rational.DIGEST_ATTR``): read from the cache (its
    checksum verified, the entry read once as the checksum reads it) the model carries it without
    hashing its arrays again, the same bits as a plain read; the same file given as a user's
    (``load_fit``) has its digest computed, so an entry edited and stamped again with a stale
    digest is not believed there."""
    import h5py

    from soil_impedance.fit import load_fit
    from soil_impedance.rational import DIGEST_ATTR, RationalModel, read_model
    from uplift_common.files import stamp_checksum
    first = fit_table(table, tol=0.01, cache_dir=tmp_path)
    entry, = tmp_path.glob("fit-*.h5")
    cached = fit_table(table, tol=0.01, cache_dir=tmp_path)
    assert cached.report.cached and "digest" in cached.model.__dict__        # kept, not computed
    hashed = RationalModel(cached.model.poles, cached.model.residues, cached.model.D, cached.model.E)
    assert cached.model.digest == hashed.digest == first.model.digest
    with h5py.File(entry, "r") as h:
        plain = read_model(h, entry)
        assert h.attrs[DIGEST_ATTR] == first.model.digest
    for name in ("poles", "residues", "D", "E"):
        a, b = getattr(plain, name), getattr(cached.model, name)
        assert a.dtype == b.dtype and a.tobytes() == b.tobytes(), name
    assert "digest" not in plain.__dict__                                     # not trusted without the cache's word
    with h5py.File(entry, "r+") as h:                                         # a stale digest, stamped again
        h.attrs[DIGEST_ATTR] = "0" * 64
        stamp_checksum(h)
    assert load_fit(entry).model.digest == first.model.digest


def _split_reference(p, R, rtol=1e-8):
    """The pole split as it was written before the residues' scale was taken lazily: every test
    against max |R|, computed first (the outcome the current one must give)."""
    rscale = max(np.abs(R).max(initial=0.0), 1e-300)
    is_real = np.abs(p.imag) <= rtol * np.abs(p)
    if np.any(np.abs(R[is_real].imag) > rtol * rscale * 1e2):
        raise FitError("real pole, complex residue")
    up = np.flatnonzero(~is_real & (p.imag > 0))
    down = list(np.flatnonzero(~is_real & (p.imag < 0)))
    if len(up) != len(down):
        raise FitError("unpaired")
    for k in up:
        j = min(down, key=lambda j: abs(p[j] - np.conj(p[k])))
        if abs(p[j] - np.conj(p[k])) > rtol * abs(p[k]) * 1e2 or np.abs(R[j] - np.conj(R[k])).max() > 1e-6 * rscale:
            raise FitError("no partner")
        down.remove(j)
    return p[is_real].real, R[is_real].real, p[up], R[up]


@pytest.mark.parametrize("case", ["exact", "real-imag-small", "real-imag-large", "pair-off-small", "pair-off-large",
                                  "pair-nan", "real-nan", "signed-zero"])
def test_the_pole_split_gives_the_outcome_of_testing_against_the_residues_scale(case):
    """``RationalModel.pole_split`` takes max |R| only when a residue difference is not exactly
    zero: on exact conjugates, residues off by less or more than the tolerances, NaN and signed
    zeros it splits (the same arrays) or refuses exactly as the test against the scale taken first."""
    rng = np.random.default_rng(7)
    n = 4
    pr = np.array([-3.0])
    pc = np.array([-1.0 + 5.0j, -0.5 + 9.0j])
    Rr = rng.standard_normal((1, n, n)).astype(complex)
    Rc = rng.standard_normal((2, n, n)) + 1j * rng.standard_normal((2, n, n))
    poles = np.concatenate([pr, np.stack([pc, pc.conj()], 1).reshape(-1)]).astype(complex)
    R = np.concatenate([Rr, np.stack([Rc, Rc.conj()], 1).reshape(4, n, n)])
    scale = np.abs(R).max()
    if case == "real-imag-small":
        R[0, 1, 2] += 1e-3 * 1e-8 * scale * 1j
    elif case == "real-imag-large":
        R[0, 1, 2] += 10 * 1e-6 * scale * 1j
    elif case == "pair-off-small":
        R[2, 0, 0] += 1e-3 * 1e-6 * scale
    elif case == "pair-off-large":
        R[2, 0, 0] += 10 * 1e-6 * scale
    elif case == "pair-nan":
        R[4, 3, 3] = np.nan
    elif case == "real-nan":
        R[0, 2, 2] = complex(1.0, np.nan)
    elif case == "signed-zero":
        R[0].imag = -0.0
        R[2].real[0, 0], R[1].real[0, 0] = 0.0, -0.0
    from soil_impedance.rational import _split_poles
    try:
        expected = _split_reference(poles, R)
    except FitError:
        with pytest.raises(FitError):
            _split_poles(poles, R)
        return
    got = _split_poles(poles, R)
    for a, b in zip(expected, got):
        assert np.asarray(a).tobytes() == np.asarray(b).tobytes()


def test_a_changed_byte_of_a_fit_entry_is_never_read_as_another_model(table, tmp_path):
    """Single-byte changes of a fit cache entry (every byte of the stored digest's value, and bytes
    spread over the whole file): each entry is refused (None, moved aside with a CacheWarning) or,
    a byte HDF5 does not read, gives the original model, arrays and digest, never another one."""
    import warnings

    from soil_impedance.cache import CacheWarning
    from soil_impedance.fit.options import FitOptions
    from soil_impedance.fit.pipeline import _cache_path, cached_fit
    options = FitOptions(tol=0.01)
    first = fit_table(table, cache_dir=tmp_path / "a", options=options)
    entry = _cache_path(table.hash, options, tmp_path / "a")
    data = entry.read_bytes()
    digest = first.model.digest.encode()            # the attribute's value, and the passivity record's copy
    starts = [k for k in range(len(data)) if data.startswith(digest, k)]
    positions = sorted({k + j for k in starts for j in range(64)} | set(range(0, len(data), max(1, len(data) // 300))))
    assert len(starts) >= 2 and len(positions) > 300
    refused = 0
    for k in positions:
        folder = tmp_path / f"b{k}"
        folder.mkdir()
        changed = bytearray(data)
        changed[k] ^= 0x10
        path = _cache_path(table.hash, options, folder)
        path.write_bytes(bytes(changed))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", CacheWarning)
            got = cached_fit(table.hash, options, folder)
        if got is None:
            refused += 1
            continue
        m = got.model
        assert m.digest == first.model.digest and all(getattr(m, a).tobytes() == getattr(first.model, a).tobytes()
                                                     for a in ("poles", "residues", "D", "E")), k
    assert refused >= 64 * len(starts)     # at least every byte of the digests' values

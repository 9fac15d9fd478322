"""Frequency-domain routes with a hysteretic impedance table (material damping as complex
moduli, Im K(0+) = 2 xi K_0: not causal), on the coarse raft of the shared Winkler case (helpers.COARSE_RAFT)
turned into a table K(f) = K (1 + 2 i xi) + i w C."""
from dataclasses import replace

import numpy as np
import pytest

from structure import ContactSettings

from orchestrator.compare import compare
from orchestrator.timefreq import GridOptions, SolveOptions, causal_table, linear_fd, solve
from helpers import COARSE_RAFT, hysteretic_table, rel
from helpers import broadband as motion

MODEL, soil = COARSE_RAFT.model, COARSE_RAFT.soil

BONDED = ContactSettings(enabled=False)


def test_causal_table_fades_the_hysteretic_offset_only():
    tab = hysteretic_table()
    K, f_c = causal_table(tab)
    f = tab.frequencies_hz
    assert 0 < f_c < 0.1 * f[-1] + 1e-12
    assert np.abs(K[0].imag).max() == 0.0                       # causal at w = 0
    above = f >= f_c
    assert np.array_equal(K[above], tab.matrices[above])        # the table itself above f_causal
    assert np.array_equal(K.real, tab.matrices.real)
    viscous = hysteretic_table(0.0)
    K2, f2 = causal_table(viscous)
    assert f2 == 0.0 and np.array_equal(K2, viscous.matrices)


def test_linear_route_with_hysteretic_table_is_padding_independent():
    """No window (the linear route's default): pad = the rule vs 2.5 x the rule agree to
    < 1e-4 everywhere, the end of the record included, for a record that stops at full
    strength. With the window (eta = ln(1e4) / (nfft dt)) the acausal part of the hysteretic
    kernel is amplified at the end of the record and the same check moves > 10x more."""
    tab = hysteretic_table()
    ag = motion(0.5, duration=8.0, taper=0.2)

    def pair(window):
        a = linear_fd(MODEL, tab, ag, 0.005, contact=BONDED, grid=GridOptions(window=window))
        b = linear_fd(MODEL, tab, ag, 0.005, contact=BONDED,
                      grid=GridOptions(window=window, pad_s=2.5 * a.info["pad_rule_s"]))
        assert b.info["nfft"] > a.info["nfft"] and a.info["pad_s"] >= a.info["pad_rule_s"]
        return max([rel(a.raft[:, j], b.raft[:, j]) for j in (0, 2, 4)]
                   + [rel(a.acc[n], b.acc[n]) for n in a.acc if n != "raft"])

    plain = pair(False)
    assert plain < 1e-4, plain
    assert pair(True) > 10 * plain


@pytest.mark.filterwarnings("ignore::orchestrator.timefreq.ExperimentalMethodWarning")
def test_uplift_route_with_hysteretic_table_is_padding_independent():
    """The uplift route (window kept, the table's hysteretic offset faded below f_causal):
    max uplift, raft rotation and floor-spectrum peaks within 0.1 % between pad = the rule
    and 2.5 x the rule (measured: 4e-6 on max uplift)."""
    tab = hysteretic_table()
    ag = motion(0.3)
    nk = SolveOptions(method="newton-krylov")          # the continuous grid's (experimental) solver
    a = solve(MODEL, tab, ag, 0.005, contact=ContactSettings(enabled=True), grid=GridOptions(bilinear=False),
              options=nk)
    b = solve(MODEL, tab, ag, 0.005, contact=ContactSettings(enabled=True),
              grid=GridOptions(bilinear=False, pad_s=2.5 * a.info["pad_rule_s"]), options=nk)
    assert a.converged and b.converged and b.info["nfft"] > a.info["nfft"]
    assert a.max_uplift() > 1e-4
    d = compare({"a": a, "b": b}, "b")["differences"]["a"]
    assert abs(d["max_uplift"]) < 1e-3 and abs(d["max_rotation"]) < 1e-3, d
    assert d["max_spectrum_peak"] < 1e-3, d


def test_uplift_march_with_hysteretic_table_is_padding_independent():
    """The default uplift route (bilinear grid, the march with the wrap-around and the
    table's non-causal part fed back): converged to 1e-10 and within 0.1 % between pad = the
    rule and 2.5 x the rule."""
    tab = hysteretic_table()
    ag = motion(0.3)
    a = solve(MODEL, tab, ag, 0.005, contact=ContactSettings(enabled=True))
    b = solve(MODEL, tab, ag, 0.005, contact=ContactSettings(enabled=True),
              grid=GridOptions(pad_s=2.5 * a.info["pad_rule_s"]))
    assert a.info["method"] == "march" and a.converged and b.converged, (a.message, b.message)
    assert a.info["residual"] < 1e-10 and a.max_uplift() > 1e-4
    d = compare({"a": a, "b": b}, "b")["differences"]["a"]
    assert abs(d["max_uplift"]) < 1e-3 and abs(d["max_rotation"]) < 1e-3, d


def test_bilinear_grid_puts_nyquist_in_the_continuation():
    """On the bilinear grid s_d is real and huge at Nyquist (z = -e^{eta dt}): Re(s_d / 2 pi i)
    = 0 there, but the point stands for an infinite frequency and belongs to the spring-dashpot
    continuation. Spline-extrapolated instead (the old band split on Re f_c), its real part
    entered the inverse FFT as a (-1)^k e^{eta t} kernel that grew 1e4-fold over the record."""
    from orchestrator.timefreq.grid import Grid
    from orchestrator.timefreq.soil import AffineBand, soil_bands

    g = Grid.build(801, 0.005, pad_s=1.0, bilinear=True)
    bands = soil_bands(hysteretic_table(), g)
    nyq = g.n_freq - 1
    assert any(isinstance(b, AffineBand) and nyq in b.idx for b in bands.bands)
    Kt = causal_table(hysteretic_table())[0][-1]
    wmax = 2 * np.pi * hysteretic_table().frequencies_hz[-1]
    K_nyq = next(b.full(g.s[[nyq]])[0] for b in bands.bands if nyq in b.idx)
    assert np.allclose(K_nyq, Kt.real + g.s[nyq] * Kt.imag / wmax, rtol=1e-12, atol=0)
    K00 = np.empty(g.n_freq, complex)
    for b in bands.bands:
        K00[b.idx] = b.full(g.s[b.idx])[:, 6, 6]
    h = np.abs(g.to_time(K00, n=g.nfft))
    k = g.nfft // 10                      # the trapezoidal dashpot's (-1)^k kernel does not decay
    assert h[-k:].max() < 100 * h[:k].max(), (h[-k:].max(), h[:k].max())


def test_nested_near_field_equals_the_step_by_step_march():
    """The march's near field in nested sub-blocks (one matrix product from a finished
    sub-block to the rest of its parent) against the step-by-step near field (sub = block, the
    march as it was), with the default nesting, one level of 5 and three levels (17, 8, 3)
    (sub-blocks that do not divide their parents): the same sums in another order, so the same
    sweeps and the same solution: max uplift to 1e-6 relative (measured ~1e-15), histories to
    1e-9."""
    from orchestrator.timefreq import WorkerPool, prepare
    from orchestrator.timefreq.march import BLOCK, SUB, defect_correction

    assert max(SUB) < BLOCK
    ag = motion(0.5)
    with WorkerPool(1) as pool:
        prob = prepare(MODEL, hysteretic_table(), ag, 0.005, grid=GridOptions().resolved(bilinear=True, window=True),
                       contact=ContactSettings(enabled=True), pool=pool)
        outs = {sub: defect_correction(prob, tol=1e-8, fold="auto", sub=sub) for sub in (BLOCK, SUB, 5, (17, 8, 3))}
    ref = outs[BLOCK]
    gap_ref = np.maximum(0.0, -(prob.z0[:, None] + ref.y))
    assert ref.converged and gap_ref.max() > 1e-3
    for sub in (SUB, 5, (17, 8, 3)):
        out = outs[sub]
        gap = np.maximum(0.0, -(prob.z0[:, None] + out.y))
        assert out.converged and len(out.history) == len(ref.history)
        assert abs(gap.max() - gap_ref.max()) <= 1e-6 * gap_ref.max()
        assert rel(out.y, ref.y) < 1e-9


def _reference_head(op, grid, n_lags, fold):
    """kernel_head as a plain inverse FFT of every entry of S (the affine bands included)."""
    N, nt, nf = op.N, grid.nt, grid.nfft
    rows = np.arange(N)
    Sc = np.ascontiguousarray(op.S_sub(rows, rows).transpose(1, 2, 0))
    if not fold:
        return grid.to_time(Sc, n=n_lags).transpose(2, 0, 1)
    k = np.arange(1, nf - nt + 1)
    hw = np.fft.irfft(Sc, n=nf, axis=-1)
    hn = hw[..., nf - k] * np.exp(-grid.eta * grid.dt * k)
    h = hw[..., :n_lags] * np.exp(grid.eta * grid.dt * np.arange(n_lags))
    h[..., 1:] -= hn[..., :n_lags - 1]
    h[..., 0] += 2.0 * hn.sum(axis=-1)
    return h.transpose(2, 0, 1)


@pytest.mark.parametrize("fold", [False, True])
def test_kernel_head_forms_the_affine_bands_from_two_scalar_series(fold):
    """The kernel head with the affine bands' A + s B as A (x) a_k + B (x) b_k equals the
    inverse FFT of every entry of S, on a table (a dense band and its spring-dashpot
    continuation) and on a Winkler soil (one affine band): 1e-12 of the largest entry."""
    from orchestrator.timefreq import prepare
    from orchestrator.timefreq.march import kernel_head

    ag = motion(0.3, duration=1.0)
    for s in (hysteretic_table(), soil()):
        prob = prepare(MODEL, s, ag, 0.005, grid=GridOptions().resolved(bilinear=True, window=True),
                       contact=ContactSettings(enabled=True))
        head = kernel_head(prob.op, prob.grid, 20, fold, chunk=7)
        ref = _reference_head(prob.op, prob.grid, 20, fold)
        assert np.abs(head - ref).max() <= 1e-12 * np.abs(ref).max()


@pytest.mark.parametrize("window", (False, True))
def test_table_band_is_the_faded_tables_spline_formed_on_demand(window):
    """The table's band (SplineBand: the table's spline plus the spline of the causal fade times
    Im K(0), never a faded copy) against the spline of causal_table's matrices fitted entry by
    entry (scipy's CubicSpline on the data, continued by its Taylor terms at f - i eta/2pi):
    to 1e-13 of its largest entry. The set-up does not form it; its pieces (a few
    frequencies formed into a work array) and the whole band agree with it, and rows_P formed
    on the table's matrices equals rows_P of the formed band to 1e-13."""
    from scipy.interpolate import CubicSpline

    from orchestrator.timefreq import prepare
    from orchestrator.timefreq.soil import Scratch, SplineBand, rows_P

    base = hysteretic_table()
    f = base.frequencies_hz
    tab = replace(base, matrices=base.matrices * (1 + 0.2 * np.sin(0.7 * f))[:, None, None])   # not a cubic in f
    prob = prepare(MODEL, tab, motion(0.5), 0.005, contact=BONDED,
                   grid=GridOptions(window=window).resolved(bilinear=False))
    band = prob.op.soil.bands[0]
    assert isinstance(band, SplineBand) and "K" not in band.__dict__
    Kt, f_c = causal_table(tab)
    assert f_c > 0
    fc = prob.grid.s[band.idx] / (2j * np.pi)
    dz = (1j * fc.imag)[:, None, None]
    sp = CubicSpline(f, Kt, axis=0)
    ref = sp(fc.real) + dz * sp(fc.real, 1) + 0.5 * dz * dz * sp(fc.real, 2)
    tol = 1e-13 * np.abs(ref).max()
    scratch = Scratch()
    groups = band.groups(7)
    assert len(groups) > 2
    for sel in groups:
        assert np.abs(band.piece(sel, scratch).K - ref[sel]).max() <= tol
    assert "K" not in band.__dict__
    parts = band.rows_P(None, prob.op.Bq)
    assert np.abs(band.K - ref).max() <= tol
    for part, direct in zip(parts, rows_P(band.K, prob.op.Bq)):
        assert np.abs(part - direct).max() <= 1e-13 * np.abs(direct).max()


def test_the_solves_set_up_is_cached_and_gives_the_same_bits(tmp_path, monkeypatch):
    """orchestrator/timefreq/setup_cache.py: the first solve of a table with a cache folder writes
    its band's rows (tf-rows) and the far field's split (tf-split) and gives the uncached solve's
    bits; a second solve of the same table, grid and structure (the same motion, or another
    record of the same length) makes neither again (both refused here) and gives the uncached
    solve's bits; a damaged split entry is moved aside with a CacheWarning and made again, the
    same bits; a table with one entry changed (the same inputs, other data) keys new entries."""
    import warnings

    from orchestrator.timefreq.farfield import AffineSplit
    from orchestrator.timefreq.soil import SplineBand
    from soil_impedance.cache import CacheWarning
    from soil_impedance.table import ImpedanceTable

    tab = hysteretic_table()
    records = (motion(0.3, duration=2.0), motion(0.25, duration=2.0, seed=5))
    cache = tmp_path / "setup"

    def run(ag, table=tab, cache_dir=cache):
        return solve(MODEL, table, ag, 0.005, contact=ContactSettings(enabled=True), cache_dir=cache_dir)

    def same(a, b):
        return all(np.array_equal(getattr(a, k), getattr(b, k)) for k in ("gap", "contact_force", "raft", "soil_w"))

    plain = [run(ag, cache_dir=None) for ag in records]
    assert not cache.exists() and plain[0].converged and plain[0].max_uplift() > 1e-4
    assert same(run(records[0]), plain[0])
    split, = cache.glob("tf-split-*.h5")
    assert len(list(cache.glob("tf-rows-*.h5"))) == 1

    def refused(*args, **kwargs):
        raise AssertionError("the set-up was made again")
    with monkeypatch.context() as m:
        m.setattr(AffineSplit, "_dense_part", staticmethod(refused))
        m.setattr(SplineBand, "rows_P", refused)
        warm = [run(ag) for ag in records]
    assert same(warm[0], plain[0]) and same(warm[1], plain[1]) and not same(plain[0], plain[1])

    data = bytearray(split.read_bytes())
    data[len(data) // 2] ^= 0x10
    split.write_bytes(bytes(data))
    with pytest.warns(CacheWarning, match="damaged cache entry .*tf-split"):
        again = run(records[0])
    assert same(again, plain[0]) and split.exists() and split.with_name(split.name + ".damaged").exists()

    K = np.array(tab.matrices)
    K[K.shape[0] // 2, 7, 7] *= 1.0 + 1e-9
    changed = ImpedanceTable(tab.frequencies_hz, K, tab.dofs, tab.provenance)
    assert changed.hash == tab.hash                        # the same inputs: the data key the entries
    with warnings.catch_warnings():
        warnings.simplefilter("error", CacheWarning)
        run(records[0], changed)
    assert len(list(cache.glob("tf-split-*.h5"))) == 2 and len(list(cache.glob("tf-rows-*.h5"))) == 2


def test_the_split_entry_is_read_mapped_and_a_changed_byte_is_never_read(tmp_path, monkeypatch):
    """setup_cache.read_mapped (the tf-split entry, written by write_mapped): the arrays come back
    the same bits, memory-mapped read-only, and a second read in the same process returns the kept
    arrays without mapping the file again. One byte of the file changed (every byte of the arrays
    and of their CRC-32 attributes, and every 19th byte of the rest, HDF5's own): either the entry
    is refused (None, a CacheWarning, the file moved aside) or what is read is the same bits and
    attributes (a byte HDF5 keeps for itself, not read); every change in the arrays' bytes or
    their CRCs is refused. The kept file rewritten in place (its times change) is checked again."""
    import warnings

    import h5py

    import orchestrator.timefreq.setup_cache as sc
    from soil_impedance.cache import CacheWarning

    rng = np.random.default_rng(3)
    arrays = {"D0": rng.standard_normal((2, 6)) + 1j * rng.standard_normal((2, 6)),
              "D1": rng.standard_normal((1, 3, 3)) + 1j * rng.standard_normal((1, 3, 3))}
    names, shapes = list(arrays), [a.shape for a in arrays.values()]
    path = tmp_path / "tf-split-x.h5"
    sc.write_mapped(path, arrays, {"packed": True})
    out, attrs = sc.read_mapped(path, names, shapes, attrs=("packed",))
    assert all(np.array_equal(a, arrays[k]) and not a.flags.writeable for a, k in zip(out, names))
    assert bool(attrs["packed"])

    def unmapped(*args, **kwargs):
        raise AssertionError("mapped again")
    with monkeypatch.context() as m:                       # kept: the same file is not mapped again
        m.setattr(np, "memmap", unmapped)
        assert sc.read_mapped(path, names, shapes, attrs=("packed",))[0][1] is out[1]

    checked = set()                                          # the bytes read_mapped reads: data and CRCs
    data = path.read_bytes()
    with h5py.File(path, "r") as f:
        for k in names:
            start = f[k].id.get_offset()
            checked.update(range(start, start + f[k].id.get_storage_size()))
            crc = data.find(int(f[k].attrs[sc.CRC_ATTR]).to_bytes(4, "little"))
            assert crc >= 0
            checked.update(range(crc, crc + 4))
    refused = 0
    for pos in sorted(checked | set(range(0, len(data), 19))):
        copy = tmp_path / "flip.h5"
        changed = bytearray(data)
        changed[pos] ^= 0x5A
        copy.write_bytes(bytes(changed))
        with warnings.catch_warnings(record=True) as said:
            warnings.simplefilter("always")
            got = sc.read_mapped(copy, names, shapes, attrs=("packed",))
        if got is None:
            refused += 1
            assert any(issubclass(w.category, CacheWarning) for w in said) and not copy.exists()
        else:
            assert pos not in checked, f"byte {pos} changed and read"
            assert all(np.array_equal(a, arrays[k]) for a, k in zip(got[0], names)) and bool(got[1]["packed"])
        for p in tmp_path.glob("flip*"):
            p.unlink()
    assert refused >= len(checked)

    sc._MAPPED.clear()
    assert sc.read_mapped(path, names, shapes, attrs=("packed",))[0][0] is not out[0]      # kept again
    changed = bytearray(data)
    changed[min(checked)] ^= 0x01
    path.write_bytes(bytes(changed))                        # rewritten in place: checked again, refused
    with pytest.warns(CacheWarning, match="damaged cache entry"):
        assert sc.read_mapped(path, names, shapes, attrs=("packed",)) is None

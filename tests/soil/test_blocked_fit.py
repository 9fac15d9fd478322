"""A table too large to hold: written frequency by frequency, read in blocks (soil_impedance.blocked),
swept straight to disk (sweep.STREAM_BYTES) and fitted block by block (fit.streamed)."""
import warnings

import h5py
import numpy as np
import pytest

from soil_impedance import ImpedanceTable, circle_mesh, impedance_sweep, sweep
from soil_impedance.blocked import BlockedTable, TableWriter, chunk_edge, in_memory
from soil_impedance.cache import CacheWarning
from soil_impedance.fit import FitOptions, streamed
from soil_impedance.fit.pipeline import fit
from soil_impedance.table import TableError


def _profile(model):
    from soil_impedance import Material, SoilProfile
    return SoilProfile((), Material(vs=500.0, rho=2000.0, nu=0.3, damping=0.03, damping_model=model))


@pytest.fixture(scope="module")
def gap_table():
    """Disk R = 10 m, 29 nodes (35 DOFs), causal 3 % half-space, 0..25 Hz, 26 frequencies, in memory."""
    return impedance_sweep(_profile("causal"), circle_mesh(10, 3.3), np.linspace(0, 25, 26),
                           outputs=("gap",))["gap"]


def _write(table, path, chunk=8):
    with TableWriter(path, table.frequencies_hz, table.dofs, table.provenance, chunk=chunk) as w:
        for k, K in enumerate(table.matrices):
            w[k] = K
    return path


def test_written_file_is_the_saved_file_chunked(gap_table, tmp_path):
    """Frequency by frequency, the writer makes the file ``save`` makes (same data digest and hash: both
    hash the content, not the layout), chunked one frequency × 8 × 8, with the digest of each chunk (its
    whole-file checksum covers them instead of the matrices); ``load`` reads it bit-identically and
    ``block`` returns exactly the slices of the matrices across all frequencies."""
    gap_table.save(tmp_path / "whole.h5")
    _write(gap_table, tmp_path / "blocked.h5")
    with h5py.File(tmp_path / "whole.h5") as a, h5py.File(tmp_path / "blocked.h5") as b:
        assert b["matrices_real"].chunks == (1, 7, 7) and a["matrices_real"].chunks is None   # 35 = 5 x 7
        for key in ("data_sha256", "hash"):
            assert a.attrs[key] == b.attrs[key]
        assert b["matrices_imag_chunk_sha256"].shape == (26, 5, 5, 32) and "matrices_real_chunk_sha256" not in a
    again = ImpedanceTable.load(tmp_path / "blocked.h5")
    assert np.array_equal(again.matrices, gap_table.matrices) and again.hash == gap_table.hash
    lazy = ImpedanceTable.open(tmp_path / "blocked.h5")
    assert isinstance(lazy, BlockedTable) and lazy.hash == gap_table.hash and lazy.dofs == gap_table.dofs
    assert np.array_equal(lazy.block(slice(3, 19), slice(8, 35)), gap_table.matrices[:, 3:19, 8:35])
    assert np.array_equal(lazy.frequency(7), gap_table.matrices[7])
    whole = in_memory(lazy)                     # for the routes that need every matrix at once
    assert isinstance(whole, ImpedanceTable) and np.array_equal(whole.matrices, gap_table.matrices)
    assert in_memory(gap_table) is gap_table
    assert (chunk_edge(599), chunk_edge(256), chunk_edge(257), chunk_edge(5)) == (120, 128, 86, 5)
    tiles = list(lazy.blocks(16))
    assert len(tiles) == 6 and all(c.start >= r.start for r, c in tiles)        # 3 x 3 tiles, upper half


def test_a_writer_that_fails_leaves_nothing_and_a_changed_file_is_refused(gap_table, tmp_path):
    path = tmp_path / "t.h5"
    f, dofs, prov = gap_table.frequencies_hz, gap_table.dofs, gap_table.provenance
    with pytest.raises(RuntimeError, match="boom"), TableWriter(path, f, dofs, prov) as w:
        w[0] = gap_table.matrices[0]
        raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(ValueError, match="1 of 26"), TableWriter(path, f, dofs, prov) as w:
        w[0] = gap_table.matrices[0]
    assert list(tmp_path.iterdir()) == []
    _write(gap_table, path)
    with h5py.File(path, "r+") as h:
        h["matrices_imag"][3, 2, 2] += 1.0
    with pytest.raises(TableError, match="changed since it was written"):
        ImpedanceTable.load(path)                   # the whole file: every chunk against its digest
    lazy = BlockedTable.open(path)                  # the matrices are checked as they are read
    assert np.array_equal(lazy.block(slice(7, 14), slice(0, 35)), gap_table.matrices[:, 7:14])
    with pytest.raises(TableError, match=r"frequency 3, rows 0\.\., columns 0\.\. .*changed since it was written"):
        lazy.block(slice(0, 7), slice(0, 7))
    with pytest.raises(TableError, match="changed since it was written"):
        BlockedTable.open(path).frequency(3)
    assert np.array_equal(BlockedTable.open(path).frequency(2), gap_table.matrices[2])
    with h5py.File(path, "r+") as h:
        h["matrices_real_chunk_sha256"][0, 0, 0, 0] ^= 1      # a digest changed: the whole-file checksum
    with pytest.raises(TableError, match="changed since it was written"):
        BlockedTable.open(path)


def test_the_sweep_streams_a_large_output_to_its_cache_entry(gap_table, tmp_path, monkeypatch):
    """Above STREAM_BYTES (here 0) the sweep writes the gap table into its cache entry as it goes and
    returns a BlockedTable: the same matrices, bit for bit, as the in-memory sweep; the next sweep reads it
    from the cache as a BlockedTable, and so an entry written by ``save`` (the layout before); a damaged
    entry is recomputed with a CacheWarning. The memory estimate counts one matrix of a streamed output."""
    monkeypatch.setattr(sweep, "STREAM_BYTES", 0)
    f = gap_table.frequencies_hz
    mesh = circle_mesh(10, 3.3)
    got = impedance_sweep(_profile("causal"), mesh, f, outputs=("gap",), cache_dir=tmp_path)["gap"]
    assert isinstance(got, BlockedTable)
    assert np.array_equal(got.matrices, gap_table.matrices) and got.hash == gap_table.hash
    (entry,) = tmp_path.glob("impedance_gap_*.h5")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        again = impedance_sweep(_profile("causal"), mesh, f, outputs=("gap",), cache_dir=tmp_path)["gap"]
        assert isinstance(again, BlockedTable) and again.path == entry
        gap_table.save(entry)                                                    # an entry of the old layout
        old = impedance_sweep(_profile("causal"), mesh, f, outputs=("gap",), cache_dir=tmp_path)["gap"]
        assert isinstance(old, BlockedTable) and np.array_equal(old.matrices, gap_table.matrices)
    with h5py.File(entry, "r+") as h:
        h["matrices_real"][0, 0, 0] *= 2
    with pytest.warns(CacheWarning, match="damaged"):
        fresh = impedance_sweep(_profile("causal"), mesh, f, outputs=("gap",), cache_dir=tmp_path)["gap"]
    assert np.array_equal(fresh.matrices, gap_table.matrices)
    blocked_dir = tmp_path / "a-file"
    blocked_dir.write_text("not a folder")                  # a cache that cannot be written: warned, held in memory
    with pytest.warns(CacheWarning, match="held in memory") as caught:
        held_here = impedance_sweep(_profile("causal"), mesh, f, outputs=("gap",), cache_dir=blocked_dir)["gap"]
    assert len(caught) == 1
    assert isinstance(held_here, ImpedanceTable) and np.array_equal(held_here.matrices, gap_table.matrices)
    g = 6 + 2500                                  # the table, plus half of it for the h5 copy of one part
    assert sweep.sweep_memory(2500, 101, ("gap",), grid=True)["outputs"] == 101 * 24 * g * g
    assert sweep.sweep_memory(2500, 101, ("gap",), grid=True, streamed=("gap",))["outputs"] == 24 * g * g


def _compare(a, b, rtol):
    ra, rb = a.report, b.report
    assert a.model.order == b.model.order and len(ra.order_history) == len(rb.order_history)
    assert np.allclose(np.array(ra.order_history), np.array(rb.order_history), rtol=rtol, atol=0)
    assert np.allclose(a.model.poles, b.model.poles, rtol=rtol, atol=0)
    Ca, Cb = a.model.coefficients, b.model.coefficients
    assert np.abs(Ca - Cb).max() <= rtol * np.abs(Ca).max()
    for key in ("max_rel_error", "max_rel_error_fit", "max_rel_error_unscaled", "low_freq_error",
                "passivity_margin", "f_causal_hz", "error_floor"):
        assert getattr(rb, key) == pytest.approx(getattr(ra, key), rel=rtol, abs=1e-15), key
    assert ra.passive == rb.passive and ra.stop_reason == rb.stop_reason and ra.tol_reached == rb.tol_reached
    for name, e in ra.block_errors.items():
        assert rb.block_errors[name] == pytest.approx(e, rel=rtol)
    for d, e in ra.rigid_errors.items():
        assert rb.rigid_errors[d] == pytest.approx(e, rel=1e-6)
    assert np.array_equal(ra.rel_error.shape, rb.rel_error.shape)


def test_the_streamed_fit_equals_the_fit_in_memory(gap_table, tmp_path):
    """Blocks of 12 (the file's chunks: the rigid DOFs and the first w ones in one, 6 blocks): the same
    orders, poles and coefficients within 1e-9 (round-off: the sums run per block, the compression by a QR
    of the blocks instead of an SVD), the same errors, rigid-raft errors and passivity verdict."""
    lazy = BlockedTable.open(_write(gap_table, tmp_path / "t.h5", chunk=12))
    assert lazy.chunk == 12 and len(list(lazy.blocks())) == 6
    opt = FitOptions(tol=0.02)
    _compare(fit(gap_table, opt), fit(lazy, opt), 1e-9)


def test_the_streamed_set_up_runs_its_qrs_on_one_blas_thread(gap_table, tmp_path, monkeypatch):
    """The set-up's tall-skinny QRs run with every BLAS pool at one thread (``uplift_common.blas.single_threaded_blas``),
    from pools of two, which are two again afterwards; its R factor is the QR's of the whole stacked
    columns (Rᵀ R = X̃ X̃ᵀ, to round-off: 1e-12 of the largest entry), and equal to the R of a set-up run
    with the pools left at two threads to round-off."""
    from threadpoolctl import threadpool_info, threadpool_limits

    def blas_threads():
        return {i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"}
    seen = []
    qr = np.linalg.qr

    def recording_qr(*args, **kw):
        seen.append(blas_threads())
        return qr(*args, **kw)
    lazy = BlockedTable.open(_write(gap_table, tmp_path / "t.h5", chunk=12))
    with threadpool_limits(limits=2, user_api="blas"):
        assert blas_threads() == {2}
        monkeypatch.setattr(np.linalg, "qr", recording_qr)
        prob = streamed.StreamedProblem(lazy, "relative", "auto")
        assert len(seen) == 6 and all(s == {1} for s in seen), seen
        assert blas_threads() == {2}
        monkeypatch.setattr(streamed, "single_threaded_blas", lambda: threadpool_limits(limits=2, user_api="blas"))
        seen.clear()
        two = streamed.StreamedProblem(lazy, "relative", "auto")
        assert len(seen) == 6 and all(s == {2} for s in seen), seen
    X = []
    for r, c, _, _, T, (i, j, ew) in prob._passes():
        Xb = streamed._columns(T, r, c, i, j) * ew
        X.append(np.concatenate([Xb.real, Xb.imag]))
    X = np.hstack(X)
    gram = X @ X.T
    assert np.abs(prob.R.T @ prob.R - gram).max() <= 1e-12 * np.abs(gram).max()
    assert np.abs(np.abs(prob.R) - np.abs(two.R)).max() <= 1e-12 * np.abs(prob.R).max()


def test_the_streamed_fit_of_a_hysteretic_table_equals_the_fit_in_memory(tmp_path, monkeypatch):
    """A hysteretic table (the causal target fades Im K(0⁺) out below f_causal, the error floor), in blocks of
    16 of a contiguous file (no chunks to follow: streamed.BLOCK): the same."""
    monkeypatch.setattr(streamed, "BLOCK", 16)
    table = impedance_sweep(_profile("hysteretic"), circle_mesh(10, 3.3), np.linspace(0, 25, 21),
                            outputs=("gap",))["gap"]
    table.save(tmp_path / "t.h5")
    lazy = BlockedTable.open(tmp_path / "t.h5")
    assert lazy.chunk is None
    opt = FitOptions(tol=0.03, max_order=4, patience=None)
    with pytest.warns(RuntimeWarning, match="hysteretic"):
        a, b = fit(table, opt), fit(lazy, opt)
    assert a.report.f_causal_hz > 0
    _compare(a, b, 1e-9)


def test_the_passivity_test_evaluates_fewer_frequencies_at_once_for_large_models(monkeypatch):
    """G(ν) is evaluated for a chunk of frequencies at once, capped so that a chunk stays below CHUNK_BYTES
    (64 × 2506² doubles would be 3.2 GB): the cap changes how many at once, not the values, nor the verdict."""
    from soil_impedance import passivity
    from helpers.passive_models import random_passive_model
    model = random_passive_model(12, 3, seed=2)
    sc = model.scaled
    nu = np.linspace(0.01, 3.0, 150)
    free = passivity._lmin(sc, nu)
    assert passivity._chunk(sc, 64) == 64
    monkeypatch.setattr(passivity, "CHUNK_BYTES", 8 * 12 ** 2 * 5)            # 5 matrices at once
    assert passivity._chunk(sc, 64) == 5 and passivity._chunk(sc, 3) == 3
    assert np.allclose(passivity._lmin(sc, nu), free, rtol=0, atol=1e-14 * np.abs(free).max())
    monkeypatch.setattr(passivity, "CHUNK_BYTES", 1)
    assert passivity._chunk(sc, 64) == 1
    assert passivity._assess(sc)["passive"]

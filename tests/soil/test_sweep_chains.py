"""The fast sweep on two cores (soil_impedance.sweep: CHAINS warm-start chains in up to CHAINS threads)
and the blocked table's chunk digests (soil_impedance.blocked).

The chained sweep against the sequential one (one chain) and both against the dense LU, within the
solver's tolerance; the same bits whatever the number of threads actually used (in memory and in the
streamed cache entry); an error in a chain reaches the caller; the fast gap matrix assembled in place
equals the direct assembly bit for bit; a damaged chunk of a cached blocked table is found when it is
first read and the scene's fit sweeps the table again.
"""
import dataclasses
import os
import threading
import warnings

import multiprocessing

import h5py
import numpy as np
import pytest

import soil_impedance.fastsolve as fastsolve
import soil_impedance.sweep as sweep
from soil_impedance import SoilProfile, SurfaceBem, circle_mesh, impedance_sweep, rectangle_mesh
from soil_impedance.blocked import BlockedTable, DamagedTableError
from soil_impedance.cache import CacheWarning
from soil_impedance.reduction import rigid_transform

SOFT = SoilProfile.homogeneous(vs=150.0, rho=1900.0, nu=0.35, damping=0.05)
TOL = 1e-4
F = np.arange(9) * 0.75                   # 0 .. 6 Hz: a fine list, where the warm starts matter


def _errors(a, b):
    """Largest difference per frequency relative to the table's largest entry at it."""
    return (np.abs(a.matrices - b.matrices).max(axis=(1, 2)) / np.abs(b.matrices).max(axis=(1, 2))).max()


@pytest.fixture(scope="module")
def tables():
    """A 97-node disk on a soft half-space: the fast sweep in two chains (two threads), in one chain
    (the sequential sweep before the chains), and the dense one."""
    mesh = circle_mesh(9.0, 1.6)
    kw = dict(outputs=("rigid", "gap"), solver="fast", solver_tol=TOL)
    chained = impedance_sweep(SOFT, mesh, F, workers=2, **kw)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(sweep, "CHAINS", 1)
        sequential = impedance_sweep(SOFT, mesh, F, workers=1, **kw)
    dense = impedance_sweep(SOFT, mesh, F, outputs=("rigid", "gap"))
    return mesh, chained, sequential, dense


def test_chained_sweep_is_the_sequential_one_within_the_tolerance(tables):
    """Two interleaved chains start GMRES from other first guesses than one chain: other iterates, every
    one within the relative residual 1e-4, so the tables differ (not bit for bit: the provenance records
    the chains) by less than the tolerance (measured: 5e-6 rigid, 2e-7 gap), and both are as close to the
    dense LU as the tolerance says."""
    mesh, chained, sequential, dense = tables
    for o in ("rigid", "gap"):
        assert not np.array_equal(chained[o].matrices, sequential[o].matrices)
        assert _errors(chained[o], sequential[o]) <= TOL
        assert _errors(chained[o], dense[o]) <= TOL and _errors(sequential[o], dense[o]) <= TOL
    assert chained["gap"].provenance["solver"]["chains"] == sweep.CHAINS == 2
    assert sequential["gap"].provenance["solver"]["chains"] == 1
    assert chained["gap"].hash != sequential["gap"].hash


@pytest.mark.parametrize("parallel", ["processes", "threads"])
def test_the_same_bits_on_one_and_two_workers(tables, tmp_path, monkeypatch, parallel):
    """The chains are a constant of the code, the workers (processes or threads) only run them: one and
    two give the same matrices bit for bit, in memory and in the streamed cache entry (same data digest
    and whole-file checksum); two workers did run the two chains (the odd frequencies in the second)."""
    mesh, chained, _, _ = tables
    log = tmp_path / "ran.txt"
    solve = sweep._Chains.solve

    def logged(self, k):
        with open(log, "a") as fh:
            fh.write(f"{k} {os.getpid()} {threading.current_thread().name}\n")
        return solve(self, k)

    monkeypatch.setattr(sweep._Chains, "solve", logged)
    monkeypatch.setattr(sweep, "PARALLEL", parallel)
    monkeypatch.setattr(sweep, "STREAM_BYTES", 0)            # the gap table streamed to its cache entry
    files, who = {}, {}
    for w in (1, 2):
        log.write_text("")
        got = impedance_sweep(SOFT, mesh, F, outputs=("gap",), solver="fast", solver_tol=TOL, workers=w,
                              cache_dir=tmp_path / str(w))["gap"]
        assert isinstance(got, BlockedTable) and np.array_equal(got.matrices, chained["gap"].matrices)
        with h5py.File(got.path) as h:
            files[w] = {a: h.attrs[a] for a in ("sha256", "data_sha256", "hash")}
        who[w] = {int(k): (int(pid), name) for k, pid, name in (line.split() for line in log.read_text().splitlines())}
    assert files[1] == files[2]
    me = (os.getpid(), threading.current_thread().name)
    assert set(who[1].values()) == {me} and sorted(who[1]) == list(range(F.size))
    odd, even = {who[2][k] for k in range(1, F.size, 2)}, {who[2][k] for k in range(0, F.size, 2)}
    assert len(odd) == len(even) == 1 and odd != even and me not in odd | even
    assert sweep.sweep_workers(1) == 1 and sweep.sweep_workers(8) == sweep.CHAINS and sweep.sweep_workers(0) == 1


def test_an_error_in_a_chain_or_in_progress_reaches_the_caller(monkeypatch):
    """A chain's FastSolveError is raised by the sweep (from the storing thread, chains in processes or
    threads); a progress callback that raises (a stop) stops the sweep; no chain process or thread is left
    running."""
    mesh = circle_mesh(6.0, 2.0)
    solve = sweep._Chains.solve

    def failing(self, k):
        if k == 5:
            raise fastsolve.FastSolveError("did not converge (test)")
        return solve(self, k)

    monkeypatch.setattr(sweep._Chains, "solve", failing)
    with pytest.raises(fastsolve.FastSolveError, match="test"):
        impedance_sweep(SOFT, mesh, F, outputs=("gap",), solver="fast", workers=2)
    monkeypatch.setattr(sweep._Chains, "solve", solve)

    class Stop(Exception):
        pass

    def progress(done, total, label):
        if done == 3:
            raise Stop

    with pytest.raises(Stop):
        impedance_sweep(SOFT, mesh, F, outputs=("gap",), solver="fast", workers=2, progress=progress)
    assert not [p for p in multiprocessing.active_children() if p.name.startswith("sweep-chain")]
    monkeypatch.setattr(sweep, "PARALLEL", "threads")
    monkeypatch.setattr(sweep._Chains, "solve", failing)
    with pytest.raises(fastsolve.FastSolveError, match="test"):
        impedance_sweep(SOFT, mesh, F, outputs=("gap",), solver="fast", workers=2)
    for t in threading.enumerate():
        if t.name.startswith("sweep-chain"):
            t.join(timeout=30)
    assert not [t for t in threading.enumerate() if t.name.startswith("sweep-chain")]


def test_the_gap_matrix_assembled_in_place_is_the_direct_one():
    """gap_and_rigid assembles Kgᵀ row by row from the symmetry orbits and symmetrises it by tiles in
    place: bit for bit the direct assembly (Kzz scattered column by column, Kg, 0.5 (Kg + Kgᵀ)) of the same
    solutions, on a square (8 maps) and a rectangle (4 maps) larger than a tile."""
    for mesh in (rectangle_mesh(34.0, 34.0, 2.0), rectangle_mesh(36.0, 28.0, 2.0)):      # 289 and 252 nodes
        bem = SurfaceBem(SOFT, mesh)
        n = mesh.n
        T = rigid_transform(mesh)
        Th = T.copy()
        Th[2::3, :] = 0.0
        out, _, sol = fastsolve.gap_and_rigid(bem, 2 * np.pi * 3.0, ("gap",), 1e-3, T, Th)
        maps = fastsolve.mesh_symmetries(mesh.xy, (2.0, 2.0))
        reps, supply = fastsolve.orbits(maps, n)
        Xh = sol["T"].copy()
        Xh[:, 2:5] = 0.0
        Xz = sol["Z"][2::3]
        Kzz = np.empty((n, n), dtype=complex)
        for p, (k, node) in zip(maps, supply):
            Kzz[p[:, None], node[None, :]] = Xz[:, k]
        Kg = np.empty((6 + n, 6 + n), dtype=complex)
        Kg[:6, :6] = Th.T @ Xh
        Kg[6:, :6] = Xh[2::3]
        Kg[:6, 6:] = Xh[2::3].T
        Kg[6:, 6:] = Kzz
        assert 6 + n > fastsolve.TILE and len(supply) in (4, 8)
        assert np.array_equal(out["gap"], 0.5 * (Kg + Kg.T))


def test_a_damaged_chunk_of_a_cached_table_is_found_and_recomputed(tmp_path, monkeypatch):
    """A cached blocked table is opened without reading its matrices; its chunks are checked as the fit's
    first pass reads them: a damaged one raises DamagedTableError before any of it is used, and the
    scene's fit moves the entry aside (CacheWarning), sweeps it again (the same bits) and fits that."""
    from orchestrator import impedance as scene_imp
    from orchestrator.scene import load_scene
    monkeypatch.setattr(sweep, "STREAM_BYTES", 0)
    base = load_scene("mat")
    scene = dataclasses.replace(base, mesh=rectangle_mesh(12.0, 12.0, 2.0), frequencies_hz=np.linspace(0, 25, 6))
    first = scene_imp.scene_impedance(scene, ("gap",), cache_dir=tmp_path)["gap"]
    want = first.matrices
    (entry,) = tmp_path.glob("impedance_gap_*.h5")
    with h5py.File(entry, "r+") as h:
        h["matrices_imag"][4, 2, 30] += 1.0                 # an upper-triangle entry: the fit reads it
    seen = []

    def first_pass(table, cache_dir=None, progress=None, options=None):
        """The fit's first pass: every upper-triangle block of the table, read once."""
        blocks = [table.block(r, c) for r, c in table.blocks()]
        seen.append(table)
        return np.concatenate([b.ravel() for b in blocks])

    monkeypatch.setattr(scene_imp, "fit_table", first_pass)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        cached = scene_imp.scene_impedance(scene, ("gap",), cache_dir=tmp_path)["gap"]     # opened lazily
    with pytest.raises(DamagedTableError, match="changed since it was written"):
        BlockedTable.open(entry).block(slice(0, 42), slice(0, 42))
    with pytest.warns(CacheWarning, match="damaged cache entry .*DamagedTableError"):
        scene_imp.scene_fit(scene, cache_dir=tmp_path, table=cached)
    assert len(seen) == 1 and seen[0] is not cached           # the table swept again was fitted
    assert np.array_equal(seen[0].matrices, want)
    assert entry.with_name(entry.name + ".damaged").exists() and entry.exists()
    user = BlockedTable.open(entry.with_name(entry.name + ".damaged"))   # not a cache entry: the error is shown
    with pytest.raises(DamagedTableError):
        scene_imp.scene_fit(scene, cache_dir=tmp_path, table=user)

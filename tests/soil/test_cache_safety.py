"""Crash-safe, concurrency-safe, verified caches (soil_impedance.cache and the sweep cache).

Writers run in forked processes (fast: numpy, scipy and h5py are already imported); a barrier
or an event inside the HDF5 write makes the overlap or the kill land mid-write every time.
"""
import multiprocessing
import os
import signal
import warnings

import h5py
import numpy as np
import pytest

import soil_impedance.sweep as sweep_mod
from soil_impedance import ImpedanceTable, SoilProfile, TableError, circle_mesh, impedance_sweep
from soil_impedance.cache import CacheWarning, read_entry
from uplift_common.files import OutputFolderError, atomic_output, stamp_checksum, verify_checksum
from soil_impedance.greens_rule import GreenRule
from soil_impedance.sweep import provenance
from soil_impedance.table import content_hash

PROFILE = SoilProfile.homogeneous(vs=200.0, rho=2000.0, nu=0.3, damping=0.05)
MESH = circle_mesh(2.0, 1.0)
FREQS = [0.0, 4.0, 8.0]
fork = pytest.mark.skipif("fork" not in multiprocessing.get_all_start_methods(),
                          reason="needs the fork start method")


def _sweep(cache_dir, outputs=("rigid",)):
    return impedance_sweep(PROFILE, MESH, FREQS, outputs=outputs, cache_dir=cache_dir)


def _entry(cache_dir):
    (path,) = cache_dir.glob("impedance_rigid_*.h5")
    return path


def _flip_bit(path, dataset, byte=11):
    """Flip one bit inside the stored data of ``dataset`` (contiguous layout)."""
    with h5py.File(path, "r") as h:
        offset = h[dataset].id.get_offset() + byte
    with open(path, "r+b") as fh:
        fh.seek(offset)
        b = fh.read(1)[0]
        fh.seek(offset)
        fh.write(bytes([b ^ 0x04]))


def _no_temporaries(folder):
    return not [p.name for p in folder.iterdir() if p.name.endswith(".tmp")]


# --- checksum ------------------------------------------------------------------------------

def _write_sample(path, order=1):
    with h5py.File(path, "w") as h:
        items = [("b", np.arange(12.0).reshape(3, 4)), ("a", np.array([1 + 2j, -0.0]))]
        for name, data in items[::order]:
            h[name] = data
        h.create_dataset("labels", data=np.array(["ux", "w12"], dtype=object),
                         dtype=h5py.string_dtype("utf-8"))
        h.create_group("g").attrs["n"] = 3
        h.attrs["provenance"] = '{"vs": 200.0}'
        return stamp_checksum(h)


def test_checksum_round_trip_and_any_change_is_detected(tmp_path):
    digest = _write_sample(tmp_path / "a.h5")
    assert digest == _write_sample(tmp_path / "b.h5", order=-1)     # creation order is irrelevant
    with h5py.File(tmp_path / "a.h5", "r") as h:
        assert h.attrs["sha256"] == digest and verify_checksum(h)
    _flip_bit(tmp_path / "a.h5", "b")                                 # one bit of one float
    with h5py.File(tmp_path / "a.h5", "r") as h:
        assert not verify_checksum(h)
    for change in (lambda h: h.attrs.__setitem__("provenance", '{"vs": 201.0}'),
                   lambda h: h["g"].attrs.__setitem__("n", 4),
                   lambda h: h.move("a", "c"),
                   lambda h: h.attrs.__delitem__("sha256")):
        _write_sample(tmp_path / "c.h5")
        with h5py.File(tmp_path / "c.h5", "r+") as h:
            change(h)
            assert not verify_checksum(h)


def test_atomic_output_keeps_the_old_file_on_error_and_needs_the_folder(tmp_path):
    target = tmp_path / "out.txt"
    target.write_text("old")
    with pytest.raises(RuntimeError), atomic_output(target) as tmp:
        assert tmp.parent == tmp_path and tmp != target
        tmp.write_text("half")
        raise RuntimeError("writer failed")
    assert target.read_text() == "old" and _no_temporaries(tmp_path)
    with atomic_output(target) as tmp:
        tmp.write_text("new")
    assert target.read_text() == "new" and _no_temporaries(tmp_path)
    with pytest.raises(OutputFolderError, match="missing"), atomic_output(tmp_path / "missing" / "x"):
        pass
    table = ImpedanceTable([1.0], np.ones((1, 1, 1)), ["uz"])
    with pytest.raises(ValueError, match=r"folder .*missing does not exist"):
        table.save(tmp_path / "missing" / "k.h5")        # a user output path: a clear error


# --- concurrent writers --------------------------------------------------------------------

def _slow_writer(barrier, cache_dir, outputs):
    """Child: sweep into ``cache_dir``, pausing inside the HDF5 write until the other child
    is inside its own write too."""
    real = h5py.Group.create_dataset

    def meet(self, *args, **kw):
        ds = real(self, *args, **kw)
        if args[0] == "frequencies_hz":
            barrier.wait(timeout=20)
        return ds
    h5py.Group.create_dataset = meet
    _sweep(cache_dir, outputs)


@fork
@pytest.mark.parametrize("repeat", range(3))
def test_two_concurrent_writers_both_succeed_and_the_entry_is_valid(tmp_path, repeat):
    ctx = multiprocessing.get_context("fork")
    barrier = ctx.Barrier(2)
    outputs = ("rigid", "gap")
    procs = [ctx.Process(target=_slow_writer, args=(barrier, tmp_path, outputs)) for _ in range(2)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(60)
    assert [p.exitcode for p in procs] == [0, 0]
    assert len(list(tmp_path.glob("*.h5"))) == 2 and _no_temporaries(tmp_path)
    fresh = _sweep(None, outputs)
    for path in tmp_path.glob("*.h5"):
        with h5py.File(path, "r") as h:
            assert verify_checksum(h)
    with warnings.catch_warnings():
        warnings.simplefilter("error", CacheWarning)
        cached = _sweep(tmp_path, outputs)
    for o in outputs:
        assert cached[o].matrices.tobytes() == fresh[o].matrices.tobytes()


# --- writer killed mid-write ---------------------------------------------------------------

def _stalled_writer(started, path, table):
    """Child: save ``table`` to ``path`` and stall inside the write (until SIGKILLed)."""
    real = h5py.Group.create_dataset

    def stall(self, *args, **kw):
        ds = real(self, *args, **kw)
        self.file.flush()
        started.set()
        signal.pause()
        return ds
    h5py.Group.create_dataset = stall
    table.save(path)


def _kill_during_save(path, table):
    ctx = multiprocessing.get_context("fork")
    started = ctx.Event()
    p = ctx.Process(target=_stalled_writer, args=(started, path, table))
    p.start()
    assert started.wait(30)
    os.kill(p.pid, signal.SIGKILL)
    p.join(30)
    assert p.exitcode == -signal.SIGKILL


@fork
def test_writer_killed_mid_write_leaves_the_old_entry_intact(tmp_path, monkeypatch):
    first = _sweep(tmp_path)["rigid"]
    path = _entry(tmp_path)
    before = path.read_bytes()
    other = ImpedanceTable(first.frequencies_hz, 2 * first.matrices, first.dofs, first.provenance)
    _kill_during_save(path, other)
    assert path.read_bytes() == before
    calls = []
    real = sweep_mod._compute
    monkeypatch.setattr(sweep_mod, "_compute", lambda *a: calls.append(1) or real(*a))
    with warnings.catch_warnings():
        warnings.simplefilter("error", CacheWarning)
        again = _sweep(tmp_path)["rigid"]
    assert calls == [] and again.matrices.tobytes() == first.matrices.tobytes()
    # the first write of an entry killed: no entry, the next run computes it silently
    fresh_dir = tmp_path / "fresh"
    fresh_dir.mkdir()
    _kill_during_save(fresh_dir / path.name, first)
    assert not (fresh_dir / path.name).exists()
    with warnings.catch_warnings():
        warnings.simplefilter("error", CacheWarning)
        assert _sweep(fresh_dir)["rigid"].matrices.tobytes() == first.matrices.tobytes()
    assert calls == [1]


# --- damaged entries -----------------------------------------------------------------------

def _zero_frequencies(path):
    """A nonsensical entry with a valid-looking structure and checksum."""
    with h5py.File(path, "r+") as h:
        h["frequencies_hz"][...] = 0.0
        stamp_checksum(h)


def _other_table(path):
    """A valid table of other inputs under this entry's name."""
    t = ImpedanceTable.load(path)
    ImpedanceTable(t.frequencies_hz, 2 * t.matrices, t.dofs, {"other": "inputs"}).save(path)


DAMAGE = {
    "bit flip in matrices": lambda p: _flip_bit(p, "matrices_real"),
    "bit flip in frequencies": lambda p: _flip_bit(p, "frequencies_hz", byte=13),
    "truncated": lambda p: os.truncate(p, os.path.getsize(p) // 2),
    "frequencies [0, 0, 0]": _zero_frequencies,
    "empty file": lambda p: open(p, "wb").close(),
    "another table": _other_table,
}


@pytest.mark.parametrize("damage", DAMAGE)
def test_damaged_entry_is_recomputed_with_a_warning(tmp_path, damage):
    fresh = _sweep(None)["rigid"]
    _sweep(tmp_path)
    path = _entry(tmp_path)
    DAMAGE[damage](path)
    with pytest.warns(CacheWarning, match=path.name):
        again = _sweep(tmp_path)["rigid"]
    assert again.matrices.tobytes() == fresh.matrices.tobytes()
    assert np.array_equal(again.frequencies_hz, FREQS)
    assert (tmp_path / (path.name + ".damaged")).is_file()           # kept for inspection
    with h5py.File(path, "r") as h:                                  # rewritten, valid
        assert verify_checksum(h)
    assert ImpedanceTable.load(path).matrices.tobytes() == fresh.matrices.tobytes()


def test_damaged_user_file_is_an_error_naming_it(tmp_path):
    _sweep(tmp_path)
    path = _entry(tmp_path)
    with h5py.File(path, "r+") as h:      # only the whole-file checksum covers this attribute
        h["frequencies_hz"].attrs["units"] = "rad/s"
    with pytest.raises(TableError, match=f"{path.name} changed since it was written"):
        ImpedanceTable.load(path)
    _flip_bit(path, "matrices_imag")
    with pytest.raises(TableError, match=f"{path.name} changed since it was written"):
        ImpedanceTable.load(path)
    with h5py.File(path, "r+") as h:      # a file without its checksum is not trusted either
        del h.attrs["sha256"]
    with pytest.raises(TableError, match=f"{path.name} carries no checksum"):
        ImpedanceTable.load(path)
    _zero_frequencies(path)
    with pytest.raises(TableError, match=f"{path.name}.*strictly increasing"):
        ImpedanceTable.load(path)


def test_read_entry_never_raises_for_a_damaged_entry(tmp_path):
    assert read_entry(tmp_path / "absent.h5", lambda h: 1) is None
    with h5py.File(tmp_path / "e.h5", "w") as h:
        h["x"] = 1.0
        stamp_checksum(h)
    assert read_entry(tmp_path / "e.h5", lambda h: h["x"][()]) == 1.0

    def reject(h):
        raise TableError("nonsense")
    with pytest.warns(CacheWarning, match="e.h5.*TableError: nonsense"):
        assert read_entry(tmp_path / "e.h5", reject) is None
    assert not (tmp_path / "e.h5").exists() and (tmp_path / "e.h5.damaged").exists()


def test_unwritable_cache_only_warns(tmp_path):
    blocker = tmp_path / "not_a_folder"
    blocker.write_text("")
    with pytest.warns(CacheWarning, match="could not write"):
        t = _sweep(blocker)["rigid"]
    assert t.matrices.tobytes() == _sweep(None)["rigid"].matrices.tobytes()


# --- the cache key -------------------------------------------------------------------------

def test_cache_key_covers_every_input():
    def key(profile=PROFILE, mesh=MESH, contact="welded", rule=None, output="rigid", f=FREQS):
        return content_hash(provenance(profile, mesh, contact, rule, output), f)
    base = key()
    assert key(rule=GreenRule()) == base                    # None is the default rule
    variants = [
        key(profile=SoilProfile.homogeneous(vs=200.0, rho=2000.0, nu=0.3, damping=0.05,
                                            damping_model="causal")),
        key(profile=SoilProfile.homogeneous(vs=200.0, rho=2000.0, nu=0.3, damping=0.04)),
        key(mesh=circle_mesh(2.0, 0.5)), key(contact="relaxed"),
        key(rule=GreenRule(nodes=GreenRule().nodes + 2)), key(output="gap"),
        key(f=[0.0, 4.0, 9.0]),
    ]
    assert len(set(variants + [base])) == len(variants) + 1


def test_each_output_is_bit_identical_whatever_else_is_requested():
    """A cached table is keyed by its own inputs only: it must not depend on the request."""
    alone = {o: _sweep(None, (o,))[o].matrices.tobytes() for o in ("rigid", "gap", "nodal")}
    for outputs in (("rigid", "gap"), ("rigid", "nodal"), ("gap", "nodal", "rigid")):
        both = _sweep(None, outputs)
        assert all(both[o].matrices.tobytes() == alone[o] for o in outputs)


def test_in_place_read_has_the_same_digest_and_copies_nothing(tmp_path, monkeypatch):
    """The verified read that puts matrices_real/imag straight into one complex array
    (uplift_common.files.ComplexPairs, what read_entry(keep=True) and ImpedanceTable.load do), with slabs
    of 5 rows read 2 rows at a time (reads crossing the hashed slabs): the digest of the plain
    slab-by-slab hash, the two parts views of one array that the table takes as its matrices
    (no copy), bit for bit (signed zeros kept); a flipped bit in either part still fails."""
    import uplift_common.files as storage
    from uplift_common.files import ComplexPairs, checksum

    n = 4
    monkeypatch.setattr(storage, "_CHUNK_BYTES", 5 * n * n * 8)
    monkeypatch.setattr(storage, "_READ_BYTES", 2 * n * n * 8)
    rng = np.random.default_rng(3)
    K = rng.standard_normal((12, n, n)) + 1j * rng.standard_normal((12, n, n))
    K[3, 1, 2] = complex(-0.0, -0.0)
    table = ImpedanceTable(np.arange(12.0), K, [f"d{i}" for i in range(n)], {"test": "in place"})
    path = tmp_path / "t.h5"
    table.save(path)
    with h5py.File(path, "r") as h:
        data, pairs = {}, ComplexPairs()
        assert checksum(h, data, pairs) == checksum(h) == h.attrs["sha256"]
        re, im = data["/matrices_real"], data["/matrices_imag"]
        assert re.base is im.base and re.base.shape == K.shape
        read = ImpedanceTable.from_hdf5(h, path, data)
    assert read.matrices is re.base and read.matrices.tobytes() == K.tobytes()
    assert ImpedanceTable.load(path).matrices.tobytes() == K.tobytes()
    for part in ("matrices_real", "matrices_imag"):
        table.save(path)
        _flip_bit(path, part, byte=8 * (7 * n * n) + 3)                # in the second slab
        with h5py.File(path, "r") as h:
            assert not verify_checksum(h, {}, ComplexPairs())

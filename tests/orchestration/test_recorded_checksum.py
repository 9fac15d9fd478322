"""The two cheaper routes to a file's checksum give the digest of the reference route.

- The results file's checksum is computed from what is written (uplift_common.files.RecordedFile),
  not read back through h5py: the digest must be the one ``checksum`` reads back from the file (the
  verifier's), for every layout the writers make (histories, a refused route, a plate raft's
  fields, the interface mesh, the groups a design run adds), with no object read back where the
  record reproduces it, and read back (the same digest) where it does not.
- The verifier's ``checksum`` lists the objects in one HDF5 walk and reads plain numeric datasets
  with h5py's low-level calls: its digest and the arrays it keeps must be those of the reading
  object by object (``_checksum_by_objects``), on a file of every kind of object.

The files are made from made-up values (no analysis), in milliseconds each.
"""
import h5py
import numpy as np
import pytest

import orchestrator.results_file as results_file
import uplift_common.files as files
from helpers.results import route_result
from helpers.scenes import tower
from orchestrator.motion import make_motion
from orchestrator.results_file import add_coordinate, add_route, add_variable, read_results, write_results
from orchestrator.scene import scene_from_dict
from structure.results import RouteResult
from uplift_common.files import (CHECKSUM_ATTR, ChangedFileError, RecordedFile, checksum, hdf5_output,
                                 require_checksum)

SCENE = tower(foundation={"lx": 6.0, "ly": 3.0, "element_size": 1.5}, motion={"duration_s": 1.0})


@pytest.fixture
def recorders(monkeypatch):
    """The RecordedFile of every results file written in the test, in order."""
    made = []

    class Recording(RecordedFile):
        def __init__(self, f):
            super().__init__(f)
            made.append(self)

    monkeypatch.setattr(results_file, "RecordedFile", Recording)
    return made


def _read_back(path) -> tuple:
    """(stored checksum, the checksum read back by the verifier) of an HDF5 file."""
    with h5py.File(path, "r") as f:
        return str(f.attrs[CHECKSUM_ATTR]), checksum(f)


def _full_result(nt=300, n=6):
    """route_result with displacements, energies, Newton counts, info and notes."""
    res = route_result("monolithic")
    rng = np.random.default_rng(5)
    t = res.time
    return res.replace(disp={"top": rng.standard_normal((nt, 3))}, newton_iters=rng.integers(0, 4, nt),
                       energy={"input": np.cumsum(rng.random(nt)), "kinetic": rng.random(nt)},
                       soil_w=rng.standard_normal((nt, n)), info={"stepper": "native", "k": [1, 2.5]},
                       wall_s=0.123456789, message="", raft=res.raft + 1e-9 * t[:, None])


def _plate_result(mesh, nt=120):
    """A made-up plate raft's result on ``mesh``: deflections, the held vertices, the moments."""
    rng = np.random.default_rng(9)
    N, m = mesh.n, 2 * mesh.n
    cells = np.arange(0, N, 3)
    return RouteResult(route="monolithic", time=0.01 * np.arange(nt), raft=rng.standard_normal((nt, 6)),
                       gap=np.abs(rng.standard_normal((nt, N))), contact_force=rng.random((nt, N)),
                       soil_w=rng.standard_normal((nt, N)), acc={"top": rng.standard_normal((nt, 3)),
                                                                 "edge": rng.standard_normal((nt, 3))},
                       xy=np.asarray(mesh.xy, float), plate_deflection=rng.standard_normal((nt, N)),
                       plate_vertex_deflection=rng.standard_normal((nt, m)),
                       plate_vertices=rng.standard_normal((m, 2)), plate_vertex_held=rng.random(m) < 0.3,
                       plate_moment=rng.standard_normal((nt, cells.size, 3)),
                       plate_moment_peak=rng.random((N, 3)), plate_moment_cells=cells)


def test_results_files_are_stamped_from_the_record_with_the_verifiers_digest(tmp_path, recorders):
    sc = scene_from_dict(SCENE, name="rect")
    motion = make_motion(sc.motion, 0.01)
    stopped = route_result("winkler", converged=False)
    refused = RouteResult.refused("timefreq", "no gap table: give foundation.mesh")
    cases = {
        "histories": dict(results={"monolithic": _full_result(), "winkler": stopped, "timefreq": refused},
                          motion=motion, scene_name="rect", scene_toml="[soil]\nname = \"é\"\n",
                          overrides=[{"option": "--pga", "value": 0.2}], mesh=sc.mesh),
        "plate": dict(results={"monolithic": _plate_result(sc.mesh)}, motion=motion, scene_name="plate",
                      mesh=sc.mesh),
        "bare": dict(results={"winkler": route_result("winkler")}),
    }
    for name, kw in cases.items():
        path = write_results(tmp_path / f"{name}.h5", **kw)
        stored, back = _read_back(path)
        assert stored == back, name
        assert recorders[-1].read_back == 0, name              # nothing read back: all from the record
    assert len(recorders) == len(cases)
    back = read_results(tmp_path / "plate.h5")["monolithic"]
    np.testing.assert_array_equal(back.plate_moment, cases["plate"]["results"]["monolithic"].plate_moment)


def test_what_the_record_does_not_reproduce_is_read_back_and_still_verifies(tmp_path, recorders):
    def extra(f):
        g = f.create_group("design")
        add_coordinate(g, "layer", np.arange(3), None, "layer")
        add_variable(g, "vs", [150.0, 300.0, 600.0], ("layer",), "m s-1", "shear-wave speed")
        g.attrs.update(converged=True, flags=[1, 2], raw=b"bytes", half=np.float32(0.5), names=["a", "b"],
                       empty=np.zeros(0), unicode="σ = 0.3")
        ds = g.create_dataset("chunked", data=np.arange(12.0).reshape(3, 4), chunks=(1, 4))
        ds.attrs["units"] = "m"
        routes = f.create_group("cases").create_group("soft").create_group("routes", track_order=True)
        add_route(routes.create_group("winkler"), route_result("winkler", gap_scale=2.0))

    path = write_results(tmp_path / "odd.h5", {"winkler": route_result("winkler")}, scene_name="odd", extra=extra)
    stored, back = _read_back(path)
    assert stored == back
    # read back: the chunked dataset (an option) and the attributes of types the record does not
    # reproduce (bool, two lists, bytes, an empty array)
    assert recorders[-1].read_back == 1 + 5


def test_a_change_the_record_does_not_follow_falls_back_to_reading_the_whole_file(tmp_path, recorders):
    def extra(f):
        f.require_group("later").attrs["note"] = "made by a call the record does not follow"
        ds = f["routes/winkler/gap"]
        ds[0, 0] = 7.0                          # a dataset changed in place after it was written

    path = write_results(tmp_path / "fallback.h5", {"winkler": route_result("winkler")}, extra=extra)
    stored, back = _read_back(path)
    assert stored == back and recorders[-1].read_back > 1
    assert read_results(path)["winkler"].gap[0, 0] == 7.0


def test_an_array_changed_by_its_writer_after_writing_is_hashed_as_stored(tmp_path):
    data = np.arange(10.0)
    with hdf5_output(tmp_path / "x.h5") as h5:
        f = RecordedFile(h5)
        f.create_dataset("a", data=data)
        data[:] = -1.0                          # the file holds 0..9: the record keeps its own copy
        f.attrs["when"] = "now"
        digest = f.stamp()
        assert f.read_back == 0
    stored, back = _read_back(tmp_path / "x.h5")
    assert stored == back == digest


def test_a_stamped_results_file_with_a_changed_attribute_is_refused(tmp_path):
    path = write_results(tmp_path / "r.h5", {"winkler": route_result("winkler")}, scene_name="toy")
    with h5py.File(path, "r+") as f:
        f["routes/winkler"].attrs["max_uplift_m"] = 0.5       # not the value written
    with h5py.File(path, "r") as f, pytest.raises(ChangedFileError, match="changed since it was written"):
        require_checksum(f, path)


def _every_kind(path):
    """An HDF5 file of every kind of object and attribute the project's files hold, and more."""
    rng = np.random.default_rng(11)
    with h5py.File(path, "w") as f:
        f.attrs.update(kind="cache", version=3, scale=0.5, flags=np.array([1, 0, 2], np.int8))
        g = f.create_group("records")
        g.create_dataset("matrix", data=rng.standard_normal((40, 7)))
        g.create_dataset("big_endian", data=rng.standard_normal(33).astype(">f8"))
        g.create_dataset("float32", data=rng.standard_normal((5, 3)).astype(np.float32))
        g.create_dataset("ints", data=rng.integers(-5, 5, (9, 2)))
        g.create_dataset("uints", data=rng.integers(0, 9, 4).astype(np.uint16))
        g.create_dataset("complex", data=rng.standard_normal(6) + 1j * rng.standard_normal(6))
        g.create_dataset("scalar", data=2.5)
        g.create_dataset("int_scalar", data=np.int64(7))
        g.create_dataset("empty", data=np.zeros((0, 3)))
        g.create_dataset("bools", data=np.array([True, False, True]))
        g.create_dataset("packed", data=rng.standard_normal((300, 4)), chunks=(16, 4), compression="gzip")
        g.create_dataset("labels", data=np.array(["a", "bé"], dtype=h5py.string_dtype()))
        g.create_dataset("fixed", data=np.array([b"xy", b"z"]))
        g.create_dataset("pairs", data=np.array([(1, 2.0)], dtype=[("i", "<i4"), ("x", "<f8")]))
        g.create_dataset("null", data=h5py.Empty("f8"))
        t = g.create_dataset("time", data=np.arange(40.0))
        t.make_scale("time")
        g["matrix"].dims[0].attach_scale(t)
        g["matrix"].attrs.update(units="m", long_name="a matrix", peak=np.float64(3.0))
        g.create_group("empty_group").attrs["note"] = "nothing"
        f.create_group("deep/er/still").create_dataset("x", data=np.ones(3))


def test_the_verifiers_low_level_reading_gives_the_reference_digest_and_arrays(tmp_path, monkeypatch):
    path = tmp_path / "every.h5"
    _every_kind(path)
    for chunk in (files._CHUNK_BYTES, 64):       # slabs of 64 bytes: several per dataset
        monkeypatch.setattr(files, "_CHUNK_BYTES", chunk)
        with h5py.File(path, "r") as f:
            fast, slow = {}, {}
            assert checksum(f, fast) == files._checksum_by_objects(f, slow) == checksum(f)
            assert sorted(fast) == sorted(slow) and len(fast) == 16       # all but the null dataspace
            for name, value in slow.items():
                assert type(fast[name]) is type(value), name          # a scalar as h5py reads it
                if isinstance(value, np.ndarray):
                    assert fast[name].dtype == value.dtype and np.array_equal(fast[name], value), name
                else:
                    assert fast[name] == value, name
    with h5py.File(path, "r+") as f:                 # and a change is seen by both
        f["records/packed"][3, 1] += 1e-12
    with h5py.File(path, "r") as f:
        assert checksum(f) == files._checksum_by_objects(f)
        changed = checksum(f)
    _every_kind(path)
    with h5py.File(path, "r") as f:
        assert checksum(f) != changed


def test_attributes_written_through_the_record_are_h5py_s_own(tmp_path):
    """A str, float or int attribute set through a RecordedFile (h5py's low-level calls) is the
    attribute h5py's ``attrs[key] = value`` makes: the same HDF5 type, shape and value, replacing
    one of the same name; the other values (bools, numpy scalars, ints beyond int64, a non-ASCII
    key) go through h5py itself; a NUL in a string is refused as h5py refuses it (nothing left);
    the record's digest is the verifier's."""
    values = {"text": "h\u00e9llo \u2013 ok", "empty": "", "x": 1.5, "nan": float("nan"), "neg": -3,
              "big": 2 ** 62, "huge": 2 ** 63, "flag": True, "np": np.float64(2.0), "caf\u00e9": "key", "twice": 1}
    plain_path, recorded_path = tmp_path / "plain.h5", tmp_path / "recorded.h5"
    with h5py.File(plain_path, "w") as f:
        for key, value in values.items():
            f.attrs[key] = value
        f.attrs["twice"] = "again"
    with hdf5_output(recorded_path) as h:
        f = RecordedFile(h)
        for key, value in values.items():
            f.attrs[key] = value
        f.attrs["twice"] = "again"
        with pytest.raises(ValueError, match="NULL"):
            f.attrs["nul"] = "a\0b"
        assert "nul" not in h.attrs
        stamped = files.stamp_checksum(f)
    with h5py.File(plain_path, "r") as a, h5py.File(recorded_path, "r") as b:
        assert set(b.attrs) - {CHECKSUM_ATTR} == set(a.attrs) == set(values)
        for key in values:
            ia, ib = h5py.h5a.open(a.id, key.encode()), h5py.h5a.open(b.id, key.encode())
            assert ia.get_type() == ib.get_type() and ia.get_space().shape == ib.get_space().shape, key
            va, vb = a.attrs[key], b.attrs[key]
            assert type(va) is type(vb) and (np.asarray(va).tobytes() == np.asarray(vb).tobytes() if
                                              not isinstance(va, str) else va == vb), key
        assert stamped == b.attrs[CHECKSUM_ATTR] == checksum(b)

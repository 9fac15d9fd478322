"""Files the project reads back are verified (uplift_common.files): a results file or an ensemble
file with any single byte of a history changed is refused ("changed since it was written", exit 2),
never read; the unmodified files give back the values written. Output paths that are not regular
files are refused, symlinks followed (the link survives), and an append re-stamps the checksum.

The files are made here without running an analysis (a RouteResult of random histories, an
ensemble assembled from made-up cell values), so each check takes milliseconds.
"""
import os
import shutil

import h5py
import numpy as np
import pytest
import xarray as xr

from orchestrator.cli import main
from orchestrator.ensemble import assemble, plan_ensemble, read_ensemble, write_ensemble
from orchestrator.results_file import ResultsFileError, check_output_path, read_results, write_results
from orchestrator.scene import scene_from_dict
from uplift_common.files import (ChangedFileError, OutputPathError, atomic_output, atomic_update,
                                    output_target, require_checksum, stamp_checksum)
from structure.results import RouteResult

FLIPS = 48          # byte positions tried per file, spread over the history's stored bytes
SCENE = {
    "soil": {"winkler": {"kv": 2.0e8, "kh": 1.5e8}},
    "foundation": {"shape": "circle", "radius": 5.0, "element_size": 2.5},
    "structure": {"nodes": [{"id": 1, "xyz": [0, 0, 0]}, {"id": 2, "xyz": [0, 0, 20], "name": "top"}],
                  "beams": [{"nodes": [1, 2], "E": 3e10, "G": 1.25e10, "A": 10.0, "Iy": 20.0, "Iz": 20.0,
                             "J": 40.0}],
                  "masses": [{"node": 2, "m": 2.0e6}], "raft": {"node": 1, "m": 1.0e6}},
    "motion": {"kind": "synthetic", "pga_g": 0.3, "duration_s": 2.0, "seed": 2},
    "analysis": {"routes": ["winkler"], "dt": 0.01},
}


def _result(nt=200, n=5):
    rng = np.random.default_rng(7)
    return RouteResult(route="winkler", time=0.01 * np.arange(nt), raft=rng.standard_normal((nt, 6)),
                       gap=np.abs(rng.standard_normal((nt, n))), contact_force=rng.standard_normal((nt, n)),
                       soil_w=rng.standard_normal((nt, n)), acc={"top": rng.standard_normal((nt, 3))},
                       xy=rng.standard_normal((n, 2)))


@pytest.fixture(scope="module")
def results_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("results") / "r.h5"
    write_results(path, {"winkler": _result()}, scene_name="toy")
    return path


@pytest.fixture(scope="module")
def ensemble_file(tmp_path_factory):
    plan = plan_ensemble(scene_from_dict(SCENE), [0.2, 0.4], seeds=[1, 2, 3])
    rng = np.random.default_rng(3)
    values = {c.key: dict(status="converged", message="", warnings="", max_uplift=float(rng.random()),
                          max_raft_rotation=float(rng.random()), min_contact_ratio=0.5, wall_time=1.0,
                          cell_time=1.0, floor_spectrum=rng.random((1, 3, 120))) for c in plan.cells}
    ds = assemble(plan, values, {}, {"workers": 1, "computed": 6, "reused": 0, "wall_s": 1.0, "cluster_s": 0.0,
                                     "setup_s": 0.0, "dt_check_s": 0.0})
    path = tmp_path_factory.mktemp("ensemble") / "e.h5"
    write_ensemble(ds, path)
    return path


def _data_span(path, name):
    """(offset, size) in the file of the contiguous stored bytes of dataset ``name``."""
    with h5py.File(path, "r") as f:
        ds = f[name]
        offset, size = ds.id.get_offset(), ds.id.get_storage_size()
    assert offset is not None and size > 0, f"{name} is not stored contiguously"
    return offset, size


def _flipped_copies(path, name, tmp_path):
    """Yield copies of ``path`` with one byte of ``name``'s data inverted, at FLIPS positions."""
    offset, size = _data_span(path, name)
    for k, pos in enumerate(np.linspace(0, size - 1, FLIPS).astype(int)):
        copy = tmp_path / f"flip{k}{path.suffix}"
        shutil.copyfile(path, copy)
        with open(copy, "r+b") as fh:
            fh.seek(offset + int(pos))
            byte = fh.read(1)
            fh.seek(offset + int(pos))
            fh.write(bytes([byte[0] ^ 0xFF]))
        yield copy


def test_results_file_round_trip(results_file):
    back = read_results(results_file)["winkler"]
    ref = _result()
    for name in ("time", "raft", "gap", "contact_force", "soil_w", "xy"):
        np.testing.assert_array_equal(getattr(back, name), getattr(ref, name))
    np.testing.assert_array_equal(back.acc["top"], ref.acc["top"])


@pytest.mark.parametrize("name", ["routes/winkler/raft_rotation", "routes/winkler/gap", "routes/winkler/acc",
                                  "routes/winkler/time", "routes/winkler/floor_spectrum"])
def test_any_flipped_byte_of_a_results_history_is_refused(results_file, tmp_path, name):
    for copy in _flipped_copies(results_file, name, tmp_path):
        with pytest.raises(ChangedFileError, match="changed since it was written"):
            read_results(copy)
        copy.unlink()


def test_compare_and_report_of_a_changed_results_file_exit_2(results_file, tmp_path, capsys):
    copy = next(_flipped_copies(results_file, "routes/winkler/gap", tmp_path))
    assert main(["compare", str(copy)]) == 2
    assert main(["report", str(copy), "-o", str(tmp_path / "rep")]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 2 and all(f"{copy} changed since it was written" in line for line in err)
    assert not (tmp_path / "rep" / "report.html").exists()


def test_ensemble_file_round_trip(ensemble_file):
    ds = read_ensemble(ensemble_file)
    with xr.open_dataset(ensemble_file, engine="h5netcdf") as raw:
        for name in ("max_uplift", "floor_spectrum", "max_uplift_fractile", "status"):
            np.testing.assert_array_equal(ds[name].values, raw[name].values)


@pytest.mark.parametrize("name", ["max_uplift", "floor_spectrum", "max_uplift_fractile"])
def test_any_flipped_byte_of_an_ensemble_is_refused(ensemble_file, tmp_path, name):
    for copy in _flipped_copies(ensemble_file, name, tmp_path):
        with pytest.raises(ChangedFileError, match="changed since it was written"):
            read_ensemble(copy)
        copy.unlink()


def test_report_of_a_changed_ensemble_exit_2(ensemble_file, tmp_path, capsys):
    copy = next(_flipped_copies(ensemble_file, "max_uplift", tmp_path))
    assert main(["report", str(copy), "-o", str(tmp_path / "rep")]) == 2
    assert f"{copy} changed since it was written" in capsys.readouterr().err


def test_a_file_without_checksum_is_refused(results_file, tmp_path):
    copy = tmp_path / "r.h5"
    shutil.copyfile(results_file, copy)
    with h5py.File(copy, "r+") as f:
        del f.attrs["sha256"]
    with pytest.raises(ChangedFileError, match="carries no checksum"):
        read_results(copy)


def test_append_then_restamp_keeps_the_file_readable(ensemble_file, tmp_path):
    """The one call for a file extended after the fact (e.g. a group appended to an ensemble)."""
    copy = tmp_path / "e.h5"
    shutil.copyfile(ensemble_file, copy)
    extra = xr.Dataset({"p": ("im", np.array([0.1, 0.5]))})
    with pytest.raises(ChangedFileError):             # appended without re-stamping: refused
        bad = tmp_path / "bad.h5"
        shutil.copyfile(ensemble_file, bad)
        extra.to_netcdf(bad, mode="a", group="extra", engine="h5netcdf")
        read_ensemble(bad)
    with atomic_update(copy) as tmp:
        extra.to_netcdf(tmp, mode="a", group="extra", engine="h5netcdf")
    np.testing.assert_array_equal(read_ensemble(copy, group="extra")["p"].values, [0.1, 0.5])
    np.testing.assert_array_equal(read_ensemble(copy)["max_uplift"].values,
                                  read_ensemble(ensemble_file)["max_uplift"].values)
    with h5py.File(copy, "r+") as f:                  # a later change is refused again
        f["extra/p"][0] = 0.2
    with pytest.raises(ChangedFileError):
        read_ensemble(copy)
    with pytest.raises(ChangedFileError), atomic_update(copy):      # and cannot be re-stamped over
        pass


# ---- output paths ------------------------------------------------------------------------------

def test_symlink_output_is_followed_and_survives(tmp_path):
    target = tmp_path / "real.h5"
    target.write_bytes(b"old")
    link = tmp_path / "link.h5"
    link.symlink_to(target)
    write_results(link, {"winkler": _result()}, scene_name="toy")
    assert link.is_symlink() and os.readlink(link) == str(target)
    np.testing.assert_array_equal(read_results(target)["winkler"].gap, _result().gap)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link.h5", "real.h5"]      # no temporary left
    dangling = tmp_path / "dangling.h5"
    dangling.symlink_to(tmp_path / "new.h5")
    with atomic_output(dangling) as tmp, h5py.File(tmp, "w") as f:
        f["x"] = [1.0]
        stamp_checksum(f)
    assert dangling.is_symlink()
    with h5py.File(tmp_path / "new.h5", "r") as f:
        require_checksum(f, "new.h5")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
def test_outputs_that_are_not_regular_files_are_refused(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    link = tmp_path / "to_pipe"
    link.symlink_to(fifo)
    (tmp_path / "file").write_text("x")
    for path, why in ((fifo, "is a FIFO"), (link, "is a FIFO"), (tmp_path / "file" / "r.h5", "is a file"),
                      (tmp_path, "is a folder")):
        with pytest.raises((ResultsFileError, OutputPathError), match=why):
            check_output_path(path)
        with pytest.raises(OutputPathError):
            output_target(path)
    assert fifo.exists() and link.is_symlink() and (tmp_path / "file").read_text() == "x"
    if os.path.exists("/dev/null"):
        with pytest.raises(ResultsFileError, match="character device"):
            check_output_path("/dev/null")

"""The results file read by xarray as it is (named dimensions, coordinates, CF units, no warning),
its stored summary, its checksum over the dimension scales, and the files of the layout before."""
import dataclasses
import json

import h5py
import numpy as np
import pytest
import xarray as xr

from orchestrator.motion import G, Motion
from orchestrator.results_file import (FORMAT_VERSION, ResultsFileError, open_results, read_motion, read_results,
                                       read_summary, summary, write_results)
from orchestrator.spectra import FLOOR_FREQUENCIES_HZ, floor_spectra
from structure.results import RouteResult, RunNotes
from uplift_common.files import ChangedFileError, stamp_checksum
from helpers import route_result

ROUTES = ("winkler", "monolithic", "cosim")


def _results():
    """A converged route with energies and displacements, a stopped one whose displacements are at
    other nodes than its accelerations, and a refused one (no histories)."""
    win = route_result("winkler").with_notes(warnings=["a warning"], timings={"solve": 0.5},
                                             info={"components": ["x", "z"]})
    nt = win.nt
    win = win.replace(disp={"top": 1e-3 * win.acc["top"]}, soil_w=1e-4 * np.ones((nt, 6)),
                      energy={"input": np.linspace(0, 1, nt), "kinetic": np.linspace(0, 0.5, nt)},
                      newton_iters=np.arange(nt) % 3)
    mono = route_result("monolithic", 2.0, converged=False).replace(disp={"raft": np.zeros((300, 3))})
    return {"winkler": win, "monolithic": mono,
            "cosim": RouteResult.refused("cosim", "refused for the test", RunNotes(skipped=("everything",)))}


@pytest.fixture(scope="module")
def results_file(tmp_path_factory):
    t = 0.01 * np.arange(300)
    motion = Motion(0.01, np.column_stack([np.sin(t), 0 * t, 0.3 * np.cos(t)]), "test motion")
    path = write_results(tmp_path_factory.mktemp("xr") / "r.h5", _results(), motion, "tiny")
    return path


@pytest.mark.filterwarnings("error")      # xarray's phony dimensions, any h5netcdf warning
def test_datatree_opens_with_named_dimensions_and_units(results_file):
    with xr.open_datatree(results_file, engine="h5netcdf") as tree:
        assert set(tree["routes"].children) == set(ROUTES) and tree.attrs["format_version"] == FORMAT_VERSION
        for node in tree.subtree:
            ds = node.to_dataset()
            assert not [d for d in ds.dims if str(d).startswith("phony_dim")], node.path
            for name, var in ds.variables.items():
                assert "long_name" in var.attrs, f"{node.path}/{name}"
                if var.dtype.kind == "f":
                    assert var.attrs.get("units"), f"{node.path}/{name} has no units"
        motion = tree["motion"].to_dataset()
        assert motion["acc"].dims == ("time", "direction") and motion["acc"].attrs["units"] == "m s-2"


@pytest.mark.filterwarnings("error")      # xarray's phony dimensions, any h5netcdf warning
def test_a_route_group_opens_as_one_dataset(results_file):
    with xr.open_dataset(results_file, group="routes/winkler", engine="h5netcdf") as ds:
        res = _results()["winkler"]
        assert ds["time"].attrs["units"] == "s" and ds["time"].dtype == float
        np.testing.assert_array_equal(ds["time"], res.time)
        assert list(ds["direction"].values) == ["x", "y", "z"] and list(ds["output"].values) == ["top"]
        np.testing.assert_array_equal(ds["node"], np.arange(6))
        np.testing.assert_array_equal(ds["x"], res.xy[:, 0])         # coordinates of the nodes
        assert "x" in ds.coords and "y" in ds.coords and ds["x"].attrs["units"] == "m"
        assert ds["gap"].dims == ("time", "node") and ds["gap"].attrs["units"] == "m"
        assert ds["contact_force"].attrs["units"] == "N"
        assert ds["acc"].dims == ("time", "output", "direction")
        np.testing.assert_array_equal(ds["acc"].sel(output="top"), res.acc["top"])
        assert ds["raft_rotation"].attrs["units"] == "rad" and ds["raft_translation"].attrs["units"] == "m"
        np.testing.assert_array_equal(ds["raft_rotation"].sel(direction="y"), res.raft[:, 4])
        assert ds["energy"].dims == ("time", "energy_term") and ds["energy"].attrs["units"] == "J"
        assert list(ds["energy_term"].values) == ["input", "kinetic"]
        assert ds["floor_spectrum"].dims == ("output", "direction", "frequency")
        assert ds["frequency"].attrs["units"] == "Hz"
        np.testing.assert_array_equal(ds["frequency"], FLOOR_FREQUENCIES_HZ)
    with xr.open_dataset(results_file, group="routes/monolithic", engine="h5netcdf") as ds:
        assert ds["disp"].dims == ("time", "disp_output", "direction")      # not the nodes of acc
        assert list(ds["disp_output"].values) == ["raft"]
    with xr.open_dataset(results_file, group="routes/cosim", engine="h5netcdf") as ds:
        assert ds.sizes["time"] == 0 and ds.attrs["status"] == "refused"


def test_the_stored_summary_is_summary(results_file):
    stored = read_summary(results_file)
    for route, res in _results().items():
        assert stored[route] == summary(res), route
        assert json.dumps(stored[route]) == json.dumps(summary(res))      # the same order as well
    with xr.open_dataset(results_file, group="routes/winkler", engine="h5netcdf") as ds:
        s = summary(_results()["winkler"])
        assert ds.attrs["max_uplift_m"] == s["max_uplift_m"] and ds.attrs["components"] == "x,z"
        assert ds.attrs["max_raft_rotation_y_rad"] == s["max_raft_rotation_axes_rad"]["y"]
        assert float(ds["peak_acc"].sel(output="top")) / G == s["peak_acc_g"]["top"]


def test_the_stored_spectrum_peaks_are_those_of_the_floor_spectra(results_file):
    res = _results()["winkler"]
    spectra = floor_spectra(res.acc, 0.01)                  # (1, 3, F): y is round-off (NaN)
    with xr.open_dataset(results_file, group="routes/winkler", engine="h5netcdf") as ds:
        np.testing.assert_array_equal(ds["floor_spectrum"], spectra)
        peak = ds["floor_spectrum_peak"].sel(output="top")
        assert float(peak.sel(direction="x")) == np.nanmax(spectra[0, 0]) and np.isnan(peak.sel(direction="y"))
        assert float(ds["floor_spectrum_peak_frequency"].sel(output="top", direction="x")) == pytest.approx(3.0, rel=0.05)
        assert float(ds["floor_spectrum_peak_frequency"].sel(output="top", direction="z")) == pytest.approx(7.0, rel=0.05)


def _same(a: RouteResult, b: RouteResult):
    for field in dataclasses.fields(RouteResult):
        x, y = getattr(a, field.name), getattr(b, field.name)
        if field.name in ("acc", "disp", "energy"):
            assert list(x) == list(y), field.name
            for k in x:
                np.testing.assert_array_equal(x[k], y[k])
        elif isinstance(x, np.ndarray):
            assert x.dtype == y.dtype and x.shape == y.shape, field.name
            np.testing.assert_array_equal(x, y)
        else:
            assert x == y, field.name


def test_read_results_gives_back_everything(results_file):
    back = read_results(results_file)
    assert list(back) == list(ROUTES) == list(read_summary(results_file))   # run order, not alphabetical
    for route, res in _results().items():
        _same(back[route], res)
    scene, _, motion = read_motion(results_file)
    assert scene == "tiny" and motion.components == ("x", "z") and motion.acc.shape == (300, 3)


def test_open_results_verifies_then_gives_xarray(results_file):
    tree = open_results(results_file)
    assert tree["routes/winkler"].to_dataset()["gap"].dims == ("time", "node")
    ds = open_results(results_file, "routes/winkler")
    assert ds.attrs["route"] == "winkler"
    with pytest.raises(ResultsFileError, match="no group 'routes/fem'"):
        open_results(results_file, "routes/fem")


@pytest.mark.parametrize("change", ["data", "units", "scale", "summary"])
def test_a_changed_file_is_still_refused(results_file, tmp_path, change):
    """A change to data, to a CF attribute, to a dimension scale (detached: the netCDF
    DIMENSION_LIST / REFERENCE_LIST attributes) or to a summary number is caught by the checksum."""
    copy = tmp_path / "changed.h5"
    copy.write_bytes(results_file.read_bytes())
    with h5py.File(copy, "r+") as f:
        g = f["routes/winkler"]
        if change == "data":
            g["gap"][5, 1] += 1e-9
        elif change == "units":
            g["gap"].attrs["units"] = "mm"
        elif change == "scale":
            g["gap"].dims[1].detach_scale(g["node"])
        else:
            g.attrs["max_uplift_m"] = 0.0
    for read in (read_results, read_summary, open_results):
        with pytest.raises(ChangedFileError, match="changed since it was written"):
            read(copy)


def _write_version_1(path, results, motion):
    """A results file of the layout before format_version 2 (as the code of that time wrote it)."""
    with h5py.File(path, "w") as f:
        f.attrs["scene"], f.attrs["created"] = "old", "2025-01-01T00:00:00"
        m = f.create_group("motion")
        m.create_dataset("acc", data=motion.acc)
        m.attrs["dt"], m.attrs["label"], m.attrs["components"] = motion.dt, motion.label, "x"
        for name, res in results.items():
            g = f.create_group(f"routes/{name}")
            for key in ("time", "raft", "gap", "contact_force", "soil_w", "newton_iters", "xy"):
                if getattr(res, key) is not None:
                    g.create_dataset(key, data=getattr(res, key))
            for key in ("acc", "disp", "energy"):
                sub = g.create_group(key)
                for item, arr in getattr(res, key).items():
                    sub.create_dataset(item, data=arr)
            g.attrs.update(route=res.route, status=res.status.value, message=res.message, wall_s=res.wall_s,
                           notes=json.dumps(res.notes.as_dict()), info=json.dumps(dict(res.info)))
        stamp_checksum(f)


def test_a_file_of_version_1_still_reads(tmp_path):
    path = tmp_path / "old.h5"
    results = _results()
    _write_version_1(path, results, Motion(0.01, np.ones((300, 3)), "old motion", ("x",)))
    back = read_results(path)
    for route, res in results.items():
        _same(back[route], res)
    assert read_motion(path)[2].label == "old motion"
    with pytest.raises(ResultsFileError, match="format_version 1.*read_results"):
        open_results(path)
    with pytest.raises(ResultsFileError, match="no stored summary"):
        read_summary(path)


def test_a_newer_version_is_refused_with_its_number(results_file, tmp_path):
    copy = tmp_path / "newer.h5"
    copy.write_bytes(results_file.read_bytes())
    with h5py.File(copy, "r+") as f:
        f.attrs["format_version"] = FORMAT_VERSION + 1
        stamp_checksum(f)
    with pytest.raises(ResultsFileError, match=f"{copy} has format_version {FORMAT_VERSION + 1}.*update uplift"):
        read_results(copy)

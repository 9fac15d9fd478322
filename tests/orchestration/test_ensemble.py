"""`uplift ensemble`: every cell equals `uplift run` of the same scene with that record and PGA;
the fractiles; a killed worker (the ensemble completes, or reports the missing cells and a
rerun fills them); resuming; bad input; the report. A small scene (reactor stick on a 21-node
raft, 1.5 s records) on real LocalClusters of 2 worker processes (the module's ensemble, the
killed worker), the synthetic seeds and the rerun on the session's scheduler (conftest)."""
import contextlib
import io
import json
import os
import re
import signal
import subprocess
import sys

import numpy as np
import pytest
import xarray as xr
from distributed import Client, LocalCluster

from orchestrator import ensemble as ens
from orchestrator.cli import main
from orchestrator.oncurve import raft_load, run_extremes
from orchestrator.results_file import read_results
from orchestrator.scene import load_scene
from orchestrator.spectra import response_spectrum
from helpers import ROOT, changed, small_reactor, write_scene
from helpers.native import seed_native

SCENE = small_reactor()
PGAS = (0.4, 0.8)


def _record_values(i):
    """1.5 s at 10 ms: a pulse of 2 + i Hz and some noise, in g (peak ~0.5 g before scaling)."""
    t = 0.01 * np.arange(151)
    noise = np.random.default_rng(i).standard_normal(t.size)
    return t, 0.5 * (np.sin(2 * np.pi * (2.0 + i) * t) * np.exp(-((t - 0.6) / 0.3) ** 2)
                     + 0.2 * noise * np.exp(-((t - 0.7) / 0.4) ** 2))


def _write_records(folder):
    """Two two-column files and one PEER AT2 file (NPTS/DT header, 5 values a line)."""
    folder.mkdir()
    for i in range(2):
        np.savetxt(folder / f"rec{i}.txt", np.column_stack(_record_values(i)))
    t, a = _record_values(2)
    lines = ["PEER NGA STRONG MOTION DATABASE RECORD", "test record, 1.5 s", "ACCELERATION TIME SERIES IN UNITS OF G",
             f"NPTS=  {a.size}, DT=   .0100 SEC"]
    lines += ["  ".join(f"{v:.10E}" for v in a[k:k + 5]) for k in range(0, a.size, 5)]
    (folder / "rec2.AT2").write_text("\n".join(lines) + "\n")
    return {"rec0.txt": ("two-column", _record_values(0)[1]), "rec1.txt": ("two-column", _record_values(1)[1]),
            "rec2.AT2": ("peer-at2", np.array([float(v) for ln in lines[4:] for v in ln.split()]))}


def _files(tmp, records) -> list:
    """The record files, one by one (each a one-component record on the scene's direction)."""
    return [str(tmp / "records" / name) for name in records]


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    """The scene, its records and the ensemble of `uplift ensemble --workers 2 --json` (3 records
    x 2 PGAs, monolithic) with a cache shared by the module."""
    tmp = tmp_path_factory.mktemp("ensemble")
    env = pytest.MonkeyPatch()
    env.setenv("UPLIFT_CACHE", str(seed_native(tmp / "cache")))     # the C runtime compiled once for the tests
    scene = tmp / "small.toml"
    write_scene(scene, SCENE)
    records = _write_records(tmp / "records")
    out = tmp / "ens.h5"
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        code = main(["ensemble", str(scene), "--records", *_files(tmp, records), "--pga", *map(str, PGAS),
                     "--workers", "2", "-o", str(out), "--json"])
    yield {"tmp": tmp, "scene": scene, "records": records, "out": out, "code": code,
           "summary": json.loads(stdout.getvalue()), "ds": xr.open_dataset(out, engine="h5netcdf").load()}
    env.undo()


def _single_run(case, name, pga, tmp):
    """`uplift run` of the scene with [motion] = the record scaled to ``pga`` (scale = pga / its
    peak in g, computed here): (summary, RouteResult)."""
    fmt, values = case["records"][name]
    motion = (f'[motion]\nkind = "record"\nfile = "{case["tmp"] / "records" / name}"\nformat = "{fmt}"\n'
              f'units = "g"\nscale = {float(pga / np.abs(values).max())!r}\n')
    path = tmp / "cell.toml"
    write_scene(path, changed(SCENE, motion=None), motion)
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        assert main(["run", str(path), "-o", str(tmp / "cell.h5"), "--json"]) == 0
    return json.loads(stdout.getvalue())["routes"]["monolithic"], read_results(tmp / "cell.h5")["monolithic"]


def test_each_cell_equals_uplift_run(case, tmp_path, monkeypatch):
    monkeypatch.setenv("UPLIFT_CACHE", str(case["tmp"] / "cache"))
    ds = case["ds"]
    assert case["code"] == 0
    assert dict(ds.sizes) == {"record": 3, "pga": 2, "route": 1, "node": 2, "direction": 3, "frequency": 120,
                              "quantile": 3}
    assert list(ds["record"].values) == ["rec0.txt", "rec1.txt", "rec2.AT2"]
    assert ds["max_uplift"].attrs["units"] == "m" and ds["pga"].attrs["units"] == "g"
    assert ds["floor_spectrum"].attrs["units"] == "m s-2" and ds["frequency"].attrs["units"] == "Hz"
    assert (ds["status"].values == "converged").all()
    rel = lambda a, b: abs(a - b) / abs(b)
    uplifts = []
    for name in case["records"]:
        for pga in PGAS:
            s, res = _single_run(case, name, pga, tmp_path)
            cell = ds.sel(record=name, pga=pga, route="monolithic")
            assert rel(float(cell["max_uplift"]), s["max_uplift_m"]) < 1e-10
            assert rel(float(cell["max_raft_rotation"]), s["max_raft_rotation_rad"]) < 1e-10
            # contact ratio: the share of nodes with gap == 0, its minimum over time
            contact = (res.gap <= 0).mean(axis=1).min()
            assert float(cell["min_contact_ratio"]) == pytest.approx(contact, rel=1e-10, abs=1e-12)
            # on the pushover curve: the moment and contact ratio of orchestrator.oncurve, as for a results file
            scene = load_scene(case["scene"])
            ext = run_extremes(res, scene.mesh.xy, scene.mesh.area, raft_load(scene.model()))
            assert rel(float(cell["max_overturning_moment"]), ext["max_moment_Nm"]) < 1e-10
            assert float(cell["min_contact_area_ratio"]) == pytest.approx(ext["min_contact_ratio"], abs=1e-12)
            assert float(cell["wall_time"]) > 0
            for node in ("top_outer", "internals_37m"):
                acc = res.acc[node]
                spectra = {d: response_spectrum(acc[:, j], 0.005, 1 / ds["frequency"].values, 0.05).psa
                           for j, d in enumerate("xyz")}
                scale = max(sa.max() for sa in spectra.values())
                for j, d in enumerate("xyz"):
                    got = cell["floor_spectrum"].sel(node=node, direction=d).values
                    if np.abs(acc[:, j]).max() <= 1e-6 * np.abs(acc).max():    # round-off: not computed
                        assert np.isnan(got).all()
                    else:   # to 1e-10 of the node's response (y, 1e-4 of x here, carries the scale's ulps)
                        np.testing.assert_allclose(got, spectra[d], rtol=1e-10, atol=1e-10 * scale)
            uplifts.append(s["max_uplift_m"])
    assert max(uplifts) > 0.01 and min(uplifts) < 0.001       # from barely lifting to strong uplift
    # fractiles over the 3 records of each PGA (linear interpolation between sorted values)
    for j, pga in enumerate(PGAS):
        u = np.sort(uplifts[j::2])
        p84 = u[1] + (0.84 * 2 - 1) * (u[2] - u[1])
        fr = ds["max_uplift_fractile"].sel(pga=pga, route="monolithic")
        assert float(fr.sel(quantile=0.5)) == pytest.approx(u[1], rel=1e-12)
        assert float(fr.sel(quantile=0.84)) == pytest.approx(p84, rel=1e-12)
        assert float(fr.sel(quantile=0.16)) == pytest.approx(u[0] + 0.32 * (u[1] - u[0]), rel=1e-12)
        js = case["summary"]["pga"][f"{pga:g}"]["monolithic"]
        assert js["median_max_uplift_m"] == pytest.approx(u[1], rel=1e-12)
        assert js["p84_max_uplift_m"] == pytest.approx(p84, rel=1e-12)
    summ = case["summary"]
    assert (summ["runs"], summ["failed"], summ["computed"], summ["reused"], summ["workers"]) == (6, 0, 6, 0, 2)
    assert summ["wall_s"] > summ["setup_s"] + summ["dt_check_s"] and summ["dt_check_s"] > 0


def test_synthetic_seeds_on_one_worker_equal_uplift_run(case, tmp_path, monkeypatch, scheduler):
    """Without --records: the scene's synthetic motion at each seed and PGA (the API, on the
    session's scheduler of one worker)."""
    monkeypatch.setenv("UPLIFT_CACHE", str(case["tmp"] / "cache"))
    ds = ens.run_ensemble(case["scene"], [0.5], seeds=[1, 2], scheduler=scheduler, cache_dir=case["tmp"] / "cache")
    assert list(ds["record"].values) == ["seed 1", "seed 2"] and list(ds["seed"].values) == [1, 2]
    for seed in (1, 2):
        path = tmp_path / "s.toml"
        write_scene(path, changed(SCENE, motion={"pga_g": 0.5, "seed": seed}))
        stdout = io.StringIO()
        with contextlib.redirect_stdout(stdout):
            assert main(["run", str(path), "-o", str(tmp_path / "s.h5"), "--json"]) == 0
        s = json.loads(stdout.getvalue())["routes"]["monolithic"]
        assert float(ds["max_uplift"].sel(record=f"seed {seed}", pga=0.5, route="monolithic")) == \
            pytest.approx(s["max_uplift_m"], rel=1e-10)


def _killer(client, log):
    """A progress callback that SIGKILLs, at the first completed cell, a worker process holding
    cells (executing or queued)."""
    pids = client.run(os.getpid)

    def progress(done, total, label):
        if log:
            return
        busy = [w for w, keys in client.processing().items() if keys and w in pids]
        if busy:
            os.kill(pids[busy[0]], signal.SIGKILL)
            log.append(busy[0])
    return progress


@pytest.mark.slow
def test_killed_worker_missing_cells_reported_then_filled(case, tmp_path):
    ref = case["ds"]
    records = _files(case["tmp"], case["records"])
    with LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=None, silence_logs=50) as cluster, \
            Client(cluster) as client:
        address = cluster.scheduler_address
        # no retry: the cells of the killed worker fail, the others complete
        cluster.scheduler.allowed_failures = 0
        out, killed = tmp_path / "ens.h5", []
        ds = ens.run_ensemble(case["scene"], PGAS, records=records, output=out, scheduler=address,
                              cache_dir=case["tmp"] / "cache", progress=_killer(client, killed))
        assert killed
        failed = ds["status"].values == ens.FAILED
        assert 1 <= failed.sum() < failed.size
        assert all("KilledWorker" in m for m in ds["message"].values[failed])
        assert np.isnan(ds["max_uplift"].values[failed]).all()
        np.testing.assert_array_equal(ds["max_uplift"].values[~failed], ref["max_uplift"].values[~failed])
        summ = ens.ensemble_summary(ds)
        assert summ["failed"] == failed.sum() and summ["computed"] == failed.size - failed.sum()
        assert {(c["record"], c["pga_g"]) for c in summ["not_converged"]} == \
            {(str(ds["record"].values[i]), float(ds["pga"].values[j])) for i, j, _ in zip(*np.nonzero(failed))}
        assert len(list((tmp_path / "ens.h5.cells").iterdir())) == failed.size - failed.sum()
        # the rerun computes the missing cells only; the result is the uninterrupted ensemble's
        cluster.scheduler.allowed_failures = 3
        ds2 = ens.run_ensemble(case["scene"], PGAS, records=records, output=out, scheduler=address,
                               cache_dir=case["tmp"] / "cache")
        assert (ds2.attrs["computed"], ds2.attrs["reused"]) == (failed.sum(), failed.size - failed.sum())
        assert (ds2["status"].values == "converged").all()
        for name in ("max_uplift", "max_raft_rotation", "min_contact_ratio", "floor_spectrum",
                     "max_uplift_fractile", "floor_spectrum_fractile"):
            np.testing.assert_array_equal(ds2[name].values, ref[name].values)
        # with retries (dask's default), a worker killed mid-run costs nothing: the ensemble completes
        killed.clear()
        ds3 = ens.run_ensemble(case["scene"], PGAS, records=records, output=tmp_path / "ens3.h5", scheduler=address,
                               cache_dir=case["tmp"] / "cache", progress=_killer(client, killed))
        assert killed and (ds3["status"].values == "converged").all()
        np.testing.assert_array_equal(ds3["floor_spectrum"].values, ref["floor_spectrum"].values)


def test_rerun_keeps_completed_cells_and_extends(case, capsys, scheduler):
    """Same -o with one more PGA: the 6 cells are kept, the 3 new ones computed (on the
    session's scheduler)."""
    out = case["tmp"] / "ens.h5"
    assert main(["ensemble", str(case["scene"]), "--records", *_files(case["tmp"], case["records"]), "--pga", "0.4", "0.8",
                 "0.6", "--scheduler", scheduler, "-o", str(out), "--json"]) == 0
    summ = json.loads(capsys.readouterr().out)
    assert (summ["runs"], summ["computed"], summ["reused"]) == (9, 3, 6)
    ds = xr.open_dataset(out, engine="h5netcdf").load()
    assert list(ds["pga"].values) == [0.4, 0.6, 0.8]
    np.testing.assert_array_equal(ds["max_uplift"].sel(pga=list(PGAS)).values, case["ds"]["max_uplift"].values)
    assert np.all(np.diff(ds["max_uplift_fractile"].sel(quantile=0.5, route="monolithic").values) > 0)


def test_cell_key_depends_on_the_inputs_only(case, monkeypatch):
    scene = load_scene(case["scene"])
    plan = ens.plan_ensemble(scene, [0.4], records=[case["tmp"] / "records" / "rec0.txt"])
    key = plan.cells[0].key
    code = (f"from orchestrator import ensemble as e; from orchestrator.scene import load_scene; "
            f"print(e.plan_ensemble(load_scene({str(case['scene'])!r}), [0.4], "
            f"records=[{str(case['tmp'] / 'records' / 'rec0.txt')!r}]).cells[0].key)")
    other = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                           env={**os.environ, "PYTHONHASHSEED": "123",
                                "PYTHONPATH": str(ROOT)}).stdout.strip()
    assert other == key
    assert ens.plan_ensemble(scene, [0.41], records=[case["tmp"] / "records" / "rec0.txt"]).cells[0].key != key
    assert ens.plan_ensemble(scene.with_routes(["winkler"]), [0.4],
                             records=[case["tmp"] / "records" / "rec0.txt"]).cells[0].key != key
    monkeypatch.setattr(ens.plan, "code_version", lambda: "changed code")
    assert ens.plan_ensemble(scene, [0.4], records=[case["tmp"] / "records" / "rec0.txt"]).cells[0].key != key


def test_fractiles_over_converged_cells_only(case):
    """assemble: a stopped and a failed cell are kept with their reason and left out of the fractiles."""
    plan = ens.plan_ensemble(load_scene(case["scene"]), [0.4], records=_files(case["tmp"], case["records"]))
    values = {}
    for (i, cell), uplift, status in zip(enumerate(plan.cells), (1.0, 5.0, 3.0), ("converged", "stopped", "")):
        if status:
            values[cell.key] = dict(status=status, message="" if i == 0 else "Newton failed", warnings="",
                                    max_uplift=uplift, max_raft_rotation=0.0, min_contact_ratio=0.5,
                                    wall_time=1.0, cell_time=1.0, floor_spectrum=np.ones((2, 3, 120)))
    ds = ens.assemble(plan, values, {plan.cells[2].key: "KilledWorker: boom"}, {})
    assert list(ds["status"].values[:, 0, 0]) == ["converged", "stopped", "failed"]
    assert list(ds["message"].values[:, 0, 0]) == ["", "Newton failed", "KilledWorker: boom"]
    assert ds["max_uplift"].values[1, 0, 0] == 5.0 and np.isnan(ds["max_uplift"].values[2, 0, 0])
    assert (ds["max_uplift_fractile"].values[:, 0, 0] == 1.0).all()
    assert int(ds["converged_records"].values[0, 0]) == 1


@pytest.mark.parametrize("args, message", [
    (["--records", "nowhere.txt", "--pga", "0.3"], "--records 'nowhere.txt': no such file or folder"),
    (["--pga", "0"], "--pga 0.0 must be a peak ground acceleration > 0 g"),
    (["--pga", "nan"], "--pga nan must be a peak ground acceleration > 0 g"),
    (["--pga", "0.3", "--route", "fem"], "argument --route: invalid choice: 'fem'"),
    (["--pga", "0.3", "--seeds", "-1"], "--seeds -1: a seed is an integer >= 0"),
    (["--pga", "0.3", "--workers", "0"], "--workers 0: a number of worker processes >= 1"),
    (["--pga", "0.3", "--workers", "2", "--scheduler", "tcp://x:1"], "not allowed with argument"),
    (["--pga", "0.3", "--scheduler", "tcp://127.0.0.1:9"], "--scheduler 'tcp://127.0.0.1:9': cannot connect"),
])
def test_bad_input_exits_2(case, tmp_path, monkeypatch, capsys, args, message):
    monkeypatch.chdir(tmp_path)
    assert main(["ensemble", str(case["scene"]), "-o", str(tmp_path / "e.h5"), "--connect-timeout", "1", *args]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "e.h5").exists()


def test_bad_record_file_is_named(case, tmp_path, capsys):
    bad = tmp_path / "bad.txt"
    bad.write_text("0.0 0.1\n0.01 zero\n")
    assert main(["ensemble", str(case["scene"]), "--records", str(bad), "--pga", "0.3"]) == 2
    assert f"{bad}, line 2" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    assert main(["ensemble", str(case["scene"]), "--records", str(tmp_path / "empty"), "--pga", "0.3"]) == 2
    assert "no record files in this folder" in capsys.readouterr().err


def test_report_of_an_ensemble(case, tmp_path, capsys):
    out = tmp_path / "rep"
    assert main(["report", str(case["out"]), "-o", str(out)]) == 0
    page = (out / "report.html").read_text()
    ds = xr.open_dataset(case["out"], engine="h5netcdf").load()
    n_pga = ds.sizes["pga"]
    median = 1e3 * float(ds["max_uplift_fractile"].sel(quantile=0.5, pga=0.8, route="monolithic"))
    assert f"<td>{median:.3f}</td>" in page and "<td>3/3</td>" in page
    images = re.findall(r"src='data:image/png;base64,([^']+)'", page)
    assert len(images) == 1 + n_pga
    assert sorted(p.name for p in out.glob("*.png")) == sorted(
        ["ensemble_against_pga.png"] + [f"ensemble_floor_spectra_{p:g}g.png" for p in ds["pga"].values])
    assert "On the static pushover curve" in page and "not a built-in scene" in page    # small.toml: no curve
    assert main(["report", str(case["out"]), "-o", str(out), "--reference", "monolithic"]) == 2
    assert "is an ensemble file" in capsys.readouterr().err
    # with the scene: every converged cell on its BEM curve
    assert main(["report", str(case["out"]), "-o", str(tmp_path / "curve"), "--pushover", str(case["scene"])]) == 0
    page = (tmp_path / "curve" / "report.html").read_text()
    assert (tmp_path / "curve" / "on_the_curve.png").is_file() and "Each cell's largest overturning moment" in page
    assert f"<td>{ds.sizes['record']}</td>" in page and "cells past the lift-off onset moment" in page

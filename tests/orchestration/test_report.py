"""`uplift report`: a self-contained HTML page from a results file; bad files exit 2."""
import base64
import re

import h5py
import numpy as np
import pytest

from orchestrator.cli import main
from orchestrator.motion import Motion
from orchestrator.results_file import summary, write_results
from helpers import route_result


@pytest.fixture
def results_file(tmp_path):
    res = {"winkler": route_result("winkler", 1.2, 0.5, converged=False), "linear": route_result("linear", 0.0, 2.0),
           "monolithic": route_result("monolithic", 1.0, 1.0)}
    motion = Motion(0.01, np.column_stack([np.sin(np.arange(300) * 0.1), np.zeros(300), np.zeros(300)]), "test motion")
    return write_results(tmp_path / "res.h5", res, motion, "tiny"), res


def test_report_is_self_contained(results_file, tmp_path, capsys):
    path, res = results_file
    out = tmp_path / "rep"
    assert main(["report", str(path), "-o", str(out), "--reference", "monolithic"]) == 0
    page = (out / "report.html").read_text()
    assert "tiny" in page and "test motion" in page
    # every route described, summarised (its summary numbers on the page) and compared
    for route, r in res.items():
        s = summary(r)
        assert f"<b>{route}</b>" in page
        assert f"<td>{1e3 * s['max_uplift_m']:.4f}</td>" in page
    assert "STOPPED: Newton failed at t = 1.5 s" in page
    assert "Route comparison (reference: monolithic)" in page
    assert "<td>+20.00</td>" in page                       # winkler max uplift 1.2x monolithic's
    # figures embedded as valid PNGs (two per route), the page references no other file
    images = re.findall(r"src='data:image/png;base64,([^']+)'", page)
    assert len(images) == 6
    assert all(base64.b64decode(d)[:8] == b"\x89PNG\r\n\x1a\n" for d in images)
    assert not re.search(r"(src|href)=['\"](?!data:)", page)
    assert sorted(p.name for p in out.glob("*.png")) == sorted(
        f"{r}_{k}.png" for r in res for k in ("raft", "floor_spectra"))


@pytest.mark.parametrize("kind", ["missing", "not-hdf5", "no-routes"])
def test_bad_results_file_exits_2(tmp_path, capsys, kind):
    path = tmp_path / "bad.h5"
    if kind == "not-hdf5":
        path.write_text("not a results file")
    elif kind == "no-routes":
        with h5py.File(path, "w") as f:
            f.attrs["scene"] = "x"
    assert main(["report", str(path), "-o", str(tmp_path / "rep")]) == 2
    err = capsys.readouterr().err
    assert str(path) in err and "uplift run SCENE -o FILE" in err
    assert not (tmp_path / "rep" / "report.html").exists()


def test_unknown_reference_exits_2(results_file, tmp_path, capsys):
    path, _ = results_file
    assert main(["report", str(path), "-o", str(tmp_path / "rep"), "--reference", "timefreq"]) == 2
    assert "--reference 'timefreq' is not in" in capsys.readouterr().err

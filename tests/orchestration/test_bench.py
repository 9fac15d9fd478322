"""`uplift bench`: rows with the contract's keys, errors against each route's finest run,
the cheapest-run mark, the CLI's JSON, and the OpenSeesPy peer (tiny configurations)."""
import json
import sys

import pytest

import orchestrator.bench as bench
from orchestrator.cli import main
from helpers.native import seed_native

TINY = {"disk-halfspace": {"winkler": {"dt": [0.02, 0.01, 0.005], "penalty": [0.1, 1.0]},
                           "linear": {"pad_s": [0.25, 2.0]},
                           "opensees": {"dt": [0.01]}}}


@pytest.fixture
def tiny(monkeypatch, tmp_path):
    """A 4 m disk mesh (21 nodes) and a 1.5 s motion; OpenSeesPy hidden (the skip path)."""
    monkeypatch.setenv("UPLIFT_CACHE", str(seed_native(tmp_path / "cache")))   # the C runtime compiled once
    monkeypatch.setattr(bench, "DISK_ELEMENT", 4.0)
    monkeypatch.setitem(bench.DISK_TOWER["motion"], "duration_s", 1.5)
    monkeypatch.setitem(bench.DISK_TOWER["motion"], "pga_g", 0.4)
    monkeypatch.setattr("orchestrator.bench.bench_config", lambda quick=False: TINY)
    monkeypatch.setattr(bench, "PEER_MODULE", "openseespy_hidden.opensees")   # its import fails


def test_quick_json_rows(tiny, capsys):
    assert main(["bench", "--quick", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)                 # exactly one JSON value on stdout
    assert isinstance(rows, list) and rows
    for r in rows:
        assert set(bench.ROW_KEYS) <= set(r)
        assert r["reference"]
    wink = [r for r in rows if r["route"] == "winkler" and r["kind"] != "cross-route"]
    # plan: the reference, 2 + 1 one-knob runs, the ladder (dt=0.01 and 0.02, both penalty=0.1)
    assert [r["kind"] for r in wink] == ["reference", "knob", "knob", "knob", "ladder", "ladder"]
    ref = wink[0]
    assert ref["knobs"] == {"dt": 0.005, "penalty": 1.0} and ref["err_max_uplift"] == 0.0
    assert ref["max_uplift_m"] > 0
    for r in wink[1:]:   # errors are the relative differences of max uplift to the reference
        assert r["err_max_uplift"] == pytest.approx(abs(r["max_uplift_m"] / ref["max_uplift_m"] - 1), rel=1e-12)
    # time-step convergence: the error falls as dt is refined
    by_dt = {r["knobs"]["dt"]: r for r in wink if r["knobs"]["penalty"] == 1.0}
    assert by_dt[0.02]["err_max_uplift"] > by_dt[0.01]["err_max_uplift"] > 0
    assert by_dt[0.02]["err_rotation"] > by_dt[0.01]["err_rotation"] > 0
    # the bonded linear route has no uplift: that error is undefined, not zero
    lin = [r for r in rows if r["route"] == "linear"]
    assert all(r["err_max_uplift"] is None and r["err_rotation"] is not None for r in lin)
    ops = [r for r in rows if r["route"] == "opensees"]
    assert ops and all(r["note"].startswith("skipped: openseespy not installed") for r in ops)


def test_mark_best_and_table():
    rows = [dict(scene="s", route="a", kind="reference", knobs={"dt": 1}, reference="a fine", wall_s=9.0,
                 err_max_uplift=0.0, err_rotation=0.0, err_spectra=0.0, max_uplift_m=1.0),
            dict(scene="s", route="a", kind="knob", knobs={"dt": 2}, reference="a fine", wall_s=3.0,
                 err_max_uplift=0.005, err_rotation=0.01, err_spectra=None, max_uplift_m=1.0),
            dict(scene="s", route="a", kind="ladder", knobs={"dt": 4}, reference="a fine", wall_s=1.0,
                 err_max_uplift=0.02, err_rotation=0.01, err_spectra=None, max_uplift_m=1.0)]
    bench.mark_best(rows)
    assert [r["best"] for r in rows] == [False, True, False]   # cheapest within 1 %, not the reference
    table = bench.format_rows(rows)
    assert "dt=2" in table and "0.500*" in table and "reference: a fine" in table
    assert "dt=2: 3.00 s, error 0.500 %" in table


def test_opensees_peer_matches_this_code(tiny, monkeypatch, tmp_path):
    """The same Winkler model in OpenSeesPy (an independent code, in a process of its own): equal
    to round-off. Skipped when openseespy is absent or cannot load its BLAS/LAPACK (Debian's
    libblas3/liblapack3), with the reason the rows give."""
    monkeypatch.setattr(bench, "PEER_MODULE", "openseespy.opensees")
    data = bench.scene_data("disk-halfspace")
    rows = bench.opensees_rows(data, "disk-halfspace", [0.01], cache_dir=None)
    if rows[0].get("note", "").startswith("skipped"):
        pytest.skip(rows[0]["note"])
    assert "openseespy" not in sys.modules                    # it ran in the peer's process
    peer = next(r for r in rows if r["kind"] == "peer")
    assert peer["max_uplift_m"] > 1e-4                        # the raft lifts
    assert peer["err_max_uplift"] < 1e-6 and peer["err_rotation"] < 1e-6


def test_plot_written(tmp_path):
    rows = [dict(scene="s", route=r, kind="knob", knobs={}, reference="x", wall_s=w, err_max_uplift=e,
                 err_rotation=e, err_spectra=None, best=False) for r, w, e in (("a", 1.0, 0.1), ("b", 2.0, 0.01))]
    out = bench.plot_rows(rows, tmp_path / "p.png")
    assert out.read_bytes()[:4] == b"\x89PNG"


def test_opensees_peer_process_that_dies_gives_skipped_rows(tiny, monkeypatch, tmp_path):
    """A peer whose process ends (here its module exits on import) gives rows with the reason,
    not a traceback, and the caller's process goes on."""
    (tmp_path / "peer_that_exits.py").write_text("import os\nos._exit(3)\n")
    monkeypatch.syspath_prepend(str(tmp_path))             # the child process gets the parent's sys.path
    monkeypatch.setattr(bench, "PEER_MODULE", "peer_that_exits")
    rows = bench.opensees_rows(bench.scene_data("disk-halfspace"), "disk-halfspace", [0.01], cache_dir=None)
    assert [r["kind"] for r in rows] == ["peer"]
    assert rows[0]["note"].startswith("skipped: openseespy not installed or cannot load")
    assert "terminated abruptly" in rows[0]["note"]

"""A hostile-input round over the commands: every refusal is clean (exit 2, one line on stderr
naming the path, value or tool and the fix, no traceback) and comes before any computation,
with nothing written or replaced. REFUSALS counts the cases (the closing note quotes it).

The scenes here need no BEM sweep to be refused (the refusals come first), so each case takes
well under a second; the two ensemble runs at the end start a real local cluster.
"""
import contextlib
import io
import json
import os
import socket
import threading
import time

import pytest

import orchestrator.cli as cli
from orchestrator.cli import main
from orchestrator.ensemble.cluster import WORKERS_PER_CORE, default_workers, local_workers
from helpers import changed, tower, write_scene
from helpers.native import seed_native

#: the tower on a 5 m disk, two frequencies, no damping, 2 s of synthetic motion; its soil apart
TOWER = tower(soil=None, foundation={"shape": "circle", "radius": 5.0, "lx": None, "ly": None},
              impedance={"frequencies_hz": [0.0, 2.0]},
              structure={"masses": [{"node": 2, "m": 2.0e6}], "raft": {"node": 1, "m": 1.0e6}, "damping": None},
              motion={"duration_s": 2.0})
BEM_SOIL = {"halfspace": {"vs": 500.0, "nu": 0.3, "rho": 2000.0}}
WINKLER_SOIL = {"winkler": {"kv": 2.0e8, "kh": 1.5e8}}


def _scene(folder, soil=BEM_SOIL, motion=None, name="s.toml", foundation=None):
    """The tower on ``soil`` with [motion] changed by ``motion`` (a dict of keys, or the whole
    table as TOML text) and [foundation] replaced by ``foundation``."""
    scene = changed(TOWER, soil=soil, **({"motion": motion} if isinstance(motion, dict) else {}))
    if foundation is not None:
        scene["foundation"] = foundation
    if isinstance(motion, str):
        scene.pop("motion")
    return write_scene(folder / name, scene, motion if isinstance(motion, str) else "")


def _fifo(path):
    os.mkfifo(path)
    return str(path)


def _silent_server():
    """A TCP server on the loopback that accepts connections and never answers; its address."""
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(8)
    held = []

    def accept():
        while True:
            try:
                held.append(srv.accept()[0])
            except OSError:
                return
    threading.Thread(target=accept, daemon=True).start()
    return f"tcp://127.0.0.1:{srv.getsockname()[1]}", srv


def _record(folder):
    (folder / "rec.dat").write_text("".join(f"{0.01 * k:.2f} {0.1 if k % 7 else -0.2}\n" for k in range(300)))


# id: (argv builder f(tmp) -> list, substring of the message); every path is under tmp
CASES = {
    "run -o device": (lambda t: ["run", _scene(t), "-o", "/dev/null"], "'/dev/null' is a character device"),
    "run -o fifo": (lambda t: ["run", _scene(t), "-o", _fifo(t / "p")], "is a FIFO (named pipe), not a regular file"),
    "run -o link to fifo": (lambda t: ["run", _scene(t), "-o", str(_link(t / "l", _fifo(t / "p")))],
                            "(the target of the link"),
    "run -o under a file": (lambda t: ["run", _scene(t), "-o", str(_file(t / "f") / "r.h5")],
                            "a folder on its way is a file"),
    "run --plot-dir a file": (lambda t: ["run", _scene(t), "--plot-dir", str(_file(t / "f"))], "is not a folder"),
    "run pga_g 1e6": (lambda t: ["run", _scene(t, motion={"pga_g": 1.0e6})],
                      "motion.pga_g = 1e+06 exceeds the intensity limit analysis.max_pga_g = 5 g"),
    "run record scale 1e6": (lambda t: (_record(t), ["run", _scene(
        t, motion='[motion]\nkind = "record"\nfile = "rec.dat"\nscale = 1.0e6\n')])[1],
        "motion.scale = 1e+06 makes the record peak at 2e+05 g, which exceeds"),
    "run pga over --max-pga": (lambda t: ["run", _scene(t), "--max-pga", "0.2"],
                               "motion.pga_g = 0.3 exceeds the intensity limit analysis.max_pga_g = 0.2 g"),
    "run --max-pga nan": (lambda t: ["run", _scene(t), "--max-pga", "nan"], "must be a finite number > 0"),
    "run one-node foundation": (lambda t: (_file(t / "n.csv", "x,y,area\n0,0,100\n"), ["run", _scene(
        t, foundation={"shape": "nodes", "file": "n.csv"})])[1],
        "1 interface node: a raft on fewer than three points cannot carry an overturning moment"),
    "run nodes on a line": (lambda t: (_file(t / "n.csv", "x,y,area\n-5,0,10\n0,0,10\n5,0,10\n"), ["run", _scene(
        t, foundation={"shape": "nodes", "file": "n.csv"})])[1], "n.csv: all 3 interface nodes lie on one line"),
    "run centre outside the nodes": (lambda t: (_file(t / "n.csv", "x,y,area\n1,1,1\n3,1,1\n1,3,1\n"), ["run", _scene(
        t, foundation={"shape": "nodes", "file": "n.csv"})])[1], "the raft centre (0, 0) is outside the footprint"),
    "impedance -o fifo": (lambda t: ["impedance", _scene(t), "-o", _fifo(t / "p")], "is a FIFO"),
    "impedance --gap device": (lambda t: ["impedance", _scene(t), "--gap", "/dev/null"], "is a character device"),
    "fit -o fifo": (lambda t: ["fit", _scene(t), "-o", _fifo(t / "p")], "is a FIFO"),
    "fit --plot folder": (lambda t: ["fit", _scene(t), "--plot", str(t)], "is a folder"),
    "export -o under a file": (lambda t: ["export", _scene(t), "-o", str(_file(t / "f") / "fmus")],
                               "lies under"),
    "export -o a file": (lambda t: ["export", _scene(t), "-o", str(_file(t / "f"))], "is not a folder"),
    "export -o holds a folder named structure.fmu": (
        lambda t: ["export", _scene(t), "-o", str(_folder(t / "x" / "structure.fmu").parent)],
        "structure.fmu' is a folder, not a regular file"),
    "export -o holds a fifo named system.ssp": (
        lambda t: ["export", _scene(t), "-o", str(_fifo_in(t / "x", "system.ssp"))], "system.ssp' is a FIFO"),
    "export --kind bogus": (lambda t: ["export", _scene(t), "-o", str(t / "x"), "--kind", "bogus"],
                            "argument --kind: invalid choice: 'bogus'"),
    "export --cross-check under a file": (
        lambda t: ["export", _scene(t), "-o", str(t / "x"), "--cross-check", str(_file(t / "f") / "xc")], "lies under"),
    "export without a layered soil": (lambda t: ["export", _scene(t, soil=WINKLER_SOIL), "-o", str(t / "x")],
                                      "has no layered soil"),
    "report of a scene": (lambda t: ["report", _scene(t), "-o", str(t / "rep")], "is a scene: `uplift report` reads"),
    "report -o a file": (lambda t: ["report", _scene(t), "-o", str(_file(t / "f"))], "is not a folder"),
    "report -o holds a fifo report.html": (lambda t: ["report", _scene(t), "-o", str(_fifo_in(t / "r", "report.html"))],
                                           "report.html' is a FIFO"),
    "report of a missing file": (lambda t: ["report", str(t / "none.h5"), "-o", str(t / "rep")], "does not exist"),
    "ensemble --pga 1e6": (lambda t: ["ensemble", _scene(t, soil=WINKLER_SOIL), "--pga", "1e6"],
                           "--pga 1000000.0 exceeds the intensity limit analysis.max_pga_g = 5 g"),
    "ensemble --pga over --max-pga": (lambda t: ["ensemble", _scene(t, soil=WINKLER_SOIL), "--pga", "3",
                                                 "--max-pga", "2"], "--pga 3.0 exceeds the intensity limit"),
    "ensemble -o device": (lambda t: ["ensemble", _scene(t, soil=WINKLER_SOIL), "--pga", "0.2", "-o", "/dev/null"],
                           "is a character device"),
    "ensemble -o fifo": (lambda t: ["ensemble", _scene(t, soil=WINKLER_SOIL), "--pga", "0.2", "-o", _fifo(t / "p")],
                         "is a FIFO"),
    "ensemble --workers -3": (lambda t: ["ensemble", _scene(t, soil=WINKLER_SOIL), "--pga", "0.2", "--workers", "-3"],
                              "--workers -3: a number of worker processes >= 1"),
    "ensemble --connect-timeout 0": (lambda t: ["ensemble", _scene(t, soil=WINKLER_SOIL), "--pga", "0.2",
                                                "--connect-timeout", "0"], "must be a finite number > 0"),
    "ensemble --scheduler refusing": (lambda t: ["ensemble", _scene(t, soil=WINKLER_SOIL), "--pga", "0.2",
                                                 "--scheduler", "tcp://127.0.0.1:9", "--connect-timeout", "2"],
                                      "--scheduler 'tcp://127.0.0.1:9': cannot connect"),
    "ensemble --scheduler not a URL": (lambda t: ["ensemble", _scene(t, soil=WINKLER_SOIL), "--pga", "0.2",
                                                  "--scheduler", "nowhere::", "--connect-timeout", "2"],
                                       "--scheduler 'nowhere::': cannot connect"),
}
REFUSALS = len(CASES) + 3          # + the cross-check folder, the silent scheduler and the missing compiler below


def _file(path, text="x"):
    path.write_text(text)
    return path


def _folder(path):
    path.mkdir(parents=True)
    return path


def _link(path, target):
    path.symlink_to(target)
    return path


def _fifo_in(folder, name):
    folder.mkdir()
    os.mkfifo(folder / name)
    return folder


def _snapshot(folder):
    return {p.relative_to(folder): (p.is_symlink(), p.is_dir(), p.stat().st_mtime_ns if p.is_file() else 0)
            for p in folder.rglob("*")}


def _refused(argv, tmp, capsys, message):
    before = _snapshot(tmp)
    t0 = time.perf_counter()
    code = main(argv)
    wall = time.perf_counter() - t0
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert code == 2, err
    if lines[0].startswith("usage: "):          # argparse: the usage, then one error line
        lines = lines[1:] if lines[-1].startswith("uplift ") else lines
        assert ": error: argument" in lines[-1], err
    else:
        assert len(lines) == 1 and lines[0].startswith("uplift: error: "), err
    assert message in err and "Traceback" not in err and out == ""
    assert _snapshot(tmp) == before, "a refused command changed its folder"
    return wall


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
@pytest.mark.parametrize("case", sorted(CASES))
def test_refused_before_any_computation(case, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    build, message = CASES[case]
    argv = build(tmp_path)
    assert _refused(argv, tmp_path, capsys, message) < 10.0


def test_cross_check_folder_holding_a_folder_named_like_an_fmu(tmp_path, capsys, monkeypatch):
    import orchestrator.crosscheck as xc
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(xc, "tool_version", lambda: "0.1.0")     # the folder's name, installed or not
    _folder(xc.model_folder(tmp_path / "xc", "soil") / "soil.fmu")
    _refused(["export", _scene(tmp_path), "-o", str(tmp_path / "x"), "--cross-check", str(tmp_path / "xc")],
             tmp_path, capsys, "soil.fmu' is a folder, not a regular file")


def test_silent_scheduler_is_a_clean_error(tmp_path, capsys, monkeypatch):
    """A scheduler address that accepts connections and never answers: refused after
    --connect-timeout, not a hang."""
    monkeypatch.chdir(tmp_path)
    address, srv = _silent_server()
    try:
        wall = _refused(["ensemble", _scene(tmp_path, soil=WINKLER_SOIL), "--pga", "0.2", "--scheduler", address,
                         "--connect-timeout", "1"], tmp_path, capsys, "no answer within 1 s")
    finally:
        srv.close()
    assert wall < 30.0


def test_missing_compiler_is_an_input_error(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    real = cli.importlib.util.find_spec
    monkeypatch.setattr(cli.importlib.util, "find_spec", lambda name, *a: None if name == "ziglang" else real(name, *a))
    _refused(["export", _scene(tmp_path), "-o", str(tmp_path / "x")], tmp_path, capsys,
             "--kind native compiles the FMUs with the C compiler of the ziglang package, which is not installed")


def test_worker_count_is_capped():
    cores = default_workers()
    assert local_workers(None, 100) == (min(cores, 100), "")
    assert local_workers(1, 100) == (1, "")
    n, note = local_workers(500, 3)
    assert n == min(3, WORKERS_PER_CORE * cores) and "--workers 500 capped to" in note
    n, note = local_workers(500, 10_000)
    assert n == WORKERS_PER_CORE * cores and f"{WORKERS_PER_CORE} per usable core" in note


@pytest.mark.slow
def test_ensemble_asked_for_hundreds_of_workers_runs_on_few(tmp_path, capsys, monkeypatch):
    """--workers 300 for two runs: two workers, a note in the summary, the runs done, no hang."""
    monkeypatch.chdir(tmp_path)
    # a cache folder of its own (no cell to reuse) holding the C runtime compiled once for the
    # tests: with --no-cache each worker compiled it into a temporary folder (~20 CPU s each)
    monkeypatch.setenv("UPLIFT_CACHE", str(seed_native(tmp_path / "cache")))
    scene = _scene(tmp_path, soil=WINKLER_SOIL, motion={"duration_s": 1.0})
    stdout = io.StringIO()
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(stdout):
        code = main(["ensemble", scene, "--seeds", "1", "2", "--pga", "0.2", "--workers", "300", "-o",
                     str(tmp_path / "e.h5"), "--json"])
    assert code == 0 and time.perf_counter() - t0 < 120
    summ = json.loads(stdout.getvalue())
    assert summ["workers"] == 2 and summ["workers_note"] == "--workers 300 capped to 2 (2 runs to compute)"
    assert summ["converged"] == 2
    assert "--workers 300 capped to 2" in capsys.readouterr().err

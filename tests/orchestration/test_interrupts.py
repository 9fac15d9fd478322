"""Ctrl-C: `uplift run`, `uplift impedance` and `uplift ensemble` in a child process, SIGINT sent
once they are computing: exit 130, one line on stderr and no traceback, the previous file at -o
left as it was and no temporary file left beside it; the ensemble keeps its finished runs in
<output>.cells/ for a resumed run, and its local cluster's processes are all gone."""
import os
import signal
import subprocess
import sys

import psutil
import pytest

from orchestrator.ensemble import CellStore, plan_ensemble
from orchestrator.scene import load_scene
from helpers import ROOT, changed, tower, write_scene

#: the tower on a 5 m disk, 21 frequencies to 20 Hz, no damping; soil, duration and step apart
SCENE = tower(soil=None, foundation={"shape": "circle", "radius": 5.0, "lx": None, "ly": None},
              impedance={"range_hz": [0.0, 20.0, 21]}, output=None,
              structure={"masses": [{"node": 2, "m": 2.0e6}], "raft": {"node": 1, "m": 1.0e6}, "damping": None})
WINKLER = {"winkler": {"kv": 2.0e8, "kh": 1.5e8}}
HALFSPACE = {"halfspace": {"vs": 500.0, "nu": 0.3, "rho": 2000.0}}


def _scene(soil, duration, dt):
    return changed(SCENE, soil=soil, motion={"duration_s": duration}, analysis={"dt": dt})


INTERRUPTED = "uplift: interrupted"
OLD = b"a previous output, to be left as it was\n"


def _restore_sigint():
    # a child started from a shell's background job inherits SIGINT ignored; Ctrl-C must reach it
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _interrupt(argv, folder, trigger):
    """Run ``uplift argv`` in ``folder``, send SIGINT at the first stderr line holding
    ``trigger``; (exit code, stderr lines)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "UPLIFT_CACHE": str(folder / "cache"), "OPENBLAS_NUM_THREADS": "1"}
    p = subprocess.Popen([sys.executable, "-m", "orchestrator.cli", *argv], cwd=folder, env=env, text=True,
                         stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                         preexec_fn=_restore_sigint)
    lines, sent, children = [], False, []
    try:
        for line in p.stderr:
            lines.append(line.rstrip("\n"))
            if trigger in line and not sent:
                children = psutil.Process(p.pid).children(recursive=True)
                p.send_signal(signal.SIGINT)
                sent = True
        code = p.wait(timeout=120)
    finally:
        if p.poll() is None:
            p.kill()
    assert sent, "the command ended before it was interrupted:\n" + "\n".join(lines)
    _, alive = psutil.wait_procs(children, timeout=10)
    assert not alive, f"processes left running after the interrupt: {alive}"     # e.g. dask workers
    return code, lines, len(children)


def _check(code, lines, out, folder, expected):
    err = "\n".join(lines)
    assert code == 130, err
    assert lines[-1].startswith(INTERRUPTED) and sum(INTERRUPTED in ln for ln in lines) == 1, err
    assert "Traceback" not in err and "Error" not in err, err
    assert out.read_bytes() == OLD
    assert sorted(p.name for p in folder.iterdir()) == sorted(expected)        # no temporary left


@pytest.mark.slow
@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
def test_run_interrupted(tmp_path):
    write_scene(tmp_path / "s.toml", _scene(WINKLER, 20.0, 0.002))
    out = tmp_path / "out.h5"
    out.write_bytes(OLD)
    code, lines, _ = _interrupt(["run", "s.toml", "-o", "out.h5", "--no-cache"], tmp_path, "run s [winkler]:  10%")
    _check(code, lines, out, tmp_path, ["s.toml", "out.h5"])


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
def test_impedance_interrupted(tmp_path):
    write_scene(tmp_path / "s.toml", _scene(HALFSPACE, 2.0, 0.01))
    out = tmp_path / "rigid.h5"
    out.write_bytes(OLD)
    code, lines, _ = _interrupt(["impedance", "s.toml", "-o", "rigid.h5", "--no-cache"], tmp_path, "impedance s:")
    _check(code, lines, out, tmp_path, ["s.toml", "rigid.h5"])


@pytest.mark.slow
@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
def test_ensemble_interrupted_keeps_finished_runs(tmp_path):
    scene = tmp_path / "s.toml"
    write_scene(scene, _scene(WINKLER, 10.0, 0.004))
    out = tmp_path / "e.h5"
    out.write_bytes(OLD)
    seeds = ["1", "2", "3", "4"]
    code, lines, workers = _interrupt(["ensemble", "s.toml", "--seeds", *seeds, "--pga", "0.3", "--workers", "1", "-o",
                              "e.h5", "--no-cache"], tmp_path, "(1/4)")
    _check(code, lines, out, tmp_path, ["s.toml", "e.h5", "e.h5.cells"])
    assert workers >= 1                 # the local cluster's processes, all gone after the interrupt
    plan = plan_ensemble(load_scene(scene), [0.3], seeds=[int(s) for s in seeds])
    store = CellStore(out)
    kept = [c for c in plan.cells if store.read(c.key) is not None]
    assert 1 <= len(kept) < len(plan.cells)
    assert len(list((tmp_path / "e.h5.cells").iterdir())) == len(kept)           # whole cells only

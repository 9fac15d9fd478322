"""Ctrl-C: `uplift run`, `uplift impedance` and `uplift ensemble` in a child process, SIGINT sent
once they are computing: exit 130, one line on stderr and no traceback, the previous file at -o
left as it was and no temporary file left beside it; the ensemble keeps its finished runs in
<output>.cells/ for a resumed run, and its local cluster's processes are all gone."""
import os
import signal
import subprocess
import sys
from pathlib import Path

import psutil
import pytest

from orchestrator.ensemble import CellStore, plan_ensemble
from orchestrator.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]
SCENE = """\
[soil]
{soil}
[foundation]
shape = "circle"
radius = 5.0
element_size = 2.5
[impedance]
range_hz = [0.0, 20.0, 21]
[structure]
nodes = [ {{ id = 1, xyz = [0, 0, 0] }}, {{ id = 2, xyz = [0, 0, 20], name = "top" }} ]
beams = [ {{ nodes = [1, 2], E = 3e10, G = 1.25e10, A = 10.0, Iy = 20.0, Iz = 20.0, J = 40.0 }} ]
masses = [ {{ node = 2, m = 2.0e6 }} ]
raft = {{ node = 1, m = 1.0e6 }}
[contact]
enabled = true
[motion]
kind = "synthetic"
pga_g = 0.3
duration_s = {duration}
seed = 2
[analysis]
routes = ["winkler"]
dt = {dt}
"""
WINKLER = "winkler = { kv = 2.0e8, kh = 1.5e8 }"
HALFSPACE = "halfspace = { vs = 500.0, nu = 0.3, rho = 2000.0 }"
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


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
def test_run_interrupted(tmp_path):
    (tmp_path / "s.toml").write_text(SCENE.format(soil=WINKLER, duration=20.0, dt=0.002))
    out = tmp_path / "out.h5"
    out.write_bytes(OLD)
    code, lines, _ = _interrupt(["run", "s.toml", "-o", "out.h5", "--no-cache"], tmp_path, "run s [winkler]:  10%")
    _check(code, lines, out, tmp_path, ["s.toml", "out.h5"])


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
def test_impedance_interrupted(tmp_path):
    (tmp_path / "s.toml").write_text(SCENE.format(soil=HALFSPACE, duration=2.0, dt=0.01))
    out = tmp_path / "rigid.h5"
    out.write_bytes(OLD)
    code, lines, _ = _interrupt(["impedance", "s.toml", "-o", "rigid.h5", "--no-cache"], tmp_path, "impedance s:")
    _check(code, lines, out, tmp_path, ["s.toml", "rigid.h5"])


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
def test_ensemble_interrupted_keeps_finished_runs(tmp_path):
    scene = tmp_path / "s.toml"
    scene.write_text(SCENE.format(soil=WINKLER, duration=10.0, dt=0.004))
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

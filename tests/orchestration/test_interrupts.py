"""Ctrl-C: `uplift run`, `uplift impedance` and `uplift ensemble` in a child process, SIGINT sent
once they are computing: exit 130, one line on stderr and no traceback, the previous file at -o
left as it was and no temporary file left beside it; the ensemble keeps its finished runs in
<output>.cells/ for a resumed run, and its local cluster's processes are all gone.

In process, the native stepper (a chunk of steps per call of the C runtime): the monolithic
route reports progress as it goes (several calls before the end), and a KeyboardInterrupt
raised between two chunks (from the progress callback) propagates with the run's memory freed,
the next run the same as a run never interrupted."""
import os
import signal
import subprocess
import sys

import numpy as np
import psutil
import pytest

from fmus import native_stepper
from orchestrator.ensemble import CellStore, plan_ensemble
from orchestrator.routes.monolithic import run_monolithic
from orchestrator.scene import load_scene
from helpers import ROOT, changed, pulse_motion, small_scene, soil_model, tower, write_scene
from helpers.native import seed_native

#: the tower on a 5 m disk, 21 frequencies to 20 Hz, no damping; soil, duration and step apart
SCENE = tower(soil=None, foundation={"shape": "circle", "radius": 5.0, "lx": None, "ly": None},
              impedance={"range_hz": [0.0, 20.0, 21]}, output=None,
              structure={"masses": [{"node": 2, "m": 2.0e6}], "raft": {"node": 1, "m": 1.0e6}, "damping": None})
WINKLER = {"winkler": {"kv": 2.0e8, "kh": 1.5e8}}
HALFSPACE = {"halfspace": {"vs": 500.0, "nu": 0.3, "rho": 2000.0}}


def _scene(soil, duration, dt):
    return changed(SCENE, soil=soil, motion={"duration_s": duration}, analysis={"dt": dt})


def _stick(n):
    """[structure] of SCENE's tower as a stick of ``n`` beams (6 n DOFs): at n = 120 the native
    stepper takes about 90 us a step (a 40 s record at 2 ms: about 1.8 s)."""
    nodes = [{"id": i + 1, "xyz": [0.0, 0.0, 20.0 * i / n]} for i in range(n + 1)]
    nodes[-1]["name"] = "top"
    beam = SCENE["structure"]["beams"][0]
    return {"nodes": nodes, "beams": [dict(beam, nodes=[i + 1, i + 2]) for i in range(n)],
            "masses": [{"node": n + 1, "m": 2.0e6}]}


INTERRUPTED = "uplift: interrupted"
OLD = b"a previous output, to be left as it was\n"


def _restore_sigint():
    # a child started from a shell's background job inherits SIGINT ignored; Ctrl-C must reach it
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _interrupt(argv, folder, trigger, cache=None):
    """Run ``uplift argv`` in ``folder`` (with the cache folder ``cache``, outside it), send
    SIGINT at the first stderr line holding ``trigger``; (exit code, stderr lines)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "UPLIFT_CACHE": str(cache or folder / "cache"),
           "OPENBLAS_NUM_THREADS": "1"}
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


@pytest.fixture
def cache(tmp_path_factory):
    """A cache folder (beside the command's folder) holding the C runtime compiled once for the
    tests: the command loads it instead of compiling it (in each process of an ensemble)."""
    return seed_native(tmp_path_factory.mktemp("cache"))


@pytest.mark.slow
@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
def test_run_interrupted(tmp_path, cache):
    """SIGINT at the route's first progress line (the first chunk of the native stepper done);
    the stick makes the steps dear enough that the run is far from its end."""
    write_scene(tmp_path / "s.toml", changed(_scene(WINKLER, 40.0, 0.002), structure=_stick(120)))
    out = tmp_path / "out.h5"
    out.write_bytes(OLD)
    code, lines, _ = _interrupt(["run", "s.toml", "-o", "out.h5"], tmp_path, "run s [winkler]:", cache)
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
def test_ensemble_interrupted_keeps_finished_runs(tmp_path, cache):
    scene = tmp_path / "s.toml"
    write_scene(scene, _scene(WINKLER, 10.0, 0.004))
    out = tmp_path / "e.h5"
    out.write_bytes(OLD)
    seeds = ["1", "2", "3", "4"]
    code, lines, workers = _interrupt(["ensemble", "s.toml", "--seeds", *seeds, "--pga", "0.3", "--workers", "1", "-o",
                              "e.h5"], tmp_path, "(1/4)", cache)
    _check(code, lines, out, tmp_path, ["s.toml", "e.h5", "e.h5.cells"])
    assert workers >= 1                 # the local cluster's processes, all gone after the interrupt
    plan = plan_ensemble(load_scene(scene), [0.3], seeds=[int(s) for s in seeds])
    store = CellStore(out)
    kept = [c for c in plan.cells if store.read(c.key) is not None]
    assert 1 <= len(kept) < len(plan.cells)
    assert len(list((tmp_path / "e.h5.cells").iterdir())) == len(kept)           # whole cells only


NATIVE = pytest.mark.skipif(native_stepper.library() is None, reason="no C compiler for the native stepper")
SMALL = small_scene()
LONG = pulse_motion(T=2.5)            # 501 samples: chunks of 200, 200 and 101


@NATIVE
def test_native_route_reports_progress_as_it_goes():
    calls = []
    res = run_monolithic(SMALL, LONG, soil_model(SMALL), progress=lambda done, total: calls.append((done, total)))
    nt = LONG.acc.shape[0]
    assert res.info["stepper"] == "native" and res.converged and res.nt == nt
    assert calls[-1] == (nt, nt) and sum(done < nt for done, _ in calls) >= 2
    assert [done for done, _ in calls] == sorted({done for done, _ in calls})      # increasing


class Counted:
    """The host library with its runs counted: opened, closed."""

    def __init__(self, lib):
        self.lib, self.opened, self.closed = lib, 0, 0

    def up_sim_open(self, *args):
        self.opened += 1
        return self.lib.up_sim_open(*args)

    def up_sim_close(self, handle):
        self.closed += 1
        return self.lib.up_sim_close(handle)

    def __getattr__(self, name):
        return getattr(self.lib, name)


@NATIVE
def test_keyboard_interrupt_between_chunks_propagates_and_frees_the_run(monkeypatch):
    from structure import NewmarkStepper
    from fmus.resources import soil_from_model
    model, dt = soil_model(SMALL), LONG.dt
    counted = Counted(native_stepper.library())

    def run(progress=None):
        st = NewmarkStepper(SMALL.model(), soil_from_model(model, dt), dt, contact=SMALL.contact, external_soil=True,
                            ag0=LONG.acc[0])
        return native_stepper.simulate_native(st, LONG.acc, SMALL.output.nodes, lib=counted, progress=progress)

    seen = []

    def interrupt(done, total):
        seen.append(done)
        if len(seen) == 2:
            raise KeyboardInterrupt
    with pytest.raises(KeyboardInterrupt):
        run(interrupt)
    assert seen == [200, 400] and counted.opened == counted.closed == 1
    after, fresh = run(), run()
    assert counted.opened == counted.closed == 3
    assert after.nt == LONG.acc.shape[0] and np.array_equal(after.raft, fresh.raft)
    monkeypatch.setattr(native_stepper, "library", lambda folder=None: counted)
    def at_once(done, total):
        raise KeyboardInterrupt
    with pytest.raises(KeyboardInterrupt):                 # through the route: not caught on the way
        run_monolithic(SMALL, LONG, model, progress=at_once)
    assert counted.opened == counted.closed == 4

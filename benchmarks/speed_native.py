"""Benchmark: the native rows of the speed table, each against the bare dense kernel measured in
the same process.

The reactor (built-in scene ``reactor``: 247 interface DOFs, its fitted soil, 10 s at 5 ms,
2000 steps), one BLAS thread. The bare kernel is the least work a soil step does: numpy,
2000 x (the history GEMV ``H g`` over the fit's poles, (6+N) x (m (6+N)), plus ``D0 x`` and
``E xdot``). Each row is a wall time (best of --repeat), its ratio to the kernel's, and the
CPU time of that run (this process and its children).

Rows (one small function each, registered with ``@row``):

  bare dense kernel              the reference (the ratio 1)
  monolithic, python stepper     ``run_monolithic(stepper="python")``: structure.simulate (wall_s)
  monolithic, native stepper     ``run_monolithic`` (the default): the C runtime in process, one
                                 call for the whole motion (wall_s: the stepper's set-up included)
  native coupled.fmu, C host     the exported coupled FMU under a plain C program (the project's
                                 test host, tests/native/host.c), the whole process: load,
                                 instantiate, 2000 steps of the bundled motion
  cosim, native pair             ``run_cosim`` (the default): the pair under the project's master
                                 (wall_s, the FMU build apart)
  cosim, python pair             ``run_cosim(kind="python")``
  ensemble, 2 workers            ``run_ensemble`` of 8 seeds x 2 PGAs on 2 local workers, from an
                                 empty output: runs per minute (cluster start and set-up included)

--busy runs every row beside one CPU-burning process (started and stopped here): the machine
has two cores, so a route that uses both feels it.

    python benchmarks/speed_native.py [--repeat 3] [--busy] [--only ROW ...]

The machine may be shared: idle means nothing else of ours runs, not that the cores are free;
compare rows of one run, and rerun when in doubt.
"""
from __future__ import annotations

import os

os.environ["OPENBLAS_NUM_THREADS"] = "1"      # before numpy: one BLAS thread, the benchmark's rule
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import contextlib
import shutil
import subprocess
import sys
import tempfile
import time
import zipfile
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

SCENE = "reactor"
DT = 0.005
ROOT = Path(__file__).resolve().parents[1]

#: the rows, in order: name -> function(Case) -> (wall s, note)
ROWS: dict = {}


def row(name):
    """Register a row: ``@row("name")`` on a function(case) -> (wall seconds, note string)."""
    def register(fn):
        ROWS[name] = fn
        return fn
    return register


@dataclass
class Case:
    """The reactor's inputs, loaded once (the cache is read, or filled on the first run)."""

    @cached_property
    def cache(self):
        from orchestrator.settings import default_cache_dir
        return default_cache_dir()

    @cached_property
    def scene(self):
        from orchestrator.scene import load_scene
        return load_scene(SCENE)

    @cached_property
    def motion(self):
        from orchestrator.motion import make_motion
        return make_motion(self.scene.motion, DT)

    @cached_property
    def fit(self):
        from orchestrator.impedance import scene_fit
        return scene_fit(self.scene, cache_dir=self.cache)

    @cached_property
    def coupled(self):
        """(folder, library, GUID, {name: value reference}) of the exported native coupled FMU."""
        from fmpy import read_model_description

        from fmus.native_build import build_native_fmus
        from fmus.native_host import fmu_binaries
        from orchestrator.export import fmu_data
        tmp = Path(tempfile.mkdtemp(prefix="speed_native_"))
        data = fmu_data(self.scene, self.fit.model, DT, self.motion)
        bins = fmu_binaries()
        path = build_native_fmus(data, tmp, coupled=True, platforms=tuple(bins), binaries=bins)["coupled"]
        with zipfile.ZipFile(path) as z:
            z.extractall(tmp / "coupled")
        md = read_model_description(str(path))
        lib = tmp / "coupled" / "binaries" / "linux64" / f"{md.coSimulation.modelIdentifier}.so"
        return tmp / "coupled", lib, md.guid, {v.name: v.valueReference for v in md.modelVariables}

    @cached_property
    def host(self):
        """The plain C host (tests/native/host.c) compiled here."""
        from fmus.native_build import fmi_headers
        exe = Path(tempfile.mkdtemp(prefix="speed_host_")) / "host"
        subprocess.run([shutil.which("cc") or "gcc", "-O2", "-rdynamic", f"-I{fmi_headers()}",
                        str(ROOT / "tests" / "native" / "host.c"), "-o", str(exe), "-ldl", "-lm"], check=True)
        return exe


@row("bare dense kernel")
def bare_kernel(case: Case):
    model = case.fit.model
    n, m = model.n, model.poles.size
    nt = case.motion.acc.shape[0]
    rng = np.random.default_rng(0)
    H = rng.standard_normal((n, m * n))
    D0, E = rng.standard_normal((n, n)), rng.standard_normal((n, n))
    g, x, xd = rng.standard_normal(m * n), rng.standard_normal(n), rng.standard_normal(n)
    out = np.empty(n)
    t0 = time.perf_counter()
    for _ in range(nt):
        np.matmul(H, g, out=out)
        out += D0 @ x
        out += E @ xd
    return time.perf_counter() - t0, f"{nt} x (H {n}x{m * n}, D0 and E {n}x{n})"


def _monolithic(case: Case, stepper: str):
    from orchestrator.routes.monolithic import run_monolithic
    res = run_monolithic(case.scene, case.motion, case.fit.model, stepper=stepper)
    return res.wall_s, f"max uplift {1e3 * res.max_uplift():.6f} mm ({res.info['stepper']})"


@row("monolithic, python stepper")
def monolithic_python(case: Case):
    return _monolithic(case, "python")


@row("monolithic, native stepper")
def monolithic_native(case: Case):
    return _monolithic(case, "native")


@row("native coupled.fmu, C host")
def coupled_c_host(case: Case):
    folder, lib, guid, vr = case.coupled
    host = case.host
    nt = case.motion.acc.shape[0]
    t0 = time.perf_counter()
    out = subprocess.run([str(host), "run", str(folder), str(lib), guid, repr(DT), str(nt - 1), str(vr["max_uplift"])],
                         capture_output=True, text=True, check=True)
    wall = time.perf_counter() - t0
    up = float(dict(line.split() for line in out.stdout.splitlines() if line[:1].isdigit())[str(vr["max_uplift"])])
    return wall, f"max uplift {1e3 * up:.6f} mm (whole process)"


def _cosim(case: Case, kind: str):
    from orchestrator.routes.cosim import run_cosim
    res = run_cosim(case.scene, case.motion, case.fit.model, kind=kind)
    return res.wall_s, (f"max uplift {1e3 * res.max_uplift():.6f} mm ({res.info['fmu_kind']} pair; FMU build "
                        f"{res.notes.timings['FMU build']:.2f} s apart)")


@row("cosim, native pair")
def cosim_native(case: Case):
    return _cosim(case, "native")


@row("cosim, python pair")
def cosim_python(case: Case):
    return _cosim(case, "python")


@row("ensemble, 2 workers")
def ensemble_two_workers(case: Case):
    from orchestrator.ensemble import run_ensemble
    scene = case.scene.with_routes(["monolithic"])
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        ds = run_ensemble(scene, [0.15, 0.3], seeds=list(range(1, 9)), output=Path(tmp) / "e.h5", workers=2,
                          cache_dir=case.cache)
        wall = time.perf_counter() - t0
    runs = int(ds["status"].size)
    return wall, f"{runs} runs, {60 * runs / wall:.1f} runs/min (cluster start, set-up and step check included)"


@contextlib.contextmanager
def busy(on: bool):
    """One CPU-burning process beside the block (when ``on``)."""
    proc = subprocess.Popen([sys.executable, "-c", "while True: pass"]) if on else None
    try:
        yield
    finally:
        if proc is not None:
            proc.terminate()
            proc.wait()


def cpu_now() -> float:
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--busy", action="store_true", help="beside one CPU-burning process")
    ap.add_argument("--only", nargs="+", choices=list(ROWS), default=None)
    args = ap.parse_args(argv)
    case = Case()
    case.fit                                            # noqa: B018  (the cache read before any timing)
    names = ["bare dense kernel"] + [r for r in (args.only or ROWS) if r != "bare dense kernel"]
    rows = {}
    with busy(args.busy):
        for name in names:
            if name.startswith("native coupled"):
                case.coupled, case.host                  # noqa: B018  (the export and the host built untimed)
            best = None
            for _ in range(1 if name.startswith("ensemble") else args.repeat):
                c0 = cpu_now()
                wall, note = ROWS[name](case)
                cpu = cpu_now() - c0
                if best is None or wall < best[0]:
                    best = (wall, cpu, note)
            rows[name] = best
            kernel = rows["bare dense kernel"][0]
            print(f"{name:32s} {best[0]:8.3f} s  {best[0] / kernel:6.2f}x  cpu {best[1]:7.2f} s  {best[2]}", flush=True)
    print(f"(reactor, 2000 steps, one BLAS thread, {'beside one busy process' if args.busy else 'idle'}; "
          f"load average {os.getloadavg()[0]:.1f} at the end)")


if __name__ == "__main__":
    main()

"""Benchmark: what each route costs against the bare dense kernel, measured in the same process.

The reactor (built-in scene ``reactor``: 247 interface DOFs, its fitted soil, 10 s at 5 ms,
2000 steps), one BLAS thread. The bare kernel is the least work a soil step does: numpy,
2000 x (the history GEMV ``H g`` over the fit's poles, (6+N) x (m (6+N)), plus ``D0 x`` and
``E xdot``). Each row is a wall time (best of --repeat), its ratio to the kernel's, and the
CPU time of that run (all threads and child processes: on a loaded machine the wall time
grows, the CPU time much less).

Rows (one small function each, registered with ``@row``; add one the same way):

  bare dense kernel          the reference (the ratio 1)
  monolithic stepping        structure.simulate (the Python stepper) on the fit's recursive
                             convolution
  monolithic route           ``run_monolithic``'s default: the C runtime in process, 200 steps
                             per call (its wall_s: the stepper's set-up included)
  monolithic, plate raft     the same on a 4 m concrete plate raft (``PLATE``: 241 nodes, 276
                             vertices, 216 free), the note its ratio to the rigid run made in the
                             same call (issue 38: at most 5x)
  native coupled.fmu         the exported native coupled FMU under a plain C program (the
                             project's test host, tests/fmu/native/host.c), the whole process: load,
                             instantiate, 2000 steps of the bundled motion
  cosim, native pair         ``run_cosim``'s default: the native pair under the project's master
                             (wall_s, the FMU build apart)
  cosim, python pair         ``run_cosim(kind="python")``
  winkler route              the winkler route's stepping in ``run_scene`` (its wall_s; the
                             cache warm)
  step check (cold)          ``step_doubling`` (the time-step check every time-stepped run makes:
                             the proxy springs at dt and dt/2), nothing cached
  ensemble, 2 workers        ``run_ensemble`` of 8 seeds x 2 PGAs on 2 local workers from an empty
                             output, runs per minute (cluster start, set-up, step check included)
  timefreq route             orchestrator.routes.timefreq.run_timefreq on the BEM table, given the
                             scene's fit (the march on its causal stand-in, orchestrator/standin.py)
  uplift run (warm)          the whole command ``uplift run reactor --route monolithic`` in a
                             fresh process, cache warm (the sweep and the fit are read here first);
                             its note gives the route's own wall time (the stepping, as the command
                             prints it, 2 decimals), the whole process's ratio to it, and the ratio
                             of CPU times (the child's against ``run_monolithic`` alone; issue 41:
                             at most 2x)
  uplift run timefreq        the same with ``--route timefreq``: what one reference run costs a
                             user, the gap table read and verified
  uplift --help              the command line's help in a fresh process (the light commands load
                             none of numpy, scipy, h5py, the FMU stack or dask)
  uplift scene               ``uplift scene reactor`` (the built-in scene's text on stdout), a fresh
                             process

--busy runs every row beside one CPU-burning process (``python -c "while True: pass"``,
started and stopped here): the machine has two cores, so a route that uses both feels it.

    python benchmarks/speed.py [--repeat 3] [--busy] [--only ROW ...] [--json] [--before CHECKOUT]

--before CHECKOUT measures the same rows on another checkout first (this file run in a child
process with PYTHONPATH=CHECKOUT, the same cache), then on this one, and prints them side by
side (before -> after: wall, ratio to each run's own kernel, CPU), beside the busy process too
with --busy; under load, compare the CPU columns.

The code measured is the one imported (PYTHONPATH), also by the ``uplift run`` row: the same
file measures another checkout with PYTHONPATH=<checkout>. The machine may be shared: idle means nothing else of ours runs, not that the cores are free;
compare rows of one run, and rerun when in doubt.
"""
from __future__ import annotations

import os

os.environ["OPENBLAS_NUM_THREADS"] = "1"      # before numpy: one BLAS thread, the benchmark's rule
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import contextlib
import json
import re
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

SCENE = "reactor"
DT = 0.005

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

    cache_dir: Path | None = None

    @cached_property
    def scene(self):
        from orchestrator.scene import load_scene
        return load_scene(SCENE)

    @cached_property
    def model(self):
        return self.scene.model()

    @cached_property
    def motion(self):
        from orchestrator.motion import make_motion
        return make_motion(self.scene.motion, DT)

    @cached_property
    def table(self):
        from orchestrator.impedance import scene_impedance
        return scene_impedance(self.scene, ("gap",), cache_dir=self._cache())["gap"]

    @cached_property
    def fit(self):
        from orchestrator.impedance import scene_fit
        return scene_fit(self.scene, cache_dir=self._cache(), table=self.table)

    @cached_property
    def coupled(self):
        """(folder, library, GUID, {name: value reference}) of the native coupled FMU, exported here."""
        import zipfile

        from fmpy import read_model_description

        from fmus.native_build import build_native_fmus
        from fmus.native_stepper import fmu_binaries
        from orchestrator.export import fmu_data
        tmp = Path(tempfile.mkdtemp(prefix="speed_coupled_"))
        bins = fmu_binaries()
        path = build_native_fmus(fmu_data(self.scene, self.fit.model, DT, self.motion), tmp, coupled=True,
                                 platforms=tuple(bins), binaries=bins)["coupled"]
        with zipfile.ZipFile(path) as z:
            z.extractall(tmp / "coupled")
        md = read_model_description(str(path))
        lib = tmp / "coupled" / "binaries" / "linux64" / f"{md.coSimulation.modelIdentifier}.so"
        return tmp / "coupled", lib, md.guid, {v.name: v.valueReference for v in md.modelVariables}

    @cached_property
    def host(self):
        """The plain C host of the native FMUs (tests/fmu/native/host.c), compiled here."""
        import shutil

        from fmus.native_build import fmi_headers
        exe = Path(tempfile.mkdtemp(prefix="speed_host_")) / "host"
        subprocess.run([shutil.which("cc") or "gcc", "-O2", "-rdynamic", f"-I{fmi_headers()}",
                        str(Path(__file__).resolve().parents[1] / "tests" / "fmu" / "native" / "host.c"), "-o", str(exe),
                        "-ldl", "-lm"], check=True)
        return exe

    def _cache(self):
        if self.cache_dir is not None:
            return self.cache_dir
        env = os.environ.get("UPLIFT_CACHE")
        return Path(env) if env else Path.home() / ".cache" / "uplift"


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


@row("monolithic stepping")
def monolithic_stepping(case: Case):
    from soil_impedance.convolution import RecursiveConvolutionSoil
    from structure import simulate
    soil = RecursiveConvolutionSoil(case.fit.model, DT)
    sc = case.scene
    t0 = time.perf_counter()
    res = simulate(case.model, soil, case.motion.acc, DT, contact=sc.contact, output_nodes=sc.output.nodes)
    return time.perf_counter() - t0, f"max uplift {1e3 * res.max_uplift():.4f} mm"


@row("monolithic route")
def monolithic_route(case: Case):
    from orchestrator.routes.monolithic import run_monolithic
    res = run_monolithic(case.scene, case.motion, case.fit.model, model=case.model)
    return res.wall_s, f"max uplift {1e3 * res.max_uplift():.4f} mm ({res.info['stepper']} stepper)"


#: the plate raft of the row "monolithic, plate raft": 4 m of concrete (a real basemat; under the
#: reactor's 10 s motion a 2 m plate's uplift grows without bound on either stepper), held rigid
#: within half the raft's radius (the scene's default)
PLATE = dict(thickness=4.0, E=30e9, nu=0.2, rho=2500.0)


@row("monolithic, plate raft")
def monolithic_plate(case: Case):
    """The reactor on a plate raft (its 241 interface nodes the plate's cells), the monolithic
    route's native stepper, against the rigid reactor's run in the same call: (the plate's wall
    s, a note with the ratios of wall and CPU times to the rigid run's, the plate run's CPU s)."""
    import dataclasses

    from orchestrator.routes.monolithic import run_monolithic
    from structure.plate_raft import PlateProperties
    sc = case.scene
    plate = dataclasses.replace(sc, analysis=dataclasses.replace(sc.analysis, routes=("monolithic",)),
                                raft=PlateProperties(rigid_radius=0.5 * sc.mesh.radius, **PLATE))
    pm = plate.plate_model(case.model)
    c0 = _cpu()
    rigid = run_monolithic(sc, case.motion, case.fit.model, model=case.model)
    c1 = _cpu()
    res = run_monolithic(plate, case.motion, case.fit.model, model=pm)
    cpu = _cpu() - c1
    return res.wall_s, (f"{res.wall_s / rigid.wall_s:.2f} x the rigid run's wall ({rigid.wall_s:.2f} s), "
                        f"{cpu / (c1 - c0):.2f} x its CPU; {pm.nf} free vertices, max uplift "
                        f"{1e3 * res.max_uplift():.2f} mm ({res.info['stepper']} stepper)"), cpu


@row("native coupled.fmu")
def native_coupled(case: Case):
    folder, lib, guid, vr = case.coupled
    nt = case.motion.acc.shape[0]
    t0 = time.perf_counter()
    out = subprocess.run([str(case.host), "run", str(folder), str(lib), guid, repr(DT), str(nt - 1),
                          str(vr["max_uplift"])], capture_output=True, text=True, check=True)
    wall = time.perf_counter() - t0
    up = float(dict(line.split() for line in out.stdout.splitlines() if line[:1].isdigit())[str(vr["max_uplift"])])
    return wall, f"max uplift {1e3 * up:.4f} mm, plain C host (whole process)"


def _cosim(case: Case, kind: str):
    from orchestrator.routes.cosim import run_cosim
    res = run_cosim(case.scene, case.motion, case.fit.model, kind=kind)
    cpu = sum(res.info["timing_cpu"].values())                  # the run's parts: the FMU build apart
    return res.wall_s, (f"max uplift {1e3 * res.max_uplift():.4f} mm ({res.info['fmu_kind']} pair; FMU build "
                        f"{res.notes.timings['FMU build']:.2f} s apart)"), cpu


@row("cosim, native pair")
def cosim_native(case: Case):
    return _cosim(case, "native")


@row("cosim, python pair")
def cosim_python(case: Case):
    return _cosim(case, "python")


@row("winkler route")
def winkler_route(case: Case):
    from orchestrator.run import run_scene
    res = run_scene(case.scene, ["winkler"], cache_dir=case._cache(), motion=case.motion)[0]["winkler"]
    return res.wall_s, f"max uplift {1e3 * res.max_uplift():.4f} mm ({res.info.get('stepper', 'python')} stepper)"


@row("step check (cold)")
def step_check_cold(case: Case):
    from fmus.native_stepper import library
    from orchestrator.run import proxy_springs, step_doubling
    library()                                       # compiled untimed (a temporary folder of the process)
    springs = proxy_springs(case.scene, True, case._cache())
    t0 = time.perf_counter()
    out = step_doubling(case.scene, case.model, springs, case.motion)      # no cache folder: stepped
    wall = time.perf_counter() - t0
    return wall, (f"dt and dt/2 on the springs, {out['window_s'][1] - out['window_s'][0]:.0f} s: "
                  f"{1e3 * out['max_uplift_m']:.4f} / {1e3 * out['max_uplift_half_dt_m']:.4f} mm")


@row("ensemble, 2 workers")
def ensemble_two_workers(case: Case):
    from orchestrator.ensemble import run_ensemble
    scene = case.scene.with_routes(["monolithic"])
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        ds = run_ensemble(scene, [0.15, 0.3], seeds=list(range(1, 9)), output=Path(tmp) / "e.h5", workers=2,
                          cache_dir=case._cache())
        wall = time.perf_counter() - t0
    runs = int(ds["status"].size)
    return wall, f"{runs} runs: {60 * runs / wall:.1f} runs/min (cluster start, set-up, step check included)"


@row("timefreq route")
def timefreq_route(case: Case):
    from orchestrator.routes.timefreq import run_timefreq
    sc = case.scene
    t0 = time.perf_counter()
    res = run_timefreq(case.motion, case.model, case.table, contact=sc.contact, output_nodes=sc.output.nodes,
                       fit=case.fit, cache_dir=case._cache())
    wall = time.perf_counter() - t0
    info = res.info
    return wall, (f"max uplift {1e3 * res.max_uplift():.6f} mm, {info['iterations']} sweeps on the "
                  f"{info['march']}, setup {info['setup_s']:.2f} s")


@row("uplift run (warm)")
def uplift_run_warm(case: Case):
    return _uplift_run(case, "monolithic")


@row("uplift run timefreq")
def uplift_run_timefreq(case: Case):
    return _uplift_run(case, "timefreq")


@row("uplift --help")
def uplift_help(case: Case):
    return _uplift_light(["--help"])


@row("uplift scene")
def uplift_scene(case: Case):
    return _uplift_light(["scene", SCENE])


def _uplift_light(args):
    """``uplift ARGS`` in a fresh process (its bytecode written, as for ``_uplift_run``): (wall s,
    note with the modules it imported)."""
    import orchestrator                             # the code under test: the one this process imports
    root = Path(orchestrator.__file__).resolve().parents[1]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")]))
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    cmd = [sys.executable, "-m", "orchestrator.cli", *args]
    with tempfile.TemporaryDirectory() as tmp:      # not the current folder: `-m` puts it first on the path
        c0, t0 = _cpu(), time.perf_counter()
        done = subprocess.run(cmd, cwd=tmp, env=env, capture_output=True, text=True)
        wall, cpu = time.perf_counter() - t0, _cpu() - c0
        probe = subprocess.run([sys.executable, "-X", "importtime", *cmd[1:]], cwd=tmp, env=env, capture_output=True,
                               text=True)
    if done.returncode:
        raise RuntimeError(f"uplift {' '.join(args)} failed ({done.returncode}): {done.stderr[-2000:]}")
    names = set(re.findall(r"^import time:\s+\d+ \|\s+\d+ \|\s*(\S+)\s*$", probe.stderr, re.M))
    heavy = sorted({n.split(".")[0] for n in names} & {"numpy", "scipy", "h5py", "fmpy", "pythonfmu", "dask"})
    return wall, f"whole process, {len(names)} modules imported" + (f" (among them {', '.join(heavy)})" if heavy else
                                                                     " (no numpy, scipy, h5py, FMU stack, dask)"), cpu


def _uplift_run(case: Case, route: str):
    """``uplift run reactor --route <route>`` in a fresh process, the cache warm: (wall s, note,
    the child's CPU s). The note gives the route's own wall time (as the command prints it) and
    the whole process's ratio to it; for the monolithic route also the ratio of the child's CPU
    time to the CPU time of the stepping alone (``run_monolithic`` on the same inputs in this
    process: on a loaded machine the wall times of the two are stretched differently, their CPU
    times much less). The child may write its bytecode (PYTHONDONTWRITEBYTECODE is dropped): an
    installed package has it compiled, so the best of --repeat is what a user's run costs."""
    case.fit                                        # noqa: B018  (the cache warm before the timed command)
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "orchestrator.cli", "run", SCENE, "--route", route,
               "-o", str(Path(tmp) / "out.h5")]
        import orchestrator                         # the code under test: the one this process imports
        root = Path(orchestrator.__file__).resolve().parents[1]
        env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")]))
        env.pop("PYTHONDONTWRITEBYTECODE", None)
        if case.cache_dir is not None:
            env["UPLIFT_CACHE"] = str(case.cache_dir)
        c0, t0 = _cpu(), time.perf_counter()
        done = subprocess.run(cmd, cwd=tmp, env=env, capture_output=True, text=True)
        wall, cpu = time.perf_counter() - t0, _cpu() - c0
    if done.returncode:
        raise RuntimeError(f"uplift run failed ({done.returncode}): {done.stderr[-2000:]}")
    stepped = re.search(rf"^{route} .*wall ([0-9.]+) s", done.stdout, re.M)          # the summary: stdout
    note = ("whole process: imports, cache reads, checks, the route" + (f" ({stepped.group(1)} s)" if stepped else "")
            + ", the results file")
    if stepped and float(stepped.group(1)) > 0:
        note += f"; {wall / float(stepped.group(1)):.2f}x its stepping"
    if route == "monolithic":
        from orchestrator.routes.monolithic import run_monolithic
        p0 = time.process_time()
        run_monolithic(case.scene, case.motion, case.fit.model, model=case.model)
        step_cpu = time.process_time() - p0
        note += f", in CPU time {cpu / step_cpu:.2f}x (the stepping alone: {step_cpu:.2f} s CPU)"
    return wall, note, cpu


@contextlib.contextmanager
def busy_process(on: bool):
    """One CPU-burning process beside the benchmark (stopped on exit), or nothing."""
    if not on:
        yield None
        return
    proc = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        time.sleep(0.5)
        yield proc
    finally:
        proc.kill()
        proc.wait()


def measure(names, repeat: int, busy: bool, case: Case | None = None) -> list:
    """[{row, wall_s (best of repeat), ratio to the bare kernel, note}] for the rows ``names``
    (the bare kernel is always measured, first)."""
    case = case or Case()
    case.fit                                        # noqa: B018  (inputs loaded before any timing)
    names = ["bare dense kernel"] + [n for n in names if n != "bare dense kernel"]
    out = []
    with busy_process(busy):
        for name in names:
            if name == "native coupled.fmu":
                case.coupled, case.host                 # noqa: B018  (the export and the host built untimed)
            if name in ("monolithic route", "monolithic, plate raft"):   # the C runtime compiled untimed: its
                from fmus.native_stepper import library  # compiler's CPU time would count in the first run
                library()
            runs = []
            for _ in range(repeat):
                c0 = _cpu()
                wall, note, *cpu = ROWS[name](case)      # a row may give its own CPU time (its timed part)
                runs.append((wall, cpu[0] if cpu else _cpu() - c0, note))
            wall, cpu, note = min(runs)                 # the best run, with its own note
            out.append({"row": name, "wall_s": wall, "cpu_s": cpu, "note": note})
    kernel = out[0]["wall_s"]
    for r in out:
        r["ratio"] = r["wall_s"] / kernel
    return out


def _cpu() -> float:
    """CPU seconds of this process (all its threads) and its finished children so far."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def format_rows(rows, busy: bool) -> str:
    head = (f"{'what':<24} {'wall s':>8} {'x kernel':>9} {'cpu s':>7}  "
            f"({'beside one busy process' if busy else 'idle'})")
    lines = [head, "-" * len(head)]
    lines += [f"{r['row']:<24} {r['wall_s']:8.3f} {r['ratio']:9.2f} {r['cpu_s']:7.2f}  {r['note']}" for r in rows]
    return "\n".join(lines)


def format_pairs(before, after, busy: bool) -> str:
    """The rows of two runs side by side: before -> after (wall s, x kernel, CPU s), the note after."""
    head = (f"{'what':<24} {'wall s':>15} {'x kernel':>15} {'cpu s':>13}  "
            f"(before -> after, {'beside one busy process' if busy else 'idle'})")
    old = {r["row"]: r for r in before}
    lines = [head, "-" * len(head)]
    for r in after:
        b = old.get(r["row"])
        pair = (lambda k, f: f"{format(b[k], f):>6} -> {format(r[k], f):<6}") if b else \
            (lambda k, f: f"{'':>6}    {format(r[k], f):<6}")
        lines.append(f"{r['row']:<24} {pair('wall_s', '.3f')} {pair('ratio', '.2f')} {pair('cpu_s', '.2f')}  {r['note']}")
    return "\n".join(lines)


def measure_before(checkout, names, repeat: int, busy: bool) -> list:
    """The rows measured on ``checkout`` (this file in a child process importing that checkout)."""
    env = dict(os.environ, PYTHONPATH=str(Path(checkout).resolve()))
    cmd = [sys.executable, str(Path(__file__).resolve()), "--json", "--repeat", str(repeat), "--only", *names]
    done = subprocess.run(cmd + (["--busy"] if busy else []), env=env, capture_output=True, text=True)
    if done.returncode:
        raise SystemExit(f"speed.py --before {checkout}: the run on it failed: {done.stderr[-2000:]}")
    return json.loads(done.stdout)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=3, help="runs per row, best kept (default 3)")
    ap.add_argument("--busy", action="store_true", help="beside one CPU-burning process")
    ap.add_argument("--only", nargs="+", choices=list(ROWS), help="these rows only (and the kernel)")
    ap.add_argument("--json", action="store_true", help="print the rows as JSON")
    ap.add_argument("--before", metavar="CHECKOUT", type=Path,
                    help="measure the rows on this checkout first and print before -> after")
    a = ap.parse_args(argv)
    if a.repeat < 1:
        ap.error("--repeat must be >= 1")
    if a.before is not None and not (a.before / "orchestrator").is_dir():
        ap.error(f"--before {a.before}: not a checkout of the project (no orchestrator/ folder in it)")
    names = a.only or list(ROWS)
    before = measure_before(a.before, names, a.repeat, a.busy) if a.before is not None else None
    rows = measure(names, a.repeat, a.busy)
    if a.json:
        print(json.dumps(rows if before is None else {"before": before, "after": rows}, indent=1))
    else:
        print(format_rows(rows, a.busy) if before is None else format_pairs(before, rows, a.busy))


if __name__ == "__main__":
    main()

"""Benchmark: how each stage of a run grows with the raft, on the mat of the scene "mat"
(100 m x 100 m on the reactor's rock) meshed at 6.25, 4, 2.94 and 2 m: 256, 625, 1156 and 2500
interface nodes (n = 6 + N DOFs of the gap model). Per size, each stage in a child process of
its own (its time, and its peak memory as ru_maxrss over what the process held before it).
Times are the process's CPU seconds (one BLAS thread: CPU time is the work, and it stays
meaningful on a machine shared with other jobs, where the wall time is not):

  sweep        one frequency (5 Hz) of the BEM sweep, rigid + gap outputs: CPU s, peak; the
               scene's F frequencies take F times as long (extrapolated, said so)
  table        bytes of the gap table at the scene's F frequencies, 16 F n^2 (computed)
  fit          the rational fit of the gap table swept at --fit-freqs frequencies (0 to 25 Hz):
               seconds, peak (sizes up to --fit-max-nodes only: the dense fit grows fast)
  history      one step of the soil's history product at --poles poles (the recursive
               convolution's history() + commit(): the GEMV over H (n, m n) and the state update)
  setup        the run's set-up on that soil: the time stepper (static preload, the base
               system, its factorisation) and the native runtime's records opened
  step         one step of the whole native run (the C runtime: history, Newton step, outputs),
               over --steps steps after the set-up, the closed Newton base included (built at
               the first Newton solve: a one-off of the step size, and of each halving level,
               spread over the --steps steps); "open s" the run at rest alone (the native records
               encoded and opened, the step size's system), which the step column leaves out

The soil of the history, set-up and step columns is a synthetic rational model of --poles poles
(real and complex pairs, residues a fixed SPD matrix times stable weights): the same sizes and
operations as a fit's, without the fit (which the dense code cannot make at 2500 nodes here); in
the step column it holds the cached forms a fitted model comes with (its real coefficients, from
the fit, and their scaled view, from the passivity test), as the run's model does.
Each stage's peak is printed beside the memory guard's estimate of it (orchestrator.memory_guard:
``mesh_sweep_memory``, ``fit_memory``, ``stepping_memory``, the interpreter's allowance
excluded), and the growth exponent of each column is fitted over the sizes (least squares of
log value on log N).

Variants by name, so that other methods are measured by the same script: ``--sweep``,
``--fit``, ``--history`` choose among SWEEPS ("dense", "fast": the FFT/Krylov solver of grid
meshes), FITS ("dense": the table in memory, "streamed": the table written to a chunked file by
one process and fitted read in blocks by another, whose peak is the fit's own) and HISTORIES
("dense"; "hmatrix": the step stage's soil a model whose residues have the soil kernel's structure
over the mat's nodes, tests/helpers ``with_kernel_terms`` on the rock's springs, its history
compressed from 600 nodes on as a run compresses it, and a pulse of --step-pga m/s^2 that lifts
a part of the mat); a new method adds a function to its table. The fit's "(est. @m)" column is the guard's
estimate at the order the fit reached (its "(est.)" one at the most poles it may use).

    OPENBLAS_NUM_THREADS=1 python benchmarks/growth.py [--sizes 16 25 34 50] [--stages sweep fit history setup step]
    # at 2500 nodes (50) the sweep and the stepper need ~3-4 GB: under the machine's big-run lock
    flock /tmp/big.lock python benchmarks/growth.py --sizes 50 --stages sweep history setup step
"""
from __future__ import annotations

import os

os.environ["OPENBLAS_NUM_THREADS"] = "1"
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SIDE = 100.0
FREQ = 5.0


def _maxrss() -> int:
    """Peak resident memory of this process so far, bytes (ru_maxrss is KiB on Linux)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def scene_at(cells: int):
    """The mat scene at cells x cells grid nodes (element size 100 m / cells)."""
    from dataclasses import replace
    from orchestrator.scene import load_scene
    from soil_impedance.mesh import rectangle_mesh
    scene = load_scene("mat")
    return replace(scene, mesh=rectangle_mesh(SIDE, SIDE, SIDE / cells))


# ---- variants ---------------------------------------------------------------------------------

def sweep_dense(scene, freqs):
    """The project's sweep (dense BEM, LU per frequency): {output: ImpedanceTable}."""
    from soil_impedance.sweep import impedance_sweep
    return impedance_sweep(scene.profile, scene.mesh, freqs, contact=scene.contact_kind, outputs=("rigid", "gap"))


def sweep_fast(scene, freqs):
    """The fast BEM solver of grid meshes (``[impedance] solver = "fast"``, soil_impedance.fastsolve:
    FFT products and a Krylov solve to the scene's solver_tol): {output: ImpedanceTable}."""
    from soil_impedance.sweep import impedance_sweep
    return impedance_sweep(scene.profile, scene.mesh, freqs, contact=scene.contact_kind, outputs=("rigid", "gap"),
                           solver="fast", solver_tol=scene.solver_tol)


def fit_dense(scene, table):
    """The project's fit (``fit_table`` at the scene's tolerance, on the mat's node coordinates)."""
    from soil_impedance.fit import fit_table
    return fit_table(table, tol=scene.analysis.fit_tol, node_xy=scene.mesh.xy)


def history_dense(model, dt):
    """The soil stepped by the project's recursive convolution (Python: GEMV over H)."""
    from soil_impedance.convolution import RecursiveConvolutionSoil
    return RecursiveConvolutionSoil(model, dt, checked=True)


def history_hmatrix(model, dt, xy=None):
    """The soil's history compressed over the nodes xy (``history="auto"``: from 600 nodes on)."""
    from soil_impedance.convolution import RecursiveConvolutionSoil
    return RecursiveConvolutionSoil(model, dt, checked=True, history="auto", xy=xy)


def fit_streamed(scene, table):
    """The streamed fit (soil_impedance.fit.streamed) of a ``BlockedTable`` on disk (``stage_fit``
    writes the swept table to a chunked file and opens it in a fresh process first)."""
    return fit_dense(scene, table)


SWEEPS = {"dense": sweep_dense, "fast": sweep_fast}
FITS = {"dense": fit_dense, "streamed": fit_streamed}
HISTORIES = {"dense": history_dense, "hmatrix": history_hmatrix}


# ---- the synthetic soil ---------------------------------------------------------------------

def synthetic_model(n: int, poles: int, k: float = 2e10):
    """A stable rational model of n DOFs: ``poles`` poles (a third real, the rest conjugate
    pairs), residues w_j S with S = k (I + 0.1 C) SPD (C a fixed smooth kernel), D = 2 K(0)-ish
    so that K(0) is SPD; E = 1e-3 S."""
    from soil_impedance.rational import RationalModel
    x = np.linspace(-1.0, 1.0, n)
    S = k * (np.eye(n) + 0.1 * np.exp(-np.abs(x[:, None] - x[None, :]) * 5.0))
    n_real = max(1, poles // 3)
    n_pair = (poles - n_real) // 2
    p = [-(20.0 + 30.0 * j) for j in range(n_real)]
    w = [0.2 * (-pj) for pj in p]
    for j in range(n_pair):
        a = complex(-10.0 - 5.0 * j, 20.0 + 25.0 * j)
        p += [a, a.conjugate()]
        c = complex(0.05 * (-a.real), 0.01 * a.imag)
        w += [c, c.conjugate()]
    p = np.array(p, complex)
    w = np.array(w, complex)
    residues = w[:, None, None] * S[None]
    static_part = float(np.real(np.sum(w / p)))              # K(0) = D - sum R / p = (2 - static_part... ) S
    D = (1.0 + abs(static_part)) * S
    return RationalModel(p, residues, D, 1e-3 * S)


# ---- stages, each in a child ------------------------------------------------------------------

def stage_sweep(cells, args):
    from soil_impedance.sweep import mesh_sweep_memory
    scene = scene_at(cells)
    base = _maxrss()
    t0 = time.process_time()
    SWEEPS[args.sweep](scene, [FREQ])
    cpu = time.process_time() - t0
    est = mesh_sweep_memory(scene.mesh, 1, ("rigid", "gap"), solver=args.sweep, solver_tol=scene.solver_tol)
    return {"n_nodes": scene.mesh.n, "sweep_s": cpu, "sweep_peak": _maxrss() - base,
            "sweep_est": est["total"] - est["base"]}


def _table_file(cells, args) -> Path:
    return Path(args.cache) / f"growth-gap-{cells}-{args.fit_freqs}-{args.sweep}.h5"


def stage_table(cells, args):
    """The gap table swept at --fit-freqs frequencies, written to a chunked file (blocked.TableWriter)
    for the streamed fit's own process."""
    from soil_impedance.blocked import TableWriter
    scene = scene_at(cells)
    freqs = np.linspace(0.0, 25.0, args.fit_freqs)
    table = SWEEPS[args.sweep](scene, freqs)["gap"]
    Path(args.cache).mkdir(parents=True, exist_ok=True)
    with TableWriter(_table_file(cells, args), table.frequencies_hz, table.dofs, table.provenance) as w:
        for k in range(freqs.size):
            w[k] = table.matrices[k]
    return {"n_nodes": scene.mesh.n}


def stage_fit(cells, args):
    from soil_impedance.fit.peak_memory import fit_memory, streamed_fit_memory
    from orchestrator.memory_guard import max_poles
    scene = scene_at(cells)
    freqs = np.linspace(0.0, 25.0, args.fit_freqs)
    if args.fit == "streamed":               # the table on disk, read in blocks; swept in another process
        from soil_impedance.blocked import BlockedTable
        if not _table_file(cells, args).exists():
            child("table", cells, args)
        table = BlockedTable.open(_table_file(cells, args))
    else:
        table = SWEEPS[args.sweep](scene, freqs)["gap"]
    base = _maxrss()
    t0 = time.process_time()
    result = FITS[args.fit](scene, table)
    cpu = time.process_time() - t0
    nb = table.n_dof
    estimate = streamed_fit_memory if args.fit == "streamed" else fit_memory
    est = estimate(nb, freqs.size, max_poles(scene, freqs.size))
    at = estimate(nb, freqs.size, int(result.model.order))
    return {"n_nodes": scene.mesh.n, "fit_s": cpu, "fit_peak": _maxrss() - base, "fit_est": est["total"],
            "fit_est_at_order": at["total"], "fit_poles": int(result.model.order), "fit_freqs": int(freqs.size)}


def step_soil(scene, args):
    """The soil of the history, set-up and step columns: the synthetic model, or (--history hmatrix)
    the rock's springs with the kernel-structured terms, compressed over the mat's nodes."""
    if args.history != "hmatrix":
        model = synthetic_model(6 + scene.mesh.n, args.poles)
        _ = (model.coefficients, model.scaled)       # the cached forms a fitted model holds (the fit's, its test's)
        return HISTORIES[args.history](model, 0.005)
    sys.path.insert(0, str(ROOT / "tests"))
    from helpers import with_kernel_terms
    from helpers.soil_double import winkler_rational
    from helpers.winkler import rock_winkler
    xy = np.asarray(scene.mesh.xy)
    model = with_kernel_terms(winkler_rational(rock_winkler(xy, scene.mesh.area, match="rocking", ky=True)), xy)
    return history_hmatrix(model, 0.005, xy)


def stage_history(cells, args):
    n = 6 + cells * cells
    soil = step_soil(scene_at(cells), args)
    rng = np.random.default_rng(0)
    x = rng.standard_normal((8, n)) * 1e-4
    soil.history()
    soil.commit(x[0], x[1])                          # warm
    reps = max(5, min(200, int(2e8 / (args.poles * n * n))))
    t0 = time.process_time()
    for k in range(reps):
        soil.history()
        soil.commit(x[k % 8], x[(k + 1) % 8])
    return {"n_nodes": cells * cells, "history_ms": 1e3 * (time.process_time() - t0) / reps}


def stage_step(cells, args):
    """Set-up and steps of the native run on the synthetic soil; the stepping stage's peak."""
    from fmus.native_stepper import library, simulate_native
    from orchestrator.memory_guard import stepping_memory
    from structure import NewmarkStepper
    scene = scene_at(cells)
    structure = scene.model()
    n = 6 + scene.mesh.n
    lib = library(Path(args.cache) / "native")
    t = np.arange(args.steps + 1) * 0.005
    ag = np.zeros((t.size, 3))
    contact = scene.contact
    if args.history == "hmatrix":                  # the kernel-structured soil, compressed; a pulse lifting the mat
        from dataclasses import replace
        sys.path.insert(0, str(ROOT / "tests"))
        from helpers import pulse_motion
        ag[:] = pulse_motion(dt=0.005, T=args.steps * 0.005, pga=args.step_pga).acc[:t.size]
        contact = replace(contact, precheck=False)
    else:
        ag[:, 0] = 0.5 * np.sin(2 * np.pi * 3.0 * t)
    base = _maxrss()
    t0 = time.process_time()
    soil = step_soil(scene, args)
    st = NewmarkStepper(structure, soil, 0.005, contact=contact, external_soil=True, ag0=ag[0])
    setup = time.process_time() - t0
    t1 = time.process_time()
    simulate_native(st, ag[:1], scene.output.nodes, lib=lib)                 # records encoded and opened, 1 step
    first = time.process_time() - t1
    t1 = time.process_time()
    simulate_native(st, ag[:1], scene.output.nodes, lib=lib)                 # again, the library warm
    first = min(first, time.process_time() - t1)
    t2 = time.process_time()
    res = simulate_native(st, ag, scene.output.nodes, lib=lib)
    run = time.process_time() - t2
    est = stepping_memory(n, args.poles, t.size, fitted=False)            # a synthetic model: no fit's forms
    return {"n_nodes": scene.mesh.n, "setup_s": setup + first, "first_s": first,
            "step_ms": 1e3 * (run - first) / args.steps,
            "step_peak": _maxrss() - base, "step_est": est["total"] - est["base"],
            "max_gap_m": float(np.max(res.gap)) if res.gap.size else 0.0,
            "lifted": float((res.gap > 0).mean(axis=1).max()) if res.gap.size else 0.0}


STAGES = {"sweep": stage_sweep, "fit": stage_fit, "history": stage_history, "step": stage_step}
CHILD_STAGES = dict(STAGES, table=stage_table)


def child(stage, cells, args) -> dict:
    """Run one stage at one size in a fresh interpreter (its own peak); its JSON answer."""
    cmd = [sys.executable, __file__, "--child", stage, str(cells), "--sweep", args.sweep, "--fit", args.fit,
           "--history", args.history, "--poles", str(args.poles), "--fit-freqs", str(args.fit_freqs),
           "--steps", str(args.steps), "--step-pga", str(args.step_pga), "--cache", args.cache]
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if out.returncode:
        return {"error": out.stderr.strip().splitlines()[-1] if out.stderr.strip() else f"exit {out.returncode}"}
    return json.loads(out.stdout.strip().splitlines()[-1])


def exponent(n, v):
    """Least-squares slope of log v on log n over the finite positive values (None if < 2)."""
    pts = [(a, b) for a, b in zip(n, v) if b is not None and b > 0]
    if len(pts) < 2:
        return None
    x, y = np.log([p[0] for p in pts]), np.log([p[1] for p in pts])
    return float(np.polyfit(x, y, 1)[0])


COLUMNS = [("sweep_s", "sweep s/freq", "{:.3g}"), ("sweep_peak", "sweep peak GiB", "{:.3g}"),
           ("sweep_est", "(est.)", "{:.3g}"), ("table", "table GiB @F", "{:.3g}"), ("fit_s", "fit s", "{:.3g}"),
           ("fit_peak", "fit peak GiB", "{:.3g}"), ("fit_est", "(est.)", "{:.3g}"),
           ("fit_est_at_order", "(est. @m)", "{:.3g}"),
           ("history_ms", "history ms", "{:.3g}"), ("setup_s", "setup s", "{:.3g}"),
           ("first_s", "open s", "{:.3g}"), ("step_ms", "step ms", "{:.3g}"), ("lifted", "lifted", "{:.2f}"),
           ("step_peak", "step peak GiB", "{:.3g}"), ("step_est", "(est.)", "{:.3g}")]
GIB = {"sweep_peak", "sweep_est", "table", "fit_peak", "fit_est", "fit_est_at_order", "step_peak", "step_est"}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[16, 25, 34, 50], help="cells per side (N = cells^2)")
    p.add_argument("--stages", nargs="+", default=list(STAGES), choices=list(STAGES))
    p.add_argument("--sweep", default="dense", choices=list(SWEEPS))
    p.add_argument("--fit", default="dense", choices=list(FITS))
    p.add_argument("--history", default="dense", choices=list(HISTORIES))
    p.add_argument("--poles", type=int, default=8, help="poles of the synthetic soil (history, setup, step)")
    p.add_argument("--fit-freqs", type=int, default=11, help="frequencies of the fitted table (0 to 25 Hz)")
    p.add_argument("--fit-max-nodes", type=int, default=700, help="largest size whose fit is measured")
    p.add_argument("--steps", type=int, default=200, help="steps of the native run (step column)")
    p.add_argument("--step-pga", type=float, default=20.0,
                   help="the pulse of the step stage with --history hmatrix, m/s^2 (x, and 0.3 of it along z)")
    p.add_argument("--freqs", type=int, default=101, help="the scene's frequency count (table column, extrapolation)")
    p.add_argument("--cache", default=os.environ.get("UPLIFT_CACHE", "/tmp/uplift-growth"),
                   help="folder of the native library")
    p.add_argument("--json", type=Path, default=None, help="also write the rows as JSON")
    p.add_argument("--child", nargs=2, metavar=("STAGE", "CELLS"), help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.child:
        print(json.dumps(CHILD_STAGES[args.child[0]](int(args.child[1]), args)))
        return 0
    rows = []
    for cells in args.sizes:
        n = cells * cells
        row = {"n_nodes": n, "table": 16 * args.freqs * (6 + n) ** 2 / 2 ** 30}
        for stage in args.stages:
            if stage == "fit" and n > args.fit_max_nodes:
                continue
            got = child(stage, cells, args)
            if "error" in got:
                print(f"{n} nodes, {stage}: {got['error']}", file=sys.stderr)
                continue
            row.update({k: (v / 2 ** 30 if k in GIB else v) for k, v in got.items() if k != "n_nodes"})
            print(f"{n} nodes, {stage}: {json.dumps(got)}", file=sys.stderr, flush=True)
        rows.append(row)
    cols = [c for c in COLUMNS if any(c[0] in r for r in rows)]
    head = f"{'N':>5s} " + " ".join(f"{c[1]:>14s}" for c in cols)
    print(f"growth on the mat's soil (sweep {args.sweep}, fit {args.fit}, history {args.history}; "
          f"{args.poles} poles; fit at {args.fit_freqs} frequencies; table at {args.freqs})")
    print(head)
    for r in rows:
        print(f"{r['n_nodes']:5d} " + " ".join(f"{c[2].format(r[c[0]]) if c[0] in r else '-':>14s}" for c in cols))
    ns = [r["n_nodes"] for r in rows]
    print(f"{'exp.':>5s} " + " ".join(
        f"{'-' if (e := exponent(ns, [r.get(c[0]) for r in rows])) is None else f'N^{e:.2f}':>14s}" for c in cols))
    for stage in ("sweep", "fit", "step"):
        pairs = [(r["n_nodes"], r[f"{stage}_est"] / r[f"{stage}_peak"]) for r in rows
                 if r.get(f"{stage}_peak", 0) > 0 and f"{stage}_est" in r]
        if pairs:
            print(f"{stage}: the guard's estimate over the measured peak: "
                  + ", ".join(f"{ratio:.2f} at {n} nodes" for n, ratio in pairs))
    if "sweep_s" in rows[-1]:
        big = rows[-1]
        print(f"extrapolated: the sweep of {big['n_nodes']} nodes at {args.freqs} frequencies ~ "
              f"{big['sweep_s'] * args.freqs / 60:.0f} min (one frequency measured x {args.freqs})")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())

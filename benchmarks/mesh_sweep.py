"""Dynamic impedance sweep on irregular (unstructured triangle) raft meshes: time and peak memory.

The reactor scene's layered causal profile (orchestrator/scenes/reactor.toml: 8 m of Vs = 1350 m/s
over Vs = 1600 m/s rock) under its raft of radius 20 m, meshed by gmsh into about 250, 500, 1000
and 2000 triangles (``tests/data/meshes/make_disks.disk_mesh``); 20 frequencies over
[0, 25] Hz; outputs rigid (6×6) and gap (6+N), as ``uplift fit`` asks. Goal: 2000 cells in at
most 8 GB peak.

    python benchmarks/mesh_sweep.py [--sizes 250 500 1000] [--frequencies 20] [--tractions constant]

Each size runs in a child process: its peak resident memory (``resource.getrusage`` maxrss of
the child) counts what BLAS/LAPACK allocate, which tracemalloc does not see. One BLAS thread.
Prints per size: cells, DOFs, the estimate of ``sweep.sweep_memory``, the measured peak, the
wall time of the sweep and per frequency; "setup" is the time before the first frequency (the
static integrals per pair of cells, the outline cells' strips), "step" the median time of one
frequency (assembly, LU, solves).

Measured (2 cores shared with five other jobs, load ~8: wall times are several times the CPU
times; estimate of the current ``sweep_memory``)::

    target  cells   DOFs  h (m)  est GB  peak GB   wall s  s/freq
       250    271    813   3.49    0.38     0.22     20.2    1.01
       500    509   1527   2.47    0.55     0.36     64.4    3.22
      1000   1013   3039   1.74    1.25     0.93    431.3   21.56
      2000   1966   5898   1.23    3.84     3.01   1090.8   54.54
      (2000 at 2 frequencies, the machine busier: est 1.91 GB, peak 1.89 GB, 209 s/frequency)

With the outline cells' edge-singular tractions (the default since; ``--tractions constant`` the
scheme above), 20 frequencies, the machine loaded (load 6-10, so wall times vary by 2x)::

    target  cells   DOFs  h (m)  est GB  peak GB   wall s  s/freq setup s  step s
       250    271    813   3.49    0.38     0.21     15.9    0.79    1.39    0.64
       500    509   1527   2.47    0.55     0.35     39.6    1.98    4.24    1.93
      1000   1013   3039   1.74    1.25     0.93    292.4   14.62   12.39   14.33
    constant tractions, run right after under the same load:
      1000   1013   3039   1.74    1.25     0.93    257.9   12.90    8.42   13.56
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")   # before numpy is imported

import argparse
import json
import math
import resource
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RADIUS = 20.0
#: cells per (R/h)² of gmsh's Frontal-Delaunay triangles on a disk (761 cells at R/h = 10)
CELLS_PER_DIVISION2 = 7.6


def child(cells: int, n_freq: int, tractions: str = "sqrt") -> dict:
    import numpy as np
    sys.path.insert(0, str(ROOT / "tests" / "data" / "meshes"))
    from make_disks import disk_mesh
    from orchestrator.scene import load_scene
    from soil_impedance import bem, cells_mesh, impedance_sweep
    from soil_impedance.sweep import sweep_memory

    bem.EDGE_TRACTIONS = tractions

    scene = load_scene("reactor")
    h = RADIUS * math.sqrt(CELLS_PER_DIVISION2 / cells)
    pts, tri = disk_mesh(RADIUS, h)
    mesh = cells_mesh(pts, triangles=tri)
    f = np.linspace(0.0, 25.0, n_freq)
    est = sweep_memory(mesh.n, f.size, ("rigid", "gap"))["total"]
    per = []
    t0 = time.perf_counter()

    def progress(done, total, label):
        per.append(time.perf_counter())

    tables = impedance_sweep(scene.profile, mesh, f, contact=scene.contact_kind, outputs=("rigid", "gap"),
                             progress=progress)
    wall = time.perf_counter() - t0
    assert len(per) == f.size and np.all(np.isfinite(tables["gap"].matrices))
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    step = float(np.median(np.diff([t0] + per)))          # one frequency, setup excluded
    return {"cells": mesh.n, "dofs": 3 * mesh.n, "estimate": est, "peak": peak, "wall": wall,
            "per_freq": wall / f.size, "h": h, "step": step, "setup": per[0] - t0 - step}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[250, 500, 1000, 2000])
    ap.add_argument("--frequencies", type=int, default=20)
    ap.add_argument("--tractions", choices=["sqrt", "constant"], default="sqrt",
                    help="the outline cells' traction scheme (bem.EDGE_TRACTIONS; constant: the scheme before)")
    ap.add_argument("--child", type=int, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        print(json.dumps(child(args.child, args.frequencies, args.tractions)))
        return 0
    print(f"{'target':>6s} {'cells':>6s} {'DOFs':>6s} {'h (m)':>6s} {'est GB':>7s} {'peak GB':>8s} "
          f"{'wall s':>8s} {'s/freq':>7s} {'setup s':>7s} {'step s':>7s}", flush=True)
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    for n in args.sizes:
        out = subprocess.run([sys.executable, __file__, "--child", str(n), "--frequencies", str(args.frequencies),
                              "--tractions", args.tractions],
                             capture_output=True, text=True, env=env)
        if out.returncode != 0:
            print(f"{n:6d} failed: {out.stderr.strip().splitlines()[-1:]}", flush=True)
            continue
        r = json.loads(out.stdout.strip().splitlines()[-1])
        print(f"{n:6d} {r['cells']:6d} {r['dofs']:6d} {r['h']:6.2f} {r['estimate'] / 1e9:7.2f} {r['peak'] / 1e9:8.2f} "
              f"{r['wall']:8.1f} {r['per_freq']:7.2f} {r['setup']:7.2f} {r['step']:7.2f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Benchmark: the static K(0) of the mat (the run's time-step check and the pushover use it) by the
dense LU and by the fast solver of grid meshes, at cells x cells nodes (element size 100 m / cells),
each solve in a fresh process (its CPU seconds, one BLAS thread, and its peak resident memory over
what the process held before), and the fast K(0)'s largest entry difference from the dense one
relative to the largest entry (the rigid 6 x 6 and, with --gap, the (6 + N)^2 gap table).

    OPENBLAS_NUM_THREADS=1 python benchmarks/static_k0.py --sizes 34
    # 2500 nodes: the dense LU of (3N)^2 complex holds ~2 GiB: under the machine's big-run lock
    nice flock /tmp/big.lock python benchmarks/static_k0.py --sizes 50
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
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def child(cells: int, solver: str, output: str, out: str) -> None:
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from growth import scene_at
    from orchestrator.impedance import scene_static
    from dataclasses import replace
    scene = replace(scene_at(cells), solver=solver)
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    t0 = time.process_time()
    K = scene_static(scene, output)                       # no cache: computed
    cpu = time.process_time() - t0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 - base
    np.save(out + ".npy", K)
    Path(out).write_text(json.dumps({"n": scene.mesh.n, "cpu_s": cpu, "peak": peak}))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[34])
    ap.add_argument("--solvers", nargs="+", default=["dense", "fast"])
    ap.add_argument("--gap", action="store_true", help="the gap table's K(0) instead of the rigid 6 x 6")
    ap.add_argument("--child", nargs=4, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.child:
        child(int(a.child[0]), a.child[1], a.child[2], a.child[3])
        return
    output = "gap" if a.gap else "rigid"
    tmp = tempfile.mkdtemp()
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    print(f"{'nodes':>6} {'solver':>6} {'cpu s':>8} {'peak GiB':>9} {'diff':>9}   ({output} K(0))")
    for cells in a.sizes:
        got = {}
        for solver in a.solvers:
            out = os.path.join(tmp, f"{cells}-{solver}.json")
            subprocess.run([sys.executable, __file__, "--child", str(cells), solver, output, out], check=True, env=env)
            got[solver] = json.loads(Path(out).read_text()), np.load(out + ".npy")
        ref = got.get("dense", (None, None))[1]
        for solver, (r, K) in got.items():
            diff = "" if ref is None or solver == "dense" else f"{np.abs(K - ref).max() / np.abs(ref).max():9.1e}"
            print(f"{r['n']:6d} {solver:>6} {r['cpu_s']:8.1f} {r['peak'] / 2 ** 30:9.2f} {diff:>9}", flush=True)


if __name__ == "__main__":
    main()

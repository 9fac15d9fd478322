"""Impedance sweep of the reactor raft on a two-layer rock profile: time, memory, cache.

Reactor raft: circle_mesh(20, 2.28), 241 nodes (723 DOFs); 10 m of Vs = 1200 m/s over a
Vs = 1800 m/s half-space (ν = 0.3, ξ = 0.03); 100 frequencies in (0, 25] Hz; outputs rigid 6×6
and rigid + gap (247×247). Budgets (docs/verification.md): < 60 s, < 4 GB, cached sweep < 1 s.

    python benchmarks/impedance_sweep.py [--quick]
    python benchmarks/impedance_sweep.py --solvers [--nodes 250 600 1200 2500] [--freqs 2 12.5 25]

``--solvers``: the dense and the fast solver (soil_impedance.fastsolve) of one sweep frequency
(rigid + gap outputs, Green's tables and assembly included) on the reactor's soil, for the
100 m x 100 m mat at about ``--nodes`` nodes (square grid, 2 m at 2500) and the reactor's disk
(R = 20 m) at the same counts: wall and CPU seconds per frequency, peak memory (VmHWM of a
child process per run), the fast tables' error against dense (largest difference relative to
the table's largest entry, at each frequency; the worst one printed) and the growth exponents
of a least-squares fit of log time on log N over the sizes >= 600. Runs of more than 1200
nodes wait for ``--lock`` (flock; the machine-wide lock of big runs), dense ones use the first
frequency only (``--dense-big-freqs``).

BLAS threads: one per process unless OPENBLAS_NUM_THREADS is set. The per-frequency matrices
(723×723) are too small for threaded LU to pay; on a loaded 2-core machine two OpenBLAS
threads made the sweep 5× slower (0.35 s vs 0.06 s per frequency, measured).
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")   # before numpy is imported

import argparse
import resource
import sys
import tempfile
import time
import tracemalloc

import numpy as np

import soil_impedance.bem as bem_module
from soil_impedance import Layer, Material, SoilProfile, SurfaceBem, circle_mesh, impedance_sweep

GREEN_TIME = [0.0]
_regular_green = bem_module._regular_green


def _timed_regular_green(*args):
    t0 = time.perf_counter()
    try:
        return _regular_green(*args)
    finally:
        GREEN_TIME[0] += time.perf_counter() - t0


bem_module._regular_green = _timed_regular_green   # split the time: Green's functions vs BEM


def profile() -> SoilProfile:
    top = Layer(vs=1200.0, rho=2400.0, nu=0.3, damping=0.03, thickness=10.0, name="soil.layers[0]")
    return SoilProfile((top,), Material(vs=1800.0, rho=2500.0, nu=0.3, damping=0.03, name="soil.halfspace"))


def timed_sweep(prof, mesh, freqs, cache_dir=None):
    per = []
    last = [time.perf_counter()]

    def progress(done, total, f):
        now = time.perf_counter()
        per.append(now - last[0])
        last[0] = now
    GREEN_TIME[0] = 0.0
    t0 = time.perf_counter()
    out = impedance_sweep(prof, mesh, freqs, outputs=("rigid", "gap"), cache_dir=cache_dir, progress=progress)
    return out, time.perf_counter() - t0, np.array(per)


CHILD = """
import json, os, sys, time
os.environ["OPENBLAS_NUM_THREADS"] = "1"
sys.path.insert(0, {root!r})
import numpy as np
from benchmarks.impedance_sweep import profile, solver_mesh
from soil_impedance import impedance_sweep
shape, nodes, solver, tol, out = {shape!r}, {nodes}, {solver!r}, {tol}, {out!r}
freqs = {freqs!r}
mesh = solver_mesh(shape, nodes)
prof = profile()
impedance_sweep(prof, mesh, [freqs[0]], outputs=("rigid",), solver="dense" if mesh.n < 200 else solver)  # warm: imports, tables
per, cpu = [], []
mats = {{"rigid": [], "gap": []}}
for f in freqs:
    t0, c0 = time.perf_counter(), time.process_time()
    t = impedance_sweep(prof, mesh, [f], outputs=("rigid", "gap"), solver=solver, solver_tol=tol)
    per.append(time.perf_counter() - t0)
    cpu.append(time.process_time() - c0)
    for k in mats:
        mats[k].append(t[k].matrices[0])
np.savez(out, rigid=np.array(mats["rigid"]), gap=np.array(mats["gap"]))
with open("/proc/self/status") as fh:
    peak = next(int(line.split()[1]) * 1024 for line in fh if line.startswith("VmHWM:"))
print(json.dumps(dict(n=mesh.n, wall=per, cpu=cpu, peak=peak)))
"""


def solver_mesh(shape: str, nodes: int):
    """The mat (square, 100 m) or the reactor's disk (R = 20 m) at about ``nodes`` grid nodes."""
    from soil_impedance.mesh import rectangle_mesh
    if shape == "square":
        side = max(2, int(round(np.sqrt(nodes))))
        return rectangle_mesh(100.0, 100.0, 100.0 / side)
    h = float(np.sqrt(np.pi * 20.0 ** 2 / nodes))
    for _ in range(8):                                   # adjust h until the disk has about ``nodes``
        mesh = circle_mesh(20.0, h)
        if abs(mesh.n - nodes) <= 0.05 * nodes:
            break
        h *= np.sqrt(mesh.n / nodes)
    return mesh


def _child(shape, nodes, solver, tol, freqs, out, lock=None):
    import json
    import shutil
    import subprocess
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    code = CHILD.format(root=root, shape=shape, nodes=nodes, solver=solver, tol=tol, freqs=list(freqs), out=out)
    cmd = [sys.executable, "-c", code]
    if lock and shutil.which("flock"):
        cmd = ["flock", lock] + cmd
    proc = subprocess.run(cmd, capture_output=True, text=True, check=True)
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _exponent(n, t):
    n, t = np.asarray(n, float), np.asarray(t, float)
    keep = n >= 550
    if keep.sum() < 2:
        return float("nan")
    return float(np.polyfit(np.log(n[keep]), np.log(t[keep]), 1)[0])


def solvers_table(nodes, freqs, tol, shapes, lock, dense_big_freqs, dense_max):
    """Print the dense / fast table (module docstring, ``--solvers``)."""
    from soil_impedance.fastsolve import AUTO_NODES
    print(f"one sweep frequency (rigid + gap), reactor soil, OPENBLAS_NUM_THREADS=1, fast tol = {tol:g} "
          f"(auto: fast from {AUTO_NODES} nodes); times are means over the frequencies {list(freqs)} Hz")
    print(f"{'shape':>7} {'nodes':>6} {'solver':>6} {'wall s':>8} {'cpu s':>8} {'peak MB':>8} "
          f"{'err rigid':>10} {'err gap':>10}")
    with tempfile.TemporaryDirectory() as tmp:
        for shape in shapes:
            rows = {"dense": [], "fast": []}
            for nn in nodes:
                dense = os.path.join(tmp, f"{shape}-{nn}-dense.npz")
                fast = os.path.join(tmp, f"{shape}-{nn}-fast.npz")
                big = nn > 1200
                fd = freqs[:dense_big_freqs] if big else freqs
                res = {}
                if nn <= dense_max:
                    res["dense"] = _child(shape, nn, "dense", tol, fd, dense, lock if big else None)
                res["fast"] = _child(shape, nn, "fast", tol, freqs, fast, lock if big else None)
                for solver, r in res.items():
                    err = ("", "")
                    if solver == "fast" and "dense" in res:
                        a, b = np.load(fast), np.load(dense)
                        k = len(fd)
                        err = tuple(f"{_errors(a[o][:k], b[o]):10.2e}" for o in ("rigid", "gap"))
                    wall, cpu = float(np.mean(r["wall"])), float(np.mean(r["cpu"]))
                    rows[solver].append((r["n"], wall, cpu))
                    print(f"{shape:>7} {r['n']:6d} {solver:>6} {wall:8.2f} {cpu:8.2f} {r['peak'] / 2 ** 20:8.0f} "
                          f"{err[0]:>10} {err[1]:>10}", flush=True)
            for solver, rr in rows.items():
                if rr:
                    n, wall, cpu = np.array(rr).T
                    print(f"{shape:>7} {solver:>6} growth exponent over N >= 600: wall {_exponent(n, wall):.2f}, "
                          f"cpu {_exponent(n, cpu):.2f}")


def _errors(a, b):
    """Worst over frequencies of max |a - b| / max |b| per frequency."""
    return float((np.abs(a - b).max(axis=(1, 2)) / np.abs(b).max(axis=(1, 2))).max())


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="20 frequencies instead of 100")
    ap.add_argument("--solvers", action="store_true", help="dense vs fast solver table (see the docstring)")
    ap.add_argument("--nodes", type=int, nargs="+", default=[250, 600, 1200, 2500])
    ap.add_argument("--freqs", type=float, nargs="+", default=[2.0, 12.5, 25.0])
    ap.add_argument("--tol", type=float, default=None, help="fast solver tolerance (default: its DEFAULT_TOL)")
    ap.add_argument("--shapes", nargs="+", default=["square", "circle"], choices=["square", "circle"])
    ap.add_argument("--lock", default="/tmp/big.lock", help="flock file of big runs ('' for none)")
    ap.add_argument("--dense-big-freqs", type=int, default=1)
    ap.add_argument("--dense-max", type=int, default=2500, help="largest node count solved dense")
    args = ap.parse_args(argv)
    if args.solvers:
        from soil_impedance.fastsolve import DEFAULT_TOL
        solvers_table(args.nodes, args.freqs, DEFAULT_TOL if args.tol is None else args.tol, args.shapes,
                      args.lock, args.dense_big_freqs, args.dense_max)
        return 0
    prof = profile()
    nf = 20 if args.quick else 100
    freqs = np.linspace(25.0 / nf, 25.0, nf)

    print("growth with node count (10 frequencies, rigid + gap outputs)")
    print(f"{'h (m)':>7} {'nodes':>6} {'radii':>6} {'s/freq':>8} {'greens':>8} {'BEM+LU':>8} {'peak MB':>8}")
    for h in (4.0, 3.0, 2.28, 1.8):
        mesh = circle_mesh(20.0, h)
        tracemalloc.start()
        _, total, per = timed_sweep(prof, mesh, freqs[:: max(1, nf // 10)][:10])
        peak = tracemalloc.get_traced_memory()[1] / 2 ** 20
        tracemalloc.stop()
        g = GREEN_TIME[0] / per.size
        print(f"{h:7.2f} {mesh.n:6d} {SurfaceBem(prof, mesh).n_radii:6d} {per.mean():8.3f} {g:8.3f} "
              f"{per.mean() - g:8.3f} {peak:8.1f}")

    mesh = circle_mesh(20.0, 2.28)
    with tempfile.TemporaryDirectory() as cache:
        tracemalloc.start()
        out, total, per = timed_sweep(prof, mesh, freqs, cache)
        peak = tracemalloc.get_traced_memory()[1] / 2 ** 20
        tracemalloc.stop()
        t0 = time.perf_counter()
        again = impedance_sweep(prof, mesh, freqs, outputs=("rigid", "gap"), cache_dir=cache)
        cached = time.perf_counter() - t0
        same = all(np.array_equal(out[k].matrices, again[k].matrices) for k in out)
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print()
    print(f"reactor raft: {mesh.n} nodes, {nf} frequencies up to 25 Hz, two-layer profile, "
          f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}")
    print(f"{'quantity':<34} {'value':>12} {'budget':>10}")
    print(f"{'total sweep (s)':<34} {total:12.2f} {'60':>10}")
    print(f"{'per frequency mean / max (s)':<34} {per.mean():6.3f}/{per.max():5.3f} {'':>10}")
    print(f"{'  of which regular_green (s/freq)':<34} {GREEN_TIME[0] / per.size:12.3f} {'':>10}")
    print(f"{'peak traced memory (MB)':<34} {peak:12.1f} {'4096':>10}")
    print(f"{'max RSS of the process (MB)':<34} {rss:12.1f} {'4096':>10}")
    print(f"{'cached sweep read-back (s)':<34} {cached:12.3f} {'1':>10}")
    print(f"{'cache identical':<34} {same!s:>12}")
    Kr = out["rigid"]
    for f in (freqs[0], 12.5, 25.0):
        K = Kr.at(f)
        print(f"  f = {f:5.2f} Hz  Kv = {K[2, 2]:.4g}  Kh = {K[0, 0]:.4g}  Kr = {K[3, 3]:.4g} (N/m, N·m/rad)")
    ok = total < 60 and cached < 1 and rss < 4096 and same
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())

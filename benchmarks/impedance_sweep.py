"""Impedance sweep of the reactor raft on a two-layer rock profile: time, memory, cache.

Reactor raft: circle_mesh(20, 2.28), 241 nodes (723 DOFs); 10 m of Vs = 1200 m/s over a
Vs = 1800 m/s half-space (ν = 0.3, ξ = 0.03); 100 frequencies in (0, 25] Hz; outputs rigid 6×6
and rigid + gap (247×247). Budgets (docs/verification.md): < 60 s, < 4 GB, cached sweep < 1 s.

    python benchmarks/impedance_sweep.py [--quick]

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


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="20 frequencies instead of 100")
    args = ap.parse_args(argv)
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

"""Per-step cost of the recursive-convolution soil (soil_impedance.convolution).

Reactor-size interface: n = 6 + 241 = 247 DOFs, 24 poles (12 conjugate pairs by default; a
random passive model, full-rank residues), dt = 5 ms. Prints a table of microseconds per
call: history() (one GEMV, m n^2 flops, the < 1 ms target), step() (= history + commit:
pole-state update, force, work), instantaneous() at a new dt (coefficients and D0 recomputed), construction
(with the passivity check), and the warping error |K_d − K(iω)|/|K| at 5 and 20 Hz.

    OPENBLAS_NUM_THREADS=1 python benchmarks/soil_step.py [--n 247] [--pairs 12] [--real 0]
"""
from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from helpers import random_passive_model

from soil_impedance.convolution import RecursiveConvolutionSoil, recursion_transfer


def per_call(fn, reps):
    fn()
    t = time.perf_counter()
    for _ in range(reps):
        fn()
    return (time.perf_counter() - t) / reps * 1e6


def bench(n, pairs, real, dt=0.005, reps=2000):
    model = random_passive_model(n, pairs, real, seed=0)
    t0 = time.perf_counter()
    soil = RecursiveConvolutionSoil(model, dt)
    t_build = time.perf_counter() - t0
    rng = np.random.default_rng(1)
    x = rng.standard_normal(n) * 1e-3
    xd = rng.standard_normal(n) * 1e-2

    def hist():
        soil._h = None                     # force the GEMV (history is cached per step)
        soil.history()

    dts = iter(dt * (1 + 1e-6 * np.arange(1, reps + 10)))
    rows = dict(
        history=per_call(hist, reps),
        step=per_call(lambda: soil.step(x, xd), reps),
        new_dt=per_call(lambda: soil.instantaneous(next(dts)), min(reps, 200)),
    )
    f = np.array([5.0, 20.0])
    K = model.frequency_response(f)
    warp = (np.linalg.norm(recursion_transfer(model, dt, f) - K, axis=(1, 2))
            / np.linalg.norm(K, axis=(1, 2)))
    return model, t_build, rows, warp


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=247)
    ap.add_argument("--pairs", type=int, default=12)
    ap.add_argument("--real", type=int, default=0)
    a = ap.parse_args()
    print(f"{'n':>5} {'poles':>5} {'pairs':>5} {'history us':>11} "
          f"{'step us':>8} {'new dt us':>10} {'build s':>8} {'warp 5Hz':>9} {'warp 20Hz':>9}")
    cases = [(a.n, a.pairs, a.real), (a.n, 0, 2 * a.pairs), (a.n, a.pairs // 2, 0), (6, 3, 2)]
    for n, pairs, real in cases:
        model, tb, r, warp = bench(n, pairs, real)
        print(f"{n:5d} {model.order:5d} {pairs:5d} {r['history']:11.1f} "
              f"{r['step']:8.1f} {r['new_dt']:10.1f} {tb:8.2f} {warp[0]:9.2e} {warp[1]:9.2e}")
    print("target: history update < 1000 us at n = 247, 24 poles (single BLAS thread)")


if __name__ == "__main__":
    main()

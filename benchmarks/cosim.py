"""Benchmark: co-simulation (two FMUs, our master) against the monolithic route on the reactor.

Reactor scene (built-in ``reactor``: 241 interface nodes, 6 + 241 = 247 soil DOFs), its
synthetic RG1.60 motion at 0.25 g (``--pga`` to change), 10 s at dt = 5 ms, with uplift.
Soil: the rational fit of the scene's gap impedance table (BEM sweep and fit cached in
$UPLIFT_CACHE or ~/.cache/uplift), run by the recursive convolution. ``--soil winkler`` uses a
stand-in of the same size (Winkler springs and dashpots with two Maxwell terms) when the
fit is not wanted.

Prints: wall time of each route (and of the FMU build), the ratio cosim / monolithic (target
<= 1.5), real-time factor (target: faster than real time), the difference between the two
(round-off expected), and the co-simulation's time per part (structure step, soil step,
transfers). Run with OPENBLAS_NUM_THREADS=1.

    python benchmarks/cosim.py [--pga 0.25] [--duration 10] [--soil fit|winkler] [--jacobi]
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np


def soil_for(scene, kind, cache_dir):
    if kind == "fit":
        from orchestrator.cosim import scene_soil_model
        t0 = time.perf_counter()
        model = scene_soil_model(scene, cache_dir=cache_dir)
        return model, f"rational fit of the gap table, {model.order} poles ({time.perf_counter() - t0:.1f} s incl. sweep/cache)"
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    from cosim_cases import winkler
    from soil_double import winkler_rational
    model = winkler_rational(winkler(scene))
    return model, f"Winkler + 2 Maxwell terms stand-in, {model.order} poles"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pga", type=float, default=0.25)
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--soil", choices=("fit", "winkler"), default="fit")
    ap.add_argument("--jacobi", action="store_true", help="also run the Jacobi schedule")
    args = ap.parse_args(argv)

    from orchestrator.cosim import run_cosim, run_monolithic
    from orchestrator.motion import synthetic_motion
    from orchestrator.scene import load_scene

    cache = Path(os.environ.get("UPLIFT_CACHE", Path.home() / ".cache" / "uplift"))
    scene = load_scene("reactor")
    dt = 0.005
    motion = synthetic_motion(pga_g=args.pga, duration_s=args.duration, dt=dt, seed=1)
    model, label = soil_for(scene, args.soil, cache)
    nt = motion.acc.shape[0]
    print(f"reactor: {scene.mesh.xy.shape[0]} interface nodes, soil {model.n} DOFs: {label}")
    print(f"motion: synthetic RG1.60 {args.pga} g, {args.duration} s at dt = {dt} s ({nt - 1} steps)\n")

    calls = {}

    def timed(name, fn, *a, **kw):
        t0 = time.perf_counter()
        r = fn(*a, **kw)
        calls[name] = time.perf_counter() - t0
        return r

    mono = timed("monolithic", run_monolithic, scene, motion, model)
    cos = timed("cosim (gauss-seidel)", run_cosim, scene, motion, model)
    runs = [("monolithic", mono), ("cosim (gauss-seidel)", cos)]
    if args.jacobi:
        runs.append(("cosim (jacobi)", timed("cosim (jacobi)", run_cosim, scene, motion, model, schedule="jacobi")))
    print(f"{'route':24s} {'run s':>8s} {'call s':>8s} {'x real time':>11s} {'max uplift mm':>14s} {'converged':>9s}")
    for name, r in runs:
        print(f"{name:24s} {r.wall_s:8.2f} {calls[name]:8.2f} {args.duration / r.wall_s:11.2f} "
              f"{1e3 * r.max_uplift():14.3f} {str(r.converged):>9s}")
    print("(run s: the route's wall_s: stepper / FMU initialisation and time loop; call s: the whole call,\n"
          " with the soil construction - its passivity check - and, for cosim, the FMU build)")
    print(f"\ncosim / monolithic wall time: {cos.wall_s / mono.wall_s:.2f} (target <= 1.5); "
          f"FMU build {cos.info['build_s']:.2f} s (in call s only)")
    d = np.abs(cos.raft - mono.raft).max() / np.abs(mono.raft).max()
    print(f"cosim vs monolithic, raft: {d:.2e} relative (round-off expected)")
    if args.jacobi:
        dj = np.abs(runs[2][1].raft - mono.raft).max() / np.abs(mono.raft).max()
        print(f"jacobi vs monolithic, raft: {dj:.2e} relative (one-step coupling lag)")
    parts = cos.info["timing"]
    total = cos.wall_s
    print(f"\n{'cosim part':24s} {'s':>8s} {'ms/step':>8s} {'share':>7s}")
    for part, s in list(parts.items()) + [("other (init, recording)", total - sum(parts.values()))]:
        print(f"{part:24s} {s:8.2f} {1e3 * s / (nt - 1):8.3f} {100 * s / total:6.1f}%")


if __name__ == "__main__":
    main()

"""Benchmark: what the linear contact pre-check saves.

A scene without uplift: the reactor stick model on its 241-node raft (Winkler springs, RCC-G
damping, as benchmarks/structure_step.py), 10 s of seeded motion at dt = 5 ms, 0.02 g. Runs
``simulate`` with the pre-check (default: the closed-contact linear recursion, one
factorisation, outputs and energies vectorised at the end) and with the nonlinear machinery
forced (``ContactSettings(precheck=False)``: Newton with line search every step), ``--repeat``
times each, interleaved; prints the median wall and CPU times, their ratio (target >= 5x) and
the largest history differences (relative to each history's peak). A run with uplift
(``--pga-uplift``, default 0.25 g) shows what the pre-check costs when it finds tension and
falls back to the nonlinear run (results bit-identical to the forced run).

``--monolithic`` adds the monolithic route of the built-in reactor scene (BEM gap table as a
rational model run by recursive convolution; uses the cached sweep and fit under
$UPLIFT_CACHE, else computes them): there the soil's recursion costs the same on both paths.

    python benchmarks/skip.py [--repeat 5] [--pga 0.02] [--pga-uplift 0.25] [--monolithic]
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from structure import ContactSettings, simulate
from structure_step import setup

PRE, FORCED = ContactSettings(), ContactSettings(precheck=False)


def timed(run, repeat):
    """(median wall s, median CPU s, last result) of ``repeat`` calls of run(settings) per setting."""
    out = {}
    for _ in range(repeat):
        for label, settings in (("pre-check", PRE), ("forced", FORCED)):
            w0, c0 = time.perf_counter(), time.process_time()
            res = run(settings)
            out.setdefault(label, []).append((time.perf_counter() - w0, time.process_time() - c0, res))
    return {k: (float(np.median([v[0] for v in vals])), float(np.median([v[1] for v in vals])), vals[-1][2])
            for k, vals in out.items()}


def differences(a, b):
    """(largest relative difference over the histories, each against its own peak; its name)."""
    pairs = {"raft": (a.raft, b.raft), "soil_w": (a.soil_w, b.soil_w),
             "dynamic contact force": (a.contact_force - a.info["P0"], b.contact_force - b.info["P0"]),
             "gap": (a.gap, b.gap)}
    pairs.update({f"acc {k}": (a.acc[k], b.acc[k]) for k in b.acc})
    pairs.update({f"energy {k}": (a.energy[k], b.energy[k]) for k in b.energy})
    d = {k: float(np.abs(x - y).max() / max(np.abs(y).max(), 1e-300)) for k, (x, y) in pairs.items()}
    worst = max(d, key=d.get)
    return d[worst], worst


def row(label, t):
    (wp, cp, rp), (wf, cf, rf) = t["pre-check"], t["forced"]
    iters = int(rf.newton_iters.sum())
    diff, where = differences(rp, rf)
    return (f"{label:34s} {wp:7.3f} {wf:7.3f} {wf / wp:6.2f}x  {cp:7.3f} {cf:7.3f} {cf / cp:6.2f}x  "
            f"{diff:9.2e} ({where})  {1e3 * rf.max_uplift():7.3f}  {iters:6d}  {rp.info['precheck'][:44]}")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--pga", type=float, default=0.02)
    ap.add_argument("--pga-uplift", type=float, default=0.25)
    ap.add_argument("--monolithic", action="store_true")
    args = ap.parse_args()
    print(f"{'case':34s} {'wall s':>7s} {'forced':>7s} {'ratio':>7s}  {'CPU s':>7s} {'forced':>7s} {'ratio':>7s}  "
          f"{'max diff (history)':>9s}  {'up mm':>7s}  {'Newton':>6s}  pre-check")
    for pga in (args.pga, args.pga_uplift):
        model, soil, ag, dt, damping = setup(pga, 1)
        t = timed(lambda c: simulate(model, soil, ag, dt, contact=c, damping=damping), args.repeat)
        print(row(f"reactor winkler {pga:g} g, {ag.shape[0] - 1} steps", t), flush=True)
    if args.monolithic:
        import dataclasses

        from fmus.resources import soil_from_model
        from orchestrator.impedance import scene_fit
        from orchestrator.motion import make_motion
        from orchestrator.scene import load_scene
        from orchestrator.settings import default_cache_dir

        scene = load_scene("reactor")
        scene = dataclasses.replace(scene, motion=dataclasses.replace(scene.motion, pga_g=args.pga))
        fit = scene_fit(scene, cache_dir=default_cache_dir()).model
        motion, model = make_motion(scene.motion, 0.005), scene.model()
        soil = soil_from_model(fit, motion.dt)
        s0 = soil.get_state()

        def mono(c):
            soil.set_state(s0)
            return simulate(model, soil, motion.acc, motion.dt, contact=c, output_nodes=scene.output.nodes)
        t = timed(mono, max(1, args.repeat // 2))
        print(row(f"reactor monolithic {args.pga:g} g", t), flush=True)


if __name__ == "__main__":
    main()

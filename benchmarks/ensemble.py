"""Benchmark: an ensemble of records on dask.distributed (``uplift ensemble``) against single runs.

Scene: the built-in reactor (241 interface nodes, 10 s at 5 ms), monolithic route. Records: 8
seeds of its synthetic RG1.60 motion (spectrum-matched, 10 s; ``--records`` for files), each
at 2 PGAs (0.15 and 0.3 g; ``--pga``). The ensemble runs on a LocalCluster of 1, then 2 worker
processes (``--workers``), each time from an empty output (nothing kept from an earlier run);
the BEM sweep and the fit come from the cache as in any run after the first (``--no-cache``:
from scratch, the cold set-up).

Prints: the single runs (``run_scene`` of each cell's scene, as ``uplift run``: the route's
stepping time wall_s, and the whole run with its own step-doubling check); then per worker
count the wall time, runs per minute, the parts of the wall time (starting the cluster; the
set-up: sweep and fit; the step-doubling check on the strongest motion, once per ensemble; the
runs), the per-run cost ((wall - cluster - set-up - check) x workers / runs) against the mean stepping
time of the single runs ("/ single", target <= 1.2) and against the mean stepping time of the
same runs inside the ensemble ("/ in-run": the ensemble's own overhead at the load of the
moment), the median over the cells of the cell time on its worker (run_scene + summary + floor
spectra) over the same cell's single stepping time, and the 1-minute load average at the end;
then the largest difference between the datasets of the worker counts (a cell must not depend
on it: 0 expected) and the fractiles of max uplift. Run with OPENBLAS_NUM_THREADS=1; on a
shared machine timings are noisy (other jobs take cores: see the load column).

    python benchmarks/ensemble.py [--workers 1 2] [--pga 0.15 0.3] [--seeds 8] [--records PATH ...]
                                  [--single N] [--no-cache]
"""
from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from orchestrator.ensemble import plan_ensemble, run_ensemble
from orchestrator.run import prepare_run, run_scene
from orchestrator.scene import load_scene
from orchestrator.settings import default_cache_dir

ROUTE = "monolithic"


def single_runs(plan, n, cache_dir):
    """{cell key: (route wall_s, whole run_scene s, max uplift m)} of single runs of the first
    ``n`` cells (all: 0)."""
    out = {}
    for cell in plan.cells[:n or None]:
        t0 = time.perf_counter()
        res = run_scene(cell.scene, [cell.route], cache_dir=cache_dir)[0][cell.route]
        out[cell.key] = (res.wall_s, time.perf_counter() - t0, res.max_uplift())
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--pga", type=float, nargs="+", default=[0.15, 0.3])
    ap.add_argument("--seeds", type=int, default=8, help="seeds 1..N of the synthetic motion")
    ap.add_argument("--records", type=Path, nargs="+", default=None, help="record files or folders instead")
    ap.add_argument("--single", type=int, default=0, help="single runs of the first N cells (default: all)")
    ap.add_argument("--no-cache", action="store_true")
    args = ap.parse_args()
    cache = None if args.no_cache else default_cache_dir()
    scene = load_scene("reactor").with_routes([ROUTE])
    seeds = None if args.records else list(range(1, args.seeds + 1))
    plan = plan_ensemble(scene, args.pga, records=args.records, seeds=seeds)
    prepare_run(scene, cache_dir=cache).settle()            # the sweep and the fit in the cache
    single = single_runs(plan, args.single, cache)
    step_s = statistics.mean(v[0] for v in single.values())
    print(f"{len(single)} single runs (reactor, {ROUTE}): stepping mean {step_s:.2f} s, whole run "
          f"{statistics.mean(v[1] for v in single.values()):.2f} s (with its step-doubling check); "
          f"load average {os.getloadavg()[0]:.1f}")
    datasets = {}
    print(f"{'workers':>7} {'runs':>5} {'wall s':>8} {'runs/min':>9} {'cluster %':>10} {'set-up %':>9} {'dt-check %':>11} "
          f"{'per run s':>10} {'/ single':>9} {'/ in-run':>9} {'cell / its single':>18} {'load':>5}")
    for w in args.workers:
        with tempfile.TemporaryDirectory() as tmp:
            ds = run_ensemble(scene, args.pga, records=args.records, seeds=seeds, output=Path(tmp) / "ensemble.h5",
                              workers=w, cache_dir=cache)
        a = ds.attrs
        runs = int(ds["status"].size)
        setup = a["setup_s"] + a["dt_check_s"]
        per_run = (a["wall_s"] - a["cluster_s"] - setup) * w / runs
        ratios = [float(ds["cell_time"].values[c.index]) / single[c.key][0] for c in plan.cells if c.key in single]
        same = max(abs(float(ds["max_uplift"].values[c.index]) - single[c.key][2]) for c in plan.cells if c.key in single)
        in_run = float(np.nanmean(ds["wall_time"].values))
        print(f"{w:>7} {runs:>5} {a['wall_s']:>8.1f} {60 * runs / a['wall_s']:>9.1f} "
              f"{100 * a['cluster_s'] / a['wall_s']:>9.1f}% {100 * a['setup_s'] / a['wall_s']:>8.1f}% "
              f"{100 * a['dt_check_s'] / a['wall_s']:>10.1f}% "
              f"{per_run:>10.2f} {per_run / step_s:>9.2f} {per_run / in_run:>9.2f} {statistics.median(ratios):>18.2f} "
              f"{os.getloadavg()[0]:>5.1f}   (max |max uplift - single run's| {same:.3g} m)")
        datasets[w] = ds
    if len(datasets) > 1:
        ref = datasets[args.workers[0]]
        for w, ds in datasets.items():
            diff = max(float(np.nanmax(np.abs(ds[v].values - ref[v].values)))
                       for v in ("max_uplift", "max_raft_rotation", "min_contact_ratio", "floor_spectrum"))
            print(f"{w} workers against {args.workers[0]}: largest difference of any cell value {diff:.3g}")
    ref = datasets[args.workers[0]]
    fr = ref["max_uplift_fractile"].sel(route=ROUTE)
    for p in ref["pga"].values:
        print(f"{p:g} g: max uplift median {1e3 * float(fr.sel(pga=p, quantile=0.5)):.3f} mm, 84th percentile "
              f"{1e3 * float(fr.sel(pga=p, quantile=0.84)):.3f} mm over {ref.sizes['record']} records")


if __name__ == "__main__":
    main()

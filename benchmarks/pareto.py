"""Benchmark: run time against error of every route and its accuracy knobs.

For the disk-halfspace scene (with the bench's tower) and the reactor scene, each route's
knobs (dt, fit tolerance, BEM element size, TF padding, contact penalty) are swept; errors on
max uplift, raft rotation and floor-spectrum peaks are measured against the route's own finest
run and against the timefreq reference; OpenSeesPy runs the Winkler route as a peer. Prints the
table (see orchestrator/bench.py) and writes the wall-time-against-error plot. Same as
``uplift bench [--quick] --plot FILE``; tens of minutes in full on 2 cores (BEM sweeps and fits
are cached under $UPLIFT_CACHE after the first run).

    python benchmarks/pareto.py [--quick] [--plot pareto.png] [--json rows.json]
"""
from __future__ import annotations

import argparse
import json
import sys

from orchestrator.bench import bench, bench_config, format_rows, json_safe, plot_rows
from orchestrator.settings import compute_threads, default_cache_dir


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="disk-halfspace only, few knob values")
    p.add_argument("--plot", default="pareto.png", help="wall time against error plot (default pareto.png)")
    p.add_argument("--json", default=None, metavar="FILE", help="also write the rows as JSON to this file")
    a = p.parse_args(argv)
    with compute_threads():
        rows = bench(bench_config(a.quick), cache_dir=default_cache_dir(),
                     log=lambda msg: print(msg, file=sys.stderr, flush=True))
    print(format_rows(rows))
    print(f"wrote {plot_rows(rows, a.plot)}", file=sys.stderr)
    if a.json:
        with open(a.json, "w") as f:
            json.dump(json_safe(rows), f, indent=1)
        print(f"wrote {a.json}", file=sys.stderr)


if __name__ == "__main__":
    main()

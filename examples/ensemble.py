"""An ensemble of motions from Python: a coarse reactor under 5 spectrum-matched motions at two
PGAs on a local dask cluster, the fractiles of max uplift over the motions, the file and its report.

    python examples/ensemble.py [--workers 2] [--records PATH ...]

The scene is the reactor stick on a coarse 20 m raft (element size 5 m) over layered rock, 5 s
motions (seeds 1-5 of its synthetic RG1.60 motion, or the records given), each at 0.15 and
0.3 g, on the monolithic route. ``run_ensemble`` returns an ``xarray.Dataset`` (dimensions
record, pga, route, node, direction, frequency, quantile; see orchestrator/ensemble.py) and
writes it to ``coarse_reactor_ensemble.h5``; rerunning the script computes nothing (the
completed runs are kept in ``coarse_reactor_ensemble.h5.cells/``).
"""
import argparse

from orchestrator.ensemble import run_ensemble
from orchestrator.progress import Progress
from orchestrator.report import write_ensemble_report
from orchestrator.scene import scene_from_dict
from orchestrator.settings import default_cache_dir

SCENE = {
    "soil": {"layers": [{"thickness": 8.0, "vs": 1350.0, "nu": 0.3, "rho": 2400.0, "damping": 0.03}],
             "halfspace": {"vs": 1600.0, "nu": 0.3, "rho": 2500.0, "damping": 0.03}, "damping_model": "causal"},
    "foundation": {"shape": "circle", "radius": 20.0, "element_size": 5.0},
    "impedance": {"range_hz": [0.0, 25.0, 51]},
    "structure": {"model": "reactor", "damping": {"modal": 0.07}},
    "contact": {"enabled": True},
    "motion": {"kind": "synthetic", "spectrum": "RG1.60", "pga_g": 0.25, "duration_s": 5.0, "seed": 1},
    "analysis": {"routes": ["monolithic"], "dt": 0.005},
    "output": {"nodes": ["top_outer", "internals_37m"]},
}

if __name__ == "__main__":      # the local cluster starts worker processes that import this file
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--records", nargs="+", default=None,
                    help="record folders (one PEER triplet each) or record files (one component each) instead of "
                         "the seeds")
    args = ap.parse_args()
    scene = scene_from_dict(SCENE, name="coarse_reactor")
    ds = run_ensemble(scene, [0.15, 0.3], records=args.records, seeds=None if args.records else [1, 2, 3, 4, 5],
                      output="coarse_reactor_ensemble.h5", workers=args.workers, cache_dir=default_cache_dir(),
                      progress=Progress("ensemble"))
    fractiles = ds["max_uplift_fractile"].sel(route="monolithic")
    for pga in ds["pga"].values:
        median, p84 = (1e3 * float(fractiles.sel(pga=pga, quantile=q)) for q in (0.5, 0.84))
        print(f"{pga:g} g: max uplift median {median:.6f} mm, 84th percentile {p84:.6f} mm "
              f"({int(ds['converged_records'].sel(pga=pga, route='monolithic'))}/{ds.sizes['record']} converged)")
    print(f"{ds.attrs['computed']} runs computed, {ds.attrs['reused']} kept, {ds.attrs['wall_s']:.1f} s; "
          "wrote coarse_reactor_ensemble.h5")
    print(f"wrote {write_ensemble_report('coarse_reactor_ensemble.h5', 'coarse_reactor_ensemble_report')}")

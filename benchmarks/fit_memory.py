"""Benchmark: the rational fit of a gap table, held in memory against read in blocks from disk.

Per table (the reactor's soil, a disk of radius 20 m meshed with about ``--nodes`` interface nodes,
swept at ``--freqs`` frequencies over 0-25 Hz and cached in $UPLIFT_CACHE; or ``--table FILE``, an
ImpedanceTable file) the fit (``fit.pipeline.fit``, default options: tol 0.01, rigid-raft correction,
passivity enforced) runs in a fresh process twice:

  memory     ImpedanceTable.load, then the fit (target.Problem: the table and its scaled copies held)
  streamed   BlockedTable.open on a chunked copy of the file, then the fit (fit.streamed.StreamedProblem)

and prints per run the wall time, the peak resident memory (ru_maxrss of the child), the poles, the
errors and the passivity verdict, and between the two runs the largest relative difference of the
poles and of the coefficients (round-off expected: same algorithm, sums in another order). "wall s"
is the child's whole run (read and fit), "cpu s" its user + system time (the honest measure on a
shared machine).

    OPENBLAS_NUM_THREADS=1 python benchmarks/fit_memory.py --nodes 250 600 [--freqs 101]
    nice flock /tmp/big.lock python benchmarks/fit_memory.py --nodes 1200 --freqs 51
    # the order search's memory: tol out of reach, every order up to max_order fitted (the table swept fast)
    nice python benchmarks/fit_memory.py --nodes 600 1200 --freqs 21 --solver fast --modes streamed --tol 1e-4 --max-order 16

The "est. MB" column is the memory guard's estimate of the child's peak at the largest order fitted.
"""
from __future__ import annotations

import os

os.environ["OPENBLAS_NUM_THREADS"] = "1"
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def table_path(nodes: int, n_freq: int, solver: str = "dense") -> Path:
    """The cache entry of the gap table of the reactor's soil under a disk of about ``nodes`` nodes
    (swept by ``solver``: "fast" for large disks, within its default residual)."""
    sys.path.insert(0, str(HERE))
    from scaling import mesh_for
    from orchestrator.scene import load_scene
    from soil_impedance.cache import default_cache_dir
    from soil_impedance.sweep import _cache_path, impedance_sweep, table_key
    scene = load_scene("reactor")
    mesh = mesh_for(nodes)
    f = np.linspace(0.0, 25.0, n_freq)
    impedance_sweep(scene.profile, mesh, f, contact=scene.contact_kind, outputs=("gap",),
                    cache_dir=default_cache_dir(), solver=solver)
    return _cache_path(default_cache_dir(), "gap", table_key(scene.profile, mesh, f, scene.contact_kind, "gap",
                                                             solver=solver))


def blocked_copy(path: Path) -> Path:
    """A chunked copy of the table file ``path`` (``blocked.TableWriter``), made once, frequency by frequency."""
    import h5py
    from soil_impedance.blocked import BlockedTable, TableWriter
    with h5py.File(path, "r") as h:
        if h["matrices_real"].chunks is not None and h["matrices_real"].chunks[0] == 1:
            return path
    out = path.with_name(path.stem + ".blocked.h5")
    if not out.exists():
        src = BlockedTable.open(path)
        with TableWriter(out, src.frequencies_hz, src.dofs, src.provenance) as w:
            for k in range(src.frequencies_hz.size):
                w[k] = src.frequency(k)
    return out


def child(mode: str, path: str, out: str, options: str = "{}") -> None:
    """One fit in this process; its measures written as JSON to ``out``."""
    import resource
    from soil_impedance.blocked import BlockedTable
    from soil_impedance.fit.options import FitOptions
    from soil_impedance.fit.pipeline import fit
    from soil_impedance.table import ImpedanceTable
    t0 = time.perf_counter()
    table = ImpedanceTable.load(path) if mode == "memory" else BlockedTable.open(path)
    t_read = time.perf_counter() - t0
    def trace(done, total, label):       # each order fitted and each passivity test: time and peak so far
        u = resource.getrusage(resource.RUSAGE_SELF)
        print(f"  [{mode}] {label} {done}/{total}: {time.perf_counter() - t0:.0f} s, cpu {u.ru_utime + u.ru_stime:.0f} s, "
              f"peak {u.ru_maxrss / 1024:.0f} MB", file=sys.stderr, flush=True)
    result = fit(table, FitOptions(**json.loads(options)), progress=trace)
    wall = time.perf_counter() - t0
    r, m = result.report, result.model
    np.savez(out + ".npz", poles=m.poles, C=m.coefficients)
    Path(out).write_text(json.dumps({
        "mode": mode, "n_dof": len(table.dofs), "n_freq": int(table.frequencies_hz.size), "read_s": t_read,
        "wall_s": wall, "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "cpu_s": sum(resource.getrusage(resource.RUSAGE_SELF)[:2]),
        "order": int(m.order), "max_fitted": int(max(h[0] for h in r.order_history)), "max_rel_error": r.max_rel_error, "passive": r.passive,
        "margin": r.passivity_margin, "passivity_method": r.passivity.get("method"),
        "passivity_evals": r.passivity.get("evaluations"), "history": r.order_history,
        "attempts": r.enforcement_attempts}))


def run(path: Path, modes, options: str = "{}") -> dict:
    out = {}
    tmp = tempfile.mkdtemp()
    for mode in modes:
        src = blocked_copy(path) if mode == "streamed" else path
        res = Path(tmp) / f"{mode}.json"
        subprocess.run([sys.executable, __file__, "--child", mode, str(src), str(res), options], check=True)
        out[mode] = json.loads(res.read_text())
        out[mode]["arrays"] = dict(np.load(str(res) + ".npz"))
    return out


def estimate(r: dict) -> float:
    """The memory guard's estimate of the run's peak (bytes): ``streamed_fit_memory`` (or ``fit_memory``
    and the table itself, held) at the largest order the search fitted, and the interpreter (``sweep.BASE_BYTES``)."""
    from soil_impedance.fit.peak_memory import fit_memory, streamed_fit_memory
    from soil_impedance.sweep import BASE_BYTES
    n, F, m = r["n_dof"], r["n_freq"], r["max_fitted"]
    if r["mode"] == "streamed":
        return streamed_fit_memory(n, F, m)["total"] + BASE_BYTES
    return fit_memory(n, F, m)["total"] + 16 * F * n * n + BASE_BYTES


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--nodes", type=int, nargs="*", default=[250, 600])
    ap.add_argument("--freqs", type=int, default=101)
    ap.add_argument("--solver", default="dense", choices=("dense", "fast"), help="the sweep's solver")
    ap.add_argument("--table", nargs="*", default=[], help="ImpedanceTable files to fit instead")
    ap.add_argument("--modes", nargs="*", default=["memory", "streamed"])
    ap.add_argument("--tol", type=float, default=None, help="the fit's tol (default FitOptions'; small: more orders)")
    ap.add_argument("--max-order", type=int, default=None, help="the fit's max_order (default FitOptions')")
    ap.add_argument("--child", nargs=4, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.child:
        child(*a.child)
        return
    options = json.dumps({k: v for k, v in (("tol", a.tol), ("max_order", a.max_order)) if v is not None})
    paths = [Path(p) for p in a.table] or [table_path(n, a.freqs, a.solver) for n in a.nodes]
    print(f"{'n dof':>6} {'F':>4} {'mode':>9} {'read s':>7} {'wall s':>7} {'cpu s':>7} {'peak MB':>8} {'poles':>5} "
          f"{'max err':>9} {'passive':>7} {'method':>11} {'evals':>6} {'est. MB':>8}")
    for p in paths:
        res = run(p, a.modes, options)
        for mode, r in res.items():
            print(f"{r['n_dof']:6d} {r['n_freq']:4d} {mode:>9} {r['read_s']:7.1f} {r['wall_s']:7.1f} {r['cpu_s']:7.1f} "
                  f"{r['peak_mb']:8.0f} {r['order']:5d} {r['max_rel_error']:9.2e} {r['passive']!s:>7} "
                  f"{r['passivity_method']!s:>11} {r['passivity_evals']!s:>6} {estimate(r) / 2 ** 20:8.0f}", flush=True)
        if len(res) == 2:
            a1, a2 = (res[m]["arrays"] for m in a.modes)
            if a1["poles"].shape == a2["poles"].shape:
                dp = np.max(np.abs(a1["poles"] - a2["poles"]) / np.abs(a1["poles"]))
                dc = np.max(np.abs(a1["C"] - a2["C"])) / np.max(np.abs(a1["C"]))
                print(f"       same order: poles differ by {dp:.1e} (relative), coefficients by {dc:.1e} "
                      "(of the largest)")
            else:
                print("       different orders")


if __name__ == "__main__":
    main()

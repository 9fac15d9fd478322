"""Benchmark: the certified passivity sweep by eigenvalues (``passivity._certified_sweep``, the "sweep"
below ``CHOLESKY_SWEEP_NA`` active DOFs) against the sweep by shifted Cholesky factorisations
(``passivity._cholesky_sweep``, from there on), on the same models, one process, one BLAS thread.

Models (say which in the table's "model" column):
  kernel    synthetic, passive by construction, kernel-structured (per pole its own SPD kernel
            matrix I + β exp(−c|x − x'|) over the DOFs, 3 real poles and 4 damped pairs, E ⪰ 0; the
            construction of tests/soil/test_passivity_certificate.py with fixed parameters); "+notch": plus a negative
            damping peak ζ = 2e-4 at 13.0123 Hz on a smooth DOF pattern (one narrow violation)
  fit       a real fit (``fit.pipeline.fit``, default options) of a gap table file (``--table``,
            e.g. the reactor's soil under a disk of 600 nodes, benchmarks/fit_memory.py's table)

Per model and sweep: the samples (factorisations and eigensolutions; the eigenvalue sweep's are all
eigensolutions), CPU seconds in total and per sample, of which the residue-norm set-up (complex SVDs for the
eigenvalue sweep, power iteration + Cholesky for the other), the verdict. ``--old-up-to N``: above N
DOFs the eigenvalue sweep is not run; its time is estimated as (its sample count at the largest
size run, or ``--old-samples``) × (the CPU time of 3 eigensolutions at this size), printed as "est".

    OPENBLAS_NUM_THREADS=1 python benchmarks/passivity_cost.py --dofs 606 1206
    nice flock /tmp/big.lock python benchmarks/passivity_cost.py --dofs 2506 --old-up-to 1300
    python benchmarks/passivity_cost.py --dofs --table /path/to/gap_table.h5
"""
from __future__ import annotations

import os

os.environ["OPENBLAS_NUM_THREADS"] = "1"
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE.parent / "tests"))       # helpers.passive_models


def kernel_model(n, f_max=25.0):
    """The synthetic passive kernel-structured model (module docstring)."""
    from soil_impedance.rational import RationalModel
    x = np.linspace(-1.0, 1.0, n)
    w_ref = 2 * np.pi * f_max

    def S(c, beta=0.3):
        return 1e9 * (np.eye(n) + beta * np.exp(-np.abs(x[:, None] - x[None, :]) * c))
    poles, res = [], []
    for j in range(3):
        p = -w_ref * (0.3 + 0.7 * j)
        poles.append(p)
        res.append(-0.2 * abs(p) * S(3.0 + j))
    for j in range(4):
        w0, z = w_ref * (0.2 + 0.35 * j), 0.15 + 0.05 * j
        p = -z * w0 + 1j * w0 * np.sqrt(1 - z * z)
        r = -0.3 * w0 ** 2 / (p - np.conj(p)) * S(2.0 + j)
        poles += [p, np.conj(p)]
        res += [r, np.conj(r)]
    poles, res = np.array(poles, complex), np.array(res, complex)
    static = np.real(np.sum(-res / poles[:, None, None], axis=0))
    return RationalModel(poles, res, 3 * S(1.0) - static, 0.02 / w_ref * S(5.0), [f"d{i}" for i in range(n)],
                         {"f_max_hz": f_max})


def notched(model, f0=13.0123, zeta=2e-4, depth=3.0):
    """``model`` plus a negative damping peak on the pattern cos(πx) (a narrow violation at f0)."""
    from helpers.passive_models import with_notch
    return with_notch(model, f0, zeta, depth, np.cos(np.pi * np.linspace(-1, 1, model.n)))


def fitted_model(path):
    from soil_impedance.fit.options import FitOptions
    from soil_impedance.fit.pipeline import fit
    from soil_impedance.table import ImpedanceTable
    table = ImpedanceTable.load(path)
    t0 = time.process_time()
    result = fit(table, FitOptions())
    return result.model, time.process_time() - t0


def run(sc, kind):
    """(samples, eigensolutions, cpu s, of which residue-norm set-up s, bands, certified) of one sweep."""
    import soil_impedance.passivity as pv
    eig, setup = [0], [0.0]
    real_lmin, name = pv._lmin, "_residue_norms" if kind == "eigen" else "_residue_bounds"
    real_norms = getattr(pv, name)

    def counted(s, nu, chunk=64):
        eig[0] += np.atleast_1d(nu).size
        return real_lmin(s, nu, chunk)

    def timed(s):
        t0 = time.process_time()
        out = real_norms(s)
        setup[0] += time.process_time() - t0
        return out
    pv._lmin = counted
    setattr(pv, name, timed)
    try:
        t0 = time.process_time()
        sweep = pv._certified_sweep if kind == "eigen" else pv._cholesky_sweep
        bands, _, _, certified, evals = sweep(sc, pv._default_grid())
        cpu = time.process_time() - t0
    finally:
        pv._lmin = real_lmin
        setattr(pv, name, real_norms)
    return evals, eig[0], cpu, setup[0], bands, certified


def eig_seconds(sc, k=3):
    import soil_impedance.passivity as pv
    t0 = time.process_time()
    pv._lmin(sc, np.linspace(0.3, 0.9, k), chunk=1)
    return (time.process_time() - t0) / k


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dofs", type=int, nargs="*", default=[606, 1206])
    ap.add_argument("--notch", action="store_true", help="also the models with a narrow violation")
    ap.add_argument("--old-up-to", type=int, default=1300)
    ap.add_argument("--old-samples", type=int, default=None,
                    help="the eigenvalue sweep's sample count for the estimate when no smaller size was run")
    ap.add_argument("--table", nargs="*", default=[], help="gap table files to fit and test")
    a = ap.parse_args(argv)
    models = []
    for n in a.dofs:
        models.append((f"kernel {n}", kernel_model(n)))
        if a.notch:
            models.append((f"kernel+notch {n}", notched(kernel_model(n))))
    for path in a.table:
        model, fit_s = fitted_model(path)
        print(f"fit of {path}: {model.n} DOFs, {model.order} poles, {fit_s:.0f} CPU s", flush=True)
        models.append((f"fit {model.n}", model))
    print(f"{'model':>18} {'sweep':>9} {'samples':>8} {'eig':>5} {'cpu s':>8} {'s/sample':>9} {'set-up s':>9} "
          f"{'certified':>9} bands (Hz)", flush=True)
    last_count = a.old_samples
    for name, model in models:
        sc = model.scaled
        hz = sc.w_ref / (2 * np.pi)
        for kind in ("eigen", "cholesky"):
            if kind == "eigen" and sc.na > a.old_up_to:
                if last_count is None:
                    continue
                per = eig_seconds(sc)
                print(f"{name:>18} {kind:>9} {last_count:8d} {'all':>5} {last_count * per:8.0f} {per:9.3f} "
                      f"{'':>9} {'(est)':>9}", flush=True)
                continue
            evals, n_eig, cpu, setup, bands, certified = run(sc, kind)
            if kind == "eigen":
                last_count = evals
            print(f"{name:>18} {kind:>9} {evals:8d} {n_eig:5d} {cpu:8.1f} {cpu / max(evals, 1):9.4f} {setup:9.1f} "
                  f"{certified!s:>9} " + ", ".join(f"{lo * hz:.4f}-{hi * hz:.4f}" for lo, hi in bands), flush=True)


if __name__ == "__main__":
    main()

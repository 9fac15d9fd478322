"""Benchmark: the cost of each iteration of the passivity enforcement (``passivity.enforce_passivity``), CPU
seconds of one process with one BLAS thread, split into the grid screen (``_Rescreen`` from
``CHOLESKY_SWEEP_NA`` active DOFs, ``_screen`` below), the cutting planes (``_planes``), the dual
(``_solve_dual``) and the certified test (``_assess``, run when the screen sees nothing).

Model: the synthetic passive kernel-structured model of benchmarks/passivity_cost.py (``--dofs`` DOFs) plus
a negative damping peak at 6.1 Hz (ζ = 1e-2, depth 2, on sin(2πx) + 0.3) and with ``--subgrid`` one at
13.0123 Hz (ζ = 3e-3, depth 3, on cos(πx)), both narrower than the dense grid's step (0.125 Hz): the
certified test finds them. Per iteration: CPU s and its parts, the screen's factorisations; at the end the
iterations, the total, the report, the change's relative size max_f |ΔK(f)| / max_f |K(f)| (entries, on the 51
fit frequencies, and with ``--dense N`` on N frequencies over the same band: minutes from 1000 DOFs), the peak
resident memory. ``--max-iter`` bounds the work (the code
before this benchmark was measured with a few iterations and extrapolated).

    OPENBLAS_NUM_THREADS=1 python benchmarks/enforcement_cost.py --dofs 606 --subgrid
    python benchmarks/enforcement_cost.py --dofs 2506 --max-iter 4
    python benchmarks/enforcement_cost.py --dofs 606 --subgrid --dense 2001
"""
from __future__ import annotations

import os

os.environ["OPENBLAS_NUM_THREADS"] = "1"
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import resource
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE.parent / "tests"))       # helpers.passive_models
sys.path.insert(0, str(HERE))                        # passivity_cost.kernel_model


def model(n, subgrid):
    from helpers.passive_models import with_notch
    from passivity_cost import kernel_model
    m = kernel_model(n)
    x = np.linspace(-1, 1, n)
    if subgrid:
        m = with_notch(m, 13.0123, 3e-3, 3.0, np.cos(np.pi * x))
    return with_notch(m, 6.1, 1e-2, 2.0, np.sin(2 * np.pi * x) + 0.3)


def relative_change(before, after, freqs, chunk=8):
    """max over freqs of |K_after − K_before| / max |K_before| (entries), a few frequencies at a time."""
    top = num = 0.0
    for i in range(0, freqs.size, chunk):
        K = before.frequency_response(freqs[i:i + chunk])
        num = max(num, float(np.abs(after.frequency_response(freqs[i:i + chunk]) - K).max()))
        top = max(top, float(np.abs(K).max()))
    return num / top


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dofs", type=int, default=606)
    ap.add_argument("--subgrid", action="store_true", help="also the peak at 13.0123 Hz")
    ap.add_argument("--max-iter", type=int, default=20)
    ap.add_argument("--dense", type=int, default=0, help="also the change on this many frequencies over 0-25 Hz")
    a = ap.parse_args(argv)
    import soil_impedance.passivity as pv
    parts, screens = {}, []

    def timed(name, f):
        def g(*args, **kw):
            t0 = time.process_time()
            try:
                return f(*args, **kw)
            finally:
                parts[name] = parts.get(name, 0.0) + time.process_time() - t0
        return g
    for name in ("_screen", "_planes", "_solve_dual", "_assess"):
        setattr(pv, name, timed(name.strip("_"), getattr(pv, name)))
    rescreen = pv._Rescreen.__call__

    def call(self, st):
        out = timed("screen", rescreen)(self, st)
        screens.append(self.calls[-1])
        return out
    pv._Rescreen.__call__ = call
    m = model(a.dofs, a.subgrid)
    t0 = time.process_time()
    last = [t0]

    def progress(done, total):
        now = time.process_time()
        extra = f"  screen factorised {screens[-1]} points" if screens else ""
        print(f"iteration {done - 1:3d}: {now - last[0]:7.1f} s  "
              + "  ".join(f"{k} {v:.1f}" for k, v in parts.items()) + extra, flush=True)
        parts.clear()
        last[0] = now
    try:
        f = np.linspace(0, 25, 51)
        out, rep, it = pv.enforce_passivity(m, f, margin=1e-3, max_iter=a.max_iter, progress=progress)
        print(f"{a.dofs} DOFs: {it} iterations, {time.process_time() - t0:.1f} CPU s; {rep}")
        for name, freqs in [("fit frequencies", f)] + ([(f"{a.dense} frequencies", np.linspace(0, 25, a.dense))]
                                                       if a.dense else []):
            print(f"change on the {name}: {relative_change(m, out, freqs):.3e} of the largest entry")
    except pv.FitError as exc:
        print(f"{a.dofs} DOFs: stopped after {time.process_time() - t0:.1f} CPU s: {exc}")
    print(f"peak resident memory {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2 ** 20:.2f} GiB")


if __name__ == "__main__":
    main()

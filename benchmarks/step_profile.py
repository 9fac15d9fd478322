"""Where a step of the native stepper goes on a large raft that lifts: the parts of a step, in ms.

The mat of the scene "mat" (100 m x 100 m, the scene's sticks) meshed at 100 / cells m (cells^2
interface nodes), on the rock's Winkler springs and wave dashpots (tests/helpers: matched on the
rock disk's static stiffness, two Maxwell terms) plus two oscillators whose shapes have the soil
kernel's structure (``with_kernel_terms``: the residues' far blocks of low rank, as a fit's), so
that the history is compressed from 600 nodes on as a run compresses it (``history="auto"`` with
the nodes' coordinates). A one-sided pulse of --pga m/s^2 (x, and 0.3 of it along z) rocks the
mat: a part of it lifts (the largest lifted share is printed).

The C runtime is compiled here with -DUP_PROFILE (stepper.c's timers: process CPU time, so the
numbers stay meaningful on a shared machine; the production build has none) and run through
``simulate_native``. Per size, ms per step (the whole run over its steps) of:

  history     the soil's history product and its commit (soil.c)
  S0 prod.    the products with the soil's matrices of the step (E v, K0C x: the soil force)
  solves      the Newton solves (Woodbury from a base), less the capacitance look-ups below
  capacit.    the capacitance matrices of new active sets (built and factorised), less the bases
  bases       the Newton bases (inverse of the closed/open matrix, Z, W), once per step size
  system      the per-step-size system (condensation), once per step size
  rest        the step less the above (set-up of the right-hand side, contact, line search, outputs)

with the counts of bases, capacitance factorisations (new active sets), Newton solves, the
compressed history's storage and D and E's (of n^2 per block; --history-tol sets the tolerance)
and the growth exponents of each column over the sizes. Above 1200 nodes: under the big-run lock.

    OPENBLAS_NUM_THREADS=1 python benchmarks/step_profile.py --sizes 16 25
    nice flock /tmp/big.lock python benchmarks/step_profile.py --sizes 34 50
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import ctypes
import dataclasses
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "benchmarks"))

PARTS = ("history", "s0", "solve", "capacitance", "base", "system", "step", "update")


def profiling_library(folder: Path, defines=()) -> ctypes.CDLL:
    """The host library (native_stepper.HOST_SOURCES) compiled with -DUP_PROFILE by cc."""
    from fmus.native_build import CFLAGS, NATIVE
    from fmus.native_stepper import HOST_SOURCES, declare
    folder.mkdir(parents=True, exist_ok=True)
    lib = folder / f"uplift-profile-{os.getpid()}.so"
    cmd = ["cc", *CFLAGS, "-DUP_PROFILE", *[f"-D{d}" for d in defines], f"-I{NATIVE / 'include'}", "-o", str(lib),
           *[str(NATIVE / s) for s in HOST_SOURCES], "-lm"]
    subprocess.run(cmd, check=True)
    h = declare(ctypes.CDLL(str(lib)))
    h.up_profile.restype = None
    h.up_profile.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int]
    return h


def profile(lib, reset=True):
    t = np.zeros(len(PARTS))
    n = np.zeros(len(PARTS), np.int64)
    lib.up_profile(t.ctypes.data, n.ctypes.data, int(reset))
    return t, n


def case(cells: int, pga: float, T: float, dt: float = 0.005, soil_kind: str = "kernel", history_tol=None):
    """(stepper at rest, motion (nt, 3), the soil) of the mat at cells x cells nodes, its history
    compressed at ``history_tol`` (None: the soil's default); soil_kind "synthetic": growth.py's step
    stage instead (its 8-pole synthetic soil, dense history, under 0.5 sin(2 pi 3 t) m/s^2 along x)."""
    from growth import scene_at, synthetic_model
    from helpers import pulse_motion, with_kernel_terms
    from helpers.soil_double import winkler_rational
    from helpers.winkler import rock_winkler
    from soil_impedance.convolution import RecursiveConvolutionSoil
    from structure import NewmarkStepper
    scene = scene_at(cells)
    xy = np.asarray(scene.mesh.xy)
    if soil_kind == "synthetic":
        t = np.arange(int(round(T / dt)) + 1) * dt
        ag = np.zeros((t.size, 3))
        ag[:, 0] = 0.5 * np.sin(2 * np.pi * 3.0 * t)
        soil = RecursiveConvolutionSoil(synthetic_model(6 + scene.mesh.n, 8), dt, checked=True)
        st = NewmarkStepper(scene.model(), soil, dt, contact=scene.contact, external_soil=True, ag0=ag[0])
        return st, ag, soil
    base = winkler_rational(rock_winkler(xy, scene.mesh.area, damped=True, match="rocking", ky=True))
    model = with_kernel_terms(base, xy)
    tol = {} if history_tol is None else {"history_tol": history_tol}
    soil = RecursiveConvolutionSoil(model, dt, checked=True, history="auto", xy=xy, **tol)
    motion = pulse_motion(dt=dt, T=T, pga=pga)
    contact = dataclasses.replace(scene.contact, precheck=False)
    st = NewmarkStepper(scene.model(), soil, dt, contact=contact, external_soil=True, ag0=motion.acc[0])
    return st, motion.acc, soil


def measure(cells, args, lib):
    from fmus.native_stepper import simulate_native
    t0 = time.process_time()
    st, ag, soil = case(cells, args.pga, args.T, soil_kind=args.soil, history_tol=args.history_tol)
    setup = time.process_time() - t0
    profile(lib)
    t1 = time.process_time()
    res = simulate_native(st, ag, [], lib=lib)
    run = time.process_time() - t1
    t, n = profile(lib)
    steps = ag.shape[0] - 1
    ms = dict(zip(PARTS, 1e3 * t / steps))
    hist = soil.compressed
    row = {"n_nodes": st.N, "history_kind": soil.history_kind, "setup_s": setup, "run_s": run, "steps": steps,
           "history_tol": None if hist is None else hist.settings["tol"],
           "storage": 1.0 if hist is None else hist.settings["storage_ratio"],
           "de_storage": 1.0 if hist is None or hist.instant is None else hist.instant.settings["storage_ratio"],
           "history": ms["history"], "s0": ms["s0"], "solves": ms["solve"] - ms["capacitance"],
           "capacitance": ms["capacitance"] - ms["base"] - ms["update"], "update": ms["update"],
           "bases": ms["base"], "system": ms["system"], "step": ms["step"],
           "n_bases": int(n[4]), "n_capacitance": int(res.info["factorisations"]) - int(n[4]),
           "n_solves": int(n[2]), "max_gap_mm": 1e3 * float(res.gap.max()),
           "lifted_share": float((res.gap > 0).mean(axis=1).max())}
    row["rest"] = row["step"] - sum(row[k] for k in ("history", "s0", "solves", "capacitance", "update", "bases",
                                                      "system"))
    return row


COLS = (("history", "history"), ("s0", "S0 prod."), ("solves", "solves"), ("capacitance", "capacit."),
        ("update", "C update"), ("bases", "bases"), ("system", "system"), ("rest", "rest"), ("step", "step ms"))


def main(argv=None) -> int:
    from growth import exponent
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[16, 25], help="cells per side (N = cells^2)")
    p.add_argument("--pga", type=float, default=4.0, help="the pulse's peak, m/s^2")
    p.add_argument("--T", type=float, default=1.0, help="the record's length, s (dt = 5 ms)")
    p.add_argument("--soil", default="kernel", choices=("kernel", "synthetic"),
                   help="the kernel-structured soil and the pulse, or growth.py's synthetic soil and sine")
    p.add_argument("--history-tol", type=float, default=None,
                   help="the compressed history's tolerance (default: soil_impedance.hhistory.DEFAULT_TOL)")
    p.add_argument("--define", nargs="*", default=[], help="more -D of the profiling build")
    p.add_argument("--json", type=Path, default=None)
    args = p.parse_args(argv)
    lib = profiling_library(Path(tempfile.mkdtemp(prefix="uplift_profile_")), args.define)
    rows = []
    for cells in args.sizes:
        row = measure(cells, args, lib)
        print(json.dumps(row), file=sys.stderr, flush=True)
        rows.append(row)
    print(f"ms per step by part (process CPU; soil {args.soil}, pulse {args.pga} m/s^2 over {args.T} s at 5 ms)")
    print(f"{'N':>5s} " + " ".join(f"{c[1]:>9s}" for c in COLS)
          + f" {'bases':>5s} {'C facts':>7s} {'solves':>6s} {'lifted':>6s} {'gap mm':>7s} {'storage':>7s} {'D,E st.':>7s}")
    for r in rows:
        print(f"{r['n_nodes']:5d} " + " ".join(f"{r[c[0]]:9.3g}" for c in COLS)
              + f" {r['n_bases']:5d} {r['n_capacitance']:7d} {r['n_solves']:6d} {r['lifted_share']:6.2f}"
              f" {r['max_gap_mm']:7.3g} {r['storage']:7.4f} {r['de_storage']:7.4f}")
    if len(rows) > 1:
        ns = [r["n_nodes"] for r in rows]
        print(f"{'exp.':>5s} " + " ".join(
            f"{'-' if (e := exponent(ns, [r[c[0]] for r in rows])) is None else f'N^{e:.2f}':>9s}" for c in COLS))
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Per-step cost of the recursive-convolution soil (soil_impedance.convolution).

Reactor-size interface: n = 6 + 241 = 247 DOFs, 24 poles (12 conjugate pairs by default; a
random passive model, full-rank residues), dt = 5 ms. Prints a table of microseconds per
call: history() (one GEMV, m n^2 flops, the < 1 ms target), step() (= history + commit:
pole-state update, force, work), instantaneous() at a new dt (coefficients and D0 recomputed), construction
(with the passivity check), and the warping error |K_d − K(iω)|/|K| at 5 and 20 Hz.

    OPENBLAS_NUM_THREADS=1 python benchmarks/soil_step.py [--n 247] [--pairs 12] [--real 0]

``--hmatrix``: the history product dense against compressed (soil_impedance/hhistory.py) on
rafts of the reactor's size (a disk of radius 20 m) meshed with about ``--nodes`` nodes, a
passive model of ``--poles`` real poles whose shapes have the soil kernel's structure
(tests/helpers: ``kernel_passive_model``). Per raft: the compression's time, storage (of
the dense size n^2 per block; the native dense product reads the packed half), largest rank,
the node block's error ||H~ - H||_2 / ||H||_2 (largest over the blocks), the time per product
of numpy (dense GEMV; compressed: three sparse products) and of the native runtime (soil.c's
up_soil_history through benchmarks/soil_history.c, compiled here with cc), and the native
compressed product against the Python one (round-off). Then the growth exponents of each
column (least squares of log t on log N over the rafts from 500 nodes on). ``--busy`` runs a
busy process beside the timings. Runs above 1200 nodes belong under the machine's big-run lock:

    nice flock /tmp/big.lock python benchmarks/soil_step.py --hmatrix --nodes 250 600 1200 2500
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
sys.path.insert(0, str(Path(__file__).resolve().parent))
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


def native_history(blob: bytes, reps: int, folder: Path):
    """(seconds per product, the last product (n,)) of the native runtime's up_soil_history on the
    encoded soil ``blob`` (benchmarks/soil_history.c, compiled into ``folder`` once)."""
    import subprocess
    root = Path(__file__).resolve().parents[1]
    exe = folder / "soil_history"
    if not exe.is_file():
        native = root / "fmus" / "native"
        subprocess.run(["cc", "-std=c99", "-O3", "-ffp-contract=off", f"-I{native / 'include'}",
                        str(root / "benchmarks" / "soil_history.c"),
                        *(str(native / f) for f in ("soil.c", "linalg.c", "resources.c")), "-lm", "-o", str(exe)],
                       check=True)
    path = folder / "model.bin"
    path.write_bytes(blob)
    out = subprocess.run([str(exe), str(path), str(reps)], check=True, capture_output=True, text=True).stdout.split()
    return float(out[0]), np.array([float(v) for v in out[1:]])


def exponent(N, t, lo=500):
    """The growth exponent of t against N: least squares of log t on log N over N >= lo (all
    when fewer than two)."""
    N, t = np.asarray(N, float), np.asarray(t, float)
    big = lo <= N
    keep = big if big.sum() >= 2 else np.ones(N.size, bool)
    return float(np.polyfit(np.log(N[keep]), np.log(t[keep]), 1)[0]) if keep.sum() >= 2 else float("nan")


def bem_model(mesh, poles, freq=5.0):
    """A model of ``poles`` real poles (0.5 to 20 Hz) whose residues are, alternately, the real
    and the imaginary part of the BEM gap impedance of the reactor's soil at ``freq`` Hz on the
    interface ``mesh`` (benchmarks/scaling.py's measurement): the ranks of a real kernel, not a passive
    model (timing and storage only)."""
    from scaling import sweep_one

    from orchestrator.scene import load_scene
    from soil_impedance.rational import RationalModel
    K, _ = sweep_one(load_scene("reactor"), mesh, freq)
    K = 0.5 * (K + K.T)
    p = -2 * np.pi * np.geomspace(0.5, 20.0, poles)
    R = np.array([(K.real if k % 2 == 0 else K.imag) * -p[k] for k in range(poles)])
    return RationalModel(p.astype(complex), R.astype(complex), K.real.copy(), np.zeros_like(K.real))


def bench_hmatrix(nodes, poles, tol, dt=0.005, busy=False, bem=False):
    """The table of ``--hmatrix`` (module docstring); returns its rows."""
    import subprocess
    import tempfile

    from helpers import kernel_passive_model
    from scaling import mesh_for

    from fmus.native_build import encode_resources, soil_records
    from soil_impedance.convolution import history_blocks
    from soil_impedance.hhistory import _norm2

    spin = subprocess.Popen([sys.executable, "-c", "while True: pass"]) if busy else None
    rows = []
    print(f"{'N':>5} {'n':>5} {'compress s':>10} {'storage':>8} {'rank':>5} {'ww error':>9} {'py dense ms':>11} "
          f"{'py hm ms':>9} {'C dense ms':>10} {'C hm ms':>8} {'C/py hm':>8}" + ("  (beside a busy process)" if busy else ""))
    try:
        with tempfile.TemporaryDirectory(prefix="uplift_hbench_") as tmp:
            for target in nodes:
                mesh = mesh_for(target)
                xy = np.asarray(mesh.xy)
                N, n = xy.shape[0], xy.shape[0] + 6
                model = bem_model(mesh, poles) if bem else kernel_passive_model(xy, 0, poles, seed=0)
                dense = RecursiveConvolutionSoil(model, dt, history="dense", checked=True)
                t0 = time.perf_counter()
                hm = RecursiveConvolutionSoil(model, dt, history="hmatrix", xy=xy, history_tol=tol, checked=True)
                t_comp = time.perf_counter() - t0
                st = hm.model.provenance["history"]
                H0, H1 = history_blocks(model), history_blocks(hm.model)
                err = max(_norm2(a[6:, 6:] - b[6:, 6:]) / max(_norm2(a[6:, 6:]), 1e-300) for a, b in zip(H0, H1))
                del H0, H1
                reps = max(5, int(2e8 / (poles * n * n)))
                for soil in (dense, hm):                 # the harness's input: five commits of x_k
                    for k in range(5):
                        x = 1e-3 * ((np.arange(n) * 7919 + k * 104729) % 1000 - 500) / 500.0
                        soil.commit(x, x)

                def hist(soil):
                    soil._h = None
                    soil.history()
                py_d = per_call(lambda s=dense: hist(s), reps) * 1e-3
                py_h = per_call(lambda s=hm: hist(s), reps) * 1e-3
                c_d, _ = native_history(encode_resources(soil_records(model, dt)), reps, Path(tmp))
                c_h, h_c = native_history(encode_resources(soil_records(hm.model, dt, hm.compressed)), reps, Path(tmp))
                h_py = hm.history()
                dev = float(np.abs(h_c - h_py).max() / np.abs(h_py).max())
                rows.append((N, t_comp, st["storage_ratio"], st["max_rank"], err, py_d, py_h, 1e3 * c_d, 1e3 * c_h, dev))
                print(f"{N:>5} {n:>5} {t_comp:>10.1f} {st['storage_ratio']:>8.3f} {st['max_rank']:>5} {err:>9.1e} "
                      f"{py_d:>11.3f} {py_h:>9.3f} {1e3 * c_d:>10.3f} {1e3 * c_h:>8.3f} {dev:>8.1e}", flush=True)
    finally:
        if spin is not None:
            spin.kill()
            spin.wait()
    N = [r[0] for r in rows]
    print("growth exponents (N >= 500): " + ", ".join(
        f"{name} {exponent(N, [r[j] for r in rows]):.2f}" for name, j in
        (("py dense", 5), ("py hm", 6), ("C dense", 7), ("C hm", 8), ("storage x N^2", 2))
        if name != "storage x N^2") + f", storage {exponent(N, [r[2] * r[0] ** 2 for r in rows]):.2f}")
    return rows


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=247)
    ap.add_argument("--pairs", type=int, default=12)
    ap.add_argument("--real", type=int, default=0)
    ap.add_argument("--hmatrix", action="store_true", help="dense against compressed history (module docstring)")
    ap.add_argument("--nodes", type=int, nargs="+", default=[250, 600, 1200])
    ap.add_argument("--poles", type=int, default=8)
    ap.add_argument("--tol", type=float, default=1e-4)
    ap.add_argument("--busy", action="store_true", help="a busy process beside the timings")
    ap.add_argument("--bem", action="store_true", help="residues from the BEM gap impedance at 5 Hz (bem_model)")
    a = ap.parse_args()
    if a.hmatrix:
        bench_hmatrix(a.nodes, a.poles, a.tol, busy=a.busy, bem=a.bem)
        return
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

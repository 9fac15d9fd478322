"""Benchmark: how the soil's cost grows with the raft, and whether a compressed realisation pays.

Rafts of the reactor's soil (layered rock, radius 20 m) meshed at three element sizes: about
240, 600 and 1200 interface nodes (n = 6 + N DOFs of the gap model). Per raft:

  sweep s/freq   one frequency (5 Hz) of the BEM sweep (the gap output; the Green's tables, the
                 flexibility, its LU, the reduction), and x 101 the reactor's table
  history/step   the bare kernel's product per step at that size, m = 8 poles: numpy's GEMV
                 over H (n, m n) plus D0 x and E xdot (the native runtime reads half of H's
                 bytes, its symmetric blocks packed, at every size)
  H-matrix       the node-node block K_ww of the impedance at 5 Hz (the residues of a fit have
                 the structure of K: the same kernel at a complex frequency) clustered by
                 recursive bisection of the nodes (leaves <= 32 nodes), blocks admissible when
                 their clusters' distance exceeds their larger diameter (eta = 1); an admissible
                 block is kept at the rank whose discarded singular values are below eps times
                 ||K_ww||_2 (eps = 1e-3 and 1e-4: the fit tolerance is 6e-2 relative);
                 storage ratio = (dense blocks + rank x (rows + cols)) / N^2 = the history
                 product's cost ratio of a realisation with those blocks, and the error of the
                 product ||K - K_H||_2 / ||K||_2 measured

On the reactor's own fit (241 nodes, 8 poles) two more measurements:

  residues       the same H-matrix compression of each residue R_k (w block)
  balanced       balanced truncation of the whole realisation (state (m n)): Hankel singular
                 values from the Gramians (closed forms for the diagonal pole blocks), the order
                 r whose H-infinity bound 2 sum_{i > r} sigma_i stays below eps times the peak
                 norm of the dynamic part; a balanced realisation is dense (A_r r x r, B_r, C_r):
                 its history cost per step r^2 + 2 r n against m n^2

Prints one table; the verdict (does a compressed realisation cut the history cost by >= 2x
within the fit tolerance?) follows from its last columns. Run with OPENBLAS_NUM_THREADS=1:

    python benchmarks/scaling.py [--nodes 240 600 1200] [--freq 5]
"""
from __future__ import annotations

import os

os.environ["OPENBLAS_NUM_THREADS"] = "1"
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import time

import numpy as np

RADIUS = 20.0
POLES = 8
EPS = (1e-3, 1e-4)
LEAF = 32


def mesh_for(nodes: int):
    """The reactor's raft (a disk of radius 20 m) meshed with about ``nodes`` interface nodes."""
    from soil_impedance.mesh import circle_mesh
    h = float(np.sqrt(np.pi * RADIUS ** 2 / nodes))
    for _ in range(8):                                     # adjust h until the mesh has about ``nodes``
        mesh = circle_mesh(RADIUS, h)
        if abs(mesh.n - nodes) <= 0.05 * nodes:
            break
        h *= np.sqrt(mesh.n / nodes)
    return mesh


def sweep_one(scene, mesh, freq):
    """(K_gap (6+N, 6+N) at freq, seconds) of one frequency of the BEM sweep of ``mesh`` on the
    scene's soil."""
    from soil_impedance.sweep import impedance_sweep
    t0 = time.perf_counter()
    table = impedance_sweep(scene.profile, mesh, [freq], contact=scene.contact_kind, outputs=("gap",))
    return table["gap"].matrices[0], time.perf_counter() - t0


def gemv_per_step(n: int, m: int = POLES, steps: int = 50) -> float:
    """Seconds per step of the bare kernel at n DOFs (H (n, m n) g + D0 x + E xdot)."""
    rng = np.random.default_rng(0)
    H = rng.standard_normal((n, m * n))
    D0, E = rng.standard_normal((n, n)), rng.standard_normal((n, n))
    g, x = rng.standard_normal(m * n), rng.standard_normal(n)
    out = np.empty(n)
    best = np.inf
    for _ in range(3):
        t0 = time.perf_counter()
        for _ in range(steps):
            np.matmul(H, g, out=out)
            out += D0 @ x
            out += E @ x
        best = min(best, (time.perf_counter() - t0) / steps)
    return best


def clusters(xy, idx, leaf=LEAF):
    """Binary cluster tree by bisection along the longer side: (indices, children)
    (soil_impedance.hhistory.clusters, the compressed history's)."""
    from soil_impedance.hhistory import clusters as tree
    return tree(xy, idx, leaf)


def _box(xy, idx):
    from soil_impedance.hhistory import box
    return box(xy, idx)


def hmatrix(K, xy, tol):
    """(storage / N^2, ||K - K_H||_2 / ||K||_2) of the H-matrix of K (N, N) on nodes xy (N, 2):
    admissible blocks truncated at singular values below tol ||K||_2."""
    N = K.shape[0]
    norm = np.linalg.norm(K, 2)
    approx = np.zeros_like(K)
    store = 0

    def walk(a, b):
        nonlocal store
        (ia, ca), (ib, cb) = a, b
        (xa, da), (xb, db) = _box(xy, ia), _box(xy, ib)
        dist = np.linalg.norm(xa - xb) - 0.5 * (da + db)
        block = K[np.ix_(ia, ib)]
        if dist > max(da, db) and min(ia.size, ib.size) > 4:              # admissible: low rank
            U, s, Vt = np.linalg.svd(block, full_matrices=False)
            r = int(np.sum(s > tol * norm))
            approx[np.ix_(ia, ib)] = (U[:, :r] * s[:r]) @ Vt[:r]
            store += r * (ia.size + ib.size)
        elif not ca or not cb:                                              # a leaf: dense
            approx[np.ix_(ia, ib)] = block
            store += block.size
        else:
            for x in ca:
                for y in cb:
                    walk(x, y)

    root = clusters(xy, np.arange(N))
    walk(root, root)
    return store / N ** 2, float(np.linalg.norm(K - approx, 2) / norm)


def balanced_order(model, tol):
    """(r, m n) of balanced truncation of the dynamic part sum_k R_k / (s - p_k) (real poles):
    the least r with 2 sum_{i > r} sigma_i <= tol max_w ||K_dyn(iw)||_2."""
    p = np.asarray(model.poles)
    if np.any(np.abs(p.imag) > 0):
        return None, None
    p = p.real
    R = np.asarray(model.residues).real
    m, n = R.shape[0], R.shape[1]
    G = -1.0 / (p[:, None] + p[None, :])                                 # P = kron(G, I)
    C = np.hstack(list(R))                                                # (n, m n)
    Q = -(C.T @ C) / np.kron(p[:, None] + p[None, :], np.ones((n, n)))   # A^T Q + Q A + C^T C = 0
    Lp = np.linalg.cholesky(np.kron(G, np.eye(n)) + 1e-300 * np.eye(m * n))
    hsv = np.sqrt(np.clip(np.linalg.eigvalsh(Lp.T @ Q @ Lp), 0, None))[::-1]
    w = np.geomspace(0.1, 1e3, 200) * 2 * np.pi
    peak = max(np.linalg.norm(np.tensordot(1.0 / (1j * wi - p), R, 1), 2) for wi in w)
    tail = 2 * np.cumsum(hsv[::-1])[::-1]                                  # tail[r] = 2 sum_{i >= r} sigma_i
    ok = np.flatnonzero(np.append(tail, 0.0) <= tol * peak)
    return int(ok[0]), m * n


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--nodes", type=int, nargs="+", default=[240, 600, 1200])
    ap.add_argument("--freq", type=float, default=5.0)
    args = ap.parse_args(argv)
    print(f"{'N':>5} {'n':>5} {'sweep s/freq':>12} {'x101 s':>8} {'GEMV ms/step':>13} {'/ N=first':>9} "
          + " ".join(f"{'H ' + format(e, 'g') + ' store':>14} {'err':>8}" for e in EPS))
    from orchestrator.scene import load_scene
    reactor = load_scene("reactor")
    first = None
    for nodes in args.nodes:
        mesh = mesh_for(nodes)
        N = mesh.n
        K, sweep_s = sweep_one(reactor, mesh, args.freq)
        step = gemv_per_step(6 + N)
        first = first or step
        Kww = np.real(K[6:, 6:])
        cols = []
        for e in EPS:
            ratio, err = hmatrix(Kww, np.asarray(mesh.xy), e)
            cols.append(f"{ratio:>14.3f} {err:>8.1e}")
        print(f"{N:>5} {6 + N:>5} {sweep_s:>12.2f} {101 * sweep_s:>8.0f} {1e3 * step:>13.3f} {step / first:>9.1f} "
              + " ".join(cols), flush=True)
    from orchestrator.impedance import scene_fit
    from orchestrator.settings import default_cache_dir
    sc = reactor
    model = scene_fit(sc, cache_dir=default_cache_dir()).model
    xy = sc.mesh.xy
    print(f"\nthe reactor's fit ({model.n} DOFs, {model.poles.size} poles): H-matrix of each residue's w block")
    for e in EPS:
        res = [hmatrix(np.real(Rk[6:, 6:]), xy, e) for Rk in model.residues]
        print(f"  eps {e:g}: storage ratio {min(r for r, _ in res):.3f} .. {max(r for r, _ in res):.3f}, "
              f"error up to {max(x for _, x in res):.1e}")
    n = model.n
    for e in EPS:
        r, states = balanced_order(model, e)
        if r is None:
            print("  balanced truncation: complex poles, not measured")
            continue
        print(f"  balanced truncation at eps {e:g}: order {r} of {states}; history cost r^2 + 2 r n = "
              f"{r * r + 2 * r * n} vs m n^2 = {POLES * n * n} ({(r * r + 2 * r * n) / (POLES * n * n):.2f}x)")


if __name__ == "__main__":
    main()

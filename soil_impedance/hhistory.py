"""The recursive convolution's history product through hierarchical matrices.

The history of the trapezoidal recursive convolution (soil_impedance/convolution.py) is
h = Σ_b H_b g_b: one real symmetric (n, n) block per real pole (R_k) and two per conjugate pair
(2 Re R_k and −2 Im R_k), g_b the block's part of the stacked pole input, n = 6 + N. Dense, one
product is m n² flops and as many bytes read (m = the blocks' count): 10 ms a step at 1200
nodes. The residues have the structure of the soil's kernel at complex frequencies, so the
parts of H_b that couple two well-separated groups of nodes are numerically of low rank.

``compress_history`` builds, over the interface nodes' coordinates, one cluster tree (recursive
bisection of the nodes' bounding box along its longer side, leaves of at most ``leaf`` nodes)
and one block partition shared by every H_b:

- the 6 rigid DOFs are a dense border: the (6, 6) block and the (6, N) block of the raft rows;
- the (N, N) node block is split recursively; a pair of clusters is *admissible* when the
  distance between their bounding boxes exceeds ``eta`` times the larger diagonal (and both
  have more than 4 nodes); admissible blocks are held as U Vᵀ, the others (leaves) dense.

A block that is exactly zero (a residue or a matrix held node by node: springs, dashpots) is
held as rank 0 whether admissible or not: no values, no work, the product unchanged.
Per H_b an admissible block keeps the singular values above ``tol`` max_i |H_b,ii|, the largest
diagonal entry of H_b's node block (``_scale``: a node's own stiffness in that block; U carries
the singular values, V is orthonormal) and is held dense when the factors would be larger. Not
the whole H_b, whose rigid rows can be orders of magnitude larger, and not the node block's
2-norm either: a gap is a local quantity, the difference of the raft's motion and the soil's at
one node, and moves with the error of the force at a node relative to that node's own
stiffness; the 2-norm of a block with a long-range kernel is its collective mode, all nodes
pushed together, many times its diagonal (for the 1 Hz oscillator of the tests' kernel terms on
the mat: 49x at 625 nodes, 69x at 1156, 105x at 2500), so a truncation relative to it coarsened
with N and let that one block move max uplift by 9.4e-3 at 625 nodes at tol 1e-4
(DEFAULT_TOL's comment). The upper blocks only
are stored: a block off the diagonal serves for its mirror through its transpose, so the
compressed H̃_b is exactly symmetric, as H_b.

The compressed history is the history of another rational model, M̃ = (poles, R̃_k, D, E) with
R̃_k assembled from the H̃_b (``CompressedHistory.model``): the soil runs M̃ exactly (its D0, its
history gains and its history all from R̃_k), and M̃'s passivity is tested like any fit's
(``soil_impedance.passivity.require_passive`` on M̃, on the same grid and exact test): the
compression is a perturbation of the fitted residues, ||R̃_k − R_k||₂ ≲ tol ||R_k||₂ summed over
the admissible blocks (``stats``: the measured relative error of each block), against a fit
tolerance of 1e-2; the re-test, not a bound, is what keeps passivity.

The model's D and E (symmetric, as a fit makes them) are compressed over the same partition by
the same rule at INSTANT_TOL_FACTOR x tol (``compress_history(instant=(D, E))``, held in
``CompressedHistory.instant``); M̃ then carries D̃ and Ẽ assembled from them, re-tested with the
residues. Ẽ's node diagonal is raised by a proved bound of its compression error (``_e_shift``,
settings ``e_shift``), so that λ_min(Ẽ) ≥ λ_min(E): a fit's E may be singular to round-off, and
an unraised Ẽ is then indefinite, which the passivity test refuses. The native stepper's other per-step products, K0C x = (D0 + c1 E) x and E v with
D0 = D + Σ_k b_k R_k, then run over the blocks too: a far block of K0C is the terms' factors
stacked with the step size's coefficients, exactly (fmus/native/stepper.c, ``k0c_blocks``).

The product holds in ``CompressedHistory``: ``matvec`` (numpy/scipy: three sparse products
over the stacked input, the reference) and ``records`` (the arrays the native runtime reads,
fmus/native/soil.c: the same blocks, dense near blocks and U Vᵀ far blocks in the permuted
order of the cluster tree).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: history product default: held dense below this many interface nodes, compressed from it on:
#: the crossover measured in the native runtime (benchmarks/soil_step.py --hmatrix, 8 poles):
#: 401 nodes 1.9x slower than dense, 497 nodes 1.7x slower (no admissible block yet), 593 nodes
#: even (1.25 against 1.39 ms) to 2x faster, 1201 nodes 1.7 to 2.9x, 2501 nodes 6.6x (docs/native.md)
HMATRIX_MIN_NODES = 600
#: truncation of the admissible blocks, relative to the largest diagonal entry of their history block's node
#: part (``_scale``). Chosen on the mat under a 20 m/s^2 pulse (tests/fmu/test_native_k0c.py's case, 200 steps,
#: history, D and E compressed, both runs native), max uplift's relative error against the dense history at
#: 625 / 1156 / 2500 nodes, and the history's storage (of n^2 per block):
#:   1e-4  4.1e-4 / 2.7e-5 / 1.6e-3    0.115 / 0.073 / 0.0445
#:   5e-5  1.0e-4 / 2.6e-4 / 2.3e-4    0.118 / 0.075 / 0.0465   (the gap histories within 1.0e-3 of the largest gap)
#:   3e-5  1.5e-4 / 1.2e-4 / 2.4e-5    0.120 / 0.077 / 0.0478
#:   2e-4  5.3e-4 / 1.5e-4 / 8.1e-4    0.112 / 0.070 / 0.0426   (the gaps 9.8e-4 / 2.5e-3 / 4.4e-3)
#: max uplift's error on one case is not monotone in tol (2e-4 passes where 1e-4 does not), the gap histories'
#: nearly is; 5e-5 is the largest tolerance from which every one measured keeps max uplift within 1e-3 at the
#: three sizes (with 3.8x to spare), for 2-5 % more storage than 1e-4. The rule before, 1e-4 relative to
#: the node block's 2-norm: 8.2e-3 / 4.2e-3 / 7.9e-2 (the gaps 1.8e-2 / 6.3e-2 / 2.1e-1 of the largest), storage
#: 0.107 / 0.062 / 0.036; at 1e-5 still 5.4e-4 / 2.9e-4 / 2.4e-3 (docs/native.md)
DEFAULT_TOL = 5e-5
#: truncation of D's and E's admissible blocks (``compress_history(instant=...)``), relative to the
#: history's: the instantaneous stiffness moves the gaps more than a residue does. On the mat at
#: 625 nodes under a lifting pulse (tests/fmu/test_native_k0c.py's run, 0.2 mm of uplift), D and E
#: at 1e-4 moved max uplift by 6.7e-3 relative, at 1e-5 by 1.5e-4 (the storage 0.282 -> 0.287 of n^2), both
#: relative to the node block's 2-norm (the rule before, 8.8x D's diagonal there); relative to the diagonal, with
#: the history at 1e-4, D and E at 1e-4 put max uplift 5.0e-4 from dense, at 1e-5 4.1e-4 (storage 0.173 -> 0.192)
INSTANT_TOL_FACTOR = 0.1
#: the largest cluster held as a leaf, nodes
DEFAULT_LEAF = 32
#: admissibility: distance > ETA x the larger cluster diagonal
DEFAULT_ETA = 1.0
#: the border: the raft's rigid DOFs ahead of the nodes' w DOFs
BORDER = 6


# ---- the cluster tree (as benchmarks/scaling.py measured it) -------------------------------------
def clusters(xy, idx, leaf=DEFAULT_LEAF):
    """Binary cluster tree of the nodes ``idx`` (indices into xy (N, 2), m) by bisection of
    their bounding box along its longer side (stable order: ties keep the index order):
    a tree (indices, children), children () for a leaf."""
    if idx.size <= leaf:
        return (idx, ())
    p = xy[idx]
    axis = int(np.argmax(p.max(axis=0) - p.min(axis=0)))
    order = idx[np.argsort(p[:, axis], kind="stable")]
    half = order.size // 2
    return (idx, (clusters(xy, order[:half], leaf), clusters(xy, order[half:], leaf)))


def box(xy, idx):
    """(centre (2,), diagonal) of the bounding box of the nodes idx, m."""
    p = xy[idx]
    lo, hi = p.min(axis=0), p.max(axis=0)
    return 0.5 * (lo + hi), float(np.linalg.norm(hi - lo))


def partition(xy, leaf=DEFAULT_LEAF, eta=DEFAULT_ETA):
    """(perm (N,), blocks) of nodes xy (N, 2): perm lists the nodes in the order of the tree's
    leaves (each cluster a contiguous range of it), blocks the upper blocks of the (N, N) node
    block as (row start, rows, column start, columns, admissible) over that order, row start
    <= column start; a block with row start == column start is on the diagonal."""
    xy = np.asarray(xy, float)
    root = clusters(xy, np.arange(xy.shape[0]), leaf)
    perm, start = [], {}

    def number(c):
        idx, kids = c
        start[id(c)] = sum(len(p) for p in perm)
        if not kids:
            perm.append(idx)
        for k in kids:
            number(k)
    number(root)
    blocks = []

    def off(a, b):
        (ia, ka), (ib, kb) = a, b
        (xa, da), (xb, db) = box(xy, ia), box(xy, ib)
        dist = np.linalg.norm(xa - xb) - 0.5 * (da + db)
        if dist > eta * max(da, db) and min(ia.size, ib.size) > 4:
            blocks.append((start[id(a)], ia.size, start[id(b)], ib.size, True))
        elif not ka or not kb:
            blocks.append((start[id(a)], ia.size, start[id(b)], ib.size, False))
        else:
            for x in ka:
                for y in kb:
                    off(x, y)

    def diag(a):
        idx, kids = a
        if not kids:
            blocks.append((start[id(a)], idx.size, start[id(a)], idx.size, False))
            return
        diag(kids[0])
        off(kids[0], kids[1])
        diag(kids[1])
    diag(root)
    return np.concatenate(perm).astype(np.int64), blocks


def _scale(A) -> float:
    """The truncation's scale of a symmetric node block A (n, n): its largest |diagonal entry| (a
    node's own stiffness in it, what a gap sees), or its 2-norm when the diagonal is all zero (a
    block of couplings only). max |A_ii| <= ||A||₂, so the truncation is never coarser than by the
    2-norm."""
    d = float(np.abs(np.diagonal(A)).max(initial=0.0))
    return d if d > 0 else _norm2(A)


def _norm2(A) -> float:
    """||A||₂ of a symmetric (n, n) A: the largest |eigenvalue| by Lanczos (exact for small n)."""
    if not np.any(A):
        return 0.0
    if A.shape[0] <= 300:
        return float(np.abs(np.linalg.eigvalsh(A)).max(initial=0.0))
    from scipy.sparse.linalg import eigsh
    v0 = np.random.default_rng(0).standard_normal(A.shape[0])       # fixed: the same ranks every time
    return float(abs(eigsh(A, k=1, which="LM", v0=v0, tol=1e-6, return_eigenvectors=False)[0]))


@dataclass(frozen=True, eq=False)
class CompressedHistory:
    """The history blocks H_b (nh, n, n) as hierarchical matrices over one partition.

    n : int                  DOFs (6 + N)
    perm : (n,) int64        DOF at each position of the permuted order (the border first, then
                             the nodes' w DOFs in the cluster tree's leaf order)
    blocks : (nblk, 4) int64 (row start, rows, column start, columns) over the permuted order,
                             upper blocks only; off the diagonal a block serves for its mirror
    ranks : (nh, nblk) int64 -1: held dense (rows x columns, row-major); r >= 0: U (r, rows)
                             then V (r, columns), the block = Uᵀ V, both row-major
    data : (total,) float    the blocks' values, history block by history block, block by block
    settings : dict          tol, leaf, eta and the measured storage and errors
    instant : CompressedHistory or None
                             the model's D and E (nh = 2) over the same partition and tolerance,
                             when they were compressed too (``compress_history(instant=...)``)
    """
    n: int
    perm: np.ndarray
    blocks: np.ndarray
    ranks: np.ndarray
    data: np.ndarray
    settings: dict = field(default_factory=dict)
    instant: CompressedHistory | None = None

    @property
    def nh(self) -> int:
        return self.ranks.shape[0]

    def offsets(self) -> np.ndarray:
        """(nh, nblk) start of each block's values in ``data``."""
        rows, cols = self.blocks[:, 1], self.blocks[:, 3]
        size = np.where(self.ranks < 0, rows * cols, self.ranks * (rows + cols)).reshape(-1)
        start = np.concatenate([[0], np.cumsum(size)[:-1]]) if size.size else size
        return start.astype(np.int64).reshape(self.ranks.shape)

    def pieces(self, b: int):
        """Yield (r0, nr, c0, nc, A, U, V) of history block b: A the dense block or None, U (r, nr)
        and V (r, nc) the factors of a low-rank one."""
        off = self.offsets()[b]
        for (r0, nr, c0, nc), r, o in zip(self.blocks, self.ranks[b], off):
            if r < 0:
                yield r0, nr, c0, nc, self.data[o:o + nr * nc].reshape(nr, nc), None, None
            else:
                U = self.data[o:o + r * nr].reshape(r, nr)
                V = self.data[o + r * nr:o + r * (nr + nc)].reshape(r, nc)
                yield r0, nr, c0, nc, None, U, V

    def dense(self, b: int) -> np.ndarray:
        """H̃_b (n, n) assembled, exactly symmetric."""
        Hp = np.zeros((self.n, self.n))
        for r0, nr, c0, nc, A, U, V in self.pieces(b):
            if A is None:
                A = U.T @ V
            Hp[r0:r0 + nr, c0:c0 + nc] = A
            if r0 != c0:
                Hp[c0:c0 + nc, r0:r0 + nr] = A.T
        out = np.empty_like(Hp)
        out[np.ix_(self.perm, self.perm)] = Hp
        return out

    @property
    def stored(self) -> int:
        """Values held (the product reads each once)."""
        return int(self.data.size)

    def operator(self, columns):
        """The product as scipy sparse matrices (near (n, L), U (n, T), V (T, L)): h = near g +
        U (V g) for g the stacked input (L,); ``columns`` (nh, n): g's index of (block, DOF)."""
        from scipy.sparse import csr_matrix
        n, perm = self.n, self.perm
        L = int(columns.max()) + 1 if columns.size else 0
        near_r, near_c, near_v = [], [], []
        u_r, u_c, u_v, v_r, v_c, v_v = [], [], [], [], [], []
        t = 0
        for b in range(self.nh):
            col = columns[b]
            for r0, nr, c0, nc, A, U, V in self.pieces(b):
                rows, cols = perm[r0:r0 + nr], perm[c0:c0 + nc]
                mirror = r0 != c0
                if A is not None:
                    near_r.append(np.repeat(rows, nc))
                    near_c.append(np.tile(col[cols], nr))
                    near_v.append(A.reshape(-1))
                    if mirror:
                        near_r.append(np.tile(cols, nr))
                        near_c.append(np.repeat(col[rows], nc))
                        near_v.append(A.reshape(-1))
                    continue
                r = U.shape[0]
                for (P, tgt), (Q, src) in (((U, rows), (V, cols)),) + ((((V, cols), (U, rows)),) if mirror else ()):
                    ks = t + np.arange(r)
                    v_r.append(np.repeat(ks, src.size))
                    v_c.append(np.tile(col[src], r))
                    v_v.append(Q.reshape(-1))
                    u_r.append(np.tile(tgt, r))
                    u_c.append(np.repeat(ks, tgt.size))
                    u_v.append(P.reshape(-1))
                    t += r
        cat = lambda parts, dt=float: np.concatenate(parts).astype(dt) if parts else np.zeros(0, dt)
        near = csr_matrix((cat(near_v), (cat(near_r, np.int64), cat(near_c, np.int64))), shape=(n, L))
        Um = csr_matrix((cat(u_v), (cat(u_r, np.int64), cat(u_c, np.int64))), shape=(n, t))
        Vm = csr_matrix((cat(v_v), (cat(v_r, np.int64), cat(v_c, np.int64))), shape=(t, L))
        return near, Um, Vm

    def records(self) -> dict:
        """The resource records of the native runtime (fmus/native/soil.c, README.md there)."""
        out = {"hm_perm": self.perm.astype(np.int64), "hm_blocks": self.blocks.astype(np.int64).reshape(-1, 4),
               "hm_ranks": self.ranks.astype(np.int64).reshape(self.nh, -1), "hm_data": self.data,
               "hm_tol": float(self.settings.get("tol", DEFAULT_TOL))}
        if self.instant is not None:
            out.update(hm_de_ranks=self.instant.ranks.astype(np.int64).reshape(2, -1), hm_de_data=self.instant.data)
        return out


def _compress_blocks(H, perm, blocks, tol, shift=None):
    """(ranks (nh, nblk), data, errors) of the symmetric blocks H (nh, n, n) over the partition
    (perm, blocks) of ``compress_history`` at the relative tolerance tol; ``shift`` (nh,) or None:
    added to each block's node diagonal after its scale is taken (the same ranks, the diagonal
    blocks are dense)."""
    nh = H.shape[0]
    ranks = np.full((nh, len(blocks)), -1, np.int64)
    data, errors = [], []
    for b in range(nh):
        Hb = H[b][np.ix_(perm, perm)]
        Hb = 0.5 * (Hb + Hb.T)
        scale = _scale(Hb[BORDER:, BORDER:])
        if shift is not None and shift[b]:
            Hb[np.arange(BORDER, Hb.shape[0]), np.arange(BORDER, Hb.shape[0])] += shift[b]
        for j, (r0, nr, c0, nc, adm) in enumerate(blocks):
            A = Hb[r0:r0 + nr, c0:c0 + nc]
            if not np.any(A):                            # exactly zero (springs, dashpots: node by node)
                ranks[b, j] = 0
                continue
            if adm:
                W, s, Vt = np.linalg.svd(A, full_matrices=False)
                r = int(np.sum(s > tol * scale))
                if r * (nr + nc) < nr * nc:
                    ranks[b, j] = r
                    data += [np.ascontiguousarray((W[:, :r] * s[:r]).T).reshape(-1),
                             np.ascontiguousarray(Vt[:r]).reshape(-1)]
                    errors.append(float(s[r] / scale) if r < s.size and scale > 0 else 0.0)
                    continue
            data.append(np.ascontiguousarray(A).reshape(-1))
    return ranks, (np.concatenate(data) if data else np.zeros(0)), errors


def _e_shift(Et, E) -> float:
    """A proved bound t ≥ ‖Ẽ − E‖₂ of the compressed E's error (its node block: the border is held
    exactly), or 0 when Ẽ = E: Ẽ + t I_nodes − E ⪰ 0, so λ_min of the raised Ẽ is at least E's own. A
    fit's E can be singular to round-off (the enforcement leaves a passing fit's E as it is), and a
    compression error of 1e-5 then makes Ẽ indefinite (a 2506-DOF mat fit: λ_min(Ẽ) = −5.7e-9 of
    the scaled model, refused by the passivity guard); the raise is a dashpot of the compression's
    own size, which only adds dissipation."""
    from .passivity import _norm_bound
    diff = Et[BORDER:, BORDER:] - 0.5 * (E[BORDER:, BORDER:] + E[BORDER:, BORDER:].T)
    return float(_norm_bound(diff)) if np.any(diff) else 0.0


def _measured(hist: CompressedHistory, blocks, errors) -> CompressedHistory:
    """``hist`` with its storage, its partition's counts and its largest discarded value in settings."""
    nh, n, ranks = hist.nh, hist.n, hist.ranks
    far = ranks >= 0
    hist.settings.update(storage_ratio=hist.stored / max(nh * n * n, 1),
                         packed_ratio=hist.stored / max(nh * n * (n + 1) / 2, 1),
                         blocks=len(blocks), far_blocks=int(sum(b[4] for b in blocks)),
                         max_rank=int(ranks[far].max(initial=0)), max_block_error=max(errors, default=0.0))
    return hist


def compress_history(H, xy, tol: float = DEFAULT_TOL, leaf: int = DEFAULT_LEAF,
                     eta: float = DEFAULT_ETA, instant=None) -> CompressedHistory:
    """The hierarchical form of the symmetric history blocks H (nh, n, n), n = 6 + N, over the
    interface nodes xy (N, 2), m (module docstring). The upper blocks are compressed and the
    lower ones taken as their transposes: H_b is symmetrised first ((H + Hᵀ) / 2, a no-op on a
    fitted model's residues).

    instant : (D, E), each (n, n) symmetric, or None
        the model's instantaneous matrices, compressed by the same rule over the same partition
        at INSTANT_TOL_FACTOR x tol (``CompressedHistory.instant``): the stepper's per-step
        products with D0 = D + Σ b_k R_k and E then run over the blocks (fmus/native/stepper.c),
        as the history's."""
    H = np.asarray(H, float)
    xy = np.asarray(xy, float)
    n = H.shape[1]
    N = n - BORDER
    if xy.shape != (N, 2):
        raise ValueError(f"xy has shape {xy.shape}: the history blocks have {n} DOFs, (6 + N) for N = {N} nodes "
                         "of (x, y)")
    if not (0 < tol < 1):
        raise ValueError(f"history tolerance {tol!r} must lie in (0, 1)")
    node_perm, node_blocks = partition(xy, leaf, eta)
    perm = np.concatenate([np.arange(BORDER), BORDER + node_perm]).astype(np.int64)
    blocks = [(0, BORDER, 0, BORDER, False), (0, BORDER, BORDER, N, False)] + \
        [(BORDER + r0, nr, BORDER + c0, nc, adm) for r0, nr, c0, nc, adm in node_blocks]
    blk = np.array([b[:4] for b in blocks], np.int64)
    settings = {"tol": float(tol), "leaf": int(leaf), "eta": float(eta)}
    de = None
    if instant is not None:
        DE = np.asarray(instant, float)
        if DE.shape != (2, n, n):
            raise ValueError(f"instant has shape {DE.shape}: give (D, E), each ({n}, {n})")
        tol_de = INSTANT_TOL_FACTOR * tol
        ranks, data, errors = _compress_blocks(DE, perm, blocks, tol_de)
        de = CompressedHistory(n, perm, blk, ranks, data, dict(settings, tol=tol_de))
        shift = _e_shift(de.dense(1), DE[1])
        if shift > 0:                                # the same blocks, E's node diagonal raised by the shift
            ranks, data, errors = _compress_blocks(DE, perm, blocks, tol_de, shift=(0.0, shift))
            de = CompressedHistory(n, perm, blk, ranks, data, dict(settings, tol=tol_de))
        de = _measured(de, blocks, errors)
        de.settings["e_shift"] = shift
    ranks, data, errors = _compress_blocks(H, perm, blocks, tol)
    return _measured(CompressedHistory(n, perm, blk, ranks, data, settings, de), blocks, errors)

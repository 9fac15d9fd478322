"""Fast solve of the grid BEM: F(ω)⁻¹ applied by FFT products and preconditioned GMRES.

On a grid mesh (circle or rectangle, ``bem._grid``) the flexibility's 3×3 block F_ij depends
only on the integer offset between nodes i and j (``SurfaceBem.offset_blocks``): F is the
restriction to the mesh's nodes of a two-level block-Toeplitz operator on the grid's bounding
box (nx × ny nodes; a circle grid is a subset of the box). Embedded in a P × Q periodic grid
(P >= 2 nx - 1, Q >= 2 ny - 1) that operator is a block circulant C, so that

    F x = R C Rᵀ x,     C = 𝓕⁻¹ diag(Ĉ) 𝓕,

R the restriction to the mesh's nodes, 𝓕 the two-dimensional FFT and Ĉ the 3×3 symbols of C
(one per Fourier mode): a product with F costs O(N log N) instead of O(N²), and F is never
formed (memory O(N) per vector).

Solve: GMRES (F is complex symmetric, not Hermitian) preconditioned on the right by
M⁻¹ = R C⁻¹ Rᵀ, the inverse of the same circulant restricted to the nodes (one more pair of
FFTs; the symbols inverted mode by mode). It leaves only the truncation of the box to the mesh
to be iterated on. Measured on the reactor's soil at 20 Hz, one vertical load, relative residual
1e-8: 14 GMRES steps on 625- and 1225-node squares, 10 on a 1200-node circle, against 43 to 51
unpreconditioned and 26 to 39 with block-Jacobi over 2x2 to 8x8 node clusters; in the sweep at
1e-4, about 5 steps per batch at 0 Hz and 10 to 15 at 25 Hz, from 250 to 2500 nodes. The right-hand sides are solved in batches (``batch_size``): the FFTs, the
Gram-Schmidt and the Givens rotations act on all the columns of a batch at once, each column with
its own Krylov space; a batch stops when every column's residual meets the tolerance. Every
column is then checked with its true residual ``||b - F x|| <= tol ||b||`` (2-norm), restarted if
not, and a column that does not converge raises ``FastSolveError``.

Symmetry (an exact addition, not an approximation): the gap table needs F⁻¹ for a vertical
unit load at every node. When the mesh is mapped onto itself by reflections of the plane about
the raft centre or its quarter turns (x -> -x, y -> -y, and x <-> y for square cells: up to the
8 maps of a square, ``mesh_symmetries``), the vertical response to a load at node g(j) is the
response to the load at j with the nodes permuted by g (the soil is isotropic in the plane and a vertical load has no
direction there), so only one load per orbit is solved: about N/8 of them on a square or a
circle grid.

The cost per frequency is O(N log N) per right-hand side times the (N-independent) iterations,
for the N/8 + 6 right-hand sides: O(N² log N) against the dense LU's O(N³).
"""
from __future__ import annotations

import numpy as np
import scipy.fft

from uplift_common.errors import ComputationError

from .bem import _grid
# the solver choice and its checks live in a light module (what a scene or a cache key reads of the
# solver without loading this one); re-exported here
from .solvers import AUTO_NODES, DEFAULT_TOL, SOLVERS, TOL_RANGE, SolverError, check_solver, resolve_solver  # noqa: F401

#: Arnoldi steps before a restart of GMRES, and restarts before giving up
RESTART = 40
MAX_RESTARTS = 8
#: bytes of Krylov basis per batch of right-hand sides (the batch size follows from it)
BASIS_BYTES = 160 * 2 ** 20


class FastSolveError(ComputationError):
    """The fast solver's GMRES did not reach its tolerance (exit 1; the dense solver always can)."""


def batch_size(n: int) -> int:
    """Right-hand sides per batch: the Krylov basis (RESTART + 1 vectors of 3n complex per
    column) within ``BASIS_BYTES``, between 8 and 256."""
    return int(min(256, max(8, BASIS_BYTES // ((RESTART + 1) * 3 * n * 16))))


def fast_memory(n: int, nx: int, ny: int, rhs: int | None = None) -> int:
    """Peak bytes of the fast solver's work per frequency (no dense F): the symbols and their
    inverses (2 × 9 P Q complex), a batch's Krylov basis, its FFT grids (three of m × 3 P Q
    complex) and vectors, the (6 + N)² gap matrix it assembles (in place, ``gap_and_rigid``), and the
    solutions of ``rhs`` right-hand sides (6 + one load per symmetry orbit; None: n/8 + 2 √n + 6,
    a centred square or circle grid's) at four frequencies (the three previous ones of its chain
    are the sweep's first guesses, ``sweep.first_guess``)."""
    P, Q = scipy.fft.next_fast_len(2 * nx - 1), scipy.fft.next_fast_len(2 * ny - 1)
    m = batch_size(n)
    if rhs is None:
        rhs = n // 8 + 2 * int(np.sqrt(n)) + 6
    return int(2 * 9 * 16 * P * Q + (RESTART + 1) * m * 3 * n * 16 + 3 * m * 3 * P * Q * 16
               + 8 * m * 3 * n * 16 + 16 * (6 + n) ** 2 + 4 * 16 * 3 * n * rhs)


def right_hand_sides(mesh) -> int:
    """Right-hand sides the fast solver solves per frequency for the gap table: 6 + one vertical
    load per orbit of the mesh's symmetries (``mesh_symmetries``)."""
    return 6 + orbits(mesh_symmetries(mesh.xy, _grid(mesh)[1]), mesh.n)[0].size


def mesh_symmetries(xy, h) -> list[np.ndarray]:
    """The node permutations of the square's symmetries (reflections about the axes and the
    diagonals, quarter and half turns, about the origin) that map the mesh onto itself.

    Parameters
    ----------
    xy : (n, 2) m      node coordinates about the raft centre (the origin)
    h : (hx, hy) m     the grid's cell sides (``bem._grid``); x <-> y only when hx == hy

    Returns a list of int arrays p (n,), identity first: map g sends node i to node p[i]. The
    nodes are matched exactly on the lattice of half cells (2 x / hx, 2 y / hy rounded; a mesh
    whose nodes are not on it within 1e-6 of a cell has the identity only); a map is kept when it
    sends every node onto a node.
    """
    xy = np.asarray(xy, dtype=float)
    n = xy.shape[0]
    u = 2 * xy / np.asarray(h, dtype=float)
    code = np.rint(u).astype(np.int64)
    if not np.allclose(u, code, rtol=0, atol=2e-6):
        return [np.arange(n)]
    index = {p: i for i, p in enumerate(map(tuple, code.tolist()))}
    maps = [np.arange(n)]
    candidates = [(-1, 1, False), (1, -1, False), (-1, -1, False)]
    if abs(h[0] - h[1]) <= 1e-12 * max(h):
        candidates += [(1, 1, True), (-1, 1, True), (1, -1, True), (-1, -1, True)]
    for sx, sy, swap in candidates:
        img = (code[:, ::-1] if swap else code) * (sx, sy)
        perm = np.fromiter((index.get(p, -1) for p in map(tuple, img.tolist())), dtype=np.int64, count=n)
        if perm.min() >= 0:
            maps.append(perm)
    return maps


def orbits(maps, n: int) -> tuple[np.ndarray, list[tuple[np.ndarray, np.ndarray]]]:
    """Orbit representatives of the n nodes under ``maps`` (a group: ``mesh_symmetries``).

    Returns (reps, supply): reps (r,) the smallest node of each orbit, and per map p (same
    order) a pair (k, nodes) of int arrays: node ``nodes[t] = p[reps[k[t]]]`` is reached from
    representative ``k[t]`` by p, every node exactly once over all maps."""
    owner = np.full(n, -1, dtype=np.int64)
    reps = []
    for j in range(n):
        if owner[j] < 0:
            reps.append(j)
            for p in maps:
                owner[p[j]] = len(reps) - 1
    reps = np.asarray(reps, dtype=np.int64)
    supply = []
    done = np.zeros(n, dtype=bool)
    for p in maps:
        img = p[reps]
        new = ~done[img]
        supply.append((np.flatnonzero(new), img[new]))
        done[img[new]] = True
    if not done.all():             # not a group (cannot happen for mesh_symmetries): no reduction
        return np.arange(n), [(np.arange(n), np.arange(n))]
    return reps, supply


class GridSolver:
    """F(ω)⁻¹ on a grid mesh by FFT products and right-preconditioned GMRES (module docstring).

    Parameters
    ----------
    bem : SurfaceBem of a grid mesh
    omega : float, rad/s
    tol : relative residual of every right-hand side (2-norm)
    """

    def __init__(self, bem, omega, tol=DEFAULT_TOL):
        ij = bem.grid_index
        if ij is None:
            raise SolverError("the fast solver needs a grid mesh (circle or rectangle)")
        blocks = bem.offset_blocks(omega)                  # (n_off, 3, 3)
        off = bem.grid_offsets
        self.tol = float(tol)
        self.n = ij.shape[0]
        ij = ij - ij.min(axis=0)
        nx, ny = ij.max(axis=0) + 1
        self.P, self.Q = scipy.fft.next_fast_len(2 * int(nx) - 1), scipy.fft.next_fast_len(2 * int(ny) - 1)
        self.nx = int(nx)
        self.flat = ij[:, 0] * self.Q + ij[:, 1]           # node -> index in the (nx, Q) rows
        kern = np.zeros((3, 3, self.P, self.Q), dtype=complex)
        kern[:, :, off[:, 0] % self.P, off[:, 1] % self.Q] = blocks.transpose(1, 2, 0)
        self.symbol = scipy.fft.fft2(kern, workers=1)       # (3, 3, P, Q)
        inv = np.linalg.inv(self.symbol.transpose(2, 3, 0, 1))
        self.inverse = np.ascontiguousarray(inv.transpose(2, 3, 0, 1))
        self.iterations = 0             # Arnoldi steps taken (summed over batches), for the record
        self.products = 0               # products with F (columns), for the record

    def _convolve(self, x, symbol):
        """R 𝓕⁻¹ (symbol 𝓕 (Rᵀ x)) for the columns x (m, 3n) (node-interleaved), as (m, 3n).

        The transforms skip the padding they can: forward along y on the nx rows of the box
        only, then along x padded to P; inverse along x, then along y on the nx rows kept."""
        m, nx, P, Q = x.shape[0], self.nx, self.P, self.Q
        grid = np.zeros((m, 3, P, Q), dtype=complex)
        grid.reshape(m, 3, P * Q)[:, :, self.flat] = x.reshape(m, self.n, 3).transpose(0, 2, 1)
        grid[:, :, :nx] = scipy.fft.fft(grid[:, :, :nx], axis=-1, workers=1)
        xh = scipy.fft.fft(grid, axis=-2, workers=1, overwrite_x=True)
        yh = np.einsum("abpq,mbpq->mapq", symbol, xh)
        y = scipy.fft.ifft(yh, axis=-2, workers=1, overwrite_x=True)[:, :, :nx]
        y = scipy.fft.ifft(y, axis=-1, workers=1, overwrite_x=True).reshape(m, 3, nx * Q)
        return np.ascontiguousarray(y[:, :, self.flat].transpose(0, 2, 1)).reshape(m, 3 * self.n)

    def matvec(self, x):
        """F x for the columns x (m, 3n)."""
        self.products += x.shape[0]
        return self._convolve(x, self.symbol)

    def precondition(self, x):
        """M⁻¹ x = R C⁻¹ Rᵀ x for the columns x (m, 3n)."""
        return self._convolve(x, self.inverse)

    def solve(self, b, x0=None):
        """F⁻¹ b, b (3n, k) real or complex, in batches of ``batch_size(n)`` columns; (3n, k).
        x0 (3n, k) or None: a first guess (only the iterations depend on it, not the tolerance)."""
        b = np.asarray(b)
        out = np.empty(b.shape, dtype=complex)
        m = batch_size(self.n)
        for c0 in range(0, b.shape[1], m):
            c1 = min(b.shape[1], c0 + m)
            guess = None if x0 is None else np.ascontiguousarray(x0[:, c0:c1].T, dtype=complex)
            out[:, c0:c1] = self._gmres(np.ascontiguousarray(b[:, c0:c1].T, dtype=complex), guess).T
        return out

    def _gmres(self, b, x0=None):
        """Right-preconditioned restarted GMRES on the rows of b (m, d), from x0 (m, d) or zero:
        x with ||b - F x|| <= tol ||b|| for every row (true residuals)."""
        m, d = b.shape
        bnorm = np.linalg.norm(b, axis=1)
        goal = self.tol * np.where(bnorm > 0, bnorm, 1.0)
        if x0 is None:
            x = np.zeros_like(b)
            r = b.copy()
            rnorm = bnorm.copy()
        else:
            x = x0.copy()
            r = b - self.matvec(x)
            rnorm = np.linalg.norm(r, axis=1)
        for _ in range(MAX_RESTARTS):
            if np.all(rnorm <= goal):
                return x
            V = np.empty((m, RESTART + 1, d), dtype=complex)
            live = rnorm > 0
            V[:, 0] = r / np.where(live, rnorm, 1.0)[:, None]
            H = np.zeros((m, RESTART + 1, RESTART), dtype=complex)
            cs = np.zeros((m, RESTART), dtype=complex)
            sn = np.zeros((m, RESTART), dtype=complex)
            g = np.zeros((m, RESTART + 1), dtype=complex)
            g[:, 0] = rnorm
            k = 0
            for k in range(RESTART):
                w = self.matvec(self.precondition(V[:, k]))
                self.iterations += 1
                for j in range(m):                   # classical Gram-Schmidt, twice (CGS2)
                    for _ in range(2):
                        h = (V[j, :k + 1] @ w[j].conj()).conj()
                        w[j] -= h @ V[j, :k + 1]
                        H[j, :k + 1, k] += h
                hn = np.linalg.norm(w, axis=1)
                H[:, k + 1, k] = hn
                V[:, k + 1] = w / np.where(hn > 0, hn, 1.0)[:, None]
                for i in range(k):                   # the previous rotations on column k
                    t = cs[:, i] * H[:, i, k] + sn[:, i] * H[:, i + 1, k]
                    H[:, i + 1, k] = -sn[:, i].conj() * H[:, i, k] + cs[:, i] * H[:, i + 1, k]
                    H[:, i, k] = t
                a, bb = H[:, k, k], H[:, k + 1, k]
                den = np.sqrt(np.abs(a) ** 2 + np.abs(bb) ** 2)
                den = np.where(den > 0, den, 1.0)
                phase = np.where(np.abs(a) > 0, a / np.where(np.abs(a) > 0, np.abs(a), 1.0), 1.0)
                cs[:, k] = np.abs(a) / den
                sn[:, k] = phase * bb.conj() / den
                H[:, k, k] = phase * den
                H[:, k + 1, k] = 0.0
                g[:, k + 1] = -sn[:, k].conj() * g[:, k]
                g[:, k] = cs[:, k] * g[:, k]
                if np.all(np.abs(g[:, k + 1]) <= 0.5 * goal):   # a margin for the true residual
                    break
            steps = k + 1
            R = H[:, :steps, :steps]
            diag = np.diagonal(R, axis1=1, axis2=2)
            R = R + np.where(np.abs(diag) > 0, 0.0, 1.0)[:, None, :] * np.eye(steps)   # idle columns
            y = np.linalg.solve(R, g[:, :steps, None])[:, :, 0]
            y[~live] = 0.0
            x += self.precondition(np.matmul(y[:, None, :], V[:, :steps])[:, 0])
            r = b - self.matvec(x)
            rnorm = np.linalg.norm(r, axis=1)
        if np.all(rnorm <= goal):
            return x
        worst = float(np.max(rnorm / np.where(bnorm > 0, bnorm, 1.0)))
        raise FastSolveError(f"the fast BEM solver reached a relative residual of {worst:.2e}, not "
                             f"{self.tol:.1e}, after {MAX_RESTARTS} restarts of {RESTART} GMRES steps: "
                             "set [impedance] solver = 'dense' (or a larger solver_tol)")


def gap_and_rigid(bem, omega, outputs, tol, T, Th, guess=None):
    """The rigid (6×6, Tᵀ F⁻¹ T) and gap ((6+N)², Bᵀ F⁻¹ B, B = [T_h, Z]) impedances at ω
    by the fast solver, both symmetrised as the dense sweep's (``sweep._compute``).

    Solved: F⁻¹ T (6 columns; T_h's non-zero columns are T's ux, uy, rz) and F⁻¹ z_j for one
    vertical unit load z_j per orbit of the mesh's reflections (``mesh_symmetries``). By F's
    symmetry the coupling block T_hᵀ F⁻¹ Z is the transpose of Zᵀ F⁻¹ T_h (vertical rows of
    the T solves).

    guess : None or the ``solutions`` of another frequency (dict "T", "Z" -> (3N, k)): first
    guesses of GMRES (``sweep._compute_fast``: extrapolated from the chain's previous frequencies).

    Returns (dict output -> matrix, GridSolver (its counters), solutions {"T", "Z"}).
    """
    mesh = bem.mesh
    n = mesh.n
    guess = guess or {}
    solver = GridSolver(bem, omega, tol)
    XT = solver.solve(T, guess.get("T"))
    solutions = {"T": XT}
    out = {}
    if "rigid" in outputs:
        Kr = T.T @ XT
        out["rigid"] = 0.5 * (Kr + Kr.T)
    if "gap" in outputs:
        Xh = XT.copy()
        Xh[:, 2:5] = 0.0                                  # F⁻¹ T_h: T_h is T without uz, rx, ry
        maps = mesh_symmetries(mesh.xy, _grid(mesh)[1])
        reps, supply = orbits(maps, n)
        maps = maps[:len(supply)]
        Z = np.zeros((3 * n, reps.size))
        Z[2 + 3 * reps, np.arange(reps.size)] = 1.0
        solutions["Z"] = solver.solve(Z, guess.get("Z"))
        # the transpose B = Kgᵀ is assembled (its vertical block row by row, from contiguous rows of
        # the solutions) and symmetrised in place: 0.5 (B + Bᵀ) = 0.5 (Kg + Kgᵀ), the same bits
        XzT = np.ascontiguousarray(solutions["Z"][2::3].T)    # (r, n): vertical response to each load
        B = np.empty((6 + n, 6 + n), dtype=complex)
        B[:6, :6] = (Th.T @ Xh).T
        B[6:, :6] = Xh[2::3]
        B[:6, 6:] = Xh[2::3].T
        Bz = B[6:, 6:]
        for p, (k, node) in zip(maps, supply):
            # K[p[i], p[rep]] = K[i, rep]: column p[rep] of K (row of B) is column rep permuted by p
            inverse = np.empty_like(p)
            inverse[p] = np.arange(p.size)
            rows = XzT[k]
            for t, j in enumerate(node):
                np.take(rows[t], inverse, out=Bz[j])
        out["gap"] = symmetrise(B)
    return out, solver, solutions


#: tile edge of ``symmetrise``
TILE = 256


def symmetrise(A):
    """0.5 (A + Aᵀ) in place, tile by tile (no temporary of A's size), the same bits as the
    expression (IEEE addition commutes); returns A."""
    m = A.shape[0]
    for i in range(0, m, TILE):
        a = A[i:i + TILE, i:i + TILE]
        a[...] = 0.5 * (a + a.T)
        for j in range(i + TILE, m, TILE):
            upper, lower = A[i:i + TILE, j:j + TILE], A[j:j + TILE, i:i + TILE]
            s = 0.5 * (upper + lower.T)
            upper[...] = s
            lower[...] = s.T
    return A


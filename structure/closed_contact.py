"""The closed-contact (linear) problem of the Newmark stepper: its solver and the kernels that
record a whole linear run at once.

With every penalty spring closed (contact disabled, or a run with no tension) the stepper's
update is linear: one factorisation of the effective matrix per step size (``ClosedSolver``),
one solve per step. ``MatVec`` is a constant sparse product made fast in a time loop;
``work`` and ``quad`` are the energy works and stored energies of a force S z over a whole
history (nt, n), the stepper's step-by-step sums vectorised over time.
"""
from __future__ import annotations

import numpy as np
from uplift_common.lazy import lazy_module

# scipy loads on first use (uplift_common.lazy): a warm run reads what it would compute
sla = lazy_module("scipy.linalg")
sp = lazy_module("scipy.sparse")
spla = lazy_module("scipy.sparse.linalg")


class ClosedSolver:
    """u = A^-1 rhs for the effective matrix A (n, n) with every contact spring closed, split
    as [[Ass, Asw], [Aws, Aww]] on the ns structure DOFs and the N soil DOFs w.

    When Aww is diagonal (springs and dashpots under each node in series with the penalty:
    Winkler soils) w is condensed exactly: S = Ass - Asw Aww^-1 Aws (ns, ns) is factorised
    densely (a stick model has few DOFs), and a solve is a few vector operations; w couples
    to the raft rows only, so Asw and Aws are kept on their bounding blocks. Otherwise (a soil
    coupling the nodes, e.g. the BEM's recursive convolution) a sparse LU of A."""

    def __init__(self, A, ns: int):
        A = sp.csr_matrix(A)
        self.n, self.ns = A.shape[0], ns
        Aww = A[ns:, ns:]
        dw = Aww.diagonal()
        self.lu = None
        if ns == 0 or (Aww - sp.diags(dw)).count_nonzero() or not np.all(dw != 0):
            self.lu = spla.splu(A.tocsc())
            return
        Asw, Aws = A[:ns, ns:], A[ns:, :ns]
        r, c = Asw.nonzero()[0], Aws.nonzero()[1]
        self.r = slice(r.min(), r.max() + 1) if r.size else slice(0, 0)
        self.c = slice(c.min(), c.max() + 1) if c.size else slice(0, 0)
        self.dw = dw
        self.Asw = Asw[self.r].toarray()                       # (rows of Asw, N)
        self.G = Aws[:, self.c].toarray() / dw[:, None]        # Aww^-1 Aws on its columns
        S = A[:ns, :ns].toarray()
        S[:, self.c] -= Asw.toarray() @ self.G
        self.S_lu = sla.lu_factor(S, check_finite=False)
        self.Sinv = sla.lu_solve(self.S_lu, np.eye(ns), check_finite=False)

    def solve(self, rhs):
        """A^-1 rhs (rhs (n,) may be overwritten)."""
        if self.lu is not None:
            return self.lu.solve(rhs)
        ns = self.ns
        t = rhs[ns:] / self.dw
        rs = rhs[:ns]
        rs[self.r] -= self.Asw @ t
        u = np.empty(self.n)
        us = u[:ns]
        np.matmul(self.Sinv, rs, out=us)
        np.subtract(t, self.G @ us[self.c], out=u[ns:])
        return u


def _rows_times(S, Z, r, c):
    """(nt, |r|): rows r of S z_k for every row z_k of Z (nt, n), S sparse and zero outside
    rows r and columns c: a dense block product when S is dense there, else sparse."""
    Sb = S[r][:, c]
    Zc = Z[:, c]
    if Sb.nnz >= 0.1 * r.size * c.size:
        return Zc @ Sb.toarray().T
    return (Sb @ np.ascontiguousarray(Zc.T)).T


def work(dY, S, Z):
    """(nt - 1,) dy_k . S (z_k + z_{k+1}) / 2 for dY (nt - 1, n), Z (nt, n) and a sparse S
    (n, n): the work increments of the force S z, on the rows and columns S touches."""
    rows, cols = S.nonzero()
    if rows.size == 0:
        return np.zeros(dY.shape[0])
    r = np.unique(rows)
    Q = _rows_times(S, Z, r, np.unique(cols))
    return np.einsum("ij,ij->i", dY[:, r], 0.5 * (Q[:-1] + Q[1:]))


def quad(Y, S):
    """(nt,) y_k . S y_k / 2 for Y (nt, n) and a sparse S (n, n)."""
    rows, cols = S.nonzero()
    r = np.unique(rows)
    return 0.5 * np.einsum("ij,ij->i", Y[:, r], _rows_times(S, Y, r, np.unique(cols)))


class MatVec:
    """y = S x for a constant sparse S, fast in a time loop: a dense product on the bounding
    block of its nonzeros when S is dense there (the modal damping of a stick model), else
    scipy's sparse product."""

    def __init__(self, S):
        S = sp.csr_matrix(S)
        rows, cols = S.nonzero()
        if rows.size == 0:
            self.mode = "zero"
            return
        self.r = slice(rows.min(), rows.max() + 1)
        self.c = slice(cols.min(), cols.max() + 1)
        block = S[self.r, self.c]
        self.mode = "dense" if block.nnz >= 0.1 * block.shape[0] * block.shape[1] else "sparse"
        self.S = block.toarray() if self.mode == "dense" else S

    def add_to(self, y, x, scale=1.0):
        """y += scale * S x."""
        if self.mode == "dense":
            y[self.r] += self.S @ x[self.c] if scale == 1.0 else scale * (self.S @ x[self.c])
        elif self.mode == "sparse":
            y += self.S @ x if scale == 1.0 else scale * (self.S @ x)

"""Static equilibrium under self-weight (and optional extra loads) with the soil's static
stiffness K(0) and unilateral penalty contact on the total force (paper §4.3).

Total-displacement formulation from the unloaded state where the raft just touches the
soil: d_i = vertical raft trace - w_i, P_i = kp_i max(0, -d_i). The active-set iteration
(exact Newton for this piecewise-linear problem) starts from full contact.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from uplift_common.lazy import lazy_module

from .errors import ConvergenceError, StructureError
from .model import StructureModel

# scipy loads on first use (uplift_common.lazy): a warm run reads what it would compute
sp = lazy_module("scipy.sparse")
spla = lazy_module("scipy.sparse.linalg")


@dataclass(frozen=True, eq=False)
class StaticState:
    """u (n_dof,) static displacements [structure | q | w], m and rad; P0 (N,) N static
    contact forces; d0 (N,) m static relative displacement (negative: penetration);
    settlement m (downward raft centre displacement, positive down); iterations."""
    u: np.ndarray
    P0: np.ndarray
    d0: np.ndarray
    settlement: float
    iterations: int

    @property
    def delta0(self) -> np.ndarray:
        """delta0_i = -d0_i (N,), m: P0_i / kp_i where in contact, minus the static gap else."""
        return -self.d0


def interface_operator(model: StructureModel) -> sp.csr_matrix:
    """B (N, n_dof): d = B u, vertical raft trace minus soil w at each interface node."""
    n, ns = model.n_interface, model.n_struct
    Bq = model.raft.vertical_trace()
    rows = np.concatenate([np.repeat(np.arange(n), 3), np.arange(n)])
    cols = np.concatenate([np.tile(ns - 6 + np.arange(2, 5), n), ns + np.arange(n)])
    vals = np.concatenate([Bq[:, 2:5].ravel(), -np.ones(n)])
    return sp.csr_matrix((vals, (rows, cols)), shape=(n, model.n_dof))


def embed(model: StructureModel, K_struct, K_soil) -> sp.csr_matrix:
    """Global (n_dof, n_dof) matrix: structural block plus soil block on the trailing x = [q, w]."""
    ns, nd = model.n_struct, model.n_dof
    A = sp.csr_matrix(K_struct)
    A = sp.block_diag([A, sp.csr_matrix((model.n_interface, model.n_interface))], format="csr")
    Ks = sp.csr_matrix(K_soil)
    off = ns - 6
    Ks = sp.csr_matrix((Ks.data, Ks.indices + off, np.concatenate([np.zeros(off, int), Ks.indptr])),
                       shape=(nd, nd))
    return (A + Ks).tocsr()


def solve_static(model: StructureModel, soil, kp, load=None, unilateral=True, max_iter=60) -> StaticState:
    """Static equilibrium. load (n_dof,) N extra to gravity (None: gravity only)."""
    K = embed(model, model.stiffness, soil.static_stiffness())
    F = np.zeros(model.n_dof)
    F[:model.n_struct] = model.gravity_load()
    if load is not None:
        F = F + load
    B = interface_operator(model)
    return solve_static_system(K, F, B, kp, model.n_struct - 4, unilateral, max_iter)


def solve_static_system(K, F, B, kp, settle_dof: int, unilateral=True, max_iter=60) -> StaticState:
    """The static equilibrium of an assembled system: K (n, n) sparse stiffness (structure and
    soil), F (n,) N loads, B (N, n) the contact operator d = B u, kp (N,) N/m penalties;
    settle_dof the index of the raft centre's uz (the settlement is -u there)."""
    kp = np.asarray(kp, float)
    active = np.ones(B.shape[0], bool)
    for it in range(1, max_iter + 1):
        Kt = (K + B.T @ sp.diags(kp * active) @ B).tocsc()
        try:
            u = spla.spsolve(Kt, F)
        except Exception as exc:  # singular
            raise StructureError(f"static preload matrix is singular ({exc}): the structure is "
                                 "not supported by the soil in every direction") from exc
        if not np.all(np.isfinite(u)):
            raise StructureError("static preload matrix is singular: the structure is not "
                                 "supported by the soil in every direction (add springs?)")
        d = B @ u
        new = d < 0 if unilateral else np.ones_like(active)
        if np.array_equal(new, active):
            P0 = kp * np.maximum(0.0, -d) if unilateral else -kp * d
            return StaticState(u, P0, d, -float(u[settle_dof]), it)
        active = new
        if not active.any():
            raise StructureError("static preload: the raft is not in contact anywhere; the "
                                 "loads overturn the structure")
    raise ConvergenceError("static preload active set did not settle", 0.0, -1, np.nan)

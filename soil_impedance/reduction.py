"""Interface reductions of a nodal impedance (node-interleaved DOFs [ux0, uy0, uz0, ux1, ...]).

* rigid raft, 6 DOFs q = (ux, uy, uz, rx, ry, rz) about the mesh origin (the raft centre):
  the trace at node i is ``[ux - rz y, uy + rz x, uz + rx y - ry x]``, ``K_r = Tᵀ K T``.
* rigid raft + N vertical gap DOFs (paper's V1/V2): u_s = T_h q + Z w, where T_h is T with its
  vertical rows zeroed (horizontal traces of the raft) and Z selects each node's vertical DOF;
  ``K_g = Bᵀ K B`` with ``B = [T_h, Z]``, DOFs ["ux","uy","uz","rx","ry","rz","w0",...].
  The uz, rx, ry rows and columns of K_g are zero: the raft's vertical motion reaches the
  soil only through w and the contact law (w_i = uz + rx y_i - ry x_i where in contact).
"""
from __future__ import annotations

import numpy as np

RIGID_DOFS = ["ux", "uy", "uz", "rx", "ry", "rz"]


def rigid_transform(mesh) -> np.ndarray:
    """T, shape (3N, 6): nodal displacements (m) of the rigid raft motion q (m, rad)."""
    x, y = mesh.xy[:, 0], mesh.xy[:, 1]
    n = mesh.n
    T = np.zeros((n, 3, 6))
    T[:, 0, 0] = 1.0
    T[:, 0, 5] = -y
    T[:, 1, 1] = 1.0
    T[:, 1, 5] = x
    T[:, 2, 2] = 1.0
    T[:, 2, 3] = y
    T[:, 2, 4] = -x
    return T.reshape(3 * n, 6)


def gap_transform(mesh) -> np.ndarray:
    """B = [T_h, Z], shape (3N, 6 + N)."""
    n = mesh.n
    Th = rigid_transform(mesh)
    Th[2::3, :] = 0.0
    Z = np.zeros((3 * n, n))
    Z[2 + 3 * np.arange(n), np.arange(n)] = 1.0
    return np.hstack([Th, Z])


def gap_dofs(n: int) -> list[str]:
    return RIGID_DOFS + [f"w{i}" for i in range(n)]


def rigid_reduction(K: np.ndarray, mesh) -> np.ndarray:
    """Rigid-raft impedance Tᵀ K T, shape (..., 6, 6); K shape (..., 3N, 3N)."""
    T = rigid_transform(mesh)
    return T.T @ K @ T


def gap_reduction(K: np.ndarray, mesh) -> np.ndarray:
    """Rigid + vertical gap impedance Bᵀ K B, shape (..., 6+N, 6+N)."""
    B = gap_transform(mesh)
    return B.T @ K @ B


def condense_gap_rigid(Kg: np.ndarray, mesh) -> np.ndarray:
    """6×6 impedance of the gap model with w tied to the raft (full contact): Pᵀ K_g P,
    P = [I6; T_v], T_v the vertical rows of T. Equals ``rigid_reduction`` of the same K."""
    Tv = rigid_transform(mesh)[2::3, :]
    P = np.vstack([np.eye(6), Tv])
    return P.T @ Kg @ P

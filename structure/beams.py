"""3D Timoshenko beam element (Euler-Bernoulli when no shear areas are given).

Local axes: x along the beam (node 1 -> node 2); for a non-vertical beam local y is
horizontal, y = (Z x ex)/|Z x ex|; for a vertical beam local y = global Y. z = x cross y.
``Iy`` is the second moment about local y (bending in the local x-z plane), ``Iz`` about
local z (bending in the local x-y plane); ``Asy``/``Asz`` the shear areas along local y/z.
DOF order per node: ux, uy, uz, rx, ry, rz.
"""
from __future__ import annotations

import numpy as np


def local_axes(p1, p2) -> tuple[np.ndarray, float]:
    """Rotation R (3, 3) whose rows are the local x, y, z axes, and the length L (m)."""
    d = np.asarray(p2, float) - np.asarray(p1, float)
    L = float(np.linalg.norm(d))
    ex = d / L
    ey = np.cross([0.0, 0.0, 1.0], ex)
    if np.linalg.norm(ey) < 1e-6 * 1.0:
        ey = np.array([0.0, 1.0, 0.0])
    ey = ey / np.linalg.norm(ey)
    ez = np.cross(ex, ey)
    return np.vstack([ex, ey, ez]), L


def local_stiffness(L, E, G, A, Iy, Iz, J, Asy=None, Asz=None) -> np.ndarray:
    """Local 12x12 stiffness of a Timoshenko beam (phi = 12 E I / (G As L^2); phi = 0 gives
    Euler-Bernoulli), N/m, N, N m."""
    k = np.zeros((12, 12))
    ea, gj = E * A / L, G * J / L
    k[np.ix_([0, 6], [0, 6])] = ea * np.array([[1, -1], [-1, 1]])
    k[np.ix_([3, 9], [3, 9])] = gj * np.array([[1, -1], [-1, 1]])
    # bending in x-y plane: v (1, 7), rz (5, 11), inertia Iz, shear area Asy
    py = 12 * E * Iz / (G * Asy * L**2) if Asy else 0.0
    c = E * Iz / ((1 + py) * L**3)
    idx = [1, 5, 7, 11]
    k[np.ix_(idx, idx)] = c * np.array([
        [12, 6 * L, -12, 6 * L],
        [6 * L, (4 + py) * L**2, -6 * L, (2 - py) * L**2],
        [-12, -6 * L, 12, -6 * L],
        [6 * L, (2 - py) * L**2, -6 * L, (4 + py) * L**2]])
    # bending in x-z plane: w (2, 8), ry (4, 10), inertia Iy, shear area Asz
    pz = 12 * E * Iy / (G * Asz * L**2) if Asz else 0.0
    c = E * Iy / ((1 + pz) * L**3)
    idx = [2, 4, 8, 10]
    k[np.ix_(idx, idx)] = c * np.array([
        [12, -6 * L, -12, -6 * L],
        [-6 * L, (4 + pz) * L**2, 6 * L, (2 - pz) * L**2],
        [-12, 6 * L, 12, 6 * L],
        [-6 * L, (2 - pz) * L**2, 6 * L, (4 + pz) * L**2]])
    return k


def global_stiffness(p1, p2, E, G, A, Iy, Iz, J, Asy=None, Asz=None) -> np.ndarray:
    """Element stiffness (12, 12) in global axes."""
    R, L = local_axes(p1, p2)
    T = np.kron(np.eye(4), R)
    return T.T @ local_stiffness(L, E, G, A, Iy, Iz, J, Asy, Asz) @ T

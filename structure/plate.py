"""Kirchhoff plate bending: the discrete Kirchhoff triangle (DKT) on triangles and quadrilaterals.

The plate lies in the plane z = const; each vertex carries three DOFs ``(w, θx, θy)``:
the deflection w (m, z up) and the rotations about the x and y axes (rad, right hand), so
that in the Kirchhoff limit ``θx = ∂w/∂y`` and ``θy = -∂w/∂x``.

The DKT element (Batoz, Bathe and Ho, 1980) interpolates the section rotations
``βx = -∂w/∂x``, ``βy = -∂w/∂y`` quadratically and imposes the Kirchhoff constraint (no
transverse shear) at the vertices and at the mid-sides: it has no shear locking at any
thickness (there is no shear energy), passes the constant-curvature patch test and converges
at O(h²) in deflection. The stiffness is integrated exactly (the curvatures are linear: a
three-point rule). Quadrilaterals are split into two triangles along their shorter diagonal.
The flexural rigidity is ``D = E t³ / (12 (1 - ν²))``.

Units: SI (m, N, Pa); DOF ordering vertex-interleaved ``[w0, θx0, θy0, w1, ...]``.
"""
from __future__ import annotations

import numpy as np
from uplift_common.lazy import lazy_module

from .errors import StructureError


# scipy loads on first use (uplift_common.lazy): a warm run reads what it would compute
sp = lazy_module("scipy.sparse")
#: three-point (degree 2) rule on the reference triangle: points (ξ, η), weights summing to 1/2
_GAUSS = (np.array([[1 / 6, 1 / 6], [2 / 3, 1 / 6], [1 / 6, 2 / 3]]), np.full(3, 1 / 6))


def flexural_rigidity(E: float, thickness: float, nu: float) -> float:
    """D = E t³ / (12 (1 - ν²)), N·m."""
    return E * thickness ** 3 / (12.0 * (1.0 - nu * nu))


def bending_matrix(E: float, thickness: float, nu: float) -> np.ndarray:
    """Moment-curvature matrix (3, 3), N·m: ``[Mx, My, Mxy] = D_b [κx, κy, 2κxy]``."""
    D = flexural_rigidity(E, thickness, nu)
    return D * np.array([[1.0, nu, 0.0], [nu, 1.0, 0.0], [0.0, 0.0, 0.5 * (1.0 - nu)]])


def _quadratic_derivatives(xi: float, eta: float) -> tuple[np.ndarray, np.ndarray]:
    """dN/dξ, dN/dη of the six quadratic shape functions (vertices 1-3, mid-sides 23, 31, 12)."""
    l1 = 1.0 - xi - eta
    dxi = np.array([1 - 4 * l1, 4 * xi - 1, 0.0, 4 * eta, -4 * eta, 4 * (l1 - xi)])
    deta = np.array([1 - 4 * l1, 0.0, 4 * eta - 1, 4 * xi, 4 * (l1 - eta), -4 * xi])
    return dxi, deta


def _dkt_coefficients(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cx, Cy (..., 9, 6) for vertex coordinates x, y (..., 3): βx = Σ_m (Cx[:, m]·U) N_m and βy
    likewise, U the element's nine DOFs (the coefficients of Batoz, Bathe and Ho, 1980)."""
    # sides k = 4, 5, 6 join vertices (2, 3), (3, 1), (1, 2)
    i, j = np.array([1, 2, 0]), np.array([2, 0, 1])
    xij, yij = x[..., i] - x[..., j], y[..., i] - y[..., j]
    l2 = xij ** 2 + yij ** 2
    a, b = -xij / l2, 0.75 * xij * yij / l2
    c = (0.25 * xij ** 2 - 0.5 * yij ** 2) / l2
    d = -yij / l2
    e = (0.25 * yij ** 2 - 0.5 * xij ** 2) / l2
    shape = x.shape[:-1] + (9, 6)
    Cx, Cy = np.zeros(shape), np.zeros(shape)
    for v in range(3):                       # vertex shape functions: βx = θy, βy = -θx
        Cx[..., 3 * v + 2, v] = 1.0
        Cy[..., 3 * v + 1, v] = -1.0
    for k in range(3):                       # mid-side k (N_{3+k}) between vertices i[k], j[k]
        m = 3 + k
        for v, s in ((i[k], 1.0), (j[k], -1.0)):
            # the side's contribution to the DOFs (w, θx, θy) of its two end vertices
            Cx[..., 3 * v:3 * v + 3, m] += np.stack([s * 1.5 * a[..., k], b[..., k], -c[..., k]], axis=-1)
            Cy[..., 3 * v:3 * v + 3, m] += np.stack([s * 1.5 * d[..., k], e[..., k], -b[..., k]], axis=-1)
    return Cx, Cy


def dkt_stiffness(x, y, Db: np.ndarray) -> np.ndarray:
    """Stiffness (..., 9, 9) of DKT triangles with vertices (x[..., k], y[..., k]) counter-clockwise."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    x31, y31 = x[..., 2] - x[..., 0], y[..., 2] - y[..., 0]
    x12, y12 = x[..., 0] - x[..., 1], y[..., 0] - y[..., 1]
    two_a = (x31 * y12 - x12 * y31)[..., None]          # 2 × area (the Jacobian of (ξ, η) -> (x, y))
    Cx, Cy = _dkt_coefficients(x, y)
    K = np.zeros(x.shape[:-1] + (9, 9))
    for (xi, eta), w in zip(*_GAUSS):
        B = _curvature_matrix(Cx, Cy, x31, y31, x12, y12, two_a, xi, eta)
        K += (w * two_a)[..., None] * np.einsum("...ki,kl,...lj->...ij", B, Db, B)
    return K


def _curvature_matrix(Cx, Cy, x31, y31, x12, y12, two_a, xi, eta) -> np.ndarray:
    """B (..., 3, 9): the curvatures [κx, κy, 2κxy] = [βx,x, βy,y, βx,y + βy,x] at (ξ, η) from
    the element's nine DOFs."""
    dxi, deta = _quadratic_derivatives(xi, eta)
    hx_xi, hx_eta, hy_xi, hy_eta = Cx @ dxi, Cx @ deta, Cy @ dxi, Cy @ deta
    return np.stack([y31[..., None] * hx_xi + y12[..., None] * hx_eta,
                     -x31[..., None] * hy_xi - x12[..., None] * hy_eta,
                     -x31[..., None] * hx_xi - x12[..., None] * hx_eta
                     + y31[..., None] * hy_xi + y12[..., None] * hy_eta], axis=-2) / two_a[..., None]


def dkt_curvatures(x, y) -> tuple[np.ndarray, np.ndarray]:
    """(B (..., 3, 9), area (...,)): the curvatures [κx, κy, 2κxy] (1/m) at the centroid of DKT
    triangles (vertices (x[..., k], y[..., k]) counter-clockwise) from their nine DOFs, and the
    triangles' areas m². κx = βx,x = -∂²w/∂x² (w up): positive where the plate is convex
    upwards (hogging)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    x31, y31 = x[..., 2] - x[..., 0], y[..., 2] - y[..., 0]
    x12, y12 = x[..., 0] - x[..., 1], y[..., 0] - y[..., 1]
    two_a = (x31 * y12 - x12 * y31)[..., None]
    Cx, Cy = _dkt_coefficients(x, y)
    return _curvature_matrix(Cx, Cy, x31, y31, x12, y12, two_a, 1 / 3, 1 / 3), 0.5 * two_a[..., 0]


def moment_operator(points, cells, E: float, thickness: float, nu: float) -> sp.csr_matrix:
    """S (3 n_cells, 3m): the bending moments per unit length [Mx, My, Mxy] (N·m/m) of each cell,
    rows interleaved per cell, from the plate's DOFs ``[w0, θx0, θy0, w1, ...]``: the DKT moments
    ``D_b B`` at the centroid of each of the cell's triangles (a quadrilateral's two, split as
    ``plate_stiffness`` splits it), averaged with the triangles' areas as weights. Sign: Mx =
    D (κx + ν κy) with κx = -∂²w/∂x² (w up): a moment is positive when it puts the plate's top
    fibre in tension (hogging); Mxy = D (1 - ν) κxy."""
    points = np.asarray(points, dtype=float)
    Db = bending_matrix(E, thickness, nu)
    tris, owner = [], []
    for i, cell in enumerate(cells):
        t = _triangles(points, [cell])
        tris.append(t)
        owner += [i] * t.shape[0]
    tris, owner = np.concatenate(tris), np.array(owner)
    B, area = dkt_curvatures(points[tris, 0], points[tris, 1])
    weight = area / np.bincount(owner, area)[owner]
    S = weight[:, None, None] * np.einsum("kl,tlj->tkj", Db, B)            # (n_tri, 3, 9)
    dofs = (3 * tris[:, :, None] + np.arange(3)).reshape(-1, 9)            # (n_tri, 9)
    rows = np.broadcast_to((3 * owner[:, None] + np.arange(3))[:, :, None], S.shape)
    cols = np.broadcast_to(dofs[:, None, :], S.shape)
    return sp.csr_matrix((S.ravel(), (rows.ravel(), cols.ravel())), shape=(3 * len(cells), 3 * points.shape[0]))


def _triangles(points: np.ndarray, cells) -> np.ndarray:
    """(n, 3) counter-clockwise vertex triples: triangles as given, quads split in two."""
    tris = []
    for cell in cells:
        cell = [int(v) for v in cell]
        if len(set(cell)) == 3 and len(cell) == 4:          # a triangle written with a repeated vertex
            cell = list(dict.fromkeys(cell))
        if len(cell) == 3:
            tris.append(cell)
        elif len(cell) == 4:
            p = points[cell]
            if np.hypot(*(p[2] - p[0])) <= np.hypot(*(p[3] - p[1])):
                tris += [[cell[0], cell[1], cell[2]], [cell[0], cell[2], cell[3]]]
            else:
                tris += [[cell[0], cell[1], cell[3]], [cell[1], cell[2], cell[3]]]
        else:
            raise StructureError(f"plate cell {cell}: a plate cell has 3 or 4 vertices")
    t = np.array(tris, dtype=np.int64).reshape(-1, 3)
    p = points[t]
    signed = ((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1])
              - (p[:, 2, 0] - p[:, 0, 0]) * (p[:, 1, 1] - p[:, 0, 1]))
    if np.any(signed == 0):
        raise StructureError(f"plate triangle {int(np.flatnonzero(signed == 0)[0])} has zero area")
    t[signed < 0] = t[signed < 0][:, ::-1]
    return t


def plate_stiffness(points, cells, E: float, thickness: float, nu: float) -> sp.csr_matrix:
    """Assembled bending stiffness (3m, 3m) of a plate on ``points`` (m, 2) and ``cells``
    (sequences of 3 or 4 vertex indices), DOFs ``[w0, θx0, θy0, w1, ...]``."""
    points = np.asarray(points, dtype=float)
    Db = bending_matrix(E, thickness, nu)
    tris = _triangles(points, cells)
    Ke = dkt_stiffness(points[tris, 0], points[tris, 1], Db)
    dofs = (3 * tris[:, :, None] + np.arange(3)).reshape(-1, 9)
    rows, cols = np.repeat(dofs, 9, axis=1), np.tile(dofs, (1, 9))
    n = 3 * points.shape[0]
    K = sp.coo_matrix((Ke.ravel(), (rows.ravel(), cols.ravel())), shape=(n, n))
    return K.tocsr()


def pressure_load(points, cells, q: float) -> np.ndarray:
    """Nodal forces (3m,) of a uniform pressure q (Pa, positive along +z): each triangle's
    q·A shared equally by its three vertices, on the w DOFs."""
    points = np.asarray(points, dtype=float)
    tris = _triangles(points, cells)
    p = points[tris]
    area = 0.5 * np.abs((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1])
                        - (p[:, 2, 0] - p[:, 0, 0]) * (p[:, 1, 1] - p[:, 0, 1]))
    f = np.zeros(3 * points.shape[0])
    np.add.at(f, 3 * tris.ravel(), np.repeat(q * area / 3.0, 3))
    return f

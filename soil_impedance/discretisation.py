"""Discretisation error of a mesh's static rigid impedances: the mesh against itself refined.

The BEM's tractions are constant per cell (on a finite-element mesh, edge-singular in the cells
along the raft's outline: ``bem.edge_strips``), collocated at the cells' area centroids (grids:
the square centres). The static rigid impedances of a mesh converge like h^p with p =
``MESH_ORDER`` = 1.5 (measured on gmsh disks of R/h = 5, 7, 10 against the closed forms,
relaxed contact: rocking and torsion 1.50-1.60 on quadrilaterals and triangles, translations
1.5 on triangles, 2.0 on quadrilaterals, tests/soil/test_bem_cells.py); grids and node lists
like h (p = ``ORDER`` = 1, test_bem_static.py). With K_h and K_{h/2} (every cell split in four,
grids at half the element size), Richardson's extrapolation K* = (2^p K_{h/2} - K_h)/(2^p - 1)
estimates the relative error of the mesh's K_h as (K_h - K*)/K*, per diagonal term: the error
of the BEM on the mesh's own outline (a polygon's missing area against the disk it approximates
is the user's geometry, not refined by splitting cells).

Circle grids keep every square whose centre is in the disk: their area and moments change
irregularly with h (the staircase), and Richardson on K_h itself is meaningless (measured: +0.3 %
estimated for a true -3.5 % at R/h = 4). For them the extrapolation is made on K_h divided by
its geometric factor (R_eq/R)^k, the equivalent radii of the squares' area (k = 1: ux, uy, uz),
second moments (k = 3: rx, ry) and polar moment (k = 3: rz), i.e. on the BEM's error alone; the
error reported is that of K_h against the disk of radius R (staircase included).
"""
from __future__ import annotations

import numpy as np

from .mesh import InterfaceMesh, MeshError, circle_mesh, rectangle_mesh
from .reduction import RIGID_DOFS

#: measured convergence order of the static rigid impedances in the element size (see above):
#: grids and node lists (constant tractions); finite-element meshes with the edge-singular shape
ORDER = 1.0
MESH_ORDER = 1.5
#: most nodes of the refined mesh: beyond, its static solve (one LU of (3N)², O(N³)) takes
#: minutes and the estimate is skipped with this reason (the reactor raft: 241 -> 965 nodes)
MAX_REFINED_NODES = 2000


class RefineError(MeshError):
    """A mesh that cannot be refined (a node list has no cells to split)."""


def refined_mesh(mesh: InterfaceMesh) -> InterfaceMesh:
    """The same raft with cells of half the size: four per cell.

    Cells (kind "cells"): a triangle into four by its edge midpoints, a quadrilateral into four
    by its edge midpoints and the mean of its vertices (nodes at the new area centroids). Grids:
    the circle at element size h/2, the rectangle with twice as many cells along x. Node lists
    (kind "nodes") have no cells: RefineError.
    """
    if mesh.kind == "circle":
        return circle_mesh(mesh.size[0], 0.5 * mesh.cell * (1 + 1e-12))
    if mesh.kind == "rectangle":
        lx, ly = mesh.size
        nx = np.unique(np.round(mesh.xy[:, 0], 9)).size
        return rectangle_mesh(lx, ly, lx / (2 * nx))
    if mesh.cells is None:
        raise RefineError(f"a {mesh.kind!r} mesh (a node list with areas) has no cells to split: "
                          "give the raft as cells (a mesh file) or a circle/rectangle grid")
    from .mesh import cells_mesh
    poly = mesh.cells
    tri = np.all(poly[:, 2] == poly[:, 3], axis=1)
    parts = []
    t = poly[tri, :3]
    if t.size:
        a, b, c = t[:, 0], t[:, 1], t[:, 2]
        ab, bc, ca = 0.5 * (a + b), 0.5 * (b + c), 0.5 * (c + a)
        for p in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca)):
            parts.append(np.stack(p + (p[2],), axis=1))
    q = poly[~tri]
    if q.size:
        a, b, c, d = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
        ab, bc, cd, da = 0.5 * (a + b), 0.5 * (b + c), 0.5 * (c + d), 0.5 * (d + a)
        m = 0.25 * (a + b + c + d)
        for p in ((a, ab, m, da), (ab, b, bc, m), (m, bc, c, cd), (da, m, cd, d)):
            parts.append(np.stack(p, axis=1))
    cells = np.concatenate(parts)
    points = cells.reshape(-1, 2)
    return cells_mesh(points, quads=np.arange(points.shape[0]).reshape(-1, 4))


def static_error_estimate(profile, mesh, contact="welded", cache_dir=None, order=None) -> dict:
    """Estimated relative discretisation error of the static rigid impedances of ``mesh``.

    ``order`` p: None, ``MESH_ORDER`` for a mesh whose outline cells carry the edge-singular
    shape (``bem.edge_tractions`` not "constant"), else ``ORDER``.

    Returns ``{"errors": {dof: relative error of K_h[dof, dof] (signed, -), ...}, "order": p,
    "n": N, "n_refined": 4N}``, or ``{"skipped": reason}`` when the refined mesh cannot be made
    (a node list), exceeds MAX_REFINED_NODES or MAX_NODES, or would not fit in the available memory (the sweep's own
    check, ``sweep.check_sweep_memory``). Both static solves go through ``static_impedance``
    (cached in ``cache_dir`` like any table).
    """
    from .bem import edge_tractions
    from .sweep import SweepMemoryError, check_sweep_memory, static_impedance
    if order is None:
        order = ORDER if edge_tractions(mesh) == "constant" else MESH_ORDER
    if 4 * mesh.n > MAX_REFINED_NODES:
        return {"skipped": f"the refined mesh would have about {4 * mesh.n} nodes, more than "
                           f"MAX_REFINED_NODES = {MAX_REFINED_NODES} (its static solve would take minutes): "
                           "compare with a run at half the element size instead"}
    try:
        fine = refined_mesh(mesh)
        check_sweep_memory(fine, 1, ("rigid",))
    except (MeshError, SweepMemoryError) as exc:
        return {"skipped": str(exc)}
    coarse_k = np.diag(static_impedance(profile, mesh, contact, "rigid", cache_dir=cache_dir).real)
    fine_k = np.diag(static_impedance(profile, fine, contact, "rigid", cache_dir=cache_dir).real)
    w = 2.0 ** order
    geometric = _geometric_factor(mesh), _geometric_factor(fine)
    extrapolated = (w * fine_k / geometric[1] - coarse_k / geometric[0]) / (w - 1)
    err = (coarse_k - extrapolated) / extrapolated
    return {"errors": {d: float(e) for d, e in zip(RIGID_DOFS, err)}, "order": order,
            "n": mesh.n, "n_refined": fine.n}


def _geometric_factor(mesh) -> np.ndarray:
    """(R_eq/R)^k per rigid DOF for a circle grid (see the module docstring), ones otherwise."""
    if mesh.kind != "circle":
        return np.ones(6)
    R, h2 = mesh.size[0], mesh.cell ** 2
    x, y = mesh.xy.T
    area = mesh.n * h2
    ix = np.sum(y ** 2 + h2 / 12) * h2            # second moment about x (rx)
    iy = np.sum(x ** 2 + h2 / 12) * h2
    j = ix + iy
    ra = np.sqrt(area / np.pi) / R
    rx, ry, rj = (4 * ix / np.pi) ** 0.25 / R, (4 * iy / np.pi) ** 0.25 / R, (2 * j / np.pi) ** 0.25 / R
    return np.array([ra, ra, ra, rx ** 3, ry ** 3, rj ** 3])

"""Interface meshes: patches of the soil surface under the raft, one node per patch.

A mesh is a set of nodes (x, y) on the plane z = 0 with the area of the patch each node
stands for. Regular meshes (circle, rectangle) are made of equal square cells of side
``cell`` on a grid: every node offset is an integer multiple of ``cell``, which the BEM
exploits (translation invariance: only distinct offsets are computed). A user node list
has no grid (``cell is None``); its patches are taken as squares of the same area. A
finite-element mesh of the raft (``cells_mesh``: triangles and quadrilaterals) keeps each
cell's true polygon (``cells``), its node at the cell's area centroid.
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from uplift_common.errors import UserInputError
from uplift_common.interface import interface_points


class MeshError(UserInputError):
    """An invalid interface mesh input; the message names the input and how to fix it."""


#: a hard limit on the interface nodes of a mesh, whatever the machine: the BEM is dense, one LU
#: of (3N)^2 complex values per frequency, O(N^3) time (minutes per frequency at N = 5000; the
#: reactor raft needs 241). Whether a sweep fits in memory is checked separately, before it
#: allocates, from the machine's available memory (``sweep.check_sweep_memory``).
MAX_NODES = 5000


def _too_many(n: float, where: str, h_min: float, about: bool = False):
    count = f"about {n:.3g}" if about else f"{n:d}"
    raise MeshError(f"{where} gives {count} interface nodes; at most MAX_NODES = {MAX_NODES} (the dense BEM "
                    f"takes O(N^3) time per frequency): use element_size >= {h_min:.3g} m")


#: above this many nodes the duplicate check finds nearest neighbours with a k-d tree, in
#: O(n log n) (scipy.spatial); at or below it by blocks of exact pairwise distances in numpy, which
#: for such sizes is as fast and spares a run the import of scipy.spatial (0.1-0.15 s)
KDTREE_NODES = 1024


def _closest_pair(xy: np.ndarray) -> tuple[float, int, int]:
    """(distance m, k, other): the smallest distance between two distinct nodes of ``xy`` (n, 2),
    n >= 2, node ``k`` and its nearest neighbour ``other`` (k the first node at that distance)."""
    n = xy.shape[0]
    if n > KDTREE_NODES:                         # nearest neighbours in O(n log n)
        from scipy.spatial import cKDTree
        dist, idx = cKDTree(xy).query(xy, k=2)
        other = np.where(idx[:, 1] != np.arange(n), idx[:, 1], idx[:, 0])
        k = int(np.argmin(dist[:, 1]))
        return float(dist[k, 1]), k, int(other[k])
    nearest, which = np.empty(n), np.empty(n, dtype=np.intp)
    for r in range(0, n, 256):                   # at most 256 x n distances at a time
        rows = np.arange(r, min(r + 256, n))
        d = np.hypot(xy[rows, None, 0] - xy[None, :, 0], xy[rows, None, 1] - xy[None, :, 1])
        d[np.arange(rows.size), rows] = np.inf  # not a node's distance to itself
        which[rows] = np.argmin(d, axis=1)
        nearest[rows] = d[np.arange(rows.size), which[rows]]
    k = int(np.argmin(nearest))
    return float(nearest[k]), k, int(which[k])


@dataclass(frozen=True, eq=False)
class InterfaceMesh:
    """Interface nodes and their tributary areas.

    Attributes
    ----------
    xy : ndarray, shape (n, 2), m     node coordinates about the raft centre
    area : ndarray, shape (n,), m^2   tributary (patch) areas
    cell : float or None, m           side of the square cells of a regular grid mesh
    kind : str                        "circle", "rectangle", "nodes" or "cells"
    size : tuple                      (radius,) or (lx, ly) for the regular shapes; () otherwise
    cells : ndarray, shape (n, 4, 2), m, or None
        the polygon of each node's cell (kind "cells", from a finite-element mesh): vertices
        counter-clockwise in the frame of ``xy``, a triangle with its third vertex repeated
        (``cells[:, 2] == cells[:, 3]``, an edge of zero length); ``xy`` is then each cell's
        area centroid and ``area`` its area
    """

    xy: np.ndarray
    area: np.ndarray
    cell: float | None = None
    kind: str = "nodes"
    size: tuple = ()
    cells: np.ndarray | None = None

    def __post_init__(self):
        xy, area = interface_points(self.xy, self.area, MeshError, "mesh")
        if xy.shape[0] > MAX_NODES:
            raise MeshError(f"the interface mesh has {xy.shape[0]} nodes; at most MAX_NODES = {MAX_NODES} "
                            "(the dense BEM takes O(N^3) time per frequency): use fewer, larger patches")
        if xy.shape[0] > 1:
            d, k, other = _closest_pair(xy)
            i, j = sorted((k, other))
            if d < 1e-9 * max(1.0, np.abs(xy).max()):
                raise MeshError(f"mesh nodes {i} and {j} coincide at ({xy[i, 0]:g}, {xy[i, 1]:g}): "
                                "remove the duplicate")
        object.__setattr__(self, "xy", xy)
        object.__setattr__(self, "area", area)

    @property
    def n(self) -> int:
        return self.xy.shape[0]

    @property
    def total_area(self) -> float:
        return float(self.area.sum())

    @property
    def radius(self) -> float:
        """Characteristic half-size R used in a0 = ωR/Vs: the disk radius, the half-width
        sqrt(lx ly)/2... for rectangles the equivalent-area radius, for node lists the
        equivalent-area radius sqrt(A/π)."""
        if self.kind == "circle":
            return float(self.size[0])
        return math.sqrt(self.total_area / math.pi)

    @property
    def patch_half_sides(self) -> np.ndarray:
        """Half side of the square patch of each node, m: cell/2 on a grid, sqrt(area)/2 otherwise."""
        if self.cell is not None:
            return np.full(self.n, 0.5 * self.cell)
        return 0.5 * np.sqrt(self.area)

    def grid_index(self) -> np.ndarray:
        """Integer grid coordinates of the nodes, shape (n, 2) (regular meshes only)."""
        if self.cell is None:
            raise MeshError("grid_index needs a regular (circle or rectangle) mesh")
        return np.rint(self.xy / self.cell - 0.5 * self._grid_shift()).astype(int)

    def _grid_shift(self) -> np.ndarray:
        # offsets of the grid origin: cell centres sit at (i + s) * cell with s in {0, 1/2}
        frac = self.xy[0] / self.cell - np.floor(self.xy[0] / self.cell)
        return np.where(np.isclose(frac, 0.5, atol=1e-6), 1.0, 0.0)


def _check_size(name: str, value) -> float:
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value) or value <= 0:
        raise MeshError(f"foundation.{name} = {value!r} must be a positive length in m")
    return float(value)


def circle_mesh(radius: float, element_size: float) -> InterfaceMesh:
    """Disk of radius R as the square cells (side h) of a grid whose centres fall inside it.

    The grid is centred on the disk (a node at the centre) with cell side ``element_size``;
    each cell keeps its full square area, so the total area differs from πR² by the
    staircase boundary (an O(h) error like the piecewise-constant tractions, and irregular
    in h: compare with closed forms at the mesh's equivalent radius sqrt(A/π)).
    """
    radius = _check_size("radius", radius)
    h = _check_size("element_size", element_size)
    if h > radius:
        raise MeshError(f"foundation.element_size = {h} m exceeds the radius {radius} m: "
                        "use element_size <= radius / 2 (about radius / 9 for the reactor raft)")
    where = f"foundation.element_size = {h:g} m on a disk of radius {radius:g} m"
    h_min = radius * math.sqrt(math.pi / MAX_NODES)
    estimate = math.pi * (radius / h) * (radius / h)
    if estimate > 2 * MAX_NODES:                         # refuse before allocating the grid
        _too_many(estimate, where, h_min, about=True)
    m = int(math.ceil(radius / h)) + 1
    i, j = np.meshgrid(np.arange(-m, m + 1), np.arange(-m, m + 1), indexing="ij")
    inside = (i ** 2 + j ** 2) * h * h <= radius * radius * (1 + 1e-12)
    xy = np.column_stack([i[inside], j[inside]]).astype(float) * h
    if xy.shape[0] > MAX_NODES:
        _too_many(xy.shape[0], where, h_min)
    area = np.full(xy.shape[0], h * h)
    return InterfaceMesh(xy, area, cell=h, kind="circle", size=(radius,))


def rectangle_mesh(lx: float, ly: float, element_size: float) -> InterfaceMesh:
    """Rectangle lx × ly centred on the origin, as nx × ny equal cells (side close to element_size).

    The cells are square only when lx/nx == ly/ny; otherwise ``cell`` is None and the patches
    are treated as equal-area squares.
    """
    lx, ly = _check_size("lx", lx), _check_size("ly", ly)
    h = _check_size("element_size", element_size)
    if h > max(lx, ly):
        raise MeshError(f"foundation.element_size = {h} m exceeds the rectangle {lx} m x {ly} m: "
                        "use element_size <= min(lx, ly) / 2")
    where = f"foundation.element_size = {h:g} m on a {lx:g} m x {ly:g} m rectangle"
    if (lx / h) * (ly / h) > 2 * MAX_NODES:                # refuse before allocating the grid
        _too_many((lx / h) * (ly / h), where, math.sqrt(lx * ly / MAX_NODES), about=True)
    nx, ny = max(1, round(lx / h)), max(1, round(ly / h))
    if nx * ny > MAX_NODES:
        _too_many(nx * ny, where, math.sqrt(lx * ly / MAX_NODES))
    hx, hy = lx / nx, ly / ny
    x = (np.arange(nx) + 0.5) * hx - lx / 2
    y = (np.arange(ny) + 0.5) * hy - ly / 2
    X, Y = np.meshgrid(x, y, indexing="ij")
    xy = np.column_stack([X.ravel(), Y.ravel()])
    cell = hx if math.isclose(hx, hy, rel_tol=1e-9) else None
    return InterfaceMesh(xy, np.full(xy.shape[0], hx * hy), cell=cell, kind="rectangle", size=(lx, ly))


def nodes_mesh(xy, area) -> InterfaceMesh:
    """A user node list with tributary areas (no grid)."""
    return InterfaceMesh(np.asarray(xy, float), np.asarray(area, float), cell=None, kind="nodes")


def polygon_area_centroid(poly: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Signed area (m^2, > 0 counter-clockwise) and area centroid of polygons, shape (n, k, 2)."""
    x, y = poly[..., 0], poly[..., 1]
    xn, yn = np.roll(x, -1, axis=-1), np.roll(y, -1, axis=-1)
    cross = x * yn - xn * y
    area = 0.5 * cross.sum(axis=-1)
    safe = np.where(area != 0, area, 1.0)
    cx = ((x + xn) * cross).sum(axis=-1) / (6 * safe)
    cy = ((y + yn) * cross).sum(axis=-1) / (6 * safe)
    return area, np.column_stack([cx, cy])


def cells_mesh(points, triangles=(), quads=(), centre=(0.0, 0.0)) -> InterfaceMesh:
    """An interface of linear triangles and quadrilaterals: one node per cell, at its area centroid.

    Parameters
    ----------
    points : array_like (m, 2), m          vertex coordinates on the raft plane
    triangles, quads : int arrays (nt, 3), (nq, 4)   vertex indices of each cell (either orientation)
    centre : (x, y), m                      the raft reference point: the mesh is shifted so that it
                                            is the origin of ``xy`` and ``cells``

    Cells are oriented counter-clockwise; a cell of zero area is refused naming its index.
    """
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 2 or not np.all(np.isfinite(pts)):
        raise MeshError(f"mesh points must be a finite (m, 2) array of x, y, got shape {pts.shape}")
    polys = []
    for conn, k in ((triangles, 3), (quads, 4)):
        conn = np.asarray(conn, dtype=np.int64).reshape(-1, k)
        if conn.size and (conn.min() < 0 or conn.max() >= pts.shape[0]):
            raise MeshError(f"mesh cells refer to vertex indices outside 0..{pts.shape[0] - 1}")
        p = pts[conn]
        polys.append(np.concatenate([p, p[:, 2:3]], axis=1) if k == 3 else p)
    poly = np.concatenate(polys) - np.asarray(centre, dtype=float)
    if poly.shape[0] == 0:
        raise MeshError("the mesh has no triangle or quadrilateral cells")
    area, centroid = polygon_area_centroid(poly)
    size = float(np.abs(poly).max())
    flat = np.flatnonzero(np.abs(area) <= 1e-12 * max(size * size, 1e-300))
    if flat.size:
        raise MeshError(f"mesh cell {flat[0]} has zero area (its vertices are on one line or repeated): "
                        "remove or repair the degenerate cells")
    tri = np.all(poly[:, 2] == poly[:, 3], axis=1)
    flip = area < 0
    poly[flip & ~tri] = poly[flip & ~tri, ::-1]
    poly[flip & tri] = poly[flip & tri][:, [1, 0, 2, 3]]     # v1 v0 v2 (v2): the repeated vertex stays last
    poly = np.ascontiguousarray(poly)
    poly.setflags(write=False)
    return InterfaceMesh(centroid, np.abs(area), cell=None, kind="cells", cells=poly)


def read_nodes_csv(path) -> InterfaceMesh:
    """Read a CSV with header ``x,y,area`` (m, m, m²), one interface node per row."""
    path = Path(path)
    if not path.is_file():
        raise MeshError(f"foundation.file = {str(path)!r}: no such file (paths are relative to the scene file)")
    with path.open(newline="") as fh:
        reader = csv.DictReader(fh)
        header = [h.strip() for h in (reader.fieldnames or [])]
        if header[:3] != ["x", "y", "area"]:
            raise MeshError(f"{path}: the CSV header must be 'x,y,area', got {','.join(header)!r}")
        rows = []
        for k, row in enumerate(reader, start=2):
            try:
                rows.append([float(row[h]) for h in reader.fieldnames[:3]])
            except (TypeError, ValueError):
                raise MeshError(f"{path}, line {k}: expected three numbers x, y, area, got {row}") from None
    if not rows:
        raise MeshError(f"{path}: the node list is empty; give at least one row x,y,area")
    data = np.array(rows)
    try:
        mesh = nodes_mesh(data[:, :2], data[:, 2])
    except MeshError as exc:
        raise MeshError(f"{path}: {exc}") from None
    check_footprint(mesh, str(path))
    return mesh


def check_footprint(mesh: InterfaceMesh, where: str) -> None:
    """Refuse a node list that cannot carry a structure's rocking: fewer than three nodes, all
    nodes on one line (no resistance to overturning about that line), or the raft centre (0, 0),
    where the weight and the overturning moment act, not strictly inside the footprint (the
    convex hull of the nodes). Areas are checked by InterfaceMesh. ``where`` names the input."""
    xy = mesh.xy
    fix = ("give at least three nodes around the raft centre (0, 0), in x, y about it, e.g. the corners "
           "and the centres of the patches under the raft")
    if mesh.n < 3:
        raise MeshError(f"{where}: {mesh.n} interface node{'s' if mesh.n > 1 else ''}: a raft on fewer than three "
                        f"points cannot carry an overturning moment; {fix}")
    extent = float(np.abs(xy).max())
    centred = xy - xy.mean(axis=0)
    s = np.linalg.svd(centred, compute_uv=False)
    if s[1] <= 1e-9 * max(s[0], extent):
        raise MeshError(f"{where}: all {mesh.n} interface nodes lie on one line: the raft cannot carry an "
                        f"overturning moment about it; {fix}")
    from scipy.spatial import ConvexHull
    hull = ConvexHull(xy)
    margin = -hull.equations[:, 2].max()        # distance of (0, 0) inside the nearest hull edge
    if margin <= 1e-6 * extent:
        raise MeshError(f"{where}: the raft centre (0, 0) is {'on the edge of' if margin > -1e-6 * extent else 'outside'}"
                        f" the footprint of the nodes (their convex hull): the weight would tip the raft over "
                        f"that edge; {fix}")

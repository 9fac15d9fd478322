"""The engineer's finite-element raft mesh as the interface: ``read_mesh(path, group, centre)``.

The file is read through meshio: gmsh ``.msh`` (2.2 and 4.1), MED ``.med``, Abaqus ``.inp``,
VTK ``.vtk`` and ``.vtu``. The interface is made of its linear triangles and quadrilaterals,
either every 2-D cell of the file (a 2-D mesh, or one whose points all have the same z) or the
cells of one named group (``group``: a gmsh physical group, an Abaqus element set or
element-based surface (``*SURFACE``: faces of linear tetrahedra, wedges, hexahedra), a MED
group), e.g. the base faces of a 3-D mesh of the raft. Each cell becomes one interface node at its area
centroid (``soil_impedance.mesh.cells_mesh``), in the frame of the raft centre ``centre``
((x, y) in the file's coordinates, m; default: the area centroid of the interface).

Refused before any computation, with a one-line ``MeshError`` naming the file and the fix: an
unreadable file or an unknown format, no 2-D cell (in the group: the groups that exist are
listed), cells off a horizontal plane z = const (non-planar or tilted), higher-order cells,
polygons, degenerate cells (zero area, a quadrilateral not convex), overlapping cells (the same
cell twice, an edge shared by more than two cells, superposed parts), a raft in several pieces,
more cells than ``MAX_NODES``, and what ``check_footprint`` refuses (the centre outside the
footprint). Holes (openings) in the raft are allowed. Coincident points of the file (the same
coordinates under two numbers) are merged before the checks.
"""
from __future__ import annotations

import contextlib
import hashlib
import io
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .mesh import MAX_NODES, InterfaceMesh, MeshError, cells_mesh, check_footprint, polygon_area_centroid

#: the formats read, by file suffix: meshio's format name and what to call it in messages
FORMATS = {".msh": ("gmsh", "gmsh"), ".med": ("med", "MED"), ".inp": ("abaqus", "Abaqus"),
           ".vtk": ("vtk", "VTK"), ".vtu": ("vtu", "VTU")}
#: the linear 2-D cells (meshio's names) and their vertex counts
LINEAR = {"triangle": 3, "quad": 4}
#: relative tolerances: points closer than MERGE x the mesh's extent are one point; z varying by
#: less than PLANE x the extent is one plane; cells apart (or into each other) by less than
#: TOUCH x the median cell size touch; a cell whose area is under FLAT x its diameter^2 is flat
MERGE, PLANE, TOUCH, FLAT = 1e-9, 1e-6, 1e-6, 1e-8


@dataclass(frozen=True)
class MeshSource:
    """Where an interface mesh was read from: the file (absolute path), the SHA-256 of its
    content, its format, the group selected (None: every 2-D cell) and the raft centre in the
    file's coordinates (m): the provenance a results file keeps."""
    path: Path
    sha256: str
    format: str
    group: str | None
    centre: tuple[float, float]

    def as_dict(self) -> dict:
        return {"path": str(self.path), "sha256": self.sha256, "format": self.format,
                "group": self.group, "centre": list(self.centre)}


def read_mesh(path, group: str | None = None, centre=None) -> InterfaceMesh:
    """The interface mesh of a finite-element file (see the module docstring).

    Parameters
    ----------
    path : str or Path            the mesh file (.msh, .med, .inp, .vtk, .vtu)
    group : str or None           the named group of cells to take (None: every 2-D cell)
    centre : (x, y) or None, m    the raft centre in the file's coordinates (None: the area
                                  centroid of the interface)

    Returns an InterfaceMesh of kind "cells" (one node per cell at its centroid, about the
    centre). Raises MeshError naming the file and the fix.
    """
    return read_mesh_source(path, group, centre)[0]


def read_mesh_source(path, group: str | None = None, centre=None) -> tuple[InterfaceMesh, MeshSource]:
    """(InterfaceMesh, MeshSource) of ``read_mesh``: the mesh and where it came from."""
    path = Path(path)
    name = f"mesh file {str(path)!r}"
    if centre is not None:
        centre = _centre(centre, name)
    fmt, label, raw = _open(path, name)
    mesh = _meshio_read(path, fmt, label, name)
    read_blocks = len(mesh.cells)
    if fmt == "abaqus":
        try:
            _add_abaqus_surfaces(mesh, raw, name)
        except MeshError:
            raise
        except (ValueError, IndexError) as exc:
            raise MeshError(f"{name}: cannot read its *ELEMENT or *SURFACE lines ({exc}): check the file, or give "
                            "the raft's base as an element set of surface elements") from None
    blocks = _select(mesh, group, label, name, read_blocks)
    pts3, tris, quads = _cells(mesh, blocks, group, name)
    pts = _planar(pts3, tris, quads, group, mesh, name)
    pts, tris, quads = _merged(pts, tris, quads)
    used = pts[np.unique(np.concatenate([tris.ravel(), quads.ravel()]))]
    offset = 0.5 * (used.min(axis=0) + used.max(axis=0))     # checks and areas near the origin (site
    pts = pts - offset                                        # coordinates: x ~ 1e5 m cost no digits)
    poly, ids = _polygons(pts, tris, quads)
    n = poly.shape[0]
    if n > MAX_NODES:
        raise MeshError(f"{name}: {n} cells, each an interface node; at most MAX_NODES = {MAX_NODES} (the BEM "
                        f"stores (3N)^2 complex values per frequency): mesh the raft coarser")
    _check_cells(poly, ids, name, offset)
    if centre is None:
        area, centroid = polygon_area_centroid(poly)
        centre = tuple(float(c) for c in (area @ centroid) / area.sum() + offset)
    try:
        out = cells_mesh(pts, tris, quads, np.subtract(centre, offset))
        _centre_inside(out, centre, name)
        check_footprint(out, name)
    except MeshError as exc:
        text = str(exc)
        raise MeshError(text if text.startswith(name) else f"{name}: {text}") from None
    source = MeshSource(path.resolve(), hashlib.sha256(raw).hexdigest(), label, group, centre)
    return out, source


def _open(path: Path, name: str):
    """(meshio format, label, bytes) of the file, or MeshError: missing, unreadable, unknown suffix."""
    fmt = FORMATS.get(path.suffix.lower())
    if fmt is None:
        known = ", ".join(f"{s} ({lab})" for s, (_, lab) in FORMATS.items())
        raise MeshError(f"{name}: unknown mesh format {path.suffix or '(no suffix)'!r}; give one of {known}")
    if not path.is_file():
        raise MeshError(f"{name}: no such file (paths are relative to the scene file)")
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise MeshError(f"{name} cannot be read: {exc.strerror}") from None
    return fmt[0], fmt[1], raw


def _meshio_read(path: Path, fmt: str, label: str, name: str):
    """meshio's reader of ``fmt`` on the file (its own, not ``meshio.read``, which exits the
    process on a file it cannot parse), its console warnings kept out of the terminal."""
    import meshio  # ~0.5 s at start-up: only scenes with a mesh file pay it
    said = io.StringIO()
    try:
        with contextlib.redirect_stderr(said), contextlib.redirect_stdout(said):
            return getattr(meshio, fmt).read(str(path))
    except MemoryError:
        raise
    except Exception as exc:                 # meshio's parsers raise anything on a damaged file
        why = " ".join((str(exc) or said.getvalue() or type(exc).__name__).split())[:200]
        raise MeshError(f"{name} cannot be read as a {label} file ({why}): check that it is a {label} mesh, "
                        f"or export it again") from None


def _groups(mesh) -> dict:
    """{group name: [per block: bool mask of its cells]} of every named group of the file:
    meshio's cell sets (gmsh 4.1 physical groups, Abaqus element sets), gmsh 2.2 physical names
    (field data and the ``gmsh:physical`` tags), MED groups (families of ``cell_tags``)."""
    sizes = [len(b.data) for b in mesh.cells]
    out = {}
    for gname, per_block in (mesh.cell_sets or {}).items():
        if gname.startswith("gmsh:"):
            continue
        masks = []
        for size, idx in zip(sizes, per_block):
            m = np.zeros(size, bool)
            if idx is not None and len(idx):
                m[np.asarray(idx, dtype=np.int64)] = True
            masks.append(m)
        out[gname] = masks
    physical = mesh.cell_data.get("gmsh:physical")
    if physical is not None:
        for gname, (tag, dim) in (mesh.field_data or {}).items():
            if gname not in out:
                out[gname] = [(np.asarray(p) == tag) & (_dim(b.type) == dim) for b, p in zip(mesh.cells, physical)]
    tags = mesh.cell_data.get("cell_tags")
    families = getattr(mesh, "cell_tags", None) or {}
    if tags is not None and families:
        names = sorted({g for gs in families.values() for g in gs})
        for gname in names:
            fams = [f for f, gs in families.items() if gname in gs]
            out.setdefault(gname, [np.isin(np.asarray(t), fams) for t in tags])
    return out


def _dim(cell_type: str) -> int:
    for prefix, d in (("vertex", 0), ("line", 1), ("triangle", 2), ("quad", 2), ("polygon", 2)):
        if cell_type.startswith(prefix):
            return d
    return 3


def _select(mesh, group, label: str, name: str, read_blocks: int) -> list:
    """[(block, mask)] of the cells to take: every cell of the file (its first ``read_blocks``
    blocks: not the faces of Abaqus surfaces), or those of ``group``."""
    if group is None:
        return [(b, np.ones(len(b.data), bool)) for b in mesh.cells[:read_blocks]]
    groups = _groups(mesh)
    if group not in groups:
        if not groups:
            hint = ("VTK files carry no named groups: write only the raft's base cells, or use a .msh, .med or "
                    ".inp file" if label in ("VTK", "VTU") else "the file has no named groups: remove "
                    "foundation.mesh_group to take every 2-D cell")
            raise MeshError(f"{name}: no group {group!r}; {hint}")
        raise MeshError(f"{name}: no group {group!r}; the groups of the file are {', '.join(sorted(groups))}: "
                        "set foundation.mesh_group to the one of the raft's base")
    return list(zip(mesh.cells, groups[group]))


#: the faces of Abaqus solid elements (meshio's cell type) by face label, 0-based node positions
ABAQUS_FACES = {
    "tetra": {"S1": (0, 1, 2), "S2": (0, 3, 1), "S3": (1, 3, 2), "S4": (2, 3, 0)},
    "wedge": {"S1": (0, 1, 2), "S2": (3, 5, 4), "S3": (0, 3, 4, 1), "S4": (1, 4, 5, 2), "S5": (2, 5, 3, 0)},
    "hexahedron": {"S1": (0, 1, 2, 3), "S2": (4, 7, 6, 5), "S3": (0, 4, 5, 1), "S4": (1, 5, 6, 2),
                   "S5": (2, 6, 7, 3), "S6": (3, 7, 4, 0)},
}


def _add_abaqus_surfaces(mesh, raw: bytes, name: str) -> None:
    """Append the element-based surfaces of an Abaqus file (``*SURFACE, NAME=base``, lines
    ``element or element set, S<k>``) to ``mesh`` as blocks of their faces (triangles,
    quadrilaterals) and cell sets of their names, which meshio does not read."""
    import meshio  # (imported by _meshio_read already)
    text = raw.decode("latin-1").splitlines()
    numbers, surfaces, k = [], {}, 0
    while k < len(text):
        line = text[k].strip()
        head = line.upper()
        k += 1
        if head.startswith("*ELEMENT") and not head.startswith("*ELEMENT OUTPUT"):
            ids = []
            while k < len(text) and not text[k].lstrip().startswith("*"):
                ids += [int(v) for v in text[k].replace(",", " ").split()]
                k += 1
            numbers.append(ids)
        elif head.startswith("*SURFACE") and "TYPE=NODE" not in head.replace(" ", ""):
            params = dict(p.split("=", 1) for p in line.replace(" ", "").split(",")[1:] if "=" in p)
            sname = next((v for key, v in params.items() if key.upper() == "NAME"), None)
            faces = []
            while k < len(text) and not text[k].lstrip().startswith("*"):
                parts = [v.strip() for v in text[k].split(",") if v.strip()]
                if len(parts) >= 2:
                    faces.append((parts[0], parts[1].upper()))
                k += 1
            if sname is not None:
                surfaces[sname] = faces
    if not surfaces:
        return
    where = {}
    for b, (block, ids) in enumerate(zip(mesh.cells, numbers)):
        width = block.data.shape[1] + 1
        if len(ids) != width * len(block.data):
            raise MeshError(f"{name}: cannot match the element numbers of its *ELEMENT blocks with the mesh read: "
                            "write the raft's base as an element set of surface elements instead of a *SURFACE")
        for i, number in enumerate(ids[::width]):
            where[number] = (b, i)
    added, sets = [], {key.upper(): v for key, v in (mesh.cell_sets or {}).items()}
    for sname, faces in surfaces.items():
        out = {3: [], 4: []}
        for item, label in faces:
            if item.lstrip("-").isdigit():
                cells = [where.get(int(item))]
            elif item.upper() in sets:
                cells = [(b, int(i)) for b, idx in enumerate(sets[item.upper()]) for i in np.asarray(idx, np.int64)]
            else:
                raise MeshError(f"{name}: *SURFACE {sname} names {item!r}, which is neither an element number "
                                "nor an element set of the file: correct the surface definition")
            for cell in cells:
                if cell is None:
                    raise MeshError(f"{name}: *SURFACE {sname} names element {item}, which the file does not have")
                block = mesh.cells[cell[0]]
                face = ABAQUS_FACES.get(block.type, {}).get(label)
                if face is None:
                    raise MeshError(f"{name}: *SURFACE {sname}: face {label} of a {block.type} element is not read "
                                    "(faces of linear tetrahedra, wedges and hexahedra are): write the raft's base "
                                    "as an element set of surface elements")
                out[len(face)].append(np.asarray(block.data[cell[1]])[list(face)])
        added += [(sname, t, np.array(f, np.int64)) for t, f in (("triangle", out[3]), ("quad", out[4])) if f]
    none = np.zeros(0, np.int64)
    read = len(mesh.cells)
    cell_sets = {key: list(v) + [none] * len(added) for key, v in (mesh.cell_sets or {}).items()}
    for sname in {a[0] for a in added}:
        cell_sets[sname] = [none] * read + [np.arange(len(c)) if s == sname else none for s, _, c in added]
    mesh.cells = list(mesh.cells) + [meshio.CellBlock(t, c) for _, t, c in added]
    mesh.cell_sets = cell_sets


def _cells(mesh, blocks, group, name):
    """(points (m, 3), triangles, quads) of the selected 2-D cells; MeshError when there
    is none, or when they are higher order or polygons."""
    tris, quads, other = [], [], {}
    for block, mask in blocks:
        if not mask.any():
            continue
        if block.type in LINEAR:
            (tris if block.type == "triangle" else quads).append(np.asarray(block.data)[mask])
        elif _dim(block.type) == 2:
            kind = block.type
            if kind == "polygon" or kind.startswith("polygon"):
                raise MeshError(f"{name}: {int(mask.sum())} polygon cells; only triangles and quadrilaterals are "
                                "read: split them (gmsh: Mesh.RecombineAll = 0 or 1)")
            raise MeshError(f"{name}: {int(mask.sum())} higher-order cells ({kind}); the interface takes linear "
                            "triangles and quadrilaterals (one node per cell): mesh with order 1 (gmsh: "
                            "Mesh.ElementOrder = 1, or -order 1)")
        else:
            other[block.type] = other.get(block.type, 0) + int(mask.sum())
    if not tris and not quads:
        where = f"group {group!r}" if group is not None else "the file"
        held = f" ({', '.join(f'{n} {t}' for t, n in other.items())})" if other else ""
        fix = ("select the group of the raft's base faces with foundation.mesh_group" if group is not None or other
               else "mesh the raft's base as triangles or quadrilaterals")
        groups = sorted(_groups(mesh))
        listed = f"; groups: {', '.join(groups)}" if groups else ""
        raise MeshError(f"{name}: {where} has no triangle or quadrilateral cells{held}: {fix}{listed}")
    tri = np.concatenate(tris).astype(np.int64) if tris else np.zeros((0, 3), np.int64)
    quad = np.concatenate(quads).astype(np.int64) if quads else np.zeros((0, 4), np.int64)
    pts = np.asarray(mesh.points, float)
    if pts.shape[1] == 2:
        pts = np.column_stack([pts, np.zeros(len(pts))])
    return pts, tri, quad


def _planar(pts3, tris, quads, group, mesh, name):
    """The (x, y) of the points when every vertex of the cells has one z (a horizontal plane),
    else MeshError (non-planar, tilted, or a 3-D mesh's faces without a group)."""
    used = np.unique(np.concatenate([tris.ravel(), quads.ravel()]))
    if used.size and (used.min() < 0 or used.max() >= len(pts3)):
        raise MeshError(f"{name}: cells refer to point numbers the file does not have: export the mesh again")
    p = pts3[used]
    if not np.all(np.isfinite(p)):
        raise MeshError(f"{name}: point coordinates that are not finite numbers: export the mesh again")
    extent = float(np.ptp(p[:, :2], axis=0).max()) or 1.0
    z = p[:, 2]
    if np.ptp(z) > PLANE * extent:
        groups = sorted(_groups(mesh))
        listed = f" (groups: {', '.join(groups)})" if groups else ""
        fix = (f"select the base faces with foundation.mesh_group{listed}" if group is None else f"group {group!r} is not the raft's base: choose its flat, horizontal faces")
        raise MeshError(f"{name}: the cells are not on one horizontal plane z = const (z from {z.min():.6g} to "
                        f"{z.max():.6g} m): the interface is the flat raft base, z up (a non-planar or tilted "
                        f"surface is refused); {fix}")
    return pts3[:, :2].copy()


def _merged(pts, tris, quads):
    """Points of the same coordinates (within MERGE x the extent) made one; unused points kept."""
    extent = float(np.abs(pts).max(initial=0.0)) or 1.0
    key = np.round(pts / (MERGE * extent)).astype(np.int64)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.ravel()
    return pts[first], inverse[tris], inverse[quads]


def _polygons(pts, tris, quads):
    """(polygons (n, 4, 2) counter-clockwise, vertex ids (n, 4)): triangles with their third
    vertex repeated, in the order triangles then quadrilaterals (that of ``cells_mesh``)."""
    ids = np.concatenate([np.concatenate([tris, tris[:, 2:3]], axis=1), quads])
    poly = pts[ids]
    area, _ = polygon_area_centroid(poly)
    flip = area < 0
    poly[flip] = poly[flip, ::-1]
    ids = ids.copy()
    ids[flip] = ids[flip, ::-1]
    return poly, ids


def _where(poly, offset, k: int) -> str:
    c = poly[k].mean(axis=0) + offset
    return f"cell {k} (near x = {c[0]:.6g}, y = {c[1]:.6g} m)"


def _check_cells(poly, ids, name, offset):
    """Degenerate, duplicate and overlapping cells, edges of more than two cells, pieces
    (``poly`` about ``offset``, the file's coordinates of its origin, which messages add back)."""
    n = poly.shape[0]
    area, _ = polygon_area_centroid(poly)
    diam = np.max(np.linalg.norm(poly[:, :, None, :] - poly[:, None, :, :], axis=-1), axis=(1, 2))
    edge = np.roll(poly, -1, axis=1) - poly                        # (n, 4, 2)
    turn = edge[:, :, 0] * np.roll(edge, -1, axis=1)[:, :, 1] - edge[:, :, 1] * np.roll(edge, -1, axis=1)[:, :, 0]
    folded = np.flatnonzero((turn < -FLAT * diam[:, None] ** 2).any(axis=1))
    if folded.size:
        raise MeshError(f"{name}: {_where(poly, offset, folded[0])} is a quadrilateral that is not convex (folded, "
                        f"bow-tie or with a reflex corner; {folded.size} such cells): repair it or split it into "
                        "triangles")
    flat = np.flatnonzero(area <= FLAT * diam ** 2)
    if flat.size:
        raise MeshError(f"{name}: {_where(poly, offset, flat[0])} has zero area (its vertices are on one line or "
                        f"repeated; {flat.size} such cells): repair or remove the degenerate cells")
    key = np.sort(ids, axis=1)
    key = np.where(key[:, :1] == key[:, 1:2], np.roll(key, -1, axis=1), key)   # a triangle's repeat first
    _, first, counts = np.unique(np.sort(key, axis=1), axis=0, return_index=True, return_counts=True)
    if (counts > 1).any():
        k = first[np.flatnonzero(counts > 1)[0]]
        raise MeshError(f"{name}: {_where(poly, offset, k)} is in the mesh {counts.max()} times (duplicate cells; "
                        f"{int((counts - 1).sum())} copies): remove the duplicates")
    a, b = ids, np.roll(ids, -1, axis=1)
    real = a != b
    edges = np.sort(np.stack([a[real], b[real]], axis=1), axis=1)
    uniq, counts = np.unique(edges, axis=0, return_counts=True)
    if (counts > 2).any():
        e = uniq[np.flatnonzero(counts > 2)[0]]
        owner = np.flatnonzero(np.isin(ids, e).sum(axis=1) >= 2)
        cells = ", ".join(_where(poly, offset, k) for k in owner[:3])
        raise MeshError(f"{name}: an edge is shared by {counts.max()} cells ({cells}): the mesh has superposed parts; "
                        "keep one layer of cells")
    size = float(np.median(np.sqrt(area)))
    i, j, sep = _near_pairs(poly, diam, TOUCH * size)
    over = np.flatnonzero(sep < -TOUCH * size)
    if over.size:
        p, q = i[over[0]], j[over[0]]
        raise MeshError(f"{name}: {_where(poly, offset, p)} and {_where(poly, offset, q)} overlap ({over.size} "
                        "overlapping pairs): the mesh has superposed parts; keep one layer of cells")
    from scipy.sparse import coo_matrix                       # only for the connectivity below
    from scipy.sparse.csgraph import connected_components      # (the same)
    touch = sep <= TOUCH * size
    graph = coo_matrix((np.ones(int(touch.sum())), (i[touch], j[touch])), shape=(n, n))
    count, label = connected_components(graph, directed=False)
    if count > 1:
        sizes = np.bincount(label)
        at = [poly[label == c].mean(axis=(0, 1)) + offset for c in range(count)]
        parts = "; ".join(f"{sizes[c]} cells around x = {at[c][0]:.4g}, y = {at[c][1]:.4g} m"
                          for c in np.argsort(-sizes)[:3])
        raise MeshError(f"{name}: the raft is in {count} pieces that do not touch ({parts}): a rigid raft is one "
                        "piece; join them, or mesh them as one surface")


def _near_pairs(poly, diam, tol):
    """(i, j, separation) of the pairs of cells whose circles about their centroids meet:
    separation > 0 apart (the largest gap along an edge normal of either), < 0 into each other
    (the separating axis test of convex polygons), about 0 touching."""
    from scipy.spatial import cKDTree                # the neighbour search of the checks only
    centre = poly.mean(axis=1)
    radius = np.linalg.norm(poly - centre[:, None, :], axis=-1).max(axis=1)
    tree = cKDTree(centre)
    rows, cols = [], []
    for k, near in enumerate(tree.query_ball_point(centre, radius + radius.max() + tol)):
        near = np.asarray(near, dtype=np.int64)
        near = near[near > k]
        rows.append(np.full(near.size, k, np.int64))
        cols.append(near)
    i, j = np.concatenate(rows), np.concatenate(cols)
    if not i.size:
        return i, j, np.zeros(0)
    sep = np.full(i.size, -np.inf)
    for chunk in range(0, i.size, 200_000):
        s = slice(chunk, chunk + 200_000)
        A, B = poly[i[s]], poly[j[s]]
        edges = np.concatenate([np.roll(A, -1, axis=1) - A, np.roll(B, -1, axis=1) - B], axis=1)   # (p, 8, 2)
        length = np.linalg.norm(edges, axis=-1)
        valid = length > 0
        normal = np.stack([-edges[..., 1], edges[..., 0]], axis=-1) / np.where(valid, length, 1.0)[..., None]
        pa = np.einsum("pad,pkd->pak", normal, A)
        pb = np.einsum("pad,pkd->pak", normal, B)
        gap = np.maximum(pb.min(axis=2) - pa.max(axis=2), pa.min(axis=2) - pb.max(axis=2))
        sep[s] = np.where(valid, gap, -np.inf).max(axis=1)
    return i, j, sep


def _centre_inside(mesh, centre, name: str) -> None:
    """Refuse a centre not strictly inside the convex hull of the cells' centroids (where the
    weight and the overturning moment act; ``check_footprint``'s rule, said in a mesh's terms)."""
    from scipy.spatial import ConvexHull, QhullError   # the hull of the check only
    try:
        hull = ConvexHull(mesh.xy)
    except QhullError:
        return                                         # on one line: check_footprint says so
    if -hull.equations[:, 2].max() <= 1e-6 * float(np.abs(mesh.xy).max()):
        raise MeshError(f"{name}: the raft centre ({centre[0]:.6g}, {centre[1]:.6g}) m is not inside the footprint "
                        "of the cells (the convex hull of their centroids): the weight would tip the raft over its "
                        "edge; set foundation.centre = [x, y] inside the raft, or omit it for the area centroid")


def _centre(centre, name: str) -> tuple[float, float]:
    ok = (isinstance(centre, (list, tuple)) and len(centre) == 2
          and all(isinstance(c, (int, float)) and not isinstance(c, bool) and math.isfinite(c) for c in centre))
    if not ok:
        raise MeshError(f"{name}: foundation.centre = {centre!r} must be [x, y], the raft centre in the mesh file's "
                        "coordinates (m); omit it for the area centroid of the raft")
    return float(centre[0]), float(centre[1])

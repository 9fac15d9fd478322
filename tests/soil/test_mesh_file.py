"""Raft meshes read from finite-element files (soil_impedance.mesh_file): every format meshio
writes from one gmsh mesh gives the same interface; groups of a 3-D mesh; every bad mesh refused
through the command line with a one-line message naming the file and the fix (exit 2).

The meshes are the committed gmsh files of tests/data/meshes (made by make_meshes.py there):
l_raft.msh, an L-shaped raft of 30 m x 30 m less a 15 m x 15 m corner (675 m^2, area centroid
(12.5, 12.5) m: the closed forms the reader is held to), 18 quadrilaterals and 26 triangles;
box.msh, a 10 m x 8 m x 4 m block in tetrahedra with the groups base, sides and block. The
other formats and the bad meshes are written by meshio at test time; no test needs gmsh.
"""
import meshio
import numpy as np
import pytest

from helpers import DATA, tower, write_scene
from orchestrator.cli import main
from soil_impedance.mesh import MeshError
from soil_impedance.mesh_file import read_mesh, read_mesh_source

MESHES = DATA / "meshes"
L_RAFT, BOX = MESHES / "l_raft.msh", MESHES / "box.msh"


def _sorted(mesh):
    """(xy, area, cells) in one order whatever the file's (by centroid)."""
    order = np.lexsort((mesh.xy[:, 1].round(9), mesh.xy[:, 0].round(9)))
    return mesh.xy[order], mesh.area[order], mesh.cells[order]


def _blocks_by_type(mesh, data=None):
    """The cells merged into one block per type (MED takes one), with ``data`` per block merged alike."""
    out, merged = {}, {}
    for k, block in enumerate(mesh.cells):
        out.setdefault(block.type, []).append(block.data)
        if data is not None:
            merged.setdefault(block.type, []).append(data[k])
    cells = [(t, np.concatenate(v)) for t, v in out.items()]
    return cells, [np.concatenate(merged[t]) for t, _ in cells] if data is not None else None


def _write(fmt, src, path):
    """``src`` (a meshio Mesh read from a gmsh file, with its physical groups) written as ``fmt``
    with its groups in that format's terms."""
    sets = {k: v for k, v in src.cell_sets.items() if not k.startswith("gmsh:")}
    if fmt == "gmsh22":
        meshio.write(path, meshio.Mesh(src.points, src.cells, cell_data={k: src.cell_data[k] for k in
                                                                         ("gmsh:physical", "gmsh:geometrical")},
                                       field_data=src.field_data), file_format="gmsh22", binary=False)
    elif fmt == "abaqus":
        # one *ELSET per group over every block, by global element number (meshio's writer
        # writes one per block under the same name, which its reader then overwrites)
        meshio.write(path, meshio.Mesh(src.points, src.cells), file_format="abaqus")
        first = np.cumsum([0] + [len(b.data) for b in src.cells])
        with open(path, "a") as fh:
            for name, per_block in sets.items():
                ids = np.concatenate([first[k] + np.asarray(v, np.int64) + 1 for k, v in enumerate(per_block)])
                fh.write(f"*ELSET, ELSET={name}\n" + "\n".join(", ".join(map(str, ids[i:i + 16]))
                                                             for i in range(0, len(ids), 16)) + "\n")
    elif fmt == "med":
        # MED groups are families: one (negative) tag per cell, each tag naming its groups
        names = sorted(sets)
        tags = [np.zeros(len(b.data), np.int64) for b in src.cells]
        for i, name in enumerate(names):
            for k, idx in enumerate(sets[name]):
                tags[k][np.asarray(idx, np.int64)] = -(i + 1)
        cells, merged = _blocks_by_type(src, tags)
        mesh = meshio.Mesh(src.points, cells, cell_data={"cell_tags": merged})
        mesh.cell_tags = {-(i + 1): [name] for i, name in enumerate(names)}
        meshio.write(path, mesh, file_format="med")
    else:
        cells, _ = _blocks_by_type(src)
        meshio.write(path, meshio.Mesh(src.points, cells), file_format=fmt)
    return path


FORMATS = {"gmsh22": "msh", "med": "med", "abaqus": "inp", "vtu": "vtu", "vtk": "vtk"}


def test_the_l_raft_against_its_closed_forms():
    mesh, source = read_mesh_source(L_RAFT)
    assert mesh.kind == "cells" and mesh.n == 44
    assert mesh.total_area == pytest.approx(675.0, rel=1e-12)
    assert source.centre == pytest.approx((12.5, 12.5), abs=1e-9)               # the L's area centroid
    assert mesh.area @ mesh.xy == pytest.approx([0.0, 0.0], abs=1e-9)           # nodes about it
    tri = mesh.cells[:, 2] == mesh.cells[:, 3]
    assert tri.all(axis=1).sum() == 26
    shifted = read_mesh(L_RAFT, centre=[10.0, 5.0])
    assert shifted.xy == pytest.approx(mesh.xy + np.array([2.5, 7.5]), abs=1e-12)
    assert source.group is None and source.format == "gmsh" and len(source.sha256) == 64


def test_site_coordinates_cost_no_accuracy(tmp_path):
    """The L raft moved to site coordinates (x ~ 5e5 m, y ~ 4.2e6 m, z = 120 m): the same
    interface about its centre, the centre moved by as much."""
    src = meshio.read(L_RAFT)
    shift = np.array([5.0e5, 4.2e6, 120.0])
    meshio.write(tmp_path / "site.msh", meshio.Mesh(src.points + shift, src.cells, cell_data={
        k: src.cell_data[k] for k in ("gmsh:physical", "gmsh:geometrical")}), file_format="gmsh22", binary=True)
    mesh, source = read_mesh_source(tmp_path / "site.msh")
    ref = read_mesh(L_RAFT)
    assert source.centre == pytest.approx((12.5 + 5.0e5, 12.5 + 4.2e6), rel=0, abs=1e-8)
    assert np.allclose(mesh.xy, ref.xy, rtol=0, atol=1e-8) and np.allclose(mesh.area, ref.area, rtol=1e-10)


@pytest.mark.parametrize("fmt", sorted(FORMATS))
def test_each_format_gives_the_same_interface(fmt, tmp_path):
    src = meshio.read(L_RAFT)
    path = _write(fmt, src, tmp_path / f"raft.{FORMATS[fmt]}")
    ref = _sorted(read_mesh(L_RAFT))
    got = _sorted(read_mesh(path))
    for a, b in zip(got, ref):
        assert np.allclose(a, b, rtol=0, atol=1e-9)
    if fmt in ("gmsh22", "med", "abaqus"):                                  # named groups survive
        grouped = _sorted(read_mesh(path, group="raft"))
        assert all(np.allclose(a, b, rtol=0, atol=1e-9) for a, b in zip(grouped, ref))


@pytest.mark.parametrize("fmt", ["msh41", "gmsh22", "med", "abaqus"])
def test_the_base_of_a_3d_mesh_by_its_group(fmt, tmp_path):
    """The box's base face (z = 0, 10 m x 8 m) selected by name: its area and centroid exact,
    the other groups refused (the sides are not one horizontal plane, the block has no faces)."""
    path = BOX if fmt == "msh41" else _write(fmt, meshio.read(BOX), tmp_path / f"box.{FORMATS[fmt]}")
    mesh, source = read_mesh_source(path, group="base")
    assert mesh.n == 120 and mesh.total_area == pytest.approx(80.0, rel=1e-12)
    assert source.centre == pytest.approx((5.0, 4.0), abs=1e-9)
    with pytest.raises(MeshError, match="not on one horizontal plane z = const .*group 'sides' is not the raft's base"):
        read_mesh(path, group="sides")
    with pytest.raises(MeshError, match=r"group 'block' has no triangle or quadrilateral cells \(\d+ tetra\)"):
        read_mesh(path, group="block")
    with pytest.raises(MeshError, match="no group 'bottom'; the groups of the file are base, block, sides"):
        read_mesh(path, group="bottom")


#: the faces of Abaqus's C3D4 tetrahedron (Abaqus Analysis User's Guide, "three-dimensional solid
#: element library": face 1 = nodes 1-2-3, 2 = 1-4-2, 3 = 2-4-3, 4 = 3-4-1), 0-based
C3D4_FACES = {1: (0, 1, 2), 2: (0, 3, 1), 3: (1, 3, 2), 4: (2, 3, 0)}


def test_an_abaqus_surface_on_the_faces_of_solid_elements(tmp_path):
    """The box's tetrahedra as an Abaqus file whose base is a *SURFACE of element faces (given
    by element sets, one per face label, and by element numbers): the same interface as the
    gmsh file's "base" group of triangles."""
    src = meshio.read(BOX)
    tets = np.concatenate([b.data for b in src.cells if b.type == "tetra"])
    path = tmp_path / "box.inp"
    meshio.write(path, meshio.Mesh(src.points, [("tetra", tets)]), file_format="abaqus")
    on_base = np.abs(src.points[:, 2]) < 1e-9
    by_label = {}
    for e, tet in enumerate(tets):
        for label, face in C3D4_FACES.items():
            if on_base[tet[list(face)]].all():
                by_label.setdefault(label, []).append(e + 1)        # meshio numbers the elements from 1
    assert sum(map(len, by_label.values())) == 120
    with open(path, "a") as fh:
        for label, elements in by_label.items():
            fh.write(f"*ELSET, ELSET=base_s{label}\n" + "\n".join(map(str, elements[1:])) + "\n")
        fh.write("*SURFACE, NAME=raft_base, TYPE=ELEMENT\n")
        for label, elements in by_label.items():
            fh.write(f"base_s{label}, S{label}\n{elements[0]}, S{label}\n")
    got = _sorted(read_mesh(path, group="raft_base"))
    ref = _sorted(read_mesh(BOX, group="base"))
    assert np.allclose(got[0], ref[0], atol=1e-9) and np.allclose(got[1], ref[1], atol=1e-9)
    with pytest.raises(MeshError, match="no group 'base'; the groups of the file are .*raft_base"):
        read_mesh(path, group="base")


def test_a_raft_with_an_opening_and_a_non_conforming_joint_is_read(tmp_path):
    """Holes are allowed (a 3 x 3 grid of 1 m squares less the middle one: 8 m^2, centroid at the
    middle); cells that touch along an edge without sharing its nodes (a hanging node) are one raft."""
    pts = np.array([[x, y, 0.0] for y in range(4) for x in range(4)], float)
    quads = [[4 * j + i, 4 * j + i + 1, 4 * j + i + 5, 4 * j + i + 4] for j in range(3) for i in range(3)
             if (i, j) != (1, 1)]
    meshio.write(tmp_path / "ring.vtu", meshio.Mesh(pts, [("quad", np.array(quads))]))
    ring, source = read_mesh_source(tmp_path / "ring.vtu")
    assert ring.n == 8 and ring.total_area == pytest.approx(8.0) and source.centre == pytest.approx((1.5, 1.5))
    pts = np.array([[0, 0], [2, 0], [2, 2], [0, 2], [3, 0], [3, 1], [2, 1], [3, 2]], float)
    joint = read_mesh(_flat(tmp_path / "joint.vtu", pts, quad=[[0, 1, 2, 3], [1, 4, 5, 6], [6, 5, 7, 2]]))
    assert joint.n == 3 and joint.total_area == pytest.approx(6.0)


def _flat(path, pts, tri=(), quad=(), z=None, cells=None):
    pts = np.asarray(pts, float)
    pts = np.column_stack([pts, np.zeros(len(pts)) if z is None else z])
    blocks = cells if cells is not None else \
        [(t, np.array(c)) for t, c in (("triangle", tri), ("quad", quad)) if len(c)]
    meshio.write(path, meshio.Mesh(pts, blocks))
    return path


SQUARE = [[0, 0], [1, 0], [1, 1], [0, 1]]
GRID = [[x, y] for y in range(3) for x in range(3)]            # 2 x 2 unit squares
GRID_QUADS = [[0, 1, 4, 3], [1, 2, 5, 4], [3, 4, 7, 6], [4, 5, 8, 7]]


def _bad(case, tmp_path):
    """(mesh file, extra [foundation] keys) of a bad mesh."""
    p = tmp_path / "raft.vtu"
    if case == "missing":
        return tmp_path / "absent.msh", {}
    if case == "unreadable":
        (tmp_path / "raft.msh").write_text("$MeshFormat\n4.1 0 8\nthis is not a mesh\n")
        return tmp_path / "raft.msh", {}
    if case == "format":
        (tmp_path / "raft.stl").write_text("solid raft\nendsolid raft\n")
        return tmp_path / "raft.stl", {}
    if case == "no-2d":
        return _flat(p, SQUARE, cells=[("line", np.array([[0, 1], [1, 2]]))]), {}
    if case == "group":
        return L_RAFT, {"mesh_group": "base"}
    if case == "nonplanar":
        return _flat(p, GRID, quad=GRID_QUADS, z=[0, 0, 0, 0, 0.5, 0, 0, 0, 0]), {}
    if case == "tilted":
        return _flat(p, GRID, quad=GRID_QUADS, z=0.1 * np.array(GRID)[:, 0]), {}
    if case == "order":
        pts = [[0, 0], [2, 0], [0, 2], [1, 0], [1, 1], [0, 1]]
        return _flat(p, pts, cells=[("triangle6", np.array([[0, 1, 2, 3, 4, 5]]))]), {}
    if case == "degenerate":
        return _flat(p, GRID + [[3, 0]], quad=GRID_QUADS, tri=[[0, 1, 9]]), {}
    if case == "bowtie":
        return _flat(p, GRID, quad=[[0, 1, 4, 3], [1, 2, 4, 5], [3, 4, 7, 6], [4, 5, 8, 7]]), {}
    if case == "duplicate":
        return _flat(p, GRID, quad=GRID_QUADS + [[4, 5, 8, 7]]), {}
    if case == "three-edge":
        pts = [[0, 0], [1, 0], [0.5, -1], [0.5, 1], [0.2, 0.8]]
        return _flat(p, pts, tri=[[0, 1, 2], [0, 1, 3], [0, 1, 4]]), {}
    if case == "superposed":
        shifted = np.array(GRID, float) + [0.5, 0.5]
        return _flat(p, np.vstack([GRID, shifted]), quad=GRID_QUADS + [[a + 9 for a in q] for q in GRID_QUADS]), {}
    if case == "pieces":
        return _flat(p, GRID + [[x + 5.0, y] for x, y in GRID], quad=GRID_QUADS + [[a + 9 for a in q] for q in GRID_QUADS]), {}
    if case == "centre":
        return L_RAFT, {"centre": [100.0, 12.5]}
    if case == "centre-type":
        return L_RAFT, {"centre": "middle"}
    raise AssertionError(case)


BAD = {
    "missing": "absent.msh': no such file (paths are relative to the scene file)",
    "unreadable": "cannot be read as a gmsh file",
    "format": "unknown mesh format '.stl'; give one of .msh (gmsh), .med (MED), .inp (Abaqus), .vtk (VTK), .vtu (VTU)",
    "no-2d": "the file has no triangle or quadrilateral cells (2 line)",
    "group": "no group 'base'; the groups of the file are raft: set foundation.mesh_group",
    "nonplanar": "the cells are not on one horizontal plane z = const (z from 0 to 0.5 m)",
    "tilted": "the cells are not on one horizontal plane z = const (z from 0 to 0.2 m)",
    "order": "1 higher-order cells (triangle6); the interface takes linear triangles and quadrilaterals",
    "degenerate": "has zero area (its vertices are on one line or repeated",
    "bowtie": "is a quadrilateral that is not convex (folded, bow-tie",
    "duplicate": "is in the mesh 2 times (duplicate cells; 1 copies): remove the duplicates",
    "three-edge": "an edge is shared by 3 cells",
    "superposed": "overlap (",
    "pieces": "the raft is in 2 pieces that do not touch (4 cells around x = 1",
    "centre": "the raft centre (100, 12.5) m is not inside the footprint of the cells",
    "centre-type": "foundation.centre = 'middle' must be [x, y], the raft centre in the mesh file's coordinates",
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_a_bad_mesh_is_refused_on_one_line_before_any_computation(case, tmp_path, capsys):
    path, extra = _bad(case, tmp_path)
    scene = tower(foundation={"shape": None, "lx": None, "ly": None, "element_size": None,
                              "mesh": path.name if case != "group" and path.parent == tmp_path else str(path),
                              **extra})
    assert main(["run", write_scene(tmp_path / "scene.toml", scene), "-o", str(tmp_path / "r.h5")]) == 2
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("uplift: error: scene file ") and "mesh file '" in lines[0], lines[0]
    assert BAD[case] in lines[0], lines[0]
    assert not (tmp_path / "r.h5").exists()

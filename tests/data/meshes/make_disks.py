"""Generate the unstructured raft meshes of the BEM tests with gmsh (run once; the .npz are committed).

    python tests/data/meshes/make_disks.py

Each ``disk_<kind>_<R/h>.npz`` holds ``points`` (m, 2), m, and ``triangles`` (nt, 3) or ``quads``
(nq, 4), vertex indices: a disk of radius R = 10 m meshed by gmsh's Frontal-Delaunay algorithm
at mesh size h (``quad``: the same recombined into quadrilaterals by Blossom, full-quad
subdivision off, so the size stays h). ``disk_graded.npz``: triangles graded from h = R/4 at
the centre to h = R/20 at the edge (size h_edge + (h - h_edge) sqrt(1 - r/R)), where the rigid
raft's traction is singular. The tests read them with numpy only (no gmsh).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
RADIUS = 10.0
#: R/h of the test meshes (three sizes: convergence order)
DIVISIONS = (5, 7, 10)


def disk_mesh(radius: float, h: float, quads: bool = False, seed: int = 0, h_edge: float | None = None):
    """Points (m, 2) and cells ((nt, 3) triangles or (nq, 4) quads) of a disk meshed by gmsh
    (size h; with ``h_edge``, graded from h at the centre to h_edge at the edge)."""
    import gmsh
    gmsh.initialize(["-noenv"])
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("General.NumThreads", 1)
        gmsh.option.setNumber("Mesh.RandomSeed", seed)
        gmsh.model.add("disk")
        gmsh.model.occ.addDisk(0, 0, 0, radius, radius)
        gmsh.model.occ.synchronize()
        if h_edge is None:
            gmsh.option.setNumber("Mesh.MeshSizeMin", h)
            gmsh.option.setNumber("Mesh.MeshSizeMax", h)
        else:
            field = gmsh.model.mesh.field.add("MathEval")
            gmsh.model.mesh.field.setString(field, "F", f"{h_edge}+({h}-{h_edge})*(1-sqrt(x*x+y*y)/{radius})^0.5")
            gmsh.model.mesh.field.setAsBackgroundMesh(field)
            for key in ("Mesh.MeshSizeExtendFromBoundary", "Mesh.MeshSizeFromPoints", "Mesh.MeshSizeFromCurvature"):
                gmsh.option.setNumber(key, 0)
        gmsh.option.setNumber("Mesh.Algorithm", 6)            # Frontal-Delaunay
        if quads:
            gmsh.option.setNumber("Mesh.RecombinationAlgorithm", 1)   # Blossom
            gmsh.option.setNumber("Mesh.RecombineAll", 1)
        gmsh.model.mesh.generate(2)
        tags, coords, _ = gmsh.model.mesh.getNodes()
        index = {int(t): k for k, t in enumerate(tags)}
        pts = coords.reshape(-1, 3)[:, :2].copy()
        etype = 3 if quads else 2
        _, nodes = gmsh.model.mesh.getElementsByType(etype)
        k = 4 if quads else 3
        conn = np.array([index[int(t)] for t in nodes], dtype=np.int64).reshape(-1, k)
    finally:
        gmsh.finalize()
    used = np.unique(conn)
    remap = np.full(pts.shape[0], -1)
    remap[used] = np.arange(used.size)
    return pts[used], remap[conn]


def main():
    for n in DIVISIONS:
        for kind in ("tri", "quad"):
            pts, conn = disk_mesh(RADIUS, RADIUS / n, quads=kind == "quad")
            key = "quads" if kind == "quad" else "triangles"
            path = HERE / f"disk_{kind}_{n}.npz"
            np.savez_compressed(path, points=pts, **{key: conn})
            print(f"{path.name}: {pts.shape[0]} points, {conn.shape[0]} cells")
    pts, conn = disk_mesh(RADIUS, RADIUS / 4, h_edge=RADIUS / 20)
    np.savez_compressed(HERE / "disk_graded.npz", points=pts, triangles=conn)
    print(f"disk_graded.npz: {pts.shape[0]} points, {conn.shape[0]} cells")


if __name__ == "__main__":
    main()

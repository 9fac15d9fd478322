"""Writes the committed test meshes with the gmsh Python package (run once; the tests read the
files and need no gmsh): ``python tests/data/meshes/make_meshes.py``.

l_raft.msh  an L-shaped raft, 30 m x 30 m less the 15 m x 15 m corner at x, y > 15 m (675 m^2,
            area centroid (12.5, 12.5) m), in the file's own coordinates (corner at the origin,
            z = 0): the 30 m x 15 m leg in 5 m quadrilaterals, the upper 15 m x 15 m leg in
            triangles of about 5 m (one conforming mesh, both kinds of cell; physical group
            "raft"), gmsh 4.1
box.msh     a 10 m x 8 m x 4 m block (z from -4 to 0) in tetrahedra with the physical groups
            "base" (the face z = 0, triangles), "sides" (the four side faces) and "block" (the
            volume), gmsh 4.1
"""
from pathlib import Path

import gmsh

HERE = Path(__file__).parent


def l_raft(path, h=5.0):
    gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.model.add("l_raft")
    geo = gmsh.model.geo
    p = [geo.addPoint(x, y, 0.0, h) for x, y in ((0, 0), (30, 0), (30, 15), (15, 15), (15, 30), (0, 30), (0, 15))]
    lines = [geo.addLine(p[a], p[b]) for a, b in ((0, 1), (1, 2), (2, 3), (3, 6), (6, 0), (3, 4), (4, 5), (5, 6))]
    low = geo.addPlaneSurface([geo.addCurveLoop([lines[0], lines[1], lines[2], lines[3], lines[4]])])
    high = geo.addPlaneSurface([geo.addCurveLoop([-lines[3], lines[5], lines[6], lines[7]])])
    along, across = int(round(30 / h)) + 1, int(round(15 / h)) + 1
    for line, n in ((lines[0], along), (lines[1], across), (lines[2], across), (lines[3], across), (lines[4], across)):
        geo.mesh.setTransfiniteCurve(line, n)
    geo.mesh.setTransfiniteSurface(low, cornerTags=[p[0], p[1], p[2], p[6]])
    geo.mesh.setRecombine(2, low)
    geo.synchronize()
    gmsh.model.addPhysicalGroup(2, [low, high], name="raft")
    gmsh.model.mesh.generate(2)
    gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
    gmsh.write(str(path))
    gmsh.finalize()


def box(path, h=2.5):
    gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.model.add("box")
    gmsh.model.occ.addBox(0, 0, -4, 10, 8, 4)
    gmsh.model.occ.synchronize()
    faces = gmsh.model.getEntities(2)
    z = {s: gmsh.model.occ.getCenterOfMass(2, s)[2] for _, s in faces}
    gmsh.model.addPhysicalGroup(2, [s for s in z if abs(z[s]) < 1e-9], name="base")
    gmsh.model.addPhysicalGroup(2, [s for s in z if -4 + 1e-9 < z[s] < -1e-9], name="sides")
    gmsh.model.addPhysicalGroup(3, [1], name="block")
    gmsh.option.setNumber("Mesh.MeshSizeMax", h)
    gmsh.model.mesh.generate(3)
    gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
    gmsh.write(str(path))
    gmsh.finalize()


if __name__ == "__main__":
    l_raft(HERE / "l_raft.msh")
    box(HERE / "box.msh")

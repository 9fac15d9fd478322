"""Generate orchestrator/scenes/mat.msh: the 100 m x 100 m mat of the scene "mat" as an irregular
gmsh mesh of about 2500 cells (the scene "mat-mesh"; committed, 97 kB).

An engineer's mesh rather than the built-in grid: unstructured triangles (gmsh's Frontal-Delaunay),
finer along the mat's edges, where the contact pressure of a rigid mat concentrates and uplift
starts, than at its centre: element size 2.4 m on the boundary growing linearly to 3.8 m at 25 m
from it (a Distance + Threshold field), which gives 2506 triangles. In the mat's own
coordinates (a corner at the origin; the scene takes the area centroid, (50, 50) m, as the raft
centre); the cells form the physical group "mat". Deterministic: one thread, the same options,
the same gmsh version give the same file (``--check`` compares a fresh mesh with the committed one).

    pip install gmsh
    python benchmarks/mat_mesh.py [--out orchestrator/scenes/mat.msh] [--check]
"""
from __future__ import annotations

import argparse
import hashlib
import sys
import tempfile
from pathlib import Path

SIDE = 100.0
#: element sizes on the edges and from DISTANCE inwards, m
H_EDGE, H_IN, DISTANCE = 2.4, 3.8, 25.0
OUT = Path(__file__).resolve().parent.parent / "orchestrator" / "scenes" / "mat.msh"


def mesh_mat(path: Path) -> int:
    """Write the mesh to ``path`` (gmsh 4.1); returns its triangle count."""
    import gmsh
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("General.NumThreads", 1)
        gmsh.model.add("mat")
        corners = [(0.0, 0.0), (SIDE, 0.0), (SIDE, SIDE), (0.0, SIDE)]
        points = [gmsh.model.geo.addPoint(x, y, 0.0) for x, y in corners]
        lines = [gmsh.model.geo.addLine(points[k], points[(k + 1) % 4]) for k in range(4)]
        surface = gmsh.model.geo.addPlaneSurface([gmsh.model.geo.addCurveLoop(lines)])
        gmsh.model.geo.synchronize()
        gmsh.model.addPhysicalGroup(2, [surface], name="mat")       # the scene's mesh_group
        distance = gmsh.model.mesh.field.add("Distance")
        gmsh.model.mesh.field.setNumbers(distance, "CurvesList", lines)
        gmsh.model.mesh.field.setNumber(distance, "Sampling", 200)
        threshold = gmsh.model.mesh.field.add("Threshold")
        gmsh.model.mesh.field.setNumber(threshold, "InField", distance)
        gmsh.model.mesh.field.setNumber(threshold, "SizeMin", H_EDGE)
        gmsh.model.mesh.field.setNumber(threshold, "SizeMax", H_IN)
        gmsh.model.mesh.field.setNumber(threshold, "DistMin", 0.0)
        gmsh.model.mesh.field.setNumber(threshold, "DistMax", DISTANCE)
        gmsh.model.mesh.field.setAsBackgroundMesh(threshold)
        for option in ("Mesh.MeshSizeExtendFromBoundary", "Mesh.MeshSizeFromPoints", "Mesh.MeshSizeFromCurvature"):
            gmsh.option.setNumber(option, 0)
        gmsh.option.setNumber("Mesh.Algorithm", 6)                  # Frontal-Delaunay
        gmsh.option.setNumber("Mesh.ElementOrder", 1)               # linear cells: one interface node each
        gmsh.option.setNumber("Mesh.RandomSeed", 1)
        gmsh.model.mesh.generate(2)
        types, tags, _ = gmsh.model.mesh.getElements(2)
        count = sum(len(t) for t in tags)
        gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
        gmsh.write(str(path))
    finally:
        gmsh.finalize()
    return count


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=OUT)
    p.add_argument("--check", action="store_true", help="mesh into a temporary file and compare it with --out")
    args = p.parse_args(argv)
    if args.check:
        with tempfile.TemporaryDirectory() as tmp:
            fresh = Path(tmp) / "mat.msh"
            mesh_mat(fresh)
            same = hashlib.sha256(fresh.read_bytes()).digest() == hashlib.sha256(args.out.read_bytes()).digest()
        print(f"{args.out}: {'identical to' if same else 'DIFFERS from'} a fresh mesh")
        return 0 if same else 1
    count = mesh_mat(args.out)
    print(f"wrote {args.out}: {count} triangles, {args.out.stat().st_size / 1024:.0f} kB")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Layered soil, surface BEM and impedance tables (docs/formulation.md).

DOF conventions: nodal impedances are node-interleaved [ux0, uy0, uz0, ux1, ...]; the rigid
raft has ["ux", "uy", "uz", "rx", "ry", "rz"] about the mesh origin; the gap model appends
["w0", ..., "w{N-1}"] (soil vertical displacement under each node).
"""
from .profile import Layer, Material, SoilError, SoilProfile
from .mesh import InterfaceMesh, MeshError, circle_mesh, nodes_mesh, read_nodes_csv, rectangle_mesh
from .bem import BemError, SurfaceBem, nodal_dofs, nodal_impedance
from .reduction import (RIGID_DOFS, condense_gap_rigid, gap_dofs, gap_reduction, gap_transform,
                        rigid_reduction, rigid_transform)
from .table import ImpedanceTable, TableError
from .sweep import impedance_sweep, static_impedance
from .rational import FitError, RationalModel
from .fit import FitOptions, FitReport, FitResult, fit_table, load_fit, save_fit

__all__ = [
    "SoilProfile", "Material", "Layer", "SoilError",
    "InterfaceMesh", "circle_mesh", "rectangle_mesh", "nodes_mesh", "read_nodes_csv", "MeshError",
    "SurfaceBem", "nodal_impedance", "nodal_dofs", "BemError",
    "rigid_transform", "gap_transform", "rigid_reduction", "gap_reduction", "condense_gap_rigid",
    "RIGID_DOFS", "gap_dofs",
    "ImpedanceTable", "TableError", "impedance_sweep", "static_impedance",
    "RationalModel", "FitError", "FitOptions", "FitReport", "FitResult", "fit_table", "save_fit", "load_fit",
]

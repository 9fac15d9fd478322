"""Layered soil, surface BEM and impedance tables (docs/formulation.md).

DOF conventions: nodal impedances are node-interleaved [ux0, uy0, uz0, ux1, ...]; the rigid
raft has ["ux", "uy", "uz", "rx", "ry", "rz"] about the mesh origin; the gap model appends
["w0", ..., "w{N-1}"] (soil vertical displacement under each node).
"""
from uplift_common.lazy import lazy_exports

#: the public names, imported from their submodule on first use (``uplift_common.lazy``)
__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "profile": ("Layer", "Material", "SoilError", "SoilProfile"),
    "mesh": ("InterfaceMesh", "MeshError", "cells_mesh", "circle_mesh", "nodes_mesh", "read_nodes_csv", "rectangle_mesh"),
    "mesh_file": ("MeshSource", "read_mesh", "read_mesh_source"),
    "bem": ("BemError", "SurfaceBem", "nodal_dofs", "nodal_impedance"),
    "reduction": ("RIGID_DOFS", "condense_gap_rigid", "gap_dofs", "gap_reduction", "gap_transform", "rigid_reduction", "rigid_transform"),
    "table": ("ImpedanceTable", "TableError"),
    "sweep": ("SweepMemoryError", "check_sweep_memory", "impedance_sweep", "static_impedance", "sweep_memory"),
    "discretisation": ("refined_mesh", "static_error_estimate"),
    "rational": ("FitError", "RationalModel"),
    "fit": ("FitOptions", "FitReport", "FitResult", "fit_table", "load_fit", "save_fit"),
})

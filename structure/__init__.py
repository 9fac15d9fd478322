"""Stick-and-raft structure, soil interface, penalty contact and Newmark-Newton stepper.

Depends on numpy and scipy only (never on soil_impedance, orchestrator or fmus).

Modules (one concept each):
  model          frozen dataclasses Node, Beam (3D Timoshenko; Euler-Bernoulli without shear
                 areas), Mass, Spring, Raft, Damping, StructureModel; sparse K, lumped M
  beams          the 12x12 beam element
  damping        fixed-base modes, modal / Rayleigh damping acting relative to the raft
  soil_interface SoilInterface protocol (K0, C0, history h, commit, state) and WinklerSoil
  contact        ContactSettings, penalty "auto" rule, contact force / gap kernels
  preload        static equilibrium under self-weight: settlement, P0
  newmark        NewmarkStepper (one step at a time; FMU-ready; a linear run at once)
  closed_contact the closed-contact (linear) solver and the vectorised energy kernels
  driver         simulate(): the driver that runs a stepper over a record into a RouteResult
  results        RouteResult, the one result type of every route
  plate          Kirchhoff plate bending: the DKT triangle (quads split in two), assembled stiffness
  plate_raft     a flexible raft: the DKT plate on the interface's cells (PlateRaftModel) and its
                 Newmark stepper (PlateStepper; simulate() takes a PlateRaftModel)
  winkler        Winkler mattress: springs, dashpots, RCC-G composite modal damping
  spec           scene tables -> objects (model_from_spec, winkler_from_spec, contact_from_spec)
  data/reactor.toml   the representative reactor building (model = "reactor")

Typical use::

    mesh = circle_mesh(20.0, 2.28)                         # in the orchestrator
    model = model_from_spec({"model": "reactor"}, mesh.xy, mesh.area)
    soil = winkler_from_spec({"kv": 2e8, "kh": 1.5e8}, mesh.xy, mesh.area)
    res = simulate(model, soil, ag, 0.005, contact=contact_from_spec({"enabled": True}))
"""
from uplift_common.lazy import lazy_exports

#: the public names, imported from their submodule on first use (``uplift_common.lazy``)
__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "contact": ("ContactSettings",),
    "damping": ("damping_matrix", "fixed_base_modes"),
    "errors": ("ConvergenceError", "StructureError"),
    "model": ("G_ACC", "Beam", "Damping", "Mass", "Node", "Raft", "Spring", "StructureModel"),
    "newmark": ("NewmarkStepper",),
    "plate": ("flexural_rigidity", "plate_stiffness", "pressure_load"),
    "plate_raft": ("PlateProperties", "PlateRaftModel", "PlateStepper", "plate_cells"),
    "preload": ("StaticState", "solve_static"),
    "results": ("RouteResult",),
    "driver": ("simulate",),
    "soil_interface": ("SoilInterface", "WinklerSoil"),
    "spec": ("contact_from_spec", "model_from_spec", "winkler_from_spec"),
})

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
  closed         the closed-contact (linear) solver and the vectorised energy kernels
  driver         simulate(): the driver that runs a stepper over a record into a RouteResult
  results        RouteResult, the one result type of every route
  winkler        Winkler mattress: springs, dashpots, RCC-G composite modal damping
  spec           scene tables -> objects (model_from_spec, winkler_from_spec, contact_from_spec)
  data/reactor.toml   the representative reactor building (model = "reactor")

Typical use::

    mesh = circle_mesh(20.0, 2.28)                         # in the orchestrator
    model = model_from_spec({"model": "reactor"}, mesh.xy, mesh.area)
    soil = winkler_from_spec({"kv": 2e8, "kh": 1.5e8}, mesh.xy, mesh.area)
    res = simulate(model, soil, ag, 0.005, contact=contact_from_spec({"enabled": True}))
"""
from .contact import ContactSettings
from .damping import damping_matrix, fixed_base_modes
from .errors import ConvergenceError, StructureError
from .model import G_ACC, Beam, Damping, Mass, Node, Raft, Spring, StructureModel
from .newmark import NewmarkStepper
from .preload import StaticState, solve_static
from .results import RouteResult
from .driver import simulate
from .soil_interface import SoilInterface, WinklerSoil
from .spec import contact_from_spec, model_from_spec, winkler_from_spec

__all__ = ["G_ACC", "Beam", "ContactSettings", "ConvergenceError", "Damping", "Mass", "NewmarkStepper",
           "Node", "Raft", "RouteResult", "SoilInterface", "Spring", "StaticState",
           "StructureError", "StructureModel", "WinklerSoil", "damping_matrix",
           "contact_from_spec", "fixed_base_modes", "model_from_spec", "simulate",
           "solve_static", "winkler_from_spec"]

"""The time-frequency (TF) reference solver: the soil applied per frequency (the BEM table
itself, no rational fit), the structure condensed exactly on the raft (rigid, or a plate's raft
coordinates), the unilateral contact
solved over the whole time range (paper §3). Depends on numpy, scipy, pyfftw, soil_impedance
and structure only: no scene, no command line.

The pieces, in the order a solve uses them:

============== ===============================================================================
solver_options GridOptions, SolveOptions, PaperOptions, NewtonKrylovOptions (frozen, checked)
grid           Grid: zero padding, exponential window, (bilinear) Laplace variable, pyfftw FFTs
soil           soil_bands: K(s) of an ImpedanceTable, WinklerSoil, RationalModel or its recursion
operator       ModalStructure, InterfaceOperator (interface stiffness S, blocked force f, raft
               back-substitution), WorkerPool (the threads of the per-frequency work)
flexible       PlateStructure: a plate raft (structure.plate_raft) condensed on its raft
               coordinates [q, t] per frequency; its static preload, its least padding
problem        prepare -> ContactProblem (grid, operator, static preload, renormalised unknown),
               ContactEquation (whole-range residual g), SolverStatus, Outcome, route_result
march          the default solver: causal marches + defect correction (MarchSweep per sweep)
farfield       the march's far field: one application of S, or the springs and dashpots in
               closed form (AffineSplit, also the kernel head)
methods        METHODS: the solvers by name (SolveOptions.method), DEFAULT "march"
experimental/  newton_krylov, paper: EXPERIMENTAL solvers, by name only, warned when used
solver         solve(): options -> prepare -> solver -> RouteResult (the ``timefreq`` route's core)
bonded         linear_fd(), solve_bonded(): the raft bonded, no uplift (the ``linear`` route's core)
============== ===============================================================================

Usage::

    from orchestrator.timefreq import GridOptions, SolveOptions, solve
    res = solve(model, table, ag, dt, contact=contact, options=SolveOptions(tol=1e-6))
    res.info["history"], res.info["residual"], res.status, res.message

The scene-level glue (the scene's table, motion, contact and output nodes) is in
``orchestrator/routes/timefreq.py`` and ``orchestrator/routes/linear.py``.
"""
from uplift_common.lazy import lazy_exports

#: the public names, imported from their submodule on first use (``uplift_common.lazy``)
__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "grid": ("Grid", "pad_rule_s"),
    "bonded": ("linear_fd", "solve_bonded"),
    "march": ("DIVERGED_M", "MarchDiverged", "MarchSweep", "defect_correction", "kernel_head", "march"),
    "methods": ("DEFAULT", "METHODS", "ExperimentalMethodWarning", "Method"),
    "operator": ("InterfaceOperator", "ModalStructure", "WorkerPool"),
    "flexible": ("PLATE_PAD_S", "PlateStructure"),
    "solver_options": ("THREADS", "GridOptions", "NewtonKrylovOptions", "PaperOptions", "SolveOptions", "with_overrides"),
    "problem": ("ContactEquation", "ContactProblem", "Outcome", "SolverStatus", "prepare", "route_result"),
    "soil": ("SoilBands", "causal_table", "soil_bands"),
    "solver": ("solve",),
})

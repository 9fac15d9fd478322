"""The time-frequency (TF) reference solver: the soil applied per frequency (the BEM table
itself, no rational fit), the structure condensed exactly on the raft, the unilateral contact
solved over the whole time range (paper §3). Depends on numpy, scipy, pyfftw, soil_impedance
and structure only: no scene, no command line.

The pieces, in the order a solve uses them:

============== ===============================================================================
options        GridOptions, SolveOptions, PaperOptions, NewtonKrylovOptions (frozen, checked)
grid           Grid: zero padding, exponential window, (bilinear) Laplace variable, pyfftw FFTs
soil           soil_bands: K(s) of an ImpedanceTable, WinklerSoil, RationalModel or its recursion
operator       ModalStructure, InterfaceOperator (interface stiffness S, blocked force f, raft
               back-substitution), WorkerPool (the threads of the per-frequency work)
problem        prepare -> ContactProblem (grid, operator, static preload, renormalised unknown),
               ContactEquation (whole-range residual g), SolverStatus, Outcome, route_result
march          the default solver: causal marches + defect correction (MarchSweep per sweep)
farfield       the march's far field: one application of S, or the springs and dashpots in
               closed form (AffineSplit, also the kernel head)
methods        METHODS: the solvers by name (SolveOptions.method), DEFAULT "march"
experimental/  newton_krylov, paper: EXPERIMENTAL solvers, by name only, warned when used
uplift         solve(): options -> prepare -> solver -> RouteResult (the ``timefreq`` route's core)
linear         linear_fd(), solve_bonded(): the raft bonded, no uplift (the ``linear`` route's core)
============== ===============================================================================

Usage::

    from orchestrator.timefreq import GridOptions, SolveOptions, solve
    res = solve(model, table, ag, dt, contact=contact, options=SolveOptions(tol=1e-6))
    res.info["history"], res.info["residual"], res.status, res.message

The scene-level glue (the scene's table, motion, contact and output nodes) is in
``orchestrator/routes/timefreq.py`` and ``orchestrator/routes/linear.py``.
"""
from orchestrator.timefreq.grid import Grid, pad_rule_s
from orchestrator.timefreq.bonded import linear_fd, solve_bonded
from orchestrator.timefreq.march import DIVERGED_M, MarchDiverged, MarchSweep, defect_correction, kernel_head, march
from orchestrator.timefreq.methods import DEFAULT, METHODS, ExperimentalMethodWarning, Method
from orchestrator.timefreq.operator import InterfaceOperator, ModalStructure, WorkerPool
from orchestrator.timefreq.solver_options import (THREADS, GridOptions, NewtonKrylovOptions, PaperOptions,
                                           SolveOptions, with_overrides)
from orchestrator.timefreq.problem import (ContactEquation, ContactProblem, Outcome, SolverStatus, prepare,
                                           route_result)
from orchestrator.timefreq.soil import SoilBands, causal_table, soil_bands
from orchestrator.timefreq.solver import solve

__all__ = ["DEFAULT", "DIVERGED_M", "METHODS", "THREADS", "ContactEquation", "ContactProblem",
           "ExperimentalMethodWarning", "Grid", "GridOptions", "InterfaceOperator", "MarchDiverged", "MarchSweep",
           "Method", "ModalStructure", "NewtonKrylovOptions", "Outcome", "PaperOptions", "SoilBands",
           "SolveOptions", "SolverStatus", "WorkerPool", "causal_table", "defect_correction", "kernel_head",
           "linear_fd", "march", "pad_rule_s", "prepare", "route_result", "soil_bands", "solve", "solve_bonded",
           "with_overrides"]

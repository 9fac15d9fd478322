"""The sweep's solver choice: the solvers, the fast solver's tolerance and when "auto" takes it,
and their checks. A light module (no scipy, no numpy): what a scene, a cache key and the memory
guard read of the solver without loading the fast solver itself (soil_impedance/fastsolve.py,
which re-exports these names, imports scipy.fft): a warm run, whose tables are read from the
cache, never loads it.
"""
from __future__ import annotations

import math

from uplift_common.errors import UserInputError

#: the sweep's solvers: "dense" (LU of F, ``sweep._compute``), "fast" (``fastsolve``, grid meshes),
#: "auto" (dense below ``AUTO_NODES`` interface nodes or on an irregular mesh, else fast)
SOLVERS = ("auto", "dense", "fast")
#: default relative residual ||b - F x|| / ||b|| of every right-hand side of the fast solver
DEFAULT_TOL = 1.0e-4
#: the admissible range of the tolerance (below 1e-12 round-off of the FFTs stalls GMRES)
TOL_RANGE = (1.0e-12, 1.0e-2)
#: "auto" picks the fast solver from this many interface nodes of a grid mesh: the measured
#: crossover of one sweep frequency, CPU seconds dense / fast (benchmarks/impedance_sweep.py
#: --solvers): 0.13 / 0.23 at 241 nodes (circle), 0.20 / 0.21 at 256 (square), 1.17 / 1.03 at
#: 593, 1.02 / 1.02 at 576, 7.9 / 3.8 at 1201, 8.9 / 4.1 at 1225; the reactor's 241 stay dense
AUTO_NODES = 500


class SolverError(UserInputError):
    """An invalid solver choice or tolerance ([impedance] solver, solver_tol)."""


def check_solver(solver, tol):
    """(solver, tol) validated: solver one of ``SOLVERS``, tol a float in ``TOL_RANGE``."""
    if solver not in SOLVERS:
        raise SolverError(f"impedance.solver = {solver!r}: use one of {SOLVERS}")
    if isinstance(tol, bool) or not isinstance(tol, (int, float)) or not _finite(tol) \
            or not TOL_RANGE[0] <= tol <= TOL_RANGE[1]:
        raise SolverError(f"impedance.solver_tol = {tol!r}: give a relative residual between "
                          f"{TOL_RANGE[0]:g} and {TOL_RANGE[1]:g} (default {DEFAULT_TOL:g})")
    return solver, float(tol)


def _finite(x) -> bool:
    """Whether the int or float ``x`` is finite (an int too large for a float is not)."""
    try:
        return math.isfinite(x)
    except OverflowError:
        return False


def resolve_solver(solver, mesh, grid: bool, outputs=("gap",)) -> str:
    """The solver of a sweep of ``outputs``: "dense" or "fast". "auto": fast on a grid mesh of
    at least ``AUTO_NODES`` nodes, else dense, and always dense for the "nodal" output (the full
    inverse: 3N right-hand sides, the LU's cost). "fast" on an irregular mesh, or for "nodal",
    is refused (SolverError)."""
    nodal = "nodal" in outputs
    if solver == "auto":
        return "fast" if grid and mesh.n >= AUTO_NODES and not nodal else "dense"
    if solver == "fast" and not grid:
        raise SolverError(f"impedance.solver = 'fast' needs a grid mesh (a circle or rectangle foundation); "
                          f"this {mesh.kind} mesh of {mesh.n} nodes has no grid: use solver = 'auto' or "
                          "'dense' (irregular meshes are solved dense)")
    if solver == "fast" and nodal:
        raise SolverError("impedance.solver = 'fast' computes the rigid and gap outputs only; the nodal "
                          "impedance (the full inverse of F) is computed dense: use solver = 'auto' or 'dense'")
    return solver

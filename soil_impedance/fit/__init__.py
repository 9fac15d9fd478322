"""Fit an ImpedanceTable with a passive common-pole rational model: ``fit_table``.

Pipeline: DOF scaling and causal target (``target``) -> poles by relaxed vector fitting on
compressed columns and residues of every entry by one least squares (``target.fit_order``) ->
for a gap table the rigid-raft correction (``rigid``) -> the order search and the passivity
enforcement of its candidates (``search``) -> report (``pipeline``); fits saved and read by
``io``, their options and constants in ``options``, the result types in ``result``. The method,
its error measures, the order criterion, causality and the work bounds are described in
docs/formulation.md ("Rational soil model").

A fit is a function of the table and its ``FitOptions`` only (every bound counts work, never
seconds); the options, the table hash, the node coordinates and the code digest are the cache
key. A tol that cannot be met is reported (``tol_reached`` False, ``message``), never hidden.
"""
from .io import load_fit, read_fit, save_fit
from .options import CODE, POLE_CAP, RIGID, RIGID_IM_FLOOR, WEIGHTINGS, FitOptions, code_version
from .pipeline import cached_fit, fit, fit_table
from .result import FitReport, FitResult
from .rigid import rigid_correct, rigid_error, rigid_errors, rigid_model, rigid_projection, rigid_protection
from .search import max_pairs
from .target import (Problem, causal_cutoff, causal_materials, causal_target, fit_order, hysteretic_floor,
                     hysteretic_part, table_scaling)

__all__ = ["CODE", "POLE_CAP", "RIGID", "RIGID_IM_FLOOR", "WEIGHTINGS", "FitOptions", "FitReport",
           "FitResult", "Problem", "cached_fit", "causal_cutoff", "causal_materials", "causal_target", "code_version", "fit",
           "fit_order", "fit_table", "hysteretic_floor", "hysteretic_part", "load_fit", "max_pairs", "read_fit",
           "rigid_correct", "rigid_error", "rigid_errors", "rigid_model", "rigid_projection", "rigid_protection",
           "save_fit", "table_scaling"]

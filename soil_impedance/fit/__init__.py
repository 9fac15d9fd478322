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
from uplift_common.lazy import lazy_exports

#: the public names, imported from their submodule on first use (``uplift_common.lazy``)
__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "continuation": ("ContinuationFit", "continuation", "continuation_fit", "continuation_model"),
    "io": ("load_fit", "read_fit", "save_fit"),
    "options": ("CODE", "POLE_CAP", "RIGID", "RIGID_IM_FLOOR", "WEIGHTINGS", "FitOptions", "code_version"),
    "pipeline": ("cached_fit", "fit", "fit_table"),
    "result": ("FitReport", "FitResult"),
    "rigid": ("rigid_correct", "rigid_error", "rigid_errors", "rigid_model", "rigid_projection", "rigid_protection"),
    "search": ("max_pairs",),
    "target": ("Problem", "causal_cutoff", "causal_materials", "causal_target", "fit_order", "hysteretic_floor", "hysteretic_part", "table_scaling"),
})

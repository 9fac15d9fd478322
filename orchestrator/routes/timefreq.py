"""``timefreq``: the paper's time-frequency method with uplift on the BEM table itself (the
reference route): the scene's gap table, motion, contact settings and output nodes handed to
``orchestrator.timefreq.solve`` (the march with the wrap-around fed back, on the bilinear grid).

API::

    from orchestrator.routes.timefreq import run_timefreq
    res = run_timefreq(motion, model, table_gap, contact=contact, output_nodes=nodes)
"""
from __future__ import annotations

import contextlib

import numpy as np

from uplift_common.errors import ComputationError, UserInputError

from orchestrator.routes.base import Route, register, route_model
from soil_impedance.blocked import in_memory

#: default tolerance on the relative whole-range residual: the reactor's max uplift and raft
#: rotation move by < 1e-6 relative from there to 1e-8 (one more sweep), far below the 0.1 %
#: the routes are compared at; solve's own 1e-10 is for the round-off checks against Newmark
TOL = 1e-6
#: keyword overrides that are neither GridOptions nor SolveOptions fields
SOLVE_KEYWORDS = ("damping", "static", "route")


def run_timefreq(motion, model, table_gap, *, contact, output_nodes, max_seconds=None, progress=None,
                 fit=None, cache_dir=None, chosen=None, **overrides):
    """RouteResult of ``solve`` on the BEM gap table ``table_gap`` (ImpedanceTable, 6+N) for
    ``motion`` (orchestrator.motion.Motion: acc (nt, 3) m/s^2, dt s), the structure ``model``,
    the ContactSettings ``contact`` and the output node names.

    max_seconds : time budget, s (None: none); progress : callable(done, total) (the progress protocol):
    the share of residual decades done, from the first sweep's residual down to the tolerance,
    as k out of n = 100 (at most 99 before the end). overrides : fields of GridOptions (pad_s,
    wrap_tol, bilinear, nfft, window) and SolveOptions (method, tol, max_iter, threads, paper,
    newton_krylov), and damping, static, route; default tol TOL.
    fit : the scene's passive fit (FitResult or RationalModel) or None: with it the march steps
    the causal stand-in (orchestrator/standin.py: the fit's poles that ``choose_poles`` keeps,
    chosen once per table, structure and step whatever the record, constrained to the route's
    continuation above the table, both cached in ``cache_dir``, on the native stepper) when that
    is passive, else the table's own kernel (and notes.warnings says why); info["march"] says
    which, info["stand_in_poles"] which poles. The answer is the table's either way (the residual
    is the table's). chosen : that choice with its constrained fit when made already
    (``standin.scene_stand_in``, once for an ensemble: ``settle``; taken when made for this
    structure and step), or None.
    cache_dir : the cache folder of the constrained fit and of the solve's set-up (the table's band
    rows and the far field's split: orchestrator/timefreq/setup_cache.py), or None: none kept.
    """
    # the solver's imports (pyfftw, scipy.interpolate: ~0.7 s) when the route runs, not with the registry
    from orchestrator.timefreq import GridOptions, SolveOptions, solve, with_overrides

    grid, options, rest = with_overrides(overrides, GridOptions(), SolveOptions(tol=TOL, max_seconds=max_seconds))
    unknown = sorted(set(rest) - set(SOLVE_KEYWORDS))
    if unknown:
        raise ValueError(f"run_timefreq: unknown option {unknown[0]!r}; options: GridOptions and SolveOptions "
                         f"fields or {', '.join(SOLVE_KEYWORDS)}")
    stand_in = None
    if fit is not None:
        # the native host and the constrained fit only when a fit is given
        from orchestrator.standin import stand_in_factory
        stand_in = stand_in_factory(table_gap, getattr(fit, "model", fit), cache_dir=cache_dir,
                                    damping=rest.get("damping"), chosen=chosen)
    return solve(model, table_gap, motion.acc, motion.dt, contact=contact, output_nodes=output_nodes,
                 grid=grid, options=options, monitor=decades_bar(progress, options.tol or TOL), stand_in=stand_in,
                 cache_dir=cache_dir, **rest)


def decades_bar(bar, tol):
    """callable(sweep, residual) driving bar(k, 100) with the share of residual decades done
    between the first sweep's residual and tol (None for bar None)."""
    if bar is None:
        return None
    first = []

    def progress(k, r):
        first.append(r)
        frac = np.log(first[0] / r) / np.log(first[0] / tol) if first[0] > tol else 1.0
        bar(int(99 * min(1.0, max(0.0, frac))), 100)
    return progress


def run(ctx, progress=None):
    fit, why = None, ""
    if getattr(ctx.scene, "raft", None) is None:    # a plate: the native stand-in marches a rigid raft only
        try:
            fit = ctx.fit()             # the scene's fit: the stand-in's poles (cached, shared with the TD routes)
        except (UserInputError, ComputationError) as exc:   # none: the march on the table's own kernel (said in the notes)
            why = str(exc).splitlines()[0]
    chosen = getattr(ctx.prepared, "made", {}).get("timefreq") if fit is not None else None
    res = run_timefreq(ctx.motion, route_model(ctx), in_memory(ctx.tables["gap"]), contact=ctx.scene.contact,
                       output_nodes=ctx.scene.output.nodes, max_seconds=ctx.scene.analysis.timefreq_max_s,
                       progress=progress, fit=fit, cache_dir=ctx.cache_dir, chosen=chosen, **ctx.options)
    if why:
        said = f"no causal stand-in (the scene's fit failed: {why}); the march on the table's own kernel ran"
        res = res.with_notes(warnings=[said])
    return res


def settle(shared):
    """An ensemble's set-up (``SharedRun.settle``): the scene's fit, the stand-in's poles (chosen
    for the scene's structure and step, whatever the record: ``standin.scene_stand_in``) and their
    constrained fit of its gap table, made once here instead of in every worker
    (``shared.made["timefreq"]``): each cell marches what a single run of its motion would. Nothing
    for a plate raft (no stand-in), nor when a fit fails (each run tries and says why)."""
    if getattr(shared.scene, "raft", None) is not None or "gap" not in shared.tables:
        return
    from orchestrator.standin import scene_stand_in      # the native host and the fit stack: only when settled
    with contextlib.suppress(UserInputError, ComputationError):
        shared.made["timefreq"] = scene_stand_in(shared.model, in_memory(shared.tables["gap"]), shared.soil_fit().model,
                                                 shared.scene.analysis.dt, cache_dir=shared.cache_dir)


ROUTE = register(Route(
    name="timefreq",
    summary="TF reference (paper §3): the BEM table per frequency, unilateral contact over the whole time "
            "range on the trapezoidal grid, solved by causal marches with the wrap-around fed back",
    run=run,
    options=("pad_s",),
    bench={"disk-halfspace": {"dt": (0.01, 0.005, 0.0025), "pad_s": (0.25, 1.0, 4.0),
                              "element_size": (3.0, 2.0, 1.5)},
           "reactor": {"dt": (0.01, 0.005), "pad_s": (0.25, 2.0), "element_size": (4.0, 2.28)}},
    quick={"disk-halfspace": {"dt": (0.01, 0.005)}},
    reference_rank=3,
    settle=settle,
))

"""The time-frequency solve with uplift (paper §3): ``solve`` -> RouteResult.

Methods (``SolveOptions.method``, by name from methods.METHODS):

* "march" (the default, march.defect_correction): the causal part of the
  equations marched step by step as the Newmark stepper does (a semi-smooth Newton on the N
  contact conditions of each step, the soil's history from the kernel of S per frequency),
  and what the periodic grid adds (the wrap-around; a table's non-causal part) fed back as a
  source, sweep after sweep, Anderson-accelerated, to the whole-range residual's tolerance.
  No global Newton step has to cross thousands of contact switches at once: on a causal soil
  (the 21-node Winkler raft) it converges from 0.1 to 1.0 g in <= 6 sweeps. A BEM table is
  not causal on the grid (springs and dashpots continue it above its last frequency): its
  march starts on the truncated kernel and starts again on the folded one
  (march.kernel_head), causal with the table's damping, if a march diverges (the truncated
  one did on the reactor from 0.6 g). A march that diverges anyway ends DIVERGED. It needs
  the bilinear grid. Its step stiffness holds the kernel's first negative lags at the step
  (march.AHEAD: on the reactor's table four sweeps instead of five, the same fixed point).
  Given a ``stand_in`` (the timefreq route with the scene's fit: orchestrator/standin.py), the
  marches step a causal stand-in instead (the fit constrained to the route's continuation, on
  the native stepper), the residual the table's: the same answer, other sweeps (on the reactor
  6 at ~0.4 CPU s each instead of 4 at ~0.75 s); the soil's own kernel when it gives none.
* "march-causal": the same marches on the plain causal kernel (no look-ahead).
* "newton-krylov" (EXPERIMENTAL, experimental/newton_krylov.py): semi-smooth Newton on the
  whole-range residual; fails from 0.4 g on the Winkler raft. The only method of the
  continuous grid, where it must be named.
* "paper" (EXPERIMENTAL, experimental/paper.py): the paper's quasi-Newton; fails from 0.2 g
  there.

With ``GridOptions(bilinear=True)`` (the default) and a RecursiveConvolutionSoil (or
WinklerSoil / RationalModel) the route solves the same discrete equations as
``structure.simulate`` (average acceleration, same penalty): the two agree to the solver
tolerance and the wrap-around (wrap_tol). On the continuous grid (bilinear=False) the sampled
contact history is interpolated band-limited and accelerations ring near impacts; a table is
evaluated at the warped frequencies on the bilinear grid, so TF vs Newmark with a fitted soil
measures the fit error alone.
"""
from __future__ import annotations

import dataclasses
import time
import warnings

import numpy as np

from soil_impedance.table import ImpedanceTable
from structure.results import RouteResult, Status
from uplift_common.errors import ComputationError

from orchestrator.timefreq.march import defect_correction
from orchestrator.timefreq.methods import DEFAULT, METHODS, ExperimentalMethodWarning
from orchestrator.timefreq.operator import WorkerPool
from orchestrator.timefreq.solver_options import GridOptions, SolveOptions
from orchestrator.timefreq.problem import ContactEquation, SolverStatus, prepare, route_result


def solve(model, soil, ag, dt, *, contact=None, damping=None, output_nodes=None, static=None,
          grid: GridOptions | None = None, options: SolveOptions | None = None, monitor=None,
          route: str = "timefreq", stand_in=None, cache_dir=None) -> RouteResult:
    """Uplift response to ground acceleration ag (nt, 3) m/s^2 at step dt (s).

    soil : ImpedanceTable ("gap", 6+N) | WinklerSoil | RationalModel | RecursiveConvolutionSoil
    contact : ContactSettings (enabled; default ContactSettings()); damping : structural damping
    (structure.damping_matrix); output_nodes : node names (None: every named node); static :
    StaticState (default: solved here); grid : GridOptions (default GridOptions(); None fields:
    the bilinear grid with the window); options : SolveOptions (default SolveOptions());
    monitor : callable(sweep, residual) after each sweep of the march (a solver monitor, not
        the progress protocol: ``orchestrator.routes.timefreq.decades_bar`` turns it into one).
    stand_in : None, or callable(prob) -> (marcher or None, reason): for the default method, a
        causal stand-in marched instead of the soil's own kernel (march.defect_correction's
        marcher; orchestrator/standin.py: the table's constrained fit on the native stepper),
        the residual and so the answer the soil's. When it gives none (reason: e.g. the
        constrained fit is not passive) or its sweeps do not converge, the march on the soil's
        own kernel runs, and the result's notes.warnings say why; info["march"] says which ran.
    cache_dir : folder where a table's set-up (the band's rows, the far field's split:
        setup_cache) is kept for the next solve of the same table, grid and structure; None: none.

    Returns a RouteResult: status CONVERGED, or STOPPED with the reason in message and the
    best iterate's histories (not converged, diverged, time budget). info["status"] the
    SolverStatus, info["history"] one dict per sweep or iteration (the solver's record),
    info["iterations"] their count, info["residual"] the final relative whole-range residual
    |g| / |f|, info["gmres_total"] the FGMRES iterations of Newton-Krylov.
    """
    t0 = time.perf_counter()
    grid = (grid or GridOptions()).resolved(bilinear=True, window=True)
    options = options or SolveOptions()
    method = METHODS[options.method or DEFAULT]
    if method.bilinear_only and not grid.bilinear:
        how = f"SolveOptions.method = {method.name!r}" if options.method else "the default method ('march')"
        raise ValueError(f"{how} needs the bilinear grid (GridOptions(bilinear=True)): on the continuous grid "
                         "the instantaneous kernel is indefinite; there only the experimental "
                         "method='newton-krylov' applies, and it must be named")
    if contact is not None and not contact.enabled:
        raise ValueError("contact.enabled is false: use the linear route (orchestrator.timefreq.linear_fd)")
    if method.experimental:
        warnings.warn(f"timefreq method {method.name!r} is experimental ({method.summary}); the robust "
                      f"method is {DEFAULT!r}", ExperimentalMethodWarning, stacklevel=2)
    deadline = None if options.max_seconds is None else t0 + float(options.max_seconds)
    with WorkerPool(options.threads) as pool:
        prob = prepare(model, soil, ag, dt, grid=grid, contact=contact, damping=damping, static=static,
                       aux_factor=method.aux_factor(options), pool=pool, cache_dir=cache_dir)
        t_setup = time.perf_counter() - t0
        out, extra, said = None, {}, []
        if stand_in is not None and method.name == DEFAULT:
            out, extra, said = _on_stand_in(prob, stand_in, options, monitor, deadline)
        if out is None:
            out, extra = method.run(prob, options, fold="auto" if isinstance(soil, ImpedanceTable) else False,
                                    monitor=monitor, deadline=deadline)
            extra = dict(extra, march="own kernel")
        info = dict(method=method.name, **extra)
        if out.residual is not None:          # the march's, through its split: a table's K not formed
            residual = float(out.residual)
        else:
            eq = ContactEquation(prob)
            residual = float(np.linalg.norm(eq.residual(out.y)) / eq.scale)
        apply_S = prob.op.n_apply
    info.update(out.extra, status=out.status.value, reason=out.reason, residual=residual,
                iterations=len(out.history), history=[dataclasses.asdict(h) for h in out.history],
                apply_S=apply_S, threads=options.threads, solve_s=time.perf_counter() - t0 - t_setup)
    z = prob.z0[:, None] + out.y
    d = -(prob.phi(z) - prob.phi(prob.z0[:, None]))
    P = prob.k[:, None] * np.maximum(z, 0.0)
    gap = np.maximum(0.0, -z)
    res = route_result(prob, route, d, P, gap, output_nodes=output_nodes,
                       status=Status.CONVERGED if out.converged else Status.STOPPED,
                       message=_message(method.name, out, residual, options.max_seconds), started=t0, info=info)
    return res.with_notes(warnings=said) if said else res


def _on_stand_in(prob, stand_in, options, monitor, deadline):
    """(Outcome or None, info, warnings) of the default march on the stand-in ``stand_in(prob)``
    (solve): None when there is none or its sweeps did not converge (the caller then marches the
    soil's own kernel; the warnings say why)."""
    try:
        marcher, why = stand_in(prob)
    except ComputationError as exc:            # the native library refused the stand-in's model
        marcher, why = None, str(exc).splitlines()[0]
    if marcher is None:
        return None, {}, [f"no causal stand-in ({why}); the march on the table's own kernel ran "
                          "(the same answer, at its cost)"]
    try:
        out = defect_correction(prob, tol=options.tol or 1e-10, max_sweeps=options.max_iter or 60, monitor=monitor,
                                deadline=deadline, stand_in=marcher)
    finally:
        if hasattr(marcher, "close"):          # its native run, kept from one march to the next
            marcher.close()
    if out.converged or out.status is SolverStatus.STOPPED:     # and the marcher's own record (its poles)
        return out, dict(march="stand-in", stand_in=why, **getattr(marcher, "info", {})), []
    return None, {}, [f"the stand-in's sweeps ended {out.status.value} ({why}; {len(out.history)} "
                      "sweeps); the march on the table's own kernel ran (the same answer, at its cost)"]


def _message(method, out, residual, max_seconds) -> str:
    """Why a solve did not converge ("" if it did)."""
    n = len(out.history)
    if out.status is SolverStatus.CONVERGED:
        return ""
    if out.status is SolverStatus.STOPPED:
        return (f"{method} stopped at its time budget ({max_seconds:g} s) after {n} iterations: relative "
                f"residual {residual:.3e}; the histories are its best iterate")
    if out.status is SolverStatus.DIVERGED and method.startswith("march"):
        return (f"{method}: {out.reason} in sweep {n}: the soil's causal part on this grid is not passive; "
                f"the histories are the best iterate (relative residual {residual:.3e}). Newton-Krylov "
                "(method='newton-krylov') or the monolithic route with the soil's passive rational fit are "
                "the alternatives")
    why = f" ({out.reason})" if out.reason else ""
    return f"{method} did not converge{why}: relative residual {residual:.3e} after {n} iterations"

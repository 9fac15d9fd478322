"""The time-frequency solve with uplift (paper §3): ``solve`` -> RouteResult.

Methods (``SolveOptions.method``):

* "march" (default on the bilinear grid, march.defect_correction): the causal part of the
  equations marched step by step as the Newmark stepper does (a semi-smooth Newton on the N
  contact conditions of each step, the soil's history from the kernel of S per frequency),
  and what the periodic grid adds (the wrap-around; a table's non-causal part) fed back as a
  source, sweep after sweep, Anderson-accelerated, to the whole-range residual's tolerance.
  No global Newton step has to cross thousands of contact switches at once: on a causal soil
  (the 21-node Winkler raft) it converges from 0.1 to 1.0 g in <= 6 sweeps. A BEM table is
  not causal on the grid (springs and dashpots continue it above its last frequency): its
  march starts on the truncated kernel and starts again on the folded one
  (march.kernel_head), causal with the table's damping, if a march diverges (the truncated
  one did on the reactor from 0.6 g). A march that diverges anyway ends DIVERGED.
* "newton-krylov" (EXPERIMENTAL; default on the continuous grid, newton_krylov.py):
  semi-smooth Newton on the whole-range residual; fails from 0.4 g on the Winkler raft.
* "paper" (EXPERIMENTAL, paper.py): the paper's quasi-Newton; fails from 0.2 g there.

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

import numpy as np

from soil_impedance.table import ImpedanceTable
from structure.results import RouteResult, Status

from orchestrator.timefreq.march import defect_correction, march, y_from_d
from orchestrator.timefreq.newton_krylov import newton_continuation
from orchestrator.timefreq.operator import WorkerPool
from orchestrator.timefreq.options import GridOptions, SolveOptions
from orchestrator.timefreq.paper import paper_scheme
from orchestrator.timefreq.problem import ContactEquation, SolverStatus, prepare, route_result


def solve(model, soil, ag, dt, *, contact=None, damping=None, output_nodes=None, static=None,
          grid: GridOptions | None = None, options: SolveOptions | None = None, progress=None,
          route: str = "timefreq") -> RouteResult:
    """Uplift response to ground acceleration ag (nt, 3) m/s^2 at step dt (s).

    soil : ImpedanceTable ("gap", 6+N) | WinklerSoil | RationalModel | RecursiveConvolutionSoil
    contact : ContactSettings (enabled; default ContactSettings()); damping : structural damping
    (structure.damping_matrix); output_nodes : node names (None: every named node); static :
    StaticState (default: solved here); grid : GridOptions (default GridOptions(); None fields:
    the bilinear grid with the window); options : SolveOptions (default SolveOptions());
    progress : callable(sweep, residual) for the march.

    Returns a RouteResult: status CONVERGED, or STOPPED with the reason in message and the
    best iterate's histories (not converged, diverged, time budget). info["status"] the
    SolverStatus, info["history"] one dict per sweep or iteration (the solver's record),
    info["iterations"] their count, info["residual"] the final relative whole-range residual
    |g| / |f|, info["gmres_total"] the FGMRES iterations of Newton-Krylov.
    """
    t0 = time.perf_counter()
    grid = (grid or GridOptions()).resolved(bilinear=True, window=True)
    options = options or SolveOptions()
    method = options.method or ("march" if grid.bilinear else "newton-krylov")
    if method == "march" and not grid.bilinear:
        raise ValueError("SolveOptions.method = 'march' needs the bilinear grid (GridOptions(bilinear=True)): on "
                         "the continuous grid the instantaneous kernel is indefinite; use 'newton-krylov' there")
    if contact is not None and not contact.enabled:
        raise ValueError("contact.enabled is false: use the linear route (orchestrator.timefreq.linear_fd)")
    deadline = None if options.max_seconds is None else t0 + float(options.max_seconds)
    aux = options.paper.aux_factor if method == "paper" else 1.0
    with WorkerPool(options.threads) as pool:
        prob = prepare(model, soil, ag, dt, grid=grid, contact=contact, damping=damping, static=static,
                       aux_factor=aux, pool=pool)
        t_setup = time.perf_counter() - t0
        info = dict(method=method)
        if method == "march":
            out = defect_correction(prob, tol=options.tol or 1e-10, max_sweeps=options.max_iter or 60,
                                    progress=progress, deadline=deadline,
                                    fold="auto" if isinstance(soil, ImpedanceTable) else False)
        elif method == "newton-krylov":
            nk = options.newton_krylov
            y0 = None
            if nk.guess == "march":
                d, info["march"] = march(prob, deadline=deadline)
                y0 = y_from_d(prob, d)
            info["guess"] = nk.guess
            out = newton_continuation(prob, tol=options.tol or 1e-10, max_iter=options.max_iter or 200,
                                      windows=nk.windows, y0=y0, deadline=deadline)
            info["gmres_total"] = int(sum(h.gmres for h in out.history))
        else:
            pa = options.paper
            out = paper_scheme(prob, rho=pa.rho, windows=pa.windows, tol=options.tol or 1e-6,
                               max_iter=options.max_iter or 200)
            info.update(rho=pa.rho, windows=pa.windows, aux_factor=pa.aux_factor)
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
    return route_result(prob, route, d, P, gap, output_nodes=output_nodes,
                        status=Status.CONVERGED if out.converged else Status.STOPPED,
                        message=_message(method, out, residual, options.max_seconds), started=t0, info=info)


def _message(method, out, residual, max_seconds) -> str:
    """Why a solve did not converge ("" if it did)."""
    n = len(out.history)
    if out.status is SolverStatus.CONVERGED:
        return ""
    if out.status is SolverStatus.STOPPED:
        return (f"{method} stopped at its time budget ({max_seconds:g} s) after {n} iterations: relative "
                f"residual {residual:.3e}; the histories are its best iterate")
    if out.status is SolverStatus.DIVERGED and method == "march":
        return (f"{method}: {out.reason} in sweep {n}: the soil's causal part on this grid is not passive; "
                f"the histories are the best iterate (relative residual {residual:.3e}). Newton-Krylov "
                "(method='newton-krylov') or the monolithic route with the soil's passive rational fit are "
                "the alternatives")
    why = f" ({out.reason})" if out.reason else ""
    return f"{method} did not converge{why}: relative residual {residual:.3e} after {n} iterations"

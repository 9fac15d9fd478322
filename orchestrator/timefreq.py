"""Time-frequency reference route (paper §3): uplift solved over the whole time range with
the soil applied per frequency.

Pieces: tf_grid (padding, exponential window, pyfftw), tf_soil (K(s) from a BEM table,
Winkler springs, a rational model or its recursion), tf_operator (structure condensed on the
raft with all fixed-base modes; interface stiffness S and blocked force f), tf_problem
(renormalised contact unknown, static preload, RouteResult), tf_march (the causal march and
its defect correction), tf_solvers (the paper's quasi-Newton and the semi-smooth
Newton-Krylov).

Methods:

* "march" (default, tf_march.defect_correction): the causal part of the equations marched step
  by step as the Newmark stepper does (a semi-smooth Newton on the N contact conditions of
  each step, the soil's history from the kernel of S per frequency), and what the periodic
  grid adds (the wrap-around; a table's non-causal part) fed back as a source, sweep after
  sweep, Anderson-accelerated, to the whole-range residual's tolerance. No global Newton step
  has to cross thousands of contact switches at once: on a causal soil (the 21-node Winkler
  raft) it converges from 0.1 to 1.0 g in <= 6 sweeps. A BEM table is not causal on the
  grid (springs and dashpots continue it above its last frequency): its march runs on the
  folded kernel (tf_march.kernel_head), causal with the table's damping, where the truncated
  one diverged on the reactor from 0.6 g. A march that diverges anyway stops with the reason
  (tf_march.MarchDiverged).
* "newton-krylov": semi-smooth Newton on the whole-range residual, FGMRES preconditioned by
  the active-set operator, line search, time horizon and load continuation; optionally
  started from the march (``guess``). On the 21-node Winkler raft (benchmarks/timefreq.py
  --map) it fails from 0.4 g from zero and from 0.6 g from the march's iterate (the
  frozen-active-set linearisation does not hold over thousands of contact switches).
* "paper" (eq. 17-20: relaxation rho, global or per-window order-0 stochastic
  linearisation): fails from 0.2 g there (0.3 g with the auxiliary stiffness at 30 K(0)).

With ``bilinear=True`` and a RecursiveConvolutionSoil (or WinklerSoil / RationalModel) the
route solves the same discrete equations as ``structure.simulate`` (average acceleration, same
penalty): the two agree to the solver tolerance and the wrap-around (wrap_tol).
"""
from __future__ import annotations

import time

import numpy as np

from orchestrator.tf_problem import prepare, result
from orchestrator.tf_solvers import newton_continuation, paper_scheme

METHODS = ("march", "newton-krylov", "paper")


def timefreq(model, soil, ag, dt, method=None, contact=None, damping=None,
             output_nodes=None, pad_s=None, wrap_tol=1e-4, bilinear=True, nfft=None, tol=None,
             max_iter=None, rho=1.0, windows=1, route="timefreq", static=None, aux_factor=1.0,
             window=True, guess=None, max_seconds=None, progress=None):
    """Uplift response to ground acceleration ag (nt, 3) m/s^2 at step dt (s).

    soil : ImpedanceTable ("gap", 6+N) | WinklerSoil | RationalModel | RecursiveConvolutionSoil
    method : "march" | "newton-krylov" | "paper" (default: "march" on a bilinear grid,
    "newton-krylov" on the continuous one, whose instantaneous kernel h_0 (a band-limited
    dashpot) is indefinite, so a step of the march has no unique solution).
    tol : relative whole-range residual |g| / |f| (default 1e-10; 1e-6 for the paper's
    scheme); max_iter : sweeps or iterations.
    rho, windows : the paper's relaxation and number of averaging windows (windows also sets
    the Newton-Krylov preconditioner); aux_factor scales the paper's auxiliary stiffness k
    (the unknown's normalisation only). guess : Newton-Krylov's initial iterate: None (zero,
    with a time horizon) or "march" (one causal march). max_seconds : time budget of the solve; when it runs
    out the last iterate is returned with converged = False and the reason in message.
    progress : callable(sweep, residual) for the march.
    bilinear : True (default) solves the trapezoidal (Newmark average-acceleration) discrete
    equations with the exact soil K(s_d): every operator is a causal recursion, so contact
    kinks do not ring (on the continuous grid, False, the sampled contact history is
    interpolated band-limited and accelerations ring near impacts); a table is evaluated at
    the warped frequencies, so TF vs Newmark with a fitted soil measures the fit error alone.
    Returns a RouteResult; info["history"] holds one entry per sweep or iteration,
    info["residual"] the final relative whole-range residual, info["gmres_total"] the FGMRES
    iterations of Newton-Krylov. A solver that does not converge returns its last iterate
    with converged = False and the reason in message.
    """
    from soil_impedance.table import ImpedanceTable
    from orchestrator.tf_march import defect_correction, march, y_from_d
    from orchestrator.tf_solvers import ContactEquation, _scale

    method = method or ("march" if bilinear else "newton-krylov")
    if method not in METHODS:
        raise ValueError(f"method = {method!r}: use one of {METHODS}")
    if method == "march" and not bilinear:
        raise ValueError("method 'march' needs the bilinear grid (bilinear=True): on the continuous "
                         "grid the instantaneous kernel is indefinite; use 'newton-krylov' there")
    if guess not in (None, "march"):
        raise ValueError(f"guess = {guess!r}: use None (zero) or 'march'")
    t0 = time.perf_counter()
    deadline = None if max_seconds is None else t0 + float(max_seconds)
    prob = prepare(model, soil, ag, dt, contact=contact, damping=damping, pad_s=pad_s,
                   wrap_tol=wrap_tol, bilinear=bilinear, nfft=nfft, static=static,
                   aux_factor=aux_factor, window=window)
    if not prob.contact.enabled:
        raise ValueError("contact.enabled is false: use the linear route (orchestrator.linear_fd)")
    t_setup = time.perf_counter() - t0
    info = dict(method=method)
    if method == "march":
        y, ok, hist = defect_correction(prob, tol=tol or 1e-10, max_sweeps=max_iter or 60,
                                        progress=progress, deadline=deadline,
                                        fold="auto" if isinstance(soil, ImpedanceTable) else False)
        info.update(iterations=len(hist), history=hist)
    elif method == "newton-krylov":
        y0 = None
        if guess == "march":
            d, info["march"] = march(prob, deadline=deadline)
            y0 = y_from_d(prob, d)
        info["guess"] = guess
        y, ok, hist, ladder = newton_continuation(prob, tol=tol or 1e-10, max_iter=max_iter or 200,
                                                  windows=windows, y0=y0, deadline=deadline)
        info.update(iterations=len(hist), continuation=ladder,
                    gmres_total=int(sum(h["gmres"] for h in hist)), history=hist)
    else:
        y, ok, hist = paper_scheme(prob, rho=rho, windows=windows, tol=tol or 1e-6,
                                   max_iter=max_iter or 200)
        info.update(iterations=len(hist), rho=rho, windows=windows, history=hist)
    eq = ContactEquation(prob)
    info["residual"] = float(np.linalg.norm(eq.residual(y)) / _scale(eq))
    info["apply_S"] = prob.op.n_apply
    info["solve_s"] = time.perf_counter() - t0 - t_setup
    z = prob.z0[:, None] + y
    d = -(prob.phi(z) - prob.phi(prob.z0[:, None]))
    P = prob.k[:, None] * np.maximum(z, 0.0)
    gap = np.maximum(0.0, -z)
    if hist and hist[-1].get("diverged"):
        ok = False
        msg = (f"{method}: {hist[-1]['diverged']} in sweep {len(hist)}: the soil's causal part on "
               "this grid is not passive; the histories are the best iterate (relative residual "
               f"{info['residual']:.3e}). Newton-Krylov (method='newton-krylov') or the monolithic "
               "route with the soil's passive rational fit are the alternatives")
    elif hist and hist[-1].get("stopped"):
        ok = False
        msg = (f"{method} stopped at its time budget ({max_seconds:g} s) after {len(hist)} "
               f"iterations: relative residual {info['residual']:.3e}; the histories are its "
               "best iterate")
    elif ok:
        msg = ""
    else:
        msg = (f"{method} did not converge: relative residual {info['residual']:.3e} after "
               f"{len(hist)} iterations")
    res = result(prob, route, d, P, gap, output_nodes, ok, msg, 0.0, info)
    res.wall_s = time.perf_counter() - t0
    return res

def run_timefreq(scene, motion, model, table_gap, method=None, contact=None,
                 damping=None, output_nodes=None, **options):
    """The ``timefreq`` route of a scene: ``timefreq`` with the scene's BEM gap table, motion
    (orchestrator.motion.Motion), structure, contact settings and output nodes. Default
    tolerance 1e-6 on the relative whole-range residual: the reactor's max uplift and raft
    rotation move by < 1e-6 relative from there to 1e-8 (one more sweep), far below the 0.1 %
    the routes are compared at; the 1e-10 of ``timefreq`` is for the round-off checks against
    Newmark."""
    options.setdefault("tol", 1e-6)
    from structure.spec import contact_from_spec

    from orchestrator.run import output_nodes as scene_nodes

    contact = contact or contact_from_spec(scene.section("contact"))
    nodes = output_nodes if output_nodes is not None else scene_nodes(scene)
    bar = options.pop("progress", None)
    if bar is not None:      # bar(k, n) as the steppers': the share of residual decades done
        tol, first = options["tol"], []

        def progress(k, r):
            first.append(r)
            frac = np.log(first[0] / r) / np.log(first[0] / tol) if first[0] > tol else 1.0
            bar(int(99 * min(1.0, max(0.0, frac))), 100)
        options["progress"] = progress
    return timefreq(model, table_gap, motion.acc, motion.dt, method=method, contact=contact,
                    damping=damping, output_nodes=nodes, **options)

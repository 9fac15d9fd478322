"""Time-frequency reference route (paper §3): uplift solved over the whole time range with
the soil applied per frequency.

Pieces: tf_grid (padding, exponential window, pyfftw), tf_soil (K(s) from a BEM table,
Winkler springs, a rational model or its recursion), tf_operator (structure condensed on the
raft with all fixed-base modes; interface stiffness S and blocked force f), tf_problem
(renormalised contact unknown, static preload, RouteResult), tf_solvers (the paper's
quasi-Newton and the semi-smooth Newton-Krylov).

Methods: "newton-krylov" (default: semi-smooth Newton, FGMRES preconditioned by the averaged
operator, line search, load continuation) and "paper" (eq. 17-20: relaxation rho, global or
per-window order-0 stochastic linearisation). With ``bilinear=True`` and a
RecursiveConvolutionSoil (or WinklerSoil / RationalModel) the route solves the same discrete
equations as ``structure.simulate`` (average acceleration, same penalty): the two agree to
the solver tolerance.
"""
from __future__ import annotations

import time

import numpy as np

from orchestrator.tf_problem import prepare, result
from orchestrator.tf_solvers import newton_continuation, paper_scheme

METHODS = ("newton-krylov", "paper")


def timefreq(model, soil, ag, dt, method="newton-krylov", contact=None, damping=None,
             output_nodes=None, pad_s=None, wrap_tol=1e-4, bilinear=True, nfft=None, tol=None,
             max_iter=None, rho=1.0, windows=1, route="timefreq", static=None, aux_factor=1.0,
             window=True):
    """Uplift response to ground acceleration ag (nt, 3) m/s^2 at step dt (s).

    soil : ImpedanceTable ("gap", 6+N) | WinklerSoil | RationalModel | RecursiveConvolutionSoil
    method : "newton-krylov" | "paper"; tol : relative residual |g| / |f| (default 1e-10 for
    Newton-Krylov, 1e-6 for the paper's scheme); rho, windows : the paper's relaxation and
    number of averaging windows (windows also sets the Newton-Krylov preconditioner);
    aux_factor scales the paper's auxiliary stiffness k (the unknown's normalisation only).
    bilinear : True (default) solves the trapezoidal (Newmark average-acceleration) discrete
    equations with the exact soil K(s_d): every operator is a causal recursion, so contact
    kinks do not ring (on the continuous grid, False, the sampled contact history is
    interpolated band-limited and accelerations ring near impacts); a table is evaluated at
    the warped frequencies, so TF vs Newmark with a fitted soil measures the fit error alone.
    Returns a RouteResult; info["history"] holds one entry per iteration, info["gmres_total"]
    the FGMRES iterations (one J v product each). A solver that does not converge returns its
    last iterate with converged = False and the reason in message.
    """
    if method not in METHODS:
        raise ValueError(f"method = {method!r}: use one of {METHODS}")
    t0 = time.perf_counter()
    prob = prepare(model, soil, ag, dt, contact=contact, damping=damping, pad_s=pad_s,
                   wrap_tol=wrap_tol, bilinear=bilinear, nfft=nfft, static=static,
                   aux_factor=aux_factor, window=window)
    if not prob.contact.enabled:
        raise ValueError("contact.enabled is false: use the linear route (orchestrator.linear_fd)")
    t_setup = time.perf_counter() - t0
    if method == "newton-krylov":
        y, ok, hist, ladder = newton_continuation(prob, tol=tol or 1e-10, max_iter=max_iter or 200,
                                                  windows=windows)
        info = dict(method=method, iterations=len(hist), continuation=ladder,
                    gmres_total=int(sum(h["gmres"] for h in hist)), history=hist)
    else:
        y, ok, hist = paper_scheme(prob, rho=rho, windows=windows, tol=tol or 1e-6,
                                   max_iter=max_iter or 200)
        info = dict(method=method, iterations=len(hist), rho=rho, windows=windows, history=hist)
    info["apply_S"] = prob.op.n_apply
    info["solve_s"] = time.perf_counter() - t0 - t_setup
    z = prob.z0[:, None] + y
    d = -(prob.phi(z) - prob.phi(prob.z0[:, None]))
    P = prob.k[:, None] * np.maximum(z, 0.0)
    gap = np.maximum(0.0, -z)
    msg = "" if ok else (f"{method} did not converge: relative residual "
                         f"{hist[-1]['residual'] if hist else float('nan'):.3e} after {len(hist)} iterations")
    res = result(prob, route, d, P, gap, output_nodes, ok, msg, 0.0, info)
    res.wall_s = time.perf_counter() - t0
    return res


def run_timefreq(scene, motion, model, table_gap, method="newton-krylov", contact=None,
                 damping=None, output_nodes=None, **options):
    """The ``timefreq`` route of a scene: ``timefreq`` with the scene's BEM gap table, motion
    (orchestrator.motion.Motion), structure, contact settings and output nodes. Default
    tolerance 1e-8 (relative residual: far below the 0.1 % the routes are compared at; the
    1e-10 of ``timefreq`` is for the round-off checks against Newmark)."""
    options.setdefault("tol", 1e-8)
    from structure.spec import contact_from_spec

    from orchestrator.run import output_nodes as scene_nodes

    contact = contact or contact_from_spec(scene.section("contact"))
    nodes = output_nodes if output_nodes is not None else scene_nodes(scene)
    return timefreq(model, table_gap, motion.acc, motion.dt, method=method, contact=contact,
                    damping=damping, output_nodes=nodes, **options)

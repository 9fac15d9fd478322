"""The solvers of the uplift solve by name: ``METHODS`` maps ``SolveOptions.method`` to a
``Method`` (how to run it on a prepared ContactProblem). ``DEFAULT`` is the robust one, the
march with the wrap-around fed back (march.py); the others live in ``experimental/``, are
never a default and warn (``ExperimentalMethodWarning``) when ``solve`` uses them.

Adding a solver is one entry: a function ``run(prob, options, *, fold, monitor, deadline)
-> (Outcome, info dict)`` and its flags.
"""
from __future__ import annotations

from dataclasses import dataclass
from collections.abc import Callable

from orchestrator.timefreq.experimental.newton_krylov import newton_continuation
from orchestrator.timefreq.experimental.paper import paper_scheme
from orchestrator.timefreq.march import AHEAD, defect_correction, march, y_from_d


class ExperimentalMethodWarning(UserWarning):
    """An experimental solver (orchestrator.timefreq.experimental) was asked for by name."""


@dataclass(frozen=True)
class Method:
    """One solver. run(prob, options, fold=, monitor=, deadline=) -> (Outcome, info);
    experimental: warn when used, never a default; bilinear_only: needs the bilinear grid
    (a positive definite instantaneous kernel); aux_factor(options): the auxiliary stiffness
    factor of the unknown's normalisation (problem.prepare); summary: one line."""
    name: str
    run: Callable
    summary: str
    experimental: bool = False
    bilinear_only: bool = False
    aux_factor: Callable = lambda options: 1.0


def _march(prob, options, *, fold, monitor, deadline, ahead=AHEAD):
    out = defect_correction(prob, tol=options.tol or 1e-10, max_sweeps=options.max_iter or 60,
                            monitor=monitor, deadline=deadline, fold=fold, ahead=ahead)
    return out, dict(ahead=ahead)


def _march_causal(prob, options, *, fold, monitor, deadline):
    return _march(prob, options, fold=fold, monitor=monitor, deadline=deadline, ahead=0)


def _newton_krylov(prob, options, *, fold, monitor, deadline):
    nk = options.newton_krylov
    info = dict(guess=nk.guess)
    y0 = None
    if nk.guess == "march":
        d, info["march"] = march(prob, deadline=deadline)
        y0 = y_from_d(prob, d)
    out = newton_continuation(prob, tol=options.tol or 1e-10, max_iter=options.max_iter or 200,
                              windows=nk.windows, y0=y0, deadline=deadline)
    info["gmres_total"] = int(sum(h.gmres for h in out.history))
    return out, info


def _paper(prob, options, *, fold, monitor, deadline):
    pa = options.paper
    out = paper_scheme(prob, rho=pa.rho, windows=pa.windows, tol=options.tol or 1e-6,
                       max_iter=options.max_iter or 200)
    return out, dict(rho=pa.rho, windows=pa.windows, aux_factor=pa.aux_factor)


#: the solvers by name (``SolveOptions.method``)
METHODS = {m.name: m for m in (
    Method("march", _march, "causal marches with the wrap-around fed back, the kernel's first negative "
           "lags held at the step (the robust default)", bilinear_only=True),
    Method("march-causal", _march_causal, "the same marches on the plain causal kernel (no look-ahead: "
           "one sweep more on a BEM table, the same fixed point)", bilinear_only=True),
    Method("newton-krylov", _newton_krylov, "semi-smooth Newton-Krylov on the whole-range residual; "
           "fails from 0.4 g on the Winkler raft", experimental=True),
    Method("paper", _paper, "the paper's quasi-Newton; fails from 0.2 g on the Winkler raft",
           experimental=True, aux_factor=lambda options: options.paper.aux_factor),
)}
#: the method of SolveOptions(method=None)
DEFAULT = "march"

"""Options of the frequency-domain routes, as small frozen dataclasses checked on construction.

``GridOptions``          the time-frequency grid: padding, window, bilinear map, FFT length
``SolveOptions``         the uplift solve: method (a name of methods.METHODS), tolerance,
                         iterations, time budget, threads, and the experimental methods' options:
``PaperOptions``         the paper's quasi-Newton scheme (relaxation, windows, auxiliary stiffness)
``NewtonKrylovOptions``  the semi-smooth Newton-Krylov solver (windows, initial iterate)

``None`` in a field means "the route's default" (said at each field). Bad values raise
ValueError naming the field and what it accepts.
"""
from __future__ import annotations

import math
from numbers import Integral, Real
from dataclasses import dataclass, field, fields, replace

#: default worker threads of the frequency-domain operator (operator.WorkerPool). The operator
#: is about a third of a reactor solve; on two shared cores (benchmarks/timefreq.py
#: --contention) a second thread is never materially slower, idle or beside a busy process:
#: its threads block (no spin-wait), unlike threaded BLAS.
THREADS = 2


def _positive(owner, name, value, allow_none=False, allow_zero=False):
    if value is None and allow_none:
        return
    ok = isinstance(value, Real) and not isinstance(value, bool) and math.isfinite(value) \
        and (value >= 0 if allow_zero else value > 0)
    if not ok:
        what = "a finite number >= 0" if allow_zero else "a finite positive number"
        raise ValueError(f"{owner}.{name} = {value!r} must be {what}" + (" or None" if allow_none else ""))


def _count(owner, name, value, allow_none=False):
    if value is None and allow_none:
        return
    if isinstance(value, bool) or not isinstance(value, Integral) or value < 1:
        raise ValueError(f"{owner}.{name} = {value!r} must be a positive integer" + (" or None" if allow_none else ""))


def _flag(owner, name, value):
    if value is not None and not isinstance(value, bool):
        raise ValueError(f"{owner}.{name} = {value!r} must be True, False or None (the route's default)")


@dataclass(frozen=True)
class GridOptions:
    """The time-frequency grid (see grid.py).

    pad_s : zero padding, s (None: the rule, max(1 s, 3 tau_1) with the window,
            max(1 s, ln(1/wrap_tol) tau_1) without; tau_1 the slowest fixed-base mode's decay time)
    wrap_tol : attenuation of what wraps around (0 < wrap_tol < 1)
    bilinear : s -> the trapezoidal s_d (the Newmark average-acceleration equations) (None: the
               route's default: True for the uplift solve, False for the linear route)
    nfft : FFT length (None: the padding rule's, rounded up to 2^a 3^b 5^c)
    window : exponential window eta = ln(1/wrap_tol) / (nfft dt) (None: the route's default:
             True for the uplift solve; the linear route keeps it on the bilinear grid only)
    """
    pad_s: float | None = None
    wrap_tol: float = 1e-4
    bilinear: bool | None = None
    nfft: int | None = None
    window: bool | None = None

    def __post_init__(self):
        _positive("GridOptions", "pad_s", self.pad_s, allow_none=True, allow_zero=True)
        _positive("GridOptions", "wrap_tol", self.wrap_tol)
        if not self.wrap_tol < 1:
            raise ValueError(f"GridOptions.wrap_tol = {self.wrap_tol!r} must be below 1 (e.g. 1e-4)")
        _count("GridOptions", "nfft", self.nfft, allow_none=True)
        _flag("GridOptions", "bilinear", self.bilinear)
        _flag("GridOptions", "window", self.window)

    def resolved(self, bilinear: bool, window: bool | None = None) -> GridOptions:
        """These options with a route's defaults in place of None: ``bilinear``, and ``window``
        (None: the window on the bilinear grid only)."""
        b = bilinear if self.bilinear is None else self.bilinear
        w = self.window if self.window is not None else (b if window is None else window)
        return replace(self, bilinear=b, window=w)


@dataclass(frozen=True)
class PaperOptions:
    """EXPERIMENTAL method "paper" (paper eq. 17-20). rho : relaxation (> 0); windows :
    averaging windows of the order-0 stochastic linearisation; aux_factor : the auxiliary
    stiffness k = aux_factor x the soil's local K(0)[w_i, w_i] (the unknown's normalisation:
    the scheme's convergence depends on it, the solution does not)."""
    rho: float = 1.0
    windows: int = 1
    aux_factor: float = 1.0

    def __post_init__(self):
        _positive("PaperOptions", "rho", self.rho)
        _count("PaperOptions", "windows", self.windows)
        _positive("PaperOptions", "aux_factor", self.aux_factor)


@dataclass(frozen=True)
class NewtonKrylovOptions:
    """EXPERIMENTAL method "newton-krylov". windows : time windows of the active-set
    preconditioner; guess : the initial iterate, None (zero, with an advancing time horizon)
    or "march" (one causal march)."""
    windows: int = 1
    guess: str | None = None

    def __post_init__(self):
        _count("NewtonKrylovOptions", "windows", self.windows)
        if self.guess not in (None, "march"):
            raise ValueError(f"NewtonKrylovOptions.guess = {self.guess!r}: use None (zero) or 'march'")


@dataclass(frozen=True)
class SolveOptions:
    """The uplift solve.

    method : a name of methods.METHODS: "march" (the default, None) or an experimental one,
             "newton-krylov" | "paper" (warned when used; the continuous grid, whose
             instantaneous kernel is indefinite, has no robust method: name one there)
    tol : relative whole-range residual |g| / |f| (None: 1e-10; 1e-6 for "paper")
    max_iter : sweeps or iterations (None: 60 sweeps of the march, 200 iterations otherwise)
    max_seconds : time budget, s (None: none); when it runs out the best iterate is returned,
                  flagged STOPPED (the only option that makes a result depend on the machine)
    threads : worker threads of the frequency-domain operator (THREADS; 1: none; the result
              does not depend on it)
    paper, newton_krylov : the experimental methods' options
    """
    method: str | None = None
    tol: float | None = None
    max_iter: int | None = None
    max_seconds: float | None = None
    threads: int = THREADS
    paper: PaperOptions = field(default_factory=PaperOptions)
    newton_krylov: NewtonKrylovOptions = field(default_factory=NewtonKrylovOptions)

    def __post_init__(self):
        # the registry imports the solvers, which import these options: looked up when checked
        from orchestrator.timefreq.methods import METHODS
        if self.method is not None and self.method not in METHODS:
            raise ValueError(f"SolveOptions.method = {self.method!r}: use one of {tuple(METHODS)} or None")
        _positive("SolveOptions", "tol", self.tol, allow_none=True)
        _count("SolveOptions", "max_iter", self.max_iter, allow_none=True)
        _positive("SolveOptions", "max_seconds", self.max_seconds, allow_none=True, allow_zero=True)
        _count("SolveOptions", "threads", self.threads)
        if not isinstance(self.paper, PaperOptions):
            raise ValueError(f"SolveOptions.paper = {self.paper!r} must be a PaperOptions")
        if not isinstance(self.newton_krylov, NewtonKrylovOptions):
            raise ValueError(f"SolveOptions.newton_krylov = {self.newton_krylov!r} must be a NewtonKrylovOptions")


def with_overrides(overrides: dict, *targets):
    """Flat keyword overrides {field: value} applied to the option objects ``targets`` (each
    key to the first target that has that field). Returns (updated targets..., the keys no
    target has, as a dict)."""
    rest = dict(overrides)
    out = []
    for t in targets:
        names = {f.name for f in fields(t)}
        mine = {k: rest.pop(k) for k in list(rest) if k in names}
        out.append(replace(t, **mine) if mine else t)
    return (*out, rest)

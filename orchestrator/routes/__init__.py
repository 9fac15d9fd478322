"""The routes of a scene, one module each, and their registry (see ``base``).

========== ==================================================================================
winkler    spring-and-dashpot mattress calibrated on the BEM (paper §4, the industrial route)
monolithic BEM impedance as a fitted rational model, recursive convolution, in process
cosim      the same as two FMUs under the project's master (equal to monolithic to round-off)
linear     the BEM table per frequency, raft bonded (no uplift): the exact linear reference
timefreq   the paper's time-frequency method with uplift on the BEM table (the reference)
========== ==================================================================================

Adding a route: a module here that calls ``register(Route(...))``, named in ``base.BUILTIN``
(imported when the route is first asked for: ``get_route``), or ``register`` from user code. Everything that
lists routes reads ``route_names()``.
"""
from orchestrator.routes.base import (Route, RouteInputError, RunContext, default_reference, get_route, has_uplift,
                                      register, route_names, unregister)

__all__ = ["Route", "RouteInputError", "RunContext", "default_reference", "get_route", "has_uplift", "register",
           "route_names", "unregister"]

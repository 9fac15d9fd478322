"""``monolithic``: the BEM soil as a fitted rational model run by the recursive convolution,
Newmark + penalty contact, in process (no FMU layer): the fast path and the co-simulation's
reference (``cosim`` equals it to round-off).

API::

    from orchestrator.routes.monolithic import run_monolithic
    res = run_monolithic(load_scene("reactor"))      # the scene's motion and fitted soil
"""
from __future__ import annotations

from fmus.resources import DEFAULT_SOIL_FACTORY, soil_from_model
from structure import ConvergenceError, simulate

from orchestrator.impedance import scene_fit
from orchestrator.motion import make_motion
from orchestrator.routes.base import Route, register


def route_inputs(scene, motion=None, soil_model=None, dt=None, cache_dir=None):
    """(motion, soil model, dt) with the scene's defaults: the motion at dt (default: the
    motion's step, else ``[analysis].dt``), the fit of the scene's gap table."""
    if dt is None:
        dt = motion.dt if motion is not None else scene.analysis.dt
    motion = make_motion(scene.motion, dt) if motion is None else motion.resampled(dt)
    if soil_model is None:
        soil_model = scene_fit(scene, cache_dir=cache_dir).model
    return motion, soil_model, float(dt)


def run_monolithic(scene, motion=None, soil_model=None, *, soil_factory: str | None = None,
                   soil_kwargs: dict | None = None, dt: float | None = None, progress=None,
                   cache_dir=None, model=None, route: str = "monolithic"):
    """``structure.simulate`` with the soil object itself.

    motion : Motion (default: the scene's [motion] at dt); soil_model : RationalModel
    (default: the fit of the scene's gap table); soil_factory : "module:callable" building the
    soil as factory(model, dt, **soil_kwargs) (default: the recursive convolution); dt : s
    (default: the motion's, else the scene's [analysis] dt); model : the structure model
    (default: built from the scene). Returns a RouteResult; a Newton failure returns the
    samples so far with status STOPPED.
    """
    motion, soil_model, dt = route_inputs(scene, motion, soil_model, dt, cache_dir)
    soil = soil_from_model(soil_model, dt, soil_factory or DEFAULT_SOIL_FACTORY, soil_kwargs)
    model = model or scene.model()
    try:
        res = simulate(model, soil, motion.acc, dt, contact=scene.contact, output_nodes=scene.output.nodes,
                       progress=progress, route=route)
    except ConvergenceError as exc:
        res = exc.result
    return res.with_notes(info={"soil_model": soil_model.provenance})


def run(ctx, progress=None):
    return run_monolithic(ctx.scene, ctx.motion, ctx.fit().model, progress=progress, model=ctx.model())


ROUTE = register(Route(
    name="monolithic",
    summary="TD-monolithic: BEM impedance as a fitted rational model run by recursive convolution, "
            "Newmark + penalty contact, in process",
    run=run,
    needs_fit=True,
    bench={"disk-halfspace": {"dt": (0.01, 0.005, 0.0025, 0.00125), "fit_tol": (0.05, 0.03, 0.02),
                              "element_size": (3.0, 2.0, 1.5), "penalty": (0.1, 1.0, 10.0)},
           "reactor": {"dt": (0.01, 0.005, 0.0025, 0.00125), "fit_tol": (0.1, 0.06, 0.04),
                       "element_size": (4.0, 3.0, 2.28), "penalty": (0.1, 1.0, 10.0)}},
    quick={"disk-halfspace": {"dt": (0.01, 0.005, 0.0025), "fit_tol": (0.05, 0.02)}},
))

"""The frequency-dependent-soil routes of a scene: ``cosim`` (two FMUs, our master) and
``monolithic`` (the same stepper and soil object in process, no FMU layer).

Both take the scene, its motion and the rational soil model, and return the RouteResult
every route returns; with the Gauss-Seidel schedule and the impedance split they agree to
round-off (tests/test_cosim_exact.py)::

    from orchestrator.cosim import run_cosim, run_monolithic, scene_soil_model
    scene = load_scene("reactor")
    soil = scene_soil_model(scene)                    # fit of the scene's gap impedance
    mono = run_monolithic(scene, soil_model=soil)
    cos = run_cosim(scene, soil_model=soil)           # schedule="gauss-seidel" by default
"""
from __future__ import annotations

import tempfile
import time as _time
from pathlib import Path


def scene_fit(scene, cache_dir=None, progress=None, table=None, **fit_options):
    """FitResult (model and report) of the scene's gap impedance table ((6+N)^2: raft DOFs and
    the soil vertical displacement under each node; swept here unless given), fitted by
    soil_impedance.fit.fit_table at the scene's ``[analysis].fit_tol`` unless ``tol`` is given."""
    from orchestrator.impedance import scene_impedance
    from orchestrator.run import scene_fit_tol
    from soil_impedance.fit import fit_table

    if table is None:
        table = scene_impedance(scene, ("gap",), cache_dir=cache_dir, progress=progress)["gap"]
    fit_options.setdefault("cache_dir", cache_dir)
    fit_options.setdefault("tol", scene_fit_tol(scene))
    fit_options.setdefault("node_xy", scene.mesh.xy)     # for the rigid-raft correction of the fit
    return fit_table(table, **fit_options)


def scene_soil_model(scene, cache_dir=None, progress=None, table=None, **fit_options):
    """The RationalModel of ``scene_fit`` (the soil of the monolithic and cosim routes)."""
    return scene_fit(scene, cache_dir, progress, table, **fit_options).model


def _inputs(scene, motion, soil_model, dt, cache_dir):
    from orchestrator.run import scene_analysis, scene_motion

    if dt is None:
        dt = motion.dt if motion is not None else scene_analysis(scene)[1]
    if motion is None:
        motion = scene_motion(scene, dt)
    elif abs(motion.dt - dt) > 1e-12 * dt:
        motion = motion.resampled(dt)
    if soil_model is None:
        soil_model = scene_soil_model(scene, cache_dir=cache_dir)
    return motion, soil_model, float(dt)


def run_monolithic(scene, motion=None, soil_model=None, *, soil_factory: str | None = None,
                   soil_kwargs: dict | None = None, dt: float | None = None, progress=None,
                   cache_dir=None, route: str = "monolithic"):
    """The in-process route: ``structure.simulate`` with the soil object itself.

    motion : Motion (default: the scene's [motion] at dt); soil_model : RationalModel
    (default: ``scene_soil_model(scene)``); soil_factory : "module:callable" building the soil
    as factory(model, dt, **soil_kwargs) (default: the recursive convolution); dt : s
    (default: the motion's, else the scene's [analysis] dt). Returns a RouteResult; a Newton
    failure returns the samples so far with converged = False.
    """
    from fmus.common import DEFAULT_SOIL_FACTORY, soil_from_model
    from orchestrator.run import output_nodes, scene_model
    from structure import ConvergenceError, simulate
    from structure.spec import contact_from_spec

    motion, soil_model, dt = _inputs(scene, motion, soil_model, dt, cache_dir)
    soil = soil_from_model(soil_model, dt, soil_factory or DEFAULT_SOIL_FACTORY, soil_kwargs)
    try:
        res = simulate(scene_model(scene), soil, motion.acc, dt, contact=contact_from_spec(scene.section("contact")),
                       output_nodes=output_nodes(scene), progress=progress, route=route)
    except ConvergenceError as exc:
        res = exc.result
    res.info["soil_model"] = soil_model.provenance
    return res


def run_cosim(scene, motion=None, soil_model=None, *, schedule: str = "gauss-seidel",
              soil_factory: str | None = None, soil_kwargs: dict | None = None, dt: float | None = None,
              workdir=None, progress=None, cache_dir=None, route: str = "cosim"):
    """The co-simulation route: export the two FMUs (into ``workdir``, a temporary directory
    by default) and run them with ``orchestrator.master.cosimulate``.

    schedule : "gauss-seidel" (default, exact), "jacobi" or "total-force" (see master.py).
    Other arguments as run_monolithic. Returns a RouteResult with ``info["timing"]`` and
    ``info["timing_cpu"]`` (wall and CPU time per part: initialisation, structure step, soil
    step, transfers) and ``info["build_s"]`` (FMU build, not in ``wall_s``).
    """
    from fmus.build import build_fmus
    from orchestrator.export import fmu_data
    from orchestrator.master import cosimulate

    motion, soil_model, dt = _inputs(scene, motion, soil_model, dt, cache_dir)
    with tempfile.TemporaryDirectory(prefix="uplift_cosim_") as tmp:
        out = Path(workdir) if workdir is not None else Path(tmp)
        t0 = _time.perf_counter()
        s, g = build_fmus(fmu_data(scene, soil_model, dt, None, soil_factory, soil_kwargs), out)
        build_s = _time.perf_counter() - t0
        res = cosimulate(s, g, motion.acc, dt, schedule=schedule, route=route, progress=progress)
    res.xy = scene.mesh.xy.copy()
    res.info.update(build_s=build_s, soil_model=soil_model.provenance)
    return res

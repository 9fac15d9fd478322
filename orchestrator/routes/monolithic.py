"""``monolithic``: the BEM soil as a fitted rational model run by the recursive convolution,
Newmark + penalty contact, structure and soil stepped together in one process (no master, no
FMI calls, no exchange between two units): the fast path and the co-simulation's reference
(``cosim`` equals it to round-off).

Two steppers compute the same discrete equations (to round-off): ``"native"`` (default), the
numerics of the native FMUs' C runtime (stepper.c, soil.c) called in process through ctypes,
without their FMI layer, a chunk of steps per call (progress reported and Ctrl-C taken between
two; fmus/native_stepper.py), and
``"python"``, ``structure.simulate`` (the readable reference). The native stepper runs the
default soil (the recursive convolution of the rational model); with another soil factory, or
where no C compiler is available, the Python stepper runs and ``notes.warnings`` says why.

API::

    from orchestrator.routes.monolithic import run_monolithic
    res = run_monolithic(load_scene("reactor"))      # the scene's motion and fitted soil
"""
from __future__ import annotations

import dataclasses
import time

import numpy as np

from fmus.resources import DEFAULT_SOIL_FACTORY, soil_from_model
from structure import ConvergenceError, simulate
from structure.plate_raft import PlateRaftModel, PlateStepper

from orchestrator.impedance import scene_fit
from orchestrator.motion import make_motion
from orchestrator.routes.base import Route, RouteInputError, register


def route_inputs(scene, motion=None, soil_model=None, dt=None, cache_dir=None):
    """(motion, soil model, dt) with the scene's defaults: the motion at dt (default: the
    motion's step, else ``[analysis].dt``), the fit of the scene's gap table."""
    if dt is None:
        dt = motion.dt if motion is not None else scene.analysis.dt
    motion = make_motion(scene.motion, dt) if motion is None else motion.resampled(dt)
    if soil_model is None:
        soil_model = scene_fit(scene, cache_dir=cache_dir).model
    return motion, soil_model, float(dt)


#: the steppers of the route: the C runtime in process, or structure.simulate
STEPPERS = ("native", "python")


def _check_stepper(stepper: str) -> None:
    if stepper not in STEPPERS:
        raise RouteInputError(f"stepper = {stepper!r}: use one of {', '.join(STEPPERS)}")


def run_monolithic(scene, motion=None, soil_model=None, *, soil_factory: str | None = None,
                   soil_kwargs: dict | None = None, dt: float | None = None, progress=None,
                   cache_dir=None, model=None, route: str = "monolithic", stepper: str = "native"):
    """The scene's structure on the soil model, stepped in process.

    motion : Motion (default: the scene's [motion] at dt); soil_model : RationalModel
    (default: the fit of the scene's gap table); soil_factory : "module:callable" building the
    soil as factory(model, dt, **soil_kwargs) (default: the recursive convolution, given the
    interface nodes ``xy``: its history product compressed from HMATRIX_MIN_NODES nodes on,
    soil_impedance/hhistory.py; ``soil_kwargs={"history": "dense"}`` keeps it whole); dt : s
    (default: the motion's, else the scene's [analysis] dt); model : the structure model
    (default: built from the scene; a scene with a plate raft: ``scene.plate_model()``, which
    either stepper runs: the C runtime's plate trace, or structure.plate_raft.PlateStepper);
    stepper : "native" (the C runtime, falling back to "python" with a warning where it cannot
    run) or "python" (``structure.simulate``).
    Returns a RouteResult (``info["stepper"]``: the one that ran); a Newton failure returns the
    samples so far with status STOPPED.
    """
    _check_stepper(stepper)                 # before the fit is read or computed
    motion, soil_model, dt = route_inputs(scene, motion, soil_model, dt, cache_dir)
    factory = soil_factory or DEFAULT_SOIL_FACTORY
    if factory == DEFAULT_SOIL_FACTORY and "xy" not in (soil_kwargs or {}):
        # the interface nodes: the history product compressed on a large raft (history = "auto")
        soil_kwargs = {**(soil_kwargs or {}), "xy": scene.mesh.xy}
    soil = soil_from_model(soil_model, dt, factory, soil_kwargs)
    model = model or (scene.plate_model() if getattr(scene, "raft", None) is not None else scene.model())
    why = (f"the soil factory {factory} has no native runtime: the Python stepper ran"
           if stepper == "native" and factory != DEFAULT_SOIL_FACTORY else "")
    warnings = []
    if isinstance(model, PlateRaftModel):
        warnings += plate_warnings(model, scene.mesh.radius)
    res = step_scene(scene, model, soil, motion, route=route, progress=progress, cache_dir=cache_dir,
                     stepper=stepper, why=why)
    info = {"soil_model": getattr(soil, "model", soil_model).provenance}     # a compressed history: its tolerance
    if isinstance(model, PlateRaftModel):
        p = model.plate
        info["raft"] = {"kind": "plate", "thickness_m": p.thickness, "E_Pa": p.E, "nu": p.nu, "rho_kg_m3": p.rho,
                        "rigid_radius_m": p.rigid_radius, "rigid_centre_m": [p.rigid_x, p.rigid_y],
                        "held_reach_m": model.held_reach, "vertices": model.n_vertices, "free_vertices": model.nf,
                        "plate_mass_kg": float(model.vertex_masses[0].sum()),
                        "dropped_mass_coupling_m": model.mass_coupling, "damping_ratio": p.damping,
                        "damping_hz": p.damping_hz, "base_cells": int(model.base_cells.size)}
    return res.with_notes(info=info, warnings=warnings)


#: a held region whose outermost vertex lies within this fraction of raft.rigid_radius is said
#: to be coarser than its radius (a 6 m radius on a 4 m grid holds the 4 m central square: 2.83 m)
HELD_REACH = 0.75


def plate_warnings(model: PlateRaftModel, radius: float) -> list:
    """What a run of the plate raft ``model`` (on a raft of ``radius`` m) says in notes.warnings:
    a held region whose mass centre is off the raft centre (its dropped mass coupling)."""
    out = []
    p = model.plate
    if model.held_reach < HELD_REACH * p.rigid_radius:
        out.append(f"the plate's held region is coarser than raft.rigid_radius = {p.rigid_radius:g} m: its outermost "
                   f"held vertex is {model.held_reach:.3g} m from its centre (the mesh's vertices within the radius "
                   "are held, no more), so the stick base is smaller and the plate softer than the radius says "
                   "(docs/formulation.md, 'Flexible raft'): refine the mesh or set the radius to a ring of vertices")
    off = model.mass_coupling
    if off <= 1e-3 * radius:
        return out
    return out + [f"the plate's held region (within {p.rigid_radius:g} m of ({p.rigid_x:g}, {p.rigid_y:g}) m) has its "
                  f"mass centre {off:.3g} m off the raft centre: its uz-rx, uz-ry mass coupling is left out of "
                  "the lumped mass (docs/formulation.md, 'Flexible raft'); a region symmetric about the centre "
                  "has none"]


def step_scene(scene, model, soil, motion, *, route: str, progress=None, cache_dir=None, stepper: str = "native",
               damping=None, as_native=None, why: str = ""):
    """The structure ``model`` on ``soil`` under ``motion`` (the scene's contact and output
    nodes), stepped by the C runtime (``stepper="native"``, where its library is available and
    ``why`` is "") or by ``structure.simulate`` (``"python"``, or the fallback: ``notes.warnings``
    says why). damping : the structural damping as ``simulate`` takes it (None: the model's);
    as_native : callable(soil, dt) -> the soil the C runtime steps, a RecursiveConvolutionSoil
    (None: ``soil`` is one). Returns a RouteResult (``info["stepper"]``: the one that ran); a
    Newton failure returns the samples so far with status STOPPED."""
    _check_stepper(stepper)
    alpha = float(getattr(getattr(scene, "analysis", None), "hht_alpha", 0.0))
    folder = None
    if stepper == "native" and not why:
        from fmus.native_stepper import cache_folder, library_note   # the FMU stack: only when it steps
        folder = cache_folder(cache_dir)
        why = library_note(folder)
    try:
        if stepper == "native" and not why:
            res = _native(model, as_native(soil, motion.dt) if as_native else soil, motion, scene, route, progress,
                          folder, damping, alpha, cache_dir)
        else:
            res = simulate(model, soil, motion.acc, motion.dt, contact=scene.contact, damping=damping, alpha=alpha,
                           output_nodes=scene.output.nodes, progress=progress, route=route,
                           raft_points=getattr(scene.output, "raft_points", None))
    except ConvergenceError as exc:
        res = exc.result
    if res.info.get("stepper") != "native":
        res = res.with_notes(info={"stepper": "python"}, warnings=[why] if why else [])
    fed = contact_energy_warning(res)
    return res.with_notes(warnings=[fed]) if fed else res


#: the share of the run's largest input energy past which the contact's net work is said to
#: feed energy in (``contact_energy_warning``): a penalty contact that conserves energy returns
#: what it stored (its work equals its potential) and dissipates at most; measured on the
#: reactor's 10 s motion: the rigid raft 3e-5, a 4 m plate 0.037, a 2 m plate 880 (unbounded)
CONTACT_ENERGY_SHARE = 0.1


def contact_energy_warning(res) -> str:
    """The warning of a run whose contact feeds energy in ("" when it does not): the contact's
    stored potential exceeding its work (the energy it gave the structure and the soil beyond
    what it took) by more than CONTACT_ENERGY_SHARE of the input work at some instant. The
    trapezoidal rule (HHT alpha 0) does not damp a motion at the step's Nyquist frequency, and a
    penalty spring under a light plate vertex oscillates far above it (its omega dt in the
    hundreds): cells that open and reclose on alternate steps then pump energy in through the
    contact's switches (docs/formulation.md, 'Flexible raft')."""
    e = res.energy or {}
    if not {"input", "contact", "contact_potential"} <= set(e) or not len(e["input"]):
        return ""
    fed = np.asarray(e["contact_potential"]) - np.asarray(e["contact"])
    ref = float(np.abs(e["input"]).max())
    top = float(np.nanmax(fed))
    if not (ref > 0 and top > CONTACT_ENERGY_SHARE * ref):     # no input work (at rest): nothing to weigh
        return ""
    k = int(np.nanargmax(fed))
    return (f"the contact fed {top:.3g} J into the run by t = {res.time[k]:.3g} s, {top / max(ref, 1e-300):.3g} x the "
            f"input work ({ref:.3g} J; energy balance: 'contact' below 'contact_potential'): penalty cells that open "
            f"and close on alternate steps, undamped by the trapezoidal rule (HHT alpha "
            f"{res.info.get('alpha', 0.0):g}); the response is not to be trusted: set analysis.hht_alpha = -0.05 "
            "(numerical damping near the step's Nyquist frequency) or a stiffer raft (docs/formulation.md, "
            "'Flexible raft')")


def _native(model, soil, motion, scene, route, progress, folder, damping, alpha=0.0, cache_dir=None):
    """The run through the C runtime (fmus.native_stepper, the library in ``folder``); wall_s
    includes the stepper's set-up: a rigid raft's records read from the cache folder ``cache_dir``
    when they are there (``fmus.native_stepper.rigid_stepper``), a plate raft's stepper built."""
    from fmus.native_stepper import library, rigid_stepper, simulate_native   # the same: only when it steps
    t0 = time.perf_counter()
    if isinstance(model, PlateRaftModel):
        st = PlateStepper(model, soil, motion.dt, contact=scene.contact, damping=damping, alpha=alpha,
                          external_soil=True, ag0=motion.acc[0])
    else:
        st = rigid_stepper(model, soil, motion.dt, contact=scene.contact, damping=damping, alpha=alpha,
                           ag0=motion.acc[0], cache_dir=cache_dir)
    try:
        res = simulate_native(st, motion.acc, scene.output.nodes, route=route, lib=library(folder),
                              progress=progress, raft_points=getattr(scene.output, "raft_points", None))
    except ConvergenceError as exc:
        exc.result = dataclasses.replace(exc.result, wall_s=time.perf_counter() - t0)
        raise
    return res.with_checked(wall_s=float(time.perf_counter() - t0))       # the histories not copied again


def run(ctx, progress=None):
    model = ctx.model()
    if getattr(ctx.scene, "raft", None) is not None:
        model = ctx.scene.plate_model(model)
    return run_monolithic(ctx.scene, ctx.motion, ctx.fit().model, progress=progress, model=model,
                          cache_dir=ctx.cache_dir, stepper=ctx.options.get("stepper", "native"))


ROUTE = register(Route(
    name="monolithic",
    summary="TD-monolithic: BEM impedance as a fitted rational model run by recursive convolution, "
            "Newmark + penalty contact, in process",
    run=run,
    needs_fit=True,
    options=("stepper",),
    bench={"disk-halfspace": {"dt": (0.01, 0.005, 0.0025, 0.00125), "fit_tol": (0.05, 0.03, 0.02),
                              "element_size": (3.0, 2.0, 1.5), "penalty": (0.1, 1.0, 10.0)},
           "reactor": {"dt": (0.01, 0.005, 0.0025, 0.00125), "fit_tol": (0.1, 0.06, 0.04),
                       "element_size": (4.0, 3.0, 2.28), "penalty": (0.1, 1.0, 10.0)}},
    quick={"disk-halfspace": {"dt": (0.01, 0.005, 0.0025), "fit_tol": (0.05, 0.02)}},
    reference_rank=2,
))

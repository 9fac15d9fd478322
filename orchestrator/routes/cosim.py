"""``cosim``: the monolithic route's stepper and soil exported as two FMI 2.0 FMUs and run by
the project's master (orchestrator.master): with the split coupling every schedule (Gauss-Seidel
in either order, Jacobi) equals the monolithic route to round-off.

The pair is native by default (the C runtime, compiled for this machine once per content hash
into the cache folder: fmus.native_stepper.fmu_binaries); ``kind="python"`` runs the pythonfmu
pair. Both carry a plate raft (foundation.raft.kind = "plate": the native runtime's plate trace,
the Python structure FMU's structure.plate_raft.PlateStepper). With a soil factory other than the
default, or where no C compiler is available, the Python pair runs and ``notes.warnings`` says
why.

API::

    from orchestrator.routes.cosim import run_cosim
    res = run_cosim(load_scene("reactor"), schedule="gauss-seidel")
"""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

from fmus.resources import DEFAULT_SOIL_FACTORY
from orchestrator.routes.base import Route, register
from orchestrator.routes.monolithic import plate_warnings, route_inputs

#: what the co-simulation says about the linear pre-check (see structure.ContactSettings)
PRECHECK_COSIM = ("not available: the FMUs advance one step at a time and cannot look ahead, so "
                  "the co-simulation runs the nonlinear contact iterations (the monolithic route "
                  "has the pre-check)")


#: the FMU kinds the route runs (fmus.native_build: compiled C; fmus.build: pythonfmu)
KINDS = ("native", "python")


def run_cosim(scene, motion=None, soil_model=None, *, schedule: str = "gauss-seidel",
              soil_factory: str | None = None, soil_kwargs: dict | None = None, dt: float | None = None,
              workdir=None, progress=None, cache_dir=None, route: str = "cosim", kind: str = "native"):
    """Export the two FMUs (into ``workdir``, a temporary folder by default) and run them with
    ``orchestrator.master.cosimulate``.

    schedule : "gauss-seidel" (default), "soil-first" or "jacobi": all exact (see master.py).
    kind : "native" (default; "python" with a warning where it cannot run) or "python".
    Other arguments as ``run_monolithic``. Returns a RouteResult with ``notes.timings`` (wall
    time per part: FMU build, initialisation, structure step, soil step, transfers; the build
    is not in ``wall_s``) and ``info["timing_cpu"]`` (CPU time per part).
    """
    # the FMU stack loads only when the route runs (`uplift --help` and scenes stay light):
    from fmus.build import build_fmus               # pythonfmu
    from fmus.native_build import build_native_fmus  # fmpy's headers, the native builder
    from orchestrator.export import fmu_data        # fmpy, the native builder
    from orchestrator.master import cosimulate      # fmpy
    if kind not in KINDS:
        raise ValueError(f"kind = {kind!r}: use one of {', '.join(KINDS)}")
    motion, soil_model, dt = route_inputs(scene, motion, soil_model, dt, cache_dir)
    warnings = []
    with tempfile.TemporaryDirectory(prefix="uplift_cosim_") as tmp:
        out = Path(workdir) if workdir is not None else Path(tmp)
        t0 = time.perf_counter()
        data = fmu_data(scene, soil_model, dt, None, soil_factory, soil_kwargs)
        if data.plate is not None:
            warnings += plate_warnings(scene.plate_model(), scene.mesh.radius)
        binaries, why = _native_runtime(data, cache_dir) if kind == "native" else (None, "")
        if binaries is not None:
            fmus = build_native_fmus(data, out, platforms=tuple(binaries), binaries=binaries)
        else:
            warnings += [why] if why else []
            fmus = build_fmus(data, out)
        build_s = time.perf_counter() - t0
        res = cosimulate(fmus["structure"], fmus["soil"], motion.acc, dt, schedule=schedule, route=route, progress=progress)
    precheck = PRECHECK_COSIM if scene.contact.enabled else "not needed: contact disabled (bonded raft, linear)"
    skipped = [] if scene.contact.enabled else ["contact disabled: one linear solve per step, no Newton"]
    return res.replace(xy=scene.mesh.xy).with_notes(
        skipped=skipped, precheck=precheck, timings={"FMU build": build_s}, warnings=warnings,
        info={"soil_model": soil_model.provenance, "fmu_kind": "native" if binaries is not None else "python"})


def _native_runtime(data, cache_dir):
    """({platform: bytes} of the native runtime for this machine, "") or (None, why not)."""
    from fmus.native_build import NativeBuildError      # the FMU stack (fmpy, pythonfmu): only when the route runs
    from fmus.native_stepper import cache_folder, fmu_binaries   # the same
    if data.soil_factory != DEFAULT_SOIL_FACTORY:
        return None, f"the soil factory {data.soil_factory} has no native runtime: the Python FMUs ran"
    try:
        return fmu_binaries(cache_folder(cache_dir)), ""
    except (NativeBuildError, OSError, ValueError) as exc:
        return None, f"the native FMUs are not available ({str(exc).splitlines()[0]}): the Python FMUs ran"


def run(ctx, progress=None):
    return run_cosim(ctx.scene, ctx.motion, ctx.fit().model, progress=progress, cache_dir=ctx.cache_dir)


ROUTE = register(Route(
    name="cosim",
    summary="TD-cosim: the monolithic stepper and soil model as two FMI 2.0 FMUs under the project's "
            "Gauss-Seidel master (equal to monolithic to round-off)",
    run=run,
    needs_fit=True,
    bench={"disk-halfspace": {"dt": (0.01, 0.005, 0.0025)}, "reactor": {"dt": (0.01, 0.005, 0.0025)}},
    quick={"disk-halfspace": {"dt": (0.01, 0.005)}},
    reference_rank=1,
))

"""Running a scene's analyses: motion, structure, soil and the routes, into one results file.

Routes available in this version:

``winkler``  the industrial spring-mattress route (paper §4): Newmark + penalty contact on
             Winkler springs. Springs from ``[soil].winkler`` when given (with its dashpots,
             and the structure's own damping); otherwise from the BEM rigid static impedance
             of the scene's foundation shared by tributary area (rocking matched), with
             RCC-G composite modal damping (7 % structural weighted by strain energy plus the
             BEM's directional radiation damping ratios Im K(f)/(2 K(0)) at each mode).
             Sharing by area cannot match both Kv and Kr of a rigid raft with positive springs
             (a spring bed on a disk has Kr/Kv <= R²/2, the rigid disk 2R²/3): the vertical
             modulus is set so that the mean rocking stiffness (Krx + Kry)/2 is exact, since
             rocking drives uplift (paper §4.2 matches rocking frequencies); the vertical
             stiffness is then too high, by a factor reported in the route's info.

The other routes of DESIGN.md (cosim, monolithic, timefreq, linear) are refused with a clear
message until they exist.
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

from orchestrator.motion import Motion, MotionError, read_record, synthetic_motion
from orchestrator.scene import SceneError, _check_keys

ROUTES = ("winkler",)
PLANNED = ("cosim", "monolithic", "timefreq", "linear")


def scene_motion(scene, dt: float) -> Motion:
    """The scene's [motion] at step dt (records are resampled linearly)."""
    m = dict(scene.section("motion"))
    kind = m.pop("kind", "synthetic")
    direction = m.pop("direction", "x")
    if kind == "synthetic":
        _check_keys(m, ("spectrum", "pga_g", "duration_s", "seed"), "motion")
        return synthetic_motion(pga_g=float(m.get("pga_g", 0.25)), duration_s=float(m.get("duration_s", 10.0)),
                                dt=dt, seed=int(m.get("seed", 1)), spectrum=m.get("spectrum", "RG1.60"),
                                direction=direction)
    if kind == "record":
        _check_keys(m, ("file", "format", "units", "scale"), "motion")
        if "file" not in m:
            raise SceneError("motion.file is missing for kind = \"record\"")
        rec = read_record(scene.base_dir / m["file"], m.get("format", "two-column"), m.get("units", "g"),
                          float(m.get("scale", 1.0)), direction)
        return rec if abs(rec.dt - dt) < 1e-12 else rec.resampled(dt)
    raise SceneError(f"motion.kind = {kind!r}: use \"synthetic\" or \"record\"")


def scene_analysis(scene) -> tuple[list, float]:
    a = scene.section("analysis")
    _check_keys(a, ("routes", "dt"), "analysis")
    routes = a.get("routes", ["winkler"])
    dt = a.get("dt", 0.005)
    if not isinstance(dt, (int, float)) or not 0 < dt <= 0.05:
        raise SceneError(f"analysis.dt = {dt!r} s must lie in (0, 0.05]: the contact and the "
                         "structure's modes up to ~30 Hz need a few steps per period")
    return check_routes(routes), float(dt)


def check_routes(routes) -> list:
    if not isinstance(routes, list) or not routes:
        raise SceneError(f"analysis.routes = {routes!r} must be a non-empty list, e.g. [\"winkler\"]")
    for r in routes:
        if r in PLANNED:
            raise SceneError(f"route {r!r} is not available in this version yet; available: {', '.join(ROUTES)}")
        if r not in ROUTES:
            raise SceneError(f"unknown route {r!r}; available: {', '.join(ROUTES)}")
    return list(routes)


def output_nodes(scene) -> list | None:
    out = scene.section("output")
    _check_keys(out, ("nodes",), "output")
    return out.get("nodes")


def scene_model(scene):
    from structure.spec import model_from_spec
    return model_from_spec(scene.section("structure"), scene.mesh.xy, scene.mesh.area)


def winkler_soil(scene, model, cache_dir=None, log=None):
    """(WinklerSoil, damping for simulate) of the winkler route (see module doc)."""
    from structure.spec import winkler_from_spec
    from structure.winkler import radiation_ratios, rccg_modal_damping, springs_from_rigid_impedance

    if "winkler" in scene.sections:
        return winkler_from_spec(scene.sections["winkler"], scene.mesh.xy, scene.mesh.area), None, {
            "springs": "soil.winkler subgrade moduli", "soil_damping": "soil.winkler dashpots"}
    from orchestrator.impedance import scene_impedance

    table = scene_impedance(scene, ("rigid",), cache_dir=cache_dir, progress=log)["rigid"]
    if table.frequencies_hz[0] != 0.0:
        raise SceneError("the winkler route calibrates its springs on K(0): include 0 Hz in "
                         "[impedance] (range_hz = [0.0, fmax, count])")
    K6 = np.real(table.matrices[0])
    soil = springs_from_rigid_impedance(K6, scene.mesh.xy, scene.mesh.area, match="rocking")
    vertical_factor = soil.rigid_stiffness()[2, 2] / K6[2, 2]
    ratio = model.damping.ratio if model.damping.kind == "modal" else 0.0
    C, modes = rccg_modal_damping(model, soil, structure_ratio=ratio,
                                  radiation=radiation_ratios(table.frequencies_hz, table.matrices))
    info = {"springs": "BEM rigid static impedance shared by area, rocking matched",
            "winkler_kv_over_bem_kv": float(vertical_factor),
            "soil_damping": "RCC-G composite modal damping",
            "modes_on_soil_hz": modes.freq[:6].tolist(), "modal_damping": modes.ratio[:6].tolist()}
    return soil, C, info


def run_scene(scene, routes=None, cache_dir=None, progress=None):
    """Run the routes of a scene. Returns (``{route: RouteResult}``, Motion, errors dict).

    A route that stops (Newton failure) keeps its results so far (``converged = False``,
    ``message`` says why) and the other routes still run.
    """
    from structure import ConvergenceError, simulate
    from structure.spec import contact_from_spec

    listed, dt = scene_analysis(scene)
    routes = check_routes(list(routes)) if routes else listed
    motion = scene_motion(scene, dt)
    model = scene_model(scene)
    contact = contact_from_spec(scene.section("contact"))
    nodes = output_nodes(scene)
    results = {}
    for route in routes:
        soil, damping, info = winkler_soil(scene, model, cache_dir)
        bar = progress(route) if progress else None
        try:
            res = simulate(model, soil, motion.acc, dt, contact=contact, damping=damping,
                           output_nodes=nodes, progress=bar, route=route)
        except ConvergenceError as exc:
            res = exc.result
        res.info.update(info)
        results[route] = res
    return results, motion


def run_scene_cli(args) -> int:
    from orchestrator.cli import EXIT_FAILED, EXIT_OK, default_cache_dir
    from orchestrator.progress import Progress
    from orchestrator.results import summary, write_results
    from orchestrator.scene import load_scene

    scene = load_scene(args.scene)
    out = args.output or Path(f"{scene.name}_results.h5")
    results, motion = run_scene(scene, args.routes, cache_dir=default_cache_dir(),
                                progress=lambda route: _steps(Progress(f"run {scene.name} [{route}]")))
    write_results(out, results, motion, scene.name)
    print(f"wrote {out}", file=sys.stderr)
    summ = {"routes": {r: summary(res) for r, res in results.items()}}
    if args.plot_dir:
        from orchestrator.plots import plot_run
        for path in plot_run(results, motion, scene, args.plot_dir):
            print(f"wrote {path}", file=sys.stderr)
    if args.json:
        print(json.dumps(summ))
    else:
        for r, s in summ["routes"].items():
            print(f"{r}: max uplift {1e3 * s['max_uplift_m']:.3f} mm at {s['max_uplift_time_s']:.3f} s, "
                  f"raft rotation {s['max_raft_rotation_rad']:.3e} rad, min contact "
                  f"{100 * s['min_contact_fraction']:.1f} %, wall {s['wall_s']:.2f} s"
                  + ("" if s["converged"] else f"  STOPPED: {results[r].message}"), file=sys.stderr)
    failed = [r for r, res in results.items() if not res.converged]
    return EXIT_FAILED if failed else EXIT_OK


def _steps(bar):
    return lambda k, nt: bar(k + 1, nt)

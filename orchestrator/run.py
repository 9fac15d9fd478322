"""Running a scene's analyses: motion, structure, soil and the routes, into one results file.

Routes available in this version:

``winkler``  the industrial spring-mattress route (paper §4): Newmark + penalty contact on
             Winkler springs, calibrated as ``[soil].winkler`` says (see ``winkler_soil``).
             By default: the BEM rigid static impedance of the scene's foundation shared by
             tributary area with the rocking stiffness exact, and RCC-G composite modal
             damping. Sharing by area cannot match both Kv and Kr of a rigid raft with
             positive springs (a spring bed on a disk has Kr/Kv <= R²/2, the rigid disk
             2R²/3); rocking drives uplift (paper §4.2 matches rocking frequencies), so the
             vertical stiffness comes out too high, by a factor reported in the route's info.

``monolithic``  Newmark + contact with the BEM soil as a fitted rational model run by the
             recursive convolution, in process (orchestrator/cosim.py).
``cosim``    the same two steppers exported as FMUs and co-simulated by our master
             (Gauss-Seidel with the impedance split: equal to monolithic to round-off).

``linear``   the exact linear reference: the BEM gap table applied per frequency, raft bonded
             (no uplift), FFT with zero padding and an exponential window (orchestrator/linear_fd.py).
``timefreq`` the paper's time-frequency reference with uplift: the BEM table per frequency, the
             contact equations over the whole time range on the bilinear (trapezoidal) grid,
             solved by causal marches with the wrap-around fed back (orchestrator/timefreq.py,
             tf_march.py); time budget ``[analysis].timefreq_max_s`` (default TIMEFREQ_MAX_S).

The rational fit of the scene's gap impedance table is shared by the routes that need it
(tolerance ``[analysis].fit_tol``, default FIT_TOL).
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from orchestrator.motion import Motion, read_record, synthetic_motion
from orchestrator.scene import SceneError, _check_keys

ROUTES = ("winkler", "monolithic", "cosim", "linear", "timefreq")
#: default fit tolerance of the rational soil model. A causal model cannot follow hysteretic
#: damping ξ closer than about ξ over the band (soil_impedance/fit.py): the reactor scene, on
#: 3 % rock, sets [analysis] fit_tol = 0.04 (8 poles, passive, ~10 s)
FIT_TOL = 0.01
#: default time budget of the timefreq route, s
TIMEFREQ_MAX_S = 600.0


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
    _check_keys(a, ("routes", "dt", "fit_tol", "timefreq_max_s"), "analysis")
    routes = a.get("routes", ["winkler"])
    dt = a.get("dt", 0.005)
    if not isinstance(dt, (int, float)) or not 0 < dt <= 0.05:
        raise SceneError(f"analysis.dt = {dt!r} s must lie in (0, 0.05]: the contact and the "
                         "structure's modes up to ~30 Hz need a few steps per period")
    scene_timefreq_budget(scene)
    return check_routes(routes), float(dt)


def scene_fit_tol(scene) -> float:
    tol = scene.section("analysis").get("fit_tol", FIT_TOL)
    if not isinstance(tol, (int, float)) or not 0 < tol < 1:
        raise SceneError(f"analysis.fit_tol = {tol!r} must lie in (0, 1) (relative fit error, e.g. 0.04)")
    return float(tol)


def scene_timefreq_budget(scene) -> float:
    """analysis.timefreq_max_s: the time-frequency route's time budget, s (default
    TIMEFREQ_MAX_S); when it runs out the route keeps its best iterate, flagged."""
    b = scene.section("analysis").get("timefreq_max_s", TIMEFREQ_MAX_S)
    if isinstance(b, bool) or not isinstance(b, (int, float)) or not b > 0:
        raise SceneError(f"analysis.timefreq_max_s = {b!r} must be a positive number of seconds, e.g. 600")
    return float(b)


def check_routes(routes) -> list:
    if not isinstance(routes, list) or not routes:
        raise SceneError(f"analysis.routes = {routes!r} must be a non-empty list, e.g. [\"winkler\"]")
    for r in routes:
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


#: fewest steps per period of the first soil-structure mode a run accepts: on the reactor,
#: 12.7 steps move the max uplift by < 1 %, 5.1 steps by +12 % (winkler) and +104 % (monolithic)
#: (benchmarks/stress.py)
MIN_STEPS_PER_PERIOD = 10


def check_time_step(scene, model, dt: float, routes, cache_dir=None) -> float:
    """Refuse a step that does not resolve the first soil-structure mode; returns its frequency.

    The mode is that of the structure on the scene's springs: the BEM static rigid impedance
    shared with the rocking stiffness exact, or ``[soil].winkler``'s moduli for a Winkler-only run
    that gives them."""
    from structure.winkler import modes_on_soil, springs_from_rigid_impedance
    if set(routes) == {"winkler"} and _explicit_winkler(scene):
        from structure.spec import winkler_from_spec
        soil = winkler_from_spec(dict(scene.sections["winkler"]), scene.mesh.xy, scene.mesh.area)
    else:
        from orchestrator.impedance import scene_static
        K0 = np.real(scene_static(scene, "rigid", cache_dir))
        soil = springs_from_rigid_impedance(K0, scene.mesh.xy, scene.mesh.area, match="rocking")
    f1 = float(modes_on_soil(model, soil).freq[0])
    if dt * f1 * MIN_STEPS_PER_PERIOD > 1.0 + 1e-9:
        raise SceneError(f"analysis.dt = {dt:g} s gives {1 / (dt * f1):.1f} steps per period of the first "
                         f"soil-structure mode ({f1:.3g} Hz): not resolved (at least {MIN_STEPS_PER_PERIOD} "
                         f"needed); use dt <= {1 / (MIN_STEPS_PER_PERIOD * f1):.3g} s")
    return f1


WINKLER_KEYS = ("springs", "match", "damping")
#: RCC-G composite modal damping acts on the whole building's motion relative to the free field,
#: rocking included, and keeps acting once the raft lifts (soil dashpots that pull): it holds the
#: raft down. Fine while uplift is a perturbation (reactor 0.25 g, ~50 % lifted: 2.63 mm against
#: 2.49 mm for the TF/BEM reference); on a small tower lifting 75 % of its nodes the BEM routes
#: and detaching dashpots give 1.6-4x its uplift at 0.25-2 g (session diagnosis, issue 7 note)
RCCG_UPLIFT_LIMIT = 0.6
RCCG_WARNING = ("RCC-G modal damping with {:.0f} % of the interface nodes lifted at once: this damping "
                "keeps acting on the lifted raft and underestimates large uplift; compare with "
                "[soil].winkler = {{ damping = \"dashpots\" }} or the monolithic route")


def winkler_soil(scene, model, cache_dir=None, log=None, table=None):
    """(WinklerSoil, structural damping for simulate, info) of the winkler route.

    ``[soil].winkler`` either gives subgrade moduli ``{ kv, kh, cv, ch }`` (N/m³, N s/m³ per
    unit area; the structure keeps its own damping), or says how to calibrate on the BEM:
    ``{ springs = "rigid" | "nodal", match = "rocking" | "vertical", damping = "rccg" | "dashpots" }``
    (all optional; the defaults are the first of each):

    springs  "rigid": the rigid static impedance K(0) shared by tributary area (paper §4.2,
             first way); "nodal": Diag(K_s22(ω = 0)) of the nodal static impedance (second way).
    match    for "rigid": which of the mean rocking or the vertical stiffness is exact (a spring
             bed cannot reproduce both, see structure.winkler).
    damping  "rccg": composite modal damping (structural ratio on the structure's strain energy
             plus the BEM's directional radiation ratios Im K(f)/(2 K(0)) on the soil's);
             "dashpots": the rigid impedance's dashpots Im K(f1)/ω1 at the first soil-structure
             frequency f1, shared like the springs, with the structure's own damping.
    """
    from structure.spec import winkler_from_spec
    from structure.winkler import (modes_on_soil, radiation_ratios, rccg_modal_damping,
                                   springs_from_nodal_diagonal, springs_from_rigid_impedance)
    from orchestrator.impedance import scene_impedance, scene_static

    spec = dict(scene.sections.get("winkler", {}))
    if _explicit_winkler(scene):
        return winkler_from_spec(spec, scene.mesh.xy, scene.mesh.area), None, {
            "springs": "soil.winkler subgrade moduli", "soil_damping": "soil.winkler dashpots"}
    _check_keys(spec, WINKLER_KEYS, "soil.winkler")
    springs, match, damping = (spec.get("springs", "rigid"), spec.get("match", "rocking"),
                               spec.get("damping", "rccg"))
    for key, value, allowed in (("springs", springs, ("rigid", "nodal")), ("match", match, ("rocking", "vertical")),
                                ("damping", damping, ("rccg", "dashpots"))):
        if value not in allowed:
            raise SceneError(f"soil.winkler.{key} = {value!r}: use " + " or ".join(f'"{a}"' for a in allowed))
    if table is None:   # the rigid table, swept here unless the caller has it
        table = scene_impedance(scene, ("rigid",), cache_dir=cache_dir, progress=log)["rigid"]
    if table.frequencies_hz[0] != 0.0:
        raise SceneError("the winkler route calibrates its springs on K(0): include 0 Hz in "
                         "[impedance] (range_hz = [0.0, fmax, count])")
    xy, area = scene.mesh.xy, scene.mesh.area
    k_ref = scene.profile.static_to_reference     # causal soil: K(0) is relaxed, springs use rho vs^2
    K6 = k_ref * np.real(table.matrices[0])
    kdiag = None if springs == "rigid" else k_ref * np.diag(scene_static(scene, "nodal", cache_dir))
    if springs == "rigid":
        soil = springs_from_rigid_impedance(K6, xy, area, match=match)
    else:
        soil = springs_from_nodal_diagonal(kdiag, xy)
    f1 = float(modes_on_soil(model, soil).freq[0])
    info = {"springs": f"{springs} static impedance" + (f", {match} matched" if springs == "rigid" else " diagonal"),
            "winkler_over_bem_static": (np.diag(soil.rigid_stiffness()) / np.diag(K6)).tolist(),
            "first_soil_structure_hz": f1}
    if damping == "dashpots":
        C6 = np.imag(table.at(f1)) / (2 * np.pi * f1)
        soil = springs_from_rigid_impedance(K6, xy, area, C6=C6, match=match) if springs == "rigid" else \
            springs_from_nodal_diagonal(kdiag, xy, cdiag=_nodal_dashpots(C6, xy, area))
        info["soil_damping"] = f"rigid impedance dashpots at {f1:.3g} Hz"
        return soil, None, info
    ratio = model.damping.ratio if model.damping.kind == "modal" else 0.0
    C, modes = rccg_modal_damping(model, soil, structure_ratio=ratio,
                                  radiation=radiation_ratios(table.frequencies_hz, table.matrices))
    info.update({"soil_damping": "RCC-G composite modal damping",
                 "modes_on_soil_hz": modes.freq[:6].tolist(), "modal_damping": modes.ratio[:6].tolist()})
    return soil, C, info


def _explicit_winkler(scene) -> bool:
    """True when [soil].winkler gives subgrade moduli (no BEM calibration needed)."""
    spec = scene.sections.get("winkler", {})
    return bool(spec) and not set(spec) & set(WINKLER_KEYS)


def _nodal_dashpots(C6, xy, area):
    """(3N,) nodal dashpots: the rigid translational dashpots shared by area (ux, uy, uz per node)."""
    w = np.asarray(area) / np.sum(area)
    return np.column_stack([C6[0, 0] * w, C6[1, 1] * w, C6[2, 2] * w]).ravel()


def run_scene(scene, routes=None, cache_dir=None, progress=None, sweep_progress=None):
    """Run the routes of a scene. Returns (``{route: RouteResult}``, Motion).

    A route that stops (Newton failure) keeps its results so far (``converged = False``,
    ``message`` says why) and the other routes still run. ``progress(route)`` returns a
    callable(k, nt) for each route; ``sweep_progress(done, total, freq_hz)`` follows the BEM
    sweep, done once for all routes (one factorisation per frequency for every output).
    """
    from structure import ConvergenceError, simulate
    from structure.spec import contact_from_spec

    listed, dt = scene_analysis(scene)
    routes = check_routes(list(routes)) if routes else listed
    motion = scene_motion(scene, dt)
    model = scene_model(scene)
    contact = contact_from_spec(scene.section("contact"))
    nodes = output_nodes(scene)
    check_time_step(scene, model, dt, routes, cache_dir)
    outputs = tuple(dict.fromkeys(
        ["rigid" for r in routes if r == "winkler" and not _explicit_winkler(scene)]
        + ["gap" for r in routes if r != "winkler"]))
    tables, sweep = {}, {}
    if outputs:
        from orchestrator.impedance import scene_impedance
        tables = scene_impedance(scene, outputs, cache_dir=cache_dir, progress=sweep_progress, stats=sweep)
    results, soil_model, fit_cached = {}, None, False
    for route in routes:
        bar = progress(route) if progress else None
        if route == "winkler":
            soil, damping, info = winkler_soil(scene, model, cache_dir, table=tables.get("rigid"))
            try:
                res = simulate(model, soil, motion.acc, dt, contact=contact, damping=damping,
                               output_nodes=nodes, progress=bar, route=route)
            except ConvergenceError as exc:
                res = exc.result
            res.info.update(info)
            if damping is not None and res.gap.size and res.uplift_fraction().max() > RCCG_UPLIFT_LIMIT:
                res.info.setdefault("warnings", []).append(RCCG_WARNING.format(
                    100 * res.uplift_fraction().max()))
        elif route in ("linear", "timefreq"):
            from orchestrator.linear_fd import run_linear
            from orchestrator.timefreq import run_timefreq
            if route == "linear":
                res = run_linear(scene, motion, model, tables["gap"])
            else:
                res = run_timefreq(scene, motion, model, tables["gap"], progress=bar,
                                   max_seconds=scene_timefreq_budget(scene))
        else:
            from orchestrator.cosim import run_cosim, run_monolithic, scene_fit
            if soil_model is None:
                fit = scene_fit(scene, cache_dir=cache_dir, table=tables["gap"])
                soil_model, fit_cached = fit.model, fit.report.cached
            run = run_cosim if route == "cosim" else run_monolithic
            res = run(scene, motion, soil_model, progress=bar, cache_dir=cache_dir)
        res.info.setdefault("skipped", []).extend(
            _route_skips(scene, route, contact, sweep, fit_cached and route in ("monolithic", "cosim")))
        if route == "cosim":
            res.info["precheck"] = (PRECHECK_COSIM if contact.enabled else
                                    "not needed: contact disabled (bonded raft, linear)")
        results[route] = res
    return results, motion


#: what the co-simulation says about the linear pre-check (see structure.ContactSettings)
PRECHECK_COSIM = ("not available: the FMUs advance one step at a time and cannot look ahead, so "
                  "the co-simulation runs the nonlinear contact iterations (the monolithic route "
                  "has the pre-check)")


def _route_skips(scene, route, contact, sweep, fit_cached) -> list:
    """What a route did not compute, besides what ``simulate`` reports (``info["skipped"]``):
    only what really happened (cache hits are those of this run)."""
    out = []
    if route == "winkler" and _explicit_winkler(scene):
        return ["soil.winkler subgrade moduli given: no BEM impedance sweep"]
    if sweep.get("from_cache"):
        out.append("impedance sweep read from cache")
    elif sweep.get("computed") and scene.profile.is_homogeneous and scene.frequencies_hz[0] == 0.0:
        out.append("homogeneous half-space: K(0) from the closed-form static kernels "
                   "(no wavenumber integral at 0 Hz)")
    n = scene.mesh.n
    if route != "winkler":
        out.append(f"rigid raft: soil interface reduced from 3N = {3 * n} to 6 + N = {6 + n} DOFs")
    if fit_cached:
        out.append("rational fit read from cache")
    if route == "cosim" and not contact.enabled:
        out.append("contact disabled: one linear solve per step, no Newton")
    return out


def run_scene_cli(args) -> int:
    from orchestrator.cli import EXIT_FAILED, EXIT_OK, default_cache_dir
    from orchestrator.progress import Progress, frequency_bar, step_bar
    from orchestrator.results import summary, write_results
    from orchestrator.scene import load_scene

    scene = load_scene(args.scene)
    out = args.output or Path(f"{scene.name}_results.h5")
    results, motion = run_scene(scene, args.routes, cache_dir=default_cache_dir(),
                                progress=lambda route: step_bar(Progress(f"run {scene.name} [{route}]")),
                                sweep_progress=frequency_bar(Progress(f"impedance {scene.name}")))
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
            if s["precheck"]:
                print(f"  linear pre-check: {s['precheck']}", file=sys.stderr)
            for item in s["skipped"]:
                print(f"  skipped: {item}", file=sys.stderr)
            for item in s["warnings"]:
                print(f"  WARNING: {item}", file=sys.stderr)
    failed = [r for r, res in results.items() if not res.converged]
    return EXIT_FAILED if failed else EXIT_OK

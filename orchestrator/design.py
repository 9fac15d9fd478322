"""Design-basis runs: the scene over its soil cases, on strain-compatible soil, with design floor
spectra ([soil] cases, [soil] strain_compatible, [output] design_spectra; docs/design_basis.md).

The smallest design that fits the run sequence: a soil case is a scene whose profile is the
case's (``case_scene``), and each case runs as a scene of its own, ``run_scene`` (its own
``prepare_run`` / ``SharedRun``: its sweep and fit, found in the caches by the case's profile),
under the same motion, made once. The strain-compatible analysis (orchestrator.site_response),
when asked, runs first, on the scene's profile under the scene's motion; the cases are then
built on the strain-compatible profile (BE = it, LB and UB = it with G / (1 + Cv) and
G (1 + Cv)). The design spectra (orchestrator.design_spectra) are computed from every case's
floor histories.

Results file (``write_design``; format_version 2, compatible: every reader of one run reads the
first case at the top level)::

    /routes/<route>          the first case (be for the Cv rule), as in a run of one soil
    /motion
    /cases                   attrs: names (JSON list, run order), rule (JSON: {"cv": 0.5} or
                             {"profiles": [...]}), reference (the case at the top level)
        /<case>              attrs: scene_toml (the case as a scene: ``load_scene`` runs it alone),
                             profile (JSON: layers and halfspace), routes ("/routes" for the first case)
            /routes/<route>  the other cases, the layout of a route group
    /design/site_response    (strain_compatible) coordinate layer; vs_initial, vs (m/s),
                             damping_initial, damping (-), g_ratio (-), strain_eff, strain_max (-)
                             per layer; attrs iterations, converged, max_change, tolerance,
                             strain_ratio, max_iterations, input, component, curves (JSON)
    /design/spectra          (design_spectra) coordinates case, route, output, direction, damping,
                             frequency (Hz), envelope_route; raw, broadened (case, route, output,
                             direction, damping, frequency) m s-2; envelope (envelope_route, output,
                             direction, damping, frequency) m s-2; attrs broadening, rule

``read_results(path, case=...)`` reads a case's routes back; ``read_design(path)`` the rest.
"""
from __future__ import annotations

import copy
import json
from dataclasses import asdict, dataclass, replace

import h5py
import numpy as np

from orchestrator.compare import route_metrics
from orchestrator.design_spectra import DesignSpectra, design_spectra
from orchestrator.motion import G, make_motion
from orchestrator.results_file import (ResultsFileError, add_coordinate, add_route, add_variable, summary,
                                       write_results)
from orchestrator.run import run_scene
from orchestrator.scene_file import scene_toml
from orchestrator.site_response import SiteResponse, strain_compatible
from orchestrator.soil_cases import case_profiles, profile_table
from orchestrator.scene import is_design  # noqa: F401  (defined beside the Scene: `uplift run` asks it without importing this module)
from uplift_common.files import require_checksum


@dataclass
class DesignRun:
    """A design-basis run: scene (the design scene, routes applied), scenes {case: Scene}, cases
    {case: {route: RouteResult}} (run order), motion, site (SiteResponse or None), spectra
    (DesignSpectra or None)."""

    scene: object
    scenes: dict
    cases: dict
    motion: object
    site: SiteResponse | None = None
    spectra: DesignSpectra | None = None


def case_scene(scene, profile):
    """``scene`` on the soil ``profile`` (one case): its source's [soil] layers and halfspace
    replaced by the profile's, without cases and strain_compatible, so that the case's scene TOML
    runs it alone; the design spectra are left out too (the design run computes them)."""
    source = copy.deepcopy(scene.source) if scene.source is not None else None
    if source is not None:
        soil = {k: v for k, v in source.get("soil", {}).items() if k not in ("cases", "strain_compatible")}
        source["soil"] = {**soil, **profile_table(profile)} if profile is not None else soil
        out = {k: v for k, v in source.get("output", {}).items() if k != "design_spectra"}
        source["output"] = out
        if not out:
            del source["output"]
    return replace(scene, profile=profile, source=source, soil_cases=None, strain_compatible=None,
                   design_spectra=None)


def design_cases(scene, motion) -> tuple[list, SiteResponse | None]:
    """([(case, Scene)], SiteResponse or None): the strain-compatible profile when asked (under
    ``motion``), then the cases on it (one case "be" without [soil] cases)."""
    base, site = scene.profile, None
    if scene.strain_compatible is not None:
        site = strain_compatible(base, motion.acc, motion.dt, scene.strain_compatible)
        base = site.profile
    profiles = case_profiles(scene.soil_cases, base) if scene.soil_cases is not None else [("be", base)]
    return [(name, case_scene(scene, p)) for name, p in profiles], site


def run_design(scene, routes=None, cache_dir=None, progress=None, sweep_progress=None, fit_progress=None,
               options=None, announce=None) -> DesignRun:
    """Run ``scene`` over its soil cases (see the module): one ``run_scene`` per case, under the
    scene's motion made once; ``announce(text)`` is told of each case before it runs. The
    progress callbacks are those of ``run_scene`` (labels prefixed by the case)."""
    if routes:
        scene = scene.with_routes(routes)
    motion = make_motion(scene.motion, scene.analysis.dt)
    scenes, site = design_cases(scene, motion)
    cases = {}
    for name, case in scenes:
        if announce is not None:
            announce(f"soil case {name}: " + ", ".join(f"vs {m.vs:.1f} m/s, damping {m.damping:.4g}"
                                                        for m in (*case.profile.layers, case.profile.halfspace)))
        label = (lambda f: None if f is None else
                 (lambda done, total, lab="", _n=name: f(done, total, f"{_n}: {lab}" if lab else _n)))
        cases[name], _ = run_scene(case, cache_dir=cache_dir, progress=label(progress), options=options,
                                   sweep_progress=label(sweep_progress), fit_progress=label(fit_progress),
                                   motion=motion)
    spectra = None
    if scene.design_spectra is not None:
        spectra = design_spectra(cases, scene.design_spectra, scene.output.nodes)
    return DesignRun(scene=scene, scenes=dict(scenes), cases=cases, motion=motion, site=site, spectra=spectra)


def rule(scene) -> dict:
    """The case rule as JSON-able data: {"cv": Cv}, {"profiles": [names]} or {} (one soil)."""
    c = scene.soil_cases
    if c is None:
        return {}
    return {"cv": c.cv} if c.cv is not None else {"profiles": list(c.names)}


def write_design(path, run: DesignRun, overrides=()):
    """Write the design run to one results file (the layout of the module docstring)."""
    names = list(run.cases)
    first = names[0]

    def extra(f):
        cg = f.create_group("cases")
        cg.attrs.update(names=json.dumps(names), rule=json.dumps(rule(run.scene)), reference=first)
        for name in names:
            g = cg.create_group(name)
            g.attrs["scene_toml"] = scene_toml(run.scenes[name])
            g.attrs["profile"] = json.dumps(profile_table(run.scenes[name].profile))
            if name == first:
                g.attrs["routes"] = "/routes"
                continue
            routes = g.create_group("routes", track_order=True)
            for route, res in run.cases[name].items():
                add_route(routes.create_group(route), res)
        d = f.create_group("design")
        if run.site is not None:
            _write_site(d.create_group("site_response"), run.site, run.scene)
        if run.spectra is not None:
            _write_spectra(d.create_group("spectra"), run.spectra)

    return write_results(path, run.cases[first], run.motion, run.scene.name, scene_toml(run.scene), overrides,
                         run.scene.mesh, run.scene.mesh_source, extra=extra)


def _write_site(g, site: SiteResponse, scene) -> None:
    cfg = scene.strain_compatible
    g.attrs.update(iterations=site.iterations, converged=site.converged, max_change=site.max_change,
                   tolerance=cfg.tolerance, strain_ratio=cfg.strain_ratio, max_iterations=cfg.max_iterations,
                   input=site.input, component=site.component,
                   curves=json.dumps([asdict(c) for c in cfg.curves]))
    layers = scene.profile.layers
    add_coordinate(g, "layer", np.arange(len(layers)), None, "layer of the profile, top down")
    add_variable(g, "thickness", [m.thickness for m in layers], ("layer",), "m", "layer thickness")
    add_variable(g, "vs_initial", [m.vs for m in layers], ("layer",), "m s-1", "low-strain shear-wave speed")
    add_variable(g, "vs", [m.vs for m in site.profile.layers], ("layer",), "m s-1",
                 "strain-compatible shear-wave speed")
    add_variable(g, "damping_initial", [m.damping for m in layers], ("layer",), "1", "low-strain damping ratio")
    add_variable(g, "damping", site.damping, ("layer",), "1", "strain-compatible damping ratio")
    add_variable(g, "g_ratio", site.g_ratio, ("layer",), "1", "strain-compatible G over low-strain G")
    add_variable(g, "strain_eff", site.strain_eff, ("layer",), "1", "effective shear strain (strain_ratio x peak)")
    add_variable(g, "strain_max", site.strain_max, ("layer",), "1", "peak shear strain at the layer's middle")


def _write_spectra(g, ds: DesignSpectra) -> None:
    g.attrs.update(broadening=ds.broadening, rule=(
        "at each frequency f, the broadened spectrum is the max of the raw one over [f/(1+r), f/(1-r)], "
        "r = broadening; envelope: max over the cases (route 'all': over the routes too)"))
    add_coordinate(g, "case", list(ds.cases), None, "soil case")
    add_coordinate(g, "route", list(ds.routes), None, "route")
    add_coordinate(g, "envelope_route", list(ds.envelope_routes), None, "route of the envelope ('all': every route)")
    add_coordinate(g, "output", list(ds.nodes), None, "output node of the structure")
    add_coordinate(g, "direction", list(ds.directions), None, "axis of the global frame (z up)")
    add_coordinate(g, "damping", list(ds.damping), "1", "damping ratio of the oscillator")
    add_coordinate(g, "frequency", ds.frequencies_hz, "Hz", "frequency of the oscillator")
    dims = ("case", "route", "output", "direction", "damping", "frequency")
    add_variable(g, "raw", ds.raw, dims, "m s-2", "pseudo-acceleration floor response spectrum")
    add_variable(g, "broadened", ds.broadened, dims, "m s-2", "broadened floor response spectrum")
    add_variable(g, "envelope", ds.envelope, ("envelope_route",) + dims[2:], "m s-2",
                 "design floor response spectrum: broadened, enveloped over the soil cases")


def read_design(path) -> dict:
    """{"cases": [...], "rule": {...}, "site_response": {name: array, attrs...} or None,
    "spectra": DesignSpectra or None} of a results file (its checksum verified)."""
    with h5py.File(path, "r") as f:
        require_checksum(f, path, "run `uplift run SCENE -o FILE` again to make a good one")
        if "cases" not in f:
            raise ResultsFileError(f"{path} holds one soil (no /cases): a design run needs [soil] cases, "
                                   "strain_compatible or [output] design_spectra in the scene")
        out = {"cases": json.loads(f["cases"].attrs["names"]), "rule": json.loads(f["cases"].attrs["rule"]),
               "site_response": None, "spectra": None}
        d = f.get("design")
        if d is not None and "site_response" in d:
            g = d["site_response"]
            out["site_response"] = {**{k: g[k][()] for k in g}, **{k: _plain(v) for k, v in g.attrs.items()
                                                                  if not k.startswith(("DIMENSION", "CLASS", "NAME", "REF"))}}
        if d is not None and "spectra" in d:
            g = d["spectra"]
            label = lambda k: tuple(str(v) for v in g[k].asstr()[()])
            out["spectra"] = DesignSpectra(cases=label("case"), routes=label("route"), nodes=label("output"),
                                           directions=label("direction"), damping=tuple(g["damping"][()]),
                                           frequencies_hz=g["frequency"][()], broadening=float(g.attrs["broadening"]),
                                           raw=g["raw"][()], broadened=g["broadened"][()],
                                           envelope_routes=label("envelope_route"), envelope=g["envelope"][()])
        return out


def _plain(v):
    if isinstance(v, bytes):
        return v.decode()
    return v.item() if hasattr(v, "item") else v


def case_envelope(cases: dict) -> dict:
    """Per route, the governing values over the soil cases of ``cases`` = {case: {route:
    RouteResult}}: max uplift (m) and its case, min contact fraction and its case, and per output
    node and direction the largest 5 % floor-spectrum peak (m/s²) and its case; also per case the
    same numbers ({"cases": {case: {route: {...}}}, "envelope": {route: {...}}})."""
    per = {}
    for case, results in cases.items():
        per[case] = {}
        for route, res in results.items():
            s = summary(res)
            m = route_metrics(res) if res.nt > 1 else {"spectrum_peaks": {}}
            per[case][route] = {"status": s["status"], "max_uplift_m": s["max_uplift_m"],
                                "min_contact_fraction": s["min_contact_fraction"],
                                "spectrum_peaks": m["spectrum_peaks"]}
    env = {}
    routes = dict.fromkeys(r for c in per.values() for r in c)
    for route in routes:
        rows = [(case, per[case][route]) for case in per if route in per[case]]
        up = max(rows, key=lambda cr: cr[1]["max_uplift_m"])
        lo = min(rows, key=lambda cr: cr[1]["min_contact_fraction"])
        peaks = {}
        for case, r in rows:
            for node, dirs in r["spectrum_peaks"].items():
                for d, v in dirs.items():
                    best = peaks.setdefault(node, {}).get(d)
                    if best is None or v > best["value"]:
                        peaks[node][d] = {"value": v, "case": case}
        env[route] = {"max_uplift_m": up[1]["max_uplift_m"], "max_uplift_case": up[0],
                      "min_contact_fraction": lo[1]["min_contact_fraction"], "min_contact_case": lo[0],
                      "spectrum_peaks": peaks}
    return {"cases": per, "envelope": env}


def format_envelope(table: dict) -> str:
    """The text table of ``case_envelope``: per case and route, then the envelope."""
    lines = ["soil cases (max uplift mm, min contact %, largest 5 % floor-spectrum peak g)"]
    for case, routes in table["cases"].items():
        for route, r in routes.items():
            peak = max((v for d in r["spectrum_peaks"].values() for v in d.values()), default=float("nan"))
            lines.append(f"  {case:>8} {route:<11} {1e3 * r['max_uplift_m']:10.4f} {100 * r['min_contact_fraction']:8.1f} "
                         f"{peak / G:8.3f}")
    lines.append("envelope over the cases (governing case in brackets)")
    for route, e in table["envelope"].items():
        lines.append(f"  {route:<11} max uplift {1e3 * e['max_uplift_m']:.4f} mm [{e['max_uplift_case']}], min contact "
                     f"{100 * e['min_contact_fraction']:.1f} % [{e['min_contact_case']}]")
        for node, dirs in e["spectrum_peaks"].items():
            lines.append("    " + node + ": " + ", ".join(f"{d} {v['value'] / G:.3f} g [{v['case']}]"
                                                          for d, v in dirs.items()))
    return "\n".join(lines)

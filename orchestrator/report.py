"""A self-contained report of a results file: ``uplift report results.h5 -o DIR``.

Writes ``DIR/report.html``: the scene, what each route is, the per-route summary (the motion's
components, max uplift and its time, raft rotation sqrt(rx² + ry²) and per axis, min contact
fraction, wall time, converged or why not), the route comparison of ``orchestrator.compare``
and the figures of the paper's kind (fig. 3-6: uplift at the raft edges, raft displacements
with and without uplift, rocking about both axes, floor response spectra in x, y and z),
embedded as base64 PNG so that the page needs no other file. The figures are also written
next to it as PNG files.

``uplift report ensemble.h5 -o DIR`` (an ensemble file, ``orchestrator.ensemble``) writes the
ensemble's page instead: the fractiles over the records per PGA and route, the runs that did
not converge and why, max uplift (raft rotation, contact ratio) against PGA and the fractile
floor spectra per PGA, and the fragility curves stored by ``uplift fragility`` (one panel per
limit state).

Both pages place the runs (an ensemble: every converged cell) on the static pushover curve of
the same scene (``oncurve_parts``, ``orchestrator.oncurve``): computed, or read from
``--pushover FILE``, refused when of another scene.
"""
from __future__ import annotations

import base64
import html
import io
import json
from pathlib import Path

import h5py
import numpy as np

from uplift_common.files import atomic_folder, atomic_output
from structure.results import Status

from orchestrator import oncurve
from orchestrator.compare import compare, format_difference
from orchestrator.design import case_envelope, format_envelope, read_design
from orchestrator.design_spectra import plot_design_spectra
from orchestrator.ensemble import ensemble_components, read_ensemble
from orchestrator.motion import G
from orchestrator.plots import dodged, plate_map_figures, pyplot, route_style, run_figures, uplift_map_figures
from orchestrator.results_file import (ResultsFileError, read_cases, read_interface, read_motion, read_results, read_scene_record,
                                       summary)
from orchestrator.routes import get_route, route_names


def route_note(name: str) -> str:
    """One line on what a route computes (the registry's summary)."""
    return get_route(name).summary if name in route_names() else "route of this results file"


def load(path):
    """(scene name, created, {route: RouteResult}, Motion or None) of a results file
    (orchestrator.results_file.ResultsFileError when it is missing or not one)."""
    results = read_results(path)
    scene, created, motion = read_motion(path)
    return scene or Path(path).stem, created, results, motion


def _table(header, rows) -> str:
    esc = lambda v: html.escape(str(v))
    head = "".join(f"<th>{esc(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{esc(v)}</td>" for v in r) + "</tr>" for r in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def summary_rows(results) -> list:
    """Rows of the per-route summary table (strings, display units)."""
    rows = []
    for route, res in results.items():
        s = summary(res)
        axes = s["max_raft_rotation_axes_rad"]
        rows.append([route, ", ".join(s["components"]) or "-", f"{1e3 * s['max_uplift_m']:.4f}",
                     f"{s['max_uplift_time_s']:.3f}", f"{s['max_raft_rotation_rad']:.4e}",
                     f"{axes['x']:.4e}", f"{axes['y']:.4e}", f"{100 * s['min_contact_fraction']:.1f}",
                     f"{s['wall_s']:.2f}", "yes" if s["converged"] else f"{s['status'].upper()}: {res.message}"])
    return rows


SUMMARY_HEADER = ["route", "components", "max uplift (mm)", "at t (s)", "max raft rotation sqrt(rx²+ry²) (rad)",
                  "max |rx| (rad)", "max |ry| (rad)", "min contact (%)", "wall (s)", "converged"]


def comparison_rows(cmp: dict) -> list:
    """Rows of the comparison table from ``orchestrator.compare.compare``'s output."""
    rows = []
    for route, m in cmp["routes"].items():
        d = cmp["differences"].get(route)
        rows.append([route, f"{1e3 * m['max_uplift_m']:.4f}", format_difference(d, "max_uplift", "max_uplift_m", ""),
                     f"{m['max_rotation_rad']:.4e}", format_difference(d, "max_rotation", "max_rotation_rad", ""),
                     "reference" if not d else "-" if d["max_spectrum_peak"] is None
                     else f"{100 * d['max_spectrum_peak']:.2f}",
                     f"{d['wall_ratio']:.2f}" if d and d["wall_ratio"] is not None else "-"])
    return rows


COMPARISON_HEADER = ["route", "max uplift (mm)", "d uplift (%, or absolute)", "max rotation (rad)",
                     "d rotation (%, or absolute)",
                     "max |d floor-spectrum peak| (%)", "wall / reference wall"]

STYLE = """body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}
table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;padding:3px 8px;text-align:right}
td:first-child,th:first-child{text-align:left}img{max-width:100%;border:1px solid #ddd;margin:.5em 0}"""


def write_report(results_path, directory, reference: str | None = None, pushover=()) -> Path:
    """Write ``directory/report.html`` (self-contained) and the figures as PNG next to it;
    ``pushover``: pushover files or scenes whose static curve the runs are drawn on
    (``pushover_curves``; without: the scene the results file stores, else the built-in scene of its
    name, whichever is the scene that ran)."""
    scene, created, results, motion = load(results_path)
    if reference is not None and reference not in results:
        raise ResultsFileError(f"--reference {reference!r} is not in {results_path} (routes: {', '.join(results)})")
    curves, notes = results_curves(results, scene, motion, pushover, f"results file {results_path}",  # refusals first
                                   read_scene_record(results_path)["scene_toml"])
    directory = Path(directory)
    with atomic_folder(directory) as stage:      # every file of the report, or none (the old ones)
        cmp = compare(results, reference=reference)
        interface = read_interface(results_path)
        figures = _save_figures(run_figures(results, motion, scene), stage)
        uplift_map = [] if interface is None else _save_figures(
            uplift_map_figures(results, interface["polygon"], scene, interface["mesh_source"]), stage)
        plate_maps = [] if interface is None else _save_figures(
            plate_map_figures(results, interface["polygon"], interface["area"], scene), stage)
        esc = html.escape
        parts = [f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>uplift report: {esc(scene)}</title>",
                 f"<style>{STYLE}</style></head><body>",
                 f"<h1>Foundation uplift: scene <code>{esc(scene)}</code></h1>",
                 f"<p>Results file <code>{esc(str(results_path))}</code>, written {esc(created)}"
                 + (f"; motion: {esc(motion.label)}, components {esc(', '.join(motion.components))}, "
                    f"{motion.acc.shape[0]} samples at {1e3 * motion.dt:g} ms" if motion is not None else "") + ".</p>",
                 "<h2>Routes</h2><ul>"
                 + "".join(f"<li><b>{esc(r)}</b>: {esc(route_note(r))}</li>"
                           for r in results) + "</ul>",
                 "<h2>Summary per route</h2>", _table(SUMMARY_HEADER, summary_rows(results)),
                 f"<h2>Route comparison (reference: {esc(cmp['reference'])})</h2>",
                 "<p>Relative differences (route − reference) / reference; floor-spectrum peaks: "
                 f"{100 * cmp['damping']:.0f} % damped pseudo-acceleration, largest difference over output "
                 "nodes and directions.</p>", _table(COMPARISON_HEADER, comparison_rows(cmp)),
                 "<h2>Figures</h2><p>Per route: uplift at the raft edges along x and y, the raft's vertical "
                 "displacements (edges and centre) and its rocking about x and y with the magnitude "
                 "sqrt(rx² + ry²) (paper fig. 3-4), floor response spectra in x, y and z (fig. 5-6; a plate raft's "
                 "<code>[output] raft_points</code> among them, under their names); dashed: "
                 "the <code>linear</code> route (no uplift) when present.</p>"]
        parts += _images(figures)
        if uplift_map:
            parts += ["<h2>Uplift over the raft</h2><p>The interface mesh (one patch per interface node: the cells "
                      "of a mesh file, the squares of a grid) coloured by the uplift of each patch at the instant of "
                      "each route's peak uplift; + the raft centre.</p>"] + _images(uplift_map)
        if plate_maps:
            parts += ["<h2>The plate raft</h2><p>Per route with a plate raft, at the instant of its peak uplift: the "
                      "uplift of each interface cell (grey: in contact) and its compressive contact pressure (its "
                      "contact force over its area; grey: lifted); beside them the largest bending moment per unit "
                      "length over the run, max(|Mx|, |My|) of each cell (static + dynamic; the DKT moments at "
                      "the cells' triangle centroids). Red outline: the held region, which moves rigidly with the "
                      "stick base; + the raft centre.</p>"] + _images(plate_maps)
        parts += design_parts(results_path, stage, reference)
        parts += oncurve_parts(results, scene, curves, notes, stage)
        _write_page(stage, parts)
    return directory / PAGE


def design_parts(results_path, directory: Path, reference: str | None = None) -> list:
    """The design-basis section of a report (orchestrator.design): per soil case the profile, the
    summary and the route comparison, the envelope over the cases, the strain-compatible soil,
    and the design floor spectra (figures and where their tables are); [] for a run of one soil."""
    cases = read_cases(results_path)
    if not cases:
        return []
    design = read_design(results_path)
    esc = html.escape
    per = {case: read_results(results_path, case) for case in cases}
    rule = design["rule"]
    how = (f"G / (1 + Cv), G, G (1 + Cv) with Cv = {rule['cv']:g} (vs / sqrt(1 + Cv), vs, vs sqrt(1 + Cv); density, "
           "Poisson's ratio and damping kept)" if "cv" in rule else "named profiles")
    parts = [f"<h2>Design basis: soil cases ({esc(', '.join(cases))})</h2>",
             f"<p>Cases: {esc(how)}. The summary and figures above are those of case <b>{esc(cases[0])}</b>. "
             "Rules and references: docs/design_basis.md.</p>"]
    with h5py.File(results_path, "r") as f:
        profiles = {case: json.loads(f[f"cases/{case}"].attrs["profile"]) for case in cases}
    rows = [[case, *(f"{m['vs']:.1f} / {m['damping']:.4f}" for m in (*p["layers"], p["halfspace"]))]
            for case, p in profiles.items()]
    n_layers = len(profiles[cases[0]]["layers"])
    parts.append(_table(["case", *(f"layer {i} vs (m/s) / damping" for i in range(n_layers)),
                         "half-space vs (m/s) / damping"], rows))
    site = design["site_response"]
    if site is not None:
        parts.append(f"<h3>Strain-compatible soil</h3><p>Equivalent-linear free-field analysis ({esc(site['input'])} "
                     f"motion, component {esc(site['component'])}, strain ratio {site['strain_ratio']:g}, tolerance "
                     f"{site['tolerance']:g}): {site['iterations']} iterations, "
                     f"{'converged' if site['converged'] else 'NOT converged'}.</p>")
        parts.append(_table(["layer", "vs low-strain (m/s)", "vs (m/s)", "G/Gmax", "damping low-strain", "damping",
                             "effective strain", "peak strain"],
                            [[i, f"{a:.1f}", f"{b:.1f}", f"{g:.4f}", f"{c:.4f}", f"{d:.4f}", f"{e:.3e}", f"{m:.3e}"]
                             for i, (a, b, g, c, d, e, m) in enumerate(zip(
                                 site["vs_initial"], site["vs"], site["g_ratio"], site["damping_initial"],
                                 site["damping"], site["strain_eff"], site["strain_max"]))]))
    for case, results in per.items():
        parts += [f"<h3>Case {esc(case)}</h3>", _table(SUMMARY_HEADER, summary_rows(results))]
        if len(results) > 1:
            ref = reference if reference in results else None
            parts.append(_table(COMPARISON_HEADER, comparison_rows(compare(results, reference=ref))))
    parts += ["<h3>Envelope over the soil cases</h3>", f"<pre>{esc(format_envelope(case_envelope(per)))}</pre>"]
    spectra = design["spectra"]
    if spectra is not None:
        paths = plot_design_spectra(spectra, directory)
        parts.append(f"<h3>Design floor response spectra</h3><p>Broadened ±{100 * spectra.broadening:g} % in "
                     "frequency (at f: the max of the raw spectrum over [f/(1+r), f/(1−r)]), enveloped over the "
                     f"cases, at damping {', '.join(f'{100 * z:g} %' for z in spectra.damping)}; tables: "
                     "<code>uplift run</code> writes them as CSV (frequency Hz, acceleration g).</p>")
        for path in paths:
            data = base64.b64encode(path.read_bytes()).decode("ascii")
            parts.append(f"<img alt='{esc(path.stem)}' src='data:image/png;base64,{data}'>")
    return parts


def _save_figures(figures, directory: Path) -> list:
    """Write each (name, Figure) as ``directory/<name>.png`` and close it; returns [(name, base64 PNG)]."""
    plt = pyplot()
    out = []
    for name, fig in figures:
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=100)
        plt.close(fig)
        with atomic_output(directory / f"{name}.png") as tmp:
            tmp.write_bytes(buf.getvalue())
        out.append((name, base64.b64encode(buf.getvalue()).decode("ascii")))
    return out


def _images(figures) -> list:
    esc = html.escape
    return [f"<h3>{esc(name)}</h3><img alt='{esc(name)}' src='data:image/png;base64,{data}'>"
            for name, data in figures]


#: the report's page in its folder
PAGE = "report.html"


def _write_page(directory: Path, parts) -> Path:
    out = directory / PAGE
    with atomic_output(out) as tmp:
        tmp.write_text("\n".join(parts + ["</body></html>"]), encoding="utf-8")
    return out


# ---- ensembles ----------------------------------------------------------------------------------

#: the fractile lines of the ensemble figures: quantile -> (label, line style)
FRACTILE_LINES = {0.5: ("median", "-"), 0.84: ("84th percentile", "--")}
#: per-cell numbers drawn against PGA: variable -> (axis label, display factor)
AGAINST_PGA = {"max_uplift": ("max uplift (mm)", 1e3), "max_raft_rotation": ("max raft rotation (mrad)", 1e3),
               "min_contact_ratio": ("min contact ratio (%)", 100.0)}


def ensemble_figures(ds):
    """Figures of an ensemble, yielded as (name, Figure): max uplift, raft rotation and contact
    ratio against PGA (each record a dot, the median a line, the 16-84 % band shaded; per route
    one colour, marker and line style, its dots and medians side by side about each PGA), then
    per PGA the fractile floor spectra (median, 84th percentile, 16-84 % band) at each output
    node in each direction with a spectrum (the motion's components and z; a direction that is
    round-off in every cell is left out and named). The caller closes each figure."""
    plt = pyplot()
    pga = ds["pga"].values
    routes = [str(r) for r in ds["route"].values]
    converged = ds["status"].values == Status.CONVERGED.value
    fig, axes = plt.subplots(1, len(AGAINST_PGA), figsize=(5 * len(AGAINST_PGA), 4.5), constrained_layout=True)
    for ax, (name, (label, factor)) in zip(axes, AGAINST_PGA.items()):
        for k, route in enumerate(routes):
            style, x = route_style(k), dodged(pga, k, len(routes))
            cells = np.where(converged[:, :, k], ds[name].values[:, :, k], np.nan) * factor
            ax.plot(np.broadcast_to(x, cells.shape).ravel(), cells.ravel(), style["marker"], color=style["color"],
                    ms=3, alpha=0.5, linestyle="none")
            q = ds[f"{name}_fractile"].sel(route=route) * factor
            ax.fill_between(pga, q.sel(quantile=0.16), q.sel(quantile=0.84), color=style["color"], alpha=0.15)
            ax.plot(x, q.sel(quantile=0.5), **style, label=f"{route}: median, 16-84 %")
        ax.set_xlabel("PGA (g)")
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
    axes[0].legend()
    fig.suptitle(f"{ds.attrs.get('scene', '')}: {ds.sizes['record']} records per PGA (dots: each record; "
                 "routes side by side about each PGA)")
    yield "ensemble_against_pga", fig
    spectra = ds["floor_spectrum_fractile"]
    candidates = [d for d in "xyz" if d in ensemble_components(ds) or d == "z"]
    directions = [d for d in candidates if np.isfinite(spectra.sel(direction=d).values).any()]
    left = [d for d in "xyz" if d not in directions]
    if not directions:
        return
    nodes = [str(n) for n in ds["node"].values]
    f = ds["frequency"].values
    for p in pga:
        fig, axes = plt.subplots(len(directions), max(1, len(nodes)), figsize=(max(9.0, 4.5 * len(nodes)),
                                 3.5 * len(directions)), squeeze=False, sharex=True, constrained_layout=True)
        for row, d in enumerate(directions):
            for col, node in enumerate(nodes):
                ax = axes[row, col]
                for k, route in enumerate(routes):
                    style = route_style(k)
                    q = spectra.sel(pga=p, route=route, node=node, direction=d) / G
                    ax.fill_between(f, q.sel(quantile=0.16), q.sel(quantile=0.84), color=style["color"], alpha=0.15)
                    for quantile, (what, line) in FRACTILE_LINES.items():
                        ax.semilogx(f, q.sel(quantile=quantile), line, color=style["color"], marker=style["marker"],
                                    ms=4, markevery=(3 * k, 12), label=f"{route}: {what}")
                ax.set_title(f"{node}, {d} ({'vertical' if d == 'z' else 'horizontal'})")
                ax.grid(True, which="both", alpha=0.3)
            axes[row, 0].set_ylabel(f"pseudo-acceleration, {100 * ds.attrs.get('damping', 0.05):g} % (g)")
        for ax in axes[-1]:
            ax.set_xlabel("frequency (Hz)")
        axes[0, 0].legend(fontsize="small")
        note = f"; not drawn: {', '.join(left)} (no response above round-off)" if left else ""
        fig.suptitle(f"{ds.attrs.get('scene', '')}: floor response spectra at {p:g} g\nover "
                     f"{ds.sizes['record']} records (band: 16-84 %){note}")
        yield f"ensemble_floor_spectra_{p:g}g", fig


def ensemble_rows(ds) -> list:
    """Rows of the per-PGA table of an ensemble (strings, display units)."""
    rows = []
    for p in ds["pga"].values:
        for route in ds["route"].values:
            q = lambda name, quantile: float(ds[f"{name}_fractile"].sel(pga=p, route=route, quantile=quantile))
            cells = ds["wall_time"].sel(pga=p, route=route).values
            rows.append([f"{p:g}", str(route), f"{int(ds['converged_records'].sel(pga=p, route=route))}/"
                         f"{ds.sizes['record']}", f"{1e3 * q('max_uplift', 0.5):.3f}",
                         f"{1e3 * q('max_uplift', 0.84):.3f}", f"{1e3 * q('max_raft_rotation', 0.5):.4f}",
                         f"{1e3 * q('max_raft_rotation', 0.84):.4f}", f"{100 * q('min_contact_ratio', 0.5):.1f}",
                         f"{100 * q('min_contact_ratio', 0.16):.1f}", f"{np.nanmedian(cells):.2f}"
                         if np.isfinite(cells).any() else "-"])
    return rows


ENSEMBLE_HEADER = ["PGA (g)", "route", "converged", "max uplift median (mm)", "max uplift 84 % (mm)",
                   "raft rotation median (mrad)", "raft rotation 84 % (mrad)", "min contact median (%)",
                   "min contact 16 % (%)", "median wall (s)"]


FRAGILITY_HEADER = ["limit state", "route", "median (g)", "beta", "ln L", "median band, bootstrap (g)",
                    "exceedances per PGA", "left out"]


def fragility_parts(path, directory: Path) -> list:
    """The page's fragility section: the fits stored in the ensemble file by ``uplift
    fragility`` (a table and one panel per limit state, also ``directory/fragility.png``)."""
    from orchestrator import fragility as frag  # scipy.optimize: only ensemble reports pay it
    fits = frag.read_fragility(path)
    if fits is None:
        return ["<h2>Fragility</h2><p>None stored: <code>uplift fragility FILE --limit 'max_uplift &gt; 5 mm'</code> "
                "fits one.</p>"]
    rows = []
    for e in frag.fragility_json(fits)["fragility"]:
        counts = ", ".join(f"{p:g} g: {z}/{n}" for p, z, n in zip(e["pga_g"], e["exceedances"], e["cells"]))
        left = ", ".join(f"{v} {k}" for k, v in e["left_out"].items() if v) or "none"
        fit = ([f"{e['median_g']:.4g}", f"{e['beta']:.3f}", f"{e['log_likelihood']:.4g}"] if e["identifiable"]
               else [f"not identifiable: {e['reason']}", "-", "-"])
        bs = e["bootstrap"]
        band = (f"{bs['median_g'][0]:.3g}-{bs['median_g'][1]:.3g} ({100 * bs['confidence']:g} %, "
                f"{bs['identified']}/{bs['samples']})" if bs and bs["median_g"] else "-")
        rows.append([e["limit"], e["route"], *fit, band, counts, left])
    figure = _save_figures([("fragility", frag.fragility_figure(fits))], directory)
    return ["<h2>Fragility</h2><p>Maximum-likelihood lognormal fits P(exceed | PGA) = &Phi;(ln(PGA / median) "
            "/ beta) on the exceedances of the converged cells per PGA (dots: the observed fractions z/n).</p>",
            _table(FRAGILITY_HEADER, rows)] + _images(figure)


def write_ensemble_report(path, directory, pushover=()) -> Path:
    """Write ``directory/report.html`` (self-contained) for an ensemble file of ``uplift
    ensemble``: the fractiles per PGA and route, the runs that did not converge and why, the
    figures of ``ensemble_figures`` (also as PNG next to it), every cell on the static pushover
    curve (``pushover`` as ``write_report``'s)."""
    ds = read_ensemble(path)
    curves, notes = ensemble_curves(ds, pushover, f"ensemble file {path}")      # refusals first
    directory = Path(directory)
    with atomic_folder(directory) as stage:      # every file of the report, or none (the old ones)
        figures = _save_figures(ensemble_figures(ds), stage)
        esc = html.escape
        a = ds.attrs
        status = ds["status"].values
        others = [[str(ds["record"].values[i]), f"{ds['pga'].values[j]:g}", str(ds["route"].values[k]),
                   str(status[i, j, k]), str(ds["message"].values[i, j, k])]
                  for i, j, k in zip(*np.nonzero(status != Status.CONVERGED.value))]
        parts = [f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>uplift ensemble: {esc(a['scene'])}</title>",
                 f"<style>{STYLE}</style></head><body>",
                 f"<h1>Foundation uplift: ensemble of scene <code>{esc(a['scene'])}</code></h1>",
                 f"<p>Ensemble file <code>{esc(str(path))}</code>, written {esc(str(a.get('created', '')))}: "
                 f"{ds.sizes['record']} records x {ds.sizes['pga']} PGAs x {ds.sizes['route']} routes = {status.size} "
                 f"runs ({a['computed']} computed, {a['reused']} kept from an earlier run) on {a['workers']} workers in "
                 f"{a['wall_s']:.1f} s (set-up: sweep and fit {a['setup_s']:.1f} s, time-step check "
                 f"{a['dt_check_s']:.1f} s).</p>",
                 "<h2>Routes</h2><ul>" + "".join(f"<li><b>{esc(str(r))}</b>: {esc(route_note(str(r)))}</li>"
                                                 for r in ds["route"].values) + "</ul>",
                 "<h2>Fractiles over the records, per PGA</h2><p>Over the converged runs only; linear "
                 "interpolation between the sorted values (numpy).</p>", _table(ENSEMBLE_HEADER, ensemble_rows(ds)),
                 "<h2>Runs that did not converge</h2>"
                 + (_table(["record", "PGA (g)", "route", "status", "why"], others) if others else "<p>None.</p>"),
                 "<h2>Figures</h2>"]
        parts += _images(figures)
        parts += ensemble_oncurve_parts(ds, curves, notes, stage)
        _write_page(stage, parts + fragility_parts(path, stage))
    return directory / PAGE


# ---- runs on the static pushover curve (orchestrator.oncurve) -----------------------------------

ONCURVE_HEADER = ["route", "soil of the curve", "max |M| (MN m)", "at t (s)", "ΣP / N then", "max rotation (mrad)",
                  "min contact (% area)", "curve's M at that rotation (MN m)", "max |M| / curve's M", "note"]


def pushover_curves(key, scene_name: str, soils, components, sources, what: str, max_rotation: float = 0.0,
                    scene_toml: str = ""):
    """({soil: oncurve.Curve}, notes) for runs of scene key ``key`` on the ``soils`` ("bem",
    "winkler"): read from the pushover files among ``sources`` (checked by their scene key: one of
    another scene is refused, OnCurveError), computed for the scenes among them (TOML files or
    built-in names, checked the same way), or, without sources, computed for the scene the file
    stores (``scene_toml``, the scene as it ran) or the built-in scene named ``scene_name``, the
    first whose key is ``key``. A computed curve rocks in the motion's
    direction (``oncurve.rocking_direction`` of ``components``) past ``max_rotation`` (rad, the
    runs' largest). ``notes``: why a curve is not there."""
    from orchestrator.pushover import read_pushover, scene_pushover  # only reports with a curve pay it
    from orchestrator.scene import builtin_scenes, load_scene, scene_from_dict, tomllib  # (same)
    from orchestrator.settings import default_cache_dir  # (same)
    curves, notes, scenes = {}, [], []
    for src in sources:
        path = Path(src)
        if path.is_file() and h5py.is_hdf5(path):
            c = oncurve.Curve.from_file(read_pushover(path), str(path))
            c.check_key(key, what)
            curves[c.soil] = c
        else:
            scenes.append((load_scene(src), f"scene {src}"))
    if not sources:
        if not key:
            notes.append(f"{what} holds no scene key (written before it was stored, or by hand): run `uplift run` "
                         "again, or draw a pushover file of the same scene with --pushover")
        elif scene_toml and oncurve.scene_key(stored := scene_from_dict(tomllib.loads(scene_toml),
                                                                        name=scene_name)) == key:
            scenes.append((stored, f"the scene stored in {what}"))
        elif scene_name in builtin_scenes() and oncurve.scene_key(load_scene(scene_name)) == key:
            scenes.append((load_scene(scene_name), f"built-in scene {scene_name}"))
        else:
            notes.append(f"the scene {scene_name!r} of {what} is not a built-in scene of the same key: give "
                         "--pushover FILE (made by `uplift pushover SCENE -o FILE`) or --pushover SCENE")
    angle, why = oncurve.rocking_direction(components)
    for scene, label in scenes:
        if oncurve.scene_key(scene) != key:
            raise oncurve.OnCurveError(f"--pushover {label}: not the scene of {what} (scene key "
                                       f"{oncurve.scene_key(scene)} against {key or 'none stored'}): its mesh, soil, "
                                       "structure or springs differ")
        if scene.structure is None:
            notes.append(f"{label} has no [structure]: no weight to push over")
            continue
        if scene.raft is not None:
            notes.append(f"{label} has a plate raft: the static pushover models a rigid raft only (no curve)")
            continue
        for soil in sorted(set(soils) - set(curves)):
            if soil == "bem" and scene.profile is None:
                notes.append(f"{label} has no half-space: no pushover on the BEM soil")
                continue
            run = scene_pushover(scene, soil=soil, direction=angle, cache_dir=default_cache_dir())
            if max_rotation > run.curve.rotation[-1]:
                run = scene_pushover(scene, soil=soil, direction=angle, max_rotation=1.25 * max_rotation,
                                     cache_dir=default_cache_dir())
            curves[soil] = oncurve.Curve.from_run(run, f"computed from {label}, direction {why}")
    for c in curves.values():
        if abs(c.direction_deg - angle) > 1e-9:
            notes.append(f"the {c.soil} curve rocks in direction {c.direction_deg:g}°, the runs' is {why}")
        if abs(c.moment[0]) > 1e-6 * max(abs(c.moment).max(), 1e-300):
            notes.append(f"the {c.soil} curve's moment at θ = 0 is {c.moment[0]:.4g} N m: the weight acts off the "
                         "raft centre, and the runs' rotations are about their tilted static state, not the level raft")
    return curves, notes


def _uplift(route: str, res=None) -> bool:
    """False for a route whose raft is bonded (the registry's ``uplift``, or the contact disabled)."""
    registered = get_route(route).uplift if route in route_names() else True
    return registered and (res is None or res.info.get("contact_enabled", True) is not False)


def _curve_list(curves) -> str:
    esc = html.escape
    return "".join(f"<li>{esc(c.soil_label)}, direction {c.direction_deg:g}°, vertical load "
                   f"{1e-6 * c.vertical:.4g} MN, full-contact rocking stiffness {c.stiffness:.4g} N m/rad, lift-off "
                   f"onset {1e-6 * c.onset_moment:.4g} MN m at {1e3 * c.onset_rotation:.4g} mrad ({esc(c.source)})</li>"
                   for c in curves.values())


ONCURVE_TEXT = ("<p>Each run's largest overturning moment |M| (about the raft centre, of the total contact "
                "forces, static preload included, beyond the weight's own: the pushover's moment), its largest "
                "raft rotation sqrt(rx² + ry²) and its smallest contact ratio (area of the nodes in contact / "
                "raft area), drawn on the static pushover curve of the same scene (<code>uplift pushover</code>, "
                "docs/pushover.md): the winkler route on its own springs, the other routes on the BEM's static "
                "gap table. The three extremes are each over the whole record, not at one instant. The curve "
                "holds the vertical load N at the static weight; in a run the total contact force ΣP varies "
                "(vertical inertia of the rocking raft), and with it the moment the contact can carry "
                "(ΣP times the distance to the edge): a run's moment may pass the curve's plateau. A hollow "
                "marker: a bonded route (no uplift), whose contact forces may pull.</p>")


def results_curves(results, scene_name: str, motion, sources, what: str, scene_toml: str = ""):
    """``pushover_curves`` for the routes of a results file (their scene key, soils, motion
    components and largest rotation; ``scene_toml``: the scene the file stores): ({soil: Curve},
    notes). Refuses a pushover of another scene."""
    ran = [res for res in results.values() if res.nt > 0]
    key = next((res.info.get("scene_key") for res in ran if res.info.get("scene_key")), None)
    components = motion.components if motion is not None else next(
        (tuple(res.info.get("components", ())) for res in ran), ("x",))
    max_rot = max((float(np.hypot(res.raft[:, 3], res.raft[:, 4]).max()) for res in ran), default=0.0)
    if not ran and not sources:
        return {}, ["no route ran"]
    return pushover_curves(key, scene_name, {oncurve.route_soil(r.route) for r in ran}, components, sources, what,
                           max_rot, scene_toml)


def oncurve_parts(results, scene_name: str, curves: dict, notes: list, directory: Path) -> list:
    """The report's section "On the static pushover curve" for a results file's routes on
    ``curves`` (``results_curves``)."""
    head = ["<h2>On the static pushover curve</h2>"]
    esc = html.escape
    if not curves:
        return head + [f"<p>Not drawn: {esc('; '.join(notes))}.</p>"]
    points, rows, left = [], [], []
    for route, res in results.items():
        c = curves.get(oncurve.route_soil(route))
        why = oncurve.unplaced(res, c)
        if why:
            left.append(f"{route}: {why}")
            continue
        p = oncurve.route_point(res, c, uplift=_uplift(route, res))
        points.append(p)
        rows.append([route, p["soil"], f"{1e-6 * p['max_moment_Nm']:.4g}", f"{p['max_moment_time_s']:.3f}",
                     f"{p['vertical_ratio_at_max_moment']:.3f}",
                     f"{1e3 * p['max_rotation_rad']:.4g}", f"{100 * p['min_contact_ratio']:.1f}",
                     f"{1e-6 * p['static_moment_at_rotation_Nm']:.4g}", f"{p['moment_over_static']:.3f}",
                     "; ".join(([] if p["uplift"] else ["no uplift (bonded)"])
                               + ([] if res.converged else [f"{res.status.value}: up to its stop"]))])
    figure = _save_figures([("on_the_curve", oncurve.oncurve_figure(
        curves, points, f"{scene_name}: runs on the static pushover curve"))], directory)
    return (head + [ONCURVE_TEXT, "<p>Curves:</p><ul>" + _curve_list(curves) + "</ul>",
                    _table(ONCURVE_HEADER, rows)]
            + [f"<p>Not drawn: {esc(x)}.</p>" for x in left] + [f"<p>Note: {esc(x)}.</p>" for x in notes]
            + _images(figure))


def ensemble_curves(ds, sources, what: str):
    """``pushover_curves`` for the cells of an ensemble: ({soil: Curve}, notes)."""
    if "max_overturning_moment" not in ds:
        return {}, [f"{what} stores no overturning moment (written before it was stored): run `uplift ensemble` again"]
    routes = [str(r) for r in ds["route"].values]
    converged = ds["status"].values == Status.CONVERGED.value
    max_rot = float(np.nanmax(np.where(converged, ds["max_raft_rotation"].values, np.nan), initial=0.0))
    return pushover_curves(ds.attrs.get("scene_key"), str(ds.attrs.get("scene", "")),
                           {oncurve.route_soil(r) for r in routes}, ensemble_components(ds), sources, what, max_rot)


def ensemble_oncurve_parts(ds, curves: dict, notes: list, directory: Path) -> list:
    """The ensemble page's section "On the static pushover curve": every converged cell's point
    on ``curves`` (``ensemble_curves``)."""
    head = ["<h2>On the static pushover curve</h2>"]
    esc = html.escape
    if not curves:
        return head + [f"<p>Not drawn: {esc('; '.join(notes))}.</p>"]
    routes = [str(r) for r in ds["route"].values]
    converged = ds["status"].values == Status.CONVERGED.value
    points, rows, left = [], [], []
    for k, route in enumerate(routes):
        soil = oncurve.route_soil(route)
        if soil not in curves:
            left.append(f"{route}: no pushover on the {soil} soil")
            continue
        onset = curves[soil].onset_moment
        for j, pga in enumerate(ds["pga"].values):
            cells = [{"route": route, "soil": soil, "uplift": _uplift(route),
                      "max_moment_Nm": float(ds["max_overturning_moment"].values[i, j, k]),
                      "max_rotation_rad": float(ds["max_raft_rotation"].values[i, j, k]),
                      "min_contact_ratio": float(ds["min_contact_area_ratio"].values[i, j, k])}
                     for i in range(ds.sizes["record"]) if converged[i, j, k]]
            cells = [c for c in cells if np.isfinite(c["max_moment_Nm"])]
            points += cells
            m = np.array([c["max_moment_Nm"] for c in cells])
            rows.append([f"{pga:g}", route, soil, str(len(cells)),
                         f"{1e-6 * np.median(m):.4g}" if m.size else "-",
                         f"{int((m > onset).sum())}/{m.size}" if np.isfinite(onset) else "-"])
    figure = _save_figures([("on_the_curve", oncurve.oncurve_figure(
        curves, points, f"{ds.attrs.get('scene', '')}: every converged cell on the static pushover curve"))],
        directory)
    header = ["PGA (g)", "route", "soil of the curve", "cells drawn", "median max |M| (MN m)",
              "cells past the lift-off onset moment"]
    return (head + [ONCURVE_TEXT.replace("Each run's", "Each cell's"), "<p>Curves:</p><ul>" + _curve_list(curves)
                    + "</ul>", _table(header, rows)]
            + [f"<p>Not drawn: {esc(x)}.</p>" for x in left] + [f"<p>Note: {esc(x)}.</p>" for x in notes]
            + _images(figure))

"""A self-contained report of a results file: ``uplift report results.h5 -o DIR``.

Writes ``DIR/report.html``: the scene, what each route is, the per-route summary (max uplift
and its time, raft rotation, min contact fraction, wall time, converged or why not), the route
comparison of ``orchestrator.compare`` and the figures of the paper's kind (fig. 3-6: uplift
at the raft edges, raft displacements with and without uplift, floor response spectra),
embedded as base64 PNG so that the page needs no other file. The figures are also written
next to it as PNG files.
"""
from __future__ import annotations

import base64
import html
import io
from pathlib import Path

from orchestrator.compare import compare
from orchestrator.plots import pyplot, run_figures
from orchestrator.results import ResultsFileError, read_motion, read_results, summary
from orchestrator.routes import get_route, route_names


def route_note(name: str) -> str:
    """One line on what a route computes (the registry's summary)."""
    return get_route(name).summary if name in route_names() else "route of this results file"


def load(path):
    """(scene name, created, {route: RouteResult}, Motion or None) of a results file
    (orchestrator.results.ResultsFileError when it is missing or not one)."""
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
        rows.append([route, f"{1e3 * s['max_uplift_m']:.4f}", f"{s['max_uplift_time_s']:.3f}",
                     f"{s['max_raft_rotation_rad']:.4e}", f"{100 * s['min_contact_fraction']:.1f}",
                     f"{s['wall_s']:.2f}", "yes" if s["converged"] else f"{s['status'].upper()}: {res.message}"])
    return rows


SUMMARY_HEADER = ["route", "max uplift (mm)", "at t (s)", "max raft rotation (rad)",
                  "min contact (%)", "wall (s)", "converged"]


def comparison_rows(cmp: dict) -> list:
    """Rows of the comparison table from ``orchestrator.compare.compare``'s output."""
    rows = []
    for route, m in cmp["routes"].items():
        d = cmp["differences"].get(route)
        pct = lambda key: f"{100 * d[key]:+.2f}" if d else "reference"
        rows.append([route, f"{1e3 * m['max_uplift_m']:.4f}", pct("max_uplift"),
                     f"{m['max_rotation_rad']:.4e}", pct("max_rotation"),
                     f"{100 * d['max_spectrum_peak']:.2f}" if d else "reference",
                     f"{d['wall_ratio']:.2f}" if d and d["wall_ratio"] is not None else "-"])
    return rows


COMPARISON_HEADER = ["route", "max uplift (mm)", "d uplift (%)", "max rotation (rad)", "d rotation (%)",
                     "max |d floor-spectrum peak| (%)", "wall / reference wall"]

STYLE = """body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}
table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;padding:3px 8px;text-align:right}
td:first-child,th:first-child{text-align:left}img{max-width:100%;border:1px solid #ddd;margin:.5em 0}"""


def write_report(results_path, directory, reference: str | None = None) -> Path:
    """Write ``directory/report.html`` (self-contained) and the figures as PNG next to it."""
    scene, created, results, motion = load(results_path)
    if reference is not None and reference not in results:
        raise ResultsFileError(f"--reference {reference!r} is not in {results_path} (routes: {', '.join(results)})")
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    cmp = compare(results, reference=reference)
    plt = pyplot()
    figures = []
    for name, fig in run_figures(results, motion, scene):
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=100)
        plt.close(fig)
        (directory / f"{name}.png").write_bytes(buf.getvalue())
        figures.append((name, base64.b64encode(buf.getvalue()).decode("ascii")))
    esc = html.escape
    parts = [f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>uplift report: {esc(scene)}</title>",
             f"<style>{STYLE}</style></head><body>",
             f"<h1>Foundation uplift: scene <code>{esc(scene)}</code></h1>",
             f"<p>Results file <code>{esc(str(results_path))}</code>, written {esc(created)}"
             + (f"; motion: {esc(motion.label)}, {motion.acc.shape[0]} samples at {1e3 * motion.dt:g} ms"
                if motion is not None else "") + ".</p>",
             "<h2>Routes</h2><ul>"
             + "".join(f"<li><b>{esc(r)}</b>: {esc(route_note(r))}</li>"
                       for r in results) + "</ul>",
             "<h2>Summary per route</h2>", _table(SUMMARY_HEADER, summary_rows(results)),
             f"<h2>Route comparison (reference: {esc(cmp['reference'])})</h2>",
             "<p>Relative differences (route − reference) / reference; floor-spectrum peaks: "
             f"{100 * cmp['damping']:.0f} % damped pseudo-acceleration, largest difference over output "
             "nodes and directions.</p>", _table(COMPARISON_HEADER, comparison_rows(cmp)),
             "<h2>Figures</h2><p>Per route: uplift at the raft edges and raft displacements (paper fig. 3-4), "
             "floor response spectra (fig. 5-6); dashed: the <code>linear</code> route (no uplift) "
             "when present.</p>"]
    parts += [f"<h3>{esc(name)}</h3><img alt='{esc(name)}' src='data:image/png;base64,{data}'>"
              for name, data in figures]
    parts.append("</body></html>")
    out = directory / "report.html"
    out.write_text("\n".join(parts), encoding="utf-8")
    return out

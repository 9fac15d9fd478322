"""Differences between routes: one function for every pair of RouteResults.

``compare(results, reference=None)`` measures, per route, max uplift (m), max raft rotation
sqrt(rx^2 + ry^2) (rad), the floor-spectrum peaks (5 % damping, pseudo-acceleration, 0.1 to
50 Hz) of every output node and horizontal/vertical direction, and the wall time; and the
relative differences (route - reference) / reference of each. The result is JSON-able;
``format_table`` prints it.
"""
from __future__ import annotations

import numpy as np

from orchestrator.routes import default_reference
from orchestrator.spectra import response_spectrum

DIRECTIONS = ("x", "y", "z")


def route_metrics(res, damping=0.05, n_periods=120) -> dict:
    """{max_uplift_m, max_rotation_rad, spectrum_peaks {node: {dir: psa m/s^2}}, wall_s, converged}."""
    periods = np.geomspace(0.02, 10.0, n_periods)
    dt = float(res.time[1] - res.time[0]) if res.nt > 1 else 1.0
    peaks = {}
    for name, acc in res.acc.items():
        acc = np.asarray(acc)
        peaks[name] = {}
        amax = np.abs(acc).max() if acc.size else 0.0
        for j, ax in enumerate(DIRECTIONS):
            if amax > 0 and np.abs(acc[:, j]).max() > 1e-6 * amax:     # skip round-off directions
                peaks[name][ax] = float(response_spectrum(acc[:, j], dt, periods, damping).psa.max())
    rot = np.hypot(res.raft[:, 3], res.raft[:, 4])
    return dict(max_uplift_m=float(res.max_uplift()), max_rotation_rad=float(rot.max()) if rot.size else 0.0,
                spectrum_peaks=peaks, wall_s=float(res.wall_s), converged=bool(res.converged))


def _rel(a, b):
    return float((a - b) / b) if b else (0.0 if a == b else float("inf"))


def compare(results: dict, reference: str | None = None, damping=0.05) -> dict:
    """Differences of every route in ``results`` ({route: RouteResult}) to ``reference``
    (default: the registry's reference route if present, e.g. "timefreq", else the first route). Returns a JSON-able dict:
    {reference, damping, routes: {route: metrics}, differences: {route: {max_uplift,
    max_rotation, spectrum_peaks {node: {dir: rel}}, max_spectrum_peak}, wall_ratio}}."""
    if not results:
        raise ValueError("compare needs at least one route")
    ref = reference or default_reference(results)
    if ref not in results:
        raise ValueError(f"reference route {ref!r} is not among the results ({', '.join(results)})")
    metrics = {r: route_metrics(res, damping) for r, res in results.items()}
    m0 = metrics[ref]
    diffs = {}
    for r, m in metrics.items():
        if r == ref:
            continue
        sp = {}
        for node, dirs in m["spectrum_peaks"].items():
            ref_dirs = m0["spectrum_peaks"].get(node, {})
            sp[node] = {ax: _rel(v, ref_dirs[ax]) for ax, v in dirs.items() if ax in ref_dirs}
        flat = [abs(v) for d in sp.values() for v in d.values()]
        diffs[r] = dict(max_uplift=_rel(m["max_uplift_m"], m0["max_uplift_m"]),
                        max_rotation=_rel(m["max_rotation_rad"], m0["max_rotation_rad"]),
                        spectrum_peaks=sp, max_spectrum_peak=max(flat) if flat else 0.0,
                        wall_ratio=_rel(m["wall_s"], m0["wall_s"]) + 1.0 if m0["wall_s"] else None)
    return dict(reference=ref, damping=damping, routes=metrics, differences=diffs)


def format_table(cmp: dict) -> str:
    """A printed table of ``compare``'s output: one line per route."""
    ref = cmp["reference"]
    lines = [f"reference: {ref}   (differences relative to it; floor spectra at "
             f"{100 * cmp['damping']:.0f} % damping)",
             f"{'route':<16}{'max uplift mm':>14}{'d uplift':>10}{'rotation rad':>14}{'d rot':>9}"
             f"{'max |d SA|':>11}{'wall s':>9}{'conv':>6}"]
    for r, m in cmp["routes"].items():
        d = cmp["differences"].get(r)
        du = f"{100 * d['max_uplift']:+.2f}%" if d else "-"
        dr = f"{100 * d['max_rotation']:+.2f}%" if d else "-"
        ds = f"{100 * d['max_spectrum_peak']:.2f}%" if d else "-"
        lines.append(f"{r:<16}{1e3 * m['max_uplift_m']:>14.4f}{du:>10}{m['max_rotation_rad']:>14.4e}"
                     f"{dr:>9}{ds:>11}{m['wall_s']:>9.2f}{'yes' if m['converged'] else 'NO':>6}")
    return "\n".join(lines)


def history_differences(a, b) -> dict:
    """How far RouteResult ``a`` is from ``b`` (the reference): max |a - b| / max |b| per
    quantity (raft, gap, contact_force, soil_w, acc/<node>), over their common samples, plus
    both max uplifts (``compare`` gives the summary metrics)."""
    nt = min(a.nt, b.nt)
    out = {}
    pairs = [(k, getattr(a, k), getattr(b, k)) for k in ("raft", "gap", "contact_force", "soil_w")]
    pairs += [(f"acc/{nm}", a.acc[nm], b.acc[nm]) for nm in b.acc if nm in a.acc]
    for key, x, y in pairs:
        scale = np.abs(y[:nt]).max()
        out[key] = float(np.abs(x[:nt] - y[:nt]).max() / scale) if scale > 0 else float(np.abs(x[:nt]).max())
    out["max_uplift_m"] = (a.max_uplift(), b.max_uplift())
    return out

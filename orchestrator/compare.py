"""Differences between routes: one function for every pair of RouteResults.

``compare(results, reference=None)`` measures, per route, max uplift (m), max raft rotation
sqrt(rx^2 + ry^2) (rad), the floor-spectrum peaks (5 % damping, pseudo-acceleration, 0.1 to
50 Hz) of every output node and horizontal/vertical direction, and the wall time; and the
relative differences (route - reference) / reference of each, with the absolute ones
(route - reference, in the quantity's unit). The default reference is the most exact route
present (timefreq, else monolithic, else cosim, else the first with uplift: never a route
without uplift, linear, for uplift quantities). A difference that cannot be relative (a zero
reference) or is not defined (max uplift of a route without uplift) is None, with the reason
in ``missing`` under the same key; the result is strict JSON (no NaN, no infinity).
``format_table`` prints it.
"""
from __future__ import annotations

import math

import numpy as np

from orchestrator.routes import default_reference, has_uplift
from orchestrator.spectra import response_spectrum

DIRECTIONS = ("x", "y", "z")
#: the quantities compared (key of the differences, of the metrics, unit of the absolute difference)
QUANTITIES = (("max_uplift", "max_uplift_m", "m"), ("max_rotation", "max_rotation_rad", "rad"))


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


def _difference(a: float, b: float, what: str) -> tuple:
    """(relative (a - b) / b or None, absolute a - b or None, reason when the relative one is None)."""
    if not (math.isfinite(a) and math.isfinite(b)):
        return None, None, f"{what}: not a finite number (route {a}, reference {b}): a run that stopped?"
    if b == 0:
        return None, a - b, f"{what}: the reference is 0, the difference is absolute"
    return (a - b) / b, a - b, None


def compare(results: dict, reference: str | None = None, damping=0.05) -> dict:
    """Differences of every route in ``results`` ({route: RouteResult}) to ``reference``
    (default: the most exact route present, ``orchestrator.routes.default_reference``:
    timefreq, else monolithic, else cosim, else the first with uplift). Returns strict-JSON-able
    {reference, reference_note, damping, routes: {route: metrics}, differences: {route:
    {max_uplift, max_rotation (relative), spectrum_peaks {node: {dir: relative}},
    max_spectrum_peak, wall_ratio, absolute {max_uplift_m, max_rotation_rad}, missing {key: why
    the value of key is None}}}}. Max uplift is not compared when the route or the reference
    lets no uplift happen (linear: raft bonded)."""
    if not results:
        raise ValueError("compare needs at least one route")
    ref = reference or default_reference(results)
    if ref not in results:
        raise ValueError(f"reference route {ref!r} is not among the results ({', '.join(results)})")
    note = ("given" if reference else
            "the most exact route present: timefreq, else monolithic, else cosim, else the first with uplift")
    if not has_uplift(ref):
        note += f"; {ref} lets no uplift happen: max uplift is not compared against it"
    metrics = {r: route_metrics(res, damping) for r, res in results.items()}
    m0 = metrics[ref]
    diffs = {}
    for r, m in metrics.items():
        if r == ref:
            continue
        d, absolute, missing = {}, {}, {}
        for key, metric, unit in QUANTITIES:
            d[key], absolute[metric], why = _difference(m[metric], m0[metric], f"{metric} ({unit})")
            if why:
                missing[key] = why
        for who in (r, ref):
            if not has_uplift(who):          # a bonded route's "uplift" is no uplift: nothing to compare
                d["max_uplift"] = absolute["max_uplift_m"] = None
                missing["max_uplift"] = f"{who} lets no uplift happen (raft bonded): its max uplift is not compared"
                break
        sp = {}
        for node, dirs in m["spectrum_peaks"].items():
            ref_dirs = m0["spectrum_peaks"].get(node, {})
            sp[node], why = {}, {}
            for ax, v in dirs.items():
                if ax in ref_dirs:
                    sp[node][ax], _, reason = _difference(v, ref_dirs[ax], f"spectrum peak {node} {ax} (m/s2)")
                    if reason:
                        why[ax] = reason
            if why:
                missing[f"spectrum_peaks.{node}"] = "; ".join(why.values())
        flat = [abs(v) for dd in sp.values() for v in dd.values() if v is not None]
        d["spectrum_peaks"] = sp
        d["max_spectrum_peak"] = max(flat) if flat else None
        if not flat:
            missing["max_spectrum_peak"] = "no floor-spectrum peak both routes have (and that is relative)"
        ratio = _difference(m["wall_s"], m0["wall_s"], "wall (s)")[0]
        d["wall_ratio"] = None if ratio is None else ratio + 1.0
        if ratio is None:
            missing["wall_ratio"] = "the reference's wall time is 0 or not finite"
        d["absolute"] = absolute
        if missing:
            d["missing"] = missing
        diffs[r] = d
    return dict(reference=ref, reference_note=note, damping=damping, routes=metrics, differences=diffs)


#: how format_table writes an absolute difference: unit, factor from SI, format
ABSOLUTE_FORMAT = {"max_uplift_m": ("mm", 1e3, "{:+.4f} {}"), "max_rotation_rad": ("rad", 1.0, "{:+.2e} {}")}


def format_difference(d: dict | None, key: str, metric: str, percent: str = "%") -> str:
    """One difference of ``compare``'s output as printed: "+1.23%" (``percent`` after the
    number), or the absolute value with its unit where the relative one is missing (a zero
    reference: "+0.1234 mm"), "-" where neither; "reference" for the reference (``d`` None)."""
    if d is None:
        return "reference"
    if d.get(key) is not None:
        return f"{100 * d[key]:+.2f}{percent}"
    value = d.get("absolute", {}).get(metric)
    if value is None:
        return "-"
    unit, factor, fmt = ABSOLUTE_FORMAT[metric]
    return fmt.format(factor * value, unit)


def format_table(cmp: dict) -> str:
    """A printed table of ``compare``'s output: one line per route, then why a difference is
    missing or absolute."""
    ref = cmp["reference"]
    lines = [f"reference: {ref} ({cmp.get('reference_note', 'given')}); differences relative to it (absolute, "
             f"with the unit, where its value is 0); floor spectra at {100 * cmp['damping']:.0f} % damping",
             f"{'route':<16}{'max uplift mm':>14}{'d uplift':>13}{'rotation rad':>14}{'d rot':>13}"
             f"{'max |d SA|':>11}{'wall s':>9}{'conv':>6}"]
    notes = []
    for r, m in cmp["routes"].items():
        d = cmp["differences"].get(r)
        du = format_difference(d, "max_uplift", "max_uplift_m") if d else "-"
        dr = format_difference(d, "max_rotation", "max_rotation_rad") if d else "-"
        ds = "-" if not d or d["max_spectrum_peak"] is None else f"{100 * d['max_spectrum_peak']:.2f}%"
        lines.append(f"{r:<16}{1e3 * m['max_uplift_m']:>14.4f}{du:>13}{m['max_rotation_rad']:>14.4e}"
                     f"{dr:>13}{ds:>11}{m['wall_s']:>9.2f}{'yes' if m['converged'] else 'NO':>6}")
        notes += [f"  {r}: {why}" for key, why in (d or {}).get("missing", {}).items() if key != "wall_ratio"]
    return "\n".join(lines + notes)


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

"""Run time against error: ``uplift bench [--quick] [--json] [--plot FILE]`` and benchmarks/pareto.py.

Each route declares its knobs and their values in the registry (``Route.bench``,
``Route.quick``; orchestrator/routes/); this module runs them.

For each scene (``disk-halfspace`` with a bench tower on it, and ``reactor``) and each route,
the route's accuracy knobs are swept:

=============  ==========================================================================
dt             time step, s ([analysis].dt; the motion is regenerated at that step)
fit_tol        rational-fit tolerance ([analysis].fit_tol; the fit picks its order from it)
element_size   BEM element size, m ([foundation].element_size: the interface mesh itself)
penalty        contact penalty as a factor of "auto" (1 = 1e4 x the soil's local static
               stiffness per node: [contact].auto_factor = factor x AUTO_FACTOR)
pad_s          TF zero padding, s (linear and timefreq; None = the rule of orchestrator.timefreq.grid)
=============  ==========================================================================

Each route's runs are: its reference (every knob at its finest value, the last of its list),
one run per coarser value of each knob with the other knobs at their finest (``kind =
"knob"``: the error that knob alone makes), and a ladder coarsening every knob together
(``kind = "ladder"``: the cheap end of the Pareto front). Errors are relative to the route's own
reference, and each row names it. ``kind = "cross-route"`` rows compare each route's reference
run with the timefreq reference (the BEM table per frequency, no rational fit), and ``kind =
"peer"`` rows run the Winkler route in OpenSeesPy (benchmarks/structure_step.py) next to this
code on the same model.

Errors: relative max uplift, relative max raft rotation sqrt(rx^2 + ry^2), and the largest
relative difference of the 5 %-damped floor-spectrum peaks over output nodes and directions
(orchestrator.compare). ``wall_s`` is the route's own run time (cached BEM sweeps and fits are
loaded, not recomputed; ``total_s`` includes that set-up). The row ``best = True`` is, per
scene and route, the cheapest run reaching ERR_TARGET on max uplift against its reference.
"""
from __future__ import annotations

import copy
import importlib.util
import math
import multiprocessing
import time
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from importlib import resources
from pathlib import Path

import numpy as np

try:
    import tomllib
except ModuleNotFoundError:  # Python < 3.11
    import tomli as tomllib

from structure import Damping, simulate
from structure.contact import AUTO_FACTOR
from structure.damping import fixed_base_modes
from structure.results import RouteResult
from uplift_common.files import save_figure

from orchestrator.compare import compare
from orchestrator.impedance import scene_impedance
from orchestrator.motion import make_motion
from orchestrator.plots import pyplot
from orchestrator.routes import default_reference, get_route, route_names
from orchestrator.routes.base import SCENE_KNOBS
from orchestrator.routes.winkler import winkler_soil
from orchestrator.run import run_scene
from orchestrator.scene import scene_from_dict

ERR_TARGET = 0.01

#: the disk-halfspace built-in has no structure: the bench puts a 20 m stick tower on it
#: (first mode on the soil 3.8 Hz, a third of the raft lifts at 0.25 g), meshed at 2 m (the
#: built-in's 1 m mesh has 314 nodes; the element-size sweep shows what 2 m costs), with 1 %
#: hysteretic damping in the half-space (DISK_DAMPING): on the undamped gap table the passivity
#: enforcement of the rational fit takes minutes and gigabytes (see the bench report)
DISK_TOWER = {
    "structure": {
        "nodes": [{"id": 1, "xyz": [0, 0, 0]}, {"id": 2, "xyz": [0, 0, 10], "name": "mid"},
                  {"id": 3, "xyz": [0, 0, 20], "name": "top"}],
        "beams": [{"nodes": [1, 2], "E": 3e10, "G": 1.25e10, "A": 20.0, "Asy": 10.0, "Asz": 10.0,
                   "Iy": 300.0, "Iz": 300.0, "J": 600.0},
                  {"nodes": [2, 3], "E": 3e10, "G": 1.25e10, "A": 20.0, "Asy": 10.0, "Asz": 10.0,
                   "Iy": 300.0, "Iz": 300.0, "J": 600.0}],
        "masses": [{"node": 2, "m": 1.5e6, "inertia": [0, 0, 0]}, {"node": 3, "m": 3.0e6, "inertia": [0, 0, 0]}],
        "raft": {"node": 1, "m": 2.0e6, "inertia": [5e7, 5e7, 1e8]},
        "damping": {"modal": 0.05},
    },
    "contact": {"enabled": True, "penalty": "auto"},
    "motion": {"kind": "synthetic", "pga_g": 0.25, "duration_s": 5.0, "seed": 3, "direction": "x"},
    "analysis": {"dt": 0.005, "fit_tol": 0.02},
    "output": {"nodes": ["top", "mid"]},
}
DISK_ELEMENT = 2.0
DISK_DAMPING = 0.01

#: the OpenSeesPy peer's time steps per scene (kind = "peer" rows; --quick: the disk only)
PEER_DTS = {"disk-halfspace": (0.01, 0.005, 0.0025), "reactor": (0.01, 0.005, 0.0025)}
PEER_DTS_QUICK = {"disk-halfspace": (0.01, 0.005)}


def bench_config(quick: bool = False) -> dict:
    """{scene: {route: {knob: values}}} of every registered route's bench knobs (``Route.bench``,
    or ``Route.quick`` with --quick), plus the OpenSeesPy peer ("opensees")."""
    config = {}
    for name in route_names():
        route = get_route(name)
        for scene, knobs in (route.quick if quick else route.bench).items():
            config.setdefault(scene, {})[name] = {k: list(v) for k, v in knobs.items()}
    for scene, dts in (PEER_DTS_QUICK if quick else PEER_DTS).items():
        if scene in config:
            config[scene]["opensees"] = {"dt": list(dts)}
    return config


ROW_KEYS = ("route", "knobs", "wall_s", "err_max_uplift", "err_rotation", "err_spectra")


def scene_data(name: str) -> dict:
    """The parsed TOML of a built-in scene; the disk gets the bench tower (DISK_TOWER)."""
    data = tomllib.loads((resources.files("orchestrator.scenes") / f"{name}.toml").read_text())
    if name == "disk-halfspace":
        data.update(copy.deepcopy(DISK_TOWER))
        data["foundation"]["element_size"] = DISK_ELEMENT
        data["soil"]["halfspace"]["damping"] = DISK_DAMPING
    return data


def knob_scene(data: dict, name: str, knobs: dict):
    """The scene ``data`` with the scene knobs dt, fit_tol, element_size and penalty applied."""
    data = copy.deepcopy(data)
    for key, section in (("dt", "analysis"), ("fit_tol", "analysis"), ("element_size", "foundation")):
        if knobs.get(key) is not None:
            data.setdefault(section, {})[key] = knobs[key]
    if knobs.get("penalty") is not None:
        data.setdefault("contact", {})["auto_factor"] = float(knobs["penalty"]) * AUTO_FACTOR
    return scene_from_dict(data, base_dir=Path(str(resources.files("orchestrator.scenes"))), name=name)


def run_route(data: dict, name: str, route: str, knobs: dict, cache_dir=None):
    """RouteResult of one route of the scene with the knobs applied (scene knobs on the scene,
    the others as route options); ``total_s`` (with the sweep and fit set-up) in its info."""
    t0 = time.perf_counter()
    scene = knob_scene(data, name, knobs)
    options = {k: v for k, v in knobs.items() if k not in SCENE_KNOBS}
    res = run_scene(scene, [route], cache_dir=cache_dir, options={route: options})[0][route]
    return res.with_notes(info={"total_s": time.perf_counter() - t0})


def plan(knob_values: dict) -> list:
    """[(kind, knobs)]: the reference, one-knob variations, then the ladder (deduplicated)."""
    ref = {k: v[-1] for k, v in knob_values.items()}
    runs = [("reference", ref)]
    for k, values in knob_values.items():
        runs += [("knob", dict(ref, **{k: v})) for v in values[:-1]]
    depth = max(len(v) for v in knob_values.values())
    runs += [("ladder", {k: v[max(0, len(v) - 1 - j)] for k, v in knob_values.items()}) for j in range(1, depth)]
    seen, out = set(), []
    for kind, knobs in runs:
        key = tuple(sorted(knobs.items()))
        if key not in seen:
            seen.add(key)
            out.append((kind, knobs))
    return out


def errors(res, ref) -> dict:
    """Relative errors of RouteResult ``res`` against ``ref`` (None where undefined: no uplift
    in the reference, no floor spectra)."""
    c = compare({"reference": ref, "run": res}, reference="reference")
    m, m0, d = c["routes"]["run"], c["routes"]["reference"], c["differences"]["run"]
    has_spectra = any(m["spectrum_peaks"].values()) and any(m0["spectrum_peaks"].values())
    return {"err_max_uplift": abs(d["max_uplift"]) if m0["max_uplift_m"] > 0 else None,
            "err_rotation": abs(d["max_rotation"]) if m0["max_rotation_rad"] > 0 else None,
            "err_spectra": d["max_spectrum_peak"] if has_spectra else None,
            "max_uplift_m": m["max_uplift_m"], "max_rotation_rad": m["max_rotation_rad"]}


def _fmt_knobs(knobs: dict) -> str:
    return ", ".join(f"{k}={'rule' if v is None else f'{v:g}'}" for k, v in knobs.items())


def _row(scene, route, kind, knobs, res, ref, ref_label) -> dict:
    row = {"scene": scene, "route": route, "kind": kind, "knobs": dict(knobs), "reference": ref_label,
           "wall_s": float(res.wall_s), "total_s": float(res.info.get("total_s", res.wall_s)),
           "converged": bool(res.converged)}
    row.update(errors(res, ref))
    if not res.converged:
        row["note"] = res.message
    return row


def route_rows(data, scene, route, knob_values, cache_dir=None, log=None, keep=None):
    """Rows of one route's sweep; ``keep`` (dict) receives the reference RouteResult."""
    runs = plan(knob_values)
    label = f"{route} at its finest knobs ({_fmt_knobs(runs[0][1])})"
    results, failed = [], []
    for kind, knobs in runs:
        try:
            res = run_route(data, scene, route, knobs, cache_dir)
        except (ValueError, RuntimeError, ArithmeticError, MemoryError) as exc:
            # a run that cannot be made (bad fit, out of memory) is a row, not the end of the bench
            failed.append({"scene": scene, "route": route, "kind": kind, "knobs": dict(knobs), "reference": label,
                           "wall_s": None, "total_s": None, "err_max_uplift": None, "err_rotation": None,
                           "err_spectra": None, "converged": False,
                           "note": f"failed: {type(exc).__name__}: {str(exc)[:200]}"})
            if log:
                log(f"{scene} {route} [{_fmt_knobs(knobs)}]: {failed[-1]['note']}")
            if kind == "reference":
                return failed
            continue
        results.append((kind, knobs, res))
        if log:
            log(f"{scene} {route} [{_fmt_knobs(knobs)}]: {res.wall_s:.2f} s, max uplift "
                f"{1e3 * res.max_uplift():.4f} mm" + ("" if res.converged else f", STOPPED: {res.message}"))
    ref = results[0][2]
    if keep is not None:
        keep[route] = (runs[0][1], ref)
    return [_row(scene, route, kind, knobs, res, ref, label) for kind, knobs, res in results] + failed


#: the peer's module (optional dependency: the [bench] extra), imported in the peer's process only
PEER_MODULE = "openseespy.opensees"


def _peer_loads(module: str) -> None:
    """In the peer's process: import ``module``; ImportError when it is absent, RuntimeError
    (openseespy) when it is installed but cannot load its BLAS/LAPACK."""
    importlib.import_module(module)


def _opensees_peer(path: str, *args):
    """In the peer's process: benchmarks/structure_step.py's ``run_opensees(*args)``."""
    spec = importlib.util.spec_from_file_location("_uplift_structure_step", path)
    peer = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(peer)
    return peer.run_opensees(*args)


def opensees_rows(data, scene, dts, cache_dir=None, log=None):
    """The Winkler route in OpenSeesPy next to this code, on the scene's model and Winkler springs
    with dashpots (the damping both codes can express: C = a1 K_beams, 7 % at the first
    fixed-base mode, as benchmarks/structure_step.py). Rows: OpenSeesPy against its own finest
    dt, and against this code's run at the same dt.

    OpenSeesPy runs in a child process of its own: it brings its own libgomp, libgfortran and
    LAPACK, and its clean-up at exit has aborted a process that had numpy's, scipy's and the
    FMUs' libraries loaded beside it (glibc: "corrupted double-linked list")."""
    def skipped(why):
        return [{"scene": scene, "route": "opensees", "kind": "peer", "knobs": {"dt": dt}, "reference": "-",
                 "wall_s": None, "total_s": None, "err_max_uplift": None, "err_rotation": None,
                 "err_spectra": None, "note": f"skipped: {why}"} for dt in dts]

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "structure_step.py"
    if not path.is_file():
        return skipped(f"{path} not found (the peer runs from a source checkout)")
    data = copy.deepcopy(data)
    data["soil"]["winkler"] = {"springs": "rigid", "match": "rocking", "damping": "dashpots"}
    runs = []
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as child:
        try:
            child.submit(_peer_loads, PEER_MODULE).result()
        except (ImportError, RuntimeError, BrokenProcessPool) as exc:
            return skipped(f"openseespy not installed or cannot load ({exc}): pip install -e \".[bench]\"; "
                           "apt-get install libblas3 liblapack3")
        for dt in dts:
            sc = knob_scene(data, scene, {"dt": dt})
            model = sc.model()
            rigid = scene_impedance(sc, ("rigid",), cache_dir=cache_dir)["rigid"]
            soil, _, _ = winkler_soil(sc, model, rigid, cache_dir)
            a1 = 2 * 0.07 / (2 * np.pi * fixed_base_modes(model).freq[0])
            ag = make_motion(sc.motion, dt).acc
            ours = simulate(model, soil, ag, dt, contact=sc.contact, damping=Damping("rayleigh", a1=a1),
                            route="winkler-dashpots")
            try:
                wall, ry, gap = child.submit(_opensees_peer, str(path), model, soil, ours.info["penalty"],
                                             ag, dt, a1).result()
            except BrokenProcessPool as exc:         # OpenSees ended its process: no rows to compare
                return skipped(f"OpenSeesPy's process ended at dt = {dt:g} ({exc})")
            raft = np.zeros((ry.size, 6))
            raft[:, 4] = ry
            ops = RouteResult(route="opensees", time=ours.time, raft=raft, gap=gap, wall_s=wall, xy=ours.xy)
            # the peer gives ry only: compare like with like
            ours_ry = ours.replace(raft=np.where(np.arange(6) == 4, ours.raft, 0.0), acc={})
            runs.append((dt, ops, ours_ry))
            if log:
                log(f"{scene} opensees [dt={dt:g}]: {wall:.2f} s (this code {ours.wall_s:.2f} s), "
                    f"max uplift {1e3 * gap.max():.4f} mm")
    rows = []
    label = f"opensees at its finest knobs (dt={dts[-1]:g})"
    for dt, ops, ours in runs:
        rows.append(_row(scene, "opensees", "reference" if dt == dts[-1] else "knob", {"dt": dt}, ops,
                         runs[-1][1], label))
        peer_row = _row(scene, "opensees", "peer", {"dt": dt}, ops, ours,
                        f"this code, same model and dt (winkler springs + dashpots, C = a1 K_beams; "
                        f"{ours.wall_s:.2f} s)")
        peer_row["wall_ratio"] = ops.wall_s / ours.wall_s
        rows.append(peer_row)
    return rows


def bench(config: dict, cache_dir=None, log=None) -> list:
    """Rows for every scene and route of ``config`` ({scene: {route: {knob: values}}}). Every dt
    runs the same accelerogram (synthetic records do not depend on the analysis step)."""
    rows = []
    for scene, routes in config.items():
        data = scene_data(scene)
        refs = {}
        for route, knob_values in routes.items():
            if route == "opensees":
                rows += opensees_rows(data, scene, knob_values["dt"], cache_dir, log)
            else:
                rows += route_rows(data, scene, route, knob_values, cache_dir, log, keep=refs)
        ref_route = default_reference(refs) if refs else None
        if ref_route is not None and get_route(ref_route).reference_rank > 0:
            ref_knobs, ref = refs[ref_route]
            label = f"{ref_route} at its finest knobs ({_fmt_knobs(ref_knobs)}): cross-route reference"
            for route, (knobs, res) in refs.items():
                if route != ref_route:
                    rows.append(_row(scene, route, "cross-route", knobs, res, ref, label))
    mark_best(rows)
    return rows


def mark_best(rows, target=ERR_TARGET):
    """Set ``best`` on the cheapest run per (scene, route) reaching ``target`` on max uplift
    against its own reference (the reference itself excluded: its error is zero by definition)."""
    groups = {}
    for r in rows:
        r["best"] = False
        if r["kind"] in ("knob", "ladder") and r["err_max_uplift"] is not None and r["err_max_uplift"] <= target:
            groups.setdefault((r["scene"], r["route"]), []).append(r)
    for group in groups.values():
        min(group, key=lambda r: r["wall_s"])["best"] = True
    return rows


def _pct(v):
    return "-" if v is None else f"{100 * v:.3f}"


def format_rows(rows) -> str:
    """The printed table: per scene and route, own-reference rows, then the cross-route and peer rows."""
    hdr = (f"{'scene':<15}{'route':<11}{'kind':<12}{'knobs':<52}{'wall s':>8}{'uplift mm':>11}"
           f"{'err upl %':>11}{'err rot %':>11}{'err SA %':>10}")
    lines = [f"errors relative to each row's reference (listed below each group); "
             f"* = cheapest run reaching {100 * ERR_TARGET:g} % on max uplift", hdr, "-" * len(hdr)]
    last = None
    for r in rows:
        group = (r["scene"], r["route"], r["reference"])
        if last is not None and group != last:
            lines.append(f"{'':<26}reference: {last[2]}")
        last = group
        uplift = "-" if r.get("max_uplift_m") is None else f"{1e3 * r['max_uplift_m']:.4f}"
        wall = "-" if r["wall_s"] is None else f"{r['wall_s']:.2f}"
        mark = "*" if r.get("best") else " "
        note = f"  {r['note']}" if r.get("note") else ""
        if r.get("wall_ratio"):
            note += f"  (wall x{r['wall_ratio']:.1f})"
        lines.append(f"{r['scene']:<15}{r['route']:<11}{r['kind']:<12}{_fmt_knobs(r['knobs']):<52}{wall:>8}"
                     f"{uplift:>11}{_pct(r['err_max_uplift']):>10}{mark}{_pct(r['err_rotation']):>11}"
                     f"{_pct(r['err_spectra']):>10}{note}")
    if last is not None:
        lines.append(f"{'':<26}reference: {last[2]}")
    lines.append("")
    lines += summary_lines(rows)
    return "\n".join(lines)


def summary_lines(rows) -> list:
    """Per scene and route: the cheapest knobs reaching the target on max uplift, or why none."""
    out = [f"cheapest knobs reaching {100 * ERR_TARGET:g} % on max uplift (against the route's own reference):"]
    seen = []
    for r in rows:
        if r["kind"] in ("reference", "knob", "ladder") and (r["scene"], r["route"]) not in seen:
            seen.append((r["scene"], r["route"]))
    for scene, route in seen:
        best = [r for r in rows if r["scene"] == scene and r["route"] == route and r.get("best")]
        ref = next(r for r in rows if r["scene"] == scene and r["route"] == route and r["kind"] == "reference")
        if best:
            b = best[0]
            text = (f"{_fmt_knobs(b['knobs'])}: {b['wall_s']:.2f} s, error {_pct(b['err_max_uplift'])} % "
                    f"(reference {ref['wall_s']:.2f} s)")
        elif ref["err_max_uplift"] is None and ref.get("max_uplift_m") == 0:
            text = "no uplift in this route (bonded raft): judged on rotation and spectra only"
        elif ref["wall_s"] is None:
            text = ref.get("note", "not run")
        else:
            text = "only the finest run itself: no coarser run within the target"
        out.append(f"  {scene:<15}{route:<11}{text}")
    return out


def plot_rows(rows, path):
    """Wall time against error (log-log), one panel per scene and error measure, one series per route."""
    plt = pyplot()
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    measures = (("err_max_uplift", "max uplift"), ("err_rotation", "raft rotation"), ("err_spectra", "floor-spectrum peak"))
    fig, axes = plt.subplots(len(scenes), 3, figsize=(15, 4.5 * len(scenes)), squeeze=False, constrained_layout=True)
    routes = list(dict.fromkeys(r["route"] for r in rows))
    for i, scene in enumerate(scenes):
        for j, (key, label) in enumerate(measures):
            ax = axes[i, j]
            for k, route in enumerate(routes):
                pts = [(r[key], r["wall_s"]) for r in rows if r["scene"] == scene and r["route"] == route
                       and r["kind"] in ("knob", "ladder") and r[key] and r["wall_s"]]
                if pts:
                    e, w = np.array(pts).T
                    ax.loglog(e, w, "o", color=f"C{k}", label=route)
                    best = [(r[key], r["wall_s"]) for r in rows if r["scene"] == scene and r["route"] == route
                            and r.get("best") and r[key]]
                    if best and key == "err_max_uplift":
                        ax.loglog(*best[0], "*", ms=16, color=f"C{k}", mec="k")
            ax.axvline(ERR_TARGET, color="k", ls=":", lw=1)
            ax.set_xlabel(f"relative error, {label} (vs the route's own finest run)")
            ax.set_ylabel("wall time (s)")
            ax.set_title(f"{scene}: {label}")
            ax.grid(True, which="both", alpha=0.3)
            if ax.get_legend_handles_labels()[0]:
                ax.legend(fontsize=8)
    save_figure(fig, path, dpi=110)           # atomically (a full disk: OutputWriteError)
    plt.close(fig)
    return Path(path)


def json_safe(v):
    if isinstance(v, dict):
        return {k: json_safe(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [json_safe(x) for x in v]
    if isinstance(v, (float, np.floating)):
        return float(v) if math.isfinite(v) else None
    if isinstance(v, (np.integer, np.bool_)):
        return v.item()
    return v

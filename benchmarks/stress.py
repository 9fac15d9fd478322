"""Numerical stability stress tests: each case stays stable and accurate, or is refused
with a clear message; the energy balance is tracked in each.

Scene: a 20 m tower (3e6 kg) on a 10 m x 10 m rigid raft, 16 interface nodes, on a half-space
(Vs 500 m/s, 3 % damping), BEM gap table 0-20 Hz; synthetic RG1.60 motion (x), 0.5 g, 5 s,
dt = 5 ms; routes ``winkler`` (spring mattress) and ``monolithic`` (BEM impedance as a passive
rational model run by the recursive convolution). Each case changes one thing (``CASES``).
The last three rows run the built-in reactor scene (241 nodes; its BEM sweep and fit are cached
in $UPLIFT_CACHE or ~/.cache/uplift: the first run sweeps for minutes).

Columns, per case and route:

outcome   "stable" (ran to the end, finite, energy balanced, within ACCURACY_TOL of its reference
          if it has one; else "inaccurate: ..."), "stopped: ..." (Newton failure,
          the stepper's ConvergenceError), "refused: ..." (bad input refused before stepping),
          "unstable" (non-finite or energy created: balance error > BALANCE_TOL or soil work < 0)
balance   energy-balance error, ``RouteResult.energy_balance_error``: max_t |W_input − (kinetic + strain + damping
          work + soil work + contact work)| / max_t |W_input| (the stepper's cumulative works;
          soil and contact works include their stored energy). Average-acceleration Newmark
          balances it to round-off.
soil_min  min_t (soil work) / max_t |W_input|: < 0 means the soil model gave energy (non-passive)
late      max |raft rocking| over the last 10 % of the run / its peak: the 200 s run must have
          come back to rest (no growth); a short run ends while the raft still rocks
residual  |raft rocking at the end| / its peak (drift: should be ~0 after the motion)
uplift    max uplift (mm); ``vs ref`` its relative change against the case's reference
          (dt 10/20 ms against dt 5 ms; penalty x1000 against the same numeric penalty x1)
n/T1      steps per period of the first soil-structure mode (rocking-matched Winkler springs on
          the BEM K(0), as the winkler route computes it): the time-step resolution
wall      route wall time (s)

    OPENBLAS_NUM_THREADS=1 python benchmarks/stress.py [--quick] [--case NAME ...] [--plot out.png]

``--quick`` runs the short versions that tests/structural/test_stress.py asserts on.

Measured (2 loaded cores, full run ~3 min): every small-scene case is "stable" on both routes,
balance 1e-14..1e-10 (7e-10 with penalty x1000), soil work never negative; 200 s: back at rest
(late 0.000, residual rocking 4e-5 / 5e-6 of the peak); dt 10 / 20 ms vs 5 ms on the same
record: max uplift -0.0 % / -0.5 % (winkler), +0.2 % / +2.9 % (monolithic); penalty x1000:
+0.0 %; PGA 2 g: 156 / 577 mm uplift, completed (the Winkler route's RCC-G modal damping keeps
acting on the lifted raft: with detaching dashpots, damping = "dashpots", it gives 588 mm; the
route warns beyond 60 % of the nodes lifted). The non-passive model is refused by default
(FitError naming the violation band and the fix); forced through, it runs but the soil work goes
negative (-1.2 % of the input): "unstable". Reactor: 2 g stable (65 / 421 mm); dt 20 ms
(12.7 steps per period of the 3.9 Hz mode) within 1 %; dt 50 ms (5.1 steps) gave +12 % (winkler) /
+104 % (monolithic) max uplift: it is now refused (run.check_time_step: at least 10 steps).
"""
from __future__ import annotations

import argparse
import copy
import os
import time
import warnings
from dataclasses import dataclass, field

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

#: a stable run balances energy to round-off (measured ~1e-12); above this it is "unstable"
BALANCE_TOL = 1e-6
#: a stable run whose max uplift is further than this from its reference is "inaccurate"
ACCURACY_TOL = 0.05

TOWER = {"nodes": [{"id": 1, "xyz": [0, 0, 0]}, {"id": 2, "xyz": [0, 0, 20], "name": "top"}],
         "beams": [{"nodes": [1, 2], "E": 3e10, "G": 1.25e10, "A": 10.0, "Iy": 20.0, "Iz": 20.0, "J": 40.0}],
         "masses": [{"node": 2, "m": 2.0e6, "inertia": [0, 0, 0]}],
         "raft": {"node": 1, "m": 1.0e6, "inertia": [1e7, 1e7, 2e7]},
         "damping": {"modal": 0.05}}

BASE = {
    "soil": {"halfspace": {"vs": 500.0, "nu": 0.3, "rho": 2000.0, "damping": 0.03}},
    "foundation": {"shape": "rectangle", "lx": 10.0, "ly": 10.0, "element_size": 2.5},
    "impedance": {"range_hz": [0.0, 20.0, 11]},
    "structure": TOWER,
    "contact": {"enabled": True},
    "motion": {"kind": "synthetic", "pga_g": 0.5, "duration_s": 5.0, "seed": 2},
    "analysis": {"routes": ["winkler", "monolithic"], "dt": 0.005, "fit_tol": 0.05},
    "output": {"nodes": ["top"]},
}


#: the short version of a case (unless it gives its own): 3 s of motion instead of 5 s
QUICK = {"motion": {"duration_s": 3.0}}


@dataclass
class Case:
    """One stress case: ``changes`` are merged into BASE (nested dicts); ``quick`` replaces them
    for the short version (default: changes + QUICK). ``reference``: "dt" (same scene at dt = 5 ms) or "penalty" (x1)."""
    name: str
    changes: dict = field(default_factory=dict)
    quick: dict | None = None
    reference: str | None = None
    penalty_factor: float = 1.0
    nonpassive: str | None = None        # "default" (refused) or "force" (run anyway)
    base: str = "small"                  # "small" (BASE) or "reactor" (the built-in scene, cached sweep)


#: the non-passive cases: weak shaking (the raft rocks on the soil, no uplift, at the
#: frequency where the model's damping is made negative), monolithic route only
NONPASSIVE = {"motion": {"pga_g": 0.1, "duration_s": 10.0}, "analysis": {"routes": ["monolithic"]}}

CASES = [
    Case("baseline 0.5 g"),
    Case("200 s motion", {"motion": {"duration_s": 200.0}},
         quick={"motion": {"duration_s": 60.0}, "analysis": {"dt": 0.01, "routes": ["winkler"]}}),
    Case("PGA 1 g", {"motion": {"pga_g": 1.0}}),
    Case("PGA 2 g", {"motion": {"pga_g": 2.0}}),
    Case("dt 10 ms", {"analysis": {"dt": 0.01}}, reference="dt"),
    Case("dt 20 ms", {"analysis": {"dt": 0.02}}, reference="dt"),
    Case("stiff soil Vs 5000", {"soil": {"halfspace": {"vs": 5000.0}}}),
    Case("soft soil Vs 120", {"soil": {"halfspace": {"vs": 120.0}}, "analysis": {"fit_tol": 0.1}}),
    Case("penalty x1000", reference="penalty", penalty_factor=1000.0),
    Case("no structural damping", {"structure": {"damping": {"modal": 0.0}}}),
    Case("undamped soil", {"soil": {"halfspace": {"damping": 0.0}}}),
    Case("undamped soil and structure", {"soil": {"halfspace": {"damping": 0.0}},
                                         "structure": {"damping": {"modal": 0.0}}}),
    Case("non-passive fit", NONPASSIVE, NONPASSIVE, nonpassive="default"),
    Case("non-passive fit forced", NONPASSIVE, NONPASSIVE, nonpassive="force"),
    Case("reactor PGA 2 g", {"motion": {"pga_g": 2.0}}, base="reactor"),
    Case("reactor dt 20 ms", {"analysis": {"dt": 0.02}}, reference="dt", base="reactor"),
    Case("reactor dt 50 ms", {"analysis": {"dt": 0.05}}, reference="dt", base="reactor"),
]


def _base(case: Case) -> dict:
    if case.base == "small":
        return BASE
    import tomllib
    from importlib import resources
    data = tomllib.loads((resources.files("orchestrator.scenes") / f"{case.base}.toml").read_text())
    data["analysis"]["routes"] = ["winkler", "monolithic"]
    return data


def _cache(case: Case):
    """The user's impedance/fit cache for the reactor (its sweep takes minutes); none for the
    small scene (fast, and the tests must not write into the user's cache)."""
    if case.base == "small":
        return None
    from orchestrator.settings import default_cache_dir
    return default_cache_dir()


def _merge(base: dict, changes: dict) -> dict:
    out = copy.deepcopy(base)
    for k, v in changes.items():
        out[k] = _merge(out.get(k, {}), v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def case_scene(case: Case, quick: bool = False, motion: dict | None = None, **extra):
    """The case's Scene (quick: its short version); ``extra`` changes merged last; ``motion``
    replaces the [motion] table."""
    from orchestrator.scene import scene_from_dict
    changes = case.changes if not quick else case.quick if case.quick is not None else _merge(case.changes, QUICK)
    data = _merge(_merge(_base(case), changes), extra)
    if motion is not None:
        data["motion"] = motion
    return scene_from_dict(data, name=case.name)


# ---- measures (one definition each) ------------------------------------------------------------
def soil_work_min(res) -> float:
    """min_t W_soil / max_t |W_input| (< 0: the soil model gave energy)."""
    return float(res.energy["soil"].min() / max(np.abs(res.energy["input"]).max(), 1e-300))


def rocking(res) -> np.ndarray:
    return np.hypot(res.raft[:, 3], res.raft[:, 4])


def late(res) -> float:
    """max |raft rocking| over the last 10 % of the run / its peak."""
    r = rocking(res)
    return float(r[res.time >= 0.9 * res.time[-1]].max() / max(r.max(), 1e-300))


def residual(res) -> float:
    r = rocking(res)
    return float(r[-1] / max(r.max(), 1e-300))


def outcome(res) -> str:
    finite = all(np.all(np.isfinite(a)) for a in (res.raft, res.gap, *res.energy.values()))
    if not finite:
        return "unstable"
    if not res.converged:
        return "stopped: " + res.message
    if res.energy_balance_error() > BALANCE_TOL or soil_work_min(res) < -BALANCE_TOL:
        return "unstable"
    return "stable"


# ---- a non-passive soil model ----------------------------------------------------------------
def with_negative_damping(model, f0_hz: float, shape, zeta: float = 0.05, depth: float = 3.0):
    """``model`` plus α ω0²/(s² + 2ζω0 s + ω0²) v vᵀ (v = shape / |shape|): a negative damping peak
    at f0 of ``depth`` × vᵀ Im K(f0) v (width ~ζ f0), what a bad fit can do near a resonance."""
    from soil_impedance.rational import RationalModel
    w0 = 2 * np.pi * f0_hz
    v = np.asarray(shape, float) / np.linalg.norm(shape)
    alpha = depth * (v @ model.frequency_response([f0_hz])[0].imag @ v) * 2 * zeta
    p = -zeta * w0 + 1j * w0 * np.sqrt(1 - zeta ** 2)
    r = alpha * w0 ** 2 / (p - np.conj(p))
    V = np.outer(v, v)
    return RationalModel(np.concatenate([model.poles, [p, np.conj(p)]]),
                         np.concatenate([model.residues, [r * V, np.conj(r) * V]]),
                         model.D, model.E, model.dofs, dict(model.provenance, passive=False))


def rocking_shape(scene) -> np.ndarray:
    """(6+N,) the soil's vertical displacements under a raft rotation about y (w_i = -x_i)."""
    return np.concatenate([np.zeros(6), -scene.mesh.xy[:, 0]])


def _first_mode_hz(scene, table_rigid) -> float:
    from orchestrator.routes.winkler import winkler_soil
    return float(winkler_soil(scene, scene.model(), table=table_rigid)[2]["first_soil_structure_hz"])


# ---- running a case --------------------------------------------------------------------------
def _penalty(scene, tables) -> float:
    """A numeric per-node penalty: "auto" (AUTO_FACTOR × the soil's local static vertical
    stiffness) averaged over the nodes of the BEM gap table."""
    from structure.contact import AUTO_FACTOR
    K0 = np.real(tables["gap"].matrices[0])
    return float(AUTO_FACTOR * np.mean(np.diag(K0)[6:]))


def _run(scene, routes, cache_dir=None, soil_model=None, soil_kwargs=None):
    """{route: RouteResult or refusal str} for a scene (the soil model given or fitted)."""
    from orchestrator.exit_codes import USER_INPUT
    from orchestrator.routes.monolithic import run_monolithic
    from orchestrator.run import run_scene
    out = {}
    for route in routes:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")        # fit tolerance notes, forced passivity
                if soil_model is not None:
                    res = run_monolithic(scene, soil_model=soil_model, soil_kwargs=soil_kwargs)
                else:
                    res = run_scene(scene, [route], cache_dir=cache_dir)[0][route]
            out[route] = f"refused: {res.message}" if res.status.value == "refused" else res
        except USER_INPUT as exc:
            out[route] = f"refused: {type(exc).__name__}: {exc}"
    return out


def run_case(case: Case, quick: bool = False) -> list[dict]:
    """One row per route: case, route, outcome, balance, soil_min, late, residual, uplift_mm,
    vs_ref, wall_s (None where it does not apply), result (RouteResult or None)."""
    from orchestrator.impedance import scene_impedance

    scene = case_scene(case, quick)
    routes, dt = scene.analysis.routes, scene.analysis.dt   # the synthetic record does not depend on dt
    cache = _cache(case)
    tables = scene_impedance(scene, ("gap", "rigid"), cache_dir=cache)
    f1 = _first_mode_hz(scene, tables["rigid"])
    soil_model = soil_kwargs = None
    extra = {}
    if case.reference == "penalty":
        extra = {"contact": {"penalty": _penalty(scene, tables)}}
        scene = case_scene(case, quick, contact={"penalty": case.penalty_factor * extra["contact"]["penalty"]})
    if case.nonpassive:
        from orchestrator.impedance import scene_fit
        good = scene_fit(scene, table=tables["gap"]).model
        soil_model = with_negative_damping(good, f1, rocking_shape(scene))
        soil_kwargs = {"force": case.nonpassive == "force"}
    t0 = time.perf_counter()
    results = _run(scene, routes, cache, soil_model, soil_kwargs)
    refs = {}
    if case.reference == "dt":
        refs = _run(case_scene(case, quick, analysis={"dt": 0.005}), routes, cache)
    elif case.reference == "penalty":
        refs = _run(case_scene(case, quick, **extra), routes, cache)
    rows = []
    for route, res in results.items():
        row = dict(case=case.name, route=route, outcome=res if isinstance(res, str) else outcome(res),
                   steps=1 / (f1 * dt), balance=None, soil_min=None, late=None, residual=None, uplift_mm=None, vs_ref=None,
                   wall_s=time.perf_counter() - t0 if isinstance(res, str) else res.wall_s, result=None)
        if not isinstance(res, str):
            row.update(balance=res.energy_balance_error(), soil_min=soil_work_min(res), uplift_mm=1e3 * res.max_uplift(),
                       result=res)
            if np.all(np.isfinite(res.raft)) and res.nt > 1:
                row.update(late=late(res), residual=residual(res))
            ref = refs.get(route)
            if ref is not None and not isinstance(ref, str) and ref.max_uplift() > 0:
                row["vs_ref"] = res.max_uplift() / ref.max_uplift() - 1
                row["reference"] = ref
                if row["outcome"] == "stable" and abs(row["vs_ref"]) > ACCURACY_TOL:
                    row["outcome"] = f"inaccurate: max uplift {row['vs_ref']:+.1%} vs its reference"
        rows.append(row)
    return rows


def _fmt(v, spec):
    return "-" if v is None else format(v, spec)


def print_table(rows) -> None:
    print(f"{'case':<28} {'route':<11} {'n/T1':>5} {'balance':>8} {'soil_min':>9} {'late':>7} {'residual':>8} "
          f"{'uplift mm':>9} {'vs ref':>7} {'wall s':>7}  outcome")
    for r in rows:
        outc = r["outcome"] if len(r["outcome"]) < 150 else r["outcome"][:147] + "..."
        print(f"{r['case']:<28} {r['route']:<11} {r['steps']:5.1f} {_fmt(r['balance'], '8.1e')} {_fmt(r['soil_min'], '9.1e')} "
              f"{_fmt(r['late'], '7.3f')} {_fmt(r['residual'], '8.1e')} {_fmt(r['uplift_mm'], '9.3f')} "
              f"{_fmt(r['vs_ref'], '+7.1%')} {r['wall_s']:7.2f}  {outc}")


def plot(rows, path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    runs = [r for r in rows if r["result"] is not None]
    fig, axes = plt.subplots(len(runs), 1, figsize=(9, 1.6 * len(runs)), sharex=False, squeeze=False)
    for ax, r in zip(axes[:, 0], runs):
        res = r["result"]
        ax.plot(res.time, 1e3 * rocking(res), lw=0.6)
        ax.set_ylabel("mrad", fontsize=7)
        ax.set_title(f"{r['case']} [{r['route']}]: {r['outcome'][:60]}", fontsize=8)
    axes[-1, 0].set_xlabel("t (s)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    print(f"wrote {path}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="the short versions tests/structural/test_stress.py runs")
    ap.add_argument("--case", action="append", help="run only these cases (by name, repeatable)")
    ap.add_argument("--plot", help="write the raft rocking histories to this PNG")
    args = ap.parse_args(argv)
    cases = [c for c in CASES if not args.case or c.name in args.case]
    rows = []
    for c in cases:
        t = time.perf_counter()
        rows += run_case(c, args.quick)
        print(f"  ({c.name}: {time.perf_counter() - t:.1f} s)", flush=True)
    print_table(rows)
    if args.plot:
        plot(rows, args.plot)
    return rows


if __name__ == "__main__":
    main()

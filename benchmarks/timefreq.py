"""Benchmark: the time-frequency reference route (paper §3) on the reactor scene.

Rows:
  reactor   built-in scene "reactor" (layered rock, R = 20 m, 241 nodes), its synthetic
            RG1.60 motion scaled to --pga (default 0.25 g), 10 s at 5 ms; the BEM "gap" table
            (cached in $UPLIFT_CACHE or ~/.cache/uplift after the first ~10 s sweep).
            Routes: timefreq (Newton-Krylov, BEM table), linear (FD, BEM table), winkler
            (TD, the industrial spring route of run.py); printed with orchestrator.compare.
  --map     convergence map over PGA 0.1 ... 1.0 g: the paper's scheme (rho = 1 and 0.5,
            global and 8-window averages) against Newton-Krylov, on the reactor structure
            with a coarse Winkler raft (21 nodes, frequency-independent K + i w C soil) so
            that the map runs in about a minute; --map-reactor uses the BEM reactor instead.

    python benchmarks/timefreq.py [--pga 0.25] [--map] [--map-reactor]
"""
from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np


def cache_dir():
    env = os.environ.get("UPLIFT_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "uplift"


def reactor(pga):
    from orchestrator.impedance import scene_impedance
    from orchestrator.motion import synthetic_motion
    from orchestrator.run import scene_model
    from orchestrator.scene import load_scene

    scene = load_scene("reactor")
    model = scene_model(scene)
    m = scene.section("motion")
    motion = synthetic_motion(pga_g=pga, duration_s=float(m.get("duration_s", 10.0)), dt=0.005,
                              seed=int(m.get("seed", 1)), spectrum=m.get("spectrum", "RG1.60"),
                              direction=m.get("direction", "x"))
    t0 = time.perf_counter()
    table = scene_impedance(scene, ("gap",), cache_dir=cache_dir())["gap"]
    return scene, model, motion, table, time.perf_counter() - t0


def row_reactor(pga):
    from orchestrator.compare import compare, format_table
    from orchestrator.linear_fd import run_linear
    from orchestrator.run import output_nodes, winkler_soil
    from orchestrator.timefreq import run_timefreq
    from structure import simulate
    from structure.spec import contact_from_spec

    scene, model, motion, table, t_table = reactor(pga)
    print(f"gap table: {table.n_dof} DOFs, {table.frequencies_hz.size} frequencies, {t_table:.1f} s (cache)")
    results = {}
    tf = run_timefreq(scene, motion, model, table)
    results["timefreq"] = tf
    lin = run_linear(scene, motion, model, table)
    results["linear"] = lin
    soil, damping, info = winkler_soil(scene, model, cache_dir())
    results["winkler"] = simulate(model, soil, motion.acc, motion.dt,
                                  contact=contact_from_spec(scene.section("contact")),
                                  damping=damping, output_nodes=output_nodes(scene), route="winkler")
    try:
        results["monolithic"] = _monolithic(scene, model, motion, table)
    except Exception as exc:  # the fit route may not exist yet
        print(f"monolithic route skipped: {exc}")
    h = tf.info
    print(f"\ntimefreq: wall {tf.wall_s:.2f} s (setup {h['setup_s']:.2f} s, solve {h['solve_s']:.2f} s), "
          f"converged {tf.converged}, Newton iterations {h['iterations']}, GMRES {h['gmres_total']}, "
          f"S applications {h['apply_S']}, continuation {h['continuation']}, nfft {h['nfft']} "
          f"(pad {h['pad_s']:.2f} s, rule {h['pad_rule_s']:.2f} s), max open nodes "
          f"{max([x['n_open'] for x in h['history']] or [0])}")
    print(f"linear: wall {lin.wall_s:.2f} s ({lin.info['bonded_solver']}, {lin.info['sweeps']} sweeps)\n")
    cmp = compare(results, "timefreq")
    print(format_table(cmp))
    return cmp


def _monolithic(scene, model, motion, table):
    """TD route with the fitted rational soil, if the project provides a fit."""
    from soil_impedance.fit import fit_table
    from soil_impedance.convolution import RecursiveConvolutionSoil
    from structure import simulate
    from structure.spec import contact_from_spec
    from orchestrator.run import output_nodes
    t0 = time.perf_counter()
    rm = fit_table(table, cache_dir=cache_dir()).model
    print(f"rational fit: {rm.order} poles, {time.perf_counter() - t0:.1f} s")
    res = simulate(model, RecursiveConvolutionSoil(rm, motion.dt), motion.acc, motion.dt,
                   contact=contact_from_spec(scene.section("contact")), output_nodes=output_nodes(scene),
                   route="monolithic")
    res.wall_s = time.perf_counter() - t0
    return res


def small_case(pga):
    from soil_impedance.mesh import circle_mesh
    from structure import WinklerSoil
    from structure._synthetic import broadband_accelerogram
    from structure.spec import model_from_spec
    from structure.winkler import dashpots_from_waves, disk_static_stiffness, springs_from_rigid_impedance

    mesh = circle_mesh(20.0, 8.0)
    model = model_from_spec({"model": "reactor", "damping": {"modal": 0.07}}, mesh.xy, mesh.area)
    E, nu, rho = 15e9, 0.3, 2500.0
    G = E / (2 * (1 + nu))
    vs = np.sqrt(G / rho)
    vp = vs * np.sqrt((2 - 2 * nu) / (1 - 2 * nu))
    s = springs_from_rigid_impedance(disk_static_stiffness(G, nu, 20.0), mesh.xy, mesh.area)
    cv, ch = dashpots_from_waves(mesh.area, rho, vp, vs)
    soil = WinklerSoil(mesh.xy, s.kv, s.kx, cv, ch)
    a = broadband_accelerogram(6.0, 0.005, pga * 9.81, seed=3)
    ag = np.zeros((a.size, 3))
    ag[:, 0] = a
    ag[:, 2] = 0.3 * a
    ag[0] = 0.0
    return model, soil, ag, 0.005


def convergence_map(pgas, use_reactor=False):
    from orchestrator.timefreq import timefreq
    from structure import ContactSettings

    variants = [("paper rho=1", dict(method="paper", rho=1.0)),
                ("paper rho=0.5", dict(method="paper", rho=0.5)),
                ("paper rho=0.5 w=8", dict(method="paper", rho=0.5, windows=8)),
                ("newton-krylov", dict(method="newton-krylov"))]
    print(f"\nconvergence map ({'reactor, BEM table' if use_reactor else 'reactor structure, 21-node Winkler raft'}): "
          "iterations (GMRES) or FAIL, max uplift mm")
    print(f"{'PGA g':>6} " + "".join(f"{v[0]:>22}" for v in variants))
    rows = []
    for pga in pgas:
        if use_reactor:
            scene, model, motion, table, _ = reactor(pga)
            soil, ag, dt = table, motion.acc, motion.dt
        else:
            model, soil, ag, dt = small_case(pga)
        cells, row = [], {"pga_g": pga}
        for name, kw in variants:
            t0 = time.perf_counter()
            r = timefreq(model, soil, ag, dt, contact=ContactSettings(), **kw)
            wall = time.perf_counter() - t0
            it = r.info["iterations"]
            g = f" ({r.info['gmres_total']})" if "gmres_total" in r.info else ""
            cells.append((f"{it}{g} {1e3 * r.max_uplift():.2f}mm" if r.converged else f"FAIL@{it}"))
            row[name] = dict(converged=r.converged, iterations=it, gmres=r.info.get("gmres_total"),
                             max_uplift_m=r.max_uplift(), wall_s=wall)
        rows.append(row)
        print(f"{pga:>6.2f} " + "".join(f"{c:>22}" for c in cells), flush=True)
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pga", type=float, default=0.25)
    ap.add_argument("--map", action="store_true")
    ap.add_argument("--map-reactor", action="store_true")
    ap.add_argument("--no-reactor", action="store_true")
    ap.add_argument("--json", type=Path)
    a = ap.parse_args()
    out = {}
    if not a.no_reactor:
        out["reactor"] = row_reactor(a.pga)
    if a.map or a.map_reactor:
        out["map"] = convergence_map(np.round(np.arange(0.1, 1.01, 0.1), 2), a.map_reactor)
    if a.json:
        a.json.write_text(json.dumps(out, default=float, indent=1))


if __name__ == "__main__":
    main()

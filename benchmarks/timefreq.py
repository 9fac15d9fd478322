"""Benchmark: the time-frequency reference route (paper §3) on the reactor scene.

Rows:
  reactor   built-in scene "reactor" (layered rock, R = 20 m, 241 nodes), its synthetic
            RG1.60 motion scaled to --pga (default 0.25 g), 10 s at 5 ms; the BEM "gap" table
            (cached in $UPLIFT_CACHE or ~/.cache/uplift after the first ~10 s sweep).
            Routes: timefreq (the march with the wrap-around fed back, bilinear grid, BEM
            table), timefreq on the continuous grid (Newton-Krylov), linear (FD, BEM table),
            winkler (TD, the industrial spring route of run.py), monolithic (TD, fit);
            printed with orchestrator.compare.
  --map     convergence map over PGA 0.1 ... 1.0 g on the reactor structure with a coarse
            Winkler raft (21 nodes, frequency-independent K + s C soil, 6 s): the paper's
            scheme (auxiliary stiffness 1 and 30 x the local static soil stiffness, rho = 1
            and 0.5), Newton-Krylov from zero and from one causal march (60 s budget each),
            and the march with the wrap-around fed back: converged?, iterations, final
            residual, time, max uplift, against Newmark's max uplift; ~20 min, mostly the
            failing Newton-Krylov runs. --map-reactor: the BEM reactor instead.

  --ladder  the verification ladder on the reactor: TF with the BEM table, TF with the
            rational fit sampled as a table, monolithic TD, linear FD vs bonded TD, and the
            fit's error on the rigid-raft impedances (what separates TF from TD).

    python benchmarks/timefreq.py [--pga 0.25] [--map] [--map-reactor] [--ladder] [--no-reactor]
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
    sweeps = " ".join(f"{x['residual']:.0e}" for x in h["history"])
    print(f"\ntimefreq: wall {tf.wall_s:.2f} s (setup {h['setup_s']:.2f} s, solve {h['solve_s']:.2f} s), "
          f"converged {tf.converged}, method {h['method']}, sweeps {h['iterations']}, residual "
          f"{h['residual']:.1e} (per sweep: {sweeps}), "
          f"S applications {h['apply_S']}, nfft {h['nfft']} (pad {h['pad_s']:.2f} s, rule "
          f"{h['pad_rule_s']:.2f} s)")
    tfc = run_timefreq(scene, motion, model, table, bilinear=False, route="timefreq-continuous")
    results["timefreq-continuous"] = tfc
    print(f"timefreq on the continuous grid (Newton-Krylov): wall {tfc.wall_s:.2f} s, Newton "
          f"iterations {tfc.info['iterations']}, GMRES {tfc.info['gmres_total']}, converged {tfc.converged}")
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


def ladder(pga):
    """The verification ladder on the reactor (issue 6a): where TF (BEM table) and TD
    (rational fit) part. Rows: TF with the table; TF with the fit sampled on the table's
    frequencies and used as a table (same interpolation, continuation above f_max, window,
    continuous grid: isolates the fit); the monolithic TD route (fit, recursive convolution,
    Newmark); linear FD with the table vs bonded TD with the fit (the fit in the linear
    regime); and the fit's error on the rigid-raft impedances P^T K P (P = [I; Bq]) over
    2-8 Hz, the band of the SSI rocking mode (3.9 Hz)."""
    from orchestrator.compare import compare, format_table
    from orchestrator.linear_fd import run_linear
    from orchestrator.run import output_nodes
    from orchestrator.timefreq import run_timefreq
    from soil_impedance.convolution import RecursiveConvolutionSoil
    from soil_impedance.fit import fit_table
    from soil_impedance.table import ImpedanceTable
    from structure import ContactSettings, simulate
    from structure.spec import contact_from_spec

    from orchestrator.run import scene_fit_tol

    scene, model, motion, table, _ = reactor(pga)
    contact = contact_from_spec(scene.section("contact"))
    fit = fit_table(table, tol=scene_fit_tol(scene), cache_dir=cache_dir())
    rm = fit.model
    f = table.frequencies_hz
    P = np.vstack([np.eye(6), model.raft.vertical_trace()])
    Kt = np.einsum("ai,fab,bj->fij", P, table.matrices, P)
    Km = np.einsum("ai,fab,bj->fij", P, rm(2j * np.pi * f), P)
    band = (f >= 2.0) & (f <= 8.0)
    print(f"fit: {rm.order} poles, max relative error {fit.report.max_rel_error:.4f} (scene fit_tol "
          f"{scene_fit_tol(scene)}); rigid-raft impedance, 2-8 Hz:")
    for i, lab in ((0, "ux"), (2, "uz"), (4, "ry")):
        e = np.abs(Km[band, i, i] - Kt[band, i, i]).max() / np.abs(Kt[band, i, i]).max()
        ei = np.abs(Km[band, i, i].imag - Kt[band, i, i].imag).max() / np.abs(Kt[band, i, i].imag).max()
        print(f"  {lab}: |K| error {100 * e:.1f} %, damping (Im K) error {100 * ei:.1f} %")
    fit_as_table = ImpedanceTable(f, rm(2j * np.pi * f), table.dofs, dict(table.provenance, fitted=True))
    res = {"tf table": run_timefreq(scene, motion, model, table, bilinear=False),
           "tf fit-table": run_timefreq(scene, motion, model, fit_as_table, bilinear=False)}
    t0 = time.perf_counter()
    res["td monolithic"] = simulate(model, RecursiveConvolutionSoil(rm, motion.dt), motion.acc, motion.dt,
                                    contact=contact, output_nodes=output_nodes(scene), route="monolithic")
    res["td monolithic"].wall_s = time.perf_counter() - t0
    print(format_table(compare(res, "tf table")))
    print(format_table(compare(res, "td monolithic")))
    lin = {"linear table": run_linear(scene, motion, model, table)}
    bonded = ContactSettings(enabled=False, penalty=contact.penalty)
    t0 = time.perf_counter()
    lin["td bonded fit"] = simulate(model, RecursiveConvolutionSoil(rm, motion.dt), motion.acc, motion.dt,
                                    contact=bonded, output_nodes=output_nodes(scene), route="bonded")
    lin["td bonded fit"].wall_s = time.perf_counter() - t0
    print(format_table(compare(lin, "linear table")))
    return compare(res, "tf table")


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


def _fit_soil(scene, table, dt):
    """The scene's rational fit run by its recursion (the Newmark column of the reactor map)."""
    from orchestrator.cosim import scene_fit
    from soil_impedance.convolution import RecursiveConvolutionSoil
    return RecursiveConvolutionSoil(scene_fit(scene, cache_dir=cache_dir(), table=table).model, dt)


def convergence_map(pgas, use_reactor=False):
    """The paper's scheme (eq. 17-20) against Newton-Krylov (from zero and from one causal
    march, budget 60 s each) and the march with the wrap-around fed back, over PGA:
    converged?, iterations or sweeps (GMRES), final relative residual |g| / |f|, wall time,
    max uplift; and Newmark's max uplift (the same discrete equations up to the wrap-around
    for the Winkler raft; the fitted soil for the reactor). The paper's scheme
    with the auxiliary stiffness k = the local static soil stiffness (aux 1, the paper's
    choice) and 30 x stiffer (aux 30, the only setting found to converge), rho = 1 and 0.5."""
    from orchestrator.timefreq import timefreq
    from structure import ContactSettings, simulate
    from structure.spec import contact_from_spec

    budget = dict(max_seconds=60.0)
    variants = [("paper aux1 rho1", dict(method="paper", rho=1.0)),
                ("paper aux30 rho1", dict(method="paper", rho=1.0, aux_factor=30.0, max_iter=400)),
                ("paper aux30 rho.5", dict(method="paper", rho=0.5, aux_factor=30.0, max_iter=400)),
                ("newton-krylov", dict(method="newton-krylov", **budget)),
                ("NK from march", dict(method="newton-krylov", guess="march", **budget)),
                ("march", dict(method="march"))]
    if use_reactor:     # the paper's aux-30 runs (400 iterations, an m^3 inverse per frequency
        # each) and Newton-Krylov from zero would take hours on 241 nodes
        variants = [v for v in variants if v[0] in ("paper aux1 rho1", "NK from march", "march")]
    print(f"\nconvergence map ({'reactor, BEM table' if use_reactor else 'reactor structure on a 21-node Winkler raft (K + s C soil), 6 s broadband motion, 30 % vertical'})")
    print("cell: converged (yes/NO), iterations (GMRES), final |g|/|f|, wall s; max uplift mm")
    print(f"{'PGA g':>6}" + "".join(f"{v[0]:>36}" for v in variants))
    rows = []
    for pga in pgas:
        if use_reactor:
            scene, model, motion, table, _ = reactor(pga)
            soil, ag, dt = table, motion.acc, motion.dt
        else:
            model, soil, ag, dt = small_case(pga)
        t0 = time.perf_counter()
        td = simulate(model, soil if not use_reactor else _fit_soil(scene, table, dt), ag, dt,
                      contact=ContactSettings() if not use_reactor else contact_from_spec(scene.section("contact")))
        cells, row = [], {"pga_g": pga, "newmark_uplift_m": td.max_uplift(),
                          "newmark_s": time.perf_counter() - t0}
        for name, kw in variants:
            t0 = time.perf_counter()
            r = timefreq(model, soil, ag, dt, contact=ContactSettings() if not use_reactor else
                         contact_from_spec(scene.section("contact")), **kw)
            wall = time.perf_counter() - t0
            it = r.info["iterations"]
            res = r.info["residual"]
            g = f"({r.info['gmres_total']})" if "gmres_total" in r.info else ""
            cells.append(f"{'yes' if r.converged else 'NO'} {it}{g} {res:.0e} {wall:.1f}s "
                         f"{1e3 * r.max_uplift():.2f}")
            row[name] = dict(converged=r.converged, iterations=it, gmres=r.info.get("gmres_total"),
                             residual=res, max_uplift_m=r.max_uplift(), wall_s=wall)
        rows.append(row)
        print(f"{pga:>6.2f}" + "".join(f"{c:>36}" for c in cells)
              + f"   Newmark {1e3 * td.max_uplift():.2f}", flush=True)
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pga", type=float, default=0.25)
    ap.add_argument("--map", action="store_true")
    ap.add_argument("--map-reactor", action="store_true")
    ap.add_argument("--ladder", action="store_true", help="TF vs TD verification ladder on the reactor")
    ap.add_argument("--no-reactor", action="store_true")
    ap.add_argument("--json", type=Path)
    a = ap.parse_args()
    out = {}
    if not a.no_reactor:
        out["reactor"] = row_reactor(a.pga)
    if a.ladder:
        out["ladder"] = ladder(a.pga)
    if a.map or a.map_reactor:
        out["map"] = convergence_map(np.round(np.arange(0.1, 1.01, 0.1), 2), a.map_reactor)
    if a.json:
        a.json.write_text(json.dumps(out, default=float, indent=1))


if __name__ == "__main__":
    main()

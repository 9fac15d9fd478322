"""Benchmark: the time-frequency reference route (paper §3) on the reactor scene.

Rows:
  reactor   built-in scene "reactor" (layered rock, R = 20 m, 241 nodes), its synthetic
            RG1.60 motion scaled to --pga (default 0.25 g), 10 s at 5 ms; the BEM "gap" table
            (cached in $UPLIFT_CACHE or ~/.cache/uplift after the first ~10 s sweep).
            Routes: timefreq (the march with the wrap-around fed back, bilinear grid, BEM
            table), timefreq on the continuous grid (Newton-Krylov), linear (FD, BEM table),
            winkler (TD, the industrial spring route), monolithic (TD, fit);
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

  --contention  the timefreq route on the reactor (one BLAS thread) with 1 and 2 worker
            threads (SolveOptions.threads), idle and beside one busy process (``python -c
            "while True: pass"``, started here): best wall time of --repeat runs in each
            state, their ratio (target <= 1.3), and the max uplift of every run against the
            1-thread idle run (the result must not depend on the threads or the load).

  --stand-in  the march with the scene's passive rational fit standing in for the table
            (march.defect_correction(stand_in=...): the fit's causal kernel marched, the
            table's whole-range residual fed back, so the fixed point stays the table's) against
            the default march on the table's own kernel: residual per sweep, CPU time, max
            uplift (--sweeps, default 30: the stand-in's budget; ~5 min); and both again on
            another reference, the table with the fit's own values above the table's last
            frequency instead of its springs and dashpots; and a stand-in with the fit's poles
            and the route's continuation as its asymptote (D = A, E = B, the residues refit:
            ``soil_impedance.fit.continuation_model``) on the table, marched on the grid (the route
            marches it natively by default: orchestrator/standin.py).

  --parts   where a march solve's CPU goes on the reactor (one thread): the far-field split and
            the kernel head, per sweep the far field, the near field's products from finished
            sub-blocks, the step solves and the rest (the step-by-step near field, residual); the default against
            float64 marches (march.SINGLE off) and against no look-ahead ("march-causal"): sweeps,
            residuals, max uplift.

    python benchmarks/timefreq.py [--pga 0.25] [--map] [--map-reactor] [--ladder] [--contention] [--stand-in]
                                  [--parts] [--no-reactor]
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np


def cache_dir():
    env = os.environ.get("UPLIFT_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "uplift"


def reactor(pga):
    from orchestrator.impedance import scene_impedance
    from orchestrator.motion import synthetic_motion
    from orchestrator.scene import load_scene
    from structure.spec import build_model

    scene = load_scene("reactor")
    model = build_model(scene.structure, scene.mesh.xy, scene.mesh.area)
    m = scene.motion
    motion = synthetic_motion(pga_g=pga, duration_s=m.duration_s, dt=0.005, seed=m.seed, spectrum=m.spectrum,
                              direction=m.direction)
    t0 = time.perf_counter()
    table = scene_impedance(scene, ("gap",), cache_dir=cache_dir())["gap"]
    return scene, model, motion, table, time.perf_counter() - t0


def scene_inputs(scene):
    """The route glue's scene keywords: contact settings and output nodes."""
    return dict(contact=scene.contact, output_nodes=scene.output.nodes)


def row_reactor(pga):
    from orchestrator.compare import compare, format_table
    from orchestrator.impedance import scene_impedance
    from orchestrator.routes.linear import run_linear
    from orchestrator.routes.timefreq import run_timefreq
    from orchestrator.routes.winkler import winkler_soil
    from structure import simulate

    scene, model, motion, table, t_table = reactor(pga)
    print(f"gap table: {table.n_dof} DOFs, {table.frequencies_hz.size} frequencies, {t_table:.1f} s (cache)")
    results = {}
    tf = run_timefreq(motion, model, table, **scene_inputs(scene))
    results["timefreq"] = tf
    lin = run_linear(motion, model, table, **scene_inputs(scene))
    results["linear"] = lin
    rigid = scene_impedance(scene, ("rigid",), cache_dir=cache_dir())["rigid"]
    soil, damping, _ = winkler_soil(scene, model, table=rigid, cache_dir=cache_dir())
    results["winkler"] = simulate(model, soil, motion.acc, motion.dt, contact=scene.contact, damping=damping,
                                  output_nodes=scene.output.nodes, route="winkler")
    try:
        results["monolithic"] = _monolithic(scene, model, motion)
    except Exception as exc:  # the fit route may not exist yet
        print(f"monolithic route skipped: {exc}")
    h = tf.info
    sweeps = " ".join(f"{x['residual']:.0e}" for x in h["history"])
    print(f"\ntimefreq: wall {tf.wall_s:.2f} s (setup {h['setup_s']:.2f} s, solve {h['solve_s']:.2f} s), "
          f"converged {tf.converged}, method {h['method']}, sweeps {h['iterations']}, residual "
          f"{h['residual']:.1e} (per sweep: {sweeps}), "
          f"S applications {h['apply_S']}, nfft {h['nfft']} (pad {h['pad_s']:.2f} s, rule "
          f"{h['pad_rule_s']:.2f} s)")
    tfc = run_timefreq(motion, model, table, **scene_inputs(scene), bilinear=False, method="newton-krylov",
                       route="timefreq-continuous")
    results["timefreq-continuous"] = tfc
    print(f"timefreq on the continuous grid (Newton-Krylov): wall {tfc.wall_s:.2f} s, Newton "
          f"iterations {tfc.info['iterations']}, GMRES {tfc.info['gmres_total']}, converged {tfc.converged}")
    print(f"linear: wall {lin.wall_s:.2f} s ({lin.info['bonded_solver']}, {lin.info['sweeps']} sweeps)\n")
    cmp = compare(results, "timefreq")
    print(format_table(cmp))
    return cmp


def _monolithic(scene, model, motion):
    """TD route with the fitted rational soil (the monolithic route; its wall time includes
    the fit or its cache read)."""
    from orchestrator.routes.monolithic import run_monolithic

    t0 = time.perf_counter()
    res = run_monolithic(scene, motion, cache_dir=cache_dir(), model=model)
    print(f"rational fit + monolithic route: {time.perf_counter() - t0:.1f} s")
    return dataclasses.replace(res, wall_s=time.perf_counter() - t0)


def _timed(fn, *args, **kw):
    """fn(*args, **kw) as a RouteResult whose wall_s is the call's."""
    t0 = time.perf_counter()
    res = fn(*args, **kw)
    return dataclasses.replace(res, wall_s=time.perf_counter() - t0)


def ladder(pga):
    """The verification ladder on the reactor: where TF (BEM table) and TD
    (rational fit) part. Rows: TF with the table; TF with the fit sampled on the table's
    frequencies and used as a table (same interpolation, continuation above f_max, window,
    continuous grid: isolates the fit); the monolithic TD route (fit, recursive convolution,
    Newmark); linear FD with the table vs bonded TD with the fit (the fit in the linear
    regime); and the fit's error on the rigid-raft impedances P^T K P (P = [I; Bq]) over
    2-8 Hz, the band of the SSI rocking mode (3.9 Hz)."""
    from orchestrator.compare import compare, format_table
    from orchestrator.impedance import scene_fit
    from orchestrator.routes.linear import run_linear
    from orchestrator.routes.timefreq import run_timefreq
    from soil_impedance.convolution import RecursiveConvolutionSoil
    from soil_impedance.table import ImpedanceTable
    from structure import ContactSettings, simulate

    scene, model, motion, table, _ = reactor(pga)
    contact, nodes = scene.contact, scene.output.nodes
    fit = scene_fit(scene, cache_dir=cache_dir(), table=table)
    rm = fit.model
    f = table.frequencies_hz
    P = np.vstack([np.eye(6), model.raft.vertical_trace()])
    Kt = np.einsum("ai,fab,bj->fij", P, table.matrices, P)
    Km = np.einsum("ai,fab,bj->fij", P, rm(2j * np.pi * f), P)
    band = (f >= 2.0) & (f <= 8.0)
    print(f"fit: {rm.order} poles, max relative error {fit.report.max_rel_error:.4f} (scene fit_tol "
          f"{scene.analysis.fit_tol}); rigid-raft impedance, 2-8 Hz:")
    for i, lab in ((0, "ux"), (2, "uz"), (4, "ry")):
        e = np.abs(Km[band, i, i] - Kt[band, i, i]).max() / np.abs(Kt[band, i, i]).max()
        ei = np.abs(Km[band, i, i].imag - Kt[band, i, i].imag).max() / np.abs(Kt[band, i, i].imag).max()
        print(f"  {lab}: |K| error {100 * e:.1f} %, damping (Im K) error {100 * ei:.1f} %")
    fit_as_table = ImpedanceTable(f, rm(2j * np.pi * f), table.dofs, dict(table.provenance, fitted=True))
    nk = dict(bilinear=False, method="newton-krylov")       # the continuous grid's (experimental) solver
    res = {"tf table": run_timefreq(motion, model, table, **scene_inputs(scene), **nk),
           "tf fit-table": run_timefreq(motion, model, fit_as_table, **scene_inputs(scene), **nk)}
    res["td monolithic"] = _timed(simulate, model, RecursiveConvolutionSoil(rm, motion.dt), motion.acc, motion.dt,
                                  contact=contact, output_nodes=nodes, route="monolithic")
    print(format_table(compare(res, "tf table")))
    print(format_table(compare(res, "td monolithic")))
    lin = {"linear table": run_linear(motion, model, table, **scene_inputs(scene))}
    bonded = ContactSettings(enabled=False, penalty=contact.penalty)
    lin["td bonded fit"] = _timed(simulate, model, RecursiveConvolutionSoil(rm, motion.dt), motion.acc, motion.dt,
                                  contact=bonded, output_nodes=nodes, route="bonded")
    print(format_table(compare(lin, "linear table")))
    return compare(res, "tf table")


def small_case(pga):
    from soil_impedance.mesh import circle_mesh
    from structure import G_ACC, WinklerSoil
    from structure.broadband import broadband_accelerogram
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
    a = broadband_accelerogram(6.0, 0.005, pga * G_ACC, seed=3)
    ag = np.zeros((a.size, 3))
    ag[:, 0] = a
    ag[:, 2] = 0.3 * a
    ag[0] = 0.0
    return model, soil, ag, 0.005


def _fit_soil(scene, table, dt):
    """The scene's rational fit run by its recursion (the Newmark column of the reactor map)."""
    from orchestrator.impedance import scene_fit
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
    from orchestrator.timefreq import NewtonKrylovOptions, PaperOptions, SolveOptions, solve
    from structure import ContactSettings, simulate

    variants = [("paper aux1 rho1", SolveOptions(method="paper", paper=PaperOptions(rho=1.0))),
                ("paper aux30 rho1", SolveOptions(method="paper", max_iter=400,
                                                  paper=PaperOptions(rho=1.0, aux_factor=30.0))),
                ("paper aux30 rho.5", SolveOptions(method="paper", max_iter=400,
                                                   paper=PaperOptions(rho=0.5, aux_factor=30.0))),
                ("newton-krylov", SolveOptions(method="newton-krylov", max_seconds=60.0)),
                ("NK from march", SolveOptions(method="newton-krylov", max_seconds=60.0,
                                               newton_krylov=NewtonKrylovOptions(guess="march"))),
                ("march", SolveOptions(method="march"))]
    if use_reactor:     # the paper's aux-30 runs (400 iterations, an m^3 inverse per frequency
        # each) and Newton-Krylov from zero would take hours on 241 nodes
        variants = [v for v in variants if v[0] in ("paper aux1 rho1", "NK from march", "march")]
    case = "reactor, BEM table" if use_reactor else \
        "reactor structure on a 21-node Winkler raft (K + s C soil), 6 s broadband motion, 30 % vertical"
    print(f"\nconvergence map ({case})")
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
        contact = scene.contact if use_reactor else ContactSettings()
        td = simulate(model, soil if not use_reactor else _fit_soil(scene, table, dt), ag, dt, contact=contact)
        cells, row = [], {"pga_g": pga, "newmark_uplift_m": td.max_uplift(),
                          "newmark_s": time.perf_counter() - t0}
        for name, options in variants:
            t0 = time.perf_counter()
            r = solve(model, soil, ag, dt, contact=contact, options=options)
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


def contention(pga, repeat=2, threads=(1, 2)):
    """The timefreq route on the reactor with 1 and 2 worker threads, one BLAS thread, idle
    and beside one busy process: each repeat runs every thread count idle, then every one
    beside the busy process (interleaved, so that a drift of the machine's load hits all
    states alike); best wall time per state, their ratio, and each run's max uplift against
    the 1-thread idle run's."""
    from threadpoolctl import threadpool_limits

    from orchestrator.routes.timefreq import run_timefreq

    scene, model, motion, table, _ = reactor(pga)
    idle, busy = ({n: [] for n in threads} for _ in range(2))
    loads = [os.getloadavg()[0]]

    def run(n, into):
        res = run_timefreq(motion, model, table, **scene_inputs(scene), threads=n)
        into[n].append((res.wall_s, res.max_uplift(), res.info["iterations"]))

    with threadpool_limits(1):
        for _ in range(repeat):
            for n in threads:
                run(n, idle)
            hog = subprocess.Popen([sys.executable, "-c", "while True: pass"])
            try:
                for n in threads:
                    run(n, busy)
            finally:
                hog.kill()
                hog.wait()
            loads.append(os.getloadavg()[0])
    ref = idle[threads[0]][0][1]
    print(f"\ntimefreq route, reactor {pga:g} g, one BLAS thread, best of {repeat} runs per state; "
          f"{os.cpu_count()} CPUs, 1-min load average {', '.join(f'{x:.1f}' for x in loads)} "
          "(start, after each repeat; the busy process adds 1)")
    print(f"{'threads':>7} {'idle s':>8} {'busy s':>8} {'ratio':>6} {'sweeps':>6} {'max uplift mm':>14} "
          f"{'max |d uplift| m vs 1 thread idle':>34}")
    rows = []
    for n in threads:
        wi, wb = min(r[0] for r in idle[n]), min(r[0] for r in busy[n])
        every = idle[n] + busy[n]
        diff = max(abs(r[1] - ref) for r in every)
        sweeps = sorted({r[2] for r in every})
        print(f"{n:>7} {wi:8.2f} {wb:8.2f} {wb / wi:6.2f} {','.join(map(str, sweeps)):>6} "
              f"{1e3 * every[0][1]:14.6f} {diff:34.3e}")
        rows.append(dict(threads=n, idle_s=[r[0] for r in idle[n]], busy_s=[r[0] for r in busy[n]],
                         ratio=wb / wi, max_uplift_m=[r[1] for r in every], max_uplift_diff_m=diff, sweeps=sweeps))
    return dict(rows=rows, load_average=loads)


def stand_in(pga, sweeps=30, tol=1e-6):
    """Residual per sweep, CPU s and max uplift of defect_correction on the reactor's table,
    marching the table's own kernel (the default), the scene's rational fit (stand_in) and the
    fit's poles with the route's continuation as asymptote (soil_impedance.fit.continuation)."""
    from orchestrator.timefreq import (GridOptions, InterfaceOperator, SoilBands, defect_correction, prepare,
                                       soil_bands)
    from orchestrator.timefreq.soil import DenseBand
    from soil_impedance.convolution import RecursiveConvolutionSoil
    from soil_impedance.fit.continuation import continuation_model

    scene, model, motion, table, _ = reactor(pga)
    fit = _fit_soil(scene, table, motion.dt)
    prob = prepare(model, table, motion.acc, motion.dt, grid=GridOptions().resolved(bilinear=True, window=True),
                   contact=scene.contact)
    st = continuation_model(table, fit.model.poles)[0]      # the route's A + s B above the table
    ops = {"fit": InterfaceOperator(model, soil_bands(fit, prob.grid), prob.grid, structure=prob.op.st),
           "continuation": InterfaceOperator(model, soil_bands(RecursiveConvolutionSoil(st, motion.dt),
                                                               prob.grid), prob.grid, structure=prob.op.st)}
    op_fit = ops["fit"]
    k0 = prob.op.soil.K0
    for name, op in ops.items():
        print(f"static stiffness, {name} stand-in against table: {np.abs(op.soil.K0 - k0).max() / np.abs(k0).max():.1e} "
              "(max entry, relative)")
    print("where the soils differ (S the interface stiffness; rho: spectral radius of S_x^-1 (S_table - S_x), the "
          "linear iteration's rate with every node open), x the fit, then the continuation stand-in:\n"
          "   f Hz  warped Hz  |dS|/|S|     rho  |dS|/|S|     rho")
    spectrum = []
    for k in np.unique(np.geomspace(1, prob.grid.n_freq - 1, 16).astype(int)):
        St = _interface_stiffness(prob.op, k)
        row = dict(f_hz=float(prob.grid.freq_hz[k]), warped_hz=float(prob.grid.warped_hz[k]))
        for name, op in ops.items():
            Sx = _interface_stiffness(op, k)
            row[f"rel_{name}"] = float(np.linalg.norm(St - Sx, 2) / np.linalg.norm(St, 2))
            row[f"rho_{name}"] = float(np.abs(np.linalg.eigvals(np.linalg.solve(Sx, St - Sx))).max())
        spectrum.append(row)
        print(f"{row['f_hz']:7.2f} {row['warped_hz']:10.2f} " + " ".join(
            f"{row[f'rel_{n}']:9.1e} {row[f'rho_{n}']:7.1e}" for n in ops))
    rows = {"spectrum": spectrum}
    # the same with the fit instead of the springs and dashpots above the table's last frequency
    # (another reference: the check that the stand-in works where the two soils agree)
    lo, hi = prob.op.soil.bands
    K_fit = op_fit.soil.bands[0].K
    above = SoilBands((lo, DenseBand(hi.idx, K_fit[hi.idx[0]:hi.idx[-1] + 1])), prob.op.soil.K0, prob.op.soil.n,
                      "table, fit above its last frequency")
    op_above = InterfaceOperator(model, above, prob.grid, structure=prob.op.st)
    prob_above = dataclasses.replace(prob, op=op_above, f=prob.grid.to_time(op_above.blocked_force(prob.ag_hat)))
    for ref, p, name, kw in (
            ("table", prob, "table kernel (default)", dict(fold="auto")),
            ("table", prob, "rational fit stand-in", dict(stand_in=dataclasses.replace(prob, op=op_fit))),
            ("table", prob, "continuation stand-in", dict(stand_in=dataclasses.replace(prob, op=ops["continuation"]))),
            ("table, fit above", prob_above, "own kernel (default)", dict(fold="auto")),
            ("table, fit above", prob_above, "rational fit stand-in", dict(stand_in=dataclasses.replace(prob, op=op_fit)))):
        c0 = time.process_time()
        out = defect_correction(p, tol=tol, max_sweeps=sweeps, **kw)
        cpu = time.process_time() - c0
        uplift = float(np.maximum(0.0, -(p.z0[:, None] + out.y)).max())
        res = [h.residual for h in out.history]
        rows[f"{ref}: {name}"] = dict(status=out.status.value, sweeps=len(res), residuals=res, cpu_s=cpu,
                                      max_uplift_m=uplift)
        print(f"{ref:<17} {name:<24} {out.status.value:<14} {len(res):3d} sweeps  cpu {cpu:6.1f} s  max uplift "
              f"{1e3 * uplift:.6f} mm  residuals " + " ".join(f"{r:.1e}" for r in res))
    return rows


def parts(pga, tol=1e-6):
    """Where a march solve's CPU goes on the reactor (one BLAS thread, one worker thread):
    the far-field split and the kernel head (once), per sweep the far field, the near field's
    products from finished sub-blocks and the step solves (each timed by thread CPU time), the
    rest (the step-by-step near field, the whole-range residual); for the default (look-ahead
    march.AHEAD, single-precision corrections march.SINGLE), with float64 marches and without
    the look-ahead (method "march-causal"): sweeps, residuals, max uplift and their difference,
    and the far field per application (float64 and float32 products) against one application
    of S on the grid."""
    import importlib

    from orchestrator.timefreq import GridOptions, WorkerPool, prepare
    from orchestrator.timefreq.farfield import AffineSplit, generic_far_field
    march = importlib.import_module("orchestrator.timefreq.march")

    scene, model, motion, table, _ = reactor(pga)
    clock = time.thread_time
    with WorkerPool(1) as pool:
        c0 = clock()
        prob = prepare(model, table, motion.acc, motion.dt, grid=GridOptions().resolved(bilinear=True, window=True),
                       contact=scene.contact, pool=pool)
        print(f"prepare: {clock() - c0:.2f} CPU s (nfft {prob.grid.nfft}, bands "
              f"{[b.idx.size for b in prob.op.soil.bands]} frequencies)")
        c0 = clock()
        split = AffineSplit(prob.op, prob.grid)
        c1 = clock()
        split.kernel(march.BLOCK, march.AHEAD)
        c2 = clock()
        print(f"far-field split {c1 - c0:.2f} CPU s, kernel head {c2 - c1:.2f} CPU s "
              f"(the inverse FFT of every entry of S: ", end="", flush=True)
        march.kernel_lags(prob.op, prob.grid, march.BLOCK, march.AHEAD)
        print(f"{clock() - c2:.2f} CPU s)")
        N, nt = prob.f.shape
        xb, H = np.random.default_rng(0).standard_normal((N, march.BLOCK)), np.zeros((N, nt))
        plain = generic_far_field(prob.op, prob.grid)
        split.dense32                                       # noqa: B018  (formed before the timing)
        for name, far, kw in (("split", split, {}), ("split, single precision", split, dict(single=True)),
                              ("one application of S", plain, {})):
            c0 = clock()
            for a in range(0, 10 * march.BLOCK, march.BLOCK):
                far(xb, a, a + march.BLOCK, H, **kw)
            print(f"far field per block, {name}: {(clock() - c0) / 10 * 1e3:.1f} CPU ms")
        rows = {}
        plain_sweep = march.CausalSweep
        spent = {}

        def timed(key, fn):
            def run(*args, **kw):
                c = clock()
                out = fn(*args, **kw)
                spent[key] += clock() - c
                return out
            return run

        class TimedSweep(plain_sweep):      # the sweep's step solves, far field, near-field products timed
            def __init__(self, *args, **kw):
                super().__init__(*args, **kw)
                self.step.solve, self.far = timed("steps", self.step.solve), timed("far", self.far)
                self._cross = timed("cross", self._cross)

        runs = {"default": dict(ahead=march.AHEAD), "float64 marches": dict(ahead=march.AHEAD, single=False),
                "no look-ahead": dict(ahead=0)}
        for label, kw in runs.items():
            spent.update(steps=0.0, far=0.0, cross=0.0)
            march.CausalSweep = TimedSweep
            try:
                c0 = clock()
                out = march.defect_correction(prob, tol=tol, fold="auto", **kw)
                total = clock() - c0
            finally:
                march.CausalSweep = plain_sweep
            res = [h.residual for h in out.history]
            uplift = float(np.maximum(0.0, -(prob.z0[:, None] + out.y)).max())
            n = len(res)
            rest = total - spent["steps"] - spent["far"] - spent["cross"]
            rows[label] = dict(sweeps=n, residuals=res, cpu_s=total, far_s=spent["far"], steps_s=spent["steps"],
                               cross_s=spent["cross"], rest_s=rest, max_uplift_m=uplift)
            print(f"{label}: {n} sweeps, {total:.2f} CPU s: far field {spent['far']:.2f}, near-field "
                  f"products from finished sub-blocks {spent['cross']:.2f}, step solves {spent['steps']:.2f}, the rest "
                  f"(split, head, the step-by-step near field, residuals) {rest:.2f}; max uplift {1e3 * uplift:.7f} mm; "
                  "residuals " + " ".join(f"{r:.1e}" for r in res))
        a = rows["default"]["max_uplift_m"]
        for label in list(runs)[1:]:
            b = rows[label]["max_uplift_m"]
            print(f"max uplift, default against {label}: {abs(a - b) / b:.1e} relative")
    return rows


def _interface_stiffness(op, k):
    """S at the grid frequency k, (N, N) complex: the soil block of its band minus the rank-6 term."""
    from orchestrator.timefreq.soil import AffineBand, dense
    for band in op.soil.bands:
        pos = np.flatnonzero(band.idx == k)
        if pos.size:
            if isinstance(band, AffineBand):
                A, B = band.ww()
                K = dense(A) + op.s[k] * dense(B)
            else:
                K = band.ww()[pos[0]]
            return K - op.Vr[k] @ op.ZV[k]
    raise IndexError(k)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pga", type=float, default=0.25)
    ap.add_argument("--map", action="store_true")
    ap.add_argument("--map-reactor", action="store_true")
    ap.add_argument("--ladder", action="store_true", help="TF vs TD verification ladder on the reactor")
    ap.add_argument("--contention", action="store_true",
                    help="wall time idle and beside one busy process, 1 and 2 worker threads")
    ap.add_argument("--repeat", type=int, default=2, help="runs per state of --contention (best kept)")
    ap.add_argument("--stand-in", action="store_true", help="the rational fit as the march's stand-in")
    ap.add_argument("--sweeps", type=int, default=30, help="sweeps of --stand-in (default 30)")
    ap.add_argument("--parts", action="store_true",
                    help="where a march solve's CPU goes; the default against float64 marches and no look-ahead")
    ap.add_argument("--no-reactor", action="store_true")
    ap.add_argument("--json", type=Path)
    a = ap.parse_args()
    out = {}
    if a.contention:
        out["contention"] = contention(a.pga, a.repeat)
    elif a.stand_in:
        out["stand_in"] = stand_in(a.pga, a.sweeps)
    elif a.parts:
        out["parts"] = parts(a.pga)
    elif not a.no_reactor:
        out["reactor"] = row_reactor(a.pga)
    if a.ladder:
        out["ladder"] = ladder(a.pga)
    if a.map or a.map_reactor:
        out["map"] = convergence_map(np.round(np.arange(0.1, 1.01, 0.1), 2), a.map_reactor)
    if a.json:
        a.json.write_text(json.dumps(out, default=float, indent=1))


if __name__ == "__main__":
    main()

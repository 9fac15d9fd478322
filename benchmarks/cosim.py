"""Benchmark: co-simulation (two FMUs, our Gauss-Seidel master) against the monolithic route on
the reactor, with the FMU layer's cost per part; ``--engines``: the exported system in every
engine (our master's three schedules, libcosim on system.ssd, fmpy's SSP runner on system.ssp,
fmpy.simulate_fmu on coupled.fmu) with start-up, per-step cost and the difference to monolithic.

Reactor scene (built-in ``reactor``: 241 interface nodes, 6 + 241 = 247 soil DOFs), its motion
(synthetic RG1.60, 0.25 g, seed 1; ``--pga``/``--duration`` to change), 10 s at the scene's
dt = 5 ms, with uplift. Soil: the rational fit of the scene's gap impedance table at the scene's
``[analysis] fit_tol`` (BEM sweep and fit cached in $UPLIFT_CACHE or ~/.cache/uplift; the
first run sweeps), run by the recursive convolution. ``--soil winkler`` uses a stand-in of the
same size (Winkler springs and dashpots with two Maxwell terms) when the fit is not wanted.

Three runs per repeat, interleaved (``--repeat``, medians reported; other jobs on the machine
make single timings noisy):

  monolithic   ``run_monolithic``: the stepper with the soil object in process (the reference)
  cosim        ``cosimulate`` over the two exported FMUs (built once, build time reported apart)
  split        the co-simulation's schedule in process, without the FMU layer: the stepper
               with an external soil history (g + Gx x + Gv xdot) and the soil object stepped
               next to it (commit, then g of the next step), doing what the FMUs do per step
               (same arithmetic: equal to cosim bit for bit). Its parts against cosim's isolate
               what the FMU layer costs.

Native FMUs (fmus/native_build.py, compiled for this platform) in each repeat too: the native
pair under the same master, the native coupled FMU stepped through its ag_x, ag_y, ag_z
inputs; their wall and CPU time, start-up (extraction, instantiation, initialisation) and time per step beside the
monolithic route's (target: the native coupled FMU faster than the monolithic route).

Prints: wall and CPU time of each route, cosim / monolithic (target <= 1.5), the real-time
factor (target > 1), the differences cosim vs monolithic (max uplift, raft, gap: round-off
expected), and per part (setup, structure step, soil history, transfers) the in-process time,
the cosim time and the FMU layer's share. Run with OPENBLAS_NUM_THREADS=1.

    python benchmarks/cosim.py [--pga 0.25] [--duration 10] [--repeat 3] [--soil fit|winkler] [--engines]
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def soil_for(scene, kind, cache_dir):
    if kind == "fit":
        from orchestrator.impedance import scene_fit
        t0 = time.perf_counter()
        tol = scene.analysis.fit_tol
        model = scene_fit(scene, cache_dir=cache_dir, tol=tol).model
        return model, (f"rational fit of the gap table at fit_tol = {tol}, {model.order} poles "
                       f"({time.perf_counter() - t0:.1f} s incl. sweep/cache)")
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    from cosim_cases import winkler
    from soil_double import winkler_rational
    model = winkler_rational(winkler(scene))
    return model, f"Winkler + 2 Maxwell terms stand-in, {model.order} poles"


def split_in_process(scene, motion, model):
    """The Gauss-Seidel schedule without the FMU layer. Returns (gap (nt, N), Timer with the
    parts named as cosimulate's)."""
    from fmus.coupling import history_ahead, history_gains
    from fmus.resources import soil_from_model
    from orchestrator.master import Timer
    from structure import NewmarkStepper

    dt, ag = motion.dt, motion.acc
    soil = soil_from_model(model, dt)
    Gx, Gv = history_gains(soil, dt)                                 # measured at export
    timer = Timer()
    st = NewmarkStepper(scene.model(), soil, dt, contact=scene.contact,
                        external_soil=True, ag0=ag[0])
    dofs = [st.model.dofs(st.model.node_by_name(nm).id)[:3] for nm in scene.output.nodes]
    timer.add("initialisation")
    nt = ag.shape[0]
    rows = np.zeros((nt, 2 * st.nb + 2 * st.N + 6 * len(dofs) + 8))
    gap = slice(2 * st.nb + st.N, 2 * st.nb + 2 * st.N)
    rows[0, gap] = st.gap()
    g, prev = np.zeros(st.nb), None
    for k in range(1, nt):
        timer.mark()
        st.set_ground_acceleration(ag[k])
        st.set_soil_history(g + Gx @ st.x + Gv @ st.xdot)
        it = st.step()
        out = [st.x, st.xdot, st.P, st.gap()] + [st.a[d] + st.ag for d in dofs] + [st.u[d] for d in dofs] \
            + [np.array(list(st.energies().values()) + [it])]      # what the structure FMU publishes
        timer.add("structure step")
        rows[k] = np.concatenate(out)                                # what the master records
        timer.add("transfers")
        if prev is not None:                                         # the state of t_{k-1}
            soil.commit(*prev)
        prev = st.x.copy(), st.xdot.copy()
        g = history_ahead(soil)
        soil.total_force(), soil.dissipated_energy()                 # what the soil FMU publishes
        timer.add("soil step")
    return rows[:, gap], timer


def native_coupled(path, motion):
    """The native coupled FMU driven by the motion's inputs ag_x, ag_y, ag_z, one step of dt per
    call (as the pair): (wall s, CPU s, start-up s, max uplift m, raft (nt, 6)); start-up: extraction,
    instantiation, initialisation."""
    from fmus.schema import AG
    from orchestrator.master import FmuSlave

    dt, nt = motion.dt, motion.acc.shape[0]
    t0, c0 = time.perf_counter(), time.process_time()
    with FmuSlave(path, "coupled", parameters={"internal_motion": False}) as C:
        C.set(*AG, motion.acc[0])
        C.initialize()
        start = time.perf_counter() - t0
        raft = np.empty((nt, 6))
        raft[0] = C.get("x")[:6]
        for k in range(1, nt):
            C.set(*AG, motion.acc[k])
            C.do_step((k - 1) * dt, dt)
            raft[k] = C.get("x")[:6]
        up = float(C.get("max_uplift")[0])
    return time.perf_counter() - t0, time.process_time() - c0, start, up, raft


def run_engines(scene, motion, model, outdir, mono):
    """The exported system once in each engine: {name: (start-up s, total s, max uplift m, max
    raft rotation rad)}, the maxima read from the FMUs' headline outputs."""
    from fmpy import simulate_fmu
    from fmpy.ssp.simulation import simulate_ssp
    from orchestrator.export import export_scene
    from orchestrator.master import FmuSlave, cosimulate

    dt, nt = motion.dt, motion.acc.shape[0]
    exp = export_scene(scene, outdir, model, motion=motion, kind="python")
    out = {}
    for schedule in ("gauss-seidel", "soil-first", "jacobi"):
        t0 = time.perf_counter()
        res = cosimulate(exp.structure, exp.soil, motion.acc, dt, schedule=schedule)
        start = res.notes.timings["initialisation"] + res.wall_s / nt      # extraction included
        out[f"master {schedule}"] = (start, time.perf_counter() - t0, res.info["fmu_max_uplift"],
                                     res.info["fmu_max_raft_rotation"])
    try:
        from libcosimpy.CosimExecution import CosimExecution
        from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
        from libcosimpy.CosimObserver import CosimObserver
        log_output_level(CosimLogLevel.WARNING)
        t0 = time.perf_counter()
        ex = CosimExecution.from_ssp_file(str(exp.ssd))
        obs = CosimObserver.create_last_value()
        ex.add_observer(obs)
        si = ex.slave_index_from_instance_name("structure")
        refs = {v.name.decode(): v.reference for v in ex.slave_variables(si)}
        ex.step(1)
        start = time.perf_counter() - t0
        ex.step(nt - 2)
        up, rot = obs.last_real_values(si, [refs["max_uplift"], refs["max_raft_rotation"]])
        out["libcosim system.ssd (Jacobi)"] = (start, time.perf_counter() - t0, up, rot)
    except ImportError:
        print("libcosimpy not installed: no libcosim row")
    t0 = time.perf_counter()
    r = simulate_ssp(str(exp.ssp), stop_time=exp.stop_time, step_size=dt)
    total = time.perf_counter() - t0
    out["fmpy simulate_ssp system.ssp"] = (float("nan"), total, r["structure.max_uplift"][-1],
                                           r["structure.max_raft_rotation"][-1])
    t0 = time.perf_counter()
    with FmuSlave(exp.coupled, "coupled") as C:
        C.initialize()
        C.do_step(0.0, dt)
    start = time.perf_counter() - t0
    t0 = time.perf_counter()
    r = simulate_fmu(str(exp.coupled), output=["max_uplift", "max_raft_rotation"])
    out["fmpy simulate_fmu coupled.fmu"] = (start, time.perf_counter() - t0, r["max_uplift"][-1],
                                            r["max_raft_rotation"][-1])
    return out


def median(values):
    return float(np.median(np.asarray(values, float)))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pga", type=float, default=None, help="g (default: the scene's, 0.25)")
    ap.add_argument("--duration", type=float, default=None, help="s (default: the scene's, 10)")
    ap.add_argument("--repeat", type=int, default=3, help="interleaved repeats (medians)")
    ap.add_argument("--soil", choices=("fit", "winkler"), default="fit")
    ap.add_argument("--engines", action="store_true",
                    help="also run the exported system once in every engine (start-up, per step, error)")
    args = ap.parse_args(argv)

    from fmus.build import build_fmus
    from fmus.native_build import build_native_fmus, host_platform
    from orchestrator.export import fmu_data
    from orchestrator.master import cosimulate
    from orchestrator.motion import synthetic_motion
    from orchestrator.routes.monolithic import run_monolithic
    from orchestrator.scene import load_scene
    from orchestrator.settings import default_cache_dir

    cache = default_cache_dir()
    scene = load_scene("reactor")
    dt = scene.analysis.dt
    m = scene.motion
    pga = m.pga_g if args.pga is None else args.pga
    duration = m.duration_s if args.duration is None else args.duration
    motion = synthetic_motion(pga_g=pga, duration_s=duration, dt=dt, seed=m.seed, spectrum=m.spectrum,
                              direction=m.direction)
    model, label = soil_for(scene, args.soil, cache)
    nt = motion.acc.shape[0]
    print(f"reactor: {scene.mesh.xy.shape[0]} interface nodes, soil {model.n} DOFs: {label}")
    print(f"motion: synthetic {m.spectrum} {pga} g, {duration} s at dt = {dt} s "
          f"({nt - 1} steps); {args.repeat} interleaved repeats, medians; "
          f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}\n")

    runs = {"monolithic": [], "cosim": [], "split": []}      # (wall s, CPU s, Timer or None)
    native = {"native pair": [], "native coupled": []}      # (wall s, CPU s, start-up s, max uplift m)
    with tempfile.TemporaryDirectory(prefix="uplift_bench_") as tmp:
        t0 = time.perf_counter()
        fmus = build_fmus(fmu_data(scene, model, dt), tmp)
        s_fmu, g_fmu = fmus["structure"], fmus["soil"]
        build_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        nat = build_native_fmus(fmu_data(scene, model, dt), Path(tmp) / "native", coupled=True,
                                platforms=(host_platform(),))
        native_build_s = time.perf_counter() - t0
        run_monolithic(scene, motion, model)           # warm-up: imports, the passivity memo
        for _ in range(args.repeat):
            c0 = time.process_time()
            mono = run_monolithic(scene, motion, model)
            c1 = time.process_time()
            cos = cosimulate(s_fmu, g_fmu, motion.acc, dt)
            c2 = time.process_time()
            t0 = time.perf_counter()
            gap_split, split = split_in_process(scene, motion, model)
            c3, split_s = time.process_time(), time.perf_counter() - t0
            runs["monolithic"].append((mono.wall_s, c1 - c0, None))
            runs["cosim"].append((cos.wall_s, c2 - c1, {"timing": cos.notes.timings,
                                                        "timing_cpu": cos.info["timing_cpu"]}))
            runs["split"].append((split_s, c3 - c2, {"timing": split.parts, "timing_cpu": split.cpu}))
            c0 = time.process_time()
            npair = cosimulate(nat["structure"], nat["soil"], motion.acc, dt)
            native["native pair"].append((npair.wall_s, time.process_time() - c0,
                                          npair.notes.timings["initialisation"], npair.max_uplift()))
            wall_c, cpu_c, start_c, up_c, raft_c = native_coupled(nat["coupled"], motion)
            native["native coupled"].append((wall_c, cpu_c, start_c, up_c))
        engines = run_engines(scene, motion, model, Path(tmp) / "export", mono) if args.engines else None

    wall = {r: median([w for w, _, _ in v]) for r, v in runs.items()}
    cpu = {r: median([c for _, c, _ in v]) for r, v in runs.items()}
    print(f"{'route':12s} {'wall s':>8s} {'CPU s':>8s} {'x real time':>11s} {'max uplift mm':>14s} {'converged':>9s}")
    for name, res in (("monolithic", mono), ("cosim", cos)):
        print(f"{name:12s} {wall[name]:8.2f} {cpu[name]:8.2f} {duration / wall[name]:11.2f} "
              f"{1e3 * res.max_uplift():14.4f} {res.converged!s:>9s}")
    print(f"{'split':12s} {wall['split']:8.2f} {cpu['split']:8.2f} {duration / wall['split']:11.2f} "
          f"{1e3 * gap_split.max():14.4f}")
    print("(wall s: the route's wall_s, stepper or FMU start-up and time loop; CPU s: process time of\n"
          f" the whole call; x real time: simulated / wall. FMU build {build_s:.2f} s, once, not included)")
    ratios = [c[0] / m_[0] for c, m_ in zip(runs["cosim"], runs["monolithic"])]
    print(f"\ncosim / monolithic: wall {wall['cosim'] / wall['monolithic']:.2f} (per repeat "
          f"{', '.join(f'{r:.2f}' for r in ratios)}), CPU {cpu['cosim'] / cpu['monolithic']:.2f}; target <= 1.5")
    print(f"cosim vs monolithic: max uplift {1e3 * abs(cos.max_uplift() - mono.max_uplift()):.1e} mm, raft "
          f"{np.abs(cos.raft - mono.raft).max() / np.abs(mono.raft).max():.1e} relative, gap "
          f"{np.abs(cos.gap - mono.gap).max():.1e} m (round-off expected); split vs cosim gap "
          f"{np.abs(gap_split - cos.gap).max():.1e} m")
    print(f"\n{'native FMUs (C)':16s} {'wall s':>8s} {'CPU s':>8s} {'start-up s':>10s} {'us/step':>8s} "
          f"{'max uplift mm':>14s} {'vs monolithic':>13s}")
    rows = {"monolithic": (wall["monolithic"], cpu["monolithic"], float("nan"), mono.max_uplift()),
            "cosim (Python)": (wall["cosim"], cpu["cosim"],
                               median([i["timing"]["initialisation"] for _, _, i in runs["cosim"]]), cos.max_uplift())}
    rows.update({name: tuple(median([r[j] for r in v]) for j in range(4)) for name, v in native.items()})
    for name, (w, c, start, up) in rows.items():
        per_step = 1e6 * (w - (0.0 if np.isnan(start) else start)) / (nt - 1)
        print(f"{name:16s} {w:8.2f} {c:8.2f} {start:10.3f} {per_step:8.0f} {1e3 * up:14.6f} "
              f"{abs(up - mono.max_uplift()) / mono.max_uplift():13.1e}")
    print(f"(the {host_platform()} binary, built in {native_build_s:.1f} s; start-up: extraction, instantiation,"
          " initialisation;\n monolithic: its wall_s, stepper construction included; native coupled driven through"
          f" its ag_x, ag_y, ag_z inputs; raft\n native coupled vs monolithic "
          f"{np.abs(raft_c - mono.raft).max() / np.abs(mono.raft).max():.1e}, native pair vs cosim "
          f"{np.abs(npair.raft - cos.raft).max() / np.abs(cos.raft).max():.1e} relative)")
    nc = rows["native coupled"]
    print(f"native coupled / monolithic: wall {nc[0] / wall['monolithic']:.2f}, CPU {nc[1] / cpu['monolithic']:.2f}"
          f"; target < 1")
    if engines is not None:
        print(f"\n{'engine (once)':34s} {'start-up s':>10s} {'us/step':>8s} {'total s':>8s} {'max uplift mm':>14s} "
              f"{'vs monolithic':>13s} {'rotation':>9s}")
        rot = np.hypot(mono.raft[:, 3], mono.raft[:, 4]).max()
        for name, (start, total, up, r) in engines.items():
            print(f"{name:34s} {start:10.2f} {1e6 * (total - start) / (nt - 1):8.0f} {total:8.2f} {1e3 * up:14.6f} "
                  f"{abs(up - mono.max_uplift()) / mono.max_uplift():13.1e} {abs(r - rot) / rot:9.1e}")
        print("(start-up: extraction, instantiation, initialisation and the first step; vs monolithic: relative\n"
              " difference of the max uplift and of the max raft rotation, from the FMUs' headline outputs)")

    notes = {"initialisation": "stepper; cosim: + FMU extraction, instantiation, initialisation",
             "structure step": "Newmark-Newton step and the outputs it publishes",
             "soil step": "recursive convolution: history, commit, outputs",
             "transfers": "split: recording; cosim: FMI get/set of inputs, outputs, recording"}
    for clock, key in (("CPU", "timing_cpu"), ("wall", "timing")):
        print(f"\n{clock + ' s, medians':18s} {'split':>7s} {'cosim':>7s} {'FMU layer':>9s} {'us/step':>8s}  part")
        tot = np.zeros(3)
        for part, note in notes.items():
            a = median([info[key][part] for _, _, info in runs["split"]])
            b = median([info[key][part] for _, _, info in runs["cosim"]])
            tot += (a, b, b - a)
            print(f"{part:18s} {a:7.3f} {b:7.3f} {b - a:+9.3f} {1e6 * (b - a) / (nt - 1):+8.1f}  {note}")
        print(f"{'total':18s} {tot[0]:7.3f} {tot[1]:7.3f} {tot[2]:+9.3f} {1e6 * tot[2] / (nt - 1):+8.1f}")


if __name__ == "__main__":
    main()

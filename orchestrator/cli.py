"""The ``uplift`` command line.

Exit codes: 0 success; 1 a computation stopped (results written so far, reason printed);
2 bad input (scene, file, option). Machine-readable output (``--json``) goes to stdout as
exactly one JSON object; progress and messages go to stderr.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

EXIT_OK, EXIT_FAILED, EXIT_INPUT = 0, 1, 2


def default_cache_dir() -> Path:
    """Impedance/fit cache: $UPLIFT_CACHE, else ~/.cache/uplift."""
    env = os.environ.get("UPLIFT_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "uplift"


def _parser() -> argparse.ArgumentParser:
    from orchestrator.scene import builtin_scenes

    p = argparse.ArgumentParser(
        prog="uplift",
        description="Foundation uplift under earthquake: soil-structure interaction with BEM impedances.",
        epilog=f"built-in scenes: {', '.join(builtin_scenes())}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    imp = sub.add_parser("impedance", help="soil impedance of the scene's foundation (BEM sweep)",
                         description="Compute the rigid-raft (6x6) and rigid+gap (6+N) impedance tables of "
                                     "the scene's foundation over the scene's frequencies.")
    imp.add_argument("scene", help="scene TOML file or built-in scene name")
    imp.add_argument("-o", "--output", type=Path, help="write the rigid 6x6 table to this HDF5 file")
    imp.add_argument("--gap", type=Path, metavar="FILE",
                     help="also compute the rigid + N vertical gap DOFs table (6+N) and write it here")
    imp.add_argument("--plot", type=Path, help="plot k(a0) and c(a0) of each rigid DOF to this image")
    imp.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    imp.add_argument("--no-cache", action="store_true", help="recompute even if the sweep is cached")
    imp.set_defaults(func=cmd_impedance)

    fit = sub.add_parser("fit", help="rational soil model of the scene's impedance (vector fitting, passivity)",
                         description="Fit the scene's impedance table with a stable, passive, common-pole "
                                     "rational model K(s) = D + sE + sum R_k/(s - p_k).")
    fit.add_argument("scene", help="scene TOML file or built-in scene name")
    fit.add_argument("--tol", type=float, default=None,
                     help="relative Frobenius error over the band (default: [analysis].fit_tol, else 0.01)")
    fit.add_argument("--table", choices=("gap", "rigid"), default="gap",
                     help="which impedance: gap = rigid raft + N vertical soil DOFs, used by the time "
                          "routes (default); rigid = 6x6")
    fit.add_argument("-o", "--output", type=Path, help="write the fitted model and its report (HDF5)")
    fit.add_argument("--plot", type=Path, help="plot table vs model and the error per frequency")
    fit.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    fit.set_defaults(func=cmd_fit)

    exp = sub.add_parser("export", help="export the structure and soil FMUs and an SSP system",
                         description="Write structure.fmu, soil.fmu and system.ssd (FMI 2.0 co-simulation, "
                                     "fixed step) for the scene; libcosimpy runs the .ssd as it is.")
    exp.add_argument("scene", help="scene TOML file or built-in scene name")
    exp.add_argument("-o", "--output", type=Path, required=True, metavar="DIR", help="output directory")
    exp.set_defaults(func=cmd_export)

    cmp = sub.add_parser("compare", help="differences between the routes of a results file",
                         description="Compare the routes of a results file (max uplift, raft rotation, "
                                     "floor-spectrum peaks, run times) against a reference route.")
    cmp.add_argument("results", type=Path, help="results HDF5 file written by `uplift run`")
    cmp.add_argument("--reference", default=None, help="reference route (default: timefreq, else the first)")
    cmp.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    cmp.set_defaults(func=cmd_compare)

    rep = sub.add_parser("report", help="self-contained HTML report of a results file",
                         description="Write DIR/report.html (figures embedded) with the per-route summary, "
                                     "the route comparison and the paper's figures 3-6; the figures "
                                     "are also written to DIR as PNG.")
    rep.add_argument("results", type=Path, help="results HDF5 file written by `uplift run`")
    rep.add_argument("-o", "--output", type=Path, required=True, metavar="DIR", help="output directory")
    rep.add_argument("--reference", default=None, help="reference route of the comparison "
                                                       "(default: timefreq, else the first)")
    rep.set_defaults(func=cmd_report)

    bench = sub.add_parser("bench", help="run time against error of every route and its accuracy knobs",
                           description="For the disk-halfspace and reactor scenes, sweep each route's "
                                       "accuracy knobs (dt, fit tolerance, BEM element size, TF padding, "
                                       "contact penalty) and measure wall time and error against the "
                                       "route's own finest run and against the cross-route reference.")
    bench.add_argument("--quick", action="store_true",
                       help="disk-halfspace only, few knob values (about a minute or two)")
    bench.add_argument("--json", action="store_true", help="print the list of rows as one JSON value on stdout")
    bench.add_argument("--plot", type=Path, default=None, metavar="FILE",
                       help="plot wall time against error (log-log) per route to this image")
    bench.set_defaults(func=cmd_bench)

    run = sub.add_parser("run", help="run the scene's analyses (time-domain routes)",
                         description="Run the scene's analyses and write the results (HDF5) and a summary.")
    run.add_argument("scene", help="scene TOML file or built-in scene name")
    run.add_argument("-o", "--output", type=Path, default=None,
                     help="results HDF5 file (default: <scene>_results.h5 in the current directory)")
    run.add_argument("--route", action="append", dest="routes", metavar="R",
                     help="route to run (repeatable); default: the scene's [analysis].routes")
    run.add_argument("--plot-dir", type=Path, default=None, help="write figures to this directory")
    run.add_argument("--json", action="store_true", help="print one JSON summary object on stdout")
    run.set_defaults(func=cmd_run)
    return p


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    from orchestrator.errors import UserInputError, ComputationError

    try:
        return args.func(args)
    except UserInputError as exc:
        print(f"uplift: error: {exc}", file=sys.stderr)
        return EXIT_INPUT
    except ComputationError as exc:
        print(f"uplift: stopped: {exc}", file=sys.stderr)
        return EXIT_FAILED
    except BrokenPipeError:
        # stdout closed early (e.g. piped into `head`): nothing more to say
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_OK


def cmd_impedance(args) -> int:
    from orchestrator.progress import Progress, frequency_bar
    from orchestrator.scene import load_scene
    from orchestrator.impedance import rigid_json, scene_impedance

    t0 = time.perf_counter()
    scene = load_scene(args.scene)
    cache = None if args.no_cache else default_cache_dir()
    outputs = ("rigid", "gap") if args.gap else ("rigid",)
    tables = scene_impedance(scene, outputs, cache_dir=cache, progress=frequency_bar(Progress(f"impedance {scene.name}")))
    wall = time.perf_counter() - t0
    for name, path in (("rigid", args.output), ("gap", args.gap)):
        if path:
            tables[name].save(path)
            print(f"wrote {path} ({name} table)", file=sys.stderr)
    if args.plot:
        from orchestrator.impedance import scene_static
        from orchestrator.plots import plot_impedance
        plot_impedance(tables["rigid"], scene, args.plot, static=scene_static(scene, cache_dir=cache))
        print(f"wrote {args.plot}", file=sys.stderr)
    if args.json:
        print(json.dumps(rigid_json(tables["rigid"], wall)))
    else:
        _print_rigid_summary(tables["rigid"], wall, file=sys.stderr)
    return EXIT_OK


def _print_rigid_summary(table, wall, file):
    import numpy as np

    diag = np.diagonal(table.matrices, axis1=1, axis2=2)
    print(f"rigid impedance, {len(table.frequencies_hz)} frequencies, {wall:.2f} s", file=file)
    print("   f (Hz) " + "".join(f"{d:>24s}" for d in table.dofs), file=file)
    for f, row in zip(table.frequencies_hz, diag):
        print(f"{f:9.3f} " + "".join(f"{z.real:12.4e}{z.imag:+12.4e}" for z in row), file=file)


def cmd_fit(args) -> int:
    from orchestrator.impedance import scene_impedance
    from orchestrator.progress import Progress, frequency_bar
    from orchestrator.run import scene_fit_tol
    from orchestrator.scene import load_scene
    from soil_impedance.fit import fit_table, save_fit

    t0 = time.perf_counter()
    scene = load_scene(args.scene)
    tol = args.tol if args.tol is not None else scene_fit_tol(scene)
    cache = default_cache_dir()
    table = scene_impedance(scene, (args.table,), cache_dir=cache,
                            progress=frequency_bar(Progress(f"impedance {scene.name}")))[args.table]
    result = fit_table(table, tol=tol, cache_dir=cache, node_xy=scene.mesh.xy if args.table == "gap" else None)
    if args.output:
        save_fit(result, args.output)
        print(f"wrote {args.output}", file=sys.stderr)
    if args.plot:
        result.plot(table, args.plot)
        print(f"wrote {args.plot}", file=sys.stderr)
    out = dict(result.report.summary(), wall_s=time.perf_counter() - t0)
    if args.json:
        print(json.dumps(out))
    else:
        print(f"{args.table} table of {scene.name}: {out['order']} poles, max relative error "
              f"{100 * out['max_rel_error']:.2f} % (tol {100 * tol:g} %), passive: {out['passive']} "
              f"(margin {out['passivity_margin']:.3g}), {out['wall_s']:.1f} s", file=sys.stderr)
    return EXIT_OK


def cmd_export(args) -> int:
    from orchestrator.cosim import scene_soil_model
    from orchestrator.export import export_scene
    from orchestrator.run import scene_fit_tol
    from orchestrator.scene import load_scene

    scene = load_scene(args.scene)
    model = scene_soil_model(scene, cache_dir=default_cache_dir(), tol=scene_fit_tol(scene))
    exported = export_scene(scene, args.output, model, cache_dir=default_cache_dir())
    for path in (exported.structure, exported.soil, exported.ssd):
        print(f"wrote {path}", file=sys.stderr)
    return EXIT_OK


def cmd_compare(args) -> int:
    from orchestrator.compare import compare, format_table
    from orchestrator.results import read_results

    if not args.results.is_file():
        raise FileNotFoundError(f"results file {str(args.results)!r} does not exist: run `uplift run SCENE -o FILE` first")
    results = read_results(args.results)
    if args.reference is not None and args.reference not in results:
        raise FileNotFoundError(f"--reference {args.reference!r} is not in {args.results} "
                                f"(routes: {', '.join(results)})")
    table = compare(results, reference=args.reference)
    if args.json:
        print(json.dumps(table))
    else:
        print(format_table(table))
    return EXIT_OK


def cmd_report(args) -> int:
    from orchestrator.report import write_report

    path = write_report(args.results, args.output, reference=args.reference)
    print(f"wrote {path}", file=sys.stderr)
    return EXIT_OK


def cmd_bench(args) -> int:
    from orchestrator.bench import run_bench_cli
    return run_bench_cli(args)


def cmd_run(args) -> int:
    from orchestrator.run import run_scene_cli
    return run_scene_cli(args)


if __name__ == "__main__":
    sys.exit(main())

"""The ``uplift`` command line: parsing, printing, exit codes.

Exit codes (orchestrator.exit_codes): 0 success; 1 a computation stopped (results written so
far, reason printed); 2 bad input (scene, file, option, a tool the machine lacks:
orchestrator.exit_codes); 3 an output could not be written (a full disk, a quota: one line naming
the path, nothing written, a previous file at -o left as it was); 130 interrupted (Ctrl-C at any
instant: one line on stderr saying whether the output was committed, no output half-written, a
previous file at -o left as it was unless the new one was committed whole). Every output path is
checked before any computation.
A command's answer (a summary, a table) goes to stdout; machine-readable output (``--json``)
goes to stdout as exactly one strict JSON object (no NaN or Infinity: ``strict_json``); progress,
``wrote ...`` lines and messages go to stderr. This is the only module that prints.
"""
from __future__ import annotations

import sys

from uplift_common import interrupts

if interrupts.started_as("orchestrator.cli", "uplift"):
    # the program itself (not a test importing it): a Ctrl-C while the modules below load (a
    # second or two) is counted, not raised mid-import; main() then stops at once (exit 130).
    # orchestrator/__init__.py did it already (before this module's source was even compiled)
    interrupts.install(held=True)

import argparse
import contextlib
import gc
import importlib.util
import json
import math
import os
import time
from dataclasses import replace
from pathlib import Path

# the start-up cost of a command is what it imports: `uplift --help`, `uplift COMMAND --help` and
# `uplift scene` load none of numpy, scipy, h5py, the FMU stack or dask (tests/orchestration/
# test_light_commands.py). Only these light modules load here; each command imports what it
# uses (the scene, the routes' computations, results files, ensembles, plots, reports, fits)
from orchestrator.ensemble import CONNECT_TIMEOUT_S, DT_CHECKS       # the package's namespace only
from orchestrator.exit_codes import (EXIT_FAILED, EXIT_INPUT, EXIT_INTERRUPTED, EXIT_OK, EXIT_WRITE, STOPPED,
                                     USER_INPUT, WRITE_FAILED)
from orchestrator.progress import Progress, labelled_bars
from orchestrator.routes import route_names                          # the names: no route's module
from orchestrator.scene_base import MAX_PGA_G, SceneError, builtin_scenes, tomllib
from orchestrator.settings import FMU_KINDS, compute_threads, default_cache_dir
from uplift_common.errors import UserInputError
from uplift_common.interrupts import REFUSED_ERRNOS, committed
from uplift_common.lazy import UNUSED_NUMPY, defer_modules

class OptionError(UserInputError):
    """Command-line options that cannot go together; the message says which to drop."""


class SetupError(UserInputError):
    """The machine lacks something a command needs (e.g. the C compiler of a native export);
    the message names it and how to get it."""


#: where the terms of the help texts are explained (every --help ends with it)
GLOSSARY = "terms (route, a0, precheck, PEER triplet, HHT, SSP, ...): docs/glossary.md"
#: the files ``uplift export`` writes into its folder
EXPORT_FILES = ("structure.fmu", "soil.fmu", "coupled.fmu", "system.ssd", "system.ssp")
#: the files of a cross-check folder of model M
CROSS_CHECK_FILES = ("{}.fmu", "{}_in.csv", "{}_ref.csv", "{}_ref.opt", "README.md")


def _fraction(text: str) -> float:
    """argparse type: a number in (0, 1)."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(v) and 0 < v < 1):
        raise argparse.ArgumentTypeError(f"{text!r} must lie in (0, 1), e.g. 0.01 for 1 %")
    return v


def _positive(text: str) -> float:
    """argparse type: a finite number > 0."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"{text!r} must be a finite number > 0")
    return v


def _non_negative(text: str) -> float:
    """argparse type: a finite number >= 0."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(v) and v >= 0):
        raise argparse.ArgumentTypeError(f"{text!r} must be a finite number >= 0")
    return v


#: the distribution whose version ``uplift --version`` prints (``uplift`` on the package index is another project)
DISTRIBUTION = "uplift-ssi"


def version() -> str:
    """The installed distribution's version (its metadata); not installed (a checkout on
    PYTHONPATH): the version of the checkout's pyproject.toml, marked so, else "unknown"."""
    import importlib.metadata                       # start-up cost: only --version reads the metadata
    try:
        return importlib.metadata.version(DISTRIBUTION)
    except importlib.metadata.PackageNotFoundError:
        pass
    pyproject = Path(__file__).resolve().parents[1] / "pyproject.toml"
    try:
        project = tomllib.loads(pyproject.read_text()).get("project", {})
        if project.get("name") == DISTRIBUTION and project.get("version"):
            return f"{project['version']} (not installed: the version of {pyproject})"
    except (OSError, ValueError):
        pass
    return "unknown (not installed: pip install -e . in the project's folder)"


class _Version(argparse.Action):
    """``--version``: print the version and exit; the distribution's metadata is read only then
    (importlib.metadata costs every other command a start-up it does not need)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        sys.stdout.write(f"uplift ({DISTRIBUTION}) {version()}\n")       # stdout, as argparse's own action
        parser.exit()


def _count(text: str) -> int:
    """argparse type: an integer >= 1."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"{text!r} must be an integer >= 1")
    return v


#: the exit codes, as ``uplift --help`` lists them (orchestrator.exit_codes, docs/conventions.md)
EXIT_CODES_HELP = (f"exit codes: {EXIT_OK} done, {EXIT_FAILED} a computation stopped (results so far written), "
                   f"{EXIT_INPUT} bad input, {EXIT_WRITE} an output could not be written (disk full: nothing "
                   f"written, the old file kept), {EXIT_INTERRUPTED} interrupted (Ctrl-C)")


class _OneCommand:
    """argparse's subcommands ``sub`` with every command registered (its name and help line: the
    commands' list, ``uplift --help``, a mistyped command's message) but, when ``only`` is given,
    the arguments of that command only: ``add_parser`` of another returns a ``_Skipped`` parser,
    whose arguments are never made (a command line is parsed by its own command's parser; the
    others' options cost 5-10 ms of every command's start)."""

    def __init__(self, sub, only: str | None):
        self._sub, self._only = sub, only

    def add_parser(self, name, **kwargs):
        parser = self._sub.add_parser(name, **kwargs)
        return parser if self._only is None or name == self._only else _Skipped()

    def __getattr__(self, name):              # choices, ...: argparse's own
        return getattr(self._sub, name)


class _Skipped:
    """A command's parser that is not used by this command line: every call (add_argument,
    set_defaults, groups) does nothing and returns the parser itself."""

    def __getattr__(self, name):
        return lambda *args, **kwargs: self


def _parser(only: str | None = None) -> argparse.ArgumentParser:
    """The command line's parser; ``only``: a command name, whose arguments alone are made
    (``_OneCommand``: for parsing a command line that starts with it)."""
    p = argparse.ArgumentParser(
        prog="uplift",
        description="Foundation uplift under earthquake: soil-structure interaction with BEM impedances.",
        epilog=f"built-in scenes: {', '.join(builtin_scenes())}; routes: {', '.join(route_names())}; "
               f"`uplift COMMAND --help` for a command's options; {EXIT_CODES_HELP}")
    p.add_argument("--version", action=_Version, help="print the version of the installed uplift-ssi and exit")
    sub = _OneCommand(p.add_subparsers(dest="command", required=True, metavar="COMMAND"), only)

    def scene_arg(cmd):
        cmd.add_argument("scene", help="scene TOML file or built-in scene name")

    def no_cache(cmd):
        cmd.add_argument("--no-cache", action="store_true",
                         help="neither read nor write the impedance and fit cache ($UPLIFT_CACHE, ~/.cache/uplift)")

    def json_flag(cmd, what="print one JSON object on stdout"):
        cmd.add_argument("--json", action="store_true", help=what)

    def max_pga(cmd):
        cmd.add_argument("--max-pga", type=_positive, default=None, metavar="G",
                         help=f"refuse motions peaking above G g (default: the scene's [analysis].max_pga_g, else "
                              f"{MAX_PGA_G:g} g)")

    run = sub.add_parser("run", help="run the scene's analyses (time-domain routes)",
                         description="Run the scene's analyses and write the results (HDF5) and a summary.")
    scene_arg(run)
    run.add_argument("-o", "--output", type=Path, default=None,
                     help="results HDF5 file (default: <scene>_results.h5 in the current directory)")
    run.add_argument("--route", action="append", dest="routes", metavar="R", choices=route_names(),
                     help=f"route to run (repeatable; {', '.join(route_names())}); default: the scene's "
                          "[analysis].routes")
    run.add_argument("--plot-dir", type=Path, default=None, help="write figures to this directory")
    run.add_argument("--design-dir", type=Path, default=None, metavar="DIR",
                     help="write the design floor spectra ([output] design_spectra) as CSV tables and figures to "
                          "this directory (default: <output stem>_design next to the results file)")
    json_flag(run, "print one JSON summary object on stdout")
    max_pga(run)
    run.add_argument("--pga", type=_positive, default=None, metavar="G",
                     help="peak ground acceleration, g: replaces [motion].pga_g (a record: scales it so that its "
                          "stronger horizontal peaks at G); recorded in the results file and the summary")
    run.add_argument("--dt", type=_positive, default=None, metavar="S",
                     help="time step, s: replaces [analysis].dt (recorded likewise)")
    run.add_argument("--duration", type=_positive, default=None, metavar="S",
                     help="length of the synthetic motion, s: replaces [motion].duration_s (recorded likewise)")
    run.add_argument("--dry-run", action="store_true",
                     help="compute nothing: load the scene, print each stage's estimated peak memory (sweep, fit, "
                          "stepping, ...) against the machine's available memory, exit 2 if the run would be refused")
    no_cache(run)
    run.set_defaults(func=cmd_run)

    scn = sub.add_parser("scene", help="write a built-in scene as a commented TOML file",
                         description="Write the built-in scene NAME as TOML, every key explained with its unit; "
                                     "the file runs as it is (`uplift run FILE` equals `uplift run NAME`): the "
                                     "files it names are copied beside it.")
    scn.add_argument("name", metavar="NAME", help=f"built-in scene ({', '.join(builtin_scenes())})")
    scn.add_argument("-o", "--output", type=Path, default=None, metavar="FILE",
                     help="write the scene to FILE (default: print it on stdout)")
    scn.set_defaults(func=cmd_scene, computes=False)        # no thread pools to limit (threadpoolctl not loaded)

    cch = sub.add_parser("cache", help="what the cache folder holds; remove the entries not used lately",
                         description="List the cache folder's entries by kind (impedance tables, fits, the "
                                     "time-frequency set-up, compiled runtimes, ...): count, size and the oldest "
                                     "use. Entries are keyed on their inputs and on the code that makes them, so "
                                     "old ones are never read again after an upgrade: --prune removes those not "
                                     "used for DAYS days (a later run recomputes what it needs). Only the "
                                     "project's entries are touched, never other files in the folder.")
    cch.add_argument("--prune", type=_non_negative, default=None, metavar="DAYS",
                     help="remove the entries not read or written for DAYS days (0: every entry)")
    json_flag(cch)
    cch.set_defaults(func=cmd_cache, computes=False)

    imp = sub.add_parser("impedance", help="soil impedance of the scene's foundation (BEM sweep)",
                         description="Compute the rigid-raft (6x6) and rigid+gap (6+N) impedance tables of "
                                     "the scene's foundation over the scene's frequencies, and estimate the "
                                     "discretisation error of its static rigid terms (the mesh against the same "
                                     "raft refined; printed, and in --json as discretisation_error).")
    scene_arg(imp)
    imp.add_argument("-o", "--output", type=Path, help="write the rigid 6x6 table to this HDF5 file")
    imp.add_argument("--gap", type=Path, metavar="FILE",
                     help="also compute the rigid + N vertical gap DOFs table (6+N) and write it here")
    imp.add_argument("--plot", type=Path, help="plot k(a0) and c(a0) of each rigid DOF to this image")
    json_flag(imp)
    no_cache(imp)
    imp.set_defaults(func=cmd_impedance)

    fit = sub.add_parser("fit", help="rational soil model of the scene's impedance (vector fitting, passivity)",
                         description="Fit the scene's impedance table with a stable, passive, common-pole "
                                     "rational model K(s) = D + sE + sum R_k/(s - p_k).")
    scene_arg(fit)
    fit.add_argument("--tol", type=_fraction, default=None,
                     help="relative Frobenius error over the band, in (0, 1) (default: [analysis].fit_tol, "
                          "else 0.01)")
    fit.add_argument("--table", choices=("gap", "rigid"), default="gap",
                     help="which impedance: gap = rigid raft + N vertical soil DOFs, used by the time "
                          "routes (default); rigid = 6x6")
    fit.add_argument("-o", "--output", type=Path, help="write the fitted model and its report (HDF5)")
    fit.add_argument("--plot", type=Path, help="plot table vs model and the error per frequency")
    json_flag(fit)
    no_cache(fit)
    fit.set_defaults(func=cmd_fit)

    exp = sub.add_parser("export", help="export the structure and soil FMUs and an SSP system",
                         description="Write structure.fmu, soil.fmu, coupled.fmu, system.ssd and system.ssp "
                                     "(FMI 2.0 co-simulation, fixed step; FMI 3.0 with --fmi-version 3) for the "
                                     "scene; libcosimpy runs the FMI 2.0 .ssd as it is. With --cross-check, also "
                                     "the FMI cross-check folders of the three FMUs with their reference results.")
    scene_arg(exp)
    exp.add_argument("-o", "--output", type=Path, required=True, metavar="DIR", help="output directory")
    exp.add_argument("--kind", choices=FMU_KINDS[::-1], default="native",
                     help="native (default): compiled C for linux64, win64 and darwin64, no Python needed by the "
                          "host; python: pythonfmu (the host needs Python with numpy and scipy). The same "
                          "variables and the same answers (docs/native.md)")
    exp.add_argument("--fmi-version", type=int, choices=(2, 3), default=2,
                     help="2 (default: what most tools load today) or 3: FMI 3.0 FMUs of the native kind, "
                          "interface vectors as arrays, binaries also for aarch64-darwin (docs/fmus.md)")
    exp.add_argument("--cross-check", type=Path, default=None, metavar="XDIR",
                     help="write XDIR/fmus/<2.0|3.0>/cs/<platform>/uplift/<version>/<Model>/ for each FMU (the FMU, "
                          "<Model>_in.csv, <Model>_ref.csv, <Model>_ref.opt, README.md; see docs/fmus.md), "
                          "checked with fmpy's cross-check validator")
    no_cache(exp)
    exp.set_defaults(func=cmd_export)

    cmp = sub.add_parser("compare", help="differences between the routes of a results file",
                         description="Compare the routes of a results file (max uplift, raft rotation, "
                                     "floor-spectrum peaks, run times) against a reference route.")
    cmp.add_argument("results", type=Path, help="results HDF5 file written by `uplift run`")
    cmp.add_argument("--reference", default=None,
                     help="reference route (default: the most exact present: timefreq, else monolithic, else cosim, "
                          "else the first with uplift; never linear, which lets nothing lift)")
    json_flag(cmp)
    cmp.set_defaults(func=cmd_compare)

    rep = sub.add_parser("report", help="self-contained HTML report of a results or ensemble file",
                         description="Write DIR/report.html (figures embedded) with the per-route summary, "
                                     "the route comparison and the paper's figures 3-6; the figures "
                                     "are also written to DIR as PNG. For an ensemble file (`uplift "
                                     "ensemble`): the fractiles per PGA, max uplift against PGA and the "
                                     "fractile floor spectra per PGA.")
    rep.add_argument("results", type=Path, help="results HDF5 file written by `uplift run` (or `uplift ensemble`)")
    rep.add_argument("-o", "--output", type=Path, required=True, metavar="DIR", help="output directory")
    rep.add_argument("--reference", default=None, help="reference route of the comparison (default: as "
                                                       "`uplift compare`: timefreq, else monolithic, else cosim)")
    rep.add_argument("--pushover", action="append", default=[], metavar="FILE|SCENE",
                     help="draw the runs on this static pushover curve: a file of `uplift pushover` (of the same "
                          "scene, else refused) or the scene to push over; repeat for both soils (default: the "
                          "built-in scene of the file's scene name, when it is the same scene)")
    rep.set_defaults(func=cmd_report)

    ens = sub.add_parser("ensemble", help="the scene under many records and PGAs (dask), fractiles over records",
                         description="Run the scene under each record (or seed of its synthetic motion) "
                                     "scaled to each PGA, on a dask.distributed cluster (one BEM sweep and "
                                     "one fit for all), and write every cell and the fractiles over the "
                                     "records (netCDF4/HDF5, xarray). A rerun with the same -o computes only "
                                     "the cells not done yet.")
    scene_arg(ens)
    ens.add_argument("--records", nargs="+", type=Path, metavar="PATH",
                     help="record folders, each one record of up to three components (a PEER triplet told by "
                          "its file names, or by a components.toml in the folder), or record files, each one "
                          "component on the scene's [motion].direction (*.AT2: PEER; *.txt, *.dat: two-column, "
                          "or the scene's [motion] format); default: the scene's motion")
    seeds = ens.add_mutually_exclusive_group()
    seeds.add_argument("--n-seeds", type=_count, default=None, metavar="N",
                       help="without --records: N synthetic motions of the scene, seeds 0, 1, ..., N-1 "
                            "(--n-seeds 8: seeds 0 to 7)")
    seeds.add_argument("--seeds", nargs="+", type=int, metavar="S",
                       help="without --records: these seeds of the scene's synthetic motion, each all its "
                            "components (--seeds 3 runs one motion, seed 3; --seeds 3 5 9 three); default: the "
                            "scene's [motion].seed")
    ens.add_argument("--pga", nargs="+", type=float, required=True, metavar="G",
                     help="peak ground accelerations (g) each record is scaled to")
    ens.add_argument("--route", action="append", dest="routes", metavar="R", choices=route_names(),
                     help=f"route to run (repeatable; {', '.join(route_names())}); default: the scene's "
                          "[analysis].routes")
    where = ens.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=None, metavar="N",
                       help="worker processes of a local dask cluster (default: the usable cores)")
    where.add_argument("--scheduler", default=None, metavar="ADDRESS",
                       help="address of a running dask scheduler (e.g. tcp://10.0.0.5:8786) instead")
    ens.add_argument("--connect-timeout", type=_positive, default=CONNECT_TIMEOUT_S, metavar="S",
                     help=f"seconds the scheduler has to answer (default {CONNECT_TIMEOUT_S:g})")
    ens.add_argument("--dt-check", choices=DT_CHECKS, default="strongest",
                     help="step-doubling check of the time step: once on the strongest motion (default) or "
                          "on each cell's motion, as `uplift run` does (about one run more per cell)")
    ens.add_argument("--case", default=None, metavar="NAME",
                     help="a scene with [soil] cases or strain_compatible: run the ensemble on this soil case "
                          "(e.g. be, lb, ub; the strain-compatible soil is that of the scene's own motion)")
    ens.add_argument("-o", "--output", type=Path, default=None,
                     help="ensemble file (default: <scene>_ensemble.h5); completed cells are kept in "
                          "<output>.cells/")
    json_flag(ens, "print one JSON summary object on stdout")
    max_pga(ens)
    no_cache(ens)
    ens.set_defaults(func=cmd_ensemble)
    env = sub.add_parser("envelope", help="design floor spectra of ensembles: fractiles broadened, enveloped over cases",
                         description="The fractile floor spectra of ensemble files (one per soil case: `uplift "
                                     "ensemble SCENE --case NAME`), broadened +-BROADENING in frequency about their "
                                     "peaks and enveloped over the files, per PGA, route, node and direction, as "
                                     "CSV tables (frequency Hz, acceleration g); docs/design_basis.md.",
                         epilog=GLOSSARY)
    env.add_argument("ensembles", nargs="+", type=Path, metavar="ENSEMBLE", help="ensemble files of `uplift ensemble`")
    env.add_argument("-o", "--output", type=Path, required=True, metavar="DIR", help="folder of the tables")
    env.add_argument("--quantile", type=float, choices=(0.16, 0.5, 0.84), default=0.84,
                     help="fractile over the records (default 0.84)")
    env.add_argument("--broadening", type=_fraction, default=0.15, metavar="R",
                     help="relative half-width of the peak broadening (default 0.15)")
    json_flag(env)
    env.set_defaults(func=cmd_envelope)
    _fragility_parser(sub, json_flag)
    _pushover_parser(sub, json_flag, scene_arg, no_cache)

    bch = sub.add_parser("bench", help="run time against error of every route and its accuracy knobs",
                         description="For the disk-halfspace and reactor scenes, sweep each route's "
                                     "accuracy knobs (dt, fit tolerance, BEM element size, TF padding, "
                                     "contact penalty) and measure wall time and error against the "
                                     "route's own finest run and against the cross-route reference.")
    bch.add_argument("--quick", action="store_true",
                     help="disk-halfspace only, few knob values (about a minute or two)")
    json_flag(bch, "print the list of rows as one JSON value on stdout")
    bch.add_argument("--plot", type=Path, default=None, metavar="FILE",
                     help="plot wall time against error (log-log) per route to this image")
    no_cache(bch)
    bch.set_defaults(func=cmd_bench)
    # every --help names the glossary of the terms it uses
    p.epilog = f"{p.epilog}; {GLOSSARY}" if p.epilog else GLOSSARY
    for cmd in sub.choices.values():
        cmd.epilog = f"{cmd.epilog}; {GLOSSARY}" if cmd.epilog else GLOSSARY
    return p


def command_list(parser: argparse.ArgumentParser) -> str:
    """The commands of ``parser``, one line each: name and its one-line help."""
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    actions = sub._choices_actions          # what argparse's own help lists: one per command, in order
    width = max(len(a.dest) for a in actions)
    return "\n".join(f"  {a.dest:<{width}}  {a.help}" for a in actions)


def main(argv=None) -> int:
    """Run the command of ``argv`` (None: the program's arguments) and return its exit code
    (module docstring). A Ctrl-C at any instant ends in exit 130 and one line saying what was
    written (``uplift_common.interrupts``); run as the program (``argv`` None), SIGINT is ignored
    once the outcome is known, so that the process is never killed by it on its way out."""
    program = argv is None
    previous = interrupts.install()
    before = len(committed())
    outcome = None
    try:
        try:
            if interrupts.received():             # a Ctrl-C while the modules loaded
                raise KeyboardInterrupt
            argv = sys.argv[1:] if program else list(argv)
            outcome = _run(argv)
        finally:
            interrupts.hold_for_exit(ignore=program)
    except KeyboardInterrupt:
        pass
    interrupts.hold_for_exit(ignore=program)
    try:
        if interrupts.received() or outcome is None:
            print(_interrupted_line(committed()[before:], "ensemble" in (argv or ())[:1]), file=sys.stderr)
            return EXIT_INTERRUPTED
        code, message = outcome
        if message:
            print(message, file=sys.stderr)
        return code
    finally:
        if not program:
            interrupts.restore(previous)
        else:
            _freeze_for_exit()


def _cache_path(args) -> Path | None:
    """The cache folder of ``args``'s command (None with --no-cache, or for a command that
    uses no cache)."""
    return None if getattr(args, "no_cache", True) else default_cache_dir()


@contextlib.contextmanager
def _compiled_once(fresh: bool, folder=None):
    """A command in a fresh process (``fresh``; else nothing changes): the methods its
    dataclasses generate are compiled once and kept in the cache ``folder``
    (``uplift_common.generated_code``: about 250 sources, 50-60 ms of a warm ``uplift run``'s
    imports; None: compiled as before, not kept); the new ones are saved at the end."""
    if not fresh:
        yield
        return
    from uplift_common.generated_code import GeneratedCode, code_file, installed   # only in a fresh process
    codes = GeneratedCode(None if folder is None else code_file(folder))
    try:
        with installed(codes):
            yield
    finally:
        codes.save()


@contextlib.contextmanager
def _loading(fresh: bool = True):
    """A command's imports in a fresh process (``fresh``; else nothing changes): numpy, h5py and
    the project's modules make tens of thousands of objects that live until the exit, and the
    cyclic collector, run every 700 allocations, would traverse them again and again while they
    are made (about 60 collections, 10-20 ms of a warm ``uplift run``, which find almost nothing).
    The block runs without it; after the block the objects made so far go to its permanent
    generation (``gc.freeze``: the command's own collections do not traverse them either) and
    the collector is back as it was (the command's garbage cycles are collected as before).
    Never in a process that has loaded numpy already (a test calling ``main``): what its
    collector has not freed yet would be kept to its end."""
    if not fresh:
        yield
        return
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        gc.freeze()
        if enabled:
            gc.enable()


def _freeze_for_exit() -> None:
    """The program's last step: move every object the command made to the collector's permanent
    generation (``gc.freeze``), so that the interpreter's exit does not run its cyclic collections
    over them (about 0.1 s CPU of a warm ``uplift run reactor``, most of the exit's cost). Nothing
    else of the exit changes: the atexit handlers, the flush of stdout and stderr and the join of
    other threads still run, and objects are still freed as their modules are cleared; only
    garbage cycles left at the exit are not collected (the process's end frees their memory, and
    HDF5 closes, flushed, a file such a cycle would still hold open when the library exits)."""
    gc.freeze()


def _interrupted_line(written, ensemble: bool = False) -> str:
    """The one line of an interrupted command: which outputs it had written (whole) before the
    Ctrl-C, if any; the cache's entries and an ensemble's finished cells are not outputs."""
    cache = default_cache_dir().resolve()
    outputs = [p for p in written if cache not in p.resolve().parents and not p.parent.name.endswith(".cells")]
    if outputs:
        return (f"uplift: interrupted after writing {', '.join(map(str, dict.fromkeys(outputs)))} (whole: the "
                "new output was committed); nothing else was written")
    return ("uplift: interrupted before the output was committed: nothing was written, a previous file at the "
            "output path is left as it was" + (" (the finished runs are kept in <output>.cells/ for a rerun)"
                                               if ensemble else ""))


def _run(argv) -> tuple:
    """(exit code, the error line or None) of the command of ``argv``; a KeyboardInterrupt
    goes through."""
    parser = _parser(argv[0] if argv and not argv[0].startswith("-") else None)
    if not argv:        # no command: the commands, one line each (a missing command is bad input: exit 2)
        print(f"{parser.format_usage()}\ncommands:\n{command_list(parser)}\n\n"
              "`uplift COMMAND --help` for a command's options, `uplift --help` for more\n"
              "uplift: error: give a COMMAND, e.g. uplift run reactor", file=sys.stderr)
        return EXIT_INPUT, None
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:        # argparse: --help (0) or a bad argument (2, message printed)
        return int(exc.code or 0), None
    try:
        if not getattr(args, "computes", True):
            return args.func(args), None
        with _compiled_once("numpy" not in sys.modules, _cache_path(args)):
            if "scipy" not in sys.modules:  # a fresh process: what scipy's import lists but no command uses
                with _loading("numpy" not in sys.modules):
                    defer_modules(UNUSED_NUMPY)  # loads on first use, not on scipy's import (~0.2 s); numpy loads
            with compute_threads():
                return args.func(args), None
    except WRITE_FAILED as exc:       # a full disk: nothing written, the old output intact
        return EXIT_WRITE, f"uplift: error: {exc}"
    except USER_INPUT as exc:
        return EXIT_INPUT, f"uplift: error: {exc}"
    except STOPPED as exc:
        return EXIT_FAILED, f"uplift: stopped: {exc}"
    except BrokenPipeError:
        # stdout closed early (e.g. piped into `head`): nothing more to say
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_OK, None
    except OSError as exc:
        refused = _refused_write(exc)
        if refused is None:
            raise
        return EXIT_WRITE, refused


def _refused_write(exc) -> str | None:
    """The one line of an OSError of a file system that refused data outside an atomic write
    (uplift_common.files.REFUSED_ERRNOS), or None."""
    if exc.errno not in REFUSED_ERRNOS:
        return None
    where = f" {exc.filename!r}" if exc.filename else ""
    return f"uplift: error: cannot write{where}: {REFUSED_ERRNOS[exc.errno]}; free some space and run the command again"


def _cache(args):
    return None if args.no_cache else default_cache_dir()


def _say(*lines):
    """Messages (what was written, warnings, progress notes): stderr."""
    for line in lines:
        print(line, file=sys.stderr)


def _out(*lines):
    """A command's answer (a summary, a table): stdout, what ``uplift CMD > file`` keeps."""
    for line in lines:
        print(line)


def strict_json(value):
    """``value`` with every non-finite number (NaN, ±inf: strict JSON has no word for them)
    replaced by None, and a dict holding one (directly or in a list) given a ``missing`` dict
    that says why under the same key (reasons already there are kept). numpy scalars become
    Python numbers."""
    return _strict(value)[0]


def _strict(value):
    """(strict value, reason it is missing or None)."""
    if isinstance(value, dict):
        out, why = {}, {}
        for k, v in value.items():
            out[k], reason = _strict(v)
            if reason:
                why[k] = reason
        if why:
            given = out.get("missing")
            out["missing"] = {**why, **(given if isinstance(given, dict) else {})}
        return out, None
    if isinstance(value, (list, tuple)):
        items = [_strict(v) for v in value]
        reasons = [r for _, r in items if r]
        return [v for v, _ in items], (f"null entries: {reasons[0]}" if reasons else None)
    np = sys.modules.get("numpy")           # numpy numbers exist only once numpy is loaded
    if isinstance(value, float) or (np is not None and isinstance(value, np.floating)):
        if math.isfinite(value):
            return float(value), None
        return None, f"not a finite number ({float(value)}): the computation gave none"
    if np is not None and isinstance(value, (np.integer, np.bool_)):
        return value.item(), None
    return value, None


def _print_json(value):
    """One strict JSON object on stdout (no NaN or Infinity, see strict_json)."""
    print(json.dumps(strict_json(value), allow_nan=False))


def cmd_run(args) -> int:
    if args.dry_run:
        return _dry_run(args)
    # start-up cost: what a run uses loads in it (the other commands do not pay it)
    with _loading("h5py" not in sys.modules):
        from orchestrator.motion import G                                        # (same)
        from orchestrator.results_file import check_output_folder, check_output_path, summary, write_results  # (same)
        from orchestrator.run import run_scene                                   # (same)
        from orchestrator.scene import is_design, load_scene                     # (same; not orchestrator.design)
        from orchestrator.scene_file import scene_toml                           # (same)
        from structure.results import Status                                     # (same)
    scene = load_scene(args.scene, max_pga_g=args.max_pga, pga_g=args.pga, dt=args.dt, duration_s=args.duration)
    out = check_output_path(args.output or Path(f"{scene.name}_results.h5"))
    if args.plot_dir is not None:
        check_output_folder(args.plot_dir, _pngs(args.plot_dir), "--plot-dir")
    if is_design(scene):
        return _run_design(args, scene, out)
    if args.design_dir is not None:
        raise OptionError(f"--design-dir: scene {scene.name!r} asks for no design spectra; add [output] "
                          "design_spectra = { damping = [0.05] } (docs/design_basis.md), or drop --design-dir")
    results, motion = run_scene(scene, args.routes, cache_dir=_cache(args),
                                progress=labelled_bars(f"run {scene.name} [{{label}}]"),
                                sweep_progress=Progress(f"impedance {scene.name}"),
                                fit_progress=labelled_bars(f"fit {scene.name}: {{label}}"))
    write_results(out, results, motion, scene.name, scene_toml(scene), scene.overrides, scene.mesh, scene.mesh_source)
    _say(f"wrote {out}")
    summ = {"motion": {"label": motion.label, "components": list(motion.components),
                       "pga_g": {a: float(p) / G for a, p in zip("xyz", motion.pga) if a in motion.components}},
            "overrides": list(scene.overrides),
            "routes": {r: summary(res) for r, res in results.items()}}
    if args.plot_dir:
        from orchestrator.plots import plot_run                  # start-up cost: only with --plot-dir
        _say(*(f"wrote {path}" for path in plot_run(results, motion, scene, args.plot_dir)))
    if args.json:
        _print_json(summ)
    else:      # the summary is the answer: stdout (`uplift run reactor > summary.txt` keeps it)
        _out(f"motion: {motion.label} (components {', '.join(motion.components)})")
        _out(*(f"override: {o['option']} {o['value']:g}: {o['key']} = {o['now']:.6g} (the scene's: {o['was']:.6g})"
               for o in scene.overrides))
        for r, s in summ["routes"].items():
            if s["status"] == Status.REFUSED.value:
                _out(f"{r}: REFUSED: {s['message']}")
                continue
            axes = s["max_raft_rotation_axes_rad"]
            _out(f"{r} [{', '.join(s['components'])}]: max uplift {1e3 * s['max_uplift_m']:.3f} mm at "
                 f"{s['max_uplift_time_s']:.3f} s, raft rotation {s['max_raft_rotation_rad']:.3e} rad "
                 f"(rx {axes['x']:.3e}, ry {axes['y']:.3e}), min contact "
                 f"{100 * s['min_contact_fraction']:.1f} %, wall {s['wall_s']:.2f} s"
                 + ("" if s["converged"] else f"  STOPPED: {s['message']}"))
            if s["precheck"]:
                _out(f"  linear pre-check: {s['precheck']}")
            _out(*(f"  skipped: {item}" for item in s["skipped"]))
            _out(*(f"  WARNING: {item}" for item in s["warnings"]))
            if not sys.stdout.isatty():     # stdout kept in a file: the warnings reach the terminal too
                _say(*(f"WARNING [{r}]: {item}" for item in s["warnings"]))
    statuses = {res.status for res in results.values()}
    if Status.REFUSED in statuses:
        return EXIT_INPUT
    return EXIT_FAILED if Status.STOPPED in statuses else EXIT_OK


def _dry_run(args) -> int:
    """``uplift run --dry-run``: the scene loaded (with the options that change it), the run's
    stages and their estimated peak memory (stdout), then the memory guard's verdict (its
    refusal raises: exit 2). Loads neither the run nor the routes' solvers (under 2 s)."""
    from orchestrator.memory_guard import check_run_memory, memory_lines, run_memory   # start-up cost: only here
    from orchestrator.scene import load_scene                                          # (same)
    from soil_impedance.sweep import available_memory                                  # (same)
    scene = load_scene(args.scene, max_pga_g=args.max_pga, pga_g=args.pga, dt=args.dt, duration_s=args.duration)
    if args.routes:
        scene = scene.with_routes(args.routes)
    _out(f"scene {scene.name}: {scene.mesh.n} interface nodes, {scene.frequencies_hz.size} frequencies, routes "
         f"{', '.join(scene.analysis.routes)}; estimated peak memory per stage:")
    cached = not getattr(args, "no_cache", False)          # large tables are streamed to the cache folder
    _out(*(f"  {line}" for line in memory_lines(run_memory(scene, cached=cached), available_memory())))
    check_run_memory(scene, cached=cached)
    _out("the run fits in the available memory (nothing was computed)")
    return EXIT_OK


def _run_design(args, scene, out: Path) -> int:
    """``uplift run`` of a scene with soil cases, strain-compatible soil or design spectra
    (orchestrator.design): every case, one results file, the design tables and figures."""
    from orchestrator.design import case_envelope, format_envelope, run_design, write_design  # only here
    from orchestrator.design_spectra import plot_design_spectra, write_tables  # (same)
    from orchestrator.results_file import check_output_folder, summary  # (same)
    from structure.results import Status  # (same)
    design_dir = None
    if scene.design_spectra is not None:
        design_dir = args.design_dir or out.with_name(f"{out.stem}_design")
        check_output_folder(design_dir, (), "--design-dir")
    elif args.design_dir is not None:
        raise OptionError(f"--design-dir: scene {scene.name!r} asks for no design spectra; add [output] "
                          "design_spectra = { damping = [0.05] } (docs/design_basis.md), or drop --design-dir")
    run = run_design(scene, args.routes, cache_dir=_cache(args),
                     progress=labelled_bars(f"run {scene.name} [{{label}}]"),
                     sweep_progress=Progress(f"impedance {scene.name}"),
                     fit_progress=labelled_bars(f"fit {scene.name}: {{label}}"), announce=_say)
    write_design(out, run, scene.overrides)
    _say(f"wrote {out}")
    if design_dir is not None:
        _say(*(f"wrote {p}" for p in write_tables(run.spectra, design_dir)))
        _say(*(f"wrote {p}" for p in plot_design_spectra(run.spectra, design_dir)))
    if args.plot_dir:
        from orchestrator.plots import plot_run                  # start-up cost: only with --plot-dir
        first = next(iter(run.cases))
        _say(*(f"wrote {path}" for path in plot_run(run.cases[first], run.motion, scene, args.plot_dir)))
    table = case_envelope(run.cases)
    site = None if run.site is None else {
        "iterations": run.site.iterations, "converged": run.site.converged, "input": run.site.input,
        "component": run.site.component, "g_ratio": run.site.g_ratio.tolist(), "damping": run.site.damping.tolist(),
        "strain_eff": run.site.strain_eff.tolist(), "vs": [m.vs for m in run.site.profile.layers]}
    if args.json:
        _print_json({"cases": {c: {r: summary(res) for r, res in rs.items()} for c, rs in run.cases.items()},
                     "envelope": table["envelope"], "site_response": site, "overrides": list(scene.overrides)})
    else:
        _out(f"motion: {run.motion.label} (components {', '.join(run.motion.components)})")
        if site is not None:
            _out(f"strain-compatible soil ({site['input']} motion, {site['component']} component): "
                 f"{site['iterations']} iterations, {'converged' if site['converged'] else 'NOT converged'}; per layer "
                 + "; ".join(f"G/Gmax {g:.3f}, damping {d:.4f}, strain {e:.3g}, vs {v:.1f} m/s"
                             for g, d, e, v in zip(site["g_ratio"], site["damping"], site["strain_eff"], site["vs"])))
        _out(format_envelope(table))
        for case, rs in run.cases.items():
            for r, res in rs.items():
                if not res.converged:
                    _out(f"{case} {r}: {res.status.value.upper()}: {res.message}")
                for item in res.notes.warnings:
                    _out(f"{case} {r}: WARNING: {item}")
                    if not sys.stdout.isatty():     # stdout kept in a file: the warnings reach the terminal too
                        _say(f"WARNING [{case} {r}]: {item}")
    statuses = {res.status for rs in run.cases.values() for res in rs.values()}
    if Status.REFUSED in statuses:
        return EXIT_INPUT
    return EXIT_FAILED if Status.STOPPED in statuses else EXIT_OK


def _pngs(folder: Path) -> list:
    """The PNG names already in ``folder`` (figures a command may replace)."""
    return sorted(p.name for p in folder.glob("*.png")) if folder.is_dir() else []


def cmd_scene(args) -> int:
    from orchestrator.scene_file import builtin_scene_text      # start-up cost: the text only, no scene loaded
    if args.output is None:
        text, _ = builtin_scene_text(args.name)
        sys.stdout.write(text)
        return EXIT_OK
    from orchestrator.results_file import check_output_path     # start-up cost: only when a file is written
    from uplift_common.files import atomic_output                # (same)
    text, companions = builtin_scene_text(args.name, args.output.parent)
    check_output_path(args.output)
    for name in companions:
        check_output_path(args.output.parent / name)
    for name, source in companions.items():
        if (args.output.parent / name).resolve() != source:
            with atomic_output(args.output.parent / name) as tmp:
                tmp.write_bytes(source.read_bytes())
            _say(f"wrote {args.output.parent / name}")
    with atomic_output(args.output) as tmp:
        tmp.write_text(text, encoding="utf-8")
    _say(f"wrote {args.output}")
    return EXIT_OK


def cmd_cache(args) -> int:
    from uplift_common.cache_folder import (cache_entries, default_cache_dir, prune_cache,  # only here
                                            size_text, usage, usage_lines)
    folder = default_cache_dir()
    removed = [] if args.prune is None else prune_cache(folder, args.prune)
    entries = cache_entries(folder)
    if args.json:
        kinds = {kind: {"entries": k["entries"], "bytes": k["bytes"]} for kind, k in usage(entries).items()}
        _out(json.dumps({"folder": str(folder), "kinds": kinds, "removed": len(removed),
                         "removed_bytes": sum(e.bytes for e in removed)}))
        return EXIT_OK
    if args.prune is not None:
        _say(f"removed {len(removed)} entries ({size_text(sum(e.bytes for e in removed))}) not used for "
             f"{args.prune:g} days")
    _out(f"cache folder {folder} ($UPLIFT_CACHE)", *usage_lines(entries))
    return EXIT_OK


def cmd_impedance(args) -> int:
    # start-up cost: what only this command uses loads in it
    import numpy as np                                           # (same)
    from orchestrator.impedance import (discretisation_lines, rigid_json, scene_discretisation_error,
                                        scene_impedance, scene_static)
    from orchestrator.plots import plot_impedance                # (same)
    from orchestrator.results_file import check_output_path      # (same)
    from orchestrator.scene import load_scene                    # (same)
    t0 = time.perf_counter()
    scene = load_scene(args.scene)
    for path in (args.output, args.gap, args.plot):
        if path is not None:
            check_output_path(path)
    cache = _cache(args)
    outputs = ("rigid", "gap") if args.gap else ("rigid",)
    tables = scene_impedance(scene, outputs, cache_dir=cache,
                             progress=Progress(f"impedance {scene.name}"))
    wall = time.perf_counter() - t0
    error = scene_discretisation_error(scene, cache_dir=cache)
    for name, path in (("rigid", args.output), ("gap", args.gap)):
        if path:
            tables[name].save(path, notes={"discretisation_error": error})
            _say(f"wrote {path} ({name} table)")
    if args.plot:
        plot_impedance(tables["rigid"], scene, args.plot, static=scene_static(scene, cache_dir=cache))
        _say(f"wrote {args.plot}")
    if args.json:
        _print_json(rigid_json(tables["rigid"], wall, error))
    else:
        table = tables["rigid"]
        diag = np.diagonal(table.matrices, axis1=1, axis2=2)
        _out(f"rigid impedance, {len(table.frequencies_hz)} frequencies, {wall:.2f} s",
             "   f (Hz) " + "".join(f"{d:>24s}" for d in table.dofs),
             *(f"{f:9.3f} " + "".join(f"{z.real:12.4e}{z.imag:+12.4e}" for z in row)
               for f, row in zip(table.frequencies_hz, diag)),
             *discretisation_lines(error))
    return EXIT_OK


def cmd_fit(args) -> int:
    # start-up cost: what only this command uses loads in it
    from orchestrator.impedance import scene_fit, scene_impedance
    from orchestrator.results_file import check_output_path      # (same)
    from orchestrator.scene import load_scene                    # (same)
    from soil_impedance.fit import save_fit                      # (same)
    t0 = time.perf_counter()
    scene = load_scene(args.scene)
    for path in (args.output, args.plot):
        if path is not None:
            check_output_path(path)
    tol = args.tol if args.tol is not None else scene.analysis.fit_tol
    cache = _cache(args)
    table = scene_impedance(scene, (args.table,), cache_dir=cache,
                            progress=Progress(f"impedance {scene.name}"))[args.table]
    xy = {"node_xy": None} if args.table == "rigid" else {}
    result = scene_fit(scene, cache_dir=cache, table=table, tol=tol, fit_progress=labelled_bars(f"fit {scene.name}: {{label}}"),
                       **xy)
    if args.output:
        save_fit(result, args.output)
        _say(f"wrote {args.output}")
    if args.plot:
        result.plot(table, args.plot)
        _say(f"wrote {args.plot}")
    out = dict(result.report.summary(), wall_s=time.perf_counter() - t0)
    if args.json:
        _print_json(out)
    else:
        _out(f"{args.table} table of {scene.name}: {out['order']} poles, max relative error "
             f"{100 * out['max_rel_error']:.2f} % (tol {100 * tol:g} %), passive: {out['passive']} "
             f"(margin {out['passivity_margin']:.3g}), {out['wall_s']:.1f} s")
    if not result.report.tol_reached:
        _say(f"WARNING: {result.report.message}")
    return EXIT_OK


def cmd_export(args) -> int:
    # the FMU stack (fmpy, pythonfmu, the native builder) loads only for an export:
    from orchestrator.crosscheck import model_folder, write_cross_check     # fmpy
    from orchestrator.export import export_scene                            # fmpy, pythonfmu
    from orchestrator.results_file import check_output_folder               # h5py
    from orchestrator.scene import load_scene             # numpy, the mesh, the structure
    scene = load_scene(args.scene)
    if scene.structure is None:
        raise SceneError(f"scene {scene.name!r} has no [structure]: nothing to export "
                         "(add [structure] model = \"reactor\", or inline nodes/beams/masses/raft)")
    if scene.profile is None:
        raise SceneError(f"scene {scene.name!r} has no layered soil: the soil FMU carries the BEM impedance "
                         "of [soil] (add halfspace = { vs = ..., nu = ..., rho = ... } and any layers)")
    check_output_folder(args.output, EXPORT_FILES)
    if args.cross_check is not None:
        check_output_folder(args.cross_check, (), "--cross-check")
        for model in ("structure", "soil", "coupled"):
            try:
                folder = model_folder(args.cross_check, model, args.fmi_version)
            except ValueError as exc:           # the package's version (the folder's name) is unknown
                raise SetupError(f"--cross-check: {exc}") from None
            check_output_folder(folder, [name.format(model) for name in CROSS_CHECK_FILES], "--cross-check")
    if args.kind == "native" and importlib.util.find_spec("ziglang") is None:
        raise SetupError("--kind native compiles the FMUs with the C compiler of the ziglang package, which is not "
                         "installed: pip install ziglang (a dependency of uplift), or export --kind python")
    if args.fmi_version == 3 and args.kind != "native":
        raise OptionError("--fmi-version 3 writes native FMUs only (pythonfmu writes FMI 2.0): drop --kind python")
    from orchestrator.impedance import scene_fit                 # start-up cost (as above)
    soil = scene_fit(scene, cache_dir=_cache(args), fit_progress=labelled_bars(f"fit {scene.name}: {{label}}")).model
    compiled = _announce_native_build(args.fmi_version) if args.kind == "native" else None
    exported = export_scene(scene, args.output, soil, cache_dir=_cache(args), kind=args.kind,
                            fmi_version=args.fmi_version, progress=compiled)
    _say(*(f"wrote {path}" for path in exported.files))
    if args.cross_check is not None:
        xc = write_cross_check(exported, args.cross_check, scene.name)
        _say(*(f"wrote {folder}/" for folder in xc.models.values()))
        _say(*(f"WARNING: {problem}" for problem in xc.problems))
    return EXIT_OK


#: what the native export's compile costs on a 2-core machine: the first build on a machine compiles
#: each platform's C library (65-95 s for FMI 2.0's three platforms, about 20-30 s a platform),
#: later builds find it in zig's cache (about 1.5 s for the three)
NATIVE_FIRST_BUILD = {2: "65-95 s", 3: "about 20-30 s a platform"}
NATIVE_CACHED_BUILD = "about 1.5 s"


def _announce_native_build(fmi_version: int):
    """Say what a native export compiles and how long it takes, before it starts; return the
    ``progress(done, total, platform)`` that reports each platform as it is done."""
    from fmus.native_build import platforms_of, sources_of       # start-up cost: only a native export
    names = list(platforms_of(fmi_version))
    _say(f"compiling the FMUs' C runtime (fmus/native: {len(sources_of(fmi_version))} C files, FMI "
         f"{fmi_version}.0) with zig for {len(names)} platforms ({', '.join(names)}): the first time on a machine "
         f"this takes {NATIVE_FIRST_BUILD[fmi_version]} (zig builds each platform's C library once), {NATIVE_CACHED_BUILD} "
         "once zig has cached them")
    last = [time.perf_counter()]

    def progress(done, total, platform=""):
        now = time.perf_counter()
        _say(f"  compiled {platform} ({done}/{total}) in {now - last[0]:.1f} s")
        last[0] = now
    return progress


def cmd_compare(args) -> int:
    from orchestrator.compare import compare, format_table       # start-up cost: only this command
    from orchestrator.results_file import ResultsFileError, read_results     # (same)
    from orchestrator.results_file import read_cases
    cases = read_cases(args.results)
    if cases:
        return _compare_cases(args, cases, compare, format_table)
    results = read_results(args.results)
    if args.reference is not None and args.reference not in results:
        raise ResultsFileError(f"--reference {args.reference!r} is not in {args.results} "
                               f"(routes: {', '.join(results)})")
    table = compare(results, reference=args.reference)
    if args.json:
        _print_json(table)
    else:
        _out(format_table(table))
    return EXIT_OK


def _compare_cases(args, cases, compare, format_table) -> int:
    """``uplift compare`` of a design run: the routes compared per soil case, then the envelope
    over the cases (orchestrator.design.case_envelope)."""
    from orchestrator.design import case_envelope, format_envelope  # only here
    from orchestrator.results_file import ResultsFileError, read_results  # (same)
    per = {case: read_results(args.results, case) for case in cases}
    for case, results in per.items():
        if args.reference is not None and args.reference not in results:
            raise ResultsFileError(f"--reference {args.reference!r} is not in {args.results}, soil case {case} "
                                   f"(routes: {', '.join(results)})")
    tables = {case: compare(results, reference=args.reference) for case, results in per.items()}
    envelope = case_envelope(per)
    if args.json:
        _print_json({"cases": tables, "envelope": envelope["envelope"]})
    else:
        for case, table in tables.items():
            _out(f"soil case {case}:", format_table(table), "")
        _out(format_envelope(envelope))
    return EXIT_OK


def cmd_report(args) -> int:
    # start-up cost: what only this command uses loads in it
    from orchestrator.ensemble import is_ensemble_file
    from orchestrator.report import write_ensemble_report, write_report   # (same)
    from orchestrator.results_file import ResultsFileError, check_output_folder   # (same)
    check_output_folder(args.output, ["report.html", *_pngs(args.output)])
    if args.results.suffix.lower() == ".toml":
        raise ResultsFileError(f"{args.results} is a scene: `uplift report` reads the file that `uplift run` or "
                               f"`uplift ensemble` wrote (uplift run {args.results} -o FILE, then uplift report "
                               "FILE -o DIR)")
    if is_ensemble_file(args.results):
        if args.reference is not None:
            raise ResultsFileError(f"--reference compares the routes of one run; {args.results} is an ensemble file")
        _say(f"wrote {write_ensemble_report(args.results, args.output, pushover=args.pushover)}")
        return EXIT_OK
    _say(f"wrote {write_report(args.results, args.output, reference=args.reference, pushover=args.pushover)}")
    return EXIT_OK


def cmd_ensemble(args) -> int:
    from orchestrator.ensemble import ensemble_summary, run_ensemble   # start-up cost: only this command
    from orchestrator.scene import load_scene                          # (same)
    scene = _ensemble_case(load_scene(args.scene, max_pga_g=args.max_pga), args.case)
    out = args.output or Path(f"{scene.name}_ensemble.h5")
    if args.n_seeds is not None and args.records is not None:
        raise OptionError("--n-seeds varies the scene's synthetic motion; --records gives the motions: drop one")
    seeds = list(range(args.n_seeds)) if args.n_seeds is not None else args.seeds
    if args.seeds is not None and len(args.seeds) == 1 and args.seeds[0] > 1 and args.records is None:
        n = args.seeds[0]     # `--seeds 3` read as "three seeds" would run one: say which it runs
        _say(f"--seeds {n}: one motion, seed {n} (for {n} motions, seeds 0 to {n - 1}: --n-seeds {n})")
    ds = run_ensemble(scene, args.pga, records=args.records, seeds=seeds, routes=args.routes, output=out,
                      workers=args.workers, scheduler=args.scheduler, cache_dir=_cache(args),
                      dt_check=args.dt_check, progress=Progress(f"ensemble {scene.name}"),
                      sweep_progress=Progress(f"impedance {scene.name}"),
                      fit_progress=labelled_bars(f"fit {scene.name}: {{label}}"), log=_say, connect_timeout=args.connect_timeout)
    _say(f"wrote {out}")
    summ = ensemble_summary(ds)
    mm = lambda v: "-" if v is None else f"{1e3 * v:.3f} mm"
    if args.json:
        _print_json(summ)
    else:
        _out(f"components {', '.join(summ['components'])}: {summ['runs']} runs ({summ['computed']} computed, {summ['reused']} kept from {out}.cells) on "
             f"{summ['workers']} workers in {summ['wall_s']:.1f} s (cluster {summ['cluster_s']:.1f} s, "
             f"sweep and fit {summ['setup_s']:.1f} s, time-step check {summ['dt_check_s']:.1f} s)"
             + (f"; {summ['workers_note']}" if summ["workers_note"] else ""))
        for pga, routes in summ["pga"].items():
            for route, v in routes.items():
                _out(f"{pga} g [{route}]: max uplift median {mm(v['median_max_uplift_m'])}, 84th percentile "
                     f"{mm(v['p84_max_uplift_m'])} ({v['converged_records']}/{ds.sizes['record']} records converged)")
        _out(*(f"{c['status'].upper()}: {c['record']} at {c['pga_g']:g} g [{c['route']}]: {c['message']}"
               for c in summ["not_converged"]))
        notes = [line for text in ds["warnings"].values.ravel() for line in text.split("\n") if line]
        _say(*(f"WARNING ({notes.count(w)} runs): {w}" for w in dict.fromkeys(notes)))
    if summ["failed"]:
        _say(f"{summ['failed']} runs failed: rerun the same command to compute them (completed runs are kept)")
    if summ["refused"]:
        return EXIT_INPUT
    return EXIT_FAILED if summ["stopped"] or summ["failed"] else EXIT_OK


def _ensemble_case(scene, case):
    """The scene an ensemble runs: ``scene`` itself, or with ``case`` its soil case (named
    ``<scene>_<case>``); a scene with soil cases needs one."""
    from orchestrator.design import design_cases  # only here
    from orchestrator.motion import make_motion  # (same)
    design = scene.soil_cases is not None or scene.strain_compatible is not None
    if case is None:
        if design:
            names = scene.soil_cases.names if scene.soil_cases is not None else ("be",)
            raise OptionError(f"scene {scene.name!r} has soil cases ({', '.join(names)}): an ensemble runs one; "
                              "give --case NAME (one ensemble per case, then `uplift envelope` on the files)")
        return scene
    if not design:
        raise OptionError(f"--case {case}: scene {scene.name!r} has no [soil] cases nor strain_compatible; drop --case")
    cases = dict(design_cases(scene, make_motion(scene.motion, scene.analysis.dt))[0])
    if case not in cases:
        raise OptionError(f"--case {case}: scene {scene.name!r} has the soil cases {', '.join(cases)}; give one of them")
    return replace(cases[case], name=f"{scene.name}_{case}")


def cmd_envelope(args) -> int:
    from orchestrator.ensemble import fractile_design_spectra, read_ensemble, write_fractile_tables  # only here
    import numpy as np  # (same)
    from orchestrator.motion import G  # (same)
    from orchestrator.results_file import check_output_folder  # (same)
    check_output_folder(args.output, (), "-o")
    datasets = {}
    for path in args.ensembles:
        ds = read_ensemble(path)
        label = str(ds.attrs.get("scene", "")) or path.stem
        if label in datasets:
            label = path.stem
        datasets[label] = ds
    design = fractile_design_spectra(datasets, args.quantile, args.broadening)
    paths = write_fractile_tables(design, args.output)
    _say(*(f"wrote {p}" for p in paths))
    peaks = {f"{pga:g}": {route: {node: {d: float(np.nanmax(design["envelope"][a, r, i, j]) / G)
                                         for j, d in enumerate(design["direction"])
                                         if np.isfinite(design["envelope"][a, r, i, j]).any()}
                                  for i, node in enumerate(design["node"])}
                          for r, route in enumerate(design["route"])}
             for a, pga in enumerate(design["pga"])}
    if args.json:
        _print_json({"cases": design["cases"], "quantile": design["quantile"], "broadening": design["broadening"],
                     "envelope_peak_g": peaks, "tables": [str(p) for p in paths]})
    else:
        _out(f"{100 * args.quantile:g}th-percentile floor spectra, broadened +-{100 * args.broadening:g} %, enveloped "
             f"over {', '.join(design['cases'])}: peak (g)")
        for pga, routes in peaks.items():
            for route, nodes in routes.items():
                _out(f"  {pga} g [{route}]: " + "; ".join(f"{n} " + ", ".join(f"{d} {v:.3f}" for d, v in dirs.items())
                                                      for n, dirs in nodes.items()))
    return EXIT_OK


def _fragility_parser(sub, json_flag):
    frg = sub.add_parser("fragility", help="lognormal fragility curves of limit states from an ensemble file",
                         description="Per limit state and route: the maximum-likelihood lognormal fragility "
                                     "P(exceed | PGA) = Phi(ln(PGA / median) / beta) from the exceedances of the "
                                     "converged cells per PGA, stored as the group 'fragility' of the ensemble "
                                     "file (drawn by `uplift report`). See docs/fragility.md.")
    frg.add_argument("ensemble", type=Path, help="ensemble file written by `uplift ensemble`")
    frg.add_argument("--limit", action="append", dest="limits", required=True, metavar="'VAR OP VALUE [UNIT]'",
                     help="limit state (repeatable): VAR a per-cell variable (max_uplift, max_raft_rotation, "
                          "min_contact_ratio, or floor_spectrum[node=N, direction=D, frequency=F]), OP one of "
                          "> >= < <=, UNIT optional (mm, mrad, %%, g, ...; default: the file's), e.g. "
                          "'max_uplift > 5 mm', 'min_contact_ratio < 75 %%'")
    frg.add_argument("--route", action="append", dest="routes", metavar="R",
                     help="route of the file (repeatable; default: all of its routes)")
    frg.add_argument("--bootstrap", type=int, default=0, metavar="N",
                     help="resample the records N times for a band on the median and beta (default 0: none)")
    frg.add_argument("--seed", type=int, default=0, help="seed of the bootstrap (default 0)")
    frg.add_argument("--confidence", type=_fraction, default=0.9, help="share of the bootstrap band (default 0.9)")
    frg.add_argument("--plot", type=Path, default=None, metavar="FILE", help="draw the curves to this image")
    frg.add_argument("--no-store", action="store_true", help="do not write the fit into the ensemble file")
    json_flag(frg, "print {\"fragility\": [...]} on stdout")
    frg.set_defaults(func=cmd_fragility)


def cmd_fragility(args) -> int:
    from orchestrator import fragility as frag  # scipy.optimize and xarray: only this command pays them
    from orchestrator.ensemble import read_ensemble              # (same)
    from orchestrator.plots import pyplot                        # (same)
    from orchestrator.results_file import check_output_path      # (same)
    if args.plot is not None:
        check_output_path(args.plot)
    try:
        fits = frag.fragility(read_ensemble(args.ensemble), args.limits, routes=args.routes, samples=args.bootstrap,
                              seed=args.seed, confidence=args.confidence)
    except frag.FragilityError as exc:     # bad input (exit 2), named with its file
        raise frag.FragilityError(f"{args.ensemble}: {exc}") from None
    if not args.no_store:
        _say(f"wrote the group {frag.GROUP!r} of {frag.store_fragility(args.ensemble, fits)}")
    if args.plot is not None:
        from uplift_common.files import save_figure               # (same)
        plt = pyplot()
        fig = frag.fragility_figure(fits, title=f"{args.ensemble.name}: fragility")
        save_figure(fig, args.plot, dpi=120)
        plt.close(fig)
        _say(f"wrote {args.plot}")
    out = frag.fragility_json(fits)
    if args.json:
        _print_json(out)
        return EXIT_OK
    for e in out["fragility"]:
        counts = ", ".join(f"{p:g} g {z}/{n}" for p, z, n in zip(e["pga_g"], e["exceedances"], e["cells"]))
        left = ", ".join(f"{v} {k}" for k, v in e["left_out"].items() if v)
        fit = (f"median {e['median_g']:.4g} g, beta {e['beta']:.3f}, ln L {e['log_likelihood']:.4g}"
               if e["identifiable"] else f"NOT IDENTIFIABLE: {e['reason']}")
        if e["bootstrap"] and e["bootstrap"]["median_g"]:
            bs = e["bootstrap"]
            fit += (f"; {100 * bs['confidence']:g} % band (bootstrap, {bs['identified']}/{bs['samples']} "
                    f"resamples fitted): median {bs['median_g'][0]:.4g}-{bs['median_g'][1]:.4g} g, "
                    f"beta {bs['beta'][0]:.3f}-{bs['beta'][1]:.3f}")
        _out(f"{e['limit']} [{e['route']}]: {fit}", f"  exceedances per PGA: {counts}"
             + (f"; left out: {left}" if left else ""))
    return EXIT_OK


def cmd_bench(args) -> int:
    from orchestrator.bench import bench, bench_config, format_rows, json_safe, plot_rows   # start-up cost
    from orchestrator.results_file import check_output_path                                  # (same)
    if args.plot is not None:
        check_output_path(args.plot)
    rows = bench(bench_config(args.quick), cache_dir=_cache(args), log=lambda msg: _say(msg))
    if args.plot:
        _say(f"wrote {plot_rows(rows, args.plot)}")
    if args.json:
        _print_json(json_safe(rows))
    else:
        print(format_rows(rows))
    return EXIT_OK if all(r.get("converged", True) for r in rows) else EXIT_FAILED


def _pushover_parser(sub, json_flag, scene_arg, no_cache):
    psh = sub.add_parser("pushover", help="static pushover of the raft on its soil: moment-rotation, contact ratio, "
                                          "lift-off onset",
                         description="Rock the raft, under the structure's weight, by a prescribed rotation in equal "
                                     "steps (displacement control) and solve the exact unilateral static contact on "
                                     "the BEM static gap table or the winkler springs: moment, settlement, contact "
                                     "ratio, edge gap and contact pressures per step, and the lift-off onset solved "
                                     "exactly (moment and eccentricity e = M/N). See docs/pushover.md.")
    scene_arg(psh)
    psh.add_argument("-o", "--output", type=Path, default=None,
                     help="pushover HDF5 file (default: <scene>_pushover.h5 in the current directory)")
    psh.add_argument("--soil", choices=("bem", "winkler"), default=None,
                     help="bem: the static BEM gap table (default when the scene has a half-space); winkler: the "
                          "scene's winkler springs")
    psh.add_argument("--direction", default="x", metavar="x|y|ANGLE",
                     help="rocking direction: x (rotation about y, default), y, or degrees from x towards y")
    psh.add_argument("--steps", type=_count, default=50, help="rotation steps (default 50)")
    psh.add_argument("--max-rotation", type=_positive, default=None, metavar="RAD",
                     help="largest rotation, rad (default: 20 times the lift-off onset rotation)")
    psh.add_argument("--vertical-load", type=float, default=0.0, metavar="N",
                     help="extra downward force on the raft, N, added to the structure's weight (default 0)")
    psh.add_argument("--plot", type=Path, default=None, metavar="FILE",
                     help="draw moment-rotation and contact ratio-moment to this image")
    json_flag(psh, "print the onset and the curve as one JSON object on stdout")
    no_cache(psh)
    psh.set_defaults(func=cmd_pushover)


def cmd_pushover(args) -> int:
    from orchestrator.pushover import plot_pushover, pushover_json, scene_pushover, write_pushover  # start-up cost
    from orchestrator.results_file import check_output_path                                       # (same)
    from orchestrator.scene import load_scene                                                     # (same)
    scene = load_scene(args.scene)
    out = check_output_path(args.output or Path(f"{scene.name}_pushover.h5"))
    if args.plot is not None:
        check_output_path(args.plot)
    run = scene_pushover(scene, soil=args.soil, direction=args.direction, steps=args.steps,
                         max_rotation=args.max_rotation, vertical_load=args.vertical_load, cache_dir=_cache(args),
                         progress=Progress(f"pushover {scene.name}"))
    write_pushover(out, run)
    _say(f"wrote {out}")
    if args.plot is not None:
        _say(f"wrote {plot_pushover(run, args.plot)}")
    summ = pushover_json(run)
    if args.json:
        _print_json(summ)
        return EXIT_OK
    on, st = summ["onset"], summ["steps"]
    _out(f"{scene.name}: static pushover on the {run.soil_label}, direction {run.direction_deg:g} deg, "
         f"{summ['nodes']} nodes, vertical load {summ['vertical_N']:.6g} N, {len(st['rotation_rad'])} points, "
         f"wall {run.wall_s:.2f} s",
         "lift-off at rest (a node is open under the weight alone)" if on["at_rest"] else
         f"lift-off onset: rotation {on['rotation_rad']:.6g} rad, moment {on['moment_Nm']:.6g} N m, "
         f"eccentricity e = M/N = {on['eccentricity_m']:.6g} m (node {on['node']}, {len(on['nodes'])} at once)",
         "  rotation (rad)    moment (N m)  e (m)   settlement (m)  contact  max gap (m)")
    _out(*(f"  {r:13.6e}  {m:14.6e}  {e:6.3f}  {s:14.6e}  {100 * c:6.1f} %  {g:11.4e}" for r, m, e, s, c, g in
           zip(st["rotation_rad"], st["moment_Nm"], st["eccentricity_m"], st["settlement_m"], st["contact_ratio"],
               st["max_gap_m"])))
    return EXIT_OK


if __name__ == "__main__":
    sys.exit(main())

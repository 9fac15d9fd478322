"""The run-level memory guard: before a run allocates anything large, the peak memory of each
stage it will run is estimated from the scene alone, and the run is refused (``RunMemoryError``,
exit 2) when the largest does not fit in the machine's available memory, naming the stage, its
estimate, what is available and the key to change. Never a MemoryError halfway through a run.

Stages (each estimate is the peak while that stage runs: what the run still holds included):

  static    K(0) of the rigid raft, one BEM frequency (the time-step check's proxy springs), by
            the scene's solver (the fast one on a large grid: no flexibility matrix):
            ``soil_impedance.sweep.mesh_sweep_memory``
  sweep     the BEM sweep over [impedance]'s frequencies, the tables of the routes run
            (``sweep_memory``: flexibility, assembly, solves and the tables themselves)
  fit       the swept tables held + the rational fit of the gap table: in memory
            (``soil_impedance.fit.peak_memory.fit_memory``), or, for a table above
            ``blocked.STREAM_BYTES`` (on disk: the run's cache folder), the streamed fit
            (``streamed_fit_memory``: blocks, one order's coefficients (the order search holds
            every order's E only), the models, the passivity sweep)
  stepping  the tables held + the fitted model + the time stepper: m x (6+N)^2 doubles for m poles
            (the history's size) in about 8 copies (``HISTORY_COPIES``: the model's residues,
            coefficients and their scaled view, the split by pole kind, the native runtime's
            records encoded), the base system (a few dense (6+N)^2 matrices) and the histories
            kept (``stepping_memory``); from HMATRIX_MIN_NODES nodes on, where the monolithic route
            compresses the history (soil_impedance/hhistory.py), the compressed model's copies
            (``COMPRESSED_COPIES``) and the native stepper's K0C over the blocks
  timefreq  the tables held + the table on the FFT grid's frequencies up to its last one, one
            (6+N)^2 complex matrix per grid frequency (the timefreq and linear routes)

The number of poles is not known before the fit: the stepping stage's estimate takes the most the
fit may use (``max_poles``: [analysis]'s fit options, at most F - 2 for F frequencies), and its
floor the fewest (``MIN_POLES``). Before the fit the guard refuses on the floor (a run that cannot
step whatever the fit makes); a time-stepped route checks the stage again with the fit's own poles
before it steps (``check_stepping_memory``), and is refused then with that estimate. Whether a
table or fit is in the cache is not asked: the estimate is that of a cold run (a warm one needs less). A run
with a cache folder writes each table above ``blocked.STREAM_BYTES`` to disk as it is swept
(``mesh_sweep_memory(..., streamed=)``: the dense solver holds the one matrix being stored; the fast
one up to 1 + LEAD + CHAINS of them, the one being stored, LEAD solved ahead and one being solved in
each of its CHAINS warm-start chains, run in as many processes): the later stages do not hold it (the
timefreq and linear routes read it whole).
``uplift run SCENE --dry-run`` prints the stages and exits (``run_memory``, ``memory_lines``).
"""
from __future__ import annotations

from dataclasses import dataclass

import soil_impedance.sweep as sweep_module
from soil_impedance.blocked import STREAM_BYTES, table_bytes
from soil_impedance.hhistory import HMATRIX_MIN_NODES
from soil_impedance.fit.peak_memory import fit_memory, streamed_fit_memory
from soil_impedance.fit.options import FitOptions
from soil_impedance.fit.search import max_pairs
from uplift_common.errors import UserInputError

from orchestrator.routes import get_route

#: share of the available memory a run may plan to use (the sweep's own guard uses the same)
MEMORY_SHARE = sweep_module.MEMORY_SHARE
#: bytes the stepping stage holds besides its matrices: the interpreter and libraries, the
#: structure model, the motion (as the sweep's estimate: ``sweep.BASE_BYTES``)
BASE_BYTES = sweep_module.BASE_BYTES
#: copies of the history matrix (8 m n^2 bytes for m poles) alive at the stepping stage's peak, which is
#: the encoding of the native run's records (``fmus.native_build.encode_resources``): held, the fitted
#: model's complex residues (2), its real coefficients from the fit (1) and their scaled view from the
#: passivity test (1), the residues split by pole kind (1); transient, the pair residues stacked for their
#: record (up to 1) and the encoded bytes three times (the growing buffer, its bytes() copy and the blob
#: with its header); once open, the C runtime's copy of the blob (1) and its packed symmetric history (1/2)
#: stay below that. The Python stepper's own history matrix is built at its first product only (the native
#: run never builds it). Measured with benchmarks/growth.py (step column, a synthetic model holding the
#: fit's cached forms) at 1156 nodes and 16 poles: 1.40 GiB over the interpreter, the estimate 1.41
#: (1.55 GiB before the history matrix was made lazy)
HISTORY_COPIES = 8.0
#: more copies of the history matrix a fit made by the pipeline holds beside those (the fit's result and what
#: its streamed problem and enforcement leave alive), which a synthetic model (HISTORY_COPIES' measurement)
#: does not have. Measured on the mat's own run (2506 DOFs, its fit's 8 poles, 2001 steps, peak resident
#: memory of the whole process): 6.72 GiB cold (the fit made in the process), 5.82 GiB warm (read back),
#: against 5.31 GiB estimated without them; with 4 the estimate is 6.81 GiB. One scene: a bound, not a law
FIT_COPIES = 4.0
#: more copies of the history matrix when the history is compressed (N >= HMATRIX_MIN_NODES: the monolithic
#: route passes the nodes, ``history="auto"``): the compressed model M̃ the soil runs, its complex residues (2)
#: and their split by pole kind (1), beside the fitted model, and the history blocks taken from the fit and
#: assembled from their compression while it runs (transient). Measured (the peak's VmHWM over the process
#: before the fitted model, 200 steps of the mat under a lifting pulse, 6 poles, kernel-structured soil):
#: the compressed stepping's peak over the dense one's 4.7 / 4.3 / 3.7 m n^2 doubles at 625 / 1156 / 2500 nodes;
#: with 3.5 the estimate is 4.6 / 6.5 / 10.3 % above the measured peaks (242 / 799 / 3562 MiB), the dense
#: estimate's own excess (20 / 18 / 16 % above its measured 157 / 534 / 2496 MiB at 6 poles) taking the rest
COMPRESSED_COPIES = 3.5
#: doubles per n^2 of the native stepper's K0C over the history's blocks, at a step size (stepper.c,
#: ``k0c_blocks``: each upper block a dense block or the terms' stacked factors, whichever is smaller):
#: at most the upper blocks' dense size, half of n^2 and the diagonal leaves' halves; one level (each
#: halving level the stepper builds holds its own, as it does its dense base system)
K0C_BLOCKS = 0.5
#: dense (6+N)^2 doubles of the stepper's base system: D0, E, K(0), the Schur complement S0, its
#: factorisations cached by active set, the sparse embeddings of D0 and E (12 bytes a value)
BASE_SYSTEM_COPIES = 12.0
#: the fewest poles a fit has (the order search starts at one pair): the stepping stage's floor before the fit
MIN_POLES = 2
#: frequencies of the FFT grid of the frequency-domain routes: padding added to the motion, s
#: (their default, ``GridOptions.pad_s`` None: at least 1 s, 3 s for the reactor's decay)
PAD_S = 3.0


class RunMemoryError(UserInputError):
    """A run whose estimated peak memory exceeds the machine's available memory, refused before
    anything large is allocated; the message names the stage, the estimate and the fix."""


@dataclass(frozen=True)
class Stage:
    """One stage of a run: name, estimated peak bytes, what the estimate is made of (text), the
    scene keys that change it (text), and ``floor``: the least it may need when ``bytes`` bounds
    what a later stage decides (the stepping before the fit: its poles), else None."""
    name: str
    bytes: int
    detail: str
    fix: str
    floor: int | None = None

    @property
    def needed(self) -> int:
        """The bytes the guard compares with the available memory: the floor when there is one."""
        return self.bytes if self.floor is None else self.floor


def _gib(b: float) -> str:
    return f"{b / 2 ** 30:.2f} GiB"


def max_poles(scene, n_freq: int) -> int:
    """The most poles the scene's fit may have: 2 x ``fit.search.max_pairs`` of its options."""
    return 2 * max_pairs(FitOptions.make(tol=scene.analysis.fit_tol), n_freq)


def stepping_memory(n_dof: int, poles: int, n_steps: int, compressed: bool | None = None,
                    fitted: bool = True) -> dict[str, int]:
    """Estimated peak bytes of stepping a rigid raft of n_dof = 6 + N interface DOFs on a
    rational soil of ``poles`` poles over ``n_steps`` steps (the tables not counted), by item:
    ``history`` HISTORY_COPIES (+ FIT_COPIES for a model the fit pipeline made: ``fitted``)
    x 8 poles n_dof^2, ``system`` BASE_SYSTEM_COPIES x 8 n_dof^2,
    ``histories`` the gaps, contact forces and soil displacements kept, twice (the runtime's rows
    and the result's arrays), ``compressed`` (the history compressed: ``compressed``, None: from
    HMATRIX_MIN_NODES nodes on, as the monolithic route does) COMPRESSED_COPIES x 8 poles n_dof^2
    and K0C_BLOCKS x 8 n_dof^2, ``base`` BASE_BYTES; and ``total``."""
    n2 = n_dof * n_dof
    N = n_dof - 6
    if compressed is None:
        compressed = N >= HMATRIX_MIN_NODES
    items = {"history": int((HISTORY_COPIES + FIT_COPIES * fitted) * 8 * poles * n2), "system": int(BASE_SYSTEM_COPIES * 8 * n2),
             "histories": 2 * 8 * n_steps * (3 * N + 64),
             "compressed": int((COMPRESSED_COPIES * poles + K0C_BLOCKS) * 8 * n2) if compressed else 0,
             "base": BASE_BYTES}
    items["total"] = sum(items.values())
    return items


def streamed_outputs(scene, outputs, cached: bool = True) -> tuple[str, ...]:
    """The outputs among ``outputs`` the sweep of ``scene`` writes to disk (``blocked.TableWriter``):
    with a cache folder (``cached``), those whose matrices take more than ``blocked.STREAM_BYTES``;
    none with ``[impedance] frequency_tol`` (the thinned sweep's tables are interpolated in memory)."""
    if getattr(scene, "frequency_tol", None) is not None:
        return ()
    n, F = scene.mesh.n, scene.frequencies_hz.size
    size = {"rigid": 6, "gap": 6 + n, "nodal": 3 * n}
    return tuple(o for o in outputs if cached and table_bytes(F, size[o]) > STREAM_BYTES)


def run_memory(scene, routes=None, cached: bool = True, poles: int | None = None) -> list[Stage]:
    """The stages a run of ``scene`` with ``routes`` (default: the scene's) will run, each with its
    estimated peak bytes (module docstring), in the order they run. ``cached``: the run has a cache
    folder (large tables are then streamed to disk); ``poles``: the fit's poles when known (None:
    the stepping stage from MIN_POLES to ``max_poles``)."""
    names = tuple(routes or scene.analysis.routes)
    chosen = [get_route(r) for r in names]
    outputs = tuple(dict.fromkeys(t for r in chosen for t in r.tables(scene)))
    mesh, F = scene.mesh, scene.frequencies_hz.size
    n = mesh.n
    nb = 6 + n
    size = ("foundation.element_size" if scene.mesh_source is None else "foundation.mesh (fewer cells)")
    stages = []
    if not outputs:
        return stages
    streamed = streamed_outputs(scene, outputs, cached)
    static = sweep_module.mesh_sweep_memory(mesh, 1, ("rigid",), scene.solver, scene.solver_tol)
    how = (f"flexibility {_gib(static['F'])}" if static["F"] else
           f"fast solver, no flexibility matrix; work {_gib(static['work'])}")
    stages.append(Stage("static", static["total"], f"K(0) of the rigid raft, {n} interface nodes ({how})", size))
    sweep = sweep_module.mesh_sweep_memory(mesh, F, outputs, scene.solver, scene.solver_tol, streamed)
    dims = {"rigid": 6, "gap": nb, "nodal": 3 * n}
    held = sum(table_bytes(F, dims[o]) for o in outputs if o not in streamed)
    on_disk = ""
    if streamed:                                    # sweep_memory's outputs: what a streamed table holds
        on_disk = (f"; {', '.join(streamed)} on disk, one matrix held (the one being stored)" if sweep["F"] else
                   f"; {', '.join(streamed)} on disk, up to {1 + sweep_module.LEAD + sweep_module.CHAINS} matrices "
                   f"held (the one being stored, {sweep_module.LEAD} solved ahead, one being solved in each of "
                   f"{sweep_module.CHAINS} warm-start chains, as many processes)")
    stages.append(Stage("sweep", sweep["total"], f"BEM sweep of {n} nodes at {F} frequencies, tables "
                        f"{', '.join(outputs)} ({_gib(held)} held{on_disk}; flexibility {_gib(sweep['F'])})",
                        f"{size}, [impedance] frequencies"))
    if "gap" not in outputs:
        return stages
    known = poles is not None
    poles = poles if known else max_poles(scene, F)
    if any(r.needs_fit for r in chosen):
        if "gap" in streamed:
            fit = streamed_fit_memory(nb, F, poles)
            what = (f"streamed fit of the {nb} x {nb} gap table at {F} frequencies on disk, at most {poles} poles "
                    f"({_gib(held)} held + {_gib(fit['total'])}: the order search's E of every order, or one order's "
                    f"coefficients fitted for the enforcement, {_gib(fit['search'])}, "
                    f"the models {_gib(fit['models'])}, the passivity sweep {_gib(fit['passivity'])})")
        else:
            fit = fit_memory(nb, F, poles)
            what = (f"rational fit of the {nb} x {nb} gap table at {F} frequencies ({_gib(held)} held "
                    f"+ {_gib(fit['total'])} of copies)")
        stages.append(Stage("fit", held + fit["total"] + BASE_BYTES, what, f"{size}, [impedance] frequencies"))
    steps = int(round(scene.motion.length_s / scene.analysis.dt)) + 1
    if any(r.needs_fit and r.time_stepped for r in chosen):
        step = stepping_memory(nb, poles, steps)
        squeezed = (f", the compressed history's model and K0C blocks {_gib(step['compressed'])}"
                    if step["compressed"] else "")
        floor = None if known else held + stepping_memory(nb, MIN_POLES, steps)["total"]
        bound = (f"the fit's {poles} poles" if known else
                 f"at most {poles} poles (at least {_gib(floor)} with {MIN_POLES}; checked again with the fit's)")
        stages.append(Stage("stepping", held + step["total"],
                            f"time stepper on the fitted soil, {bound}: history matrix "
                            f"{poles} x {nb}^2 doubles ({_gib(8 * poles * nb * nb)}) and its copies "
                            f"{_gib(step['history'])}{squeezed}, {steps} steps", f"{size}, analysis.routes", floor))
    frequency_domain = [r.name for r in chosen if "gap" in r.tables(scene) and not r.needs_fit]
    if frequency_domain:
        band = int(scene.frequencies_hz[-1] * (scene.motion.length_s + PAD_S)) + 1
        tf = 16 * band * nb * nb + (table_bytes(F, nb) if "gap" in streamed else 0)    # read whole
        stages.append(Stage("timefreq", held + tf + BASE_BYTES,
                            f"routes {', '.join(frequency_domain)}: the gap table at {band} FFT grid frequencies "
                            f"({_gib(tf)})", f"{size}, analysis.routes (drop {', '.join(frequency_domain)})"))
    return stages


def check_run_memory(scene, routes=None, cached: bool = True) -> list[Stage]:
    """``run_memory``'s stages, or RunMemoryError when the largest need (``Stage.needed``: the
    stepping's floor before the fit) exceeds ``MEMORY_SHARE`` of the machine's available memory
    (``soil_impedance.sweep.available_memory``; unknown: no check)."""
    stages = run_memory(scene, routes, cached)
    _refuse_above(scene, stages)
    return stages


def check_stepping_memory(scene, poles: int, routes=None, cached: bool = True) -> Stage | None:
    """The stepping stage of ``run_memory`` with the fit's ``poles``, or RunMemoryError when it
    exceeds ``MEMORY_SHARE`` of the available memory: what a time-stepped route checks once the
    fit is known, before it steps. None when the run has no stepping stage."""
    stage = next((s for s in run_memory(scene, routes, cached, poles) if s.name == "stepping"), None)
    if stage is not None:
        _refuse_above(scene, [stage])
    return stage


def _refuse_above(scene, stages) -> None:
    avail = sweep_module.available_memory()
    if not stages or avail is None:
        return
    worst = max(stages, key=lambda s: s.needed)
    if worst.needed > MEMORY_SHARE * avail:
        raise RunMemoryError(
            f"scene {scene.name!r}: the {worst.name} stage needs {'at least' if worst.floor is not None else 'about'} "
            f"{_gib(worst.needed)} ({worst.detail}) but "
            f"the machine has {_gib(avail)} available (MemAvailable; a run plans on {100 * MEMORY_SHARE:.0f} % of "
            f"it): change {worst.fix} (memory grows like N^2 in the interface nodes and like the frequency "
            f"count); `uplift run {scene.name} --dry-run` lists every stage")


def memory_lines(stages, available: int | None = None) -> list[str]:
    """The lines of ``uplift run --dry-run``: one per stage (its estimate and what it holds) and
    the machine's available memory."""
    out = [f"{s.name:9s} {_gib(s.bytes):>11s}  {s.detail}" for s in stages] or \
        ["no stage needs the BEM: nothing large is allocated"]
    if available is not None:
        out.append(f"available {_gib(available):>11s}  MemAvailable; a run plans on {100 * MEMORY_SHARE:.0f} % "
                   f"of it ({_gib(MEMORY_SHARE * available)})")
    return out

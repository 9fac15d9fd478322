"""Frequency sweep of the surface BEM into ImpedanceTables, cached in HDF5 by content hash.

Cache entries (``impedance_<output>_<hash>.h5`` in ``cache_dir``) are keyed by every input that
changes the result (``provenance`` + frequencies), written atomically with a whole-file checksum
and verified on read (``cache``): concurrent runs of the same scene each write their own
temporary file (the last one wins), and a damaged entry (truncated, altered, nonsensical) is
discarded with a ``CacheWarning`` and recomputed, never reported as an input error.
"""
from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import math
import os
import threading
import warnings
from pathlib import Path

import numpy as np
from uplift_common.lazy import lazy_module

from .blocked import STREAM_BYTES, BlockedTable, DamagedTableError, TableWriter, table_bytes
from .bem import CHUNK_PAIRS, CONTACTS, RADIAL_TOL, BemError, SurfaceBem, _grid, edge_tractions, nodal_dofs
from uplift_common.code import code_digest
from uplift_common.errors import UserInputError
from uplift_common.files import OutputWriteError

from .cache import CacheWarning, discard_entry, read_entry, write_entry
from .greens_rule import GreenRule
from .profile import CAUSAL_CUTOFF_HZ, CAUSAL_REFERENCE_HZ
from .reduction import RIGID_DOFS, gap_dofs, gap_transform, rigid_transform
from .solvers import DEFAULT_TOL, check_solver, resolve_solver
from .table import ImpedanceTable, TableError, content_hash

# scipy loads on first use (uplift_common.lazy): a warm run reads what it would compute
sla = lazy_module("scipy.linalg")
# the fast solver too: it imports scipy.fft at its top, deferred to a fast sweep's first FFT; the
# solver's choice and checks (every run's memory guard and cache keys) are in a light module
fastsolve = lazy_module("soil_impedance.fastsolve", defer=("scipy.fft",))

OUTPUTS = ("rigid", "gap", "nodal")
#: the code a table depends on: its digest is one of the table's inputs (a changed kernel misses the cache)
CODE = ("soil_impedance.profile", "soil_impedance.patch", "soil_impedance.bem", "soil_impedance.greens",
        "soil_impedance.greens_layers", "soil_impedance.greens_rule", "soil_impedance.reduction", "soil_impedance.sweep")


#: the fast solver's code: its digest is recorded in the provenance of the tables it computes
#: only (a change to it misses the cache of fast tables, never of dense ones)
FAST_CODE = ("soil_impedance.fastsolve", "soil_impedance.solvers")


def code_version() -> str:
    """The digest (12 hex digits) of the sweep's code (``CODE``)."""
    return code_digest(*CODE)[:12]


def _material_dict(m) -> dict:
    d = {k: getattr(m, k) for k in ("vs", "rho", "damping", "damping_model")}
    d["nu"] = m.poisson
    if m.damping_model == "causal":
        d["causal"] = {"cutoff_hz": CAUSAL_CUTOFF_HZ, "reference_hz": CAUSAL_REFERENCE_HZ}
    if dataclasses.is_dataclass(m) and hasattr(m, "thickness"):
        d["thickness"] = m.thickness
    return d


def _mesh_dict(mesh) -> dict:
    h = hashlib.sha256(np.ascontiguousarray(mesh.xy, "<f8").tobytes()
                       + np.ascontiguousarray(mesh.area, "<f8").tobytes())
    if mesh.cells is not None:
        h.update(np.ascontiguousarray(mesh.cells, "<f8").tobytes())
    return {"kind": mesh.kind, "size": list(mesh.size), "cell": mesh.cell, "n": mesh.n,
            "arrays_sha256": h.hexdigest()}


def provenance(profile, mesh, contact, rule, output, solver="dense", solver_tol=DEFAULT_TOL) -> dict:
    """The inputs of one sweep output, as a JSON-able dict (hashed with the frequencies).

    ``rule=None`` is recorded as the default ``GreenRule()`` it stands for (every field). An
    irregular mesh records the relative tolerance of its radial interpolation of the regular
    kernel (``bem.RADIAL_TOL``; also in the code digest) and its traction scheme
    (``bem.edge_tractions``: "constant", or "sqrt-8" for the cells of a mesh file). A table of
    the fast solver (``solver`` resolved by ``solvers.resolve_solver`` to "fast") records
    ``solver = {"name": "fast", "tol": solver_tol, "code": digest of FAST_CODE, "chains": CHAINS}``
    (the warm-start chains of ``_compute_fast``: the iterates within the tolerance depend on them); a dense
    table records nothing more (its keys are those of the dense sweep before the option)."""
    prov = {"profile": {"layers": [_material_dict(l) for l in profile.layers],
                        "halfspace": _material_dict(profile.halfspace)},
            "mesh": _mesh_dict(mesh), "contact": contact,
            "rule": repr(GreenRule() if rule is None else rule),
            "output": output, "code_version": code_version(),
            "dof_order": "node-interleaved [ux0,uy0,uz0,ux1,...]" if output == "nodal" else output}
    if _grid(mesh) is None:
        prov["radial_tol"] = RADIAL_TOL
        prov["tractions"] = edge_tractions(mesh)
    if _solver_for(mesh, solver, solver_tol, (output,)) == "fast":
        prov["solver"] = {"name": "fast", "tol": float(solver_tol), "code": code_digest(*FAST_CODE)[:12],
                          "chains": CHAINS}
    return prov


def _solver_for(mesh, solver, solver_tol, outputs) -> str:
    """The solver ("dense" or "fast") a sweep of ``outputs`` uses (``solvers.resolve_solver``)."""
    check_solver(solver, solver_tol)
    return resolve_solver(solver, mesh, _grid(mesh) is not None, outputs)


def table_key(profile, mesh, frequencies_hz, contact="welded", output="gap", rule=None,
              solver="dense", solver_tol=DEFAULT_TOL) -> str:
    """The cache key of one sweep output (``ImpedanceTable.hash``: its inputs and the BEM code's
    digest, ``provenance`` + frequencies), from the inputs alone: nothing is swept or read. What
    is derived from a table and keyed by its hash (a rational fit) can be found with it."""
    return content_hash(provenance(profile, mesh, contact, rule, output, solver, solver_tol),
                        _frequencies(frequencies_hz))


def _frequencies(frequencies_hz) -> np.ndarray:
    return np.asarray(frequencies_hz, dtype=float).reshape(-1)


def _cache_path(cache_dir, output, key) -> Path:
    return Path(cache_dir) / f"impedance_{output}_{key[:20]}.h5"


def _read_cached(path, key, blocked=False):
    """The table cached at ``path`` for inputs hash ``key``, or None (absent, or damaged: then
    moved aside with a CacheWarning, see ``cache.read_entry``). blocked: a ``BlockedTable`` (the
    matrices left on disk, read in blocks, each chunk checked against its digest when it is first
    read: a damaged one raises ``DamagedTableError`` then, see ``discard_damaged``), else an
    ``ImpedanceTable`` in memory."""
    def reader(h, data=None):
        # read_entry verified the checksum (a blocked table's: without its chunks); an ImpedanceTable
        # is read once, as it verified it
        if blocked:
            table = BlockedTable.open(path, checksum=False)
            table.entry_stat = os.stat(path)
        else:
            table = ImpedanceTable.from_hdf5(h, path, data)
        if table.hash != key:
            raise TableError(f"holds the table of inputs {table.hash[:20]}, not {key[:20]}")
        return table
    return read_entry(path, reader, keep=not blocked, chunks=not blocked)


def discard_damaged(table, error: DamagedTableError, cache_dir) -> bool:
    """A ``DamagedTableError`` met while reading ``table`` (a blocked table): if it is an entry of the
    cache folder ``cache_dir``, move it aside with a ``CacheWarning`` (``cache.discard_entry``) and
    return True (the caller sweeps again: the entry is recomputed); else False (a table file the
    user gave: the error is theirs to see)."""
    if cache_dir is None or not isinstance(table, BlockedTable) or not hasattr(table, "entry_stat") \
            or Path(table.path).resolve().parent != Path(cache_dir).resolve():
        return False
    discard_entry(table.path, f"{type(error).__name__}: {error}", table.entry_stat, stacklevel=3)
    return True


class SweepMemoryError(UserInputError):
    """A sweep that would not fit in the machine's available memory (refused before allocating)."""


#: bytes of the interpreter with numpy/scipy/h5py loaded, counted in every estimate
BASE_BYTES = 200 * 2 ** 20
#: share of MemAvailable a sweep may plan to use (the rest: the OS, the estimate's own error)
MEMORY_SHARE = 0.9
#: added to the arrays' bytes: what the allocator keeps of freed temporaries (measured with
#: benchmarks/mesh_sweep.py: 1966 cells peaked 11 % above the arrays' sum plus the interpreter)
MARGIN = 0.15


def sweep_memory(n: int, n_freq: int, outputs=("rigid", "gap"), grid: bool = False, solver: str = "dense",
                 box=None, rhs=None, streamed=()) -> dict[str, int]:
    """Estimated peak bytes of ``impedance_sweep`` by item (and ``"total"``), before allocating.

    Parameters
    ----------
    n : int              interface nodes (3n DOFs)
    n_freq : int         frequencies swept (the outputs hold one matrix per frequency)
    outputs : iterable   among "rigid", "gap", "nodal"
    grid : bool          circle/rectangle grid meshes (assembly by distinct offsets), else irregular
    solver : "dense" or "fast" (resolved, ``solvers.resolve_solver``)
    box : (nx, ny)       the fast solver's grid box in nodes (None: a square of 2 sqrt(n / π)
                         nodes a side, a circle grid's, larger than a square grid's sqrt(n))
    rhs : int            the fast solver's right-hand sides per frequency (None: a symmetric
                         grid's, ``fastsolve.fast_memory``; ``fastsolve.right_hand_sides``)
    streamed : iterable  outputs written to disk frequency by frequency (``blocked.TableWriter``):
                         one matrix each is held, not n_freq

    Items: ``F`` the flexibility (3n)² complex, factorised in place (LU); ``assembly``: grid
    meshes gather (n², 3, 3) complex blocks and transpose them into F (one more F-sized array,
    freed before the solves: counted beyond ``work`` only), irregular ones hold the six static basis integrals per pair (48 n² bytes) and row blocks of
    ``CHUNK_PAIRS`` pairs; ``work``: per frequency, ``nodal`` inverts a copy of F and symmetrises
    (three more), ``gap`` solves for 6 + n right-hand sides (B real, X complex, K_g twice);
    ``outputs``: the tables held, n_freq matrices each, plus half the largest for the h5 copy of
    its real or imaginary part; ``margin``: ``MARGIN`` of all these (the allocator keeps part of
    the freed temporaries); ``base``: the interpreter and libraries.

    The fast solver (grid meshes) holds no F: ``F`` is 0, ``assembly`` the blocks at the distinct
    offsets (at most 4 n of 3×3 complex, three copies), ``work`` ``fastsolve.fast_memory`` (the
    FFT symbols, one batch's Krylov basis and grids, the N × N vertical block) once per warm-start
    chain (``CHAINS`` workers at most, one for a single frequency; it counts the matrix each assembles), ``outputs`` the one
    being stored and the ``LEAD`` more the chains may have solved ahead, beside the tables.
    """
    m = 3 * n
    if solver == "fast":
        if box is None:
            side = int(math.ceil(2 * math.sqrt(n / math.pi))) + 1
            box = (side, side)
        held = [16 * (1 + LEAD if o in streamed else n_freq + LEAD) * {"rigid": 6, "gap": 6 + n}[o] ** 2
                for o in outputs]
        items = {"F": 0, "assembly": 3 * 4 * n * 9 * 16, "work": min(CHAINS, max(1, n_freq)) * fastsolve.fast_memory(n, *box, rhs=rhs),
                 "outputs": sum(held) + (max(held) // 2 if held else 0)}
        items["margin"] = int(MARGIN * sum(items.values()))
        items["base"] = BASE_BYTES
        items["total"] = sum(items.values())
        return items
    fsize = 16 * m * m
    sizes = {"rigid": 6, "gap": 6 + n, "nodal": m}
    outputs = tuple(outputs)
    # grid: blocks gathered per pair and transposed; irregular: basis per pair + polygon temporaries
    assembly = 2 * fsize + 8 * n * n if grid else 48 * n * n + 40 * 4 * 8 * CHUNK_PAIRS
    work = 0
    if "nodal" in outputs:              # the inverse stays alive through the gap solve
        work += 3 * fsize
    if "gap" in outputs:
        g = 6 + n
        work += 24 * m * g + 3 * 16 * g * g
    if grid:
        # a grid's gathered blocks (one F-sized copy beside F while it is transposed into it) are
        # freed before the factorisation: the assembly and the solves' work do not coexist, so
        # only what the assembly holds beyond the work counts (benchmarks/growth.py, one frequency:
        # 625 and 1156 grid nodes peaked at 2.57 F and 2.53 F over the interpreter, estimated at
        # 1.00 and 1.01 times that; the sum of all three overestimated them by 1.8 and 1.6 times)
        assembly = max(0, fsize + 8 * n * n - work)
    held = [16 * (1 if o in streamed else n_freq) * sizes[o] ** 2 for o in outputs]
    items = {"F": fsize, "assembly": assembly, "work": work,
             "outputs": sum(held) + (max(held) // 2 if held else 0)}
    items["margin"] = int(MARGIN * sum(items.values()))
    items["base"] = BASE_BYTES
    items["total"] = sum(items.values())
    return items


def mesh_sweep_memory(mesh, n_freq: int, outputs=("rigid", "gap"), solver="dense",
                      solver_tol=DEFAULT_TOL, streamed=()) -> dict[str, int]:
    """``sweep_memory`` of a sweep of ``mesh`` (its node count, whether it is a grid, and the
    fast solver's grid box and right-hand sides when ``solver`` resolves to it), the estimate
    ``check_sweep_memory`` checks; the run-level guard (``orchestrator.memory_guard``) uses it."""
    grid = _grid(mesh)
    solver = _solver_for(mesh, solver, solver_tol, outputs)
    box = rhs = None
    if solver == "fast":
        box = tuple(int(v) for v in np.ptp(grid[0], axis=0) + 1)
        rhs = fastsolve.right_hand_sides(mesh)
    return sweep_memory(mesh.n, n_freq, outputs, grid=grid is not None, solver=solver, box=box, rhs=rhs,
                        streamed=streamed)


def available_memory() -> int | None:
    """Bytes the machine can give a new allocation: MemAvailable of /proc/meminfo, else the free
    physical pages (os.sysconf); None if neither is known."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return None


def _gib(b: float) -> str:
    return f"{b / 2 ** 30:.2f} GiB"



def check_sweep_memory(mesh, n_freq: int, outputs=("rigid", "gap"), solver="dense",
                       solver_tol=DEFAULT_TOL, streamed=()) -> dict[str, int]:
    """Refuse (SweepMemoryError, exit 2) a sweep whose ``sweep_memory`` estimate exceeds
    ``MEMORY_SHARE`` of ``available_memory()``; returns the estimate otherwise. ``solver`` as
    ``impedance_sweep``'s (resolved here: the fast solver's estimate holds no dense F); ``streamed``
    the outputs written to disk frequency by frequency (one matrix each held)."""
    est = mesh_sweep_memory(mesh, n_freq, outputs, solver, solver_tol, streamed)
    avail = available_memory()
    if avail is not None and est["total"] > MEMORY_SHARE * avail:
        per = est["total"] - est["outputs"]
        fast = _solver_for(mesh, solver, solver_tol, outputs) == "fast"
        hint = "" if fast or _grid(mesh) is None else "; a grid of 500 nodes or more may use [impedance] solver = 'fast'"
        raise SweepMemoryError(
            f"the impedance sweep of {mesh.n} interface nodes at {n_freq} frequenc{'y' if n_freq == 1 else 'ies'} (outputs "
            f"{', '.join(outputs)}) needs about {_gib(est['total'])} (flexibility {_gib(est['F'])}, "
            f"tables {_gib(est['outputs'])}) but the machine has {_gib(avail)} available "
            f"(MemAvailable): use a coarser mesh (larger foundation.element_size, fewer cells: memory "
            f"grows like N² with the dense solver{hint}) or fewer frequencies ([impedance].range_hz; the tables alone take "
            f"{_gib(est['outputs'] / max(n_freq, 1))} per frequency, the rest {_gib(per)})")
    return est


def impedance_sweep(profile, mesh, frequencies_hz, contact="welded", outputs=("rigid", "gap"),
                    cache_dir=None, progress=None, rule=None, solver="dense",
                    solver_tol=DEFAULT_TOL, workers=None) -> dict[str, ImpedanceTable]:
    """Impedance of ``mesh`` on ``profile`` at each frequency, reduced as asked.

    Parameters
    ----------
    profile : SoilProfile
    mesh : InterfaceMesh                 nodes about the raft centre
    frequencies_hz : array_like, Hz      strictly increasing, >= 0 (0 = static, exactly)
    contact : "welded" or "relaxed"
    outputs : iterable of "rigid" (6×6), "gap" (6+N), "nodal" (3N, large)
    cache_dir : path or None             read/write ``impedance_<output>_<hash>.h5`` there
                                         (None: no cache, always compute)
    progress : callable(done, total, label) or None, called after each frequency (label: "2.5 Hz")
    rule : passed to ``greens.regular_green``
    solver : "dense" (one LU of F per frequency), "fast" (grid meshes: FFT products and GMRES,
             ``fastsolve``; rigid and gap outputs) or "auto" (fast on a grid of at least
             ``solvers.AUTO_NODES`` nodes, except for "nodal"; else dense)
    solver_tol : the fast solver's relative residual ||b - F x|| / ||b|| per right-hand side
             (recorded in the provenance of its tables; ignored by the dense solver)
    workers : threads of the fast solver's warm-start chains (``sweep_workers``; None: the cores
             this process may use, at most ``CHAINS``): the wall time only, the same bits whatever it is

    Raises SweepMemoryError (a UserInputError) before computing when the estimated peak memory
    (``sweep_memory``) does not fit in the machine's available memory.

    Returns
    -------
    dict output -> ImpedanceTable; DOFs ``RIGID_DOFS``, ``gap_dofs(N)`` or ``nodal_dofs(N)``.
    With a cache_dir, an output larger than ``blocked.STREAM_BYTES`` (e.g. the gap table of 600
    nodes at 101 frequencies, 0.6 GB) is written to its cache entry as it is computed and returned
    as a ``blocked.BlockedTable`` (the matrices read in blocks from disk); the file is the same
    as ``ImpedanceTable.save`` would write (same datasets, digests and checksum), chunked.

    One LU factorisation of F per frequency (dense), or the solves of ``fastsolve.gap_and_rigid``
    (fast); K_out = Bᵀ F⁻¹ B (symmetrised).

    Performance: the matrices are small (723×723 for 241 nodes); run with one BLAS thread
    (the orchestrator does): threaded BLAS is no faster on them and several times slower
    beside a busy process.
    """
    if contact not in CONTACTS:
        raise BemError(f"contact = {contact!r}: use one of {CONTACTS}")
    outputs = tuple(dict.fromkeys(outputs))
    bad = [o for o in outputs if o not in OUTPUTS]
    if bad or not outputs:
        raise BemError(f"outputs = {outputs!r}: choose among {OUTPUTS}")
    f = _frequencies(frequencies_hz)
    if f.size == 0 or not np.all(np.isfinite(f)) or np.any(f < 0) or np.any(np.diff(f) <= 0):
        raise BemError("frequencies_hz must be a non-empty, strictly increasing list of finite "
                       "values >= 0 Hz")

    provs = {o: provenance(profile, mesh, contact, rule, o, solver, solver_tol) for o in outputs}
    dofs = {"rigid": RIGID_DOFS, "gap": gap_dofs(mesh.n), "nodal": nodal_dofs(mesh.n)}
    # large outputs (more than blocked.STREAM_BYTES) stay on disk: written to their cache entry frequency
    # by frequency (blocked.TableWriter) and returned as a BlockedTable
    large = {o for o in outputs if cache_dir is not None and table_bytes(f.size, len(dofs[o])) > STREAM_BYTES}
    tables = {}
    if cache_dir is not None:
        for o in outputs:
            key = content_hash(provs[o], f)
            table = _read_cached(_cache_path(cache_dir, o, key), key, blocked=o in large)
            if table is not None:
                tables[o] = table
    todo = [o for o in outputs if o not in tables]
    if todo:
        with contextlib.ExitStack() as stack:
            sinks = {}
            for o in (o for o in todo if o in large):
                try:
                    Path(cache_dir).mkdir(parents=True, exist_ok=True)
                    sinks[o] = stack.enter_context(TableWriter(_cache_path(cache_dir, o, content_hash(provs[o], f)),
                                                               f, dofs[o], provs[o]))
                except (OSError, OutputWriteError) as exc:      # a cache that cannot be written only warns
                    why = exc.reason if isinstance(exc, OutputWriteError) else exc
                    warnings.warn(CacheWarning(f"cannot write the {o} table's cache entry in {cache_dir} ({why}): "
                                               "it is held in memory"), stacklevel=2)
            check_sweep_memory(mesh, f.size, todo, solver, solver_tol, list(sinks))   # before anything large
            bem = SurfaceBem(profile, mesh, contact, rule)
            fast = [o for o in todo if "solver" in provs[o]]
            dense = [o for o in todo if o not in fast]
            computed = {}
            if dense:
                computed.update(_compute(bem, f, dense, progress, sinks))
            if fast:
                computed.update(_compute_fast(bem, f, fast, progress, solver_tol, sinks, workers))
        for o in todo:
            if o in sinks:
                tables[o] = BlockedTable.open(sinks[o].path, verify=False)      # just written
                continue
            tables[o] = ImpedanceTable(f, computed[o], dofs[o], provs[o])
            if cache_dir is not None and o not in large:          # (a large one's writer already warned)
                write_entry(_cache_path(cache_dir, o, tables[o].hash), tables[o].save)
    return {o: tables[o] for o in outputs}


def _compute(bem, f, outputs, progress, sinks=None) -> dict[str, np.ndarray]:
    """Loop over frequencies: one flexibility F and one LU factorisation per frequency.

    Each output is computed the same way whatever else is requested, so that a cached table
    (keyed by its own inputs only) is bit-identical to a fresh one: rigid = Tᵀ F⁻¹ T (6
    columns), gap = Bᵀ F⁻¹ G (6 + N columns; Bᵀ X uses the structure of B, Z is a row
    selection), nodal = F⁻¹ (``SurfaceBem.impedance``), all symmetrised. (Condensing the rigid
    6×6 from the gap one, Pᵀ K_g P, is exact in theory but differs by round-off, 3e-16.)
    sinks : {output: blocked.TableWriter}, the outputs written there frequency by frequency
    (``sink[k] = K``) instead of held in memory.
    """
    mesh = bem.mesh
    n = mesh.n
    T = rigid_transform(mesh)
    Th = T.copy()
    Th[2::3, :] = 0.0
    G = gap_transform(mesh)
    sizes = {"rigid": 6, "gap": 6 + n, "nodal": 3 * n}
    sinks = sinks or {}
    out = {o: sinks[o] if o in sinks else np.empty((f.size, sizes[o], sizes[o]), dtype=complex) for o in outputs}
    for k, fk in enumerate(f):
        F = bem.flexibility(2 * math.pi * fk)
        if "nodal" in outputs:                # as SurfaceBem.impedance, keeping F
            K = sla.inv(F.T, check_finite=False).T
            out["nodal"][k] = 0.5 * (K + K.T)
        if "rigid" in outputs or "gap" in outputs:
            # as SurfaceBem.solve: LAPACK wants Fortran order, factor Fᵀ and solve with trans=1
            lu = sla.lu_factor(F.T, overwrite_a=True, check_finite=False)
        if "rigid" in outputs:
            Kr = T.T @ sla.lu_solve(lu, T, trans=1, check_finite=False)
            out["rigid"][k] = 0.5 * (Kr + Kr.T)
        if "gap" in outputs:
            X = sla.lu_solve(lu, G, trans=1, check_finite=False)
            Kg = np.empty((6 + n, 6 + n), dtype=complex)
            Kg[:6] = Th.T @ X
            Kg[6:] = X[2::3]
            out["gap"][k] = 0.5 * (Kg + Kg.T)
        if progress is not None:
            progress(k + 1, f.size, f"{fk:.3g} Hz")
    return out


#: warm-start chains of the fast sweep (a constant of the code, never the machine's core count: the
#: table is a function of the inputs only): frequency k is solved in chain k % CHAINS, GMRES starting
#: from that chain's own previous solutions (``first_guess``); the chains run in up to CHAINS threads
#: (``sweep_workers``), with the same bits whatever the number of threads. Recorded in the fast
#: tables' provenance (the first guesses, hence the iterates within the tolerance, depend on it).
CHAINS = 2
#: frequencies the chains may solve ahead of the next one stored beyond one per thread (slack for
#: unequal solves; each one is a matrix held: at most 2 + CHAINS of an output, ``sweep_memory``)
LEAD = 1


def sweep_workers(workers: int | None = None) -> int:
    """Threads running the fast sweep's chains: ``workers`` (None: the cores this process may use,
    ``os.sched_getaffinity``), between 1 and ``CHAINS``. It changes the wall time only, never the table."""
    if workers is None:
        workers = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    workers = max(1, min(CHAINS, int(workers)))
    while CHAINS % workers:                         # each thread owns whole chains
        workers -= 1
    return workers


def first_guess(past, f: float):
    """GMRES's first guesses at frequency ``f`` from ``past``, the (frequency, solutions) of a chain's
    last frequencies (at most ``WARM``): the polynomial through them (Lagrange form) evaluated at f,
    quadratic from three on (measured on the 625-node mat, 16 frequencies at 0.25 Hz: 20 % less CPU
    than the line through the last two, sequential or in two chains); None without any."""
    if not past:
        return None
    fs = [p[0] for p in past]
    weights = [math.prod((f - b) / (a - b) for j, b in enumerate(fs) if j != i) for i, a in enumerate(fs)]
    return {key: sum(w * p[1][key] for w, p in zip(weights, past)) for key in past[-1][1]}


#: solutions a chain keeps for its first guesses (``first_guess``)
WARM = 3


class _Chains:
    """The fast solves of some chains (``CHAINS``), each warm-started within itself: ``solve(k)`` for
    the frequencies of those chains in increasing order gives the same matrices whatever other
    ``_Chains`` solve the other chains, in this thread or another."""

    def __init__(self, bem, f, outputs, tol, T, Th):
        self.bem, self.f, self.outputs, self.tol, self.T, self.Th = bem, f, outputs, tol, T, Th
        self.past = {}                              # chain -> [(f, solutions)] of its last WARM frequencies

    def solve(self, k: int) -> dict:
        past = self.past.get(k % CHAINS, [])
        fk = float(self.f[k])
        mats, _, solutions = fastsolve.gap_and_rigid(self.bem, 2 * math.pi * fk, self.outputs, self.tol,
                                                     self.T, self.Th, first_guess(past, fk))
        self.past[k % CHAINS] = (past + [(fk, solutions)])[-WARM:]
        return mats


#: how the chains run beside the storing thread: "processes" (forked, each chain's matrices sent back
#: through a pipe) or "threads"; the same bits either way
PARALLEL = "processes"


def _can_fork() -> bool:
    """Whether chain processes can be forked here (not from a daemonic process: a pool's worker)."""
    import multiprocessing
    return "fork" in multiprocessing.get_all_start_methods() and not multiprocessing.current_process().daemon


def _chain_process(w, workers, conn, bem, f, outputs, tol, T, Th):
    """A forked chain process: the frequencies w, w + workers, ... solved in order (``_Chains``), each
    sent on ``conn`` as a header (k, [(output, shape)]) and each matrix's bytes; an error as
    ("error", exception). Ctrl-C is the parent's to handle (it ends this process)."""
    import gc
    import signal
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)     # the parent's terminate() ends it, whatever it inherited
    # no cyclic collection here: a garbage cycle of the parent's holding an HDF5 object (the table being
    # written is open) must not be closed by this copy, which shares the file's descriptor
    gc.disable()
    try:
        chains = _Chains(bem, f, outputs, tol, T, Th)
        for k in range(w, f.size, workers):
            mats = chains.solve(k)
            conn.send((k, [(o, mats[o].shape) for o in outputs]))
            for o in outputs:
                conn.send_bytes(np.ascontiguousarray(mats[o], dtype=complex).reshape(-1).view(np.uint8))
    except BaseException as exc:                    # raised again in the parent
        try:
            conn.send(("error", exc))
        except Exception:                           # an exception that does not pickle
            conn.send(("error", fastsolve.FastSolveError(f"{type(exc).__name__}: {exc}")))
    finally:
        conn.close()


def _run_processes(bem, f, outputs, tol, T, Th, workers, store):
    """``_compute_fast``'s chains in ``workers`` forked processes; ``store(k, mats)`` here, in frequency
    order (each process sends its next frequency once the last one is received: at most one ahead)."""
    import multiprocessing
    ctx = multiprocessing.get_context("fork")
    pipes, procs = [], []
    try:
        for w in range(workers):
            recv, send = ctx.Pipe(duplex=False)
            proc = ctx.Process(target=_chain_process, args=(w, workers, send, bem, f, outputs, tol, T, Th),
                               name=f"sweep-chain-{w}", daemon=True)
            proc.start()
            send.close()
            pipes.append(recv)
            procs.append(proc)
        for k in range(f.size):
            conn = pipes[k % workers]
            try:
                head = conn.recv()
                if head[0] == "error":
                    raise head[1]
                mats = {}
                for o, shape in head[1]:
                    mats[o] = np.empty(shape, dtype=complex)
                    conn.recv_bytes_into(mats[o].reshape(-1).view(np.uint8))
            except EOFError:
                procs[k % workers].join(timeout=5)
                raise fastsolve.FastSolveError(f"the fast sweep's chain process {k % workers} ended before frequency {k} "
                                     f"(exit code {procs[k % workers].exitcode}): run it again, or with "
                                     "[impedance] solver = 'dense'") from None
            if head[0] != k:
                raise fastsolve.FastSolveError(f"the fast sweep's chain process sent frequency {head[0]}, expected {k}")
            store(k, mats)
    finally:
        for proc in procs:
            if proc.is_alive() and proc.exitcode is None:
                proc.join(timeout=0.1)
            if proc.is_alive():
                proc.terminate()
            proc.join()
        for conn in pipes:
            conn.close()


def _compute_fast(bem, f, outputs, progress, tol, sinks=None, workers=None) -> dict[str, np.ndarray]:
    """The rigid and gap outputs by the fast solver (``fastsolve.gap_and_rigid``): the same matrices as
    ``_compute`` within the relative residual ``tol``. The frequencies are split into ``CHAINS``
    interleaved chains; GMRES starts from the solutions of the chain's previous three frequencies,
    extrapolated in frequency (``first_guess``: fewer iterations on a fine frequency list; every
    solve still meets ``tol``). ``sweep_workers(workers)`` workers solve the chains while this thread
    stores the matrices in frequency order and reports progress: forked processes (``PARALLEL``,
    ``_run_processes``: one frequency ahead each, its matrices sent through a pipe), or threads
    (where a process cannot fork, or ``PARALLEL = "threads"``: the FFTs, the einsum and BLAS release
    the GIL, 4 % of a frequency's samples hold it, but a thread preempted while holding it stalls
    the other; at most ``LEAD`` frequencies beyond one per thread ahead of the last one stored).
    sinks: as ``_compute``'s."""
    n = bem.mesh.n
    T = rigid_transform(bem.mesh)
    Th = T.copy()
    Th[2::3, :] = 0.0
    sizes = {"rigid": 6, "gap": 6 + n}
    sinks = sinks or {}
    out = {o: sinks[o] if o in sinks else np.empty((f.size, sizes[o], sizes[o]), dtype=complex) for o in outputs}

    def store(k, mats):
        for o in outputs:
            out[o][k] = mats[o]
        if progress is not None:
            progress(k + 1, f.size, f"{f[k]:.3g} Hz")

    workers = min(sweep_workers(workers), f.size)
    if workers == 1:
        chains = _Chains(bem, f, outputs, tol, T, Th)
        for k in range(f.size):
            store(k, chains.solve(k))
        return out
    fastsolve.scipy.fft.next_fast_len(2)             # the lazy modules loaded here, not in a race
    if PARALLEL == "processes" and _can_fork():
        _run_processes(bem, f, outputs, tol, T, Th, workers, store)
        return out
    ready, state = threading.Condition(), {"stored": 0, "error": None, "stop": False}
    done = {}

    def work(w):
        chains = _Chains(bem, f, outputs, tol, T, Th)
        try:
            for k in range(w, f.size, workers):     # chain k % CHAINS: worker w has the chains w, w + workers, ...
                with ready:
                    ready.wait_for(lambda: state["stop"] or k < state["stored"] + LEAD + workers)
                    if state["stop"]:
                        return
                mats = chains.solve(k)
                with ready:
                    done[k] = mats
                    ready.notify_all()
        except BaseException as exc:                # raised again in the storing thread
            with ready:
                state["error"] = state["error"] or exc
                ready.notify_all()

    threads = [threading.Thread(target=work, args=(w,), name=f"sweep-chain-{w}", daemon=True) for w in range(workers)]
    for t in threads:
        t.start()
    try:
        for k in range(f.size):
            with ready:
                ready.wait_for(lambda: k in done or state["error"] is not None)
                if k not in done:
                    raise state["error"]
                mats = done.pop(k)
            store(k, mats)
            with ready:
                state["stored"] = k + 1
                ready.notify_all()
    finally:
        # on an error or a stop (progress may raise) the threads end after their current frequency,
        # unwaited for: the caller's error is not held up by a solve it no longer needs
        with ready:
            state["stop"] = True
            ready.notify_all()
    for t in threads:
        t.join()
    return out


def static_impedance(profile, mesh, contact="welded", output="rigid", rule=None,
                     cache_dir=None, solver="dense", solver_tol=DEFAULT_TOL) -> np.ndarray:
    """K(0) (f = 0 exactly) for one output, shape (n, n), complex (Im from hysteretic damping;
    real for the causal model); solver, solver_tol as ``impedance_sweep``."""
    return impedance_sweep(profile, mesh, [0.0], contact, (output,), cache_dir, rule=rule,
                           solver=solver, solver_tol=solver_tol)[output].matrices[0].copy()

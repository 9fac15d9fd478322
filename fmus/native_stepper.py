"""The native C runtime run in process: the monolithic route's fast path.

The stepper and the soil of the native FMUs (fmus/native/: stepper.c, soil.c, linalg.c,
resources.c) with ``simulate.c``'s entry points: ``up_sim_open`` sets a run up, ``up_sim_steps``
steps it a chunk of samples at a time (``CHUNK``, a fixed count: the host reports progress and
takes Ctrl-C between two chunks; the same bits whatever the chunks), ``up_sim_close`` frees it.
The library is compiled for this machine by the FMUs' builder
(``fmus.native_build.compile_runtime``: the system compiler, else ziglang's), once per content
hash of its sources, the compiler and the flags, into the cache folder (``<cache>/native/``; a
temporary folder of the process for a run without cache), and loaded with ctypes.
``structure.simulate`` (the Python stepper, structure/newmark.py) stays the readable reference;
the two agree to round-off (tests/fmu/test_native_stepper.py, test_native_springs.py: 1e-10 on a
bonded raft, with uplift and step halving within max(1e-10, 100 x the scene's round-off spread),
tests/helpers/roundoff.py).

API::

    from fmus.native_stepper import library, simulate_native
    if library() is not None:                       # None: no compiler here (library_note() says why)
        res = simulate_native(stepper, ag, output_nodes=["top"])
"""
from __future__ import annotations

import ctypes
import hashlib
import json
import os
import shutil
import subprocess
import sys
import threading
import time
import types
from pathlib import Path

import numpy as np

from fmus.native_build import (CFLAGS, SOURCES, NativeBuildError, compile_runtime,
                               encode_resources, host_platform, soil_records, stepper_records)
from fmus.schema import ENERGY_TERMS, row_slices, row_width
from soil_impedance.cache import feed, read_entry, write_entry
from uplift_common.code import code_digest
from uplift_common.files import atomic_output, hdf5_output, stamp_checksum
from uplift_common.errors import UserInputError

#: the C files of the in-process library (the numerics and simulate.c; no FMI side)
HOST_SOURCES = ("simulate.c", "stepper.c", "soil.c", "linalg.c", "resources.c", "spectra.c")

_lock = threading.Lock()
_loaded: dict = {}                  # folder -> (CDLL or None, note)


def _compiler(folder=None) -> tuple[str, str]:
    """(compiler for compile_runtime, its identity for the hash): the system compiler ($CC, else
    cc) when there is one (its identity kept in ``folder``: ``_system_identity``), else ziglang's."""
    cc = os.environ.get("CC", "cc")
    found = shutil.which(cc)
    if found:
        return "cc", _system_identity(cc, found, folder)
    out = subprocess.run([sys.executable, "-m", "ziglang", "version"], capture_output=True, text=True, timeout=60)
    if out.returncode != 0:
        raise NativeBuildError("no C compiler: neither $CC / cc nor the ziglang package (pip install ziglang)")
    return "zig", f"zig {out.stdout.strip()}"


def _system_identity(cc: str, found: str, folder=None) -> str:
    """The identity of the system compiler ``cc`` (found at ``found``) in a library's hash:
    ``"{cc}: {its --version}"``. With a ``folder`` it is kept there (``compiler-<key>.txt``,
    with the SHA-256 of its text, written atomically) under the key of the compiler's file (its
    path, resolved path, device, inode, size, modification and change times): a warm run reads
    it back instead of starting the compiler (5-15 ms of a process's wall time); a compiler
    changed in place or replaced is a new key, a damaged entry is asked again."""
    real = os.path.realpath(found)
    st = os.stat(real)
    key = hashlib.sha256(repr((cc, found, real, st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns,
                               st.st_ctime_ns)).encode()).hexdigest()[:24]
    kept = None if folder is None else Path(folder) / f"compiler-{key}.txt"
    if kept is not None:
        try:
            digest, _, ident = kept.read_text(encoding="utf-8").partition("\n")
            if digest == hashlib.sha256(ident.encode()).hexdigest():
                return ident
        except (OSError, UnicodeDecodeError):
            pass
    out = subprocess.run([cc, "--version"], capture_output=True, text=True, timeout=60)
    ident = f"{cc}: {out.stdout.strip()}"
    if kept is not None and out.returncode == 0:
        try:
            kept.parent.mkdir(parents=True, exist_ok=True)
            with atomic_output(kept) as tmp:
                tmp.write_text(f"{hashlib.sha256(ident.encode()).hexdigest()}\n{ident}", encoding="utf-8")
        except (OSError, UserInputError):       # a refused write (OutputWriteError, OutputPathError):
            pass                                # not kept, asked again next time
    return ident


def _digest(compiler_id: str) -> str:
    """The content hash of a library: the C runtime's sources and headers (``code_digest`` of
    fmus/native, as every cache of the project), the compiler, the flags and the platform."""
    h = hashlib.sha256(code_digest("fmus.native").encode())
    h.update(f"\0{compiler_id}\0{' '.join(CFLAGS)}\0{host_platform()}".encode())
    return h.hexdigest()[:24]


def _compiled(folder: Path, stem: str, sources) -> Path:
    """The shared library of ``sources`` for this machine in ``folder``, compiled when its
    content hash (``_digest``) is not there yet."""
    compiler, ident = _compiler(folder)
    path = folder / f"{stem}-{_digest(ident)}.{'dll' if sys.platform == 'win32' else 'so'}"
    if not path.is_file():
        blob = compile_runtime((host_platform(),), compiler, sources=sources)[host_platform()]
        folder.mkdir(parents=True, exist_ok=True)
        with atomic_output(path) as tmp:          # a concurrent build writes the same bytes
            tmp.write_bytes(blob)
    return path


def declare(lib: ctypes.CDLL) -> ctypes.CDLL:
    """``lib`` (a host library of simulate.c) with the signatures of its entry points set."""
    p, i64 = ctypes.c_void_p, ctypes.c_int64
    for name, restype, argtypes in (
            ("up_sim_open", p, [ctypes.c_char_p, ctypes.c_uint64, p, ctypes.c_char_p]),
            ("up_sim_width", i64, [p]),
            ("up_sim_steps", ctypes.c_int, [p, p, i64, i64, p, p, p, ctypes.c_char_p]),
            ("up_sim_steps_src", ctypes.c_int, [p, p, p, i64, i64, p, p, p, ctypes.c_char_p]),
            ("up_sim_rewind", None, [p, p]),
            ("up_sim_correction", ctypes.c_int, [p, i64, ctypes.c_int]),
            ("up_sim_lean", None, [p, ctypes.c_int]),
            ("up_sim_close", None, [p]),
            ("up_simulate", ctypes.c_int, [ctypes.c_char_p, ctypes.c_uint64, p, i64, p, p, p, ctypes.c_char_p])):
        f = getattr(lib, name)
        f.restype, f.argtypes = restype, argtypes
    return lib


def _build(folder: Path) -> ctypes.CDLL:
    return declare(ctypes.CDLL(str(_compiled(folder, "uplift-host", HOST_SOURCES))))


_private: list = []                # the process's temporary folder, when no folder is given


def _folder(folder) -> Path:
    """``folder``, or (None) a temporary folder of this process, removed at exit: nothing is
    written to the cache (a run with --no-cache), the library is compiled once per process."""
    if folder is not None:
        return Path(folder)
    with _lock:
        if not _private:
            import atexit
            import tempfile
            _private.append(Path(tempfile.mkdtemp(prefix="uplift_native_")))
            atexit.register(shutil.rmtree, _private[0], True)
        return _private[0]


def cache_folder(cache_dir) -> Path | None:
    """Where the library of a run with the cache folder ``cache_dir`` lives: ``<cache_dir>/native``,
    or None (a temporary folder of the process) when the run uses no cache."""
    return None if cache_dir is None else Path(cache_dir) / "native"


def fmu_binaries(folder=None) -> dict:
    """{host platform: bytes} of the native FMUs' FMI 2.0 runtime compiled for this machine, from
    ``folder`` as ``library`` (compiled on first use), for ``build_native_fmus(...,
    binaries=...)``; raises NativeBuildError (or OSError) when it cannot be compiled here."""
    path = _compiled(_folder(folder), "uplift-fmu2", SOURCES)
    return {host_platform(): path.read_bytes()}


def library(folder=None):
    """The loaded host library (ctypes.CDLL), built on first use into ``folder`` (a run's
    ``cache_folder(cache_dir)``; None: a temporary folder of this process); None when it cannot be
    built here (``library_note`` says why)."""
    folder = _folder(folder)
    with _lock:
        if folder not in _loaded:
            try:
                _loaded[folder] = (_build(folder), "")
            except (NativeBuildError, OSError, subprocess.SubprocessError, ValueError) as exc:
                _loaded[folder] = (None, f"the native stepper is not available ({str(exc).splitlines()[0]}): "
                                         "the Python stepper ran")
        return _loaded[folder][0]


def loaded_library():
    """A host library this process has loaded already (``library``), or None: nothing is built or
    loaded here (orchestrator.spectra's response spectra take its C loop when a run has one)."""
    with _lock:
        return next((lib for lib, _ in _loaded.values() if lib is not None), None)


def library_note(folder=None) -> str:
    """Why ``library(folder)`` is None ("" when it is loaded)."""
    library(folder)
    return _loaded[_folder(folder)][1]


def springs_soil(soil, dt: float):
    """A soil without memory (springs and dashpots: ``instantaneous(dt)`` -> (K, C), no history
    force, e.g. structure.WinklerSoil) as the RecursiveConvolutionSoil of the rational model
    D = K, E = C with no pole: the same equations, in the form the native stepper runs.
    Passivity is not checked again (springs and dashpots of non-negative constants)."""
    from soil_impedance.convolution import RecursiveConvolutionSoil
    from soil_impedance.rational import RationalModel
    dense = lambda a: np.asarray(a.toarray() if hasattr(a, "toarray") else a, float)
    K, C = soil.instantaneous(dt)
    n = soil.n_dof
    model = RationalModel(np.zeros(0, complex), np.zeros((0, n, n), complex), dense(K), dense(C))
    return RecursiveConvolutionSoil(model, dt, checked=True)


#: samples per call of the C runtime (progress is reported and an interrupt taken between two):
#: a fixed count, so that the answer does not depend on time (it does not depend on the count)
CHUNK = 200


def encode_run(st, output_nodes=(), extra_dofs=()) -> bytes:
    """The resource records of a run of the stepper ``st`` (its matrices, static state, contact
    settings, soil model, step) with acc/disp histories of the nodes ``output_nodes`` (then of the
    DOF triples ``extra_dofs``: ``plate_dofs``): what the C runtime reads (``simulate_native``,
    ``native_max_uplift``; also a cache key of its answer). ``st`` may be a ``CachedStepper``
    (its records read back from the cache: the same bytes)."""
    model = st.model

    dofs = [model.dofs(model.node_by_name(nm).id)[:3] for nm in output_nodes] + list(extra_dofs)
    soil = getattr(st.soil, "soil", st.soil)       # a plate stepper's soil: the wrapper of the soil's own
    cached = getattr(st, "records", None)
    mine = stepper_records(st, dofs) if cached is None else \
        {**cached, "node_dofs": np.array(dofs, np.int64).reshape(-1, 3)}
    return encode_resources({**soil_records(soil.model, st.dt, getattr(soil, "compressed", None)), **mine})


#: what a rigid raft stepper's records depend on besides its inputs: the code that makes them (the
#: structure's matrices, damping, static state and penalty; their records) and this module's keys
STEPPER_CODE = ("structure", "fmus.native_build", "fmus.native_stepper")


class CachedStepper:
    """What the C runtime and ``simulate_native`` read of a rigid raft's ``structure.NewmarkStepper``,
    read back from the cache (``rigid_stepper``): its records (``fmus.native_build.stepper_records``,
    their order kept), the model, the soil, the step, the contact settings and the static state."""

    def __init__(self, model, soil, dt: float, contact, records: dict, settlement: float):
        self.model, self.soil, self.dt, self.contact, self.records = model, soil, float(dt), contact, records
        self.alpha = float(records["alpha"])
        self.ns, self.N = int(records["ns"]), int(records["N"])
        self.Bq3, self.kp, self.P0, self.delta0 = records["Bq3"], records["kp"], records["P0"], records["delta0"]
        self.static = types.SimpleNamespace(settlement=settlement)


def rigid_stepper(model, soil, dt: float, contact=None, damping=None, alpha: float = 0.0, ag0=(0.0, 0.0, 0.0),
                  cache_dir=None):
    """``structure.NewmarkStepper(model, soil, dt, contact, damping, alpha, external_soil=True,
    ag0=ag0)`` for ``simulate_native``, its records kept in the cache folder ``cache_dir``
    (``stepper-<key>.h5``, checksummed, verified on read) under the key of what the stepper reads
    (``stepper_key``): a warm run gets a ``CachedStepper`` instead, no matrix assembled, no static
    solve, no modal damping (scipy is not imported), the same records to the bit. Without a cache
    folder, or with inputs the key cannot digest, the stepper itself."""
    from structure import NewmarkStepper
    key = None if cache_dir is None else stepper_key(model, soil, dt, contact, damping, alpha)
    path = None if key is None else Path(cache_dir) / f"stepper-{key[:24]}.h5"
    if path is not None:
        hit = read_entry(path, lambda f, data: CachedStepper(model, soil, dt, contact or _contact(),
                                                             *_read_records(f, data)), keep=True, pairs=False)
        if hit is not None:
            return hit
    st = NewmarkStepper(model, soil, dt, contact=contact, damping=damping, alpha=alpha, external_soil=True, ag0=ag0)
    if path is not None:
        records = stepper_records(st, np.zeros((0, 3), np.int64))

        def writer(p):
            with hdf5_output(p) as f:
                for name, value in records.items():
                    f.create_dataset(f"records/{name}", data=value)
                f.attrs["order"] = json.dumps(list(records))
                f.attrs["settlement"] = float(st.static.settlement)
                stamp_checksum(f)
        write_entry(path, writer)
    return st


def _contact():
    from structure import ContactSettings          # the default settings, as NewmarkStepper makes them
    return ContactSettings()


def _read_records(f, data: dict) -> tuple:
    """(records in their order, settlement) of a ``rigid_stepper`` entry; ``data``: its datasets
    as the checksum's verification read them (``read_entry(keep=True)``)."""
    order = json.loads(f.attrs["order"])
    stored = sorted(name[len("/records/"):] for name in data if name.startswith("/records/"))
    if sorted(order) != stored or len(stored) != len(data):
        raise ValueError(f"records {stored} do not match their order {order}")
    return {name: data[f"/records/{name}"] for name in order}, float(f.attrs["settlement"])


def stepper_key(model, soil, dt: float, contact, damping, alpha: float) -> str | None:
    """SHA-256 of what a rigid raft's NewmarkStepper reads to make its records: ``STEPPER_CODE``,
    the structure model (every field), the soil's size and static stiffness (its penalty and
    static state), the step, the contact settings, the damping and the HHT alpha; None when one
    of them has no digest (``feed`` raises TypeError: nothing is kept)."""
    h = hashlib.sha256(code_digest(*STEPPER_CODE).encode())
    K = soil.static_stiffness()
    try:
        for part in (model, int(soil.n_dof), np.asarray(K.toarray() if hasattr(K, "toarray") else K, float),
                     float(dt), contact, damping, float(alpha)):
            feed(h, part)
    except TypeError:
        return None
    return h.hexdigest()


def plate_dofs(st) -> list:
    """A plate raft's DOFs that its results read (``PlateRaftModel.plate_columns``: q, the free
    vertices' rotations and deflections t, 6 + 3 nf, ascending) as DOF triples: recorded as the
    pseudo output nodes' displacements and accelerations, so the C runtime's rows carry them;
    [] for a rigid raft."""
    cols = getattr(st.model, "plate_columns", None)
    if st.Bq3 is not None or cols is None:
        return []
    return [tuple(int(k) for k in cols[j:j + 3]) for j in range(0, len(cols), 3)]


def _stepped(lib, blob: bytes, ag, take, chunk: int = CHUNK, progress=None, into=None):
    """Run the encoded model ``blob`` (``encode_run``) over ``ag`` (nt, 3), ``chunk`` samples per
    call of the C runtime; after each call ``take(k0, rows, iters)`` with the rows and Newton
    counts of samples k0 .. k0 + len(rows) - 1 (a buffer the next call overwrites), then
    ``progress(done, nt)``. into: (rows (nt, width), iters (nt,) int64), C-ordered: each call
    writes its samples there in place (``take`` gets views of them: nothing to copy). Returns
    (stats (3): samples computed, factorisations, halved steps; the stepper's message, "" when
    every sample was computed). An exception between two calls propagates, the run freed."""
    if chunk < 1:
        raise ValueError(f"chunk = {chunk}: the samples per call must be at least 1")
    nt = ag.shape[0]
    stats = np.zeros(3, np.int64)
    err = ctypes.create_string_buffer(1024)
    handle = lib.up_sim_open(blob, len(blob), ag.ctypes.data, err)
    if not handle:
        raise NativeBuildError(f"the native stepper refused the model: {err.value.decode(errors='replace')}")
    try:
        width = lib.up_sim_width(handle)
        if into is not None:
            rows, iters = into
            if rows.shape != (nt, width) or iters.shape != (nt,) or not (rows.flags.c_contiguous and rows.dtype == float
                                                                        and iters.dtype == np.int64):
                raise ValueError(f"into: rows ({nt}, {width}) float and iters ({nt},) int64, C-ordered, needed")
        else:
            rows = np.empty((min(chunk, nt), width))
            iters = np.empty(rows.shape[0], np.int64)
        rc, k = 0, 0
        while rc == 0 and k < nt:
            k1 = min(k + chunk, nt)
            at = k if into is not None else 0           # the first row this call writes
            rc = lib.up_sim_steps(handle, ag.ctypes.data, k, k1, rows[at:].ctypes.data, iters[at:].ctypes.data,
                                  stats.ctypes.data, err)
            if rc < 0:
                raise NativeBuildError(f"the native stepper stopped: {err.value.decode(errors='replace')}")
            done = int(stats[0])
            take(k, rows[at:at + done - k], iters[at:at + done - k])
            k = k1
            if rc == 0 and progress is not None:
                progress(k, nt)
    finally:
        lib.up_sim_close(handle)
    return stats, err.value.decode(errors="replace") if rc else ""


def _checked(ag, lib):
    """(ag as a contiguous float array, the library), or the error of a run that cannot start."""
    lib = lib or library()
    if lib is None:
        raise NativeBuildError(library_note())
    ag = np.ascontiguousarray(ag, float)
    if ag.ndim != 2 or ag.shape[1] != 3 or not np.all(np.isfinite(ag)):
        from structure import StructureError
        raise StructureError(f"ground acceleration must be a finite (nt, 3) array, got shape {ag.shape}")
    return ag, lib


def _plate_histories(st, node, ag, raft_points, names) -> dict:
    """A plate raft's records as ``structure.simulate`` gives them, from the pseudo nodes'
    rows ``node`` (nt, k, 6) (absolute accelerations, then displacements, of the DOF triples
    ``plate_dofs``) and the motion ``ag`` (nt, 3): the plate's deflections and moments
    (``PlateStepper.plate_outputs`` on the recorded columns, after the run), the vertices, the
    held ones, the stick-base cells; with ``raft_points`` ({name: (x, y)}), their acc (absolute)
    and disp histories and info (``structure.plate_raft.raft_point_operators``)."""
    from structure.plate_raft import raft_point_operators
    pm = st.model
    cols = pm.plate_columns
    nt = node.shape[0]
    U = node[:, :, 3:].reshape(nt, -1)
    out = {**st.plate_outputs(U, cols), "plate_vertices": np.array(pm.points),
           "plate_moment_cells": pm.base_cells.copy(), "plate_vertex_held": pm.slaved.copy()}
    ops, info = raft_point_operators(pm, raft_points, names)
    if ops:
        A = (node[:, :, :3] - ag[:nt, None, :]).reshape(nt, -1)     # relative accelerations
        out["points"] = ({nm: (P[:, cols] @ A.T).T + ag[:nt] for nm, P in ops.items()},
                         {nm: (P[:, cols] @ U.T).T for nm, P in ops.items()}, info)
    return out


def native_max_uplift(st, ag, lib=None, blob: bytes | None = None) -> float:
    """Max gap (m) of ``simulate_native(st, ag, [])``, NaN when a step's Newton iteration fails:
    only the gaps are read, a chunk at a time (the time-step check's run). blob: ``encode_run(st)``
    when the caller has it already."""
    ag, lib = _checked(ag, lib)
    tops = []                                      # each chunk's largest gap

    def take(k0, rows, iters):
        if rows.size and st.N:
            tops.append(float(rows[:, row_slices(st.N, 0)["gap"]].max()))
    _, message = _stepped(lib, encode_run(st) if blob is None else blob, ag, take)
    return float("nan") if message else max(tops, default=0.0)    # as RouteResult.max_uplift


def simulate_native(st, ag, output_nodes=None, route: str = "native", lib=None, progress=None,
                    chunk: int = CHUNK, raft_points=None):
    """``structure.simulate`` through the C runtime: the same histories to round-off.

    st : structure.NewmarkStepper at rest (external_soil=True), built on the soil and the model
         to run: its matrices, static state, penalty and contact settings are what the C stepper
         steps; its soil must be a RecursiveConvolutionSoil (``st.soil.model``: the rational model)
    ag : (nt, 3) m/s^2 at k dt; output_nodes : node names with acc/disp histories (None: every
    named node, as ``simulate``); raft_points : {name: (x, y) m} of a plate raft, as ``simulate``
    takes them (their acc and disp join the nodes'; ``info["raft_points"]``)
    lib : the library (default ``library()``: a temporary folder of the process; it must be available)
    progress : callable(done, total) or None, called after every ``chunk`` samples (done of
    total = nt samples computed, as ``simulate``); the run is stepped ``chunk`` samples per call
    of the C runtime, the same bits whatever ``chunk``; an exception raised between two calls
    (KeyboardInterrupt, or one raised by ``progress``) propagates, the run's memory freed.
    A plate raft's deflections, bending moments and raft points are computed from the recorded
    columns after the run (``PlateStepper.plate_outputs``), as ``simulate`` gives them.
    Returns a RouteResult (notes: the precheck is not run: every step is a Newton step, one
    product with a cached inverse while the active set holds); a Newton failure raises
    ConvergenceError with ``.result`` holding the samples so far, as ``simulate`` does.
    """
    from structure import ConvergenceError
    from structure.results import RouteResult, RunNotes, Status

    t0 = time.perf_counter()
    ag, lib = _checked(ag, lib)
    model = st.model
    names = [n.name for n in model.nodes if n.name] if output_nodes is None else list(output_nodes)
    extra = plate_dofs(st)                         # a plate: the DOFs its results read as pseudo nodes
    if raft_points and not extra:
        from structure import StructureError
        raise StructureError("raft points need a plate raft (a rigid raft's motion is its master's: ask for the "
                             "raft node instead)")
    nt, N, m = ag.shape[0], st.N, len(names) + len(extra)
    at = row_slices(N, m)                          # the row layout of simulate.c (uplift_schema.h)
    rows = np.empty((nt, row_width(N, m)))
    iters = np.empty(nt, np.int64)
    # the C runtime writes each chunk's samples into rows and iters themselves
    stats, message = _stepped(lib, encode_run(st, names, extra), ag, lambda *a: None, chunk, progress,
                              into=(rows, iters))
    rows, iters = rows[:int(stats[0])], iters[:int(stats[0])]
    nt = rows.shape[0]
    node = rows[:, at["nodes"]].reshape(nt, m, 6)
    energy = rows[:, at["energy"]]
    enabled = st.contact.enabled
    info = dict(settlement=st.static.settlement, P0=st.P0.copy(), penalty=st.kp.copy(), delta0=st.delta0.copy(),
                dt=st.dt, alpha=st.alpha, contact_enabled=enabled, factorisations=int(stats[1]),
                subdivided_steps=int(stats[2]), stepper="native")
    precheck = ("not run: the native stepper takes a Newton step at every step (one product with a cached "
                "inverse while the active set holds)" if enabled else "not needed: contact disabled (bonded raft, linear)")
    plate = _plate_histories(st, node[:, len(names):], ag, raft_points, names) if extra else {}
    acc = {nm: node[:, j, :3].copy() for j, nm in enumerate(names)}
    disp = {nm: node[:, j, 3:].copy() for j, nm in enumerate(names)}
    if "points" in plate:
        p_acc, p_disp, info["raft_points"] = plate.pop("points")
        acc.update(p_acc)
        disp.update(p_disp)
    # the histories as views of the rows: RouteResult keeps its own read-only copy of each
    res = RouteResult(route=route, time=st.dt * np.arange(nt), raft=rows[:, at["raft"]],
                      gap=rows[:, at["gap"]], contact_force=rows[:, at["contact_force"]],
                      soil_w=rows[:, at["soil_w"]],
                      acc=acc, disp=disp,
                      energy={k: energy[:, j].copy() for j, k in enumerate(ENERGY_TERMS)},
                      newton_iters=iters.astype(int), wall_s=time.perf_counter() - t0, xy=np.array(model.raft.xy),
                      notes=RunNotes(precheck=precheck), info=info,
                      **plate)
    if message:
        exc = ConvergenceError(message, nt * st.dt, -1, float("nan"))
        exc.result = res.truncated(nt, Status.STOPPED, message)
        raise exc
    return res

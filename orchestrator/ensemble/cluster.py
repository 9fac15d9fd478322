"""The dask cluster of an ensemble: a LocalCluster sized to the cells and the machine, or an
existing scheduler, and the cells run on it (the shared parts scattered once)."""
from __future__ import annotations

import concurrent.futures
import logging
import math
import multiprocessing.spawn as spawn
import os
import shlex
import shutil
import signal
import tempfile
import threading
from contextlib import contextmanager

from orchestrator.settings import thread_count
from uplift_common import interrupts

from . import CONNECT_TIMEOUT_S      # defined in the package: the command line reads it there
from .plan import EnsembleError
from .store import run_cell

#: a local cluster starts at most this many worker processes per usable core (more only queue
#: for the cores, each with its own memory and start-up)
WORKERS_PER_CORE = 2
#: dask settings of the local workers, each chosen on the CPU time of the reactor's monolithic
#: run in a worker against the same run in process: no statistical profiler (it samples the
#: running task's stack every 10 ms, a cost of its own), and glibc's own heap trimming rather
#: than dask's MALLOC_TRIM_THRESHOLD_ = 64 KiB (with it the stepper's temporaries go back to
#: the system and fault in again)
LOCAL_WORKER_CONFIG = {"distributed.worker.profile.enabled": False,
                       "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}


def default_workers() -> int:
    """The cores this process may use."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def local_workers(requested: int | None, n_cells: int) -> tuple[int, str]:
    """(worker processes of a local cluster, a note for the user or ""): ``requested`` (default:
    the usable cores) capped to the cells to run and to WORKERS_PER_CORE x the usable cores."""
    cores = default_workers()
    limit = min(n_cells, WORKERS_PER_CORE * cores)
    if requested is None:
        return max(1, min(cores, limit)), ""
    if requested <= limit:
        return requested, ""
    why = (f"{n_cells} runs to compute" if n_cells < WORKERS_PER_CORE * cores
           else f"{WORKERS_PER_CORE} per usable core, {cores} cores")
    return max(1, limit), f"--workers {requested} capped to {max(1, limit)} ({why})"


def check_timeout(timeout) -> float:
    """A connect timeout in seconds (finite, > 0), else EnsembleError."""
    try:
        t = float(timeout)
    except (TypeError, ValueError):
        t = float("nan")
    if not (math.isfinite(t) and t > 0):
        raise EnsembleError(f"--connect-timeout {timeout!r}: a number of seconds > 0, e.g. 10")
    return t


def _probe(address: str, timeout: float) -> None:
    """Ask the scheduler at ``address`` for its identity within ``timeout`` s (dask's own
    client waits forever on a server that accepts the connection and never answers)."""
    import asyncio  # only when connecting (40 ms of every command otherwise)

    from distributed.comm import connect  # heavy import, see _client

    async def identity():
        comm = await connect(address, timeout=timeout)
        try:
            await comm.write({"op": "identity", "reply": True})
            return await comm.read()
        finally:
            comm.abort()

    async def bounded():
        return await asyncio.wait_for(identity(), timeout)

    with concurrent.futures.ThreadPoolExecutor(1) as pool:     # its own event loop, even under a running one
        reply = pool.submit(asyncio.run, bounded()).result()
    if not isinstance(reply, dict) or reply.get("type") != "Scheduler":
        raise ValueError(f"it answered, but not as a dask scheduler ({str(reply)[:80]})")


@contextmanager
def _client(workers, scheduler, log, timeout: float = CONNECT_TIMEOUT_S):
    """A dask Client: on an existing scheduler (which must answer within ``timeout`` s), or on a
    LocalCluster of ``workers`` worker processes (``local_workers``) with one thread each and the
    BLAS thread count of this process; the cluster is shut down on exit, whatever the exit."""
    import asyncio  # start-up cost: only when a cluster is used (as dask below)

    import dask  # heavy import (~1 s): only ensembles pay it
    from dask.distributed import Client, LocalCluster  # (same)
    timeouts = (TimeoutError, asyncio.TimeoutError)      # a time limit reached (asyncio's before Python 3.11)
    if scheduler is not None:
        try:
            _probe(scheduler, timeout)
            client = Client(scheduler, timeout=timeout)
        except (OSError, *timeouts, ValueError) as exc:
            why = f"no answer within {timeout:g} s" if isinstance(exc, timeouts) else str(exc)
            raise EnsembleError(f"--scheduler {scheduler!r}: cannot connect ({why}); give the address of a "
                                "running dask scheduler, e.g. tcp://10.0.0.5:8786, or a longer "
                                "--connect-timeout") from None
        with client:
            try:
                client.wait_for_workers(1, timeout=timeout)
            except (OSError, *timeouts) as exc:
                raise EnsembleError(f"--scheduler {scheduler!r}: no worker joined within "
                                    f"{timeout:g} s ({exc}); start workers with "
                                    f"`dask worker {scheduler} --nthreads 1`") from None
            threads = set(client.nthreads().values())
            if log is not None and threads != {1}:
                log(f"workers of {scheduler} run {max(threads)} threads each: cells running side by side share "
                    "a process (BLAS thread limits, memory); start them with --nthreads 1")
            yield client
        return
    n = str(thread_count())
    env = {"UPLIFT_THREADS": n, "OMP_NUM_THREADS": n, "OPENBLAS_NUM_THREADS": n, "MKL_NUM_THREADS": n}
    with _workers_ignore_sigint():
        # a Ctrl-C while the cluster starts is raised once it is in the `with` that shuts it down
        # (raised inside LocalCluster's constructor, it left a half-made cluster that dask's exit
        # handler then failed to close, with a traceback)
        with interrupts.held(defer=True):
            with dask.config.set(LOCAL_WORKER_CONFIG):
                cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                       dashboard_address=None, silence_logs=logging.CRITICAL, env=env)
            try:
                client = Client(cluster)
            except BaseException:
                cluster.close()
                raise
        with cluster, client:
            interrupts.raise_owed()
            yield client


@contextmanager
def _workers_ignore_sigint():
    """Start worker processes with SIGINT ignored: a Ctrl-C at a terminal reaches the whole
    process group, and the workers would each print a traceback; this process stops them
    when it handles the interrupt itself. The workers are started (multiprocessing's spawn)
    through a two-line shell wrapper that ignores SIGINT and execs Python, which keeps it
    ignored for the process's life; this process goes on taking Ctrl-C all the while (it is
    never lost, ``uplift_common.interrupts``). Without a POSIX shell, SIGINT is ignored here
    while the cluster starts (a Ctrl-C of that time is lost)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    if os.name == "posix" and os.path.exists("/bin/sh"):
        folder = tempfile.mkdtemp(prefix="uplift_workers_")
        wrapper = os.path.join(folder, "python")
        with open(wrapper, "w") as f:
            f.write(f"#!/bin/sh\ntrap '' INT\nexec {shlex.quote(os.fsdecode(spawn.get_executable()))} \"$@\"\n")
        os.chmod(wrapper, 0o755)
        before = spawn.get_executable()
        spawn.set_executable(wrapper)
        try:
            yield
        finally:
            spawn.set_executable(before)
            shutil.rmtree(folder, ignore_errors=True)
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _run_cells(client, cells, shared, nodes, cache_dir, store, progress):
    """Run ``cells`` on the cluster, ``shared`` scattered once to every worker; each result is
    stored as it arrives. Returns ({key: values}, {key: reason} of the cells that failed)."""
    from dask.distributed import as_completed  # heavy import, see _client
    shared_future = client.scatter(shared, broadcast=True)
    futures = {client.submit(run_cell, c.scene, c.route, shared_future, nodes, cache_dir, pure=False): c
               for c in cells}
    done, failures = {}, {}
    for n, future in enumerate(as_completed(futures), start=1):
        cell = futures[future]
        try:
            values = future.result()
        except Exception as exc:
            failures[cell.key] = f"{type(exc).__name__}: {exc}"
        else:
            done[cell.key] = values
            if store is not None:
                store.write(cell.key, values)
        future.release()
        if progress is not None:
            progress(n, len(cells), cell.label + (" FAILED" if cell.key in failures else ""))
    return done, failures

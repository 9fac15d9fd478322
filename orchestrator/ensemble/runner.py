"""Running an ensemble: plan, reuse the stored cells, set up the shared parts once, run the
others on the cluster, assemble and write the dataset."""
from __future__ import annotations

import dataclasses
import json
import time

import numpy as np

from orchestrator.motion import make_motion
from orchestrator.results_file import check_output_path
from orchestrator.routes import get_route
from orchestrator.run import prepare_run, step_doubling, strongest_window
from orchestrator.scene import Scene, load_scene
from orchestrator.settings import compute_threads

from .cluster import CONNECT_TIMEOUT_S, _client, _run_cells, check_timeout, local_workers
from .dataset import assemble, write_ensemble
from .plan import EnsembleError, Plan, plan_ensemble
from .store import CellStore
from .triplets import PEER_NAMES


def run_ensemble(scene, pgas, records=None, seeds=None, routes=None, output=None, workers: int | None = None,
                 scheduler: str | None = None, cache_dir=None, dt_check: str = "strongest", progress=None,
                 sweep_progress=None, fit_progress=None, log=None, connect_timeout: float = CONNECT_TIMEOUT_S):
    """Run ``scene`` (a Scene, a TOML path or a built-in name) on ``routes`` (default: the
    scene's) under ``records`` (record files or folders) or ``seeds`` of its synthetic motion,
    each at every PGA of ``pgas`` (g); returns the ``xarray.Dataset`` of the package docstring
    and, with ``output``, writes it there (resuming from ``<output>.cells/``).

    workers : worker processes of a LocalCluster (default: the usable cores), at most one per
    cell to compute and ``cluster.WORKERS_PER_CORE`` per usable core (a cap is noted in the
    dataset's ``workers_note`` and logged); scheduler : the address of an existing dask
    scheduler instead (e.g. "tcp://10.0.0.5:8786"), which must answer within
    ``connect_timeout`` s (EnsembleError otherwise); dt_check : "strongest" or "each" (package docstring);
    progress(done, total, label) follows the cells, sweep_progress and fit_progress the set-up
    (as in ``run_scene``); log(message) receives notes for the user. Bad input raises before
    any computation (EnsembleError, SceneError, ResultsFileError: all ValueErrors).
    """
    t0 = time.perf_counter()
    scene = scene if isinstance(scene, Scene) else load_scene(scene)
    if routes:
        scene = scene.with_routes(routes)
    if workers is not None and scheduler is not None:
        raise EnsembleError("give --workers (a local cluster) or --scheduler (an existing one), not both")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise EnsembleError(f"--workers {workers!r}: a number of worker processes >= 1")
    connect_timeout = check_timeout(connect_timeout)
    out = check_output_path(output) if output is not None else None
    plan = plan_ensemble(scene, pgas, records, seeds, dt_check)
    for rec in plan.records if log is not None else ():
        if rec.told == PEER_NAMES:
            log(f"{rec.label}: " + ", ".join(f"{a} = {f.name}" for a, f in rec.files) + " (told by PEER's file names)")
    store = CellStore(out) if out is not None else None
    values = {}
    for cell in plan.cells if store is not None else ():
        found = store.read(cell.key)
        if found is not None:
            values[cell.key] = found
    todo = [c for c in plan.cells if c.key not in values]
    failures, times, n_workers, check = {}, dict.fromkeys(("cluster_s", "setup_s", "dt_check_s"), 0.0), 0, None
    note = ""
    if todo:
        if scheduler is None:
            workers, note = local_workers(workers, len(todo))
            if note and log is not None:
                log(note)
        t = time.perf_counter()
        with _client(workers, scheduler, log, connect_timeout) as client:
            n_workers = len(client.scheduler_info()["workers"])
            t1 = time.perf_counter()
            shared = prepare_run(plan.scene, cache_dir=cache_dir, sweep_progress=sweep_progress,
                                 fit_progress=fit_progress).settle()     # the fit made once for every cell
            t2 = time.perf_counter()
            if dt_check == "strongest":
                with compute_threads():
                    check = strongest_check(plan, shared, cache_dir)
                shared = dataclasses.replace(shared, dt_check=check)
            times.update(cluster_s=t1 - t, setup_s=t2 - t1, dt_check_s=time.perf_counter() - t2)
            done, failures = _run_cells(client, todo, shared, plan.nodes, cache_dir, store, progress)
        values.update(done)
    attrs = {**times, "wall_s": time.perf_counter() - t0, "workers": n_workers, "workers_note": note,
             "computed": len(todo) - len(failures), "reused": len(plan.cells) - len(todo),
             "dt_check": dt_check, "dt_check_result": json.dumps(check)}
    ds = assemble(plan, values, failures, attrs)
    if out is not None:
        write_ensemble(ds, out)
    return ds


def strongest_check(plan: Plan, shared, cache_dir=None):
    """The step-doubling check (``run.step_doubling``) on the ensemble's strongest motion: at the
    largest PGA, the record with the largest Arias intensity over its strongest window; None
    when no route of the plan is time-stepped with contact. The record and PGA are added."""
    scene = plan.scene
    if not (scene.contact.enabled and any(get_route(r).time_stepped for r in plan.routes)):
        return None
    dt = scene.analysis.dt
    top = [c for c in plan.cells if c.index[1] == len(plan.pgas) - 1 and c.index[2] == 0]
    motions = [make_motion(c.scene.motion, dt) for c in top]
    arias = [float((strongest_window(m)[0].acc ** 2).sum()) for m in motions]
    k = int(np.argmax(arias))
    check = step_doubling(scene, shared.model, shared.springs, motions[k], cache_dir)
    return {**check, "record": plan.records[top[k].index[0]].label, "pga_g": plan.pgas[-1]}

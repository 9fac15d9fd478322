"""Ensembles of records: one scene run under many motions at several PGAs, on dask.distributed,
reduced to one ``xarray.Dataset`` with the fractiles over the records.

A design or fragility study runs a set of recorded (or spectrum-matched) motions, each scaled
to each intensity level, and reads fractiles over the records. Here a *cell* is one (record,
pga, route): exactly ``uplift run`` of the scene with that motion: a record folder (up to three
components, e.g. a PEER triplet, told by ``triplets``) scaled so that its stronger horizontal
peaks at the PGA, the other components by the same factor (without a horizontal, the vertical
at the PGA; ``[motion]`` kind = "record", components = its files, scale = that factor); a
record file, one component on the scene's direction, scaled so that its peak is the PGA; or,
without records, the scene's synthetic motion (each of its components) at that PGA and seed.
Every record of an ensemble runs the same components. A cell keeps what the
run's summary gives (``orchestrator.results_file.summary``: max uplift, max raft rotation, minimum
contact ratio, wall time, status) and the floor response spectra of the scene's output nodes.

What the cells share is computed once per ensemble, on the calling process, and scattered to
the workers once (``orchestrator.run.prepare_run``, then ``SharedRun.settle``): the structure
model, the BEM sweep, the rational fit (or its error: every cell of a route that needs it is
then refused or stopped with the reason) and the proxy springs of the time-step checks. The
step-doubling check of the time step (``run.step_doubling``, a warning) runs by default once,
on the ensemble's strongest motion (largest Arias intensity over its strongest window, at
the largest PGA), and stands for every cell; ``dt_check="each"`` checks every cell's own motion as ``uplift run`` does (it costs about
one monolithic run more per cell). A cell's numbers do not depend on it.

Cells run on a dask.distributed cluster: a LocalCluster of N worker processes, one thread
each, dask's statistical profiler off and glibc's heap trimming (LOCAL_WORKER_CONFIG), or an
existing cluster given by its scheduler address (its workers need this package and should run
one thread each with the profiler off: ``DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED=False dask
worker ADDRESS --nthreads 1``). A cell runs
under the thread discipline of a single run (one BLAS thread, ``$UPLIFT_THREADS``) and depends
on its inputs only, not on the number of workers or the order of completion. A cell whose task
fails (its worker killed more often than the scheduler allows, an exception) is recorded as
"failed" with the reason; the others complete.

Resuming: with an output file, every completed cell is written as it finishes to the folder
``<output>.cells/`` (one small HDF5 file per cell, atomic, checksummed), named by a hash of its
inputs (the scene's content, the record files' SHA-256 and components, the PGA, the route,
the dt check, the package's sources); the output file is assembled from them at the end. A rerun with the same
output keeps the cells whose inputs match and computes the others (failed ones included).

The dataset (``write_ensemble``: netCDF4 through h5netcdf, ``xarray.open_dataset(path,
engine="h5netcdf")``) has the dimensions record, pga (g), route, node, direction (x, y, z),
frequency (Hz) and quantile (0.16, 0.5, 0.84). Per cell: ``max_uplift`` (m),
``max_raft_rotation`` (rad, sqrt(rx² + ry²)), ``min_contact_ratio`` (share of the interface
nodes in contact, gap = 0, its minimum over time), ``max_overturning_moment`` (N m) and
``min_contact_area_ratio`` (area in contact / raft area): the cell on the static pushover curve
(``orchestrator.oncurve``; NaN in a cell made without them), ``floor_spectrum`` (5 % damped
pseudo-acceleration, m/s², at FREQUENCIES_HZ; NaN in a direction of round-off response),
``wall_time`` (the route's, s), ``cell_time`` (the whole cell on its worker, s), ``status``
(converged | stopped | refused | failed), ``message``, ``warnings``. Per PGA and route: ``<name>_fractile`` over the records, from the
converged cells only (numpy's linear quantiles), and ``converged_records``. Per record and
direction: the file, its SHA-256 and its peak (g, unscaled); per record the scale factor of
each PGA, or the seed. The attribute ``components`` ("x y z") says which components ran
(``ensemble_components``); ``scene_key`` what a pushover of the scene depends on
(``orchestrator.oncurve.scene_key``).

The package: ``plan`` (inputs checked, cells, keys), ``triplets`` (the components of a record
folder), ``store`` (one cell's run and values, the
cell store), ``cluster`` (the dask cluster and the cells run on it), ``dataset`` (assembly,
file, summary), ``runner`` (``run_ensemble``), ``fractile_design`` (the fractile floor spectra of several ensembles,
one per soil case, broadened and enveloped: ``uplift envelope``).
"""
from uplift_common.lazy import lazy_exports

#: seconds to wait for an existing scheduler to answer (and for its first worker); the
#: command line's --connect-timeout (defined here, where the command line reads it without
#: loading the submodules: ``cluster`` uses it)
CONNECT_TIMEOUT_S = 10.0
#: the step-doubling checks an ensemble can make (``plan``; the command line's --dt-check)
DT_CHECKS = ("strongest", "each")

#: the public names, imported from their submodule on first use (``uplift_common.lazy``)
__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "cluster": ("LOCAL_WORKER_CONFIG", "default_workers"),
    "fractile_design": ("fractile_design_spectra", "write_fractile_tables"),
    "dataset": ("FRACTILE_VARIABLES", "KIND", "QUANTILES", "assemble", "ensemble_components", "ensemble_summary", "is_ensemble_file", "read_ensemble", "write_ensemble"),
    "plan": ("RECORD_SUFFIXES", "Cell", "EnsembleError", "Plan", "Record", "cell_key", "code_version", "plan_ensemble", "record_sources"),
    "runner": ("run_ensemble", "strongest_check"),
    "store": ("CELL_VARIABLES", "DAMPING", "DIRECTIONS", "FAILED", "FREQUENCIES_HZ", "ONCURVE_VARIABLES", "ROUNDOFF", "TEXT_VARIABLES", "CellStore", "cell_values", "run_cell"),
    "triplets": ("COMPONENTS_FILE", "folder_components", "peer_component"),
})
__all__ += ["CONNECT_TIMEOUT_S", "DT_CHECKS"]

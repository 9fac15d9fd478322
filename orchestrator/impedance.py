"""The scene's impedance sweep and its rational fit (glue between a Scene and soil_impedance)."""
from __future__ import annotations

import numpy as np

from soil_impedance import impedance_sweep, static_impedance
from soil_impedance.fit import FitOptions, cached_fit, fit_table
from soil_impedance.blocked import DamagedTableError
from soil_impedance.sweep import discard_damaged, table_key


def scene_impedance(scene, outputs=("rigid",), cache_dir=None, progress=None, stats=None):
    """``{output: ImpedanceTable}`` over the scene's frequencies (cached when cache_dir is set).

    stats : dict or None, filled with ``computed`` (frequencies solved by the BEM in this call:
    0 when every output was read from the cache) and ``from_cache`` (True in that case); with
    ``[impedance] frequency_tol`` also ``thinning``: the run notes' lines of the thinned sweep
    (``soil_impedance.frequencies.thinned_sweep``: the tables interpolated onto the scene's grid)."""
    solved = []

    def counting(done, total, label=""):
        solved.append(done)
        if progress is not None:
            progress(done, total, label)

    tol = getattr(scene, "frequency_tol", None)
    sweep = dict(contact=scene.contact_kind, outputs=outputs, cache_dir=cache_dir, progress=counting,
                 solver=scene.solver, solver_tol=scene.solver_tol)
    if tol is not None:
        from soil_impedance.frequencies import thinned_sweep     # start-up cost: only a thinned sweep
        tables, report = thinned_sweep(lambda f: impedance_sweep(scene.profile, scene.mesh, f, **sweep),
                                       scene.frequencies_hz, tol)
        if stats is not None:
            stats["thinning"] = report.lines()
    else:
        tables = impedance_sweep(scene.profile, scene.mesh, scene.frequencies_hz, **sweep)
    if stats is not None:
        stats.update(computed=len(solved), from_cache=cache_dir is not None and not solved)
    return tables


def scene_static(scene, output="rigid", cache_dir=None) -> np.ndarray:
    """K(ω = 0) of the scene's foundation, complex (n, n), by the scene's ``[impedance] solver``
    for the rigid and gap outputs (the fast solver on a large grid: within ``solver_tol`` as the
    sweep's frequencies, its cache entry keyed by the solver and tolerance; a dense one's key is
    that of ``soil_impedance.sweep.static_impedance``); the nodal output (the full inverse) is
    always dense."""
    solver = scene.solver if output != "nodal" else "dense"
    return static_impedance(scene.profile, scene.mesh, contact=scene.contact_kind, output=output,
                            cache_dir=cache_dir, solver=solver, solver_tol=scene.solver_tol)


def scene_fit(scene, cache_dir=None, progress=None, table=None, fit_progress=None, **fit_options):
    """FitResult (model and report) of the scene's gap impedance table ((6+N)^2: raft DOFs and
    the soil vertical displacement under each node), fitted by soil_impedance.fit.fit_table at
    the scene's ``[analysis].fit_tol`` unless ``tol`` is given (and on the scene's node
    coordinates unless ``node_xy`` is). Without ``table``, a fit cached for the scene is read
    (``cached_scene_fit``: the table is neither swept nor read), else the table is swept (or
    read from the cache) and fitted. progress follows the sweep, fit_progress the fit (label:
    its stage); both follow the progress protocol (orchestrator.progress). A cached table read in
    blocks whose chunk is found damaged as the fit reads it (``DamagedTableError``: nothing of it
    used) is moved aside with a CacheWarning, swept again and fitted from the start."""
    options = _fit_options(scene, fit_options)
    if table is None:
        hit = cached_scene_fit(scene, cache_dir, options)
        if hit is not None:
            return hit
        table = scene_impedance(scene, ("gap",), cache_dir=cache_dir, progress=progress)["gap"]
    try:
        return fit_table(table, cache_dir=cache_dir, progress=fit_progress, options=options)
    except DamagedTableError as exc:
        if not discard_damaged(table, exc, cache_dir):
            raise
    table = scene_impedance(scene, ("gap",), cache_dir=cache_dir, progress=progress)["gap"]
    return fit_table(table, cache_dir=cache_dir, progress=fit_progress, options=options)


def cached_scene_fit(scene, cache_dir, options=None):
    """The scene's fit from the cache folder ``cache_dir`` (None: no cache), or None. Found by the
    key of the gap table it is made from (``soil_impedance.sweep.table_key``: the scene's soil,
    mesh, contact and frequencies and the BEM code's digest) with the fit's options (default:
    the scene's) and the fit code's digest: the 100 MB table is neither swept nor read, and a
    change of any of them is a miss. The entry itself is verified on read (its checksum)."""
    if cache_dir is None or getattr(scene, "frequency_tol", None) is not None:
        return None                     # a thinned table's key is known once it is swept
    key = table_key(scene.profile, scene.mesh, scene.frequencies_hz, scene.contact_kind, "gap",
                    solver=scene.solver, solver_tol=scene.solver_tol)
    return cached_fit(key, options or _fit_options(scene, {}), cache_dir)


def _fit_options(scene, fit_options) -> FitOptions:
    """FitOptions of the scene's fit: ``[analysis].fit_tol`` and the mesh's node coordinates
    unless ``fit_options`` (FitOptions' keyword options) say otherwise."""
    fit_options = dict(fit_options)
    fit_options.setdefault("tol", scene.analysis.fit_tol)
    fit_options.setdefault("node_xy", scene.mesh.xy)     # for the rigid-raft correction of the fit
    return FitOptions.make(**fit_options)


def scene_discretisation_error(scene, cache_dir=None) -> dict:
    """Estimated relative discretisation error of the scene's static rigid impedances (its mesh
    against the same raft refined, Richardson: ``soil_impedance.discretisation``), or
    ``{"skipped": reason}``. Both static solves are cached like any table."""
    from soil_impedance.discretisation import static_error_estimate    # start-up cost: not on a run's path
    return static_error_estimate(scene.profile, scene.mesh, scene.contact_kind, cache_dir=cache_dir)


#: the static terms of the error lines, by rigid DOF
TERMS = {"ux": "Kh (x)", "uy": "Kh (y)", "uz": "Kv", "rx": "Kr (x)", "ry": "Kr (y)", "rz": "Kt"}


def discretisation_lines(estimate: dict) -> list[str]:
    """The text lines of ``uplift impedance`` for a ``scene_discretisation_error`` result: a
    heading, then one line per term (its signed relative error, %), or why it was skipped."""
    if "skipped" in estimate:
        return [f"discretisation error: not estimated: {estimate['skipped']}"]
    head = (f"discretisation error of the static rigid impedances (mesh of {estimate['n']} nodes vs refined, "
            f"{estimate['n_refined']} nodes; Richardson, order {estimate['order']:g}):")
    return [head, *(f"  {TERMS[d]:7s} {100 * e:+7.2f} %" for d, e in estimate["errors"].items())]


def rigid_json(table, wall_s: float, discretisation: dict | None = None) -> dict:
    """The ``uplift impedance --json`` object: per frequency a 6×6 list of [re, im]; and the
    ``discretisation_error`` estimate (``scene_discretisation_error``) when given."""
    out = {
        "frequencies_hz": [float(f) for f in table.frequencies_hz],
        "dofs": list(table.dofs),
        "rigid": [[[[float(z.real), float(z.imag)] for z in row] for row in K] for K in table.matrices],
        "wall_s": float(wall_s),
    }
    if discretisation is not None:
        out["discretisation_error"] = discretisation
    return out

"""The scene's impedance sweep and its rational fit (glue between a Scene and soil_impedance)."""
from __future__ import annotations

import numpy as np

from soil_impedance import impedance_sweep, static_impedance
from soil_impedance.fit import fit_table


def scene_impedance(scene, outputs=("rigid",), cache_dir=None, progress=None, stats=None):
    """``{output: ImpedanceTable}`` over the scene's frequencies (cached when cache_dir is set).

    stats : dict or None, filled with ``computed`` (frequencies solved by the BEM in this call:
    0 when every output was read from the cache) and ``from_cache`` (True in that case)."""
    solved = []

    def counting(done, total, label=""):
        solved.append(done)
        if progress is not None:
            progress(done, total, label)

    tables = impedance_sweep(scene.profile, scene.mesh, scene.frequencies_hz, contact=scene.contact_kind,
                             outputs=outputs, cache_dir=cache_dir, progress=counting)
    if stats is not None:
        stats.update(computed=len(solved), from_cache=cache_dir is not None and not solved)
    return tables


def scene_static(scene, output="rigid", cache_dir=None) -> np.ndarray:
    """K(ω = 0) of the scene's foundation, complex (n, n)."""
    return static_impedance(scene.profile, scene.mesh, contact=scene.contact_kind, output=output,
                            cache_dir=cache_dir)


def scene_fit(scene, cache_dir=None, progress=None, table=None, fit_progress=None, **fit_options):
    """FitResult (model and report) of the scene's gap impedance table ((6+N)^2: raft DOFs and
    the soil vertical displacement under each node; swept here unless given), fitted by
    soil_impedance.fit.fit_table at the scene's ``[analysis].fit_tol`` unless ``tol`` is given.
    progress follows the sweep, fit_progress the fit (label: its stage); both follow the
    progress protocol (orchestrator.progress)."""
    if table is None:
        table = scene_impedance(scene, ("gap",), cache_dir=cache_dir, progress=progress)["gap"]
    fit_options.setdefault("cache_dir", cache_dir)
    fit_options.setdefault("progress", fit_progress)
    fit_options.setdefault("tol", scene.analysis.fit_tol)
    fit_options.setdefault("node_xy", scene.mesh.xy)     # for the rigid-raft correction of the fit
    return fit_table(table, **fit_options)


def rigid_json(table, wall_s: float) -> dict:
    """The ``uplift impedance --json`` object: per frequency a 6×6 list of [re, im]."""
    return {
        "frequencies_hz": [float(f) for f in table.frequencies_hz],
        "dofs": list(table.dofs),
        "rigid": [[[[float(z.real), float(z.imag)] for z in row] for row in K] for K in table.matrices],
        "wall_s": float(wall_s),
    }

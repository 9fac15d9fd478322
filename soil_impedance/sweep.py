"""Frequency sweep of the surface BEM into ImpedanceTables, cached in HDF5 by content hash."""
from __future__ import annotations

import dataclasses
import hashlib
import math
from pathlib import Path

import numpy as np

from .bem import CONTACTS, BemError, SurfaceBem, nodal_dofs
from .profile import CAUSAL_CUTOFF_HZ, CAUSAL_REFERENCE_HZ
from .reduction import RIGID_DOFS, gap_dofs, gap_transform, rigid_transform
from .table import ImpedanceTable, content_hash

OUTPUTS = ("rigid", "gap", "nodal")
_CODE_FILES = ("profile.py", "patch.py", "bem.py", "greens.py", "greens_layers.py", "greens_rule.py",
               "reduction.py", "sweep.py")


def code_version() -> str:
    """Package version + a digest of the numerical sources (a changed kernel misses the cache)."""
    try:
        from importlib.metadata import version
        pkg = version("uplift")
    except Exception:  # pragma: no cover - not installed
        pkg = "unknown"
    h = hashlib.sha256()
    here = Path(__file__).parent
    for name in _CODE_FILES:
        p = here / name
        if p.is_file():
            h.update(name.encode() + p.read_bytes())
    return f"{pkg}+{h.hexdigest()[:12]}"


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
    return {"kind": mesh.kind, "size": list(mesh.size), "cell": mesh.cell, "n": mesh.n,
            "arrays_sha256": h.hexdigest()}


def provenance(profile, mesh, contact, rule, output) -> dict:
    """The inputs of one sweep output, as a JSON-able dict (hashed with the frequencies)."""
    return {"profile": {"layers": [_material_dict(l) for l in profile.layers],
                        "halfspace": _material_dict(profile.halfspace)},
            "mesh": _mesh_dict(mesh), "contact": contact, "rule": repr(rule),
            "output": output, "code_version": code_version(),
            "dof_order": "node-interleaved [ux0,uy0,uz0,ux1,...]" if output == "nodal" else output}


def _cache_path(cache_dir, output, key) -> Path:
    return Path(cache_dir) / f"impedance_{output}_{key[:20]}.h5"


def impedance_sweep(profile, mesh, frequencies_hz, contact="welded", outputs=("rigid", "gap"),
                    cache_dir=None, progress=None, rule=None) -> dict[str, ImpedanceTable]:
    """Impedance of ``mesh`` on ``profile`` at each frequency, reduced as asked.

    Parameters
    ----------
    profile : SoilProfile
    mesh : InterfaceMesh                 nodes about the raft centre
    frequencies_hz : array_like, Hz      strictly increasing, >= 0 (0 = static, exactly)
    contact : "welded" or "relaxed"
    outputs : iterable of "rigid" (6×6), "gap" (6+N), "nodal" (3N, large)
    cache_dir : path or None             read/write ``impedance_<output>_<hash>.h5`` there
    progress : callable(done, total, freq_hz) or None, called after each frequency
    rule : passed to ``greens.regular_green``

    Returns
    -------
    dict output -> ImpedanceTable; DOFs ``RIGID_DOFS``, ``gap_dofs(N)`` or ``nodal_dofs(N)``.
    One LU factorisation of F per frequency; K_out = Bᵀ F⁻¹ B (symmetrised).

    Performance: the matrices are small (723×723 for 241 nodes); run with
    ``OPENBLAS_NUM_THREADS=1`` (set before numpy is imported). On a loaded 2-core machine
    threaded BLAS made the reactor sweep 5× slower (0.35 s vs 0.06 s per frequency).
    """
    if contact not in CONTACTS:
        raise BemError(f"contact = {contact!r}: use one of {CONTACTS}")
    outputs = tuple(dict.fromkeys(outputs))
    bad = [o for o in outputs if o not in OUTPUTS]
    if bad or not outputs:
        raise BemError(f"outputs = {outputs!r}: choose among {OUTPUTS}")
    f = np.asarray(frequencies_hz, dtype=float).reshape(-1)
    if f.size == 0 or not np.all(np.isfinite(f)) or np.any(f < 0) or np.any(np.diff(f) <= 0):
        raise BemError("frequencies_hz must be a non-empty, strictly increasing list of finite "
                       "values >= 0 Hz")
    provs = {o: provenance(profile, mesh, contact, rule, o) for o in outputs}
    tables = {}
    if cache_dir is not None:
        for o in outputs:
            path = _cache_path(cache_dir, o, content_hash(provs[o], f))
            if path.is_file():
                tables[o] = ImpedanceTable.load(path)
    todo = [o for o in outputs if o not in tables]
    if todo:
        computed = _compute(SurfaceBem(profile, mesh, contact, rule), f, todo, progress)
        dofs = {"rigid": RIGID_DOFS, "gap": gap_dofs(mesh.n), "nodal": nodal_dofs(mesh.n)}
        for o in todo:
            tables[o] = ImpedanceTable(f, computed[o], dofs[o], provs[o])
            if cache_dir is not None:
                Path(cache_dir).mkdir(parents=True, exist_ok=True)
                tables[o].save(_cache_path(cache_dir, o, tables[o].hash))
    return {o: tables[o] for o in outputs}


def _compute(bem, f, outputs, progress) -> dict[str, np.ndarray]:
    """Loop over frequencies: one LU of F per frequency, solve only for the needed columns.

    With "gap" requested the rigid 6×6 is condensed from it (Pᵀ K_g P, exact), otherwise the
    rigid output solves for the 6 columns of T only; Bᵀ X uses the structure of B (Z is a
    row selection), not a dense product.
    """
    mesh = bem.mesh
    n = mesh.n
    T = rigid_transform(mesh)
    Th = T.copy()
    Th[2::3, :] = 0.0
    P = np.vstack([np.eye(6), T[2::3, :]])                # w tied to the raft
    sizes = {"rigid": 6, "gap": 6 + n, "nodal": 3 * n}
    out = {o: np.empty((f.size, sizes[o], sizes[o]), dtype=complex) for o in outputs}
    need_gap = "gap" in outputs or ("rigid" in outputs and "nodal" in outputs)
    rhs = gap_transform(mesh) if need_gap else T
    for k, fk in enumerate(f):
        omega = 2 * math.pi * fk
        if "nodal" in outputs:
            K = bem.impedance(omega)
            out["nodal"][k] = K
            X = K @ rhs
        else:
            X = bem.solve(omega, rhs)
        if need_gap:
            Kg = np.empty((6 + n, 6 + n), dtype=complex)
            Kg[:6] = Th.T @ X
            Kg[6:] = X[2::3]
            Kg = 0.5 * (Kg + Kg.T)
            if "gap" in outputs:
                out["gap"][k] = Kg
            if "rigid" in outputs:
                out["rigid"][k] = P.T @ Kg @ P
        elif "rigid" in outputs:
            Kr = T.T @ X
            out["rigid"][k] = 0.5 * (Kr + Kr.T)
        if progress is not None:
            progress(k + 1, f.size, float(fk))
    return out


def static_impedance(profile, mesh, contact="welded", output="rigid", rule=None,
                     cache_dir=None) -> np.ndarray:
    """K(0) (f = 0 exactly) for one output, shape (n, n), complex (Im from hysteretic damping;
    real for the causal model)."""
    return impedance_sweep(profile, mesh, [0.0], contact, (output,), cache_dir,
                           rule=rule)[output].matrices[0].copy()

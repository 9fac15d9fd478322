"""Build the FMUs with pythonfmu and fix their model descriptions.

``build_fmus`` writes ``structure.fmu`` and ``soil.fmu`` (the pair, exact under any master:
see fmus/coupling.py) and, when asked, ``coupled.fmu`` (both in one FMU). Each is self-contained:
its data in ``resources/`` (JSON settings, npz arrays) and a copy of the project's modules it
runs under a private package name (``resources/_uplift_<digest>/``, see ``fmus.bundle``), so
that a host's own modules never shadow them; the host must provide Python 3.10+ with the
packages of ``resources/requirements.txt`` (pythonfmu FMUs run in the host's libpython). The npz arrays are stored uncompressed (see
``_compression``).

pythonfmu writes no output dependencies and no ``InitialUnknowns``; ``fix_model_description``
adds them (outputs depend on no input at the same communication point: no direct
feedthrough), so ``fmpy.validation.validate_fmu`` reports nothing, and puts the guard
(fmus/pyguard.py) in front of pythonfmu's library: the FMU's binary checks every argument of
every FMI call (NULL and foreign pointers, GUID, resources, state machine, causality and
variability) and forwards the legal calls to pythonfmu's, shipped beside it.
"""
from __future__ import annotations

import json
import sys
import tempfile
import xml.etree.ElementTree as ET
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from fmus.bundle import bundle, requirements_of
from fmus.coupling import history_gains
from fmus.pyguard import install_guard
from fmus.resources import (DEFAULT_SOIL_FACTORY, MESH_FILE, MOTION_FILE, REQUIREMENTS_FILE, SOIL_INSTANT_FILE,
                            SOIL_MODEL_FILE, save_rational, soil_from_model)
from uplift_common.files import atomic_output

HERE = Path(__file__).resolve().parent
OPTIONS = dict(canHandleVariableCommunicationStepSize=False, canGetAndSetFMUstate=True,
               canSerializeFMUstate=True, canInterpolateInputs=False, needsExecutionTool=True)


@dataclass(frozen=True, eq=False)
class FmuData:
    """Everything the two FMUs carry.

    structure : dict               the scene's [structure] table (model_from_spec)
    contact : dict                 the scene's [contact] table (contact_from_spec)
    xy : (N, 2) m, area : (N,) m^2 interface nodes
    soil_model : RationalModel     the soil (6+N DOFs [q, w])
    dt : float, s                  fixed communication step
    output_nodes : list of str     named nodes with acc_/disp_ outputs
    motion : (nt, 3) m/s^2 or None ground motion bundled in the structure FMU (at dt)
    soil_factory : "module:callable" building the soil as factory(model, dt, **soil_kwargs)
    extra_modules : paths of .py files or packages bundled too (e.g. a custom soil factory)
    damping, alpha                 structural damping override (None or a modal ratio), HHT alpha
    plate : dict or None           a plate raft (structure.plate_raft; None: the rigid raft):
                                   "properties" {thickness m, E Pa, nu, rho kg/m^3, rigid_radius m}
                                   and its mesh "points" (m, 2) m, "cells" (N vertex tuples),
                                   "trace" (N, m) sparse: ``plate_cells``' output
    """
    structure: dict
    contact: dict
    xy: np.ndarray
    area: np.ndarray
    soil_model: object
    dt: float
    output_nodes: list = field(default_factory=list)
    motion: np.ndarray | None = None
    soil_factory: str = DEFAULT_SOIL_FACTORY
    soil_kwargs: dict = field(default_factory=dict)
    extra_modules: tuple = ()
    damping: float | None = None
    alpha: float = 0.0
    plate: dict | None = None


def build_fmus(data: FmuData, outdir, coupled: bool = False) -> dict:
    """Write ``outdir/structure.fmu`` and ``outdir/soil.fmu`` (and ``coupled.fmu`` if
    ``coupled``); returns ``{"structure": path, "soil": path[, "coupled": path]}``.

    The soil object is built once here: its passivity is verified (the FMUs then skip the
    test at instantiation: the verdict is part of the exported model) and its instantaneous
    matrices and history gains are computed for the structure FMU."""
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    n = data.soil_model.n
    N = np.asarray(data.xy).shape[0]
    if n != 6 + N:
        raise ValueError(f"the soil model has {n} DOFs, the interface needs 6 + N = {6 + N}")
    kwargs = dict(data.soil_kwargs)
    soil = soil_from_model(data.soil_model, data.dt, data.soil_factory, kwargs)     # verifies passivity
    if data.soil_factory == DEFAULT_SOIL_FACTORY:
        kwargs["checked"] = True
    stop = None if data.motion is None else (np.asarray(data.motion).shape[0] - 1) * float(data.dt)
    common = {"dt": float(data.dt), "n_dof": n, "stop_time": stop,
              "soil": {"factory": data.soil_factory, "kwargs": kwargs}}
    stepper = {**common, "n_interface": N, "structure": data.structure, "contact": data.contact,
               "damping": data.damping, "alpha": data.alpha, "output_nodes": list(data.output_nodes),
               "motion": data.motion is not None,
               "plate": None if data.plate is None else {k: float(v) for k, v in data.plate["properties"].items()}}
    roles = {"structure": stepper, "soil": common}
    if coupled:
        roles["coupled"] = stepper
    extra = [Path(p).resolve() for p in data.extra_modules]
    out = {}
    with tempfile.TemporaryDirectory(prefix="uplift_fmu_") as tmp:
        for role, settings in roles.items():
            d = Path(tmp) / role
            d.mkdir()
            (d / f"uplift_{role}.json").write_text(json.dumps(settings, indent=1))
            save_rational(d / SOIL_MODEL_FILE, data.soil_model)      # the structure's sub-steps need it
            if role != "soil":
                np.savez(d / MESH_FILE, xy=np.asarray(data.xy, float), area=np.asarray(data.area, float),
                         **plate_arrays(data.plate))
                if data.motion is not None:
                    np.savez(d / MOTION_FILE, acc=np.asarray(data.motion, float), dt=float(data.dt))
            if role == "structure":
                _save_instantaneous(d / SOIL_INSTANT_FILE, soil, data.dt)
        private, script_of = bundle(Path(tmp) / "bundle", extra, [f"fmus.{role}_fmu" for role in roles]
                                    + [data.soil_factory.partition(":")[0]])
        requirements = "\n".join(requirements_of(private)) + "\n"
        for role in roles:
            d = Path(tmp) / role
            (d / REQUIREMENTS_FILE).write_text(requirements)
            out[role] = _build(script_of(HERE / f"{role}_fmu.py"), outdir / f"{role}.fmu",
                               sorted(d.iterdir()) + [private])
    return out


def plate_arrays(plate) -> dict:
    """The plate's mesh as the structure FMU's mesh file carries it (``fmus.stepper.plate_model``
    reads it back): plate_points (m, 2) m, plate_cells (N, 4) vertex indices (-1 after a
    triangle's 3), the trace weights (N, m) as CSR arrays; none for a rigid raft."""
    if plate is None:
        return {}
    import scipy.sparse as sp
    cells = np.full((len(plate["cells"]), 4), -1, np.int64)
    for i, c in enumerate(plate["cells"]):
        cells[i, :len(c)] = c
    C = sp.csr_matrix(plate["trace"])
    return dict(plate_points=np.asarray(plate["points"], float), plate_cells=cells, plate_trace_data=C.data,
                plate_trace_indices=C.indices.astype(np.int64), plate_trace_indptr=C.indptr.astype(np.int64))


def _save_instantaneous(path, soil, dt) -> None:
    """What the structure FMU folds in, dense, computed by the soil object itself (the soil owns
    its discretisation), once, at export: K0, C0 at dt, K_static and the history gains Gx, Gv
    (fmus.coupling.history_gains)."""
    import scipy.sparse as sp
    dense = lambda a: a.toarray() if sp.issparse(a) else np.asarray(a, float)
    K0, C0 = soil.instantaneous(float(dt))
    Gx, Gv = history_gains(soil, float(dt))
    np.savez(path, K0=dense(K0), C0=dense(C0), K_static=dense(soil.static_stiffness()), Gx=Gx, Gv=Gv,
             dt=float(dt))


def _build(script: Path, dest: Path, files) -> Path:
    from pythonfmu.builder import FmuBuilder

    saved, modules = list(sys.path), set(sys.modules)
    try:
        FmuBuilder.build_FMU(script, dest=dest, project_files=files, **OPTIONS)
    finally:
        # the builder imports the script and the bundled code from the build folder and leaves
        # them behind: an FMU loaded later in this process would reuse them (from a folder
        # that no longer exists) instead of its own resources
        sys.path[:] = saved
        for name in set(sys.modules) - modules:
            if name == script.stem or name.startswith("_uplift_"):
                del sys.modules[name]
    fix_model_description(dest, guard=True)
    return dest


def fix_model_description(fmu_path, guard: bool = False) -> None:
    """Rewrite ModelStructure: every output listed with ``dependencies=""`` (no direct
    feedthrough: outputs at a communication point depend on the state only) under Outputs and
    under InitialUnknowns (computed at initialisation); outputs get ``initial="calculated"``
    without a start value (FMI 2.0 forbids start for calculated variables). ``guard``: also put
    the guard library in front of pythonfmu's (fmus.pyguard.install_guard), with the variable
    table of the fixed description."""
    fmu_path = Path(fmu_path)
    with zipfile.ZipFile(fmu_path) as z:
        items = {i.filename: z.read(i.filename) for i in z.infolist()}
    root = ET.fromstring(items["modelDescription.xml"])
    identifier = root.find("CoSimulation").get("modelIdentifier")
    outputs = []
    for k, sv in enumerate(root.find("ModelVariables"), start=1):
        if sv.get("causality") == "output":
            outputs.append(k)
            sv.set("initial", "calculated")
            for child in sv:
                child.attrib.pop("start", None)
    ms = root.find("ModelStructure")
    for child in list(ms):
        ms.remove(child)
    if outputs:
        for tag in ("Outputs", "InitialUnknowns"):
            node = ET.SubElement(ms, tag)
            for k in outputs:
                ET.SubElement(node, "Unknown", index=str(k), dependencies="")
    ET.indent(root)
    items["modelDescription.xml"] = ET.tostring(root, encoding="UTF-8", xml_declaration=True)
    if guard:
        items = install_guard(items, identifier)
    with atomic_output(fmu_path) as tmp, zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as z:
        for name, blob in items.items():
            z.writestr(name, blob, compress_type=_compression(name))


def _compression(name: str) -> int:
    """Zip method of an FMU member: the npz arrays (the soil model's residues: ~9 MB of float64
    on the reactor) are stored, since they barely deflate (~2x) and every instantiation would
    inflate them again (extraction is part of a co-simulation's start-up); the rest deflated."""
    return zipfile.ZIP_STORED if name.endswith(".npz") else zipfile.ZIP_DEFLATED

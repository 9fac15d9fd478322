"""``uplift export``: a scene as FMUs and an SSP system.

``export_scene(scene, outdir)`` writes::

    outdir/structure.fmu   Newmark-contact stepper (the scene's structure, contact, motion)
    outdir/soil.fmu        the soil protocol object (recursive convolution of the rational model)
    outdir/coupled.fmu     both in one FMU (nothing to connect; for tools that run one FMU)
    outdir/system.ssd      SSP 1.0 system of the pair: both components, the coupling connections
                           (x, xdot, x_time from the structure to the soil; g, g_time back) and
                           the motion inputs ag_x, ag_y, ag_z of the structure (free),
                           the fixed-step algorithm named (OSP annotation) so that libcosim
                           (libcosimpy) runs it as it is, and OMSimulator's simulation
                           information (its fixed-step master at dt); the motion is bundled in
                           the structure FMU (internal_motion = true)
    outdir/system.ssp      the same system packaged (SystemStructure.ssd + resources/*.fmu), for
                           SSP tools such as fmpy's ``simulate_ssp``

The pair is exact under any master (Jacobi as in libcosim and fmpy's SSP runner, Gauss-Seidel
in either order): see fmus/coupling.py and orchestrator/master.py. ``kind="native"`` writes the
same three FMUs as compiled C code (fmus/native_build.py, docs/native.md): the same variables,
the same coupling, the same answers, and no Python needed in the host; ``fmi_version=3`` writes
them as FMI 3.0 FMUs (interface vectors as arrays).
"""
from __future__ import annotations

import dataclasses
import importlib
import tempfile
import xml.etree.ElementTree as ET
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from fmpy import read_model_description

from fmus.build import FmuData, build_fmus
from fmus.bundle import PACKAGES
from fmus.resources import DEFAULT_SOIL_FACTORY
from fmus.schema import AG
from fmus.native_build import FMI_VERSIONS, build_native_fmus
from uplift_common.files import atomic_folder, atomic_output
from structure.spec import contact_table

from orchestrator.impedance import scene_fit
from orchestrator.motion import make_motion
from orchestrator.settings import FMU_KINDS

#: the kinds of FMU export_scene writes: pythonfmu, or the native C runtime (fmus/native_build.py)
KINDS = FMU_KINDS
SSD = "http://ssp-standard.org/SSP1/SystemStructureDescription"
SSC = "http://ssp-standard.org/SSP1/SystemStructureCommon"
OSP = "http://opensimulationplatform.com/SSP/OSPAnnotations"
OMS = "https://raw.githubusercontent.com/OpenModelica/OMSimulator/master/schema/oms.xsd"


@dataclass(frozen=True)
class Export:
    """Paths written by export_scene (``fmi_version``: 2 or 3)."""
    structure: Path
    soil: Path
    coupled: Path
    ssd: Path
    ssp: Path
    dt: float
    stop_time: float
    fmi_version: int = 2

    @property
    def files(self) -> tuple:
        return self.structure, self.soil, self.coupled, self.ssd, self.ssp


def factory_modules(soil_factory: str) -> tuple:
    """Source files to bundle for a soil factory that lives outside the project's packages."""
    module = soil_factory.partition(":")[0]
    if module.split(".")[0] in PACKAGES:
        return ()
    mod = importlib.import_module(module)
    path = Path(mod.__file__)
    return (path.parent,) if path.name == "__init__.py" else (path,)


def fmu_data(scene, soil_model, dt: float, motion=None, soil_factory: str | None = None,
             soil_kwargs: dict | None = None, extra_modules=()):
    """The FmuData of a scene (structure and contact tables, interface mesh, outputs; a plate
    raft's properties and mesh: ``plate_data``)."""
    factory = soil_factory or DEFAULT_SOIL_FACTORY
    nodes = scene.output.nodes
    if nodes is None:
        nodes = [n.name for n in scene.model().nodes if n.name]
    return FmuData(structure=scene.structure.as_table(inline=True), contact=contact_table(scene.contact),
                   xy=np.asarray(scene.mesh.xy), area=np.asarray(scene.mesh.area), soil_model=soil_model,
                   dt=float(dt), output_nodes=list(nodes),
                   motion=None if motion is None else np.asarray(motion.acc, float),
                   soil_factory=factory, soil_kwargs=dict(soil_kwargs or {}),
                   extra_modules=tuple(extra_modules) + factory_modules(factory), plate=plate_data(scene),
                   alpha=float(getattr(getattr(scene, "analysis", None), "hht_alpha", 0.0)))


def plate_data(scene) -> dict | None:
    """FmuData.plate of a scene with a plate raft (None: a rigid raft): the properties and the
    mesh of ``scene.plate_model()`` (the FMU rebuilds the same PlateRaftModel from them)."""
    if getattr(scene, "raft", None) is None:
        return None
    pm = scene.plate_model()
    return {"properties": dataclasses.asdict(pm.plate), "points": pm.points, "cells": pm.cells, "trace": pm.trace}


def export_scene(scene, outdir, soil_model=None, *, dt: float | None = None, motion=None,
                 soil_factory: str | None = None, soil_kwargs: dict | None = None,
                 extra_modules=(), cache_dir=None, kind: str = "native", fmi_version: int = 2,
                 progress=None) -> Export:
    """Write structure.fmu, soil.fmu, coupled.fmu, system.ssd and system.ssp for ``scene``
    into ``outdir``.

    soil_model : RationalModel of the scene's gap impedance (None: fitted from the scene,
                 see orchestrator.impedance.scene_fit)
    dt : s (default: the scene's [analysis] dt); motion : Motion (default: the scene's)
    soil_factory : "module:callable" building the soil from (model, dt, **soil_kwargs)
    kind : "native" (default: the C runtime of fmus/native compiled for linux64, win64 and
           darwin64, no Python in the host; the default soil factory only) or "python" (pythonfmu:
           the host needs Python with numpy and scipy); both carry a plate raft (the structure
           and coupled FMUs); the same variables and the same answers
    fmi_version : 2 (default) or 3: FMI 3.0 co-simulation FMUs of the native runtime (the
                  interface vectors as arrays, binaries for x86_64-linux, x86_64-windows,
                  x86_64-darwin and aarch64-darwin), the same answers; the pair's system.ssd
                  connects the arrays, one connection each
    progress : native kind: ``progress(done, total, platform)`` as each platform's runtime is
               compiled (orchestrator.progress's protocol; fmus.native_build.compile_runtime)
    """
    if kind not in KINDS:
        raise ValueError(f"kind = {kind!r}: use one of {', '.join(KINDS)}")
    if fmi_version not in FMI_VERSIONS:
        raise ValueError(f"fmi_version = {fmi_version!r}: use one of {', '.join(map(str, FMI_VERSIONS))}")
    if fmi_version == 3 and kind != "native":
        raise ValueError("fmi_version = 3: FMI 3.0 FMUs are native only (pythonfmu writes FMI 2.0): export with "
                         "kind = 'native'")
    if dt is None:
        dt = scene.analysis.dt
    if motion is None:
        motion = make_motion(scene.motion, dt)
    if soil_model is None:
        soil_model = scene_fit(scene, cache_dir=cache_dir).model
    data = fmu_data(scene, soil_model, dt, motion, soil_factory, soil_kwargs, extra_modules)
    outdir = Path(outdir)
    stop = (motion.acc.shape[0] - 1) * dt
    # the five files are written in a staging folder and moved into outdir together at the end
    # (uplift_common.files.atomic_folder): an export that fails, is interrupted or killed leaves
    # outdir as it was
    with atomic_folder(outdir) as stage:
        if kind == "native":
            fmus = build_native_fmus(data, stage, coupled=True, fmi_version=fmi_version, progress=progress)
        else:
            fmus = build_fmus(data, stage, coupled=True)
        write_ssd(stage / "system.ssd", fmus["structure"], fmus["soil"], dt, stop, name=scene.name)
        write_ssp(stage / "system.ssp", fmus["structure"], fmus["soil"], dt, stop, name=scene.name)
        names = {role: Path(path).name for role, path in fmus.items()}
    return Export(*(outdir / names[role] for role in ("structure", "soil", "coupled")), outdir / "system.ssd",
                  outdir / "system.ssp", float(dt), float(stop), fmi_version)


#: outputs of the structure listed as SSD connectors beside the coupling (what an SSP tool records)
HEADLINE = ("max_uplift", "max_raft_rotation")


def write_ssd(path, structure_fmu, soil_fmu, dt: float, stop_time: float, name: str = "uplift",
              source_dir: str | None = None) -> Path:
    """SSP system: components "structure" and "soil" (sources relative to the .ssd, or under
    ``source_dir`` inside an SSP), the coupling (every input of one component from the output
    of the same name of the other: FMI 2.0 scalars; FMI 3.0 arrays, one connection per array,
    which SSP 1.0, with no array type, types as Real), the structure's motion inputs ag_x, ag_y, ag_z as free
    connectors (the motion is bundled: a tool may connect a source to them with internal_motion
    = false), the headline outputs, DefaultExperiment with the OSP FixedStepAlgorithm of step dt, and the
    system's OMSimulator annotation (SimulationInformation: its fixed-step master "oms-ma" at dt,
    which OMSimulator needs to import the SSP; other tools ignore it)."""
    path = Path(path)
    ET.register_namespace("ssd", SSD)
    ET.register_namespace("ssc", SSC)
    ET.register_namespace("osp", OSP)
    ET.register_namespace("oms", OMS)
    q = lambda ns, tag: f"{{{ns}}}{tag}"
    md = {comp: read_model_description(str(fmu)) for comp, fmu in (("structure", structure_fmu), ("soil", soil_fmu))}
    kinds = {comp: {v.name: v.causality for v in m.modelVariables if v.type in ("Real", "Float64")}
             for comp, m in md.items()}
    pairs = [(a, v, b, v) for a, b in (("structure", "soil"), ("soil", "structure"))
             for v, kind in kinds[b].items() if kind == "input" and kinds[a].get(v) == "output"]
    ports = {comp: [v for a, v, b, _ in pairs if comp in (a, b)] for comp in md}
    ports["structure"] += [v for v in AG + HEADLINE if v in kinds["structure"]]
    root = ET.Element(q(SSD, "SystemStructureDescription"), {"version": "1.0", "name": name})
    system = ET.SubElement(root, q(SSD, "System"), {"name": name})
    elements = ET.SubElement(system, q(SSD, "Elements"))
    for comp, fmu in (("structure", structure_fmu), ("soil", soil_fmu)):
        source = (f"{source_dir}/{Path(fmu).name}" if source_dir else
                  Path(fmu).resolve().relative_to(path.resolve().parent).as_posix())
        el = ET.SubElement(elements, q(SSD, "Component"), {"name": comp, "source": source,
                                                           "type": "application/x-fmu-sharedlibrary"})
        conns = ET.SubElement(el, q(SSD, "Connectors"))
        for v in ports[comp]:
            c = ET.SubElement(conns, q(SSD, "Connector"), {"name": v, "kind": kinds[comp][v]})
            ET.SubElement(c, q(SSC, "Real"))
    connections = ET.SubElement(system, q(SSD, "Connections"))
    for a, va, b, vb in pairs:
        ET.SubElement(connections, q(SSD, "Connection"), {"startElement": a, "startConnector": va,
                                                          "endElement": b, "endConnector": vb})
    # OMSimulator's simulation information (its fixed-step master at dt); other tools ignore it
    oms = ET.SubElement(ET.SubElement(ET.SubElement(system, q(SSD, "Annotations")), q(SSC, "Annotation"),
                                      {"type": "org.openmodelica"}), q(OMS, "Annotations"))
    ET.SubElement(ET.SubElement(oms, q(OMS, "SimulationInformation")), q(OMS, "FixedStepMaster"),
                  {"description": "oms-ma", "stepSize": repr(float(dt)), "absoluteTolerance": "0.0001",
                   "relativeTolerance": "0.0001"})
    ex = ET.SubElement(root, q(SSD, "DefaultExperiment"), {"startTime": "0.0", "stopTime": repr(float(stop_time))})
    ann = ET.SubElement(ET.SubElement(ex, q(SSD, "Annotations")), q(SSC, "Annotation"),
                        {"type": "com.opensimulationplatform"})
    alg = ET.SubElement(ann, q(OSP, "Algorithm"))
    ET.SubElement(alg, q(OSP, "FixedStepAlgorithm"), {"baseStepSize": repr(float(dt))})
    ET.indent(root)
    with atomic_output(path) as tmp:
        tmp.write_bytes(ET.tostring(root, encoding="UTF-8", xml_declaration=True))
    return path


def write_ssp(path, structure_fmu, soil_fmu, dt: float, stop_time: float, name: str = "uplift") -> Path:
    """The SSP package of the pair: SystemStructure.ssd (as write_ssd, sources under
    resources/) and the two FMUs in resources/."""
    path = Path(path)
    with tempfile.TemporaryDirectory(prefix="uplift_ssp_") as tmp:
        ssd = write_ssd(Path(tmp) / "SystemStructure.ssd", structure_fmu, soil_fmu, dt, stop_time, name,
                        source_dir="resources")
        with atomic_output(path) as out, zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as z:
            z.write(ssd, "SystemStructure.ssd")
            for fmu in (structure_fmu, soil_fmu):
                z.write(fmu, f"resources/{Path(fmu).name}", compress_type=zipfile.ZIP_STORED)
    return path

"""``uplift export``: a scene as two FMUs and an SSP system description.

``export_scene(scene, outdir)`` writes::

    outdir/structure.fmu   Newmark-contact stepper (the scene's structure, contact, motion)
    outdir/soil.fmu        the soil protocol object (recursive convolution of the rational model)
    outdir/system.ssd      SSP 1.0 system: both components, every x/xdot/h connection, and the
                           fixed-step algorithm named (OSP annotation) so that libcosim
                           (libcosimpy) runs it as it is; the motion is bundled in the
                           structure FMU (internal_motion = true)

An engine with a parallel fixed-step algorithm (libcosim) runs the Jacobi schedule of
``orchestrator.master``; our master runs Gauss-Seidel by default (exact, see master.py).
"""
from __future__ import annotations

import importlib
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from fmpy import read_model_description

from fmus.build import PACKAGES, FmuData, build_fmus
from fmus.common import DEFAULT_SOIL_FACTORY
from structure.spec import contact_table

from orchestrator.impedance import scene_fit
from orchestrator.motion import make_motion

SSD = "http://ssp-standard.org/SSP1/SystemStructureDescription"
SSC = "http://ssp-standard.org/SSP1/SystemStructureCommon"
OSP = "http://opensimulationplatform.com/SSP/OSPAnnotations"


@dataclass(frozen=True)
class Export:
    """Paths written by export_scene."""
    structure: Path
    soil: Path
    ssd: Path
    dt: float
    stop_time: float


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
    """The FmuData of a scene (structure and contact tables, interface mesh, outputs)."""
    factory = soil_factory or DEFAULT_SOIL_FACTORY
    nodes = scene.output.nodes
    if nodes is None:
        nodes = [n.name for n in scene.model().nodes if n.name]
    return FmuData(structure=scene.structure.as_table(), contact=contact_table(scene.contact),
                   xy=np.asarray(scene.mesh.xy), area=np.asarray(scene.mesh.area), soil_model=soil_model,
                   dt=float(dt), output_nodes=list(nodes),
                   motion=None if motion is None else np.asarray(motion.acc, float),
                   soil_factory=factory, soil_kwargs=dict(soil_kwargs or {}),
                   extra_modules=tuple(extra_modules) + factory_modules(factory))


def export_scene(scene, outdir, soil_model=None, *, dt: float | None = None, motion=None,
                 soil_factory: str | None = None, soil_kwargs: dict | None = None,
                 extra_modules=(), cache_dir=None) -> Export:
    """Write structure.fmu, soil.fmu and system.ssd for ``scene`` into ``outdir``.

    soil_model : RationalModel of the scene's gap impedance (None: fitted from the scene,
                 see orchestrator.impedance.scene_fit)
    dt : s (default: the scene's [analysis] dt); motion : Motion (default: the scene's)
    soil_factory : "module:callable" building the soil from (model, dt, **soil_kwargs)
    """
    if dt is None:
        dt = scene.analysis.dt
    if motion is None:
        motion = make_motion(scene.motion, dt)
    if soil_model is None:
        soil_model = scene_fit(scene, cache_dir=cache_dir).model
    data = fmu_data(scene, soil_model, dt, motion, soil_factory, soil_kwargs, extra_modules)
    outdir = Path(outdir)
    s, g = build_fmus(data, outdir)
    stop = (motion.acc.shape[0] - 1) * dt
    ssd = write_ssd(outdir / "system.ssd", s, g, dt, stop, name=scene.name)
    return Export(s, g, ssd, float(dt), float(stop))


def write_ssd(path, structure_fmu, soil_fmu, dt: float, stop_time: float, name: str = "uplift") -> Path:
    """SSP system: components "structure" and "soil" (sources relative to the .ssd), the
    split coupling (structure.x/xdot -> soil.x/xdot, soil.h -> structure.h), DefaultExperiment
    with the OSP FixedStepAlgorithm of step dt."""
    path = Path(path)
    ET.register_namespace("ssd", SSD)
    ET.register_namespace("ssc", SSC)
    ET.register_namespace("osp", OSP)
    q = lambda ns, tag: f"{{{ns}}}{tag}"
    root = ET.Element(q(SSD, "SystemStructureDescription"), {"version": "1.0", "name": name})
    system = ET.SubElement(root, q(SSD, "System"), {"name": name})
    elements = ET.SubElement(system, q(SSD, "Elements"))
    ports = {}
    for comp, fmu in (("structure", structure_fmu), ("soil", soil_fmu)):
        md = read_model_description(str(fmu))
        source = Path(fmu).resolve().relative_to(path.resolve().parent).as_posix()
        el = ET.SubElement(elements, q(SSD, "Component"), {"name": comp, "source": source,
                                                           "type": "application/x-fmu-sharedlibrary"})
        conns = ET.SubElement(el, q(SSD, "Connectors"))
        ports[comp] = []
        for v in md.modelVariables:
            if v.causality in ("input", "output") and v.type == "Real":
                c = ET.SubElement(conns, q(SSD, "Connector"), {"name": v.name, "kind": v.causality})
                ET.SubElement(c, q(SSC, "Real"))
                ports[comp].append(v.name)
    connections = ET.SubElement(system, q(SSD, "Connections"))
    pairs = [("structure", v, "soil", v) for v in ports["soil"] if v.split("[")[0] in ("x", "xdot")]
    pairs += [("soil", v, "structure", v) for v in ports["structure"] if v.split("[")[0] == "h"]
    for a, va, b, vb in pairs:
        ET.SubElement(connections, q(SSD, "Connection"), {"startElement": a, "startConnector": va,
                                                          "endElement": b, "endConnector": vb})
    ex = ET.SubElement(root, q(SSD, "DefaultExperiment"), {"startTime": "0.0", "stopTime": repr(float(stop_time))})
    ann = ET.SubElement(ET.SubElement(ex, q(SSD, "Annotations")), q(SSC, "Annotation"),
                        {"type": "com.opensimulationplatform"})
    alg = ET.SubElement(ann, q(OSP, "Algorithm"))
    ET.SubElement(alg, q(OSP, "FixedStepAlgorithm"), {"baseStepSize": repr(float(dt))})
    ET.indent(root)
    path.write_bytes(ET.tostring(root, encoding="UTF-8", xml_declaration=True))
    return path

"""What an FMU of the Python kind reads from its ``resources/`` folder (written by
``fmus.build``), and the soil it rebuilds from it.

    uplift_<role>.json    settings: dt, the soil factory, the structure spec, contact, outputs
    uplift_soil_model.npz the rational soil model (poles, residues, D, E, dofs)
    uplift_mesh.npz       xy (N, 2) m, area (N,) m^2 of the interface nodes (structure, coupled)
    uplift_soil_instantaneous.npz  K0, C0 at the FMU's dt, K_static of the soil and the history
                          gains Gx, Gv (structure only: it folds them in without the soil)
    uplift_motion.npz     acc (nt, 3) m/s^2, dt s: the bundled ground motion (structure, coupled)
    requirements.txt      what the host Python needs (fmus.bundle.requirements_of)

A soil is "any object following the soil protocol" (structure.soil_interface) that a factory
``"module:callable"`` builds as ``factory(model, dt, **kwargs)`` from the RationalModel in the
resources (the default factory is ``soil_impedance.convolution:RecursiveConvolutionSoil``).
"""
from __future__ import annotations

import importlib
import json
import sys
from pathlib import Path

import numpy as np

DEFAULT_SOIL_FACTORY = "soil_impedance.convolution:RecursiveConvolutionSoil"
SOIL_MODEL_FILE = "uplift_soil_model.npz"
SOIL_INSTANT_FILE = "uplift_soil_instantaneous.npz"
MESH_FILE = "uplift_mesh.npz"
MOTION_FILE = "uplift_motion.npz"
REQUIREMENTS_FILE = "requirements.txt"


# ---- resources --------------------------------------------------------------------------------
def read_settings(resources, role: str) -> dict:
    return json.loads((Path(resources) / f"uplift_{role}.json").read_text())


def save_rational(path, model) -> None:
    """Write a RationalModel to npz (no pickles)."""
    np.savez(path, poles=model.poles, residues=model.residues, D=model.D, E=model.E,
             dofs=np.array(model.dofs, dtype=str),
             provenance=np.array(json.dumps(model.provenance, default=str)))


def load_rational(path):
    from soil_impedance.rational import RationalModel
    with np.load(path, allow_pickle=False) as z:
        return RationalModel(z["poles"], z["residues"], z["D"], z["E"], [str(d) for d in z["dofs"]],
                             json.loads(str(z["provenance"])))


#: the private package of the code inside an FMU (fmus.build.bundle), "" in the project: a
#: factory named "soil_impedance.convolution:..." or a bundled module loads the bundled copy
PREFIX = __name__[:-len("fmus.resources")]


def adopt_resources(resources) -> None:
    """Inside an FMU, point the bundled package at this instance's resources (its ``adopt``,
    see fmus.build.PACKAGE_INIT); nothing in the project itself."""
    if PREFIX:
        sys.modules[PREFIX.rstrip(".")].adopt(str(resources))


def import_object(spec: str):
    """``"package.module:attr"`` -> the object (a soil factory): the bundled module inside an
    FMU, else the host's."""
    module, _, attr = spec.partition(":")
    if not attr:
        raise ValueError(f"soil factory {spec!r} must read 'module:callable'")
    try:
        obj = importlib.import_module(PREFIX + module)
    except ModuleNotFoundError:
        if not PREFIX:
            raise
        obj = importlib.import_module(module)
    for part in attr.split("."):
        obj = getattr(obj, part)
    return obj


def make_soil(resources, settings: dict):
    """The soil object of the resources: factory(RationalModel, dt, **kwargs)."""
    soil = settings["soil"]
    model = load_rational(Path(resources) / SOIL_MODEL_FILE)
    return soil_from_model(model, settings["dt"], soil["factory"], soil.get("kwargs", {}))


def soil_from_model(model, dt: float, factory: str = DEFAULT_SOIL_FACTORY, kwargs: dict | None = None):
    """The soil object ``factory(model, dt, **kwargs)`` (the recursive convolution's
    constructor tests passivity unless ``checked=True``: the exported FMUs pass it, the
    exporter having tested it once)."""
    return import_object(factory)(model, float(dt), **dict(kwargs or {}))

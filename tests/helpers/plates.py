"""Plate rafts shared by the plate tests: a square plate mesh (``square``), the reactor's sticks
on a 20 m concrete plate (``reactor_plate``, ``CONCRETE``, ``peaks``), the small plate scene of
the route tests (``PLATE``, ``PLATE_SCENE``)."""
import dataclasses

import numpy as np

from soil_impedance.mesh import circle_mesh
from structure.plate_raft import PlateProperties, PlateRaftModel, plate_cells
from structure.spec import model_from_spec

from .winkler import NU, R, RHO


def square(n, a=1.0, jitter=0.0, seed=0):
    """(n + 1)² points of the square [0, a]², n² quads; interior points moved by up to jitter·h."""
    x = np.linspace(0.0, a, n + 1)
    X, Y = np.meshgrid(x, x, indexing="ij")
    pts = np.column_stack([X.ravel(), Y.ravel()])
    inner = (pts > 1e-12).all(axis=1) & (pts < a - 1e-12).all(axis=1)
    pts[inner] += jitter * (a / n) * np.random.default_rng(seed).uniform(-1, 1, (inner.sum(), 2))
    idx = lambda i, j: i * (n + 1) + j
    quads = [[idx(i, j), idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1)] for i in range(n) for j in range(n)]
    return pts, quads


CONCRETE = dict(E=30e9, nu=0.2, rho=2500.0)


def reactor_plate(element_size=4.0, stiffening=1.0, rigid_radius=6.0, thickness=None):
    """(mesh, PlateRaftModel): the reactor sticks on a 20 m concrete plate of the raft's mass
    (thickness = raft mass / (rho A)), E ``stiffening`` times the concrete's."""
    mesh = circle_mesh(20.0, element_size)
    stick = model_from_spec({"model": "reactor", "damping": {"modal": 0.07}}, mesh.xy, mesh.area)
    t = thickness or stick.raft.m / (CONCRETE["rho"] * mesh.area.sum())
    stick = dataclasses.replace(stick, raft=dataclasses.replace(stick.raft, m=0.0, inertia=(0.0, 0.0, 0.0)))
    plate = PlateProperties(t, CONCRETE["E"] * stiffening, CONCRETE["nu"], CONCRETE["rho"], rigid_radius)
    return mesh, PlateRaftModel(stick, plate, *plate_cells(mesh.xy, mesh.cell))


def peaks(res):
    return res.max_uplift(), np.abs(res.raft[:, 3:5]).max()


PLATE = {"kind": "plate", "thickness": 2.0, "E": 30e9, "nu": 0.2, "rho": 2500.0}
PLATE_SCENE = {
    "soil": {"halfspace": {"vs": 1600.0, "nu": NU, "rho": RHO}},
    "foundation": {"shape": "circle", "radius": R, "element_size": 5.0, "raft": PLATE},
    "structure": {"model": "reactor", "damping": {"modal": 0.07}},
    "contact": {"enabled": True},
    "analysis": {"dt": 0.005, "routes": ["monolithic"]},
    "output": {"nodes": ["top_outer", "internals_37m"]},
}

"""Shared small cases for the co-simulation tests: a reactor stick on a coarse raft (21 nodes)
over hard rock, a short strong motion (uplift), and a rational soil with a nonzero history
(Winkler springs and wave dashpots with two Maxwell relaxation terms)."""
import numpy as np

from orchestrator.motion import Motion
from orchestrator.scene import scene_from_dict
from structure.winkler import dashpots_from_waves, disk_static_stiffness, springs_from_rigid_impedance
from structure import WinklerSoil
from soil_double import winkler_rational

E_ROCK, NU, RHO, R = 15e9, 0.3, 2500.0, 20.0


def small_scene(element_size=8.0, contact=True, structure="reactor"):
    return scene_from_dict({
        "soil": {"halfspace": {"vs": 1600.0, "nu": NU, "rho": RHO}},
        "foundation": {"shape": "circle", "radius": R, "element_size": element_size},
        "structure": {"model": structure, "damping": {"modal": 0.07}},
        "contact": {"enabled": contact},
        "analysis": {"dt": 0.005},
        "output": {"nodes": ["top_outer", "internals_37m"]},
    }, name="small")


def winkler(scene, stiffness_scale=1.0, dashpots=True):
    G = E_ROCK / (2 * (1 + NU))
    vs = np.sqrt(G / RHO)
    vp = vs * np.sqrt((2 - 2 * NU) / (1 - 2 * NU))
    s = springs_from_rigid_impedance(stiffness_scale * disk_static_stiffness(G, NU, R), scene.mesh.xy,
                                     scene.mesh.area, match="rocking")
    cv, ch = dashpots_from_waves(scene.mesh.area, RHO, vp, vs) if dashpots else (0.0, 0.0)
    return WinklerSoil(scene.mesh.xy, s.kv, s.kx, cv, ch, ky=s.ky)


def soil_model(scene, stiffness_scale=1.0):
    return winkler_rational(winkler(scene, stiffness_scale))


def pulse_motion(dt=0.005, T=1.5, pga=8.0, tp=0.6, y=0.0):
    """A strong one-sided pulse (x and z): uplift within the first second. ``y`` > 0 adds a
    component along y, y pga times a pulse of 2 tp / 3 starting tp / 4 later (x, y and z at
    once: the raft rocks about both axes)."""
    t = dt * np.arange(int(round(T / dt)) + 1)
    s = np.where(t < tp, np.sin(np.pi * t / tp) ** 3, 0.0)
    acc = np.zeros((t.size, 3))
    acc[:, 0] = pga * s
    acc[:, 2] = 0.3 * pga * s
    if y:
        ty = t - tp / 4
        acc[:, 1] = y * pga * np.where((ty > 0) & (ty < 2 * tp / 3), np.sin(1.5 * np.pi * ty / tp) ** 3, 0.0)
    return Motion(dt, acc, "pulse")


def rocks_about_both_axes(res, ratio=0.2) -> bool:
    """The raft of a RouteResult rocks about x and y: each peak at least ``ratio`` of the other."""
    rx, ry = np.abs(res.raft[:, 3]).max(), np.abs(res.raft[:, 4]).max()
    return min(rx, ry) >= ratio * max(rx, ry)


#: the motion the exported pair is built with (tests/conftest.py ``exported``)
EXPORT_MOTION = pulse_motion(T=0.6)

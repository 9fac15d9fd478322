"""Shared small cases for the frequency-domain route tests: the reactor stick model on a coarse
raft (21 nodes) over frequency-independent Winkler springs and dashpots (both routes exact)."""
import numpy as np

from soil_impedance.mesh import circle_mesh
from structure import WinklerSoil
from structure.broadband import broadband_accelerogram
from structure.spec import model_from_spec
from structure.winkler import dashpots_from_waves, disk_static_stiffness, springs_from_rigid_impedance

MESH = circle_mesh(20.0, 8.0)
MODEL = model_from_spec({"model": "reactor", "damping": {"modal": 0.07}}, MESH.xy, MESH.area)
E, NU, RHO = 15e9, 0.3, 2500.0
G = E / (2 * (1 + NU))
VS = np.sqrt(G / RHO)
VP = VS * np.sqrt((2 - 2 * NU) / (1 - 2 * NU))


def soil():
    s = springs_from_rigid_impedance(disk_static_stiffness(G, NU, 20.0), MESH.xy, MESH.area)
    cv, ch = dashpots_from_waves(MESH.area, RHO, VP, VS)
    return WinklerSoil(MESH.xy, s.kv, s.kx, cv, ch)


def motion(pga_g, duration=4.0, dt=0.005, seed=3, vertical=0.3, taper=1.0):
    """Broadband motion (x, and vertical * x along z) ending quietly: a cosine taper over the
    last ``taper`` s (a record cut at full strength makes any sampled-input FFT method ring
    before the cut)."""
    a = broadband_accelerogram(duration, dt, pga_g * 9.81, seed=seed)
    t = dt * np.arange(a.size)
    a = a * np.where(t > t[-1] - taper, 0.5 * (1 + np.cos(np.pi * (t - t[-1] + taper) / taper)), 1.0)
    ag = np.zeros((a.size, 3))
    ag[:, 0] = a
    ag[:, 2] = vertical * a
    ag[0] = 0.0
    return ag


def smooth_pulse(dt, T=3.0, amp=3.0, tp=0.6):
    """A C2 pulse (sin^3) sampled at dt: the same continuous input at every dt."""
    t = dt * np.arange(round(T / dt) + 1)
    s = np.where(t < tp, np.sin(np.pi * t / tp) ** 3, 0.0)
    ag = np.zeros((t.size, 3))
    ag[:, 0] = amp * s
    ag[:, 2] = 0.3 * amp * s
    return ag


def rel(a, b):
    return float(np.abs(np.asarray(a) - np.asarray(b)).max() / np.abs(np.asarray(b)).max())

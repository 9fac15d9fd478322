"""Uplift onset of an SDOF on a rigid mat: closed-form threshold time within one step.

Mass m on a massless Euler-Bernoulli stick of height H, on a massless rigid raft on
undamped Winkler springs (circle mesh). Ground acceleration ramp a_g = kappa t along x.
Before uplift the system is a linear SDOF with flexibility H^3/(3EI) + 1/Kh + H^2/Kr
(Kr from the springs in series with the penalty), so the absolute acceleration of the mass
is kappa (t - sin(w t)/w), the base moment m H times that, and the first node lifts when the
moment reaches N * sum(A x^2) / (sum(A) x_max) (discrete-mesh form of N R / 4).
"""
import numpy as np
from scipy.optimize import brentq

from soil_impedance.mesh import circle_mesh
from structure import Beam, ContactSettings, Mass, Node, Raft, StructureModel, WinklerSoil, simulate
from structure.contact import AUTO_FACTOR
from structure.model import G_ACC


def test_sdof_uplift_onset_time():
    mesh = circle_mesh(10.0, 2.0)
    xy, area = mesh.xy, mesh.area
    m, H, E, I = 2.0e6, 20.0, 3.0e10, 30.0
    kmod, khmod = 1.0e8, 1.0e8
    model = StructureModel((Node(1, (0, 0, 0)), Node(2, (0, 0, H), "top")),
                           (Beam((1, 2), E, E / 2.4, 10.0, I, I, 2 * I),), (Mass(2, m),),
                           Raft(1, xy, area))
    soil = WinklerSoil(xy, kmod * area, kh=khmod * area)
    keff = kmod * area * AUTO_FACTOR / (1 + AUTO_FACTOR)
    Kr = (keff * xy[:, 0] ** 2).sum()
    Kh = (khmod * area).sum()
    k = 1.0 / (H**3 / (3 * E * I) + 1 / Kh + H**2 / Kr)
    w = np.sqrt(k / m)
    N = m * G_ACC
    M_up = N * (area * xy[:, 0] ** 2).sum() / (area.sum() * np.abs(xy[:, 0]).max())
    kappa = 2.0   # m/s^3
    t_star = brentq(lambda t: m * H * kappa * (t - np.sin(w * t) / w) - M_up, 1e-6, 10.0)
    dt = 0.002
    nt = int((t_star + 0.3) / dt)
    ag = np.zeros((nt, 3))
    ag[:, 0] = kappa * dt * np.arange(nt)
    res = simulate(model, soil, ag, dt, contact=ContactSettings(), damping=0.0)
    lifted = np.flatnonzero((res.gap > 0).any(axis=1))
    assert lifted.size, "no uplift"
    t_on = res.time[lifted[0]]
    print("onset", t_on, t_star, (t_on - t_star) / dt)
    assert 0 <= t_on - t_star <= dt, (t_on, t_star)
    # before onset: linear response = closed form (Newmark period error only)
    k_pre = lifted[0] - 5
    acc_cf = kappa * (res.time[k_pre] - np.sin(w * res.time[k_pre]) / w)
    assert abs(res.acc["top"][k_pre, 0] - acc_cf) / acc_cf < 2e-3

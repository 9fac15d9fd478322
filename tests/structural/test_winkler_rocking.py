"""Quasi-static rigid strip on no-tension Winkler springs: closed-form moment-rotation.

Strip of width B (unit length), Winkler modulus k (N/m^3), vertical load N. Full contact
until M_up = N B / 6 (theta_up = 2 N / (k B^2)); beyond, M = (N B / 2)(1 - (2/3) sqrt(theta_up /
theta)) and the contact length fraction is sqrt(theta_up / theta).
"""
import numpy as np
import pytest

from structure import Node, Raft, Spring, StructureModel, WinklerSoil, solve_static
from structure.contact import AUTO_FACTOR
from structure.model import G_ACC

B, K_MOD, MASS, NX = 10.0, 2.0e8, 5.0e6, 400


def strip():
    h = B / NX
    x = -B / 2 + h * (np.arange(NX) + 0.5)
    xy = np.column_stack([x, np.zeros(NX)])
    area = np.full(NX, h)
    raft = Raft(1, xy, area, m=MASS)
    # rx and rz are not restrained by a line of springs on y = 0: hold them with a spring
    model = StructureModel((Node(1, (0, 0, 0)),), (), (), raft,
                           (Spring(1, (0, 0, 0, 1e12, 0, 1e12)),))
    soil = WinklerSoil(xy, K_MOD * area, kh=K_MOD * area)
    return model, soil, h


@pytest.mark.parametrize("ratio", [0.5, 0.95, 1.2, 1.6, 2.2, 2.8])
def test_strip_moment_rotation(ratio):
    model, soil, h = strip()
    kv = soil.kv
    kp = AUTO_FACTOR * kv
    k_eff = K_MOD * AUTO_FACTOR / (1 + AUTO_FACTOR)          # springs in series with the penalty
    N = MASS * G_ACC
    M_up = N * B / 6
    M = ratio * M_up
    load = np.zeros(model.n_dof)
    load[model.raft_dofs[4]] = M          # moment about +y: presses the x > 0 side
    st = solve_static(model, soil, kp, load)
    theta = st.u[model.raft_dofs[4]]
    theta_up = 2 * N / (k_eff * B**2)
    if ratio <= 1:
        M_cf = k_eff * B**3 / 12 * theta
        frac_cf = 1.0
    else:
        M_cf = N * B / 2 * (1 - 2 / 3 * np.sqrt(theta_up / theta))
        frac_cf = np.sqrt(theta_up / theta)
    assert abs(M_cf - M) / M < 5e-3, (M, M_cf)
    frac = (st.P0 > 0).sum() * h / B
    assert abs(frac - frac_cf) <= h / B + 5e-3 * frac_cf
    assert abs(st.P0.sum() - N) / N < 1e-9                    # vertical equilibrium
    assert abs((st.P0 * model.raft.xy[:, 0]).sum() - M) / M < 1e-9   # moment equilibrium

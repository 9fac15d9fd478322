"""Winkler mattress: spring sharing, nodal diagonal, RCC-G composite modal damping."""
import numpy as np

from soil_impedance.mesh import circle_mesh
from structure.spec import model_from_spec
from structure.winkler import (disk_static_stiffness, modes_on_soil, radiation_ratios,
                               rccg_modal_damping, springs_from_nodal_diagonal,
                               springs_from_rigid_impedance)

MESH = circle_mesh(20.0, 2.28)
G, NU, R = 15e9 / 2.6, 0.3, 20.0
K6 = disk_static_stiffness(G, NU, R)


def test_disk_closed_forms():
    assert np.isclose(K6[2, 2], 4 * G * R / (1 - NU)) and np.isclose(K6[0, 0], 8 * G * R / (2 - NU))
    assert np.isclose(K6[3, 3], 8 * G * R**3 / (3 * (1 - NU))) and np.isclose(K6[5, 5], 16 * G * R**3 / 3)


def test_area_sharing_reproduces_translations_and_known_rocking_deficit():
    s = springs_from_rigid_impedance(K6, MESH.xy, MESH.area)
    Kr = s.rigid_stiffness()
    for j in (0, 1, 2):
        assert np.isclose(Kr[j, j], K6[j, j], rtol=1e-12)
    # area sharing gives Kv I / A: for the disk 3/8 of Kr, up to the mesh's I/A vs R^2/4
    I_over_A = (MESH.area * MESH.xy[:, 0] ** 2).sum() / MESH.area.sum()
    assert np.isclose(Kr[4, 4], K6[2, 2] * I_over_A, rtol=1e-12)
    assert abs(Kr[4, 4] / K6[4, 4] - 0.375) < 0.02
    m = springs_from_rigid_impedance(K6, MESH.xy, MESH.area, match="rocking").rigid_stiffness()
    assert np.isclose(0.5 * (m[3, 3] + m[4, 4]), K6[4, 4], rtol=1e-10)
    assert np.isclose(m[0, 0], K6[0, 0], rtol=1e-10) and m[2, 2] > 2.5 * K6[2, 2]


def test_nodal_diagonal_springs():
    n = MESH.n
    kd = np.arange(1, 3 * n + 1, dtype=float)
    s = springs_from_nodal_diagonal(kd, MESH.xy)
    assert np.array_equal(s.kx, kd[0::3]) and np.array_equal(s.ky, kd[1::3]) and np.array_equal(s.kv, kd[2::3])


def test_rccg_rule_energy_weighting():
    model = model_from_spec({"model": "reactor"}, MESH.xy, MESH.area)
    soil = springs_from_rigid_impedance(K6, MESH.xy, MESH.area)
    sm = modes_on_soil(model, soil)
    total = sm.structure_energy + sm.soil_energy.sum(axis=1)
    assert np.allclose(total, 1.0, atol=1e-8)
    # same ratio everywhere -> every mode gets that ratio
    C, sm1 = rccg_modal_damping(model, soil, 0.05, radiation=lambda f: np.full(6, 0.05))
    assert np.allclose(sm1.ratio, 0.05, rtol=1e-8)
    # C reproduces the ratios: Phi^T C Phi = diag(2 xi w)
    freqs = np.array([0.0, 50.0])
    rad = np.array([[0.2] * 6, [0.2] * 6])
    C, sm2 = rccg_modal_damping(model, soil, 0.07, radiation=(freqs, rad))
    D = sm2.shapes.T @ C @ sm2.shapes
    assert np.allclose(np.diag(D), 2 * sm2.ratio * 2 * np.pi * sm2.freq, rtol=1e-6)
    k = np.argmax(sm2.soil_energy.sum(axis=1))
    e = sm2.soil_energy[k].sum()
    assert np.isclose(sm2.ratio[k], 0.07 * (1 - e) + 0.2 * e)


def test_radiation_ratios_from_impedance():
    f = np.array([0.0, 5.0, 10.0])
    K = np.zeros((3, 6, 6), complex)
    for i, fk in enumerate(f):
        K[i] = K6 * (1 + 0.3j * fk / 10)
    ff, xi = radiation_ratios(f, K)
    assert np.allclose(xi[:, 2], [0.0, 0.075, 0.15])


def test_rigid_dashpots_shared_by_area():
    C6 = np.diag([1e9, 1e9, 2e9, 0, 0, 0])
    s = springs_from_rigid_impedance(K6, MESH.xy, MESH.area, C6=C6)
    assert np.allclose(s.cv, 2e9 * MESH.area / MESH.area.sum())
    assert np.allclose(s.rigid_damping()[[0, 1, 2], [0, 1, 2]], [1e9, 1e9, 2e9])

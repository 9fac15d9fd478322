"""Interface reductions: rigid 6×6 and rigid + vertical gap DOFs."""
import numpy as np
import pytest

from soil_impedance import (RIGID_DOFS, SoilProfile, SurfaceBem, circle_mesh, condense_gap_rigid,
                            gap_dofs, gap_reduction, gap_transform, rigid_reduction, rigid_transform)


@pytest.fixture(scope="module")
def case():
    mesh = circle_mesh(6.0, 1.5)
    prof = SoilProfile.homogeneous(vs=200.0, rho=2000.0, nu=0.3, damping=0.04)
    return mesh, SurfaceBem(prof, mesh, "welded").impedance(0.0)


def test_rigid_trace_is_a_rigid_motion(case):
    mesh, _ = case
    T = rigid_transform(mesh)
    x, y = mesh.xy.T
    q = np.array([0.1, -0.2, 0.3, 0.01, -0.02, 0.03])
    u = (T @ q).reshape(-1, 3)
    # small rotation r = (rx, ry, rz) of point (x, y, 0): u = t + r × p
    p = np.column_stack([x, y, np.zeros_like(x)])
    assert np.allclose(u, q[:3] + np.cross(q[3:], p), rtol=0, atol=1e-14)


def test_gap_condensed_as_rigid_equals_rigid_reduction(case):
    mesh, K = case
    Kr = rigid_reduction(K, mesh)
    Kg = gap_reduction(K, mesh)
    assert Kg.shape == (6 + mesh.n, 6 + mesh.n)
    assert np.abs(condense_gap_rigid(Kg, mesh) - Kr).max() <= 1e-12 * np.abs(Kr).max()
    for M in (Kr, Kg):
        assert np.abs(M - M.T).max() <= 1e-12 * np.abs(M).max()
    # vertical raft DOFs act only through w: their rows/columns are zero
    assert np.all(Kg[[2, 3, 4], :] == 0) and np.all(Kg[:, [2, 3, 4]] == 0)
    assert np.linalg.eigvalsh(Kr.real).min() > 0


def test_reductions_agree_with_solve_route(case):
    mesh, K = case
    prof = SoilProfile.homogeneous(vs=200.0, rho=2000.0, nu=0.3, damping=0.04)
    B = gap_transform(mesh)
    Kg = B.T @ SurfaceBem(prof, mesh, "welded").solve(0.0, B)
    assert np.abs(Kg - gap_reduction(K, mesh)).max() <= 1e-9 * np.abs(Kg).max()


def test_labels():
    assert RIGID_DOFS == ["ux", "uy", "uz", "rx", "ry", "rz"]
    assert gap_dofs(3) == RIGID_DOFS + ["w0", "w1", "w2"]


def test_sweep_routes_agree():
    # the three code paths of the sweep (rigid alone: 6-column solve; rigid + gap: rigid condensed
    # from gap; nodal: full inverse) give the same matrices, dynamic layered case, welded
    from soil_impedance import Layer, Material, impedance_sweep
    prof = SoilProfile((Layer(vs=150.0, rho=1900.0, nu=0.3, damping=0.02, thickness=3.0),),
                       Material(vs=300.0, rho=2100.0, nu=0.3, damping=0.02))
    mesh = circle_mesh(4.0, 1.0)
    f = [0.0, 5.0, 15.0]
    alone = impedance_sweep(prof, mesh, f, outputs=("rigid",))["rigid"].matrices
    both = impedance_sweep(prof, mesh, f, outputs=("rigid", "gap"))
    full = impedance_sweep(prof, mesh, f, outputs=("nodal", "rigid", "gap"))
    scale = np.abs(alone).max()
    assert np.abs(both["rigid"].matrices - alone).max() <= 1e-9 * scale
    assert np.abs(full["rigid"].matrices - alone).max() <= 1e-9 * scale
    assert np.abs(full["gap"].matrices - both["gap"].matrices).max() <= 1e-9 * np.abs(both["gap"].matrices).max()
    Kn = full["nodal"].matrices
    assert np.abs(rigid_reduction(Kn, mesh) - alone).max() <= 1e-9 * scale
    assert np.abs(gap_reduction(Kn, mesh) - both["gap"].matrices).max() <= 1e-9 * np.abs(Kn).max()
    assert full["nodal"].dofs[:4] == ["ux0", "uy0", "uz0", "ux1"]

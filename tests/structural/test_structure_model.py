"""Structural model: beam element, fixed-base modes, preload, reactor data."""
import numpy as np

from soil_impedance.mesh import circle_mesh
from structure import Beam, Mass, Node, Raft, StructureModel, fixed_base_modes, solve_static
from structure.contact import AUTO_FACTOR
from structure.damping import damping_matrix
from structure.model import G_ACC
from structure.spec import model_from_spec
from structure.winkler import disk_static_stiffness, modes_on_soil, springs_from_rigid_impedance

MESH = circle_mesh(20.0, 2.28)


def cantilever(ne, L=10.0, E=2e11, A=0.01, I=1e-4, rho=7850.0, shear=None, tip=0.0):
    nodes = tuple(Node(i + 1, (0, 0, L * i / ne), "tip" if i == ne else None) for i in range(ne + 1))
    beams = tuple(Beam((i + 1, i + 2), E, E / 2.6, A, I, I, 2 * I, shear, shear, rho)
                  for i in range(ne))
    masses = (Mass(ne + 1, tip),) if tip else ()
    raft = Raft(1, np.array([[0.0, 0.0]]), np.array([1.0]))
    return StructureModel(nodes, beams, masses, raft)


def test_cantilever_frequencies_closed_form():
    L, E, A, I, rho = 10.0, 2e11, 0.01, 1e-4, 7850.0
    model = cantilever(60, L, E, A, I, rho)
    f = fixed_base_modes(model).freq
    bl = np.array([1.87510407, 4.69409113, 7.85475744])
    f_cf = bl**2 / (2 * np.pi * L**2) * np.sqrt(E * I / (rho * A))
    bending = f[f < 1.2 * f_cf[-1]]
    bending = bending[::2]                  # each bending frequency appears in x and y
    rel = np.abs(bending[:3] - f_cf) / f_cf
    assert np.all(rel < 2e-3), rel           # lumped mass, 60 elements: O(h^2)


def test_single_mass_cantilever_frequency():
    L, E, I, m = 20.0, 3e10, 2.0, 1e6
    model = cantilever(1, L, E, 1.0, I, 0.0, tip=m)
    f = fixed_base_modes(model).freq
    assert abs(f[0] - np.sqrt(3 * E * I / (m * L**3)) / (2 * np.pi)) / f[0] < 1e-10


def test_timoshenko_tip_deflection():
    L, E, A, I, As = 10.0, 2e11, 0.01, 1e-4, 0.005
    model = cantilever(4, L, E, A, I, 0.0, shear=As)
    K = model.stiffness.toarray()
    free = np.arange(model.n_struct - 6)
    P = 1e4
    f = np.zeros(free.size)
    tip = model.dofs(5)
    f[tip[0]] = P
    u = np.linalg.solve(K[np.ix_(free, free)], f)
    exact = P * L**3 / (3 * E * I) + P * L / (E / 2.6 * As)
    assert abs(u[tip[0]] - exact) / exact < 1e-10


def test_modal_damping_matrix_gives_ratio_and_no_rigid_damping():
    model = model_from_spec({"model": "reactor"}, MESH.xy, MESH.area)
    C = damping_matrix(model)
    modes = fixed_base_modes(model)
    phi = modes.shapes
    D = phi.T @ C @ phi
    assert np.allclose(np.diag(D), 2 * 0.07 * modes.omega, rtol=1e-8)
    assert np.abs(D - np.diag(np.diag(D))).max() < 1e-8 * np.diag(D).max()
    T = model.rigid_transform
    assert np.abs(C @ T).max() < 1e-8 * np.abs(C).max()     # rigid-body motion is not damped


def reactor_soil():
    E, nu, R = 15e9, 0.3, 20.0
    G = E / (2 * (1 + nu))
    return springs_from_rigid_impedance(disk_static_stiffness(G, nu, R), MESH.xy, MESH.area,
                                        match="rocking")


def test_reactor_dominant_soil_structure_mode():
    # on homogeneous E = 15 GPa rock with the rigid-disk rocking stiffness: 4.1 Hz (on the
    # layered rock of the built-in reactor scene, 3.94 Hz: tests/orchestration/test_run.py)
    model = model_from_spec({"model": "reactor"}, MESH.xy, MESH.area)
    names = {n.name for n in model.nodes}
    assert {"top_outer", "top_inner", "internals_37m"} <= names
    assert model.node_by_name("internals_37m").xyz[2] == 37.0
    sm = modes_on_soil(model, reactor_soil())
    r = model.influence[:, 0]
    part = (sm.shapes.T @ (model.mass * r)) ** 2 / model.total_mass
    k = np.argmax(part)
    assert abs(sm.freq[k] - 4.1) < 0.1 and part[k] > 0.5, (sm.freq[k], part[k])


def test_preload_settlement_and_contact_forces():
    model = model_from_spec({"model": "reactor"}, MESH.xy, MESH.area)
    soil = reactor_soil()
    kp = AUTO_FACTOR * soil.kv
    st = solve_static(model, soil, kp)
    W = model.total_mass * G_ACC
    assert abs(st.P0.sum() - W) / W < 1e-10
    keff = soil.kv * kp / (soil.kv + kp)
    assert abs(st.settlement - W / keff.sum()) / st.settlement < 1e-8
    assert np.allclose(st.P0 / MESH.area, W / MESH.area.sum(), rtol=1e-8)   # uniform pressure
    assert np.allclose(st.delta0, st.P0 / kp, rtol=1e-10)

"""Static preload with partial uplift (eccentric mass): the dynamic state starts in
equilibrium, so zero ground motion gives zero response and the static gaps persist."""
import numpy as np

from soil_impedance.mesh import circle_mesh
from structure import Beam, Mass, Node, Raft, StructureModel, WinklerSoil, simulate, solve_static
from structure.contact import AUTO_FACTOR
from structure.model import G_ACC


def eccentric():
    mesh = circle_mesh(10.0, 1.0)
    E = 3e10
    nodes = (Node(1, (0, 0, 0)), Node(2, (4.0, 0, 8.0), "mass"))
    model = StructureModel(nodes, (Beam((1, 2), E, E / 2.4, 20.0, 50.0, 50.0, 100.0),),
                           (Mass(2, 3e6),), Raft(1, mesh.xy, mesh.area, 1e5, (1e6, 1e6, 2e6)))
    soil = WinklerSoil(mesh.xy, 1e8 * mesh.area, kh=1e8 * mesh.area)
    return model, soil, mesh


def test_static_partial_uplift_and_rest():
    model, soil, mesh = eccentric()
    st = solve_static(model, soil, AUTO_FACTOR * soil.kv)
    W = model.total_mass * G_ACC
    assert abs(st.P0.sum() - W) < 1e-8 * W
    M = 3e6 * G_ACC * 4.0                               # moment of the eccentric weight
    assert abs((st.P0 * mesh.xy[:, 0]).sum() - M) < 1e-8 * M
    lifted = st.P0 == 0
    assert 0.05 < lifted.mean() < 0.6                   # e > R/4: part of the raft is off statically
    ag = np.zeros((200, 3))
    r = simulate(model, soil, ag, 0.01, static=st)
    assert np.abs(r.raft).max() == 0.0 and np.abs(r.soil_w).max() == 0.0
    static_gap = np.maximum(0.0, st.d0)
    assert np.allclose(r.gap, static_gap[None, :], atol=1e-15)
    assert np.allclose(r.contact_force, st.P0[None, :], rtol=1e-12)
    assert r.newton_iters[1:].max() <= 1

"""Every invalid mesh / BEM / sweep input fails with its own message naming the input."""
import numpy as np
import pytest

from soil_impedance import (BemError, MeshError, SoilProfile, SurfaceBem, circle_mesh, impedance_sweep,
                            nodes_mesh, read_nodes_csv, rectangle_mesh)

PROF = SoilProfile.homogeneous(vs=200.0, rho=2000.0, nu=0.3)


@pytest.mark.parametrize("make, match", [
    (lambda: circle_mesh(-1.0, 0.5), r"foundation.radius = -1.0 m?u?s?t? ?.*positive"),
    (lambda: circle_mesh(10.0, 0.0), r"foundation.element_size = 0.0"),
    (lambda: circle_mesh(10.0, float("nan")), r"foundation.element_size = nan"),
    (lambda: circle_mesh(2.0, 3.0), r"exceeds the radius"),
    (lambda: rectangle_mesh(0.0, 5.0, 1.0), r"foundation.lx = 0.0"),
    (lambda: rectangle_mesh(5.0, -2.0, 1.0), r"foundation.ly = -2.0"),
    (lambda: nodes_mesh(np.zeros((3, 3)), np.ones(3)), r"\(n, 2\) array"),
    (lambda: nodes_mesh(np.zeros((0, 2)), np.ones(0)), r"n >= 1"),
    (lambda: nodes_mesh([[0, 0], [1, 0]], [1.0]), r"one value per node"),
    (lambda: nodes_mesh([[0, 0], [np.inf, 0]], [1.0, 1.0]), r"finite"),
    (lambda: nodes_mesh([[0, 0], [1, 0]], [1.0, 0.0]), r"node 1 has area 0: every tributary area must be > 0"),
    (lambda: nodes_mesh([[0, 0], [1, 0], [0, 0]], [1.0, 1.0, 1.0]), r"nodes 0 and 2 coincide"),
])
def test_invalid_mesh_inputs(make, match):
    with pytest.raises(MeshError, match=match):
        make()


def test_mesh_messages_print_plain_numbers():
    with pytest.raises(MeshError) as err:
        nodes_mesh([[0, 0], [1, 0]], [1.0, 0.0])
    assert "np.float64" not in str(err.value)


def test_invalid_node_csv(tmp_path):
    with pytest.raises(MeshError, match="no such file"):
        read_nodes_csv(tmp_path / "missing.csv")
    (tmp_path / "h.csv").write_text("x,y,a\n0,0,1\n")
    with pytest.raises(MeshError, match="header must be 'x,y,area'"):
        read_nodes_csv(tmp_path / "h.csv")
    (tmp_path / "v.csv").write_text("x,y,area\n0,0,1\n1,zz,1\n")
    with pytest.raises(MeshError, match="line 3"):
        read_nodes_csv(tmp_path / "v.csv")
    (tmp_path / "e.csv").write_text("x,y,area\n")
    with pytest.raises(MeshError, match="empty"):
        read_nodes_csv(tmp_path / "e.csv")


def test_invalid_bem_and_sweep_inputs():
    mesh = circle_mesh(3.0, 1.0)
    with pytest.raises(BemError, match="contact = 'glued'"):
        SurfaceBem(PROF, mesh, "glued")
    with pytest.raises(BemError, match="omega = -1.0"):
        SurfaceBem(PROF, mesh).flexibility(-1.0)
    with pytest.raises(BemError, match="contact = 'bonded'"):
        impedance_sweep(PROF, mesh, [0.0], contact="bonded")
    with pytest.raises(BemError, match="outputs"):
        impedance_sweep(PROF, mesh, [0.0], outputs=("stiffness",))
    with pytest.raises(BemError, match="strictly increasing"):
        impedance_sweep(PROF, mesh, [1.0, 1.0])
    with pytest.raises(BemError, match="strictly increasing"):
        impedance_sweep(PROF, mesh, [-1.0, 1.0])

"""The interface mesh's duplicate-node check: exact pairwise distances in numpy for the meshes a
run meets (no scipy.spatial import), the k-d tree above ``KDTREE_NODES``; both find the same pair."""
import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial import cKDTree

from soil_impedance import mesh as mesh_mod
from soil_impedance.mesh import KDTREE_NODES, MeshError, _closest_pair, nodes_mesh


@pytest.mark.parametrize("n", [2, 3, 257, 600])
def test_closest_pair_is_the_k_d_trees(n, monkeypatch):
    rng = np.random.default_rng(n)
    xy = rng.uniform(-7, 7, (n, 2))
    dist, idx = cKDTree(xy).query(xy, k=2)                  # an independent nearest-neighbour search
    k = int(np.argmin(dist[:, 1]))
    d, kk, other = _closest_pair(xy)
    assert (kk, other) == (k, int(idx[k, 1])) and d == pytest.approx(dist[k, 1], rel=1e-14)
    monkeypatch.setattr(mesh_mod, "KDTREE_NODES", 1)          # the tree's branch: the same pair
    assert _closest_pair(xy)[1:] == (k, int(idx[k, 1]))


@pytest.mark.parametrize("n", [300, KDTREE_NODES + 5])
def test_a_duplicate_is_refused_naming_both_nodes_on_either_branch(n):
    rng = np.random.default_rng(5)
    xy = rng.uniform(-5, 5, (n, 2))
    xy[n - 7] = xy[11] + 1e-12                               # within the tolerance: the same node
    with pytest.raises(MeshError, match=f"nodes 11 and {n - 7} coincide"):
        nodes_mesh(xy, np.ones(n))
    xy[n - 7] = xy[11] + 1e-6                                # a close but distinct node is accepted
    assert nodes_mesh(xy, np.ones(n)).n == n


def test_the_reactor_raft_is_checked_without_scipy_spatial():
    code = ("import sys; from soil_impedance.mesh import circle_mesh; m = circle_mesh(10.0, 1.2); "
            "print(m.n, 'scipy.spatial' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert int(out[0]) > 1 and out[1] == "False"

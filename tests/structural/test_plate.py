"""The DKT plate element alone: rigid-body modes, the constant-curvature patch test, and the
simply supported square plate under uniform load against Navier's series (closed form)."""
import numpy as np
import pytest
import scipy.sparse.linalg as spl

from helpers.plates import square
from structure.plate import bending_matrix, dkt_stiffness, flexural_rigidity, plate_stiffness, pressure_load

E, T, NU = 30e9, 0.1, 0.3


def navier_centre(a, q, D, terms=201):
    """Centre deflection of a simply supported square plate a × a under uniform q (double sine series)."""
    m = np.arange(1, terms, 2)
    M, N = np.meshgrid(m, m, indexing="ij")
    s = np.sin(M * np.pi / 2) * np.sin(N * np.pi / 2) / (M * N * ((M / a) ** 2 + (N / a) ** 2) ** 2)
    return 16 * q / (np.pi ** 6 * D) * s.sum()


def test_a_triangle_has_exactly_the_three_rigid_modes():
    K = dkt_stiffness([0.0, 2.0, 0.3], [0.0, 0.4, 1.5], bending_matrix(E, T, NU))
    ev = np.linalg.eigvalsh(K)
    assert np.allclose(K, K.T, rtol=0, atol=1e-9 * ev[-1])
    assert np.all(np.abs(ev[:3]) < 1e-10 * ev[-1]) and ev[3] > 1e-3 * ev[-1]
    # the rigid modes: translation w = 1, rotations w = y (θx = 1), w = -x (θy = 1)
    for w, tx, ty in ((lambda x, y: 1.0, 0.0, 0.0), (lambda x, y: y, 1.0, 0.0), (lambda x, y: -x, 0.0, 1.0)):
        u = np.array([[w(x, y), tx, ty] for x, y in ((0.0, 0.0), (2.0, 0.4), (0.3, 1.5))]).ravel()
        assert np.abs(K @ u).max() < 1e-9 * ev[-1]


@pytest.mark.parametrize("field", ["xx", "yy", "xy"])
def test_constant_curvature_patch_test_on_a_distorted_mesh(field):
    """A quadratic deflection imposed on the boundary is reproduced exactly inside (the element
    represents every constant-curvature state, whatever the mesh)."""
    pts, quads = square(4, jitter=0.3, seed=1)
    w, wx, wy = {"xx": (lambda x, y: x * x, lambda x, y: 2 * x, lambda x, y: 0 * x),
                 "yy": (lambda x, y: y * y, lambda x, y: 0 * x, lambda x, y: 2 * y),
                 "xy": (lambda x, y: x * y, lambda x, y: y, lambda x, y: x)}[field]
    x, y = pts[:, 0], pts[:, 1]
    exact = np.column_stack([w(x, y), wy(x, y), -wx(x, y)]).ravel()      # (w, θx = w,y, θy = -w,x)
    K = plate_stiffness(pts, quads, E, T, NU).tocsr()
    boundary = np.flatnonzero((pts < 1e-12).any(axis=1) | (pts > 1 - 1e-12).any(axis=1))
    fixed = (3 * boundary[:, None] + np.arange(3)).ravel()
    free = np.setdiff1d(np.arange(exact.size), fixed)
    u = exact.copy()
    u[free] = spl.spsolve(K[free][:, free].tocsc(), -K[free][:, fixed] @ exact[fixed])
    assert np.abs(u - exact).max() < 1e-9


def _centre_deflection(n, a=1.0, q=1e4):
    pts, quads = square(n, a)
    K = plate_stiffness(pts, quads, E, T, NU).tocsr()
    f = pressure_load(pts, quads, q)
    x, y = pts[:, 0], pts[:, 1]
    on_x = np.isclose(x, 0) | np.isclose(x, a)
    on_y = np.isclose(y, 0) | np.isclose(y, a)
    # hard simple support: w = 0 and the rotation about the edge's normal (the tangential slope) 0
    fixed = np.concatenate([3 * np.flatnonzero(on_x | on_y), 3 * np.flatnonzero(on_x) + 1,
                            3 * np.flatnonzero(on_y) + 2])
    free = np.setdiff1d(np.arange(f.size), fixed)
    u = np.zeros_like(f)
    u[free] = spl.spsolve(K[free][:, free].tocsc(), f[free])
    return u[3 * np.argmin(np.hypot(x - a / 2, y - a / 2))]


def test_simply_supported_square_plate_against_navier_second_order():
    ref = navier_centre(1.0, 1e4, flexural_rigidity(E, T, NU))
    errors = [abs(_centre_deflection(n) / ref - 1) for n in (8, 16, 32)]
    assert errors[1] < 0.01                   # within 1 % at 16 x 16 quads (512 triangles): 0.25 %
    order = np.log2(np.array(errors[:-1]) / errors[1:])
    assert np.all((order > 1.8) & (order < 2.2)), order   # O(h²): measured 2.07, 2.04

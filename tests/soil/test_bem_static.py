"""Static surface BEM: closed-form patch integrals, reciprocity, rigid disk on a half-space."""
import functools
import math

import numpy as np
import pytest
from scipy.integrate import dblquad

from soil_impedance import SoilProfile, SurfaceBem, circle_mesh, nodes_mesh, rectangle_mesh, rigid_transform
from soil_impedance.patch import radial_to_cartesian, static_patch_kernel, static_radial

R = 10.0


def _point_kernel(mat, x, y):
    return radial_to_cartesian(*static_radial(mat, math.hypot(x, y)), x, y)


def test_patch_integrals_match_numerical_quadrature():
    # closed forms vs adaptive quadrature of the point kernel over a 1.0 × 1.2 rectangle
    mat = SoilProfile.homogeneous(vs=150.0, rho=1900.0, nu=0.3).top
    d, ax, ay = (1.3, 0.7), 0.5, 0.6
    P = static_patch_kernel(mat, d[0], d[1], ax, ay).real
    for a in range(3):
        for b in range(3):
            v = dblquad(lambda y, x: _point_kernel(mat, x, y)[a, b].real,
                        d[0] - ax, d[0] + ax, d[1] - ay, d[1] + ay, epsabs=1e-20, epsrel=1e-10)[0]
            assert P[a, b] == pytest.approx(v / (4 * ax * ay), rel=1e-7, abs=1e-9 * abs(P).max())


def test_self_patch_closed_form_and_far_field_limit():
    mat = SoilProfile.homogeneous(vs=150.0, rho=1900.0, nu=0.25).top
    G, nu, a = mat.shear_modulus, 0.25, 0.5
    P = static_patch_kernel(mat, 0.0, 0.0, a, a).real
    # centre of a uniformly loaded square (side 2a): u_z = (1-ν)/(2πG) · 8a ln(1+√2) / (4a²)
    assert P[2, 2] == pytest.approx((1 - nu) / (2 * math.pi * G) * 8 * a * math.log(1 + math.sqrt(2)) / (4 * a * a), rel=1e-12)
    assert abs(P[0, 2]) < 1e-14 * P[2, 2] and abs(P[0, 1]) < 1e-14 * P[2, 2]
    # far away a patch acts as a point force: relative error O((a/d)^2)
    far = static_patch_kernel(mat, 30.0, 17.0, a, a).real
    pt = _point_kernel(mat, 30.0, 17.0).real
    assert np.abs(far - pt).max() < 1e-3 * np.abs(pt).max()


@pytest.mark.parametrize("mesh", [circle_mesh(5.0, 1.0),
                                  nodes_mesh([[0, 0], [1.5, 0.2], [0.3, 2.0], [-1.1, -0.9]],
                                             [1.0, 1.5, 0.8, 1.2])], ids=["grid", "nodes"])
@pytest.mark.parametrize("contact", ["welded", "relaxed"])
def test_flexibility_and_impedance_symmetric_positive(mesh, contact):
    prof = SoilProfile.homogeneous(vs=150.0, rho=1900.0, nu=0.3, damping=0.05)
    bem = SurfaceBem(prof, mesh, contact)
    F = bem.flexibility(0.0)
    assert np.abs(F - F.T).max() <= 1e-12 * np.abs(F).max()
    K = bem.impedance(0.0)
    assert np.abs(K - K.T).max() <= 1e-10 * np.abs(K).max()
    assert np.linalg.eigvalsh(K.real).min() > 0          # static stiffness positive definite
    assert np.linalg.eigvalsh(K.imag).min() > 0          # hysteretic damping: Im K = 2ξ Re K
    assert np.allclose(K.imag, 2 * 0.05 * K.real, rtol=1e-9, atol=1e-9 * abs(K).max())


def test_grid_offsets_equal_direct_pairwise_assembly():
    # translation invariance must give exactly the same F as the pairwise (node-list) route
    prof = SoilProfile.homogeneous(vs=150.0, rho=1900.0, nu=0.3)
    grid = circle_mesh(4.0, 1.0)
    F_grid = SurfaceBem(prof, grid).flexibility(0.0)
    F_pair = SurfaceBem(prof, nodes_mesh(grid.xy, grid.area)).flexibility(0.0)
    assert np.abs(F_grid - F_pair).max() <= 1e-13 * np.abs(F_grid).max()
    assert SurfaceBem(prof, grid).n_radii < grid.n ** 2 / 4


def _equivalent_radii(mesh):
    """Disk radii with the mesh's area, second moment and polar moment (cells as squares)."""
    h2 = mesh.cell ** 2
    x, y = mesh.xy.T
    A = mesh.total_area
    I = np.sum(y ** 2 + mesh.cell ** 2 / 12) * h2
    J = np.sum(x ** 2 + y ** 2 + mesh.cell ** 2 / 6) * h2
    return math.sqrt(A / math.pi), (4 * I / math.pi) ** 0.25, (2 * J / math.pi) ** 0.25


SIZES = (8, 12, 16)   # R/h


@functools.cache
def _disk_ratios(nu, contact):
    """K_BEM / K_closed-form on meshes h = R/n (closed forms at the mesh's equivalent radii)."""
    prof = SoilProfile.homogeneous(vs=100.0, rho=2000.0, nu=nu)
    G = prof.top.shear_modulus
    rows = []
    for n in SIZES:
        mesh = circle_mesh(R, R / n * (1 + 1e-12))
        Ra, Ri, Rj = _equivalent_radii(mesh)
        T = rigid_transform(mesh)
        K = (T.T @ SurfaceBem(prof, mesh, contact).solve(0.0, T)).real
        kv = 4 * G * Ra / (1 - nu) if contact == "relaxed" else 4 * G * Ra * math.log(3 - 4 * nu) / (1 - 2 * nu)
        rows.append([K[2, 2] / kv, K[0, 0] / (8 * G * Ra / (2 - nu)), K[1, 1] / (8 * G * Ra / (2 - nu)),
                     K[3, 3] / (8 * G * Ri ** 3 / (3 * (1 - nu))), K[5, 5] / (16 * G * Rj ** 3 / 3)])
    return np.array(rows)   # columns: v, hx, hy, r, t


def _rate_and_extrapolation(ratios):
    h = 1.0 / np.array(SIZES)
    err = np.abs(ratios - 1.0)
    rate = np.polyfit(np.log(h), np.log(err), 1)[0]
    rich = (h[-2] * ratios[-1] - h[-1] * ratios[-2]) / (h[-2] - h[-1])   # assumes O(h)
    return rate, rich


@pytest.mark.parametrize("nu", [0.25, 1 / 3, 0.45])
def test_rigid_disk_relaxed_matches_exact_closed_forms(nu):
    # relaxed contact: Kv = 4GR/(1-ν), Kh = 8GR/(2-ν), Kr = 8GR³/(3(1-ν)), Kt = 16GR³/3 are exact
    ratios = _disk_ratios(nu, "relaxed")
    for col, name in enumerate(["v", "hx", "hy", "r", "t"]):
        rate, rich = _rate_and_extrapolation(ratios[:, col])
        assert 0.6 < rate < 1.6, f"K{name}: convergence rate {rate:.2f}, expected ~1 (O(h))"
        assert abs(rich - 1) < 0.01, f"K{name}: Richardson-extrapolated ratio {rich:.4f}, want 1 ± 1%"
        assert abs(ratios[-1, col] - 1) < 0.03, f"K{name} at h = R/16: ratio {ratios[-1, col]:.4f}"


@pytest.mark.parametrize("nu", [0.25, 1 / 3, 0.45])
def test_rigid_disk_welded(nu):
    ratios = _disk_ratios(nu, "welded")
    relaxed = _disk_ratios(nu, "relaxed")
    # Mossakovskii's bonded punch Kv = 4GR ln(3-4ν)/(1-2ν) and the torsion Kt = 16GR³/3 are exact
    for col, name in [(0, "v"), (4, "t")]:
        rate, rich = _rate_and_extrapolation(ratios[:, col])
        assert 0.6 < rate < 1.6, f"K{name}: convergence rate {rate:.2f}"
        assert abs(rich - 1) < 0.01, f"K{name}: Richardson ratio {rich:.4f}, want 1 ± 1%"
    # Kh = 8GR/(2-ν) is the relaxed formula: welded within 3% after extrapolation
    _, rich_h = _rate_and_extrapolation(ratios[:, 1])
    assert abs(rich_h - 1) < 0.03, f"welded Kh: ratio {rich_h:.4f} to 8GR/(2-ν), want ±3%"
    # bonding adds constraints: welded Kv, Kh, Kr >= relaxed ones (to 0.2 % discretisation noise)
    assert np.all(ratios[:, [0, 1, 3]] * np.array([math.log(3 - 4 * nu) / (1 - 2 * nu) * (1 - nu), 1, 1])
                  >= relaxed[:, [0, 1, 3]] * 0.998)


def test_rectangle_with_non_square_cells():
    # 20 m × 10 m with h = 1.1 m: nx = 18 (hx = 1.111 m), ny = 9 (hy = 1.111 m) -> square cells;
    # with h = 1.3 m: nx = 15 (hx = 1.333 m), ny = 8 (hy = 1.25 m) -> non-square cells, whose
    # grid route must use the true hx × hy rectangles (translation invariance with hx != hy)
    prof = SoilProfile.homogeneous(vs=100.0, rho=2000.0, nu=1 / 3)
    square, skew = rectangle_mesh(20.0, 10.0, 1.1), rectangle_mesh(20.0, 10.0, 1.3)
    assert square.cell is not None and skew.cell is None
    F = SurfaceBem(prof, skew, "welded").flexibility(0.0)
    for i, j in [(0, 0), (0, 37), (5, 90)]:
        d = skew.xy[i] - skew.xy[j]
        ref = static_patch_kernel(prof.top, d[0], d[1], 20.0 / 15 / 2, 10.0 / 8 / 2)
        assert np.allclose(F[3 * i:3 * i + 3, 3 * j:3 * j + 3], ref, rtol=1e-12, atol=1e-12 * abs(ref).max())
    # both discretisations of the same rectangle agree within their O(h) error (3 %)
    K = []
    for mesh in (square, skew):
        T = rigid_transform(mesh)
        K.append(np.diag(T.T @ SurfaceBem(prof, mesh, "relaxed").solve(0.0, T)).real)
    assert np.allclose(K[1], K[0], rtol=0.03)

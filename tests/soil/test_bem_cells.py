"""BEM on true cell shapes (kind "cells") and the bounded-memory irregular assembly.

Polygon integrals of the static kernel against the rectangle closed forms and quadrature; the
same squares as a grid and as cells; the radial interpolation of the regular kernel against
direct evaluation; rigid-disk accuracy and convergence order on gmsh meshes
(tests/data/meshes/make_disks.py); the discretisation-error estimate; the memory estimate.
"""
import functools
import math
from pathlib import Path

import numpy as np
import pytest

import soil_impedance.sweep as sweep_module
from soil_impedance import (Layer, SoilProfile, SurfaceBem, cells_mesh, circle_mesh, impedance_sweep, nodes_mesh,
                            rectangle_mesh, rigid_transform)
from soil_impedance.bem import RADIAL_TOL, RadialRegular, max_pair_distance
from soil_impedance.discretisation import refined_mesh, static_error_estimate
from soil_impedance.patch import polygon_integrals, rectangle_integrals
from soil_impedance.sweep import SweepMemoryError, sweep_memory

MESHES = Path(__file__).resolve().parents[1] / "data" / "meshes"
R = 10.0
KERNELS = [lambda x, y, r: 1 / r, lambda x, y, r: x * x / r ** 3, lambda x, y, r: y * y / r ** 3,
           lambda x, y, r: x * y / r ** 3, lambda x, y, r: x / r ** 2, lambda x, y, r: y / r ** 2]


def _disk(kind, n=None):
    d = np.load(MESHES / (f"disk_{kind}_{n}.npz" if n else f"disk_{kind}.npz"))
    return cells_mesh(d["points"], d.get("triangles", ()), d.get("quads", ()))


def _rect_poly(dx, dy, ax, ay):
    return np.array([[dx - ax, dy - ay], [dx + ax, dy - ay], [dx + ax, dy + ay], [dx - ax, dy + ay]])


@pytest.mark.parametrize("centre", [(0.0, 0.0), (0.2, -0.3), (0.5, 0.1), (0.5, 0.6), (1.3, 0.7),
                                    (-2.0, 0.6), (7.0, -4.0)],
                         ids=["centre", "inside", "on-edge", "on-vertex", "near", "aligned", "far"])
def test_polygon_integrals_equal_rectangle_closed_forms(centre):
    # a 1.0 × 1.2 rectangle as a quad and as two triangles (a repeated vertex), field point
    # inside, on an edge, on a vertex and outside: the rectangle closed forms to round-off
    ax, ay = 0.5, 0.6
    ref = rectangle_integrals(centre[0], centre[1], ax, ay)
    p = _rect_poly(centre[0], centre[1], ax, ay)
    quad = polygon_integrals(p)
    tris = polygon_integrals(np.stack([p[[0, 1, 2, 2]], p[[0, 2, 3, 3]]])).sum(axis=-1)
    shifted = polygon_integrals(np.roll(p, 1, axis=0))            # another first vertex
    scale = np.abs(ref).max()
    for got in (quad, tris, shifted):
        assert np.abs(got - ref).max() <= 1e-13 * scale


def _triangle_quadrature(tri, field, order=48):
    """∫ over the triangle of the six kernels at p = field - y (collapsed Gauss-Legendre)."""
    x, w = np.polynomial.legendre.leggauss(order)
    u, wu = 0.5 * (x + 1), 0.5 * w
    U, V = np.meshgrid(u, u, indexing="ij")
    s, t = U, V * (1 - U)                        # Duffy: (s, t) over the unit triangle
    W = np.outer(wu, wu) * (1 - U)
    a, b, c = tri
    y = a + s[..., None] * (b - a) + t[..., None] * (c - a)
    jac = abs((b - a)[0] * (c - a)[1] - (b - a)[1] * (c - a)[0])
    p = field - y
    r = np.hypot(p[..., 0], p[..., 1])
    return np.array([(k(p[..., 0], p[..., 1], r) * W).sum() * jac for k in KERNELS])


@pytest.mark.parametrize("field", [(3.0, 2.0), (-1.5, 0.4), (0.6, -2.2)])
def test_polygon_integrals_match_quadrature_away_from_the_singularity(field):
    tri = np.array([[0.1, 0.2], [1.3, -0.1], [0.6, 1.1]])
    q = np.concatenate([np.asarray(field) - tri, [np.asarray(field) - tri[2]]])   # p = x - y, still CCW
    got = polygon_integrals(q)
    ref = _triangle_quadrature(tri, np.asarray(field))
    assert np.abs(got - ref).max() <= 1e-12 * np.abs(ref).max()


def test_polygon_integrals_of_a_general_quad_are_the_sum_of_its_triangles():
    # a convex quad with no symmetry, the field point inside one half: quad = two triangles, and
    # the singular integral of 1/r is finite and positive
    quad = np.array([[-0.9, -0.4], [1.1, -0.7], [0.8, 0.9], [-0.5, 1.2]])
    for field in ([0.1, 0.2], [-0.9, -0.4], [1.5, 2.0]):
        q = np.asarray(field) - quad
        whole = polygon_integrals(q)
        halves = polygon_integrals(np.stack([q[[0, 1, 2, 2]], q[[0, 2, 3, 3]]])).sum(axis=-1)
        assert np.abs(whole - halves).max() <= 1e-14 * np.abs(whole).max()
        assert np.all(np.isfinite(whole)) and whole[0] > 0


def _square_quads(lx, ly, nx, ny):
    x = np.linspace(-lx / 2, lx / 2, nx + 1)
    y = np.linspace(-ly / 2, ly / 2, ny + 1)
    X, Y = np.meshgrid(x, y, indexing="ij")
    idx = np.arange(X.size).reshape(X.shape)
    quads = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], -1).reshape(-1, 4)
    return cells_mesh(np.column_stack([X.ravel(), Y.ravel()]), quads=quads)


def _layered():
    return SoilProfile((Layer(vs=150.0, rho=1900.0, nu=0.3, damping=0.03, thickness=4.0),),
                       SoilProfile.homogeneous(vs=300.0, rho=2000.0, nu=0.3, damping=0.03).halfspace)


def test_rectangle_grid_and_the_same_squares_as_cells_agree():
    # same cells, same collocation: static homogeneous (no regular part) to round-off; dynamic
    # layered (the grid evaluates the regular kernel at the exact radii, the cells interpolate
    # it) within the interpolation tolerance
    grid = rectangle_mesh(8.0, 5.0, 1.0)
    cells = _square_quads(8.0, 5.0, 8, 5)
    assert np.allclose(cells.xy, grid.xy, rtol=0, atol=1e-14)
    homo = SoilProfile.homogeneous(vs=150.0, rho=1900.0, nu=0.3, damping=0.05)
    Fg, Fc = SurfaceBem(homo, grid).flexibility(0.0), SurfaceBem(homo, cells).flexibility(0.0)
    assert np.abs(Fg - Fc).max() <= 1e-14 * np.abs(Fg).max()
    prof, w = _layered(), 2 * math.pi * 12.0
    bem = SurfaceBem(prof, cells)
    Fg, Fc = SurfaceBem(prof, grid).flexibility(w), bem.flexibility(w)
    regular = np.abs(Fg - SurfaceBem(SoilProfile((), prof.top), grid).flexibility(0.0)).max()
    assert np.abs(Fg - Fc).max() <= RADIAL_TOL * regular
    assert 0 < bem.n_radii < cells.n ** 2 / 4


def _jittered_triangles(nx=6, ny=4, seed=5):
    """A 6 m × 4 m raft of 2 nx ny triangles of unequal shapes (interior vertices moved)."""
    x, y = np.meshgrid(np.linspace(-3, 3, nx + 1), np.linspace(-2, 2, ny + 1), indexing="ij")
    pts = np.column_stack([x.ravel(), y.ravel()])
    inner = (np.abs(pts[:, 0]) < 3) & (np.abs(pts[:, 1]) < 2)
    pts[inner] += np.random.default_rng(seed).uniform(-0.25, 0.25, (inner.sum(), 2))
    idx = np.arange(pts.shape[0]).reshape(nx + 1, ny + 1)
    q = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], -1).reshape(-1, 4)
    return cells_mesh(pts, triangles=np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]]))


def test_radial_interpolation_against_direct_evaluation():
    # the spline of the regular kernel against regular_green at every pair radius (radial_tol=0),
    # same wavenumber rule: the difference is the interpolation alone, within the tolerance
    mesh = _jittered_triangles()
    prof = _layered()
    for f_hz in (0.0, 20.0):
        w = 2 * math.pi * f_hz
        interp, direct = SurfaceBem(prof, mesh), SurfaceBem(prof, mesh, radial_tol=0.0)
        Fi, Fd = interp.flexibility(w), direct.flexibility(w)
        # the static part (top half-space at ω = 0: hysteretic, same G*) and the regular part's size
        static = SurfaceBem(SoilProfile((), prof.top), mesh).flexibility(0.0)
        scale = np.abs(Fd - static).max()            # measured: diff 5e-9 (0 Hz), 4e-9 (20 Hz) of it
        diff = np.abs(Fi - Fd).max()
        assert diff <= RADIAL_TOL * scale, f"{f_hz} Hz: {diff / scale:.2e} of the regular part"
        assert interp.n_radii > 0 and direct.n_radii == 0


def test_radial_grid_refines_until_the_bound_and_is_deterministic():
    prof = _layered()
    a = RadialRegular(prof, 2 * math.pi * 10.0, 0.5, 12.0, 2.0)
    b = RadialRegular(prof, 2 * math.pi * 10.0, 0.5, 12.0, 2.0)
    loose = RadialRegular(prof, 2 * math.pi * 10.0, 0.5, 12.0, 2.0, tol=1e-3)
    assert a.converged and a.error <= RADIAL_TOL and a.r.size > loose.r.size
    r = np.linspace(0.5, 12.0, 777)
    assert all(np.array_equal(x, y) for x, y in zip(a(r), b(r)))
    assert np.allclose(a(np.zeros(3))[0], a.at_zero[0])
    for xy in ([[0.0, 0.0]], [[0.0, 0.0], [1.5, 0.0]]):      # no or one non-zero radius: exact values
        mesh = nodes_mesh(xy, np.ones(len(xy)))
        w = 2 * math.pi * 5.0
        assert np.array_equal(SurfaceBem(prof, mesh).flexibility(w), SurfaceBem(prof, mesh, radial_tol=0).flexibility(w))


def test_max_pair_distance_and_duplicate_check_in_n_log_n():
    rng = np.random.default_rng(3)
    xy = rng.uniform(-5, 5, (400, 2))
    d = np.hypot(*(xy[:, None] - xy[None]).transpose(2, 0, 1))
    assert max_pair_distance(xy) == pytest.approx(d.max(), rel=1e-15)
    assert max_pair_distance([[0, 0], [1, 0], [3, 0], [2, 0], [-1, 0]]) == 4.0
    xy[123] = xy[45]
    with pytest.raises(Exception, match="nodes 45 and 123 coincide"):
        nodes_mesh(xy, np.ones(400))


CLOSED = {"uz": lambda G, nu: 4 * G * R / (1 - nu), "ux": lambda G, nu: 8 * G * R / (2 - nu),
          "rx": lambda G, nu: 8 * G * R ** 3 / (3 * (1 - nu)), "rz": lambda G, nu: 16 * G * R ** 3 / 3}
DOF = {"ux": 0, "uy": 1, "uz": 2, "rx": 3, "ry": 4, "rz": 5}


@functools.cache
def _disk_errors(kind, n=None, nu=1 / 3):
    prof = SoilProfile.homogeneous(vs=100.0, rho=2000.0, nu=nu)
    G = prof.top.shear_modulus
    mesh = _disk(kind, n)
    T = rigid_transform(mesh)
    K = np.diag((T.T @ SurfaceBem(prof, mesh, "relaxed").solve(0.0, T)).real)
    ref = {"ux": CLOSED["ux"], "uy": CLOSED["ux"], "uz": CLOSED["uz"], "rx": CLOSED["rx"],
           "ry": CLOSED["rx"], "rz": CLOSED["rz"]}
    return {d: K[k] / ref[d](G, nu) - 1 for d, k in DOF.items()}


@pytest.mark.parametrize("kind", [pytest.param("tri", marks=pytest.mark.slow), "quad"])
def test_rigid_disk_on_unstructured_cells_converges_at_order_one(kind):
    # relaxed contact on a gmsh disk R = 10 m at R/h = 5, 7, 10 against the exact closed forms.
    # Measured (nu = 1/3), R/h = 10: triangles (761 cells) Kh, Kv -1.16 %, Kr -3.5 %, Kt -3.4 %;
    # quads (387 cells) Kh, Kv -1.6 %, Kr, Kt -4.8 %: the brief's 2.5 % on Kr, Kt is not met with
    # centroid collocation (rocking loads the edge, where the traction is singular); the order
    # is ~1 (triangles 1.05-1.10, quads 0.95-1.0), so Richardson's extrapolation meets it
    errs = {n: _disk_errors(kind, n) for n in (5, 7, 10)}
    h = np.array([1 / 5, 1 / 7, 1 / 10])
    for d in DOF:
        e = np.array([errs[n][d] for n in (5, 7, 10)])
        assert np.all(e < 0), f"{d}: constant tractions make the raft too flexible, {e}"
        order = np.polyfit(np.log(h), np.log(-e), 1)[0]
        assert 0.85 < order < 1.25, f"K{d} ({kind}): order {order:.2f}"
        rich = (h[1] * e[2] - h[2] * e[1]) / (h[1] - h[2])             # order 1, R/h = 7 and 10
        assert abs(rich) < 0.012, f"K{d} ({kind}): Richardson error {rich:.4f}"
    tol = {"tri": (0.015, 0.036), "quad": (0.017, 0.05)}[kind]
    for d in ("ux", "uy", "uz"):
        assert abs(errs[10][d]) < tol[0], f"K{d} at R/h = 10: {errs[10][d]:.4f}"
    for d in ("rx", "ry", "rz"):
        assert abs(errs[10][d]) < tol[1], f"K{d} at R/h = 10: {errs[10][d]:.4f}"


@pytest.mark.slow
def test_rigid_disk_on_a_mesh_graded_toward_the_edge_meets_the_targets():
    # where uniform R/10 triangles miss 2.5 % on Kr, Kt (-3.5 %): the error is the edge, where the
    # rigid raft's traction is singular; triangles graded from R/4 to R/20 at the edge (613
    # cells, fewer than the 761 of uniform R/10) give Kh, Kv -0.69 %, Kr, Kt -2.0 to -2.1 %
    errs = _disk_errors("graded")
    for d in ("ux", "uy", "uz"):
        assert -0.015 < errs[d] < 0, f"K{d}: {errs[d]:.4f}"
    for d in ("rx", "ry", "rz"):
        assert -0.025 < errs[d] < 0, f"K{d}: {errs[d]:.4f}"


@pytest.mark.slow
def test_circle_grid_and_triangle_mesh_of_the_disk_agree():
    # two discretisations of the same disk, both O(h): at R/h = 10 within their stated errors
    # (grid ~1.5 % on Kv from the staircase, the mesh -1.2 %; rocking 3.5-4 % each)
    prof = SoilProfile.homogeneous(vs=100.0, rho=2000.0, nu=1 / 3)
    K = []
    for mesh in (circle_mesh(R, R / 10 * (1 + 1e-12)), _disk("tri", 10)):
        T = rigid_transform(mesh)
        K.append(np.diag((T.T @ SurfaceBem(prof, mesh, "relaxed").solve(0.0, T)).real))
    rel = K[1] / K[0] - 1
    assert np.all(np.abs(rel[:3]) < 0.03) and np.all(np.abs(rel[3:]) < 0.06), rel


def test_refined_mesh_splits_every_cell_in_four():
    for kind in ("tri", "quad"):
        mesh = _disk(kind, 5)
        fine = refined_mesh(mesh)
        assert fine.n == 4 * mesh.n
        assert fine.total_area == pytest.approx(mesh.total_area, rel=1e-13)
        assert np.allclose((fine.area[:, None] * fine.xy).sum(0), (mesh.area[:, None] * mesh.xy).sum(0), atol=1e-10)
    assert refined_mesh(circle_mesh(10.0, 2.0)).cell == pytest.approx(1.0)
    assert "no cells to split" in static_error_estimate(SoilProfile.homogeneous(100.0, 2000.0, 0.3),
                                                        nodes_mesh([[0, 0], [1, 0], [0, 1]], [1, 1, 1]))["skipped"]


@pytest.mark.parametrize("kind", [pytest.param("tri", marks=pytest.mark.slow), "quad"])
def test_discretisation_error_estimate_predicts_the_true_error(kind):
    # the estimate (mesh vs cells split in four, Richardson with p = 1) against the error to the
    # closed forms at R/h = 5: within 20 % of it (the rest: the polygon's missing area, 0.64 %,
    # which splitting cells does not refine)
    prof = SoilProfile.homogeneous(vs=100.0, rho=2000.0, nu=1 / 3)
    est = static_error_estimate(prof, _disk(kind, 5), "relaxed")
    true = _disk_errors(kind, 5)
    for d in DOF:
        assert est["errors"][d] == pytest.approx(true[d], rel=0.2), d


def test_memory_estimate_refuses_before_allocating(monkeypatch):
    # 4000 irregular nodes at 200 frequencies (gap tables of 4006² complex each: ~51 GB) on a
    # machine with 4 GiB available: refused with the estimate, the memory and the fix, and
    # nothing of the BEM is built
    xy = np.stack(np.meshgrid(np.arange(80.0), np.arange(50.0)), -1).reshape(-1, 2) - [39.5, 24.5]
    mesh = nodes_mesh(xy, np.ones(4000))
    monkeypatch.setattr(sweep_module, "available_memory", lambda: 4 * 2 ** 30)
    monkeypatch.setattr(sweep_module, "SurfaceBem", lambda *a, **k: pytest.fail("allocated before refusing"))
    with pytest.raises(SweepMemoryError, match=r"needs about .* GiB .* has 4.00 GiB available.*coarser mesh"):
        impedance_sweep(SoilProfile.homogeneous(100.0, 2000.0, 0.3), mesh, np.linspace(0, 20, 200))
    est = sweep_memory(4000, 200, ("rigid", "gap"))
    assert est["F"] == 16 * 12000 ** 2 and est["outputs"] >= 200 * 16 * 4006 ** 2
    assert sweep_memory(4000, 1, ("rigid",))["total"] < est["total"]


PEAK_CHILD = """
import sys
import numpy as np
sys.path.insert(0, {tests!r})
from test_bem_cells import _jittered_triangles
from soil_impedance import SoilProfile, impedance_sweep
from soil_impedance.sweep import sweep_memory
import scipy.interpolate, scipy.linalg, scipy.spatial, scipy.special    # what a sweep loads

def peak():       # this program's peak resident memory, bytes (VmHWM: not the parent's, as maxrss can be)
    with open("/proc/self/status") as fh:
        return next(int(line.split()[1]) * 1024 for line in fh if line.startswith("VmHWM:"))

mesh = _jittered_triangles(30, 15)
prof = SoilProfile.homogeneous(vs=200.0, rho=2000.0, nu=0.3, damping=0.05)
base = peak()
impedance_sweep(prof, mesh, [0.0, 5.0], outputs=("rigid", "gap"))
items = sweep_memory(mesh.n, 2, ("rigid", "gap"))
print(mesh.n, items["total"] - items["base"], peak() - base)
"""


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="the peak memory is read from /proc (Linux)")
def test_memory_estimate_bounds_the_measured_peak():
    # the estimate against the peak resident memory (VmHWM, which counts what LAPACK allocates)
    # of a real sweep in a child process: 900 irregular cells, rigid + gap, two frequencies; both
    # above what the process held with every library loaded (the interpreter's own size varies
    # with the environment: BASE_BYTES is a round allowance for it)
    import os
    import subprocess
    import sys
    code = PEAK_CHILD.format(tests=str(Path(__file__).resolve().parent))
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    n, estimate, peak = (int(v) for v in out.stdout.split())
    assert n == 900
    # measured: 413 MiB estimated for 382 MiB added
    assert peak <= estimate <= 1.6 * peak, f"estimate {estimate / 2**20:.0f} MiB, peak {peak / 2**20:.0f} MiB"

"""The exact static unilateral contact and the rotation-controlled pushover
(structure/static_contact.py) against the closed forms of a rigid raft on uniform Winkler springs:
lift-off onset at the kern (rectangle e = B/6, disk e = R/4; on the node grid exactly at the
discrete kern), then the no-tension section (rectangle: contact length 3(B/2 - e); disk: the
circular segment, integrated numerically) and the moment-rotation curve. docs/pushover.md."""
import numpy as np
import pytest
from scipy.integrate import quad
from scipy.optimize import brentq
from threadpoolctl import threadpool_limits

from soil_impedance.mesh import circle_mesh, rectangle_mesh
from structure.static_contact import liftoff_onset, pushover, rocking_vector, solve_contact
from structure.winkler import springs_from_moduli

K_SUB, W = 5.0e7, 1.0e7            # subgrade modulus N/m^3, vertical load N
LOAD = np.array([0.0, 0.0, -W, 0.0, 0.0, 0.0])
B, L, R = 10.0, 6.0, 10.0


@pytest.fixture(autouse=True)
def _one_blas_thread():
    """Small dense solves: one BLAS thread, as the orchestrator runs them (orchestrator.settings);
    two threads beside a busy process made these tests 4-10 times slower (measured)."""
    with threadpool_limits(limits=1):
        yield


def _springs(mesh):
    return springs_from_moduli(mesh.xy, mesh.area, K_SUB, K_SUB).static_stiffness().toarray()


def _discrete_kern(mesh, angle):
    """Onset eccentricity of a rigid raft on equal springs per area at the nodes: sum A s^2 /
    (sum A max s), s = n . r (the grids are symmetric: no product of inertia)."""
    s = mesh.xy @ np.array([np.cos(angle), np.sin(angle)])
    return (mesh.area * s**2).sum() / (mesh.area.sum() * s.max())


@pytest.mark.parametrize("h", [1.0, 0.5])
def test_rectangle_onset_at_the_kern(h):
    """Cell-centred grid of side h: the discrete kern is (B + h)/6 exactly (sum of x^2 over the
    centres = B^3/12 - B h^2/12, outermost centre B/2 - h/2): the onset matches it to 1e-10 and
    the continuum B/6 within h/6, the whole edge row of nodes lifting at once."""
    mesh = rectangle_mesh(B, L, h)
    on = liftoff_onset(_springs(mesh), mesh.xy, LOAD, rocking_vector(0.0))
    assert on.eccentricity == pytest.approx((B + h) / 6, rel=1e-10)
    assert on.eccentricity == pytest.approx(_discrete_kern(mesh, 0.0), rel=1e-10)
    assert abs(on.eccentricity - B / 6) <= h / 6 * (1 + 1e-9)
    assert len(on.nodes) == round(L / h) and on.vertical == pytest.approx(W, rel=1e-12)
    # the closed-form rotation: M = k theta I, I = L B^3/12 (grid: L (B^3 - B h^2)/12)
    assert on.stiffness == pytest.approx(K_SUB * L * (B**3 - B * h * h) / 12, rel=1e-10)


@pytest.mark.parametrize("h", [1.0, 0.5])
@pytest.mark.parametrize("angle", [0.0, np.pi / 6])
def test_disk_onset_at_the_kern(h, angle):
    """Staircase disk grid: the onset equals the grid's exact kern to 1e-10 and the continuum
    R/4 within h/10 (measured: 1.0 % and 0.04 % along x, 3.3 % and 0.4 % at 30 degrees for
    h = R/10 and R/20)."""
    mesh = circle_mesh(R, h)
    on = liftoff_onset(_springs(mesh), mesh.xy, LOAD, rocking_vector(angle))
    assert on.eccentricity == pytest.approx(_discrete_kern(mesh, angle), rel=1e-10)
    assert abs(on.eccentricity - R / 4) <= h / 10


def test_rectangle_after_liftoff_follows_the_no_tension_section():
    """After lift-off the contact length is 3 (B/2 - e) (contact ratio 3 (1/2 - e/B)) and, with
    c = sqrt(2 W / (k L theta)), M = W (B/2 - c/3). On the grid the contact front moves by whole
    cells: the ratio within 0.6 h/B (measured 0.049 and 0.025 at h/B = 0.1 and 0.05: O(h)), the
    moment within 2 (h/B)^2 (measured 1.6 % and 0.40 %: O(h^2))."""
    errs = {}
    for h in (1.0, 0.5):
        mesh = rectangle_mesh(B, L, h)
        K = _springs(mesh)
        on = liftoff_onset(K, mesh.xy, LOAD, rocking_vector(0.0))
        theta = np.linspace(0.0, 20 * on.rotation, 41)
        c = pushover(K, mesh.xy, mesh.area, LOAD, rocking_vector(0.0), theta)
        e = c.moment / W
        after = theta > on.rotation * 1.05
        before = theta <= on.rotation
        assert np.all(c.contact_ratio[before] == 1.0) and np.all(c.max_gap[before] == 0.0)
        assert np.allclose(c.moment[before], on.stiffness * theta[before], rtol=1e-10, atol=1e-6 * W)
        ratio = np.abs(c.contact_ratio[after] - 3 * (0.5 - e[after] / B)).max()
        length = np.sqrt(2 * W / (K_SUB * L * theta[after]))
        moment = np.abs(c.moment[after] / (W * (B / 2 - length / 3)) - 1).max()
        assert ratio <= 0.6 * h / B
        assert moment <= 2 * (h / B) ** 2
        errs[h] = moment
        # equilibrium and complementarity at every step
        assert np.allclose(c.force.sum(axis=1), W, rtol=1e-10)
        assert np.all(c.force >= 0) and np.all(c.gap >= 0)
        assert np.abs(c.force * c.gap).max() <= 1e-12 * W * c.gap.max()
        assert np.allclose((c.force * mesh.xy[:, 0]).sum(axis=1), c.moment, rtol=1e-9, atol=1e-6 * W)
    assert errs[0.5] < errs[1.0] / 3            # second order in h


def _segment(x0):
    """Disk of radius R pressed for x > x0 with p = x - x0: (force, moment, contact ratio) per unit k theta."""
    chord = lambda x: 2 * np.sqrt(max(R * R - x * x, 0.0))
    n = quad(lambda x: (x - x0) * chord(x), x0, R)[0]
    m = quad(lambda x: (x - x0) * x * chord(x), x0, R)[0]
    return n, m, quad(chord, x0, R)[0] / (np.pi * R * R)


def test_disk_after_liftoff_follows_the_circular_section():
    """Contact ratio against e and moment against rotation of the no-tension circular section
    (numerical integration over the segment x > x0): ratio within 0.4 h/R (measured 0.032 and
    0.015 at h/R = 0.1 and 0.05), moment within 2.5 (h/R)^2 (measured 1.9 % and 0.44 %)."""
    for h in (1.0, 0.5):
        mesh = circle_mesh(R, h)
        K = _springs(mesh)
        on = liftoff_onset(K, mesh.xy, LOAD, rocking_vector(0.0))
        theta = on.rotation * np.array([1.5, 3.0, 8.0, 20.0])
        c = pushover(K, mesh.xy, mesh.area, LOAD, rocking_vector(0.0), theta)
        for th, m, ratio in zip(theta, c.moment, c.contact_ratio):
            x0 = brentq(lambda x: _segment(x)[1] / _segment(x)[0] - m / W, -R + 1e-9, R - 1e-6)
            assert abs(ratio - _segment(x0)[2]) <= 0.4 * h / R
            x0 = brentq(lambda x: K_SUB * th * _segment(x)[0] - W, -R + 1e-9, R - 1e-6)
            assert abs(m / (K_SUB * th * _segment(x0)[1]) - 1) <= 2.5 * (h / R) ** 2


def test_onset_point_is_the_kink_and_the_path_does_not_depend_on_the_start():
    """At the onset rotation every node is closed and the first node's force is zero (to
    round-off); a step solved cold (from full contact) equals the warm-started pushover's."""
    mesh = circle_mesh(R, 2.0)
    K = _springs(mesh)
    a = rocking_vector(0.7)
    on = liftoff_onset(K, mesh.xy, LOAD, a)
    s = solve_contact(K, mesh.xy, LOAD, a, on.rotation)
    assert s.closed.all() and abs(s.P[on.node]) <= 1e-9 * W and s.moment == pytest.approx(on.moment, rel=1e-10)
    theta = on.rotation * np.linspace(0, 10, 11)
    c = pushover(K, mesh.xy, mesh.area, LOAD, a, theta)
    cold = solve_contact(K, mesh.xy, LOAD, a, theta[-1])
    assert np.allclose(cold.P, c.force[-1], rtol=1e-9, atol=1e-9 * W)
    assert cold.moment == pytest.approx(c.moment[-1], rel=1e-10)
    assert c.contact_ratio[-1] < 0.5 and np.all(np.diff(c.contact_ratio) <= 0)

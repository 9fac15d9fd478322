"""A plate raft's results (structure.plate_raft): the DKT bending moments against Navier's series
and the constant-curvature states, the contact pressures against the vertical equilibrium of the
structure, the raft points' motion against the raft's rigid motion and the plate's deflections,
the plate's own damping."""
import dataclasses

import numpy as np
import pytest
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spl

from helpers.cases import pulse_motion
from helpers.plates import reactor_plate, square
from helpers.winkler import rock_winkler
from structure import ContactSettings, StructureError, simulate
from structure.damping import damping_matrix
from structure.model import G_ACC
from structure.plate import bending_matrix, flexural_rigidity, moment_operator, plate_stiffness, pressure_load
from structure.model import vertical_trace
from structure.plate_raft import PlateProperties, PlateStepper

E, T, NU = 30e9, 0.1, 0.3


def navier_centre_moment(a, q, D, nu, terms=801):
    """Mx = My at the centre of a simply supported square plate a x a under uniform q (the double
    sine series: M = D pi^2 sum W_mn (m^2 + nu n^2) / a^2 sin(m pi/2) sin(n pi/2))."""
    m = np.arange(1, terms, 2)
    M, N = np.meshgrid(m, m, indexing="ij")
    W = 16 * q / (np.pi ** 6 * D * M * N * ((M / a) ** 2 + (N / a) ** 2) ** 2)
    return D * np.pi ** 2 * (W * (M ** 2 + nu * N ** 2) / a ** 2 * np.sin(M * np.pi / 2) * np.sin(N * np.pi / 2)).sum()


def _centre_moment(n, a=1.0, q=1e4):
    """[Mx, My, Mxy] at the centre of the simply supported n x n plate: the mean of the four
    cells that meet there (n even)."""
    pts, quads = square(n, a)
    K = plate_stiffness(pts, quads, E, T, NU).tocsr()
    f = pressure_load(pts, quads, q)
    x, y = pts[:, 0], pts[:, 1]
    on_x, on_y = np.isclose(x, 0) | np.isclose(x, a), np.isclose(y, 0) | np.isclose(y, a)
    fixed = np.concatenate([3 * np.flatnonzero(on_x | on_y), 3 * np.flatnonzero(on_x) + 1,
                            3 * np.flatnonzero(on_y) + 2])
    free = np.setdiff1d(np.arange(f.size), fixed)
    u = np.zeros_like(f)
    u[free] = spl.spsolve(K[free][:, free].tocsc(), f[free])
    M = (moment_operator(pts, quads, E, T, NU) @ u).reshape(-1, 3)
    centre = np.array([pts[c].mean(axis=0) for c in quads])
    d = np.hypot(*(centre - a / 2).T)
    return M[d <= d.min() * (1 + 1e-9)].mean(axis=0)


def test_centre_moment_of_the_simply_supported_square_plate_against_navier_second_order():
    q = 1e4
    ref = navier_centre_moment(1.0, q, flexural_rigidity(E, T, NU), NU)
    assert np.isclose(ref / q, 0.0479, rtol=2e-3)                    # the tabulated 0.0479 q a^2
    M = np.array([_centre_moment(n, q=q) for n in (8, 16, 32)])
    assert np.allclose(M[:, 0], M[:, 1], rtol=1e-9)                   # symmetry
    assert np.all(np.abs(M[:, 2]) < 1e-3 * ref)          # no twist at the centre (the diagonals: 2e-4 at 8 x 8)
    errors = np.abs(M[:, 0] / ref - 1)
    assert errors[2] < 5e-3, errors                                   # measured 5.7 %, 1.43 %, 0.36 %
    order = np.log2(errors[:-1] / errors[1:])
    assert np.all((order > 1.9) & (order < 2.1)), order              # O(h^2): measured 2.00, 2.00


@pytest.mark.parametrize("field, kappa", [("xx", (-2.0, 0.0, 0.0)), ("yy", (0.0, -2.0, 0.0)),
                                          ("xy", (0.0, 0.0, -2.0))])
def test_constant_curvature_moments_are_exact_on_a_distorted_mesh(field, kappa):
    """w = x^2, y^2, xy (w up): curvatures [κx, κy, 2κxy] = -[w,xx, w,yy, 2 w,xy] exactly in every
    cell, the moments D_b κ (the sign: a sagging plate, w,xx > 0, has Mx < 0)."""
    pts, quads = square(4, jitter=0.3, seed=2)
    x, y = pts.T
    w, wx, wy = {"xx": (x * x, 2 * x, 0 * x), "yy": (y * y, 0 * x, 2 * y), "xy": (x * y, y, x)}[field]
    u = np.column_stack([w, wy, -wx]).ravel()
    M = (moment_operator(pts, quads, E, T, NU) @ u).reshape(-1, 3)
    exact = bending_matrix(E, T, NU) @ np.array(kappa)
    assert np.abs(M - exact).max() < 1e-9 * np.abs(exact).max()


def _plate_run(**plate):
    mesh, pm = reactor_plate(thickness=plate.pop("thickness", 2.0))
    if plate:
        pm = type(pm)(pm.stick, dataclasses.replace(pm.plate, **plate), pm.points, pm.cells, pm.trace)
    return mesh, pm


def test_contact_pressures_balance_the_weight_and_the_inertia_forces():
    """Sum of pressure x area = the soil's vertical force = the weight plus the vertical inertia
    forces of every mass (sticks, plate), at rest and at every step of a run with uplift (the
    structure's stiffness and damping move no force under a rigid vertical translation)."""
    mesh, pm = _plate_run()
    soil = rock_winkler(mesh.xy, mesh.area)
    mo = pulse_motion(0.005, 0.8)
    st = PlateStepper(pm, soil, mo.dt, contact=ContactSettings(), ag0=mo.acc[0])
    area = pm.cell_area
    assert np.allclose(area, mesh.area, rtol=1e-12)                  # the cells are the BEM's patches
    weight = G_ACC * pm.total_mass
    assert abs((st.P0 / area) @ area / weight - 1) < 1e-12
    rz = pm.influence[:, 2]
    lifted, worst = 0, 0.0
    for k in range(1, mo.acc.shape[0]):
        st.set_ground_acceleration(mo.acc[k])
        st.step()
        inertia = rz @ (pm.mass * (st.a + pm.influence @ mo.acc[k]))
        worst = max(worst, abs((st.P / area) @ area - weight - inertia) / weight)
        lifted = max(lifted, int((st.gap() > 0).sum()))
    assert lifted > 10                                                # the raft lifts over many cells
    assert worst < 1e-10, worst                                       # measured 9.5e-13 (at rest 2.3e-13)


def test_moments_at_the_stick_base_and_their_peaks_in_a_run():
    mesh, pm = _plate_run()
    mo = pulse_motion(0.005, 0.8)
    res = simulate(pm, rock_winkler(mesh.xy, mesh.area), mo.acc, mo.dt, raft_points={"edge": (18.0, 0.0),
                                                                                    "held": (2.0, 2.0)})
    assert res.max_uplift() > 1e-2
    # the base cells: those with held and free vertices; the held cells bend not at all
    base = res.plate_moment_cells
    held = np.array([pm.slaved[list(c)].all() for c in pm.cells])
    straddle = np.array([pm.slaved[list(c)].any() for c in pm.cells]) & ~held
    assert np.array_equal(base, np.flatnonzero(straddle)) and base.size > 0
    assert np.array_equal(res.plate_vertex_held, pm.slaved)
    # the moments of every step: the moment operator on the stepper's states, the static state's
    # included (at t = 0 the dynamic state is zero: the static moments)
    st = PlateStepper(pm, rock_winkler(mesh.xy, mesh.area), mo.dt, contact=ContactSettings(), ag0=mo.acc[0])
    M0 = (pm.moment_operator @ st.static.u).reshape(-1, 3)
    assert np.allclose(res.plate_moment[0], M0[base], rtol=1e-12, atol=1e-9 * np.abs(M0).max())
    assert np.abs(M0[held]).max() < 1e-9 * np.abs(M0).max()
    assert np.allclose(res.plate_moment_peak[base], np.abs(res.plate_moment).max(axis=0), rtol=1e-14)
    assert np.abs(res.plate_moment).max() > 2 * np.abs(M0[base]).max()      # the rocking bends the base
    # the raft points: a held point moves rigidly with the raft; a free one with its vertex
    info = res.info["raft_points"]
    k = info["held"]["vertex"]
    x, y = pm.points[k]
    assert pm.slaved[k] and not pm.slaved[info["edge"]["vertex"]]
    rigid_z = res.raft[:, 2] + res.raft[:, 3] * y - res.raft[:, 4] * x
    assert np.allclose(res.disp["held"][:, 2], rigid_z, rtol=0, atol=1e-12 * np.abs(rigid_z).max())
    assert np.allclose(res.disp["held"][:, 0], res.raft[:, 0] - res.raft[:, 5] * y, rtol=0, atol=1e-15)
    e = info["edge"]["vertex"]
    assert np.array_equal(res.disp["edge"][:, 2], res.plate_vertex_deflection[:, e])
    # their accelerations are those of the displacements under the average-acceleration rule:
    # u(n+1) - 2 u(n) + u(n-1) = dt^2 / 4 (a(n+1) + 2 a(n) + a(n-1)) (no halved step in this run)
    assert res.info["subdivided_steps"] == 0
    for name in ("edge", "held"):
        u, a = res.disp[name], res.acc[name] - mo.acc
        lhs = u[2:] - 2 * u[1:-1] + u[:-2]
        rhs = mo.dt ** 2 / 4 * (a[2:] + 2 * a[1:-1] + a[:-2])
        assert np.abs(lhs - rhs).max() < 1e-10 * np.abs(lhs).max(), name      # measured 2.6e-13, 5.6e-13
    with pytest.raises(StructureError, match="off the raft"):
        simulate(pm, rock_winkler(mesh.xy, mesh.area), mo.acc, mo.dt, raft_points={"far": (60.0, 0.0)})
    with pytest.raises(StructureError, match="need a plate raft"):
        simulate(pm.stick, rock_winkler(mesh.xy, mesh.area), mo.acc, mo.dt, raft_points={"a": (0.0, 0.0)})


def test_the_plate_damping_is_stiffness_proportional_at_its_ratio():
    """C_plate = 2 zeta / omega_ref K_plate: the plate's bending modes (the raft master held, the
    sticks left out) have the damping ratio zeta f / f_ref, and the undamped plate's C is the
    sticks' alone."""
    _, pm = _plate_run(thickness=1.0, damping=0.04, damping_hz=8.0)
    _, undamped = _plate_run(thickness=1.0)
    Ps = pm.stick_map
    C = (pm.damping() - undamped.damping()).toarray()
    assert np.array_equal(undamped.damping().toarray(), (Ps.T @ sp.csr_matrix(
        damping_matrix(pm.stick)) @ Ps).toarray())
    K = (pm.stiffness - Ps.T @ pm.stick.stiffness @ Ps).toarray()
    M = pm.mass - Ps.T @ pm.stick.mass
    free = np.concatenate([pm.ns_struct - 6 + np.arange(2 * pm.nf), pm.i_t])       # θ and w of the free vertices
    lam, V = sla.eigh(K[np.ix_(free, free)], np.diag(M[free]))
    f = np.sqrt(lam[:5]) / (2 * np.pi)
    zeta = np.einsum("ij,ik,kj->j", V[:, :5], C[np.ix_(free, free)], V[:, :5]) / (2 * 2 * np.pi * f)
    assert np.allclose(zeta, 0.04 * f / 8.0, rtol=1e-9), (f, zeta)
    with pytest.raises(StructureError, match="raft.damping"):
        PlateProperties(1.0, 30e9, 0.2, 2500.0, 6.0, damping=1.5)


def test_a_held_region_off_the_centre_and_one_coarser_than_its_radius_are_said():
    """rigid_x, rigid_y move the held region (the vertices within rigid_radius of that point); the
    monolithic route says when the mesh holds a region well inside the radius (a 6 m radius on
    the 4 m grid: the central 4 m square, its outermost vertex 2.83 m out) and when the region's
    mass centre is off the raft centre."""
    from orchestrator.routes.monolithic import plate_warnings
    mesh, pm = reactor_plate(element_size=4.0, rigid_radius=6.0)
    assert np.isclose(pm.held_reach, np.hypot(2.0, 2.0)) and pm.slaved.sum() == 4
    assert any("coarser than raft.rigid_radius = 6 m" in w for w in plate_warnings(pm, 20.0))
    _, fine = reactor_plate(element_size=2.0, rigid_radius=6.0)
    assert not plate_warnings(fine, 20.0)
    off = type(pm)(pm.stick, dataclasses.replace(pm.plate, rigid_radius=6.5, rigid_x=4.0, rigid_y=-2.0), pm.points,
                   pm.cells, pm.trace)
    r = np.hypot(pm.points[:, 0] - 4.0, pm.points[:, 1] + 2.0)
    assert np.array_equal(off.slaved, r <= 6.5) and off.mass_coupling > 1.0
    assert any("mass centre" in w and "(4, -2) m" in w for w in plate_warnings(off, 20.0))
    # the off-centre held region still moves rigidly about the raft centre: a rigid motion of q
    # is the plate's rigid motion, without strain
    u = np.zeros(off.n_dof)
    u[off.i_q[3]] = 1e-3
    u[off.i_t] = 1e-3 * off.points[off.free, 1]
    u[off.ns_struct - 6 + 2 * np.arange(off.nf)] = 1e-3
    Kp = off.stiffness - off.stick_map.T @ off.stick.stiffness @ off.stick_map
    assert np.abs(Kp @ u).max() < 1e-12 * abs(Kp).max() * 1e-3
    with pytest.raises(StructureError, match="raft.rigid_x"):
        PlateProperties(1.0, 30e9, 0.2, 2500.0, 6.0, rigid_x=float("nan"))


def _static_rocking(pm, Kww):
    """(exact, first order) relative excess of the plate raft's static rocking rotation over the
    rigid raft's on the vertical soil stiffness Kww (N, N) (the plate's nodes bonded to the soil,
    a unit moment about y on the stick base), and the rigid raft's node forces (N,). First order:
    the rigid raft's soil tractions laid on the plate, its held region clamped: the complementary
    energy F^T Kp^-1 F over the rigid raft's M theta0 (the plate's compliance in series)."""
    m, x, y = pm.n_vertices, pm.points[:, 0], pm.points[:, 1]
    Kp = plate_stiffness(pm.points, pm.cells, pm.plate.E, pm.plate.thickness, pm.plate.nu).toarray()
    s, f = np.flatnonzero(pm.slaved), pm.free
    T = np.zeros((3 * m, 3 + 3 * f.size))                  # [uz, rx, ry of the base | w, θx, θy free]
    T[3 * s, 0], T[3 * s, 1], T[3 * s, 2], T[3 * s + 1, 1], T[3 * s + 2, 2] = 1.0, y[s], -x[s], 1.0, 1.0
    for j, k in enumerate(f):
        T[3 * k:3 * k + 3, 3 + 3 * j:6 + 3 * j] = np.eye(3)
    Kpl = T.T @ Kp @ T
    W = pm.trace.toarray() @ T[0::3]
    theta = np.linalg.solve(Kpl + W.T @ Kww @ W, np.eye(Kpl.shape[0])[2])[2]
    Bq = vertical_trace(pm.stick.raft.xy)[:, 2:5]
    q0 = np.linalg.solve(Bq.T @ Kww @ Bq, [0.0, 0.0, 1.0])
    t = Kww @ (Bq @ q0)
    F = np.zeros(3 * f.size)
    F[0::3] = (pm.trace.T @ t)[f]
    return theta / q0[2] - 1, F @ np.linalg.solve(Kpl[3:, 3:], F) / q0[2], t


def test_the_rigid_limit_constant_is_the_plate_compliance_under_the_soil_tractions():
    """The 1/E distance of a stiff plate from the rigid raft, statically: the exact bonded rocking
    rotation against the first-order prediction (the rigid punch's soil tractions on the plate,
    unit-E compliance): equal to 1e-3 of the constant, on Winkler springs and on the BEM half-space
    (relaxed K(0)). The BEM's tractions peak at the edge (4.2 x their mean, Winkler's 2.1 x), so
    the same plate is 2.8 x farther from rigid there: physical, not an artefact of the trace
    weights or masses (no masses here). The coarse grid's artefact: a 6 m radius on 4 m cells
    holds the central 4 m square only, and the distance is 2.7 x the resolved mesh's."""
    from soil_impedance.bem import SurfaceBem
    from soil_impedance.profile import Material, SoilProfile
    from helpers.winkler import NU, RHO, VS
    out = {}
    for h in (4.0, 2.86):
        mesh, pm = reactor_plate(element_size=h, stiffening=1e3)
        bem = SurfaceBem(SoilProfile((), Material(vs=VS, rho=RHO, nu=NU, damping=0.0)), mesh,
                         "relaxed").impedance(0.0).real[2::3, 2::3]
        soils = {"winkler": rock_winkler(mesh.xy, mesh.area).static_stiffness().toarray()[6:, 6:],
                 "bem": 0.5 * (bem + bem.T)}
        for name, K in soils.items():
            exact, first, t = _static_rocking(pm, K)
            stiffer = _static_rocking(reactor_plate(element_size=h, stiffening=1e4)[1], K)[0]
            assert abs(first / exact - 1) < 1e-3, (h, name, exact, first)
            assert abs(exact / stiffer / 10 - 1) < 5e-3, (h, name, exact, stiffer)      # 1/E
            out[h, name] = exact, np.abs(t).max() / np.abs(t).mean()
    # measured (1000 x concrete, 6 m base): h = 2.86: Winkler 0.296 %, BEM 0.840 %; h = 4: 0.819 %, 2.31 %
    assert 2.5 < out[2.86, "bem"][0] / out[2.86, "winkler"][0] < 3.1, out
    assert out[2.86, "bem"][1] > 1.8 * out[2.86, "winkler"][1], out
    assert 0.007 < out[2.86, "bem"][0] < 0.0095, out
    assert out[4.0, "bem"][0] > 2.4 * out[2.86, "bem"][0], out


def test_the_closed_contact_march_gives_the_newton_path_s_moments_and_raft_points():
    """A plate that does not lift: the closed-contact march's moments, their peaks and the raft
    points' motion (computed over the whole history at the end) equal the step-by-step Newton
    path's (contact.precheck = false: recorded step by step) to round-off."""
    mesh, pm = reactor_plate(rigid_radius=12.0)             # 6.6 m: every node in contact at rest
    mo = pulse_motion(0.005, 0.5, pga=0.3)
    pts = {"edge": (18.0, 0.0), "held": (2.0, 2.0)}
    closed, newton = (simulate(pm, rock_winkler(mesh.xy, mesh.area), mo.acc, mo.dt, contact=ContactSettings(
        precheck=pre), raft_points=pts) for pre in (True, False))
    assert "no tension" in closed.notes.precheck and newton.newton_iters.sum() > 0
    assert closed.max_uplift() == newton.max_uplift() == 0.0
    scale = np.abs(newton.plate_moment).max()
    assert np.abs(closed.plate_moment - newton.plate_moment).max() < 1e-9 * scale
    assert np.abs(closed.plate_moment_peak - newton.plate_moment_peak).max() < 1e-9 * scale
    for name in pts:
        a = np.abs(newton.acc[name]).max()
        assert np.abs(closed.acc[name] - newton.acc[name]).max() < 1e-9 * a, name

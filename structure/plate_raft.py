"""A flexible raft: a DKT plate on the interface's cells, rigid in its plane, its stick base made
rigid over a stated radius, stepped by the Python Newmark stepper (docs/formulation.md,
"Flexible raft").

The soil is unchanged: its interface DOFs stay x = [q, w] (6 + N), q the raft's rigid DOFs
about the centre (the soil's horizontal DOFs are condensed on the rigid in-plane motion ux, uy,
rz; its uz, rx, ry rows and columns are zero), w the soil's vertical displacement under each
interface node. Only the structure's vertical trace changes: the rigid raft's
d_i = Bq_i . q - w_i becomes d_i = t_i - w_i, t_i = sum_k c_ik w_k the plate's deflection at
node i interpolated from the deflections w_k of its cell's vertices (weights that reproduce
linear fields exactly: 1/4 at a grid square's centre, 1/3 at a triangle's centroid, the inverse
bilinear map at a quadrilateral's area centroid), so a rigid motion of the plate gives Bq q.

Plate: DKT (structure.plate), vertices the cells' corners (merged), DOFs (w, θx, θy) per vertex.
Vertices within ``rigid_radius`` of the raft centre are slaved to the raft master's (uz, rx, ry):
w_k = uz + rx y_k - ry x_k, θx = rx, θy = ry (eliminated: T^T K T). The whole plate moves with
(ux, uy, rz) in its plane. Mass lumped per vertex: rho t A_k (A_k the vertex's share of its
cells' areas, equal shares) on w and on the in-plane q (ux, uy; rz: rho t A_k r_k^2); rotary
rho t^3/12 A_k on θx, θy. A slaved vertex's mass goes to the master's diagonal
(uz: m_k; rx: m_k y_k^2 + J_k; ry: m_k x_k^2 + J_k), its off-diagonal terms (uz-rx: sum m_k y_k,
uz-ry: -sum m_k x_k) dropped: they vanish for a rigid region symmetric about the centre
(``PlateRaftModel.mass_coupling`` gives their size). The plate's own damping (``damping``, a
ratio at ``damping_hz``) is stiffness proportional, C_plate = beta G^T Kp G with beta = 2 zeta /
(2 pi f): zeta at f, zeta f'/f at f' (0 by default: the soil's radiation and material damping
act on it).

Results (``PlateStepper.plate_outputs``): the vertex deflections and their trace at the nodes,
the bending moments per unit length [Mx, My, Mxy] (N m/m, static + dynamic) of each interface
cell (``moment_operator``: the DKT moments at its triangles' centroids, area-averaged), among
them the stick-base cells (``base_cells``: the cells with vertices both in and out of the held
region), and the motion of the raft points (``point_operator``: the nearest vertex's vertical
deflection with the raft's in-plane rigid motion).

Global DOF layout (n_dof = n_struct + 3 nf + N, nf free vertices):
  [6 DOFs of every non-raft node | θx, θy of each free vertex | q (6) | w of each free vertex |
   N soil w]
so that the Newmark stepper's interior block (condensed by a sparse LU) is the sticks and the
plate rotations, and its boundary block uB = [q, t, w] (6 + nf + N) carries the contact:
d = Bc uB, Bc = [C_slaved Bq | C_free | -I].
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from uplift_common.lazy import lazy_module

from .contact import contact_force, penalty_stiffness
from .damping import damping_matrix
from .errors import StructureError
from .model import G_ACC, StructureModel
from .newmark import NewmarkStepper
from .plate import moment_operator, plate_stiffness
from .preload import solve_static_system
from .soil_interface import SoilInterface


# scipy loads on first use (uplift_common.lazy): a warm run reads what it would compute
sla = lazy_module("scipy.linalg")
sp = lazy_module("scipy.sparse")
#: ranges accepted for the plate's properties (SI): thickness m, E Pa, nu -, rho kg/m^3
PLATE_RANGES = {"thickness": (1e-3, 50.0), "E": (1e6, 1e15), "nu": (0.0, 0.499), "rho": (0.0, 2e4)}
#: ranges of the plate's damping: ratio (-) at the frequency damping_hz (Hz)
DAMPING_RANGES = {"damping": (0.0, 1.0), "damping_hz": (1e-3, 1e3)}


@dataclass(frozen=True)
class PlateProperties:
    """The raft as a plate: thickness m, E Pa, nu (-), rho kg/m^3; rigid_radius m: the plate
    vertices within it of the point (rigid_x, rigid_y) m (default the raft centre) move rigidly
    with the raft master (the stick base);
    damping: the plate's stiffness-proportional damping ratio at damping_hz (Hz) (module notes)."""
    thickness: float
    E: float
    nu: float
    rho: float
    rigid_radius: float
    damping: float = 0.0
    damping_hz: float = 10.0
    rigid_x: float = 0.0
    rigid_y: float = 0.0

    def __post_init__(self):
        for key, (lo, hi) in {**PLATE_RANGES, **DAMPING_RANGES}.items():
            v = getattr(self, key)
            if not isinstance(v, (int, float)) or isinstance(v, bool) or not np.isfinite(v) or not lo <= v <= hi:
                raise StructureError(f"raft.{key} = {v!r} must be a number in [{lo:g}, {hi:g}]")
        if not (isinstance(self.rigid_radius, (int, float)) and np.isfinite(self.rigid_radius)
                and self.rigid_radius > 0):
            raise StructureError(f"raft.rigid_radius = {self.rigid_radius!r} must be a positive length in m")
        for key in ("rigid_x", "rigid_y"):
            v = getattr(self, key)
            if not isinstance(v, (int, float)) or isinstance(v, bool) or not np.isfinite(v):
                raise StructureError(f"raft.{key} = {v!r} must be a finite coordinate in m (about the raft centre)")


def plate_cells(xy, cell=None, polygons=None):
    """(points (m, 2), cells [vertex tuples], C (N, m) csr) of the plate on the interface cells:
    a grid's squares of side ``cell`` centred on the nodes ``xy`` (N, 2), or the ``polygons``
    (N, 4, 2) of a mesh file (a triangle with a vertex repeated); C the trace weights of each
    node (its cell's vertices; linear fields reproduced exactly)."""
    xy = np.asarray(xy, float)
    N = xy.shape[0]
    if polygons is not None:
        poly = np.asarray(polygons, float)
    elif cell is not None:
        poly = xy[:, None, :] + 0.5 * cell * np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
    else:
        raise StructureError("a plate raft needs the interface's cells: a circle or rectangle grid of square "
                             "cells, or a mesh file (foundation.mesh); a node list (shape = \"nodes\") has none")
    scale = max(np.abs(poly).max(), 1.0)
    key = np.rint(poly.reshape(-1, 2) / (1e-7 * scale)).astype(np.int64)
    _, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
    points = poly.reshape(-1, 2)[first]
    ids = inv.reshape(N, -1)
    cells, rows, cols, vals = [], [], [], []
    for i in range(N):
        c = list(dict.fromkeys(int(v) for v in ids[i]))
        cells.append(tuple(c))
        if len(c) == 3:
            w = np.full(3, 1.0 / 3.0)
        elif len(c) == 4:
            w = _bilinear_weights(points[c], xy[i])
        else:
            raise StructureError(f"interface cell {i} has {len(c)} distinct vertices: a plate cell has 3 or 4")
        rows += [i] * len(c)
        cols += c
        vals += list(w)
    C = sp.csr_matrix((vals, (rows, cols)), shape=(N, points.shape[0]))
    return points, cells, C


def _bilinear_weights(p, x):
    """Bilinear shape functions (4,) of the quadrilateral p (4, 2) at the point x (2,) (the inverse
    bilinear map by Newton; the centre of a parallelogram exactly)."""
    s = np.zeros(2)
    sg = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], float)
    for _ in range(20):
        N = 0.25 * (1 + sg[:, 0] * s[0]) * (1 + sg[:, 1] * s[1])
        r = N @ p - x
        if np.abs(r).max() <= 1e-13 * max(np.abs(p).max(), 1.0):
            break
        dN = 0.25 * np.column_stack([sg[:, 0] * (1 + sg[:, 1] * s[1]), sg[:, 1] * (1 + sg[:, 0] * s[0])])
        s = s - np.linalg.solve(p.T @ dN, r)
    return 0.25 * (1 + sg[:, 0] * s[0]) * (1 + sg[:, 1] * s[1])


class PlateRaftModel:
    """The stick model on a plate raft. ``model``: the StructureModel (its Raft: the interface
    nodes, the master node at the centre; the raft's own mass and inertia at the master are
    kept as given: set them to zero when the plate is the raft's mass); ``plate``:
    PlateProperties; ``points``, ``cells``, ``trace``: ``plate_cells``. Exposes what the driver
    reads of a StructureModel (nodes, raft, dofs, node_by_name, n_interface) and the global
    matrices of the layout in the module docstring."""

    def __init__(self, model: StructureModel, plate: PlateProperties, points, cells, trace):
        self.stick, self.plate = model, plate
        self.points = np.asarray(points, float)
        self.cells = tuple(tuple(c) for c in cells)
        self.trace = sp.csr_matrix(trace)
        m, N = self.points.shape[0], model.n_interface
        if self.trace.shape != (N, m):
            raise StructureError(f"plate trace weights {self.trace.shape} do not match {N} nodes and {m} vertices")
        r = np.hypot(self.points[:, 0] - plate.rigid_x, self.points[:, 1] - plate.rigid_y)
        self.slaved = r <= plate.rigid_radius * (1 + 1e-9)
        if self.slaved.sum() < 3:
            raise StructureError(f"raft.rigid_radius = {plate.rigid_radius:g} m holds {int(self.slaved.sum())} plate "
                                 f"vertices: the stick base needs at least 3 (the nearest vertices are "
                                 f"{np.sort(r)[2]:.3g} m from its centre); raise it")
        #: m: the held region's outermost vertex from its centre (on a coarse mesh well inside
        #: rigid_radius: the region that is held is then smaller than the radius says)
        self.held_reach = float(r[self.slaved].max())
        self.free = np.flatnonzero(~self.slaved)
        self.nf = nf = self.free.size
        ns = model.n_struct
        self.ns_struct = ns
        self.n_dof = ns + 3 * nf + N
        self.ni = ns - 6 + 2 * nf
        self.i_q = self.ni + np.arange(6)
        self.i_t = self.ni + 6 + np.arange(nf)
        self.i_soil = self.ni + 6 + nf + np.arange(N)
        self.nb = self.n_dof - self.ni

    # ---- what the driver reads of a StructureModel -----------------------------------
    @property
    def nodes(self):
        return self.stick.nodes

    @property
    def raft(self):
        return self.stick.raft

    @property
    def n_interface(self) -> int:
        return self.stick.n_interface

    @property
    def n_vertices(self) -> int:
        return self.points.shape[0]

    def dofs(self, nid: int) -> np.ndarray:
        """The 6 global DOF indices of structure node nid (the raft master: q)."""
        d = self.stick.dofs(nid)
        return np.where(d < self.ns_struct - 6, d, d - (self.ns_struct - 6) + self.ni)

    def node_by_name(self, name: str):
        return self.stick.node_by_name(name)

    # ---- maps ----------------------------------------------------------------------------
    @cached_property
    def stick_map(self) -> sp.csr_matrix:
        """Ps (n_struct, n_dof): the stick model's DOFs from the global ones."""
        ns = self.ns_struct
        cols = np.concatenate([np.arange(ns - 6), self.i_q])
        return sp.csr_matrix((np.ones(ns), (np.arange(ns), cols)), shape=(ns, self.n_dof))

    @cached_property
    def plate_map(self) -> sp.csr_matrix:
        """G (3m, n_dof): the plate's vertex DOFs (w, θx, θy) from the global ones."""
        m = self.n_vertices
        rows, cols, vals = [], [], []
        s = np.flatnonzero(self.slaved)
        x, y = self.points[s, 0], self.points[s, 1]
        uz, rx, ry = self.i_q[2], self.i_q[3], self.i_q[4]
        for r_, c_, v_ in ((3 * s, uz, 1.0), (3 * s, rx, y), (3 * s, ry, -x), (3 * s + 1, rx, 1.0), (3 * s + 2, ry, 1.0)):
            rows.append(r_); cols.append(np.full(s.size, c_)); vals.append(np.broadcast_to(v_, s.shape))
        f, j = self.free, np.arange(self.nf)
        i_rot = self.ns_struct - 6 + 2 * j
        for r_, c_ in ((3 * f, self.i_t), (3 * f + 1, i_rot), (3 * f + 2, i_rot + 1)):
            rows.append(r_); cols.append(c_); vals.append(np.ones(f.size))
        return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                             shape=(3 * m, self.n_dof))

    @cached_property
    def vertex_map(self) -> sp.csr_matrix:
        """Gw (m, n_dof): the vertex deflections w_k."""
        return self.plate_map[0::3].tocsr()

    @cached_property
    def interface_operator(self) -> sp.csr_matrix:
        """B (N, n_dof): d = B u = t - w (plate trace minus soil w)."""
        N = self.n_interface
        S = sp.csr_matrix((np.ones(N), (np.arange(N), self.i_soil)), shape=(N, self.n_dof))
        return (self.trace @ self.vertex_map - S).tocsr()

    @cached_property
    def boundary_trace(self) -> sp.csr_matrix:
        """Bc (N, nb): d = Bc uB on the boundary block uB = [q, t, w]."""
        return self.interface_operator[:, self.ni:].tocsr()

    # ---- matrices ------------------------------------------------------------------------
    @cached_property
    def cell_area(self) -> np.ndarray:
        """(N,) m^2: the area of each interface node's cell (the contact pressure's divisor)."""
        A = np.zeros(len(self.cells))
        for i, c in enumerate(self.cells):
            p = self.points[list(c)]
            A[i] = 0.5 * abs(np.dot(p[:, 0], np.roll(p[:, 1], -1)) - np.dot(np.roll(p[:, 0], -1), p[:, 1]))
        return A

    @cached_property
    def vertex_area(self) -> np.ndarray:
        """A_k (m,), m^2: each cell's area shared equally by its vertices."""
        A = np.zeros(self.n_vertices)
        for c, a in zip(self.cells, self.cell_area):
            A[list(c)] += a / len(c)
        return A

    @cached_property
    def moment_operator(self) -> sp.csr_matrix:
        """(3N, n_dof): the bending moments per unit length [Mx, My, Mxy] (N m/m) of each
        interface cell, rows interleaved per cell, from the global DOFs (``structure.plate.
        moment_operator``: positive when the top fibre is in tension)."""
        p = self.plate
        return (moment_operator(self.points, self.cells, p.E, p.thickness, p.nu) @ self.plate_map).tocsr()

    @cached_property
    def base_cells(self) -> np.ndarray:
        """The interface cells around the stick base (node indices, ascending): those with
        vertices both in and out of the held region, where the plate leaves the rigid region."""
        return np.array([i for i, c in enumerate(self.cells)
                         if self.slaved[list(c)].any() and not self.slaved[list(c)].all()], dtype=np.int64)

    def nearest_vertex(self, x: float, y: float) -> int:
        """The plate vertex nearest the point (x, y) m about the raft centre; a point farther
        than a cell's diagonal from every vertex (off the raft) raises StructureError."""
        d = np.hypot(self.points[:, 0] - x, self.points[:, 1] - y)
        k = int(np.argmin(d))
        reach = np.sqrt(2.0 * self.cell_area.max())
        if d[k] > reach:
            raise StructureError(f"raft point ({x:g}, {y:g}) m is {d[k]:.3g} m from the nearest plate vertex (more "
                                 f"than a cell's diagonal, {reach:.3g} m): it is off the raft; give a point on it")
        return k

    def point_operator(self, vertex: int) -> sp.csr_matrix:
        """(3, n_dof): the displacement (x, y, z) of plate vertex ``vertex`` from the global DOFs:
        the raft's rigid in-plane motion (ux - rz y, uy + rz x) and the vertex's deflection w."""
        x, y = self.points[vertex]
        q = self.i_q
        rows = sp.csr_matrix(([1.0, -y, 1.0, x], ([0, 0, 1, 1], [q[0], q[5], q[1], q[5]])), shape=(2, self.n_dof))
        return sp.vstack([rows, self.vertex_map[vertex]], format="csr")

    @cached_property
    def plate_columns(self) -> np.ndarray:
        """The global DOFs the plate's results read (ascending, 6 + 3 nf of them): the raft's q,
        each free vertex's rotations θx, θy and deflection t; ``moment_operator``, ``vertex_map``
        and every ``point_operator`` are zero off them (the native stepper records these alone)."""
        i_rot = self.ns_struct - 6 + np.arange(2 * self.nf)
        return np.sort(np.concatenate([i_rot, self.i_q, self.i_t]))

    @cached_property
    def stiffness(self) -> sp.csr_matrix:
        """K (n_dof, n_dof): the sticks (Ps^T K Ps) and the plate (G^T Kp G); no soil."""
        p = self.plate
        Kp = plate_stiffness(self.points, self.cells, p.E, p.thickness, p.nu)
        Ps, G = self.stick_map, self.plate_map
        return (Ps.T @ self.stick.stiffness @ Ps + G.T @ Kp @ G).tocsr()

    @cached_property
    def vertex_masses(self) -> tuple:
        """(m_k, J_k) (m,): lumped vertex mass kg and rotary inertia kg m^2."""
        p = self.plate
        return p.rho * p.thickness * self.vertex_area, p.rho * p.thickness ** 3 / 12 * self.vertex_area

    @cached_property
    def mass(self) -> np.ndarray:
        """Diagonal lumped mass (n_dof,), kg and kg m^2 (module docstring); zero on the soil w."""
        M = self.stick_map.T @ self.stick.mass
        mk, Jk = self.vertex_masses
        x, y = self.points.T
        s, f, q = self.slaved, self.free, self.i_q
        M[q[0]] += mk.sum()
        M[q[1]] += mk.sum()
        M[q[5]] += (mk * (x * x + y * y)).sum()
        M[q[2]] += mk[s].sum()
        M[q[3]] += (mk[s] * y[s] ** 2 + Jk[s]).sum()
        M[q[4]] += (mk[s] * x[s] ** 2 + Jk[s]).sum()
        M[self.i_t] += mk[f]
        i_rot = self.ns_struct - 6 + 2 * np.arange(self.nf)
        M[i_rot] += Jk[f]
        M[i_rot + 1] += Jk[f]
        return M

    @property
    def mass_coupling(self) -> float:
        """The dropped off-diagonal mass of the rigid region over its mass, m: max(|sum m_k y_k|,
        |sum m_k x_k|) / sum m_k (0 for a region symmetric about the centre)."""
        mk = self.vertex_masses[0][self.slaved]
        p = self.points[self.slaved]
        return float(np.abs(mk @ p).max() / max(mk.sum(), 1e-300))

    @cached_property
    def influence(self) -> np.ndarray:
        """r (n_dof, 3): DOF motion per unit ground displacement in x, y, z."""
        r = self.stick_map.T @ self.stick.influence
        r[self.i_t, 2] = 1.0
        return r

    def gravity_load(self) -> np.ndarray:
        """Self-weight (n_dof,), N."""
        return -G_ACC * self.mass * self.influence[:, 2]

    @property
    def total_mass(self) -> float:
        return float(self.stick.total_mass + self.vertex_masses[0].sum())

    @property
    def plate_beta(self) -> float:
        """beta (s): the plate's stiffness-proportional damping coefficient 2 zeta / (2 pi f)."""
        return 2.0 * self.plate.damping / (2.0 * np.pi * self.plate.damping_hz)

    def damping(self, damping=None) -> sp.csr_matrix:
        """The sticks' structural damping on the global DOFs, plus the plate's own, beta G^T Kp
        G (none at the default damping = 0: the matrix is then the sticks' alone, exactly)."""
        Ps = self.stick_map
        C = Ps.T @ sp.csr_matrix(damping_matrix(self.stick, damping)) @ Ps
        if self.plate.damping > 0:
            p, G = self.plate, self.plate_map
            C = C + self.plate_beta * (G.T @ plate_stiffness(self.points, self.cells, p.E, p.thickness, p.nu) @ G)
        return C.tocsr()


class _PlateSoil(SoilInterface):
    """The soil on the boundary block [q, t, w] (6 + nf + N): zero on the plate deflections t."""

    def __init__(self, soil, nf: int, N: int):
        self.soil, self.n_dof = soil, 6 + nf + N
        self.sel = np.concatenate([np.arange(6), 6 + nf + np.arange(N)])
        self.S = sp.csr_matrix((np.ones(6 + N), (np.arange(6 + N), self.sel)), shape=(6 + N, self.n_dof))

    def _ext(self, K):
        return (self.S.T @ sp.csr_matrix(K) @ self.S).tocsr()

    def instantaneous(self, dt):
        # called at every (sub)step (the soil takes its step size from it): the extension is kept
        # while the soil returns the same matrices
        K0, C0 = self.soil.instantaneous(dt)
        last = getattr(self, "_last", None)
        if last is None or last[0] is not K0 or last[1] is not C0:
            last = self._last = (K0, C0, self._ext(K0), self._ext(C0))
        return last[2], last[3]

    def history(self):
        h = np.zeros(self.n_dof)
        h[self.sel] = self.soil.history()
        return h

    def commit(self, x, xdot):
        self.soil.commit(x[self.sel], xdot[self.sel])

    def static_stiffness(self):
        return self._ext(self.soil.static_stiffness())

    def get_state(self):
        return self.soil.get_state()

    def set_state(self, state):
        self.soil.set_state(state)


class PlateStepper(NewmarkStepper):
    """NewmarkStepper on a PlateRaftModel: the same discrete equations, step rule, Newton,
    line search and closed-contact march, with the contact operator d = Bc [q, t, w] of the
    plate (the hooks ``_trace``, ``_contact``, ``_jacobian_lu``...). With ``external_soil``
    (the structure FMU) the soil's history force h comes on the soil's DOFs [q, w] (6 + N)
    through ``set_soil_history`` and is laid on the boundary block [q, t, w] (zero on t)."""

    def _init(self, model, soil, dt, contact, damping, alpha, static, external_soil, ag0):
        if not isinstance(model, PlateRaftModel):
            raise StructureError("PlateStepper steps a PlateRaftModel")
        self._scheme(model, soil, dt, contact, alpha)
        N = model.n_interface
        self.soil = _PlateSoil(soil, model.nf, N)
        self.external_soil = bool(external_soil)
        self.N, self.n, self.ni, self.nb = N, model.n_dof, model.ni, model.nb
        self.ns = self.n - N                         # u[ns:] = the soil w, as for the rigid raft
        self.Bc = model.boundary_trace
        self.BcT = self.Bc.T.tocsr()
        # Bc^T diag(s) Bc as sum_i s_i b_i b_i^T: the flat positions in (nb, nb) and the products
        # b_ia b_ib of each node's row (a few vertices and its soil w), gathered once
        Bc = self.Bc.tocsr()
        pos, prod, node = [], [], []
        for i in range(N):
            c, v = Bc.indices[Bc.indptr[i]:Bc.indptr[i + 1]], Bc.data[Bc.indptr[i]:Bc.indptr[i + 1]]
            pos.append((c[:, None] * self.nb + c[None, :]).ravel())
            prod.append(np.outer(v, v).ravel())
            node.append(np.full(c.size * c.size, i))
        self._jpos, self._jprod, self._jnode = (np.concatenate(a) for a in (pos, prod, node))
        self.kp = penalty_stiffness(self.contact, soil.static_stiffness(), N)
        self.Ks = model.stiffness
        if static is None:
            K = (self.Ks + self._embed_soil(self.soil.static_stiffness())).tocsr()
            static = solve_static_system(K, model.gravity_load(), model.interface_operator, self.kp,
                                         int(model.i_q[2]), unilateral=self.contact.enabled)
        self.static = static
        self.P0 = self.static.P0.copy()
        self.delta0 = self.static.delta0.copy()
        self.M = model.mass.copy()
        self.Cs = model.damping(damping)
        self.Mr = self.M[:, None] * model.influence
        self.Bq3 = None
        self._start(ag0)

    # ---- inputs ----------------------------------------------------------------------
    def set_soil_history(self, h) -> None:
        """Soil history force h (6+N,) on the soil's DOFs [q, w], N, for the next step (external
        soil only): zero on the plate deflections t of the boundary block."""
        h_ext = np.zeros(self.nb)
        h_ext[self.soil.sel] = np.asarray(h, float).reshape(6 + self.N)
        self._h_ext = h_ext

    def next_inputs(self) -> tuple:
        """(a_g(t + dt) (3,) m/s^2, h (6+N,) N on [q, w]): what ``set_soil_history`` takes back."""
        return self._ag_next.copy(), self._h_ext[self.soil.sel].copy()

    # ---- outputs ---------------------------------------------------------------------
    @property
    def x(self) -> np.ndarray:
        """The soil's interface displacements [q, w] (6+N,)."""
        return self.u[self.ni:][self.soil.sel]

    @property
    def xdot(self) -> np.ndarray:
        return self.v[self.ni:][self.soil.sel]

    def relative_vertical(self, u=None) -> np.ndarray:
        u = self.u if u is None else u
        return self.Bc @ u[self.ni:]

    def plate_deflections(self, U) -> tuple:
        """(vertex deflections (..., m), trace at the interface nodes (..., N)), m, of the states
        U (..., n_dof): dynamic, relative to the static state and the free field."""
        U = np.asarray(U)
        W = (self.model.vertex_map @ U.reshape(-1, self.n).T).T
        T = (self.model.trace @ W.T).T
        return W.reshape(U.shape[:-1] + (-1,)), T.reshape(U.shape[:-1] + (-1,))

    def plate_moments(self, U) -> np.ndarray:
        """(..., N, 3) N m/m: the bending moments [Mx, My, Mxy] of each interface cell in the
        states U (..., n_dof) (dynamic), the static state's added: the total moments."""
        U = np.asarray(U)
        Mm = (self.model.moment_operator @ (U.reshape(-1, self.n) + self.static.u).T).T
        return Mm.reshape(U.shape[:-1] + (self.N, 3))

    def plate_outputs(self, U, cols=None) -> dict:
        """The plate's records of the states U (nt, n_dof), or of their global DOFs ``cols``
        alone (U (nt, len(cols)); ``cols`` ascending, holding ``model.plate_columns``: the native
        stepper's records): plate_vertex_deflection (nt, m), plate_deflection (nt, N) m,
        plate_moment (nt, n_base, 3) N m/m at the stick-base cells (``PlateRaftModel.base_cells``;
        static + dynamic, as ``plate_moments``) and plate_moment_peak (N, 3) N m/m: the largest
        |Mx|, |My|, |Mxy| of each cell over the states (evaluated in blocks of 256 states)."""
        pm = self.model
        cols = np.arange(self.n) if cols is None else np.asarray(cols, np.int64)
        if cols.size != self.n and (np.any(np.diff(cols) <= 0) or not np.isin(pm.plate_columns, cols).all()):
            raise StructureError("plate_outputs: cols must be ascending and hold the plate's columns")
        Gw, Mop, u0 = pm.vertex_map[:, cols], pm.moment_operator[:, cols], self.static.u[cols]
        U = np.asarray(U).reshape(-1, cols.size)
        W = (Gw @ U.T).T
        T = (pm.trace @ W.T).T
        base = pm.base_cells
        Mb = np.zeros((U.shape[0], base.size, 3))
        peak = np.zeros((self.N, 3))
        for k in range(0, U.shape[0], 256):
            Mk = (Mop @ (U[k:k + 256] + u0).T).T.reshape(-1, self.N, 3)
            Mb[k:k + 256] = Mk[:, base]
            peak = np.maximum(peak, np.abs(Mk).max(axis=0))
        return dict(plate_vertex_deflection=W, plate_deflection=T, plate_moment=Mb, plate_moment_peak=peak)

    # ---- the hooks of the trace ------------------------------------------------------------
    def _embed_soil(self, K0):
        return sp.block_diag([sp.csr_matrix((self.ni, self.ni)), sp.csr_matrix(K0)], format="csr")

    def _interface_operator(self):
        return self.model.interface_operator

    def _trace(self, uB):
        return self.Bc @ uB

    def _relative_block(self, U):
        return (self.Bc @ U[:, self.ni:].T).T

    def _relative_history(self, out, U):
        return self._relative_block(U)

    def _contact(self, uB):
        d = self.Bc @ uB
        if self.contact.enabled:
            P, act = contact_force(d, self.delta0, self.kp)
        else:
            P, act = self.P0 - self.kp * d, np.ones(self.N, bool)
        dp = P - self.P0
        return P, act, -(self.BcT @ dp)

    def _jacobian_lu(self, sysd, active):
        key = (sysd["key"], active.tobytes())
        lu = self._lu_cache.get(key)
        if lu is not None:
            self._lu_cache.move_to_end(key)
            return lu
        s = (1 + self.alpha) * self.kp * active
        J = sysd["S0"] + np.bincount(self._jpos, self._jprod * s[self._jnode],
                                     minlength=self.nb * self.nb).reshape(self.nb, self.nb)
        lu = sla.lu_factor(J, check_finite=False)
        self.n_factorisations += 1
        self._lu_cache[key] = lu
        if len(self._lu_cache) > 16:
            self._lu_cache.popitem(last=False)
        return lu

    def closed_histories(self, ag, Zh, H, dofs) -> dict:
        out = super().closed_histories(ag, Zh, H, dofs)
        out.update(self.plate_outputs(Zh[:, 0]))
        return out


def rigid_equivalent(pm: PlateRaftModel) -> StructureModel:
    """The rigid-raft StructureModel with the plate's lumped mass and inertia (about the centre:
    m = sum m_k; Ixx = sum m_k y_k^2 + J_k, Iyy = sum m_k x_k^2 + J_k, Izz = sum m_k r_k^2)
    added to the raft master's: the rigid limit's reference."""
    mk, Jk = pm.vertex_masses
    x, y = pm.points.T
    r = pm.stick.raft
    raft = dataclasses.replace(r, m=r.m + mk.sum(), inertia=(r.inertia[0] + (mk * y * y + Jk).sum(),
                                                             r.inertia[1] + (mk * x * x + Jk).sum(),
                                                             r.inertia[2] + (mk * (x * x + y * y)).sum()))
    return dataclasses.replace(pm.stick, raft=raft)


def raft_point_operators(model, raft_points, names=()) -> tuple:
    """({name: P (3, n_dof)}, {name: info}) of the raft points asked for (``structure.simulate``; the native
    stepper's run too): P the displacement of the point's vertex from the global DOFs; a point
    named as one of the output nodes ``names`` raises StructureError."""
    if not raft_points:
        return {}, {}
    clash = sorted(set(raft_points) & set(names))
    if clash:
        raise StructureError(f"raft point {clash[0]!r} has the name of a structure output node: rename it")
    if not isinstance(model, PlateRaftModel):
        raise StructureError("raft points need a plate raft (a rigid raft's motion is its master's: ask for the "
                             "raft node instead)")
    ops, info = {}, {}
    for name, (x, y) in raft_points.items():
        k = model.nearest_vertex(float(x), float(y))
        ops[name] = model.point_operator(k)
        info[name] = {"x_m": float(x), "y_m": float(y), "vertex": k, "vertex_x_m": float(model.points[k, 0]),
                      "vertex_y_m": float(model.points[k, 1])}
    return ops, info

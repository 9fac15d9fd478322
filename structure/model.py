"""Stick-and-raft structural model: immutable description and its sparse matrices.

Beams are 3D Timoshenko elements (Euler-Bernoulli when no shear areas are given), masses
are lumped (diagonal mass matrix, rotary inertias about global axes at the node). The raft
is rigid: its master node sits at the raft centre on z = 0 and carries the raft rigid-body
DOFs q = (ux, uy, uz, rx, ry, rz); the N interface points (xy about the raft centre, with
tributary areas) are slaved to it.

Global DOF layout (n_dof = n_struct + N):
  [6 DOFs of every non-raft node, in node order | 6 raft DOFs q | N soil vertical DOFs w]
The interface vector x = [q, w] is the trailing block of length 6 + N.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from uplift_common.interface import interface_points
from uplift_common.lazy import lazy_module

from .beams import global_stiffness
from .errors import StructureError

# scipy loads on first use (uplift_common.lazy): a warm run reads what it would compute
sp = lazy_module("scipy.sparse")

G_ACC = 9.81  # m/s^2, gravity acts along -z


@dataclass(frozen=True)
class Node:
    id: int
    xyz: tuple
    name: str | None = None


@dataclass(frozen=True)
class Beam:
    """Beam between two node ids. E, G: Pa; A, Asy, Asz: m^2; Iy, Iz, J: m^4; rho: kg/m^3
    (optional distributed mass, lumped half to each end)."""
    nodes: tuple
    E: float
    G: float
    A: float
    Iy: float
    Iz: float
    J: float
    Asy: float | None = None
    Asz: float | None = None
    rho: float = 0.0


@dataclass(frozen=True)
class Mass:
    """Lumped mass m (kg) and rotary inertias (Ixx, Iyy, Izz) (kg m^2) at a node."""
    node: int
    m: float
    inertia: tuple = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Spring:
    """Discrete spring, 6 components (N/m, N m/rad) in global axes; node to ground when
    node2 is None, else node to node2."""
    node: int
    k: tuple
    node2: int | None = None


@dataclass(frozen=True, eq=False)
class Raft:
    """Rigid raft: master node id (at the raft centre, z = 0), interface points
    xy (N, 2) m about the centre, tributary areas (N,) m^2, raft mass kg and inertias kg m^2."""
    node: int
    xy: np.ndarray
    area: np.ndarray
    m: float = 0.0
    inertia: tuple = (0.0, 0.0, 0.0)

    def __post_init__(self):
        xy, area = interface_points(self.xy, self.area, StructureError, "raft interface")
        object.__setattr__(self, "xy", xy)
        object.__setattr__(self, "area", area)

    @property
    def n(self) -> int:
        return self.xy.shape[0]

    def vertical_trace(self) -> np.ndarray:
        """Bq (N, 6): vertical displacement of each interface point, uz + rx y - ry x."""
        return vertical_trace(self.xy)


def vertical_trace(xy) -> np.ndarray:
    """Bq (N, 6): the rigid raft's vertical displacement at the points ``xy`` (N, 2) m about its
    centre, t = Bq q = uz + rx y - ry x."""
    xy = np.asarray(xy, float)
    B = np.zeros((xy.shape[0], 6))
    B[:, 2] = 1.0
    B[:, 3] = xy[:, 1]
    B[:, 4] = -xy[:, 0]
    return B


@dataclass(frozen=True)
class Damping:
    """Structural damping: kind "modal" (ratio of every fixed-base mode), "rayleigh"
    (C = a0 M + a1 K applied to deformations relative to the raft) or "none"."""
    kind: str = "none"
    ratio: float = 0.0
    a0: float = 0.0
    a1: float = 0.0


@dataclass(frozen=True, eq=False)
class StructureModel:
    nodes: tuple
    beams: tuple
    masses: tuple
    raft: Raft
    springs: tuple = ()
    damping: Damping = field(default_factory=Damping)

    def __post_init__(self):
        ids = [n.id for n in self.nodes]
        if len(set(ids)) != len(ids):
            raise StructureError("structure node ids must be unique")
        known = set(ids)
        for b in self.beams:
            for nid in b.nodes:
                if nid not in known:
                    raise StructureError(f"beam {b.nodes} refers to unknown node {nid}")
        for m in self.masses:
            if m.node not in known:
                raise StructureError(f"mass at unknown node {m.node}")
        for s in self.springs:
            if s.node not in known or (s.node2 is not None and s.node2 not in known):
                raise StructureError(f"spring at unknown node {s.node}/{s.node2}")
        if self.raft.node not in known:
            raise StructureError(f"raft node {self.raft.node} is not a structure node")
        z = self.node(self.raft.node).xyz[2]
        if abs(z) > 1e-9:
            raise StructureError(f"raft node {self.raft.node} must lie on z = 0 (got z = {z})")

    # ---- DOF numbering -------------------------------------------------------------
    def node(self, nid: int) -> Node:
        return self.nodes[self._pos[nid]]

    @cached_property
    def _pos(self) -> dict:
        return {n.id: i for i, n in enumerate(self.nodes)}

    @cached_property
    def order(self) -> dict:
        """node id -> block index (raft master last)."""
        others = [n.id for n in self.nodes if n.id != self.raft.node]
        return {nid: k for k, nid in enumerate(others + [self.raft.node])}

    def dofs(self, nid: int) -> np.ndarray:
        """The 6 global DOF indices of node nid."""
        return 6 * self.order[nid] + np.arange(6)

    @property
    def n_struct(self) -> int:
        return 6 * len(self.nodes)

    @property
    def n_interface(self) -> int:
        return self.raft.n

    @property
    def n_dof(self) -> int:
        return self.n_struct + self.raft.n

    @property
    def raft_dofs(self) -> np.ndarray:
        return np.arange(self.n_struct - 6, self.n_struct)

    def node_by_name(self, name: str) -> Node:
        for n in self.nodes:
            if n.name == name:
                return n
        raise StructureError(f"no structure node named {name!r}; named nodes: "
                             f"{[n.name for n in self.nodes if n.name]}")

    # ---- matrices (structural DOFs only, n_struct) -----------------------------------
    @cached_property
    def stiffness(self) -> sp.csr_matrix:
        """K (n_struct, n_struct), sparse: beams and springs."""
        rows, cols, vals = [], [], []
        xyz = {n.id: np.asarray(n.xyz, float) for n in self.nodes}
        for b in self.beams:
            ke = global_stiffness(xyz[b.nodes[0]], xyz[b.nodes[1]], b.E, b.G, b.A, b.Iy, b.Iz,
                                  b.J, b.Asy, b.Asz)
            idx = np.concatenate([self.dofs(b.nodes[0]), self.dofs(b.nodes[1])])
            rows.append(np.repeat(idx, 12)); cols.append(np.tile(idx, 12)); vals.append(ke.ravel())
        for s in self.springs:
            k = np.asarray(s.k, float)
            i = self.dofs(s.node)
            rows.append(i); cols.append(i); vals.append(k)
            if s.node2 is not None:
                j = self.dofs(s.node2)
                rows += [j, i, j]; cols += [j, j, i]; vals += [k, -k, -k]
        n = self.n_struct
        if not rows:
            return sp.csr_matrix((n, n))
        K = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(n, n)).tocsr()
        K.sum_duplicates()
        return K

    @cached_property
    def mass(self) -> np.ndarray:
        """Diagonal of the lumped mass matrix (n_struct,), kg and kg m^2."""
        m = np.zeros(self.n_struct)
        xyz = {n.id: np.asarray(n.xyz, float) for n in self.nodes}
        for b in self.beams:
            if b.rho:
                half = 0.5 * b.rho * b.A * np.linalg.norm(xyz[b.nodes[1]] - xyz[b.nodes[0]])
                for nid in b.nodes:
                    m[self.dofs(nid)[:3]] += half
        for ms in self.masses:
            d = self.dofs(ms.node)
            m[d[:3]] += ms.m
            m[d[3:]] += np.asarray(ms.inertia, float)
        d = self.raft_dofs
        m[d[:3]] += self.raft.m
        m[d[3:]] += np.asarray(self.raft.inertia, float)
        return m

    @cached_property
    def influence(self) -> np.ndarray:
        """r (n_struct, 3): DOF motion per unit ground displacement in x, y, z."""
        r = np.zeros((self.n_struct, 3))
        for k in range(len(self.nodes)):
            r[6 * k + np.arange(3), np.arange(3)] = 1.0
        return r

    @cached_property
    def rigid_transform(self) -> np.ndarray:
        """T (n_struct, 6): displacement of every structural DOF for a unit rigid-body motion
        q of the raft (about the raft centre)."""
        c = np.asarray(self.node(self.raft.node).xyz, float)
        T = np.zeros((self.n_struct, 6))
        for n in self.nodes:
            x, y, z = np.asarray(n.xyz, float) - c
            d = self.dofs(n.id)
            T[d, :] = np.array([[1, 0, 0, 0, z, -y], [0, 1, 0, -z, 0, x], [0, 0, 1, y, -x, 0],
                                [0, 0, 0, 1, 0, 0], [0, 0, 0, 0, 1, 0], [0, 0, 0, 0, 0, 1]])
        return T

    def gravity_load(self) -> np.ndarray:
        """Self-weight (n_struct,), N: -g times the translational z mass."""
        f = np.zeros(self.n_struct)
        f[2::6] = -G_ACC * self.mass[2::6]
        return f

    @property
    def total_mass(self) -> float:
        return float(self.mass[0::6].sum())

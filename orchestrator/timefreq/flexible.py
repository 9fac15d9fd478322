"""A plate raft (``structure.plate_raft.PlateRaftModel``) condensed on its raft coordinates per
frequency, for the frequency-domain routes.

The rigid raft's contact coordinates x = [q, w] -> [q, d], d = Bq q - w, P = [I; Bq]
(``operator``) become, for a plate, r = [q, t] (6 + nf: the raft master's rigid DOFs and the
deflections of the plate's free vertices) and d = B r - w, B = [C_held Bq | C_free] (N, 6 + nf)
the plate's trace at the interface nodes (``PlateRaftModel.boundary_trace`` without its -I on
w), P = [[I, 0]; B]. The structure on r, exactly (the stepper's own equations: the global
layout's K, diagonal M and C = Ps^T C_stick Ps):

    A_r(s) = [A_q^stick(s) on q] + Kc + s^2 M_r + s^2 W diag(1 / (lam_j (lam_j + s^2))) W^T
    b(s)   = [b^stick(s) on q] - M_r r_r

- the sticks on q (their interior condensed with all their fixed-base modes, ``ModalStructure``
  of the stick model, whose raft master carries no mass: the plate is the raft's mass);
- the plate's rotations θ of its free vertices (rotary inertia J, no damping, coupled to r
  only through the plate's stiffness) condensed exactly: Z_θθ^-1 = K_θθ^-1 - s^2 V diag(1 /
  (lam (lam + s^2))) V^T from K_θθ V = J V diag(lam), V^T J V = I, so Kc = K_rr - K_rθ
  K_θθ^-1 K_θr (the plate's static stiffness on r, a direct solve) and W = K_rθ V;
- the plate's lumped masses on r, M_r (the in-plane q, the held region on uz, rx, ry, the free
  vertices' w), loaded by the ground acceleration through the influence r_r.

The plate's cost per frequency is (6 + nf)^2 x 2 nf: a small raft's (a few seconds at 60
vertices and 1000 frequencies), not the reactor's 276-vertex plate.
"""
from __future__ import annotations

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from structure.plate import plate_stiffness
from structure.preload import solve_static_system
from structure.plate_raft import PlateRaftModel

from orchestrator.timefreq.operator import ModalStructure

#: the least padding, s, of a plate raft's grid (its default pad_s: the sticks' decay rule gives
#: ~1.2 s): the plate's parts that lift ring with no damping but the structure's, and their
#: wrap-around kept the march from converging on the 49-node test plate (1.16 s: stalled at a
#: residual of 4e-6; 2 s: converged, max uplift -0.21 % off the monolithic route; 3 s: +0.03 %;
#: 4 s: 3e-6, one sweep)
PLATE_PAD_S = 4.0


def is_plate(model) -> bool:
    """The model is a plate raft (its raft coordinates are [q, t], not q alone)."""
    return isinstance(model, PlateRaftModel)


def structure_of(model, damping=None):
    """The structure's condensation on its raft coordinates: ModalStructure (a rigid raft, on
    q) or PlateStructure (a plate raft, on [q, t])."""
    return PlateStructure(model, damping) if is_plate(model) else ModalStructure(model, damping)


class PlateStructure:
    """ModalStructure's interface for a PlateRaftModel (module notes): ``blocks(s)`` on r = [q,
    t], ``node_response`` of the sticks' nodes, ``decay_rates`` (the sticks'), ``trace`` B (N,
    6 + nf) dense, ``vertex_trace`` (m, 6 + nf) the vertex deflections from r."""

    def __init__(self, pm: PlateRaftModel, damping=None):
        self.model = pm
        self.sticks = ModalStructure(pm.stick, damping)
        ns6, nf = pm.ns_struct - 6, pm.nf
        th = ns6 + np.arange(2 * nf)                                   # the free vertices' θx, θy
        r = pm.ni + np.arange(6 + nf)                                  # [q, t]
        self.nr = r.size
        p = pm.plate
        G = pm.plate_map
        Kg = (G.T @ plate_stiffness(pm.points, pm.cells, p.E, p.thickness, p.nu) @ G).tocsr()
        Krr = Kg[r][:, r].toarray()
        Krt = Kg[r][:, th].toarray()
        Ktt = Kg[th][:, th]
        M_stick = pm.stick_map.T @ pm.stick.mass
        J = pm.mass[th]
        self.Mr = pm.mass[r] - M_stick[r]                              # the plate's masses on r
        self.load = -(self.Mr[:, None] * pm.influence[r])              # (nr, 3)
        if th.size:
            X = spla.splu(Ktt.tocsc()).solve(Krt.T)
            self.Kc = Krr - Krt @ X
            if np.all(J > 0):
                lam, V = sla.eigh(Ktt.toarray(), np.diag(J))
                self.lam, self.W = lam, Krt @ V
            else:                                                      # massless rotations: static
                self.lam, self.W = np.ones(0), np.zeros((r.size, 0))
        else:
            self.Kc, self.lam, self.W = Krr, np.ones(0), np.zeros((r.size, 0))
        self.Kc = 0.5 * (self.Kc + self.Kc.T)
        self.trace = pm.boundary_trace[:, :self.nr].toarray()
        self.vertex_trace = pm.vertex_map[:, r].toarray()

    @property
    def decay_rates(self) -> np.ndarray:
        return self.sticks.decay_rates

    def blocks(self, s):
        """A_r (F, nr, nr) and b (F, nr, 3) at the Laplace variables s (F,)."""
        s2 = s * s
        Aq, bq = self.sticks.blocks(s)
        F = s.size
        A = np.empty((F, self.nr, self.nr), complex)
        A[:] = self.Kc
        A += s2[:, None, None] * np.diag(self.Mr)
        if self.lam.size:
            # sum_j W_ij g_j(s) W_kj for every s as one real GEMM: (W (x) W) (nr^2, n_θ) times
            # g's real and imaginary parts (n_θ, F), 128 frequencies at a time
            nr = self.nr
            WW = (self.W[:, None, :] * self.W[None, :, :]).reshape(nr * nr, -1)
            for c in range(0, F, 128):
                j = slice(c, c + 128)
                g = s2[j, None] / (self.lam * (self.lam + s2[j, None]))  # (f, n_θ)
                A[j].real += (WW @ g.real.T).T.reshape(-1, nr, nr)
                A[j].imag += (WW @ g.imag.T).T.reshape(-1, nr, nr)
        A[:, :6, :6] += Aq
        b = np.empty((F, self.nr, 3), complex)
        b[:] = self.load
        b[:, :6] += bq
        return A, b

    def node_response(self, dofs, s, r, ag):
        """Relative displacement (3, F) at the sticks' DOFs ``dofs`` (the stick model's
        numbering) for the raft coordinates r (nr, F) and ground acceleration ag (3, F)."""
        return self.sticks.node_response(dofs, s, r[:6], ag)


def plate_static(pm: PlateRaftModel, K0, kp, unilateral: bool = True):
    """The plate's static preload on the soil's static stiffness K0 (6 + N, 6 + N) on [q, w]:
    the PlateStepper's own (its K on the global layout, gravity, d = B u, penalty kp)."""
    N, ni = pm.n_interface, pm.ni
    sel = np.concatenate([np.arange(6), 6 + pm.nf + np.arange(N)])
    S = sp.csr_matrix((np.ones(6 + N), (np.arange(6 + N), ni + sel)), shape=(6 + N, pm.n_dof))
    K = (pm.stiffness + S.T @ sp.csr_matrix(K0) @ S).tocsr()
    return solve_static_system(K, pm.gravity_load(), pm.interface_operator, kp, int(pm.i_q[2]),
                               unilateral=unilateral)

"""The structure-soil system condensed on the contact: d -> contact force, per frequency.

Unknowns in the frequency domain (Laplace variable s, see tf_grid): raft q (6), soil w (N),
and the fixed-base modal coordinates eta of the structure. The structure is condensed on q
exactly with *all* its fixed-base modes (massless DOFs are condensed statically in the modes,
exact for the lumped masses; the damping must be diagonal in the modes: modal or Rayleigh):

    u_struct = T q + Phi eta,   (s^2 + c_j s + w_j^2) eta_j = -L_j (a_g + s^2 q)   (L = Phi^T M T)
    A_q(s) q = s^2 M_T q - s^4 L^T D^-1 L q,    load b(s) a_g = -(M_T - s^2 L^T D^-1 L)[:, :3] a_g

In the contact coordinates x = [q, w] -> [q, d], d = Bq q - w (raft vertical trace minus soil
w, the contact's relative displacement), with P = [I; Bq] and the soil K(s) on [q, w]:

    Z_qq q - Vl d = b a_g,       -Vr q + K_ww d = p
    Z_qq = A_q + P^T K P,  Vr = K[w, :] P,  Vl = P^T K[:, w]

so the contact force p (dynamic, on the raft +Bq^T p, on the soil -p) and d satisfy
p = S d - f with the interface dynamic stiffness S = K_ww - Vr Z_qq^-1 Vl (N x N) and the
blocked force f = Vr Z_qq^-1 b a_g. Z_qq is the raft bonded to the soil (regular at s -> 0);
S is applied as K_ww (the soil's bands) minus a rank-6 term; it is never formed for all N.
"""
from __future__ import annotations

import numpy as np

from structure import damping_matrix, fixed_base_modes


class ModalStructure:
    """Fixed-base modal data of a StructureModel: w (m,) rad/s, c (m,) 1/s (= 2 xi w), Phi
    (n_struct, m), L (m, 6), M_T (6, 6) rigid-body mass about the raft centre."""

    def __init__(self, model, damping=None):
        modes = fixed_base_modes(model)
        Phi = modes.shapes
        C = damping_matrix(model, damping)
        Cm = Phi.T @ C @ Phi
        c = np.diag(Cm).copy()
        off = np.abs(Cm - np.diag(c)).max() if c.size else 0.0
        if off > 1e-8 * max(np.abs(c).max(), 1e-30):
            raise ValueError("the structural damping is not diagonal in the fixed-base modes (an explicit "
                             "damping matrix?): the frequency-domain routes need modal or Rayleigh damping")
        T = model.rigid_transform
        KT = model.stiffness @ T
        if np.abs(KT).max() > 1e-9 * max(abs(model.stiffness).max(), 1.0):
            raise ValueError("the structure has springs to the ground (K T != 0): the frequency-domain "
                             "condensation assumes the structure is supported by the raft only")
        m = model.mass
        self.w = modes.omega
        self.c = c
        self.Phi = Phi
        self.T = T
        self.L = Phi.T @ (m[:, None] * T)
        self.MT = T.T @ (m[:, None] * T)

    @property
    def decay_rates(self) -> np.ndarray:
        return 0.5 * self.c

    def blocks(self, s):
        """A_q (F, 6, 6) and b (F, 6, 3) at the Laplace variables s (F,)."""
        s2 = s * s
        Dinv = 1.0 / (s2[:, None] + self.c * s[:, None] + self.w**2)        # (F, m)
        LL = np.einsum("fj,ja,jb->fab", Dinv, self.L, self.L)               # (F, 6, 6)
        A = s2[:, None, None] * self.MT - (s2 * s2)[:, None, None] * LL
        b = -(self.MT[:, :3] - s2[:, None, None] * LL[:, :, :3])
        return A, b

    def node_response(self, dofs, s, q, ag):
        """Relative displacement (3, F) at the global DOFs ``dofs`` (3,) for raft q (6, F) and
        ground acceleration ag (3, F)."""
        s2 = s * s
        Dinv = 1.0 / (s2[:, None] + self.c * s[:, None] + self.w**2)        # (F, m)
        force = self.L[:, :3] @ ag + self.L @ (s2[None, :] * q)             # (m, F)
        eta = -Dinv.T * force
        return self.T[dofs] @ q + self.Phi[dofs] @ eta


class InterfaceOperator:
    """S(s), f(s) and the back-substitution of the condensed system on one Grid.

    Parameters
    ----------
    model : StructureModel
    soil : SoilBands                 K(s) on [q, w] (tf_soil.soil_bands)
    grid : Grid
    damping : None | float | Damping structural damping (see structure.damping_matrix)
    """

    def __init__(self, model, soil, grid, damping=None, structure: ModalStructure | None = None):
        if soil.n != 6 + model.n_interface:
            raise ValueError(f"the soil has {soil.n} DOFs, the raft needs 6 + N = {6 + model.n_interface}")
        self.model, self.soil, self.grid = model, soil, grid
        self.st = structure or ModalStructure(model, damping)
        self.N = model.n_interface
        s = grid.s
        self.s = s
        Bq = model.raft.vertical_trace()
        self.Bq = Bq
        F = s.size
        A, b = self.st.blocks(s)
        self.b = b
        self.Vr = np.empty((F, self.N, 6), complex)
        self.Vl = np.empty((F, 6, self.N), complex)
        Zqq = A.copy()
        for band in soil.bands:
            Vr, Vl, KPP = band.rows_P(s[band.idx], Bq)
            self.Vr[band.idx], self.Vl[band.idx] = Vr, Vl
            Zqq[band.idx] += KPP
        self.Zinv = np.linalg.inv(Zqq)
        self.n_apply = 0

    # ---- the interface stiffness -----------------------------------------------------------
    def apply_S(self, X):
        """X (N, F) complex -> S X (N, F)."""
        self.n_apply += 1
        Xf = np.ascontiguousarray(X.T)[:, :, None]                          # (F, N, 1)
        Y = np.empty_like(Xf)
        for band in self.soil.bands:
            Y[band.idx] = band.apply_ww(Xf[band.idx], self.s[band.idx])
        t = self.Zinv @ (self.Vl @ Xf)                                     # (F, 6, 1)
        Y -= self.Vr @ t
        return Y[:, :, 0].T

    def S_sub(self, rows, cols):
        """S[rows, cols] (F, m_r, m_c)."""
        F = self.s.size
        out = np.empty((F, rows.size, cols.size), complex)
        for band in self.soil.bands:
            out[band.idx] = band.sub_ww(rows, cols, self.s[band.idx])
        out -= self.Vr[:, rows] @ (self.Zinv @ self.Vl[:, :, cols])
        return out

    def blocked_force(self, ag_hat):
        """f (N, F) for ground acceleration ag_hat (3, F)."""
        t = self.Zinv @ (self.b @ ag_hat.T[:, :, None])
        return (self.Vr @ t)[:, :, 0].T

    def raft(self, ag_hat, d_hat):
        """q (6, F) from the ground motion (3, F) and the contact displacement d (N, F)."""
        rhs = self.b @ ag_hat.T[:, :, None] + self.Vl @ np.ascontiguousarray(d_hat.T)[:, :, None]
        return (self.Zinv @ rhs)[:, :, 0].T

"""The one soil interface every soil model implements (Winkler, recursive convolution, FMU).

Interface DOFs x = [q, w], n = 6 + N: q the raft rigid-body DOFs (ux, uy, uz, rx, ry, rz
about the raft centre), w the soil vertical displacement under each of the N interface
nodes (massless, algebraic rows). The force applied TO the soil at step n is

    f_n = K0 x_n + C0 xdot_n + h_n        (the foundation receives -f_n)

with (K0, C0) the instantaneous matrices for the step size dt and h_n a history force that
depends only on the past (zero for a memoryless soil).

Contract (what a stepper does with a soil, per step t_n -> t_{n+1}):
  1. ``instantaneous(dt)`` -> (K0, C0), dense or sparse (n, n); called once per distinct dt
     (also for sub-steps: a soil that supports sub-stepping takes its current step size
     from the last call);
  2. ``history()`` -> h (n,) for the step being solved, N;
  3. after the step is accepted, ``commit(x, xdot)`` with the converged x_{n+1}, xdot_{n+1}.
  ``get_state()`` / ``set_state(s)`` save and restore everything ``commit`` changes (copies
  of numpy arrays), for step rejection and FMU rollback. ``static_stiffness()`` is K(omega=0),
  used by the static preload.
"""
from __future__ import annotations

from functools import cached_property

import numpy as np
from uplift_common.lazy import lazy_module

from .errors import StructureError

# scipy loads on first use (uplift_common.lazy): a warm run reads what it would compute
sp = lazy_module("scipy.sparse")


class SoilInterface:
    """Base class: a memoryless soil with h = 0 unless a subclass says otherwise."""

    n_dof: int

    def instantaneous(self, dt: float):
        raise NotImplementedError

    def history(self) -> np.ndarray:
        return np.zeros(self.n_dof)

    def commit(self, x: np.ndarray, xdot: np.ndarray) -> None:
        pass

    def static_stiffness(self):
        raise NotImplementedError

    def get_state(self) -> dict:
        return {}

    def set_state(self, state: dict) -> None:
        pass


def _positive(name, a, n):
    a = np.broadcast_to(np.asarray(a, float), (n,)).copy()
    bad = np.flatnonzero(~np.isfinite(a) | (a < 0))
    if bad.size:
        raise StructureError(f"{name}[{bad[0]}] = {a[bad[0]]!r} must be >= 0")
    return a


class WinklerSoil(SoilInterface):
    """Independent springs and dashpots under each interface node.

    kv, cv : (N,) N/m, N s/m      vertical, on w_i to ground
    kx, ky, cx, cy : (N,)          horizontal, on the raft horizontal trace at node i,
                                   (ux - rz y_i, uy + rz x_i) to ground
    xy : (N, 2) m                  node coordinates about the raft centre
    h = 0; K0 and C0 are sparse (6+N, 6+N).
    """

    def __init__(self, xy, kv, kh=0.0, cv=0.0, ch=0.0, ky=None, cy=None):
        xy = np.asarray(xy, float)
        n = xy.shape[0]
        self.xy = xy
        self.kv = _positive("kv", kv, n)
        self.kx = _positive("kh", kh, n)
        self.ky = self.kx.copy() if ky is None else _positive("ky", ky, n)
        self.cv = _positive("cv", cv, n)
        self.cx = _positive("ch", ch, n)
        self.cy = self.cx.copy() if cy is None else _positive("cy", cy, n)
        self.n_dof = 6 + n
        self._dt = None

    @cached_property
    def _K(self):
        """The stiffness matrix, assembled on first use (a warm run's checks read their answers)."""
        return self._assemble(self.kv, self.kx, self.ky)

    @cached_property
    def _C(self):
        return self._assemble(self.cv, self.cx, self.cy)

    def _assemble(self, v, hx, hy):
        x, y = self.xy[:, 0], self.xy[:, 1]
        # horizontal traces: tx = ux - rz y (dofs 0, 5), ty = uy + rz x (dofs 1, 5)
        Kq = np.zeros((6, 6))
        Kq[0, 0] = hx.sum()
        Kq[0, 5] = Kq[5, 0] = -(hx * y).sum()
        Kq[1, 1] = hy.sum()
        Kq[1, 5] = Kq[5, 1] = (hy * x).sum()
        Kq[5, 5] = (hx * y**2).sum() + (hy * x**2).sum()
        return sp.block_diag([sp.csr_matrix(Kq), sp.diags(v)], format="csr")

    def instantaneous(self, dt: float):
        self._dt = dt
        return self._K, self._C

    def static_stiffness(self):
        return self._K

    def rigid_stiffness(self) -> np.ndarray:
        """6x6 raft stiffness of the springs with w bonded to the raft (w = vertical trace)."""
        return _rigid(self._K, self.xy)

    def rigid_damping(self) -> np.ndarray:
        return _rigid(self._C, self.xy)


def _rigid(K, xy):
    n = xy.shape[0]
    Bx = np.zeros((6 + n, 6))
    Bx[:6] = np.eye(6)
    Bx[6:, 2] = 1.0
    Bx[6:, 3] = xy[:, 1]
    Bx[6:, 4] = -xy[:, 0]
    return Bx.T @ (K @ Bx)

"""A test double of the recursive-convolution soil: K(s) = D + s E + sum_k R_k / (s - p_k)
discretised by the trapezoidal rule (consistent with average-acceleration Newmark), with a
nonzero history force. Implements the soil protocol of structure.soil_interface, built as
``TrapezoidRationalSoil(model, dt)`` like the real RecursiveConvolutionSoil.

Per pole, z_k' = p_k z_k + x; trapezoid: z_{n+1} = a_k z_n + b_k (x_{n+1} + x_n),
a = (1 + p dt/2)/(1 - p dt/2), b = (dt/2)/(1 - p dt/2). The force on the soil
f = D x + E xdot + Re sum R_k z_k = K0 x_{n+1} + C0 xdot_{n+1} + h_n with
K0 = D + Re sum b_k R_k, C0 = E, h_n = Re sum R_k (a_k z_n + b_k x_n).
"""
import numpy as np
import scipy.sparse as sp

from soil_impedance.rational import RationalModel


class TrapezoidRationalSoil:
    def __init__(self, model: RationalModel, dt: float):
        self.model = model
        self.n_dof = model.n
        self.p, self.R = np.asarray(model.poles), np.asarray(model.residues)
        self.z = np.zeros((self.p.size, self.n_dof), complex)
        self.x = np.zeros(self.n_dof)
        self.xd = np.zeros(self.n_dof)
        self.work = 0.0
        self.instantaneous(dt)

    def instantaneous(self, dt):
        self.dt = dt
        den = 1 - self.p * dt / 2
        self.a, self.b = (1 + self.p * dt / 2) / den, (dt / 2) / den
        K0 = self.model.D + np.real(np.einsum("k,kij->ij", self.b, self.R))
        return K0, self.model.E

    def history(self):
        zz = self.a[:, None] * self.z + self.b[:, None] * self.x[None, :]
        return np.real(np.einsum("kij,kj->i", self.R, zz))

    def total_force(self):
        return self.model.D @ self.x + self.model.E @ self.xd + np.real(np.einsum("kij,kj->i", self.R, self.z))

    def commit(self, x, xdot):
        f_old = self.total_force()
        self.z = self.a[:, None] * self.z + self.b[:, None] * (x + self.x)[None, :]
        dx = x - self.x
        self.x, self.xd = np.array(x, float), np.array(xdot, float)
        self.work += dx @ (0.5 * (f_old + self.total_force()))

    def dissipated_energy(self):
        return self.work            # work done on the soil (a test double: no stored-energy split)

    def static_stiffness(self):
        return self.model.D - np.real(np.einsum("k,kij->ij", 1 / self.p, self.R))

    def get_state(self):
        return {"z": self.z.copy(), "x": self.x.copy(), "xd": self.xd.copy(), "work": self.work}

    def set_state(self, s):
        self.z, self.x, self.xd = np.array(s["z"]), np.array(s["x"]), np.array(s["xd"])
        self.work = float(s["work"])


def winkler_rational(winkler, poles=(-30.0, -150.0), ratios=(0.3, 0.2), dashpot_scale=1.0):
    """A passive rational model on a Winkler soil's matrices:
    K(s) = K_w (1 + sum_k r_k s / (s - p_k)) + s C_w, real poles p_k < 0, r_k > 0
    (s/(s-p) = 1 + p/(s-p): D = K_w (1 + sum r_k), R_k = r_k p_k K_w)."""
    Kw, Cw = (m.toarray() if sp.issparse(m) else np.asarray(m) for m in winkler.instantaneous(1.0))
    p = np.asarray(poles, complex)
    r = np.asarray(ratios, float)
    D = Kw * (1 + r.sum())
    R = np.array([rk * pk.real * Kw for rk, pk in zip(r, p)], complex)
    n = Kw.shape[0]
    dofs = ["ux", "uy", "uz", "rx", "ry", "rz"] + [f"w{i}" for i in range(n - 6)]
    return RationalModel(p, R, D, dashpot_scale * Cw, dofs, {"source": "tests/soil_double.winkler_rational"})

"""The soil interface protocol: a soil with a history force and dense K0 plugs in unchanged.

TrapezoidalDashpotSoil expresses Winkler springs and dashpots through the history channel,
as a recursive-convolution soil will: with the trapezoidal rule xdot_{n+1} = 2/dt (x_{n+1} -
x_n) - xdot_n (which is what average-acceleration Newmark uses), f = K x + C xdot becomes
f_{n+1} = (K + 2C/dt) x_{n+1} + h, h = -C (2 x_n / dt + xdot_n), C0 = 0. The stepper must
reproduce the WinklerSoil run to round-off, with contact switching and sub-stepping.
"""
import numpy as np

from structure import ContactSettings, SoilInterface, WinklerSoil, simulate
from structure.broadband import broadband_accelerogram
from helpers import FINE_RAFT

MODEL, soil = FINE_RAFT.model, FINE_RAFT.soil


class TrapezoidalDashpotSoil(SoilInterface):
    def __init__(self, winkler: WinklerSoil):
        K, C = winkler.instantaneous(1.0)
        self.K, self.C = K.toarray(), C.toarray()       # dense, like a convolution soil
        self.n_dof = self.K.shape[0]
        self.x = np.zeros(self.n_dof)
        self.xd = np.zeros(self.n_dof)
        self.dt = None

    def instantaneous(self, dt):
        self.dt = dt
        return self.K + 2 * self.C / dt, np.zeros_like(self.K)

    def history(self):
        return -self.C @ (2 * self.x / self.dt + self.xd)

    def commit(self, x, xdot):
        # xdot from the stepper is Newmark's; for C0 = 0 rows the trapezoidal rate is the same
        self.xd = 2 * (x - self.x) / self.dt - self.xd
        self.x = x.copy()

    def static_stiffness(self):
        return self.K

    def get_state(self):
        return {"x": self.x.copy(), "xd": self.xd.copy()}

    def set_state(self, s):
        self.x, self.xd = s["x"].copy(), s["xd"].copy()


def test_history_soil_reproduces_winkler_dashpots_with_uplift():
    dt = 0.005
    ag = np.zeros((801, 3))
    ag[:, 0] = broadband_accelerogram(4.0, dt, 0.8 * 9.81, seed=7)
    w = soil(damped=True)
    r_ref = simulate(MODEL, w, ag, dt)
    r_hist = simulate(MODEL, TrapezoidalDashpotSoil(w), ag, dt)
    assert r_ref.max_uplift() > 1e-3
    scale = np.abs(r_ref.raft).max(axis=0)
    assert np.all(np.abs(r_hist.raft - r_ref.raft).max(axis=0) <= 1e-7 * scale + 1e-15)
    assert np.abs(r_hist.gap - r_ref.gap).max() <= 1e-7 * r_ref.gap.max()
    e = r_hist.energy
    lhs = e["kinetic"] + e["strain"] + e["damping"] + e["soil"] + e["contact"]
    assert np.abs(e["input"] - lhs).max() < 1e-6 * e["input"].max()


def test_history_soil_with_forced_substeps():
    """Sub-stepping calls instantaneous(dt/2^k): the history soil follows the step size."""
    dt = 0.005
    ag = np.zeros((401, 3))
    ag[:, 0] = broadband_accelerogram(2.0, dt, 1.5 * 9.81, seed=7)
    w = soil(damped=True)
    few = ContactSettings(max_iter=2, max_subdiv=8)     # forces halvings at contact changes
    r_ref = simulate(MODEL, w, ag, dt, contact=few)
    r_hist = simulate(MODEL, TrapezoidalDashpotSoil(w), ag, dt, contact=few)
    assert r_ref.info["subdivided_steps"] > 0             # some steps were subdivided
    scale = np.abs(r_ref.raft).max()
    assert np.abs(r_hist.raft - r_ref.raft).max() <= 1e-6 * scale

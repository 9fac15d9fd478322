"""The structure FMU: ``structure.NewmarkStepper`` (Newmark + penalty contact + Newton) with the
soil's instantaneous matrices folded in and the soil's history force completed from its input.

Variables: the outputs and the inputs ag_x, ag_y, ag_z of fmus/stepper.py, and (n = 6 + N)

  inputs   g[0..n-1]   N, N.m  the soil FMU's output g: its history force for this structure step
                           without the part driven by the structure's latest state
           g_time      s   the soil FMU's output g_time (start of the step g is meant for)
  outputs  x_time      s   time of x (= t): connect to the soil FMU's input x_time

A step from t takes g of t (now, or held from the previous step: fmus.coupling.StampedInput)
and the history force h = g + Gx x(t) + Gv xdot(t) with the soil's gains computed at export,
folds the soil's (K0, C0) into the implicit matrix and solves the step. This is the monolithic
route's step to round-off, under Jacobi and under Gauss-Seidel in either order.
"""
from __future__ import annotations

import numpy as np
from pythonfmu import Fmi2Slave

from fmus.real_variables import RealBank, register_schema
from fmus.coupling import StampedInput
from fmus.resources import SOIL_INSTANT_FILE, make_soil, read_settings
from fmus.slave import BankedSlave
from fmus.stepper import StepperOutputs


class InstantaneousSoil:
    """The soil as the structure sees it with an external history: (K0, C0) at the FMU's dt,
    K(0) and the history gains, read from resources. Another step size (Newton sub-stepping)
    builds the soil object itself once, lazily, and asks it."""

    def __init__(self, resources, settings):
        self.resources, self.settings = resources, settings
        with np.load(f"{resources}/{SOIL_INSTANT_FILE}", allow_pickle=False) as z:
            self.K0, self.C0, self.K_static, self.dt = z["K0"], z["C0"], z["K_static"], float(z["dt"])
            self.Gx, self.Gv = z["Gx"], z["Gv"]
        self.n_dof = self.K0.shape[0]
        self._soil = None

    def instantaneous(self, dt):
        if dt == self.dt:
            return self.K0, self.C0
        if self._soil is None:
            self._soil = make_soil(self.resources, self.settings)
        return self._soil.instantaneous(dt)

    def static_stiffness(self):
        return self.K_static


class UpliftStructure(StepperOutputs, BankedSlave, Fmi2Slave):
    author = "uplift"
    description = "Stick-and-raft structure with unilateral (penalty) contact, Newmark-Newton"
    inputs = ("g", "g_time", "ag")

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.settings = s = read_settings(self.resources, "structure")
        self._init_life_cycle(s["dt"])
        n = int(s["n_dof"])
        self.bank = RealBank()
        self.sl = register_schema(self, "structure", n, int(s["n_interface"]), s["output_nodes"])
        self._register_stepper(s)
        self.stamped = {"g": StampedInput("g", "g_time", np.zeros(n))}

    def _build(self):
        self.soil = InstantaneousSoil(self.resources, self.settings)
        self._build_stepper(self.soil, external_soil=True)

    def _publish(self):
        super()._publish()
        self.bank.values[self.sl["x_time"]] = self.stepper.t

    def _step(self, t):
        st, v, soil = self.stepper, self.bank.values, self.soil
        g = self.stamped["g"].take(t, self.dt, v[self.sl["g_time"]][0], v[self.sl["g"]])
        st.set_ground_acceleration(self._ag_next(t))
        st.set_soil_history(g + soil.Gx @ st.x + soil.Gv @ st.xdot)
        v[self.sl["newton_iters"]] = st.step()
        self._publish()

"""The soil FMU: a soil object of the protocol in structure.soil_interface (by default the
recursive convolution of the fitted rational model) built from resources/.

Variables (n = 6 + N interface DOFs; SI units)

  (the variables of fmus/schema.py, role "soil")
  inputs   x[0..n-1]     m, rad       interface displacements: the structure's output x
           xdot[0..n-1]  m/s, rad/s   interface velocities: the structure's output xdot
           x_time        s            the structure's time of x (its output x_time)
  outputs  g[0..n-1]     N    the soil's history force for the structure's next step without
                              the part driven by the structure's latest state (the structure
                              adds Gx x + Gv xdot itself): depends on the soil's past only
           g_time        s    start time of the structure step g is meant for
           f[0..n-1]     N, N.m  total force on the soil at the last committed state (at g_time − dt)
           dissipated_energy  J   energy dissipated in the soil so far (NaN if the soil
                              object does not report it)

A step from t commits the interface state of t (taken now or held from the previous step, see
fmus.coupling.StampedInput) and publishes g for the structure step from t + dt. At t = 0 the
soil is at rest: nothing to commit, g = 0 for the step from 0. Exact under Jacobi and under
Gauss-Seidel in either order.
"""
from __future__ import annotations

import numpy as np
from pythonfmu import Fmi2Slave

from fmus.real_variables import RealBank, register_schema
from fmus.coupling import StampedInput, history_ahead
from fmus.resources import make_soil, read_settings
from fmus.slave import BankedSlave


class UpliftSoil(BankedSlave, Fmi2Slave):
    author = "uplift"
    description = "Frequency-dependent soil: recursive convolution of a rational impedance model"
    engine = "soil"
    inputs = ("x", "xdot", "x_time")

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.settings = read_settings(self.resources, "soil")
        self._init_life_cycle(self.settings["dt"])
        n = int(self.settings["n_dof"])
        self.bank = RealBank()
        self.sl = register_schema(self, "soil", n, n - 6)
        self.stamped = {"x": StampedInput("x, xdot", "x_time", np.zeros(2 * n))}
        self.soil = None

    def _build(self):
        self.soil = make_soil(self.resources, self.settings)
        self.soil.instantaneous(self.dt)
        self._publish(np.zeros(self.soil.n_dof), 0.0)

    def _publish(self, g, t_next):
        v, sl, soil = self.bank.values, self.sl, self.soil
        v[sl["g"]] = g
        v[sl["g_time"]] = t_next
        v[sl["f"]] = soil.total_force() if hasattr(soil, "total_force") else np.nan
        v[sl["dissipated_energy"]] = soil.dissipated_energy() if hasattr(soil, "dissipated_energy") else np.nan

    def _step(self, t):
        v, sl, n = self.bank.values, self.sl, self.soil.n_dof
        state = self.stamped["x"].take(t, self.dt, v[sl["x_time"]][0], v[sl["x"].start:sl["xdot"].stop])
        if t > 0.5 * self.dt:                   # at t = 0 the soil is at rest: nothing to commit
            self.soil.commit(state[:n].copy(), state[n:].copy())
        self._publish(history_ahead(self.soil), t + self.dt)

    def _engine_state(self):
        return self.soil.get_state()

    def _restore_engine(self, state):
        self.soil.set_state(state)

"""The soil FMU: a soil object of the protocol in structure.soil_interface (by default the
recursive convolution of the fitted rational model) built from resources/.

Variables (n = 6 + N interface DOFs; SI units)

  inputs   x[0..n-1]     m, rad     interface displacements at the end of the step being taken
           xdot[0..n-1]  m/s, rad/s (Gauss-Seidel: the structure's outputs at t + dt)
  outputs  h[0..n-1]     N   history force for the NEXT structure step (depends on the past only)
           f[0..n-1]     N   total force on the soil at the last committed state
                             f = K0 x + C0 xdot + h (plain total-force coupling reads this)
           dissipated_energy  J   energy dissipated in the soil so far (NaN if the soil
                             object does not report it)

A step commits (x, xdot) to the soil and publishes h for the next step; outputs at
initialisation are those of the soil at rest.
"""
from __future__ import annotations

import numpy as np
from pythonfmu import Fmi2Causality, Fmi2Slave

from fmus.common import (BankedSlave, RealBank, check_step, copy_state, make_soil, read_settings,
                         register_vector)


class UpliftSoil(BankedSlave, Fmi2Slave):
    author = "uplift"
    description = "Frequency-dependent soil: recursive convolution of a rational impedance model"
    engine = "soil"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.settings = read_settings(self.resources, "soil")
        self.dt = float(self.settings["dt"])
        n = int(self.settings["n_dof"])
        self.bank = RealBank()
        inp, out = Fmi2Causality.input, Fmi2Causality.output
        self.sl = {
            "x": register_vector(self, "x", n, inp, description="interface displacements, m / rad"),
            "xdot": register_vector(self, "xdot", n, inp, description="interface velocities"),
            "h": register_vector(self, "h", n, out, description="history force for the next step, N"),
            "f": register_vector(self, "f", n, out, description="total force on the soil, N"),
            "dissipated_energy": register_vector(self, "dissipated_energy", None, out,
                                                 description="energy dissipated in the soil, J"),
        }
        self.soil = None
        self.last_error = ""

    def _build(self):
        self.soil = make_soil(self.resources, self.settings)
        self.K0, self.C0 = self.soil.instantaneous(self.dt)
        self._publish(self.soil.history())

    def _publish(self, h_used):
        """Outputs after a commit: h for the next step, the total force of the state just
        committed (h_used: the history that entered that state)."""
        v, sl, soil = self.bank.values, self.sl, self.soil
        if hasattr(soil, "total_force"):
            v[sl["f"]] = soil.total_force()
        else:
            v[sl["f"]] = self.K0 @ v[sl["x"]] + self.C0 @ v[sl["xdot"]] + h_used
        v[sl["dissipated_energy"]] = soil.dissipated_energy() if hasattr(soil, "dissipated_energy") else np.nan
        v[sl["h"]] = soil.history()

    def _step(self, t, step_size):
        check_step(self.dt, step_size)
        v = self.bank.values
        h_used = v[self.sl["h"]].copy()
        self.soil.commit(v[self.sl["x"]].copy(), v[self.sl["xdot"]].copy())
        self._publish(h_used)

    def _get_fmu_state(self):
        state = {"bank": self.bank.values.copy()}
        if self.soil is not None:
            state["soil"] = copy_state(self.soil.get_state())
        return state

    def _set_fmu_state(self, state):
        self.bank.values[:] = state["bank"]
        if "soil" in state and self.soil is not None:
            self.soil.set_state(copy_state(state["soil"]))

"""What the structure FMU and the coupled FMU share: ``structure.NewmarkStepper`` built from
the resources, the ground motion (bundled or an input), and the outputs.

Outputs (n = 6 + N interface DOFs [q, w], N interface nodes; SI units)

  x[0..n-1]      m, rad      interface displacements [q, w] at t
  xdot[0..n-1]   m/s, rad/s
  P[0..N-1]      N           total compressive contact forces
  gap[0..N-1]    m           uplift
  acc_<node>[0..2] m/s2, disp_<node>[0..2] m   absolute acceleration, relative displacement
  energy.<term>  J           cumulative works and stored energies (see RouteResult)
  newton_iters   1           linear solves of the last step
  max_uplift     m           running maximum of gap over the nodes and the steps so far
  max_raft_rotation  rad     running maximum of hypot(rx, ry) of the raft

Input ``ag[0..2]`` (m/s2): the ground acceleration at the END of the coming step, a_g(t + dt)
(the scheme is implicit), read only when the parameter ``internal_motion`` is false; by
default the motion bundled in resources drives the FMU (after its last sample: zero).
Outputs are computed at initialisation (the static state) and after each step; none depends
on an input at the same communication point (no direct feedthrough).
"""
from __future__ import annotations

import numpy as np
from pythonfmu import Boolean, Fmi2Causality
from pythonfmu.enums import Fmi2Variability

from fmus.common import MESH_FILE, MOTION_FILE, interface_units, register_vector

ENERGY_TERMS = ("input", "kinetic", "strain", "damping", "soil", "contact", "contact_potential")


class StepperOutputs:
    """Mixin (with fmus.common.BankedSlave): registers ``ag`` and the outputs, builds the
    stepper from the resources with the soil the FMU gives it (``_soil``), publishes."""

    engine = "stepper"

    def _register_stepper(self, settings):
        n, N = int(settings["n_dof"]), int(settings["n_interface"])
        self.nodes = list(settings["output_nodes"])
        inp, out = Fmi2Causality.input, Fmi2Causality.output
        sl = self.sl
        sl["ag"] = register_vector(self, "ag", 3, inp, description="ground acceleration at t + dt", unit="m/s2")
        sl["x"] = register_vector(self, "x", n, out, description="interface displacements [q, w]",
                                  unit=interface_units(n, "m", "rad"))
        sl["xdot"] = register_vector(self, "xdot", n, out, description="interface velocities",
                                     unit=interface_units(n, "m/s", "rad/s"))
        sl["P"] = register_vector(self, "P", N, out, description="total contact forces", unit="N")
        sl["gap"] = register_vector(self, "gap", N, out, description="uplift", unit="m")
        for nm in self.nodes:
            sl[f"acc_{nm}"] = register_vector(self, f"acc_{nm}", 3, out,
                                              description=f"absolute acceleration of {nm}", unit="m/s2")
            sl[f"disp_{nm}"] = register_vector(self, f"disp_{nm}", 3, out, description=f"displacement of {nm}",
                                               unit="m")
        for term in ENERGY_TERMS:
            sl[f"energy.{term}"] = register_vector(self, f"energy.{term}", None, out,
                                                   description=f"energy term {term}", unit="J")
        sl["newton_iters"] = register_vector(self, "newton_iters", None, out,
                                             description="linear solves of the last step", unit="1")
        sl["max_uplift"] = register_vector(self, "max_uplift", None, out,
                                           description="running maximum of the uplift", unit="m")
        sl["max_raft_rotation"] = register_vector(self, "max_raft_rotation", None, out,
                                                  description="running maximum of the raft rotation", unit="rad")
        self.internal_motion = bool(settings.get("motion"))
        self.register_variable(Boolean("internal_motion", causality=Fmi2Causality.parameter,
                                       variability=Fmi2Variability.fixed,
                                       description="true: the ground motion bundled in resources; "
                                                   "false: the input ag"), nested=False)
        self.stepper = None

    def _build_stepper(self, soil, external_soil: bool):
        from structure import NewmarkStepper
        from structure.spec import contact_from_spec, model_from_spec

        s, res = self.settings, self.resources
        with np.load(f"{res}/{MESH_FILE}", allow_pickle=False) as z:
            xy, area = z["xy"], z["area"]
        self.motion = None
        if self.internal_motion:
            if not s.get("motion"):
                raise ValueError("internal_motion = true but this FMU was exported without a motion: "
                                 "set internal_motion = false and drive the input ag")
            with np.load(f"{res}/{MOTION_FILE}", allow_pickle=False) as z:
                self.motion = np.array(z["acc"], float)
        model = model_from_spec(s["structure"], xy, area)
        ag0 = self.motion[0] if self.internal_motion else self.bank.values[self.sl["ag"]]
        self.stepper = NewmarkStepper(model, soil, self.dt, contact=contact_from_spec(s["contact"]),
                                      damping=s.get("damping"), alpha=float(s.get("alpha", 0.0)),
                                      external_soil=external_soil, ag0=ag0)
        self._dofs = {nm: model.dofs(model.node_by_name(nm).id)[:3] for nm in self.nodes}
        v = self.bank.values
        v[self.sl["max_uplift"]] = v[self.sl["max_raft_rotation"]] = 0.0
        self._publish()

    def _ag_next(self, t):
        """a_g(t + dt): the bundled motion's sample, or the input ag."""
        if not self.internal_motion:
            return self.bank.values[self.sl["ag"]].copy()
        k = int(round(t / self.dt)) + 1
        return self.motion[k] if k < self.motion.shape[0] else np.zeros(3)

    def _publish(self):
        st, v, sl = self.stepper, self.bank.values, self.sl
        v[sl["x"]] = st.x
        v[sl["xdot"]] = st.xdot
        v[sl["P"]] = st.P
        gap = st.gap()
        v[sl["gap"]] = gap
        for nm, d in self._dofs.items():
            v[sl[f"acc_{nm}"]] = st.a[d] + st.ag
            v[sl[f"disp_{nm}"]] = st.u[d]
        for term, value in st.energies().items():
            v[sl[f"energy.{term}"]] = value
        q = st.x
        v[sl["max_uplift"]] = max(v[sl["max_uplift"]], float(gap.max()) if gap.size else 0.0)
        v[sl["max_raft_rotation"]] = max(v[sl["max_raft_rotation"]], float(np.hypot(q[3], q[4])))

    def _engine_state(self):
        st = self.stepper
        return {"stepper": st.get_state(), "ag_next": st._ag_next.copy(), "h_ext": st._h_ext.copy()}

    def _restore_engine(self, state):
        st = self.stepper
        st.set_state(state["stepper"])
        st._ag_next, st._h_ext = np.array(state["ag_next"]), np.array(state["h_ext"])

"""What the structure FMU and the coupled FMU share: ``structure.NewmarkStepper`` built from
the resources, the ground motion (bundled or an input), and the outputs.

Outputs (fmus/schema.py; n = 6 + N interface DOFs [q, w], N interface nodes; SI units)

  x[0..n-1]      m, rad      interface displacements [q, w] at t
  xdot[0..n-1]   m/s, rad/s
  P[0..N-1]      N           total compressive contact forces
  gap[0..N-1]    m           uplift
  acc_<node>[0..2] m/s2, disp_<node>[0..2] m   absolute acceleration, relative displacement
  energy.<term>  J           cumulative works and stored energies (see RouteResult)
  newton_iters   1           linear solves of the last step
  max_uplift     m           running maximum of gap over the nodes and the steps so far
  max_raft_rotation  rad     running maximum of hypot(rx, ry) of the raft

Inputs ``ag_x, ag_y, ag_z`` (m/s2, the slot ``ag``): the ground acceleration along x, y, z at
the END of the coming step, a_g(t + dt) (the scheme is implicit), read only when the parameter
``internal_motion`` is false; by default the motion bundled in resources (every component of
the scene's motion) drives the FMU (after its last sample: zero).
A plate raft (the settings' "plate", the plate's mesh in the mesh file: fmus.build.plate_arrays)
is stepped by ``structure.plate_raft.PlateStepper``: the same variables (x, xdot are the soil's
DOFs [q, w]; acc_/disp_ of the sticks' nodes), the plate's own deflections are not outputs.
Outputs are computed at initialisation (the static state) and after each step; none depends
on an input at the same communication point (no direct feedthrough).
"""
from __future__ import annotations

import numpy as np
from pythonfmu import Boolean, Fmi2Causality
from pythonfmu.enums import Fmi2Variability

from fmus.resources import MESH_FILE, MOTION_FILE
from fmus.schema import INTERNAL_MOTION_DESCRIPTION, message


class StepperOutputs:
    """Mixin (with fmus.slave.BankedSlave): registers the parameter internal_motion, builds the
    stepper from the resources with the soil the FMU gives it (``_soil``), publishes."""

    engine = "stepper"

    def _register_stepper(self, settings):
        """After the schema's Real variables (fmus.real_variables.register_schema): the Boolean parameter."""
        self.nodes = list(settings["output_nodes"])
        self.internal_motion = bool(settings.get("motion"))
        self.register_variable(Boolean("internal_motion", causality=Fmi2Causality.parameter,
                                       variability=Fmi2Variability.fixed, description=INTERNAL_MOTION_DESCRIPTION),
                               nested=False)
        self.stepper = None

    def _build_stepper(self, soil, external_soil: bool):
        from structure import NewmarkStepper
        from structure.plate_raft import PlateStepper
        from structure.spec import contact_from_spec, model_from_spec

        s, res = self.settings, self.resources
        with np.load(f"{res}/{MESH_FILE}", allow_pickle=False) as z:
            xy, area = z["xy"], z["area"]
            mesh = {k: z[k] for k in z.files}
        self.motion = None
        if self.internal_motion:
            if not s.get("motion"):
                raise ValueError(message("no_motion"))
            with np.load(f"{res}/{MOTION_FILE}", allow_pickle=False) as z:
                self.motion = np.array(z["acc"], float)
        model = model_from_spec(s["structure"], xy, area)
        if s.get("plate"):
            model = plate_model(model, s["plate"], mesh)
        ag0 = self.motion[0] if self.internal_motion else self.bank.values[self.sl["ag"]]
        stepper = PlateStepper if s.get("plate") else NewmarkStepper
        self.stepper = stepper(model, soil, self.dt, contact=contact_from_spec(s["contact"]),
                               damping=s.get("damping"), alpha=float(s.get("alpha", 0.0)),
                               external_soil=external_soil, ag0=ag0)
        self._dofs = {nm: model.dofs(model.node_by_name(nm).id)[:3] for nm in self.nodes}
        v = self.bank.values
        v[self.sl["max_uplift"]] = v[self.sl["max_raft_rotation"]] = 0.0
        self._publish()

    def _ag_next(self, t):
        """a_g(t + dt): the bundled motion's sample, or the inputs ag_x, ag_y, ag_z."""
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
        ag_next, h_next = st.next_inputs()
        return {"stepper": st.get_state(), "ag_next": ag_next, "h_ext": h_next}

    def _restore_engine(self, state):
        st = self.stepper
        st.set_state(state["stepper"])
        st.set_ground_acceleration(np.array(state["ag_next"]))
        st.set_soil_history(np.array(state["h_ext"]))


def plate_model(stick, properties: dict, mesh: dict):
    """The PlateRaftModel of the resources: the stick model with its raft master's mass and
    inertia replaced by the plate's (as ``orchestrator.scene.Scene.plate_model``), the plate's
    properties (settings) and mesh (the mesh file's arrays, fmus.build.plate_arrays)."""
    import dataclasses

    import scipy.sparse as sp

    from structure.plate_raft import PlateProperties, PlateRaftModel

    stick = dataclasses.replace(stick, raft=dataclasses.replace(stick.raft, m=0.0, inertia=(0.0, 0.0, 0.0)))
    points = mesh["plate_points"]
    cells = [tuple(int(v) for v in c if v >= 0) for c in mesh["plate_cells"]]
    trace = sp.csr_matrix((mesh["plate_trace_data"], mesh["plate_trace_indices"], mesh["plate_trace_indptr"]),
                          shape=(len(cells), points.shape[0]))
    return PlateRaftModel(stick, PlateProperties(**properties), points, cells, trace)

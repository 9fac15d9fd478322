"""The structure FMU: ``structure.NewmarkStepper`` (Newmark + penalty contact + Newton) with the
soil's instantaneous matrices folded in and the soil's history force as an input.

Variables (n = 6 + N interface DOFs [q, w], N interface nodes; SI units)

  inputs      h[0..n-1]    N     soil history force for the coming step, h_{k+1}
              ag[0..2]     m/s^2 ground acceleration at the END of the coming step, a_g(t + dt)
                                 (the scheme is implicit); read only when internal_motion = false
  outputs     x[0..n-1]    m, rad   interface displacements [q, w] at t
              xdot[0..n-1] m/s, rad/s
              P[0..N-1]    N     total compressive contact forces
              gap[0..N-1]  m     uplift
              acc_<node>[0..2], disp_<node>[0..2]   absolute acceleration, relative displacement
              energy.<term>  J   cumulative works and stored energies (see RouteResult)
              newton_iters       linear solves of the last step (a Real: read with the others)
  parameters  internal_motion  (Boolean) true: a_g from the motion bundled in resources
              impedance_split  (Boolean) true: fold (K0, C0) of the soil into the implicit matrix
                               and take h as input; false: plain total-force coupling (h is the
                               soil's total force, explicit; unstable on stiff soils, kept to
                               show why it is not the default)

Outputs are computed at initialisation (the static state) and after each step; no output
depends on an input at the same communication point (no direct feedthrough).
"""
from __future__ import annotations

import numpy as np
from pythonfmu import Boolean, Fmi2Causality, Fmi2Slave
from pythonfmu.enums import Fmi2Variability

from fmus.common import (MESH_FILE, MOTION_FILE, SOIL_INSTANT_FILE, BankedSlave, RealBank, check_step,
                         copy_state, guarded, make_soil, read_settings, register_vector)

ENERGY_TERMS = ("input", "kinetic", "strain", "damping", "soil", "contact", "contact_potential")


class InstantaneousSoil:
    """The soil as the structure sees it with an external history: (K0, C0) at the FMU's dt
    and K(0), read from resources. Another step size (Newton sub-stepping) builds the soil
    object itself once, lazily, and asks it."""

    def __init__(self, resources, settings):
        self.resources, self.settings = resources, settings
        with np.load(f"{resources}/{SOIL_INSTANT_FILE}", allow_pickle=False) as z:
            self.K0, self.C0, self.K_static, self.dt = z["K0"], z["C0"], z["K_static"], float(z["dt"])
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


class TotalForceView:
    """A soil seen by plain total-force coupling: nothing folded into the structure
    (K0 = C0 = 0); the static preload still uses the soil's static stiffness."""

    def __init__(self, soil):
        import scipy.sparse as sp
        self.soil, self.n_dof = soil, soil.n_dof
        self._zero = sp.csr_matrix((soil.n_dof, soil.n_dof))

    def instantaneous(self, dt):
        return self._zero, self._zero

    def static_stiffness(self):
        return self.soil.static_stiffness()


class UpliftStructure(BankedSlave, Fmi2Slave):
    author = "uplift"
    description = "Stick-and-raft structure with unilateral (penalty) contact, Newmark-Newton"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.settings = read_settings(self.resources, "structure")
        s = self.settings
        self.dt = float(s["dt"])
        n, N = int(s["n_dof"]), int(s["n_interface"])
        self.nodes = list(s["output_nodes"])
        self.bank = RealBank()
        inp, out = Fmi2Causality.input, Fmi2Causality.output
        self.sl = {
            "h": register_vector(self, "h", n, inp, description="soil history force for the coming step, N"),
            "ag": register_vector(self, "ag", 3, inp, description="ground acceleration at t + dt, m/s2"),
            "x": register_vector(self, "x", n, out, description="interface displacements [q, w], m / rad"),
            "xdot": register_vector(self, "xdot", n, out, description="interface velocities, m/s / rad/s"),
            "P": register_vector(self, "P", N, out, description="total contact forces, N"),
            "gap": register_vector(self, "gap", N, out, description="uplift, m"),
        }
        for nm in self.nodes:
            self.sl[f"acc_{nm}"] = register_vector(self, f"acc_{nm}", 3, out,
                                                   description=f"absolute acceleration of {nm}, m/s2")
            self.sl[f"disp_{nm}"] = register_vector(self, f"disp_{nm}", 3, out,
                                                    description=f"displacement of {nm}, m")
        for term in ENERGY_TERMS:
            self.sl[f"energy.{term}"] = register_vector(self, f"energy.{term}", None, out,
                                                        description=f"energy term {term}, J")
        self.sl["newton_iters"] = register_vector(self, "newton_iters", None, out,
                                                  description="linear solves of the last step")
        self.internal_motion = bool(s.get("motion"))
        self.impedance_split = True
        fixed = Fmi2Variability.fixed
        self.register_variable(Boolean("internal_motion", causality=Fmi2Causality.parameter,
                                       variability=fixed), nested=False)
        self.register_variable(Boolean("impedance_split", causality=Fmi2Causality.parameter,
                                       variability=fixed), nested=False)
        self.stepper = None
        self._built_with = None
        self.last_error = ""

    # ---- fast Real access (one gather/scatter per FMI call) ----------------------------------

    # ---- life cycle ------------------------------------------------------------------------
    def _build(self):
        from structure import NewmarkStepper
        from structure.spec import contact_from_spec, model_from_spec

        s, res = self.settings, self.resources
        with np.load(f"{res}/{MESH_FILE}", allow_pickle=False) as z:
            xy, area = z["xy"], z["area"]
        self.motion = None
        if s.get("motion"):
            with np.load(f"{res}/{MOTION_FILE}", allow_pickle=False) as z:
                self.motion = np.array(z["acc"], float)
        self.model = model_from_spec(s["structure"], xy, area)
        soil = InstantaneousSoil(res, s)
        if not self.impedance_split:
            soil = TotalForceView(soil)
        ag0 = self._ag_at(0.0) if self.internal_motion else self.bank.values[self.sl["ag"]]
        self.stepper = NewmarkStepper(self.model, soil, self.dt, contact=contact_from_spec(s["contact"]),
                                      damping=s.get("damping"), alpha=float(s.get("alpha", 0.0)),
                                      external_soil=True, ag0=ag0)
        self._dofs = {nm: self.model.dofs(self.model.node_by_name(nm).id)[:3] for nm in self.nodes}
        self._built_with = (self.internal_motion, self.impedance_split)
        self._publish()

    def _ag_at(self, t):
        if self.motion is None:
            raise ValueError("internal_motion = true but this FMU was exported without a motion")
        k = int(round(t / self.dt))
        return self.motion[k] if k < self.motion.shape[0] else np.zeros(3)

    def _publish(self):
        st, v, sl = self.stepper, self.bank.values, self.sl
        v[sl["x"]] = st.x
        v[sl["xdot"]] = st.xdot
        v[sl["P"]] = st.P
        v[sl["gap"]] = st.gap()
        for nm, d in self._dofs.items():
            v[sl[f"acc_{nm}"]] = st.a[d] + st.ag
            v[sl[f"disp_{nm}"]] = st.u[d]
        for term, value in st.energies().items():
            v[sl[f"energy.{term}"]] = value

    def exit_initialization_mode(self):
        if self.stepper is None or self._built_with != (self.internal_motion, self.impedance_split):
            guarded(self, "initialisation", self._build)

    def _step(self, t, step_size):
        check_step(self.dt, step_size)
        st, v = self.stepper, self.bank.values
        st.set_ground_acceleration(self._ag_at(t + step_size) if self.internal_motion else v[self.sl["ag"]])
        st.set_soil_history(v[self.sl["h"]])
        v[self.sl["newton_iters"]] = st.step()
        self._publish()

    # ---- FMU state: the stepper's full numpy state, the variables and the pending inputs -----
    def _get_fmu_state(self):
        state = {"bank": self.bank.values.copy()}
        if self.stepper is not None:
            st = self.stepper
            state["stepper"] = copy_state(st.get_state())
            state["ag_next"], state["h_ext"] = st._ag_next.copy(), st._h_ext.copy()
        return state

    def _set_fmu_state(self, state):
        self.bank.values[:] = state["bank"]
        if "stepper" in state and self.stepper is not None:
            st = self.stepper
            st.set_state(copy_state(state["stepper"]))
            st._ag_next, st._h_ext = np.array(state["ag_next"]), np.array(state["h_ext"])

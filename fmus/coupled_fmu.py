"""The coupled FMU: the structure and the soil in one co-simulation FMU, the monolithic
route's stepper (``structure.NewmarkStepper`` advancing the soil object itself) one step per
communication step. For tools that run one FMU at a time (``fmpy simulate``) or treat
co-simulation FMUs as direct feedthrough (Simulink): nothing to connect.

Variables: the outputs and the inputs ag_x, ag_y, ag_z of fmus/stepper.py. Driven by the
motion bundled in resources by default (parameter internal_motion = true); false: by the inputs
ag_x, ag_y, ag_z (held over a communication step). A communication step may be any multiple of the exported dt (fmpy's
``simulate_fmu`` picks one when a record has more than 1000 steps): the FMU steps dt inside.
"""
from __future__ import annotations

from pythonfmu import Fmi2Slave

from fmus.real_variables import RealBank, register_schema
from fmus.resources import make_soil, read_settings
from fmus.slave import BankedSlave
from fmus.stepper import StepperOutputs


class UpliftCoupled(StepperOutputs, BankedSlave, Fmi2Slave):
    author = "uplift"
    description = "Structure on frequency-dependent soil with uplift: Newmark-Newton, recursive convolution"
    inputs = ("ag",)
    multistep = True

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.settings = s = read_settings(self.resources, "coupled")
        self._init_life_cycle(s["dt"])
        self.bank = RealBank()
        self.sl = register_schema(self, "coupled", int(s["n_dof"]), int(s["n_interface"]), s["output_nodes"])
        self._register_stepper(s)
        self.stamped = {}

    def _build(self):
        self._build_stepper(make_soil(self.resources, self.settings), external_soil=False)

    def _step(self, t):
        st, v = self.stepper, self.bank.values
        st.set_ground_acceleration(self._ag_next(t))
        v[self.sl["newton_iters"]] = st.step()
        self._publish()

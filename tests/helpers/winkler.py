"""The shared Winkler case: the reactor stick model on a 20 m disk over rock (E = 15 GPa,
ν = 0.3, ρ = 2500 kg/m³), the soil as springs sharing the disk's static stiffness and wave
dashpots under each node (frequency-independent: every route is exact on it)."""
from functools import cached_property

import numpy as np

from soil_impedance.mesh import circle_mesh
from structure import WinklerSoil
from structure.spec import model_from_spec
from structure.winkler import dashpots_from_waves, disk_static_stiffness, springs_from_rigid_impedance

E_ROCK, NU, RHO, R = 15e9, 0.3, 2500.0, 20.0
G_ROCK = E_ROCK / (2 * (1 + NU))
VS = np.sqrt(G_ROCK / RHO)
VP = VS * np.sqrt((2 - 2 * NU) / (1 - 2 * NU))


def rock_winkler(xy, area, damped=True, stiffness_scale=1.0, match=None, ky=False) -> WinklerSoil:
    """Springs (kv, kx; ky too when ``ky``) matched on ``stiffness_scale`` times the rock disk's
    static stiffness (``match`` as ``springs_from_rigid_impedance``, its default when None) and,
    when ``damped``, the wave dashpots, for the nodes ``xy`` (N, 2) m of areas ``area`` (N,) m²."""
    K6 = stiffness_scale * disk_static_stiffness(G_ROCK, NU, R)
    s = springs_from_rigid_impedance(K6, xy, area) if match is None else \
        springs_from_rigid_impedance(K6, xy, area, match=match)
    cv, ch = dashpots_from_waves(area, RHO, VP, VS) if damped else (0.0, 0.0)
    return WinklerSoil(xy, s.kv, s.kx, cv, ch, ky=s.ky) if ky else WinklerSoil(xy, s.kv, s.kx, cv, ch)


def reactor_on_rock(element_size, damping=None):
    """(mesh, model): the 20 m disk meshed at ``element_size`` m and the reactor stick model on
    it (its own damping unless ``damping`` is a scene's [structure].damping table)."""
    mesh = circle_mesh(R, element_size)
    spec = {"model": "reactor"} if damping is None else {"model": "reactor", "damping": damping}
    return mesh, model_from_spec(spec, mesh.xy, mesh.area)


class RockCase:
    """The reactor on the rock disk meshed at ``element_size`` m, built on first use: ``mesh``,
    ``model`` and ``soil(damped=True)`` (a new WinklerSoil: it carries state)."""

    def __init__(self, element_size, damping=None):
        self.element_size, self.damping = element_size, damping

    @cached_property
    def _built(self):
        return reactor_on_rock(self.element_size, self.damping)

    @property
    def mesh(self):
        return self._built[0]

    @property
    def model(self):
        return self._built[1]

    def soil(self, damped=True) -> WinklerSoil:
        return rock_winkler(self.mesh.xy, self.mesh.area, damped=damped)


#: the stepper tests' case: 241 nodes (2.28 m elements), the reactor's own damping
FINE_RAFT = RockCase(2.28)
#: the frequency-domain tests' case: 21 nodes (8 m elements), 7 % modal damping
COARSE_RAFT = RockCase(8.0, {"modal": 0.07})


def hysteretic_table(xi=0.03):
    """The coarse raft's springs and dashpots as a table with hysteretic damping ξ (complex
    moduli, Im K(0+) = 2 ξ K_0: not causal): K (1 + 2iξ) + iω C at 0..25 Hz, 51 frequencies."""
    from soil_impedance.table import ImpedanceTable
    w = COARSE_RAFT.soil()
    K = w.static_stiffness().toarray()
    C = w.instantaneous(0.005)[1].toarray()
    f = np.linspace(0.0, 25.0, 51)
    Kf = K[None] * (1 + 2j * xi) + 2j * np.pi * f[:, None, None] * C[None]
    return ImpedanceTable(f, Kf, [f"d{i}" for i in range(K.shape[0])], {"test": f"hysteretic {xi}"})

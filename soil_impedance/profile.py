"""Horizontally layered soil over a homogeneous half-space.

Every material is linear viscoelastic with damping ratio ``damping`` = ξ, in one of two models
(``damping_model``; harmonic convention e^{+iωt}, docs/conventions.md; the same complex factor
multiplies both moduli, so ν is real and frequency independent):

* ``"hysteretic"`` (default): ``G* = ρ vs² (1 + 2iξ)`` at every frequency. Not causal
  (Kramers-Kronig: a constant loss factor needs Re G* rising with frequency, and Im G*(0⁺) ≠ 0);
  the rational fit fades the offset below a cut-off (``soil_impedance.fit``; docs/formulation.md, Causality) and
  cannot follow Re and Im together in the band.
* ``"causal"``: constant Q with a low-frequency cut-off, the shifted Kjartansson (1979) power law

      G*(ω) = G0 ((iω + ω1) / ω1)^(2γ),     γ = arctan(2ξ) / π,

  i.e. G0 (1 + s/ω1)^(2γ) in the Laplace variable s = iω: analytic for Re s > −ω1, hence causal
  (its relaxation function vanishes for t < 0), real at ω = 0 (static modulus G0), loss factor
  Im/Re = tan(2γ arctan(ω/ω1)), which rises from 0 to 2ξ (half of it at ω1, 99 % from 100 ω1
  up), and Re G* grows by ≈ (4ξ/π) per e-fold of frequency (the Kramers-Kronig dispersion of a
  constant Q). Choices:

  - ``CAUSAL_REFERENCE_HZ`` = 1 Hz: the given vs is the shear-wave speed at 1 Hz,
    Re G*(2π · 1 Hz) = ρ vs² (the reference frequency of seismological Q models, inside the
    1-10 Hz band where site vs is measured). For ξ = 3 %: Re G*/ρvs² = 0.893 static, 0.949 at
    0.25 Hz, 1.054 at 4 Hz, 1.092 at 10 Hz, 1.130 at 25 Hz; loss factor 87 %, 97 %, 99.2 %,
    99.7 % of 2ξ at 0.25, 1, 4, 10 Hz.
  - ``CAUSAL_CUTOFF_HZ`` = 0.05 Hz: a material property, independent of the sweep's frequencies;
    below the earthquake band (≥ 0.1 Hz), so the damping is within 6 % of ξ from 0.5 Hz up and
    within 2 % over the soil-structure band (≥ 2 Hz). A lower ω1 lowers G0 further (the
    dispersion keeps going: ≈ 4ξ/π · ln 10 = 8.8 % per decade for ξ = 3 %) and puts a sharper
    transition between the table's f = 0 and its first frequency.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from uplift_common.errors import UserInputError

DAMPING_MODELS = ("hysteretic", "causal")
CAUSAL_REFERENCE_HZ = 1.0   # the given vs holds at this frequency (causal model)
CAUSAL_CUTOFF_HZ = 0.05     # ω1 / 2π: below it the causal material loses its damping


class SoilError(UserInputError):
    """An invalid soil profile; the message names the input and how to fix it."""


@dataclass(frozen=True)
class Material:
    """An isotropic viscoelastic material.

    Give ``nu`` (Poisson ratio) or ``vp`` (P-wave speed, m/s), not both unless consistent.

    Parameters
    ----------
    vs : float, m/s       shear-wave speed, > 0
    rho : float, kg/m^3   mass density, > 0
    nu : float            Poisson ratio in (0, 0.5)
    vp : float, m/s       P-wave speed, >= vs*sqrt(2) (i.e. nu >= 0)
    damping : float       damping ratio ξ in [0, 0.5) (loss factor 2ξ)
    damping_model : str   "hysteretic" (G* = G (1 + 2iξ)) or "causal" (constant Q with a cut-off,
                          see the module docstring; then Re G*(1 Hz) = ρ vs²)
    """

    vs: float
    rho: float
    nu: float | None = None
    vp: float | None = None
    damping: float = 0.0
    damping_model: str = "hysteretic"
    name: str = field(default="material", compare=False)

    def __post_init__(self):
        where = self.name
        for key in ("vs", "rho"):
            value = getattr(self, key)
            if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
                raise SoilError(f"{where}: {key} = {value!r} must be a positive finite number")
        if not (0.0 <= self.damping < 0.5) or not math.isfinite(self.damping):
            raise SoilError(f"{where}: damping = {self.damping!r} must lie in [0, 0.5) "
                            "(a damping ratio, e.g. 0.05 for 5 %)")
        if self.damping_model not in DAMPING_MODELS:
            raise SoilError(f"{where}: damping_model = {self.damping_model!r}: use one of "
                            + ", ".join(repr(m) for m in DAMPING_MODELS))
        if self.nu is None and self.vp is None:
            raise SoilError(f"{where}: give either nu (Poisson ratio) or vp (P-wave speed)")
        if self.vp is not None:
            if not math.isfinite(self.vp) or self.vp < self.vs * math.sqrt(2.0):
                raise SoilError(
                    f"{where}: vp = {self.vp!r} m/s is below vs*sqrt(2) = "
                    f"{self.vs * math.sqrt(2.0):.6g} m/s (Poisson ratio < 0); "
                    "raise vp or give nu instead")
            nu_from_vp = _nu_from_speeds(self.vs, self.vp)
            if self.nu is not None and abs(nu_from_vp - self.nu) > 1e-6:
                raise SoilError(f"{where}: nu = {self.nu!r} and vp = {self.vp!r} disagree "
                                f"(vp implies nu = {nu_from_vp:.6g}); give only one")
        nu = self.poisson
        if not (0.0 < nu < 0.5):
            raise SoilError(f"{where}: Poisson ratio nu = {nu!r} must lie in (0, 0.5); "
                            "0.5 (incompressible) makes vp infinite, use e.g. 0.49")

    @property
    def poisson(self) -> float:
        return self.nu if self.nu is not None else _nu_from_speeds(self.vs, self.vp)

    @property
    def shear_modulus(self) -> float:
        """G = rho vs^2, Pa: Re G* (causal model: at ``CAUSAL_REFERENCE_HZ``)."""
        return self.rho * self.vs ** 2

    @property
    def p_speed(self) -> float:
        """vp, m/s."""
        nu = self.poisson
        return self.vs * math.sqrt(2.0 * (1.0 - nu) / (1.0 - 2.0 * nu))

    def complex_shear_modulus(self, omega=None):
        """G*(ω), Pa (complex; an array if omega is one).

        Parameters
        ----------
        omega : float or array_like, rad/s, or None. The hysteretic model ignores it (None
            allowed); the causal one needs it (ω = 0: the real static modulus G0).
        """
        if self.damping_model == "hysteretic":
            g = self.shear_modulus * (1.0 + 2j * self.damping)
            return g if np.ndim(omega) == 0 else np.full(np.shape(omega), g)
        if omega is None:
            raise SoilError(f"{self.name}: the causal damping model is frequency dependent: "
                            "complex_shear_modulus needs omega (rad/s)")
        return self.shear_modulus / self.static_to_reference * causal_factor(
            omega, 2.0 * math.pi * CAUSAL_CUTOFF_HZ, self.damping)

    @property
    def static_to_reference(self) -> float:
        """Re G*(reference) / G*(0): rho vs^2 over the relaxed static modulus G0 of the causal
        model (1 for the hysteretic one, whose Re G* is rho vs^2 at every frequency)."""
        if self.damping_model != "causal":
            return 1.0
        return float(causal_factor(2.0 * math.pi * CAUSAL_REFERENCE_HZ,
                                   2.0 * math.pi * CAUSAL_CUTOFF_HZ, self.damping).real)


def causal_factor(omega, omega1, damping):
    """(1 + iω/ω1)^(2γ), γ = arctan(2 damping)/π: the causal model's G*(ω)/G*(0).

    omega: rad/s, float or array (negative ω gives the complex conjugate; complex ω = s/i is
    allowed: the Laplace-domain value). Principal power: 1 + s/ω1 has a positive real part for
    Re s > −ω1, so the function is analytic there."""
    gamma = math.atan(2.0 * damping) / math.pi
    return (1.0 + 1j * np.asarray(omega) / omega1) ** (2.0 * gamma)


def _nu_from_speeds(vs: float, vp: float) -> float:
    r2 = (vp / vs) ** 2
    return (r2 - 2.0) / (2.0 * (r2 - 1.0))


@dataclass(frozen=True)
class Layer(Material):
    """A horizontal layer: a Material with a thickness (m, > 0)."""

    thickness: float = 0.0

    def __post_init__(self):
        super().__post_init__()
        t = self.thickness
        if not isinstance(t, (int, float)) or not math.isfinite(t) or t <= 0:
            raise SoilError(f"{self.name}: thickness = {t!r} m must be a positive finite number")


@dataclass(frozen=True)
class SoilProfile:
    """Layers (top first) over a half-space. ``layers`` may be empty (homogeneous)."""

    layers: tuple[Layer, ...]
    halfspace: Material

    def __post_init__(self):
        if self.halfspace is None:
            raise SoilError("soil profile has no half-space: give [soil].halfspace")
        if not isinstance(self.halfspace, Material):
            raise SoilError("soil.halfspace must be a Material")
        object.__setattr__(self, "layers", tuple(self.layers))
        for i, layer in enumerate(self.layers):
            if not isinstance(layer, Layer):
                raise SoilError(f"soil.layers[{i}] must be a Layer (with a thickness)")

    @classmethod
    def homogeneous(cls, vs, rho, nu=None, vp=None, damping=0.0,
                    damping_model="hysteretic") -> SoilProfile:
        return cls((), Material(vs=vs, rho=rho, nu=nu, vp=vp, damping=damping,
                                damping_model=damping_model, name="soil.halfspace"))

    @property
    def static_to_reference(self) -> float:
        """Re G*(reference) / G*(0) of the materials: the factor that turns the relaxed static
        stiffness K(0) of a causal profile into the static stiffness at the moduli rho vs^2
        (what a spring calibrated on K(0) is expected to carry); 1 for hysteretic materials.
        Exact when every material has the same damping ratio (a common factor of all moduli);
        otherwise the half-space's factor."""
        return self.halfspace.static_to_reference

    @property
    def is_homogeneous(self) -> bool:
        """True when every layer has the half-space's properties (the exact kernel applies)."""
        hs = self.halfspace
        def key(m):
            return m.vs, m.rho, m.poisson, m.damping, m.damping_model
        return all(key(l) == key(hs) for l in self.layers)

    @property
    def top(self) -> Material:
        """The material at the surface (its static half-space solution is the singular part)."""
        return self.layers[0] if self.layers else self.halfspace

    @property
    def depth(self) -> float:
        """Total thickness of the layers, m."""
        return sum(l.thickness for l in self.layers)

    def with_halfspace_only(self) -> SoilProfile:
        return replace(self, layers=())

"""Horizontally layered soil over a homogeneous half-space.

Every material is linear viscoelastic with a frequency-independent (hysteretic) damping
ratio ``damping``: in the frequency domain the moduli are complex,
``G* = G (1 + 2i damping)`` (harmonic convention e^{+iωt}, DESIGN.md §2). This model is not
causal; the time-domain soil model handles that (see ``soil_impedance.rational``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace


class SoilError(ValueError):
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
    damping : float       hysteretic damping ratio in [0, 0.5)
    """

    vs: float
    rho: float
    nu: float | None = None
    vp: float | None = None
    damping: float = 0.0
    name: str = field(default="material", compare=False)

    def __post_init__(self):
        where = self.name
        for key in ("vs", "rho"):
            value = getattr(self, key)
            if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
                raise SoilError(f"{where}: {key} = {value!r} must be a positive finite number")
        if not (0.0 <= self.damping < 0.5) or not math.isfinite(self.damping):
            raise SoilError(f"{where}: damping = {self.damping!r} must lie in [0, 0.5) "
                            "(a hysteretic damping ratio, e.g. 0.05 for 5 %)")
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
        """G = rho vs^2, Pa (real part)."""
        return self.rho * self.vs ** 2

    @property
    def p_speed(self) -> float:
        """vp, m/s."""
        nu = self.poisson
        return self.vs * math.sqrt(2.0 * (1.0 - nu) / (1.0 - 2.0 * nu))

    def complex_shear_modulus(self) -> complex:
        """G* = G (1 + 2i damping), Pa."""
        return self.shear_modulus * (1.0 + 2j * self.damping)


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
    def homogeneous(cls, vs, rho, nu=None, vp=None, damping=0.0) -> "SoilProfile":
        return cls((), Material(vs=vs, rho=rho, nu=nu, vp=vp, damping=damping, name="soil.halfspace"))

    @property
    def is_homogeneous(self) -> bool:
        """True when every layer has the half-space's properties (the exact kernel applies)."""
        hs = self.halfspace
        return all((l.vs, l.rho, l.poisson, l.damping) == (hs.vs, hs.rho, hs.poisson, hs.damping)
                   for l in self.layers)

    @property
    def top(self) -> Material:
        """The material at the surface (its static half-space solution is the singular part)."""
        return self.layers[0] if self.layers else self.halfspace

    @property
    def depth(self) -> float:
        """Total thickness of the layers, m."""
        return sum(l.thickness for l in self.layers)

    def with_halfspace_only(self) -> "SoilProfile":
        return replace(self, layers=())

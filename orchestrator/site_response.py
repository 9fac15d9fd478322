"""Strain-compatible soil: the equivalent-linear free-field response of the layered profile under
the scene's motion ([soil] strain_compatible; docs/design_basis.md).

The profile's layers over its half-space are a 1-D column of horizontal layers crossed by
vertically propagating shear (SH) waves, solved in the frequency domain (the SHAKE method,
Schnabel, Lysmer & Seed 1972) by pystrata's ``EquivalentLinearCalculator``: in each iteration
the peak shear strain at the middle of every layer is computed under the motion, the
effective strain is ``strain_ratio`` times it, and the layer's shear modulus G = G_max
G/G_max(strain) and damping D(strain) are read on its curves (``LayerCurves``: Darendeli 2001
with the layer's stated damping as its small-strain damping, a user table, or linear);
iterations stop when no G nor D changes by more than ``tolerance`` (relative), or after
``max_iterations``. The half-space stays linear with its own damping.

Choices (stated): the scene's horizontal motion is the input, the stronger horizontal component
when there are two (a vertical-only motion is refused: P waves are not part of this analysis);
it acts at the top of the half-space, as an outcrop motion ("outcrop", default: the rock's
motion where it outcrops, twice the incident wave) or as the motion within the profile there
("within"); the soil is dry (the mean effective stress of Darendeli's curves is the dry
overburden at the layer's middle times (1 + 2 k0)/3); each layer of the scene is one layer of
the column (no sub-layers); the motion under the raft remains the scene's motion: the site
response gives the soil's properties only. pystrata's complex modulus is G (sqrt(1 - 4 D^2) +
2i D) (Dormieux & Canou); the BEM then uses the iterated vs and D in the scene's damping model.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.constants import g as G_PYSTRATA

from orchestrator.soil_cases import StrainCompatibleConfig
from soil_impedance.profile import SoilProfile
from uplift_common.errors import UserInputError


class SiteResponseError(UserInputError):
    """A strain-compatible analysis that cannot run (pystrata missing, no horizontal motion)."""


@dataclass(frozen=True)
class SiteResponse:
    """The result of the equivalent-linear analysis: profile (the scene's with each layer's vs and
    damping replaced by the strain-compatible ones), per layer (top down) g_ratio (G/G_max),
    damping (ratio), strain_eff (effective shear strain, decimal) and strain_max (peak shear
    strain, decimal); iterations (passes of the iteration), converged (the tolerance reached),
    max_change (the largest relative change of G or D in the last pass), component (the motion's
    axis used), input ("outcrop" | "within")."""

    profile: SoilProfile
    g_ratio: np.ndarray
    damping: np.ndarray
    strain_eff: np.ndarray
    strain_max: np.ndarray
    iterations: int
    converged: bool
    max_change: float
    component: str
    input: str


def _pystrata():
    try:
        import pystrata  # optional dependency (the "site" extra), 5-10 s to import: only strain-compatible runs
    except ModuleNotFoundError:
        raise SiteResponseError("soil.strain_compatible needs pystrata (equivalent-linear site response): "
                                "pip install 'uplift-ssi[site]' (or pip install pystrata), or remove "
                                "strain_compatible from [soil]") from None
    return pystrata


def pystrata_profile(profile: SoilProfile, config: StrainCompatibleConfig):
    """The pystrata Profile of ``profile`` with the curves of ``config`` (units: kN/m^3, m, m/s;
    unit weights and accelerations in g use pystrata's own g, scipy's 9.80665 m/s², so that its
    densities are the scene's and its strains those of the motion in m/s²)."""
    ps = _pystrata()
    layers, sigma_v = [], 0.0                             # dry overburden at the layer's top, kPa
    for layer, curves in zip(profile.layers, config.curves):
        unit_wt = layer.rho * G_PYSTRATA / 1000.0                 # kN/m^3
        mid = sigma_v + unit_wt * layer.thickness / 2
        if curves.model == "darendeli":
            soil = ps.site.DarendeliSoilType(unit_wt=unit_wt, plas_index=curves.pi, ocr=curves.ocr,
                                             stress_mean=mid * (1 + 2 * curves.k0) / 3, freq=curves.freq_hz,
                                             num_cycles=curves.cycles, damping_min=layer.damping)
        elif curves.model == "table":
            soil = ps.site.SoilType(layer.name, unit_wt,
                                    ps.site.NonlinearProperty("g_ratio", curves.strain, curves.g_ratio, "mod_reduc"),
                                    ps.site.NonlinearProperty("damping", curves.strain, curves.damping, "damping"))
        else:
            soil = ps.site.SoilType(layer.name, unit_wt, None, layer.damping)
        layers.append(ps.site.Layer(soil, layer.thickness, layer.vs))
        sigma_v += unit_wt * layer.thickness
    hs = profile.halfspace
    layers.append(ps.site.Layer(ps.site.SoilType("halfspace", hs.rho * G_PYSTRATA / 1000.0, None, hs.damping), 0, hs.vs))
    return ps.site.Profile(layers)


def _calculator(config: StrainCompatibleConfig):
    """pystrata's EquivalentLinearCalculator that also counts its passes (the wave field is
    computed once before the iteration, then once per pass)."""
    ps = _pystrata()

    class Counting(ps.propagation.EquivalentLinearCalculator):
        solves = 0

        def _calc_waves(self, *args):                     # one call per pass, one before them
            self.solves += 1
            return super()._calc_waves(*args)

    return Counting(strain_ratio=config.strain_ratio, tolerance=config.tolerance,
                    max_iterations=config.max_iterations, strain_limit=0.05)


def horizontal_component(acc) -> tuple[str, np.ndarray]:
    """(axis, history m/s²) of the stronger horizontal component of ``acc`` (nt, 3)."""
    acc = np.asarray(acc, float)
    peaks = np.abs(acc[:, :2]).max(axis=0)
    if not peaks.max() > 0:
        raise SiteResponseError("soil.strain_compatible: the motion has no horizontal component (the site response "
                                "propagates shear waves): shake x or y, or remove strain_compatible")
    k = int(np.argmax(peaks))
    return "xy"[k], acc[:, k]


def strain_compatible(profile: SoilProfile, acc, dt: float, config: StrainCompatibleConfig) -> SiteResponse:
    """The equivalent-linear analysis of ``profile`` under the ground motion ``acc`` (nt, 3) m/s²
    sampled at ``dt`` s (its stronger horizontal component), with ``config``; see the module."""
    ps = _pystrata()
    axis, history = horizontal_component(acc)
    motion = ps.motion.TimeSeriesMotion("scene", "scene motion", dt, history / G_PYSTRATA)
    column = pystrata_profile(profile, config)
    calc = _calculator(config)
    calc(motion, column, column.location(config.input, index=-1))
    soil = column[:-1]
    g_ratio = np.array([float(layer.shear_mod_reduc) for layer in soil])
    damping = np.array([float(layer.damping) for layer in soil])
    change = max(float(layer.max_error) for layer in soil)
    layers = tuple(replace(layer, vs=layer.vs * math.sqrt(g), vp=None if layer.vp is None else layer.vp * math.sqrt(g),
                           damping=float(d))
                   for layer, g, d in zip(profile.layers, g_ratio, damping))
    return SiteResponse(profile=SoilProfile(layers, profile.halfspace), g_ratio=g_ratio, damping=damping,
                        strain_eff=np.array([float(layer.strain) for layer in soil]),
                        strain_max=np.array([float(layer.strain_max) for layer in soil]),
                        iterations=calc.solves - 1, converged=change < config.tolerance, max_change=change,
                        component=axis, input=config.input)

"""The plausible range of every physical input, in one place (docs/conventions.md, "Plausible
ranges", lists the same table).

A number can be finite and positive and still absurd: a shear-wave speed of 1e308 m/s overflows
the BEM's arithmetic after minutes of work, a record sample of 1e308 g overflows the scaling, a
scene of 150,000 layers computes for minutes before anything fails. Every physical input is
therefore checked against a generous range of engineering plausibility before any computation
(the scene loader, the structure parser and the record reader call ``check_plausible``): the
ranges hold every real site, building and record with a wide margin, and refuse only values
that are typos (a unit slip of 10^3 and more, an exponent too many) or beyond what the methods
are meant for. The refusal names the key, its value, the range and its unit.

Usage::

    check_plausible("soil.halfspace.vs", 1e308, "vs", SceneError)
    # SceneError: soil.halfspace.vs = 1e+308 m/s lies outside the plausible range [1, 10000] m/s
    # of a shear-wave speed: check the value and its unit (docs/conventions.md, Plausible ranges)
"""
from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Range:
    """[lo, hi] in ``unit`` (a magnitude: ``signed`` checks |value| against hi, lo unused)."""
    lo: float
    hi: float
    unit: str
    what: str
    signed: bool = False


#: quantity -> its plausible range (SI units; record samples in the record's own units)
PLAUSIBLE = {
    # soil ([soil] layers and half-space)
    "vs": Range(1.0, 1.0e4, "m/s", "shear-wave speed"),
    "vp": Range(1.0, 2.0e4, "m/s", "compression-wave speed"),
    "rho": Range(100.0, 3.0e4, "kg/m3", "mass density"),
    "thickness": Range(1.0e-3, 1.0e4, "m", "layer thickness"),
    # (the material damping ratio and Poisson's ratio have their own ranges, [0, 0.5) and
    # (0, 0.5): soil_impedance.profile.Material)
    # foundation
    "radius": Range(0.1, 1.0e3, "m", "raft radius"),
    "length": Range(0.1, 2.0e3, "m", "raft side"),
    "element_size": Range(1.0e-3, 1.0e3, "m", "element size"),
    # structure
    "coordinate": Range(0.0, 1.0e4, "m", "node coordinate", signed=True),
    "modulus": Range(1.0e3, 1.0e16, "Pa", "elastic modulus (E or G)"),
    "area": Range(1.0e-8, 1.0e6, "m2", "section area"),
    "second_moment": Range(1.0e-16, 1.0e10, "m4", "second moment of area (Iy, Iz, J)"),
    "beam_density": Range(0.0, 1.0e6, "kg/m3", "beam density"),
    "mass": Range(0.0, 1.0e12, "kg", "mass"),
    "rotary_inertia": Range(0.0, 1.0e18, "kg m2", "rotary inertia"),
    "stiffness": Range(0.0, 1.0e16, "N/m or N m/rad", "spring stiffness"),
    "rayleigh_a0": Range(0.0, 1.0e3, "1/s", "Rayleigh mass coefficient"),
    "rayleigh_a1": Range(0.0, 10.0, "s", "Rayleigh stiffness coefficient"),
    # winkler springs, contact
    "subgrade_modulus": Range(0.0, 1.0e13, "N/m3", "subgrade modulus"),
    "subgrade_damping": Range(0.0, 1.0e12, "N s/m3", "subgrade damping"),
    "penalty": Range(0.0, 1.0e20, "N/m", "contact penalty stiffness"),
    "penalty_factor": Range(0.0, 1.0e8, "", "contact penalty factor"),
    # motion
    "frequency": Range(0.0, 1.0e3, "Hz", "impedance frequency"),
    "scale": Range(1.0e-6, 1.0e6, "", "record scale factor", signed=True),
    "sample_g": Range(0.0, 50.0, "g", "record sample", signed=True),
    "sample_ms2": Range(0.0, 500.0, "m/s2", "record sample", signed=True),
    "record_time": Range(0.0, 1.0e6, "s", "record time", signed=True),
}

#: most soil layers over the half-space (a real profile has tens; each layer costs the BEM's
#: Green's functions a little at every frequency)
MAX_LAYERS = 200
#: most structure nodes (a stick or frame model of a building has tens to a few thousand)
MAX_STRUCTURE_NODES = 20_000
#: most beams, masses or springs of a structure (each list)
MAX_STRUCTURE_ELEMENTS = 50_000


def plausible_range(quantity: str) -> str:
    """The range of ``quantity`` as text: "[1, 10000] m/s"."""
    r = PLAUSIBLE[quantity]
    unit = f" {r.unit}" if r.unit else ""
    return f"|value| <= {r.hi:g}{unit}" if r.signed else f"[{r.lo:g}, {r.hi:g}]{unit}"


def is_plausible(value, quantity: str) -> bool:
    """True if ``value`` (a real number) lies in the plausible range of ``quantity``; a value
    that is not a real number, or not positive where the range is (a sign error), is left to
    the caller's own checks (True): their message says what the value must be."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return True
    r = PLAUSIBLE[quantity]
    try:
        v = float(value)
    except OverflowError:                   # an int beyond the float range
        return False
    if math.isnan(v) or (not r.signed and r.lo > 0 and v <= 0):
        return True                          # "not a finite number", "must be > 0": the caller's message
    return abs(v) <= r.hi if r.signed else r.lo <= v <= r.hi


def check_plausible(where: str, value, quantity: str, error=ValueError):
    """``value`` if it lies in the plausible range of ``quantity`` (PLAUSIBLE), else raise
    ``error`` naming ``where`` (the key), the value, the range and its unit. A value that is not
    a real number passes (the caller's type check says what it must be)."""
    if is_plausible(value, quantity):
        return value
    r = PLAUSIBLE[quantity]
    unit = f" {r.unit}" if r.unit and not r.unit.startswith("N/m or") else ""
    article = "an" if r.what[0] in "aeiou" else "a"
    raise error(f"{where} = {_show(value)}{unit} lies outside the plausible range {plausible_range(quantity)} of "
                f"{article} {r.what}: check the value and its unit (docs/conventions.md, Plausible ranges)")


def check_count(where: str, count: int, most: int, what: str, error=ValueError) -> None:
    """Raise ``error`` when ``count`` (of layers, nodes, ...) exceeds ``most``, before any parsing of
    them: the message names ``where``, the count and the limit."""
    if count > most:
        raise error(f"{where} has {count} {what}; at most {most} (docs/conventions.md, Plausible ranges): "
                    "check the file")


def _show(value) -> str:
    try:
        return f"{float(value):g}"
    except OverflowError:
        text = str(value)
        return text if len(text) <= 30 else f"{text[:12]}...({len(text)} digits)"

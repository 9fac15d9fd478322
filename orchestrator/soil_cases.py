"""Design soil cases and strain-compatible soil settings ([soil] cases, [soil] strain_compatible).

Practice (ASCE 4-16 §2.3, US NRC SRP 3.7.2 §II.4, docs/design_basis.md): the soil-structure
analysis runs for a best-estimate (BE), a lower-bound (LB) and an upper-bound (UB) soil. With a
coefficient of variation Cv of the shear modulus (SRP: Cv >= 0.5 for a well-investigated site),

    G_LB = G_BE / (1 + Cv),        G_UB = G_BE (1 + Cv),

at constant density and Poisson's ratio, so vs (and vp) scale by 1/sqrt(1 + Cv) and
sqrt(1 + Cv). The rule applies to every material of the profile, layers and half-space alike;
material damping is kept as stated (the strain-compatible damping when ``strain_compatible``
is given). A case is a SoilProfile: the sweep and fit caches, keyed by the profile, key it.

``[soil] cases`` is either ``{ cv = 0.5 }`` (cases "be", "lb", "ub", in that order) or
``{ profiles = [ { name = "soft", layers = [...], halfspace = {...} }, ... ] }`` (named
profiles typed in full, the first one the reference case of the results file).

``[soil] strain_compatible`` (``StrainCompatibleConfig``) describes the equivalent-linear
free-field analysis that replaces the low-strain vs and damping of each layer by strain-compatible
ones (orchestrator.site_response); the cases are then built on the strain-compatible profile.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import partial

from soil_impedance.profile import SoilProfile
from structure.spec import check_choice, check_keys, check_number, show
from uplift_common.errors import UserInputError


class SoilCaseError(UserInputError):
    """An invalid [soil] cases or strain_compatible table; the message names the key and the fix."""


_keys = partial(check_keys, error=SoilCaseError)
_number = partial(check_number, error=SoilCaseError)
_choice = partial(check_choice, error=SoilCaseError)

#: the smallest coefficient of variation of the shear modulus a case rule accepts (SRP 3.7.2 §II.4:
#: "Cv should not be less than 0.5"), and a sanity limit above which a value is taken for a typo
CV_MIN = 0.5
CV_MAX = 10.0
#: the case names of the Cv rule, in the order they are run and written
CV_CASES = ("be", "lb", "ub")
#: the wave speeds of each case of the Cv rule, as a function of the BE speed and Cv: G / (1 + Cv),
#: G, G (1 + Cv) at constant density, i.e. v / sqrt(1 + Cv), v, v sqrt(1 + Cv)
CV_SPEEDS = {"be": lambda v, cv: v, "lb": lambda v, cv: v / math.sqrt(1.0 + cv), "ub": lambda v, cv: v * math.sqrt(1.0 + cv)}


@dataclass(frozen=True)
class SoilCases:
    """[soil] cases: ``cv`` (the Cv rule: cases be, lb, ub) or ``profiles`` (((name, SoilProfile), ...),
    named profiles given in full); exactly one of the two is set."""

    cv: float | None = None
    profiles: tuple | None = None

    @property
    def names(self) -> tuple[str, ...]:
        return CV_CASES if self.cv is not None else tuple(n for n, _ in self.profiles)


def scaled_profile(profile: SoilProfile, speed) -> SoilProfile:
    """``profile`` with every wave speed v (vs, and vp when given) replaced by ``speed(v)``; density,
    Poisson's ratio, damping and thicknesses kept (so G = rho vs^2 scales by (speed(v)/v)^2)."""
    def scale(m):
        return replace(m, vs=speed(m.vs), vp=None if m.vp is None else speed(m.vp))
    return SoilProfile(tuple(scale(layer) for layer in profile.layers), scale(profile.halfspace))


def case_profiles(cases: SoilCases, base: SoilProfile) -> list:
    """[(case name, SoilProfile)]: the Cv rule applied to ``base`` (the BE profile: the scene's,
    or its strain-compatible version), or the named profiles as given."""
    if cases.cv is None:
        return list(cases.profiles)
    return [(name, base if name == "be" else scaled_profile(base, partial(CV_SPEEDS[name], cv=cases.cv)))
            for name in CV_CASES]


def profile_table(profile: SoilProfile) -> dict:
    """The [soil] keys layers and halfspace of ``profile`` (floats kept exactly): what a scene
    typed by hand with this profile holds."""
    def table(m, thickness=None):
        out = {} if thickness is None else {"thickness": thickness}
        out.update(vs=m.vs, rho=m.rho, damping=m.damping)
        out.update({"nu": m.nu} if m.nu is not None else {})
        out.update({"vp": m.vp} if m.vp is not None else {})
        return out
    return {"layers": [table(layer, layer.thickness) for layer in profile.layers],
            "halfspace": table(profile.halfspace)}


def parse_cases(table, parse_profile) -> SoilCases:
    """[soil] cases: ``{ cv = 0.5 }`` or ``{ profiles = [ { name, layers, halfspace }, ... ] }``;
    ``parse_profile(table, where)`` turns one profile table into a SoilProfile (the scene's parser)."""
    _keys(table, ("cv", "profiles"), "soil.cases")
    if ("cv" in table) == ("profiles" in table):
        raise SoilCaseError("soil.cases: give cv (the rule G/(1+cv), G, G(1+cv): cases be, lb, ub), e.g. "
                            "cases = { cv = 0.5 }, or profiles = [ { name = ..., layers = [...], halfspace = {...} } ]")
    if "cv" in table:
        cv = _number("soil.cases.cv", table["cv"], CV_MIN, CV_MAX, lo_open=False, expect=(
            f"a coefficient of variation of the shear modulus in [{CV_MIN:g}, {CV_MAX:g}] (SRP 3.7.2: "
            "at least 0.5), e.g. 0.5"))
        return SoilCases(cv=float(cv))
    profiles = table["profiles"]
    if not isinstance(profiles, list) or not profiles:
        raise SoilCaseError(f"soil.cases.profiles = {show(profiles)} must be a non-empty list of "
                            "{ name = ..., layers = [...], halfspace = {...} }")
    out = []
    for i, p in enumerate(profiles):
        where = f"soil.cases.profiles[{i}]"
        _keys(p, ("name", "layers", "halfspace"), where, required=("name", "halfspace"))
        name = p["name"]
        if not isinstance(name, str) or not name.isidentifier():
            raise SoilCaseError(f"{where}.name = {show(name)} must be a short name of letters, digits and _, "
                                'e.g. "soft"')
        if name in (n for n, _ in out):
            raise SoilCaseError(f"soil.cases.profiles: the name {name!r} is given twice")
        out.append((name, parse_profile({k: v for k, v in p.items() if k != "name"}, where)))
    return SoilCases(profiles=tuple(out))


# ---- strain-compatible soil -----------------------------------------------------------------

#: the wave field of the scene's motion in the site response: "outcrop" (the motion of the
#: half-space rock at an outcrop, 2 x its incident wave) or "within" (the motion at the top of
#: the half-space, under the layers)
INPUTS = ("outcrop", "within")
CURVE_MODELS = ("darendeli", "table", "linear")
STRAIN_RATIO = 0.65
TOLERANCE = 0.01
MAX_ITERATIONS = 15


@dataclass(frozen=True)
class LayerCurves:
    """Modulus-reduction and damping curves of one layer. model "linear": none (the layer keeps its
    properties); "darendeli": Darendeli (2001), plasticity index ``pi`` (%), over-consolidation
    ratio ``ocr``, at-rest coefficient ``k0`` (the mean effective stress at the layer's middle is
    sigma_v (1 + 2 k0)/3, sigma_v its dry overburden), loading frequency ``freq_hz`` and ``cycles``;
    small-strain damping: the layer's stated damping; "table": ``strain`` (decimal, increasing,
    > 0), ``g_ratio`` (G/Gmax) and ``damping`` (ratio) at those strains (log-linear between them)."""

    model: str = "darendeli"
    pi: float = 0.0
    ocr: float = 1.0
    k0: float = 0.5
    freq_hz: float = 1.0
    cycles: float = 10.0
    strain: tuple = ()
    g_ratio: tuple = ()
    damping: tuple = ()


@dataclass(frozen=True)
class StrainCompatibleConfig:
    """[soil] strain_compatible: input ("outcrop" | "within"), strain_ratio (effective over peak
    strain, in (0, 1]), tolerance (largest relative change of G and damping between iterations that
    stops them), max_iterations, curves (one LayerCurves per layer, top down)."""

    curves: tuple
    input: str = "outcrop"
    strain_ratio: float = STRAIN_RATIO
    tolerance: float = TOLERANCE
    max_iterations: int = MAX_ITERATIONS


def parse_strain_compatible(table, n_layers: int) -> StrainCompatibleConfig:
    """[soil] strain_compatible = { curves = [...one per layer...], input, strain_ratio, tolerance,
    max_iterations }; a curve is "darendeli", "linear", or a table { model = "darendeli", pi, ocr,
    k0, freq_hz, cycles } or { model = "table", strain, g_ratio, damping }."""
    where = "soil.strain_compatible"
    _keys(table, ("curves", "input", "strain_ratio", "tolerance", "max_iterations"), where)
    if n_layers == 0:
        raise SoilCaseError(f"{where}: the profile has no layers (a homogeneous half-space stays linear): remove "
                            "strain_compatible, or give soil.layers")
    curves = table.get("curves", "darendeli")
    if isinstance(curves, str):
        curves = [curves] * n_layers
    if not isinstance(curves, list) or len(curves) != n_layers:
        raise SoilCaseError(f"{where}.curves = {show(curves)} must be one curve per layer ({n_layers}): "
                            '"darendeli", "linear", { model = "darendeli", pi = 15 } or { model = "table", '
                            "strain = [...], g_ratio = [...], damping = [...] }")
    parsed = tuple(_curves(c, f"{where}.curves[{i}]") for i, c in enumerate(curves))
    return StrainCompatibleConfig(
        curves=parsed,
        input=_choice(f"{where}.input", table.get("input", "outcrop"), INPUTS,
                      hint="outcrop: the motion of the rock at an outcrop; within: at the top of the half-space"),
        strain_ratio=float(_number(f"{where}.strain_ratio", table.get("strain_ratio", STRAIN_RATIO), 0.0, 1.0,
                                   expect="an effective over peak strain ratio in (0, 1], e.g. 0.65")),
        tolerance=float(_number(f"{where}.tolerance", table.get("tolerance", TOLERANCE), 0.0, 0.5,
                                expect="a relative change in (0, 0.5], e.g. 0.01")),
        max_iterations=int(_number(f"{where}.max_iterations", table.get("max_iterations", MAX_ITERATIONS), 1, 100,
                                   lo_open=False, integer=True, expect="an integer in [1, 100], e.g. 15")))


def _curves(c, where: str) -> LayerCurves:
    if isinstance(c, str):
        c = {"model": c}
    if not isinstance(c, dict):
        raise SoilCaseError(f"{where} = {show(c)} must be \"darendeli\", \"linear\" or a table {{ model = ... }}")
    model = _choice(f"{where}.model", c.get("model", "darendeli"), CURVE_MODELS)
    if model == "linear":
        _keys(c, ("model",), where)
        return LayerCurves(model="linear")
    if model == "darendeli":
        _keys(c, ("model", "pi", "ocr", "k0", "freq_hz", "cycles"), where)
        return LayerCurves(model="darendeli",
                           pi=float(_number(f"{where}.pi", c.get("pi", 0.0), 0.0, 200.0, lo_open=False,
                                            expect="a plasticity index in [0, 200] %")),
                           ocr=float(_number(f"{where}.ocr", c.get("ocr", 1.0), 1.0, 50.0, lo_open=False,
                                             expect="an over-consolidation ratio in [1, 50]")),
                           k0=float(_number(f"{where}.k0", c.get("k0", 0.5), 0.0, 3.0,
                                            expect="an at-rest earth pressure coefficient in (0, 3]")),
                           freq_hz=float(_number(f"{where}.freq_hz", c.get("freq_hz", 1.0), 0.0, 100.0)),
                           cycles=float(_number(f"{where}.cycles", c.get("cycles", 10.0), 0.0, 1000.0)))
    _keys(c, ("model", "strain", "g_ratio", "damping"), where, required=("strain", "g_ratio", "damping"))
    cols = {}
    for key in ("strain", "g_ratio", "damping"):
        v = c[key]
        if not isinstance(v, list) or len(v) < 2:
            raise SoilCaseError(f"{where}.{key} = {show(v)} must be a list of at least 2 numbers")
        cols[key] = tuple(float(_number(f"{where}.{key}[{i}]", x)) for i, x in enumerate(v))
    if not len(cols["strain"]) == len(cols["g_ratio"]) == len(cols["damping"]):
        raise SoilCaseError(f"{where}: strain, g_ratio and damping must have the same length")
    s = cols["strain"]
    if s[0] <= 0 or any(b <= a for a, b in zip(s, s[1:])):
        raise SoilCaseError(f"{where}.strain must be > 0 and strictly increasing (decimal strains, e.g. 1e-6 ... 1e-2)")
    if any(not 0 < g <= 1 for g in cols["g_ratio"]) or any(not 0 <= d < 0.5 for d in cols["damping"]):
        raise SoilCaseError(f"{where}: g_ratio must lie in (0, 1] and damping in [0, 0.5)")
    return LayerCurves(model="table", **cols)

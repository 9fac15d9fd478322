"""``winkler``: the industrial spring-mattress route (paper §4).

Newmark + penalty contact on Winkler springs, calibrated as ``[soil].winkler`` says: either
subgrade moduli ``{ kv, kh, cv, ch }`` (N/m³, N s/m³ per unit area; the structure keeps its
own damping; no BEM sweep), or a calibration on the BEM:
``{ springs = "rigid" | "nodal", match = "rocking" | "vertical", damping = "rccg" | "dashpots" }``
(the defaults are the first of each):

springs  "rigid": the rigid static impedance K(0) shared by tributary area (paper §4.2, first
         way); "nodal": Diag(K_s22(ω = 0)) of the nodal static impedance (second way).
match    for "rigid": which of the mean rocking or the vertical stiffness is exact. Sharing by
         area cannot match both Kv and Kr of a rigid raft with positive springs (a spring bed
         on a disk has Kr/Kv <= R²/2, the rigid disk 2R²/3); rocking drives uplift (paper §4.2
         matches rocking frequencies), so the vertical stiffness comes out too high, by a
         factor reported in the result's info.
damping  "rccg": composite modal damping (structural ratio on the structure's strain energy
         plus the BEM's directional radiation ratios Im K(f)/(2 K(0)) on the soil's);
         "dashpots": the rigid impedance's dashpots Im K(f1)/ω1 at the first soil-structure
         frequency f1, shared like the springs, with the structure's own damping.

Stepped by the monolithic route's C runtime in process (the springs and dashpots as a rational
model without pole, ``fmus.native_stepper.springs_soil``; the structural damping, RCC-G's included,
passed through), a chunk of steps per call; the Python stepper (``structure.simulate``, the
reference the native one equals to round-off) where no C compiler is available, with a warning
(``info["stepper"]`` says which ran; the route option ``stepper = "python"`` runs it, e.g.
``run_scene(scene, ["winkler"], options={"winkler": {"stepper": "python"}})``).
"""
from __future__ import annotations

import numpy as np

from structure.spec import winkler_from_moduli
from structure.winkler import (modes_on_soil, radiation_ratios, rccg_modal_damping, springs_from_nodal_diagonal,
                               springs_from_rigid_impedance)

from orchestrator.impedance import scene_static
from orchestrator.routes.base import Route, RouteInputError, register
from orchestrator.routes.monolithic import step_scene

#: RCC-G composite modal damping acts on the whole building's motion relative to the free field,
#: rocking included, and keeps acting once the raft lifts (soil dashpots that pull): it holds the
#: raft down. Fine while uplift is a perturbation (reactor 0.25 g, ~50 % lifted: 2.63 mm against
#: 2.49 mm for the TF/BEM reference); on a small tower lifting 75 % of its nodes the BEM routes
#: and detaching dashpots give 1.6-4x its uplift at 0.25-2 g
RCCG_UPLIFT_LIMIT = 0.6
RCCG_WARNING = ("RCC-G modal damping with {:.0f} % of the interface nodes lifted at once: this damping "
                "keeps acting on the lifted raft and underestimates large uplift; compare with "
                "[soil].winkler = {{ damping = \"dashpots\" }} or the monolithic route")


def winkler_soil(scene, model, table=None, cache_dir=None):
    """(WinklerSoil, structural damping for simulate or None, info) of the scene's
    ``[soil].winkler`` (see the module docstring); ``table`` is the scene's rigid impedance
    table (needed unless the moduli are explicit)."""
    cfg = scene.winkler
    xy, area = scene.mesh.xy, scene.mesh.area
    if cfg.explicit:
        return winkler_from_moduli(cfg.moduli, xy, area), None, {
            "springs": "soil.winkler subgrade moduli", "soil_damping": "soil.winkler dashpots"}
    if table is None or table.frequencies_hz[0] != 0.0:
        raise RouteInputError("the winkler route calibrates its springs on K(0): include 0 Hz in "
                              "[impedance] (range_hz = [0.0, fmax, count])")
    K6 = scene.profile.static_to_reference * np.real(table.matrices[0])
    soil, label, kdiag = calibrated_springs(scene, K6, cache_dir)
    f1 = float(modes_on_soil(model, soil).freq[0])
    info = {"springs": label,
            "winkler_over_bem_static": (np.diag(soil.rigid_stiffness()) / np.diag(K6)).tolist(),
            "first_soil_structure_hz": f1}
    if cfg.damping == "dashpots":
        C6 = np.imag(table.at(f1)) / (2 * np.pi * f1)
        if cfg.springs == "rigid":
            soil = springs_from_rigid_impedance(K6, xy, area, C6=C6, match=cfg.match)
        else:
            soil = springs_from_nodal_diagonal(kdiag, xy, cdiag=_nodal_dashpots(C6, area))
        info["soil_damping"] = f"rigid impedance dashpots at {f1:.3g} Hz"
        return soil, None, info
    ratio = model.damping.ratio if model.damping.kind == "modal" else 0.0
    C, modes = rccg_modal_damping(model, soil, structure_ratio=ratio,
                                  radiation=radiation_ratios(table.frequencies_hz, table.matrices))
    info.update({"soil_damping": "RCC-G composite modal damping",
                 "modes_on_soil_hz": modes.freq[:6].tolist(), "modal_damping": modes.ratio[:6].tolist()})
    return soil, C, info


def calibrated_springs(scene, K6, cache_dir=None):
    """(WinklerSoil without dashpots, label, the nodal diagonal (3N,) or None) of the scene's
    ``[soil].winkler`` calibrated on the BEM at the moduli rho vs^2 (a causal soil's K(0) is
    relaxed): the static rigid impedance ``K6`` (6, 6), already at those moduli, shared by area
    ("rigid"), or the diagonal of the nodal static impedance (``scene_static``; "nodal")."""
    cfg = scene.winkler
    if cfg.springs == "rigid":
        return (springs_from_rigid_impedance(K6, scene.mesh.xy, scene.mesh.area, match=cfg.match),
                f"rigid static impedance, {cfg.match} matched", None)
    kdiag = scene.profile.static_to_reference * np.diag(scene_static(scene, "nodal", cache_dir))
    return springs_from_nodal_diagonal(kdiag, scene.mesh.xy), "nodal static impedance diagonal", kdiag


def static_springs(scene, cache_dir=None):
    """(WinklerSoil, label): the springs of the scene's ``[soil].winkler`` as ``winkler_soil``
    calibrates them, without dashpots (what a static analysis needs): the subgrade moduli, or
    ``calibrated_springs`` on the static rigid impedance K(0) (``scene_static``)."""
    cfg = scene.winkler
    if cfg.explicit:
        return winkler_from_moduli(cfg.moduli, scene.mesh.xy, scene.mesh.area), "soil.winkler subgrade moduli"
    K6 = None if cfg.springs != "rigid" else \
        scene.profile.static_to_reference * np.real(scene_static(scene, "rigid", cache_dir))
    soil, label, _ = calibrated_springs(scene, K6, cache_dir)
    return soil, label


def _nodal_dashpots(C6, area):
    """(3N,) nodal dashpots: the rigid translational dashpots shared by area (ux, uy, uz per node)."""
    w = np.asarray(area) / np.sum(area)
    return np.column_stack([C6[0, 0] * w, C6[1, 1] * w, C6[2, 2] * w]).ravel()


def _springs_soil(soil, dt):
    from fmus.native_stepper import springs_soil    # the FMU stack: only when the native stepper runs
    return springs_soil(soil, dt)


def run(ctx, progress=None):
    scene, model = ctx.scene, ctx.model()
    soil, damping, info = winkler_soil(scene, model, ctx.tables.get("rigid"), ctx.cache_dir)
    res = step_scene(scene, model, soil, ctx.motion, route="winkler", progress=progress, cache_dir=ctx.cache_dir,
                     stepper=ctx.options.get("stepper", "native"), damping=damping, as_native=_springs_soil)
    warnings = []
    if damping is not None and res.gap.size and res.uplift_fraction().max() > RCCG_UPLIFT_LIMIT:
        warnings.append(RCCG_WARNING.format(100 * res.uplift_fraction().max()))
    skipped = ["soil.winkler subgrade moduli given: no BEM impedance sweep"] if scene.winkler.explicit else []
    return res.with_notes(skipped=skipped, warnings=warnings, info=info)


ROUTE = register(Route(
    name="winkler",
    summary="TD-Winkler: spring-and-dashpot mattress calibrated on the BEM static impedance, "
            "Newmark + penalty contact (paper §4, the industrial route)",
    run=run,
    tables=lambda scene: () if scene.winkler.explicit else ("rigid",),
    options=("stepper",),
    bench={"disk-halfspace": {"dt": (0.01, 0.005, 0.0025, 0.00125), "penalty": (0.1, 1.0, 10.0),
                              "element_size": (3.0, 2.0, 1.5)},
           "reactor": {"dt": (0.01, 0.005, 0.0025, 0.00125), "penalty": (0.1, 1.0, 10.0),
                       "element_size": (4.0, 3.0, 2.28)}},
    quick={"disk-halfspace": {"dt": (0.01, 0.005, 0.0025), "penalty": (0.1, 1.0)}},
))

"""Penalty unilateral contact between the rigid raft and the soil, on the total force.

At interface node i the relative vertical displacement (dynamic perturbation) is
d_i = (uz + rx y_i - ry x_i) - w_i (raft above soil positive). With delta0_i the static
penetration (delta0_i = P0_i / kp_i when in contact at rest):

    P_i = kp_i max(0, delta0_i - d_i)     total compressive contact force, N
    p_i = P_i - P0_i                      dynamic part
    g_i = max(0, d_i - delta0_i)          gap (uplift), m

The contact acts on the raft with +P_i (upwards) and on the soil node with -P_i. As an
internal-force vector on x = [q, w]: f_c = -B^T (P - P0), B (N, 6+N) = [Bq, -I].

Penalty "auto": kp_i = auto_factor * K(0)[w_i, w_i] (default AUTO_FACTOR), the soil's local
static vertical stiffness under node i. The soil spring and the penalty act in series, so the contact
softens the soil by 1/(1 + AUTO_FACTOR) = 1e-4; multiplying kp by 10 moves the results by
less than that (measured in tests/structural/test_contact_penalty.py).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

AUTO_FACTOR = 1.0e4


@dataclass(frozen=True)
class ContactSettings:
    """enabled: unilateral contact (False: raft bonded to the soil through the same penalty
    springs, linear). penalty: "auto" or kp per node, N/m; auto_factor: kp / local soil static
    stiffness for "auto". Newton: tol (relative residual),
    max_iter per (sub)step, max_subdiv halvings of the step (min step dt / 2**max_subdiv).

    precheck: ``simulate`` first runs the closed-contact (linear) problem, one factorisation
    for the whole run; if no node goes into tension (the gap never opens) that IS the
    unilateral solution, because the penalty law is linear while closed, and it is returned
    without Newton. At the first step with tension it falls back to the full nonlinear run
    from t = 0 (same result as precheck=False). False forces the nonlinear machinery (scene
    key ``[contact] precheck = false``). Steppers driven one step at a time (FMUs) cannot
    look ahead and ignore it."""
    enabled: bool = True
    penalty: object = "auto"
    auto_factor: float = AUTO_FACTOR
    tol: float = 1e-9
    max_iter: int = 25
    max_subdiv: int = 6
    precheck: bool = True


def penalty_stiffness(settings: ContactSettings, soil_static, n: int) -> np.ndarray:
    """kp (N,), N/m, from the settings and the soil static stiffness K(0) (6+N, 6+N)."""
    if isinstance(settings.penalty, str):
        d = np.asarray(soil_static.diagonal() if hasattr(soil_static, "diagonal")
                       else np.diag(soil_static), float)[6:6 + n]
        ref = np.where(d > 0, d, d.max() if d.max() > 0 else 1.0)
        return settings.auto_factor * ref
    return np.broadcast_to(np.asarray(settings.penalty, float), (n,)).copy()


def contact_force(d, delta0, kp):
    """P (N,) total contact force and the active mask for relative displacements d (N,)."""
    pen = delta0 - d
    active = pen > 0
    return np.where(active, kp * pen, 0.0), active


def gap(d, delta0):
    """g (N,) >= 0, m."""
    return np.maximum(0.0, d - delta0)

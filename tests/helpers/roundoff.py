"""Round-off sensitivity of a run, for comparing two implementations of the same equations (the
native stepper against the Python one): "equal to 1e-10" is a property of the scene, not of the
code. A raft that lifts and rocks strongly amplifies round-off (a contact that opens one step
earlier or later in one run than in the other), so two steppers whose operations differ only in
their order drift apart by more than 1e-10 there while being the same equations.

``roundoff_spread(run, ag)`` measures that amplification on the reference: ``run`` repeated with
the ground acceleration scaled by 1 + k eps (k = +1, -1, +2, -2, ...: ``n`` runs, eps = 1e-14,
a change of the input of the size of its round-off), giving per compared history its spread, the
largest ``rel`` of a perturbed run to the unperturbed one. ``assert_within_spread(res, ref,
spread)`` then holds each history of ``res`` to ``max(floor, factor * spread)`` of ``ref``: the
floor (1e-10) on a mild scene, a small multiple of the measured spread where the scene amplifies
round-off (FACTOR: why 100). A change of the equations (a coefficient off by 1e-6) moves the
histories by far more than round-off does, and still fails.

The histories of a RouteResult are named raft, gap, contact_force, soil_w, acc.<node>,
disp.<node>, energy.<term> (``histories``); a mapping of arrays is taken as it is.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from .checks import rel

#: the size of the input's perturbation (relative), the multiple of the spread a difference may
#: reach, the tolerance on a scene that does not amplify round-off. FACTOR from measurements
#: (2 cores, AVX2 build, the scenes of tests/fmu/test_native_*.py): the native and the Python
#: stepper differ by 4 to 28 times the spread on every history above the floor, two paths of the
#: C stepper by 1 to 2 times (scaling the input leaves each language's LU factors, so the part of
#: the round-off they make, the same in every perturbed run: the spread sees the amplification,
#: not that part); one coefficient of the C stepper changed by 1e-6 moves a history by 1.8e5
#: times its spread or more
EPS, FACTOR, FLOOR = 1e-14, 100.0, 1e-10


def histories(res) -> dict:
    """{name: array} of a RouteResult's compared histories (a mapping: as it is)."""
    if isinstance(res, Mapping):
        return {k: np.asarray(v) for k, v in res.items()}
    out = {name: getattr(res, name) for name in ("raft", "gap", "contact_force", "soil_w")}
    out.update({f"acc.{nm}": a for nm, a in res.acc.items()})
    out.update({f"disp.{nm}": d for nm, d in res.disp.items()})
    out.update({f"energy.{k}": e for k, e in res.energy.items()})
    return out


def scales(n: int = 3, eps: float = EPS) -> list:
    """The n factors 1 + k eps, k = +1, -1, +2, -2, ..."""
    ks = [sign * k for k in range(1, n // 2 + 2) for sign in (1, -1)][:n]
    return [1.0 + k * eps for k in ks]


@dataclass(frozen=True)
class Spread:
    """The unperturbed run ``base``, the factors of the perturbed runs and, per history, the
    largest rel of a perturbed run to ``base`` (``rel``)."""
    base: object
    factors: tuple
    rel: dict

    def tol(self, name: str, factor: float = FACTOR, floor: float = FLOOR) -> float:
        """max(floor, factor * spread of ``name``)."""
        return max(floor, factor * self.rel[name])

    def largest(self) -> tuple:
        """(name, spread) of the history that spreads most."""
        name = max(self.rel, key=self.rel.get)
        return name, self.rel[name]


def roundoff_spread(run, ag, n: int = 3, eps: float = EPS, base=None) -> Spread:
    """``run(ag)`` (-> a RouteResult or a mapping of arrays) and ``n`` runs under ``ag`` scaled
    by 1 + k eps (``scales``): the spread of each history (see the module). base : ``run(ag)``
    when the caller has it already (not run again)."""
    ag = np.asarray(ag, float)
    base = run(ag) if base is None else base
    ref = histories(base)
    spread = dict.fromkeys(ref, 0.0)
    factors = scales(n, eps)
    for f in factors:
        got = histories(run(ag * f))
        for name, a in ref.items():
            spread[name] = max(spread[name], rel(got[name], a))
    return Spread(base, tuple(factors), spread)


def within_spread(res, ref, spread: Spread, factor: float = FACTOR, floor: float = FLOOR) -> dict:
    """{name: (rel(res, ref), its tolerance max(floor, factor * spread))} over the histories of
    ``ref``."""
    got, want = histories(res), histories(ref)
    return {name: (rel(got[name], a), spread.tol(name, factor, floor)) for name, a in want.items()}


def assert_within_spread(res, ref, spread: Spread, factor: float = FACTOR, floor: float = FLOOR):
    """Each history of ``res`` within max(floor, factor * its spread) of ``ref`` (the message
    names the histories beyond it, with the difference, the tolerance and the spread)."""
    checks = within_spread(res, ref, spread, factor, floor)
    bad = {name: (d, t) for name, (d, t) in checks.items() if not d <= t}
    assert not bad, "beyond round-off: " + "; ".join(
        f"{name} {d:.3g} > {t:.3g} (spread {spread.rel[name]:.3g})" for name, (d, t) in bad.items())
    return checks

"""The split coupling that makes the pair of FMUs exact under any master (docs/formulation.md).

The force on the soil at step k is f_k = K0 x_k + C0 xdot_k + h_k with h_k depending on the past
only. For a linear soil, h_{k+1} = g_{k+1} + Gx x_k + Gv xdot_k where g_{k+1} depends on the
states up to k - 1 only: the soil FMU publishes g (``history_ahead``), the structure FMU adds
the part driven by its own latest state with the constant gains (``history_gains``, measured at
export). A parallel (Jacobi) master hands the structure the soil's g one step after the soil
computed it, which is exactly when it is needed, so the pair is exact under Jacobi; the time
stamps x_time and g_time (``StampedInput``) make it exact under either sequential
(Gauss-Seidel) order too.
"""
from __future__ import annotations

import numpy as np

from fmus.schema import TIME_TOL, message
from uplift_common.errors import UserInputError


#: relative asymmetry (to the largest entry) up to which a measured gain is round-off of a symmetric one
SYMMETRY_RTOL = 1e-14


def history_gains(soil, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(Gx, Gv), each (n, n): how the history force of the step after next depends on the next
    committed state, h_{k+2} = g_{k+2} + Gx x_{k+1} + Gv xdot_{k+1}. Constant for a linear soil
    at a fixed dt: from the soil's own ``history_gains()`` when it has one (the recursive
    convolution's closed form), else measured (``measured_gains``), once at export. Gx is made
    exactly symmetric when it is to round-off (SYMMETRY_RTOL; the residues of a reciprocal
    soil are symmetric): the native structure FMU then reads half of it per step (and skips Gv
    when it is zero, as for the recursive convolution, whose history does not depend on
    xdot)."""
    if hasattr(soil, "history_gains"):
        soil.instantaneous(dt)
        Gx, Gv = soil.history_gains()
    else:
        Gx, Gv = measured_gains(soil, dt)
    if np.abs(Gx - Gx.T).max() <= SYMMETRY_RTOL * np.abs(Gx).max():
        Gx = 0.5 * (Gx + Gx.T)          # a reciprocal soil's gain, symmetric to round-off: exactly so
    return Gx, Gv


def measured_gains(soil, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """history_gains' (Gx, Gv) measured on a soil at rest (where g = 0) by committing unit
    states: 2n commits. The soil is left at rest."""
    n = soil.n_dof
    soil.instantaneous(dt)
    rest = soil.get_state()
    zero, e = np.zeros(n), np.zeros(n)
    Gx, Gv = np.empty((n, n)), np.empty((n, n))
    for i in range(n):
        e[i] = 1.0
        for G, state in ((Gx, (e, zero)), (Gv, (zero, e))):
            soil.set_state(rest)
            soil.commit(*state)
            G[:, i] = soil.history()
        e[i] = 0.0
    soil.set_state(rest)
    return Gx, Gv


def history_ahead(soil) -> np.ndarray:
    """g_{k+2} (n,), N: the history force of the step after next with a zero state committed
    next, i.e. the part of h_{k+2} that does not depend on x_{k+1}, xdot_{k+1}. The soil is
    left as it was."""
    saved = soil.get_state()
    zero = np.zeros(soil.n_dof)
    soil.commit(zero, zero)
    g = soil.history()
    soil.set_state(saved)
    return g


class StepRefused(UserInputError):
    """A call the FMU refuses (wrong time, step size or state, non-finite input, a wrong stamp):
    the call fails with this message, the instance is left as it was."""


class StampedInput:
    """An input vector sent with the time it belongs to (the partner FMU's own time), so that
    one FMU is exact under any master.

    At a step from t, a parallel (Jacobi) master hands over the partner's outputs at t; a
    sequential (Gauss-Seidel) master that stepped the partner first hands over its outputs at
    t + dt. The stamp tells which: values of t are used now; values of t + dt are held for the
    next step and the values held from the previous step (those of t) are used now. Both FMUs
    start at rest, so the values held at t = 0 are ``rest``. Any other stamp is a wiring error.
    """

    def __init__(self, name: str, stamp_name: str, rest):
        self.name, self.stamp_name = name, stamp_name
        self.held_t, self.held = 0.0, np.array(rest, float)

    def take(self, t: float, dt: float, stamp: float, values) -> np.ndarray:
        stamp, tol = float(stamp), TIME_TOL * dt
        if abs(stamp - t) <= tol:
            return values
        if abs(stamp - (t + dt)) <= tol and abs(self.held_t - t) <= tol:
            used, self.held_t, self.held = self.held, float(stamp), np.array(values, float)
            return used
        raise StepRefused(message("stamp", name=self.name, stamp_name=self.stamp_name, stamp=repr(stamp),
                                  t=repr(t)))

    def get_state(self) -> dict:
        return {"t": self.held_t, "values": self.held.copy()}

    def set_state(self, state: dict) -> None:
        self.held_t, self.held = float(state["t"]), np.array(state["values"], float)

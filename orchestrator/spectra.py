"""Response spectra by the Nigam-Jennings recurrence (exact for piecewise-linear input).

For a unit-mass oscillator ü + 2ζω u̇ + ω² u = −a_g(t), the state (u, u̇) at t_{n+1} follows
from the state at t_n and the two input samples exactly when a_g is linear over the step
(Nigam & Jennings 1969; coefficients as in Chopra, Dynamics of Structures, Table 5.2.1).
"""
from __future__ import annotations

import ctypes
import sys
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Spectrum:
    """Response spectrum at one damping ratio.

    periods : (P,) s; sd : (P,) m; psv : (P,) m/s = ω sd; psa : (P,) m/s² = ω² sd;
    sa : (P,) m/s² peak absolute acceleration.
    """

    periods: np.ndarray
    damping: float
    sd: np.ndarray
    psv: np.ndarray
    psa: np.ndarray
    sa: np.ndarray

    @property
    def frequencies(self) -> np.ndarray:
        return 1.0 / self.periods


def _coefficients(omega, zeta, dt):
    """Recurrence matrices so that [u, v]_{n+1} = A [u, v]_n + B0 p_n + B1 p_{n+1}, p = −a_g."""
    wd = omega * np.sqrt(1.0 - zeta ** 2)
    e = np.exp(-zeta * omega * dt)
    s, c = np.sin(wd * dt), np.cos(wd * dt)
    r = zeta / np.sqrt(1.0 - zeta ** 2)
    k = omega ** 2
    a11 = e * (r * s + c)
    a12 = e * s / wd
    a21 = -e * omega / np.sqrt(1.0 - zeta ** 2) * s
    a22 = e * (c - r * s)
    b0u = (2 * zeta / (omega * dt) + e * (((1 - 2 * zeta ** 2) / (wd * dt) - r) * s
                                           - (1 + 2 * zeta / (omega * dt)) * c)) / k
    b1u = (1 - 2 * zeta / (omega * dt) + e * ((2 * zeta ** 2 - 1) / (wd * dt) * s
                                               + 2 * zeta / (omega * dt) * c)) / k
    b0v = (-1.0 / dt + e * ((omega / np.sqrt(1 - zeta ** 2) + r / dt) * s + c / dt)) / k
    b1v = (1.0 - e * (r * s + c)) / (k * dt)
    return a11, a12, a21, a22, b0u, b1u, b0v, b1v


#: steps whose input terms and states are held at once by ``response_spectra``
_CHUNK = 256


def response_spectrum(acc, dt: float, periods, damping: float = 0.05) -> Spectrum:
    """Response spectrum of an acceleration history.

    Parameters
    ----------
    acc : array, shape (nt,), m/s² (any consistent unit: sd then scales with it)
    dt : float, s          sampling step (the input is linear between samples)
    periods : array, (P,) s, > 0
    damping : float        ratio of critical damping, in [0, 1)
    """
    acc = np.asarray(acc, float)
    if acc.ndim != 1:
        raise ValueError("response_spectrum: acc must be a 1-D history with at least 2 samples")
    return response_spectra(acc[:, None], dt, periods, damping)[0]


def response_spectra(acc, dt: float, periods, damping: float = 0.05) -> list:
    """Response spectra of the m histories acc (nt, m) (columns), in one pass over time: the
    same recurrence as ``response_spectrum`` on (m, P) arrays (each column's numbers are those
    of its own ``response_spectrum``). Returns a list of m Spectrum."""
    acc = np.asarray(acc, float)
    periods = np.asarray(periods, float)
    if acc.ndim != 2 or acc.shape[0] < 2:
        raise ValueError("response_spectrum: acc must be a 1-D history with at least 2 samples")
    if np.any(periods <= 0) or not (0.0 <= damping < 1.0) or dt <= 0:
        raise ValueError("response_spectrum: periods and dt must be > 0 and damping in [0, 1)")
    omega = 2 * np.pi / periods
    a11, a12, a21, a22, b0u, b1u, b0v, b1v = _coefficients(omega, damping, dt)
    shape = (acc.shape[1], omega.size)
    cv, cu = 2 * damping * omega, omega ** 2
    native = _native()
    if native is not None:                                 # the same loop in C: the same bits
        coef = np.ascontiguousarray(np.broadcast_arrays(a11, a12, a21, a22, b0u, b1u, b0v, b1v, cv, cu), float)
        umax, amax = np.empty(shape), np.empty(shape)
        a = np.ascontiguousarray(acc)
        native(a.shape[0], shape[0], shape[1], a.ctypes.data, coef.ctypes.data, umax.ctypes.data, amax.ctypes.data)
        return _spectra(periods, damping, omega, umax, amax)
    p = -acc[:, None, :, None]                             # (nt, 1, m, 1)
    diag, off = np.stack([a11, a22])[:, None], np.stack([a12, a21])[:, None]     # (2, 1, P)
    b0, b1 = np.stack([b0u, b0v])[:, None], np.stack([b1u, b1v])[:, None]
    x = np.zeros((2, *shape))                              # (u, v) of every oscillator
    umax, amax = np.zeros(shape), np.zeros(shape)
    for k0 in range(0, acc.shape[0] - 1, _CHUNK):          # memory: _CHUNK steps of (2, m, P) at a time
        k1 = min(k0 + _CHUNK, acc.shape[0] - 1)
        in0, in1 = b0 * p[k0:k1], b1 * p[k0 + 1:k1 + 1]    # the input terms of the chunk's steps
        xs = np.empty((k1 - k0, 2, *shape))
        for n in range(k1 - k0):                           # only the recurrence steps one by one: u = a11 u
            x = diag * x + off * x[::-1] + in0[n] + in1[n]     # + a12 v + b0u p_n + b1u p_n+1, v likewise
            xs[n] = x
        np.maximum(umax, np.abs(xs[:, 0]).max(axis=0), out=umax)
        np.maximum(amax, np.abs(cv * xs[:, 1] + cu * xs[:, 0]).max(axis=0), out=amax)
    return _spectra(periods, damping, omega, umax, amax)


def _spectra(periods, damping, omega, umax, amax) -> list:
    return [Spectrum(periods, damping, umax[j], omega * umax[j], omega ** 2 * umax[j], amax[j])
            for j in range(umax.shape[0])]


def _native():
    """The native runtime's ``up_response_spectra`` (fmus/native/spectra.c, the loop of
    ``response_spectra`` in C: the same bits, about twenty times faster) when this process has
    loaded the in-process library already (a run of a native route: ``fmus.native_stepper
    .loaded_library``), else None: the numpy loop, nothing compiled or imported for it."""
    stepper = sys.modules.get("fmus.native_stepper")
    lib = None if stepper is None else stepper.loaded_library()
    fn = getattr(lib, "up_response_spectra", None) if lib is not None else None
    if fn is not None and fn.argtypes is None:
        i64, p = ctypes.c_int64, ctypes.c_void_p
        fn.restype, fn.argtypes = None, [i64, i64, i64, p, p, p, p]
    return fn


#: floor response spectra of a run (results file, report figures, ensemble cells): frequencies
#: (Hz), ratio of critical damping, and the share of a node's peak acceleration below which a
#: direction is round-off (e.g. y under an x motion of a symmetric structure: no spectrum)
FLOOR_FREQUENCIES_HZ = np.geomspace(0.5, 40.0, 120)
FLOOR_DAMPING = 0.05
ROUNDOFF = 1e-6


def excited(acc) -> np.ndarray:
    """(3,) bool: the columns of ``acc`` (nt, 3) above round-off (``ROUNDOFF`` of its peak)."""
    acc = np.asarray(acc, float)
    return np.abs(acc).max(axis=0, initial=0.0) > ROUNDOFF * np.abs(acc).max(initial=0.0)


def floor_spectra(acc: dict, dt: float, names=None, frequencies=FLOOR_FREQUENCIES_HZ,
                  damping: float = FLOOR_DAMPING) -> np.ndarray:
    """Pseudo-acceleration floor spectra (len(names), 3, F), m/s², of the histories
    ``acc`` {name: (nt, 3) m/s²} sampled at ``dt`` (s), at ``frequencies`` (F,) Hz, in one pass
    over time; NaN for a name missing from ``acc`` and in round-off directions (``excited``).
    ``names``: default, those of ``acc`` in order."""
    names = list(acc) if names is None else list(names)
    frequencies = np.asarray(frequencies, float)
    out = np.full((len(names), 3, frequencies.size), np.nan)
    which, columns = [], []
    for i, name in enumerate(names):
        a = acc.get(name)
        if a is None or np.shape(a)[0] < 2:
            continue
        for j in np.flatnonzero(excited(a)):
            which.append((i, j))
            columns.append(np.asarray(a)[:, j])
    if columns:
        for (i, j), sp in zip(which, response_spectra(np.stack(columns, axis=1), dt, 1 / frequencies, damping)):
            out[i, j] = sp.psa
    return out


def broaden(freqs, values, ratio: float = 0.15):
    """Peak broadening of a floor spectrum by ±ratio in frequency (envelope of the shifted curves).

    freqs : (P,) increasing, Hz; values : (P,) spectrum ordinates.
    """
    freqs = np.asarray(freqs, float)
    values = np.asarray(values, float)
    out = values.copy()
    # each ordinate S(f_k) is spread over [f_k (1 - ratio), f_k (1 + ratio)]
    for k in range(freqs.size):
        window = (freqs >= freqs[k] * (1 - ratio)) & (freqs <= freqs[k] * (1 + ratio))
        out[window] = np.maximum(out[window], values[k])
    return out

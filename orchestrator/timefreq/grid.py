"""The time-frequency grid: zero padding, exponential window, FFTs through pyfftw.

A causal signal x(t) on t_k = k dt, k < nt, is zero-padded to nfft samples, weighted by
e^{-eta t} and transformed (rfft). A transfer function H is applied at the complex frequency
s_k = i w_k + eta (w_k = 2 pi k / (nfft dt)), i.e. at w_k - i eta in the e^{+iwt} convention,
and the inverse transform is multiplied back by e^{+eta t}. This computes the causal
(linear, not circular) convolution of x with the impulse response of H on [0, nfft dt) up to
wrap-around terms h(t + nfft dt) e^{-eta nfft dt}: the window damps what wraps around, the
padding lets the physical response decay first (Kausel & Roesset's complex-frequency method).

Padding rule (``Grid.build``): nfft dt >= T + pad_s with pad_s >= max(1 s, 3 tau_1), tau_1 =
1 / (xi_1 w_1) the decay time of the slowest fixed-base mode, and eta = ln(1/wrap_tol) /
(nfft dt) (default wrap_tol = 1e-4): what wraps around is damped by e^{-3} from the physics
and by wrap_tol from the window. A longer pad keeps the rule's eta (the window changes how
sampled input near Nyquist is interpolated, an O(eta dt) effect on the feedthrough, so eta is
held fixed when only the padding varies). Undoing the window amplifies round-off by at most
e^{eta T} < 1/wrap_tol, and so it does any non-causal part of H (a hysteretic table's
Im K ~ sign(w)): h(-tau) comes back at the end of the padded record times e^{eta (nfft dt -
tau)}. Without the window (eta = 0, ``GridOptions(window=False)``, the linear route's
default) the physics alone must damp the wrap-around: pad_s >= max(1 s, ln(1/wrap_tol) tau_1),
and nothing is amplified.

``bilinear=True`` replaces s by the trapezoidal (Newmark average-acceleration) operator
s_d = (2/dt)(z - 1)/(z + 1) at z = e^{s dt}: the frequency-domain solution then equals the
Newmark one at the samples (for a_g(0) = 0, zero initial state).
"""
from __future__ import annotations

import sys
import threading
from dataclasses import dataclass

import numpy as np


def _import_pyfftw():
    """pyfftw without dask: its package init imports pyfftw.interfaces, which imports dask.array
    (and xarray with it, ~0.9 s) when dask is installed, only to offer a dask interface the
    solver never uses. The import of dask.array.fft is refused while pyfftw loads (unless dask
    is loaded already), and allowed again after."""
    block = "pyfftw" not in sys.modules and "dask.array.fft" not in sys.modules
    if block:
        sys.modules["dask.array.fft"] = None          # an import of it raises ImportError
    try:
        # here, not at the top: the import must run with dask.array.fft refused
        import pyfftw
        import pyfftw.builders  # (the same reason)
    finally:
        if block and sys.modules.get("dask.array.fft", 0) is None:
            del sys.modules["dask.array.fft"]
    return pyfftw, pyfftw.builders


pyfftw, fb = _import_pyfftw()

#: FFTW plans per thread (a plan owns its input buffer: two threads transforming through one
#: plan would write each other's data)
_PLANS = threading.local()


def _fast_len(n: int) -> int:
    """Smallest 2^a 3^b 5^c >= n (FFTW is fast on those)."""
    best = 1 << (int(n - 1).bit_length())
    p5 = 1
    while p5 < best:
        p35 = p5
        while p35 < best:
            m = p35
            while m < n:
                m *= 2
            best = min(best, m)
            p35 *= 3
        p5 *= 5
    return best


def _plan(kind: str, shape: tuple, nfft: int):
    """Cached pyfftw builder for rfft/irfft of a C-contiguous array along the last axis (one
    cache per thread)."""
    plans = _PLANS.__dict__.setdefault("cache", {})
    key = (kind, shape, nfft)
    plan = plans.get(key)
    if plan is None:
        if kind == "r":
            a = pyfftw.empty_aligned(shape[:-1] + (nfft,), dtype="float64")
            plan = fb.rfft(a, n=nfft, axis=-1, planner_effort="FFTW_ESTIMATE", threads=1,
                           avoid_copy=False)
        else:
            a = pyfftw.empty_aligned(shape[:-1] + (nfft // 2 + 1,), dtype="complex128")
            plan = fb.irfft(a, n=nfft, axis=-1, planner_effort="FFTW_ESTIMATE", threads=1,
                            avoid_copy=False)
        if len(plans) > 64:
            plans.pop(next(iter(plans)))
        plans[key] = plan
    return plan


@dataclass(frozen=True, eq=False)
class Grid:
    """nt samples at dt (s) padded to nfft; eta (1/s) window rate; s (F,) complex, the
    continuous or bilinear Laplace variable at the F = nfft/2 + 1 FFT frequencies."""

    nt: int
    dt: float
    nfft: int
    eta: float
    bilinear: bool = False

    @classmethod
    def build(cls, nt: int, dt: float, pad_s: float = 3.0, wrap_tol: float = 1e-4,
              bilinear: bool = False, nfft: int | None = None, eta_pad_s: float | None = None) -> Grid:
        """eta_pad_s: the padding (s) that sets eta (default pad_s): a longer pad than the
        rule keeps the rule's eta, so that only the wrap-around changes with the padding."""
        if nfft is None:
            nfft = _fast_len(nt + int(np.ceil(pad_s / dt)))
        if nfft < nt:
            raise ValueError(f"nfft = {nfft} is shorter than the signal ({nt} samples)")
        n_eta = nfft if eta_pad_s is None else min(nfft, _fast_len(nt + int(np.ceil(eta_pad_s / dt))))
        eta = np.log(1.0 / wrap_tol) / (n_eta * dt)
        return cls(int(nt), float(dt), int(nfft), float(eta), bool(bilinear))

    @property
    def n_freq(self) -> int:
        return self.nfft // 2 + 1

    @property
    def freq_hz(self) -> np.ndarray:
        return np.arange(self.n_freq) / (self.nfft * self.dt)

    @property
    def s(self) -> np.ndarray:
        """(F,) complex, 1/s: i w + eta, or the trapezoidal s_d at z = e^{(i w + eta) dt}."""
        sc = 2j * np.pi * self.freq_hz + self.eta
        if not self.bilinear:
            return sc
        z = np.exp(sc * self.dt)
        return 2.0 / self.dt * (z - 1.0) / (z + 1.0)

    @property
    def warped_hz(self) -> np.ndarray:
        """(F,) the real frequency each grid point stands for: f, or on a bilinear grid its
        trapezoidal image tan(pi f dt) / (pi dt) (~1e16 / (pi dt) at Nyquist, where s_d is
        real: Re(s_d / 2 pi i) is no frequency there)."""
        f = self.freq_hz
        return np.tan(np.pi * f * self.dt) / (np.pi * self.dt) if self.bilinear else f

    @property
    def z(self) -> np.ndarray:
        return np.exp((2j * np.pi * self.freq_hz + self.eta) * self.dt)

    def _weights(self, n):
        return np.exp(-self.eta * self.dt * np.arange(n))

    def plans(self, rows: int):
        """(forward, inverse): the cached pyfftw plans of to_freq and to_time for (rows, nfft)
        real <-> (rows, F) complex (one pair per thread), for callers that fill input_array in
        place and read the call's output_array (valid until the plan's next call in the thread):
        no window, no padding, no copies."""
        return _plan("r", (rows, self.nfft), self.nfft), _plan("c", (rows, self.n_freq), self.nfft)

    def to_freq(self, x) -> np.ndarray:
        """x (..., nt) real -> X (..., F) complex (padded, windowed rfft)."""
        x = np.asarray(x, float)
        shape = x.shape[:-1] + (self.nfft,)
        plan = _plan("r", shape, self.nfft)
        buf = plan.input_array
        buf[...] = 0.0
        n = min(x.shape[-1], self.nfft)
        buf[..., :n] = x[..., :n] * self._weights(n)
        return plan().copy()

    def to_time(self, X, n: int | None = None) -> np.ndarray:
        """X (..., F) complex -> x (..., n) real (default n = nt), window undone."""
        n = self.nt if n is None else n
        X = np.asarray(X, complex)
        plan = _plan("c", X.shape, self.nfft)
        plan.input_array[...] = X
        out = plan()
        return out[..., :n] * np.exp(self.eta * self.dt * np.arange(n))


def pad_rule_s(decay_rates, minimum: float = 1.0, n_tau: float = 3.0) -> float:
    """The padding the rule asks for, s: max(minimum, n_tau tau_1), tau_1 = 1 / min(xi_j w_j)
    over the fixed-base modes (decay_rates (m,) 1/s); undamped modes are ignored. n_tau = 3
    with the window (which adds the factor wrap_tol), ln(1 / wrap_tol) without it."""
    r = np.asarray(decay_rates, float)
    r = r[r > 0]
    return float(max(minimum, n_tau / r.min())) if r.size else float(minimum)

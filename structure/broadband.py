"""A seeded broadband test accelerogram for tests and benchmarks (not a design motion:
spectrum-compatible motions are made by the orchestrator).

Gaussian white noise shaped by a Kanai-Tajimi filter (fg = 4 Hz, zeta_g = 0.6) with a
Clough-Penzien high-pass (0.4 Hz), under a Jennings envelope (rise 1.5 s, strong phase
to 5.5 s, exponential decay), scaled to the requested peak ground acceleration.
"""
from __future__ import annotations

import numpy as np


def broadband_accelerogram(duration: float, dt: float, pga: float, seed: int = 0,
                           fg: float = 4.0, zg: float = 0.6) -> np.ndarray:
    """(nt,) m/s^2 at t_k = k dt, nt = round(duration/dt) + 1, peak |a| = pga (m/s^2)."""
    nt = int(round(duration / dt)) + 1
    rng = np.random.default_rng(seed)
    nfft = 2 * nt
    f = np.fft.rfftfreq(nfft, dt)
    wg, wf = 2 * np.pi * fg, 2 * np.pi * 0.4
    w = 2 * np.pi * f
    kt = (wg**4 + (2 * zg * wg * w) ** 2) / ((wg**2 - w**2) ** 2 + (2 * zg * wg * w) ** 2)
    hp = w**4 / ((wf**2 - w**2) ** 2 + (2 * 0.6 * wf * w) ** 2)
    spec = np.fft.rfft(rng.standard_normal(nfft)) * np.sqrt(kt * hp)
    a = np.fft.irfft(spec, nfft)[:nt]
    t = dt * np.arange(nt)
    env = np.where(t < 1.5, (t / 1.5) ** 2, np.where(t < 5.5, 1.0, np.exp(-0.5 * (t - 5.5))))
    a = a * env
    return pga * a / np.abs(a).max()

"""Ground motions for tests, (nt, 3) m/s² at t_k = k dt (x, y, z)."""
import numpy as np

from structure import G_ACC
from structure.broadband import broadband_accelerogram


def broadband(pga_g, duration=4.0, dt=0.005, seed=3, vertical=0.3, taper=1.0):
    """Broadband motion (x, and vertical * x along z) ending quietly: a cosine taper over the
    last ``taper`` s (a record cut at full strength makes any sampled-input FFT method ring
    before the cut)."""
    a = broadband_accelerogram(duration, dt, pga_g * G_ACC, seed=seed)
    t = dt * np.arange(a.size)
    a = a * np.where(t > t[-1] - taper, 0.5 * (1 + np.cos(np.pi * (t - t[-1] + taper) / taper)), 1.0)
    ag = np.zeros((a.size, 3))
    ag[:, 0] = a
    ag[:, 2] = vertical * a
    ag[0] = 0.0
    return ag


def smooth_pulse(dt, T=3.0, amp=3.0, tp=0.6):
    """A C2 pulse (sin^3) sampled at dt: the same continuous input at every dt (x, and 0.3 of
    it along z)."""
    t = dt * np.arange(round(T / dt) + 1)
    s = np.where(t < tp, np.sin(np.pi * t / tp) ** 3, 0.0)
    ag = np.zeros((t.size, 3))
    ag[:, 0] = amp * s
    ag[:, 2] = 0.3 * amp * s
    return ag


def stepper_pulse(dt, T=1.2):
    """The stepper tests' pulse: sin^3 over 0.5 s, 2 m/s² along x and 0.7 m/s² along z."""
    t = dt * np.arange(int(round(T / dt)) + 1)
    a = np.zeros((t.size, 3))
    tp = 0.5
    s = np.where(t < tp, np.sin(np.pi * t / tp) ** 3, 0.0)
    a[:, 0] = 2.0 * s
    a[:, 2] = 0.7 * s
    return a

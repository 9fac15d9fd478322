"""Discrete recursive convolution of a rational soil model, consistent with Newmark.

The model K(s) = D + s E + Σ_k R_k / (s − p_k) (``RationalModel``) is run in time as the
state-space system, per pole, y_k' = p_k y_k + u (y_k an n-vector), f = D u + E u' + Σ R_k y_k,
discretised by the trapezoidal rule — the rule average-acceleration Newmark applies to the
velocity (u'_n = (2/dt)(u_n − u_{n−1}) − u'_{n−1}):

    y_{k,n} = a_k y_{k,n−1} + b_k (u_n + u_{n−1}),  a_k = (1 + p_k dt/2)/(1 − p_k dt/2),
                                                    b_k = (dt/2)/(1 − p_k dt/2)
    f_n = D0 u_n + E u'_n + h_n,   D0 = D + Σ_k b_k R_k,
                                   h_n = Σ_k R_k (a_k y_{k,n−1} + b_k u_{n−1})

h_n depends only on the past (the split DESIGN.md §4 and §6 rely on). Its z-transform is

    K_d(z) = D + s_b(z) E + Σ_k R_k b_k (z + 1)/(z − a_k),   s_b(z) = (2/dt)(z − 1)/(z + 1)

which equals K(s_b(z)) exactly (the bilinear / Tustin map): at z = e^{iωdt}, s_b = (2i/dt)
tan(ωdt/2), so the steady-state harmonic response is K at the warped frequency, within
O((ωdt)^2) of K(iω). |a_k| < 1 for Re p_k < 0 at every dt (A-stable), and the bilinear map
sends the imaginary axis onto the unit circle, so a passive model stays passive at every dt.

Work on the soil, W_n = Σ_m (u_m − u_{m−1})·(f_m + f_{m−1})/2 (the trapezoidal ∫ f·u' dt of
the stepper's energy balance), is ≥ the stored energy ≥ 0 for a passive model from rest:
the trapezoidal rule evaluates the continuous dissipation inequality dV/dt ≤ 2 u'·f at the
step mid-values exactly. It includes recoverable (spring, pole-state) energy.

Complex poles are carried once per conjugate pair (the partner contributes the complex
conjugate): h = H g with one real matrix H (n, (m_r + 2 m_c) n) stacking R_k of the real poles
and [2 Re R_k, −2 Im R_k] of the pairs, so one history update is one GEMV, m n^2 flops.
"""
from __future__ import annotations

import importlib
import warnings

import numpy as np

from .rational import FitError, RationalModel


class NonPassiveError(FitError):
    """A rational model that is not passive, handed to a time stepper without force=True."""


class PassivityWarning(UserWarning):
    """A non-passive model is run because the caller forced it."""


# ---- bilinear map and the recursion's z-transform ----------------------------------------
def bilinear_s(freq_hz, dt: float) -> np.ndarray:
    """s_b = (2/dt)(z − 1)/(z + 1) at z = e^{iωdt}, = (2i/dt) tan(ωdt/2); ω = 2π f, rad/s."""
    w = 2 * np.pi * np.asarray(freq_hz, float)
    return 2j / dt * np.tan(0.5 * w * dt)


def bilinear_coefficients(poles, dt: float):
    """(a, b) of the trapezoidal pole recursion y_n = a y_{n−1} + b (u_n + u_{n−1})."""
    p = np.asarray(poles, complex)
    den = 1.0 - 0.5 * dt * p
    return (1.0 + 0.5 * dt * p) / den, 0.5 * dt / den


def recursion_transfer(model: RationalModel, dt: float, freq_hz) -> np.ndarray:
    """K_d(z) of the recursion at z = e^{iωdt}, shape (F, n, n), built from the recursion's
    own coefficients (a_k, b_k): D + s_b E + Σ R_k b_k (z+1)/(z−a_k). Equals
    ``model(bilinear_s(freq_hz, dt))`` to round-off; this is the operator a time-frequency
    solver must use to reproduce the Newmark run exactly."""
    f = np.atleast_1d(np.asarray(freq_hz, float))
    z = np.exp(2j * np.pi * f * dt)
    a, b = bilinear_coefficients(model.poles, dt)
    sb = 2 / dt * (z - 1) / (z + 1)
    g = b * (z[:, None] + 1) / (z[:, None] - a)          # (F, m)
    return (model.D + sb[:, None, None] * model.E
            + np.einsum("fk,kij->fij", g, model.residues))


# ---- passivity gate ----------------------------------------------------------------------
def passivity_margin(model: RationalModel, n_freq: int = 400):
    """Dense-grid passivity check: (margin, omega) with margin = min over a log grid (and at
    every pole's resonance) of λ_min(Herm Im K(iω)) / max|λ|, relative; also λ_min(E)/|E|
    at ω = ∞ (reported as omega = inf). A grid can miss a narrow violation: the passivity
    module (Hamiltonian test) supersedes this when present."""
    p = model.poles
    scale = np.abs(p) if p.size else np.array([1.0])
    lo, hi = max(scale.min(), 1e-6) * 1e-3, max(scale.max(), 1e-6) * 1e3
    w = np.geomspace(lo, hi, n_freq)
    if p.size:
        wr = np.abs(p.imag)[:, None] + np.abs(p.real)[:, None] * np.linspace(-2, 2, 9)
        w = np.union1d(w, wr[wr > 0])
    worst, w_worst = np.inf, np.nan
    for chunk in np.array_split(w, max(1, w.size // 32)):
        K = model(1j * chunk)
        H = (K - np.conj(np.swapaxes(K, -1, -2))) / 2j
        lam = np.linalg.eigvalsh(H)
        rel = lam[:, 0] / np.maximum(np.abs(lam).max(axis=1), 1e-300)
        i = int(np.argmin(rel))
        if rel[i] < worst:
            worst, w_worst = float(rel[i]), float(chunk[i])
    if np.any(model.E):
        lamE = np.linalg.eigvalsh(0.5 * (model.E + model.E.T))
        relE = lamE[0] / np.abs(lamE).max()
        if relE < worst:
            worst, w_worst = float(relE), np.inf
    return worst, w_worst


def require_passive(model: RationalModel, force: bool = False, tol: float = 1e-9) -> None:
    """Raise NonPassiveError unless the model is passive; with force=True warn instead.
    Delegates to ``soil_impedance.passivity.require_passive`` when that module exists."""
    try:
        passivity = importlib.import_module(__package__ + ".passivity")
    except ModuleNotFoundError as exc:
        if exc.name != __package__ + ".passivity":
            raise
        passivity = None
    if passivity is not None and hasattr(passivity, "require_passive"):
        passivity.require_passive(model, force)
    else:
        grid_require_passive(model, force, tol)


def grid_require_passive(model: RationalModel, force: bool = False, tol: float = 1e-9) -> None:
    """``require_passive`` by the dense-grid check ``passivity_margin`` (the fallback)."""
    margin, w = passivity_margin(model)
    if margin >= -tol:
        return
    msg = (f"rational soil model is not passive: the Hermitian part of Im K(iω) has a negative "
           f"eigenvalue ({margin:.3g} relative) at ω = {w:.4g} rad/s ({w / (2 * np.pi):.4g} Hz); "
           "enforce passivity on the fit, or pass force=True to run it anyway")
    if not force:
        raise NonPassiveError(msg)
    warnings.warn(msg, PassivityWarning, stacklevel=3)


# ---- pole bookkeeping -------------------------------------------------------------------
def split_poles(model: RationalModel, rtol: float = 1e-8):
    """(p_real (m_r,), R_real (m_r, n, n) real, p_pair (m_c,) with Im p > 0, R_pair (m_c, n, n)).
    Raises FitError when a complex pole lacks its conjugate or conjugate residues differ."""
    p, R = model.poles, model.residues
    rscale = max(np.abs(R).max(initial=0.0), 1e-300)
    is_real = np.abs(p.imag) <= rtol * np.abs(p)
    if np.any(np.abs(R[is_real].imag) > rtol * rscale * 1e2):
        raise FitError("a real pole carries a complex residue: the model's impulse response "
                       "would not be real; refit with real residues for real poles")
    up = np.flatnonzero(~is_real & (p.imag > 0))
    down = list(np.flatnonzero(~is_real & (p.imag < 0)))
    if len(up) != len(down):
        raise FitError(f"{len(up)} poles with Im p > 0 but {len(down)} with Im p < 0: complex "
                       "poles must come in conjugate pairs")
    for k in up:
        j = min(down, key=lambda j: abs(p[j] - np.conj(p[k])))
        if abs(p[j] - np.conj(p[k])) > rtol * abs(p[k]) * 1e2 or \
                np.abs(R[j] - np.conj(R[k])).max() > 1e-6 * rscale:
            raise FitError(f"pole {p[k]:.6g} has no conjugate partner with conjugate residue")
        down.remove(j)
    return (np.ascontiguousarray(p[is_real].real), np.ascontiguousarray(R[is_real].real),
            p[up], np.ascontiguousarray(R[up]))


# ---- the soil ------------------------------------------------------------------------------
class RecursiveConvolutionSoil:
    """A RationalModel run as the trapezoidal recursive convolution (soil protocol, duck-typed:
    see structure/soil_interface.py).

    Parameters
    ----------
    model : RationalModel         n = 6 + N interface DOFs, passive unless force
    dt : float, s                  initial step size; ``instantaneous(dt')`` changes it at any
                                   time (coefficients recomputed, states carried over: the
                                   trapezoidal rule with a variable step)
    force : bool                   run a non-passive model (with a PassivityWarning)

    Per step: ``instantaneous(dt)`` -> (K0, C0) = (D0, E) dense (n, n); ``history()`` -> h_n
    (n,), N; ``commit(x, xdot)`` with the converged x_n, m and xdot_n, m/s. ``step(x, xdot=None)``
    does history + commit for a standalone run (xdot from the trapezoidal rule if omitted) and
    returns f_n. State: pole states y (input form, so a dt change needs no transformation),
    u_{n−1}, u'_{n−1}, f_{n−1}, work, dt; ``get_state``/``set_state`` copy numpy arrays.
    """

    def __init__(self, model: RationalModel, dt: float, force: bool = False):
        if not dt > 0:
            raise ValueError(f"time step dt = {dt!r} must be > 0")
        require_passive(model, force)
        self.model = model
        n = model.n
        self.n_dof = n
        pr, Rr, pc, Rc = split_poles(model)
        self._pr, self._pc = pr, pc
        self._Rr, self._Rc = Rr, Rc
        mr, mc = pr.size, pc.size
        Hr = np.transpose(Rr, (1, 0, 2)).reshape(n, mr * n)
        Hc = np.stack([2 * Rc.real, -2 * Rc.imag], axis=-1)         # (mc, n, n, 2)
        Hc = np.transpose(Hc, (1, 0, 2, 3)).reshape(n, 2 * mc * n)   # (re, im) interleaved
        self._H = np.ascontiguousarray(np.hstack([Hr, Hc]))
        # g = [a y + b u] stacked; the complex block viewed as interleaved (re, im) pairs
        self._g = np.zeros((mr + 2 * mc) * n)
        self._gr = self._g[: mr * n].reshape(mr, n)
        self._gc = self._g[mr * n:].view(complex).reshape(mc, n)
        self.E = np.array(model.E, float)
        self.E.setflags(write=False)
        self._coef = {}
        self._set_dt(float(dt))
        self._yr = np.zeros((mr, n))
        self._yc = np.zeros((mc, n), complex)
        self._u = np.zeros(n)
        self._ud = np.zeros(n)
        self._f = np.zeros(n)
        self._work = 0.0
        self._h = None
        self._K_static = None

    # ---- coefficients per dt --------------------------------------------------------------
    def _set_dt(self, dt):
        if dt not in self._coef:
            if len(self._coef) > 8:
                self._coef.pop(next(iter(self._coef)))
            ar, br = bilinear_coefficients(self._pr, dt)
            ac, bc = bilinear_coefficients(self._pc, dt)
            ar, br = ar.real, br.real
            D0 = self.model.D + np.tensordot(br, self._Rr, 1) + 2 * np.tensordot(bc, self._Rc, 1).real
            D0 = 0.5 * (D0 + D0.T)
            D0.setflags(write=False)
            self._coef[dt] = (ar, br, ac, bc, D0)
        self.dt = dt
        self._ar, self._br, self._ac, self._bc, self.D0 = self._coef[dt]
        self._h = None

    # ---- protocol -------------------------------------------------------------------------
    def instantaneous(self, dt: float):
        """(K0, C0) = (D0(dt), E), dense read-only (n, n); makes dt the current step size."""
        if dt != self.dt:
            self._set_dt(float(dt))
        return self.D0, self.E

    def history(self) -> np.ndarray:
        """h_n (n,), N: the force on the soil at t_n + dt with zero x_n and xdot_n."""
        if self._h is None:
            u = self._u
            np.multiply(self._ar[:, None], self._yr, out=self._gr)
            self._gr += self._br[:, None] * u
            np.multiply(self._ac[:, None], self._yc, out=self._gc)
            self._gc += self._bc[:, None] * u
            self._h = self._H @ self._g
        return self._h.copy()

    def commit(self, x, xdot) -> None:
        """Accept x_n (n,), m and xdot_n (n,), m/s: advance the pole states and the work."""
        x = np.asarray(x, float)
        xdot = np.asarray(xdot, float)
        h = self.history()
        f = self.D0 @ x + self.E @ xdot + h
        self._work += (x - self._u) @ (0.5 * (f + self._f))
        w = x + self._u
        self._yr *= self._ar[:, None]
        self._yr += self._br[:, None] * w
        self._yc *= self._ac[:, None]
        self._yc += self._bc[:, None] * w
        self._u = x.copy()
        self._ud = xdot.copy()
        self._f = f
        self._h = None

    def step(self, x, xdot=None) -> np.ndarray:
        """Standalone step to x_n: xdot_n by the trapezoidal rule when omitted. Returns f_n."""
        x = np.asarray(x, float)
        if xdot is None:
            xdot = 2.0 / self.dt * (x - self._u) - self._ud
        self.commit(x, xdot)
        return self._f.copy()

    def static_stiffness(self) -> np.ndarray:
        """K(0) = D − Σ R_k / p_k, real (n, n)."""
        if self._K_static is None:
            K = self.model(np.zeros(1))[0].real
            self._K_static = 0.5 * (K + K.T)
        return self._K_static

    def total_force(self) -> np.ndarray:
        """f_n (n,), N: force applied to the soil at the last committed step."""
        return self._f.copy()

    def dissipated_energy(self) -> float:
        """Work done on the soil since rest, J: Σ (u_m − u_{m−1})·(f_m + f_{m−1})/2 (≥ 0 for a
        passive model; includes the bounded recoverable energy stored in springs and poles)."""
        return float(self._work)

    def transfer(self, freq_hz) -> np.ndarray:
        """K_d(e^{iωdt}) (F, n, n) of the recursion at the current dt."""
        return recursion_transfer(self.model, self.dt, freq_hz)

    def get_state(self) -> dict:
        return dict(yr=self._yr.copy(), yc=self._yc.copy(), u=self._u.copy(), ud=self._ud.copy(),
                    f=self._f.copy(), work=self._work, dt=self.dt)

    def set_state(self, s: dict) -> None:
        self._yr = np.array(s["yr"], float, copy=True)
        self._yc = np.array(s["yc"], complex, copy=True)
        self._u = np.array(s["u"], float, copy=True)
        self._ud = np.array(s["ud"], float, copy=True)
        self._f = np.array(s["f"], float, copy=True)
        self._work = float(s["work"])
        self._set_dt(float(s["dt"]))


# ---- passive test models ---------------------------------------------------------------------
def oscillator_model(D, E=None, terms=(), maxwell=(), dofs=None) -> RationalModel:
    """A passive RationalModel from mechanical building blocks (for tests and benchmarks).

    D, E : (n, n) PSD springs and dashpots to ground.
    terms : iterable of (k, c, m, W): an internal mass m, tied by a spring k to the interface
        and by a dashpot c to ground, seen through the PSD shape W (n, n): the scalar
        k − k^2/(m s^2 + c s + k) = k + Σ r/(s − p) times W (passive: a condensed mechanical
        system); complex pair when c^2 < 4 m k.
    maxwell : iterable of (k, c, W): spring k in series with dashpot c, k s/(s + k/c) W.
    """
    D = np.array(D, float)
    n = D.shape[0]
    E = np.zeros((n, n)) if E is None else np.array(E, float)
    poles, res = [], []
    for k, c, m, W in terms:
        W = np.asarray(W, float)
        p1, p2 = np.roots([m, c, k]).astype(complex)
        D = D + k * W
        poles += [p1, p2]
        res += [-k * k / (m * (p1 - p2)) * W, -k * k / (m * (p2 - p1)) * W]
    for k, c, W in maxwell:
        W = np.asarray(W, float)
        a = k / c
        D = D + k * W
        poles.append(-a + 0j)
        res.append(-k * a * W + 0j)
    return RationalModel(np.array(poles, complex), np.array(res, complex).reshape(len(poles), n, n),
                         D, E, dofs=dofs or [], provenance={"source": "oscillator_model"})


def random_passive_model(n: int, n_pairs: int, n_real: int = 0, seed: int = 0,
                         f_range=(0.5, 20.0)) -> RationalModel:
    """Random passive model: n DOFs, n_pairs oscillator pairs with resonances log-spread over
    f_range (Hz) and damping ratios 5-40 %, n_real Maxwell poles, full-rank PSD shapes."""
    rng = np.random.default_rng(seed)

    def psd():
        G = rng.standard_normal((n, n)) / np.sqrt(n)
        return G @ G.T + 0.05 * np.eye(n)

    fr = np.geomspace(*f_range, max(n_pairs, 1))[:n_pairs]
    terms = []
    for f in fr:
        w0, zeta = 2 * np.pi * f, rng.uniform(0.05, 0.4)
        k = rng.uniform(0.5, 2.0)
        m = k / w0**2
        terms.append((k, 2 * zeta * np.sqrt(k * m), m, psd()))
    maxwell = [(rng.uniform(0.5, 2.0), rng.uniform(0.5, 2.0) / (2 * np.pi * f), psd())
               for f in np.geomspace(*f_range, max(n_real, 1))[:n_real]]
    return oscillator_model(psd(), 0.02 * psd(), terms, maxwell)

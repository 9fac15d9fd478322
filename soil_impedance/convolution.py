"""Discrete recursive convolution of a rational soil model, consistent with Newmark.

The model K(s) = D + s E + Σ_k R_k / (s − p_k) (``RationalModel``) is run in time as the
state-space system, per pole, y_k' = p_k y_k + u (y_k an n-vector), f = D u + E u' + Σ R_k y_k,
discretised by the trapezoidal rule — the rule average-acceleration Newmark applies to the
velocity (u'_n = (2/dt)(u_n − u_{n−1}) − u'_{n−1}):

    y_{k,n} = a_k y_{k,n−1} + b_k (u_n + u_{n−1}),  a_k = (1 + p_k dt/2)/(1 − p_k dt/2),
                                                    b_k = (dt/2)/(1 − p_k dt/2)
    f_n = D0 u_n + E u'_n + h_n,   D0 = D + Σ_k b_k R_k,
                                   h_n = Σ_k R_k (a_k y_{k,n−1} + b_k u_{n−1})

h_n depends only on the past (the split the steppers rely on). Its z-transform is

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
On a large interface (``history="hmatrix"``, or ``"auto"`` from HMATRIX_MIN_NODES nodes on when
the nodes' coordinates are given) the blocks of H are held as hierarchical matrices
(soil_impedance/hhistory.py): the soil then runs the compressed model M̃ (the residues
assembled from the compressed blocks, within ``history_tol`` of the fit's), whose passivity
is tested as a fit's.
"""
from __future__ import annotations

import numpy as np

from .hhistory import DEFAULT_LEAF, DEFAULT_TOL, HMATRIX_MIN_NODES, compress_history
from .passivity import VERIFIED, require_passive
from .rational import FitError, RationalModel

#: the forms of the history product (``RecursiveConvolutionSoil(history=...)``)
HISTORY_KINDS = ("auto", "dense", "hmatrix")


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
    force : bool                   run a non-passive model (with a RuntimeWarning); else a
                                   non-passive model is refused (``passivity.require_passive``:
                                   FitError naming the violation bands and the fix)
    checked : bool                 the caller has verified passivity already (an exported FMU:
                                   verified once at export), the test is not run again
    history : str                  "dense" (H held whole), "hmatrix" (its blocks compressed:
                                   hhistory.compress_history over xy) or "auto" (default):
                                   "hmatrix" when xy is given and N >= HMATRIX_MIN_NODES, else
                                   "dense" (the reactor's 241 nodes: dense)
    xy : (N, 2) array, m, or None  the interface nodes (the cluster tree of "hmatrix")
    history_tol : float            relative truncation of the compressed blocks, to each block's largest
                                   node diagonal entry (default hhistory.DEFAULT_TOL, 5e-5);
                                   recorded in ``model.provenance["history"]``
    history_leaf : int             the largest cluster held as a leaf, nodes (default 32)

    Per step: ``instantaneous(dt)`` -> (K0, C0) = (D0, E) dense (n, n); ``history()`` -> h_n
    (n,), N; ``commit(x, xdot)`` with the converged x_n, m and xdot_n, m/s. ``step(x, xdot=None)``
    does history + commit for a standalone run (xdot from the trapezoidal rule if omitted) and
    returns f_n. State: pole states y (input form, so a dt change needs no transformation),
    u_{n−1}, u'_{n−1}, f_{n−1}, work, dt; ``get_state``/``set_state`` copy numpy arrays.
    """

    def __init__(self, model: RationalModel, dt: float, force: bool = False, checked: bool = False,
                 history: str = "auto", xy=None, history_tol: float = DEFAULT_TOL,
                 history_leaf: int = DEFAULT_LEAF):
        if not dt > 0:
            raise ValueError(f"time step dt = {dt!r} must be > 0")
        self.source_model = model
        self.compressed = None
        self.history_kind = history_kind(history, model.n, xy)
        if self.history_kind == "hmatrix":
            self.compressed, model = compressed_model(model, xy, history_tol, history_leaf)
        if not checked:
            require_passive(model, force)
        self.model = model
        n = model.n
        self.n_dof = n
        pr, Rr, pc, Rc = model.pole_split
        self._pr, self._pc = pr, pc
        self._Rr, self._Rc = Rr, Rc
        mr, mc = pr.size, pc.size
        # the dense history matrix H (n, m n doubles: as large as the residues) is built at the first
        # history product (``_history_matrix``), not here: a native run (fmus.native_stepper) takes the
        # residues from the model and builds its own, and never holds this one
        self._H = None
        if self.compressed is not None:
            self._ops = self.compressed.operator(stacked_columns(n, mr, mc))
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
            if self.compressed is None:
                if self._H is None:
                    self._H = self._history_matrix()
                self._h = self._H @ self._g
            else:
                near, U, V = self._ops
                self._h = near @ self._g + U @ (V @ self._g)
        return self._h.copy()

    def _history_matrix(self) -> np.ndarray:
        """H (n, (m_r + 2 m_c) n): the real residues, then each pair's (2 Re R, -2 Im R) interleaved."""
        n, Rr, Rc = self.n_dof, self._Rr, self._Rc
        mr, mc = Rr.shape[0], Rc.shape[0]
        Hr = np.transpose(Rr, (1, 0, 2)).reshape(n, mr * n)
        Hc = np.stack([2 * Rc.real, -2 * Rc.imag], axis=-1)         # (mc, n, n, 2)
        Hc = np.transpose(Hc, (1, 0, 2, 3)).reshape(n, 2 * mc * n)   # (re, im) interleaved
        return np.ascontiguousarray(np.hstack([Hr, Hc]))

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

    def history_gains(self):
        """(Gx, Gv) (n, n) at the current dt, in closed form: how the history of the step after
        next depends on the state committed next (fmus.coupling.history_gains measures them on
        any soil). Committing x from rest puts the pole states at b x, whose history is then
        H [b (a + 1) x]: Gx = Σ R_k b_k (a_k + 1) (a pair: 2 Re), and Gv = 0 (the recursion's
        history does not depend on xdot)."""
        cr = self._br * (self._ar + 1.0)
        cc = self._bc * (self._ac + 1.0)
        Gx = np.tensordot(cr, self._Rr, 1) + 2 * np.tensordot(cc, self._Rc, 1).real
        return Gx, np.zeros_like(Gx)

    def static_stiffness(self) -> np.ndarray:
        """K(0) = D − Σ R_k / p_k, real (n, n)."""
        return self.model.static

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


# ---- the compressed history ------------------------------------------------------------------
def history_kind(history: str, n: int, xy) -> str:
    """"dense" or "hmatrix": the form of the history product asked (``history``, one of
    HISTORY_KINDS) for n DOFs and the nodes xy (None: not given)."""
    if history not in HISTORY_KINDS:
        raise FitError(f"soil option history = {history!r}: use one of {', '.join(map(repr, HISTORY_KINDS))}")
    if history == "hmatrix" and xy is None:
        raise FitError("soil option history = 'hmatrix' needs the interface nodes' coordinates: pass xy "
                       "(N, 2), m, with it (or history = 'dense')")
    if history == "auto":
        return "hmatrix" if xy is not None and n - 6 >= HMATRIX_MIN_NODES else "dense"
    return history


def stacked_columns(n: int, mr: int, mc: int) -> np.ndarray:
    """(mr + 2 mc, n) index in the stacked pole input g of (history block, DOF): the real poles'
    blocks first, then each pair's (re, im) interleaved per DOF."""
    j = np.arange(n)
    real = [b * n + j for b in range(mr)]
    pair = [mr * n + (k * n + j) * 2 + im for k in range(mc) for im in (0, 1)]
    return np.array(real + pair, np.int64).reshape(mr + 2 * mc, n)


def history_blocks(model: RationalModel) -> np.ndarray:
    """(mr + 2 mc, n, n) the history blocks of ``model``: R_k of the real poles, then per
    conjugate pair 2 Re R_k and −2 Im R_k."""
    pr, Rr, pc, Rc = model.pole_split
    pairs = np.stack([2 * Rc.real, -2 * Rc.imag], axis=1).reshape(-1, model.n, model.n)
    return np.concatenate([Rr, pairs]).reshape(-1, model.n, model.n)


def compressed_model(model: RationalModel, xy, tol: float = DEFAULT_TOL, leaf: int = DEFAULT_LEAF,
                     instant: bool = True):
    """(CompressedHistory, M̃): the history blocks of ``model`` compressed over the nodes xy
    (hhistory.compress_history) and the rational model whose residues are the compressed
    blocks assembled (real poles first, then each pair's pole and its conjugate: vectfit's canonical order), D and E
    compressed over the same partition (at hhistory.INSTANT_TOL_FACTOR x tol) and assembled when both are
    symmetric (as a fit makes them) and ``instant``, else the model's. ``M̃.provenance["history"]`` records the tolerance, the partition's settings, the
    storage ratio and the largest discarded singular value, and the source model's digest."""
    xy = np.asarray(xy, float)
    if xy.ndim != 2 or xy.shape != (model.n - 6, 2):
        raise FitError(f"soil option xy has shape {xy.shape}: give the (N, 2) coordinates of the N = "
                       f"{model.n - 6} interface nodes, m")
    D, E = np.asarray(model.D, float), np.asarray(model.E, float)
    symmetric = np.array_equal(D, D.T) and np.array_equal(E, E.T)
    hist = compress_history(history_blocks(model), xy, tol, int(leaf), instant=(D, E) if instant and symmetric else None)
    if hist.instant is not None:
        D, E = hist.instant.dense(0), hist.instant.dense(1)
    pr, _, pc, _ = model.pole_split
    mr, mc = pr.size, pc.size
    Ht = np.array([hist.dense(b) for b in range(hist.nh)])
    Rr = Ht[:mr].astype(complex)
    Rc = 0.5 * Ht[mr::2] - 0.5j * Ht[mr + 1::2]
    prov = {k: v for k, v in model.provenance.items() if k != VERIFIED}
    prov["history"] = {"kind": "hmatrix", **hist.settings, "source_digest": model.digest}
    if hist.instant is not None:
        prov["history"]["instant"] = {k: hist.instant.settings[k] for k in ("storage_ratio", "max_rank",
                                                                             "max_block_error", "e_shift")}
    poles = np.concatenate([pr.astype(complex), np.stack([pc, pc.conj()], 1).reshape(-1)])
    residues = np.concatenate([Rr, np.stack([Rc, Rc.conj()], 1).reshape(2 * mc, model.n, model.n)])
    new = RationalModel(poles, residues.reshape(mr + 2 * mc, model.n, model.n), D, E, list(model.dofs), prov)
    return hist, new

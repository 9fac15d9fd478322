"""Passivity of a rational soil model: assessment, exact tests, enforcement and the stepper guard.

Criterion (harmonic convention e^{+iωt}; K maps displacements u to forces f on the soil). The mean
power absorbed by the soil is ½ Re(fᴴ iω u) = (ω/2) uᴴ G(ω) u with

    G(ω) = (K(iω) − K(iω)ᴴ) / (2i)      (= Im K(iω) for a symmetric K),

so the model is passive iff G(ω) ⪰ 0 for every ω > 0, the E term is PSD (ω → ∞) and the static
stiffness K(0) is PSD; equivalently Z(s) = K(s)/s (velocity → force) is positive real, since
Herm Z(iω) = G(ω)/ω. Everything below works on the DOF-scaled model S K S with
S = diag(K_ii(0))^{-1/2} (DOFs whose rows are identically zero are left out) and in normalised
frequency ν = ω/ω_ref, ω_ref = 2π·(top of the fitted band). The **passivity margin** is

    margin = min_{ω>0} λ_min(S G(ω) S) · ω_ref/ω            (dimensionless, ≥ 0 when passive)

(the eigenvalues of Im K(iω)/ω, made dimensionless).

Tests that cannot miss a narrow violation:
* ``method="hamiltonian"``: the frequencies where G(ω) is singular. For a symmetric model
  G(ν) = ν H(ν²) with H(x) = E − Σ_k R_k/(x + p_k²), a pole-residue form in x = ν² whose real
  zeros are the real eigenvalues of one real eigenproblem of size Σ rank R_k ≤ m·n (``_crossings``;
  the zeros of the Hamiltonian pencil of Φ(s) = K(s) − K(−s)ᵀ, folded s² = −x: a quarter of its
  size, and real). Between two crossings the sign of λ_min is constant: one evaluation per
  interval gives the violation bands.
* ``method="sweep"`` (large n, where the eigenproblem is too big): an adaptive sweep with a certified
  lower bound. By Weyl, on [a, b] λ_min(G) ≥ (λ_a + λ_b − L(b − a))/2 with
  L = ‖E‖ + Σ_k ‖R_k‖₂ / dist(p_k, i[a, b])²; intervals are bisected until the bound is ≥ 0 or a
  violation is found, and the tail ω > ω_hi is cleared by ω λ_min(E) ≥ Σ_k ‖R_k‖/(ω − |p_k|).
  From ``CHOLESKY_SWEEP_NA`` active DOFs (``_cholesky_sweep``), where an eigensolution of the
  (6+N)² matrix per node is what costs (2.75 s at 2506 DOFs, about 500-3300 nodes), no eigenvalues:
  on M(ν) = G(ν)/ν = E − Σ_k R_k/(ν² + p_k²) (finite at ν = 0, even in ν), Taylor's theorem gives on
  [c − h, c + h] M(ν) ⪰ M(c) + (ν − c) M'(c) − ½h² L₂ I with L₂ ≥ ‖M''‖ there (``_curvatures``), so two
  Cholesky factorisations, M(c) ± h M'(c) − ½h² L₂ I ≻ 0, certify the interval (0.16 s each at 2506
  DOFs); intervals are bisected from a coarse grid, violations found by the sign of M(c) + ROUND_OFF·I,
  and the tail cleared by λ_min(E) ≥ Σ_k ‖R_k‖/(ν² − |p_k|²). The residue norms are bounded by power
  iteration and Cholesky (``_norm_bound``), not complex SVDs. A successful factorisation proves
  positive definiteness up to its backward error (about n·ε·‖M‖, below ROUND_OFF at these sizes),
  the same footing as the eigenvalues it replaces. Below ``CHOLESKY_SWEEP_NA`` the eigenvalue sweep
  stays (seconds; the reactor's 247-DOF fit and report unchanged).
``method="auto"`` uses the exact test when m·n + n ≤ ``max_pencil`` (1500; 4500 when E is well
conditioned, a standard eigenproblem), else the sweep.

Enforcement (``enforce_passivity``): residue perturbation. With the model in real coefficient form
K(s) = Σ_b φ_b(s) C_b (``RationalModel.coefficients``), find the change ΔC minimising the fit's
weighted least-squares change Σ_f w_f² ‖Σ_b φ_b(iω_f) ΔC_b‖_F² subject to G(ω_j) + ΔG(ω_j) ⪰
margin·ω_j/ω_ref at the violation frequencies (samples across each band, geometric when it spans
decades, and its neighbours). G is linear in C, so the only approximation is the sampling in ω; the
matrix inequality is imposed by cutting planes ⟨N, G + ΔG − margin·ν_j⟩ ≥ 0, N ⪰ 0: one per
eigenvector v below the margin (N = v vᵀ, the ``RANK_ONE_PLANES`` deepest per sample) and, when
more are below it, the deficit plane N = (margin·ν_j − G(ν_j))₊ (those eigenvectors weighted by
their depth: the supporting plane at the nearest matrix that meets the margin). One plane per
eigenvector alone stalls when hundreds of eigenvalues are below the margin: an undamped half-space
has Im K ≈ 0 on every evanescent surface pattern (~300 of the 320 DOFs of disk-halfspace) and the
fit's round-off there is ±0.25 % of K(0); each step rotated the eigenvectors and the margin did
not improve (207 s, and the 7-pole fit was given up). The objective is Kronecker-structured, so the
QP is solved through its small dual (one NNLS over the planes, the ``MAX_PLANES`` deepest new ones
per iteration; planes near ν = 0 are scaled by 1/ν so that they keep their weight); the planes are
accumulated over the iterations against the original model (the active ones: a plane whose
multiplier is zero is dropped). E is then projected on the PSD cone (with a small floor so that
the tail is certifiable) and K(0) on the PSD cone through D.

``protect`` (the rigid-raft impedance of a gap table) stretches the scaled coordinates along the
given DOF patterns before all of this (congruence T = I + U(σ − 1)Uᵀ, S⁻¹R = U σ Vᵀ): a change of
their impedance Rᵀ K R then costs σ² times more, their margin target is margin/σ², and the
passivity verdict is unchanged (congruence keeps the inertia). Without it the enforcement of the
7-pole disk-halfspace fit moved the rocking damping by 4 % (the fit's rigid error was 0.2 %).

Each iteration is checked first on the dense grid (``_screen``: a Cholesky factorisation per
frequency, the sign of λ_min only); the exact test runs only when the grid sees no violation.
From ``CHOLESKY_SWEEP_NA`` active DOFs (a (6+N)² gap-table fit: 449 factorisations of the grid and a full
eigh per plane sample were minutes per iteration at 2506 DOFs) the cost of an iteration is bounded by
what the violations and the change reach, not by the grid, with the same verdicts: the screen
(``_Rescreen``) keeps per grid point a slack proved by a shifted Cholesky factorisation and lowers it by a
bound of the coefficients' change (Weyl, Frobenius norm through one small Gram matrix), factorising again
only where it runs out; bands that the exact test finds between the grid's points are refined into the
grid (``_Rescreen.refine``), so the exact test runs again only when the refined grid is clean (it is the
final certificate, not a per-iteration cost); the planes take only the eigenpairs below the margin (a
Cholesky factorisation at the margin first, then dsyevr for those: ``_partial_eigh``); and the
depth (the progress measure) is the planes' sampled λ_min/ν instead of 64 grid eigensolutions.
Below ``CHOLESKY_SWEEP_NA`` all of this is as it was (the reactor's fit bit for bit).
Narrow, deep violations (a lightly damped pole between the fit's frequencies and the grid's points) were
closed slowly by these planes, three ways: nine samples across a band missed its minimum; the cheapest
change was one the fit's frequencies do not see (two peaks 0.09 Hz apart on different patterns: the change
deepened one and opened a band above the fitted range); and the eigenvector below the margin turned at each
step, so a sample whose plane was met failed again by a little (synthetic 1006- and 1206-DOF models not
passive after 20 iterations). From ``CHOLESKY_SWEEP_NA``, therefore: the planes sample each band at
``PLANE_SAMPLES`` points (deficit planes, na² doubles each, at nine of them only); the change is also
measured over every violation band seen so far that is narrower than two steps of the fit's frequencies, as
the fit's measure would be if it had frequencies there (``_between``, ``_band_gram``: the quadrature of the
same weighted integral of ‖ΔK‖², overlapping bands counted once); and each rank-one plane at a sample where
at most ``RANK_ONE_PLANES`` directions fail asks for its deficit d times ``OVERSHOOT`` above the margin, at
most ``OVERSHOOT_CAP``·ν (``_Planes.lift``: what the eigenvector's turn takes back is then paid from the
overshoot, not by another iteration; where more directions fail the deficit plane covers them, and an
overshoot there stalled the null-noise model of the tests). Those models became passive in 2 iterations;
the price is a change up to about half as large again on the fit's frequencies, and a final margin above
the target (docs/formulation.md, "Passivity").
Repeated until the exact test passes, the worst margin seen stops improving (``stall``
iterations: the cutting-plane iterates are not monotone, 4 gave up on fits that converged at
iteration 11) or the work bound ``max_iter`` is spent (no wall-clock limit: the result depends on
the inputs only).
"""
from __future__ import annotations

import warnings
from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np

from .rational import FitError, RationalModel, ScaledModel
from .vectfit import pole_kinds, real_basis

MAX_PENCIL = 1500          # "auto": the exact test up to this state size m·na + na, else the sweep
REPORT_CACHE_SIZE = 64     # passivity reports kept (by model content)
MAX_PLANES = 600           # enforcement: cutting planes added per iteration at most (the deepest)
RANK_ONE_PLANES = 16       # enforcement, per sample: one plane per eigenvector below the margin up to this many
ROUND_OFF = 1e-12          # a margin (scaled model) down to −ROUND_OFF is round-off, no violation
CHUNK_BYTES = 256 * 2 ** 20  # G(ν) is evaluated for at most this many bytes of frequencies at once
CHOLESKY_SWEEP_NA = 400    # "sweep": by shifted Cholesky factorisations from this many active DOFs, else by eigenvalues
BAND_BISECTIONS = 5        # Cholesky sweep: sign bisections that narrow each edge of a violation band
SIGN_LEVEL = 2             # Cholesky sweep: an interval failing after this many bisections has its centre's sign tested
MARGIN_PROBES = 4          # certified sweep: nodes whose eigenvalues are solved for the reported margin
REFINE_POINTS = 33         # enforcement from CHOLESKY_SWEEP_NA: screen points added across a band the grid missed
PLANE_SAMPLES = 33         # enforcement from CHOLESKY_SWEEP_NA: plane samples across each band (9 below)
OVERSHOOT = 0.5            # enforcement from CHOLESKY_SWEEP_NA: a rank-one plane asks for margin + OVERSHOOT × its deficit,
OVERSHOOT_CAP = 0.1        # ... at most this much more (λ/ν of the scaled model)


@dataclass(frozen=True)
class PassivityReport:
    """Outcome of ``check_passive``.

    passive : bool                 no violation band, E ⪰ 0 and K(0) ⪰ 0 (active DOFs)
    margin : float                 min_ω λ_min(S G(ω) S)·ω_ref/ω found (see module docstring)
    margin_freq_hz : float         where it was found
    bands_hz : list of (lo, hi)    violation bands, Hz (hi may be inf)
    method : str                   "hamiltonian" or "sweep"
    certified : bool               the test covers all ω > 0 (False: sweep budget or tail not cleared)
    crossings_hz : list            frequencies where λ_min(G) changes sign (hamiltonian)
    e_min : float                  λ_min of the scaled E·ω_ref (≥ 0 required)
    static_min : float             λ_min of the scaled K(0) (≥ 0 required)
    evaluations : int              number of G(ω) eigen-evaluations
    """

    passive: bool
    margin: float
    margin_freq_hz: float
    bands_hz: list
    method: str
    certified: bool
    crossings_hz: list = field(default_factory=list)
    e_min: float = 0.0
    static_min: float = 0.0
    evaluations: int = 0

    def to_dict(self) -> dict:
        return {"passive": bool(self.passive), "passivity_margin": float(self.margin),
                "margin_freq_hz": float(self.margin_freq_hz),
                "bands_hz": [[float(a), float(b)] for a, b in self.bands_hz], "method": self.method,
                "certified": bool(self.certified), "e_min": float(self.e_min),
                "static_min": float(self.static_min), "evaluations": int(self.evaluations),
                "crossings_hz": [float(c) for c in self.crossings_hz]}

    @classmethod
    def from_dict(cls, d) -> PassivityReport:
        """The report of ``to_dict`` (FitError naming the missing key of a malformed one)."""
        try:
            return cls(bool(d["passive"]), float(d["passivity_margin"]), float(d["margin_freq_hz"]),
                       [(float(a), float(b)) for a, b in d["bands_hz"]], str(d["method"]), bool(d["certified"]),
                       [float(c) for c in d.get("crossings_hz", [])], float(d["e_min"]),
                       float(d["static_min"]), int(d["evaluations"]))
        except (KeyError, TypeError, ValueError) as exc:
            raise FitError(f"malformed passivity report ({type(exc).__name__}: {exc})") from None

    def __str__(self) -> str:
        bands = ", ".join(f"{a:.4g}-{b:.4g} Hz" for a, b in self.bands_hz) or "none"
        return (f"{'passive' if self.passive else 'NOT passive'} ({self.method}"
                f"{'' if self.certified else ', uncertified'}): margin {self.margin:.3e} at "
                f"{self.margin_freq_hz:.4g} Hz, {'round-off ' if self.passive and self.bands_hz else 'violation '}"
                f"bands: {bands}, λmin(E) {self.e_min:.2e}, "
                f"λmin(K0) {self.static_min:.2e}")


# ------------------------------------------------------------------------------------------
# the scaled, normalised model (RationalModel.scaled)
# ------------------------------------------------------------------------------------------
def _G(sc: ScaledModel, nu) -> np.ndarray:
    """Scaled G at normalised frequencies ν (F,): shape (F, na, na), real symmetric."""
    nu = np.atleast_1d(np.asarray(nu, float))
    Phi = real_basis(1j * nu, sc.poles).imag
    return (Phi @ sc.columns.T).reshape(nu.size, sc.na, sc.na)     # symmetric: C is


def _chunk(sc: ScaledModel, chunk: int) -> int:
    """Frequencies per evaluation of G: ``chunk``, fewer when ``chunk`` matrices of na² doubles would pass
    ``CHUNK_BYTES`` (64 at the reactor's 247 DOFs and up to 631; 5 at 2506 DOFs, where 64 would be 3.2 GB)."""
    return int(max(1, min(chunk, CHUNK_BYTES // (8 * max(sc.na, 1) ** 2))))


def _lmin(sc: ScaledModel, nu, chunk=64) -> np.ndarray:
    """λ_min(G(ν)) for each ν (not divided by ν)."""
    nu = np.atleast_1d(np.asarray(nu, float))
    out = np.empty(nu.size)
    chunk = _chunk(sc, chunk)
    for i in range(0, nu.size, chunk):
        out[i:i + chunk] = np.linalg.eigvalsh(_G(sc, nu[i:i + chunk]))[:, 0]
    return out


def _positive_definite(sc: ScaledModel, nu, chunk=64, shift=0.0) -> np.ndarray:
    """Whether G(ν) + shift·ν·I ≻ 0 for each ν, i.e. λ_min(G)/ν > −shift (a Cholesky factorisation
    each: the sign at a third of the cost of the eigenvalues)."""
    from scipy.linalg.lapack import dpotrf
    nu = np.asarray(nu, float)
    out = np.empty(nu.size, bool)
    diag = np.arange(sc.na)
    chunk = _chunk(sc, chunk)
    for i in range(0, out.size, chunk):
        for j, G in enumerate(_G(sc, nu[i:i + chunk])):
            G[diag, diag] += shift * nu[i + j]
            out[i + j] = dpotrf(G, lower=1, clean=0, overwrite_a=1)[1] == 0
    return out


def _residue_norms(sc: ScaledModel) -> np.ndarray:
    R = sc.residues
    return np.array([np.linalg.norm(r, 2) for r in R]) if R.size else np.zeros(0)


# ------------------------------------------------------------------------------------------
# exact tests
# ------------------------------------------------------------------------------------------
def state_size(sc: ScaledModel) -> int:
    """Size bound of the exact test's eigenproblem, m·na + na (``_crossings``)."""
    return sc.poles.size * sc.na + sc.na


def _regular_E(sc: ScaledModel) -> bool:
    """E well conditioned (λ_min > 1e-8 λ_max): the exact test is a standard eigenproblem, about
    three times cheaper than the generalized one (``_crossings``)."""
    lam = np.linalg.eigvalsh(sc.C[-1])
    return bool(lam[0] > 1e-8 * max(abs(lam[-1]), 1e-300))


def _crossings(sc: ScaledModel, rank_tol=1e-12, imag_tol=1e-6) -> np.ndarray:
    """Normalised ν > 0 where G(ν) is singular, by one real eigenproblem in x = ν².

    For a symmetric, conjugate-closed model G(ν) = Im K(iν) = ν H(ν²) with
    H(x) = E − Σ_k R_k/(x + p_k²): a pole-residue form in x (poles q_k = −p_k², residues −R_k).
    Its real state-space realisation (per real pole a rank-r block, per conjugate pair one real
    2r block [[σ, −τ], [τ, σ]], q = σ + iτ) H(x) = E + C (xI − A)⁻¹ B has the zeros
    eig(A − B E⁻¹ C) (E well conditioned) or the finite eigenvalues of the pencil
    ([[A, B], [C, E]], diag(I, 0)); the real positive ones are the crossings ν = √x. Size
    Σ_k rank R_k ≤ m·na: a quarter of the Hamiltonian pencil of Φ(s) = K(s) − K(−s)ᵀ, and real.
    """
    import scipy.linalg as sla
    m = sc.poles.size
    R = sc.residues
    scale = max(np.abs(R).max() if R.size else 0.0, 1e-300)
    As, Bs, Cs = [], [], []
    for k, kind in enumerate(pole_kinds(sc.poles)):
        if kind == 2:
            continue
        q = -sc.poles[k] ** 2
        if kind == 0:
            u, sv, vh = np.linalg.svd(-R[k].real)
        else:
            u, sv, vh = np.linalg.svd(-R[k])
        r = int(np.sum(sv > rank_tol * scale))
        if r == 0:
            continue
        L, Rt = u[:, :r] * sv[:r], vh[:r]
        if kind == 0:
            As.append(np.full((1, 1), q.real) * np.eye(r))
            Bs.append(Rt)
            Cs.append(L)
        else:
            I = np.eye(r)
            As.append(np.block([[q.real * I, -q.imag * I], [q.imag * I, q.real * I]]))
            Bs.append(np.vstack([Rt.real, Rt.imag]))
            Cs.append(np.hstack([2 * L.real, -2 * L.imag]))
    E = sc.C[m + 1]
    if not As:
        return np.zeros(0)
    A = sla.block_diag(*As)
    B = np.vstack(Bs)
    Cm = np.hstack(Cs)
    if _regular_E(sc):
        x = np.linalg.eigvals(A - B @ np.linalg.solve(E, Cm))
    else:
        nx = A.shape[0]
        M = np.block([[A, B], [Cm, E]])
        N = np.zeros_like(M)
        N[:nx, :nx] = np.eye(nx)
        x = sla.eigvals(M, N)
        x = x[np.isfinite(x)]
    r = np.sqrt(np.abs(x))
    keep = (x.real > 1e-18) & (np.abs(x.imag) <= 2 * imag_tol * r * np.maximum(r, 1.0))
    return np.unique(np.round(np.sqrt(x[keep].real), 12))


def _bands_from_crossings(sc, crossings, grid):
    """Violation intervals (ν) from the crossing frequencies plus the dense grid."""
    edges = np.concatenate([[0.0], np.sort(crossings), [np.inf]])
    mids = []
    for a, b in zip(edges[:-1], edges[1:]):
        mids.append(0.5 * (a + b) if np.isfinite(b) else (2 * a if a > 0 else 1.0))
    definite = _positive_definite(sc, np.array(mids))
    bands = []
    for (a, b), ok in zip(zip(edges[:-1], edges[1:]), definite):
        if ok:
            continue
        if bands and bands[-1][1] == a:     # a crossing of another eigenvalue inside a violation:
            bands[-1] = (bands[-1][0], b)   # one band (else each piece gets its own constraints)
        else:
            bands.append((a, b))
    return bands, len(mids)


def _M_basis(nu, poles, order=0) -> np.ndarray:
    """The basis of M(ν) = G(ν)/ν (``order`` 0) or of dM/dν (1) at ν (F,) ≥ 0, shape (F, m + 2): ``real_basis``'
    Im at iν over ν in closed form, finite at ν = 0. With q = 1/(ν² + p²): per real pole −Re q, per pair
    (−2 Re q, 2 Im q), D's column 0, E's 1; for dM/dν, q is replaced by dq/dν = −2ν q² and E's column is 0."""
    nu = np.atleast_1d(np.asarray(nu, float))
    q = 1.0 / (nu[:, None] ** 2 + poles[None, :] ** 2) if poles.size else np.zeros((nu.size, 0), complex)
    if order:
        q = -2 * nu[:, None] * q * q
    cols = []
    for k, kind in enumerate(pole_kinds(poles)):
        if kind == 0:
            cols.append(-q[:, k].real)
        elif kind == 1:
            cols += [-2 * q[:, k].real, 2 * q[:, k].imag]
    cols += [np.zeros(nu.size), np.full(nu.size, 0.0 if order else 1.0)]
    return np.column_stack(cols)


def _M(sc: ScaledModel, nu, order=0) -> np.ndarray:
    """M(ν) = G(ν)/ν = E − Σ_k R_k/(ν² + p_k²) (``order`` 0; every pole, a pair's two members each) or
    dM/dν (1) at normalised frequencies ν (F,) ≥ 0: shape (F, na, na), real symmetric, finite at ν = 0."""
    nu = np.atleast_1d(np.asarray(nu, float))
    return (_M_basis(nu, sc.poles, order) @ sc.columns.T).reshape(nu.size, sc.na, sc.na)


def _bounded_below(sc: ScaledModel, nu, shifts, chunk=64) -> np.ndarray:
    """Whether M(ν) − s·I ≻ 0 for each ν and shift s, i.e. λ_min(M(ν)) > s: one Cholesky factorisation
    (LAPACK potrf, n³/3) each, on the F-ordered view of the symmetric M so that nothing is copied."""
    from scipy.linalg.lapack import dpotrf
    nu = np.asarray(nu, float)
    out = np.empty(nu.size, bool)
    diag = np.arange(sc.na)
    chunk = _chunk(sc, chunk)
    for i in range(0, nu.size, chunk):
        for j, M in enumerate(_M(sc, nu[i:i + chunk])):
            M[diag, diag] -= shifts[i + j]
            out[i + j] = dpotrf(M.T, lower=1, clean=0, overwrite_a=1)[1] == 0
    return out


def _second_order(sc: ScaledModel, c, h, s, chunk=64):
    """Per interval [c − h, c + h]: whether M(c) ± h·M'(c) − s·I ≻ 0 (both signs; the second factorisation
    only when the first succeeds), so that M(c) + t·M'(c) ⪰ s·I for every |t| ≤ h (a convex combination
    of the two). Returns (passed, factorisations)."""
    from scipy.linalg.lapack import dpotrf
    out = np.zeros(c.size, bool)
    n_fact = 0
    diag = np.arange(sc.na)
    chunk = max(1, _chunk(sc, chunk) // 2)
    work = np.empty((sc.na, sc.na), order="F")
    for i in range(0, c.size, chunk):
        cc = c[i:i + chunk]
        B = np.concatenate([_M_basis(cc, sc.poles), _M_basis(cc, sc.poles, 1)])
        MM = (B @ sc.columns.T).reshape(2, cc.size, sc.na, sc.na)
        for j in range(cc.size):
            ok = True
            for sign in (1.0, -1.0):
                np.multiply(MM[1, j].T, sign * h[i + j], out=work)
                work += MM[0, j].T
                work[diag, diag] -= s[i + j]
                n_fact += 1
                if dpotrf(work, lower=1, clean=0, overwrite_a=1)[1] != 0:
                    ok = False
                    break
            out[i + j] = ok
    return out, n_fact


def _norm_bound(A, iters=30) -> float:
    """A proved upper bound of ‖A‖₂ for a real symmetric A without its eigenvalues: a power-iteration
    estimate (from a fixed start) raised by 5 %, then by 25 % until two Cholesky factorisations,
    t·I ∓ A ≻ 0, succeed (the SVD of a 2506² residue takes minutes; this, about a second)."""
    from scipy.linalg.lapack import dpotrf
    n = A.shape[0]
    v = np.ones(n) / np.sqrt(n)
    est = 0.0
    for _ in range(iters):
        w = A @ v
        est = float(np.linalg.norm(w))
        if est == 0.0:
            break
        v = w / est
    t = max(1.05 * est, 1e-300 + np.abs(A).max() * 1e-12)
    diag = np.arange(n)
    work = np.empty((n, n), order="F")
    for _ in range(200):
        if all(_factor_shifted(work, A, sign, t, diag, dpotrf) for sign in (1.0, -1.0)):
            return t
        t *= 1.25
    return float(np.abs(A).sum(axis=1).max())                # the ∞-norm bound (not reached in practice)


def _factor_shifted(work, A, sign, t, diag, dpotrf) -> bool:
    """Whether t·I − sign·A ≻ 0 (one Cholesky factorisation in ``work``)."""
    np.multiply(A.T, -sign, out=work)
    work[diag, diag] += t
    return dpotrf(work, lower=1, clean=0, overwrite_a=1)[1] == 0


def _residue_bounds(sc: ScaledModel) -> np.ndarray:
    """Per pole, an upper bound of ‖R_k‖₂ good for the sums of ``_curvatures`` and ``_tail``: a real pole's
    ‖C_k‖₂, each member of a pair sqrt(‖A‖₂² + ‖B‖₂²) (R = A + iB the pair's two real coefficient matrices:
    ‖Re(R w)‖ = ‖A Re w − B Im w‖ ≤ sqrt(‖A‖² + ‖B‖²)|w|), each by ``_norm_bound``."""
    m = sc.poles.size
    t = np.array([_norm_bound(sc.C[k]) for k in range(m)])
    out = t.copy()
    for k, kind in enumerate(pole_kinds(sc.poles)):
        if kind == 1:
            out[k] = out[k + 1] = np.hypot(t[k], t[k + 1])
    return out


def _curvatures(sc: ScaledModel, rn, a, b) -> np.ndarray:
    """Upper bounds of ‖d²M/dν²‖₂ on the intervals [a, b]: d²M/dν² = Σ_k R_k (2/(ν² + p_k²)² − 8ν²/(ν² + p_k²)³)
    (every pole) and |ν² + p²| = |p − iν| |p + iν| ≥ D_k = d_k⁺ d_k⁻, the distances of p_k to the segments
    ±i[a, b]: ‖d²M/dν²‖ ≤ Σ_k ‖R_k‖ (2/D_k² + 8b²/D_k³)."""
    p = sc.poles
    if not p.size:
        return np.zeros(a.size)
    d_plus = np.abs(p[None, :] - 1j * np.clip(p.imag[None, :], a[:, None], b[:, None]))
    d_minus = np.abs(p[None, :] + 1j * np.clip(-p.imag[None, :], a[:, None], b[:, None]))
    D = d_plus * d_minus
    return np.sum(rn[None, :] * (2 / D ** 2 + 8 * b[:, None] ** 2 / D ** 3), axis=1)


def _tail(sc: ScaledModel, rn, top):
    """(ν_hi, cleared): above ν_hi > max |p_k|, λ_min(M) ≥ λ_min(E) − Σ_k ‖R_k‖/(ν² − |p_k|²) ≥ 0 (the bound
    grows with ν); (top, False) when E is not positive definite or no ν_hi up to 1.25^200 clears it."""
    m = sc.poles.size
    e_min = np.linalg.eigvalsh(sc.C[m + 1])[0] if sc.na else 0.0
    pa = np.abs(sc.poles)
    nu = 1.0
    if e_min > 0:
        for _ in range(200):
            if (not pa.size or nu > pa.max() * (1 + 1e-9)) and e_min >= np.sum(rn / (nu ** 2 - pa ** 2)):
                return nu, True
            nu *= 1.25
    return top, False


def _cholesky_sweep(sc, grid, max_evals=4000, probes=MARGIN_PROBES):
    """Certified sweep by shifted Cholesky factorisations (module docstring); returns (bands in ν, the
    points ν > 0 where λ_min(G) was computed, those λ_min(G), certified, factorisations + eigensolutions).

    On M(ν) = G(ν)/ν (its λ_min is the margin's quantity), Taylor's theorem with the remainder bounded
    gives M(ν) ⪰ M(c) + (ν − c) M'(c) − ½ h² L₂ I on [c − h, c + h], L₂ ≥ ‖M''‖ there (``_curvatures``):
    two Cholesky factorisations that succeed, M(c) ± h M'(c) − ½ h² L₂ I ≻ 0 (``_second_order``), prove
    M ≻ 0 on the whole interval. Intervals start on a coarse grid from 0 to the tail's ν_hi (``_tail``)
    and are bisected until they pass. One that fails after ``SIGN_LEVEL`` bisections has its centre's
    sign tested (M(c) + ROUND_OFF·I ≻ 0, one factorisation); a centre that fails it is a violation: the
    interval is a band (touching bands merge) and is not split further; each band edge is then narrowed
    by ``BAND_BISECTIONS`` sign tests between the band's end and its outermost violating centre, and one
    eigensolution per band (at its first violating centre) gives its depth. The reported margin is the least eigenvalue found: those, and at the centres of the
    ``probes`` narrowest certified intervals (where the certificate was hardest)."""
    rn = _residue_bounds(sc)
    nu_hi, certified = _tail(sc, rn, max(grid[-1], 1.0))
    edges = np.linspace(0.0, min(2.0, nu_hi), 17)
    if nu_hi > 2.0:
        n_geo = int(np.ceil(np.log(nu_hi / 2) / np.log(1.5))) + 1
        edges = np.concatenate([edges, np.geomspace(2.0, nu_hi, n_geo)[1:]])
    a, b = edges[:-1], edges[1:]
    level = np.zeros(a.size, int)
    done, bad = [], []
    evals = 0
    while a.size:
        if evals + 3 * a.size > max_evals:
            certified = False
            break
        c, h = 0.5 * (a + b), 0.5 * (b - a)
        ok, n_fact = _second_order(sc, c, h, 0.5 * h ** 2 * _curvatures(sc, rn, a, b))
        evals += n_fact
        done.append(np.column_stack([a[ok], b[ok]]))
        tiny = ~ok & (b - a <= 1e-12 * b)                  # not certified, not split further
        certified = certified and not tiny.any()
        violates = np.zeros(a.size, bool)
        test = np.nonzero(~ok & ~tiny & (level >= SIGN_LEVEL))[0]
        if test.size:
            violates[test] = ~_bounded_below(sc, c[test], np.full(test.size, -ROUND_OFF))
            evals += test.size
            bad.append(np.column_stack([a[violates], b[violates]]))
        split = ~ok & ~tiny & ~violates
        a, b, level = np.concatenate([a[split], c[split]]), np.concatenate([c[split], b[split]]), np.tile(level[split] + 1, 2)
    bands, first, last = [], [], []                      # merged bands, their first and last violating centres
    for lo, hi in (sorted(map(tuple, np.concatenate(bad))) if bad else []):
        if bands and bands[-1][1] >= lo:
            bands[-1] = (bands[-1][0], max(bands[-1][1], hi))
        else:
            bands.append((lo, hi))
            first.append(0.5 * (lo + hi))
        last[len(bands) - 1:] = [0.5 * (lo + hi)]
    if bands:                                          # each edge: bisection on the sign between the
        out = np.array([lo for lo, _ in bands] + [hi for _, hi in bands])     # interval's end and the
        inn = np.array(first + last)                                          # violating centre
        for _ in range(BAND_BISECTIONS):
            mid = 0.5 * (out + inn)
            neg = ~_bounded_below(sc, mid, np.full(mid.size, -ROUND_OFF))
            evals += mid.size
            inn, out = np.where(neg, mid, inn), np.where(neg, out, mid)
        bands = [(float(lo), float(hi)) for lo, hi in zip(out[:len(bands)], out[len(bands):])]
    # the margin: one eigensolution per band, and at the centres of the narrowest certified intervals
    done = np.concatenate(done) if done else np.zeros((0, 2))
    narrow = done[np.argsort(done[:, 1] - done[:, 0], kind="stable")[:probes]]
    pts = np.concatenate([first, narrow.mean(axis=1)])
    vals = _lmin(sc, pts) if pts.size else np.zeros(0)
    return bands, pts, vals, certified, evals + pts.size


def _certified_sweep(sc, grid, max_evals=4000):
    """Adaptive certified sweep; returns (bands in ν, nodes, λ_min at nodes, certified, evals)."""
    m = sc.poles.size
    rn = _residue_norms(sc)
    E = sc.C[m + 1]
    e_norm = np.linalg.norm(E, 2)
    e_min = np.linalg.eigvalsh(E)[0]
    pa = np.abs(sc.poles)
    # tail: ν λmin(E) ≥ Σ ||R_k|| / (ν − |p_k|)
    nu_hi, tail_ok = max(grid[-1], 1.0), False
    if e_min > 0:
        for _ in range(200):
            if nu_hi > 2 * (pa.max() if pa.size else 0) and nu_hi * e_min >= np.sum(rn / (nu_hi - pa)):
                tail_ok = True
                break
            nu_hi *= 1.5
    nodes = np.unique(np.concatenate([grid, np.geomspace(grid[-1], nu_hi, 40)]))
    vals = _lmin(sc, nodes)
    evals = nodes.size
    certified = tail_ok
    while True:
        a, b = nodes[:-1], nodes[1:]
        # distance of each pole to the segment i[a, b]
        im = np.clip(sc.poles.imag[None, :], a[:, None], b[:, None])
        dist = np.abs(1j * im - sc.poles[None, :])
        L = e_norm + np.sum(rn[None, :] / dist ** 2, axis=1)
        lb = 0.5 * (vals[:-1] + vals[1:] - L * (b - a))
        need = (lb < 0) & (vals[:-1] >= 0) & (vals[1:] >= 0) & ((b - a) > 1e-12 * b)
        if not need.any():
            break
        if evals + need.sum() > max_evals:
            certified = False
            break
        new = 0.5 * (a[need] + b[need])
        nv = _lmin(sc, new)
        evals += new.size
        order = np.argsort(np.concatenate([nodes, new]))
        nodes = np.concatenate([nodes, new])[order]
        vals = np.concatenate([vals, nv])[order]
    return _runs(nodes, vals < 0), nodes, vals, certified, evals


def _runs(nodes, bad) -> list:
    """Bands (ν) around each run of ``bad`` nodes, widened to the neighbouring nodes (0 below the
    first node, ∞ above the last)."""
    bands = []
    i = 0
    while i < nodes.size:
        if bad[i]:
            j = i
            while j + 1 < nodes.size and bad[j + 1]:
                j += 1
            lo = nodes[i - 1] if i > 0 else 0.0
            hi = nodes[j + 1] if j + 1 < nodes.size else np.inf
            bands.append((lo, hi))
            i = j + 1
        else:
            i += 1
    return bands


def _default_grid(n_grid=400):
    return np.concatenate([np.linspace(1e-4, 2.0, n_grid), np.geomspace(2.0, 50.0, n_grid // 8)[1:]])


def _band_samples(band, n=9):
    """n points inside a band (ν): linear, geometric when it spans more than a factor 4."""
    a, b = band
    if not np.isfinite(b):
        return np.geomspace(max(a, 1e-6) * 1.001, max(a, 1e-6) * 100, n)
    if a > 0 and b > 4 * a:
        return np.geomspace(a, b, n + 2)[1:-1]
    return np.linspace(a, b, n + 2)[1:-1]


def _assess(sc: ScaledModel, method="auto", n_grid=400, max_pencil=MAX_PENCIL, violations_only=False):
    """The passivity test (module docstring) as a dict (``_report`` makes it a PassivityReport).
    violations_only: when the exact test finds a violation deeper than round-off, return it without
    the margin on the dense grid (the enforcement needs the bands, not the margin)."""
    grid = _default_grid(n_grid)
    if method == "auto":
        method = "hamiltonian" if state_size(sc) <= max_pencil * (1 + 2 * _regular_E(sc)) else "sweep"
    crossings = np.zeros(0)
    if method == "hamiltonian":
        crossings = _crossings(sc)
        bands, evals = _bands_from_crossings(sc, crossings, grid)
        if violations_only and bands:
            a = _verdict(sc, method, bands, crossings, np.zeros(0), np.zeros(0), True, evals)
            if not a["passive"]:
                return a
        nodes = grid
        vals = _lmin(sc, nodes)
        evals += nodes.size
        certified = True
        # the grid must agree with the crossings: a negative grid value outside every band
        # means a crossing was lost to round-off; fall back to the grid's verdict there
        for v, x in zip(vals, nodes):
            if v < 0 and not any(a <= x <= b for a, b in bands):
                bands.append((x, x))
    elif method == "sweep":
        sweep = _cholesky_sweep if sc.na >= CHOLESKY_SWEEP_NA else _certified_sweep
        bands, nodes, vals, certified, evals = sweep(sc, grid)
    else:
        raise FitError(f"unknown passivity method {method!r}: use 'auto', 'hamiltonian' or 'sweep'")
    return _verdict(sc, method, bands, crossings, nodes, vals, certified, evals)


def _verdict(sc, method, bands, crossings, nodes, vals, certified, evals) -> dict:
    """Margin (min of λ_min/ν over the nodes and samples inside the bands), E and K(0), verdict."""
    na = sc.na
    pts = np.concatenate([nodes] + [_band_samples(b) for b in bands])
    mu = np.concatenate([vals / nodes, _lmin(sc, pts[nodes.size:]) / pts[nodes.size:]])
    evals += pts.size - nodes.size
    k = int(np.argmin(mu))
    m = sc.poles.size
    e_min = float(np.linalg.eigvalsh(sc.C[m + 1])[0]) if na else 0.0
    K0 = np.real(np.einsum("b,bij->ij", real_basis(np.zeros(1), sc.poles)[0], sc.C.astype(complex)))
    static_min = float(np.linalg.eigvalsh(0.5 * (K0 + K0.T))[0]) if na else 0.0
    e_tol = -1e-12 * max(np.abs(sc.C[m + 1]).max(), 1e-300)
    # a band whose depth is round-off (the margin, sampled inside every band, >= -1e-12 of the
    # scaled model) is no violation: a 10-pole reactor fit had one at 6e11 Hz, 9.8e-16 deep
    passive = e_min >= e_tol and static_min >= 0 and float(mu[k]) >= -ROUND_OFF
    return dict(method=method, bands=bands, crossings=crossings, margin=float(mu[k]), margin_nu=float(pts[k]),
                certified=certified, e_min=e_min, static_min=static_min, passive=passive, evals=evals)


def _report(sc, a) -> PassivityReport:
    hz = sc.w_ref / (2 * np.pi)
    return PassivityReport(a["passive"], a["margin"], a["margin_nu"] * hz,
                           [(lo * hz, hi * hz) for lo, hi in a["bands"]], a["method"], a["certified"],
                           [float(c * hz) for c in a["crossings"]], a["e_min"], a["static_min"], a["evals"])


_REPORTS: OrderedDict = OrderedDict()   # (model digest, settings) -> report, the last REPORT_CACHE_SIZE

#: provenance key of a passivity test stored with a model (``with_verified_passivity``)
VERIFIED = "passivity_verified"


def check_passive(model: RationalModel, method="auto", n_grid=400, max_pencil=MAX_PENCIL) -> PassivityReport:
    """Passivity of ``model``: dense grid + an exact test (see module docstring).

    The exact test costs up to seconds for a (6+N)² model, so it runs once per model content:
    a test stored in the model's provenance by ``with_verified_passivity`` (a fit stores it;
    it travels with the model into the fit cache, whose entries are checksummed, and to worker
    processes) is used when its digest and settings are this model's and these; otherwise the
    last ``REPORT_CACHE_SIZE`` reports are kept by the model's content, so the fit, the export
    and each soil stepper built from one model in a process share one check.
    """
    key = (model.digest, method, n_grid, max_pencil)
    if key in _REPORTS:
        _REPORTS.move_to_end(key)
    else:
        stored = _stored_report(model, method, n_grid, max_pencil)
        if stored is None:
            sc = model.scaled
            stored = _report(sc, _assess(sc, method, n_grid, max_pencil))
        _REPORTS[key] = stored
        while len(_REPORTS) > REPORT_CACHE_SIZE:
            _REPORTS.popitem(last=False)
    return _REPORTS[key]


def _remember(model: RationalModel, sc: ScaledModel, method, used: str, report: PassivityReport) -> None:
    """Keep ``report``, the passing test of the scaled model ``sc`` at the default grid and
    ``MAX_PENCIL`` (``method`` asked, ``used`` run), as ``check_passive(model, ...)``'s when
    ``model.scaled`` is ``sc`` exactly (same active DOFs, scaling, reference frequency, poles and
    coefficients, bit for bit): the test is deterministic in those, so running it again (the
    certified sweep: minutes at 1207 DOFs) would give this report. Kept for ``method`` and, when
    ``used`` is what "auto" picks for this size, for "auto" (``with_verified_passivity``'s)."""
    t = model.scaled
    if t is not sc and not (t.w_ref == sc.w_ref and all(np.array_equal(getattr(t, k), getattr(sc, k))
                                                         for k in ("idx", "S", "poles", "C"))):
        return
    auto = "hamiltonian" if state_size(sc) <= MAX_PENCIL * (1 + 2 * _regular_E(sc)) else "sweep"
    for m in {method, "auto"} if used == auto else {method}:
        key = (model.digest, m, 400, MAX_PENCIL)
        _REPORTS[key] = report
        _REPORTS.move_to_end(key)
    while len(_REPORTS) > REPORT_CACHE_SIZE:
        _REPORTS.popitem(last=False)


def _settings(method, n_grid, max_pencil) -> dict:
    return {"method": str(method), "n_grid": int(n_grid), "max_pencil": int(max_pencil)}


def _stored_report(model: RationalModel, method, n_grid, max_pencil) -> PassivityReport | None:
    """The report stored in the model's provenance for this content and these settings, or None."""
    rec = model.provenance.get(VERIFIED)
    if not isinstance(rec, dict) or rec.get("digest") != model.digest or \
            rec.get("settings") != _settings(method, n_grid, max_pencil) or not isinstance(rec.get("report"), dict):
        return None
    return PassivityReport.from_dict(rec["report"])


def with_verified_passivity(model: RationalModel, method="auto", n_grid=400,
                            max_pencil=MAX_PENCIL) -> RationalModel:
    """``model`` with ``check_passive(model, ...)``'s report stored in its provenance (key
    VERIFIED: the content digest it was run on, the settings, the report), so the time
    steppers' guard (``require_passive``) reads it instead of testing again. A model whose
    content changes no longer matches its digest and is tested again."""
    rep = check_passive(model, method, n_grid, max_pencil)
    rec = {"digest": model.digest, "settings": _settings(method, n_grid, max_pencil), "report": rep.to_dict()}
    return model.with_provenance(dict(model.provenance, **{VERIFIED: rec}))


def require_passive(model: RationalModel, force=False, report: PassivityReport | None = None) -> PassivityReport:
    """Guard before a time stepper: raise FitError on a non-passive model (warn only if force)."""
    report = report or check_passive(model)
    if not report.passive:
        msg = (f"rational soil model is not passive ({report}); a time simulation may blow up. "
               "Fix: fit with enforce=True (or call soil_impedance.passivity.enforce_passivity), "
               "or pass force=True to run anyway")
        if not force:
            raise FitError(msg)
        warnings.warn(msg.replace("pass force=True to run anyway", "running anyway (force=True)"),
                      RuntimeWarning, stacklevel=2)
    return report


# ------------------------------------------------------------------------------------------
# enforcement
# ------------------------------------------------------------------------------------------
def _stretch(sc: ScaledModel, protect, n: int):
    """(T, T⁻¹), (na, na), of the protected DOF patterns ``protect`` (n, k) in the scaled coordinates
    (module docstring), or (None, None): T = I + U(σ − 1)Uᵀ with S⁻¹R = U σ Vᵀ, σ < 1 left at 1 (a
    pattern is never made cheaper to change than the Frobenius measure)."""
    if protect is None:
        return None, None
    R = np.asarray(protect, float)
    if R.ndim != 2 or R.shape[0] != n or not np.all(np.isfinite(R)):
        raise FitError(f"protect must be a finite ({n}, k) matrix of DOF patterns (one row per model DOF), "
                       f"got shape {R.shape}")
    U, sig, _ = np.linalg.svd(R[sc.idx] / sc.S[:, None], full_matrices=False)
    U, sig = U[:, sig > 1], sig[sig > 1]
    eye = np.eye(sc.na)
    return eye + (U * (sig - 1)) @ U.T, eye + (U * (1 / sig - 1)) @ U.T


def _screen(sc: ScaledModel, grid, limit=64):
    """The enforcement's pre-screen: (violation bands (ν), worst λ_min/ν, its ν) seen on the grid.
    Bands are the runs of grid points where λ_min(G)/ν ≤ −``ROUND_OFF`` (a Cholesky factorisation
    each, ``_runs``; the exact test's tolerance: a G singular to round-off is no violation); the worst value is the minimum of λ_min/ν over at most ``limit`` of those points,
    evenly spread (the progress measure of the enforcement). ([], nan, nan) when the grid sees none:
    then the exact test decides."""
    bad = ~_positive_definite(sc, grid, shift=ROUND_OFF)
    if not bad.any():
        return [], np.nan, np.nan
    idx = np.nonzero(bad)[0]
    idx = idx[np.unique(np.linspace(0, idx.size - 1, min(limit, idx.size)).round().astype(int))]
    mu = _lmin(sc, grid[idx]) / grid[idx]
    return _runs(grid, bad), float(mu.min()), float(grid[idx[np.argmin(mu)]])


def _factor_lower(A, shift, dpotrf):
    """Whether A − shift·I ≻ 0 for a real symmetric A (C-ordered; factorised in place on its F-ordered
    view, the same matrix, so nothing is copied): (success, the factor's F-ordered array)."""
    F = A.T
    F[np.diag_indices(F.shape[0])] -= shift
    return dpotrf(F, lower=1, clean=0, overwrite_a=1)[1] == 0, F


def _smallest_estimate(L, dpotrs, iters=3) -> float:
    """An estimate (from above) of λ_min(A) from its Cholesky factor L (F-ordered, lower): 1/‖A⁻¹x‖ after
    ``iters`` steps of inverse iteration from a fixed start (two triangular solves each, 2n² flops, memory-bound:
    about a factorisation's time at 1006 DOFs for six steps, hence three). Only a guess of the next shift (``_Rescreen``), never a proof."""
    n = L.shape[0]
    x = np.cos(np.arange(1, n + 1) * 0.7548776662466927) + 0.5      # fixed, deterministic start
    x /= np.linalg.norm(x)
    y = x
    for _ in range(iters):
        y = dpotrs(L, x, lower=1)[0]
        ny = float(np.linalg.norm(y))
        if not np.isfinite(ny) or ny == 0.0:
            return 0.0
        x = y / ny
    return 1.0 / ny


class _Rescreen:
    """The enforcement's grid screen from ``CHOLESKY_SWEEP_NA`` active DOFs: the same verdict per grid
    point as ``_screen`` (λ_min(G(ν))/ν ≤ −``ROUND_OFF`` is a violation), at a cost bounded by the
    points the enforcement's change reaches, not by the grid.

    Each point carries a proved slack σ ≥ 0 with λ_min(G(ν))/ν ≥ σ − ROUND_OFF for the model last screened
    (−1: a violation). It is proved by one Cholesky factorisation of G(ν) − s·ν·I, at
    s = ½ × an estimate of λ_min/ν (inverse iteration on the factor of the point's last factorisation,
    else of the grid neighbour's), σ = s + ROUND_OFF; if that factorisation fails, the plain test
    G(ν) + ROUND_OFF·ν·I ≻ 0 decides (σ = 0 when it passes). When the coefficients change by ΔC (the
    model's columns against those of the last screen), Weyl's inequality and ‖·‖₂ ≤ ‖·‖_F give
    |λ_min(G + ΔG) − λ_min(G)| ≤ ‖ΔG(ν)‖_F = sqrt(g(ν)ᵀ W g(ν)), g(ν) the basis' Im at iν and
    W_bc = ⟨ΔC_b, ΔC_c⟩ (one (m + 2)² Gram matrix for the whole grid), so σ drops by that over ν, and only
    the points whose σ turns negative (and the violations) are factorised again; ``refine`` adds points
    across bands found between the grid's. Returns what ``_screen``
    returns, with the depth NaN (the enforcement then takes the planes' sampled depth: the eigenvalues at
    64 grid points of ``_screen`` cost 3 minutes at 2506 DOFs)."""

    def __init__(self, grid):
        self.grid = np.asarray(grid, float)
        self.slack = np.full(self.grid.size, -1.0)
        self.estimate = np.full(self.grid.size, np.nan)      # λ_min/ν estimates (the next shift's guess)
        self.C = None                                          # the coefficients last screened
        self.factorisations = 0
        self.calls = []                                        # points factorised per call

    def refine(self, bands, n=REFINE_POINTS) -> None:
        """Add ``n`` points across each finite band ± half its width (violations the exact test found
        between the grid's points), factorised at the next call: the following iterations see such a band
        on the grid, and the exact test runs again only when the refined grid is clean."""
        new = [np.linspace(max(lo - 0.5 * (hi - lo), 0.0), hi + 0.5 * (hi - lo), n) for lo, hi in bands
               if np.isfinite(hi) and hi > lo]
        new = np.setdiff1d(np.concatenate(new), self.grid) if new else np.zeros(0)
        new = new[new > 0]
        if not new.size:
            return
        grid = np.concatenate([self.grid, new])
        order = np.argsort(grid, kind="stable")
        self.grid = grid[order]
        self.slack = np.concatenate([self.slack, np.full(new.size, -1.0)])[order]
        self.estimate = np.concatenate([self.estimate, np.full(new.size, np.nan)])[order]

    def change_bound(self, st: ScaledModel) -> np.ndarray:
        """sqrt(g(ν)ᵀ W g(ν)) ≥ ‖G_new(ν) − G_old(ν)‖_F at each grid point (see the class docstring)."""
        nb = st.C.shape[0]
        new, old = st.C.reshape(nb, -1), self.C.reshape(nb, -1)
        W = np.zeros((nb, nb))
        step = max(1, (1 << 22) // nb)
        for j in range(0, new.shape[1], step):
            d = new[:, j:j + step] - old[:, j:j + step]
            W += d @ d.T
        g = real_basis(1j * self.grid, st.poles).imag
        q = np.einsum("fb,bc,fc->f", g, W, g)
        q += 1e-10 * np.einsum("fb,bc,fc->f", np.abs(g), np.abs(W), np.abs(g))    # its rounding (cancellation)
        return np.sqrt(np.maximum(q, 0.0)) * (1 + 1e-8) + 1e-300

    def __call__(self, st: ScaledModel):
        from scipy.linalg.lapack import dpotrf, dpotrs
        grid = self.grid
        if self.C is not None and st.C is not self.C:
            drop = self.change_bound(st) / grid
            self.slack = np.where(self.slack >= 0, self.slack - drop, -1.0)
        redo = np.nonzero(self.slack < 0)[0]
        chunk = _chunk(st, 64)
        for i0 in range(0, redo.size, chunk):
            pts = redo[i0:i0 + chunk]
            for i, G in zip(pts, _G(st, grid[pts])):
                nu = grid[i]
                guess = self.estimate[i]
                if not np.isfinite(guess) and i > 0:
                    guess = self.estimate[i - 1]
                s = 0.5 * guess if np.isfinite(guess) and guess > 0 else np.nan
                if np.isfinite(s):
                    ok, L = _factor_lower(G, s * nu, dpotrf)
                    self.factorisations += 1
                    if ok:
                        self.slack[i] = s + ROUND_OFF
                        self.estimate[i] = s + _smallest_estimate(L, dpotrs) / nu
                        continue
                    G = _G(st, [nu])[0]                        # the guess was too high: the plain test
                ok, L = _factor_lower(G, -ROUND_OFF * nu, dpotrf)
                self.factorisations += 1
                self.slack[i] = 0.0 if ok else -1.0
                self.estimate[i] = _smallest_estimate(L, dpotrs) / nu - ROUND_OFF if ok else -1.0
        self.calls.append(int(redo.size))
        self.C = st.C
        bad = self.slack < 0
        if not bad.any():
            return [], np.nan, np.nan
        return _runs(grid, bad), np.nan, np.nan


@dataclass(frozen=True)
class _Planes:
    """Cutting planes of the enforcement: rank-one ones v vᵀ (at ν1 (p,), V (p, na) unit vectors) and
    deficit ones (at νd (q,), N (q, na²) flattened, unit Frobenius norm); ``lift`` (p + q,): what each
    asks for above the margin, in the units of λ (``_planes``' overshoot; zeros by default)."""

    nu1: np.ndarray
    V: np.ndarray
    nud: np.ndarray
    N: np.ndarray
    lift: np.ndarray = None

    def __post_init__(self):
        if self.lift is None:
            object.__setattr__(self, "lift", np.zeros(self.nu1.size + self.nud.size))

    @classmethod
    def none(cls, na) -> _Planes:
        return cls(np.zeros(0), np.zeros((0, na)), np.zeros(0), np.zeros((0, na * na)))

    def __add__(self, other) -> _Planes:
        k, j = self.nu1.size, other.nu1.size
        lift = np.concatenate([self.lift[:k], other.lift[:j], self.lift[k:], other.lift[j:]])
        return _Planes(*(np.concatenate([a, b]) for a, b in zip(
            (self.nu1, self.V, self.nud, self.N), (other.nu1, other.V, other.nud, other.N))), lift)

    def kept(self, keep) -> _Planes:
        """The planes where ``keep`` (rank-one ones first) is True."""
        k1, kd = keep[:self.nu1.size], keep[self.nu1.size:]
        return _Planes(self.nu1[k1], self.V[k1], self.nud[kd], self.N[kd], self.lift[keep])

    @property
    def size(self) -> int:
        return self.nu1.size + self.nud.size


def _full_eigh(sc: ScaledModel, nus, margin):
    """(ν, eigenvalues ascending, eigenvectors) of G at each ν of ``nus``: every eigenpair."""
    lam, vec = np.linalg.eigh(_G(sc, nus))
    return zip(nus, lam, vec)


def _partial_eigh(sc: ScaledModel, nus, margin):
    """(ν, eigenvalues ascending, eigenvectors) of G at each ν of ``nus``: only the eigenpairs below
    margin·ν, the ones the planes use (``_full_eigh``'s to round-off, up to the eigenvectors' signs and
    their basis inside a repeated eigenvalue). A Cholesky factorisation of G − margin·ν·I first (n³/3): when
    it succeeds there is none; else LAPACK's dsyevr for the eigenvalues in (−∞, margin·ν] (a tridiagonal
    reduction, then bisection and inverse iteration for those alone: a third of a full eigh at 1206 DOFs)."""
    import scipy.linalg as sla
    from scipy.linalg.lapack import dpotrf
    for nu, G in zip(nus, _G(sc, nus)):
        keep = G.copy()
        ok, _ = _factor_lower(G, margin * nu, dpotrf)
        if ok:
            yield nu, np.zeros(0), np.zeros((sc.na, 0))
            continue
        lam, X = sla.eigh(keep, subset_by_value=(-np.inf, margin * nu), driver="evr", check_finite=False)
        yield nu, lam, X


def _planes(sc: ScaledModel, bands, margin, n_samples=9, limit=MAX_PLANES, rank_one=RANK_ONE_PLANES, chunk=32,
            partial=None, overshoot=None):
    """Cutting planes at samples across each band and its neighbours (module docstring): (``_Planes``,
    (worst sampled λ_min/ν, its ν)). At each sample, with (λ_i, v_i) the eigenpairs of G(ν) and
    d_i = margin·ν − λ_i > 0 their deficits: one plane v_i v_iᵀ for each of the ``rank_one`` deepest,
    and when there are more, the deficit plane Σ_i d_i v_i v_iᵀ/‖d‖ too. The ``limit`` deepest planes
    (d_i, resp. ‖d‖) are kept. ``partial`` (default: from ``CHOLESKY_SWEEP_NA`` active DOFs) solves only for
    the eigenpairs below the margin (``_partial_eigh``); a sample without any counts margin as its depth.
    ``overshoot`` = (ρ, cap): each rank-one plane asks for min(ρ d_i, cap·ν) above the margin (its ``lift``)."""
    pts, deficit = [], []                # deficit: where a deficit plane (na² doubles) may be made
    stride = max(1, (n_samples - 1) // 8)  # at 9 of the samples of a band, however many: its memory bounded
    for a, b in bands:
        pts += list(_band_samples((a, b), n_samples))
        deficit += [k % stride == 0 for k in range(n_samples)]
        if np.isfinite(b):
            w = max(b - a, 1e-6 * max(b, 1e-3))
            pts += [max(a - 0.25 * w, 1e-6), b + 0.25 * w]
            deficit += [True, True]
        else:
            pts += [max(a * 0.95, 1e-6)]
            deficit += [True]
    pts = np.array(pts)
    na = sc.na
    nu1, V, size1, nud, N, sized, worst = [], [], [], [], [], [], (np.inf, np.nan)
    few = []                             # per rank-one plane: its sample has no deficit plane (few directions)
    chunk = _chunk(sc, chunk)
    eigen = _partial_eigh if partial or (partial is None and na >= CHOLESKY_SWEEP_NA) else _full_eigh
    for i in range(0, pts.size, chunk):
        for j, (nu, lv, X) in enumerate(eigen(sc, pts[i:i + chunk], margin)):
            if not lv.size:                             # G ⪰ margin·ν: no plane here
                worst = min(worst, (margin, nu))
                continue
            worst = min(worst, (lv[0] / nu, nu))
            d = margin * nu - lv
            sel = np.nonzero(d > 0)[0]                 # λ ascending: the deepest first
            nu1 += [nu] * min(sel.size, rank_one)
            V += list(X[:, sel[:rank_one]].T)
            size1 += list(d[sel[:rank_one]])
            few += [sel.size <= rank_one] * min(sel.size, rank_one)
            if sel.size > rank_one and deficit[i + j]:
                dn = np.linalg.norm(d[sel])
                nud.append(nu)
                N.append(((X[:, sel] * (d[sel] / dn)) @ X[:, sel].T).ravel())
                sized.append(dn)
    size = np.array(size1 + sized)
    keep = np.zeros(size.size, bool)
    keep[np.argsort(-size, kind="stable")[:limit]] = True
    lift = None
    if overshoot is not None:
        rho, cap = overshoot
        lift = np.where(few, np.minimum(rho * np.array(size1), cap * np.array(nu1)), 0.0)
        lift = np.concatenate([lift, np.zeros(len(sized))])
    planes = _Planes(np.array(nu1), np.array(V).reshape(-1, na), np.array(nud), np.array(N).reshape(-1, na * na), lift)
    return planes.kept(keep), worst


def _solve_dual(sc0: ScaledModel, planes: _Planes, Qinv, margin):
    """Minimal weighted change ΔC of the coefficients of ``sc0`` meeting every plane
    ⟨N_c, G(ν_c) + ΔG(ν_c)⟩ ≥ margin·ν_c·tr N_c + lift_c (N_c = v vᵀ for a rank-one plane):
    ΔC_b = Σ_c μ_c (Q⁻¹ g_c)_b N_c with g_c the basis' Im at iν_c over ν_c (a plane near ν = 0 keeps
    its weight) and μ ≥ 0 the NNLS solution of the dual. Returns (ΔC, μ)."""
    from scipy.optimize import nnls
    nb, na = sc0.C.shape[0], sc0.na
    p = planes
    nus = np.concatenate([p.nu1, p.nud])
    g = real_basis(1j * nus, sc0.poles).imag / nus[:, None]              # (nc, nb)
    CV = (sc0.C.reshape(nb * na, na) @ p.V.T).reshape(nb, na, -1)         # C_b v
    NC = np.vstack([(CV * p.V.T[None]).sum(axis=1).T, p.N @ sc0.C.reshape(nb, -1).T])   # ⟨N_c, C_b⟩
    trace = np.concatenate([np.ones(p.nu1.size), p.N[:, ::na + 1].sum(axis=1)])
    t = margin * trace - np.sum(g * NC, axis=1)
    if p.lift.any():                                                     # overshoot (from CHOLESKY_SWEEP_NA)
        t = t + p.lift / nus
    NV = np.einsum("qip,pi->pq", p.N.reshape(-1, na, na) @ p.V.T, p.V)   # vᵀ N v
    gram = np.block([[(p.V @ p.V.T) ** 2, NV], [NV.T, p.N @ p.N.T]])
    QG = Qinv @ g.T                                                      # (nb, nc)
    M = (g @ QG) * gram
    s = 1.0 / np.sqrt(np.maximum(np.diag(M), 1e-300))                     # unit diagonal: M spans decades
    M = 0.5 * (M + M.T) * s[:, None] * s[None, :] + 1e-12 * np.eye(M.shape[0])
    try:
        L = np.linalg.cholesky(M)
    except np.linalg.LinAlgError:                                        # PSD to round-off only
        lam, U = np.linalg.eigh(M)
        L = U * np.sqrt(np.maximum(lam, 1e-12))
    mu, _ = nnls(L.T, np.linalg.solve(L, s * t), maxiter=50 * M.shape[0])
    mu = mu * s
    coef = QG * mu[None, :]
    k = p.nu1.size
    dC = (coef[:, k:] @ p.N).reshape(nb, na, na) + (coef[:, :k, None] * p.V[None]).transpose(0, 2, 1) @ p.V
    return dC, mu


def _band_gram(nu_f, w, bands, poles, n=PLANE_SAMPLES) -> np.ndarray:
    """The measure of a change over the violation bands seen (ν), added to the fit's (``enforce_passivity``
    from ``CHOLESKY_SWEEP_NA``): Σ_x c_x² Re/Im φ(ix) φ(ix)ᵀ over ``n`` points x across each finite band,
    c_x² = w(x)² · h_x / Δ(x), w the fit's weights interpolated, Δ the spacing of its frequencies there and
    h_x the point's share of its band (the midpoints between the sorted points of overlapping bands bound
    it): the quadrature of the same integral Σ_f w_f² ‖ΔK(iω_f)‖² samples at the fit's frequencies, so a
    band between them weighs what it would if the fit had frequencies there, and overlapping bands are not
    counted twice. (nb, nb)."""
    nb = real_basis(np.zeros(1), poles).shape[1]
    finite = sorted((a, b) for a, b in bands if np.isfinite(b) and b > a)
    nu_f, first = np.unique(nu_f, return_index=True)           # sorted, for the interpolations
    w = np.asarray(w, float)[first]
    if nu_f.size < 2 or not finite:
        return np.zeros((nb, nb))
    groups = [[finite[0]]]
    for a, b in finite[1:]:                                    # overlapping bands: one group
        if a <= max(hi for _, hi in groups[-1]):
            groups[-1].append((a, b))
        else:
            groups.append([(a, b)])
    xs, hs = [], []
    for group in groups:
        lo, hi = min(a for a, _ in group), max(b for _, b in group)
        x = np.unique(np.concatenate([_band_samples(band, n) for band in group]))
        edges = np.concatenate([[lo], 0.5 * (x[1:] + x[:-1]), [hi]])
        xs.append(x)
        hs.append(np.diff(edges))
    x, h = np.concatenate(xs), np.concatenate(hs)
    spacing = np.interp(x, nu_f, np.gradient(nu_f))
    c = np.interp(x, nu_f, w) * np.sqrt(h / spacing)
    A = real_basis(1j * x, poles) * c[:, None]
    Ar = np.concatenate([A.real, A.imag])
    return Ar.T @ Ar


def _between(band, nu_f) -> bool:
    """Whether a band (ν) is narrower than two steps of the fit's frequencies ``nu_f`` around it (the fit's
    measure sees it at one frequency at most: ``_band_gram`` measures the change there)."""
    lo, hi = band
    nu = np.unique(nu_f)
    if not np.isfinite(hi) or nu.size < 2:
        return False
    return bool(hi - lo < 2 * np.interp(0.5 * (lo + hi), nu, np.gradient(nu)))


def enforce_passivity(model: RationalModel, freq_hz=None, weights=None, margin=1e-4, max_iter=30,
                      method="auto", e_floor=1e-6, progress=None, stall=8, protect=None):
    """Perturb the residues (and D, E) of ``model`` until the exact test passes (module docstring).

    freq_hz : (F,) Hz, weights : (F,)   the fit's frequencies and per-frequency weights (on the
        DOF-scaled matrices); they define the least-squares change that is minimised
        (default: 200 frequencies over [0, f_ref], uniform).
    margin : target passivity margin (dimensionless, see module docstring).
    max_iter : the work bound: at most this many corrections, each followed by one test (the grid
        pre-screen, and the exact test when the grid sees no violation: milliseconds for a small
        model, seconds for a (6+N)² one).
    progress : optional callable(done, total) after each test (total = max_iter + 1).
    stall : give up (FitError) after this many iterations without raising the worst margin seen (on
        the grid, else at the samples of the exact test's bands) by 5 % (a violation the cutting
        planes do not reduce: fewer poles are the remedy).
    protect : optional (n, k) DOF patterns R whose impedance Rᵀ K R the change must spare, each
        column scaled so that ‖S⁻¹ R‖² is the cost of a change of Rᵀ K R relative to the Frobenius
        measure (module docstring; ``fit`` passes the rigid-raft projection of a gap table).
    Returns (model, PassivityReport, iterations); the report is the exact test's, on the scaling of
    ``model``. Raises FitError (attribute ``iterations``) if not passive after max_iter iterations,
    or stalled.
    """
    sc0 = model.scaled
    T, Ti = _stretch(sc0, protect, model.n)
    st0 = sc0 if T is None else sc0.with_coefficients(T @ sc0.C @ T)      # the stretched coordinates
    if freq_hz is None:
        freq_hz = np.linspace(0, sc0.w_ref / (2 * np.pi), 200)
    nu_f = 2 * np.pi * np.asarray(freq_hz, float) / sc0.w_ref
    w = np.ones(nu_f.size) if weights is None else np.asarray(weights, float)
    A = real_basis(1j * nu_f, sc0.poles) * w[:, None]
    Ar = np.concatenate([A.real, A.imag])
    Q = Ar.T @ Ar
    Q += 1e-10 * np.trace(Q) / Q.shape[0] * np.eye(Q.shape[0])
    Qinv = np.linalg.inv(Q)
    m = sc0.poles.size
    K0_basis = real_basis(np.zeros(1), sc0.poles)[0]
    seen = []                  # the violation bands so far (from CHOLESKY_SWEEP_NA: ``_band_gram``)
    grid = _default_grid()
    planes = _Planes.none(sc0.na)
    st, sc = st0, sc0          # the current model, stretched and not
    best, since, bands = np.nan, 0, []
    large = sc0.na >= CHOLESKY_SWEEP_NA
    screen = _Rescreen(grid) if large else (lambda s: _screen(s, grid))
    if large:
        from scipy.linalg.lapack import dpotrf
    for it in range(max_iter + 1):
        bands, depth, at = screen(st)
        if not bands:
            a = _assess(sc, method, violations_only=True)
            if a["passive"]:
                if progress is not None:
                    progress(it + 1, max_iter + 1)
                prov = dict(model.provenance, passivity_enforced=True, passivity_iterations=it)
                out = model.with_provenance(prov) if it == 0 else sc0.unscale(sc.C, model, prov)
                rep = _report(sc0, a)
                _remember(out, sc, method, a["method"], rep)
                return out, rep, it
            bands = a["bands"]
            if isinstance(screen, _Rescreen):
                screen.refine(bands)
        if progress is not None:
            progress(it + 1, max_iter + 1)
        if it == max_iter:
            break
        if large:
            fresh = [b for b in bands if b not in seen and _between(b, nu_f)]
            if fresh:
                seen += fresh
                Qinv = np.linalg.inv(Q + _band_gram(nu_f, w, seen, sc0.poles))
            new, worst = _planes(st, bands, margin, n_samples=PLANE_SAMPLES, overshoot=(OVERSHOOT, OVERSHOOT_CAP))
        else:
            new, worst = _planes(st, bands, margin)
        if np.isnan(depth):                    # a violation the grid does not see: its sampled depth
            depth, at = worst
        if it == 0 or depth > best + 0.05 * abs(best):
            best, since = depth, 0
        else:
            since += 1
        if since >= stall:
            raise _failure(f"passivity enforcement stalled: no progress in {stall} iterations "
                           f"({_state(sc0, bands, depth, at)}): refit with fewer poles", it)
        planes = planes + new
        C = np.array(st0.C)
        if planes.size:
            dC, mu = _solve_dual(st0, planes, Qinv, margin)
            C = C + dC
            planes = planes.kept(mu > 0)                        # the active cutting planes
        if T is not None:
            C = Ti @ C @ Ti
        # E ⪰ floor·max eig (PSD projection; the floor makes the high-frequency tail certifiable)
        if not (large and _above_floor(C[m + 1], e_floor)):
            lam, vec = np.linalg.eigh(0.5 * (C[m + 1] + C[m + 1].T))
            floor = e_floor * max(lam.max(), 1e-300)
            C[m + 1] = (vec * np.maximum(lam, floor)) @ vec.T
        # K(0) ⪰ 0 through D (D does not change G)
        if large:                              # C is real: no complex copy of it (3 GB at 2506 DOFs, 30 poles)
            K0 = np.tensordot(K0_basis.real, C, axes=1)
        else:
            K0 = np.real(np.einsum("b,bij->ij", K0_basis, C.astype(complex)))
        if not (large and _factor_lower(0.5 * (K0 + K0.T), 0.0, dpotrf)[0]):
            lam0, vec0 = np.linalg.eigh(0.5 * (K0 + K0.T))
            if lam0[0] < 0:
                C[m] += (vec0 * np.maximum(-lam0, 0)) @ vec0.T
        sc = sc0.with_coefficients(C)
        st = sc if T is None else sc0.with_coefficients(T @ sc.C @ T)
    raise _failure(f"passivity enforcement did not converge in {max_iter} iterations "
                   f"({_state(sc0, bands, best, np.nan)}): refit with more poles or a lower tolerance, "
                   "or raise max_iter", max_iter)


def _above_floor(E, e_floor) -> bool:
    """Whether λ_min(E) ≥ e_floor·λ_max(E) is proved (then the enforcement's projection of E would move it
    by round-off only): a Cholesky factorisation of E − e_floor·t·I with t ≥ ‖E‖₂ (``_norm_bound``), a few
    factorisations instead of a full eigh (5 s at 2506 DOFs)."""
    from scipy.linalg.lapack import dpotrf
    E = 0.5 * (E + E.T)
    return _factor_lower(E, e_floor * _norm_bound(E), dpotrf)[0]


def _state(sc, bands, depth, at) -> str:
    """The violation an enforcement ended on, for its FitError."""
    hz = sc.w_ref / (2 * np.pi)
    where = f" at {at * hz:.4g} Hz" if np.isfinite(at) else ""
    return (f"worst margin seen {depth:.3e}{where}, violation bands: "
            + (", ".join(f"{a * hz:.4g}-{b * hz:.4g} Hz" for a, b in bands) or "none"))


def _failure(message, iterations) -> FitError:
    """The FitError of a failed enforcement, with its ``iterations`` (the work spent)."""
    exc = FitError(message)
    exc.iterations = iterations
    return exc

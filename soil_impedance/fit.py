"""Fit an ImpedanceTable with a passive common-pole rational model: ``fit_table``.

Pipeline: DOF scaling → causal target → pole identification on compressed
columns (relaxed vector fitting, ``vectfit``) → residues of every independent entry by one linear
least squares → (gap tables) rigid-raft correction (``rigid_correct``) → order chosen as the
smallest number of pole pairs meeting ``tol`` → E projected on the PSD cone → passivity enforced
(``passivity``) → report.

Conventions. The fit works on the DOF-scaled matrices S K S, S = diag(|Re K_ii(f_0)|)^{-1/2}
(f_0: lowest table frequency; DOFs whose rows are identically zero, e.g. uz, rx, ry of the
"gap" table, are left out and stay exactly zero in the model), in normalised frequency
ν = ω/ω_ref, ω_ref = 2π f_max. The error measure is the relative Frobenius error per frequency

    e(f) = ‖S (K_model(i2πf) − K_table(f)) S‖_F / ‖S K_table(f) S‖_F,

and ``max_rel_error`` is its maximum over the fitted band f ≥ f_causal (all f when f_causal = 0);
the unscaled error (SI units, dominated by the rotational terms) is reported too. Only the upper
triangle is fitted (D and every residue symmetric by construction); off-diagonal entries carry
weight √2 so that the least squares measures the full Frobenius norm.

Order selection of a gap table (DOFs ux..rz + w_1..w_N, with the rigid-raft correction on). Its
Frobenius norm is dominated by the N soil DOFs: on the reactor (N = 241, causal soil) 4 poles meet
1 % overall while the rigid-raft rocking impedance Pᵀ K P (``rigid_projection``), the quantity the
soil-structure response sees in full contact, is 5 % off in Im (its damping). So the order must also
meet ``tol`` on ``rigid_error``: the max over the six rigid DOFs of the relative Re and Im errors of
the diagonal of Pᵀ K P (``rigid_errors``), over the same band f ≥ f_causal as e(f) (every table
frequency for a causal soil): one band for both measures, and no soil-structure band to guess (the
reactor's is 2-8 Hz, a stiffer or softer site moves it). The selection criterion is
max(max_rel_error, rigid_error), measured on the rigid-corrected model before enforcement in the
order search and after it for the returned model (``tol_reached``). On the reactor at tol 0.01
this selects 8 poles (rigid error 0.3 %, overall 1e-4) instead of 4 (``benchmarks/soil_fit.py``).
The passivity enforcement is told to spare Pᵀ K P (``rigid_protection``: its change costs about its
relative error in the criterion): on disk-halfspace (undamped, 320 active DOFs) the 7-pole fit's
rigid error stays 0.195 % through the enforcement, where a Frobenius-only least-squares change
moved the rocking damping by 4 %; the fit takes 12 s instead of 207 s and meets tol 0.01.

Weighting: "relative" (default) w_f = 1/‖S K(f) S‖_F, the criterion itself; "uniform" w_f = 1
(absolute error in scaled units: favours the high-frequency end where |K| is large);
"entry": per entry inverse magnitude 1/max(|K_ij(f)|, 1e-3·max_f |K_ij|) for the residues (poles
are still identified with the relative weights; one least squares per entry: slower for large n).

Causality (the choice). Hysteretic material damping (complex moduli) gives Im K(ω → 0) → 2ξ K_0,
which no causal model can follow: a real rational K(iω) has Im K(0) = 0 and Im K odd in ω. Below
f_causal the hysteretic offset H0 = Im K(0⁺) (extrapolated to f = 0) is faded out of the target,
Im K_target(f) = Im K(f) − H0·(1 − f/f_causal)², real part kept: C¹ at f_causal and linear in f at
0 (an equivalent viscous damping, the low-frequency behaviour of any causal model). The fit is
then causal over the whole axis. ``f_causal_hz="auto"`` detects hysteretic damping (|H0| above
1e-3 of |K(f_0)|) and uses the first table frequency ≥ 5 % of f_max, otherwise 0 (the target is
the table); a table whose provenance says every material is causal (``damping_model = "causal"``,
``soil_impedance.profile``) is never faded, even when its first frequency is above the material's
cut-off (then Im K(f_0) extrapolates to a nonzero H0, which is not hysteretic damping). The error
against the original table below f_causal is reported as
``low_freq_error`` (≈ 2ξ at f = 0); it is not part of tol. Above f_causal a frequency-independent
loss factor is still not Kramers–Kronig consistent (a causal model must pair it with a
logarithmic dispersion of Re K), so the band error has a floor ≈ ξ that no order removes
(measured on k(1 + 2iξ) + iωc over 1..20 Hz: 1.1 %, 3.3 %, 5.4 % for ξ = 0.01, 0.03, 0.05;
reactor gap table with ξ = 0.03: 3–4 %). ``patience`` stops the order search on that floor.
A causal soil (``damping_model = "causal"``) has no such floor: the same reactor table computed
with it is fitted to 0.4 % with 4 poles, 0.03 % with 6 (``benchmarks/soil_fit.py --causal``).

Determinism and bounds. A fit is a function of the table and its ``FitOptions`` only: every budget
is counted in work (pole pairs tried, ``max_pairs``; orders enforced, 1 + ``max_enforce``;
iterations per enforcement, ``enforce_iter``), never in seconds, so a loaded machine gets the same
model, later. The options, the table hash, the node coordinates and the code digest are the cache
key. A tol that cannot be met within the bounds is reported (``tol_reached`` False, ``message``),
never hidden; ``progress(stage, done, total)`` follows the order search and each enforcement.
"""
from __future__ import annotations

import hashlib
import json
import time
import warnings
from dataclasses import asdict, dataclass, field, replace
from functools import cached_property
from pathlib import Path

import numpy as np

from .passivity import PassivityReport, check_passive, enforce_passivity, with_verified_passivity
from .rational import FitError, RationalModel, read_model, write_model
from .vectfit import canonical_poles, compress, fit_coefficients, initial_poles, real_basis, vector_fit

WEIGHTINGS = ("relative", "uniform", "entry")
RIGID = ("ux", "uy", "uz", "rx", "ry", "rz")
POLE_CAP = 30.0           # normalised |p| above which a pole only mimics a constant: dropped
RIGID_IM_FLOOR = 0.01     # rigid_errors: Im K_dd errors relative to max(|Im K_dd|, this · |K_dd|)
CODE_FILES = ("vectfit.py", "passivity.py", "fit.py", "rational.py")    # their digest is in the cache key


@dataclass(frozen=True)
class FitOptions:
    """Everything that changes a fit besides the table: the cache key (with the table hash and the
    code digest, ``cache_key``) and the report's ``settings``. Work bounds only, no wall-clock limit:
    a fit is a function of its inputs.

    tol : requested max relative Frobenius error over the band (scaled DOFs); for a gap table with
        the rigid-raft correction, also the max relative Re and Im error of the rigid-raft impedance
        (``rigid_error``, see the module docstring "Order selection of a gap table")
    max_order : maximum number of poles tried (pairs are added one at a time); never more than
        F − 2 for a table of F frequencies (``max_pairs``)
    weighting : "relative" | "uniform" | "entry"
    enforce : enforce passivity (else only check it; the report says whether the model is passive)
    f_causal_hz : "auto" or a frequency (Hz) below which hysteretic damping is replaced (causality)
    n_iter : vector-fitting iterations per order
    margin : target passivity margin of the enforcement (``passivity``)
    passivity_method : "auto" | "hamiltonian" | "sweep"
    patience : stop adding pole pairs when the last ``patience`` orders did not improve the best
        error by 20 % (the causality floor of a hysteretic table); None: try up to max_order
    max_enforce : at most 1 + max_enforce orders go through passivity enforcement (the first
        candidate, larger orders that may meet tol, smaller ones when none could be made passive)
    enforce_iter : iteration cap of each enforcement (each iteration costs one test: the grid
        pre-screen, and the exact test when the grid sees no violation)
    rigid_correction : "auto" | True | False. For a "gap" table, correct the fitted model so that its
        rigid-raft impedance in full contact Pᵀ K P follows the table's, Re and Im separately
        (``rigid_correct``; the Frobenius criterion barely sees it, and the rocking damping Im K
        came out ~30 % low on the reactor). Applied before passivity enforcement; the report's
        ``rigid_errors`` are measured after it. The order selection then requires them to meet tol.
        "auto": when the node coordinates are known (``node_xy`` or the table's provenance), True:
        FitError if they are not, False: off (neither the correction nor the rigid criterion).
    node_xy : ((x, y), ...) interface node coordinates (m) of a gap table, or None: rebuilt from the
        table's provenance (``FitOptions.make`` converts an (N, 2) array)
    """

    tol: float = 0.01
    max_order: int = 30
    weighting: str = "relative"
    enforce: bool = True
    f_causal_hz: float | str = "auto"
    n_iter: int = 12
    margin: float = 1e-3
    passivity_method: str = "auto"
    patience: int | None = 4
    max_enforce: int = 3
    enforce_iter: int = 20
    rigid_correction: bool | str = "auto"
    node_xy: tuple | None = None

    def __post_init__(self):
        if self.weighting not in WEIGHTINGS:
            raise FitError(f"weighting {self.weighting!r} unknown: use one of {WEIGHTINGS}")
        if self.rigid_correction not in ("auto", True, False):
            raise FitError(f"rigid_correction = {self.rigid_correction!r}: use 'auto', True or False")
        if self.passivity_method not in ("auto", "hamiltonian", "sweep"):
            raise FitError(f"passivity_method = {self.passivity_method!r}: use 'auto', 'hamiltonian' or 'sweep'")
        if not (np.isfinite(self.tol) and self.tol > 0):
            raise FitError(f"tol = {self.tol!r} must be a positive number (relative error, e.g. 0.01)")
        for name in ("max_order", "n_iter", "max_enforce", "enforce_iter"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < (1 if name != "max_enforce" else 0):
                raise FitError(f"{name} = {v!r} must be a positive integer")
        if self.patience is not None and (not isinstance(self.patience, (int, np.integer)) or self.patience < 1):
            raise FitError(f"patience = {self.patience!r} must be a positive integer or None")
        if self.f_causal_hz != "auto" and not (isinstance(self.f_causal_hz, (int, float)) and self.f_causal_hz >= 0):
            raise FitError(f"f_causal_hz = {self.f_causal_hz!r}: use 'auto' or a frequency >= 0 (Hz)")

    @classmethod
    def make(cls, node_xy=None, **options) -> FitOptions:
        """FitOptions from keyword options, ``node_xy`` given as an (N, 2) array (or None)."""
        xy = None
        if node_xy is not None:
            a = np.asarray(node_xy, float)
            if a.ndim != 2 or a.shape[1] != 2 or not np.all(np.isfinite(a)):
                raise FitError(f"node_xy must be finite (N, 2) node coordinates, got shape {a.shape}")
            xy = tuple(map(tuple, a.tolist()))
        return cls(node_xy=xy, **options)

    def settings(self) -> dict:
        """The options as a JSON-able dict (node_xy as a digest): the report's ``settings``."""
        d = asdict(self)
        xy = d.pop("node_xy")
        d["node_xy_sha"] = None if xy is None else hashlib.sha256(
            np.ascontiguousarray(xy, "<f8").tobytes()).hexdigest()[:16]
        return d

    def cache_key(self, table) -> str:
        """SHA-256 of the table hash, every option (``settings``) and the fit code's digest."""
        h = hashlib.sha256(table.hash.encode())
        h.update(json.dumps(self.settings(), sort_keys=True, default=str).encode())
        h.update(code_digest().encode())
        return h.hexdigest()


@dataclass(frozen=True)
class FitReport:
    """What ``fit_table`` measured (all errors relative Frobenius on DOF-scaled matrices).

    order : int                       number of poles (a conjugate pair counts two)
    max_rel_error : float             max over f ≥ f_causal of e(f), after enforcement
    rel_error : ndarray (F,)          e(f) against the table, per table frequency
    freq_hz : ndarray (F,)            the table frequencies
    max_rel_error_fit : float         the same before passivity enforcement
    max_rel_error_unscaled : float    relative Frobenius error in SI units
    low_freq_error : float            max e(f) for f < f_causal (hysteretic → causal), 0 if none
    f_causal_hz : float
    block_errors : dict               per DOF block ("rigid", "rigid-w", "w"): max over the band of
                                      ‖Δ_block‖_F/‖K_block‖_F ("own") and /‖K‖_F ("total")
    passive, passivity_margin : bool, float      see ``passivity.PassivityReport``
    passivity : dict                  the full PassivityReport.to_dict()
    order_history : list              [(order, max_rel_error)] tried during order selection; gap tables
                                      with the rigid criterion: [(order, max_rel_error, rigid_error)]
    settings : dict                   ``FitOptions.settings()`` (node_xy as node_xy_sha) + rigid_corrected
    wall_s : float                    fit + enforcement wall time, s (the load time on a cache hit): a
                                      measurement only, nothing else in the result depends on it
    cached : bool
    tol_reached : bool                max_rel_error <= tol (and, for gap tables, every rigid_errors
                                      re and im <= tol: the order-selection criterion)
    message : str                     why tol was missed and which tol is reachable ("" if reached)
    error_floor : float               a-priori hysteretic floor estimate ≈ 1.1 ξ (0: not hysteretic)
    stop_reason : str                 why the order search stopped
    enforcement_attempts : list       [(order, passive, criterion after, iterations)] per enforcement
                                      (a failed one: criterion nan)
    rigid_errors : dict               gap tables: errors of the rigid-raft impedance Pᵀ K P per rigid DOF
                                      (``rigid_errors``), max over f ≥ f_causal, after enforcement
                                      ({} for other tables or without node coordinates)
    """

    order: int
    max_rel_error: float
    rel_error: np.ndarray
    freq_hz: np.ndarray
    max_rel_error_fit: float
    max_rel_error_unscaled: float
    low_freq_error: float
    f_causal_hz: float
    block_errors: dict
    passive: bool
    passivity_margin: float
    passivity: dict
    order_history: list
    settings: dict
    wall_s: float
    cached: bool = False
    tol_reached: bool = True
    message: str = ""
    error_floor: float = 0.0
    stop_reason: str = ""
    enforcement_attempts: list = field(default_factory=list)
    rigid_errors: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        d = {k: getattr(self, k) for k in self.__dataclass_fields__}
        d["rel_error"] = [float(x) for x in self.rel_error]
        d["freq_hz"] = [float(x) for x in self.freq_hz]
        return json.loads(json.dumps(d, default=float))

    def summary(self) -> dict:
        """The ``uplift fit --json`` object."""
        return {"order": int(self.order), "max_rel_error": float(self.max_rel_error),
                "passive": bool(self.passive), "passivity_margin": float(self.passivity_margin),
                "wall_s": float(self.wall_s)}

    @classmethod
    def from_dict(cls, d) -> FitReport:
        d = dict(d)
        d["rel_error"] = np.asarray(d["rel_error"], float)
        d["freq_hz"] = np.asarray(d["freq_hz"], float)
        d["order_history"] = [tuple(x) for x in d["order_history"]]
        return cls(**d)


@dataclass(frozen=True, eq=False)
class FitResult:
    model: RationalModel
    report: FitReport

    def plot(self, table, path):
        from .fit_plot import plot_fit
        return plot_fit(self, table, path)


# ------------------------------------------------------------------------------------------
def table_scaling(table):
    """(active DOF indices, S) for the table: nonzero rows, S_i = |Re K_ii(f_0)|^{-1/2}."""
    K = table.matrices
    rowmax = np.max(np.abs(K), axis=(0, 2))
    idx = np.nonzero(rowmax > 0)[0]
    d = np.abs(K[0].real.diagonal())[idx]
    fallback = np.max(np.abs(np.einsum("fii->fi", K)), axis=0)[idx]
    d = np.where(d > 1e-9 * fallback, d, fallback)
    return idx, 1.0 / np.sqrt(d)


def causal_cutoff(table, Ks, f_causal_hz="auto", fraction=0.05) -> float:
    """f_causal (Hz) for the causal target; see the module docstring."""
    f = table.frequencies_hz
    if f_causal_hz != "auto":
        return float(f_causal_hz)
    if causal_materials(table):
        return 0.0
    im0 = np.linalg.norm(hysteretic_part(f, Ks))
    if im0 <= 1e-3 * np.linalg.norm(Ks[0]):
        return 0.0
    return float(f[np.nonzero(f >= fraction * f[-1])[0][0]])


def causal_materials(table) -> bool:
    """True when the table's provenance lists its soil materials, all with the causal model."""
    profile = table.provenance.get("profile")
    if not isinstance(profile, dict) or "halfspace" not in profile:
        return False
    mats = list(profile.get("layers") or []) + [profile["halfspace"]]
    return all(isinstance(m, dict) and m.get("damping_model") == "causal" for m in mats)


def hysteretic_part(f, Ks) -> np.ndarray:
    """Im K extrapolated to f = 0 (linear through the two lowest positive frequencies)."""
    if f[0] == 0:
        return Ks[0].imag.copy()
    pos = np.nonzero(f > 0)[0]
    if pos.size < 2:
        return np.zeros(Ks.shape[1:])
    i1, i2 = pos[:2]
    return Ks[i1].imag - f[i1] * (Ks[i2].imag - Ks[i1].imag) / (f[i2] - f[i1])


def causal_target(f, Ks, f_c):
    """Ks with the hysteretic offset H0 = Im K(0⁺) faded out below f_c:
    Im K_target(f) = Im K(f) − H0·(1 − f/f_c)² for f < f_c (C¹ at f_c, linear in f at 0)."""
    if f_c <= 0:
        return Ks
    H0 = hysteretic_part(f, Ks)
    out = Ks.copy()
    low = f < f_c
    out[low] = out[low] - 1j * ((1 - f[low] / f_c) ** 2)[:, None, None] * H0[None]
    return out


def _blocks(dofs):
    rigid = np.array([d in RIGID for d in dofs])
    if rigid.all() or not rigid.any():
        return {"all": (np.arange(len(dofs)), np.arange(len(dofs)))}
    r, w = np.nonzero(rigid)[0], np.nonzero(~rigid)[0]
    return {"rigid": (r, r), "rigid-w": (r, w), "w": (w, w)}


def _errors(Km, Kt):
    """Per-frequency relative Frobenius error, shape (F,)."""
    num = np.linalg.norm((Km - Kt).reshape(Kt.shape[0], -1), axis=1)
    den = np.linalg.norm(Kt.reshape(Kt.shape[0], -1), axis=1)
    return num / np.where(den > 0, den, 1.0)


def code_digest() -> str:
    """SHA-256 (12 hex digits) of the fit's source files (``CODE_FILES``): part of the cache key."""
    h = hashlib.sha256()
    here = Path(__file__).parent
    for name in CODE_FILES:
        h.update((here / name).read_bytes())
    return h.hexdigest()[:12]



# ------------------------------------------------------------------------------------------
# rigid-raft projection of a gap table and its correction
# ------------------------------------------------------------------------------------------
def rigid_projection(table, node_xy=None):
    """P, shape (6+N, 6), of a "gap" table (DOFs RIGID + w_1..w_N), or None for other tables.

    With the raft bonded to the soil, w_i = uz + rx y_i − ry x_i (``reduction.rigid_transform``),
    so the rigid-raft impedance in full contact is Pᵀ K_gap P with P = [I6; T_v]
    (``reduction.condense_gap_rigid``). node_xy : (N, 2) node coordinates about the raft centre;
    default: the table's mesh rebuilt from its provenance (circle and square-cell rectangle meshes,
    checked against the recorded mesh digest). FitError when they are needed and unknown.
    """
    dofs = list(table.dofs)
    n = len(dofs) - len(RIGID)
    if n <= 0 or tuple(dofs[:6]) != RIGID or dofs[6:] != [f"w{i}" for i in range(n)]:
        return None
    if node_xy is None:
        node_xy = _provenance_nodes(table.provenance)
        if node_xy is None:
            raise FitError("the rigid-raft correction needs the interface node coordinates, which the "
                           "table's provenance does not rebuild: pass node_xy=mesh.xy (shape (N, 2)) or "
                           "rigid_correction=False")
    xy = np.asarray(node_xy, float)
    if xy.shape != (n, 2) or not np.all(np.isfinite(xy)):
        raise FitError(f"node_xy must be finite (N, 2) = ({n}, 2) node coordinates for this gap table, "
                       f"got shape {xy.shape}")
    Tv = np.zeros((n, 6))
    Tv[:, 2], Tv[:, 3], Tv[:, 4] = 1.0, xy[:, 1], -xy[:, 0]      # as reduction.rigid_transform
    return np.vstack([np.eye(6), Tv])


def _provenance_nodes(prov):
    """Node coordinates of the mesh recorded in a sweep's provenance, or None."""
    from .mesh import MeshError, circle_mesh, rectangle_mesh
    from .sweep import _mesh_dict
    m = prov.get("mesh") or {}
    try:
        if m.get("kind") == "circle":
            mesh = circle_mesh(m["size"][0], m["cell"])
        elif m.get("kind") == "rectangle" and m.get("cell"):
            mesh = rectangle_mesh(*m["size"], m["cell"])
        else:
            return None
    except (KeyError, TypeError, IndexError, MeshError):
        return None
    return mesh.xy if _mesh_dict(mesh) == m else None


def rigid_model(model, P) -> RationalModel:
    """The rigid-raft impedance Pᵀ K(s) P of ``model`` as a 6×6 RationalModel (same poles): cheap to
    evaluate, unlike the (6+N)² model."""
    return RationalModel(model.poles, P.T @ model.residues @ P, P.T @ model.D @ P, P.T @ model.E @ P,
                         list(RIGID))


def rigid_errors(model, target, freq_hz, P, band):
    """Per rigid DOF d, max over ``band`` (bool mask of freq_hz) of the relative errors of the
    rigid-raft impedance Pᵀ K P, model against target (F, n, n): {d: {"re", "im", "abs"}} with
    re = |ΔRe K_dd|/|Re K_dd|, im = |ΔIm K_dd|/max(|Im K_dd|, RIGID_IM_FLOOR·|K_dd|),
    abs = |ΔK_dd|/|K_dd|.
    The floor (1 % of |K_dd|) keeps the Im measure finite where the target is undamped (Im K(0) = 0)
    and does not ask for the relative accuracy of a negligible damping: a loss factor Im K/|K| below
    1 % (soil damping ratio < 0.5 %, e.g. the rocking radiation damping of an undamped soil at low
    frequency, 0.1 % at a0 = 0.25) weighs nothing beside the structure's 5-7 %; a causal 3 % rock
    has Im K/|K| ≥ 6 % at every f > 0, where the floor never acts."""
    Kt = P.T @ target[band] @ P
    Km = rigid_model(model, P).frequency_response(np.asarray(freq_hz)[band])
    dt, dm = np.einsum("faa->fa", Kt), np.einsum("faa->fa", Km)
    out = {}
    for k, name in enumerate(RIGID):
        t, m = dt[:, k], dm[:, k]
        im_ref = np.maximum(np.abs(t.imag), RIGID_IM_FLOOR * np.abs(t))
        out[name] = {"re": float(np.max(np.abs(m.real - t.real) / np.abs(t.real))),
                     "im": float(np.max(np.abs(m.imag - t.imag) / im_ref)),
                     "abs": float(np.max(np.abs(m - t) / np.abs(t)))}
    return out


def rigid_protection(prob, P) -> np.ndarray:
    """``enforce_passivity``'s ``protect`` for a gap table: P with column d scaled by √(κ/ref_d),
    κ = max_f ‖S K_target S‖_F (the scale of the relative Frobenius measure the enforcement minimises)
    and ref_d = RIGID_IM_FLOOR · min over the band of |(Pᵀ K P)_dd| (the smallest error scale of
    ``rigid_errors``), so that a change of the rigid-raft impedance costs about as much as its
    relative error in the order-selection criterion."""
    KP = prob.table.matrices[prob.band] @ P
    ref = RIGID_IM_FLOOR * np.abs(np.einsum("ia,fia->fa", P, KP)).min(axis=0)
    kappa = 1.0 / prob.w_rel.min()
    return P * np.sqrt(np.divide(kappa, ref, out=np.ones_like(ref), where=ref > 0))[None, :]


def rigid_error(errors) -> float:
    """The order-selection measure of ``rigid_errors``' output: max over rigid DOFs of the Re and Im errors."""
    return max((max(e["re"], e["im"]) for e in errors.values()), default=0.0)


def rigid_correct(model, target, freq_hz, P, floor=0.02, f_c=0.0) -> RationalModel:
    """``model`` + Q Δ(s) Qᵀ: the rigid-raft impedance Pᵀ K P corrected to follow the target's.

    Δ(s) = D_Δ + Σ_k R_Δk/(s − p_k) (the model's poles, no s term so E is untouched, symmetric
    residues, conjugate pairs) fits the 6×6 residual Pᵀ (K_target − K_model) P by weighted linear
    least squares, one per upper-triangle entry (i, j), with Re and Im weighted separately relative
    to the target: 1/max(|Re K_ij|, ε) and 1/max(|Im K_ij|, ε), ε = ``floor``·√(|K_ii K_jj|), so
    that the small imaginary parts (rocking damping at low a0) count as much as the stiffnesses.
    Q = P_a (P_aᵀ P_a)⁻¹ on the model's active DOFs (zero rows stay zero): Pᵀ Q = I, hence
    Pᵀ (Q Δ Qᵀ) P = Δ exactly; the rank-6 change of the w block is smooth (linear in x, y).
    target : (F, n, n) complex, the (causal) target at ``freq_hz``. f_c : below it (where the
    target's Im K is the faded hysteretic one) Im K is weighted like Re K, relative to |K_ij|.
    Weights with a zero denominator (an entry identically zero) are dropped.
    """
    f = np.asarray(freq_hz, float)
    w_ref = 2 * np.pi * float(model.provenance.get("f_max_hz") or f[-1])
    Kt = P.T @ target @ P
    Delta = Kt - rigid_model(model, P).frequency_response(f)
    A = real_basis(2j * np.pi * f / w_ref, model.poles / w_ref, const=True, linear=False)
    diag = np.abs(np.einsum("faa->fa", Kt))
    m = model.order
    Cd = np.zeros((m + 1, 6, 6))
    for i, j in zip(*np.triu_indices(6)):
        eps = floor * np.sqrt(diag[:, i] * diag[:, j])
        if not np.any(eps > 0):
            continue
        dr = np.maximum(np.abs(Kt[:, i, j].real), eps)
        di = np.maximum(np.abs(Kt[:, i, j].imag), np.where(f >= f_c, eps, np.maximum(np.abs(Kt[:, i, j]), eps)))
        wr = np.divide(1.0, dr, out=np.zeros_like(dr), where=dr > 0)
        wi = np.divide(1.0, di, out=np.zeros_like(di), where=di > 0)
        M = np.concatenate([wr[:, None] * A.real, wi[:, None] * A.imag])
        rhs = np.concatenate([wr * Delta[:, i, j].real, wi * Delta[:, i, j].imag])
        col = np.linalg.norm(M, axis=0)
        col[col == 0] = 1.0
        Cd[:, i, j] = Cd[:, j, i] = np.linalg.lstsq(M / col, rhs, rcond=None)[0] / col
    Cd[:m] *= w_ref                                   # basis 1/(ν − p/ω_ref) = ω_ref/(s − p)
    C = np.array(model.coefficients)
    active = np.max(np.abs(C), axis=(0, 2)) > 0
    Pa = P * active[:, None]
    Q = Pa @ np.linalg.inv(Pa.T @ Pa)
    C[:m + 1] += Q[None] @ Cd @ Q.T[None]
    C = 0.5 * (C + C.transpose(0, 2, 1))
    return RationalModel.from_coefficients(model.poles, C, model.dofs, dict(model.provenance, rigid_corrected=True))


# ------------------------------------------------------------------------------------------
class _Problem:
    """The table in fit form: upper-triangle entries of S K S, weights, normalised s."""

    def __init__(self, table, weighting, f_causal_hz):
        if weighting not in WEIGHTINGS:
            raise FitError(f"weighting {weighting!r} unknown: use one of {WEIGHTINGS}")
        f = table.frequencies_hz
        if f.size < 4:
            raise FitError(f"table has {f.size} frequencies: a rational fit needs at least 4 (recompute the sweep)")
        self.table, self.f = table, f
        self.idx, self.S = table_scaling(table)
        if self.idx.size == 0:
            raise FitError("table is identically zero: nothing to fit")
        K = table.matrices[:, self.idx][:, :, self.idx]
        self.Ks = K * self.S[None, :, None] * self.S[None, None, :]
        self.f_c = causal_cutoff(table, self.Ks, f_causal_hz)
        self.target = causal_target(f, self.Ks, self.f_c)
        self.w_ref = 2 * np.pi * f[-1]
        self.s = 1j * 2 * np.pi * f / self.w_ref
        na = self.idx.size
        self.iu = np.triu_indices(na)
        self.ew = np.where(self.iu[0] == self.iu[1], 1.0, np.sqrt(2.0))
        self.X = self.target[:, self.iu[0], self.iu[1]] * self.ew      # (F, M)
        self.w_rel = 1.0 / np.maximum(np.linalg.norm(self.target.reshape(f.size, -1), axis=1), 1e-300)
        self.weighting = weighting
        self.w = self.w_rel if weighting != "uniform" else np.full(f.size, 1.0 / np.abs(self.X).max())
        self.band = f >= self.f_c
        self.Y = compress(self.X, self.w_rel)

    def coefficients(self, poles):
        """(nb, M) coefficients with E projected on the PSD cone."""
        C = self._solve(poles, self.X, linear=True)
        E = self._matrix(C[-1])
        lam, vec = np.linalg.eigh(E)
        if lam[0] < 0:
            Ep = (vec * np.maximum(lam, 0)) @ vec.T
            ep = Ep[self.iu] * self.ew
            C = np.vstack([self._solve(poles, self.X - self.s[:, None] * ep[None], linear=False), ep[None]])
        return C

    def _solve(self, poles, X, linear):
        if self.weighting != "entry":
            return fit_coefficients(self.s, X, self.w, poles, const=True, linear=linear)
        mag = np.abs(X)
        we = 1.0 / np.maximum(mag, 1e-3 * mag.max(axis=0, keepdims=True) + 1e-300)
        A = real_basis(self.s, poles, const=True, linear=linear)
        out = np.empty((A.shape[1], X.shape[1]))
        for j in range(X.shape[1]):
            Aw = A * we[:, j:j + 1]
            out[:, j] = np.linalg.lstsq(np.concatenate([Aw.real, Aw.imag]),
                                        np.concatenate([(we[:, j] * X[:, j]).real, (we[:, j] * X[:, j]).imag]),
                                        rcond=None)[0]
        return out

    def _matrix(self, v):
        na = self.idx.size
        M = np.zeros((na, na))
        M[self.iu] = v / self.ew
        return M + np.triu(M, 1).T

    def model(self, poles, C, provenance) -> RationalModel:
        """Unscaled, full-size RationalModel."""
        m = poles.size
        n = self.table.n_dof
        mats = np.stack([self._matrix(c) for c in C])
        mats[:m] *= self.w_ref
        mats[m + 1] /= self.w_ref
        mats = mats / self.S[None, :, None] / self.S[None, None, :]
        mats = 0.5 * (mats + mats.transpose(0, 2, 1))
        full = np.zeros((m + 2, n, n))
        full[np.ix_(range(m + 2), self.idx, self.idx)] = mats
        return RationalModel.from_coefficients(poles * self.w_ref, full, self.table.dofs, provenance)

    @cached_property
    def unscaled_target(self):
        """The causal target in SI units, full size (F, n, n) (zero rows stay zero)."""
        out = np.zeros(self.table.matrices.shape, complex)
        T = self.target / self.S[None, :, None] / self.S[None, None, :]
        out[np.ix_(range(self.f.size), self.idx, self.idx)] = T
        return out

    def scaled_response(self, model):
        K = model.frequency_response(self.f)[:, self.idx][:, :, self.idx]
        return K * self.S[None, :, None] * self.S[None, None, :]


def _fit_order(prob, n_pairs, n_iter):
    poles = vector_fit(prob.s, prob.Y, prob.w_rel, initial_poles(n_pairs, 1.0), n_iter=n_iter)
    keep = np.abs(poles) <= POLE_CAP
    poles = canonical_poles(poles[keep])
    C = prob.coefficients(poles)
    res = real_basis(prob.s, poles) @ C - prob.X       # rows: Frobenius norms (√2 weights)
    err = np.linalg.norm(res, axis=1) / np.maximum(np.linalg.norm(prob.X, axis=1), 1e-300)
    return poles, C, float(err[prob.band].max())


def hysteretic_floor(prob) -> float:
    """A-priori estimate of the band error floor of a causal fit: ≈ 1.1 ξ with the loss factor
    2ξ = ‖H0‖_F/‖Re K(f_0)‖_F (scaled), H0 = Im K(0⁺); 0 when the table is not hysteretic."""
    if prob.f_c <= 0:
        return 0.0
    H0 = hysteretic_part(prob.f, prob.Ks)
    return float(1.1 * 0.5 * np.linalg.norm(H0) / max(np.linalg.norm(prob.Ks[0].real), 1e-300))


def _round_up(x, digits=2) -> float:
    if x <= 0:
        return 0.0
    e = np.floor(np.log10(x)) - (digits - 1)
    return float(np.ceil(x / 10 ** e - 1e-9) * 10 ** e)


def _candidates(errs, tol, floor):
    """(first, up, down) indices into the fitted orders (selection criterion ``errs``, by increasing
    order) for passivity enforcement.

    first: the smallest order meeting tol; if none does, the smallest order at the plateau (error
    within 5 % of the best, or within 1.2 × the hysteretic floor estimate). up: larger orders worth
    trying afterwards (meeting tol, resp. lowering the error: the record orders), by increasing order.
    down: smaller orders, fallback when enforcement fails or misses tol (fewer poles are easier): halving the
    number of pole pairs first (the enforcement budget max_enforce reaches far down), then the others by
    decreasing order."""
    errs = np.asarray(errs, float)
    best = errs.min()
    ok = np.nonzero(errs <= tol)[0]
    if ok.size:
        first = int(ok[0])
        up = [int(i) for i in ok[1:]]
    else:
        good = max(1.05 * best, 1.2 * floor)
        first = int(np.nonzero(errs <= good)[0][0])
        up, rec = [], errs[first]
        for i in range(first + 1, errs.size):
            if errs[i] < 0.97 * rec:
                up.append(i)
                rec = errs[i]
    halving = [first >> k for k in range(1, first.bit_length() + 1)]     # first/2, first/4, ..., 0
    down = list(dict.fromkeys(halving + list(range(first - 1, -1, -1))))
    return first, up, down



# ------------------------------------------------------------------------------------------
# the fit in parts: order search, passivity candidates, message, report
# ------------------------------------------------------------------------------------------
def max_pairs(options: FitOptions, n_freq: int) -> int:
    """Pole pairs the order search may try: max_order/2, and at most (F − 2)/2 for F table
    frequencies, so that each entry's least squares keeps at least twice as many real equations
    (2F) as unknowns (m poles + D + E): with fewer the fit interpolates the table, with spurious
    resonances between its frequencies that passivity enforcement cannot remove (small raft,
    21 frequencies, 3 % hysteretic soil: 30 poles met 0.8 % where the causal floor is 3.3 %, and
    no enforcement converged)."""
    return max(1, min(options.max_order, n_freq - 2) // 2)


class _Search:
    """The fitted orders of one fit, by increasing order (one more pole pair each), and their
    selection criterion before enforcement: the band error, and for gap tables with the rigid-raft
    correction max(band error, rigid-raft Re/Im error)."""

    def __init__(self, prob, options: FitOptions, P, prov, progress):
        self.prob, self.options, self.P, self.prov = prob, options, P, prov
        self.max_pairs = max_pairs(options, prob.f.size)
        self.protect = None if P is None else rigid_protection(prob, P)
        self.fits = []            # (poles, C, max_rel_error, criterion)
        self.history = []         # report.order_history
        self.progress = progress

    def build(self, i, corrected=True) -> RationalModel:
        """The model of fitted order i (rigid-corrected unless ``corrected`` is False)."""
        poles, C = self.fits[i][:2]
        model = self.prob.model(poles, C, self.prov)
        if self.P is None or not corrected:
            return model
        return rigid_correct(model, self.prob.unscaled_target, self.prob.f, self.P, f_c=self.prob.f_c)

    def rigid_error(self, model) -> float:
        if self.P is None:
            return 0.0
        return rigid_error(rigid_errors(model, self.prob.table.matrices, self.prob.f, self.P, self.prob.band))

    def criterion(self, model) -> float:
        """The selection criterion of a model (e.g. after enforcement)."""
        band_error = float(np.max(_errors(self.prob.scaled_response(model), self.prob.Ks)[self.prob.band]))
        return max(band_error, self.rigid_error(model))

    def fit_next(self) -> float:
        """Fit the next order; its criterion (before enforcement)."""
        poles, C, err = _fit_order(self.prob, len(self.fits) + 1, self.options.n_iter)
        self.fits.append((poles, C, err, err))
        if self.P is None:
            self.history.append((int(poles.size), err))
        else:
            rig = self.rigid_error(self.build(len(self.fits) - 1))
            self.fits[-1] = (poles, C, err, max(err, rig))
            self.history.append((int(poles.size), err, rig))
        if self.progress is not None:
            self.progress("order search", len(self.fits), self.max_pairs)
        return self.fits[-1][3]

    def run(self) -> str:
        """Fit orders until tol is met, the criterion stalls (``patience``) or max_pairs; the reason."""
        tol, patience = self.options.tol, self.options.patience
        while len(self.fits) < self.max_pairs:
            if self.fit_next() <= tol:
                return "tol reached"
            errs = [fit[3] for fit in self.fits]
            if patience and len(errs) > patience and min(errs[-patience:]) > 0.8 * min(errs[:-patience]):
                return f"error stalled at {min(errs):.3g} over the last {patience} orders"
        return "max_order"

    def further(self):
        """Orders above the last one fitted that meet tol, fitted on demand (enforcement may push the
        criterion above tol: on gap tables, the rigid-raft Im K at low frequency)."""
        while len(self.fits) < self.max_pairs:
            if self.fit_next() <= self.options.tol:
                yield len(self.fits) - 1


def _enforce_candidates(search: _Search, stop: str, floor: float, progress):
    """Passivity enforcement of the candidate orders (``_candidates``), bounded by work: at most
    1 + max_enforce orders, each with at most enforce_iter iterations per variant (the rigid-corrected
    model, then the plain fit). Returns (best, attempts, failures, notes) with best = (criterion,
    model, PassivityReport, max_rel_error before enforcement) or None when no order was made passive."""
    opt, prob = search.options, search.prob
    first, up, down = _candidates([fit[3] for fit in search.fits], opt.tol, floor)
    if stop == "tol reached":
        up = search.further()
    attempts, failures, notes = [], [], []
    budget = [1 + opt.max_enforce]

    def attempt(i):
        budget[0] -= 1
        poles, err_fit = search.fits[i][0], search.fits[i][2]
        stage = f"passivity {poles.size} poles"
        for corrected in ((True, False) if search.P is not None else (False,)):
            what = "rigid-corrected " if corrected else ""
            tick = None if progress is None else (lambda done, total, s=stage + (" (plain fit)" if not corrected and
                                                  search.P is not None else ""): progress(s, done, total))
            try:
                model, rep, it = enforce_passivity(search.build(i, corrected), prob.f, prob.w_rel, margin=opt.margin,
                                                   method=opt.passivity_method, max_iter=opt.enforce_iter,
                                                   progress=tick, protect=search.protect)
                break
            except FitError as exc:
                failures.append(f"{poles.size} poles {what}: {exc}")
                attempts.append((int(poles.size), False, float("nan"), exc.iterations))
        else:
            return None
        e = search.criterion(model)
        attempts.append((int(poles.size), True, e, int(it)))
        return (e, model, rep, err_fit)

    best = attempt(first)
    at_floor = best is not None and floor > 0 and opt.tol < floor and best[0] <= 1.2 * floor
    if at_floor and up:
        notes.append("at the hysteretic floor: larger orders not tried")
    if best is not None and best[0] > opt.tol and not at_floor:
        for i in up:                       # more poles: lower error or tol met, while the budget allows
            if budget[0] <= 0:
                notes.append(f"at most {opt.max_enforce} further orders are tried (max_enforce)")
                break
            got = attempt(i)
            if got is None:
                notes.append(f"passivity enforcement failed at {search.fits[i][0].size} poles")
                break
            if got[0] < best[0]:
                best = got
            if best[0] <= opt.tol:
                break
    if best is None or (best[0] > opt.tol and not at_floor):
        for i in down:                     # fewer poles: easier to make passive, and may need a smaller change
            if best is not None and search.fits[i][3] >= best[0]:
                continue                       # already worse before enforcement
            if budget[0] <= 0:
                notes.append(f"at most {1 + opt.max_enforce} orders are enforced (max_enforce)")
                break
            got = attempt(i)
            if got is not None and (best is None or got[0] < best[0]):
                best = got
            if best is not None and best[0] <= opt.tol:
                break
    return best, attempts, failures, notes


def _message(search: _Search, best, stop, notes, floor) -> str:
    """Why tol was missed and which tol is reachable ("" when reached)."""
    err, model, prep = best[:3]
    tol = search.options.tol
    if err <= tol:
        return ""
    what = "max rel error" if search.P is None else "max(rel error, rigid-raft Re/Im error)"
    parts = [f"tol {tol:g} not reached: returning the best {'passive ' if prep.passive else ''}model found, "
             f"{model.order} poles, {what} {err:.3g} (order search: {stop}"
             + (f"; {'; '.join(notes)}" if notes else "") + ")."]
    if floor > 0:
        parts.append(f"The table has hysteretic damping (loss factor 2ξ ≈ {floor / 0.55:.2g}), which no causal "
                     f"model follows (Kramers–Kronig): the band error has a floor ≈ ξ ≈ {floor:.2g} "
                     "(soil_impedance.fit, causality note).")
    parts.append(f"Raise tol to ~{_round_up(1.05 * err):g}.")
    return " ".join(parts)


def fit_table(table, tol=None, *, cache_dir=None, node_xy=None, progress=None, options: FitOptions | None = None,
              **kwargs) -> FitResult:
    """Passive common-pole rational model of ``table`` (see the module docstring).

    table : ImpedanceTable
    tol (default 0.01), node_xy and the keyword options : ``FitOptions`` (max_order, weighting, enforce, f_causal_hz,
        n_iter, margin, passivity_method, patience, max_enforce, enforce_iter, rigid_correction), or
        ``options`` given whole (then tol, node_xy and kwargs must not be)
    cache_dir : directory for fitted models, keyed by ``FitOptions.cache_key`` (table hash, options,
        node_xy, code digest); entries are written atomically with a content checksum, a damaged
        one is recomputed with a ``soil_impedance.cache.CacheWarning``
    progress : optional callable(stage: str, done: int, total: int), called after each fitted order
        (stage "order search", total = the pole pairs it may try) and after each passivity test
        of an enforcement iteration (stage "passivity <m> poles", or "... (plain fit)" when the
        rigid-corrected model failed; total = enforce_iter + 1; it stops early when passive)

    Order search and enforcement: the orders are fitted cheaply (compressed columns) until tol is
    met (the criterion: max_rel_error, and for gap tables rigid_error too), the criterion stalls
    (``patience``) or max_order; then passivity is enforced on the smallest order meeting tol; if
    enforcement pushed the criterion above tol, the next orders meeting it are fitted and enforced.
    If no order meets tol the smallest order at the error plateau is enforced first, then (unless tol
    is below the hysteretic floor estimate and that model is already within 1.2 × the floor) larger
    orders that lower the error are tried (the best passive one is kept; stop at the first failure);
    if none could be made passive, or (away from the hysteretic floor) none meets tol after its
    enforcement, smaller orders are tried too (those whose fit is not already worse than the best
    enforced model), the best passive one kept (the soft-soil stress case's 8-pole fit came out
    passive but 185 % off, its 6-pole one 28 %). At most 1 + max_enforce orders are
    enforced in all, each with at most enforce_iter iterations: the work is bounded, and the result
    depends on the inputs only (no wall-clock budget). Never an exception for a missed tol: the
    report's ``tol_reached`` is False and ``message`` says why (e.g. the hysteretic error floor
    ``error_floor``) and what tol is reachable; a RuntimeWarning carries the same message.
    FitError only if no order can be made passive within the bounds (nothing is cached then).
    """
    if options is None:
        options = FitOptions.make(node_xy, **({} if tol is None else {"tol": tol}), **kwargs)
    elif kwargs or node_xy is not None or tol is not None:
        raise FitError("fit_table: give either options=FitOptions(...) or tol/node_xy/keyword options, not both")
    path = None
    if cache_dir is not None:
        path = Path(cache_dir) / f"fit-{options.cache_key(table)[:24]}.h5"
        from .cache import read_entry
        hit = read_entry(path, lambda h: _read_fit(h, path))
        if hit is not None:
            return hit
    result = fit(table, options, progress)
    if path is not None:
        save_fit(result, path)
    return result


def fit(table, options: FitOptions, progress=None) -> FitResult:
    """The fit itself (no cache): ``fit_table`` with its options given whole."""
    t0 = time.perf_counter()
    P = _projection(table, options)
    prob = _Problem(table, options.weighting, options.f_causal_hz)
    floor = hysteretic_floor(prob)
    settings = dict(options.settings(), rigid_corrected=P is not None)
    prov = {"source_table_hash": table.hash, "f_max_hz": float(table.frequencies_hz[-1]),
            "f_causal_hz": prob.f_c, "fit_settings": settings, "code": code_digest()}
    search = _Search(prob, options, P, prov, progress)
    stop = search.run()
    if options.enforce:
        best, attempts, failures, notes = _enforce_candidates(search, stop, floor, progress)
        if best is None:
            raise FitError(f"no fitted order could be made passive within the work bounds (max_enforce = "
                           f"{options.max_enforce}, enforce_iter = {options.enforce_iter}): " + "; ".join(failures))
    else:
        first = _candidates([fit[3] for fit in search.fits], options.tol, floor)[0]
        model = search.build(first)
        best, attempts, failures, notes = ((search.criterion(model), model,
                                            check_passive(model, method=options.passivity_method),
                                            search.fits[first][2]), [], [], [])
    err_after, model, prep, err_fit = best
    message = _message(search, best, stop, notes, floor)
    if message:
        warnings.warn(message, RuntimeWarning, stacklevel=3)
    report = _report(prob, model, prep, err_fit, search.history, settings, time.perf_counter() - t0)
    report = replace(report, tol_reached=bool(err_after <= options.tol), message=message, error_floor=float(floor),
                     stop_reason=stop, enforcement_attempts=[list(a) for a in attempts],
                     rigid_errors={} if P is None else rigid_errors(model, table.matrices, prob.f, P, prob.band))
    model = model.with_provenance(dict(model.provenance, **({"enforcement_fallback": failures} if failures else {}),
                                       max_rel_error=report.max_rel_error, passive=report.passive,
                                       passivity_margin=report.passivity_margin))
    # the steppers' passivity test (default settings), run once here and stored with the model
    return FitResult(with_verified_passivity(model), report)


def _projection(table, options: FitOptions):
    """P of the rigid-raft correction (``rigid_projection``), or None when it is off."""
    if not options.rigid_correction:
        return None
    try:
        P = rigid_projection(table, options.node_xy)
    except FitError:
        if options.rigid_correction is True:
            raise
        return None
    if P is None and options.rigid_correction is True:
        raise FitError(f"rigid_correction=True needs a gap table (DOFs {list(RIGID)} + w0..), got "
                       f"{table.dofs[:8]}: use rigid_correction='auto' or False")
    return P


def _report(prob, model, prep: PassivityReport, err_fit, history, settings, wall):
    Kfull = model.frequency_response(prob.f)
    Km = Kfull[:, prob.idx][:, :, prob.idx] * prob.S[None, :, None] * prob.S[None, None, :]
    e_t = _errors(Km, prob.Ks)
    low = ~prob.band
    e_un = _errors(Kfull, prob.table.matrices)
    blocks = {}
    dofs = [prob.table.dofs[i] for i in prob.idx]
    tot = np.linalg.norm(prob.Ks.reshape(prob.f.size, -1), axis=1)
    sel = prob.band
    for name, (r, c) in _blocks(dofs).items():
        d = np.linalg.norm((Km - prob.Ks)[:, r][:, :, c].reshape(prob.f.size, -1), axis=1)
        own = np.linalg.norm(prob.Ks[:, r][:, :, c].reshape(prob.f.size, -1), axis=1)
        blocks[name] = {"own": float(np.max(d[sel] / np.where(own[sel] > 0, own[sel], 1.0))),
                        "total": float(np.max(d[sel] / tot[sel]))}
    return FitReport(order=int(model.order), max_rel_error=float(np.max(e_t[prob.band])),
                     rel_error=e_t, freq_hz=prob.f.copy(),
                     max_rel_error_fit=float(err_fit), max_rel_error_unscaled=float(np.max(e_un[prob.band])),
                     low_freq_error=float(e_t[low].max()) if low.any() else 0.0, f_causal_hz=float(prob.f_c),
                     block_errors=blocks, passive=bool(prep.passive), passivity_margin=float(prep.margin),
                     passivity=prep.to_dict(), order_history=history, settings=settings, wall_s=float(wall))


# ------------------------------------------------------------------------------------------
# files
# ------------------------------------------------------------------------------------------
def save_fit(result: FitResult, path) -> None:
    """Model (``rational.write_model`` layout) + the report as JSON attribute ``fit_report`` + the
    content checksum (``storage.stamp_checksum``), written atomically (``storage.atomic_output``)."""
    import h5py

    from .storage import atomic_output, stamp_checksum
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_output(path) as tmp, h5py.File(tmp, "w") as h:
        write_model(h, result.model)
        h.attrs["fit_report"] = json.dumps(result.report.to_dict())
        stamp_checksum(h)


def load_fit(path) -> FitResult:
    """Read a FitResult written by ``save_fit`` (report.cached = True, wall_s = load time); FitError
    naming the file when it is not one, or when it changed since it was written (its checksum)."""
    import h5py

    from .storage import ChangedFileError, require_checksum
    try:
        h = h5py.File(path, "r")
    except OSError as exc:
        raise FitError(f"{path}: cannot open as an HDF5 fit ({exc})") from None
    with h:
        try:
            require_checksum(h, path, "refit the table")
        except ChangedFileError as exc:
            raise FitError(str(exc)) from None
        return _read_fit(h, path)


def _read_fit(h, path) -> FitResult:
    t0 = time.perf_counter()
    model = read_model(h, path)
    if "fit_report" not in h.attrs:
        raise FitError(f"{path}: a rational model without a fit report: refit the table")
    d = json.loads(h.attrs["fit_report"])
    d.update(cached=True, wall_s=time.perf_counter() - t0)
    return FitResult(model, FitReport.from_dict(d))

"""What changes a fit besides its table: ``FitOptions`` (the cache key with the table hash and
the code digest), and the constants of the fit."""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, fields
import numpy as np
from uplift_common.code import code_digest

from ..rational import FitError

WEIGHTINGS = ("relative", "uniform", "entry")
RIGID = ("ux", "uy", "uz", "rx", "ry", "rz")
POLE_CAP = 30.0           # normalised |p| above which a pole only mimics a constant: dropped
RIGID_IM_FLOOR = 0.01     # rigid_errors: Im K_dd errors relative to max(|Im K_dd|, this · |K_dd|)
#: the code a fit depends on (the fit package and the kernels it runs): its digest is in the cache key
CODE = ("soil_impedance.fit", "soil_impedance.vectfit", "soil_impedance.passivity", "soil_impedance.rational")


@dataclass(frozen=True)
class FitOptions:
    """Everything that changes a fit besides the table: the cache key (with the table hash and the
    code digest, ``cache_key``) and the report's ``settings``. Work bounds only, no wall-clock limit:
    a fit is a function of its inputs.

    tol : requested max relative Frobenius error over the band (scaled DOFs); for a gap table with
        the rigid-raft correction, also the max relative Re and Im error of the rigid-raft impedance
        (``rigid_error``; docs/formulation.md, "Rational soil model")
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
        """The options as a JSON-able dict (node_xy as a digest): the report's ``settings``. The
        fields are scalars, taken as they are (``dataclasses.asdict``'s deep copy of the node
        coordinates, thousands of tuples, is not made)."""
        d = {f.name: getattr(self, f.name) for f in fields(self)}
        xy = d.pop("node_xy")
        d["node_xy_sha"] = None if xy is None else hashlib.sha256(
            np.ascontiguousarray(xy, "<f8").tobytes()).hexdigest()[:16]
        return d

    def cache_key(self, table_hash: str) -> str:
        """SHA-256 of the table's hash (``ImpedanceTable.hash``: the inputs that made it), every
        option (``settings``) and the fit code's digest."""
        h = hashlib.sha256(table_hash.encode())
        h.update(json.dumps(self.settings(), sort_keys=True, default=str).encode())
        h.update(code_version().encode())
        return h.hexdigest()


def code_version() -> str:
    """The digest (12 hex digits) of the fit's code (``CODE``): part of the cache key."""
    return code_digest(*CODE)[:12]

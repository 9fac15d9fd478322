"""The fit constrained to the time-frequency route's continuation: ``continuation_fit``.

The time-frequency route (orchestrator/timefreq) continues a table above its last frequency
f_max by springs and dashpots, K = A + s B with A = Re K(f_max) and B = Im K(f_max) / (2 pi
f_max) (the table's causal target, ``target.causal_target``). A stand-in for the table that the
route's march can step at a rational model's cost must have that asymptote, or the defect
correction's linear rate rho(S_x^-1 (S_table - S_x)) passes 1 above the table (the plain fit's: 2.4
at 63 Hz, 34 at Nyquist on the reactor; benchmarks/timefreq.py --stand-in). This fit takes
given poles (the scene's passive fit's), fixes D = A and E = B and refits the residues to the
causal target minus A + s B at the table's frequencies by one real least squares (every entry
a right-hand side, rows weighted by 1 / |K(f)|_F), symmetrised; then tests its passivity
(``passivity.check_passive``, stored with the model). It is less accurate on the table than
the fit (3.1e-2 against 9e-4 relative at worst on the reactor, at 25 Hz), which costs sweeps,
not accuracy: the route's residual stays the table's.

Cached like the fits (``cache_dir``): keyed by the table's data (``data_digest``) and frequencies,
the poles, the fit code's digest; checksummed and written atomically (``soil_impedance.cache``).
"""
from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .options import code_version
from .target import causal_cutoff, causal_target


@dataclass(frozen=True)
class ContinuationFit:
    """model : RationalModel (poles given, D = A, E = B, its passivity test stored);
    passive : its verdict; margin : the test's margin; max_rel_error : max over the table's
    frequencies of |K_model - K_target|_F / |K_target|_F; cached : read from the cache;
    wall_s : s."""
    model: object
    passive: bool
    margin: float
    max_rel_error: float
    cached: bool = False
    wall_s: float = 0.0


def continuation(table):
    """(A, B) (n, n) real: the route's springs and dashpots above the table's last frequency
    (orchestrator.timefreq.soil's affine band), from the table's causal target at f_max."""
    K = np.asarray(table.matrices)
    f = np.asarray(table.frequencies_hz, float)
    top = causal_target(f, K, causal_cutoff(table, K))[-1]
    return np.ascontiguousarray(top.real), np.ascontiguousarray(top.imag / (2 * np.pi * f[-1]))


def continuation_model(table, poles, dofs=None):
    """(RationalModel with the given ``poles``, D = A, E = B of ``continuation``, the residues
    refit; max relative error on the table's causal target)."""
    from ..rational import RationalModel
    from ..vectfit import coefficients_to_residues

    poles = np.asarray(poles, complex)
    f, s, K, A, B, w, Phi, Y = _least_squares(table, poles)
    coef = np.linalg.lstsq(Phi, Y, rcond=None)[0]
    n = K.shape[1]
    R = coefficients_to_residues(coef.reshape(-1, n, n), poles)
    model = RationalModel(poles, 0.5 * (R + np.swapaxes(R, 1, 2)), A, B,
                          dofs=list(table.dofs) if dofs is None else dofs,
                          provenance={"source_table_data_sha256": table.data_digest, "constrained": "route continuation above "
                                      f"{f[-1]:g} Hz: D = Re K(f_max), E = Im K(f_max) / (2 pi f_max)"})
    err = np.linalg.norm((model(s) - K).reshape(f.size, -1), axis=1) * w
    return model, float(err.max())


def _least_squares(table, poles):
    """The weighted real least squares of ``continuation_model`` (module notes): (f, s, the causal
    target K (F, n, n), A, B, the row weights w (F,), the stacked real columns Phi (2F, m) and
    right-hand sides Y (2F, n^2))."""
    from ..vectfit import real_basis

    f = np.asarray(table.frequencies_hz, float)
    K = causal_target(f, np.asarray(table.matrices), causal_cutoff(table, np.asarray(table.matrices)))
    A, B = continuation(table)
    s = 2j * np.pi * f
    w = 1.0 / np.linalg.norm(K.reshape(f.size, -1), axis=1)
    Phi = w[:, None] * real_basis(s, poles, const=False, linear=False)
    Y = w[:, None] * (K - A[None] - s[:, None, None] * B[None]).reshape(f.size, -1)
    return f, s, K, A, B, w, np.concatenate([Phi.real, Phi.imag]), np.concatenate([Y.real, Y.imag])


class ContinuationBasis:
    """``continuation_model``'s residues on every subset of ``poles`` at once, for choosing the
    stand-in's poles (orchestrator/standin.py, ``choose_poles``): the weighted least squares
    ``continuation_model`` solves, projected once on the orthonormal basis Q of all the poles'
    columns (the same rows and weights). A subset's columns are Q R[:, cols], so its least
    squares is R[:, cols] c = Q^T Y, (m x m_sub) with n^2 right-hand sides instead of (2 F x
    m_sub): the same coefficients to round-off (tested), without a pass over the table per
    subset. ``units``: the subsets' elements, each a real pole or a complex pair (its two
    columns); ``residues(kept)`` -> (poles, residues (m_sub, n, n) symmetrised) of the units
    ``kept``; A, B the continuation's springs and dashpots (D and E)."""

    def __init__(self, table, poles):
        self.poles = np.asarray(poles, complex)
        _, _, K, self.A, self.B, _, Phi, Y = _least_squares(table, self.poles)
        Q, self.R = np.linalg.qr(Phi)
        self.C = Q.T @ Y                                              # (m, n^2)
        self.n = K.shape[1]
        self.units = self.units_of(self.poles)

    def residues(self, kept):
        """(poles (m_sub,), residues (m_sub, n, n) complex, symmetrised) of the units ``kept``."""
        from ..vectfit import coefficients_to_residues

        cols = self.columns(kept)
        coef = np.linalg.lstsq(self.R[:, cols], self.C, rcond=None)[0]
        poles = self.poles[cols]
        R = coefficients_to_residues(coef.reshape(-1, self.n, self.n), poles)
        return poles, 0.5 * (R + np.swapaxes(R, 1, 2))

    def columns(self, kept) -> list:
        """The columns of the units ``kept`` (a real pole's one, a pair's two), in the fit's order."""
        return [c for u in sorted(kept) for c in self.units[u]]

    def unit_poles(self, kept) -> np.ndarray:
        """The poles of the units ``kept``, in the fit's order."""
        return self.kept_poles(self.poles, kept)

    @staticmethod
    def units_of(poles) -> tuple:
        """The units of ``poles``: the index of each real pole, the two of each complex pair, in order."""
        from ..vectfit import pole_kinds

        kind = pole_kinds(poles)
        return tuple((k,) if kind[k] == 0 else (k, k + 1) for k in range(poles.size) if kind[k] != 2)

    @staticmethod
    def kept_poles(poles, kept) -> np.ndarray:
        """The poles of ``poles`` in the units ``kept`` (a real pole or a complex pair each, as
        ``units`` numbers them), in their order."""
        poles = np.asarray(poles, complex)
        units = ContinuationBasis.units_of(poles)
        return poles[[c for u in sorted(kept) for c in units[u]]]


def continuation_fit(table, poles, *, cache_dir=None, keep: str = "always") -> ContinuationFit:
    """The passive-tested stand-in of ``table`` with ``poles`` (module notes), from the cache
    ``cache_dir`` when there (None: no cache). keep : "always" (a new fit is written to the
    cache), or "passive" (only when it passed: a subset tried and rejected, which no later run
    reads, is not kept: orchestrator/standin.py, ``choose_poles``)."""
    from ..passivity import check_passive, with_verified_passivity

    if keep not in ("always", "passive"):
        raise ValueError(f"continuation_fit: keep = {keep!r}, not \"always\" or \"passive\"")
    t0 = time.perf_counter()
    poles = np.asarray(poles, complex)
    path = None
    if cache_dir is not None:
        path = _cache_path(table, poles, cache_dir)
        hit = _read(path)
        if hit is not None:
            return hit
    model, err = continuation_model(table, poles)
    rep = check_passive(model)                      # kept by the model's digest: not run again below
    model = with_verified_passivity(model)
    out = ContinuationFit(model, bool(rep.passive), float(rep.margin), err, False, time.perf_counter() - t0)
    if path is not None and (keep == "always" or out.passive):
        from ..cache import write_entry
        write_entry(path, lambda p: _save(out, p))
    return out


def _cache_path(table, poles, cache_dir) -> Path:
    """The entry of ``table``'s fit on ``poles``: keyed by what it is made of, the table's data (its
    ``data_digest``: the matrices and DOF labels) and frequencies, the poles and the fit's code
    (not the table's input hash: a table of the same data made otherwise shares it)."""
    h = hashlib.sha256(table.data_digest.encode())
    h.update(np.ascontiguousarray(table.frequencies_hz, float).tobytes())
    h.update(np.ascontiguousarray(poles, complex).tobytes())
    h.update(code_version().encode())
    return Path(cache_dir) / f"standin-{h.hexdigest()[:24]}.h5"


def _save(fit: ContinuationFit, path) -> None:
    from uplift_common.files import hdf5_output, stamp_checksum

    from ..rational import write_model
    with hdf5_output(Path(path)) as h:
        write_model(h, fit.model)
        h.attrs["passive"] = fit.passive
        h.attrs["margin"] = fit.margin
        h.attrs["max_rel_error"] = fit.max_rel_error
        stamp_checksum(h)


def _read(path) -> ContinuationFit | None:
    from ..cache import read_entry
    from ..rational import read_model

    def reader(h):
        t0 = time.perf_counter()
        model = read_model(h, path)
        return ContinuationFit(model, bool(h.attrs["passive"]), float(h.attrs["margin"]),
                               float(h.attrs["max_rel_error"]), True, time.perf_counter() - t0)
    return read_entry(path, reader)

"""Rational (pole-residue) soil models: K(s) ≈ D + s E + Σ_k R_k / (s − p_k).

The common-pole form used by the time-domain soil (DESIGN.md §4): every entry of the
matrix shares the poles ``p_k``; the harmonic convention is e^{+iωt}, so the frequency
response is K(iω) and must match an ImpedanceTable's K(ω). A model is real (real impulse
response) when complex poles come in conjugate pairs with conjugate residues; stable when
Re p_k < 0; passive when the Hermitian part of Im K(iω) is positive semi-definite for ω > 0.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


class FitError(ValueError):
    """A rational model that cannot be used as asked (unstable, non-real, non-passive...)."""


@dataclass(frozen=True, eq=False)
class RationalModel:
    """K(s) = D + s E + Σ_k R_k / (s − p_k).

    poles : ndarray (m,), complex, rad/s   Re p < 0; complex poles listed with their conjugate
    residues : ndarray (m, n, n), complex  symmetric matrices; conj(p) carries conj(R)
    D : ndarray (n, n), real symmetric     N/m (or N, N·m per DOF pair)
    E : ndarray (n, n), real symmetric PSD N s/m
    dofs : list of str                     labels of the n DOFs (as the source table)
    provenance : dict                      source table hash, fit settings, errors
    """

    poles: np.ndarray
    residues: np.ndarray
    D: np.ndarray
    E: np.ndarray
    dofs: list = field(default_factory=list)
    provenance: dict = field(default_factory=dict)

    def __post_init__(self):
        p = np.asarray(self.poles, complex).reshape(-1)
        R = np.asarray(self.residues, complex)
        D = np.asarray(self.D, float)
        E = np.asarray(self.E, float)
        n = D.shape[0]
        if D.shape != (n, n) or E.shape != (n, n) or R.shape != (p.size, n, n):
            raise FitError(f"inconsistent shapes: poles {p.shape}, residues {R.shape}, D {D.shape}, E {E.shape}")
        if np.any(p.real >= 0):
            raise FitError(f"unstable model: pole {p[np.argmax(p.real)]} has Re p >= 0")
        for name, value in (("poles", p), ("residues", R), ("D", D), ("E", E)):
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        object.__setattr__(self, "dofs", list(self.dofs) or [f"d{i}" for i in range(n)])

    @property
    def n(self) -> int:
        return self.D.shape[0]

    @property
    def order(self) -> int:
        """Number of poles (a conjugate pair counts two)."""
        return self.poles.size

    def __call__(self, s) -> np.ndarray:
        """K(s) for an array of complex s: shape s.shape + (n, n)."""
        s = np.asarray(s, complex)
        out = self.D + s[..., None, None] * self.E
        out = out + np.einsum("...k,kij->...ij", 1.0 / (s[..., None] - self.poles), self.residues)
        return out

    def frequency_response(self, freq_hz) -> np.ndarray:
        """K(iω) at ω = 2π f, shape (F, n, n), comparable with an ImpedanceTable's matrices."""
        return self(2j * np.pi * np.asarray(freq_hz, float))


# ---------------------------------------------------------------------------------------------
# Real coefficient form and HDF5 I/O (added by the fit; the contract above is unchanged)
# ---------------------------------------------------------------------------------------------
MODEL_FORMAT = "uplift.RationalModel"
MODEL_FORMAT_VERSION = 1


def to_coefficients(model: RationalModel) -> np.ndarray:
    """Real coefficient form, shape (m + 2, n, n): K(s) = Σ_b φ_b(s) C_b.

    The basis φ_b is ``vectfit.real_basis(s, model.poles)``: one column per real pole, two per
    conjugate pair (residue c1 + i c2 on p, c1 − i c2 on p̄), then 1 (C = D) and s (C = E).
    """
    from .vectfit import residues_to_coefficients
    return np.concatenate([residues_to_coefficients(model.residues, model.poles),
                           model.D[None], model.E[None]])


def from_coefficients(poles, coefficients, dofs=(), provenance=None) -> RationalModel:
    """Inverse of ``to_coefficients`` (poles in ``vectfit.canonical_poles`` order)."""
    from .vectfit import coefficients_to_residues
    C = np.asarray(coefficients, float)
    m = np.asarray(poles).size
    return RationalModel(poles, coefficients_to_residues(C[:m], poles), C[m], C[m + 1],
                         list(dofs), dict(provenance or {}))


def save_model(model: RationalModel, path) -> None:
    """Write a model to HDF5 (overwrites).

    Layout: /poles_real, /poles_imag (m,) rad/s; /residues_real, /residues_imag (m, n, n);
    /D, /E (n, n); /dofs utf-8 (n,); attrs format = "uplift.RationalModel", format_version = 1,
    provenance (JSON).
    """
    import json
    import h5py
    with h5py.File(path, "w") as h:
        h.attrs["format"] = MODEL_FORMAT
        h.attrs["format_version"] = MODEL_FORMAT_VERSION
        h.attrs["provenance"] = json.dumps(model.provenance, sort_keys=True, default=str)
        h.create_dataset("poles_real", data=model.poles.real).attrs["units"] = "rad/s"
        h.create_dataset("poles_imag", data=model.poles.imag).attrs["units"] = "rad/s"
        h.create_dataset("residues_real", data=model.residues.real)
        h.create_dataset("residues_imag", data=model.residues.imag)
        h.create_dataset("D", data=model.D)
        h.create_dataset("E", data=model.E)
        h.create_dataset("dofs", data=np.array(model.dofs, dtype=object), dtype=h5py.string_dtype("utf-8"))


def load_model(path) -> RationalModel:
    """Read a model written by ``save_model``; FitError on a missing or foreign file."""
    import json
    import h5py
    try:
        h = h5py.File(path, "r")
    except OSError as exc:
        raise FitError(f"{path}: cannot open as an HDF5 rational model ({exc})") from None
    with h:
        if h.attrs.get("format") != MODEL_FORMAT:
            raise FitError(f"{path}: not an {MODEL_FORMAT} file (attribute 'format' missing or wrong)")
        if int(h.attrs.get("format_version", -1)) != MODEL_FORMAT_VERSION:
            raise FitError(f"{path}: format_version {h.attrs.get('format_version')}, "
                           f"this code reads {MODEL_FORMAT_VERSION}: refit the table")
        try:
            p = h["poles_real"][()] + 1j * h["poles_imag"][()]
            R = h["residues_real"][()] + 1j * h["residues_imag"][()]
            D, E = h["D"][()], h["E"][()]
            dofs = [d.decode() if isinstance(d, bytes) else str(d) for d in h["dofs"][()]]
            prov = json.loads(h.attrs["provenance"])
        except KeyError as exc:
            raise FitError(f"{path}: missing dataset or attribute {exc}: refit the table") from None
    return RationalModel(p, R, D, E, dofs, prov)


RationalModel.save = save_model
RationalModel.load = staticmethod(load_model)

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

"""Rational (pole-residue) soil models: K(s) ≈ D + s E + Σ_k R_k / (s − p_k).

The common-pole form used by the time-domain soil: every entry of the
matrix shares the poles ``p_k``; the harmonic convention is e^{+iωt}, so the frequency
response is K(iω) and must match an ImpedanceTable's K(ω). A model is real (real impulse
response) when complex poles come in conjugate pairs with conjugate residues; stable when
Re p_k < 0; passive when the Hermitian part of Im K(iω) is positive semi-definite for ω > 0.

One model, the forms its users need, each computed once (cached on the frozen model):
``coefficients`` (real-basis form, the fit's and the passivity enforcement's unknowns),
``scaled`` (the DOF-scaled, frequency-normalised view the passivity test works on),
``pole_split`` (real poles and one pole per conjugate pair, the recursive convolution's
state-space form), ``static`` (K(0)) and ``digest`` (content hash). ``from_coefficients``
builds a model from the real-basis form and keeps it; ``with_provenance`` copies a model
with its cached forms.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from uplift_common.errors import UserInputError


class FitError(UserInputError):
    """A rational model that cannot be used as asked (unstable, non-real, non-passive...)."""


def _frozen(a):
    a.setflags(write=False)
    return a


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

    @classmethod
    def from_coefficients(cls, poles, coefficients, dofs=(), provenance=None) -> RationalModel:
        """The model of the real coefficient form C, shape (m + 2, n, n) (see ``coefficients``;
        poles in ``vectfit.canonical_poles`` order); C is kept as the model's ``coefficients``."""
        from .vectfit import coefficients_to_residues
        C = np.array(coefficients, float)
        m = np.asarray(poles).size
        model = cls(poles, coefficients_to_residues(C[:m], poles), C[m], C[m + 1], list(dofs),
                    dict(provenance or {}))
        model.__dict__["coefficients"] = _frozen(C)
        return model

    def with_provenance(self, provenance: dict) -> RationalModel:
        """The same model with another provenance; the cached forms are shared (the scaled view
        only while the reference frequency "f_max_hz" is unchanged)."""
        new = object.__new__(type(self))
        new.__dict__.update(self.__dict__)
        object.__setattr__(new, "provenance", dict(provenance))
        if provenance.get("f_max_hz") != self.provenance.get("f_max_hz"):
            new.__dict__.pop("scaled", None)
        return new

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

    # ---- derived forms (computed once) --------------------------------------------------------
    @cached_property
    def coefficients(self) -> np.ndarray:
        """Real coefficient form, shape (m + 2, n, n), read-only: K(s) = Σ_b φ_b(s) C_b.

        The basis φ_b is ``vectfit.real_basis(s, model.poles)``: one column per real pole, two per
        conjugate pair (residue c1 + i c2 on p, c1 − i c2 on p̄), then 1 (C = D) and s (C = E).
        """
        from .vectfit import residues_to_coefficients
        return _frozen(np.concatenate([residues_to_coefficients(self.residues, self.poles),
                                       self.D[None], self.E[None]]))

    @cached_property
    def static(self) -> np.ndarray:
        """K(0) = D − Σ R_k / p_k, real symmetric (n, n), read-only."""
        K = self(np.zeros(1))[0].real
        return _frozen(0.5 * (K + K.T))

    @cached_property
    def digest(self) -> str:
        """SHA-256 of poles, residues, D and E (the content; not dofs or provenance)."""
        h = hashlib.sha256()
        for a in (self.poles, self.residues, self.D, self.E):
            h.update(np.ascontiguousarray(a).tobytes())
        return h.hexdigest()

    @cached_property
    def scaled(self) -> ScaledModel:
        """The DOF-scaled, frequency-normalised view (``ScaledModel``) of the passivity test."""
        return ScaledModel.of(self)

    @cached_property
    def pole_split(self):
        """(p_real (m_r,), R_real (m_r, n, n) real, p_pair (m_c,) with Im p > 0, R_pair (m_c, n, n)):
        the state-space form of the recursive convolution (one state per real pole, one complex
        state per conjugate pair). FitError when a complex pole lacks its conjugate, conjugate
        residues differ, or a real pole carries a complex residue."""
        return _split_poles(self.poles, self.residues)


def _split_poles(p, R, rtol: float = 1e-8):
    """``RationalModel.pole_split``. The residues' scale max |R| (a pass over all of them) is taken
    only when a test needs it: a residue difference that is exactly zero (real poles' residues
    with zero imaginary parts, conjugate residues stored exactly conjugate, as a fit makes them)
    passes whatever the scale (> 0), so the outcome is that of testing every one against it."""
    scale = []

    def rscale():
        if not scale:
            scale.append(max(np.abs(R).max(initial=0.0), 1e-300))
        return scale[0]
    is_real = np.abs(p.imag) <= rtol * np.abs(p)
    real = R if is_real.all() else R[is_real]      # the real poles' residues (all of them: no copy)
    imag = real.imag
    if np.any(imag) and np.any(np.abs(imag) > rtol * rscale() * 1e2):
        raise FitError("a real pole carries a complex residue: the model's impulse response "
                       "would not be real; refit with real residues for real poles")
    up = np.flatnonzero(~is_real & (p.imag > 0))
    down = list(np.flatnonzero(~is_real & (p.imag < 0)))
    if len(up) != len(down):
        raise FitError(f"{len(up)} poles with Im p > 0 but {len(down)} with Im p < 0: complex "
                       "poles must come in conjugate pairs")
    for k in up:
        j = min(down, key=lambda j: abs(p[j] - np.conj(p[k])))
        if abs(p[j] - np.conj(p[k])) > rtol * abs(p[k]) * 1e2 or (
                not _conjugate(R[j], R[k]) and np.abs(R[j] - np.conj(R[k])).max() > 1e-6 * rscale()):
            raise FitError(f"pole {p[k]:.6g} has no conjugate partner with conjugate residue")
        down.remove(j)
    return (_frozen(np.ascontiguousarray(p[is_real].real)), _frozen(np.ascontiguousarray(real.real)),
            _frozen(p[up]), _frozen(np.ascontiguousarray(R[up])))


def _conjugate(a, b) -> bool:
    """a == conj(b) exactly, entry by entry (then |a - conj(b)| is 0 everywhere; NaN: False)."""
    return bool(np.array_equal(a.real, b.real) and np.array_equal(a.imag, -b.imag))


def _symmetric(C):
    return _frozen(0.5 * (C + C.transpose(0, 2, 1)))


@dataclass(frozen=True, eq=False)
class ScaledModel:
    """A model in the passivity test's units: S K S on the active DOFs, normalised frequency.

    idx : (na,) active DOFs (a nonzero row in some coefficient); S : (na,) the DOF scaling
    S_i = |K_ii(0)|^{-1/2} (fallback max_b |C_b,ii|); w_ref : rad/s, 2π × the top of the fitted
    band (provenance "f_max_hz"), else max |p|; poles : p / w_ref; C : (m + 2, na, na) the
    coefficients on ``vectfit.real_basis(iν, poles)``, ν = ω / w_ref (exactly symmetric, read-only).
    """

    idx: np.ndarray
    S: np.ndarray
    w_ref: float
    poles: np.ndarray
    C: np.ndarray

    @classmethod
    def of(cls, model: RationalModel) -> ScaledModel:
        C = model.coefficients
        idx = np.nonzero(np.max(np.abs(C), axis=(0, 2)) > 1e-300)[0]
        d = np.abs(np.diag(model.static))[idx]
        fallback = np.max(np.abs(np.einsum("bii->bi", C)), axis=0)[idx]
        d = np.where(d > 1e-12 * fallback, d, fallback)
        S = 1.0 / np.sqrt(np.where(d > 0, d, 1.0))
        f = model.provenance.get("f_max_hz")
        w_ref = 2 * np.pi * float(f) if f else (float(np.max(np.abs(model.poles))) if model.order else 1.0)
        Cs = C[:, idx][:, :, idx] * S[None, :, None] * S[None, None, :]
        m = model.order
        Cs[:m] /= w_ref
        Cs[m + 1] *= w_ref
        return cls(_frozen(idx), _frozen(S), w_ref, _frozen(model.poles / w_ref), _symmetric(Cs))

    def with_coefficients(self, C) -> ScaledModel:
        """The same scaling and poles with other (scaled) coefficients (symmetrised)."""
        return ScaledModel(self.idx, self.S, self.w_ref, self.poles, _symmetric(np.asarray(C, float)))

    @property
    def na(self) -> int:
        return self.idx.size

    @cached_property
    def columns(self) -> np.ndarray:
        """C as columns, (na², m + 2), read-only: G(ν) = (Φ(ν) columnsᵀ).reshape(na, na) is one GEMM
        in the layout BLAS runs fastest (a transposed operand)."""
        return _frozen(np.ascontiguousarray(self.C.reshape(self.C.shape[0], -1).T))

    @cached_property
    def residues(self) -> np.ndarray:
        """Scaled, normalised residues (m, na, na), complex."""
        from .vectfit import coefficients_to_residues
        return _frozen(coefficients_to_residues(self.C[:self.poles.size], self.poles))

    def unscale(self, C_scaled, model: RationalModel, provenance=None) -> RationalModel:
        """``model`` with its active block replaced by the scaled coefficients ``C_scaled`` (symmetrised)."""
        C = np.array(C_scaled, float)
        m = self.poles.size
        C[:m] *= self.w_ref
        C[m + 1] /= self.w_ref
        C = C / self.S[None, :, None] / self.S[None, None, :]
        full = np.array(model.coefficients)
        full[np.ix_(range(full.shape[0]), self.idx, self.idx)] = 0.5 * (C + C.transpose(0, 2, 1))
        return RationalModel.from_coefficients(model.poles, full, model.dofs,
                                               model.provenance if provenance is None else provenance)


# ---------------------------------------------------------------------------------------------
# HDF5 I/O
# ---------------------------------------------------------------------------------------------
MODEL_FORMAT = "uplift.RationalModel"
MODEL_FORMAT_VERSION = 1
#: root attribute of a model file: the model's ``digest`` (SHA-256 of its poles, residues, D and E)
DIGEST_ATTR = "digest"


def save_model(model: RationalModel, path) -> None:
    """Write a model to HDF5 (overwrites); layout: ``write_model``."""
    import h5py
    with h5py.File(path, "w") as h:
        write_model(h, model)


def write_model(h, model: RationalModel) -> None:
    """Write ``model`` into the open, writable h5py File ``h``.

    Layout: /poles_real, /poles_imag (m,) rad/s; /residues_real, /residues_imag (m, n, n);
    /D, /E (n, n); /dofs utf-8 (n,); attrs format = "uplift.RationalModel", format_version = 1,
    provenance (JSON), digest (the model's ``digest``: what a reader of a checksummed cache entry
    takes instead of hashing the residues again, ``read_model(trust_digest=True)``).
    """
    import json
    import h5py
    h.attrs["format"] = MODEL_FORMAT
    h.attrs["format_version"] = MODEL_FORMAT_VERSION
    h.attrs["provenance"] = json.dumps(model.provenance, sort_keys=True, default=str)
    h.attrs[DIGEST_ATTR] = model.digest
    h.create_dataset("poles_real", data=model.poles.real).attrs["units"] = "rad/s"
    h.create_dataset("poles_imag", data=model.poles.imag).attrs["units"] = "rad/s"
    h.create_dataset("residues_real", data=model.residues.real)
    h.create_dataset("residues_imag", data=model.residues.imag)
    h.create_dataset("D", data=model.D)
    h.create_dataset("E", data=model.E)
    h.create_dataset("dofs", data=np.array(model.dofs, dtype=object), dtype=h5py.string_dtype("utf-8"))


def load_model(path) -> RationalModel:
    """Read a model written by ``save_model``; FitError on a missing or foreign file."""
    import h5py
    try:
        h = h5py.File(path, "r")
    except OSError as exc:
        raise FitError(f"{path}: cannot open as an HDF5 rational model ({exc})") from None
    with h:
        return read_model(h, path)


def _complex(re, im) -> np.ndarray:
    """re + i im bit for bit (``re + 1j * im`` turns -0.0 into 0.0: another content digest)."""
    out = np.empty(np.shape(re), complex)
    out.real, out.imag = re, im
    return out


def read_model(h, path="", data=None, trust_digest: bool = False) -> RationalModel:
    """The model in the open h5py File ``h`` (``write_model`` layout); FitError naming ``path``
    when it is not one. data: its datasets as a checksum verification read them
    (``{"/name": array}``, ``uplift_common.files.checksum(keep=...)``; a ``<name>_real`` and
    ``<name>_imag`` pair read into one complex array, ``ComplexPairs``, is taken as it is), not
    read again. trust_digest: the file is a cache entry of this code whose checksum was just
    verified (``soil_impedance.cache.read_entry``), so its stored ``digest`` attribute is that of
    the arrays read (it was computed from them when they were written) and is kept as the
    model's ``digest`` instead of hashing them again; a file a user may have edited and stamped
    again is never trusted (``load_model``, ``load_fit``: the digest is computed)."""
    import json
    if h.attrs.get("format") != MODEL_FORMAT:
        raise FitError(f"{path}: not an {MODEL_FORMAT} file (attribute 'format' missing or wrong)")
    if int(h.attrs.get("format_version", -1)) != MODEL_FORMAT_VERSION:
        raise FitError(f"{path}: format_version {h.attrs.get('format_version')}, "
                       f"this code reads {MODEL_FORMAT_VERSION}: refit the table")
    read = (lambda name: h[name][()]) if data is None else (lambda name: data["/" + name])
    try:
        p = _pair(read("poles_real"), read("poles_imag"))
        R = _pair(read("residues_real"), read("residues_imag"))
        D, E = read("D"), read("E")
        dofs = [d.decode() if isinstance(d, bytes) else str(d) for d in read("dofs")]
        prov = json.loads(h.attrs["provenance"])
    except KeyError as exc:
        raise FitError(f"{path}: missing dataset or attribute {exc}: refit the table") from None
    model = RationalModel(p, R, D, E, dofs, prov)
    stored = h.attrs.get(DIGEST_ATTR) if trust_digest else None
    if isinstance(stored, str) and len(stored) == 64:
        model.__dict__["digest"] = stored
    return model


def _pair(re, im) -> np.ndarray:
    """``_complex(re, im)``; the complex array itself when ``re`` and ``im`` are its two parts (a
    checksum's ``ComplexPairs`` reads a pair that way): the same bits, not copied."""
    whole = re.base
    if isinstance(whole, np.ndarray) and whole is im.base and whole.dtype == np.complex128 \
            and whole.shape == re.shape == im.shape and re.strides == im.strides == whole.strides:
        start = whole.__array_interface__["data"][0]
        if re.__array_interface__["data"][0] == start and im.__array_interface__["data"][0] == start + 8:
            return whole
    return _complex(re, im)


RationalModel.save = save_model
RationalModel.load = staticmethod(load_model)

"""ImpedanceTable: complex impedance matrices over frequency, with provenance and HDF5 I/O.

HDF5 layout (open it with h5py, HDFView, MATLAB ``h5read``...):
  /frequencies_hz   float64 (F,)          Hz
  /matrices_real    float64 (F, n, n)     SI: N/m, N/rad, N·m/m, N·m/rad per DOF pair
  /matrices_imag    float64 (F, n, n)
  /dofs             utf-8 strings (n,)
  attrs: format = "uplift.ImpedanceTable", format_version = 1, hash (of the inputs: provenance
         + frequencies), data_sha256 (of matrices + dofs, checked on load), provenance (JSON),
         notes (JSON, optional: what the writer adds about the table, e.g. the discretisation
         error estimate of ``uplift impedance``; not an input, not in the hash),
         sha256 (of the whole file, ``uplift_common.files.stamp_checksum``; checked on load: a file that
         changed since it was written, or carries none, is refused)

Files are written atomically (``uplift_common.files.atomic_output``): a reader sees the old file or the
complete new one, never a half-written one.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from uplift_common.files import ChangedFileError, ComplexPairs, hdf5_output, require_checksum, stamp_checksum
from uplift_common.errors import UserInputError

FORMAT = "uplift.ImpedanceTable"
FORMAT_VERSION = 1


class TableError(UserInputError):
    """An invalid impedance table, file or interpolation request."""


def content_hash(provenance: dict, frequencies_hz) -> str:
    """SHA-256 (hex) of the canonical JSON of ``provenance`` and the frequency bytes."""
    h = hashlib.sha256(json.dumps(provenance, sort_keys=True, default=str).encode())
    h.update(np.ascontiguousarray(frequencies_hz, dtype="<f8").tobytes())
    return h.hexdigest()


def _complex(re, im) -> np.ndarray:
    """The complex matrices of the parts re and im: the array they are the parts of when they
    were read in place (``uplift_common.files.ComplexPairs``), else a copy (bit-exact, signed zeros kept)."""
    base = re.base
    if isinstance(base, np.ndarray) and base is im.base and base.dtype == complex and base.shape == re.shape \
            and re.strides == im.strides == base.strides \
            and re.ctypes.data == base.ctypes.data and im.ctypes.data == base.ctypes.data + 8:
        return base
    K = np.empty(re.shape, dtype=complex)
    K.real, K.imag = re, im
    return K


def _data_digest(table) -> str:
    h = hashlib.sha256(memoryview(np.ascontiguousarray(table.matrices, dtype="<c16")).cast("B"))
    h.update("\n".join(table.dofs).encode())
    return h.hexdigest()


@dataclass(frozen=True, eq=False)
class ImpedanceTable:
    """Impedance matrices K(f) at increasing frequencies.

    Attributes
    ----------
    frequencies_hz : ndarray, shape (F,), Hz, strictly increasing, >= 0
    matrices : ndarray, shape (F, n, n), complex     forces on the soil per unit displacement
    dofs : list[str], length n                        DOF labels (e.g. "ux", "rx", "w12")
    provenance : dict                                 the inputs that made the table (JSON-able)
    """

    frequencies_hz: np.ndarray
    matrices: np.ndarray
    dofs: list
    provenance: dict = field(default_factory=dict)

    def __post_init__(self):
        f = np.asarray(self.frequencies_hz, dtype=float).reshape(-1)
        K = np.asarray(self.matrices, dtype=complex)
        dofs = [str(d) for d in self.dofs]
        if f.size == 0 or not np.all(np.isfinite(f)) or np.any(f < 0):
            raise TableError("frequencies_hz must be a non-empty array of finite values >= 0")
        if np.any(np.diff(f) <= 0):
            raise TableError("frequencies_hz must be strictly increasing")
        if K.ndim != 3 or K.shape[0] != f.size or K.shape[1] != K.shape[2]:
            raise TableError(f"matrices must have shape (F={f.size}, n, n), got {K.shape}")
        if len(dofs) != K.shape[1]:
            raise TableError(f"dofs has {len(dofs)} labels for {K.shape[1]} matrix rows")
        f.setflags(write=False)
        K.setflags(write=False)
        object.__setattr__(self, "frequencies_hz", f)
        object.__setattr__(self, "matrices", K)
        object.__setattr__(self, "dofs", dofs)
        object.__setattr__(self, "provenance", dict(self.provenance))

    def __repr__(self) -> str:
        f = self.frequencies_hz
        return (f"ImpedanceTable({f.size} frequencies {f[0]:g}..{f[-1]:g} Hz, {self.n_dof} DOFs "
                f"{self.dofs[:6]}{'...' if self.n_dof > 6 else ''}, hash {self.hash[:12]})")

    @property
    def hash(self) -> str:
        """Content hash of the inputs (provenance and frequencies): the cache key."""
        return content_hash(self.provenance, self.frequencies_hz)

    @cached_property
    def data_digest(self) -> str:
        """SHA-256 (hex) of the data (the matrices' bytes and the DOF labels: the ``data_sha256``
        a saved table carries), computed once per table (its arrays are read-only): a table read
        from a file has it from its own verification, for free; the key of values made from the
        data themselves (the time-frequency route's set-up: orchestrator/timefreq/setup_cache.py)."""
        return _data_digest(self)

    @property
    def n_dof(self) -> int:
        return len(self.dofs)

    def index(self, label: str) -> int:
        try:
            return self.dofs.index(label)
        except ValueError:
            raise TableError(f"no DOF {label!r} in this table; its DOFs start {self.dofs[:8]}") from None

    def at(self, freq_hz):
        """K at ``freq_hz`` (scalar or array, Hz): cubic spline (not-a-knot) in f on the real
        and imaginary parts (linear below 4 frequencies; exact at the table frequencies).
        Negative f returns conj K(|f|). Outside [f_min, f_max] raises TableError.

        Returns
        -------
        ndarray, shape (n, n) for a scalar, (m, n, n) for an array of m frequencies
        """
        q0 = np.asarray(freq_hz, dtype=float)
        q = np.atleast_1d(q0)
        a = np.abs(q)
        f = self.frequencies_hz
        tol = 1e-9 * max(f[-1], 1.0)
        if np.any(~np.isfinite(a)) or np.any(a < f[0] - tol) or np.any(a > f[-1] + tol):
            raise TableError(f"frequency {freq_hz!r} Hz is outside the table range "
                             f"[{f[0]:g}, {f[-1]:g}] Hz: recompute the sweep over a wider range")
        a = np.clip(a, f[0], f[-1])
        if f.size == 1:
            out = np.broadcast_to(self.matrices[0], a.shape + self.matrices.shape[1:]).copy()
        else:
            from scipy.interpolate import CubicSpline, interp1d
            if f.size < 4:
                re = interp1d(f, self.matrices.real, axis=0)(a)
                im = interp1d(f, self.matrices.imag, axis=0)(a)
            else:
                re = CubicSpline(f, self.matrices.real, axis=0)(a)
                im = CubicSpline(f, self.matrices.imag, axis=0)(a)
            out = re + 1j * im
            hit = np.isclose(a[..., None], f, rtol=0, atol=tol)   # exact at the nodes
            if hit.any():
                idx = np.nonzero(hit.any(-1))
                out[idx] = self.matrices[hit[idx].argmax(-1)]
        neg = q < 0
        if np.any(neg):
            out[neg] = np.conj(out[neg])
        return out[0] if q0.ndim == 0 else out

    def save(self, path, notes: dict | None = None) -> None:
        """Write the table to an HDF5 file, atomically (replaces an existing file only once the
        new one is complete; the folder must exist: ``uplift_common.files.OutputFolderError`` otherwise).
        ``notes``: a JSON-able dict stored as the ``notes`` attribute (not part of the hash)."""
        import h5py
        with hdf5_output(path) as h:
            if notes is not None:
                h.attrs["notes"] = json.dumps(notes, sort_keys=True, default=str)
            h.attrs["format"] = FORMAT
            h.attrs["format_version"] = FORMAT_VERSION
            h.attrs["hash"] = self.hash
            h.attrs["data_sha256"] = self.data_digest
            h.attrs["provenance"] = json.dumps(self.provenance, sort_keys=True, default=str)
            h.create_dataset("frequencies_hz", data=self.frequencies_hz).attrs["units"] = "Hz"
            for part in ("real", "imag"):
                ds = h.create_dataset(f"matrices_{part}", data=getattr(self.matrices, part))
                ds.attrs["units"] = "SI: N/m, N/rad, N·m/m, N·m/rad (by DOF pair)"
            h.create_dataset("dofs", data=np.array(self.dofs, dtype=object),
                             dtype=h5py.string_dtype("utf-8"))
            stamp_checksum(h)

    @classmethod
    def load(cls, path) -> ImpedanceTable:
        """Read a table written by ``save``; TableError naming the file if it is missing,
        foreign, altered or truncated."""
        import h5py
        try:
            h = h5py.File(path, "r")
        except OSError as exc:
            raise TableError(f"{path}: cannot open as an HDF5 impedance table ({exc})") from None
        with h:
            return cls.from_hdf5(h, path)

    @classmethod
    def open(cls, path):
        """The table in ``path`` read lazily, in blocks (``blocked.BlockedTable``: the matrices stay on
        disk; for tables too large to hold), verified as ``load`` verifies it."""
        from .blocked import BlockedTable
        return BlockedTable.open(path)

    @classmethod
    def from_hdf5(cls, h, path, data: dict | None = None) -> ImpedanceTable:
        """Read the table in the open h5py file ``h`` (``path`` names it in errors); checks the
        format, the whole-file checksum and the hash and data digest. data: the file's datasets as
        the caller's checksum verification read them (``cache.read_entry(..., keep=True)``): the
        checksum is not computed again. Either way the file is read once, the matrices straight
        into the table's complex array when read with ``into=uplift_common.files.ComplexPairs()`` (as
        ``cache.read_entry`` does)."""
        if h.attrs.get("format") != FORMAT:
            raise TableError(f"{path}: not an {FORMAT} file (attribute 'format' missing or wrong)")
        version = int(h.attrs.get("format_version", -1))
        if version != FORMAT_VERSION:
            raise TableError(f"{path}: format_version {version}, this code reads {FORMAT_VERSION}")
        if data is None:
            data = {}
            try:
                require_checksum(h, path, "delete it and recompute", keep=data, into=ComplexPairs())
            except ChangedFileError as exc:
                raise TableError(str(exc)) from None
        try:
            f = data["/frequencies_hz"]
            re, im = data["/matrices_real"], data["/matrices_imag"]
            if re.ndim != 3 or re.shape != im.shape:
                raise TableError(f"{path}: matrices_real/imag must have the same shape (F, n, n), "
                                 f"got {re.shape} and {im.shape}")
            K = _complex(re, im)
            dofs = [d.decode() if isinstance(d, bytes) else str(d) for d in data["/dofs"]]
            prov = json.loads(h.attrs["provenance"])
            stored = str(h.attrs["hash"])
            digest = str(h.attrs["data_sha256"])
        except KeyError as exc:
            raise TableError(f"{path}: missing dataset or attribute {exc}") from None
        except (OSError, json.JSONDecodeError) as exc:
            raise TableError(f"{path}: unreadable ({exc}): delete it and recompute") from None
        try:
            table = cls(f, K, dofs, prov)
        except TableError as exc:
            raise TableError(f"{path}: {exc}") from None
        if table.hash != stored or table.data_digest != digest:
            raise TableError(f"{path}: stored hash or data_sha256 does not match the content "
                             "(file altered or truncated?): delete it and recompute")
        return table

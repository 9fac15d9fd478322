"""An impedance table too large to hold: written one frequency at a time, read in blocks.

A gap table is (6 + N)² complex per frequency: 100 MB at N = 2500, 10 GB over the reactor scene's
101 frequencies. ``TableWriter`` stores each frequency's matrix as the sweep computes it, straight
into the cache entry's HDF5 file; ``BlockedTable`` reads a block of entries across all frequencies
(``block``) without reading the rest.

The file is an ordinary ``table.ImpedanceTable`` file (same datasets, attributes, hash, data
digest and whole-file checksum: ``ImpedanceTable.load`` reads it whole, bit-identically), with
``matrices_real`` and ``matrices_imag`` stored in chunks of one frequency × ``CHUNK`` × ``CHUNK``
entries: a frequency is written as whole chunks (no chunk read back), a block of ``CHUNK`` rows ×
``CHUNK`` columns across the F frequencies is F chunk reads (F · 128 KB per part at CHUNK = 128).
The full matrix is stored, not its upper triangle: the fit reads the upper-triangle blocks only
(half the bytes), and the file keeps the ``ImpedanceTable`` layout every reader knows.

The writer is atomic (``uplift_common.files.atomic_output``: a temporary file renamed at the end,
removed on any error) and computes the data digest (SHA-256 of the complex matrices, frequency
after frequency: the same bytes as ``table._data_digest`` of the whole array) as it goes; the
whole-file checksum is stamped at the end (``stamp_checksum`` reads the datasets in slabs of
about 64 MB). ``BlockedTable.open`` verifies both, streaming, before anything is read from it.
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import sys
from pathlib import Path

import numpy as np

from uplift_common.files import atomic_output, stamp_checksum, verify_checksum

from .table import FORMAT, FORMAT_VERSION, ImpedanceTable, TableError, content_hash

#: chunk edge (entries) of the matrices in a blocked file; also the default block of ``BlockedTable.blocks``
CHUNK = 128
#: tables whose matrices take more bytes than this (complex, all frequencies) are written by the sweep
#: frequency by frequency into their cache entry and handed on as a ``BlockedTable`` (docs/formulation.md,
#: "The fit's memory": the reactor's 98 MB table stays in memory; a 600-node one, 0.6 GB, does not)
STREAM_BYTES = 256 * 2 ** 20


def chunk_edge(n: int, chunk: int = CHUNK) -> int:
    """The chunk edge for n DOFs: at most ``chunk``, tiling n with the fewest chunks as evenly as possible
    (HDF5 stores a partial edge chunk whole: 599 DOFs in chunks of 128 took 14 % more disk, of 120 0.3 %)."""
    return -(-n // -(-n // max(1, int(chunk)))) if n else 1


def table_bytes(n_freq: int, n_dof: int) -> int:
    """Bytes of the complex matrices of a table (F, n, n)."""
    return 16 * n_freq * n_dof * n_dof


class TableWriter:
    """Write an ``ImpedanceTable`` file one frequency at a time (``writer[k] = K`` for k = 0, 1, ...).

    Use as a context manager; the file appears at ``path`` (atomically) when the block ends
    normally after every frequency was written, never otherwise::

        with TableWriter(path, f, dofs, provenance) as w:
            for k in range(f.size):
                w[k] = K_k                     # (n, n) complex
        table = BlockedTable.open(path)
    """

    def __init__(self, path, frequencies_hz, dofs, provenance, notes: dict | None = None, chunk: int = CHUNK):
        self.path = Path(path)
        self.f = np.asarray(frequencies_hz, dtype=float).reshape(-1)
        self.dofs = [str(d) for d in dofs]
        self.provenance = dict(provenance)
        self.notes = notes
        self.n = len(self.dofs)
        self.chunk = chunk_edge(self.n, chunk)
        self._stack = None
        self._next = 0

    def __enter__(self) -> TableWriter:
        import h5py
        self._stack = contextlib.ExitStack()
        try:
            tmp = self._stack.enter_context(atomic_output(self.path))
            self._h = self._stack.enter_context(h5py.File(tmp, "w"))
        except BaseException:
            self._stack.close()
            raise
        shape, chunks = (self.f.size, self.n, self.n), (1, self.chunk, self.chunk)
        self._ds = [self._h.create_dataset(f"matrices_{p}", shape=shape, dtype="<f8", chunks=chunks)
                    for p in ("real", "imag")]
        self._digest = hashlib.sha256()
        return self

    def __setitem__(self, k: int, K) -> None:
        if k != self._next:
            raise ValueError(f"TableWriter: frequency {k} written after {self._next - 1}: write them in order")
        K = np.asarray(K, dtype=complex)
        if K.shape != (self.n, self.n):
            raise ValueError(f"TableWriter: matrix of shape {K.shape}, expected {(self.n, self.n)}")
        self._ds[0][k] = K.real
        self._ds[1][k] = K.imag
        self._digest.update(memoryview(np.ascontiguousarray(K, dtype="<c16")).cast("B"))
        self._next += 1

    def __exit__(self, kind, exc, tb):
        import h5py
        try:
            if kind is None:
                if self._next != self.f.size:
                    raise ValueError(f"TableWriter: {self._next} of {self.f.size} frequencies written")
                h = self._h
                self._digest.update("\n".join(self.dofs).encode())
                if self.notes is not None:
                    h.attrs["notes"] = json.dumps(self.notes, sort_keys=True, default=str)
                h.attrs["format"] = FORMAT
                h.attrs["format_version"] = FORMAT_VERSION
                h.attrs["hash"] = content_hash(self.provenance, self.f)
                h.attrs["data_sha256"] = self._digest.hexdigest()
                h.attrs["provenance"] = json.dumps(self.provenance, sort_keys=True, default=str)
                h.create_dataset("frequencies_hz", data=self.f).attrs["units"] = "Hz"
                for ds in self._ds:
                    ds.attrs["units"] = "SI: N/m, N/rad, N·m/m, N·m/rad (by DOF pair)"
                h.create_dataset("dofs", data=np.array(self.dofs, dtype=object), dtype=h5py.string_dtype("utf-8"))
                stamp_checksum(h)
        except BaseException:
            self._stack.__exit__(*sys.exc_info())
            raise
        return self._stack.__exit__(kind, exc, tb)


class BlockedTable:
    """An ``ImpedanceTable`` file read in blocks: the frequencies, DOFs and provenance in memory, the
    matrices on disk (``block``, ``frequency``, ``blocks``). ``load()`` reads it whole as an
    ``ImpedanceTable``; ``matrices`` does the same (the whole array: for small tables and tests).

    Open it with ``BlockedTable.open(path)`` (verifies the file first) or ``ImpedanceTable.open``.
    """

    def __init__(self, path, frequencies_hz, dofs, provenance):
        self.path = Path(path)
        f = np.asarray(frequencies_hz, dtype=float)
        f.setflags(write=False)
        self.frequencies_hz = f
        self.dofs = list(dofs)
        self.provenance = dict(provenance)
        self.chunk = None               # the chunk edge of the file's matrices (None: not chunked by frequency)

    @classmethod
    def open(cls, path, verify: bool = True, checksum: bool | None = None) -> BlockedTable:
        """The table in ``path`` (an ``ImpedanceTable`` file, blocked or not), its whole-file checksum,
        hash and data digest verified by streaming reads (slabs of about 64 MB) unless ``verify`` is
        False (the writer that just wrote it); TableError naming the file otherwise. checksum=False:
        the whole-file checksum is not verified again (``cache.read_entry`` just did), the rest is."""
        checksum = verify if checksum is None else checksum
        import h5py
        try:
            h = h5py.File(path, "r")
        except OSError as exc:
            raise TableError(f"{path}: cannot open as an HDF5 impedance table ({exc})") from None
        with h:
            if h.attrs.get("format") != FORMAT:
                raise TableError(f"{path}: not an {FORMAT} file (attribute 'format' missing or wrong)")
            version = int(h.attrs.get("format_version", -1))
            if version != FORMAT_VERSION:
                raise TableError(f"{path}: format_version {version}, this code reads {FORMAT_VERSION}")
            if checksum and not verify_checksum(h):
                raise TableError(f"{path} changed since it was written (its data no longer match its checksum, "
                                 "or it carries none): delete it and recompute")
            try:
                f = h["frequencies_hz"][()]
                dofs = [d.decode() if isinstance(d, bytes) else str(d) for d in h["dofs"][()]]
                prov = json.loads(h.attrs["provenance"])
                stored, digest = str(h.attrs["hash"]), str(h.attrs["data_sha256"])
                shape = h["matrices_real"].shape
                if h["matrices_imag"].shape != shape or shape != (f.size, len(dofs), len(dofs)):
                    raise TableError(f"{path}: matrices of shape {shape}, expected {(f.size, len(dofs), len(dofs))}")
            except KeyError as exc:
                raise TableError(f"{path}: missing dataset or attribute {exc}") from None
            table = cls(path, f, dofs, prov)
            chunks = h["matrices_real"].chunks
            if chunks is not None and chunks[0] == 1 and chunks[1] == chunks[2]:
                table.chunk = int(chunks[1])
            if table.hash != stored:
                raise TableError(f"{path}: stored hash does not match the content: delete it and recompute")
            if verify:
                d = hashlib.sha256()
                for k in range(f.size):
                    d.update(memoryview(np.ascontiguousarray(table._read(h, k), dtype="<c16")).cast("B"))
                d.update("\n".join(dofs).encode())
                if d.hexdigest() != digest:
                    raise TableError(f"{path}: stored data_sha256 does not match the content: delete it and recompute")
        return table

    def __repr__(self) -> str:
        f = self.frequencies_hz
        return (f"BlockedTable({f.size} frequencies {f[0]:g}..{f[-1]:g} Hz, {self.n_dof} DOFs, "
                f"on disk {self.path.name}, hash {self.hash[:12]})")

    @property
    def hash(self) -> str:
        return content_hash(self.provenance, self.frequencies_hz)

    @property
    def n_dof(self) -> int:
        return len(self.dofs)

    @property
    def nbytes(self) -> int:
        return table_bytes(self.frequencies_hz.size, self.n_dof)

    @staticmethod
    def _read(h, k):
        """K(f_k) from the open file ``h``, complex (n, n)."""
        re = h["matrices_real"][k]
        K = np.empty(re.shape, complex)
        K.real, K.imag = re, h["matrices_imag"][k]
        return K

    def block(self, rows: slice, cols: slice) -> np.ndarray:
        """K[:, rows, cols] across all frequencies, complex (F, r, c): one read per part."""
        import h5py
        with h5py.File(self.path, "r") as h:
            re = h["matrices_real"][:, rows, cols]
            K = np.empty(re.shape, complex)
            K.real = re
            del re
            K.imag = h["matrices_imag"][:, rows, cols]
        return K

    def frequency(self, k: int) -> np.ndarray:
        """K(f_k), complex (n, n)."""
        import h5py
        with h5py.File(self.path, "r") as h:
            return self._read(h, k)

    def blocks(self, size: int | None = None, upper: bool = True):
        """(rows, cols) slices of the blocks of edge ``size`` tiling the matrix, row block by row block
        (the upper triangle's blocks, diagonal ones included, when ``upper``). Default size: the file's
        chunk edge (each block is then whole chunks), else ``CHUNK``."""
        size = size or self.chunk or CHUNK
        n = self.n_dof
        starts = range(0, n, size)
        for i in starts:
            for j in starts:
                if upper and j < i:
                    continue
                yield slice(i, min(i + size, n)), slice(j, min(j + size, n))

    def load(self) -> ImpedanceTable:
        """The whole table in memory (``ImpedanceTable.load``: verified again)."""
        return ImpedanceTable.load(self.path)

    @property
    def matrices(self) -> np.ndarray:
        """All the matrices, complex (F, n, n): reads the whole table (small tables, tests)."""
        return self.block(slice(None), slice(None))



def in_memory(table):
    """``table`` as an ``ImpedanceTable`` in memory: a ``BlockedTable`` is read whole (``load``), anything
    else is returned as it is. For the consumers that need every matrix at once (the frequency-domain
    routes: their bands hold K at every frequency of the grid)."""
    return table.load() if isinstance(table, BlockedTable) else table

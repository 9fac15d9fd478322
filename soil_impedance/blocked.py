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
after frequency: the same bytes as ``table._data_digest`` of the whole array) as it goes, and the
SHA-256 of every chunk of ``matrices_real`` and ``matrices_imag`` as it writes it (each chunk
written whole, ``write_direct_chunk``), into the datasets ``matrices_<part>_chunk_sha256`` (F, b,
b, 32) that ``uplift_common.files.CHUNK_DIGESTS_ATTR`` names: the whole-file checksum stamped at
the end covers those digests, not the matrices, and reads nothing back (10 GB at the mat's 2506
DOFs). Any verification of the whole file (``ImpedanceTable.load``, ``cache.read_entry``) checks
every chunk against its digest. ``BlockedTable.open`` checks the whole-file checksum without the
matrices and then each chunk the first time it is read (``block``, ``frequency``): a table is
read once, by its first consumer's pass (the fit's first pass reads every upper-triangle block),
never in a pass of its own, and a damaged chunk raises ``DamagedTableError`` before any of its
entries is used (the cache's reader then discards the entry and recomputes it,
``soil_impedance.sweep.discard_damaged``). A file without chunk digests (older, or from
``ImpedanceTable.save``) is verified whole at ``open``, as before.
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import sys
from pathlib import Path

import numpy as np

from uplift_common.files import CHUNK_DIGESTS_ATTR, atomic_output, chunk_digest, stamp_checksum, verify_checksum

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


class DamagedTableError(TableError):
    """A chunk of a blocked table's matrices does not match its digest (the file changed since it was
    written): nothing of it was used; a cache entry is discarded and recomputed."""


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
        self._grid = -(-self.n // self.chunk)
        self._ds, self._digests = [], []
        for p in ("real", "imag"):
            ds = self._h.create_dataset(f"matrices_{p}", shape=shape, dtype="<f8", chunks=chunks)
            ds.attrs[CHUNK_DIGESTS_ATTR] = f"matrices_{p}_chunk_sha256"
            self._ds.append(ds)
            self._digests.append(self._h.create_dataset(f"matrices_{p}_chunk_sha256", dtype="u1",
                                                        shape=(self.f.size, self._grid, self._grid, 32)))
        self._buffer = np.zeros((self.chunk, self.chunk))
        self._digest = hashlib.sha256()
        return self

    def __setitem__(self, k: int, K) -> None:
        if k != self._next:
            raise ValueError(f"TableWriter: frequency {k} written after {self._next - 1}: write them in order")
        K = np.asarray(K, dtype=complex)
        if K.shape != (self.n, self.n):
            raise ValueError(f"TableWriter: matrix of shape {K.shape}, expected {(self.n, self.n)}")
        c = self.chunk
        for part, ds, store in zip((K.real, K.imag), self._ds, self._digests):
            digests = np.empty((self._grid, self._grid, 32), np.uint8)
            for i, j in np.ndindex(self._grid, self._grid):
                block = np.ascontiguousarray(part[i * c:(i + 1) * c, j * c:(j + 1) * c])
                digests[i, j] = np.frombuffer(chunk_digest(block), np.uint8)
                if block.shape != (c, c):               # an edge chunk is stored whole, padded
                    self._buffer[...] = 0.0
                    self._buffer[:block.shape[0], :block.shape[1]] = block
                    block = self._buffer
                ds.id.write_direct_chunk((k, i * c, j * c), block)
            store[k] = digests
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
        self._digests = None            # {"real", "imag"}: the chunk digests (F, b, b, 32) still to check against
        self._checked = None            # (F, b, b) bool: the chunks checked so far (both parts)

    @classmethod
    def open(cls, path, verify: bool = True, checksum: bool | None = None) -> BlockedTable:
        """The table in ``path`` (an ``ImpedanceTable`` file, blocked or not), verified unless ``verify``
        is False (the writer that just wrote it); TableError naming the file otherwise. A file with
        chunk digests (``TableWriter``'s): its whole-file checksum (the digests, not the matrices) and
        hash now, each chunk when it is first read (``DamagedTableError``); any other file: its
        whole-file checksum, hash and data digest now, by streaming reads (slabs of about 64 MB).
        checksum=False: the whole-file checksum is not verified again (``cache.read_entry`` just did,
        with ``chunks=False`` for a file with chunk digests), the rest is."""
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
            digested = all(CHUNK_DIGESTS_ATTR in h[f"matrices_{p}"].attrs for p in ("real", "imag")
                           if f"matrices_{p}" in h)
            if checksum and not verify_checksum(h, chunks=not digested):
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
            if verify and digested:
                if table.chunk is None:
                    raise TableError(f"{path}: chunk digests on matrices not chunked by frequency: delete it and recompute")
                table._digests = {p: h[f"matrices_{p}_chunk_sha256"][()] for p in ("real", "imag")}
                grid = -(-len(dofs) // table.chunk)
                if any(d.shape != (f.size, grid, grid, 32) for d in table._digests.values()):
                    raise TableError(f"{path}: chunk digests of the wrong shape: delete it and recompute")
                table._checked = np.zeros((f.size, grid, grid), dtype=bool)
            elif verify:
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

    def _region(self, h, freqs: slice, rows: slice, cols: slice) -> np.ndarray:
        """K[freqs, rows, cols] (unit-step slices within the matrix), complex, its chunks not yet
        checked checked against their digests as they are read (both parts; DamagedTableError)."""
        ks, r, c = (range(*s.indices(n)) for s, n in zip((freqs, rows, cols), (self.frequencies_hz.size,
                                                                                self.n_dof, self.n_dof)))
        K = np.empty((len(ks), len(r), len(c)), complex)
        e = self.chunk
        todo = None
        if self._checked is not None and len(ks) and len(r) and len(c):
            chunks = np.s_[ks.start:ks.stop, r.start // e:-(-r.stop // e), c.start // e:-(-c.stop // e)]
            if not self._checked[chunks].all():
                todo = chunks
        if todo is None:
            sel = np.s_[ks.start:ks.stop, r.start:r.stop, c.start:c.stop]
            K.real = h["matrices_real"][sel]
            K.imag = h["matrices_imag"][sel]
            return K
        # the chunks the region touches, read whole and checked, the region cut from them
        r0, r1 = todo[1].start * e, min(self.n_dof, todo[1].stop * e)
        c0, c1 = todo[2].start * e, min(self.n_dof, todo[2].stop * e)
        for part in ("real", "imag"):
            data = h[f"matrices_{part}"][ks.start:ks.stop, r0:r1, c0:c1]
            digests = self._digests[part]
            for t, i, j in zip(*np.nonzero(~self._checked[todo])):
                k, bi, bj = ks.start + t, todo[1].start + i, todo[2].start + j
                block = data[t, bi * e - r0:(bi + 1) * e - r0, bj * e - c0:(bj + 1) * e - c0]
                if chunk_digest(block) != bytes(digests[k, bi, bj]):
                    raise DamagedTableError(
                        f"{self.path}: the chunk of matrices_{part} at frequency {k}, rows {bi * e}.., columns "
                        f"{bj * e}.. does not match its digest (the file changed since it was written): "
                        "delete it and recompute")
            setattr(K, part, data[:, r.start - r0:r.stop - r0, c.start - c0:c.stop - c0])
        self._checked[todo] = True
        return K

    def block(self, rows: slice, cols: slice) -> np.ndarray:
        """K[:, rows, cols] across all frequencies, complex (F, r, c): one read per part (a chunk read
        for the first time is checked against its digest: a block of whole chunks, as ``blocks``
        gives them, reads nothing more)."""
        import h5py
        with h5py.File(self.path, "r") as h:
            return self._region(h, slice(None), rows, cols)

    def frequency(self, k: int) -> np.ndarray:
        """K(f_k), complex (n, n)."""
        import h5py
        k = range(self.frequencies_hz.size)[k]
        with h5py.File(self.path, "r") as h:
            return self._region(h, slice(k, k + 1), slice(None), slice(None))[0]

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

"""Files the project writes and reads back: atomic writes, output paths, data checksums.

Atomic writes. Two processes writing the same file name interleave their writes, and a process
killed (or interrupted) mid-write leaves a truncated file. Every file is therefore written
under a unique temporary name in the target folder and renamed onto the target only once
complete (``os.replace`` is atomic on one file system): a reader sees the old file or the new
one, never a mix, and concurrent writers each succeed (the last one wins).

Orphans, full disks, Ctrl-C. A temporary is named ``.<name>.<host>-<pid>.<random>.tmp``; one
left by a process that died (kill -9, a crash) is removed by the next write to the same file
(``sweep_orphans``, once per folder and process: its pid no longer runs on this machine). The several files of one output
folder (an export, a report) are written in a staging folder and moved in together
(``atomic_folder``). A file system that refuses the data (no space left, a quota, a file size
limit, an I/O error) raises ``OutputWriteError`` naming the path and the space left, nothing
written; HDF5 files are made in memory and written in one write of this process
(``hdf5_output``), so that HDF5 never meets the error itself. The rename and the clean-up are
held against Ctrl-C (``uplift_common.interrupts``), and ``committed()`` lists what was renamed
into place (what an interrupted command did write, whole).

Output paths. A rename replaces whatever the name points at: a device, a FIFO or a socket
would be destroyed and a symlink turned into a plain file. ``output_target`` refuses a path
that exists and is not a regular file (``OutputPathError``), and follows a symlink: the file
is written atomically at the link's target and the link survives.

Checksums. Every HDF5 file the project reads back (results, ensembles, cache entries,
impedance tables, fits) carries a SHA-256 of its whole content (every group, dataset and
attribute, in name order) as its root attribute ``"sha256"``; ``require_checksum`` refuses
one whose content no longer matches (``ChangedFileError``: it changed since it was written).
A writer that fills its file through ``RecordedFile`` (the results file) has the digest taken
from what it wrote, not read back (the same digest; whatever the record cannot reproduce is read
back).
A dataset too large to read back for its writer's checksum (an impedance table written one
frequency at a time, ``soil_impedance.blocked``) may carry the SHA-256 of each of its chunks
instead (``CHUNK_DIGESTS_ATTR``, ``chunk_digest``): the whole-file checksum then covers the
digests, not the data, and a verification checks each chunk against its digest (all of them,
or, with ``chunks=False``, none: the reader checks each chunk when it reads it, as an
impedance table read in blocks does).

Usage::

    with hdf5_output(path) as f:             # in memory, then atomic_output
        ...                                  # write datasets and attributes
        stamp_checksum(f)
    with atomic_output(path) as tmp:         # any other file
        tmp.write_text(text)
    with h5py.File(path, "r") as f:
        require_checksum(f, path)            # ChangedFileError if it changed
    with atomic_update(path) as copy:        # append to a stamped file: a verified copy in
        ds.to_netcdf(copy, mode="a", group="extra", engine="h5netcdf")
                                             # memory, re-stamped and written atomically on exit
"""
from __future__ import annotations

import contextlib
import errno
import hashlib
import io
import os
import re
import shutil
import stat
import tempfile
from pathlib import Path

import h5py
import numpy as np
from uplift_common import interrupts
from uplift_common.cache_folder import size_text
from uplift_common.errors import OutputWriteError, UserInputError

CHECKSUM_ATTR = "sha256"
_CHUNK_BYTES = 1 << 26          # datasets are hashed in slabs of about 64 MiB along axis 0
_READ_BYTES = 1 << 22           # a dataset read in place (``into``) is read about 4 MiB at a time
#: attribute of a chunked dataset naming the uint8 dataset beside it (same group) that holds the
#: SHA-256 of each of its chunks, shape (chunks along each axis..., 32): ``chunk_digest``
CHUNK_DIGESTS_ATTR = "chunk_sha256"
_UMASK = os.umask(0o022)
os.umask(_UMASK)


class OutputPathError(UserInputError):
    """An output path that cannot be written as a file: it exists and is not a regular file
    (a device, a FIFO, a socket, a folder), or it lies under a file."""


class OutputFolderError(FileNotFoundError, OutputPathError):
    """The folder of an output file does not exist (the caller decides whether to create it)."""


class ChangedFileError(UserInputError):
    """A file the project wrote whose content no longer matches its checksum (or that has
    none): it changed since it was written, and nothing is read from it."""


# ---- output paths and atomic writes -------------------------------------------------------------

def output_target(path) -> Path:
    """The file to write for the output ``path``: ``path`` itself, or the target of the symlink
    ``path`` (followed to the end). Raises OutputPathError when the path (or the link's target)
    exists and is not a regular file, or when a folder on its way is a file."""
    path = Path(path)
    target = Path(os.path.realpath(path)) if path.is_symlink() else path
    try:
        mode = os.stat(target).st_mode
    except FileNotFoundError:
        return target
    except NotADirectoryError:
        raise OutputPathError(f"cannot write {str(path)!r}: a folder on its way is a file; "
                              "choose another path") from None
    except OSError as exc:
        raise OutputPathError(f"cannot write {str(path)!r}: {exc.strerror}; choose another path") from None
    if stat.S_ISREG(mode):
        return target
    what = {stat.S_IFDIR: "a folder", stat.S_IFCHR: "a character device", stat.S_IFBLK: "a block device",
            stat.S_IFIFO: "a FIFO (named pipe)", stat.S_IFSOCK: "a socket"}.get(stat.S_IFMT(mode), "not a regular file")
    via = f" (the target of the link {str(path)!r})" if target != path else ""
    raise OutputPathError(f"output {str(target)!r}{via} is {what}, not a regular file: it would be replaced; "
                          "give the path of a new or regular file")


@contextlib.contextmanager
def atomic_output(path):
    """Yield a unique temporary ``Path`` next to the file to write; the caller writes it completely.

    The file to write is ``output_target(path)`` (a symlink is followed; a path that is not a
    regular file raises OutputPathError). On normal exit the temporary file is flushed to disk
    (fsync), renamed onto the target (``os.replace``, atomic) and the folder entry is synced; on
    any exception, KeyboardInterrupt included, it is removed and the exception re-raised: the old
    file stays intact until the new one is complete, and concurrent writers never share a
    temporary name (``temporary_name``: host, pid and a random suffix). The rename and the
    removal are held against Ctrl-C (``uplift_common.interrupts.held``: a SIGINT there is raised
    after them). Temporaries of the same target left by a process that died (kill -9, a power
    cut) are removed first (``sweep_orphans``, once per folder and process). A file system that refuses the data (full,
    quota, file size limit, I/O error) raises OutputWriteError naming the path. Raises
    OutputFolderError if the folder is missing.
    """
    target = output_target(path)
    folder = target.parent
    if not folder.is_dir():
        raise OutputFolderError(f"cannot write {path}: folder {folder} does not exist "
                                "(create it first or choose another path)")
    _sweep_once(folder)
    tmp = None
    try:
        with interrupts.held():                 # created and recorded at once: never left unnamed
            fd, name = tempfile.mkstemp(dir=folder, prefix=_temporary_prefix(target.name), suffix=".tmp")
            os.close(fd)
            tmp = Path(name)
        yield tmp
        os.chmod(tmp, 0o666 & ~_UMASK)          # mkstemp makes 0600; keep the usual mode
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        output_target(path)                     # still a regular file (or absent) at the rename
        with interrupts.held():
            os.replace(tmp, target)
            interrupts.note_committed(target)
            tmp = None
    except BaseException as exc:
        with interrupts.held():
            if tmp is not None:
                with contextlib.suppress(OSError):
                    tmp.unlink()
        refused = _refused(exc)
        if refused is not None:
            raise OutputWriteError(_refusal_message(path, folder, refused, exc), refused,
                                   _reason(folder, refused)) from None
        raise
    _fsync_folder(folder)


#: errno values of a file system that refuses data (not a bad path: those are refused before)
REFUSED_ERRNOS = interrupts.REFUSED_ERRNOS
committed = interrupts.committed


#: how HDF5 reports the errno of a failed write in its messages (h5py raises them as OSError
#: or RuntimeError without an errno attribute): "file write failed: ..., errno = 28, ..."
_HDF5_ERRNO = re.compile(r"errno = (\d+)")


def _refused(exc):
    """The errno of REFUSED_ERRNOS behind ``exc`` (itself or an exception it was raised from or
    while handling; an OSError's errno, or the errno an HDF5 message quotes), or None."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        if isinstance(exc, (OutputWriteError, KeyboardInterrupt)):
            return None
        if isinstance(exc, OSError) and exc.errno in REFUSED_ERRNOS:
            return exc.errno
        if isinstance(exc, (OSError, RuntimeError)):
            quoted = [int(n) for n in _HDF5_ERRNO.findall(str(exc)) if int(n) in REFUSED_ERRNOS]
            if quoted:
                return quoted[0]
        exc = exc.__cause__ or exc.__context__
    return None


def _reason(folder: Path, code: int) -> str:
    """The refusal in words and the space left on the folder's file system (when known)."""
    free = ""
    with contextlib.suppress(OSError):
        st = os.statvfs(folder)
        free = f"; {size_text(st.f_bavail * st.f_frsize)} free on its file system"
    return f"{REFUSED_ERRNOS[code]} (errno {errno.errorcode.get(code, code)}){free}"


def _refusal_message(path, folder: Path, code: int, exc, left: str = "") -> str:
    left = left or f"a previous {Path(path).name} is left as it was"
    return (f"cannot write {str(path)!r}: {_reason(folder, code)}; free some space (or choose another path) and "
            f"run the command again: nothing was written, {left}")


# ---- temporaries and the orphans of dead processes ----------------------------------------------

def _host_name() -> str:
    """This machine's name, as ``socket.gethostname()`` gives it (on POSIX the kernel's node name,
    ``os.uname``: the socket module is not loaded for it)."""
    if hasattr(os, "uname"):
        return os.uname().nodename
    import socket
    return socket.gethostname()


#: this machine, in temporary names (a folder shared by several machines: a pid means nothing on
#: another one, and its temporaries are never swept from here)
HOST = hashlib.sha256(_host_name().encode()).hexdigest()[:8]
_TEMPORARY = re.compile(r"^\.(?P<name>.+)\.(?:(?P<host>[0-9a-f]{8})-)?(?P<pid>\d+)\.[A-Za-z0-9_]+\.tmp$")


_SWEPT: set = set()


def _sweep_once(folder) -> None:
    """``sweep_orphans(folder)``, once per folder and process (the orphans of dead processes do
    not come back; an ensemble writes thousands of cells into one folder)."""
    key = os.path.realpath(folder)
    if key not in _SWEPT:
        _SWEPT.add(key)
        sweep_orphans(folder)


def _temporary_prefix(name: str) -> str:
    return f".{name}.{HOST}-{os.getpid()}."


def temporary_name(name: str) -> str:
    """A unique name for a temporary of the file (or folder) ``name``, hidden, that
    ``sweep_orphans`` removes once this process is gone: ``.<name>.<host>-<pid>.<random>.tmp``."""
    return f"{_temporary_prefix(name)}{os.urandom(6).hex()}.tmp"


def _alive(pid: int) -> bool:
    """Whether process ``pid`` may be running (True when it cannot be told)."""
    if pid == os.getpid():
        return True
    if os.name == "nt":                          # os.kill(pid, 0) would terminate it there
        try:
            import psutil  # not everywhere: only Windows needs it here
        except ImportError:
            return True
        return psutil.pid_exists(pid)
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, OSError):
        return True                             # another user's process, or cannot tell: keep it
    return True


def sweep_orphans(folder, name: str | None = None) -> list:
    """Remove from ``folder`` the temporaries (``temporary_name``) of ``name`` (None: of any
    name) left by a process of this machine that is no longer running (killed, crashed); return
    their paths. The older form without the host (``.<name>.<pid>.<random>.tmp``, written before)
    is removed as well when it is of ``name``, or (``name`` None) when the file it was for
    exists beside it. A temporary whose process runs (or may: the pid of another user) is kept;
    so is one of another machine. Errors are ignored (best effort: the next command tries
    again)."""
    removed = []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed
    for entry in entries:
        m = _TEMPORARY.match(entry.name)
        if m is None or (name is not None and m["name"] != name) or m["host"] not in (None, HOST):
            continue
        if m["host"] is None and name is None and not os.path.lexists(os.path.join(folder, m["name"])):
            continue
        if _alive(int(m["pid"])):
            continue
        try:
            if entry.is_dir(follow_symlinks=False):
                shutil.rmtree(entry.path)
            else:
                os.unlink(entry.path)
        except OSError:
            continue
        removed.append(Path(entry.path))
    return removed


@contextlib.contextmanager
def atomic_folder(folder):
    """Several files of one folder written as one output: yield a staging folder (hidden, inside
    ``folder``, which is made if missing); the caller writes its files there under their final
    names. On normal exit each file is flushed to disk and renamed into ``folder`` (a symlink in
    ``folder`` is followed; each file is whole, old or new) and the staging folder removed; on
    any exception, KeyboardInterrupt included, the staging folder is removed (and ``folder``, if
    this call made it), nothing in ``folder`` having changed. Staging folders of dead processes
    are swept first (``sweep_orphans``); a file system that refuses the data raises
    OutputWriteError naming the folder."""
    folder = Path(folder)
    made = []
    for parent in [*reversed(folder.absolute().parents), folder.absolute()]:
        if not parent.exists():
            made.append(parent)
    stage = None
    try:
        folder.mkdir(parents=True, exist_ok=True)
        _sweep_once(folder)
        with interrupts.held():
            stage = folder / temporary_name("stage")
            stage.mkdir()
        yield stage
        names = sorted(p.name for p in stage.iterdir())
        for name in names:
            fd = os.open(stage / name, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
            output_target(folder / name)        # still a regular file (or absent) at the rename
        with interrupts.held():
            for name in names:
                target = output_target(folder / name)
                os.replace(stage / name, target)
                interrupts.note_committed(target)
            shutil.rmtree(stage, ignore_errors=True)
            stage = None
    except BaseException as exc:
        with interrupts.held():
            if stage is not None:
                shutil.rmtree(stage, ignore_errors=True)
            for parent in reversed(made):
                with contextlib.suppress(OSError):
                    parent.rmdir()              # only if empty: what this call made
        refused = exc.errno if isinstance(exc, OutputWriteError) else _refused(exc)   # a file of the stage's
        if refused is not None:
            where = folder.parent if made else folder
            raise OutputWriteError(_refusal_message(folder, where, refused, exc, "the files in "
                                                    f"{str(folder)!r} are left as they were"), refused,
                                   _reason(where, refused)) from None
        raise
    _fsync_folder(folder)


@contextlib.contextmanager
def hdf5_output(path):
    """Yield an ``h5py.File`` open for writing in memory (HDF5's core driver, no backing store);
    on normal exit its image is written to ``path`` in one write of this process
    (``write_image``: atomically, ``atomic_output``). HDF5 itself never writes to the disk: a
    disk that fills raises a clean OutputWriteError here, whereas an HDF5 file whose writes fail
    leaves the library in a broken state (errors printed as objects are freed, then a crash at
    the process's exit). The caller stamps the checksum last (``stamp_checksum``), as usual."""
    f = h5py.File(f"uplift-in-memory-{os.getpid()}-{os.urandom(8).hex()}.h5", "w", driver="core",
                  backing_store=False)
    try:
        yield f
        f.flush()
        image = f.id.get_file_image()
    finally:
        f.close()
    write_image(path, image)


def write_image(path, data) -> Path:
    """Write the bytes ``data`` (e.g. an HDF5 file image made in memory) to ``path`` atomically
    (``atomic_output``); returns ``path``. A refusal (OutputWriteError) says the space needed."""
    try:
        with atomic_output(path) as tmp, open(tmp, "wb") as out:
            out.write(data)
    except OutputWriteError as exc:
        need = f"{size_text(len(data))} needed"
        text, reason = str(exc), exc.reason
        if "free on its file system" in text:
            text = text.replace("free on its file system", f"free on its file system, {need}", 1)
            reason = reason.replace("free on its file system", f"free on its file system, {need}", 1)
        raise OutputWriteError(text, exc.errno, reason) from None
    return Path(path)


def save_figure(fig, path, **savefig) -> Path:
    """Write the matplotlib figure ``fig`` to ``path`` atomically (``atomic_output``: a full
    disk or a Ctrl-C leaves the old image), in the format of the path's suffix (PNG without
    one); ``savefig``: matplotlib's options (dpi, ...). Returns ``path``."""
    fmt = Path(path).suffix[1:].lower() or "png"
    with atomic_output(path) as tmp:
        fig.savefig(tmp, format=fmt, **savefig)
    return Path(path)


@contextlib.contextmanager
def atomic_update(path):
    """Append to the stamped HDF5 file ``path``: yield a copy of it in memory (``io.BytesIO``)
    for the caller to modify (``h5py.File(copy, "r+")``, xarray ``to_netcdf(copy, mode="a",
    engine="h5netcdf")``), then re-stamp its checksum and write it onto ``path`` atomically
    (``write_image``: HDF5 never writes to the disk itself, ``hdf5_output``'s reason). The file
    is verified first (ChangedFileError)."""
    path = Path(path)
    with h5py.File(path, "r") as f:
        require_checksum(f, path)
    copy = io.BytesIO(output_target(path).read_bytes())
    yield copy
    stamp_file(copy)
    write_image(path, copy.getbuffer())


def _fsync_folder(folder) -> None:
    """Make the rename durable (best effort: not every platform can open a folder)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


# ---- checksums ----------------------------------------------------------------------------------

def _update_value(h, value, f=None) -> None:
    """Feed an attribute or dataset value (dtype, shape, bytes) into hash ``h``; object
    references are hashed by the name of the object they point at in ``f`` (their bytes are
    addresses), compound values field by field."""
    if isinstance(value, h5py.Reference):
        try:                                    # an object unlinked since (e.g. a replaced group) has no name
            name = (f[value].name if value and f is not None else "") or "(unlinked)"
        except (KeyError, ValueError):
            name = "(dangling)"
        h.update(b"ref " + name.encode())
        return
    a = np.asarray(value)
    h.update(f"{a.shape}".encode())
    if a.dtype.names:                           # compound (e.g. netCDF's REFERENCE_LIST)
        for field in a.dtype.names:
            h.update(b"field " + field.encode())
            _update_value(h, a[field], f)
    elif a.dtype.kind in "OSU":                 # strings (fixed or variable length), objects
        h.update(b"str")
        for x in a.reshape(-1):
            if isinstance(x, (h5py.Reference, np.ndarray)):
                _update_value(h, x, f)
                continue
            b = x.encode() if isinstance(x, str) else bytes(x)
            h.update(len(b).to_bytes(8, "little") + b)
    else:
        h.update(a.dtype.str.encode())
        h.update(np.ascontiguousarray(a).reshape(-1).view(np.uint8))     # the bytes, not a copy of them


def chunk_digest(a) -> bytes:
    """SHA-256 (32 bytes) of the chunk data ``a`` (the part of a chunk inside its dataset), in C
    order, as the dataset's dtype gives it: what ``CHUNK_DIGESTS_ATTR``'s dataset holds."""
    return hashlib.sha256(np.ascontiguousarray(a).reshape(-1).view(np.uint8)).digest()


def chunk_digests(ds):
    """The digests dataset of the chunk-digested dataset ``ds`` (``CHUNK_DIGESTS_ATTR``), or None."""
    name = ds.attrs.get(CHUNK_DIGESTS_ATTR)
    if name is None:
        return None
    return ds.parent[name.decode() if isinstance(name, bytes) else str(name)]


def _check_chunks(ds, data=None) -> None:
    """Check every chunk of the chunk-digested dataset ``ds`` against its digest, reading it slab of
    chunks by slab along axis 0 (or from ``data``, its content already read); ValueError if one differs."""
    digests = chunk_digests(ds)[()]
    edge = ds.chunks
    grid = tuple(-(-n // c) for n, c in zip(ds.shape, edge))
    if digests.shape != grid + (32,):
        raise ValueError(f"{ds.name}: chunk digests of shape {digests.shape}, expected {grid + (32,)}")
    for i in range(grid[0]):
        rows = slice(i * edge[0], min(ds.shape[0], (i + 1) * edge[0]))
        slab = ds[rows] if data is None else data[rows]
        for index in np.ndindex(*grid[1:]):
            sel = tuple(slice(j * c, (j + 1) * c) for j, c in zip(index, edge[1:]))
            if chunk_digest(np.asarray(slab[(slice(None),) + sel], dtype=ds.dtype)) != bytes(digests[(i,) + index]):
                raise ValueError(f"{ds.name}: chunk {(i,) + index} does not match its digest")


def _update_dataset(h, ds, f, keep=None, into=None, chunks=True) -> None:
    """Feed dataset ``ds`` into ``h`` in slabs along axis 0; with ``keep`` (a dict) it is read
    whole, once, hashed slab by slab from memory (the same digest) and kept as ``keep[ds.name]``;
    with ``into`` as well, a numeric dataset for which ``into(ds)`` gives an array (ds's shape,
    any dtype and strides: a view) is read into it a few rows at a time through a small buffer
    (the same digest; no copy of the dataset made) and that array is kept. A chunk-digested
    dataset (``CHUNK_DIGESTS_ATTR``) feeds its dtype and shape only (its digests are another
    dataset, fed as any); its chunks are checked against them unless ``chunks`` is False."""
    h.update(f"dataset {ds.dtype.str} {ds.shape}".encode())
    if ds.shape is None:                        # null dataspace
        return
    if ds.chunks is not None and CHUNK_DIGESTS_ATTR in ds.attrs:
        h.update(b" chunk-digested")
        data = None
        if keep is not None:
            data = into(ds) if into is not None else None
            if data is not None and data.shape == ds.shape:
                step = max(1, _READ_BYTES // max(1, ds.dtype.itemsize * ds.size // ds.shape[0]))
                for i in range(0, ds.shape[0], step):
                    data[i:i + step] = ds[i:i + step]
            else:
                data = ds[()]
            keep[ds.name] = data
        if chunks:
            _check_chunks(ds, data)
        return
    numeric = ds.ndim > 0 and ds.size > 0 and ds.dtype.kind in "fiuc" and not ds.dtype.names
    dest = into(ds) if keep is not None and into is not None and numeric else None
    if dest is not None:
        if dest.shape != ds.shape:
            raise ValueError(f"into gave an array of shape {dest.shape} for the dataset {ds.name} {ds.shape}")
        _read_into(h, ds, dest)
        keep[ds.name] = dest
        return
    whole = ds[()] if keep is not None else None
    if keep is not None:
        keep[ds.name] = whole
    if ds.ndim == 0 or ds.size == 0:
        _update_value(h, ds[()] if whole is None else whole, f)
        return
    if whole is not None:
        _update_slabs(h, whole, ds.dtype.itemsize, f)
        return
    row = max(1, ds.dtype.itemsize * ds.size // ds.shape[0])
    step = max(1, _CHUNK_BYTES // row)
    for i in range(0, ds.shape[0], step):
        _update_value(h, ds[i:i + step], f)


def _update_slabs(h, a, itemsize: int, f=None) -> None:
    """The slabs of ``_update_dataset`` (along axis 0, about _CHUNK_BYTES each) of the array
    ``a`` in memory, a dataset's value of item size ``itemsize`` (its stored type's, e.g. 8
    for a variable-length string) and of at least one dimension and one element."""
    row = max(1, itemsize * a.size // a.shape[0])
    step = max(1, _CHUNK_BYTES // row)
    for i in range(0, a.shape[0], step):
        _update_value(h, a[i:i + step], f)


def _read_into(h, ds, dest) -> None:
    """Hash the numeric dataset ``ds`` as ``_update_dataset`` does (its slabs: shape, dtype,
    bytes) while reading it into ``dest``, _READ_BYTES at a time through one buffer."""
    row = max(1, ds.dtype.itemsize * ds.size // ds.shape[0])
    step = max(1, _CHUNK_BYTES // row)
    sub = max(1, min(step, _READ_BYTES // row))
    buf = np.empty((min(sub, ds.shape[0]),) + ds.shape[1:], ds.dtype)
    for i in range(0, ds.shape[0], step):
        rows = min(step, ds.shape[0] - i)
        h.update(f"{(rows,) + ds.shape[1:]}".encode())         # as _update_value on the slab
        h.update(buf.dtype.str.encode())
        for j in range(i, i + rows, sub):
            b = buf[:min(sub, i + rows - j)]
            ds.read_direct(b, np.s_[j:j + b.shape[0]])
            h.update(b.reshape(-1).view(np.uint8))
            dest[j:j + b.shape[0]] = b


class ComplexPairs:
    """``into`` for ``checksum``: a complex array stored as two float datasets ``<name>_real``
    and ``<name>_imag`` (the same shape, in one group) is read straight into one complex array,
    kept as its two parts (views: ``keep["/<name>_real"].base`` is the array): no float copy
    of the data is made, nor a complex one by the caller."""

    def __init__(self):
        self._arrays = {}

    def __call__(self, ds):
        stem, _, part = ds.name.rpartition("_")
        if part not in ("real", "imag") or ds.dtype.kind != "f":
            return None
        K = self._arrays.get(stem)
        if K is None:
            K = self._arrays[stem] = np.empty(ds.shape, complex)
        return getattr(K, part) if K.shape == ds.shape else None


def _update_attrs(h, obj, f, skip=()) -> None:
    for key in sorted(obj.attrs):
        if key not in skip:
            h.update(b"attr " + key.encode() + b"\0")
            _update_value(h, obj.attrs[key], f)


def checksum(f: h5py.File, keep: dict | None = None, into=None, chunks: bool = True) -> str:
    """SHA-256 (hex) of every group, dataset and attribute of ``f`` in name order, except the
    root checksum attribute. keep: a dict filled with every dataset's value as it was read and
    hashed (``{"/name": ndarray}``), for a caller that would otherwise read it again; into
    (with keep): ``into(ds)`` -> an array to read the numeric dataset ``ds`` into (a view of
    the caller's own, of ds's shape), or None (read it as usual); the digest is the same.

    The objects are listed by one walk of HDF5 (``h5o.visit``, with each object's kind and
    attribute count), plain numeric datasets read with h5py's low-level calls
    (``_update_plain``), an object without attributes not opened for them: the digest of
    ``_checksum_by_objects`` (every object opened and read through h5py's objects, the
    reference the tests compare with), several times cheaper on a file of many small datasets.
    chunks: check the chunks of chunk-digested datasets (ValueError if one differs; False: not
    read: a reader checks each chunk it reads against its digest)."""
    found = {}
    try:
        h5py.h5o.visit(f.id, lambda n, info: found.__setitem__(n.decode(), (info.type, info.num_attrs)), info=True)
    except UnicodeDecodeError:                  # a name h5py would not decode either: its own walk
        return _checksum_by_objects(f, keep, into, chunks)
    found.pop(".", None)
    h = hashlib.sha256()
    _update_attrs(h, f, f, skip=(CHECKSUM_ATTR,))
    for name in sorted(found):
        kind, n_attrs = found[name]
        h.update(b"\0object " + name.encode() + b"\0")
        if kind == h5py.h5o.TYPE_GROUP:
            h.update(b"group")
        elif not (kind == h5py.h5o.TYPE_DATASET and into is None and _update_plain(h, f, name, keep)):
            obj = f[name]
            if isinstance(obj, h5py.Dataset):
                _update_dataset(h, obj, f, keep, into, chunks)
            else:
                h.update(b"group")
        if n_attrs:
            _update_attrs(h, f[name], f)
    return h.hexdigest()


def _checksum_by_objects(f: h5py.File, keep: dict | None = None, into=None, chunks: bool = True) -> str:
    """``checksum`` read object by object through h5py's high-level objects."""
    h = hashlib.sha256()
    _update_attrs(h, f, f, skip=(CHECKSUM_ATTR,))
    names = []
    f.visit(names.append)
    for name in sorted(names):
        obj = f[name]
        h.update(b"\0object " + name.encode() + b"\0")
        if isinstance(obj, h5py.Dataset):
            _update_dataset(h, obj, f, keep, into, chunks)
        else:
            h.update(b"group")
        _update_attrs(h, obj, f)
    return h.hexdigest()


def _update_plain(h, f, name: str, keep=None) -> bool:
    """``_update_dataset`` of a plain numeric dataset (integers, floats, complex numbers; a
    scalar, or an array of at least one element and at most _CHUNK_BYTES) through h5py's
    low-level calls, read whole (kept in ``keep`` as h5py reads it: a scalar as a numpy scalar):
    the same digest without h5py's per-object machinery, several times cheaper on a small
    dataset. False, nothing hashed, for any other dataset (a chunk-digested one among them)."""
    dsid = h5py.h5d.open(f.id, name.encode())
    if h5py.h5a.exists(dsid, CHUNK_DIGESTS_ATTR.encode()):
        return False
    dtype, shape = dsid.dtype, dsid.shape
    size = 0 if shape is None else 1            # None: a null dataspace
    for n in shape or ():
        size *= n
    if dtype.kind not in "iufc" or dtype.names or dtype.metadata or size == 0 or dtype.itemsize * size > _CHUNK_BYTES:
        return False
    a = np.empty(shape, dtype)
    dsid.read(h5py.h5s.ALL, h5py.h5s.ALL, a)
    h.update(f"dataset {dtype.str} {shape}".encode())
    if shape:
        _update_slabs(h, a, dtype.itemsize)
    else:
        _update_value(h, a)
    if keep is not None:
        keep["/" + name] = a if shape else a[()]
    return True


def stamp_checksum(f: h5py.File) -> str:
    """Compute the SHA-256 of the whole content of the open, writable file ``f`` (every dataset:
    name, dtype, shape, bytes; every attribute: name, value; in a deterministic order), store it
    as root attribute ``"sha256"`` and return it. Call it last, after every write."""
    if isinstance(f, RecordedFile):
        return f.stamp()
    f.flush()
    digest = checksum(f, chunks=False)          # a chunk-digested dataset's digests are its writer's
    f.attrs[CHECKSUM_ATTR] = digest
    return digest


def stamp_file(path) -> str:
    """Stamp the checksum of the HDF5 file ``path`` (or file-like object: an image in memory) in
    place (a file written by another library, e.g. xarray, before it is renamed into place) and
    return it."""
    with h5py.File(path, "r+") as f:
        return stamp_checksum(f)


def verify_checksum(f: h5py.File, keep: dict | None = None, into=None, chunks: bool = True) -> bool:
    """True if the root ``"sha256"`` attribute matches the content of ``f``; False when it is
    missing, different, or part of the file cannot be read. keep, into, chunks: as ``checksum``
    (chunks=False: the caller checks each chunk of a chunk-digested dataset as it reads it)."""
    stored = f.attrs.get(CHECKSUM_ATTR)
    if stored is None:
        return False
    if isinstance(stored, bytes):
        stored = stored.decode(errors="replace")
    try:
        return str(stored) == checksum(f, keep, into, chunks)
    except (OSError, KeyError, RuntimeError, ValueError, TypeError):
        return False


def require_checksum(f: h5py.File, path, remedy: str = "write it again", keep: dict | None = None,
                     into=None) -> None:
    """Raise ChangedFileError naming ``path`` unless ``f`` carries a checksum that matches its
    content; ``remedy`` says how to get a good file again. keep, into: as ``checksum``."""
    if CHECKSUM_ATTR not in f.attrs:
        raise ChangedFileError(f"{path} carries no checksum of its data (root attribute {CHECKSUM_ATTR!r}): "
                               f"it was not written by this version, or changed since it was written; {remedy}")
    if not verify_checksum(f, keep, into):
        raise ChangedFileError(f"{path} changed since it was written (its data no longer match its "
                               f"checksum): nothing is read from it; {remedy}")


# ---- the checksum of the content as it is written -----------------------------------------------

#: an attribute whose value is read back from the file when the checksum is computed (a type
#: whose stored form the record does not reproduce: bytes, bools, lists, NUL characters, ...)
_READ_BACK = object()
#: the methods of an h5py group or dataset that change a file in ways the record does not follow:
#: a RecordedFile that sees one called hashes the file as read back (``checksum``)
_UNRECORDED = frozenset({"create_dataset_like", "create_virtual_dataset", "require_group", "require_dataset",
                         "copy", "move", "build_virtual_dataset", "resize", "write_direct"})
#: the attributes HDF5's dimension scales write (recorded from make_scale and attach_scale)
_SCALE_ATTRS = frozenset({"CLASS", "NAME", "REFERENCE_LIST", "DIMENSION_LIST"})


class _Record:
    """What ``checksum`` reads of one object: its kind, its stored value (a dataset), its
    attributes, and the dimension-scale attributes HDF5 makes (CLASS, NAME, REFERENCE_LIST,
    DIMENSION_LIST); ``exact`` False: the object is read back from the file instead."""

    __slots__ = ("attrs", "data", "dims", "exact", "kind", "name", "refs", "scale")

    def __init__(self, name: str, kind: str):
        self.name, self.kind = name, kind
        self.data = None
        self.attrs = {}
        self.scale = None           # the NAME of a dimension scale (make_scale)
        self.refs = []              # a scale's REFERENCE_LIST: (dataset name, axis), in attachment order
        self.dims = None            # a dataset's DIMENSION_LIST: [scale names] per axis
        self.exact = True

    def attr_count(self) -> int:
        extra = (2 if self.scale is not None else 0) + (1 if self.refs else 0) + (1 if self.dims else 0)
        return len(self.attrs) + extra


def _attr_form(value):
    """The value ``checksum`` reads back of an attribute written as ``value`` (h5py's own
    conversion, for the types whose stored form is known), or _READ_BACK."""
    if isinstance(value, str):
        return value if "\0" not in value else _READ_BACK       # a vlen string ends at a NUL
    if isinstance(value, (bool, np.bool_)):
        return _READ_BACK
    if isinstance(value, (int, float, np.integer, np.floating, np.ndarray)):
        a = np.array(value)                                       # a copy: the value as it was
        if a.dtype.kind in "iuf" and not a.dtype.names and (a.ndim == 0 or a.size):
            return a
    return _READ_BACK


class RecordedFile:
    """An h5py file open for writing (``hdf5_output``'s) whose content is recorded as it is
    written, for ``stamp_checksum`` to hash without reading the file back.

    ``checksum`` reads every object and attribute back through h5py: on a results file (about 35
    objects and 140 attributes) that costs about ten times its SHA-256. A writer that makes its
    groups, datasets, attributes and dimension scales through this object (and the groups and
    datasets it returns: ``create_group``, ``create_dataset(name, data=...)``, ``attrs[key] =``,
    ``attrs.update``, ``make_scale``, ``dims[axis].attach_scale``) has each recorded in the form
    ``checksum`` reads it back: a numeric or string dataset as its array (a copy: the caller may
    change its own afterwards), a string or number attribute as its value, the attributes HDF5's
    dimension scales add (CLASS, NAME, REFERENCE_LIST, DIMENSION_LIST) from the calls made.
    ``stamp()`` hashes the record in ``checksum``'s order and gives the same digest. Whatever the
    record does not reproduce is read back from the file: an attribute of another type (bytes,
    bool, a list), a dataset made with ``shape``, ``dtype`` or options, an object changed in
    place; the whole file when the record and the file differ in their objects or attribute
    counts (one listing by HDF5, ``h5o.visit``) or when a call the record does not follow was
    made (``_UNRECORDED``). ``read_back`` counts the objects so read (0: none), for the tests.

    Reading goes to the h5py objects: ``g[name]``, ``name in g``, ``g.attrs[key]``."""

    def __init__(self, f: h5py.File):
        self.file = f
        self.root = _Record("", "group")
        self.objects: dict = {}     # name relative to the root -> _Record
        self.made: dict = {}        # name relative to the root -> the h5py object made (not looked up again)
        self.exact = True
        self.read_back = 0
        self._group = _RecordedGroup(f, self.root, self)

    def __getattr__(self, name):
        return getattr(self._group, name)

    def __getitem__(self, name):
        return self._group[name]

    def __contains__(self, name):
        return name in self.file

    def __iter__(self):
        return iter(self.file)

    def __len__(self):
        return len(self.file)

    @property
    def attrs(self):
        return self._group.attrs

    def _child(self, parent: _Record, name: str, kind: str) -> _Record:
        if "/" in name or name in ("", ".", ".."):
            self.exact = False      # intermediate groups, absolute paths: not followed
        rec = _Record(f"{parent.name}/{name}" if parent.name else name, kind)
        if rec.name in self.objects:
            self.exact = False
        self.objects[rec.name] = rec
        return rec

    def _matches_file(self) -> bool:
        """Whether the file holds exactly the recorded objects, each with its recorded number of
        attributes (the root's without the checksum attribute)."""
        if not self.exact:
            return False
        found = {}
        h5py.h5o.visit(self.file.id, lambda n, info: found.__setitem__(n.decode("utf-8", "replace"),
                                                                       (info.type, info.num_attrs)), info=True)
        kinds = {"group": h5py.h5o.TYPE_GROUP, "dataset": h5py.h5o.TYPE_DATASET}
        if len(found) != len(self.objects):
            return False
        for name, rec in self.objects.items():
            if found.get(name) != (kinds[rec.kind], rec.attr_count()):
                return False
        root = h5py.h5o.get_info(self.file.id).num_attrs
        return root - (CHECKSUM_ATTR in self.file.attrs) == len(self.root.attrs) - (CHECKSUM_ATTR in self.root.attrs)

    def digest(self) -> str:
        """``checksum(self.file)``, from the record (read back where it falls short)."""
        self.file.flush()
        if not self._matches_file():
            self.read_back = len(self.objects) + 1
            return checksum(self.file)
        f = self.file
        h = hashlib.sha256()
        self._update_attrs(h, self.root, f, skip=(CHECKSUM_ATTR,))
        for name in sorted(self.objects):
            rec = self.objects[name]
            h.update(b"\0object " + name.encode() + b"\0")
            if not rec.exact:
                self.read_back += 1
                obj = f[name]
                if isinstance(obj, h5py.Dataset):
                    _update_dataset(h, obj, f)
                else:
                    h.update(b"group")
                _update_attrs(h, obj, f)
                continue
            if rec.kind == "dataset":
                a, itemsize = rec.data
                h.update(f"dataset {a.dtype.str} {a.shape}".encode())
                if a.ndim == 0 or a.size == 0:
                    _update_value(h, a, f)
                else:
                    _update_slabs(h, a, itemsize, f)
            else:
                h.update(b"group")
            self._update_attrs(h, rec, f)
        return h.hexdigest()

    def _update_attrs(self, h, rec: _Record, f, skip=()) -> None:
        """``_update_attrs`` of the recorded object ``rec``: its attributes and its dimension
        scales', in name order, as h5py reads them back."""
        forms = dict(rec.attrs)
        if rec.scale is not None:
            forms["CLASS"] = np.bytes_(b"DIMENSION_SCALE")
            forms["NAME"] = np.bytes_(rec.scale.encode())
        if rec.refs:
            forms["REFERENCE_LIST"] = rec.refs
        if rec.dims:
            forms["DIMENSION_LIST"] = rec.dims
        for key in sorted(forms):
            if key in skip:
                continue
            h.update(b"attr " + key.encode() + b"\0")
            value = forms[key]
            if key == "REFERENCE_LIST" and value is rec.refs:
                h.update(f"{(len(value),)}".encode() + b"field dataset")     # compound (dataset, dimension)
                _update_names(h, [name for name, _ in value])
                h.update(b"field dimension")
                _update_value(h, np.array([axis for _, axis in value], "<u4"))
            elif key == "DIMENSION_LIST" and value is rec.dims:
                h.update(f"{(len(value),)}".encode() + b"str")               # a vlen of references per axis
                for names in value:
                    _update_names(h, names)
            elif value is _READ_BACK:
                self.read_back += 1
                obj = f[rec.name] if rec.name else f
                _update_value(h, obj.attrs[key], f)
            else:
                _update_value(h, value, f)

    def stamp(self) -> str:
        """Store the digest as the root attribute ``"sha256"`` and return it (``stamp_checksum``)."""
        digest = self.digest()
        self.file.attrs[CHECKSUM_ATTR] = digest
        return digest


def _update_names(h, names) -> None:
    """``_update_value`` of an array of object references to the objects ``names`` (relative to
    the root): as ``checksum`` hashes references, by the absolute names they point at."""
    h.update(f"{(len(names),)}".encode() + b"str")
    for name in names:
        h.update(b"ref /" + name.encode())


class _Recorded:
    """An h5py group or dataset of a RecordedFile: writes recorded, reads passed through."""

    def __init__(self, obj, rec: _Record, owner: RecordedFile):
        object.__setattr__(self, "_obj", obj)
        object.__setattr__(self, "_rec", rec)
        object.__setattr__(self, "_owner", owner)

    def __getattr__(self, name):
        if name in _UNRECORDED:
            self._owner.exact = False
        return getattr(self._obj, name)

    def __setattr__(self, name, value):
        self._owner.exact = False
        setattr(self._obj, name, value)

    @property
    def name(self) -> str:
        return "/" + self._rec.name

    @property
    def attrs(self):
        return _RecordedAttrs(self._obj.attrs, self._rec)

    def __contains__(self, name):
        return name in self._obj

    def __iter__(self):
        return iter(self._obj)

    def __len__(self):
        return len(self._obj)

    def __setitem__(self, key, value):
        if isinstance(self, _RecordedDataset):
            self._rec.exact = False     # the data changed in place: read back
        else:
            self._owner.exact = False   # a new link or dataset: not followed
        self._obj[key] = value

    def __delitem__(self, key):
        self._owner.exact = False
        del self._obj[key]


class _RecordedGroup(_Recorded):

    def create_group(self, name, track_order=None):
        rec = self._owner._child(self._rec, name, "group")
        g = self._owner.made[rec.name] = self._obj.create_group(name, track_order=track_order)
        return _RecordedGroup(g, rec, self._owner)

    def create_dataset(self, name, shape=None, dtype=None, data=None, **kwds):
        ds = self._obj.create_dataset(name, shape, dtype, data, **kwds)
        rec = self._owner._child(self._rec, name, "dataset")
        self._owner.made[rec.name] = ds
        rec.exact = False
        if shape is None and dtype is None and data is not None and not kwds:
            a = np.array(data)                  # a copy: the caller may change its array afterwards
            stored = ds.dtype
            numbers = a.dtype.kind in "iufc" and not a.dtype.names and a.dtype == stored
            strings = (a.dtype.kind == "O" and a.ndim > 0          # vlen UTF-8, read back as their bytes
                       and getattr(h5py.check_string_dtype(stored), "encoding", None) == "utf-8"
                       and all(isinstance(x, str) and "\0" not in x for x in a.reshape(-1)))
            if (numbers or strings) and a.shape == ds.shape:
                rec.data, rec.exact = (a, stored.itemsize), True
        return _RecordedDataset(ds, rec, self._owner)

    def __getitem__(self, name):
        key = name.strip("/") if name.startswith("/") or not self._rec.name else f"{self._rec.name}/{name}"
        rec = self._owner.objects.get(key)
        if rec is None:
            obj = self._obj[name]
            self._owner.exact = False   # an object the record does not know: its writes are not followed
            return obj
        cls = _RecordedGroup if rec.kind == "group" else _RecordedDataset
        # the object made here (a dimension scale's, looked up for each of its variables), while no
        # change the record does not follow (a deletion, a move) was made
        obj = self._owner.made.get(key) if self._owner.exact else None
        return cls(self._obj[name] if obj is None else obj, rec, self._owner)


class _RecordedDataset(_Recorded):

    def __getitem__(self, key):
        return self._obj[key]

    def make_scale(self, name: str = ""):
        self._obj.make_scale(name)
        if self._rec.scale is not None or not name or not name.isascii() or "\0" in name:
            self._rec.exact = False
        self._rec.scale = name

    @property
    def dims(self):
        return _RecordedDims(self._obj.dims, self._rec, self._owner, len(self._obj.shape or ()))


class _RecordedDims:
    """``ds.dims`` of a recorded dataset: ``dims[axis].attach_scale(scale)`` recorded."""

    def __init__(self, dims, rec: _Record, owner: RecordedFile, ndim: int):
        self._dims, self._rec, self._owner, self._ndim = dims, rec, owner, ndim

    def __getitem__(self, axis):
        return _RecordedDim(self._dims[axis], axis, self._rec, self._owner, self._ndim)

    def __getattr__(self, name):
        self._rec.exact = False
        return getattr(self._dims, name)

    def __len__(self):
        return len(self._dims)


class _RecordedDim:

    def __init__(self, dim, axis, rec: _Record, owner: RecordedFile, ndim: int):
        object.__setattr__(self, "_dim", dim)
        object.__setattr__(self, "_at", (axis, rec, owner, ndim))

    def attach_scale(self, scale):
        axis, rec, owner, ndim = self._at
        if isinstance(scale, _RecordedDataset):
            self._dim.attach_scale(scale._obj)
            target = scale._rec
            if rec.dims is None:
                rec.dims = [[] for _ in range(ndim)]
            if (not isinstance(axis, int) or not 0 <= axis < len(rec.dims) or target.scale is None
                    or target.name in rec.dims[axis]):
                rec.exact = target.exact = False
                return
            rec.dims[axis].append(target.name)
            target.refs.append((rec.name, axis))
        else:
            self._dim.attach_scale(scale)
            rec.exact = False
            owner.exact = False     # the scale's own attributes change too

    def __getattr__(self, name):
        self._at[1].exact = False
        self._at[2].exact = False
        return getattr(self._dim, name)

    def __setattr__(self, name, value):
        self._at[1].exact = False
        setattr(self._dim, name, value)


_PLAIN_TYPES: dict = {}           # str, float, int -> (dtype, file type, memory type) as h5py makes them


def _plain_types(kind):
    if kind not in _PLAIN_TYPES:
        dtype = h5py.string_dtype() if kind is str else np.asarray(kind(0)).dtype
        _PLAIN_TYPES[kind] = (dtype, h5py.h5t.py_create(dtype, logical=True), h5py.h5t.py_create(dtype))
    return _PLAIN_TYPES[kind]


def _set_plain_attr(attrs, key, value) -> bool:
    """``attrs[key] = value`` (an h5py AttributeManager) through h5py's low-level calls when the
    value is a ``str``, ``float`` or ``int`` (exactly those types; an int within int64) and the
    key is ASCII: the attribute h5py's ``attrs.create`` makes (the same calls: a scalar of h5py's
    type for the value, an existing one deleted first), without its per-call conversions. False,
    nothing written, for anything else."""
    kind = type(value)
    if kind not in (str, float, int) or not key.isascii() or (kind is int and not -2 ** 63 <= value < 2 ** 63):
        return False
    dtype, file_type, memory_type = _plain_types(kind)
    name = key.encode("ascii")
    oid = attrs._id
    if h5py.h5a.exists(oid, name):
        h5py.h5a.delete(oid, name)
    attr = h5py.h5a.create(oid, name, file_type, h5py.h5s.create(h5py.h5s.SCALAR))
    try:
        attr.write(np.asarray(value, dtype=dtype), mtype=memory_type)
    except BaseException:
        attr.close()
        h5py.h5a.delete(oid, name)
        raise
    attr.close()
    return True


class _RecordedAttrs:
    """``obj.attrs`` of a recorded object: every write recorded, reads passed through."""

    def __init__(self, attrs, rec: _Record):
        self._attrs, self._rec = attrs, rec

    def __setitem__(self, key, value):
        if not _set_plain_attr(self._attrs, key, value):
            self._attrs[key] = value
        if key in _SCALE_ATTRS:         # one HDF5's dimension scales keep: read the object back
            self._rec.attrs[key] = _READ_BACK
            self._rec.exact = False
        else:
            self._rec.attrs[key] = _attr_form(value)

    def update(self, other=(), **kw):
        for key, value in dict(other, **kw).items():
            self[key] = value

    def create(self, name, data, shape=None, dtype=None):
        self._attrs.create(name, data, shape, dtype)
        self._rec.attrs[name] = _READ_BACK

    def modify(self, name, value):
        self._attrs.modify(name, value)
        self._rec.attrs[name] = _READ_BACK

    def __delitem__(self, key):
        del self._attrs[key]
        self._rec.attrs.pop(key, None)

    def __getitem__(self, key):
        return self._attrs[key]

    def __contains__(self, key):
        return key in self._attrs

    def __iter__(self):
        return iter(self._attrs)

    def __len__(self):
        return len(self._attrs)

    def __getattr__(self, name):
        return getattr(self._attrs, name)

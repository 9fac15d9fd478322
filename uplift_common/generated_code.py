"""The methods that ``dataclasses`` generates, compiled once and kept (a command's start-up).

Python 3.11's ``@dataclass`` writes the source of each method it adds (``__init__``, ``__repr__``,
``__eq__``, ``__hash__``, a frozen class's ``__setattr__``...) and compiles it with ``exec``, one
method at a time: the 47 classes a warm ``uplift run`` imports compile about 250 such sources,
about a quarter of the instructions of its start-up outside numpy and h5py (callgrind). The
source depends only on the class (its fields, their defaults, the decorator's options), so its
code object can be kept: ``GeneratedCode.exec`` stands for ``exec`` in the ``dataclasses``
module (``installed``) and compiles a source it has not seen as ``exec`` would (file name
``"<string>"``, no inherited ``__future__`` flags, the interpreter's optimisation level), then
runs the code object in the namespaces it is given: the classes, their methods and their
behaviour are those ``exec`` of the source makes. ``save`` writes the code objects to one file
(``marshal``, with its SHA-256, atomically); the next process reads them back. The file is
keyed on the interpreter (its version and bytecode magic number); a damaged file is ignored (and
rewritten), anything not a string is executed as given.
"""
from __future__ import annotations

import contextlib
import hashlib
import importlib.util
import marshal
import sys
from pathlib import Path

_exec = exec
#: more distinct sources than this (code changed many times): the file starts again
MAX_ENTRIES = 5000


def code_file(folder) -> Path:
    """The file of ``folder`` (a cache folder) that keeps this interpreter's generated code."""
    key = hashlib.sha256(f"{sys.version}\0{importlib.util.MAGIC_NUMBER.hex()}\0{sys.flags.optimize}".encode())
    return Path(folder) / f"dataclasses-{key.hexdigest()[:24]}.bin"


class GeneratedCode:
    """Code objects of generated sources, read from ``path`` (None: kept in memory only)."""

    def __init__(self, path=None):
        self.path = None if path is None else Path(path)
        self.codes: dict = {}
        self.new = 0                      # sources compiled here and not saved yet
        if self.path is not None:
            self.codes = _read(self.path)

    def exec(self, source, globals=None, locals=None, /, **kwargs):
        """``exec(source, globals, locals)``, a string source's code object compiled once."""
        if type(source) is str:
            code = self.codes.get(source)
            if code is None:
                code = self.codes[source] = compile(source, "<string>", "exec", dont_inherit=True)
                self.new += 1
            source = code
        if globals is None:                 # the caller's namespaces, as exec takes them
            frame = sys._getframe(1)
            globals, locals = frame.f_globals, frame.f_locals if locals is None else locals
        return _exec(source, globals, locals, **kwargs)

    def save(self) -> None:
        """Write the code objects (when new ones were compiled) to ``path``, atomically; a
        folder that cannot take it is left as it is (they are compiled again next time)."""
        if self.path is None or not self.new:
            return
        from uplift_common.errors import UserInputError     # at the end of a command: numpy and h5py are loaded
        from uplift_common.files import atomic_output       # (same)
        codes = self.codes if len(self.codes) <= MAX_ENTRIES else {}
        body = marshal.dumps(codes)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            with atomic_output(self.path) as tmp:
                tmp.write_bytes(hashlib.sha256(body).digest() + body)
            self.new = 0
        except (OSError, UserInputError):   # a refused write (OutputWriteError, OutputPathError): not kept
            pass


def _read(path: Path) -> dict:
    """The code objects kept in ``path``; {} for a missing, damaged or foreign file."""
    try:
        blob = path.read_bytes()
    except OSError:
        return {}
    body = blob[32:]
    if len(blob) < 32 or hashlib.sha256(body).digest() != blob[:32]:
        return {}
    try:
        codes = marshal.loads(body)
    except (EOFError, ValueError, TypeError):
        return {}
    if not isinstance(codes, dict) or not all(type(k) is str and type(v) is type(_read.__code__)
                                              for k, v in codes.items()):
        return {}
    return codes


@contextlib.contextmanager
def installed(codes: GeneratedCode):
    """``dataclasses`` compiles through ``codes`` inside the block (its module's name ``exec``,
    which the generated methods are made with, is ``codes.exec``); as before after it."""
    import dataclasses
    had = "exec" in vars(dataclasses)
    before = vars(dataclasses).get("exec")
    dataclasses.exec = codes.exec
    try:
        yield codes
    finally:
        if had:
            dataclasses.exec = before
        else:
            del dataclasses.exec

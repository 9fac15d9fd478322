"""Ctrl-C (SIGINT) at any instant: a command either stops before it commits an output or after,
never in the middle of a commit, never silently, never killed by the signal.

Python turns SIGINT into a ``KeyboardInterrupt`` raised wherever the main thread happens to be.
Three places make that unsafe: the commit of a file (the rename onto the target and the removal
of the temporary: interrupted there, the command cannot tell whether the new file is in place),
a ``__del__`` or a weakref callback (an exception raised there is printed as "Exception ignored
in ..." and swallowed: the command goes on and exits 0), and the interpreter's own exit (once
Python has put the default action back, a SIGINT kills the process by the signal).

``install()`` (the command line, once, in the main thread) replaces Python's SIGINT handler by
one that counts every SIGINT (``received``) and raises ``KeyboardInterrupt`` unless held;
``held()`` is a section in which a SIGINT is only counted, and raised as ``KeyboardInterrupt``
when the outermost held section ends (``uplift_common.files`` holds the commit of every file);
``hold_for_exit()`` counts from then on without raising and ignores the signal, for a command
that has finished and only prints and exits. A ``KeyboardInterrupt`` swallowed by a ``__del__``
or a callback is silent (``sys.unraisablehook``) but still counted: the command line asks
``received()`` before it exits and exits 130 even when nothing raised.

Usage::

    interrupts.install()
    try:
        code = command()
    except KeyboardInterrupt:
        code = None
    interrupts.hold_for_exit()
    if interrupts.received():
        ...                                   # one line, exit 130
    with interrupts.held():                   # a SIGINT in here is raised at its end
        os.replace(tmp, target)
"""
from __future__ import annotations

import contextlib
import errno
import signal
import sys
import threading

_state = {"received": 0, "depth": 0, "owed": False, "closing": False}


def _handler(signum, frame):
    _state["received"] += 1
    if _state["depth"] or _state["closing"]:
        _state["owed"] = not _state["closing"]
        return
    raise KeyboardInterrupt


def _unraisable(hook):
    def unraisable(info):
        if isinstance(info.exc_value, KeyboardInterrupt):   # a Ctrl-C inside a __del__ or a callback:
            return                                          # counted by the handler; nothing printed
        hook(info)
    return unraisable


def started_as(module: str, script: str) -> bool:
    """True when this process is the program ``python -m <module>`` or its console script
    ``<script>`` (the interpreter's own command line, ``sys.orig_argv``): a module may then hold
    SIGINT while it loads (``install(held=True)``), since its ``main`` installs the handler."""
    argv = list(getattr(sys, "orig_argv", sys.argv))
    i = 1
    while i < len(argv):
        arg = argv[i]
        if arg == "-m":
            return argv[i + 1:i + 2] == [module]
        if arg == "-c":
            return False
        if arg in ("-X", "-W"):                  # the interpreter's options that take a value
            i += 2
            continue
        if not arg.startswith("-"):              # the script the interpreter runs
            name = arg.replace("\\", "/").rpartition("/")[2]
            return name in (script, f"{script}.exe", f"{script}-script.py")
        i += 1
    return False


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


def install(held: bool = False):
    """Handle SIGINT as this module says (main thread only; a SIGINT that is ignored, as in a
    shell's background job, stays ignored) and return the handler it replaces (for
    ``restore``). The count starts again at zero, unless the handler is already in place and
    holding (then it is kept: a program that held SIGINT while its modules loaded,
    ``held=True``, finds the SIGINTs of that time counted). ``held``: hold SIGINT until the next ``install()``."""
    previous = signal.getsignal(signal.SIGINT) if _main_thread() else None
    if previous is not _handler or not _state["depth"]:     # not holding since the modules loaded:
        _state.update(received=0, owed=False)                # a handler left by an earlier command starts over
    _state.update(depth=1 if held else 0, closing=False)
    if not _main_thread() or previous is signal.SIG_IGN:
        return previous
    signal.signal(signal.SIGINT, _handler)
    if not getattr(sys.unraisablehook, "_uplift", False):
        hook = _unraisable(sys.unraisablehook)
        hook._uplift = True
        sys.unraisablehook = hook
    return previous


def restore(previous) -> None:
    """Put back the SIGINT handler ``install`` replaced (a command run inside another program,
    e.g. a test calling the command line's ``main``)."""
    if _main_thread() and previous is not None:
        signal.signal(signal.SIGINT, previous)
    _state.update(depth=0, owed=False, closing=False)


def received() -> int:
    """How many SIGINTs arrived since ``install()`` (raised, held or swallowed alike)."""
    return _state["received"]


@contextlib.contextmanager
def held(defer: bool = False):
    """A section that a SIGINT does not cut: it is counted and raised as ``KeyboardInterrupt``
    when the outermost held section ends (after it, whole; when an exception is already on its
    way out of the section, that one goes on, and ``received`` still tells). When ``install``
    did not run, the handler is put in place for the section's duration (unless SIGINT is
    ignored or handled by someone else). Outside the main thread nothing is needed: Python
    raises KeyboardInterrupt in the main thread only. ``defer``: the SIGINT of the section is
    not raised at its end but by the next ``raise_owed()`` (e.g. once what the section built is
    in a ``with`` that will shut it down)."""
    if not _main_thread():
        yield
        return
    previous = signal.getsignal(signal.SIGINT)
    ours = previous is _handler
    if not ours and previous is signal.default_int_handler:
        signal.signal(signal.SIGINT, _handler)
        ours = True
        restore = True
    else:
        restore = False
    _state["depth"] += 1
    try:
        yield
    finally:
        _state["depth"] -= 1
        if restore:
            signal.signal(signal.SIGINT, previous)
        if ours and _state["depth"] == 0 and _state["owed"] and not defer:
            _state["owed"] = False
            if sys.exc_info()[0] is None:      # an error already on its way keeps its message
                raise KeyboardInterrupt


def raise_owed() -> None:
    """Raise the KeyboardInterrupt of a SIGINT that a ``held(defer=True)`` section took, if any."""
    if _state["owed"] and not _state["depth"]:
        _state["owed"] = False
        raise KeyboardInterrupt


def hold_for_exit(ignore: bool = True) -> None:
    """From now on a SIGINT is counted, never raised; ``ignore``: then ignored (SIG_IGN, which
    the interpreter keeps to its end): the process can no longer be cut or killed by it while it
    prints its last line and exits."""
    _state["closing"] = True
    if ignore and _main_thread() and signal.getsignal(signal.SIGINT) is _handler:
        signal.signal(signal.SIGINT, signal.SIG_IGN)


#: errno values of a file system that refuses data (not a bad path: those are refused before);
#: here, not in uplift_common.files, so that the command line's first lines need no numpy or h5py
REFUSED_ERRNOS = {errno.ENOSPC: "no space left on device", errno.EDQUOT: "disk quota exceeded",
                  errno.EFBIG: "file too large for the file system (or the process's file size limit)",
                  errno.EIO: "input/output error"}
_COMMITTED: list = []


def note_committed(path) -> None:
    """Record that ``path`` was renamed into place whole (``uplift_common.files.atomic_output``)."""
    _COMMITTED.append(path)


def committed() -> list:
    """The files ``atomic_output`` renamed into place in this process, in order (what a command
    interrupted afterwards did write, whole)."""
    return list(_COMMITTED)

"""The two families every error class of the project belongs to (one rule for the exit codes).

``UserInputError``: a problem the user can fix (a scene, a file, an option, the machine lacking
something a command needs); its message names the key, file or tool and the fix. The command
line exits 2. ``ComputationError``: a computation that could not finish (Newton failing, a
diverging march, a failed reference run); results so far are written by the caller, the command
line exits 1. Each error class is defined where it is raised, as a subclass of one family
(tests/orchestration/test_error_families.py checks every class of every package).
"""


class UserInputError(ValueError):
    """Bad input: a scene, a file, an option, the environment; the message says what to fix."""


class ComputationError(RuntimeError):
    """A computation that stopped before its end; the message says where and why."""


class OutputWriteError(UserInputError):
    """The file system refused the data of an output (no space left, a quota, a file size
    limit, an I/O error): nothing was written, a previous file at the path is left as it was.
    The command line exits 3 (orchestrator.exit_codes.EXIT_WRITE). ``errno``: the refusal's
    (uplift_common.interrupts.REFUSED_ERRNOS); ``reason``: it in words, with the space left (for a shorter message)."""

    def __init__(self, message: str, code: int | None = None, reason: str = ""):
        super().__init__(message)
        self.errno, self.reason = code, reason or message

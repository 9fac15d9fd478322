"""The command line's exit codes, and which exceptions give which.

0 success; 1 a computation stopped (results so far are written, with the reason); 2 bad input
(the message names the key or file and what would fix it); 3 an output could not be written: the
file system refused the data (no space left, a quota, a file size limit, an I/O error; the
message names the path and the space left), nothing was written and a previous file at the path
is left as it was; 130 interrupted (Ctrl-C: one line saying what was written, if anything).

Every error class of the project belongs to one of the two families of
``uplift_common.errors`` and is defined where it is raised: ``UserInputError`` exits 2,
``ComputationError`` exits 1. Beside the families: a file a command names that is not there
(``FileNotFoundError``) is the user's to fix, and a ``RuntimeError`` or ``ArithmeticError`` from
a library (a singular factorisation, an overflow) stopped a computation.
"""
from uplift_common.errors import ComputationError, OutputWriteError, UserInputError

EXIT_OK, EXIT_FAILED, EXIT_INPUT = 0, 1, 2
#: an output could not be written (a full disk, ...): its own code, checked before bad input
#: (OutputWriteError is a UserInputError: freeing space is the user's to do)
EXIT_WRITE = 3
#: interrupted by the user (Ctrl-C, SIGINT): 128 + 2, as shells report it
EXIT_INTERRUPTED = 130

#: exit 3: the file system refused an output's data (nothing written, the old file intact)
WRITE_FAILED = (OutputWriteError,)
#: exit 2: bad input (a route refuses the scene with the message)
USER_INPUT = (UserInputError, FileNotFoundError)
#: exit 1: a computation that stopped (a route keeps its results so far)
STOPPED = (ComputationError, RuntimeError, ArithmeticError)

"""The command line's exit codes, and which exceptions give which.

0 success; 1 a computation stopped (results so far are written, with the reason); 2 bad input
(the message names the key or file and what would fix it); 130 interrupted (Ctrl-C).

Every error class of the project belongs to one of the two families of
``uplift_common.errors`` and is defined where it is raised: ``UserInputError`` exits 2,
``ComputationError`` exits 1. Beside the families: a file a command names that is not there
(``FileNotFoundError``) is the user's to fix, and a ``RuntimeError`` or ``ArithmeticError`` from
a library (a singular factorisation, an overflow) stopped a computation.
"""
from uplift_common.errors import ComputationError, UserInputError

EXIT_OK, EXIT_FAILED, EXIT_INPUT = 0, 1, 2
#: interrupted by the user (Ctrl-C, SIGINT): 128 + 2, as shells report it
EXIT_INTERRUPTED = 130

#: exit 2: bad input (a route refuses the scene with the message)
USER_INPUT = (UserInputError, FileNotFoundError)
#: exit 1: a computation that stopped (a route keeps its results so far)
STOPPED = (ComputationError, RuntimeError, ArithmeticError)

"""Which exceptions are the user's input (exit 2) and which a computation that stopped (exit 1).

One rule: every problem the user can fix (a scene, a file, an option, the machine lacking
something a command needs) raises an exception of the ``UserInputError`` family, whose message
names the key, file or tool and the fix (exit 2); every computation that could not finish
(Newton failing, a diverging march, a failed reference run) raises one of the
``ComputationError`` family (exit 1, results so far written by the caller). Every error class of
the project belongs to exactly one family (tests/orchestration/test_error_families.py checks it).
"""
from fmus.coupling import StepRefused
from fmus.fmu_state import StateRefused
from soil_impedance import BemError, MeshError, SoilError, TableError
from soil_impedance.rational import FitError
from soil_impedance.storage import ChangedFileError, OutputPathError

from structure import StructureError

from orchestrator.motion import MotionError
from orchestrator.results import ResultsFileError
from orchestrator.routes import RouteInputError
from orchestrator.scene import SceneError


class EnsembleError(ValueError):
    """Bad input to an ensemble (a record, a PGA, a seed, the cluster); the message names it."""


class FragilityError(ValueError):
    """Bad input to a fragility fit (a limit, a route, a file); the message names it and the fix."""


class OptionError(ValueError):
    """Command-line options that cannot go together; the message says which to drop."""


class SetupError(ValueError):
    """The machine lacks something a command needs (e.g. the C compiler of a native export);
    the message names it and how to get it."""


#: bad input: a scene, a file, an option, the environment; the message says what to fix
UserInputError = (SceneError, SoilError, MeshError, BemError, TableError, MotionError, StructureError, FitError,
                  RouteInputError, ResultsFileError, EnsembleError, FragilityError, OutputPathError, ChangedFileError, SetupError, OptionError,
                  StepRefused, StateRefused, FileNotFoundError)
#: a computation that stopped (results so far are written by the caller)
ComputationError = (RuntimeError, ArithmeticError)

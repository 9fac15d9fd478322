"""Which exceptions are the user's input (exit 2) and which a computation that stopped (exit 1).

Every domain error of the project subclasses ValueError (bad input, the message says what to
fix) or RuntimeError (a computation that could not finish, e.g. Newton failing).
"""
from soil_impedance import BemError, MeshError, SoilError, TableError
from soil_impedance.rational import FitError

from structure import StructureError

from orchestrator.motion import MotionError
from orchestrator.results import ResultsFileError
from orchestrator.routes import RouteInputError
from orchestrator.scene import SceneError

#: bad input: a scene, a file, an option; the message says what to fix
UserInputError = (SceneError, SoilError, MeshError, BemError, TableError, MotionError, StructureError, FitError,
                  RouteInputError, ResultsFileError, FileNotFoundError)
#: a computation that stopped (results so far are written by the caller)
ComputationError = (RuntimeError, ArithmeticError)

"""Which exceptions are the user's input (exit 2) and which are a computation that stopped (exit 1)."""
from soil_impedance.mesh import MeshError
from soil_impedance.profile import SoilError

from orchestrator.scene import SceneError

#: bad input: a scene, a file, an option; the message says what to fix
UserInputError = (SceneError, SoilError, MeshError, FileNotFoundError)
#: a computation that stopped (results so far are written by the caller)
ComputationError = (RuntimeError, ArithmeticError)

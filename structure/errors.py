"""Domain exceptions of the structure package."""
from __future__ import annotations

from uplift_common.errors import ComputationError, UserInputError


class StructureError(UserInputError):
    """An invalid structure, soil-spring or contact input; the message names the input at
    fault and what would fix it (e.g. ``structure.beams[0].E = -3 must be > 0``)."""


class ConvergenceError(ComputationError):
    """The Newton contact iteration failed even at the smallest allowed sub-step.

    Attributes
    ----------
    time : float, s        time of the step that failed
    node : int             interface node index with the largest residual (-1 if unknown)
    residual : float, N    norm of the condensed residual at the last iterate
    result : RouteResult or None
        the results up to the last accepted step (set by ``simulate``), for the caller to save.
    """

    def __init__(self, message: str, time: float, node: int, residual: float, result=None):
        super().__init__(message)
        self.time = float(time)
        self.node = int(node)
        self.residual = float(residual)
        self.result = result

"""The compiled kernel: the rig's terms (:mod:`.terms`) apart from the solver (:mod:`.solver`).

:mod:`.layout` fixes the parameter vector's order and the status codes.  Nothing here
raises: the solver returns a status code that the model layer turns into an error (for a
user) or a penalty / ``-inf`` (for least squares or a likelihood).

Nothing is compiled on import: :func:`rotorbayes.kernel.solver.entry` compiles an entry
point for its signature (or loads it from numba's cache) when it is first asked for.
"""

from .layout import NAMES, STATUS_MESSAGES
from .solver import residuals_batch_into, residuals_into, simulate_batch_into, simulate_into

__all__ = [
    "NAMES",
    "STATUS_MESSAGES",
    "residuals_batch_into",
    "residuals_into",
    "simulate_batch_into",
    "simulate_into",
]

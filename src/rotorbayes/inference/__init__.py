"""Inference: problems, least squares, multistart and the parallel map layer.

* :mod:`.problem` — :class:`Problem`: residuals, status and Jacobians for any parameters;
* :mod:`.least_squares` — :func:`fit` (the thesis's lsqnonlin method), :func:`quality`;
* :mod:`.multistart` — many fits from spread starts, clustered and explained;
* :mod:`.parallel` — the one map layer for independent tasks.
"""

from .least_squares import FAIL_RESIDUAL, FitResult, fit, quality
from .multistart import MultistartResult, cluster_ends, describe_spread, latin_hypercube, multistart
from .parallel import Mapper, get_mapper
from .problem import CHANNELS, Evaluation, Problem, local_name

__all__ = [
    "CHANNELS", "Evaluation", "FAIL_RESIDUAL", "FitResult", "Mapper", "MultistartResult",
    "Problem", "cluster_ends", "describe_spread", "fit", "get_mapper", "latin_hypercube",
    "local_name", "multistart", "quality",
]  # fmt: skip

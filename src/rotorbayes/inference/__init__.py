"""Inference: problems, least squares, multistart and the parallel map layer.

* :mod:`.problem` — :class:`Problem`: residuals, status and Jacobians for any parameters;
* :mod:`.parameter_map` — :class:`ParameterMap`: free names, bounds, the vector ``x``;
* :mod:`.least_squares` — :func:`fit` (the thesis's lsqnonlin method), :func:`quality`;
* :mod:`.starts` — starts from the data (the equations of motion as a regression);
* :mod:`.first_fit` — :func:`fit_from_data`: data start, fit, restarts if not at the floor;
* :mod:`.uncertainty` — honest standard errors: block-robust, rounding simulated, input hold;
* :mod:`.assess` — RMS against the encoder floor, and warnings on what to distrust;
* :mod:`.multistart` — many fits from spread starts, clustered and explained;
* :mod:`.parallel` — the one map layer for independent tasks.
"""

from .assess import Assessment, assess
from .first_fit import FirstFit, fit_from_data
from .least_squares import (
    FAIL_RESIDUAL,
    FitResult,
    StartError,
    attach_uncertainty,
    fit,
    quality,
)
from .multistart import MultistartResult, cluster_ends, describe_spread, latin_hypercube, multistart
from .parameter_map import ParameterMap
from .problem import CHANNELS, Evaluation, Problem, local_name
from .starts import DataStart, data_start
from .uncertainty import Uncertainty, fit_uncertainty

__all__ = [
    "Assessment", "DataStart", "FirstFit", "StartError", "assess", "data_start",
    "fit_from_data", "CHANNELS", "Evaluation", "FAIL_RESIDUAL", "FitResult",
    "MultistartResult", "ParameterMap",
    "Problem", "cluster_ends", "describe_spread", "fit", "latin_hypercube",
    "local_name", "multistart", "quality", "Uncertainty", "attach_uncertainty",
    "fit_uncertainty",
]  # fmt: skip

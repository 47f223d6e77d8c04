"""Diagnosis: where the model fails and which physical effect is missing.

* :mod:`.diagnose` — :func:`diagnose`: the verdict (noise or not), the ranking and advice;
* :mod:`.score` — score (Lagrange-multiplier) tests of every catalogue effect that is off,
  from the residual and the Jacobian at the fit (no refit per candidate);
* :mod:`.torque` — the missing-torque map, for what the catalogue does not hold.
"""

from .diagnose import Diagnosis, diagnose
from .score import EffectScore, candidates, score_tests
from .torque import TorqueMap, missing_torque

__all__ = [
    "Diagnosis",
    "EffectScore",
    "TorqueMap",
    "candidates",
    "diagnose",
    "missing_torque",
    "score_tests",
]

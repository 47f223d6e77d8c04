"""The rig model: parameters, friction laws, the registry of effects, configurations and
simulation.

* :mod:`.parameters` — names, units, bounds, the thesis's tables as named sets;
* :mod:`.effects` — the catalogue of physical effects and user-defined effects;
* :mod:`.configurations` — upper / coupled / brake, and :class:`Model` (a configuration
  with its active effects);
* :mod:`.friction` — friction laws;
* :mod:`.simulate` — :class:`Simulator` and :func:`simulate`.
"""

from .configurations import CONFIGS, CONFIGURATIONS, Model, check_config
from .effects import CATALOGUE, Effect, EffectError
from .info import Parameter
from .parameters import INFO, NAMES, ParameterError, resolve, thesis_set
from .simulate import (
    DEFAULT_STEP,
    Simulation,
    SimulationError,
    Simulator,
    physics_problems,
    simulate,
)  # fmt: skip

__all__ = [
    "CATALOGUE", "CONFIGS", "CONFIGURATIONS", "DEFAULT_STEP", "Effect", "EffectError", "INFO",
    "Model", "NAMES", "Parameter", "ParameterError", "Simulation", "SimulationError",
    "Simulator", "check_config", "physics_problems", "resolve", "simulate", "thesis_set",
]  # fmt: skip

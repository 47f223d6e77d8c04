"""rotorbayes: Bayesian parameter inference for the TU Eindhoven drill-string rig.

Quick start::

    import rotorbayes as rb
    t, u = rb.signals.estimation_signal(30.0, seed=1)
    sim = rb.simulate("thesis:4.3:P_ref", u, dt=t[1] - t[0], config="brake")
    sim.theta_l, sim.alpha, sim.mode_l

See ``docs/model.md`` for the equations and parameters.
"""

from . import data, effects, parameters, plots, signals
from .data import Experiment, load_experiment, save_experiment
from .examples import example_names, load_example
from .model import CONFIGS, Simulation, SimulationError, Simulator, simulate
from .parameters import NAMES, ParameterError

__version__ = "0.1.0"

__all__ = [
    "CONFIGS",
    "NAMES",
    "Experiment",
    "ParameterError",
    "Simulation",
    "SimulationError",
    "Simulator",
    "data",
    "example_names",
    "load_example",
    "effects",
    "load_experiment",
    "parameters",
    "plots",
    "save_experiment",
    "signals",
    "simulate",
]

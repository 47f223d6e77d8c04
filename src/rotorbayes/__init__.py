"""rotorbayes: Bayesian parameter inference for the TU Eindhoven drill-string rig.

Quick start::

    import rotorbayes as rb
    t, u = rb.signals.estimation_signal(30.0, seed=1)
    sim = rb.simulate("thesis:4.3:P_ref", u, dt=t[1] - t[0], config="brake")
    sim.theta_l, sim.alpha, sim.mode_l

The pipeline, one subpackage per stage: :mod:`rotorbayes.model` (parameters, effects,
configurations, simulation) -> :mod:`rotorbayes.kernel` (compiled terms and solver) ->
:mod:`rotorbayes.inference` (problems, least squares, multistart, the likelihood and
sampling, identifiability, the parallel map) -> :mod:`rotorbayes.diagnosis` (verdict,
missing effects, missing torque, comparisons) -> :mod:`rotorbayes.commands` (the command
line, and a whole study from an analysis file in :mod:`rotorbayes.commands.study`).
Beside the pipeline: :mod:`rotorbayes.io` (measurement files, rig files, result folders),
:mod:`rotorbayes.figures`, :mod:`rotorbayes.report` and :mod:`rotorbayes.util` (exit codes,
number formats, fit metrics, the first compile).
See ``docs/model.md`` for the equations and ``docs/effects.md`` for the effects.
"""

import os as _os
import sys as _sys

# The integrator's batches run on numba's threads; a BLAS pool on the same two cores would
# fight them (the linear algebra here is small), and an SVD on several BLAS threads rounds
# otherwise than on one (a fit's end point would differ from its workers').  Set before
# NumPy loads, unless the user chose otherwise; where NumPy is loaded already (a script that
# imported it first), its BLAS is limited in place.
_BLAS_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
_blas_chosen = any(_v in _os.environ for _v in _BLAS_VARS)
for _v in _BLAS_VARS:
    _os.environ.setdefault(_v, "1")
if "numpy" in _sys.modules and not _blas_chosen:
    try:
        from threadpoolctl import threadpool_limits as _threadpool_limits

        _threadpool_limits(limits=1, user_api="blas")
    except ImportError:  # pragma: no cover - installed with scikit-learn, a dependency
        pass
# numba's OpenMP threads (the batch kernels) would otherwise spin after every parallel call
# and take a core from the user's own code for a while (measured: 5.7 ms of CPU in the
# 0.2 s after a call, none with passive waiting; benchmarks/bench_threads.py).
_os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

# The kernel compiles on first import (tens of seconds with a cold numba cache): said once.
from .util.coldstart import compile_kernel as _compile_kernel
from .util.coldstart import interrupted_while_loading as _interrupted_while_loading
from .util.coldstart import stop_at_once_while_loading as _stop_at_once_while_loading

_stop_at_once_while_loading()  # the command only: a Ctrl-C while loading ends it at once

try:
    _compile_kernel()

    from .io import measurements as data
    from .io.examples import example_names, load_example
    from .io.measurements import Experiment, load_experiment, save_experiment
    from .io.rigfiles import ReadSpec
    from .model import (
        CONFIGS,
        NAMES,
        Effect,
        Model,
        Parameter,
        ParameterError,
        Simulation,
        SimulationError,
        Simulator,
        effects,
        parameters,
        signals,
        simulate,
    )  # fmt: skip
except KeyboardInterrupt:
    # A Ctrl-C while the command line loads (numba's import, a cold compile) is an ordinary
    # stop of the command, not a crash: exit 130 with a word, no traceback.  Python code
    # that imports the package gets its KeyboardInterrupt as usual.
    _interrupted_while_loading()
    raise

from .util import __version__ as __version__  # noqa: E402

__all__ = [
    "CONFIGS", "NAMES", "Effect", "Experiment", "Model", "Parameter", "ParameterError", "ReadSpec",
    "Simulation", "SimulationError", "Simulator", "data", "effects", "example_names",
    "load_example", "load_experiment", "parameters", "save_experiment", "signals", "simulate",
]  # fmt: skip

"""Imported once by the fork server of local process pools
(:func:`rotorbayes.inference.parallel.process_context`): the package, scipy's optimiser and
the compiled kernel are loaded here, so that every worker forked from the server starts
with them (milliseconds, instead of seconds of imports and cache loading per worker).

Only serial kernel entry points are loaded here: no numba parallel function, so no thread
team exists in the server when it forks (GNU OpenMP's does not survive a fork); each worker
loads the parallel ones after its fork."""

import contextlib

with contextlib.suppress(Exception):  # a failed warm-up leaves the workers to load it
    import scipy.optimize  # noqa: F401 - loaded once for every worker

    from . import least_squares, multistart  # noqa: F401 - the tasks' modules
    from .parallel import warm_kernel

    warm_kernel(parallel_entries=False)

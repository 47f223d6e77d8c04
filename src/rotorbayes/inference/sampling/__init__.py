"""Posterior sampling with emcee from the least-squares point, checkpointed to HDF5.

* **Moves** (:data:`MOVES`, ``sample --moves``): emcee's stretch move alone, or mixtures
  with differential-evolution moves; the default :data:`DEFAULT_MOVES` was chosen by the
  effective samples per second measured side by side (``benchmarks/bench_sampler_moves.py``).
  The moves of a run are stored with its chains, so ``--resume`` continues with the same ones.
* Walkers start from the least-squares fit (:func:`start_walkers`): drawn from the fit's
  covariance in sampling coordinates (the curvature of the likelihood being sampled) at its
  full width, a sampled noise scale at the residuals' RMS, so the ensemble starts close to
  the posterior instead of expanding from a small ball; the log-posterior is vectorised
  (emcee ``vectorize=True``: all walkers in one parallel kernel batch).
* The wall time and CPU time of each ensemble are kept with its chains (summed over
  ``--resume`` sessions), for the effective samples per second in the summary.
* Every step is written to ``chain.h5`` (emcee's HDF5 backend) with the sampler's random
  state, so a run killed at any moment (even SIGKILL) resumes where its last completed step
  ended, and, with the same seed, continues exactly as an uninterrupted run would.
* Two or more **independent ensembles** (own seeds, own HDF5 groups) give R-hat; the
  walkers of one ensemble are not independent chains (each move uses the others), so R-hat
  across walkers would mean little.  Burn-in and thinning come from the integrated
  autocorrelation time τ; convergence asks N > 50 τ for every parameter.
* A checkpoint is checked before it is continued (:func:`check_checkpoint`): an empty,
  truncated or overwritten ``chain.h5``, or one made with other walkers or coordinates, is
  refused (:class:`CheckpointError`), never silently restarted.
* ``should_stop`` (Ctrl-C, recorded by the caller) ends a run between two steps, after the
  step is saved (:class:`SamplingStopped`).
* A full disk never damages the checkpoint: ``chain.h5`` owns the blocks of its coming
  steps before they are written (:func:`preallocate`), and where that is impossible a disk
  that is nearly full ends the run between two steps
  (:class:`~rotorbayes.util.exitcodes.EnvironmentFailure`).
* **One loop** (:func:`sample`): every ensemble is a chain of segments of steps, run by an
  executor (:mod:`~rotorbayes.inference.parallel`; without one, the serial executor: one
  ensemble after the other, one step a segment, in this process) and appended to
  ``chain.h5`` by this process alone; the chains do not depend on the executor.

One file per idea:

=====================  ===============================================================
``moves.py``           the moves, the fit proposal and its re-centring
``walkers.py``         where the walkers of a new ensemble start
``segment.py``         one task: a segment of steps from a carried state
``run.py``             the loop: :func:`sample`, :func:`run_ensemble`
``store.py``           where the steps go: ``chain.h5``'s groups, or memory
``checkpoint.py``      checks, recovery from the copy kept beside it, steps held
``locks.py``           opening ``chain.h5`` while another program reads it
``disk.py``            disk room: preallocation, reserves, the nearly-full stop
``convergence.py``     burn-in, thinning and the warnings in words
=====================  ===============================================================
"""

from __future__ import annotations

from .checkpoint import (
    CheckpointDamaged,
    CheckpointError,
    Snapshot,
    check_checkpoint,
    recover_checkpoint,
    save_settings,
    steps_held,
    stored_moves,
)
from .convergence import burn_thin, convergence
from .disk import DiskReserve, SummaryReserve, chain_bytes, preallocate
from .locks import LOCK_WAIT, CheckpointBusy, open_h5
from .moves import (
    ACCEPTANCE,
    ADAPT_AT,
    DEFAULT_MOVES,
    LEGACY_MOVES,
    MOVES,
    FitProposalMove,
    emcee_moves,
    fit_covariance,
    fit_proposal,
    noise_start,
    uses_fit_proposal,
)
from .run import (
    SEGMENT_FIRST,
    SEGMENT_MAX,
    SEGMENT_SECONDS,
    SamplingStopped,
    run_ensemble,
    sample,
)
from .store import EnsembleRun, read_ensemble
from .walkers import STARTS, start_walkers

__all__ = [
    "ACCEPTANCE",
    "ADAPT_AT",
    "DEFAULT_MOVES",
    "LEGACY_MOVES",
    "LOCK_WAIT",
    "MOVES",
    "SEGMENT_FIRST",
    "SEGMENT_MAX",
    "SEGMENT_SECONDS",
    "STARTS",
    "CheckpointBusy",
    "CheckpointDamaged",
    "CheckpointError",
    "DiskReserve",
    "EnsembleRun",
    "FitProposalMove",
    "SamplingStopped",
    "Snapshot",
    "SummaryReserve",
    "burn_thin",
    "chain_bytes",
    "check_checkpoint",
    "convergence",
    "emcee_moves",
    "fit_covariance",
    "fit_proposal",
    "noise_start",
    "open_h5",
    "preallocate",
    "read_ensemble",
    "recover_checkpoint",
    "run_ensemble",
    "sample",
    "save_settings",
    "start_walkers",
    "steps_held",
    "stored_moves",
    "uses_fit_proposal",
]

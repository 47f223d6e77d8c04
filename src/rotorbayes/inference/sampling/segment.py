"""One task of the sampling loop: a segment of steps of one ensemble, run by emcee from the
state the task carries (positions, log-probabilities, the random state, the fit proposal),
the steps kept in memory and returned with the random state after each; nothing is written
here, so a segment runs the same in this process, a thread, another process or on a Dask
worker."""

from __future__ import annotations

import os
import time
from dataclasses import dataclass

import emcee
import numpy as np

from ..likelihood import LogPosterior
from .moves import emcee_moves
from .walkers import start_walkers


@dataclass
class _Segment:
    """One task: ``n`` steps of ensemble ``name`` from a given emcee state.

    ``coords`` None: a new ensemble, placed from ``x_fit`` with ``seed``
    (:func:`~.walkers.start_walkers`, and emcee's random state from the same seed).
    ``random_state`` is the sampler's (numpy RandomState's) state; ``proposal`` the fit
    proposal's mean and covariance (moves that use it)."""

    name: str
    n: int
    moves: str
    proposal: tuple | None
    coords: np.ndarray | None = None
    log_prob: np.ndarray | None = None
    random_state: tuple | None = None
    seed: int = 0
    x_fit: np.ndarray | None = None
    n_walkers: int = 0
    start: str = "fit"
    origin: int = 0  # the process id of the command


@dataclass
class _Chunk:
    """What a segment returns: every step's positions, log-probabilities, acceptances and
    the random state after it (so the checkpoint after any step can be continued)."""

    name: str
    chain: np.ndarray  # (n, walkers, ndim)
    log_prob: np.ndarray  # (n, walkers)
    accepted: np.ndarray  # (n, walkers) bool
    random_states: list
    seconds: float
    cpu_seconds: float
    pid: int
    calls: int
    failed: int


def _run_segment(logpost: LogPosterior, seg: _Segment, keep: dict | None = None) -> _Chunk:
    """Run one segment (a task on a worker): emcee from the state the segment carries,
    the steps kept in memory and returned; nothing is written here.

    ``keep`` (in this process only, an ensemble's own dict): the emcee sampler is kept there
    and used again by the ensemble's next segment with the same moves and proposal, which
    spares emcee's set-up of every one-step segment (the state and the random state come
    from the segment all the same)."""
    if os.getpid() != seg.origin:
        # A worker process runs one task per core: the walkers in one numba thread (the
        # count is per thread, and a Dask task's thread is not the one set up at start).
        import copy

        import numba

        numba.set_num_threads(1)
        # A Dask worker of several threads runs several segments at once on the one
        # log-posterior it holds: each counts its own evaluations on a copy (the data
        # are shared, not copied).
        logpost = copy.copy(logpost)
    t0, c0 = time.perf_counter(), time.process_time()
    calls0, failed0 = logpost.n_calls, logpost.n_failed
    if seg.coords is None:
        rng = np.random.default_rng(seg.seed)
        p0 = start_walkers(logpost, seg.x_fit, seg.n_walkers, rng, start=seg.start)
        state = emcee.State(p0, random_state=np.random.RandomState(seg.seed).get_state())
    else:
        state = emcee.State(seg.coords, log_prob=seg.log_prob, random_state=seg.random_state)
    n_walkers = state.coords.shape[0]
    kind = (id(logpost), seg.moves, id(seg.proposal), n_walkers)
    if keep is not None and keep.get("kind") == kind:
        sampler = keep["sampler"]
        sampler.reset()
    else:
        sampler = emcee.EnsembleSampler(
            n_walkers,
            logpost.ndim,
            logpost,
            vectorize=True,
            moves=emcee_moves(seg.moves, seg.proposal),
        )
        if keep is not None:
            keep.update(kind=kind, sampler=sampler, proposal=seg.proposal)
    backend = sampler.backend
    chain = np.empty((seg.n, n_walkers, logpost.ndim))
    logp = np.empty((seg.n, n_walkers))
    acc = np.zeros((seg.n, n_walkers), bool)
    states = []
    before = np.zeros(n_walkers, int)
    # A continued state was checked when its ensemble began (as in one uninterrupted run).
    for k, st in enumerate(
        sampler.sample(
            state,
            iterations=seg.n,
            progress=False,
            store=True,
            skip_initial_state_check=seg.coords is not None,
        )
    ):
        chain[k], logp[k] = st.coords, st.log_prob
        acc[k] = backend.accepted > before
        before = backend.accepted.copy()
        states.append(st.random_state)
    return _Chunk(
        seg.name,
        chain,
        logp,
        acc,
        states,
        time.perf_counter() - t0,
        time.process_time() - c0,
        os.getpid(),
        logpost.n_calls - calls0,
        logpost.n_failed - failed0,
    )

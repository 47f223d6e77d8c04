"""Where the steps of the ensembles go: the groups of ``chain.h5`` (emcee's HDF5 backend,
one group per ensemble, with the sampler's random state after every step, so a run resumes
exactly), or memory for a run without checkpoints. The sampling loop sees one interface:
begin a group, append a segment's steps, read the last state, the chain and the stored fit
proposal, keep attributes (moves, proposal, clocks), and read an ensemble back
(:class:`EnsembleRun`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import emcee
import numpy as np

from .locks import WaitingBackend, open_h5
from .moves import LEGACY_MOVES


@dataclass
class EnsembleRun:
    """The chain of one ensemble read back from the HDF5 file."""

    name: str
    chain: np.ndarray  # (steps, walkers, ndim)
    log_prob: np.ndarray  # (steps, walkers)
    acceptance: np.ndarray  # (walkers,)
    tau: np.ndarray  # (ndim,), nan where it could not be estimated
    moves: str = "stretch"
    seconds: float = math.nan  # wall time of the sampling, summed over sessions
    cpu_seconds: float = math.nan  # CPU time of the process meanwhile (all its threads)


class _Store:
    """What the sampling loop asks of a store; the groups are emcee backends."""

    path: Path | None = None

    def backend(self, name: str):
        raise NotImplementedError

    def reset(self, name: str, n_walkers: int, ndim: int) -> None:
        """Make ``name`` an empty group of ``n_walkers`` x ``ndim``."""
        self.backend(name).reset(n_walkers, ndim)

    def attrs(self, name: str) -> dict:
        raise NotImplementedError

    def set_attrs(self, name: str, **attrs) -> None:
        raise NotImplementedError

    def proposal(self, name: str):
        """The fit proposal a group holds (the fit's, or the adapted one after
        :data:`~.moves.ADAPT_AT` steps) and whether it is adapted; None without one."""
        a = self.attrs(name)
        if "proposal_mean" not in a:
            return None
        return (
            (np.asarray(a["proposal_mean"], float), np.asarray(a["proposal_cov"], float)),
            "proposal_adapted" in a,
        )

    def last_state(self, name: str) -> emcee.State:
        return self.backend(name).get_last_sample()

    def chain(self, name: str) -> np.ndarray:
        return self.backend(name).get_chain()

    def grow(self, name: str, n: int) -> None:
        """Room for ``n`` more steps after those held."""
        self.backend(name).grow(n, None)

    def save(self, name: str, chain, log_prob, accepted, random_states) -> None:
        """Append steps one at a time, each as emcee saves its own (positions,
        log-probabilities, acceptances, then the random state and the step count): a kill
        between two writes leaves a checkpoint that continues exactly."""
        backend = self.backend(name)
        for k in range(chain.shape[0]):
            backend.save_step(
                emcee.State(chain[k], log_prob=log_prob[k], random_state=random_states[k]),
                accepted[k],
            )

    def add_seconds(self, name: str, wall: float, cpu: float) -> None:
        """Add wall and CPU time of the sampling to the group's totals."""
        raise NotImplementedError

    def run(self, name: str) -> EnsembleRun:
        raise NotImplementedError


class H5Store(_Store):
    """The groups of ``chain.h5`` (every opening waits out another reader's lock)."""

    path: Path

    def __init__(self, path: Path):
        self.path = Path(path)

    def backend(self, name: str) -> emcee.backends.HDFBackend:
        return WaitingBackend(str(self.path), name=name)

    def attrs(self, name: str) -> dict:
        with open_h5(self.path, "r") as f:
            return dict(f[name].attrs)

    def set_attrs(self, name: str, **attrs) -> None:
        with open_h5(self.path, "a") as f:
            for k, v in attrs.items():
                f[name].attrs[k] = v

    def add_seconds(self, name: str, wall: float, cpu: float) -> None:
        try:
            with open_h5(self.path, "a") as f:
                a = f[name].attrs
                a["sampling_seconds"] = float(a.get("sampling_seconds", 0.0)) + wall
                a["cpu_seconds"] = float(a.get("cpu_seconds", 0.0)) + cpu
        except Exception:  # noqa: BLE001 - the clock must never cost a step or a checkpoint
            pass

    def run(self, name: str) -> EnsembleRun:
        return read_ensemble(self.path, name)


class MemoryStore(_Store):
    """The groups in memory (emcee's ``Backend``): a run without checkpoints."""

    def __init__(self):
        self.backends: dict[str, emcee.backends.Backend] = {}
        self._attrs: dict[str, dict] = {}

    def backend(self, name: str) -> emcee.backends.Backend:
        return self.backends.setdefault(name, emcee.backends.Backend())

    def attrs(self, name: str) -> dict:
        return self._attrs.setdefault(name, {})

    def set_attrs(self, name: str, **attrs) -> None:
        self.attrs(name).update(attrs)

    def add_seconds(self, name: str, wall: float, cpu: float) -> None:
        a = self.attrs(name)
        a["sampling_seconds"] = a.get("sampling_seconds", 0.0) + wall
        a["cpu_seconds"] = a.get("cpu_seconds", 0.0) + cpu

    def run(self, name: str) -> EnsembleRun:
        run = _run_of(self.backend(name), name)
        a = self.attrs(name)
        run.moves = str(a.get("moves", run.moves))
        run.seconds = float(a.get("sampling_seconds", math.nan))
        run.cpu_seconds = float(a.get("cpu_seconds", math.nan))
        return run


def _run_of(backend, name: str) -> EnsembleRun:
    chain = backend.get_chain()
    tau = np.full(chain.shape[2], np.nan)
    if chain.shape[0] >= 20:
        try:
            tau = emcee.autocorr.integrated_time(chain, tol=0)
        except Exception:  # noqa: BLE001 - too short: τ stays unknown
            pass
    run = EnsembleRun(
        name,
        chain,
        backend.get_log_prob(),
        backend.accepted / max(backend.iteration, 1),
        np.asarray(tau, float),
    )
    if isinstance(backend, emcee.backends.HDFBackend):
        with backend.open() as f:
            a = f[name].attrs
            run.moves = str(a.get("moves", LEGACY_MOVES))
            run.seconds = float(a.get("sampling_seconds", math.nan))
            run.cpu_seconds = float(a.get("cpu_seconds", math.nan))
    return run


def read_ensemble(path: Path, name: str) -> EnsembleRun:
    return _run_of(WaitingBackend(str(path), name=name), name)

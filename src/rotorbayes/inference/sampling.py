"""Posterior sampling with emcee from the least-squares point, checkpointed to HDF5.

* Walkers start in a small ball shaped by the Gauss-Newton covariance at the fit
  (:meth:`LogPosterior.start_ball`); the log-posterior is vectorised (emcee
  ``vectorize=True``: all walkers in one parallel kernel batch).
* Every step is written to ``chain.h5`` (emcee's HDF5 backend) with the sampler's random
  state, so a run killed at any moment (even SIGKILL) resumes where its last completed step
  ended, and, with the same seed, continues exactly as an uninterrupted run would.
* Two or more **independent ensembles** (own seeds, own HDF5 groups) give R-hat; the
  walkers of one ensemble are not independent chains (each move uses the others), so R-hat
  across walkers would mean little.  Burn-in and thinning come from the integrated
  autocorrelation time τ; convergence asks N > 50 τ for every parameter.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import emcee
import numpy as np

from ..outputs import write_text_atomic
from .likelihood import LogPosterior


@dataclass
class EnsembleRun:
    """The chain of one ensemble read back from the HDF5 file."""

    name: str
    chain: np.ndarray  # (steps, walkers, ndim)
    log_prob: np.ndarray  # (steps, walkers)
    acceptance: np.ndarray  # (walkers,)
    tau: np.ndarray  # (ndim,), nan where it could not be estimated


def _backend(path: Path, name: str) -> emcee.backends.HDFBackend:
    return emcee.backends.HDFBackend(str(path), name=name)


def run_ensemble(
    logpost: LogPosterior,
    path: Path | None,
    name: str,
    *,
    n_walkers: int,
    n_steps: int,
    x_fit=None,
    seed: int = 0,
    progress: bool = True,
) -> int:
    """Run (or continue) one ensemble until its HDF5 group holds ``n_steps`` steps.

    Returns the number of steps taken in this call.  A group that already holds steps is
    continued from its last state and random state (``--resume``).
    """
    backend = _backend(path, name) if path is not None else emcee.backends.Backend()
    done = 0
    if path is not None and path.exists():
        try:
            done = backend.iteration
        except (KeyError, OSError):
            done = 0
    if done >= n_steps:
        return 0
    if done == 0:
        if path is not None and path.exists():
            backend.reset(n_walkers, logpost.ndim)
        rng = np.random.default_rng(seed)
        p0 = logpost.start_ball(x_fit, n_walkers, rng)
        # emcee's own RandomState from the seed: the same seed gives the same run.
        state = emcee.State(p0, random_state=np.random.RandomState(seed).get_state())
    else:
        state = None  # emcee continues from the backend's last sample and random state
    sampler = emcee.EnsembleSampler(n_walkers, logpost.ndim, logpost, vectorize=True,
                                    backend=backend)
    sampler.run_mcmc(state, n_steps - done, progress=progress, store=True)
    if path is None:
        return _run_of(backend, name)
    return n_steps - done


def _run_of(backend, name: str) -> EnsembleRun:
    chain = backend.get_chain()
    tau = np.full(chain.shape[2], np.nan)
    if chain.shape[0] >= 20:
        try:
            tau = emcee.autocorr.integrated_time(chain, tol=0)
        except Exception:  # noqa: BLE001 - too short: τ stays unknown
            pass
    return EnsembleRun(name, chain, backend.get_log_prob(),
                       backend.accepted / max(backend.iteration, 1), np.asarray(tau, float))


def read_ensemble(path: Path, name: str) -> EnsembleRun:
    return _run_of(_backend(path, name), name)


def burn_thin(runs: list[EnsembleRun]) -> tuple[int, int]:
    """Burn-in (2 max τ) and thinning (τ_min / 2), from all ensembles' τ."""
    taus = np.concatenate([r.tau for r in runs])
    taus = taus[np.isfinite(taus)]
    n = min(r.chain.shape[0] for r in runs)
    if taus.size == 0:
        return n // 2, 1
    burn = min(int(math.ceil(2 * taus.max())), n // 2)
    thin = max(1, int(taus.min() // 2))
    return burn, thin


def convergence(runs: list[EnsembleRun], names: list[str]) -> list[str]:
    """Warnings in words: N > 50 τ per parameter, acceptance, ensembles' agreement."""
    out = []
    for r in runs:
        n = r.chain.shape[0]
        bad = [f"{nm} (τ {t:.0f})" for nm, t in zip(names, r.tau, strict=True)
               if not (np.isfinite(t) and n > 50 * t)]
        if bad:
            out.append(f"{r.name}: {n} steps are not more than 50 τ for "
                       f"{', '.join(bad)}: run longer (--resume --steps N) before trusting "
                       "the intervals")
        acc = float(np.mean(r.acceptance))
        if not 0.15 <= acc <= 0.7:
            out.append(f"{r.name}: acceptance {acc:.2f} (expected 0.2-0.5)")
    return out


def save_settings(folder: Path, settings: dict) -> None:
    write_text_atomic(Path(folder) / "settings.json", json.dumps(settings, indent=2))


def sample(
    logpost: LogPosterior,
    x_fit,
    folder: Path | None,
    *,
    n_walkers: int = 32,
    n_steps: int = 2000,
    n_ensembles: int = 2,
    seed: int = 0,
    progress: bool = True,
) -> list[EnsembleRun]:
    """Run (or continue) ``n_ensembles`` ensembles into ``folder/chain.h5`` (in memory,
    without checkpoints, when ``folder`` is None)."""
    if folder is None:
        return [run_ensemble(logpost, None, f"ensemble{e}", n_walkers=n_walkers,
                             n_steps=n_steps, x_fit=x_fit, seed=seed + 1000 * e,
                             progress=progress) for e in range(n_ensembles)]
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "chain.h5"
    for e in range(n_ensembles):
        t0 = time.perf_counter()
        taken = run_ensemble(logpost, path, f"ensemble{e}", n_walkers=n_walkers,
                             n_steps=n_steps, x_fit=x_fit, seed=seed + 1000 * e,
                             progress=progress)
        if progress and taken:
            print(f"ensemble {e}: {taken} steps in {time.perf_counter() - t0:.1f} s",
                  flush=True)
    return [read_ensemble(path, f"ensemble{e}") for e in range(n_ensembles)]

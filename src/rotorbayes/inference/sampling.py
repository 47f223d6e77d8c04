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
* A checkpoint is checked before it is continued (:func:`check_checkpoint`): an empty,
  truncated or overwritten ``chain.h5``, or one made with other walkers or coordinates, is
  refused (:class:`CheckpointError`), never silently restarted.
* ``should_stop`` (Ctrl-C, recorded by the caller) ends a run between two steps, after the
  step is saved (:class:`SamplingStopped`).
* A full disk never damages the checkpoint: ``chain.h5`` owns the blocks of its coming
  steps before they are written (:func:`preallocate`), and where that is impossible a disk
  that is nearly full ends the run between two steps
  (:class:`~rotorbayes.exitcodes.EnvironmentFailure`).
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import emcee
import numpy as np

from ..exitcodes import EnvironmentFailure
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


class CheckpointError(ValueError):
    """``chain.h5`` is damaged or belongs to another run; the message says what to do."""


class SamplingStopped(Exception):
    """A run ended between two steps on request; every finished step is saved."""

    def __init__(self, ensemble: str, step: int, total: int):
        super().__init__(f"{ensemble} stopped after step {step} of {total}")
        self.ensemble, self.step, self.total = ensemble, step, total


def chain_bytes(n_walkers: int, ndim: int, n_steps: int, n_ensembles: int) -> int:
    """A generous bound on what ``chain.h5`` grows to: the chain and log-probability in
    float64 plus HDF5's bookkeeping per step (measured 4.5-7.2 kB a step for 10-64 walkers:
    every step is a chunk of its own)."""
    per_step = 8 * n_walkers * (ndim + 1) * 1.1 + 8192 + 64 * n_walkers
    return int(per_step * n_steps * n_ensembles) + 200_000


def check_checkpoint(path: Path, *, n_walkers: int, ndim: int,
                     n_ensembles: int) -> dict[str, int]:
    """The steps each ensemble of ``path`` holds, after checking it can be continued.

    A missing file holds nothing (a run killed before its first step). Raises
    :class:`CheckpointError` for an empty, unreadable, truncated or foreign file.
    """
    import h5py

    path = Path(path)
    if not path.exists():
        return {}
    fix = (f"--resume cannot continue it (its finished steps cannot be trusted). Keep it for "
           f"inspection by moving it away; to start the sampling again from step 0, delete "
           f"{path} and run --resume again, or run `rotorbayes sample FIT --out "
           f"{path.parent} --force`")
    size = path.stat().st_size
    if size == 0:
        raise CheckpointError(f"{path}: the checkpoint is empty (0 bytes): damaged; {fix}")
    steps: dict[str, int] = {}
    try:
        with h5py.File(path, "r") as f:
            for e in range(n_ensembles):
                name = f"ensemble{e}"
                if name not in f:
                    continue  # killed before this ensemble began: it starts at step 0
                g = f[name]
                it = int(g.attrs["iteration"])
                chain, logp = g["chain"], g["log_prob"]
                if (int(g.attrs["nwalkers"]), int(g.attrs["ndim"])) != (n_walkers, ndim):
                    raise CheckpointError(
                        f"{path}: {name} holds {g.attrs['nwalkers']} walkers x "
                        f"{g.attrs['ndim']} coordinates, but this run has {n_walkers} x "
                        f"{ndim} (settings.json or the fit changed); {fix}")
                if not 0 <= it <= chain.shape[0] or logp.shape[0] < it:
                    raise CheckpointError(f"{path}: {name} says {it} steps but holds "
                                          f"{chain.shape[0]}: damaged; {fix}")
                for k in g.attrs:  # the random state: a write cut short shows here
                    np.asarray(g.attrs[k])
                np.asarray(g["accepted"][:])
                if it:
                    c = np.asarray(chain[it - 1])  # reading the data finds a truncation
                    lp = np.asarray(logp[:it])
                    np.asarray(chain[:it])
                    if not np.all(np.isfinite(c)) or np.isnan(lp).any():
                        raise CheckpointError(f"{path}: {name} holds non-numbers in its "
                                              f"last step: damaged; {fix}")
                    if not any(k.startswith("random_state_") for k in g.attrs):
                        raise CheckpointError(f"{path}: {name} lacks the random state: "
                                              f"damaged; {fix}")
                steps[name] = it
    except CheckpointError:
        raise
    except Exception as exc:  # noqa: BLE001 - h5py raises OSError, KeyError, ValueError...
        first = str(exc).splitlines()[0][:160] if str(exc) else type(exc).__name__
        raise CheckpointError(f"{path}: cannot be read as a checkpoint ({first}): damaged "
                              f"(truncated or overwritten?); {fix}") from None
    return steps


def steps_held(path: Path) -> int:
    """The steps all ensembles of ``path`` hold (0 when absent or unreadable)."""
    import h5py

    try:
        with h5py.File(path, "r") as f:
            return sum(int(g.attrs.get("iteration", 0)) for g in f.values())
    except Exception:  # noqa: BLE001 - absent or damaged: nothing usable
        return 0


def preallocate(path: Path, nbytes: int) -> bool:
    """Give ``path`` ``nbytes`` more disk blocks past its end without changing its size
    (Linux ``fallocate`` with ``FALLOC_FL_KEEP_SIZE``).

    HDF5 then writes the coming steps into blocks the file already owns, so a disk that
    another program fills meanwhile cannot make a write fail half-way (which would damage
    the checkpoint). False where this is not possible (other systems, file systems without
    it, no room): then the sampler watches the free space instead.
    """
    import ctypes
    import ctypes.util

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        fallocate = libc.fallocate
    except (OSError, AttributeError):
        return False
    fallocate.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_longlong, ctypes.c_longlong]
    try:
        fd = os.open(path, os.O_RDWR)
    except OSError:
        return False
    try:
        return fallocate(fd, 1, os.fstat(fd).st_size, int(nbytes)) == 0  # 1: KEEP_SIZE
    finally:
        os.close(fd)


class DiskReserve:
    """Disk space held for the files written after the chains (posterior.nc, figures): a
    hidden file beside ``chain.h5``, given back just before they are written
    (:meth:`close`), so a disk filled meanwhile by another program does not starve them."""

    def __init__(self, folder: Path, nbytes: int):
        self.path = Path(folder) / ".chain.h5.reserve"
        if nbytes <= 0:
            return
        try:
            fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        except OSError:
            return
        try:
            os.posix_fallocate(fd, 0, int(nbytes))
        except (OSError, AttributeError):
            os.ftruncate(fd, 0)  # no room: run without a reserve
        finally:
            os.close(fd)

    def close(self) -> None:
        try:
            os.unlink(self.path)
        except OSError:
            pass


def _free_bytes(folder: Path) -> float:
    try:
        st = os.statvfs(folder)
    except OSError:
        return math.inf
    return st.f_bavail * st.f_frsize if st.f_blocks > 0 else math.inf


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
    done: int = 0,
    should_stop: Callable[[], bool] | None = None,
    owned: bool = False,
) -> int:
    """Run (or continue) one ensemble until its HDF5 group holds ``n_steps`` steps.

    ``done`` is the number of steps the group already holds (see :func:`check_checkpoint`);
    such a group is continued from its last state and random state (``--resume``). Returns
    the number of steps taken in this call. ``should_stop`` is asked after every saved step;
    when it says yes, :class:`SamplingStopped` is raised. ``owned``: the file already owns
    the disk blocks of these steps (:func:`preallocate`); otherwise the run stops, between
    two steps, when the disk is nearly full.
    """
    backend = _backend(path, name) if path is not None else emcee.backends.Backend()
    if done >= n_steps:
        return 0
    if done == 0:
        if path is not None:
            backend.reset(n_walkers, logpost.ndim)
        rng = np.random.default_rng(seed)
        p0 = logpost.start_ball(x_fit, n_walkers, rng)
        # emcee's own RandomState from the seed: the same seed gives the same run.
        state = emcee.State(p0, random_state=np.random.RandomState(seed).get_state())
    else:
        state = None  # emcee continues from the backend's last sample and random state
    sampler = emcee.EnsembleSampler(n_walkers, logpost.ndim, logpost, vectorize=True,
                                    backend=backend)
    if state is None:
        state = sampler._previous_state
    # Room for ten more steps, so HDF5 never meets a full disk in the middle of a write.
    step_bytes = 8 * n_walkers * (logpost.ndim + 1) * 10 + 100_000
    k = done
    for _ in sampler.sample(state, iterations=n_steps - done, progress=progress, store=True):
        k += 1  # emcee has saved the step before it yields it
        if (path is not None and not owned and k < n_steps
                and _free_bytes(path.parent) < step_bytes):
            raise EnvironmentFailure(
                f"{path.parent}: the disk is nearly full; sampling stopped after step {k} of "
                f"{n_steps} of {name} and every finished step is kept in {path}. Free some "
                f"space and continue with `rotorbayes sample {path.parent} --resume`")
        if should_stop is not None and k < n_steps and should_stop():
            raise SamplingStopped(name, k, n_steps)
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
    should_stop: Callable[[], bool] | None = None,
    keep_free: int = 0,
) -> list[EnsembleRun]:
    """Run (or continue) ``n_ensembles`` ensembles into ``folder/chain.h5`` (in memory,
    without checkpoints, when ``folder`` is None).

    An existing ``chain.h5`` is checked first (:func:`check_checkpoint`; a damaged one
    raises :class:`CheckpointError`); ``should_stop`` see :func:`run_ensemble`.
    """
    if folder is None:
        return [run_ensemble(logpost, None, f"ensemble{e}", n_walkers=n_walkers,
                             n_steps=n_steps, x_fit=x_fit, seed=seed + 1000 * e,
                             progress=progress) for e in range(n_ensembles)]
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "chain.h5"
    held = check_checkpoint(path, n_walkers=n_walkers, ndim=logpost.ndim,
                            n_ensembles=n_ensembles)
    left = sum(max(0, n_steps - held.get(f"ensemble{e}", 0)) for e in range(n_ensembles))
    owned = False
    if left:
        import h5py

        if not path.exists():
            with h5py.File(path, "a"):
                pass  # an empty HDF5 file, to own the blocks of the coming steps
        # Every coming step's blocks, owned by chain.h5 before the first is written.
        owned = preallocate(path, chain_bytes(n_walkers, logpost.ndim, left, 1))
    reserve = DiskReserve(folder, keep_free if left else 0)
    try:
        _run_all(logpost, x_fit, path, held, n_walkers=n_walkers, n_steps=n_steps,
                 n_ensembles=n_ensembles, seed=seed, progress=progress,
                 should_stop=should_stop, owned=owned)
    finally:
        reserve.close()
        if owned:  # give back the blocks past the end that were not needed
            try:
                os.truncate(path, os.stat(path).st_size)
            except OSError:
                pass
    return [read_ensemble(path, f"ensemble{e}") for e in range(n_ensembles)]


def _run_all(logpost, x_fit, path, held, *, n_walkers, n_steps, n_ensembles, seed,
             progress, should_stop, owned) -> None:
    for e in range(n_ensembles):
        t0 = time.perf_counter()
        name = f"ensemble{e}"
        taken = run_ensemble(logpost, path, name, n_walkers=n_walkers,
                             n_steps=n_steps, x_fit=x_fit, seed=seed + 1000 * e,
                             progress=progress, done=held.get(name, 0),
                             should_stop=should_stop, owned=owned)
        if progress and taken:
            print(f"ensemble {e}: {taken} steps in {time.perf_counter() - t0:.1f} s",
                  flush=True)

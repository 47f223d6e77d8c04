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
"""

from __future__ import annotations

import errno
import json
import math
import os
import shutil
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import emcee
import numpy as np

from ..io.outputs import write_text_atomic
from ..util.exitcodes import EnvironmentFailure
from .likelihood import LogPosterior


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


#: The sampler's moves (``sample --moves``): name -> (emcee moves with weights, words).
#: Every one is affine-invariant except the snooker move; all keep detailed balance, so
#: they differ only in how fast the walkers forget where they were.
MOVES = {
    "stretch": ((("stretch", 1.0),),
                "emcee's stretch move alone (a = 2; rotorbayes's default before the mixed moves)"),
    "de": ((("de", 1.0),), "differential evolution alone (emcee's DEMove, γ = 2.38/√(2d))"),
    "de-mix": ((("de", 0.8), ("snooker", 0.2)),
               "differential evolution 80 % and DE snooker 20 % (emcee's DEMove, "
               "DESnookerMove)"),
    "de-stretch": ((("de", 0.6), ("snooker", 0.2), ("stretch", 0.2)),
                   "differential evolution 60 %, DE snooker 20 %, stretch 20 %"),
    "fit-de": ((("fit", 0.5), ("de", 0.5)),
               "independence proposals from the fit's covariance (a Student t, 5 degrees "
               "of freedom, 1.2 x its width; re-centred once on the ensemble's draws after "
               "150 steps) 50 %, differential evolution 50 %"),
}
#: Mean acceptance outside (low, high) is warned about, per moves (with the range expected).
#: Independence proposals are accepted less often than local moves without mixing worse:
#: each accepted one moves a walker across the posterior (measured on the 1 kHz brake
#: posterior: 0.19-0.24 with τ 19-32 steps, where de-mix had 0.39 and τ 42-49).
ACCEPTANCE = {"stretch": (0.15, 0.7, "0.2-0.5"), "de": (0.15, 0.7, "0.2-0.5"),
              "de-mix": (0.15, 0.7, "0.2-0.5"), "de-stretch": (0.15, 0.7, "0.2-0.5"),
              "fit-de": (0.05, 0.9, "0.1-0.6")}
#: Step after which the fit proposal (``fit-de``) is re-centred, once, on the mean and
#: covariance of the ensemble's draws of the steps since ADAPT_AT/2, and then kept fixed: the
#: least-squares point is not exactly the posterior's centre, nor its curvature the
#: posterior's covariance, and in 15 dimensions small differences cost most acceptances.
#: Each step's kernel keeps the posterior (the proposal never depends on the current walkers).
ADAPT_AT = 150
#: The default, chosen by measured ESS per second (``benchmarks/bench_sampler_moves.py``).
DEFAULT_MOVES = "fit-de"
#: Moves of a run whose checkpoint does not name them (written before moves were stored).
LEGACY_MOVES = "stretch"
#: How the walkers start: ``fit`` draws them from the fit's covariance at full width (noise
#: coordinates from the residuals); ``ball`` is the former small ball (0.1 of that width,
#: noise coordinates at the floor ± 1 %).
STARTS = ("fit", "ball")


class FitProposalMove(emcee.moves.MHMove):
    """Independence proposals from the least-squares fit: every walker proposes a point drawn
    from a multivariate Student t (``nu`` degrees of freedom) centred on the fit with
    ``scale`` squared times the fit's covariance, accepted by Metropolis-Hastings with the
    proposal's density ratio. The proposal does not depend on the walkers, so the chain keeps
    the posterior exactly whatever the fit's quality; where the posterior is close to the
    fit's Gaussian (much data, as here) most proposals are accepted and a walker's next
    position is nearly independent of its last. The t's heavy tails keep the tails of a
    wider posterior reachable. Its random numbers come from the sampler's random state
    (resumed bit for bit)."""

    def __init__(self, mean, cov, nu: float = 5.0, scale: float = 1.2):
        self.mean = np.asarray(mean, float)
        lam, V = np.linalg.eigh(0.5 * (np.asarray(cov, float) + np.asarray(cov, float).T))
        lam = np.maximum(lam, 1e-300)
        self.root = V * (scale * np.sqrt(lam))  # cov * scale² = root rootᵀ
        self.inv_root = (V / (scale * np.sqrt(lam))).T
        self.nu, self.scale = float(nu), float(scale)
        super().__init__(self._propose, ndim=self.mean.size)

    def set(self, mean, cov) -> None:
        """Another centre and covariance (the same ``nu`` and ``scale``)."""
        self.__init__(mean, cov, self.nu, self.scale)

    def _log_q(self, x: np.ndarray) -> np.ndarray:
        y = (x - self.mean) @ self.inv_root.T
        m = np.einsum("ij,ij->i", y, y)
        return -0.5 * (self.nu + self.mean.size) * np.log1p(m / self.nu)

    def _propose(self, x0: np.ndarray, random):
        n, d = x0.shape
        g = random.randn(n, d)
        w = np.sqrt(random.chisquare(self.nu, n) / self.nu)
        q = self.mean + (g / w[:, None]) @ self.root.T
        return q, self._log_q(x0) - self._log_q(q)


def emcee_moves(name: str, proposal: tuple[np.ndarray, np.ndarray] | None = None) -> list:
    """The emcee move objects, with weights, of :data:`MOVES` ``name`` (``proposal``: the
    mean and covariance of :class:`FitProposalMove`, for moves that use it)."""
    if name not in MOVES:
        raise ValueError(f"moves {name!r}: choose one of {', '.join(MOVES)}")
    make = {"stretch": emcee.moves.StretchMove, "de": emcee.moves.DEMove,
            "snooker": emcee.moves.DESnookerMove,
            "fit": lambda: FitProposalMove(*proposal)}
    return [(make[kind](), weight) for kind, weight in MOVES[name][0]]


def uses_fit_proposal(name: str) -> bool:
    return any(kind == "fit" for kind, _ in MOVES[name][0])


def fit_proposal(logpost: LogPosterior, x_fit) -> tuple[np.ndarray, np.ndarray]:
    """Mean and covariance of every sampling coordinate at the fit: the parameters'
    :func:`fit_covariance`, the noise coordinates' :func:`noise_start` (independent)."""
    nc, ns = noise_start(logpost, x_fit)
    mean = np.concatenate([logpost.to_z(np.asarray(x_fit, float))[: logpost.k], nc])
    cov = np.zeros((logpost.ndim, logpost.ndim))
    cov[: logpost.k, : logpost.k] = fit_covariance(logpost, x_fit)
    cov[logpost.k:, logpost.k:] = np.diag(ns**2)
    return mean, cov


def noise_start(logpost: LogPosterior, x_fit) -> tuple[np.ndarray, np.ndarray]:
    """Centre and spread of the noise coordinates (``log σ``, ``φ``) from the residuals at
    the fit: σ the residual's RMS per channel (with AR(1) errors the innovations' RMS, φ
    the lag-1 autocorrelation), spreads their large-sample posterior standard deviations."""
    n_noise = logpost.ndim - logpost.k
    if n_noise == 0:
        return np.zeros(0), np.zeros(0)
    r = np.asarray(logpost.problem.residuals(np.asarray(x_fit, float)), float)
    parts: dict[str, list[np.ndarray]] = {}
    for (c, a, b) in logpost.segments:  # several experiments: pooled per channel
        parts.setdefault(c, []).append(r[a:b] / logpost.problem.weights[c])
    logs, phis, sd_s, sd_p = {}, {}, {}, {}
    for c, pieces in parts.items():
        e = np.concatenate(pieces)
        n = max(e.size, 2)
        phi = 0.0
        if logpost.ar1:
            den = float(e[:-1] @ e[:-1])
            phi = float(np.clip((e[1:] @ e[:-1]) / den, -0.99, 0.99)) if den > 0 else 0.0
            e = e[1:] - phi * e[:-1]
        rms = math.sqrt(float(e @ e) / max(e.size, 1))
        s = rms if rms > 0 and math.isfinite(rms) else logpost.floor[c]
        logs[c] = math.log(min(max(s, 2e-8), 5.0))  # inside the prior's 1e-8..10 rad
        sd_s[c] = 1.0 / math.sqrt(2 * n)
        phis[c], sd_p[c] = phi, math.sqrt(max(1 - phi**2, 1e-4) / n)
    centre = [logs[c] for c in logpost.channels]
    spread = [sd_s[c] for c in logpost.channels]
    if logpost.ar1:
        centre += [phis[c] for c in logpost.channels]
        spread += [sd_p[c] for c in logpost.channels]
    return np.array(centre), np.array(spread)


def fit_covariance(logpost: LogPosterior, x_fit) -> np.ndarray:
    """Covariance of the parameter coordinates at the fit: the inverse curvature of the
    likelihood being sampled (with ``robust`` noise the fit's honest covariance). A
    direction the data do not determine at all (an exact symmetry) gets a 1 % spread."""
    x_fit = np.asarray(x_fit, float)
    if logpost.noise == "sampled":
        # The residuals' own scale (σ's start), not the floor: σ² scales the covariance.
        nc, _ = noise_start(logpost, x_fit)
        sig = {c: math.exp(v) for c, v in zip(logpost.channels, nc, strict=False)}
        J, _ = logpost.problem.jacobian(x_fit)
        w = np.empty(J.shape[0])
        for (c, a, b) in logpost.segments:
            w[a:b] = 1.0 / (sig[c] * logpost.problem.weights[c])
        Jz = J * w[:, None] * np.where(logpost.log, x_fit, 1.0)[None, :]
        Hz = Jz.T @ Jz
    else:
        Hz = logpost._precision_iid(x_fit)
    if logpost.adjust is not None:
        Hz = logpost.adjust.T @ Hz @ logpost.adjust
    lam, V = np.linalg.eigh(0.5 * (Hz + Hz.T))
    var = np.where(lam > 1e-10 * max(lam.max(), 1e-300), 1.0 / np.maximum(lam, 1e-300),
                   1e-4)
    cov = (V * var) @ V.T
    evals = np.linalg.eigvalsh(cov)
    if not np.all(np.isfinite(evals)) or evals.max() <= 0:
        cov = np.diag(np.full(logpost.k, 1e-6))
    return cov


def start_walkers(logpost: LogPosterior, x_fit, n_walkers: int, rng, *,
                  start: str = "fit") -> np.ndarray:
    """Starting positions of ``n_walkers``, each with a finite log-posterior.

    ``fit``: drawn from :func:`fit_covariance` at full width around the fit, the noise
    coordinates from :func:`noise_start`, so the ensemble starts where the posterior is
    (when it is near Gaussian) instead of spending its first hundreds of steps expanding;
    ``ball``: :meth:`LogPosterior.start_ball` (0.1 of the width, the former start).
    """
    if start == "ball":
        return logpost.start_ball(x_fit, n_walkers, rng)
    if start != "fit":
        raise ValueError(f"start {start!r}: choose one of {', '.join(STARTS)}")
    x_fit = np.asarray(x_fit, float)
    cov = fit_covariance(logpost, x_fit)
    z0 = logpost.to_z(x_fit)[: logpost.k]
    nc, ns = noise_start(logpost, x_fit)
    out = np.empty((n_walkers, logpost.ndim))
    i = tries = 0
    while i < n_walkers:
        tries += 1
        if tries > 50 * n_walkers:
            raise RuntimeError("cannot place the walkers: the posterior is -inf all around "
                               "the fit (check the priors and bounds)")
        zz = np.empty(logpost.ndim)
        zz[: logpost.k] = rng.multivariate_normal(z0, cov, method="eigh")
        zz[logpost.k:] = nc + ns * rng.standard_normal(nc.size)
        if np.isfinite(logpost(zz[None, :])[0]):
            out[i] = zz
            i += 1
    return out


#: Seconds a write to ``chain.h5`` waits while another program holds the file open for
#: reading (HDF5 locks the file: a reader - emcee's ``HDFBackend`` or h5py in a notebook
#: peeking at the chains - makes a write fail at once).
LOCK_WAIT = 60.0


class CheckpointBusy(OSError):
    """Another program held ``chain.h5`` open for longer than :data:`LOCK_WAIT`."""


def _is_lock_error(exc: BaseException) -> bool:
    return isinstance(exc, BlockingIOError) or "unable to lock file" in str(exc)


def open_h5(path, mode: str = "r", wait: float | None = None):
    """``h5py.File(path, mode)``, waiting up to ``wait`` seconds (:data:`LOCK_WAIT`) while
    another process holds the file's lock; then :class:`CheckpointBusy` names the file and
    what to do."""
    import h5py

    return _waiting(lambda: h5py.File(path, mode), path, LOCK_WAIT if wait is None else wait)


def _waiting(opener: Callable, path, wait: float):
    t0, pause = time.monotonic(), 0.01
    while True:
        try:
            return opener()
        except OSError as exc:
            if not _is_lock_error(exc):
                raise
            if time.monotonic() - t0 >= wait:
                raise CheckpointBusy(
                    errno.EAGAIN, f"{path}: another program has held the file open for "
                    f"{wait:.0f} s (reading the chains while they are written?); every "
                    "finished step is kept. Close it there, then continue with --resume"
                ) from None
        time.sleep(pause)
        pause = min(2 * pause, 0.5)


class _Backend(emcee.backends.HDFBackend):
    """emcee's HDF5 backend whose every opening waits out another reader's lock."""

    def open(self, mode="r"):
        return _waiting(lambda: emcee.backends.HDFBackend.open(self, mode), self.filename,
                        LOCK_WAIT)


def _backend(path: Path, name: str) -> emcee.backends.HDFBackend:
    return _Backend(str(path), name=name)


class CheckpointError(ValueError):
    """``chain.h5`` is damaged or belongs to another run; the message says what to do."""


class CheckpointDamaged(CheckpointError):
    """The checkpoint cannot be read or holds what no finished step leaves."""


class SamplingStopped(Exception):
    """A run ended between two steps on request; every finished step is saved."""

    def __init__(self, ensemble: str, step: int, total: int,
                 others: dict[str, int] | None = None):
        others = {k: v for k, v in (others or {}).items() if k != ensemble}
        more = "".join(f", {k} after step {v}" for k, v in others.items())
        super().__init__(f"{ensemble} stopped after step {step} of {total}{more}")
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

    path = Path(path)
    if not path.exists():
        return {}
    fix = (f"--resume cannot continue it (its finished steps cannot be trusted). Keep it for "
           f"inspection by moving it away; to start the sampling again from step 0, delete "
           f"{path} and run --resume again, or run `rotorbayes sample FIT --out "
           f"{path.parent} --force`")
    size = path.stat().st_size
    if size == 0:
        raise CheckpointDamaged(f"{path}: the checkpoint is empty (0 bytes): damaged; {fix}")
    steps: dict[str, int] = {}
    try:
        with open_h5(path, "r") as f:
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
                    raise CheckpointDamaged(f"{path}: {name} says {it} steps but holds "
                                          f"{chain.shape[0]}: damaged; {fix}")
                for k in g.attrs:  # the random state: a write cut short shows here
                    np.asarray(g.attrs[k])
                np.asarray(g["accepted"][:])
                if it:
                    c = np.asarray(chain[it - 1])  # reading the data finds a truncation
                    lp = np.asarray(logp[:it])
                    np.asarray(chain[:it])
                    if not np.all(np.isfinite(c)) or np.isnan(lp).any():
                        raise CheckpointDamaged(f"{path}: {name} holds non-numbers in its "
                                              f"last step: damaged; {fix}")
                    if not any(k.startswith("random_state_") for k in g.attrs):
                        raise CheckpointDamaged(f"{path}: {name} lacks the random state: "
                                              f"damaged; {fix}")
                steps[name] = it
    except CheckpointError:
        raise
    except Exception as exc:  # noqa: BLE001 - h5py raises OSError, KeyError, ValueError...
        first = str(exc).splitlines()[0][:160] if str(exc) else type(exc).__name__
        raise CheckpointDamaged(f"{path}: cannot be read as a checkpoint ({first}): damaged "
                              f"(truncated or overwritten?); {fix}") from None
    return steps


def steps_held(path: Path) -> int:
    """The steps all ensembles of ``path`` hold (0 when absent or unreadable)."""

    try:
        with open_h5(path, "r", wait=5.0) as f:
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


class SummaryReserve:
    """Disk room held, file by file, for what is written after the chains (posterior.nc, the
    tables, the figures), from before the first step until each file is written.

    Each file ``NAME`` has a hidden ``.NAME.reserve`` beside it that owns the disk blocks of
    the file's estimated size (``posix_fallocate``). :meth:`write` puts the file's bytes into
    those blocks, gives back the rest and renames the reserve to ``NAME``: no new room is
    needed for the bytes within the estimate, so a disk that another program fills in the
    meantime cannot starve the file (only bytes beyond the estimate need new room). Where
    the room cannot be held (no ``posix_fallocate``, no room), :meth:`write` writes the
    file through the same hidden name and a rename, as any other file.
    """

    SUFFIX = ".reserve"

    def __init__(self, folder: Path, sizes: dict[str, int]):
        self.folder = Path(folder)
        self.held: dict[str, int] = {}
        for name, nbytes in sizes.items():
            if nbytes > 0 and self._hold(self.path(name), int(nbytes)):
                self.held[name] = int(nbytes)

    def path(self, name: str) -> Path:
        """The hidden reserve of ``name``."""
        return self.folder / f".{name}{self.SUFFIX}"

    @staticmethod
    def _hold(path: Path, nbytes: int) -> bool:
        try:
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o666)
        except OSError:
            return False
        try:
            os.posix_fallocate(fd, 0, nbytes)
            return True
        except (OSError, AttributeError):
            _unlink(path)  # no room (or no fallocate): this file goes without a reserve
            return False
        finally:
            os.close(fd)

    def write(self, name: str, data) -> Path:
        """Write the bytes ``data`` as ``folder/NAME``: into its reserve (a rename puts it in
        place, so a failed write never leaves a half file under the name)."""
        res = self.path(name)
        target = self.folder / name
        self.held.pop(name, None)
        mode = "r+b" if res.exists() else "wb"
        try:
            with open(res, mode) as fh:
                fh.write(data)
                fh.truncate()
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(res, target)
        except BaseException:
            _unlink(res)
            raise
        return target

    def close(self) -> None:
        """Give back the room of every file not written."""
        for name in list(self.held):
            _unlink(self.path(name))
        self.held.clear()

    @classmethod
    def clear(cls, folder: Path) -> None:
        """Remove the reserves a killed run left in ``folder`` (free space, not results)."""
        for p in Path(folder).glob(f".*{cls.SUFFIX}"):
            _unlink(p)


class Snapshot:
    """A copy of ``chain.h5`` as it stood after a saved step, kept beside it as
    ``.chain.h5.good`` while a run is under way.

    HDF5 is not crash-consistent: a SIGKILL (or the out-of-memory killer) while it flushes
    the file's metadata can leave ``chain.h5`` unreadable as a whole. The copy is taken
    only between two steps, when the file is closed (so it is whole), into a temporary
    name and then renamed over the previous one (so a kill during the copy leaves the
    previous copy). It is renewed at most every :attr:`EVERY` seconds, and never more
    often than keeps its cost below 5 % of the run (a copy that took 0.2 s waits 4 s); it is
    skipped when the disk could not hold it and two more (the run's own room comes first).
    :func:`recover_checkpoint` puts it back when ``chain.h5`` is found damaged; a run that
    ends (finished, stopped by Ctrl-C, or stopped by a filling disk, all between two steps)
    deletes it.
    """

    NAME = ".chain.h5.good"
    EVERY = 5.0
    MARGIN = 16_000_000

    def __init__(self, path: Path):
        self.path = Path(path)
        self.copy = self.path.with_name(self.NAME)
        self.tmp = self.path.with_name(self.NAME + ".tmp")
        self.next = 0.0
        self.taken = 0
        _unlink(self.tmp)  # left by a run killed in the middle of a copy

    def take(self, force: bool = False) -> None:
        """Copy ``chain.h5`` now if it is time (``force``: whatever the time)."""
        now = time.perf_counter()
        if not force and now < self.next:
            return
        try:
            size = self.path.stat().st_size
            if _free_bytes(self.path.parent) < 2 * size + self.MARGIN:
                self.next = now + self.EVERY
                return
            shutil.copyfile(self.path, self.tmp)
            os.replace(self.tmp, self.copy)
            self.taken += 1
        except OSError:
            _unlink(self.tmp)  # no room or no access: the run goes on without a new copy
        self.next = now + max(self.EVERY, 20.0 * (time.perf_counter() - now))

    def discard(self) -> None:
        """The run ended between two steps: ``chain.h5`` is whole, the copy not needed."""
        _unlink(self.tmp)
        _unlink(self.copy)


def _unlink(path: Path) -> None:
    try:
        path.unlink(missing_ok=True)
    except OSError:
        pass


def recover_checkpoint(path: Path, *, n_walkers: int, ndim: int,
                       n_ensembles: int) -> tuple[dict[str, int], str | None]:
    """:func:`check_checkpoint`, and when ``path`` is damaged but the :class:`Snapshot`
    beside it is whole, that copy put in its place: ``(steps held, what was done)``.

    The damaged file is kept as ``chain.h5.damaged`` (never deleted); the steps after the
    copy are sampled again, and with the same seed they are the same steps (the copy holds
    the random state of its last step). With no usable copy the original
    :class:`CheckpointError` stands.
    """
    path = Path(path)
    copy = path.with_name(Snapshot.NAME)
    try:
        return check_checkpoint(path, n_walkers=n_walkers, ndim=ndim,
                                n_ensembles=n_ensembles), None
    except CheckpointDamaged as exc:
        if not copy.exists():
            raise
        damage = str(exc).split(";")[0]
        try:
            held = check_checkpoint(copy, n_walkers=n_walkers, ndim=ndim,
                                    n_ensembles=n_ensembles)
        except CheckpointError as other:
            raise CheckpointDamaged(f"{exc} (the copy {copy.name} beside it cannot serve "
                                    f"either: {str(other).split(';')[0]})") from None
    kept = path.with_name(path.name + ".damaged")
    k = 1
    while kept.exists():
        k += 1
        kept = path.with_name(f"{path.name}.damaged{k}")
    os.replace(path, kept)
    os.replace(copy, path)
    steps = ", ".join(f"{n} {v}" for n, v in sorted(held.items())) or "no step yet"
    note = (f"{damage}; it was killed while it wrote. Restored the copy kept beside it "
            f"(steps held: {steps}); the damaged file is kept as {kept.name} (delete it "
            "when you no longer need it). The steps after the copy are sampled again, the "
            "same steps with the same seed")
    return held, note


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
    moves: str = DEFAULT_MOVES,
    start: str = "fit",
    snapshot: Snapshot | None = None,
):
    """Run (or continue) one ensemble until its HDF5 group holds ``n_steps`` steps.

    ``done`` is the number of steps the group already holds (see :func:`check_checkpoint`);
    such a group is continued from its last state and random state (``--resume``). Returns
    the number of steps taken in this call (the :class:`EnsembleRun` when ``path`` is None).
    ``should_stop`` is asked after every saved step; when it says yes,
    :class:`SamplingStopped` is raised. ``owned``: the file already owns the disk blocks of
    these steps (:func:`preallocate`); otherwise the run stops, between two steps, when the
    disk is nearly full. ``moves`` (:data:`MOVES`) is stored with the group; ``start``
    (:data:`STARTS`) places the walkers of a new group (:func:`start_walkers`);
    ``snapshot`` (:class:`Snapshot`) copies the checkpoint between steps now and then.
    """
    backend = _backend(path, name) if path is not None else emcee.backends.Backend()
    if done >= n_steps:
        return 0 if path is not None else _run_of(backend, name, moves)
    proposal, adapted = _begin_group(backend, path, name, done, n_walkers, logpost.ndim,
                                     moves, lambda: fit_proposal(logpost, x_fit))
    if done == 0:
        rng = np.random.default_rng(seed)
        p0 = start_walkers(logpost, x_fit, n_walkers, rng, start=start)
        # emcee's own RandomState from the seed: the same seed gives the same run.
        state = emcee.State(p0, random_state=np.random.RandomState(seed).get_state())
    else:
        state = None  # emcee continues from the backend's last sample and random state
    move_list = emcee_moves(moves, proposal)
    sampler = emcee.EnsembleSampler(n_walkers, logpost.ndim, logpost, vectorize=True,
                                    backend=backend, moves=move_list)
    if state is None:
        state = sampler._previous_state
    # Room for ten more steps, so HDF5 never meets a full disk in the middle of a write.
    step_bytes = 8 * n_walkers * (logpost.ndim + 1) * 10 + 100_000
    k = done
    clock = _Clock(path, name)
    try:
        for _ in sampler.sample(state, iterations=n_steps - done, progress=progress,
                                store=True):
            k += 1  # emcee has saved the step before it yields it
            clock.tick()
            if proposal is not None and not adapted and k == ADAPT_AT:
                # The fit's proposal re-centred once on the ensemble's own draws, then fixed.
                proposal, adapted = _adapted(backend.get_chain(), proposal), True
                for mv, _ in move_list:
                    if isinstance(mv, FitProposalMove):
                        mv.set(*proposal)
                if path is not None:
                    _set_attrs(path, name, proposal_mean=proposal[0],
                               proposal_cov=proposal[1], proposal_adapted=ADAPT_AT)
            if snapshot is not None:
                snapshot.take()
            if (path is not None and not owned and k < n_steps
                    and _free_bytes(path.parent) < step_bytes):
                raise EnvironmentFailure(
                    f"{path.parent}: the disk is nearly full; sampling stopped after step {k} "
                    f"of {n_steps} of {name} and every finished step is kept in {path}. Free "
                    f"some space and continue with `rotorbayes sample {path.parent} --resume`")
            if should_stop is not None and k < n_steps and should_stop():
                raise SamplingStopped(name, k, n_steps)
    except (OSError, EnvironmentFailure):
        raise  # a disk in trouble: no further write to the checkpoint
    except BaseException:
        clock.save()
        raise
    clock.save()
    if path is None:
        run = _run_of(backend, name, moves)
        run.seconds, run.cpu_seconds = clock.wall, clock.cpu
        return run
    return n_steps - done


def _begin_group(backend, path: Path | None, name: str, done: int, n_walkers: int,
                 ndim: int, moves: str, fit_prop: Callable[[], tuple]) -> tuple:
    """``(proposal, adapted)`` for an ensemble that holds ``done`` steps, with its HDF5
    group made ready: a new group (``done`` 0) is reset and records its moves, clocks and
    proposal; a group stopped between step ADAPT_AT and its record of the re-centred
    proposal gets that record now. ``fit_prop()`` gives the fit's proposal when the group
    holds none (moves without one: ``(None, False)``)."""
    proposal, adapted = None, False
    if uses_fit_proposal(moves):
        stored = _stored_proposal(path, name) if done else None
        proposal, adapted = stored if stored is not None else (fit_prop(), False)
        if done >= ADAPT_AT and not adapted:  # stopped between the step and its record
            proposal, adapted = _adapted(backend.get_chain(), proposal), True
            _set_attrs(path, name, proposal_mean=proposal[0], proposal_cov=proposal[1],
                       proposal_adapted=ADAPT_AT)
    if done == 0 and path is not None:
        backend.reset(n_walkers, ndim)
        extra = {} if proposal is None else {"proposal_mean": proposal[0],
                                             "proposal_cov": proposal[1]}
        _set_attrs(path, name, moves=moves, sampling_seconds=0.0, cpu_seconds=0.0, **extra)
    return proposal, adapted


def _stored_proposal(path: Path | None, name: str):
    """The fit proposal a group holds (the fit's, or the adapted one after
    :data:`ADAPT_AT` steps) and whether it is adapted; a resumed run uses it, bit for bit."""
    import h5py

    if path is None:
        return None
    with h5py.File(path, "r") as f:
        a = f[name].attrs
        if "proposal_mean" not in a:
            return None
        return ((np.asarray(a["proposal_mean"], float), np.asarray(a["proposal_cov"], float)),
                "proposal_adapted" in a)


def _adapted(chain: np.ndarray, proposal):
    """Mean and covariance of the draws of steps ADAPT_AT/2 .. ADAPT_AT - 1 (every walker);
    the previous proposal where they cannot give a positive definite covariance."""
    z = np.asarray(chain[ADAPT_AT // 2 : ADAPT_AT], float).reshape(-1, chain.shape[-1])
    if z.shape[0] < 10 * z.shape[1]:
        return proposal
    cov = np.cov(z.T)
    if not np.all(np.isfinite(cov)) or np.linalg.eigvalsh(cov).min() <= 0:
        return proposal
    return z.mean(axis=0), cov


def _set_attrs(path: Path, name: str, **attrs) -> None:

    with open_h5(path, "a") as f:
        for k, v in attrs.items():
            f[name].attrs[k] = v


class _Clock:
    """Wall and CPU time of a sampling session, added to the group's totals now and then
    (every :attr:`EVERY` s and at the end), so a killed run loses at most a few seconds."""

    EVERY = 10.0

    def __init__(self, path: Path | None, name: str):
        self.path, self.name = path, name
        self.t0, self.c0 = time.perf_counter(), time.process_time()
        self.saved_t, self.saved_c = self.t0, self.c0
        self.wall = self.cpu = 0.0

    def tick(self) -> None:
        if self.path is not None and time.perf_counter() - self.saved_t > self.EVERY:
            self.save()

    def save(self) -> None:
        t, c = time.perf_counter(), time.process_time()
        dw, dc = t - self.saved_t, c - self.saved_c
        self.saved_t, self.saved_c = t, c
        self.wall, self.cpu = t - self.t0, c - self.c0
        if self.path is None:
            return
        try:

            with open_h5(self.path, "a") as f:
                a = f[self.name].attrs
                a["sampling_seconds"] = float(a.get("sampling_seconds", 0.0)) + dw
                a["cpu_seconds"] = float(a.get("cpu_seconds", 0.0)) + dc
        except Exception:  # noqa: BLE001 - the clock must never cost a step or a checkpoint
            pass


def _run_of(backend, name: str, moves: str | None = None) -> EnsembleRun:
    chain = backend.get_chain()
    tau = np.full(chain.shape[2], np.nan)
    if chain.shape[0] >= 20:
        try:
            tau = emcee.autocorr.integrated_time(chain, tol=0)
        except Exception:  # noqa: BLE001 - too short: τ stays unknown
            pass
    run = EnsembleRun(name, chain, backend.get_log_prob(),
                      backend.accepted / max(backend.iteration, 1), np.asarray(tau, float))
    if isinstance(backend, emcee.backends.HDFBackend):
        with backend.open() as f:
            a = f[name].attrs
            run.moves = str(a.get("moves", LEGACY_MOVES))
            run.seconds = float(a.get("sampling_seconds", math.nan))
            run.cpu_seconds = float(a.get("cpu_seconds", math.nan))
    elif moves is not None:
        run.moves = moves
    return run


def read_ensemble(path: Path, name: str) -> EnsembleRun:
    return _run_of(_backend(path, name), name)


def stored_moves(path: Path) -> dict[str, str]:
    """The moves each ensemble of ``path`` was sampled with (:data:`LEGACY_MOVES` for a
    group written before they were stored)."""
    import h5py

    if not Path(path).exists():
        return {}
    try:
        with h5py.File(path, "r") as f:
            return {k: str(g.attrs.get("moves", LEGACY_MOVES)) for k, g in f.items()
                    if int(g.attrs.get("iteration", 0)) > 0}
    except Exception:  # noqa: BLE001 - check_checkpoint says what is wrong with the file
        return {}


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
        lo, hi, expected = ACCEPTANCE.get(r.moves, ACCEPTANCE["stretch"])
        if not lo <= acc <= hi:
            out.append(f"{r.name}: acceptance {acc:.2f} (expected {expected} with "
                       f"--moves {r.moves})")
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
    moves: str | None = None,
    start: str = "fit",
    executor=None,
) -> list[EnsembleRun]:
    """Run (or continue) ``n_ensembles`` ensembles into ``folder/chain.h5`` (in memory,
    without checkpoints, when ``folder`` is None).

    ``moves`` names the proposals (:data:`MOVES`; None: those the checkpoint holds, else
    :data:`DEFAULT_MOVES`); a checkpoint made with other moves is refused
    (:class:`CheckpointError`), so a resumed run continues exactly as it began. ``start``
    places the walkers of a new run (:func:`start_walkers`). An existing ``chain.h5`` is
    checked first (:func:`check_checkpoint`; a damaged one raises :class:`CheckpointError`);
    ``should_stop`` see :func:`run_ensemble`.

    ``executor`` (:mod:`~rotorbayes.inference.parallel`; None: one ensemble after the other
    in this process, emcee's own loop) runs the ensembles concurrently, in segments of steps
    (:func:`_run_on_executor`): only this process writes ``chain.h5``, step by step, and the
    chains are bit for bit those of the serial run.
    """
    if moves is not None and moves not in MOVES:
        raise ValueError(f"moves {moves!r}: choose one of {', '.join(MOVES)}")
    if folder is None:
        return [run_ensemble(logpost, None, f"ensemble{e}", n_walkers=n_walkers,
                             n_steps=n_steps, x_fit=x_fit, seed=seed + 1000 * e,
                             progress=progress, moves=moves or DEFAULT_MOVES, start=start)
                for e in range(n_ensembles)]
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "chain.h5"
    held, restored = recover_checkpoint(path, n_walkers=n_walkers, ndim=logpost.ndim,
                                        n_ensembles=n_ensembles)
    if restored:
        warnings.warn(restored, RuntimeWarning, stacklevel=2)
    stored = stored_moves(path)
    kinds = set(stored.values())
    if len(kinds) > 1:
        raise CheckpointError(f"{path}: its ensembles were sampled with different moves "
                              f"({', '.join(sorted(kinds))}); it cannot be continued as one run")
    if kinds and moves is not None and moves not in kinds:
        raise CheckpointError(f"{path}: its chains were sampled with --moves "
                              f"{next(iter(kinds))}, not {moves}; a resumed run continues "
                              "with the moves it began with (leave --moves out, or start a "
                              "new run with --out)")
    moves = next(iter(kinds)) if kinds else (moves or DEFAULT_MOVES)
    left = sum(max(0, n_steps - held.get(f"ensemble{e}", 0)) for e in range(n_ensembles))
    owned = False
    if left:

        if not path.exists():
            with open_h5(path, "a"):
                pass  # an empty HDF5 file, to own the blocks of the coming steps
        # Every coming step's blocks, owned by chain.h5 before the first is written.
        owned = preallocate(path, chain_bytes(n_walkers, logpost.ndim, left, 1))
    reserve = DiskReserve(folder, keep_free if left else 0)
    snapshot = Snapshot(path)
    if not held:
        snapshot.discard()  # a copy from an earlier run whose chain.h5 was removed
    try:
        run = _run_all if executor is None else _run_on_executor
        kw = {} if executor is None else {"executor": executor}
        run(logpost, x_fit, path, held, n_walkers=n_walkers, n_steps=n_steps,
            n_ensembles=n_ensembles, seed=seed, progress=progress,
            should_stop=should_stop, owned=owned, moves=moves, start=start,
            snapshot=snapshot if left else None, **kw)
    except (SamplingStopped, EnvironmentFailure):
        snapshot.discard()  # stopped between two steps: chain.h5 is whole
        raise
    else:
        snapshot.discard()
    finally:
        reserve.close()
        if owned:  # give back the blocks past the end that were not needed
            try:
                os.truncate(path, os.stat(path).st_size)
            except OSError:
                pass
    return [read_ensemble(path, f"ensemble{e}") for e in range(n_ensembles)]


def _run_all(logpost, x_fit, path, held, *, n_walkers, n_steps, n_ensembles, seed,
             progress, should_stop, owned, moves, start, snapshot) -> None:
    for e in range(n_ensembles):
        t0 = time.perf_counter()
        name = f"ensemble{e}"
        taken = run_ensemble(logpost, path, name, n_walkers=n_walkers,
                             n_steps=n_steps, x_fit=x_fit, seed=seed + 1000 * e,
                             progress=progress, done=held.get(name, 0),
                             should_stop=should_stop, owned=owned, moves=moves, start=start,
                             snapshot=snapshot)
        if progress and taken:
            dt = time.perf_counter() - t0
            print(f"ensemble {e}: {taken} steps in {dt:.1f} s "
                  f"({taken * n_walkers / max(dt, 1e-9):.0f} log-posterior evaluations/s)",
                  flush=True)


# ----------------------------------------------------- ensembles on an executor (segments)

#: Steps of an ensemble's first segment on an executor; later segments aim at
#: :data:`SEGMENT_SECONDS` of work each (at most :data:`SEGMENT_MAX` steps), so a Ctrl-C
#: waits little and the checkpoint is written often.
SEGMENT_FIRST, SEGMENT_SECONDS, SEGMENT_MAX = 5, 2.0, 500


@dataclass
class _Segment:
    """One task: ``n`` steps of ensemble ``name`` from a given emcee state.

    ``coords`` None: a new ensemble, placed from ``x_fit`` with ``seed`` (as
    :func:`run_ensemble` does). ``random_state`` is the sampler's (numpy RandomState's)
    state; ``proposal`` the fit proposal's mean and covariance (moves that use it)."""

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


def _run_segment(logpost: LogPosterior, seg: _Segment) -> _Chunk:
    """Run one segment (a task on a worker): emcee from the state the segment carries,
    the steps kept in memory and returned; nothing is written here."""
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
    sampler = emcee.EnsembleSampler(n_walkers, logpost.ndim, logpost, vectorize=True,
                                    moves=emcee_moves(seg.moves, seg.proposal))
    backend = sampler.backend
    chain = np.empty((seg.n, n_walkers, logpost.ndim))
    logp = np.empty((seg.n, n_walkers))
    acc = np.zeros((seg.n, n_walkers), bool)
    states = []
    before = np.zeros(n_walkers, int)
    # A continued state was checked when its ensemble began (as in one uninterrupted run).
    for k, st in enumerate(sampler.sample(state, iterations=seg.n, progress=False,
                                          store=True,
                                          skip_initial_state_check=seg.coords is not None)):
        chain[k], logp[k] = st.coords, st.log_prob
        acc[k] = backend.accepted > before
        before = backend.accepted.copy()
        states.append(st.random_state)
    return _Chunk(seg.name, chain, logp, acc, states, time.perf_counter() - t0,
                  time.process_time() - c0, os.getpid(), logpost.n_calls - calls0,
                  logpost.n_failed - failed0)


def _save_chunk(path: Path, name: str, chunk: _Chunk) -> None:
    """Append a chunk to the ensemble's group one step at a time, each step as emcee saves
    its own (positions, log-probabilities, acceptances, then the random state and the
    step count): a kill between two writes leaves a checkpoint that continues exactly."""
    backend = _backend(path, name)
    backend.grow(chunk.chain.shape[0], None)
    for k in range(chunk.chain.shape[0]):
        backend.save_step(emcee.State(chunk.chain[k], log_prob=chunk.log_prob[k],
                                      random_state=chunk.random_states[k]),
                          chunk.accepted[k])


def _run_on_executor(logpost, x_fit, path, held, *, n_walkers, n_steps, n_ensembles, seed,
                     progress, should_stop, owned, moves, start, snapshot,
                     executor) -> None:
    """The ensembles concurrently on ``executor``, in segments.

    Each ensemble is a chain of tasks: a worker runs a segment of steps from the state the
    task carries (positions, log-probabilities, the random state, the fit proposal) and
    returns the steps; this process appends them to ``chain.h5`` step by step (the only
    writer) and sends the ensemble's next segment. A segment never crosses
    :data:`ADAPT_AT`, where the fit proposal is re-centred here from the stored chain, as
    the serial run does. The random state travels whole, so the chains do not depend on
    where or in how many segments they were run: bit for bit the serial ones. The
    log-posterior (the data) goes to every worker once (Dask scatters it; threads share it;
    a process pool gets it with each segment, not with each step). ``should_stop`` is asked
    while waiting: the segments still running are dropped (their steps were never written)."""
    from concurrent.futures import FIRST_COMPLETED, CancelledError
    from concurrent.futures import wait as _wait

    from . import parallel

    active: dict[str, dict] = {}
    fit_prop: list = []

    def the_fit_proposal():  # computed once, for all the ensembles that begin now
        if not fit_prop:
            fit_prop.append(fit_proposal(logpost, x_fit))
        return fit_prop[0]

    for e in range(n_ensembles):
        name = f"ensemble{e}"
        done = held.get(name, 0)
        if done >= n_steps:
            continue
        backend = _backend(path, name)
        proposal, adapted = _begin_group(backend, path, name, done, n_walkers, logpost.ndim,
                                         moves, the_fit_proposal)
        seg = _Segment(name, 0, moves, proposal, origin=os.getpid())
        if done == 0:
            seg.seed, seg.x_fit, seg.n_walkers, seg.start = (seed + 1000 * e, x_fit,
                                                            n_walkers, start)
        else:
            last = backend.get_last_sample()
            seg.coords, seg.log_prob, seg.random_state = (last.coords, last.log_prob,
                                                          last.random_state)
        active[name] = {"e": e, "done": done, "seg": seg, "adapted": adapted,
                        "per_step": None, "t0": time.perf_counter(), "taken": 0}
    if not active:
        return
    total = sum(n_steps - a["done"] for a in active.values())
    step_bytes = 8 * n_walkers * (logpost.ndim + 1) + 8192
    shared = parallel.share(executor, logpost)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=total, desc=f"{len(active)} ensembles", unit="step", leave=False)
    futures: dict = {}
    me = os.getpid()

    def submit(name: str) -> None:
        a = active[name]
        left = n_steps - a["done"]
        n = SEGMENT_FIRST if a["per_step"] is None else int(
            SEGMENT_SECONDS / max(a["per_step"], 1e-6))
        n = max(1, min(n, SEGMENT_MAX, left))
        if a["seg"].proposal is not None and not a["adapted"] and a["done"] < ADAPT_AT:
            n = min(n, ADAPT_AT - a["done"])  # the proposal is re-centred at ADAPT_AT
        a["seg"].n = n
        futures[executor.submit(_run_segment, shared, a["seg"])] = name

    try:
        for name in active:
            submit(name)
        while futures:
            if should_stop is not None and should_stop():
                raise _stopped(active, n_steps)
            ready, _ = _wait(list(futures), timeout=0.2, return_when=FIRST_COMPLETED)
            for f in sorted(ready, key=lambda f: active[futures[f]]["e"]):
                name = futures.pop(f)
                a = active[name]
                try:
                    chunk = f.result()
                except CancelledError:
                    raise _lost(executor, path, active, n_steps, total) from None
                except OSError as exc:
                    if parallel.client_gone(executor):
                        raise _lost(executor, path, active, n_steps, total) from exc
                    raise
                n = chunk.chain.shape[0]
                if (not owned and _free_bytes(path.parent) < step_bytes * n + 100_000):
                    raise EnvironmentFailure(
                        f"{path.parent}: the disk is nearly full; sampling stopped after "
                        f"step {a['done']} of {n_steps} of {name} and every finished step "
                        f"is kept in {path}. Free some space and continue with "
                        f"`rotorbayes sample {path.parent} --resume`")
                _save_chunk(path, name, chunk)
                _add_seconds(path, name, chunk.seconds, chunk.cpu_seconds)
                if chunk.pid != me:  # counted in another process's copy
                    logpost.n_calls += chunk.calls
                    logpost.n_failed += chunk.failed
                a["done"] += n
                a["taken"] += n
                a["per_step"] = chunk.seconds / n
                seg = a["seg"]
                seg.coords, seg.log_prob = chunk.chain[-1], chunk.log_prob[-1]
                seg.random_state, seg.x_fit = chunk.random_states[-1], None
                if seg.proposal is not None and not a["adapted"] and a["done"] == ADAPT_AT:
                    seg.proposal = _adapted(_backend(path, name).get_chain(), seg.proposal)
                    a["adapted"] = True
                    _set_attrs(path, name, proposal_mean=seg.proposal[0],
                               proposal_cov=seg.proposal[1], proposal_adapted=ADAPT_AT)
                if snapshot is not None:
                    snapshot.take()
                if bar is not None:
                    bar.update(n)
                    bar.set_postfix_str(_where(active, n_steps))
                if a["done"] < n_steps:
                    if should_stop is not None and should_stop():
                        raise _stopped(active, n_steps)
                    submit(name)
                elif progress:
                    dt = time.perf_counter() - a["t0"]
                    msg = (f"ensemble {a['e']}: {a['taken']} steps in {dt:.1f} s "
                           f"({a['taken'] * n_walkers / max(dt, 1e-9):.0f} log-posterior "
                           "evaluations/s)")
                    (bar.write(msg) if bar is not None else print(msg, flush=True))
    finally:
        for f in futures:
            f.cancel()
        if bar is not None:
            bar.close()


def _where(active: dict, n_steps: int) -> str:
    """Each ensemble's steps, for the progress bar: ``e0 40/120 e1 35/120``."""
    return " ".join(f"e{a['e']} {a['done']}/{n_steps}" for a in active.values())


def _stopped(active: dict, n_steps: int) -> SamplingStopped:
    """Stopped on request: where every ensemble of this session stands (all saved)."""
    first = next(iter(active))
    return SamplingStopped(first, active[first]["done"], n_steps,
                           {n: a["done"] for n, a in active.items()})


def _lost(executor, path: Path, active: dict, n_steps: int, total: int):
    """The error for a Dask scheduler lost while the ensembles ran on it."""
    from . import parallel

    return parallel.lost_scheduler(
        executor, total - _left(active, n_steps), total, unit="steps",
        then=f"every finished step is kept in {path}. Continue with `rotorbayes sample "
        f"{path.parent} --resume` (on this machine; or with --scheduler once the "
        "scheduler and its workers run again)")


def _left(active: dict, n_steps: int) -> int:
    return sum(n_steps - a["done"] for a in active.values())


def _add_seconds(path: Path, name: str, wall: float, cpu: float) -> None:
    """Add a segment's wall and CPU time (on its worker) to the group's totals."""
    try:

        with open_h5(path, "a") as f:
            a = f[name].attrs
            a["sampling_seconds"] = float(a.get("sampling_seconds", 0.0)) + wall
            a["cpu_seconds"] = float(a.get("cpu_seconds", 0.0)) + cpu
    except Exception:  # noqa: BLE001 - the clock must never cost a step or a checkpoint
        pass

"""The checkpoint ``chain.h5``: checked before it is continued (an empty, truncated or
overwritten file, or one made with other walkers or coordinates, is refused, never silently
restarted), a whole copy kept beside it between steps (:class:`Snapshot`) and put back when
a kill damaged it (:func:`recover_checkpoint`), the steps and moves it holds, and the run's
``settings.json``."""

from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path

import numpy as np

from ...io.outputs import write_text_atomic
from .disk import free_bytes, unlink
from .locks import open_h5
from .moves import LEGACY_MOVES


class CheckpointError(ValueError):
    """``chain.h5`` is damaged or belongs to another run; the message says what to do."""


class CheckpointDamaged(CheckpointError):
    """The checkpoint cannot be read or holds what no finished step leaves."""


def check_checkpoint(path: Path, *, n_walkers: int, ndim: int, n_ensembles: int) -> dict[str, int]:
    """The steps each ensemble of ``path`` holds, after checking it can be continued.

    A missing file holds nothing (a run killed before its first step). Raises
    :class:`CheckpointError` for an empty, unreadable, truncated or foreign file.
    """

    path = Path(path)
    if not path.exists():
        return {}
    fix = (
        f"--resume cannot continue it (its finished steps cannot be trusted). Keep it for "
        f"inspection by moving it away; to start the sampling again from step 0, delete "
        f"{path} and run --resume again, or run `rotorbayes sample FIT --out "
        f"{path.parent} --force`"
    )
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
                        f"{ndim} (settings.json or the fit changed); {fix}"
                    )
                if not 0 <= it <= chain.shape[0] or logp.shape[0] < it:
                    raise CheckpointDamaged(
                        f"{path}: {name} says {it} steps but holds {chain.shape[0]}: damaged; {fix}"
                    )
                for k in g.attrs:  # the random state: a write cut short shows here
                    np.asarray(g.attrs[k])
                np.asarray(g["accepted"][:])
                if it:
                    c = np.asarray(chain[it - 1])  # reading the data finds a truncation
                    lp = np.asarray(logp[:it])
                    np.asarray(chain[:it])
                    if not np.all(np.isfinite(c)) or np.isnan(lp).any():
                        raise CheckpointDamaged(
                            f"{path}: {name} holds non-numbers in its last step: damaged; {fix}"
                        )
                    if not any(k.startswith("random_state_") for k in g.attrs):
                        raise CheckpointDamaged(
                            f"{path}: {name} lacks the random state: damaged; {fix}"
                        )
                steps[name] = it
    except CheckpointError:
        raise
    except Exception as exc:  # noqa: BLE001 - h5py raises OSError, KeyError, ValueError...
        first = str(exc).splitlines()[0][:160] if str(exc) else type(exc).__name__
        raise CheckpointDamaged(
            f"{path}: cannot be read as a checkpoint ({first}): damaged "
            f"(truncated or overwritten?); {fix}"
        ) from None
    return steps


def steps_held(path: Path) -> int:
    """The steps all ensembles of ``path`` hold (0 when absent or unreadable)."""

    try:
        with open_h5(path, "r", wait=5.0) as f:
            return sum(int(g.attrs.get("iteration", 0)) for g in f.values())
    except Exception:  # noqa: BLE001 - absent or damaged: nothing usable
        return 0


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
        unlink(self.tmp)  # left by a run killed in the middle of a copy

    def take(self, force: bool = False) -> None:
        """Copy ``chain.h5`` now if it is time (``force``: whatever the time)."""
        now = time.perf_counter()
        if not force and now < self.next:
            return
        try:
            size = self.path.stat().st_size
            if free_bytes(self.path.parent) < 2 * size + self.MARGIN:
                self.next = now + self.EVERY
                return
            shutil.copyfile(self.path, self.tmp)
            os.replace(self.tmp, self.copy)
            self.taken += 1
        except OSError:
            unlink(self.tmp)  # no room or no access: the run goes on without a new copy
        self.next = now + max(self.EVERY, 20.0 * (time.perf_counter() - now))

    def discard(self) -> None:
        """The run ended between two steps: ``chain.h5`` is whole, the copy not needed."""
        unlink(self.tmp)
        unlink(self.copy)


def recover_checkpoint(
    path: Path, *, n_walkers: int, ndim: int, n_ensembles: int
) -> tuple[dict[str, int], str | None]:
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
        return check_checkpoint(path, n_walkers=n_walkers, ndim=ndim, n_ensembles=n_ensembles), None
    except CheckpointDamaged as exc:
        if not copy.exists():
            raise
        damage = str(exc).split(";")[0]
        try:
            held = check_checkpoint(copy, n_walkers=n_walkers, ndim=ndim, n_ensembles=n_ensembles)
        except CheckpointError as other:
            raise CheckpointDamaged(
                f"{exc} (the copy {copy.name} beside it cannot serve "
                f"either: {str(other).split(';')[0]})"
            ) from None
    kept = path.with_name(path.name + ".damaged")
    k = 1
    while kept.exists():
        k += 1
        kept = path.with_name(f"{path.name}.damaged{k}")
    os.replace(path, kept)
    os.replace(copy, path)
    steps = ", ".join(f"{n} {v}" for n, v in sorted(held.items())) or "no step yet"
    note = (
        f"{damage}; it was killed while it wrote. Restored the copy kept beside it "
        f"(steps held: {steps}); the damaged file is kept as {kept.name} (delete it "
        "when you no longer need it). The steps after the copy are sampled again, the "
        "same steps with the same seed"
    )
    return held, note


def stored_moves(path: Path) -> dict[str, str]:
    """The moves each ensemble of ``path`` was sampled with (:data:`LEGACY_MOVES` for a
    group written before they were stored)."""
    import h5py

    if not Path(path).exists():
        return {}
    try:
        with h5py.File(path, "r") as f:
            return {
                k: str(g.attrs.get("moves", LEGACY_MOVES))
                for k, g in f.items()
                if int(g.attrs.get("iteration", 0)) > 0
            }
    except Exception:  # noqa: BLE001 - check_checkpoint says what is wrong with the file
        return {}


def save_settings(folder: Path, settings: dict) -> None:
    write_text_atomic(Path(folder) / "settings.json", json.dumps(settings, indent=2))

"""Opening ``chain.h5`` while another program reads it: HDF5 locks the file, and a reader
(emcee's ``HDFBackend`` or h5py in a notebook peeking at the chains) makes a write fail at
once; every opening here waits the lock out for a while instead."""

from __future__ import annotations

import errno
import time
from collections.abc import Callable

import emcee

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
                    errno.EAGAIN,
                    f"{path}: another program has held the file open for "
                    f"{wait:.0f} s (reading the chains while they are written?); every "
                    "finished step is kept. Close it there, then continue with --resume",
                ) from None
        time.sleep(pause)
        pause = min(2 * pause, 0.5)


class WaitingBackend(emcee.backends.HDFBackend):
    """emcee's HDF5 backend whose every opening waits out another reader's lock."""

    def open(self, mode="r"):
        return _waiting(
            lambda: emcee.backends.HDFBackend.open(self, mode), self.filename, LOCK_WAIT
        )

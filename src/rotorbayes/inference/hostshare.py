"""The cores of one host, shared by the tasks of every Dask worker on it.

A local process pool shares its machine's cores among the tasks running now (each gets
``cores // running`` numba threads inside its kernel batches): when the last starts of a
multistart run alone, they take the idle cores.  A Dask worker knows only its own threads;
sixteen one-thread workers on one host left the last starts on one core each while fifteen
sat idle.  :class:`HostShare` keeps, per host and per scheduler, two counters every worker
on the host sees: the threads the workers brought (``--nthreads``; dask-jobqueue's
``cores / processes``), and the tasks running.  A task's share is the first (at most the
cores this process may run on, and numba's thread count) divided by the second.

The counters live in a small file under the temporary directory (``rotorbayes-UID/``), a
slot per worker (its process id, its threads, its tasks running), mapped into each worker
and changed under an exclusive lock (``fcntl``).  The slot of a worker whose process is
gone (killed in a task) no longer counts from the next task's start on, and is reused.
Where ``fcntl`` or the directory is not available, :func:`open_host_share` gives None and
each worker shares its own threads only.  Whatever the share, the results are the same
bits: the kernel's batches and the triangle give the same bits on any thread count.
"""

from __future__ import annotations

import contextlib
import hashlib
import mmap
import os
import struct
import tempfile
from pathlib import Path

#: A worker's slot: its process id, the threads it brought, its tasks running now.
_SLOT = struct.Struct("qqq")
#: Workers one host's file holds (a 256-core node of one-thread workers).
SLOTS = 256


def usable_cores() -> int:
    """Cores this process may run on (its affinity: a batch job's allocation)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def _alive(pid: int) -> bool:
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # another user's process of that id: not one of ours, but alive
        return True
    return True


class HostShare:
    """This worker's slot among one scheduler's workers on this host (see the module's
    words); the slots of workers whose process is gone (killed in a task) do not count."""

    def __init__(self, path: Path, threads: int):
        import fcntl

        self._fcntl = fcntl
        self.path = path
        self._fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o600)
        size = SLOTS * _SLOT.size
        try:
            with self._locked():
                if os.fstat(self._fd).st_size < size:
                    os.ftruncate(self._fd, size)
            self._map = mmap.mmap(self._fd, size)
            with self._locked():
                free = [i for i in range(SLOTS) if not _alive(self._slot(i)[0])]
                if not free:
                    raise OSError("no free slot")
                self._i = free[0]
                _SLOT.pack_into(self._map, self._i * _SLOT.size, os.getpid(), max(1, threads), 0)
        except Exception:
            with contextlib.suppress(Exception):
                self._map.close()
            os.close(self._fd)
            raise
        self._cores = usable_cores()
        self._live: list[int] = []
        self._refresh()

    @contextlib.contextmanager
    def _locked(self):
        self._fcntl.flock(self._fd, self._fcntl.LOCK_EX)
        try:
            yield
        finally:
            self._fcntl.flock(self._fd, self._fcntl.LOCK_UN)

    def _slot(self, i: int) -> tuple[int, int, int]:
        return _SLOT.unpack_from(self._map, i * _SLOT.size)

    def _refresh(self) -> None:
        """Which slots are live workers' (checked when a task starts, not per batch)."""
        self._live = [i for i in range(SLOTS) if _alive(self._slot(i)[0])]

    def _add_running(self, d: int) -> None:
        with self._locked():
            pid, threads, running = self._slot(self._i)
            _SLOT.pack_into(self._map, self._i * _SLOT.size, pid, threads, running + d)

    def enter(self) -> None:
        self._add_running(1)
        self._refresh()

    def leave(self) -> None:
        self._add_running(-1)

    def threads(self) -> int:
        """This task's share: the live workers' threads on this host (at most its usable
        cores) over their tasks running now."""
        import numba

        threads = running = 0
        for i in self._live:
            _, t, n = self._slot(i)
            threads += t
            running += n
        cap = min(threads, self._cores, int(numba.config.NUMBA_NUM_THREADS))
        return max(1, cap // max(1, running))

    def close(self) -> None:
        """This worker leaves: its slot is freed; the last one removes the file."""
        with self._locked():
            _SLOT.pack_into(self._map, self._i * _SLOT.size, 0, 0, 0)
            if not any(_alive(self._slot(i)[0]) for i in range(SLOTS)):
                with contextlib.suppress(OSError):
                    self.path.unlink()
        self._map.close()
        os.close(self._fd)


def open_host_share(scheduler: str, threads: int) -> HostShare | None:
    """The host's share for the workers of the scheduler at ``scheduler``, this worker
    bringing ``threads``; None where it cannot be kept (no ``fcntl``, no writable
    temporary directory)."""
    try:
        folder = Path(tempfile.gettempdir()) / f"rotorbayes-{os.getuid()}"
        folder.mkdir(mode=0o700, exist_ok=True)
        key = hashlib.sha1(scheduler.encode()).hexdigest()[:16]
        return HostShare(folder / f"cores-{key}", threads)
    except (ImportError, AttributeError, OSError):
        return None


__all__ = ["HostShare", "open_host_share", "usable_cores"]

"""Disk room for a sampling run: a bound on what ``chain.h5`` grows to, its coming steps'
blocks owned before they are written, room held for the files written after the chains,
and the clean stop when the disk is nearly full anyway."""

from __future__ import annotations

import math
import os
from pathlib import Path

from ...util.exitcodes import EnvironmentFailure


def chain_bytes(n_walkers: int, ndim: int, n_steps: int, n_ensembles: int) -> int:
    """A generous bound on what ``chain.h5`` grows to: the chain and log-probability in
    float64 plus HDF5's bookkeeping per step (measured 4.5-7.2 kB a step for 10-64 walkers:
    every step is a chunk of its own)."""
    per_step = 8 * n_walkers * (ndim + 1) * 1.1 + 8192 + 64 * n_walkers
    return int(per_step * n_steps * n_ensembles) + 200_000


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
            unlink(path)  # no room (or no fallocate): this file goes without a reserve
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
            unlink(res)
            raise
        return target

    def close(self) -> None:
        """Give back the room of every file not written."""
        for name in list(self.held):
            unlink(self.path(name))
        self.held.clear()

    @classmethod
    def clear(cls, folder: Path) -> None:
        """Remove the reserves a killed run left in ``folder`` (free space, not results)."""
        for p in Path(folder).glob(f".*{cls.SUFFIX}"):
            unlink(p)


def unlink(path: Path) -> None:
    try:
        path.unlink(missing_ok=True)
    except OSError:
        pass


def free_bytes(folder: Path) -> float:
    try:
        st = os.statvfs(folder)
    except OSError:
        return math.inf
    return st.f_bavail * st.f_frsize if st.f_blocks > 0 else math.inf


def disk_full(path: Path, name: str, done: int, n_steps: int) -> EnvironmentFailure:
    """The clean stop between two steps when the disk of ``path`` is nearly full."""
    return EnvironmentFailure(
        f"{path.parent}: the disk is nearly full; sampling stopped after step {done} of "
        f"{n_steps} of {name} and every finished step is kept in {path}. Free some space "
        f"and continue with `rotorbayes sample {path.parent} --resume`"
    )

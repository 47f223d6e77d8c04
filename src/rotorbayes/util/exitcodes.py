"""What the ``rotorbayes`` command's exit code says: one table, used by every command.

=====  ===============================================================================
code   meaning
=====  ===============================================================================
0      done: the results are complete in the output folder
1      ran to the end and wrote its results, but the fit did not converge
2      refused: bad input (a file, an option, an analysis file, a damaged checkpoint, a
       result folder that is not ours); nothing was written or changed
3      the environment failed: the disk is full, a folder is not writable, a read or
       write failed; the message names the file, earlier results are left as they were
4      busy: another rotorbayes process is working on the same result folder, or another
       program held ``chain.h5`` open for over a minute; wait for it (or stop it) and
       run again
130    interrupted (Ctrl-C or SIGTERM); the message says what was kept and how to go on
141    the reader of the output went away (e.g. ``| head``); not an error of ours
=====  ===============================================================================

``docs/cli.md`` and the README show the same table.
"""

from __future__ import annotations

import errno

DONE = 0
NOT_CONVERGED = 1
REFUSED = 2
ENVIRONMENT = 3
BUSY = 4
INTERRUPTED = 130
BROKEN_PIPE = 141

#: The table above as (code, meaning) rows (for ``--help`` and the docs test).
TABLE = (
    (DONE, "done"),
    (NOT_CONVERGED, "ran, but the fit did not converge (results written)"),
    (REFUSED, "refused input; nothing written or changed"),
    (ENVIRONMENT, "environment or I/O failure (disk full, folder not writable)"),
    (
        BUSY,
        "another rotorbayes process works on the same result folder, or another "
        "program holds chain.h5 open",
    ),
    (INTERRUPTED, "interrupted; the message says what was kept"),
    (BROKEN_PIPE, "the output's reader went away"),
)


class Refused(Exception):
    """The user's input is refused (an option, a file, a folder): exit code 2.

    The message names the value and says what to give instead; nothing was written.
    """


class Interrupted(Exception):
    """Ctrl-C, reported in one message (what was kept, how to continue): exit code 130."""


class EnvironmentFailure(Exception):
    """The machine, not the input, failed (disk full, no permission...): exit code 3.

    The message names the file and what to do.
    """


class Busy(Exception):
    """Another process holds the result folder's lock: exit code 4."""


#: errno values that are the environment's fault, not the user's input.
ENVIRONMENT_ERRNOS = frozenset(
    {
        errno.ENOSPC,
        errno.EDQUOT,
        errno.EROFS,
        errno.EACCES,
        errno.EPERM,
        errno.EIO,
        errno.EMFILE,
        errno.ENFILE,
        errno.ENOMEM,
        errno.EFBIG,
        errno.ESTALE,
    }
)


def is_disk_full(exc: BaseException) -> bool:
    """True for ENOSPC/EDQUOT, also when a library (h5py, netCDF) only says it in words."""
    if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return True
    text = str(exc)
    return "No space left on device" in text or "errno = 28" in text or "Disk quota" in text


def describe_environment(exc: BaseException, path=None) -> str:
    """A plain message for an environment failure on ``path`` (or the exception's file)."""
    where = path if path is not None else getattr(exc, "filename", None)
    where = f"{where}: " if where else ""
    if is_disk_full(exc):
        return (
            f"{where}the disk is full (no space left on the device); free some space (or "
            "choose an output folder on another disk) and run again"
        )
    if isinstance(exc, OSError) and exc.errno in (errno.EACCES, errno.EPERM):
        return (
            f"{where}permission denied; check the permissions of the file and its "
            "folder (or choose another path) and run again"
        )
    if isinstance(exc, OSError) and exc.errno == errno.EROFS:
        return f"{where}the file system is read-only; choose an output folder elsewhere"
    what = getattr(exc, "strerror", None) or str(exc) or type(exc).__name__
    return f"{where}{what}; check the disk and the folder's permissions and run again"


def exiting_after_command() -> None:
    """Called when a command has finished and said so (whatever its exit code).

    A Ctrl-C from then on could only kill the interpreter while it exits (Python restores
    the default handler there), so the process would die by SIGINT after a complete,
    reported result.  In the ``rotorbayes`` process itself SIGINT is ignored from here on;
    Python code that calls :func:`rotorbayes.cli.main` keeps its handler.
    """
    import signal

    from .coldstart import launched_as_command

    forget_caught_ctrl_c()
    if launched_as_command():
        signal.signal(signal.SIGINT, signal.SIG_IGN)


def forget_caught_ctrl_c() -> None:
    """Make sure a Ctrl-C the command caught and reported does not kill the process at exit.

    CPython remembers, in a flag of its own, when code run by ``exec`` or ``eval`` of a
    string ended with a KeyboardInterrupt, even when a caller then caught it; under
    ``python -m`` the interpreter reads that flag as it exits and kills itself by SIGINT
    (exit -2) whatever exit code the program chose.  numba and the standard library run such
    strings while a command works (generated wrappers, named tuples), so a Ctrl-C landing in
    one, caught and reported by the command, ended ``python -m rotorbayes.cli`` by SIGINT
    after its message (1 of 6 stops in a CI run on 3.13).  Every string evaluation resets
    the flag as it starts, so evaluating one that ends normally clears it."""
    exec("None", {})  # a constant string: it resets that flag and does nothing else

"""Output files and folders that appear whole or not at all.

* :func:`output_folder` builds a result folder (``fit``, ``multistart``, ``demo``) in a hidden
  temporary sibling ``.{name}.partial-XXXX`` and moves it into place only when the block ends
  without an exception; with ``force`` an earlier folder of that name is replaced only then.
  A failed or interrupted run leaves neither an empty nor a half-written folder behind (nor
  the parent folders it had to create).
* ``force`` replaces only what rotorbayes wrote (:func:`check_replaceable`): an empty folder,
  or a result folder, recognised by the :data:`MARKER` file every result folder gets, or
  (from earlier versions) by one of :data:`RESULT_FILES`. A folder of the user's own files,
  the working folder or a folder above it, and a folder holding one of the command's
  inputs are refused, with or without ``force``. A symbolic link given as the folder is
  followed: the folder it points to is written (or replaced), never the link.
* :func:`write_text_atomic` and :func:`save_figure_atomic` write one file through a
  temporary file in the same folder and :func:`os.replace`, so a reader never sees half a
  file and a failure leaves the old file (or none) in place.

* :func:`folder_lock` is the one lock of a result folder (``flock`` on a hidden sibling file
  ``.NAME.lock``): a second process that wants the same folder is refused at once with
  :class:`~rotorbayes.util.exitcodes.Busy`. :func:`output_folder` takes it, and under it removes
  the ``.NAME.partial-*`` folders an earlier killed run left behind (and says so).
* :class:`InterruptGuard` turns Ctrl-C into a flag while results are being written, so an
  interrupt after the work is done keeps the work.
* :func:`check_free_space` refuses, before any work, a folder whose disk cannot hold the
  results (:class:`~rotorbayes.util.exitcodes.EnvironmentFailure`, exit code 3).

Errors a user can fix (the path is a file, a folder holds earlier results, a parent folder is
missing) raise :class:`OutputError` with the path and the fix in the message.
"""

from __future__ import annotations

import contextlib
import fcntl
import glob
import os
import secrets
import shutil
import signal
import sys
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path

from ..util.exitcodes import Busy, EnvironmentFailure, describe_environment

__all__ = [
    "OutputError",
    "output_folder",
    "check_output_file",
    "write_text_atomic",
    "save_figure_atomic",
    "PARTIAL_TAG",
    "folder_lock",
    "clean_stale",
    "InterruptGuard",
    "check_free_space",
    "MIN_FREE_BYTES",
    "MARKER",
    "RESULT_FILES",
    "result_mark",
    "check_replaceable",
    "follow_link",
]

#: Part of the name of the temporary folder a result is built in (``.NAME.partial-XXXX``).
PARTIAL_TAG = ".partial-"


class OutputError(ValueError):
    """An output path that cannot be used; the message names it and says what to do."""


def _missing_parents(path: Path) -> list[Path]:
    """The ancestors of ``path`` that do not exist, outermost first."""
    missing = []
    p = path.parent
    while not p.exists():
        missing.append(p)
        if p.parent == p:
            break
        p = p.parent
    return missing[::-1]


#: The file every result folder gets (:func:`output_folder` writes it first): ``--force``
#: replaces a folder that holds it.
MARKER = ".rotorbayes"
MARKER_TEXT = "A result folder written by rotorbayes: `--force` may replace this folder whole.\n"
#: The documents that mark a result folder from a version that wrote no :data:`MARKER`
#: (each command's main document, a study's record, a posterior's chain and samples).
RESULT_FILES = (
    "fit.json",
    "multistart.json",
    "diagnosis.json",
    "compare.json",
    "identify.json",
    "design.json",
    "run.json",
    "chain.h5",
    "posterior.nc",
)
#: Entries of a folder named in a message (then "... N entries").
_SHOWN = 4


def result_mark(folder: str | os.PathLike) -> str | None:
    """The file that marks ``folder`` as a result rotorbayes wrote (:data:`MARKER`, one of
    :data:`RESULT_FILES`, or a sample's ``settings.json``), "empty" for an empty folder,
    None for a folder of anything else (a missing folder: None)."""
    folder = Path(folder)
    try:
        if not any(folder.iterdir()):
            return "empty"
    except OSError:
        return None
    for name in (MARKER, *RESULT_FILES):
        if (folder / name).is_file():
            return name
    if _is_sample_settings(folder / "settings.json"):
        return "settings.json"
    return None


def _is_sample_settings(path: Path) -> bool:
    """Whether ``path`` is the settings.json of ``rotorbayes sample`` (a small JSON object
    naming the fit, the walkers and the steps): a sample stopped before its first step
    holds nothing else."""
    import json

    try:
        if not path.is_file() or path.stat().st_size > 1_000_000:
            return False
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(doc, dict) and {"fit", "walkers", "steps"} <= set(doc)


def _contents(folder: Path) -> str:
    """The first few entries of ``folder`` for a message: "thesis.tex, chapters/, ..."."""
    try:
        names = sorted(p.name + ("/" if p.is_dir() else "") for p in folder.iterdir())
    except OSError:
        return "unreadable entries"
    more = f", ... ({len(names)} entries)" if len(names) > _SHOWN else ""
    return ", ".join(names[:_SHOWN]) + more


def _input_paths(inputs) -> list[Path]:
    """The files and folders among a command's ``inputs`` (option values: paths, lists of
    them, ``FILE.py:NAME`` effects, named sets and ``example:NAME`` that are no file)."""
    out: list[Path] = []
    for spec in inputs or ():
        if spec is None:
            continue
        if isinstance(spec, list | tuple | set):
            out += _input_paths(spec)
            continue
        text = os.fspath(spec)
        if not isinstance(text, str) or text.startswith("example:"):
            continue
        p = Path(text)
        if not os.path.lexists(p) and ":" in text:  # an effect: FILE.py:NAME
            p = Path(text.rsplit(":", 1)[0])
        if os.path.lexists(p):
            out.append(p)
    return out


def check_replaceable(
    out: str | os.PathLike, force: bool, *, flag: str = "--out", inputs=()
) -> None:
    """Refuse (:class:`OutputError`, exit code 2), before any work, a result folder ``out``
    that must not be written or replaced.

    Refused with or without ``force``: the working folder or a folder above it; a folder
    that holds one of the command's ``inputs`` (paths, or lists of them: the data files,
    ``--p0``, a fit folder read...), or is one; a folder of anything but a result
    (:func:`result_mark` is None: the user's own files). Without ``force`` also a result
    folder that is not empty. A missing or empty folder is fine.
    """
    out = Path(out)
    target = Path(os.path.realpath(out))
    try:
        here = Path.cwd().resolve()
    except OSError:  # the working folder was removed: nothing of it to protect
        here = None
    if here is not None and (target == here or target in here.parents):
        where = "the working folder" if target == here else "a folder above the working folder"
        raise OutputError(
            f"{flag} {out}: is {where} ({target}); results go into a folder of their own, "
            f"which --force may later replace whole -- give a new folder name (e.g. {flag} "
            "results); nothing was changed"
        )
    for p in _input_paths(inputs):
        rp = Path(os.path.realpath(p))
        if rp == target or target in rp.parents:
            what = "is" if rp == target else "holds"
            raise OutputError(
                f"{flag} {out}: {what} {p}, an input of this command; the results would "
                f"replace it -- write them into another folder (give another {flag}); "
                "nothing was changed"
            )
    if not out.is_dir():
        return
    mark = result_mark(out)
    if mark == "empty":
        return
    if mark is None:
        raise OutputError(
            f"{flag} {out}: the folder holds files rotorbayes did not write ("
            f"{_contents(out)}); --force replaces only a result folder rotorbayes wrote (or "
            f"an empty one) -- give a new folder name for the results; nothing was changed"
        )
    if not force:
        raise OutputError(
            f"{out}/ already holds results ({mark}); choose another {flag} or pass --force "
            "to replace them"
        )


def follow_link(out: Path, flag: str) -> Path:
    """``out``, or the folder it links to (a link is followed, never replaced)."""
    if not out.is_symlink():
        return out
    target = Path(os.path.realpath(out))
    if not target.parent.is_dir():
        raise OutputError(
            f"{flag} {out}: is a link to {target}, whose folder "
            f"{target.parent}/ does not exist; create it, or give another "
            f"{flag}"
        )
    return target


def _check_folder_target(out: Path, force: bool, flag: str, inputs=()) -> None:
    if out.exists() and not out.is_dir():
        raise OutputError(
            f"{flag} {out}: is a file, not a folder; results are written into a folder -- "
            f"give a new folder name (e.g. {flag} {out.with_suffix('')}_out)"
        )
    check_replaceable(out, force, flag=flag, inputs=inputs)
    for p in (out.parent, *out.parents):
        if p.exists():
            if not p.is_dir():
                raise OutputError(
                    f"{flag} {out}: {p} is a file, not a folder; choose another {flag}"
                )
            break


@contextlib.contextmanager
def output_folder(
    path: str | os.PathLike, force: bool = False, *, flag: str = "--out", inputs=()
) -> Iterator[Path]:
    """Build a result folder in a temporary sibling and move it to ``path`` on success.

    Parameters
    ----------
    path : str or os.PathLike
        The folder the results end up in. Missing parent folders are created (and removed
        again if the run fails).
    force : bool
        Replace an existing folder that holds results (at the end, after success). Without it
        such a folder is an error, raised before any work is done. Only a result folder is
        replaced (:func:`check_replaceable`): a folder of other files is refused either way.
    flag : str
        The option named in messages.
    inputs : sequence
        The command's inputs (paths, or lists of them; values that are no file are
        skipped): a folder that holds one is refused.

    Yields
    ------
    pathlib.Path
        The temporary folder to write into.

    Raises
    ------
    OutputError
        If ``path`` is a file, or holds results and ``force`` is false, or holds anything
        but results, or is the working folder (or above it), or holds an input, or a parent
        is a file.

    Notes
    -----
    On any exception, ``KeyboardInterrupt`` included, the temporary folder is removed and the
    exception propagates. A caller that wants to keep partial results after Ctrl-C (e.g.
    the finished starts of a multistart) catches the interrupt inside the block, writes what
    it has and leaves the block normally.
    """
    out = follow_link(Path(path), flag)
    _check_folder_target(out, force, flag, inputs)
    created = _missing_parents(out)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        _remove_created(created)
        raise EnvironmentFailure(
            f"{flag} {out}: cannot create the folder {out.parent} ("
            f"{describe_environment(exc, '')}); choose another {flag}"
        ) from None
    try:
        with folder_lock(out, flag=flag, other=flag):
            # Again, under the lock: another run may have finished meanwhile.
            _check_folder_target(out, force, flag, inputs)
            clean_stale(out)
            check_free_space(out.parent, MIN_FREE_BYTES, what=f"{flag} {out}")
            try:
                tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}{PARTIAL_TAG}", dir=out.parent))
            except OSError as exc:
                raise EnvironmentFailure(
                    f"{flag} {out}: cannot write into {out.parent} ("
                    f"{describe_environment(exc, '')}); choose another "
                    f"{flag}"
                ) from None
            # mkdtemp makes the folder private (0700); a result folder gets the usual
            # permissions.
            with contextlib.suppress(OSError):
                umask = os.umask(0)
                os.umask(umask)
                os.chmod(tmp, 0o777 & ~umask)
            try:
                # The mark that lets a later --force replace this folder (and nothing else).
                (tmp / MARKER).write_text(MARKER_TEXT, encoding="utf-8")
                yield tmp
                _move_into_place(tmp, out, force, flag)
            except BaseException:
                shutil.rmtree(tmp, ignore_errors=True)
                raise
    except BaseException:
        _remove_created(created)
        raise


#: Free space a result folder's disk must have before a run starts (bytes). A fit folder
#: with its figures takes about 0.2-1 MB; runs that know their size ask for more.
MIN_FREE_BYTES = 2_000_000


def check_free_space(folder: str | os.PathLike, need: int, *, what: str) -> None:
    """Refuse (:class:`EnvironmentFailure`) when ``folder``'s disk has less than ``need``
    bytes free: better before the work than a disk-full error after it."""
    try:
        st = os.statvfs(folder)
    except OSError:
        return  # no statistics (an exotic file system): the writes will tell
    free = st.f_bavail * st.f_frsize
    if st.f_blocks > 0 and free < need:
        raise EnvironmentFailure(
            f"{what}: the disk of {folder} has {free / 1e6:.2f} MB free, less than the "
            f"{need / 1e6:.2f} MB the results need; free some space or choose a folder on "
            "another disk (nothing was written)"
        )


#: Locks this process holds (a command that locks a folder twice does not block itself).
_HELD: dict[str, int] = {}


def _lock_path(out: Path) -> Path:
    return out.parent / f".{out.name}.lock"


@contextlib.contextmanager
def folder_lock(
    path: str | os.PathLike, *, flag: str = "--out", other: str | None = "--out"
) -> Iterator[None]:
    """Hold the one lock of result folder ``path`` (its parent folder must exist).

    ``flag`` starts the messages about the folder ("--out"); ``other`` is what the user may
    change to write elsewhere (None: nothing to choose).

    The lock is ``flock`` on ``.NAME.lock`` beside the folder; it is released (and the file
    removed) when the block ends, and by the kernel when the process dies, even by SIGKILL.
    Raises :class:`Busy` when another process holds it, :class:`EnvironmentFailure` when the
    lock file cannot be made.
    """
    out = Path(path)
    key = str(out.absolute())
    if key in _HELD:
        yield
        return
    lock = _lock_path(out)
    while True:
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o666)
        except OSError as exc:
            raise EnvironmentFailure(
                f"{flag} {out}: cannot make the lock file {lock} ({describe_environment(exc, '')})"
            ) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            try:
                owner = os.read(fd, 64).decode(errors="replace").strip()
            except OSError:
                owner = ""
            os.close(fd)
            who = f" (process {owner})" if owner.isdigit() else ""
            raise Busy(
                f"{out}/ is in use by another rotorbayes process{who}; two runs must "
                "not write one result folder. Wait for it to finish (or stop it) and "
                "run again" + (f", or choose another {other}" if other else "")
            ) from None
        # The holder before us may have removed the file between our open and our lock.
        try:
            same = os.stat(lock).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    with contextlib.suppress(OSError):
        os.ftruncate(fd, 0)
        os.write(fd, str(os.getpid()).encode())
    _HELD[key] = fd
    try:
        yield
    finally:
        del _HELD[key]
        with contextlib.suppress(OSError):
            os.unlink(lock)
        os.close(fd)


def clean_stale(out: Path) -> list[str]:
    """Remove what a killed run left beside ``out`` (call it under :func:`folder_lock`).

    ``.NAME.partial-*`` folders are unfinished results: removed. ``.NAME.old-*`` is an
    earlier result moved aside while a new one was put in place: put back when ``out`` is
    missing (a kill between the two renames), else removed. Says what it did on stderr.
    """
    done = []
    for p in sorted(out.parent.glob(f".{out.name}{PARTIAL_TAG}*")):
        shutil.rmtree(p, ignore_errors=True)
        done.append(f"removed {p.name}/, an unfinished result left by an interrupted run")
    for p in sorted(out.parent.glob(f".{out.name}.old-*")):
        if not out.exists():
            os.rename(p, out)
            done.append(f"restored {out}/ from {p.name}/ (a run was killed while replacing it)")
        else:
            shutil.rmtree(p, ignore_errors=True)
            done.append(f"removed {p.name}/, a replaced result a killed run had not yet deleted")
    for msg in done:
        print(f"note: {msg}", file=sys.stderr)
    return done


class InterruptGuard:
    """While started, Ctrl-C (SIGINT) is recorded instead of raised.

    Use it from the moment the work is done until its results are in place, then
    :meth:`stop`: :attr:`hit` says whether the user asked to stop meanwhile. A guard
    started outside the main thread does nothing (signals go to the main thread).
    """

    def __init__(self) -> None:
        self.hit = 0
        self._old = None
        self._on = False

    def _handler(self, signum, frame) -> None:
        self.hit += 1

    def start(self) -> InterruptGuard:
        if not self._on and threading.current_thread() is threading.main_thread():
            self._old = signal.signal(signal.SIGINT, self._handler)
            self._on = True
        return self

    def stop(self) -> int:
        if self._on:
            signal.signal(signal.SIGINT, self._old)
            self._on = False
        return self.hit

    def __enter__(self) -> InterruptGuard:
        return self  # ``with guard:`` only makes sure it is stopped at the block's end

    def __exit__(self, *exc) -> None:
        self.stop()


def _move_into_place(tmp: Path, out: Path, force: bool, flag: str) -> None:
    old = None
    if out.is_dir():
        mark = result_mark(out)
        if mark is None:  # files put there while we worked
            raise OutputError(
                f"{flag} {out}: the folder now holds files rotorbayes did not "
                f"write ({_contents(out)}), put there while this run worked; "
                f"they were left as they are -- run again with another {flag}"
            )
        if mark != "empty" and not force:  # appeared while we worked
            raise OutputError(
                f"{out}/ already holds results (written while this run "
                f"worked); choose another {flag} or pass --force"
            )
        old = out.with_name(f".{out.name}.old-{secrets.token_hex(4)}")
        os.rename(out, old)
    elif out.exists():
        raise OutputError(f"{flag} {out}: is a file, not a folder; give a new folder name")
    try:
        os.rename(tmp, out)
    except OSError:
        if old is not None:
            os.rename(old, out)  # put the earlier results back
        raise
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def _remove_created(created: list[Path]) -> None:
    """Remove the parent folders this run created, innermost first, if still empty."""
    for p in reversed(created):
        try:
            p.rmdir()
        except OSError:
            break


def check_output_file(
    path: str | os.PathLike, *, flag: str, force: bool = False, example: str = "out.csv"
) -> Path:
    """Refuse, before any work, an output file whose folder is missing or that exists.

    Returns the path. Raises :class:`OutputError` naming the path and the fix.
    """
    p = Path(path)
    folder = p.parent
    if p.is_dir():
        raise OutputError(f"{flag} {p}: is a folder; give a file name (e.g. {flag} {p / example})")
    if not folder.is_dir():
        what = "is a file, not a folder" if folder.exists() else "does not exist"
        raise OutputError(
            f"{flag} {p}: the folder {folder}/ {what}; create it first "
            f"(mkdir -p {folder}) or choose another {flag}"
        )
    if p.exists() and not force:
        raise OutputError(
            f"{flag} {p}: the file exists; choose another {flag} or pass --force to overwrite it"
        )
    if not os.access(folder, os.W_OK):
        raise EnvironmentFailure(
            f"{flag} {p}: the folder {folder}/ is not writable (permission"
            f" denied); make it writable or choose another {flag}"
        )
    return p


def tmp_name(path: Path) -> Path:
    """A hidden temporary name beside ``path`` (same folder, so a rename puts it in place).

    Temporary files of ``path`` left by a process that no longer runs (a SIGKILL between
    the write and the rename) are removed first."""
    for old in path.parent.glob(f".{glob.escape(path.stem)}.*.tmp{glob.escape(path.suffix)}"):
        pid = old.name[len(path.stem) + 2 :].split(".", 1)[0]
        if pid.isdigit() and not _alive(int(pid)):
            with contextlib.suppress(OSError):
                old.unlink()
    return path.with_name(f".{path.stem}.{os.getpid()}.{secrets.token_hex(4)}.tmp{path.suffix}")


def _alive(pid: int) -> bool:
    """Whether a process ``pid`` runs on this machine (this one always does)."""
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # another user's process, or not allowed to ask: keep its files
        return True
    return True


def write_text_atomic(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` to ``path`` through a temporary file beside it and a rename."""
    path = Path(path)
    tmp = tmp_name(path)
    try:
        with open(tmp, "w", encoding="utf-8", newline="\n") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
    return path


def save_figure_atomic(fig, path: str | os.PathLike, *, dpi: int = 100, close: bool = True) -> Path:
    """``fig.savefig(path)`` through a temporary file beside it and a rename.

    The format comes from ``path``'s suffix (the temporary file keeps it).
    """
    path = Path(path)
    tmp = tmp_name(path)
    try:
        fig.savefig(tmp, dpi=dpi, format=path.suffix[1:] or None)
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        if close:
            import matplotlib.pyplot as plt

            plt.close(fig)
    return path

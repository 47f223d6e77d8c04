"""Output files and folders that appear whole or not at all.

* :func:`output_folder` builds a result folder (``fit``, ``multistart``, ``demo``) in a hidden
  temporary sibling ``.{name}.partial-XXXX`` and moves it into place only when the block ends
  without an exception; with ``force`` an earlier folder of that name is replaced only then.
  A failed or interrupted run leaves neither an empty nor a half-written folder behind (nor
  the parent folders it had to create).
* :func:`write_text_atomic` and :func:`save_figure_atomic` write one file through a
  temporary file in the same folder and :func:`os.replace`, so a reader never sees half a
  file and a failure leaves the old file (or none) in place.

Errors a user can fix (the path is a file, a folder holds earlier results, a parent folder is
missing) raise :class:`OutputError` with the path and the fix in the message.
"""

from __future__ import annotations

import contextlib
import os
import secrets
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

__all__ = [
    "OutputError",
    "output_folder",
    "check_output_file",
    "write_text_atomic",
    "save_figure_atomic",
    "PARTIAL_TAG",
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


def _check_folder_target(out: Path, force: bool, flag: str) -> None:
    if out.exists() and not out.is_dir():
        raise OutputError(
            f"{flag} {out}: is a file, not a folder; results are written into a folder -- "
            f"give a new folder name (e.g. {flag} {out.with_suffix('')}_out)"
        )
    if out.is_dir() and any(out.iterdir()) and not force:
        raise OutputError(
            f"{out}/ already holds results; choose another {flag} or pass --force to "
            "replace them"
        )
    for p in (out.parent, *out.parents):
        if p.exists():
            if not p.is_dir():
                raise OutputError(f"{flag} {out}: {p} is a file, not a folder; choose "
                                  f"another {flag}")
            break


@contextlib.contextmanager
def output_folder(path: str | os.PathLike, force: bool = False, *,
                  flag: str = "--out") -> Iterator[Path]:
    """Build a result folder in a temporary sibling and move it to ``path`` on success.

    Parameters
    ----------
    path : str or os.PathLike
        The folder the results end up in. Missing parent folders are created (and removed
        again if the run fails).
    force : bool
        Replace an existing folder that holds results (at the end, after success). Without it
        such a folder is an error, raised before any work is done.
    flag : str
        The option named in messages.

    Yields
    ------
    pathlib.Path
        The temporary folder to write into.

    Raises
    ------
    OutputError
        If ``path`` is a file, or holds results and ``force`` is false, or a parent is a file.

    Notes
    -----
    On any exception, ``KeyboardInterrupt`` included, the temporary folder is removed and the
    exception propagates. A caller that wants to keep partial results after Ctrl-C (e.g.
    the finished starts of a multistart) catches the interrupt inside the block, writes what
    it has and leaves the block normally.
    """
    out = Path(path)
    _check_folder_target(out, force, flag)
    created = _missing_parents(out)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        _remove_created(created)
        raise OutputError(f"{flag} {out}: cannot create the folder {out.parent} "
                          f"({exc.strerror}); choose another {flag}") from None
    try:
        tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}{PARTIAL_TAG}", dir=out.parent))
    except OSError as exc:
        _remove_created(created)
        raise OutputError(f"{flag} {out}: cannot write into {out.parent} ({exc.strerror}); "
                          f"choose another {flag}") from None
    # mkdtemp makes the folder private (0700); a result folder gets the usual permissions.
    with contextlib.suppress(OSError):
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o777 & ~umask)
    try:
        yield tmp
        _move_into_place(tmp, out, force, flag)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        _remove_created(created)
        raise


def _move_into_place(tmp: Path, out: Path, force: bool, flag: str) -> None:
    old = None
    if out.is_dir():
        if any(out.iterdir()) and not force:  # appeared while we worked
            raise OutputError(f"{out}/ already holds results (written while this run "
                              f"worked); choose another {flag} or pass --force")
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


def check_output_file(path: str | os.PathLike, *, flag: str, force: bool = False,
                      example: str = "out.csv") -> Path:
    """Refuse, before any work, an output file whose folder is missing or that exists.

    Returns the path. Raises :class:`OutputError` naming the path and the fix.
    """
    p = Path(path)
    folder = p.parent
    if p.is_dir():
        raise OutputError(f"{flag} {p}: is a folder; give a file name (e.g. {flag} "
                          f"{p / example})")
    if not folder.is_dir():
        what = "is a file, not a folder" if folder.exists() else "does not exist"
        raise OutputError(f"{flag} {p}: the folder {folder}/ {what}; create it first "
                          f"(mkdir -p {folder}) or choose another {flag}")
    if p.exists() and not force:
        raise OutputError(f"{flag} {p}: the file exists; choose another {flag} or pass "
                          "--force to overwrite it")
    if not os.access(folder, os.W_OK):
        raise OutputError(f"{flag} {p}: the folder {folder}/ is not writable; choose "
                          f"another {flag}")
    return p


def _tmp_name(path: Path) -> Path:
    return path.with_name(f".{path.stem}.{os.getpid()}.{secrets.token_hex(4)}.tmp{path.suffix}")


def write_text_atomic(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` to ``path`` through a temporary file beside it and a rename."""
    path = Path(path)
    tmp = _tmp_name(path)
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


def save_figure_atomic(fig, path: str | os.PathLike, *, dpi: int = 100,
                       close: bool = True) -> Path:
    """``fig.savefig(path)`` through a temporary file beside it and a rename.

    The format comes from ``path``'s suffix (the temporary file keeps it).
    """
    path = Path(path)
    tmp = _tmp_name(path)
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

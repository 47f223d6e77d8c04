"""The ``rotorbayes`` command line: a table of commands and their exit codes.

Each command is a module of :mod:`rotorbayes.commands`, named after it, with

* ``HELP`` — one line for ``rotorbayes --help``;
* ``add_arguments(parser)`` — its options (argparse; ``--max-nfev`` arrives as
  ``max_nfev``);
* a function of the command's name that takes those options as keyword arguments and
  returns an :class:`~rotorbayes.commands.common.Outcome` (exit code, the folder written,
  its main document).  Python users call the same function.

This module only parses the arguments, calls that function with every option the parser
produced (a missing or extra keyword is a TypeError at once, never a silently ignored
option), appends what the command printed to ``log.txt`` in the folder it wrote, and turns
exceptions into messages and exit codes (:mod:`rotorbayes.util.exitcodes`).

Adding a command ``NAME``
-------------------------
1. Write ``src/rotorbayes/commands/NAME.py`` with ``HELP``, ``add_arguments(parser)`` and
   ``def NAME(...) -> Outcome`` (see ``commands/report.py`` for a small one; shared option
   groups and number types are in :mod:`rotorbayes.commands.options`).  Raise
   :class:`~rotorbayes.util.exitcodes.Refused` for bad input (exit code 2, no traceback).
2. Add ``"NAME"`` to :data:`COMMANDS` below.  Nothing else here changes; the docs' command
   reference (``docs/cli.md``) is generated from this parser.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import sys
import warnings
from pathlib import Path

from .io.measurements import DataFileError
from .io.outputs import OutputError
from .model import ParameterError, SimulationError
from .util import exitcodes as EXIT

DESCRIPTION = (
    "Bayesian parameter inference for the TU Eindhoven drill-string rig. The loop: fit "
    "(a start from the data), compare and diagnose (is the error noise? which effect is "
    "missing?), fit --add EFFECT, sample and identify, report; or all of it from one "
    "analysis file with run, or on the bundled data with demo."
)

#: The commands, in the order ``rotorbayes --help`` lists them: each NAME is the module
#: ``rotorbayes.commands.NAME`` and its function ``NAME``.
COMMANDS = (
    "simulate",
    "fit",
    "multistart",
    "demo",
    "run",
    "diagnose",
    "compare",
    "sample",
    "identify",
    "design",
    "report",
    "params",
    "effects",
)

#: Errors that are the user's input (exit code 2): printed as one line, no traceback.
#: (A result folder that cannot be read, rotorbayes.inference.results.ResultError, is a
#: ValueError.)
REFUSED = (
    EXIT.Refused,
    DataFileError,
    ParameterError,
    ValueError,
    FileExistsError,
    SimulationError,
    OutputError,
)


def command_module(name: str):
    """The module of the command ``name`` (``rotorbayes.commands.NAME``)."""
    return importlib.import_module(f"{__package__}.commands.{name}")


class _Formatter(argparse.HelpFormatter):
    """Help that shows each option's default (unless it is None/False or already named)."""

    def _get_help_string(self, action):
        text = action.help or ""
        if (
            "%(default)" in text
            or "default" in text
            or action.default is None
            or action.default is False
            or action.default is argparse.SUPPRESS
            or not action.option_strings
            or not text
            # A --no-X switch (store_false) defaults to doing X: "(default: True)" beside
            # "skip X" read as if X were off by default.
            or isinstance(action, argparse._StoreFalseAction)
        ):
            return text
        return f"{text} (default: %(default)s)"


class _Parser(argparse.ArgumentParser):
    """One-line usage errors: ``rotorbayes CMD: error: ...`` and exit code 2; help that
    shows the defaults (also for the subcommands, which are made with this class)."""

    def __init__(self, *args, **kw):
        kw.setdefault("formatter_class", _Formatter)
        super().__init__(*args, **kw)

    def add_argument(self, *args, **kw):
        # An option without help text would hide its default; give it one that shows it.
        default = kw.get("default")
        if (
            kw.get("help") is None
            and args
            and str(args[0]).startswith("-")
            and default is not None
            and default is not False
        ):
            kw["help"] = "(default: %(default)s)"
        return super().add_argument(*args, **kw)

    def error(self, message):
        sys.stderr.write(f"{self.prog}: error: {message} (see `{self.prog} --help`)\n")
        sys.exit(2)


def build_parser() -> argparse.ArgumentParser:
    """The ``rotorbayes`` parser: one subcommand per entry of :data:`COMMANDS`."""
    from .util import __version__

    ap = _Parser(prog="rotorbayes", description=DESCRIPTION)
    ap.add_argument(
        "--version",
        action="version",
        version=f"%(prog)s {__version__}",
        help="print the version and exit",
    )
    sub = ap.add_subparsers(dest="cmd", required=True)
    for name in COMMANDS:
        module = command_module(name)
        module.add_arguments(sub.add_parser(name, help=module.HELP))
    return ap


def run_command(a: argparse.Namespace):
    """Call the command ``a.cmd``'s function with the parsed options; its Outcome."""
    options = {k: v for k, v in vars(a).items() if k not in ("cmd", "_argv")}
    return getattr(command_module(a.cmd), a.cmd)(**options)


class _Capture:
    """A stream that writes through and keeps a copy (for the output folder's log)."""

    def __init__(self, stream):
        self.stream, self.parts = stream, []

    def write(self, text):
        self.parts.append(text)
        return self.stream.write(text)

    def flush(self):
        self.stream.flush()

    def isatty(self):
        return self.stream.isatty()

    def fileno(self):
        return self.stream.fileno()


class _logged:
    """Keep what a command prints and append it to ``log.txt`` in the folder it wrote
    (``folder``, set from its Outcome once it has finished)."""

    def __init__(self, a):
        self.a, self.folder = a, None

    def __enter__(self):
        import datetime

        self.started = datetime.datetime.now().isoformat(timespec="seconds")
        self.out, self.err = sys.stdout, sys.stderr
        self.cap_out, self.cap_err = _Capture(sys.stdout), _Capture(sys.stderr)
        sys.stdout, sys.stderr = self.cap_out, self.cap_err
        return self

    def __exit__(self, *exc):
        sys.stdout, sys.stderr = self.out, self.err
        folder = self.folder
        # Only a command that ran to its end logs: a refused one must not touch a folder.
        if exc[0] is None and folder is not None and Path(folder).is_dir():
            import datetime

            stamp = datetime.datetime.now().isoformat(timespec="seconds")
            text = "".join(self.cap_out.parts)
            # Progress bars (carriage returns) are for the terminal, not the log.
            err = "".join(p for p in self.cap_err.parts if "\r" not in p and "it/s" not in p)
            try:
                with (Path(folder) / "log.txt").open("a") as fh:
                    fh.write(
                        f"==== {self.started} rotorbayes {' '.join(self.a._argv)} "
                        f"(ended {stamp})\n{text}"
                    )
                    if err:
                        fh.write(f"---- stderr\n{err}")
            except OSError:
                pass
        return False


@contextlib.contextmanager
def _own_warnings(cmd: str):
    """The package's own warnings (a data file's voltage above the rig's limit, ...) as one
    line each, ``rotorbayes CMD: warning: ...``, each message once; Python's form (source
    file, line and code) is for the warnings of other libraries."""
    seen = set()
    show = warnings.showwarning

    def _show(message, category, filename, lineno, file=None, line=None):
        if not category.__module__.startswith("rotorbayes"):
            return show(message, category, filename, lineno, file, line)
        text = str(message)
        if text not in seen:
            seen.add(text)
            print(f"rotorbayes {cmd}: warning: {text}", file=sys.stderr)

    warnings.showwarning = _show
    try:
        yield
    finally:
        warnings.showwarning = show


def main(argv=None) -> int:
    """Run one command; its exit code (:mod:`rotorbayes.util.exitcodes`)."""
    from .util import coldstart

    coldstart.end_with_parent()  # a study started by `run a.toml b.toml` ends with its starter
    try:
        return _main(argv)
    finally:
        EXIT.exiting_after_command()


def _main(argv=None) -> int:
    try:
        ap = build_parser()  # imports every command's module: seconds on a busy machine
        a = ap.parse_args(argv)
    except SystemExit as exc:  # --help, --version (0) or a usage error (2), already printed
        return exc.code if isinstance(exc.code, int) else 2
    except KeyboardInterrupt:  # Python code calling main(); the command ends at once instead
        print(
            "rotorbayes: interrupted (Ctrl-C) while starting; nothing was written", file=sys.stderr
        )
        return EXIT.INTERRUPTED
    from .util import coldstart

    coldstart.loaded()  # a Ctrl-C is each command's own business from here on
    a._argv = list(sys.argv[1:] if argv is None else argv)
    if isinstance(getattr(a, "out", None), str) and len(a.out) > 1:
        a.out = a.out.rstrip("/")  # messages add their own "/": "fit0/", never "fit0//"
    try:
        return _run_and_report(a)
    except Exception as exc:
        if not coldstart.ctrl_c_seen():
            raise
        # A Ctrl-C that C code turned into another exception (coldstart.ctrl_c_seen):
        # results are whole or absent whatever the exception, so the stop is what it was.
        code = _interrupted(a)
        print(
            f"rotorbayes {a.cmd}: (the stop surfaced as {type(exc).__name__}: {str(exc)[:160]})",
            file=sys.stderr,
        )
        return code


def _interrupted(a) -> int:
    # Every command builds its results whole or not at all (a partial folder, atomic
    # files), and keeps work that was done (InterruptGuard): what is left is true.
    print(
        f"rotorbayes {a.cmd}: interrupted (Ctrl-C) before its results were complete; "
        "it wrote nothing new (earlier results, if any, are unchanged)",
        file=sys.stderr,
    )
    return EXIT.INTERRUPTED


def _run_and_report(a) -> int:
    """Run the parsed command; its exit code, with each known failure as one message."""
    try:
        with _logged(a) as log, _own_warnings(a.cmd):
            outcome = run_command(a)
            log.folder = outcome.folder
        sys.stdout.flush()  # a closed pipe shows here, not at exit
        return outcome.exit_code
    except EXIT.Interrupted as exc:
        print(f"rotorbayes {a.cmd}: {exc}", file=sys.stderr)
        return EXIT.INTERRUPTED
    except KeyboardInterrupt:
        return _interrupted(a)
    except BrokenPipeError:
        # The reader (e.g. `| head`) stopped reading: not an error of ours. Python's recipe:
        # point stdout at devnull so the flush at exit does not fail again.
        try:
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
        except (OSError, ValueError):
            pass
        return EXIT.BROKEN_PIPE
    except EXIT.Busy as exc:
        print(f"rotorbayes {a.cmd}: busy: {exc}", file=sys.stderr)
        return EXIT.BUSY
    except EXIT.EnvironmentFailure as exc:
        print(f"rotorbayes {a.cmd}: error: {exc}", file=sys.stderr)
        return EXIT.ENVIRONMENT
    except REFUSED as exc:
        print(f"rotorbayes {a.cmd}: error: {exc}", file=sys.stderr)
        return EXIT.REFUSED
    except (OSError, RuntimeError, MemoryError) as exc:
        if (
            isinstance(exc, MemoryError)
            or EXIT.is_disk_full(exc)
            or (isinstance(exc, OSError) and exc.errno in EXIT.ENVIRONMENT_ERRNOS)
        ):
            print(f"rotorbayes {a.cmd}: error: {EXIT.describe_environment(exc)}", file=sys.stderr)
            return EXIT.ENVIRONMENT
        if not isinstance(exc, OSError) or exc.filename is None:
            raise  # not about a path the user gave: a bug, show it
        what = exc.strerror or type(exc).__name__
        print(
            f"rotorbayes {a.cmd}: error: {exc.filename}: {what}; check the path and its "
            "permissions",
            file=sys.stderr,
        )
        return EXIT.REFUSED


if __name__ == "__main__":
    sys.exit(main())

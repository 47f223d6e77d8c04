"""Reading the TOML files users write (parameter sets, priors, analysis files).

One reader, so every TOML file gets the same treatment: a byte-order mark (which some
editors on Windows put in front of a UTF-8 file) is accepted, and a missing file, a folder, a
binary file or invalid TOML is an error of the caller's kind that names the file and says
what to do.
"""

from __future__ import annotations

import tomllib
from pathlib import Path


def read_toml(path: str | Path, error: type[Exception], what: str,
              form: str = "write `name = value` lines") -> dict:
    """The TOML document in ``path``; ``error(message)`` for anything that is not one.

    ``what`` names the file's role in messages ("parameter file", "priors file", ...), and
    ``form`` says how a valid file looks.
    """
    p = Path(path)
    try:
        raw = p.read_bytes()
    except FileNotFoundError:
        raise error(f"{p}: {what} not found (looked in {p.absolute().parent})") from None
    except IsADirectoryError:
        raise error(f"{p}: is a folder; cannot read it as a {what}") from None
    except OSError as exc:
        raise error(f"{p}: cannot read the {what} ({exc.strerror})") from None
    try:
        text = raw.decode("utf-8-sig")  # a leading byte-order mark is dropped
    except UnicodeDecodeError:
        raise error(f"{p}: not a UTF-8 text file; a {what} is plain text ({form})") from None
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{p}: not valid TOML ({exc}); {form}") from None
    return doc


def read_toml_text(path: str | Path, error: type[Exception], what: str) -> str:
    """The text of a TOML file (byte-order mark dropped), for records such as run.json."""
    p = Path(path)
    try:
        return p.read_bytes().decode("utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise error(f"{p}: cannot read the {what} ({exc})") from None

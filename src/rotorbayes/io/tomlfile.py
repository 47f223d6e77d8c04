"""Reading the TOML and JSON files users write or hand over (parameter sets, priors,
analysis files, fit.json).

One reader, so every TOML file gets the same treatment: a byte-order mark (which some
editors on Windows put in front of a UTF-8 file) is accepted, and a missing file, a folder, a
binary file or invalid TOML is an error of the caller's kind that names the file and says
what to do.

Python's TOML and JSON parsers recurse once per level of nested arrays and tables, so a
file of 100 000 ``[`` ends in a ``RecursionError`` deep inside the parser.  Every text is
therefore scanned for its nesting depth first (:func:`check_nesting`, one pass over its
brackets outside strings and comments): deeper than :data:`MAX_NESTING` is refused with the
file and the line.
"""

from __future__ import annotations

import json
import re
import tomllib
from pathlib import Path

#: Deepest nesting of arrays and tables (TOML) or arrays and objects (JSON) a file may
#: have.  rotorbayes's own files nest 6 levels at most (fit.json); the parsers recurse
#: about three frames per level and Python stops at 1000 frames.
MAX_NESTING = 64

# Tokens of a nesting scan: strings and comments (skipped whole, so a bracket inside one
# does not count) and the brackets themselves.
_TOML_TOKENS = re.compile(
    r'"""(?:[^\\]|\\.)*?"""'  # multi-line basic string
    r"|'''.*?'''"  # multi-line literal string
    r'|"(?:[^"\\\n]|\\.)*"'  # basic string
    r"|'[^'\n]*'"  # literal string
    r"|#[^\n]*"  # comment
    r"|[\[\]{}]",
    re.DOTALL,
)
_JSON_TOKENS = re.compile(r'"(?:[^"\\]|\\.)*"|[\[\]{}]', re.DOTALL)


def nesting_depth(
    text: str, *, kind: str = "toml", limit: int = MAX_NESTING
) -> tuple[int, int | None]:
    """The deepest nesting of brackets in ``text`` (a ``kind`` "toml" or "json" document),
    outside strings and comments, and the offset where it first went beyond ``limit``
    (None if it never did; the scan stops there).  Unbalanced brackets are the parser's
    business, not this scan's."""
    if text.count("[") + text.count("{") <= limit:  # cannot nest deeper: no scan
        return 0, None
    tokens = _TOML_TOKENS if kind == "toml" else _JSON_TOKENS
    depth = deepest = 0
    for m in tokens.finditer(text):
        c = m.group()
        if c in "[{":
            depth += 1
            if depth > limit:
                return depth, m.start()
            deepest = max(deepest, depth)
        elif c in "]}":
            depth = max(0, depth - 1)
    return deepest, None


def check_nesting(
    text: str, path: str | Path, error: type[Exception], what: str, *, kind: str = "toml"
) -> None:
    """``error(message)`` when ``text`` (the contents of ``path``) nests arrays or tables
    deeper than :data:`MAX_NESTING`; the message names the file, the line and the limit."""
    _, where = nesting_depth(text, kind=kind)
    if where is None:
        return
    line = text.count("\n", 0, where) + 1
    inner = "arrays and tables" if kind == "toml" else "arrays and objects"
    a = "an" if what[:1].lower() in "aeiou" else "a"
    raise error(
        f"{path}, line {line}: {inner} nested more than {MAX_NESTING} levels deep "
        f"(the limit); {a} {what} nests a few levels at most, so this file is "
        f"damaged or not {a} {what}: check it, or give another"
    )


def read_toml(
    path: str | Path, error: type[Exception], what: str, form: str = "write `name = value` lines"
) -> dict:
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
    check_nesting(text, p, error, what)
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


def loads_json(text: str, path: str | Path, error: type[Exception], what: str):
    """The JSON document ``text`` read from ``path``: its nesting checked first
    (:func:`check_nesting`), then parsed.  A text that is not JSON raises the parser's
    ``ValueError`` for the caller to word; one nested too deep raises ``error``."""
    check_nesting(text, path, error, what, kind="json")
    return json.loads(text)

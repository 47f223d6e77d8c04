"""One source for documented defaults (issue 36, point 4): the help, the README and docs/
read the same figure as the program.

* The default Runge-Kutta step, wherever a page gives it "at 1 kHz", is
  :func:`rotorbayes.model.simulate.default_step` at 1 ms, and so is ``fit --help``'s
  (README once said 55 ms while ``fit --help`` said 25 ms).
* Every default in the reference tables of ``docs/analysis_file.md`` that is also an
  option of the command the table runs is that option's default (its parser default, or
  the "(default X" its help gives when the parser's is None).
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import pytest

from rotorbayes.cli import build_parser
from rotorbayes.model.simulate import default_step

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
#: Tables of the analysis file and the command each one's keys are options of.
TABLE_COMMAND = {
    "analysis": "fit",
    "fit": "fit",
    "sample": "sample",
    "identify": "identify",
    "design": "design",
}


def _subparsers():
    p = build_parser()
    return next(a for a in p._actions if isinstance(a, argparse._SubParsersAction)).choices


def test_default_step_is_one_figure_everywhere():
    want = f"{1e3 * default_step(1e-3):.0f} ms"
    found = []
    for page in PAGES:
        for m in re.finditer(r"(\d+(?:\.\d+)?) ms (?:at 1 kHz|·√)", page.read_text()):
            found.append((page.name, m.group(1) + " ms"))
    assert found, "no page gives the default step"
    bad = [f for f in found if f[1] != want]
    assert not bad, f"pages giving another default step than {want}: {bad}"
    for cmd in ("fit", "multistart"):
        text = _subparsers()[cmd].format_help()
        assert f"(default: {want} at 1 kHz" in " ".join(text.split()), cmd


def _effective_default(action):
    if action.default is not None and action.default is not False:
        return action.default
    m = re.search(r"\(default:? ([^;),]+)", " ".join((action.help or "").split()))
    return m.group(1).strip() if m else None


def _same(doc: str, value) -> bool:
    doc = doc.strip().strip("`").strip('"')
    try:
        return float(doc) == float(value)
    except (TypeError, ValueError):
        return doc == str(value)


def _table_rows():
    text = (ROOT / "docs" / "analysis_file.md").read_text()
    table = None
    for line in text.splitlines():
        m = re.match(r"### `\[(\w+)\]`", line)
        if m:
            table = m.group(1)
            continue
        m = re.match(r"\| `(\w+)` \| [^|]+ \| ([^|]+) \|", line)
        if m and table in TABLE_COMMAND:
            yield table, m.group(1), m.group(2).strip()


def test_analysis_file_defaults_are_the_commands():
    subs = _subparsers()
    checked = 0
    for table, key, doc in _table_rows():
        act = next((a for a in subs[TABLE_COMMAND[table]]._actions if a.dest == key), None)
        value = None if act is None else _effective_default(act)
        if value is None or not re.fullmatch(r'`?"?[\w.\-]+"?`?', doc):
            continue  # not an option, or a default in words ("the data's")
        checked += 1
        assert _same(doc, value), (
            f"docs/analysis_file.md [{table}] {key}: default {doc}, "
            f"but `rotorbayes {TABLE_COMMAND[table]}` has {value!r}"
        )
    assert checked >= 14


@pytest.mark.parametrize("cmd", ["fit", "multistart"])
def test_help_shows_the_read_options(cmd):
    text = " ".join(_subparsers()[cmd].format_help().split())
    for opt in ("--columns", "--time-unit", "--angle-unit", "--counts-per-rev", ".mat"):
        assert opt in text

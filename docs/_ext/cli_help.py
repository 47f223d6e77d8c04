"""Sphinx extension: the command-line reference, rendered from the argparse parser.

The directive ::

    .. cli-help:: rotorbayes.cli:build_parser

imports the module, calls the function (it must return an :class:`argparse.ArgumentParser`)
and writes the top-level help and, for every subcommand, a section titled
``rotorbayes NAME`` with its one-line summary and its full ``--help`` text.  The page is
made at build time from the same parser the command uses, so it cannot go stale.  No
third-party argparse extension is used.
"""

from __future__ import annotations

import argparse
import importlib
import os
import re
from contextlib import contextmanager

from docutils import nodes
from docutils.parsers.rst import Directive, directives

#: Width of the rendered help: argparse reads it from COLUMNS (else the terminal); fixed
#: here so the page does not depend on the machine that builds it.
HELP_WIDTH = 80

#: reST markup in help texts taken from docstrings (``x``, :mod:`x`), shown as plain text.
_ROLE = re.compile(r":[a-z:]+:`~?([^`]+)`")


@contextmanager
def _columns(width: int):
    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = str(width)
    try:
        yield
    finally:
        if old is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = old


def _subcommands(parser: argparse.ArgumentParser):
    """``(name, summary, subparser)`` for every subcommand, in the order they were added."""
    for action in parser._actions:  # argparse has no public accessor for these
        if isinstance(action, argparse._SubParsersAction):
            summaries = {a.dest: a.help or "" for a in action._choices_actions}
            seen = set()
            for name, sub in action.choices.items():
                if id(sub) in seen:  # an alias
                    continue
                seen.add(id(sub))
                yield name, summaries.get(name, ""), sub


def _help_block(text: str) -> nodes.literal_block:
    text = _ROLE.sub(r"\1", text).replace("``", "")
    block = nodes.literal_block(text, text)
    block["language"] = "text"
    return block


class CLIHelp(Directive):
    required_arguments = 1  # module:function returning the parser
    has_content = False
    option_spec = {"width": directives.positive_int}

    def run(self):
        spec = self.arguments[0]
        module, _, func = spec.partition(":")
        try:
            parser = getattr(importlib.import_module(module), func)()
        except Exception as exc:  # noqa: BLE001 - reported as a build error
            raise self.error(f"cli-help: cannot build the parser from {spec}: {exc}") from exc
        width = self.options.get("width", HELP_WIDTH)
        env = self.state.document.settings.env
        out: list[nodes.Node] = []
        with _columns(width):
            top = parser.format_help()
            out.append(_help_block(top))
            for name, summary, sub in _subcommands(parser):
                title = f"{parser.prog} {name}"
                section = nodes.section(ids=[nodes.make_id(f"cli-{name}")], names=[
                    nodes.fully_normalize_name(title)])
                section += nodes.title(title, "", nodes.literal(title, title))
                if summary:
                    section += nodes.paragraph(summary, summary[0].upper() + summary[1:]
                                               + ("" if summary.endswith(".") else "."))
                section += _help_block(sub.format_help())
                out.append(section)
        # Rebuild the page whenever the CLI's source changes.
        mod = importlib.import_module(module)
        if getattr(mod, "__file__", None):
            env.note_dependency(mod.__file__)
        return out


def setup(app):
    app.add_directive("cli-help", CLIHelp)
    return {"version": "1.0", "parallel_read_safe": True, "parallel_write_safe": True}

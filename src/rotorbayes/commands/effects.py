"""``rotorbayes effects``: the catalogue of physical effects."""

from __future__ import annotations

from ..model import effects as _effects
from .common import Outcome

HELP = "list the catalogue of physical effects"


def add_arguments(e) -> None:
    e.add_argument("name", nargs="*", help="show these effects only (NAME or FILE.py:NAME)")


def effects(name=()) -> Outcome:
    """Describe the effects ``name`` (catalogue names or FILE.py:NAME), or the whole
    catalogue and each configuration's base effects."""
    if name:
        for spec in name:
            print(_effects.resolve([spec])[0].describe())
        return Outcome()
    print(
        "The catalogue of physical effects (switch one on with --add NAME; a user effect "
        "with --add FILE.py:NAME, see docs/effects.md).\n"
    )
    for e in _effects.CATALOGUE.values():
        print(e.describe() + "\n")
    from ..model import CONFIGURATIONS

    print(
        "Friction laws to hold against the switch model (--add NAME; not nested in it, so "
        "diagnose never tries them: fit both and compare on validation data):\n"
    )
    for e in _effects.LAWS.values():
        print(e.describe() + "\n")

    print("Base models (on unless --without NAME):")
    for c in CONFIGURATIONS.values():
        print(f"    {c.name:<8} {', '.join(c.base_effects) or '(none)'}")
    return Outcome()

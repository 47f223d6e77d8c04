"""``rotorbayes params``: the parameters and named sets, or one set's values."""

from __future__ import annotations

from ..model import parameters as _params
from .common import Outcome, param_spec

HELP = "list parameters and named sets, or show one set"


def add_arguments(p) -> None:
    p.add_argument("name", nargs="?", help="a named set (thesis:4.2:P0), TOML file or "
                   "fit.json")


def params(name: str | None = None) -> Outcome:
    """Print the parameter table and the named sets, or the values of one set ``name`` (a
    named set, TOML file or fit.json; then ``Outcome.doc`` holds them)."""
    if name:
        p = _params.resolve(param_spec(name))
        for n in _params.NAMES:
            v = p[n]
            if v != v and n == "Ts_l":  # nan: the null value, no Stribeck peak
                print(f"{n:<12} {'= Tc_l':>12}  {_params.INFO[n].unit}  (no Stribeck peak: "
                      "the lower_stribeck effect is off)")
                continue
            print(f"{n:<12} {v:12.6g}  {_params.INFO[n].unit}")
        return Outcome(doc={n: p[n] for n in _params.NAMES})
    print(_params.table_markdown())
    print("\nnamed sets: " + ", ".join(_params.named_sets()))
    return Outcome()

"""``rotorbayes params``: the parameters and named sets, or one set's values."""

from __future__ import annotations

from ..model import parameters as _params
from .common import Outcome, fit_json, param_spec

HELP = "list parameters and named sets, or show one set"


def add_arguments(p) -> None:
    p.add_argument(
        "name",
        nargs="?",
        help="a named set (thesis:4.2:P0), TOML file or "
        "fit.json (a fit's user effects' parameters included)",
    )


def params(name: str | None = None) -> Outcome:
    """Print the parameter table and the named sets, or the values of one set ``name`` (a
    named set, TOML file or fit.json; then ``Outcome.doc`` holds them).

    A fit with user effects shows their parameters too, as fit.json records them (value and
    unit): showing them imports no effect file (effect files are code; commands that
    simulate check them first, see :func:`rotorbayes.inference.results.check_effect_files`).
    """
    if name:
        raw = param_spec(name)
        user, units, owners = _user_values(name, raw)
        if user:
            raw = {k: v for k, v in raw.items() if k not in user}
        p = _params.resolve(raw)
        for n in _params.NAMES:
            v = p[n]
            if v != v and n == "Ts_l":  # nan: the null value, no Stribeck peak
                print(
                    f"{n:<12} {'= Tc_l':>12}  {_params.INFO[n].unit}  (no Stribeck peak: "
                    "the lower_stribeck effect is off)"
                )
                continue
            print(f"{n:<12} {v:12.6g}  {_params.INFO[n].unit}")
        for n, v in user.items():
            print(f"{n:<12} {v:12.6g}  {units.get(n, '')}  (user effect {owners})")
        return Outcome(doc={**{n: p[n] for n in _params.NAMES}, **user})
    print(_params.table_markdown())
    print("\nnamed sets: " + ", ".join(_params.named_sets()))
    return Outcome()


def _user_values(name: str, raw) -> tuple[dict[str, float], dict[str, str], str]:
    """The values of user effects' parameters in the fit ``name`` points to (read from its
    fit.json, the effect files not imported), their units, and the effects' names."""
    doc = fit_json(name)
    if not isinstance(raw, dict) or not isinstance(doc, dict):
        return {}, {}, ""
    specs = [
        s
        for s in doc.get("added_effects") or ()
        if isinstance(s, str) and s.rpartition(":")[0].endswith(".py")
    ]
    if not specs:
        return {}, {}, ""
    user = {k: v for k, v in raw.items() if k not in _params.INFO}
    table = doc.get("parameters") if isinstance(doc.get("parameters"), dict) else {}
    units = {
        k: str(rec.get("unit", ""))
        for k, rec in table.items()
        if k in user and isinstance(rec, dict)
    }
    owners = ", ".join(s.rpartition(":")[2] for s in specs)
    return user, units, owners

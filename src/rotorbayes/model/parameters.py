"""Parameter names, units, physical bounds and the thesis's parameter tables.

Every parameter of the rig model has one name used everywhere (files, API, plots).
The base model's parameters are declared here, each catalogue effect's with its effect
(:mod:`rotorbayes.model.effects`); :data:`INFO` joins them in the order of the compiled
kernel's parameter vector (:mod:`rotorbayes.kernel.layout`).

Thesis tables (Wegman 2006) are available as named sets ``"thesis:<table>:<row>"``,
e.g. ``"thesis:4.2:P0"``. Each named set is *complete*: the thesis lists only the
parameters estimated in that step, and the remaining ones are taken from the step
that came before it (upper part -> lower part -> brake), as in the thesis's procedure.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path

from ..kernel.layout import NAMES
from .effects import CATALOGUE
from .info import Parameter

#: Parameters of the base model (thesis eqs. 2.1-2.6 with symmetric friction).  The
#: parameters of the catalogue effects are declared with their effect in
#: :mod:`rotorbayes.model.effects`.
BASE: tuple[Parameter, ...] = (
    Parameter("k_m", "N m/V", 0.1, 20.0, math.nan, "motor constant (torque per input volt)"),
    Parameter("J_u", "kg m^2", 0.05, 5.0, 0.4765, "upper disc inertia (eq. 5.4: 0.4765)"),
    Parameter("Tc_u", "N m", 0.0, 3.0, 0.0, "upper Coulomb friction (mean of both directions)"),
    Parameter("b_u", "N m s/rad", 0.0, 20.0, 0.0, "upper viscous friction (mean)"),
    Parameter("J_l", "kg m^2", 1e-3, 1.0, 0.0414, "lower disc inertia"),
    Parameter("k_alpha", "N m/rad", 1e-3, 1.0, 0.080, "string torsional stiffness (eq. 5.11)"),
    Parameter("Tc_l", "N m", 0.0, 1.0, 0.0, "lower Coulomb friction (bearing, or brake)"),
    Parameter("b_l", "N m s/rad", 0.0, 1.0, 0.0, "lower viscous friction (mean)"),
)


def _all_parameters() -> dict[str, Parameter]:
    out = {p.name: p for p in BASE}
    for e in CATALOGUE.values():
        for p in e.parameters:
            out[p.name] = p
    missing = set(NAMES) ^ set(out)
    if missing:  # the kernel layout and the registry must describe the same parameters
        raise RuntimeError(f"kernel layout and parameter registry disagree on {missing}")
    return {n: out[n] for n in NAMES}


#: Metadata of every built-in parameter by name, in kernel order.
INFO: dict[str, Parameter] = _all_parameters()
#: Position of each name in the kernel's parameter vector.
INDEX: dict[str, int] = {n: i for i, n in enumerate(NAMES)}
#: Kept for readers of older code: the metadata class.
ParameterInfo = Parameter

# Geometry-derived values (thesis eqs. 5.4 and 5.11).
J_U_EQ_5_4 = 7.9e3 * math.pi / 32 * 0.40**4 * 0.024
K_ALPHA_EQ_5_11 = 2.0e11 * (2e-3) ** 4 * math.pi / (64 * (1 + 1 / 3) * 1.47)


class ParameterError(ValueError):
    """A parameter name, value or file is invalid."""


def unknown_name_message(name: str) -> str:
    """Error text for an unknown parameter name, listing the valid ones."""
    return f"unknown parameter {name!r}; valid names are: {', '.join(NAMES)}"


def check_names(names, *, where: str = "") -> None:
    """Raise :class:`ParameterError` if any name is not a model parameter."""
    for n in names:
        if n not in INFO:
            prefix = f"{where}: " if where else ""
            raise ParameterError(prefix + unknown_name_message(n))


# --------------------------------------------------------------------------------------
# The thesis's tables.  Values are copied from the tables as printed; asymmetric pairs
# (Tc_lp/Tc_ln, b_lp/b_ln) are converted to mean and half-difference.
# --------------------------------------------------------------------------------------
def _pair(pos: float, neg: float) -> tuple[float, float]:
    """Mean and half-difference of a positive/negative-direction pair."""
    return (pos + neg) / 2, (pos - neg) / 2


_T41 = {
    "P_ref": dict(k_m=4.3228, Tc_u=0.3798, dTc_u=-0.0058, b_u=2.4245, db_u=-0.0084),
    "P0": dict(k_m=6.0, Tc_u=1.0, dTc_u=0.0, b_u=4.0, db_u=-0.2),
    "P": dict(k_m=4.5743, Tc_u=0.4757, dTc_u=-0.0046, b_u=2.5523, db_u=0.0022),
}
_T42 = {
    "P_ref": dict(J_l=0.0414, k_alpha=0.0775, Tc_l=0.0171, b_l=0.0092),
    "P0": dict(J_l=0.0550, k_alpha=0.0900, Tc_l=0.0200, b_l=0.0130),
    "P": dict(J_l=0.0498, k_alpha=0.0930, Tc_l=0.0202, b_l=0.0108),
}
_T43 = {
    "P_ref": dict(Tc_l=0.0473, b_l=0.0105, Ts_l=0.2781, ws_l=1.4302, delta_l=2.0575),
    "P0": dict(Tc_l=0.0490, b_l=0.0120, Ts_l=0.2850, ws_l=1.6000, delta_l=2.1500),
    "P": dict(Tc_l=0.0478, b_l=0.0109, Ts_l=0.2796, ws_l=1.4367, delta_l=2.0731),
}
_T51 = {
    "P0": dict(_T41["P_ref"]),
    "P": dict(k_m=4.3687, Tc_u=0.3827, dTc_u=-0.0076, b_u=2.4506, db_u=-0.0079),
}
_T52 = {
    "P0": dict(J_l=0.0414, k_alpha=0.080, Tc_l=0.0171, b_l=0.0092),
    "P": dict(J_l=0.0414, k_alpha=0.0775, Tc_l=0.0171, b_l=0.0089),
}
_tc53, _dtc53 = _pair(0.0139, 0.0244)
_b53, _db53 = _pair(0.0093, 0.0079)
_T53 = {
    "P0": dict(J_l=0.0414, k_alpha=0.0775, Tc_l=0.0171, dTc_l=0.0, b_l=0.0089, db_l=0.0),
    "P": dict(J_l=0.0414, k_alpha=0.0775, Tc_l=_tc53, dTc_l=_dtc53, b_l=_b53, db_l=_db53),
}
_b54, _db54 = _pair(0.0096, 0.0089)
_T54 = {
    # The brake step assumes symmetric Coulomb friction (thesis §5.3.1).
    "P0": dict(
        Tc_l=0.0473, dTc_l=0.0, b_l=0.0105, db_l=0.0, Ts_l=0.2781, ws_l=1.4302, delta_l=2.0575
    ),
    "P": dict(
        Tc_l=0.0430, dTc_l=0.0, b_l=_b54, db_l=_db54, Ts_l=0.2832, ws_l=1.4502, delta_l=1.7504
    ),
}

#: Which configuration each table belongs to.
TABLE_CONFIG = {
    "4.1": "upper",
    "4.2": "coupled",
    "4.3": "brake",
    "5.1": "upper",
    "5.2": "coupled",
    "5.3": "coupled",
    "5.4": "brake",
}


def null_values() -> dict[str, float]:
    """All parameters at their null (effect off) values, with ``J_u`` from eq. 5.4."""
    vals = {n: INFO[n].null for n in NAMES}
    vals["J_u"] = round(J_U_EQ_5_4, 4)
    return vals


def _compose(*parts: Mapping[str, float]) -> dict[str, float]:
    out = null_values()
    for p in parts:
        out.update(p)
    return out


def _build_thesis_sets() -> dict[str, dict[str, float]]:
    sets: dict[str, dict[str, float]] = {}
    # Chapter 4: simulated data from P_ref; earlier steps' P_ref fill in the rest.
    for row in ("P_ref", "P0", "P"):
        sets[f"4.1:{row}"] = _compose(_T41[row])
        sets[f"4.2:{row}"] = _compose(_T41["P_ref"], _T42[row])
        sets[f"4.3:{row}"] = _compose(_T41["P_ref"], _T42["P_ref"], _T43[row])
    # Chapter 5: each step starts from the previous step's final P.
    for row in ("P0", "P"):
        sets[f"5.1:{row}"] = _compose(_T51[row])
        sets[f"5.2:{row}"] = _compose(_T51["P"], _T52[row])
        sets[f"5.3:{row}"] = _compose(_T51["P"], _T53[row])
        sets[f"5.4:{row}"] = _compose(_T51["P"], _T53["P"], _T54[row])
    return sets


_THESIS_SETS = _build_thesis_sets()

#: Parameters estimated in each thesis table (the table's columns).
TABLE_FREE = {
    "4.1": tuple(_T41["P"]),
    "4.2": tuple(_T42["P"]),
    "4.3": tuple(_T43["P"]),
    "5.1": tuple(_T51["P"]),
    "5.2": tuple(_T52["P"]),
    "5.3": tuple(_T53["P"]),
    "5.4": ("Tc_l", "b_l", "db_l", "Ts_l", "ws_l", "delta_l"),
}

#: The default full parameter set of each configuration (thesis chapter 4 P_ref).
DEFAULT_SET = {
    "upper": "thesis:4.1:P_ref",
    "coupled": "thesis:4.2:P_ref",
    "brake": "thesis:4.3:P_ref",
}


def named_sets() -> list[str]:
    """Names of all bundled parameter sets, e.g. ``'thesis:4.2:P0'``."""
    return [f"thesis:{k}" for k in _THESIS_SETS]


def thesis_set(table: str, row: str) -> dict[str, float]:
    """A complete parameter set from a thesis table.

    Parameters
    ----------
    table : str
        ``'4.1'`` ... ``'4.3'`` (simulated data) or ``'5.1'`` ... ``'5.4'`` (measured).
    row : str
        ``'P_ref'`` (chapter 4 only), ``'P0'`` or ``'P'``.
    """
    key = f"{table}:{row}"
    if key not in _THESIS_SETS:
        raise ParameterError(f"no thesis set {key!r}; available: {', '.join(sorted(_THESIS_SETS))}")
    return dict(_THESIS_SETS[key])


def load_toml(path: str | Path, _chain: tuple[str, ...] = ()) -> dict[str, float]:
    """Read a parameter file.

    The file holds ``name = value`` pairs, at top level or in a ``[parameters]``
    table, and optionally ``base = "thesis:4.2:P0"`` naming the set (or another parameter
    file) it overrides. A chain of ``base`` files that comes back to a file is an error.
    """
    from ..io.tomlfile import read_toml

    path = Path(path)
    here = str(path.resolve())
    if here in _chain:
        loop = " -> ".join([*_chain[_chain.index(here) :], here])
        raise ParameterError(
            f"{path}: its base files name each other in a loop ({loop}); "
            'end the chain with a named set such as base = "thesis:4.2:P0"'
        )
    raw = read_toml(path, ParameterError, "parameter file")
    base = raw.pop("base", None)
    table = raw.pop("parameters", {})
    if not isinstance(table, dict):
        raise ParameterError(
            f"{path}: parameters = {table!r} must be a table: write "
            "[parameters] on its own line, then `name = value` lines"
        )
    clash = sorted(set(raw) & set(table))
    if clash:
        raise ParameterError(
            f"{path}: {', '.join(clash)} given both at the top and in "
            "[parameters]; give each value once"
        )
    values = {**raw, **table}
    if base is not None and not isinstance(base, str):
        raise ParameterError(
            f"{path}: base = {base!r} must be a string naming a set "
            '("thesis:4.2:P0") or another parameter file'
        )
    if base is not None and not base.startswith("thesis:"):
        named = base
        b = Path(base)
        base = b if b.is_absolute() or b.exists() else path.parent / b
        if not named.strip() or not base.is_file():
            why = (
                "is empty"
                if not named.strip()
                else "is a folder, not a parameter file"
                if base.is_dir()
                else f"is not a file (looked for {base.absolute()})"
            )
            raise ParameterError(
                f"{path}: base = {named!r} {why}; name a set such as "
                'base = "thesis:4.2:P0" or another parameter file '
                "(a path relative to this file)"
            )
    out: dict[str, float] = {}
    if base is not None:
        out = (
            resolve(base)
            if isinstance(base, str)
            else {**resolve(None), **load_toml(base, (*_chain, here))}
        )
    for name, val in values.items():
        if name not in INFO:
            raise ParameterError(f"{path}: {unknown_name_message(name)}")
        if not isinstance(val, int | float) or isinstance(val, bool):
            raise ParameterError(
                f"{path}: {name} = {val!r} is not a number; write a plain "
                f"number, e.g. {name} = {INFO[name].lower:g}"
            )
        info = INFO[name]
        val = float(val)
        if math.isnan(val) and math.isnan(info.null) and name == "Ts_l":
            out[name] = val  # Ts_l = nan means "equal to Tc_l" (no Stribeck peak)
            continue
        if not (info.lower <= val <= info.upper):
            raise ParameterError(
                f"{path}: {name} = {val:g} {info.unit} lies outside its physical bounds "
                f"[{info.lower:g}, {info.upper:g}] ({info.description}); correct this value "
                "in the file"
            )
        out[name] = val
    return out


def resolve(spec, *, config: str | None = None) -> dict[str, float]:
    """Turn a parameter specification into a complete ``{name: value}`` dict.

    Parameters
    ----------
    spec : None, str, pathlib.Path or mapping
        ``None`` gives the configuration's default set; a string is a named set
        (``'thesis:4.2:P0'``) or a TOML file path; a mapping overrides the default
        set of ``config`` name by name.
    config : str, optional
        ``'upper'``, ``'coupled'`` or ``'brake'``; chooses the default set.
    """
    base = thesis_set(*DEFAULT_SET[config or "brake"].split(":")[1:])
    if spec is None:
        return base
    if isinstance(spec, str | Path):
        s = str(spec)
        if s.startswith("thesis:"):
            parts = s.split(":")
            if len(parts) != 3:
                raise ParameterError(f"named set {s!r} must look like 'thesis:4.2:P0'")
            return thesis_set(parts[1], parts[2])
        if s.endswith(".toml") or Path(s).exists():
            base.update(load_toml(s))
            return base
        raise ParameterError(
            f"{s!r}: not found (no file or folder of that name) and not a named set "
            f"({', '.join(named_sets()[:3])}, ...); give a fit folder, a TOML file of "
            "values or a named set"
        )
    if isinstance(spec, Mapping):
        check_names(spec)
        base.update({k: float(v) for k, v in spec.items()})
        return base
    raise ParameterError(f"cannot read parameters from a {type(spec).__name__}")


def check_bounds(values: Mapping[str, float], names=None, *, what: str = "") -> None:
    """Raise :class:`ParameterError` if a value lies outside its physical bounds."""
    for n in names if names is not None else values:
        v = values[n]
        info = INFO[n]
        if math.isnan(v) and n == "Ts_l":
            continue
        if not (info.lower <= v <= info.upper):
            raise ParameterError(
                f"{what + ': ' if what else ''}{n} = {v:g} {info.unit} lies outside its physical "
                f"bounds [{info.lower:g}, {info.upper:g}]; choose a value inside them"
            )


def table_markdown() -> str:
    """A markdown table of every parameter with unit, bounds and meaning."""
    rows = ["| name | unit | bounds | null | meaning |", "|---|---|---|---|---|"]
    for p in INFO.values():
        null = ("= Tc_l" if p.name == "Ts_l" else "—") if math.isnan(p.null) else f"{p.null:g}"
        rows.append(
            f"| `{p.name}` | {p.unit} | [{p.lower:g}, {p.upper:g}] | {null} | {p.description} |"
        )
    return "\n".join(rows)

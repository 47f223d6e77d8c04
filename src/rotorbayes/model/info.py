"""What the toolkit knows about one parameter: unit, bounds, null value, typical start."""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Parameter:
    """Metadata of one model parameter.

    Attributes
    ----------
    name : str
        The parameter's name (as in DESIGN.md; user effects choose their own).
    unit : str
        SI unit.
    lower, upper : float
        Physical bounds used by estimation, sampling and validation.
    null : float
        The value at which the parameter's effect is switched off.  ``nan`` for
        ``Ts_l`` means "equal to ``Tc_l``" (no Stribeck part).
    description : str
        One line of physics.
    start : float
        A typical value to start a fit from when the effect is added (``nan``: start at
        the null value).
    nuisance : bool
        The parameter has no meaning at the effect's null (the Stribeck velocity and
        shape when the static level equals the Coulomb level).
    """

    name: str
    unit: str
    lower: float
    upper: float
    null: float
    description: str
    start: float = math.nan
    nuisance: bool = False

    def __post_init__(self):
        if not self.name.isidentifier():
            raise ValueError(f"parameter name {self.name!r} must be a Python identifier")
        if not (self.lower < self.upper):
            raise ValueError(
                f"parameter {self.name}: lower bound {self.lower:g} must be below the upper "
                f"bound {self.upper:g}"
            )
        for what, v in (("null", self.null), ("start", self.start)):
            if not math.isnan(v) and not (self.lower <= v <= self.upper):
                raise ValueError(
                    f"parameter {self.name}: {what} value {v:g} lies outside its bounds "
                    f"[{self.lower:g}, {self.upper:g}]"
                )

"""When no input can help: the registry's exact equivalences, read as data.

An :class:`~rotorbayes.model.effects.Equivalence` with ``input_can_break=False`` says that
within its scope (e.g. any single experiment) no input tells its effects apart, and what
does instead (its ``procedure``).  This module finds the ones that apply to a design
target; every word the user sees comes from the registry entry.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np

from ..inference.problem import UPPER_PARAMETERS, local_name
from ..model import effects as _effects


def registry_ties() -> list[_effects.Equivalence]:
    """Every exact equivalence in the catalogue that no input can break (each once)."""
    out: list[_effects.Equivalence] = []
    for e in _effects.CATALOGUE.values():
        for q in e.equivalences:
            if (
                isinstance(q, _effects.Equivalence)
                and not q.input_can_break
                and all(q is not o and str(q) != str(o) for o in out)
            ):
                out.append(q)
    return out


def _needed_free(tie, prescribed_upper: bool) -> list[str]:
    need = list(tie.also_free)
    if prescribed_upper:
        need = [n for n in need if n not in UPPER_PARAMETERS]
    return need


def tie_between(
    effects: Sequence[str],
    free: Iterable[str],
    *,
    n_experiments: int = 1,
    prescribed_upper: bool = False,
):
    """The registry tie that makes candidate ``effects`` indistinguishable by any input,
    given the parameters free in the candidates' fits and the number of experiments in the
    data; ``None`` if there is none."""
    free_base = {local_name(n)[0] for n in free}
    want = set(effects)
    for tie in registry_ties():
        if not tie.holds_for(n_experiments):
            continue
        if want <= set(tie.effects) and all(
            n in free_base for n in _needed_free(tie, prescribed_upper)
        ):
            return tie
    return None


def tie_in_direction(
    names: Sequence[str],
    v: np.ndarray,
    active_effects: Iterable[str],
    *,
    n_experiments: int = 1,
    prescribed_upper: bool = False,
    share: float = 0.9,
):
    """The registry tie that a (sloppiest) direction ``v`` lies in: every effect of the tie
    on and free, the tie's extra parameters free, and at least ``share`` of ``v``'s squared
    length on the tie's parameters.  ``None`` if there is none."""
    on = set(active_effects)
    base = [local_name(n)[0] for n in names]
    v = np.asarray(v, float)
    total = float(v @ v) or 1.0
    for tie in registry_ties():
        if not tie.holds_for(n_experiments) or not set(tie.effects) <= on:
            continue
        params = set(_needed_free(tie, prescribed_upper))
        for e in tie.effects:
            params |= {p.name for p in _effects.CATALOGUE[e].switches}
        if not all(p in base for p in params):
            continue
        mass = sum(float(v[j]) ** 2 for j, b in enumerate(base) if b in params)
        if mass >= share * total:
            return tie
    return None


def no_input_words(tie) -> str:
    """The plain-words account of a tie no input breaks, with its procedure."""
    return (
        f"No input can help: {tie}. This holds in {tie.scope}, whatever the input. "
        f"What separates them: {tie.procedure}."
    )

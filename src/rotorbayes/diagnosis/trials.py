"""Trial refits: far from the floor, a refit of every candidate decides which effect helps.

The score tests (:mod:`.score`) are linear at the fit.  Near the floor they are powerful and
cheap; far above it the fit sits in a basin shaped by what is missing, and the linear
prediction can miss the effect that is there.  Measured on data from the independent
reference (coupled, 30 s at 1 kHz): with a motor dead zone of 0.3 V hidden, the first fit
ends at 927x the floor, the score tests rank ``input_delay`` first (predicted 747x) and the
dead zone nowhere (p 1); a refit with ``motor_deadzone`` added reaches 0.95x, one with
``input_delay`` 670x.  With a voltage offset larger than the upper Coulomb level hidden, the
offset is "equivalent to the free parameters" at the fit (a change of dTc_u), yet dTc_u is
held by its validity constraint there; the refit with ``voltage_offset`` reaches 1.0x.

:func:`trial_refits` therefore refits the fit once per candidate effect, each with the search
of :mod:`rotorbayes.inference.refit` (several starts of the effect's parameters, the rest
from the fit), and ranks the effects by where the refit ended.  It costs one refit search
per candidate (about half a minute per candidate for 30 s at 1 kHz on two cores), so
``diagnose`` runs it only far from the floor (:data:`TRIAL_ABOVE`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..inference.problem import Problem, local_name

#: ``diagnose`` runs trial refits when the worst fitted channel is above this many floors
#: and the model is inadequate (near the floor the score tests decide, and cheaply).
TRIAL_ABOVE = 3.0


@dataclass
class Trial:
    """Where the refit with one effect added ended."""

    effect: str
    ratio: float  # worst fitted channel's RMS over the floor (estimation data)
    values: dict[str, float] = field(default_factory=dict)
    on_bound: list[str] = field(default_factory=list)
    chose: str = ""
    disagreed: bool = False
    failed: str = ""
    #: Worst fitted channel's RMS/floor on the validation data (each run with its own
    #: torsion), where trials tie on the estimation data; NaN when not computed.
    validation: float = math.nan
    #: Where the refit turned the effect into the opposite of its physics (the registry's
    #: :attr:`rotorbayes.model.effects.Effect.inverted`): its fall is no claim for it.
    inverted: str = ""
    #: With :attr:`inverted`: the model's own parameters that keep what the effect fits
    #: where it is harmless (``Tc_l`` at the standstill level ``Ts_l``).
    instead: dict[str, float] = field(default_factory=dict)
    #: The effect's parameters all ended at their null values (the effect off): the fall
    #: is the refit's escape from a local minimum of the model without it, not the effect.
    at_null: bool = False
    result: Any = field(default=None, repr=False)  # the refit (a FitResult)

    def as_dict(self) -> dict:
        return {
            "effect": self.effect,
            "rms_over_floor": self.ratio if math.isfinite(self.ratio) else None,
            "values": self.values,
            "on_bound": self.on_bound,
            "start": self.chose,
            "starts_disagreed": self.disagreed,
            "failed": self.failed or None,
            "validation_rms_over_floor": (
                self.validation if math.isfinite(self.validation) else None
            ),
            "inverted": self.inverted or None,
            "at_null": self.at_null,
        }


def _on_bound(prob: Problem, x: np.ndarray, names: Sequence[str]) -> list[str]:
    out = []
    for n in names:
        j = prob.names.index(n)
        width = prob.upper[j] - prob.lower[j]
        if math.isfinite(width) and min(x[j] - prob.lower[j], prob.upper[j] - x[j]) <= 1e-3 * width:
            out.append(n)
    return out


def _at_null(effect, values: Mapping[str, float]) -> bool:
    """Every searched parameter of ``effect`` with a null value ended at it (to 1e-9 of its
    bounds' width): the refit switched the effect off.  Measured: two pre-wound runs with
    a motor torque that sags with speed, the first fit in a local minimum; the trial with
    string_damping ended at c_alpha = 2.8e-21 (its null, a bound) and 3162x -> 2889x the
    floor -- the base model's better basin, which a multistart found -- and was chosen."""
    checked = False
    for prm in effect.parameters:
        v = values.get(prm.name)
        if v is None or not math.isfinite(prm.null) or prm.nuisance:
            continue
        width = prm.upper - prm.lower if math.isfinite(prm.upper - prm.lower) else 1.0
        if abs(v - prm.null) > 1e-9 * max(width, abs(prm.null), 1e-300):
            return False
        checked = True
    return checked


def trial_refits(
    problem: Problem,
    x: np.ndarray,
    effects: Sequence[str],
    starts: Mapping[str, Mapping[str, float]] | None = None,
    *,
    verbose: bool = False,
    **fit_kw,
) -> list[Trial]:
    """Refit ``problem`` at ``x`` once per effect in ``effects`` (catalogue names), each
    with its parameters searched from several starts (``starts[effect]``: the diagnosis's
    one-step estimates and nuisance grid point), every other parameter from ``x``.  Returns
    the trials best first (the smallest worst RMS/floor); a refit that cannot be done is a
    failed trial, never a result."""
    from ..inference.refit import added_names, refit_added
    from ..model import effects as _effects

    fit_kw = {"uncertainty": False, **fit_kw}
    vals = {**problem.base, **problem.values(x)}
    out: list[Trial] = []
    for name in effects:
        t0 = time.perf_counter()
        e = _effects.resolve([name])[0]
        try:
            pe = problem.like(
                model=problem.model.with_effects([name]),
                free=[
                    *problem.names_base(),
                    *[p for p in e.names if p not in problem.names_base()],
                ],
            )
            x0 = pe.start_vector({**pe.base, **vals})
            diag = {
                n: v
                for n, v in (starts or {}).get(e.name, {}).items()
                if n in pe.names and math.isfinite(v)
            }
            r = refit_added(pe, x0, diag, [e.name], verbose=False, **fit_kw)
        except Exception as exc:  # noqa: BLE001 - a trial that cannot run is reported as such
            out.append(Trial(name, math.inf, failed=str(exc)))
            continue
        searched = added_names(pe, [e.name])
        xr = r.result.x
        t = Trial(
            name,
            r.starts[r.kept].ratio,
            {n: float(xr[pe.names.index(n)]) for n in searched},
            _on_bound(pe, xr, searched),
            r.chose,
            r.disagreed(),
            result=r.result,
        )
        if e.inverted is not None:
            t.inverted, t.instead = e.inverted({**pe.base, **pe.values(xr)})
        t.at_null = _at_null(e, t.values)
        out.append(t)
        t.effect = name  # as the user names it (a file's effect with its file)
        if verbose:
            print(
                f"  trial refit with {name}: {t.ratio:.3g}x the floor "
                f"({time.perf_counter() - t0:.1f} s)",
                flush=True,
            )
    out.sort(key=lambda t: (t.ratio, t.effect))
    return out


def trial_table(trials: Sequence[Trial], before: float) -> str:
    """The trials as lines: effect, where its refit ended, its parameters."""
    lines = []
    for t in trials:
        if t.failed:
            lines.append(f"  {t.effect:<26} failed: {t.failed}")
            continue
        vals = ", ".join(f"{n} = {v:.4g}" for n, v in t.values.items())
        tag = f"  [on a bound: {', '.join(t.on_bound)}]" if t.on_bound else ""
        tag += "  [inverted]" if t.inverted else ""
        tag += "  [ended at its null: the effect off]" if t.at_null else ""
        lines.append(f"  {t.effect:<26} {before:.3g}x -> {t.ratio:.3g}x  ({vals}){tag}")
    return "\n".join(lines)


#: Trials whose worst RMS/floor on the estimation data lie within this factor of the best
#: are tied there (an exact tie such as initial_torsion and lower_asymmetric_coulomb on one
#: experiment); validation data, where there are some, decide between them.
TIE = 1.05


def validation_ratio(problem: Problem, x: np.ndarray, experiments) -> float:
    """Worst fitted channel's RMS over its floor on validation ``experiments`` at ``x``,
    each run with its own torsion (:meth:`Problem.validation_params`)."""
    floors = problem.noise_floors()[0]
    worst = 0.0
    for ex in experiments:
        p, _ = problem.validation_params(x, ex)
        s = problem.simulator_for(ex).simulate(p, raise_on_failure=False)
        if not s.ok:
            return math.inf
        for c in problem.channels:
            d = getattr(ex, c) - getattr(s, c)
            worst = max(worst, math.sqrt(float(np.mean(d * d))) / floors[c])
    return worst


def trial_choice(trials: Sequence[Trial], before: float, validation=()) -> Trial | None:
    """The effect whose refit lowered the worst RMS/floor most, if materially (see
    :func:`.diagnose.is_material`), not inverted (:attr:`Trial.inverted`) and not at its
    null (:attr:`Trial.at_null`); None otherwise.  Trials tied with the best on the
    estimation data (:data:`TIE`), each itself a material fall, are told apart by
    ``validation`` experiments when given (their :attr:`Trial.validation` is filled)."""
    from .diagnose import is_material

    ok = [
        t
        for t in trials
        if not t.failed and not t.inverted and not t.at_null and math.isfinite(t.ratio)
    ]
    if not ok:
        return None
    best = min(ok, key=lambda t: (t.ratio, t.effect))
    if not is_material(before, best.ratio):
        return None
    # A refit that switched its effect off ends as low: the others' falls may be the same
    # escape from a local minimum of the model as it is -- nothing is chosen before the
    # model is refitted from several starts (the string_damping case above: voltage_offset
    # then "decided" at 2.89e3x beside it).
    if any(t.at_null and not t.failed and t.ratio <= TIE * best.ratio for t in trials):
        return None
    # Tied with the best, and material on their own: a trial within TIE of a material best
    # that lowers the figure immaterially itself (449x -> 440x beside 449x -> 424x) is not
    # worth adding, whatever the validation data prefer.
    tied = [t for t in ok if t.ratio <= TIE * best.ratio and is_material(before, t.ratio)]
    if len(tied) > 1 and validation:
        for t in tied:
            try:
                t.validation = validation_ratio(t.result.problem, t.result.x, validation)
            except Exception:  # noqa: BLE001 - a run that cannot be simulated: no vote
                t.validation = math.inf
        best = min(tied, key=lambda t: (t.validation, t.ratio, t.effect))
    return best


def point_without(problem: Problem, trial: Trial) -> np.ndarray:
    """The point of ``problem`` (the fit's, without the trial's effect) at an inverted
    trial's refit, its effect replaced by :attr:`Trial.instead`: where what the effect
    stood in for shows in the missing torque.  Measured on a quadratic drag hidden in
    reference data (first fit 179x the floor, its map 2.2x its noise: no proposal), the
    point of the upside-down lower_stribeck trial with Tc_l at its Ts_l gave the drag's
    term, c_l_w2 = 0.000497 (truth 0.0005), and the refit with it 0.97x the floor
    (validation 1.88x, 95.7x before)."""
    r = trial.result
    vals = {n: v for n, v in r.problem.values(r.x).items() if n in problem.names}
    vals.update({n: v for n, v in trial.instead.items() if n in problem.names})
    return problem.start_vector({**problem.base, **vals})


def one_step_starts(ranking) -> dict[str, dict[str, float]]:
    """Per effect of a diagnosis's ranking: its one-step estimates and best nuisance grid
    point (what ``fit --p0`` of the diagnosed folder starts from)."""
    out: dict[str, dict[str, float]] = {}
    for s in ranking:
        d = {n: float(v) for n, v in s.step.items() if math.isfinite(v)}
        d.update({k: float(v) for k, v in (s.nuisance or {}).items()})
        out[s.effect] = {local_name(n)[0] if "[" not in n else n: v for n, v in d.items()}
    return out

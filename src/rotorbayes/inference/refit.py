"""Adding an effect to a fit: a refit that searches the new effect's parameters.

A fit with an effect added (``rotorbayes fit --p0 FIT/ --add NAME``, the refit that
``diagnose`` prints, each step of ``rotorbayes run``) starts from the parent fit.  Every
parameter the parent estimated has a good start there; the added effect's parameters do
not: the score test's one-step estimate is a linear prediction at the parent (far from the
floor it can overshoot into another basin), the effect's typical value is a guess, and the
nuisance parameters of a shape (a Stribeck velocity, a phase) have no gradient at the null.
One start decides the outcome more often than not (a user's Stribeck refit ended at 111x
the floor with the levels on their bounds; from the typical start the same effect reached
3.6x).

:func:`refit_added` therefore fits from several starts that differ only in the added
effects' parameters, the rest from the parent fit:

* the diagnosis's one-step estimate, with the best point of its nuisance grid;
* the effect's typical start;
* starts spread over the nuisance shape parameters (the grid the score test scans);
* a start from the data (the equations of motion as a regression with the effect on),
  where the regression reaches the effect's parameters;

keeps the fit with the smallest estimation SSR and says when the starts disagreed.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from .assess import floor_ratio
from .least_squares import FitResult
from .multistart import _fit_start
from .parallel import DefaultPool, SerialExecutor, current_executor, progress, run_tasks
from .problem import Problem, local_name

#: Stribeck velocities [rad/s] and shape exponents of the spread starts (a subset of the
#: score test's grid: three decades of velocity, a smooth and a sharp shape).
WS_STARTS = (0.2, 1.0, 5.0)
DELTA_STARTS = (1.0, 2.0)
#: Above this many residuals (long data: 100 s of both channels at 1 kHz) the starts are
#: screened with :data:`SCREEN_NFEV` evaluations each and only the best is fitted to the
#: end.
LONG_RESIDUALS = 200_000
SCREEN_NFEV = 25
#: Two end points whose worst RMS/floor differ by more than this factor "disagree".
DISAGREE = 1.25
#: A refit ending above the diagnosis's prediction by more than this factor says so.
ABOVE_PREDICTION = 1.1


@dataclass
class RefitStart:
    """One start of the search and where it ended."""

    label: str
    x0: np.ndarray
    ratio: float = math.nan  # worst fitted channel's RMS over the floor at the end
    ssr: float = math.nan
    success: bool = False
    failed: str = ""

    def as_dict(self, problem: Problem, names: list[str]) -> dict:
        return {
            "start": self.label,
            "values": {n: float(self.x0[problem.names.index(n)]) for n in names},
            "rms_over_floor": self.ratio if math.isfinite(self.ratio) else None,
            "ssr": self.ssr if math.isfinite(self.ssr) else None,
            "success": self.success,
            "failed": self.failed or None,
        }


@dataclass
class Refit:
    """The kept fit of :func:`refit_added` and every start tried."""

    result: FitResult
    starts: list[RefitStart]
    kept: int
    searched: list[str]  # the added effects' free parameters (the ones the starts vary)
    notes: list[str] = field(default_factory=list)

    @property
    def chose(self) -> str:
        return self.starts[self.kept].label

    def disagreed(self) -> bool:
        r = [s.ratio for s in self.starts if math.isfinite(s.ratio)]
        return len(r) > 1 and max(r) > DISAGREE * min(r)

    def table(self) -> str:
        """One line per start: where it began (the added parameters) and where it ended."""
        rows = []
        for i, s in enumerate(self.starts):
            vals = ", ".join(
                f"{n} {s.x0[self.result.problem.names.index(n)]:.3g}" for n in self.searched
            )
            end = (
                f"{s.ratio:.3g}x the floor"
                if math.isfinite(s.ratio)
                else f"failed ({s.failed})"
                if s.failed
                else "failed"
            )
            mark = ""
            if i == self.kept:
                # Where the kept start ended (a start "the effect off" reads as if the
                # effect had stayed off when every start ties).
                x = self.result.x
                at = ", ".join(
                    f"{n} {x[self.result.problem.names.index(n)]:.3g}" for n in self.searched
                )
                mark = f"  <- kept (ended at {at})" if at else "  <- kept"
            rows.append(f"  {s.label:<42} {vals:<44} -> {end}{mark}")
        return "\n".join(rows)

    def as_dict(self) -> dict:
        prob = self.result.problem
        return {
            "searched": list(self.searched),
            "kept": self.chose,
            "disagreed": self.disagreed(),
            "notes": list(self.notes),
            "starts": [s.as_dict(prob, self.searched) for s in self.starts],
        }


def added_names(problem: Problem, effects=None) -> list[str]:
    """The free parameters of the effects added to the problem's model (of those named in
    ``effects``, default every added one)."""
    out = []
    for e in _new_effects(problem, effects):
        for p in e.names:
            out += [n for n in problem.names if local_name(n)[0] == p and n not in out]
    return out


def _new_effects(problem: Problem, effects=None) -> list:
    """The added effects of the problem's model that ``effects`` names (all when None)."""
    if effects is None:
        return list(problem.model.added)
    want = {e if isinstance(e, str) else e.name for e in effects}
    return [e for e in problem.model.added if e.name in want]


def _put(problem: Problem, x: np.ndarray, values: Mapping[str, float]) -> np.ndarray | None:
    """``x`` with some values replaced; None when a value lies outside its bounds."""
    x = np.array(x, float)
    for n, v in values.items():
        if n not in problem.names:
            continue
        j = problem.names.index(n)
        if not (problem.lower[j] <= v <= problem.upper[j]) or not math.isfinite(v):
            return None
        x[j] = v
    return x


def refit_starts(
    problem: Problem,
    x_parent: np.ndarray,
    diagnosed: Mapping[str, float],
    effects=None,
    *,
    data_start: bool = True,
) -> list[RefitStart]:
    """The starts of :func:`refit_added`: ``x_parent`` (the parent fit, the added effects'
    parameters at their typical start) with the added parameters varied.

    ``diagnosed`` holds the diagnosis's one-step estimates and best nuisance grid point
    (:func:`rotorbayes.inference.results.diagnosis_starts`), empty when there is no diagnosis;
    ``effects`` names the effects new to this fit (default every added one: effects the
    parent had keep its values).
    """
    new = _new_effects(problem, effects)
    names = added_names(problem, effects)
    starts: list[RefitStart] = []

    def add(label: str, x) -> None:
        if x is None:
            return
        x = np.clip(np.asarray(x, float), problem.lower, problem.upper)
        if any(np.array_equal(x, s.x0) for s in starts):
            return
        starts.append(RefitStart(label, x))

    if diagnosed:
        add("the diagnosis's one-step estimate", _put(problem, x_parent, diagnosed))
    add("the effect's typical start", x_parent)
    # The parent itself (the effect at its null): the refit never ends above the parent.
    nulls: dict[str, float | None] = {}
    pv = problem.params_for(x_parent, 0)
    for e in new:
        for p in e.parameters:
            if p.nuisance:
                continue
            v = pv.get("Tc_l") if p.name == "Ts_l" else p.null
            nulls.update({n: v for n in names if local_name(n)[0] == p.name})
    known = {n: v for n, v in nulls.items() if v is not None and math.isfinite(v)}
    if nulls and len(known) == len(nulls):
        add("the effect off (the parent fit itself)", _put(problem, x_parent, known))
    # Spread over the nuisance shape parameters (no gradient at the null: the optimiser
    # keeps whatever it starts with unless the data pull hard).
    spread: list[dict[str, float]] = [{}]
    for e in new:
        for p in e.parameters:
            if not p.nuisance or p.name not in names:
                continue
            grid: tuple[float, ...]
            if p.name == "ws_l":
                grid = WS_STARTS
            elif p.name == "delta_l":
                grid = DELTA_STARTS
            else:
                lo, hi = float(p.lower), float(p.upper)
                if not (math.isfinite(lo) and math.isfinite(hi)):
                    continue
                grid = tuple(lo + (hi - lo) * (k + 0.5) / 4 for k in range(4))
            spread = [{**s, p.name: v} for s in spread for v in grid]
    base = _put(
        problem,
        x_parent,
        {
            k: v
            for k, v in diagnosed.items()
            if k not in {p.name for e in new for p in e.parameters if p.nuisance}
        },
    )
    base = x_parent if base is None else base
    for s in spread:
        if s:
            add(
                "spread: " + ", ".join(f"{k} {v:.3g}" for k, v in s.items()), _put(problem, base, s)
            )
    if not any(p.nuisance for e in new for p in e.parameters):
        # No shape to spread: the size of the effect itself, a decade either side of
        # the typical start (an effect far from the floor can be larger or smaller); a
        # signed parameter that starts at 0 (an offset, a torsion) both ways, at a tenth
        # and a third of its range's half-width.
        for f in (0.1, 10.0):
            vals = {
                n: float(x_parent[problem.names.index(n)]) * f
                for n in names
                if x_parent[problem.names.index(n)] != 0
            }
            if vals:
                add(f"spread: the added parameters x{f:g}", _put(problem, x_parent, vals))
        for f in (-0.3, -0.1, 0.1, 0.3):
            vals = {}
            for n in names:
                j = problem.names.index(n)
                lo, hi = problem.lower[j], problem.upper[j]
                if x_parent[j] == 0 and lo < 0 < hi and math.isfinite(hi - lo):
                    vals[n] = f * 0.5 * (hi - lo)
            if vals:
                add(
                    "spread: " + ", ".join(f"{n} {v:+.3g}" for n, v in vals.items()),
                    _put(problem, x_parent, vals),
                )
    if data_start:
        x = _data_start(problem, x_parent, names)
        if x is not None:
            add("a start from the data with the effect", x)
    return starts


def _data_start(problem: Problem, x_parent: np.ndarray, names: list[str]):
    """The regression start of the model with the effect on (every free parameter), or
    None when the regression does not reach any added parameter."""
    from .first_fit import _within_constraints
    from .starts import data_start

    try:
        ds = data_start(problem)
        x = problem.x_from(ds.values)
    except Exception:  # noqa: BLE001 - a regression that fails is one start fewer
        return None
    x = _within_constraints(problem, np.clip(x, problem.lower, problem.upper))
    # Reached: estimated by the regression, or set from what it found (an upper
    # asymmetry beyond its level is a voltage offset, see _within_constraints).
    reached = [
        n
        for n in names
        if str(ds.source.get(local_name(n)[0], "")).startswith("data")
        or x[problem.names.index(n)] != x_parent[problem.names.index(n)]
    ]
    return x if reached else None


def refit_added(
    problem: Problem,
    x_parent: np.ndarray,
    diagnosed: Mapping[str, float],
    effects=None,
    *,
    workers: int = 2,
    executor=None,
    verbose: bool = False,
    **fit_kw,
) -> Refit:
    """Fit ``problem`` (a parent fit's model with effects added) from the starts of
    :func:`refit_starts`, keep the smallest estimation SSR, and give it honest standard
    errors.  Starts that cannot be fitted are counted as failures, never as minima."""
    from .first_fit import LOCAL_PARALLEL_BYTES, _complete

    starts = refit_starts(problem, x_parent, diagnosed, effects)
    names = added_names(problem, effects)
    kw = dict(fit_kw)
    kw["uncertainty"] = False
    if verbose:
        print(
            f"searching the added parameters ({', '.join(names)}) from {len(starts)} "
            "starts, every other parameter from the parent fit:",
            flush=True,
        )
    if 8 * problem.n_residuals * len(problem.names) > LOCAL_PARALLEL_BYTES and isinstance(
        executor if executor is not None else current_executor(),
        ThreadPoolExecutor | DefaultPool | type(None),
    ):
        executor, workers = SerialExecutor(), 1  # long data: one fit's Jacobian at a time
    # Long data: every start screened with a few evaluations, the best one finished
    # (nine full fits of 4 x 600 s would take the better part of an hour).
    screen = problem.n_residuals > LONG_RESIDUALS and len(starts) > 1
    if screen:
        kw["max_nfev"] = min(SCREEN_NFEV, int(kw.get("max_nfev", 200)))
        if verbose:
            print(
                f"  long data ({problem.n_residuals} residuals): each start screened with "
                f"at most {kw['max_nfev']} evaluations, the best one then fitted to the "
                "end",
                flush=True,
            )
    tasks = run_tasks(
        _fit_start, [s.x0 for s in starts], shared=(problem, kw), executor=executor, workers=workers
    )
    results: dict[int, FitResult] = {}
    for j, (r, why) in progress(tasks, len(starts), "refit starts", enabled=verbose):
        s = starts[j]
        if r is None:
            s.failed = why
            continue
        r.problem = problem  # a process or Dask worker sent back its own copy
        s.ssr, s.success = float(r.ssr), bool(r.success)
        s.ratio = floor_ratio(problem, r.x)
        results[j] = r
    if not results:
        from .least_squares import StartError

        raise StartError(
            "no start of the refit could be fitted: "
            + "; ".join(f"{s.label}: {s.failed}" for s in starts)
        )
    # In start order on ties: the choice does not depend on who finished first.
    kept = min(results, key=lambda j: (results[j].ssr, j))
    best = results[kept]
    if screen:
        from .least_squares import fit as _fit

        best = _fit(problem, best.x, **{**fit_kw, "uncertainty": False})
        s = starts[kept]
        best.x0 = s.x0  # where the search began, as the start column says
        s.ssr, s.success, s.ratio = (
            float(best.ssr),
            bool(best.success),
            floor_ratio(problem, best.x),
        )
        s.label += " (screened, then fitted to the end)"
    _complete(best, fit_kw)
    out = Refit(best, starts, kept, names)
    if out.disagreed():
        ends = sorted((s.ratio, s.label) for s in starts if math.isfinite(s.ratio))
        out.notes.append(
            f"the starts disagreed ({ends[0][0]:.3g}x to {ends[-1][0]:.3g}x the floor): the "
            f"start decides where this fit ends, so the kept one ({out.chose}) is the best "
            "found, not proven the best there is; `rotorbayes multistart` searches wider"
        )
    return out


def prediction_note(
    ratio: float, predicted: float | None, effects: list[str], command: str | None = None
) -> str | None:
    """What to say when a refit ends above the worst RMS/floor the diagnosis predicted for
    adding ``effects`` (None when it does not, or there was no prediction)."""
    if predicted is None or not math.isfinite(predicted) or not math.isfinite(ratio):
        return None
    if ratio <= ABOVE_PREDICTION * predicted:
        return None
    what = " and ".join(effects)
    return (
        f"the refit ended at {ratio:.3g}x the floor, above the {predicted:.3g}x the "
        f"diagnosis predicted for adding {what}: no start reached the basin the score "
        "test saw, or the effect is not what the data lack (its one-step prediction is "
        "linear in a small change). Distrust this fit; run `rotorbayes diagnose` on the "
        "parent again with a different candidate, or search wider with `rotorbayes "
        "multistart`" + (f" ({command})" if command else "")
    )


def diagnosis_prediction(doc: Mapping | None, effects: list[str]) -> float | None:
    """The worst predicted RMS/floor the diagnosis beside a parent fit gave for adding one
    of ``effects`` (the only one added; None for several or none)."""
    if not doc or len(effects) != 1:
        return None
    for row in doc.get("ranking", []):
        if row.get("effect") == effects[0]:
            j = row.get("judgement") or {}
            v = j.get("predicted_worst_rms_over_floor")
            if v is None and row.get("predicted_rms_over_floor"):
                v = max(row["predicted_rms_over_floor"].values())
            return float(v) if v is not None else None
    return None


def effect_names(problem: Problem) -> list[str]:
    """Names of the added effects as the command line writes them."""
    return [
        e.name if e.source == "catalogue" else f"{e.source}:{e.name}" for e in problem.model.added
    ]


__all__ = [
    "Refit",
    "RefitStart",
    "added_names",
    "diagnosis_prediction",
    "effect_names",
    "prediction_note",
    "refit_added",
    "refit_starts",
]

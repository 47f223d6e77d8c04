"""How good a fit is and what to distrust: the verdict printed with every result.

* per experiment and channel, the residual RMS as a multiple of the encoder quantisation
  floor (:func:`rotorbayes.io.measurements.quantisation_floor`, thesis §2.2) on estimation and
  validation data;
* a warning for every estimate at or near a bound (and what that usually means), every
  free parameter the residual does not depend on, every fixed parameter that would lower
  the SSR much if freed while the fit is far above the floor (one Gauss-Newton step in
  that parameter, the others re-adjusted), and a fit that did not converge.

Nothing here changes a number; it says which numbers to trust.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..io.measurements import quantisation_floor
from ..kernel.terms import CONSTRAINTS
from .problem import local_name

#: RMS / floor up to which a channel counts as "at the floor" and "near the floor".
AT_FLOOR = 1.5
NEAR_FLOOR = 3.0

#: Validation data this far above the floor get a note when the estimation data are at it;
#: the spread of the estimates' own predictions there (:func:`validation_spread`) says
#: whether their uncertainty explains it.
VALIDATION_NOTE = 1.5
#: Relative distance to a bound (of the bounds' width) that counts as "at the bound".
BOUND_TOL = 1e-3
#: An estimate nearer a bound than two standard errors is warned about when it is
#: also within this fraction of its range of it.
NEAR_BOUND = 0.05
#: The integrator's own error (RMS, its steps against finer ones) above this share
#: of the floor is material: added in quadrature it alone would raise the RMS / floor of a
#: fit at the floor by over 4 % -- and it is not noise, so tests and intervals see it.
INTEGRATION_LIMIT = 0.3


@dataclass
class Assessment:
    """Fit quality against the noise floor, and warnings in words."""

    channels: list[dict]
    warnings: list[str] = field(default_factory=list)
    at_bound: list[str] = field(default_factory=list)
    #: Nearer a bound than two standard errors (and within NEAR_BOUND of the range).
    near_bound: list[str] = field(default_factory=list)
    fixed_suspects: list[dict] = field(default_factory=list)
    jitter_floor: bool = False  # a floor is the data's own jitter, not the encoder's step
    #: What the validation data's worst RMS/floor would be if the model were right and only
    #: the estimates' own uncertainty separated the fit from the truth (see
    #: :func:`validation_spread`); None when not computed.
    spread: dict | None = None

    @property
    def worst_ratio(self) -> float:
        """The headline number: the worst fitted channel's RMS / floor on the *estimation*
        data -- the same number `diagnose`, the restarts and `compare` use."""
        r = [c["ratio"] for c in self.channels if c["fitted"] and c["data"] == "estimation"]
        return max(r) if r else math.nan

    @property
    def integration_ratio(self) -> float:
        """The integrator's own error (RMS) over the floor, worst fitted channel on any
        data (NaN when not checked)."""
        r = [
            c["integration_ratio"]
            for c in self.channels
            if c["fitted"] and c.get("integration_ratio") is not None
        ]
        return max(r) if r else math.nan

    def integration_line(self) -> str:
        """One line: the integrator's own error at the fit, per fitted channel."""
        rows = [
            c
            for c in self.channels
            if c["fitted"] and c["data"] == "estimation" and c.get("integration_max") is not None
        ]
        if not rows:
            return "integration check: not made (the simulation failed at the fit)"
        several = len({c["experiment"] for c in rows}) > 1
        parts = ", ".join(
            (f"{c['experiment']} " if several else "")
            + f"{c['channel']} {c['integration_max']:.2g} rad largest "
            f"({c['integration_ratio']:.2g}x the floor as RMS)"
            for c in rows
        )
        fine = rows[0].get("integration_fine_step")
        against = f"steps of {1e3 * fine:.3g} ms" if fine else "finer steps"
        return f"integration check at the fit (its step grid against {against}): {parts}"

    @property
    def worst_ratio_validation(self) -> float:
        """The same on the validation data (NaN without validation data)."""
        r = [c["ratio"] for c in self.channels if c["fitted"] and c["data"] == "validation"]
        return max(r) if r else math.nan

    @property
    def verdict(self) -> str:
        text = self._verdict()
        if self.jitter_floor:
            text = text.replace("the encoder floor", "the noise floor").replace(
                "the quantisation RMS",
                "the floor (the data's jitter is above the encoder's quantisation)",
            )
        return text

    def _verdict(self) -> str:
        w = self.worst_ratio
        if not math.isfinite(w):
            return "no fitted channel could be simulated"
        v = self.worst_ratio_validation
        val = f"; validation data: {_times(v)} the floor" if math.isfinite(v) else ""
        if w <= AT_FLOOR:
            text = (
                f"at the encoder floor on the estimation data (worst fitted channel "
                f"{_times(w)} the quantisation RMS{val})"
            )
        elif w <= NEAR_FLOOR:
            text = (
                f"near the encoder floor on the estimation data (worst fitted channel "
                f"{_times(w)} the quantisation RMS{val})"
            )
        else:
            text = (
                f"{_times(w)} the encoder floor on the estimation data (worst fitted "
                f"channel{val}): the model does not explain the data to the encoders' "
                "resolution (a missing effect, a wrong fixed value or a wrong basin)"
            )
        if math.isfinite(v) and v > NEAR_FLOOR >= w:
            text += "; " + self.validation_words()
        return text

    def validation_words(self) -> str:
        """Why the validation data sit above the floor while the estimation data do not:
        more than the estimates' uncertainty explains (the model does not predict), or
        within it (the estimation data do not determine the parameters well enough)."""
        v = self.worst_ratio_validation
        sp = self.spread
        if sp is None:
            return (
                "above the floor on the validation data: the model fits these data "
                "but does not predict others"
            )
        if "undetermined" in sp:
            return (
                "above the floor on the validation data, and the estimation data do not "
                f"determine {', '.join(sp['undetermined'])} (infinite standard errors): "
                "the gap may be theirs rather than a missing effect; fit both together"
            )
        band = f"{_times(sp['q10'])}-{_times(sp['q90'])}"
        if v <= sp["q90"]:
            return (
                f"above the floor on the validation data, but within what the estimates' "
                f"own uncertainty predicts there ({band} for 80 % of {sp['draws']} "
                "parameter draws from the fit's covariance): these data do not determine "
                "the parameters well enough to predict that experiment to the floor; fit "
                "both together to narrow them"
            )
        return (
            f"above the floor on the validation data, more than the estimates' own "
            f"uncertainty predicts there ({band} for 80 % of {sp['draws']} parameter "
            "draws from the fit's covariance): the model fits these data but does not "
            "predict others (a missing effect these data do not excite)"
        )

    def table(self) -> str:
        rows = [
            f"{'data':<10} {'experiment':<22} {'channel':<8} {'RMS [rad]':>10} "
            f"{'floor':>9} {'x floor':>8}"
        ]
        for c in self.channels:
            mark = "" if c["fitted"] else "  (not fitted)"
            rows.append(
                f"{c['data']:<10} {str(c['experiment'])[-22:]:<22} {c['channel']:<8} "
                f"{c['rms']:10.3g} {c['floor']:9.2g} {c['ratio']:8.2f}{mark}"
            )
        return "\n".join(rows)

    def as_dict(self) -> dict:
        return {
            "verdict": self.verdict,
            "worst_ratio_to_floor": self.worst_ratio,
            "worst_ratio_to_floor_validation": (
                None if math.isnan(self.worst_ratio_validation) else self.worst_ratio_validation
            ),
            "headline": "worst fitted channel's RMS / floor on the estimation data",
            "integration_ratio": (
                None if math.isnan(self.integration_ratio) else self.integration_ratio
            ),
            "integration": self.integration_line(),
            "channels": self.channels,
            "warnings": self.warnings,
            "at_bound": self.at_bound,
            "near_bound": self.near_bound,
            "fixed_suspects": self.fixed_suspects,
            "validation_spread": self.spread,
        }


def floor_ratio(problem, x: np.ndarray) -> float:
    """Worst fitted channel's residual RMS over its noise floor at ``x`` (``inf`` when the
    model cannot be simulated there): the headline number of a fit."""
    ev = problem.evaluate(x)
    if not ev.ok:
        return math.inf
    return max(problem.rms_over_floor(ev.residuals).values())


def _times(r: float) -> str:
    """A ratio to the floor as printed everywhere: 1.01x, 12.3x, 710x, 2712x."""
    return f"{r:.3g}x" if r < 1000 else f"{r:.0f}x"


def channel_rows(problem, quality_rows, data: str, floors: dict | None = None) -> list[dict]:
    """RMS per experiment and channel with its noise floor and the ratio."""
    out = []
    floors = floors or {}
    for r in quality_rows:
        for c, st in r["channels"].items():
            floor = floors.get(c, quantisation_floor(c))
            rms = math.sqrt(st["ssr"] / st["n"])
            integ = r.get("integration", {}).get(c)
            out.append(
                {
                    "data": data,
                    "experiment": str(r["experiment"]),
                    "channel": c,
                    "rms": rms,
                    "floor": floor,
                    "ratio": rms / floor,
                    "fitted": c in problem.channels,
                    # the integrator's own error there (None: not checked)
                    "integration_max": None if integ is None else integ["max"],
                    "integration_fine_step": None if integ is None else integ.get("fine_step"),
                    "integration_ratio": None if integ is None else integ["rms"] / floor,
                }
            )
    return out


def integration_warning(problem, ratio: float) -> str | None:
    """What to say when the integrator's own error at a fit (RMS over the floor) is
    material (above :data:`INTEGRATION_LIMIT`); None when it is not."""
    if not (math.isfinite(ratio) and ratio > INTEGRATION_LIMIT):
        return None
    step = problem.sims[0].step if problem.sims else math.nan
    return (
        f"the integrator's own error at this fit is {ratio:.2g}x the floor (RMS, its "
        f"steps of up to {1e3 * step:.3g} ms against finer ones): part of the residual is "
        "the integration, not the model, so distrust the verdict, the diagnosis and the "
        f"intervals; fit again with a shorter step (--step {step / 3:.2g}) and report "
        "the input and parameters (the default step should have been short enough)"
    )


def validation_spread(
    result, experiments, floors: dict, *, draws: int = 40, seed: int = 0, validation_alpha0=None
) -> dict | None:
    """The worst fitted channel's RMS/floor that ``experiments`` (validation data) would
    show if the model were right and the truth were a draw from the fit's honest
    covariance: per draw ``sqrt(floor² + mean((sim(draw) - sim(fit))²)) / floor``, the worst
    channel over the experiments; its 10 %, 50 % and 90 % points over ``draws`` draws
    (fixed seed). ``{"undetermined": names}`` when the covariance is not finite there (the
    data do not determine those parameters); None when fewer than half the draws
    simulate.

    Each validation run keeps the ``alpha0`` of the figure it explains
    (:meth:`~rotorbayes.inference.Problem.validation_params` at the fit; ``validation_alpha0``
    gives the records or values decided there, one per experiment, else they are decided
    here) in every draw."""
    prob = result.problem
    cov = np.asarray(result.honest_covariance(), float)
    if not experiments or cov.size == 0:
        return None
    if not np.all(np.isfinite(cov)):
        bad = [n for n, row in zip(result.names, cov, strict=True) if not np.all(np.isfinite(row))]
        return {"undetermined": bad}
    rng = np.random.default_rng(seed)
    try:
        Z = rng.multivariate_normal(np.asarray(result.x, float), cov, size=draws, method="eigh")
    except (np.linalg.LinAlgError, ValueError):
        return None
    lo, hi = prob.lower, prob.upper
    x_fit = np.asarray(result.x, float)
    given = list(validation_alpha0) if validation_alpha0 is not None else [None] * len(experiments)
    torsion = [
        prob.validation_params(x_fit, ex, g)[1] for ex, g in zip(experiments, given, strict=True)
    ]

    def angles(x, ex, sim, rec):
        s = sim.simulate(prob.validation_params(x, ex, rec)[0], raise_on_failure=False)
        return {"theta_u": s.theta_u, "theta_l": s.theta_l}

    sims = [prob.simulator_for(ex) for ex in experiments]
    runs = list(zip(experiments, sims, torsion, strict=True))
    at_fit = [angles(x_fit, ex, sim, rec) for ex, sim, rec in runs]
    worst = []
    for z in Z:
        z = np.clip(z, lo, hi)
        w = 0.0
        for (ex, sim, rec), ref in zip(runs, at_fit, strict=True):
            got = angles(z, ex, sim, rec)
            for c in prob.channels:
                d = got[c] - ref[c] if got[c] is not None and ref[c] is not None else None
                if d is None or not np.all(np.isfinite(d)):
                    w = math.nan
                    break
                f = floors.get(c, quantisation_floor(c))
                w = max(w, math.sqrt(f * f + float(np.mean(d * d))) / f)
        if math.isfinite(w):
            worst.append(w)
    if len(worst) < draws / 2:
        return None
    q10, q50, q90 = np.quantile(worst, [0.1, 0.5, 0.9])
    return {"q10": float(q10), "q50": float(q50), "q90": float(q90), "draws": len(worst)}


def assess(
    result, q_est, q_val=(), *, sources: dict | None = None, val_experiments=()
) -> Assessment:
    """The :class:`Assessment` of a :class:`~rotorbayes.inference.FitResult`.

    ``q_est`` / ``q_val`` are :func:`~rotorbayes.inference.quality` rows on estimation and
    validation data; ``sources`` says where each fixed value came from (for the words).
    ``val_experiments``: the validation data themselves; when they sit above the floor and
    the estimation data do not, :func:`validation_spread` says whether the estimates' own
    uncertainty explains the gap.
    """
    prob = result.problem
    floors, notes = prob.noise_floors()
    a = Assessment(
        channels=channel_rows(prob, q_est, "estimation", floors)
        + channel_rows(prob, q_val, "validation", floors)
    )
    v = a.worst_ratio_validation
    if val_experiments and math.isfinite(v) and v > VALIDATION_NOTE and a.worst_ratio <= NEAR_FLOOR:
        # The runs' alpha0 as the figure had them (quality's rows carry the records).
        recs = [r.get("validation_alpha0") for r in q_val]
        a.spread = validation_spread(
            result,
            list(val_experiments),
            floors,
            validation_alpha0=recs if len(recs) == len(val_experiments) else None,
        )
    a.warnings.extend(notes)
    a.jitter_floor = bool(notes)
    sources = sources or {}
    if not result.success:
        a.warnings.append(f"the fit did not converge: {result.message}")
    warn = integration_warning(prob, a.integration_ratio)
    if warn:
        a.warnings.append(warn)
    # Estimates at or near a bound: within BOUND_TOL of the range, or nearer to it than two
    # standard errors and within NEAR_BOUND of the range (trial 10: delta_l 4.991 of at
    # most 5, standard error 4.6, passed without a word).
    se = getattr(result, "stderr", None)
    se = np.full(len(result.names), np.nan) if se is None else np.asarray(se, float)
    for n, v, lo, hi, e in zip(result.names, result.x, prob.lower, prob.upper, se, strict=True):
        width = hi - lo
        unit = prob.info(n).unit
        d_lo, d_hi = v - lo, hi - v
        at = d_lo <= BOUND_TOL * width or d_hi <= BOUND_TOL * width
        near = (
            not at
            and math.isfinite(e)
            and e > 0
            and min(d_lo, d_hi) < min(2.0 * e, NEAR_BOUND * width)
        )
        if at or near:
            which, b = ("lower", lo) if d_lo <= d_hi else ("upper", hi)
            (a.at_bound if at else a.near_bound).append(n)
            if which == "lower" and b == 0:
                why = (
                    "the data show none of it, or the fit stopped in a wrong basin "
                    "where it does not matter; with the RMS far above the floor suspect "
                    "the latter"
                )
            else:
                why = (
                    "the fit wants to leave the physical range: usually a wrong basin, "
                    "a missing effect or a wrong fixed value; its standard error means "
                    "nothing"
                )
            where = (
                f"at its {which} bound {b:g} (within {100 * BOUND_TOL:g} % of its "
                f"range, {lo:g} to {hi:g})"
                if at
                else f"{min(d_lo, d_hi):.2g} from its {which} bound {b:g}, less than two "
                f"standard errors ({e:.2g} each; range {lo:g} to {hi:g})"
            )
            a.warnings.append(f"{n} = {v:.4g} {unit} is {where}: {why}")
    # Validity constraints between two parameters (Tc >= |dTc|, ...): the optimiser sees a
    # wall there, and an end point on it is as suspect as one on a bound.
    free = {local_name(n)[0] for n in result.names}
    p = result.params
    for names, text, _ in CONSTRAINTS:
        if len(names) != 2 or not (set(names) & free) or not all(n in p for n in names):
            continue
        a_, b_ = names
        info = prob.model.info[a_]
        if p[a_] - abs(p[b_]) <= BOUND_TOL * (info.upper - info.lower):
            a.warnings.append(
                f"the estimate ends on the validity constraint '{text}' ({a_} = {p[a_]:.4g}, "
                f"{b_} = {p[b_]:.4g}): the fit was stopped by it, which usually means a "
                "wrong basin, a missing effect or a wrong fixed value"
            )
    a.warnings.extend(stribeck_words(result))
    und = result.undetermined()
    if und:
        a.warnings.append(
            f"the data do not determine {', '.join(und)} (the Jacobian is singular along a "
            "direction they take part in): their standard errors are infinite and their "
            "values arbitrary along it; fix one of them or give more informative data"
        )
    # Free parameters the residual does not depend on.
    sigma = min(floors.values())
    for j, n in enumerate(result.names):
        info = prob.info(n)
        s = max(abs(result.x[j]), 1e-3 * (info.upper - info.lower))
        if np.linalg.norm(result.jac[:, j]) * s < sigma:
            a.warnings.append(
                f"{n} does not influence the residual (changing it by {s:.3g} {info.unit} "
                "changes the fit by less than the encoder noise): its estimate is arbitrary; "
                "fix it, or check that the effect it belongs to is excited by this input"
            )
    # Fixed parameters, when the fit is far above the floor.
    if a.worst_ratio > NEAR_FLOOR:
        a.fixed_suspects = fixed_influence(result, sources)
        for s in a.fixed_suspects:
            far = _far_words(s["value"], s["step_to"])
            a.warnings.append(
                f"fixed {s['name']} = {s['value']:.4g} {s['unit']} ({s['source']}): freeing it "
                f"would lower the SSR by about {s['ssr_drop_percent']:.0f} % (one step moves "
                f"it to {s['step_to']:.4g}{far}); check it, or free it with --free"
            )
    return a


def _far_words(value: float, step_to: float) -> str:
    """What a fixed value's one step says when it moves it by more than a factor 2 (a new
    user's fit 1071x the floor moved a geometric inertia 7x): more likely a stand-in for
    what is missing than a wrong value."""
    if value == 0 or not math.isfinite(step_to):
        return ""
    ratio = step_to / value
    if 0.5 <= ratio <= 2.0:
        return ""
    return (
        f", {ratio:.2g} times its value: more likely standing in for a missing effect "
        "than a wrong value"
    )


def stribeck_words(result) -> list[str]:
    """What a fitted lower Stribeck effect says of itself: a static level below the Coulomb
    level (friction that rises with speed from standstill, the opposite of the effect's
    physics: it stands in for something else), or the two levels equal within their
    standard errors (no static peak: the effect is not needed, and its velocity and shape
    mean nothing).  Measured: a cogging torque the catalogue lacks was taken up by
    lower_stribeck with Ts_l 0.0183 below Tc_l 0.0243, unremarked."""
    names = list(result.names)
    if "Ts_l" not in names or "Tc_l" not in names:
        return []
    i, j = names.index("Ts_l"), names.index("Tc_l")
    ts, tc = float(result.x[i]), float(result.x[j])
    try:
        cov = np.asarray(result.honest_covariance(), float)
        var = cov[i, i] + cov[j, j] - 2.0 * cov[i, j]
    except Exception:  # noqa: BLE001 - no covariance: the sign alone is said
        var = math.nan
    se = math.sqrt(var) if math.isfinite(var) and var > 0 else math.nan
    d = ts - tc
    unit = result.problem.info("Ts_l").unit
    pm = f" ± {se:.2g}" if math.isfinite(se) else ""
    if math.isfinite(se) and abs(d) <= 2.0 * se and not d < -0.5 * abs(ts):
        base = "lower_stribeck" in result.problem.model.configuration.base_effects
        how = (
            "--without lower_stribeck"
            if base
            else "from the fit it was added to, with the other effects added since"
        )
        return [
            f"lower_stribeck: Ts_l - Tc_l = {d:.3g}{pm} {unit}, zero within two standard "
            "errors: no static friction peak in these data, so the effect is not needed "
            f"(ws_l and delta_l mean nothing); refit without it ({how})"
        ]
    if d < 0:
        # (Below by more than half the static level, whatever the standard error: a fit
        # that stopped early had Ts_l 0.0274 below Tc_l 0.63 +- 0.38 and was told the
        # effect was "not needed", the effect that had taken it from 697x to 1.28x.)
        return [
            f"lower_stribeck: Ts_l = {ts:.4g} is below Tc_l = {tc:.4g} {unit} "
            f"(by {-d:.3g}{pm}): the fitted friction rises with speed from standstill, the "
            "opposite of a Stribeck effect (static friction above the Coulomb level); it "
            "stands in for something else (a missing effect, a wrong fixed value or a "
            "wrong basin): distrust its parameters and the fall it gave"
        ]
    return []


def fixed_influence(result, sources: dict, *, min_drop: float = 0.1) -> list[dict]:
    """Fixed active parameters whose freeing would lower the SSR by more than ``min_drop``
    of it, by one Gauss-Newton step with the free parameters re-adjusted."""
    prob = result.problem
    free = {local_name(n)[0] for n in result.names}
    cands = [
        n
        for n in prob.model.active
        if n not in free
        and n != "alpha0"
        and math.isfinite(prob.base.get(n, math.nan))
        and not (prob.model.info[n].lower == prob.model.info[n].upper)
    ]
    if not cands:
        return []
    try:
        r = prob.residuals(result.x)
        Jf, _ = prob.jacobian(result.x, cands, r0=r)
    except Exception:  # noqa: BLE001 - an unsimulable perturbation: no advice, no harm
        return []
    if not np.all(np.isfinite(r)):
        return []
    from .least_squares import tsqr

    # [J | Jf_k | r] = Q T, factorised over row blocks (no copy of J, no Q: long data): the
    # part of Jf_k and of r that J cannot explain is T's rows below J's.
    ssr = float(r @ r)
    out = []
    kj = result.jac.shape[1]
    for k, n in enumerate(cands):
        T = tsqr(result.jac, Jf[:, k], r)[kj:, kj:]
        gg = float(T[:, 0] @ T[:, 0])
        if gg <= 0:
            continue
        gr = float(T[:, 0] @ T[:, 1])
        drop = gr**2 / gg
        step_to = float(prob.base[n] - gr / gg)
        info = prob.model.info[n]
        # A step far outside the physical range is not a prediction to quote.
        if drop > min_drop * ssr and info.lower <= step_to <= info.upper:
            out.append(
                {
                    "name": n,
                    "value": float(prob.base[n]),
                    "unit": prob.model.info[n].unit,
                    "source": sources.get(n, "fixed"),
                    "ssr_drop_percent": 100 * drop / ssr,
                    "step_to": step_to,
                }
            )
    return sorted(out, key=lambda d: -d["ssr_drop_percent"])

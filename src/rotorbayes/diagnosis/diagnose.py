"""The diagnosis of a fit: is the remaining error noise, and if not, what is missing?

:func:`diagnose` combines

1. the verdict: the residual RMS of every fitted channel against the noise floor (encoder
   quantisation, plus Gaussian noise if the user says the data have it);
2. the score tests of every catalogue effect that is off (:mod:`.score`), Holm-corrected;
3. the missing-torque map (:mod:`.torque`) for what the catalogue does not hold.

The verdict comes first and is a boolean, ``adequate``.

The rule: significance is not enough
------------------------------------
With thousands of samples a score test detects effects far too small to matter: a delay of
a thousandth of a sample (how the input's unknown shape between samples reads), a torque of
a micro-newton-metre.  A catalogue effect is therefore *claimed* — and a fit called
inadequate because of it — only when it is

1. **significant**: its score test's p-value, Holm-corrected over the effects tested, is
   below :data:`LEVEL`, and it is not equivalent to the free parameters;
2. **material**: adding it is predicted (one Gauss-Newton step) to lower the worst fitted
   channel's RMS/floor by at least :data:`MATERIAL_FRACTION` of its current value *and* by
   at least :data:`MATERIAL_FLOOR_UNITS` floor units (1.01 -> 1.009 is immaterial; 392 -> 1.0
   and 1.3 -> 1.0 are material);
3. **resolvable**: its one-step size reaches what the data can resolve, as the effect's
   registry entry states (:class:`rotorbayes.model.effects.Resolution`: a delay of at least
   a tenth of a sample; a torque at least the friction level's autocorrelation-robust
   standard error);

and the missing-torque map does not point at a variable the effect cannot produce (an
angle or a drift in time).  An effect that is significant but fails 2 or 3 is reported as
*detectable but immaterial* (``immaterial`` in ``diagnosis.json``, with its p-value,
predicted RMS/floor and size against resolution), never as a reason for INADEQUATE.

The verdict: ``adequate`` when the worst channel is at the floor (at most
:data:`rotorbayes.inference.assess.AT_FLOOR` times it) and no effect is claimed.  A fit
above the floor is inadequate even when no catalogue effect is material — the error is not
noise — and the text says that no catalogue effect would lower it, names the missing-torque
map's dependence if the map can support one, and points to writing a user effect
(``docs/effects.md``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..inference.assess import AT_FLOOR, NEAR_FLOOR
from ..inference.problem import Problem, local_name
from ..model import effects as _effects
from .score import EffectScore, score_tests
from .torque import ANGLE_VARIABLES, SHORT, TESTED_BY, TorqueMap, apart, missing_torque

#: Significance level of the ranking (after Holm's correction).
LEVEL = 0.01
#: Far above the floor (worst channel above
#: :data:`rotorbayes.inference.assess.NEAR_FLOOR` times it), an effect that is material and
#: resolvable but not significant at :data:`LEVEL` is named as the one to try (not claimed)
#: if its adjusted p is below this; nearer the floor the tests have their power.
TRY_LEVEL = 0.2
#: A claim must be predicted to lower the worst channel's RMS/floor by at least this
#: fraction of its current value ...
MATERIAL_FRACTION = 0.05
#: ... and by at least this many floor units.
MATERIAL_FLOOR_UNITS = 0.1
#: Missing-torque variables each catalogue effect can produce (a superset of what
#: :data:`rotorbayes.diagnosis.torque.TESTED_BY` says the effect tests: an effect named
#: there for a variable produces it).
EXPLAINS = {e.name: set(e.explains) for e in _effects.CATALOGUE.values()}
#: Variables no catalogue effect produces: a strong dependence on them rules a claim out.
FOREIGN = {*ANGLE_VARIABLES, "time"}


def is_material(before: float, after: float) -> bool:
    """Whether a change of the worst channel's RMS/floor from ``before`` to ``after`` is
    material: a fall of at least :data:`MATERIAL_FRACTION` of ``before`` and at least
    :data:`MATERIAL_FLOOR_UNITS` floor units."""
    fall = before - after
    return bool(fall >= MATERIAL_FRACTION * before and fall >= MATERIAL_FLOOR_UNITS)


#: Stands in the advice for the refit command; the ``diagnose`` command puts the real one
#: (the fit's model, data and folder) in its place (:mod:`rotorbayes.commands.diagnose`).
REFIT_TOKEN = "rotorbayes fit ... --p0 FIT/"


@dataclass
class Diagnosis:
    """Verdict, ranking of catalogue effects and the missing-torque maps of one fit."""

    adequate: bool
    verdict: str
    rms_over_floor: dict[str, float]
    floor: dict[str, float]
    ranking: list[EffectScore]
    maps: list[TorqueMap]
    claimed: str | None
    advice: str
    ssr: float
    seconds: float
    noise_std: float = 0.0
    evidence: list[str] = field(default_factory=list)
    judgements: dict[str, dict] = field(default_factory=dict)
    immaterial: list[dict] = field(default_factory=list)
    #: Far above the floor with nothing claimed: the effect to try first (material,
    #: resolvable, not significant; see :data:`TRY_LEVEL`).
    candidate: str | None = None
    #: Per disc: where a map's words and the score tests disagree, the sentence that says
    #: so (:func:`map_agreement`); absent where they agree or there is nothing to weigh.
    map_notes: dict[str, str] = field(default_factory=dict)

    def map_words(self, m: TorqueMap) -> str:
        """A map's words with what the score tests say against them, if anything."""
        note = self.map_notes.get(m.disc)
        return m.words() + (f"; but {note}" if note else "")

    def as_dict(self) -> dict:
        ranking = []
        for s in self.ranking:
            row = s.as_dict()
            if s.effect in self.judgements:
                row["judgement"] = self.judgements[s.effect]
            ranking.append(row)
        return {
            "adequate": self.adequate,
            "verdict": self.verdict,
            "claimed_effect": self.claimed,
            "candidate_effect": self.candidate,
            "advice": self.advice,
            "evidence": self.evidence,
            "immaterial": self.immaterial,
            "rule": {
                "level": LEVEL,
                "material_fraction": MATERIAL_FRACTION,
                "material_floor_units": MATERIAL_FLOOR_UNITS,
                "at_floor": AT_FLOOR,
            },
            "rms_over_floor": self.rms_over_floor,
            "floor_rad": self.floor,
            "noise_std_rad": self.noise_std,
            "ssr": self.ssr,
            "ranking": ranking,
            "missing_torque": [
                dict(m.as_dict(), words=self.map_words(m), agreement=self.map_notes.get(m.disc))
                for m in self.maps
            ],
            "level": LEVEL,
            "seconds": self.seconds,
        }

    def text(self) -> str:
        lines = [f"verdict: {'ADEQUATE' if self.adequate else 'INADEQUATE'} — {self.verdict}"]
        lines += [f"  {e}" for e in self.evidence]
        lines.append("")
        # A user's own effects (--add) are ranked beside the catalogue's.
        yours = any(r.effect not in _effects.CATALOGUE for r in self.ranking)
        which = "effects (the catalogue's and yours)" if yours else "catalogue effects"
        lines.append(
            f"{which} that are off: those worth a claim first (largest "
            "predicted fall of the error first), then by adjusted p (score tests at "
            f"the fit; p adjusted by Holm over {len(self.ranking)} effects):"
        )
        lines.append(
            f"  {'effect':<26} {'p':>9} {'p adj.':>9} {'pred. RMS/floor':>16}  one-step estimate"
        )
        for s in self.ranking:
            pred = ", ".join(f"{c} {v:.3g}" for c, v in s.predicted_rms_ratio.items())
            est = ", ".join(
                f"{n} = {v:.3g} {u}" if math.isfinite(v) else f"{n}: —"
                for (n, v), u in zip(s.step.items(), s.units, strict=True)
            )
            tag = ""
            if s.blind:
                tag = (
                    "  [no first-order effect at its null: the test cannot see it; "
                    "refit with it (fit --add) to judge it]"
                )
            elif s.equivalent_to_free:
                tag = "  [equivalent to the free parameters: cannot be told apart]"
            elif s.alike:
                tag = f"  [indistinguishable here from {', '.join(s.alike)}]"
            j = self.judgements.get(s.effect)
            if j and j["significant"] and not j["claimable"]:
                tag += "  [detectable but immaterial]"
            lines.append(
                f"  {s.effect:<26} {s.p_value:9.2g} {s.p_adjusted:9.2g} {pred:>16}  {est}{tag}"
            )
        if self.immaterial:
            lines.append("")
            lines.append(
                "detectable but immaterial (a significant score test, yet not "
                "evidence that the effect is there: a claim needs a predicted fall "
                f"of the worst RMS/floor of at least {100 * MATERIAL_FRACTION:g} % "
                f"and {MATERIAL_FLOOR_UNITS:g} floor units, and a size the data can "
                "resolve; below that, what the test sees is as likely the input's "
                "unknown shape between samples or the encoder rounding):"
            )
            for item in self.immaterial:
                lines.append("  " + item["words"])
        lines.append("")
        lines.append("missing-torque map (measured angles, slip samples):")
        for m in self.maps:
            lines.append("  " + self.map_words(m))
        if not self.maps:
            lines.append(
                "  none: fewer than 50 samples in clear slip (at rest, friction "
                "balances any torque, so a map has nothing to show)"
            )
        lines.append("")
        lines.append(self.advice)
        return "\n".join(lines)


def diagnose(
    problem: Problem,
    x: np.ndarray,
    *,
    noise_std: float = 0.0,
    n_blocks: int = 30,
    seed: int = 0,
    user_effects: Sequence[str] = (),
) -> Diagnosis:
    """Diagnose the fit ``x`` of ``problem``.

    Parameters
    ----------
    noise_std : float
        Gaussian measurement noise [rad] the data carry besides encoder quantisation
        (0 for synthetic quantised data; the floor becomes ``sqrt(q²/12 + noise_std²)``).
    user_effects : sequence of str
        Effects of your own (``FILE.py:NAME``) to test beside the catalogue's, with the
        same rules: a score test at the fit, a one-step estimate, a predicted fall.
    """
    t0 = time.perf_counter()
    floor, notes = problem.noise_floors(noise_std if noise_std else None)
    r = problem.residuals(x)
    if not np.all(np.isfinite(r)):
        raise ValueError("the model cannot be simulated at this fit; nothing to diagnose")
    ratios = problem.rms_over_floor(r, floor)
    worst = max(ratios.values())
    context: dict = {}
    extra = {}
    for spec in user_effects:
        pe = problem.with_effects([spec])
        new = [e for e in pe.model.effects if e.name not in problem.model.effect_names]
        if not new:
            raise ValueError(f"{spec}: the fit has this effect on already; nothing to test")
        extra[new[0].name] = pe
    ranking = score_tests(
        problem, x, n_blocks=n_blocks, seed=seed, floor=floor, context=context, extra=extra
    )
    maps = missing_torque(problem, x, floors=floor)
    pooled = (
        f" (the worst of the {len(problem.experiments)} experiments, as `fit` quotes it)"
        if len(problem.experiments) > 1
        else ""
    )
    evidence = notes + [
        "residual RMS / noise floor: "
        + ", ".join(f"{c} {v:.2f} (floor {floor[c]:.2g} rad)" for c, v in ratios.items())
        + pooled
    ]
    judgements = {s.effect: _judge(s, problem, x, worst, context) for s in ranking}

    # Effects worth a claim come first, the one predicted to lower the error most first
    # (all of them are significant: size decides; ties keep the score tests' order), then
    # the rest by adjusted p.  The first row is what the advice names.
    def order(s):
        j = judgements[s.effect]
        return (
            (0, float(f"{j['predicted_worst_rms_over_floor']:.3g}")) if j["claimable"] else (1, 0.0)
        )

    ranking = sorted(ranking, key=order)
    significant = [s for s in ranking if judgements[s.effect]["significant"]]
    claimable = [s for s in significant if judgements[s.effect]["claimable"]]
    immaterial = [
        dict(judgements[s.effect], effect=s.effect)
        for s in significant
        if not judgements[s.effect]["claimable"]
    ]
    at_floor = worst <= AT_FLOOR
    adequate = at_floor and not claimable
    untested = None
    # The map to quote: the one whose explained torque stands highest above its own noise
    # (a disc that lacks a large torque makes the other disc's fitted parameters absorb
    # part of it, and that disc's map then shows a clean but secondary dependence).
    strongest = max(
        (m for m in maps if m.strongest and m.supports_words),
        key=lambda m: math.sqrt(max(m.strongest[1], 0.0)) * m.rms / max(m.noise_rms, 1e-300),
        default=None,
    )
    foreign = None
    if strongest is not None and strongest.strongest[0] in FOREIGN and strongest.strongest[1] > 0.5:
        foreign = strongest
    claimed = None
    notes: dict[str, str] = {}
    n_imm = f"; {len(immaterial)} detectable but immaterial, listed below" if immaterial else ""
    # Material but without the tests' support, largest predicted fall first.
    unsupported = sorted(
        (
            s
            for s in ranking
            if judgements[s.effect]["material"]
            and not judgements[s.effect]["significant"]
            and not s.equivalent_to_free
        ),
        key=lambda s: judgements[s.effect]["predicted_worst_rms_over_floor"],
    )
    if adequate:
        notes = _notes(maps, ranking, judgements, None)
        if unsupported:
            # "No effect would change the fit materially" would contradict the table:
            # one would, by the one-step prediction, but its test does not support it.
            u = unsupported[0]
            w, pr = apart(worst, judgements[u.effect]["predicted_worst_rms_over_floor"])
            verdict = (
                f"the remaining error is consistent with measurement noise (worst "
                f"channel {worst:.2f}x the floor; no catalogue effect is both supported "
                f"by its test and material: {u.effect} is predicted to lower it from "
                f"{w}x to {pr}x, but its test gives p {u.p_adjusted:.2g} after "
                f"correction{n_imm})"
            )
            advice = (
                "Nothing the tests support to add: the model explains these data to the "
                f"encoders' resolution. {u.effect} would lower the worst RMS/floor from "
                f"{w}x to {pr}x by its one-step prediction, but its score test does not "
                f"support it (p {u.p_adjusted:.2g} after correction, a claim needs "
                f"{LEVEL:g}); a longer record, or a refit with --add {u.effect} judged "
                "by `rotorbayes compare` on validation data, would tell whether it is "
                "there."
            )
        else:
            verdict = (
                f"the remaining error is consistent with measurement noise (worst "
                f"channel {worst:.2f}x the floor; no catalogue effect would change the "
                f"fit materially{n_imm})"
            )
            advice = "Nothing to add: the model explains these data to the encoders' resolution."
        if immaterial:
            advice += (
                " What the tests detect is far too small to matter (see 'detectable "
                "but immaterial'); adding it would not change the fit materially."
            )
    else:
        top = claimable[0] if claimable else None
        # Far above the floor the score tests lose power (their variance is estimated from
        # the residuals, which the missing physics dominates): an effect predicted to lower
        # the error materially, and of a size the data resolve, is then named as the one to
        # try -- not claimed -- rather than left out.
        untested = (
            next(
                (
                    s
                    for s in unsupported
                    if judgements[s.effect]["resolvable"]
                    and s.p_adjusted < TRY_LEVEL
                    and worst > NEAR_FLOOR
                ),
                None,
            )
            if top is None
            else None
        )
        vetoed = None
        if untested is not None and _vetoes(foreign, untested.effect):
            vetoed, untested = untested, None  # as for a claim: the dependence comes first
        if top is not None and not _vetoes(foreign, top.effect):
            foreign = None
        if top is not None:
            j = judgements[top.effect]
            pred = j["predicted_worst_rms_over_floor"]
            verdict = (
                f"the model does not explain the data: worst channel {worst:.3g}x the "
                f"floor; adding {top.effect} is predicted to lower it to {pred:.3g}x"
                if not at_floor
                else f"the error is near the floor ({worst:.2f}x) but {top.effect} is "
                f"significant and material (predicted {pred:.3g}x)"
            )
        elif untested is not None:
            pred = judgements[untested.effect]["predicted_worst_rms_over_floor"]
            verdict = (
                f"the error is not noise: worst channel {worst:.3g}x the floor; no "
                f"catalogue effect passes the significance test, but adding "
                f"{untested.effect} is predicted to lower it to {pred:.3g}x (p "
                f"{untested.p_adjusted:.2g} after correction): worth a refit"
            )
        elif vetoed is not None:
            verdict = (
                f"the error is not noise: worst channel {worst:.3g}x the floor; "
                f"{vetoed.effect} would lower it to "
                f"{judgements[vetoed.effect]['predicted_worst_rms_over_floor']:.3g}x but "
                "cannot produce the dependence the missing-torque map shows (below)"
            )
        elif unsupported:
            # Material but without the tests' support: say so, not "immaterial".
            u = unsupported[0]
            j = judgements[u.effect]
            verdict = (
                f"the error is not noise: worst channel {worst:.3g}x the floor, and "
                "no catalogue effect is supported by the tests (the largest "
                f"predicted fall, {u.effect} to "
                f"{j['predicted_worst_rms_over_floor']:.3g}x, has p "
                f"{u.p_adjusted:.2g} after correction"
                + ("" if j["resolvable"] else ", and a size below what the data resolve")
                + ")"
            )
        else:
            verdict = "the error is not noise: " + nothing_material_words(
                worst, ranking, judgements
            )
        if top is not None and foreign is None:
            claimed = top.effect
        named = claimed or (untested.effect if untested is not None else None)
        notes = _notes(maps, ranking, judgements, named)
        if claimed is not None:
            tie = [s.effect for s in significant[1:] if s.effect in top.alike]
            est = _estimate_words(top)
            advice = (
                f"Most likely missing: {top.effect} — {top.physics.rstrip('.')} "
                f"(p {top.p_adjusted:.2g}"
                f" after correction; one-step estimate {est}; predicted worst RMS/floor "
                f"{worst:.3g} -> "
                f"{judgements[top.effect]['predicted_worst_rms_over_floor']:.3g})."
            )
            if tie:
                advice += (
                    f" These data cannot tell it from {', '.join(tie)} (their "
                    "corrections are nearly parallel); validation data or another "
                    "input can."
                )
            if top.equivalences:
                advice += " Registry: " + "; ".join(top.equivalences) + "."
            advice += (
                f"\nAdd it and refit: {REFIT_TOKEN} --add "
                f"{top.effect}; then diagnose the new fit (one effect at a time)."
            )
        elif untested is not None:
            where = _map_words(None, strongest, maps, notes)
            est = _estimate_words(untested)
            advice = (
                f"Worth trying first: {untested.effect} — "
                f"{untested.physics.rstrip('.')} (one-step "
                f"estimate {est}; predicted worst RMS/floor {worst:.3g} -> "
                f"{judgements[untested.effect]['predicted_worst_rms_over_floor']:.3g}). "
                f"Its score test is not significant (p {untested.p_adjusted:.2g} after "
                "correction): this far above the floor the tests have little power, so "
                "a refit decides, not the test. Missing-torque map: " + where + ".\n"
                f"Add it and refit: {REFIT_TOKEN} --add "
                f"{untested.effect}; keep it only if `rotorbayes compare` finds the new "
                "fit materially better on validation data, then diagnose the new fit. "
                "If it does not help, make sure the fit is not a local minimum "
                "(`rotorbayes multistart`)."
            )
        else:
            where = _map_words(foreign, strongest, maps, notes)
            best = top if top is not None else vetoed
            advice = (
                "No catalogue effect explains the residual"
                + (
                    f" (the best, {best.effect}, is material but cannot produce the "
                    "dependence below)"
                    if best is not None
                    else ""
                )
                + f": {where}.\nFirst make sure the fit is not a local minimum "
                "(`rotorbayes multistart` with the fit's options; a better basin is "
                "then the --p0 of a new fit). If it is the best there is, write a user "
                "effect for it (docs/effects.md; examples/angle_friction.py is a worked "
                "example), test it with `rotorbayes diagnose` of this fit and --add "
                "FILE.py:NAME, and refit with the same --add."
            )
    return Diagnosis(
        adequate=adequate,
        verdict=verdict,
        rms_over_floor=ratios,
        floor=floor,
        ranking=ranking,
        maps=maps,
        claimed=claimed,
        advice=advice,
        ssr=float(r @ r),
        seconds=time.perf_counter() - t0,
        noise_std=noise_std,
        evidence=evidence,
        judgements=judgements,
        immaterial=immaterial,
        candidate=untested.effect if not adequate and untested is not None else None,
        map_notes=notes,
    )


def _vetoes(foreign: TorqueMap | None, effect: str) -> bool:
    """Whether the map's clear dependence on a variable no catalogue effect produces
    (``foreign``) rules ``effect`` out: it beats every variable the effect could produce,
    on the same disc's map, by 0.2 in R² (or the effect produces none of them)."""
    if foreign is None or effect not in _effects.CATALOGUE:
        # A user's own effect is written for whatever the map shows: it is judged by its
        # score test and its predicted fall alone.
        return False
    own = [r2 for var, r2 in foreign.ranking if var in EXPLAINS.get(effect, ())]
    return not own or foreign.strongest[1] >= max(own) + 0.2


def _estimate_words(s: EffectScore) -> str:
    """``t_delay ≈ 0.0069 s``: an effect's one-step estimate."""
    return ", ".join(
        f"{n} ≈ {v:.3g} {u}" for (n, v), u in zip(s.step.items(), s.units, strict=True)
    )


def _map_words(
    foreign: TorqueMap | None,
    strongest: TorqueMap | None,
    maps,
    notes: dict[str, str] | None = None,
) -> str:
    """The missing-torque map to quote: a foreign dependence, else the map standing
    highest above its noise, else every map (with what the tests say against it)."""
    notes = notes or {}

    def words(x: TorqueMap) -> str:
        return x.words() + (f"; but {notes[x.disc]}" if notes.get(x.disc) else "")

    m = foreign or strongest
    if m is not None:
        return words(m)
    return "; ".join(words(x) for x in maps) or "no missing-torque map could be made"


def nothing_material_words(
    worst: float, ranking: Sequence[EffectScore], judgements: dict[str, dict]
) -> str:
    """The verdict's words when no catalogue effect is material and none is material
    without the tests' support: "worst channel W x the floor, and ...".

    A prediction is quoted as the best only when it is below the current figure ``worst``;
    when every one-step prediction is at or above it, the words say that no catalogue
    effect is predicted to lower the error (a rise is never "the best")."""
    head = f"worst channel {worst:.3g}x the floor, and "
    preds = [
        (judgements[s.effect]["predicted_worst_rms_over_floor"], i, s)
        for i, s in enumerate(ranking)
        if not s.equivalent_to_free and s.effect in judgements
    ]
    lower = sorted(x for x in preds if x[0] < worst)
    if not lower:
        return head + (
            "no catalogue effect is predicted to lower it (every one-step "
            f"prediction is at or above {worst:.3g}x)"
        )
    detectable = [x for x in lower if judgements[x[2].effect]["significant"]]
    pred, _, s = (detectable or lower)[0]
    j = judgements[s.effect]
    w, pr = apart(worst, pred)
    if detectable and j["material"]:
        # significant and material, yet not claimable: its size is below what the data
        # resolve
        return head + (
            f"no catalogue effect passes the claim rule (the best detectable, "
            f"{s.effect}, is predicted to lower it from {w}x to {pr}x, but its "
            "size is below what the data resolve)"
        )
    if detectable:
        return head + (
            f"no catalogue effect would lower it materially (the best "
            f"detectable, {s.effect}, is predicted to lower it only from {w}x "
            f"to {pr}x)"
        )
    return head + (
        f"no catalogue effect would lower it materially (the largest predicted "
        f"fall, {s.effect}, from {w}x to {pr}x, is immaterial and its test not "
        "significant)"
    )


def effect_discs(effect: str) -> set[str]:
    """The discs ("l", "u") whose balance a catalogue effect's torque enters directly."""
    if effect.startswith("lower_"):
        return {"l"}
    e = _effects.CATALOGUE.get(effect)
    if e is not None and e.motor:
        return {"u"}
    return {"l", "u"}


def _or_list(names: Sequence[str]) -> str:
    """``"a, b or c"``; ``""`` for none."""
    names = list(names)
    if not names:
        return ""
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " or " + names[-1]


def _produces(effect: str) -> str:
    """What a catalogue effect's torque would vary with, in the map's words (a user's
    effect: none the catalogue's table knows)."""
    own = EXPLAINS.get(effect, set())
    return _or_list([SHORT[k] for k in SHORT if k in own]) or "none of the map's variables"


def map_agreement(
    tmap: TorqueMap,
    ranking: Sequence[EffectScore],
    judgements: dict[str, dict],
    named: str | None = None,
) -> str:
    """Whether a map's named dependence and the score tests agree: ``""`` when they do
    (or the map names no dependence), else a sentence that says which contradicts which,
    with the numbers, and what else it could be.

    * The map names a dependence (``tmap.supports_words``) whose usual cause the catalogue
      holds (:data:`rotorbayes.diagnosis.torque.TESTED_BY`), but no such effect is claimable
      or ``named``: the tests of the catalogue's version do not support the map's cause.
    * The tests name an effect (``named``: the claimed one, or the one worth trying) whose
      torque enters this disc but would not vary with the map's variable
      (:data:`EXPLAINS`): one of the two findings is a side effect of the other.

    Parameters
    ----------
    ranking, judgements : the score tests and their judgements (:func:`diagnose`).
    named : the effect the advice names (claimed or worth trying), if any.
    """
    if not tmap.supports_words:
        return ""
    var = tmap.strongest[0]
    scores = {s.effect: s for s in ranking}
    by_disc, otherwise = TESTED_BY.get(var, ({}, ""))
    family = [scores[e] for e in by_disc.get(tmap.disc, ()) if e in scores]

    def backed(s: EffectScore) -> bool:
        j = judgements.get(s.effect, {})
        return s.effect == named or bool(j.get("claimable"))

    def fall(s: EffectScore) -> str:
        j = judgements[s.effect]
        w, pr = apart(j["rms_over_floor"], j["predicted_worst_rms_over_floor"])
        return f"predicted {w}x -> {pr}x"

    if family and not any(backed(s) for s in family):
        parts = []
        for s in family:
            j = judgements.get(s.effect, {})
            if s.equivalent_to_free:
                parts.append(f"{s.effect} cannot be told from the free parameters")
            elif j.get("significant"):
                parts.append(
                    f"{s.effect} p {s.p_adjusted:.2g} after correction but not claimable, {fall(s)}"
                )
            else:
                parts.append(f"{s.effect} p {s.p_adjusted:.2g} after correction")
        if all(s.equivalent_to_free for s in family):
            lead = (
                "the catalogue's version of that cause cannot be tested on these data "
                f"({'; '.join(parts)})"
            )
        else:
            lead = (
                "the score test of the catalogue's version of that cause does not "
                f"support it ({'; '.join(parts)})"
            )
        mine = {s.effect for s in family}
        others = sorted(
            (s for s in ranking if backed(s) and s.effect not in mine),
            key=lambda s: s.effect != named,
        )
        if not others:
            return (
                f"{lead}: it may be {otherwise}, or a side effect of a torque missing "
                "elsewhere (a fit that lacks a torque bends its parameters to take part "
                "of it)"
            )
        o = others[0]
        if o.effect not in EXPLAINS:  # the user's own effect: what it varies with is theirs
            how = f"is your own (the catalogue does not say whether it varies with {SHORT[var]})"
        elif var in EXPLAINS[o.effect]:
            how = "can vary with " + SHORT[var] + " too"
        else:
            how = f"would vary with {_produces(o.effect)}, not with {SHORT[var]}"
        return (
            f"{lead}; the tests point at {o.effect} instead (p {o.p_adjusted:.2g} after "
            f"correction, {fall(o)}), whose torque {how}: the map's dependence may be a "
            "side effect of it (a fit that lacks a torque bends its parameters, on both "
            f"discs, to take part of it), or {otherwise}"
        )
    if named is None or named not in _effects.CATALOGUE or named not in scores:
        return ""
    if (
        tmap.disc not in effect_discs(named)
        or var in EXPLAINS.get(named, ())
        or any(s.effect == named for s in family)
    ):
        return ""
    s = scores[named]
    what = "claim" if judgements.get(named, {}).get("claimable") else "name as worth trying"
    return (
        f"the score tests {what} {named} (p {s.p_adjusted:.2g} after correction, "
        f"{fall(s)}), whose torque would vary with {_produces(named)}, not with "
        f"{SHORT[var]}: one of the two findings is a side effect of the other; refit with "
        f"{named} and diagnose again"
    )


def _notes(maps, ranking, judgements, named) -> dict[str, str]:
    """:func:`map_agreement` of every map, where it has something to say."""
    out = {}
    for m in maps:
        note = map_agreement(m, ranking, judgements, named)
        if note:
            out[m.disc] = note
    return out


def _rms_speeds(problem: Problem, x: np.ndarray) -> dict[str, float]:
    """RMS speeds of the fit's simulation over all experiments [rad/s]."""
    acc = {"omega_u": [], "omega_l": [], "dalpha": []}
    for i in range(len(problem.experiments)):
        sim = problem.simulate(x, i)
        acc["omega_u"].append(np.asarray(sim.omega_u))
        if sim.omega_l is not None:
            acc["omega_l"].append(np.asarray(sim.omega_l))
            acc["dalpha"].append(np.asarray(sim.omega_l) - np.asarray(sim.omega_u))
    return {
        k: float(np.sqrt(np.mean(np.concatenate(v) ** 2))) if v else math.nan
        for k, v in acc.items()
    }


def _judge(s: EffectScore, problem: Problem, x: np.ndarray, worst: float, context: dict) -> dict:
    """Significant, material, resolvable? With the numbers (see the module docstring)."""
    pred = max(s.predicted_rms_ratio.values()) if s.predicted_rms_ratio else worst
    fall = worst - pred
    significant = bool(s.p_adjusted < LEVEL and not s.equivalent_to_free)
    material = is_material(worst, pred)
    effect = _effects.CATALOGUE.get(s.effect)
    res = effect.resolution if effect is not None else None
    sizes = [abs(v) for v in s.size.values() if math.isfinite(v)]
    size = max(sizes) if sizes else math.nan
    out = {
        "significant": significant,
        "material": material,
        "p_value": s.p_value,
        "p_adjusted": s.p_adjusted,
        "rms_over_floor": worst,
        "predicted_rms_over_floor": s.predicted_rms_ratio,
        "predicted_worst_rms_over_floor": pred,
        "predicted_fall": fall,
    }
    if res is None or not math.isfinite(size):
        out.update(
            size=None, resolution=None, resolvable=True, resolution_words="no resolution stated"
        )
    else:
        unit = problem.model.info[local_name(next(iter(s.size)))[0]].unit
        if res.kind == "sample":
            dt = min(ex.dt for ex in problem.experiments)
            out.update(
                size={"value": size, "unit": unit},
                resolution={"value": res.factor * dt, "unit": unit, "samples": res.factor},
            )
            resolvable = size >= res.factor * dt
        else:
            if res.per_unit in ("", None):
                per = 1.0
            elif res.per_unit in ("omega_u", "omega_l", "dalpha"):
                if "speeds" not in context:
                    context["speeds"] = _rms_speeds(problem, x)
                per = context["speeds"][res.per_unit]
            else:
                per = float(problem.params_for(x, 0).get(res.per_unit, math.nan))
            se = context.get("robust_se", {}).get(f"Tc_{res.disc}", math.nan)
            torque = size * per
            out.update(
                size={"value": size, "unit": unit, "torque_N_m": torque},
                resolution={
                    "torque_N_m": res.factor * se,
                    "of": f"robust standard error of Tc_{res.disc}",
                },
            )
            # Without a known uncertainty (Tc fixed) only the materiality rule applies.
            resolvable = (
                not math.isfinite(se) or not math.isfinite(torque) or torque >= res.factor * se
            )
        out.update(resolvable=bool(resolvable), resolution_words=res.words)
    out["claimable"] = bool(significant and material and out["resolvable"])
    why = []
    if not significant:
        why.append(
            "equivalent to the free parameters"
            if s.equivalent_to_free
            else f"not significant (a claim needs p < {LEVEL:g} after correction)"
        )
    if not material:
        w, pr = apart(worst, pred, 4)
        change = (
            f"a fall of {fall:.2g} ({100 * fall / worst if worst else 0:.2g} %)"
            if fall > 0
            else "no fall"
            if fall == 0
            else f"a rise of {-fall:.2g} ({-100 * fall / worst if worst else 0:.2g} %)"
        )
        why.append(f"predicted worst RMS/floor {w} -> {pr}, {change}: immaterial")
    if not out["resolvable"]:
        if res.kind == "sample":
            why.append(
                f"size {size:.2g} s is below the resolution "
                f"{out['resolution']['value']:.2g} s ({res.factor:g} sample): "
                f"{res.words}"
            )
        else:
            why.append(
                f"size {size:.2g} {out['size']['unit']} ({out['size']['torque_N_m']:.2g}"
                f" N m) is below the resolution {out['resolution']['torque_N_m']:.2g}"
                f" N m: {res.words}"
            )
    out["words"] = f"{s.effect}: p {s.p_adjusted:.2g} after correction; " + (
        "; ".join(why) if why else "claimable"
    )
    return out

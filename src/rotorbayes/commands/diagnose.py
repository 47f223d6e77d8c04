"""``rotorbayes diagnose``: is the remaining error noise? which effect is missing?"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

from ..inference.assess import VALIDATION_NOTE
from ..io.outputs import InterruptGuard, save_figure_atomic, write_text_atomic
from ..util.exitcodes import Interrupted, Refused
from .common import Outcome, say_glitches, strict_json
from .options import add_changed_data_option, add_trust_option, ranged

HELP = (
    "is the remaining error noise? which effect is missing? (writes diagnosis.json and "
    "figures into the fit folder)"
)


def add_arguments(g) -> None:
    g.add_argument("fit", help="a folder written by `rotorbayes fit`")
    g.add_argument(
        "--noise",
        type=ranged(ge=0, le=1, why=" rad (a standard deviation)"),
        default=None,
        help="Gaussian measurement noise std [rad] besides encoder quantisation (default 0)",
    )
    g.add_argument(
        "--add",
        action="append",
        metavar="FILE.py:NAME",
        default=None,
        help="an effect of your own to test beside the catalogue's (repeatable): "
        "a score test at the fit, a one-step estimate that `fit --p0` of this "
        "folder starts from, a predicted fall (see docs/effects.md)",
    )
    g.add_argument(
        "--no-trials",
        dest="trials",
        action="store_false",
        help="far above the floor, skip the trial refits (one refit of every "
        "candidate effect, its parameters searched, ranked by where it ends)",
    )
    g.add_argument(
        "--no-proposal",
        dest="proposal",
        action="store_false",
        help="when no catalogue effect brings the fit near the floor, do not "
        "propose a missing term (a sparse regression of the missing torque, "
        "written as proposal.py beside the fit with its refit command)",
    )
    add_trust_option(g)
    add_changed_data_option(g)


def _integration(result) -> dict:
    """The integrator's own error at the fit, in words (what a verdict must not forget)."""
    from ..inference import quality
    from ..inference.assess import Assessment, channel_rows, integration_warning

    prob = result.problem
    floors, _ = prob.noise_floors()
    a = Assessment(channels=channel_rows(prob, quality(prob, result.x), "estimation", floors))
    r = a.integration_ratio
    return {
        "ratio": None if math.isnan(r) else r,
        "line": a.integration_line(),
        "warning": integration_warning(prob, r),
    }


def diagnose(
    fit: str,
    *,
    noise: float | None = None,
    trust_effects: bool = False,
    add: list[str] | None = None,
    trials: bool = True,
    accept_changed_data: bool = False,
    proposal: bool = True,
) -> Outcome:
    """Verdict, ranking of missing effects and missing-torque map of the fit folder ``fit``
    (written into it: diagnosis.json, diagnosis_candidates.png, missing_torque.png).
    ``noise`` is Gaussian measurement noise [rad] besides the encoders' rounding.  A data
    file changed since the fit is refused unless ``accept_changed_data`` (then
    diagnosis.json names it under ``data_changed``).  ``proposal``: when no catalogue
    effect brings the fit near the floor, propose a missing term (proposal.py in the fit
    folder, :mod:`rotorbayes.diagnosis.proposal`).  ``Outcome.doc`` is diagnosis.json's
    document."""
    from ..diagnosis import diagnose as run_diagnosis
    from ..diagnosis.figures import plot_candidates, plot_torque_map
    from ..inference.results import load_fit
    from ..io.outputs import folder_lock

    t_start = time.perf_counter()
    result = load_fit(fit, trust_effects=trust_effects, accept_changed_data=accept_changed_data)
    if noise is not None and not (noise >= 0 and math.isfinite(noise)):
        raise Refused(f"--noise {noise}: give the Gaussian noise std in rad (>= 0)")
    print(
        f"diagnosing {result.folder}/ ({result.doc['config']} configuration, "
        f"{len(result.problem.names)} free parameters, effects: "
        f"{', '.join(result.problem.model.effect_names) or 'none'})"
    )
    say_glitches(result.problem.experiments, result.validation)  # as loaded here
    specs = {}
    for spec in add or []:
        if ":" not in spec or not spec.split(":", 1)[0].endswith(".py"):
            raise Refused(
                f"--add {spec}: give an effect of your own as FILE.py:NAME (the "
                "catalogue's effects are tested anyway)"
            )
        from ..model import effects as _effects

        try:
            e = _effects.resolve([spec])[0]
        except (_effects.EffectError, ValueError) as exc:
            raise Refused(f"--add {spec}: {exc}") from None
        if e.name in result.problem.model.effect_names:
            raise Refused(f"--add {spec}: the fit has {e.name} on already; nothing to test")
        specs[e.name] = spec
    if specs:
        print(f"testing beside the catalogue: {', '.join(specs.values())}")
    d = run_diagnosis(
        result.problem, result.x, noise_std=noise or 0.0, user_effects=list(specs.values())
    )
    d.advice = _with_refit_command(d.advice, result.folder, result.doc, specs)
    print()
    print(d.text())
    cautions = _cautions(result)
    for line in cautions:
        print(f"warning: {line}")
    tried, stood_in = _trials(result, d, specs) if trials else (None, [])
    proposed = _proposal(result, d, tried, specs, stood_in) if proposal else None
    integ = _integration(result)
    print(integ["line"])
    fa = result.doc.get("assessment") or {}
    v = fa.get("worst_ratio_to_floor_validation")
    val = result.validation_summary()  # each run with the alpha0 the fit decided for it
    if val is not None:
        print(val["text"])
        v = val["worst_ratio_to_floor"]
    sp = fa.get("validation_spread")
    if d.adequate and isinstance(v, (int, float)) and v > VALIDATION_NOTE:
        if any(" is inverted at this fit " in c for c in cautions):
            why = (
                "an effect of the model is inverted at this fit (above): the gap is more "
                "likely what it stands in for than the parameters' uncertainty"
            )
        elif isinstance(sp, dict) and sp.get("undetermined"):
            why = (
                f"the estimation data do not determine {', '.join(sp['undetermined'])} "
                "(infinite standard errors), so the gap may be theirs rather than a "
                "missing effect: fit both together"
            )
        elif isinstance(sp, dict) and v <= sp.get("q90", -1.0):
            why = (
                f"within what the estimates' own uncertainty predicts there "
                f"({sp['q10']:.3g}x-{sp['q90']:.3g}x for 80 % of {sp['draws']} parameter "
                "draws): these data do not determine the parameters well enough to "
                "predict that experiment to the floor; fit both together to narrow them"
            )
        else:
            why = (
                "the model fits these data but predicts others less well (a missing "
                "effect these data do not excite, or parameters they do not determine)"
                + (
                    f"; the estimates' own uncertainty explains up to {sp['q90']:.3g}x "
                    "(90 % of parameter draws)"
                    if isinstance(sp, dict) and "q90" in sp
                    else ""
                )
                + ": compare the fit on its validation data, or fit both together"
            )
        print(
            f"note: this verdict is on the estimation data; the fit's validation data are "
            f"at {v:.3g}x the floor: {why}"
        )
    if integ["warning"]:
        print(f"warning: {integ['warning']}", file=sys.stderr)
    doc = d.as_dict()
    doc["integration"] = integ
    doc["validation"] = (
        None if val is None else {k: val[k] for k in ("worst_ratio_to_floor", "alpha0")}
    )
    doc["fit"] = str(result.folder)
    doc["trials"] = tried
    doc["cautions"] = cautions
    doc["refit_choice"] = (tried or {}).get("choice")
    doc["proposal"] = None if proposed is None else proposed.as_dict()
    if result.changed_data:  # diagnosed on data the fit was not made from
        doc["data_changed"] = result.changed_data
    # The three files go together: one lock on the fit folder, and Ctrl-C waits for them.
    with folder_lock(result.folder, flag="diagnose", other=None), InterruptGuard().start() as guard:
        figs = [
            (plot_candidates(result.problem, result.x, d)[0], "diagnosis_candidates.png"),
            (plot_torque_map(d)[0], "missing_torque.png"),
        ]
        for fig, name in figs:
            save_figure_atomic(fig, result.folder / name)
        if proposed is not None and proposed.kept:
            from ..diagnosis.proposal import FILE_NAME, write_effect_file

            written = Path(write_effect_file(proposed, result.folder, proposed.command)).name
            if written != FILE_NAME:  # an earlier, different proposal.py is kept
                old = proposed.file
                proposed.file = str(Path(old).with_name(written))
                proposed.command = proposed.command.replace(f"{old}:", f"{proposed.file}:")
                print(
                    f"{old} exists with other content (kept: you may have edited it, or "
                    f"refitted it); this proposal is {proposed.file}: refit it with\n"
                    f"  {proposed.command}"
                )
            doc["proposal"] = proposed.as_dict()
        write_text_atomic(result.folder / "diagnosis.json", strict_json(doc))
    if guard.hit:
        raise Interrupted(
            f"interrupted (Ctrl-C) after the diagnosis had finished; it was "
            f"kept, complete, in {result.folder}/ (diagnosis.json and figures)"
        )
    also = f", {Path(proposed.file).name}" if proposed is not None and proposed.kept else ""
    print(
        f"\nwrote {result.folder}/diagnosis.json, diagnosis_candidates.png, "
        f"missing_torque.png{also} (the diagnosis {d.seconds:.1f} s, with "
        f"{'the trial refits and ' if trials else ''}the figures "
        f"{time.perf_counter() - t_start:.1f} s)"
    )
    return Outcome(folder=Path(fit), doc=doc)


def _cautions(result) -> list[str]:
    """What speaks against trusting the diagnosed fit itself, whatever the verdict: a fit
    that stopped before converging, and effects of its model that the fit turned into the
    opposite of their physics (the registry's ``inverted``: an upside-down Stribeck curve
    that takes up a friction rising with speed reached 1.28x on the estimation run, 36.6x
    on the validation run, and was diagnosed ADEQUATE unremarked)."""
    out = []
    doc = result.doc
    if doc.get("success") is False:
        out.append(
            f"the fit did not converge ({doc.get('message') or 'stopped early'}): its "
            "parameters, figures and this diagnosis are of a point short of the minimum; "
            "refit with a larger --max-nfev (or --p0 from it) before you trust them"
        )
    prob = result.problem
    values = {**prob.base, **prob.values(result.x)}
    for e in prob.model.effects:
        why = e.inverted(values)[0] if e.inverted is not None else ""
        if why:
            where = (
                f"refit without it (--without {e.name})"
                if e.name in prob.model.configuration.base_effects
                else "diagnose the fit it was added to: its trial refits and proposal name "
                "what is missing"
            )
            out.append(
                f"{e.name} is inverted at this fit ({why}): it stands in for something the "
                f"model lacks, so the fit's nearness to the floor is no evidence for the "
                f"model; {where}"
            )
    return out


def _trials(result, d, specs: dict) -> tuple[dict | None, list]:
    """Far above the floor (and the model inadequate): refit every candidate effect with its
    parameters searched (:mod:`rotorbayes.diagnosis.trials`), print the ranking and what
    it decides against the score tests; None when not run.  Also the trials that ended
    inverted, for the proposal (:func:`_proposal`)."""
    from ..diagnosis.diagnose import REFIT_TOKEN, is_material
    from ..diagnosis.score import candidates
    from ..diagnosis.trials import (
        TIE,
        TRIAL_ABOVE,
        one_step_starts,
        trial_choice,
        trial_refits,
        trial_table,
    )

    worst = max(d.rms_over_floor.values())
    if d.adequate or not worst > TRIAL_ABOVE:
        return None, []
    prob = result.problem
    names = [e.name for e in candidates(prob)] + list(specs.values())
    print(
        f"\ntrial refits ({worst:.3g}x the floor: far from it the score tests are linear "
        f"guesses, so each of the {len(names)} candidates is refitted, its parameters "
        "searched from several starts; --no-trials skips this):",
        flush=True,
    )
    trials = trial_refits(prob, result.x, names, one_step_starts(d.ranking), verbose=True)
    print(trial_table(trials, worst))
    for t in trials:
        if t.inverted:
            print(f"  [inverted] {t.effect}: {t.inverted}; no claim for it")
    if any(t.at_null for t in trials):
        print("  [ended at its null]: the refit switched the effect off; its fall is no claim")
    best = trial_choice(trials, worst, result.validation)
    tied = [t for t in trials if math.isfinite(t.validation)]
    if len(tied) > 1:
        print(
            f"tied on the estimation data (within {100 * (TIE - 1):.0f} %): "
            + ", ".join(f"{t.effect} {t.validation:.3g}x" for t in tied)
            + " the floor on the validation data (each run with its own torsion)"
        )
    named = d.claimed or d.candidate
    by_name = {t.effect: t for t in trials}
    # Falls that only an inverted effect gives (a friction rising with speed fitted as a
    # Stribeck curve upside down) stand in for something the catalogue lacks: said, and
    # never claimed -- a claim of the score tests for that effect is withdrawn.
    inverted = [
        t
        for t in trials
        if t.inverted and not t.failed and (best is None or t.ratio < best.ratio)
        and is_material(worst, t.ratio)
    ]  # fmt: skip
    stands_in = "".join(
        f"{t.effect} reaches {t.ratio:.3g}x only inverted ({t.inverted}): it stands in for "
        "something the catalogue lacks and is not claimed. "
        for t in inverted
    )
    # A trial whose effect ended switched off (its parameters at their nulls) lowered the
    # error by leaving a local minimum of the model as it is: said, never chosen.
    ended = [t for t in trials if not t.failed and not t.inverted and not t.at_null]
    nulls = [
        t
        for t in trials
        if t.at_null and not t.failed and is_material(worst, t.ratio)
        and (not ended or t.ratio <= TIE * min(e.ratio for e in ended))
    ]  # fmt: skip
    if nulls:
        stands_in += (
            ", ".join(f"{t.effect} ({t.ratio:.3g}x)" for t in nulls)
            + " lowered it with the effect switched off (its parameters ended at their null "
            "values): the fit is in a local minimum of the model as it is, which the refit "
            "left; refit the model from several starts first (`rotorbayes multistart`). "
        )
    withdrawn = d.claimed if d.claimed in {t.effect for t in inverted + nulls} else None
    if withdrawn:
        stands_in += f"The score tests' claim for {withdrawn} is withdrawn. "
    if best is None and nulls:
        words = stands_in + (
            "The other trials end no lower, so their falls may be the same escape: no "
            "catalogue effect is claimed before the model is refitted from several starts"
        )
    elif best is None:
        first = next((t for t in trials if not t.failed and not t.inverted and not t.at_null), None)
        words = stands_in + (
            f"{'No' if stands_in else 'no'} trial refit lowers the worst RMS/floor materially"
            + (f" (the best, {first.effect}, ends at {first.ratio:.3g}x)" if first else "")
            + ": what is missing is not in the catalogue, or the fit is in a wrong basin; "
            "see the missing-torque map"
            + (" and the proposal below" if inverted else "")
            + ", try `rotorbayes multistart`, or write the effect yourself "
            "(docs/effects.md)"
        )
    elif best.effect == named or (specs.get(named or "") == best.effect):
        words = stands_in + (
            f"{'The' if stands_in else 'the'} trial refits agree with the diagnosis: "
            f"{best.effect} lowers the worst "
            f"RMS/floor most, {worst:.3g}x -> {best.ratio:.3g}x"
        )
    else:
        other = by_name.get(named or "")
        than = (
            f"; the effect the score tests named, {named}, reaches {other.ratio:.3g}x"
            if other is not None and not other.failed and not other.inverted
            else ""
        )
        cmd = _with_refit_command(
            f"{REFIT_TOKEN} --add {best.effect}", result.folder, result.doc, specs
        )
        # Far from the floor even with it: the catalogue's best, not an order (a fresh-eyes
        # user followed "Add it and refit" for lower_stribeck, 678x -> 634x, validation
        # 879x -> 1437x, when the proposal below reached 0.997x).
        add = (
            f"Add it and refit: {cmd}"
            if best.ratio <= TRIAL_ABOVE
            else f"It is the catalogue's best; add it ({cmd}) only if the proposal below, "
            "where there is one, does not do better"
        )
        words = stands_in + (
            f"{'The' if stands_in else 'the'} trial refits decide: {best.effect} lowers "
            f"the worst RMS/floor to {best.ratio:.3g}x (from {worst:.3g}x){than}. {add}"
        )
    if best is not None and math.isfinite(best.validation):
        # Tied on the estimation data; the validation runs chose (whichever branch above).
        beaten = [
            t
            for t in trials
            if t is not best
            and math.isfinite(t.validation)
            and t.validation > TIE * best.validation
        ]
        if beaten:
            words += (
                f". {best.effect} and "
                + ", ".join(t.effect for t in beaten)
                + " are tied on the estimation data; the validation data decide ("
                + ", ".join(
                    [f"{best.effect} {best.validation:.3g}x"]
                    + [f"{t.effect} {t.validation:.3g}x" for t in beaten]
                )
                + " the floor, each run with its own torsion)"
            )
    if best is not None:
        # Still tied after the validation data (or with none to ask): say so.
        alike = [
            t.effect
            for t in trials
            if t is not best
            and not t.failed
            and not t.inverted
            and t.ratio <= TIE * best.ratio
            and is_material(worst, t.ratio)
            and (not math.isfinite(best.validation) or t.validation <= TIE * best.validation)
        ]
        if alike:
            words += (
                f". Tied with {', '.join(alike)}: "
                + (
                    "the estimation and validation data"
                    if math.isfinite(best.validation)
                    else "these data"
                )
                + " cannot tell them apart; an experiment that separates them "
                "(`rotorbayes design --separate`) or one more run with a different "
                "initial torsion would"
            )
    if best is not None and best.on_bound:
        words += f" (its {', '.join(best.on_bound)} ended on a bound: distrust the size)"
    if best is not None and best.ratio > TRIAL_ABOVE:
        # The best catalogue effect helps, but leaves the fit far from the floor: say that
        # most of what is missing lies outside the catalogue, not only what to add.
        words += (
            f". Even with it the fit stays {best.ratio:.3g}x the floor: most of what "
            "is missing is not in the catalogue (or the fit is in a wrong basin: "
            "`rotorbayes multistart`); see the missing-torque map and the proposal "
            "below, or write the physics as your own effect -- with a state of its "
            "own if it has memory (docs/effects.md)"
        )
    print(words)
    if withdrawn:
        d.claimed = None  # diagnosis.json's claimed_effect: nothing to add for it
    escape = None
    if best is None and nulls:
        # The better basin of the model as it is, where the lowest such trial ended: what
        # `run` refits from (a --p0 of the model's own parameters).
        t = min(nulls, key=lambda t: t.ratio)
        own = set(prob.names)
        escape = {
            "effect": t.effect,
            "rms_over_floor": t.ratio,
            "params": {
                n: float(v) for n, v in t.result.problem.values(t.result.x).items() if n in own
            },
        }
    return {
        "ran_above": TRIAL_ABOVE,
        "before": worst,
        "choice": None if best is None else best.effect,
        "words": words,
        "trials": [t.as_dict() for t in trials],
        "withdrawn_claim": withdrawn,
        "escape": escape,
    }, inverted


def _proposal(result, d, tried: dict | None, specs: dict, stood_in=()):
    """When no catalogue effect brings the fit near the floor and a map's missing torque is
    well above its noise: the proposed missing term (:mod:`rotorbayes.diagnosis.proposal`),
    printed with its refit command; the caller writes its file.  None: not looked for.
    ``stood_in``: trials that ended inverted (:func:`_trials`), where the term is looked for
    when the fit's own map gives none."""
    import os

    from ..diagnosis.diagnose import REFIT_TOKEN
    from ..diagnosis.proposal import FILE_NAME, catalogue_near_floor, propose

    why = catalogue_near_floor(d, tried)
    p = propose(d.maps, catalogue_near_floor=bool(why))
    if why:
        p.reason = why
    if not p.kept and not why and stood_in:
        # What an inverted trial stood in for shows at its point, the effect replaced by
        # the model's own parameters (trials.point_without): propose from there.
        from ..diagnosis.torque import missing_torque
        from ..diagnosis.trials import point_without

        t = min(stood_in, key=lambda t: t.ratio)
        try:
            maps = missing_torque(result.problem, point_without(result.problem, t))
        except Exception:  # noqa: BLE001 - no map there: the proposal at the fit stands
            maps = []
        if maps:
            p2 = propose(maps, catalogue_near_floor=False)
            if p2.kept:
                at = ", ".join(f"{n} = {v:.4g}" for n, v in t.instead.items())
                p2.where = (
                    f"not at the fit (there: {p.reason}) but at the inverted {t.effect} "
                    f"trial's point with {at} instead of it, where what it stood in for "
                    "shows"
                )
                p = p2
    if p.kept:
        # A fit made with an earlier proposal has "proposed" on: this one gets other names.
        model = result.problem.model
        p.rename([*model.effect_names, *model.info])
        path = result.folder / FILE_NAME
        rel = os.path.relpath(path)
        spec = f"{rel if len(rel) < len(str(path)) else path}:{p.effect}"
        cmd = _with_refit_command(
            f"{REFIT_TOKEN} --add {p.effect}", result.folder, result.doc, {**specs, p.effect: spec}
        )
        # The file is written by diagnose, beside the fit: the refit trusts it as the fit's
        # own (a folder from elsewhere needs --trust-effects, as any effect file does).
        p.file, p.command = str(spec.rpartition(":")[0]), cmd
    if p.kept or not why:
        print()
        print(p.words())
    return p


def _with_refit_command(
    advice: str, folder: Path, doc: dict, specs: dict[str, str] | None = None
) -> str:
    """The advice with its generic refit command made concrete: the fit's model, data and
    validation files (as the user can type them from here), ``--p0`` the fit folder, the
    effect, and a new folder beside the fit."""
    import os
    import re
    import shlex

    from ..diagnosis.diagnose import REFIT_TOKEN
    from ..io.examples import EXAMPLES

    def here(entry: dict) -> str:
        path = str(entry.get("path", ""))
        if not path:
            return "DATA.csv"
        if Path(path).parent.resolve() == EXAMPLES.resolve():
            return f"example:{Path(path).stem}"
        rel = os.path.relpath(path)
        return shlex.quote(rel if len(rel) < len(path) else path)

    files = " ".join(here(e) for e in doc.get("data_files") or []) or "DATA.csv"
    val = "".join(f" --validate {here(e)}" for e in doc.get("validation_files") or [])
    # A validation run's torsion the user gave goes with it into the refit ('fit' for the
    # runs whose torsion was fitted on that run alone).
    given = [t if isinstance(t, dict) else {} for t in doc.get("validation_alpha0") or []]
    if any(t.get("how") == "given" for t in given):
        val += "".join(
            f" --validate-alpha0 {t['value']!r}"
            if t.get("how") == "given"
            else " --validate-alpha0 fit"
            for t in given
        )
    extra = " --prescribed-upper" if doc.get("prescribed_upper") else ""
    chans = doc.get("channels")
    if isinstance(chans, list) and chans and len(chans) == 1:
        extra += f" --channels {chans[0]}"
    name = shlex.quote(os.path.relpath(folder))
    out = folder.name

    def command(m: re.Match) -> str:
        effect = m.group(1)
        spec = shlex.quote((specs or {}).get(effect, effect))
        return (
            f"rotorbayes fit --model {doc.get('config', 'MODEL')} {files}{val}{extra} "
            f"--p0 {name}/ --add {spec} --out {shlex.quote(out + '_' + effect)}/"
        )

    return re.sub(re.escape(REFIT_TOKEN) + r" --add (\S+?)(?=[;\s]|$)", command, advice)

"""``rotorbayes fit``: least squares from a start, judged against the encoder floor.

:func:`fit` writes fit.json and figures into a result folder (:func:`execute` does the
same from a :class:`~rotorbayes.commands.config.FitOptions`); :func:`build_problem` (also
used by ``multistart``) turns the problem options into an estimation problem.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

from ..io.outputs import InterruptGuard, output_folder, save_figure_atomic
from ..model import SimulationError
from ..model import effects as _effects
from ..model import parameters as _params
from ..util import exitcodes as EXIT
from ..util.exitcodes import Interrupted, Refused
from .common import (
    Outcome,
    csv_list,
    fit_effects,
    fit_json,
    load_experiments,
    resolve_values,
    run_values,
    strict_json,
)
from .config import FitOptions, ProblemOptions, ReadOptions, SolverOptions
from .options import MAX_RESTARTS, add_fit_options, ranged

HELP = "least squares from a start P0"


def add_arguments(f) -> None:
    add_fit_options(f)
    f.add_argument(
        "--validate",
        action="append",
        metavar="FILE",
        help="a validation CSV file or example:NAME; repeat the option for several "
        "(--validate a.csv --validate b.csv)",
    )
    f.add_argument(
        "--validate-alpha0",
        action="append",
        metavar="RAD|fit",
        type=_validation_torsion,
        help="the initial string torsion [rad] of a validation run, once per "
        "--validate file in the same order ('fit': fitted on that run alone, the "
        "default whenever the model has a pre-wound string, as with several "
        "estimation files)",
    )
    f.add_argument(
        "--p0",
        help="start: named set (thesis:4.2:P0), TOML or fit.json "
        "(default: a start computed from the data); a fit.json of an upper-"
        "configuration fit also fixes the upper-disc parameters it estimated",
    )
    f.add_argument(
        "--restarts",
        type=ranged(int, ge=0, le=MAX_RESTARTS),
        default=6,
        help="without --p0: extra fits around the data start when the first one "
        "ends above 3x the encoder floor",
    )
    f.add_argument(
        "--no-search",
        dest="search",
        action="store_false",
        help="with --p0 and effects added: start their parameters at one point "
        "(the diagnosis's one-step estimate, else the effect's typical value) "
        "instead of fitting from several starts of them and keeping the best",
    )


def _validation_torsion(text):
    """A ``--validate-alpha0`` value: a number [rad], or 'fit' (None: fitted on that run)."""
    if text is None or (isinstance(text, str) and text.strip().lower() == "fit"):
        return None
    try:
        v = float(text)
    except (TypeError, ValueError):
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a number; give the validation run's initial torsion in rad, "
            "or 'fit' to fit it on that run alone"
        ) from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"{text!r}: give a finite torsion in rad, or 'fit'")
    return v


def fit(
    data,
    *,
    model: str,
    out: str,
    validate=None,
    validate_alpha0=None,
    p0: str | None = None,
    restarts: int = 6,
    free=None,
    fixed=None,
    base: str | None = None,
    add=None,
    without=None,
    channels=None,
    weights: str | None = None,
    prescribed_upper: bool = False,
    max_nfev: int = 200,
    ftol: float = 1e-10,
    xtol: float = 1e-10,
    gtol: float = 1e-10,
    jacobian: str | None = None,
    force: bool = False,
    trust_effects: bool = False,
    step: float | None = None,
    search: bool = True,
    keep_glitches: bool = False,
    columns=None,
    time_unit: str | None = None,
    angle_unit: str | None = None,
    counts_per_rev=None,
) -> Outcome:
    """Fit the ``model`` configuration ("upper", "coupled" or "brake") to the measurement
    files ``data`` and write fit.json and figures into the folder ``out``.

    The start is ``p0`` (a named set, TOML file or fit.json; a fit folder chains the fits)
    or, without it, one computed from the data (with up to ``restarts`` restarts).  ``add``
    and ``without`` switch effects on and off; ``free``/``fixed``/``channels`` (lists or
    comma-separated names) and ``weights`` ("theta_l=1,theta_u=0.1") choose what is fitted;
    ``validate`` names validation files; ``validate_alpha0`` gives each one's initial string
    torsion [rad] ("fit" or None: fitted on that run alone, the default whenever the model
    has a pre-wound string).  With ``p0`` and effects added, ``search``
    fits from several starts of the added parameters (:mod:`rotorbayes.inference.refit`)
    and keeps the best.  ``columns``, ``time_unit``, ``angle_unit`` and ``counts_per_rev``
    say how to read a rig's own files (:class:`rotorbayes.io.rigfiles.ReadSpec`; every data
    and validation file alike); fit.json records them, so later commands read the files
    the same way.  The folder appears only when the fit has finished
    (``force`` replaces an earlier one).  ``Outcome.doc`` is the fit.json document;
    ``exit_code`` is 1 when the fit did not converge.
    """
    problem = ProblemOptions(
        model=model,
        data=data,
        free=free,
        fixed=fixed,
        base=base,
        add=add,
        without=without,
        channels=channels,
        weights=weights,
        prescribed_upper=prescribed_upper,
        step=step,
        keep_glitches=keep_glitches,
        trust_effects=trust_effects,
        read=ReadOptions(columns, time_unit, angle_unit, counts_per_rev),
    )
    return execute(
        FitOptions(
            problem=problem,
            out=out,
            solver=SolverOptions(
                max_nfev=max_nfev, ftol=ftol, xtol=xtol, gtol=gtol, jacobian=jacobian
            ),
            validate=validate,
            validate_alpha0=validate_alpha0,
            p0=p0,
            restarts=restarts,
            search=search,
            force=force,
        )
    )


def execute(options: FitOptions) -> Outcome:
    """:func:`fit` with its options as one :class:`~rotorbayes.commands.config.FitOptions`
    (the form the study builds)."""
    o, pr = options, options.problem
    if o.solver.jacobian == "sensitivity":  # compiled aside while the solver compiles
        from ..util.coldstart import sensitivity_aside

        sensitivity_aside("rotorbayes.inference.problem:compile_sensitivity_kernel")
    guard = InterruptGuard()
    try:
        with output_folder(
            o.out, o.force, inputs=[pr.data, o.validate, o.p0, pr.base, pr.add]
        ) as folder:
            doc = _run(o, folder, guard)
        from ..inference.taskstore import remove_store

        remove_store(o.out)  # the fit folder is complete: no restart left to resume
    except KeyboardInterrupt as exc:
        raise _fit_interrupted(exc, o.out) from None
    except SimulationError as exc:
        from ..inference import StartError

        if isinstance(exc, StartError) and o.p0 and o.p0 not in str(exc):
            raise Refused(f"--p0 {o.p0}: {exc}") from None
        raise
    finally:
        guard.stop()
    if guard.hit:
        raise Interrupted(
            f"interrupted (Ctrl-C) after the fit had finished; its results were "
            f"kept, complete, in {o.out}/ (fit.json and the figures)"
        )
    return Outcome(EXIT.DONE if doc["success"] else EXIT.NOT_CONVERGED, Path(o.out), doc)


def build_model(problem: ProblemOptions, n_experiments: int, carrier: str | None = None):
    """The model: configuration, base effects minus --without, effects inherited from the
    fit.json ``carrier`` names (fit: --p0; multistart: --around), plus --add."""
    from ..model import Model

    pr = problem
    added = list(pr.add or [])
    specs = fit_effects(carrier, pr.model, pr.trust_effects)
    inherited = [e for e in specs if e not in added]
    if (
        n_experiments > 1
        and pr.model != "upper"
        and "initial_torsion" not in added
        and "initial_torsion" not in inherited
    ):
        added.append("initial_torsion")
    model = Model(
        pr.model,
        [*inherited, *added],
        without=pr.without or (),
        prescribed_upper=pr.prescribed_upper,
    )
    if inherited:
        print(f"effects carried over from {carrier}: {', '.join(inherited)}")
    return model, added


def build_problem(
    problem: ProblemOptions,
    exps,
    *,
    p0: str | None = None,
    carrier: str | None = None,
    start_spec=None,
    also=(),
):
    """The estimation problem of the fit/multistart options ``problem`` and the start
    ``p0`` (fit's --p0; effects are carried over from ``carrier``, by default ``p0``).

    ``--add`` frees the effect's parameters, also when ``--free`` is given.  ``--step`` is
    checked against every data file, the validation files ``also`` included; a problem
    with nothing to fit, or a file too short to fit, is refused.
    """
    from ..inference import Problem
    from ..inference.least_squares import check_fittable
    from ..model.simulate import check_step

    pr = problem
    for ex in [*exps, *also]:
        try:
            check_step(pr.step, ex.dt, ex.n, what="--step", where=str(ex.path or ex.name))
        except _params.ParameterError as exc:
            raise Refused(str(exc)) from None

    model, added = build_model(pr, len(exps), carrier or p0)
    free = csv_list(pr.free, "--free")
    fixed = csv_list(pr.fixed, "--fixed") or []
    # Chaining the thesis's steps: a start from an upper-configuration fit fixes the motor
    # and upper-disc parameters it estimated (unless --free says otherwise).
    from_upper: dict[str, float] = {}
    doc = fit_json(p0)
    if doc is not None and doc.get("config") == "upper" and pr.model != "upper" and free is None:
        est = doc.get("estimates", {})
        from_upper = {n: v["value"] for n, v in est.items() if n in model.active}
        fixed += [n for n in from_upper if n not in fixed]
    if free is not None:
        clash = [n for n in fixed if n in free]
        if clash:
            raise Refused(f"{', '.join(clash)} is both --fixed and --free; remove it from one")
        for e in _effects.resolve(added):
            free += [p for p in e.names if p not in free and p not in fixed]
    for n in fixed:
        if n.split("[")[0] not in model.info:
            raise Refused("--fixed: " + _params.unknown_name_message(n))
    base_spec = pr.base or start_spec
    base = resolve_values(base_spec, model) if base_spec else None
    channels = tuple(csv_list(pr.channels, "--channels")) if pr.channels else None
    weights = (
        _parse_weights(pr.weights, pr.model, channels, pr.prescribed_upper)
        if pr.weights is not None
        else None
    )
    prob = Problem(
        model,
        exps,
        free=free,
        base=base,
        channels=channels,
        weights=weights,
        fixed=fixed,
        step=pr.step,
        run_starts=run_values(p0),
    )
    if not prob.names:
        given = pr.fixed if isinstance(pr.fixed, str) else ",".join(pr.fixed or ())
        why, how = (
            (
                f"--fixed {given}: that is every free parameter of this fit",
                "leave it out of --fixed",
            )
            if given
            else ("this fit has no free parameter", "name it with --free")
        )
        raise Refused(f"{why}, so nothing is left to fit; free at least one ({how})")
    try:
        check_fittable(prob)
    except _params.ParameterError as exc:
        raise Refused(str(exc)) from None
    return prob, from_upper


def _parse_weights(text: str, config: str, channels, prescribed_upper: bool) -> dict:
    """``--weights theta_l=1,theta_u=0.1``: channel names and positive finite weights."""
    from ..inference.problem import MAX_WEIGHT, MIN_WEIGHT

    if config == "upper":
        valid = ("theta_u",)
    elif prescribed_upper:
        valid = ("theta_l",)
    else:
        valid = ("theta_u", "theta_l")
    if channels:
        valid = tuple(c for c in valid if c in channels) or valid
    example = ",".join(f"{c}={w}" for c, w in zip(valid, ("1", "0.1"), strict=False))
    form = (
        f"write CHANNEL=WEIGHT pairs separated by commas, e.g. --weights {example} "
        f"(channels of this fit: {', '.join(valid)})"
    )
    weights: dict[str, float] = {}
    items = [x.strip() for x in text.split(",")]
    if not any(items):
        raise Refused(f"--weights {text!r} is empty; {form}")
    for item in items:
        if not item:
            raise Refused(f"--weights {text!r}: an empty entry (two commas?); {form}")
        name, eq, value = item.partition("=")
        name, value = name.strip(), value.strip()
        if not eq:
            sep = next((c for c in ":; " if c in item), None)
            hint = f"use '=' instead of {sep!r}; " if sep else ""
            raise Refused(f"--weights: {item!r} has no '='; {hint}{form}")
        if name not in valid:
            what = (
                "not a channel of this fit"
                if name in ("theta_u", "theta_l", "alpha")
                else "an unknown channel"
            )
            raise Refused(f"--weights: {name!r} is {what}; {form}")
        if name in weights:
            raise Refused(f"--weights: {name} is given twice; give each channel once")
        try:
            w = float(value)
        except ValueError:
            raise Refused(
                f"--weights: the weight {value!r} of {name} is not a number; {form}"
            ) from None
        if not (math.isfinite(w) and w > 0):
            raise Refused(
                f"--weights: the weight of {name} is {value}; it must be a finite "
                "number > 0 (a channel you do not want to fit is left out with "
                "--channels instead)"
            )
        if not MIN_WEIGHT <= w <= MAX_WEIGHT:
            raise Refused(
                f"--weights: the weight of {name} is {value}; give a weight between "
                f"{MIN_WEIGHT:g} and {MAX_WEIGHT:g} (weights set how much one "
                "channel counts against the other; beyond that a channel is ignored "
                "in effect, or its squared residuals overflow; a channel you do not "
                "want to fit is left out with --channels instead)"
            )
        weights[name] = w
    return weights


def _fmt_params(prob, names, x, se=None, x0=None, at_bound=(), near_bound=()) -> str:
    rows = [f"{'parameter':<12} {'estimate':>12} {'std. error':>12} {'start':>12}  unit"]
    from ..util.numformat import mean_sd

    for i, n in enumerate(names):
        # The standard error to two significant digits and the estimate to the same
        # decimal place (a value printed to 5 digits beside an error of 1e-6 of it cannot
        # be compared with anything); without one, the estimate to 6 digits.
        value, err = mean_sd(float(x[i]), float(se[i]) if se is not None else math.nan)
        s = f"{'AT BOUND':>12}" if n in at_bound else f"{err:>12}"
        st = f"{x0[i]:12.5g}" if x0 is not None else ""
        rows.append(
            f"{n:<12} {value:>12} {s} {st}  "
            f"{prob.info(n).unit}" + ("  NEAR A BOUND" if n in near_bound else "")
        )
    return "\n".join(rows)


def _uncertainty_words(res) -> str:
    """What the standard errors mean, in a few lines (inference.uncertainty)."""
    u = res.uncertainty
    infl = u.inflation()
    ok = np.isfinite(infl)
    lines = [
        "std. errors: honest — rounding to encoder counts simulated as it is, model "
        "error from the residuals' time blocks, an allowance for the input between "
        "samples"
    ]
    if ok.any():
        j = int(np.nanargmax(np.where(ok, infl, -np.inf)))
        lines.append(
            f"  they are {np.median(infl[ok]):.2g}x (median; {u.names[j]} {infl[j]:.2g}x) the "
            f"ones independent noise at the floor would give; the rounding alone leaves "
            f"the information of about {u.n_eff:.3g} independent samples of {u.n_samples}"
        )
    sh = u.shares()
    keys = ("noise", "model_error", "input_hold")
    # Parameters without a finite standard error have no shares: left out of the mean,
    # and said in words when no parameter has one (never "nan %").
    finite = [v for v in sh.values() if all(math.isfinite(v[k]) for k in keys)]
    if finite:
        tot = {k: float(np.mean([v[k] for v in finite])) for k in keys}
        lines.append(
            f"  variance, mean over parameters: noise {100 * tot['noise']:.0f} %, "
            f"model error {100 * tot['model_error']:.0f} %, input between samples "
            f"{100 * tot['input_hold']:.0f} %"
        )
    else:
        lines.append(
            "  no parameter has a finite standard error: the data do not determine "
            "them (see the warnings below)"
        )
    if u.warning():
        lines.append("  warning: " + u.warning())
    return "\n".join(lines)


def _quality_table(rows, label: str) -> str:
    from ..util.metrics import ChannelFit, fit_table

    out = []
    for r in rows:
        fits = [
            ChannelFit(**{k: v for k, v in c.items() if k in ChannelFit.__dataclass_fields__})
            for c in r["channels"].values()
        ]
        out.append(fit_table(fits, title=f"{label}: {r['experiment']}"))
    return "\n\n".join(out)


def _sources(options: FitOptions, prob, fixed_from_upper: dict) -> dict[str, str]:
    """Where the value of every parameter that is not estimated came from."""
    pr = options.problem
    default = _params.DEFAULT_SET[pr.model]
    src = {}
    for n in prob.model.active:
        if n == "J_u":
            src[n] = "eq. 5.4 (disc geometry)" if not (pr.base or options.p0) else None
        src[n] = src.get(n) or (
            f"upper-disc fit {options.p0}"
            if n in fixed_from_upper
            else f"--base {pr.base}"
            if pr.base
            else f"--p0 {options.p0}"
            if options.p0
            else f"default set {default}"
        )
    return src


def _run(
    options: FitOptions,
    out: Path,  # noqa: C901 - one linear report
    guard=None,
) -> dict:
    """Fit, print and write fit.json + figures; returns the JSON document.

    ``guard`` (an :class:`~rotorbayes.io.outputs.InterruptGuard`) is started once the fit has
    finished: a Ctrl-C after that keeps the result.
    """
    from .. import inference
    from ..figures.plots import plot_fit, plot_friction
    from ..inference.results import data_record
    from .common import glitch_record, say_glitches

    pr = options.problem
    # Glitches (encoder spikes) are named and left out unless --keep-glitches.
    exps = load_experiments(pr.data, pr.model, keep_glitches=pr.keep_glitches, read=pr.read.spec)
    val = (
        load_experiments(
            options.validate, pr.model, keep_glitches=pr.keep_glitches, read=pr.read.spec
        )
        if options.validate
        else []
    )
    say_glitches(exps, val)
    # The start set also fixes the values of the parameters that are not estimated.
    prob, fixed_from_upper = build_problem(pr, exps, p0=options.p0, start_spec=options.p0, also=val)
    val_alpha0 = _check_validation_torsion(options, prob, val)
    sources = _sources(options, prob, fixed_from_upper)
    print(
        f"model: {pr.model} configuration with {', '.join(prob.model.effect_names) or 'no effects'}"
    )
    print(
        f"fitting {len(prob.names)} parameters ({', '.join(prob.names)}) of the {pr.model} "
        f"configuration to {len(exps)} experiment(s), channels {', '.join(prob.channels)}"
    )
    if fixed_from_upper:
        print(f"fixed from the upper-disc fit {options.p0}: {', '.join(fixed_from_upper)}")
    fit_kw = options.solver.keywords()
    start_source: dict[str, str] = {}
    refit = None  # the search over an added effect's starts (--p0 with --add)
    if options.p0 and not fixed_from_upper:
        start = dict(prob.base)
        if pr.base:
            start.update(resolve_values(options.p0, prob.model))
        x0 = prob.start_vector(start)
        # A parameter the --p0 fit did not have (its effect was off there, or it is a user
        # effect's) starts at its effect's default, not at a value of that fit.
        p0_params = (fit_json(options.p0) or {}).get("parameters") or {}
        # (alpha0[1] of a --p0 fit of one run: that fit's alpha0, not a default.)
        start_source = {
            n: f"--p0 {options.p0}"
            if not p0_params
            or (
                (
                    p0_params.get(n)
                    or p0_params.get(inference.local_name(n)[0])
                    or {"status": "off"}
                ).get("status")
                != "off"
            )
            else "the effect's default"
            for n in prob.names
        }
        from ..inference.results import diagnosis_starts

        # The effects new to this fit: those --add names, and any whose parameters the
        # --p0 fit did not have (their start is the effect's default).
        add_names = {s.rpartition(":")[2] for s in (pr.add or [])}
        new_effects = [
            e
            for e in prob.model.added
            if e.name in add_names
            or any(start_source.get(n) == "the effect's default" for n in e.names)
        ]
        diagnosed = {
            n: v
            for n, v in diagnosis_starts(options.p0, [e.name for e in new_effects]).items()
            if n in prob.names
        }
        print(f"start: --p0 {options.p0}")
        from ..inference.refit import added_names as _searched

        if options.search and _searched(prob, new_effects):
            from ..inference.refit import refit_added

            refit = refit_added(prob, x0, diagnosed, new_effects, verbose=True, **fit_kw)
            res = refit.result
            print(refit.table())
            for note in refit.notes:
                print("note: " + note)
            for n in refit.searched:
                start_source[n] = f"refit search: {refit.chose}"
            chose = f"--p0 {options.p0}, added parameters from {refit.chose}"
        else:
            refit = None
            for n, v in diagnosed.items():
                j = prob.names.index(n)
                if prob.lower[j] < v < prob.upper[j]:
                    x0[j] = v
                    start_source[n] = "the diagnosis of the --p0 fit (one-step estimate)"
            if prob.model.added:
                print(
                    "start of the added effects' parameters: "
                    + ", ".join(
                        f"{n} = {x0[prob.names.index(n)]:.4g} ({start_source[n]})"
                        for e in prob.model.added
                        for n in e.names
                        if n in prob.names
                    )
                )
            res = inference.fit(prob, x0, verbose=True, **fit_kw)
            chose = f"--p0 {options.p0}"
    else:
        print(
            "start: computed from the data (the equations of motion as a regression on "
            "smoothed derivatives of the measured angles; give --p0 to choose one)"
        )
        from ..inference.taskstore import store_path

        # The fit from the data start and each finished restart are kept beside --out:
        # a re-run after a kill or Ctrl-C skips them.
        ff = inference.fit_from_data(
            prob, restarts=options.restarts, verbose=True, resume=store_path(options.out), **fit_kw
        )
        res, chose = ff.result, ff.chose
        start_source = {
            n: ff.start.source.get(n, ff.start.source.get(inference.local_name(n)[0], ""))
            for n in prob.names
        }
        if ff.restarts:
            print(f"{len(ff.restarts)} restarts tried; kept {ff.chose}")
    if guard is not None:
        guard.start()  # the work is done: from here on Ctrl-C must not throw it away
    status = "" if res.success else "DID NOT CONVERGE: "
    print(
        f"\n{status}{res.message} ({res.nfev} evaluations, {res.njev} Jacobians, "
        f"{res.seconds:.1f} s)\n"
    )
    q_est = inference.quality(prob, res.x)
    q_val = inference.quality(prob, res.x, val, validation_alpha0=val_alpha0) if val else []
    torsion = [r["validation_alpha0"] for r in q_val]
    assessment = inference.assess(res, q_est, q_val, sources=sources, val_experiments=val or ())
    print(
        _fmt_params(
            prob, res.names, res.x, res.stderr, res.x0, assessment.at_bound, assessment.near_bound
        )
    )
    if chose.startswith("restart"):  # trial 10 read this column as the data start above
        print(f"start: where the kept fit, {chose}, began (not the start from the data)")
    if res.uncertainty is not None:
        print(_uncertainty_words(res))
    print()
    print(_quality_table(q_est, "estimation data"))
    if q_val:
        print()
        print(_quality_table(q_val, "validation data"))
        for t in torsion:
            if t is not None:
                print(t.words(assessment.worst_ratio_validation))
    print("\nresidual RMS against the encoder quantisation floor (resolution/sqrt(12)):")
    print(assessment.table())
    print(f"verdict: {assessment.verdict}")
    print(assessment.integration_line())
    if refit is not None:
        _refit_words(refit, assessment, options)
    w, V = res.sloppy_directions()
    sloppy = {n: float(c) for n, c in zip(res.names, V[:, 0], strict=True)}
    ratio = float(w[-1] / max(w[0], 1e-300))
    # Only positive parameters: a common scaling "in log scale" means nothing for signed ones.
    positive = {
        n for n, v, lo in zip(res.names, res.x, prob.lower, strict=True) if v > 0 and lo >= 0
    }
    movers = [n for n, c in sloppy.items() if abs(c) > 0.3 and n in positive]
    if len(movers) >= 2 and ratio > 1e4:
        print(
            f"\nIdentifiability: the least-determined direction (Fisher eigenvalue ratio "
            f"{ratio:.1e}) moves {', '.join(movers)} together "
            f"({', '.join(f'{n} {sloppy[n]:+.2f}' for n in movers)} in log scale); the data "
            "fix their ratios far better than their values."
        )
    free_base = {inference.local_name(n)[0] for n in res.names}
    parameters = {}
    for n in prob.model.info:
        if n in free_base:
            continue
        on = n in prob.model.active
        parameters[n] = {
            "value": prob.base.get(n) if on else prob.model.info[n].null,
            "unit": prob.model.info[n].unit,
            "status": "fixed" if on else "off",
            "source": sources.get(n)
            if on
            else f"effect {getattr(_effects.effect_of(n), 'name', '?')} is off",
        }
    for i, n in enumerate(res.names):
        parameters[n] = {
            "value": float(res.x[i]),
            "unit": prob.info(n).unit,
            "status": "free",
            "stderr": float(res.stderr[i]),
            "start": float(res.x0[i]),
            "source": "estimated",
            "start_source": start_source.get(n, ""),
            "at_bound": n in assessment.at_bound,
            "near_bound": n in assessment.near_bound,
        }
    doc = {
        "config": pr.model,
        "effects": list(prob.effects),
        "added_effects": [
            e.name if e.source == "catalogue" else f"{e.source}:{e.name}" for e in prob.model.added
        ],
        "channels": list(prob.channels),
        # Absolute paths (a fit folder works from any working folder), paths relative to the
        # fit folder (a project moved whole) and hashes; effect files' hashes (they are code).
        "data": [str(Path(e.path).absolute()) for e in exps],
        "glitches": glitch_record(exps, val),
        "validation": [str(Path(e.path).absolute()) for e in val],
        # The SHA-256 of the bytes fitted, and how they were read (names, units).
        "data_files": data_record(exps, Path(options.out), pr.read.spec),
        "validation_files": data_record(val, Path(options.out), pr.read.spec),
        "effect_files": {
            e.source: _effects.file_sha256(e.source)
            for e in prob.model.added
            if e.source != "catalogue"
        },
        "success": res.success,
        "message": res.message,
        "nfev": res.nfev,
        "jacobian": res.jacobian_method,
        "seconds": res.seconds,
        "ssr": res.ssr,
        "n_residuals": res.n_residuals,
        "start": chose,
        "free": list(res.names),
        "prescribed_upper": bool(prob.prescribed_upper),
        "step": prob.step,  # the largest Runge-Kutta step [s]; None: the default
        "weights": dict(prob.weights),
        "parent": _parent_of(options.p0),
        "refit": refit.as_dict() if refit is not None else None,
        "assessment": assessment.as_dict(),
        "parameters": parameters,
        "estimates": {
            n: {
                "value": float(v),
                "stderr": float(s),
                "stderr_iid": float(si),
                "start": float(s0),
                "unit": prob.info(n).unit,
            }
            for n, v, s, si, s0 in zip(
                res.names, res.x, res.stderr, res.stderr_iid, res.x0, strict=True
            )
        },
        "uncertainty": res.uncertainty.as_dict() if res.uncertainty is not None else None,
        "params": res.params,
        # Each validation run's own initial torsion and how it was chosen: every later
        # command (compare, diagnose, the report, run) evaluates validation data with it.
        "validation_alpha0": [None if t is None else t.as_dict() for t in torsion]
        if prob.config != "upper"
        else [],
        "quality": {
            "estimation": [{k: v for k, v in r.items() if k != "simulation"} for r in q_est],
            "validation": [
                {k: v for k, v in r.items() if k not in ("simulation", "validation_alpha0")}
                for r in q_val
            ],
        },
        "fisher": {"eigenvalues_log": [float(v) for v in w], "sloppiest_direction": sloppy},
        "correlation": res.correlation().tolist(),
    }
    (out / "fit.json").write_text(strict_json(doc))
    for label, rows, exs in (("est", q_est, exps), ("val", q_val, val)):
        for i, (r, ex) in enumerate(zip(rows, exs, strict=True)):
            s = r["simulation"]
            meas, simd, txt = {}, {}, {}
            for c, st in r["channels"].items():
                simc = {"theta_u": s.theta_u, "theta_l": s.theta_l, "alpha": s.alpha}[c]
                measc = {
                    "theta_u": ex.theta_u,
                    "theta_l": ex.theta_l,
                    "alpha": None
                    if ex.theta_l is None
                    else ex.theta_l - ex.theta_u + s.params["alpha0"],
                }[c]
                meas[c], simd[c] = measc, simc
                txt[c] = (
                    f"R² {st['r2']:.4f}, fit {st['nrmse_fit']:.2f} %, "
                    f"max |e| {st['max_abs_error']:.3g} rad"
                )
            fig, _ = plot_fit(
                ex.t,
                meas,
                simd,
                mode=s.mode_l,
                metrics=txt,
                title=f"{pr.model}: {label} data {Path(str(ex.path)).name}",
                glitches=getattr(ex, "glitches", None) or (),
            )
            save_figure_atomic(fig, out / f"fit_{label}_{i}.png")
    shape_discs = ("u",) if pr.model == "upper" else ("u", "l")
    # An effect's own friction-level shift depends on the state and time: not drawn, said
    # (a proposed friction rising with speed squared was left out of the curve unsaid).
    shifts = [e.name for e in prob.model.effects if e.friction_shift is not None]
    fig, _ = plot_friction(
        res.params,
        discs=shape_discs,
        shape=prob.shape,
        title=f"fitted friction, {pr.model} configuration",
        note=(
            f"not drawn: the friction-level shift of {', '.join(shifts)} (a function of "
            "the state and time); these curves are the model's friction without it"
            if shifts
            else ""
        ),
    )
    save_figure_atomic(fig, out / "friction.png")
    print(f"\nwrote {Path(options.out) / 'fit.json'} and figures in {options.out}/")
    for wtxt in assessment.warnings:
        print(f"warning: {wtxt}", file=sys.stderr)
    return doc


def _refit_words(refit, assessment, options: FitOptions) -> None:
    """Where the refit ended against what the diagnosis beside the --p0 fit predicted for
    the added effect; a warning (printed and kept in fit.json) when it ended above it."""
    import json

    from ..inference.refit import diagnosis_prediction, prediction_note

    folder = Path(options.p0) if Path(options.p0).is_dir() else Path(options.p0).parent
    try:
        diag = json.loads((folder / "diagnosis.json").read_text())
    except (OSError, ValueError):
        diag = None
    effects = [
        e.name
        for e in refit.result.problem.model.added
        if any(n.split("[")[0] in e.names for n in refit.searched)
    ]
    pred = diagnosis_prediction(diag, effects)
    ratio = assessment.worst_ratio
    if pred is not None:
        where = "below" if ratio < pred else "at" if ratio <= pred * 1.1 else "above"
        print(
            f"the diagnosis of {options.p0} predicted {pred:.3g}x the floor for adding "
            f"{' and '.join(effects)}; the refit ended at {ratio:.3g}x ({where} it)"
        )
    adds = "".join(
        f" --add {e.name if e.source == 'catalogue' else f'{e.source}:{e.name}'}"
        for e in refit.result.problem.model.added
    )
    note = prediction_note(
        ratio,
        pred,
        effects,
        f"rotorbayes multistart --model {options.problem.model} "
        f"{' '.join(options.problem.data)}"
        f"{adds} --around {options.out}/ "
        f"--out {options.out.rstrip('/')}_ms/",
    )
    if note:
        assessment.warnings.append(note)


def _check_validation_torsion(options: FitOptions, prob, val) -> list | None:
    """``--validate-alpha0``, checked before any work: one value per validation file, each
    one the model can take (:meth:`~rotorbayes.inference.Problem.validation_params`).
    Returns the values (None: fitted on that run alone) or None when none were given."""
    given = options.validate_alpha0
    if given is None:
        return None
    given = [given] if isinstance(given, int | float | str) else list(given)
    try:
        given = [_validation_torsion(v) for v in given]
    except argparse.ArgumentTypeError as exc:
        raise Refused(f"--validate-alpha0: {exc}") from None
    if not val:
        raise Refused(
            "--validate-alpha0 gives the initial torsion of validation runs, but "
            "there is no --validate file; add --validate FILE or leave it out"
        )
    if len(given) != len(val):
        raise Refused(
            f"--validate-alpha0 is given {len(given)} times for {len(val)} "
            "--validate files; give it once per validation file, in the same order "
            "('fit' for a run whose torsion is fitted on that run alone)"
        )
    if prob.config == "upper" and any(v is not None for v in given):
        raise Refused(
            "--validate-alpha0: the upper configuration has no string, so no "
            "initial torsion; leave the option out"
        )
    x = prob.x_from(prob.base)  # any point: the check is on the values alone
    for v, ex in zip(given, val, strict=True):
        if v is None:
            continue
        try:
            prob.validation_params(x, ex, v)
        except _params.ParameterError as exc:
            raise Refused(f"--validate-alpha0 {v:g}: {exc}") from None
    return given


def _parent_of(p0: str | None) -> str | None:
    """The fit folder a --p0 fit.json belongs to (the chain of fits), else None."""
    if not p0:
        return None
    p = Path(p0)
    if p.is_dir() and (p / "fit.json").exists():
        return str(p.resolve())
    if p.name == "fit.json" and p.exists():
        return str(p.parent.resolve())
    return None


def _fit_interrupted(exc: KeyboardInterrupt, out: str) -> Interrupted:
    """The message for Ctrl-C during a fit: nothing written, the best point so far."""
    from ..inference.least_squares import FitInterrupted
    from ..inference.taskstore import store_path

    text = f"interrupted (Ctrl-C); nothing was written to {out}/"
    kept = list(store_path(out).glob("*.npz"))
    if kept:
        text += (
            f" (the {len(kept)} fit(s) from the data start and its restarts that had "
            f"finished are kept in {store_path(out)}/: the same command with the same "
            "--out skips them)"
        )
    if isinstance(exc, FitInterrupted):
        vals = "\n".join(
            f"{n} = {float(v)!r}" for n, v in zip(exc.names, exc.x, strict=True) if "[" not in n
        )
        text += (
            f". The best point after {exc.nfev} evaluations (SSR {exc.ssr:.6g} rad²) "
            f"was:\n{vals}\nTo continue from it, save these lines in a file such as "
            "best.toml and run the fit again with --p0 best.toml"
        )
    elif not kept:
        text += " (no fit evaluation had finished yet)"
    return Interrupted(text)

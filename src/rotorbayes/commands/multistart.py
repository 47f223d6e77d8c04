"""``rotorbayes multistart``: many fits from spread starts; waterfall and spread."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..io.outputs import InterruptGuard, output_folder, save_figure_atomic
from ..util import exitcodes as EXIT
from ..util.exitcodes import Interrupted
from .common import (
    Outcome,
    glitch_record,
    json_default,
    load_experiments,
    resolve_values,
    say_glitches,
)
from .config import (
    ExecutorOptions,
    MultistartOptions,
    ProblemOptions,
    ReadOptions,
    SolverOptions,
)
from .fit import build_problem
from .options import MAX_STARTS, add_fit_options, add_parallel_options, ranged

HELP = "many fits from spread starts; waterfall and spread"


def add_arguments(m) -> None:
    add_fit_options(m)
    m.add_argument(
        "--starts",
        type=ranged(int, ge=1, le=MAX_STARTS, why=" (one fit per start)"),
        default=32,
        metavar="N",
        help="number of fits from different starts",
    )
    m.add_argument(
        "--around",
        help="spread starts around this set (named set, TOML or "
        "fit.json) instead of over the bounds",
    )
    m.add_argument(
        "--spread",
        type=ranged(
            gt=0, le=5, why=" (the log-sd of the start factors; 0.3 spreads by about ±30 %)"
        ),
        default=0.3,
        help="log-sd of the spread around --around",
    )
    m.add_argument("--seed", type=ranged(int, ge=0), default=0, help="seed of the starts")
    add_parallel_options(m, "fits")


def multistart(
    data,
    *,
    model: str,
    out: str,
    starts: int = 32,
    around: str | None = None,
    spread: float = 0.3,
    seed: int = 0,
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
    backend: str | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    force: bool = False,
    trust_effects: bool = False,
    step: float | None = None,
    keep_glitches: bool = False,
    columns=None,
    time_unit: str | None = None,
    angle_unit: str | None = None,
    counts_per_rev=None,
) -> Outcome:
    """``starts`` fits of the ``model`` configuration to ``data`` from spread starts (a
    Latin hypercube over the bounds, or a log-normal ``spread`` around the set ``around``);
    writes multistart.json, summary.txt and the waterfall and spread figures into ``out``.

    The fit options are those of :func:`rotorbayes.commands.fit.fit` (glitches in the data
    are named and left out unless ``keep_glitches``); ``backend``,
    ``workers`` and ``scheduler`` choose where the fits run.  ``Outcome.doc`` is
    multistart.json's document.
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
        MultistartOptions(
            problem=problem,
            out=out,
            solver=SolverOptions(
                max_nfev=max_nfev, ftol=ftol, xtol=xtol, gtol=gtol, jacobian=jacobian
            ),
            executor=ExecutorOptions(backend=backend, workers=workers, scheduler=scheduler),
            starts=starts,
            around=around,
            spread=spread,
            seed=seed,
            force=force,
        )
    )


def execute(options: MultistartOptions) -> Outcome:
    """:func:`multistart` with its options as one
    :class:`~rotorbayes.commands.config.MultistartOptions` (the form the study builds)."""
    from .. import inference
    from ..figures.plots import plot_parameter_spread, plot_waterfall, quantisation_floor_ssr
    from ..inference.taskstore import remove_store, store_path

    o, pr = options, options.problem
    if o.solver.jacobian == "sensitivity":  # compiled aside while the solver compiles
        from ..util.coldstart import sensitivity_aside

        sensitivity_aside("rotorbayes.inference.problem:compile_sensitivity_kernel")
    guard = InterruptGuard()
    with guard, output_folder(o.out, o.force, inputs=[pr.data, o.around, pr.base, pr.add]) as out:
        exps = load_experiments(
            pr.data, pr.model, keep_glitches=pr.keep_glitches, read=pr.read.spec
        )
        say_glitches(exps)
        prob, _ = build_problem(pr, exps, carrier=o.around)
        around = None
        if o.around:
            # A fit folder's values, user effects' too (their effects are on: build_model
            # carries them over from --around as fit does from --p0).
            around = resolve_values(o.around, prob.model)
        how = (
            f"log-normal spread {o.spread:.2f} around {o.around}"
            if around
            else "Latin hypercube over the bounds"
        )
        print(f"multistart: {o.starts} fits of {', '.join(prob.names)} ({how})")
        if o.solver.jacobian is None and o.starts >= 8 and prob.sensitivity_support() is None:
            print(
                "  Jacobians by forward differences (the default); --jacobian sensitivity "
                "takes them from the kernel's forward sensitivities, exact and measured at "
                "about a third of the CPU time per start (compiled once, on first use)"
            )
        with o.executor.open() as ex:
            # Each finished start is kept beside --out: a re-run after a kill skips it.
            ms = inference.multistart(
                prob,
                o.starts,
                seed=o.seed,
                around=around,
                spread=o.spread,
                executor=ex,
                resume=store_path(o.out),
                **o.solver.keywords(),
            )
        guard.start()  # the starts are done: from here on Ctrl-C must not throw them away
        n_done = int(ms.ssr.size) + len(ms.failed)
        if ms.interrupted and n_done == 0:
            raise Interrupted(
                f"interrupted (Ctrl-C) before any start had finished; nothing "
                f"was written to {o.out}/"
            )
        order = np.argsort(ms.ssr)
        print("\nbest end points:")
        print(" rank  cluster        SSR   " + " ".join(f"{n:>10}" for n in ms.names))
        for r, i in enumerate(order[: min(10, len(order))]):
            print(
                f" {r + 1:4d}  {ms.clusters[i]:7d}  {ms.ssr[i]:9.4g}   "
                + " ".join(f"{v:10.4g}" for v in ms.ends[i])
            )
        summary = ms.summary()
        print("\n" + summary)
        doc = {
            "config": pr.model,
            "names": ms.names,
            "starts": ms.starts,
            "ends": ms.ends,
            "ssr": ms.ssr,
            "success": ms.success,
            "clusters": ms.clusters,
            "summary": summary,
            "data": [str(e.path) for e in exps],
            "read": pr.read.spec.as_dict(),
            "glitches": glitch_record(exps),
            "n_requested": o.starts,
            "n_finished": n_done,
            "interrupted": ms.interrupted,
            "start_index": ms.start_index,
            "failed": {str(k): v for k, v in ms.failed.items()},
        }
        (out / "multistart.json").write_text(json.dumps(doc, indent=2, default=json_default))
        written = ["multistart.json"]
        if ms.ssr.size:
            floor = quantisation_floor_ssr(prob)
            fig, _ = plot_waterfall(
                ms.ssr,
                labels=ms.clusters,
                n_failed=len(ms.failed),
                noise_floor_ssr=floor,
                title=f"multistart, {pr.model}: sorted final SSR",
            )
            save_figure_atomic(fig, out / "waterfall.png")
            fig, _ = plot_parameter_spread(
                ms.names,
                ms.ends,
                ms.ssr,
                clusters=ms.clusters,
                noise_floor_ssr=floor,
                units={n: prob.info(n).unit for n in ms.names},
                title=f"multistart, {pr.model}: end points",
            )
            save_figure_atomic(fig, out / "parameter_spread.png")
            written += ["waterfall.png", "parameter_spread.png"]
        (out / "summary.txt").write_text(summary + "\n")
        written.append("summary.txt")
    print(f"\nwrote {o.out}/: {', '.join(written)}")
    if not ms.interrupted:
        remove_store(o.out)  # the result is complete: nothing left to resume
    if ms.interrupted:
        rest = o.starts - n_done
        raise Interrupted(
            f"interrupted (Ctrl-C) after {n_done} of {o.starts} starts; the finished ones are in "
            f"{o.out}/ (multistart.json, summary.txt). For the other {rest}, run again with "
            f"--starts {rest} --seed {o.seed + 1} and another --out (a new seed gives new "
            "starts), or repeat the whole command with --force"
        )
    if guard.hit:
        raise Interrupted(
            f"interrupted (Ctrl-C) after all {n_done} starts had finished; the "
            f"results were kept, complete, in {o.out}/"
        )
    return Outcome(EXIT.DONE, Path(o.out), doc)

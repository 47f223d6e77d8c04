"""``rotorbayes identify``: which parameter combinations the data fix."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from ..io.outputs import output_folder, save_figure_atomic, write_text_atomic
from ..util.exitcodes import Refused
from .common import Outcome, csv_list, strict_json
from .config import ExecutorOptions, FitFolderOptions, IdentifyOptions
from .options import add_changed_data_option, add_parallel_options, add_trust_option, ranged

HELP = "which parameter combinations the data fix: Fisher directions in words, profile likelihoods"


def add_arguments(i) -> None:
    i.add_argument("fit", help="a folder written by `rotorbayes fit`")
    i.add_argument("--out", required=True, help="output folder")
    i.add_argument("--profiles", help="comma-separated free parameters to profile")
    i.add_argument(
        "--points",
        type=ranged(int, ge=3, le=1001, why=" (grid points)"),
        default=11,
        help="grid points per profile",
    )
    add_parallel_options(i, "profile fits")
    i.add_argument("--posterior", help="a sample folder: corner plot of its posterior")
    i.add_argument("--multistart", help="a multistart folder: its end points on the corner")
    i.add_argument("--force", action="store_true", help="overwrite results in --out")
    add_trust_option(i)
    add_changed_data_option(i)


def identify(
    fit: str,
    *,
    out: str,
    profiles=None,
    points: int = 11,
    posterior: str | None = None,
    multistart: str | None = None,
    backend: str | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    force: bool = False,
    trust_effects: bool = False,
    accept_changed_data: bool = False,
) -> Outcome:
    """Fisher eigen-analysis of the fit folder ``fit`` in words, profile likelihoods of the
    free parameters ``profiles`` (a list or comma-separated names; ``points`` grid points
    each, run where ``backend``/``workers``/``scheduler`` say), and with ``posterior`` (a
    sample folder) a corner plot, ``multistart``'s end points on it; written into ``out``.
    ``Outcome.doc`` is identify.json's document."""
    return execute(
        IdentifyOptions(
            fit=fit,
            out=out,
            profiles=profiles,
            points=points,
            posterior=posterior,
            multistart=multistart,
            force=force,
            fit_folder=FitFolderOptions(
                trust_effects=trust_effects, accept_changed_data=accept_changed_data
            ),
            executor=ExecutorOptions(backend=backend, workers=workers, scheduler=scheduler),
        )
    )


def execute(options: IdentifyOptions) -> Outcome:
    """:func:`identify` with its options as one
    :class:`~rotorbayes.commands.config.IdentifyOptions` (the form the study builds)."""
    o = options
    result = o.fit_folder.load(o.fit)
    prob = result.problem
    names = csv_list(o.profiles, "--profiles") or []
    for n in names:
        if n not in prob.names:
            raise Refused(
                f"--profiles: {n} is not a free parameter of {result.folder}/; the "
                f"free ones are {', '.join(prob.names)}"
            )
    if o.points < 3:
        raise Refused(f"--points {o.points}: give at least 3 grid points")
    idata = _posterior(o.posterior, prob, result.folder) if o.posterior else None
    if o.multistart and not (Path(o.multistart) / "multistart.json").exists():
        raise Refused(
            f"--multistart {o.multistart}: no multistart.json there; give a folder "
            "written by `rotorbayes multistart`"
        )
    with output_folder(o.out, o.force, inputs=[o.fit, o.posterior, o.multistart]) as folder:
        written, doc = _identify_into(o, result, prob, names, folder, idata)
    from ..inference.taskstore import remove_store

    remove_store(o.out)  # complete: no profile point left to resume
    print(f"\nwrote {', '.join(written)} in {o.out}/")
    return Outcome(folder=Path(o.out), doc=doc)


def _posterior(folder: str, prob, fit_folder: Path):
    """The posterior of the sample folder ``folder``, read before anything is written; a
    missing, damaged or foreign posterior.nc is refused with its name and what to do."""
    from ..inference import arviz_compat

    path = Path(folder) / "posterior.nc"
    if not path.exists() and not path.is_symlink():
        raise Refused(
            f"--posterior {folder}: no posterior.nc there; give a folder written "
            "by `rotorbayes sample`"
        )
    redo = (
        f"`rotorbayes sample {folder} --resume` writes it again from the chains in "
        f"{folder}/chain.h5 (no new steps)"
        if (Path(folder) / "chain.h5").exists()
        else "sample again"
    )
    try:
        idata = arviz_compat.load(path)
    except arviz_compat.PosteriorFileError as exc:
        raise Refused(f"--posterior: {exc}; {redo}, or leave out --posterior") from None
    have = set(arviz_compat.group(idata, "posterior").data_vars)
    lacking = [n for n in prob.names if n not in have]
    if lacking:
        raise Refused(
            f"--posterior: {path} holds no draws of {', '.join(lacking)}, free in "
            f"{fit_folder}/: it was sampled from another fit; give the sample "
            "folder of this fit, or leave out --posterior"
        )
    return idata


def _profiles_into(a: IdentifyOptions, prob, fit, profiles, se, ex, doc) -> None:
    """Each profile's grid points on the executor ``ex``; printed and added to ``doc``."""
    from ..inference import identify as inference_identify
    from ..inference.taskstore import store_path
    from ..util.numformat import fmt_interval_at

    for n in profiles:
        t0 = time.perf_counter()
        pr = inference_identify.profile(
            prob,
            fit.x,
            n,
            n_points=a.points,
            stderr=se.get(n),
            executor=ex,
            resume=store_path(a.out),
        )
        # (finished points are kept: a re-run skips them)
        doc["profiles"].append(pr)
        iv = inference_identify.profile_interval(pr)
        ends = (
            ""
            if iv["lo"] is None
            else fmt_interval_at(iv["lo"], iv["hi"], (iv["hi"] - iv["lo"]) / 3.92)
        )
        print(
            f"profile of {n}: {a.points} points in {time.perf_counter() - t0:.1f} s; "
            + (
                f"95 % interval (Δχ² < 3.84) about [{ends}] "
                f"{pr['unit']} (ends interpolated between grid points)"
                if iv["lo"] is not None
                else "no grid point within Δχ² < 3.84"
            )
            + (
                f"; {iv['note']}"
                if iv["note"] and iv["lo"] is not None
                else f" ({iv['note']})"
                if iv["note"]
                else ""
            )
        )


def _identify_into(
    a: IdentifyOptions, fit, prob, profiles, out: Path, idata=None
) -> tuple[list[str], dict]:
    from ..inference import identify as inference_identify

    F = inference_identify.fisher(prob, fit.x)
    words = inference_identify.describe(F)
    print(
        f"Fisher information of {fit.folder}/ at the fit (noise at each channel's floor; "
        "log coordinates for positive parameters):"
    )
    print("  eigenvalues " + ", ".join(f"{v:.3g}" for v in F.eigenvalues))
    for w in words:
        print("  " + w)
    doc = {"fit": str(fit.folder), "fisher": F.as_dict(), "words": words, "profiles": []}
    from ..figures import posterior as posterior_figures

    save_figure_atomic(posterior_figures.plot_fisher(F)[0], out / "fisher.png")
    written = ["identify.json", "fisher.png"]
    if profiles:
        se = dict(
            zip(
                prob.names,
                fit.doc and [fit.doc["estimates"][n]["stderr"] or 0.0 for n in prob.names],
                strict=True,
            )
        )
        # One executor (one cluster, if any) for every profile.
        with a.executor.open() as ex:
            _profiles_into(a, prob, fit, profiles, se, ex, doc)
        save_figure_atomic(
            posterior_figures.plot_profiles(doc["profiles"])[0], out / "profiles.png"
        )
        written.append("profiles.png")
    if a.posterior:
        overlay = None
        if a.multistart:
            ms = json.loads((Path(a.multistart) / "multistart.json").read_text())
            if ms.get("names") != list(prob.names):
                raise Refused(
                    f"{a.multistart}: its free parameters {ms.get('names')} "
                    f"differ from the fit's {list(prob.names)}"
                )
            overlay = np.array(ms["ends"])
        save_figure_atomic(
            posterior_figures.plot_corner(idata, prob, overlay=overlay), out / "corner.png"
        )
        written.append("corner.png")
    write_text_atomic(out / "identify.json", strict_json(doc))
    write_text_atomic(out / "summary.txt", "\n".join(words) + "\n")
    return [*written, "summary.txt"], doc

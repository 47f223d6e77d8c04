"""``rotorbayes run``: a whole study from an analysis file, or the studies of several."""

from __future__ import annotations

import time
from pathlib import Path

from .common import Outcome
from .config import ExecutorOptions
from .options import add_parallel_options

HELP = (
    "a whole study from an analysis file (TOML; see docs/analysis_file.md), or several "
    "studies at once"
)


def add_arguments(r) -> None:
    r.add_argument(
        "analysis",
        nargs="+",
        help="the analysis file; several files (e.g. one per data set) run as "
        "independent studies, several at a time",
    )
    r.add_argument("--force", action="store_true", help="rerun every stage")
    r.add_argument("--quiet", action="store_true", help="print only the summary")
    add_parallel_options(
        r, "independent fits (restarts, profile points), or the studies of several analysis files"
    )


def run(
    analysis: str | list[str],
    *,
    force: bool = False,
    quiet: bool = False,
    backend: str | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
) -> Outcome:
    """Run the study the analysis file ``analysis`` describes
    (:func:`rotorbayes.commands.study.analysis.run`)
    with one executor for its parallel tasks (the options, else the file's [parallel]
    table).  ``Outcome.doc`` is the run record (run.json).

    Several files are independent studies, one task each on the executor
    (:mod:`rotorbayes.commands.study.batch`); ``Outcome.doc`` is then ``{"studies": [...]}``."""
    files = [analysis] if isinstance(analysis, (str, Path)) else list(analysis)
    if len(files) > 1:
        from .study.batch import run_studies

        return run_studies(
            files, force=force, quiet=quiet, backend=backend, workers=workers, scheduler=scheduler
        )
    from .study.analysis import load_analysis
    from .study.analysis import run as run_study

    t0 = time.perf_counter()
    where = ExecutorOptions(backend=backend, workers=workers, scheduler=scheduler)
    with where.open(file=load_analysis(files[0]).table("parallel")):
        rec = run_study(files[0], quiet=quiet, force=force)
    kept = [s["name"] for s in rec.get("stages", []) if s.get("skipped")]
    n = len(rec.get("stages", []))
    again = (
        "; every stage's inputs were unchanged: all kept, nothing rerun (--force reruns)"
        if kept and len(kept) == n
        else f"; {len(kept)} of {n} stages kept (inputs unchanged)"
        if kept
        else ""
    )
    print(
        f"\nstudy done in {time.perf_counter() - t0:.0f} s{again}; outputs and run.json in "
        f"{Path(rec['final_fit']).parent}/"
    )
    verdict = _final_words(rec)
    if verdict:
        print(verdict)
    if rec.get("report"):
        print(f"report: {rec['report']}")
    return Outcome(doc=rec)


def _final_words(rec: dict) -> str:
    """The final fit's verdict in one line ("" where the record lacks it): the study's last
    word, beside the report's."""
    import json

    try:
        doc = json.loads((Path(rec["final_fit"]) / "fit.json").read_text())
        verdict = doc["assessment"]["verdict"]
    except (KeyError, OSError, TypeError, ValueError):
        return ""
    added = rec.get("added_effects") or []
    what = f" (effects added: {', '.join(added)})" if added else ""
    if not verdict:
        return ""
    # What the verdict alone would hide: a final fit that stopped before converging (a
    # study ended on one, its exit code 1 in run.json, and said nothing), and the fit's own
    # warnings (an inverted Stribeck effect standing in for a missing drag).
    if doc.get("success") is False:
        verdict += f"; but it DID NOT CONVERGE ({doc.get('message') or 'stopped early'})"
    warns = [
        w
        for w in (doc.get("assessment") or {}).get("warnings") or []
        if not str(w).startswith("the fit did not converge")
    ]
    if warns:
        verdict += f"; {len(warns)} warning(s) in its fit.json, first: {warns[0]}"
    worst = (doc.get("assessment") or {}).get("worst_ratio_to_floor")
    if added and isinstance(worst, (int, float)) and worst > 3.0:
        # Far from the floor any freedom lowers the error a little (two pre-wound runs, a
        # motor torque sagging with speed: upper_stribeck and lower_asymmetric_viscous were
        # added, neither in the data, the fit still 2513x the floor).
        verdict += (
            "; the effects were added far from the floor, where any freedom lowers the "
            "error: none is shown to be in the data"
        )
    return f"final fit, {Path(rec['final_fit']).name}{what}: {verdict}"

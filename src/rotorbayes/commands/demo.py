"""``rotorbayes demo``: the whole story on the bundled hidden-effect data."""

from __future__ import annotations

import time
from pathlib import Path

from ..util.exitcodes import Refused
from .common import Outcome

HELP = (
    "the whole story on the bundled hidden-effect data: fit, diagnose, add effects, "
    "sample, identify, HTML report"
)


def add_arguments(d) -> None:
    d.add_argument("--out", default="rotorbayes-demo", help="output folder")
    d.add_argument("--force", action="store_true", help="rerun every stage")
    d.add_argument(
        "--quiet",
        action="store_true",
        help="print only the summary (the log file in the output folder has everything)",
    )


def demo(*, out: str = "rotorbayes-demo", force: bool = False, quiet: bool = False) -> Outcome:
    """Run the bundled analysis file (coupled data with a hidden effect) into ``out``: first
    fit from the data, diagnosis, effects added one at a time, the posterior,
    identifiability and an HTML report.  ``Outcome.doc`` is the study's run record."""
    from importlib.resources import files

    from .study.analysis import run

    path = files("rotorbayes") / "data" / "demo.toml"
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise Refused(f"--out {out}: is a file; give a folder name")
    print(
        f"rotorbayes demo: the bundled (synthetic) coupled data with a hidden physical "
        f"effect: first fit from the data, diagnosis, effects added one at a time, the "
        f"posterior, identifiability and an HTML report, into {out}/\n"
        f"(the analysis file: {path}; rerunning skips the stages whose inputs did not "
        "change; --force reruns all)"
    )
    t0 = time.perf_counter()
    rec = run(path, quiet=quiet, force=force, out=out)
    print(
        f"\ndemo done in {time.perf_counter() - t0:.0f} s; effects added: "
        f"{', '.join(rec.get('added_effects', [])) or 'none'}"
    )
    if rec.get("report"):
        print(f"open the report: {rec['report']}")
    return Outcome(doc=rec)

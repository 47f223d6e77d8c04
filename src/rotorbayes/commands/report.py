"""``rotorbayes report``: one self-contained HTML page for a result folder."""

from __future__ import annotations

import sys

from ..util.exitcodes import Refused
from .common import Outcome

HELP = (
    "report.html: one self-contained HTML page (figures embedded) for a study folder or "
    "any fit/compare/sample/identify folder"
)


def add_arguments(rp) -> None:
    rp.add_argument(
        "folder", help="a folder written by run, demo, fit, compare, sample or identify"
    )
    rp.add_argument(
        "--out",
        help="the HTML file to write, ending in .html (default: "
        "FOLDER/report.html); an existing file is replaced only if it is a report "
        "rotorbayes wrote",
    )
    rp.add_argument(
        "--force",
        action="store_true",
        help="replace an existing .html file that is not a rotorbayes report",
    )


def report(folder: str, *, out: str | None = None, force: bool = False) -> Outcome:
    """Write report.html (or ``out``) for a study folder or any fit, compare, sample or
    identify folder.  ``Outcome.doc`` names the file, its sections and what was absent."""
    from ..report import ReportError, write_report

    try:
        rep = write_report(folder, out, force=force)
    except ReportError as exc:
        raise Refused(str(exc)) from None
    size = rep.size
    human = f"{size / 1e6:.1f} MB" if size >= 1e6 else f"{size / 1e3:.0f} kB"
    print(f"wrote {rep.path} ({human}, {size} bytes)")
    print(f"sections: {', '.join(rep.sections)}")
    if rep.absent:
        print(f"absent (not in {folder}): {', '.join(rep.absent)}")
    for p in rep.problems:
        print(f"warning: section {p}", file=sys.stderr)
    return Outcome(
        doc={
            "path": str(rep.path),
            "bytes": size,
            "sections": list(rep.sections),
            "absent": list(rep.absent),
            "problems": list(rep.problems),
        }
    )

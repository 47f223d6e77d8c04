"""The HTML report of a result folder: ``rotorbayes report FOLDER``.

:func:`build_report` writes ``FOLDER/report.html``: one self-contained file (figures
embedded as data URIs, inline CSS, no external resources) for a whole study written by
``rotorbayes run`` / ``rotorbayes demo`` or for any single result folder (a fit, compare,
sample or identify folder).  It renders the sections whose results are there and says which
are absent and how to make them.
"""

from .discover import ReportError, discover
from .html import SECTIONS, Report, build_report, render_report, write_report

__all__ = [
    "SECTIONS",
    "Report",
    "ReportError",
    "build_report",
    "discover",
    "render_report",
    "write_report",
]

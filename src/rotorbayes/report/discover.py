"""Find the results a folder holds: a whole study or a single fit/compare/sample/identify
folder.

Only the files are read (JSON, Markdown, figures); nothing is recomputed, so a report is
quick and works without the data (it says when a data file is gone).
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path


class ReportError(ValueError):
    """The folder is missing or holds nothing to report (printed without a traceback)."""


#: The file that marks each kind of result folder.
MARKERS = {
    "fit": "fit.json",
    "compare": "compare.json",
    "sample": "settings.json",
    "identify": "identify.json",
}


def read_json(path: Path) -> dict | None:
    """A JSON file as a dict, or None when it is absent (an unreadable file raises)."""
    if not path.exists():
        return None
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise ReportError(f"{path}: cannot be read ({exc})") from None
    if not isinstance(doc, dict):
        raise ReportError(f"{path}: not a JSON object; was it written by rotorbayes?")
    return doc


def kind_of(folder: Path) -> str | None:
    """``fit``, ``compare``, ``sample`` or ``identify`` for a result folder, else None."""
    if (folder / "fit.json").exists():
        return "fit"
    if (folder / "compare.json").exists():
        return "compare"
    if (folder / "identify.json").exists():
        return "identify"
    if (folder / "settings.json").exists() and any(
        (folder / n).exists() for n in ("summary.md", "posterior.nc", "chain.h5")
    ):
        return "sample"
    return None


def _natural(p: Path):
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", p.name)]


@dataclass
class FitInfo:
    """One fit folder: its fit.json and, if diagnosed, its diagnosis.json."""

    folder: Path
    doc: dict
    diagnosis: dict | None = None

    @property
    def label(self) -> str:
        return self.folder.name


@dataclass
class Found:
    """What a folder holds (see :func:`discover`)."""

    root: Path
    kind: str  # study, fit, compare, sample, identify
    run: dict | None = None
    chain: list[FitInfo] = field(default_factory=list)  # oldest first; the last is the final
    compare: Path | None = None
    posterior: Path | None = None
    identify: Path | None = None

    @property
    def final(self) -> FitInfo | None:
        return self.chain[-1] if self.chain else None


def load_fit_info(folder: Path) -> FitInfo:
    doc = read_json(folder / "fit.json")
    return FitInfo(folder, doc or {}, read_json(folder / "diagnosis.json"))


def fit_chain(folder: Path) -> list[FitInfo]:
    """The fit in ``folder`` and the fits it started from (``parent`` links), oldest first."""
    out, seen, cur = [], set(), folder
    while cur is not None and (cur / "fit.json").exists() and cur.resolve() not in seen:
        seen.add(cur.resolve())
        info = load_fit_info(cur)
        out.append(info)
        parent = info.doc.get("parent")
        cur = _moved(Path(parent), cur) if parent else None
    return out[::-1]


def _moved(path: Path, near: Path) -> Path:
    """``path`` as recorded, or, if it is gone (the study folder was moved or copied, or the
    path was relative to another working folder), the folder of that name beside ``near``."""
    if (path / "fit.json").exists():
        return path
    sibling = near.parent / path.name
    return sibling if (sibling / "fit.json").exists() else path


def _sub(root: Path, kind: str, preferred: str) -> Path | None:
    p = root / preferred
    if p.is_dir() and kind_of(p) == kind:
        return p
    subs = sorted((d for d in root.iterdir() if d.is_dir() and kind_of(d) == kind), key=_natural)
    return subs[-1] if subs else None


def discover(folder: str | Path) -> Found:
    """What ``folder`` holds: a study (``run.json`` or result sub-folders) or one result
    folder; raises :class:`ReportError` if it is missing or holds no results."""
    root = Path(folder)
    if not root.exists():
        raise ReportError(
            f"{root}: no such folder; give a folder written by rotorbayes "
            "(run, demo, fit, compare, sample or identify)"
        )
    if not root.is_dir():
        raise ReportError(f"{root}: is a file, not a folder; give the result folder that holds it")
    kind = kind_of(root)
    if kind == "fit":
        comp = root / "compare"
        return Found(
            root, "fit", chain=fit_chain(root), compare=comp if kind_of(comp) == "compare" else None
        )
    if kind == "compare":
        return Found(root, "compare", compare=root)
    if kind == "sample":
        # The posterior of a fit: the fit (and the chain it ends, its comparison) too, from
        # the folder settings.json names (or one of that name beside this one, if moved).
        found = Found(root, "sample", posterior=root)
        fit = (read_json(root / "settings.json") or {}).get("fit")
        if isinstance(fit, str) and fit:
            p = _moved(Path(fit), root)
            if (p / "fit.json").exists():
                found.chain = fit_chain(p)
                comp = p / "compare"
                found.compare = comp if kind_of(comp) == "compare" else None
        return found
    if kind == "identify":
        return Found(root, "identify", identify=root)
    run = read_json(root / "run.json")
    subs = [d for d in root.iterdir() if d.is_dir() and kind_of(d)]
    if run is None and not subs:
        raise ReportError(
            f"{root}: nothing to report: it holds no run.json and no result "
            "folders (fit.json, compare.json, identify.json or a sample's "
            "settings.json); run `rotorbayes fit`, `rotorbayes run "
            "analysis.toml` or `rotorbayes demo` first"
        )
    found = Found(root, "study", run=run)
    final = None
    if run and run.get("final_fit"):
        p = _moved(Path(run["final_fit"]), root / "x")
        final = p if (p / "fit.json").exists() else None
    if final is None:
        fits = [d for d in subs if kind_of(d) == "fit"]
        # The final fit is the end of the longest chain (ties: the last by name).
        chains = sorted(
            ((len(fit_chain(d)), _natural(d), d) for d in fits), key=lambda t: (t[0], t[1])
        )
        final = chains[-1][2] if chains else None
    if final is not None:
        found.chain = fit_chain(final)
    found.compare = _sub(root, "compare", "compare")
    if found.compare is None and final is not None and kind_of(final / "compare") == "compare":
        found.compare = final / "compare"
    found.posterior = _sub(root, "sample", "posterior")
    found.identify = _sub(root, "identify", "identify")
    if run is None and not (found.chain or found.compare or found.posterior or found.identify):
        raise ReportError(f"{root}: nothing to report")
    return found

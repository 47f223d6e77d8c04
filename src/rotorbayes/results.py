"""Result folders: read a fit back as the problem and point it came from.

``rotorbayes fit`` writes ``fit.json`` with everything needed to rebuild its
:class:`~rotorbayes.inference.Problem`: configuration, effects (catalogue names and user
files), data files, free parameters, channels, weights, the full parameter set and the
parent fit it started from.  :func:`load_fit` rebuilds it; ``diagnose``, ``compare`` and
``sample`` start from there.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .data import load_experiment
from .model.configurations import CONFIGURATIONS, Model


class ResultError(ValueError):
    """A result folder is missing, incomplete or from an incompatible version."""


@dataclass
class LoadedFit:
    """A fit read back from its folder."""

    folder: Path
    doc: dict
    problem: object
    x: np.ndarray
    validation: list

    @property
    def parent(self) -> Path | None:
        p = self.doc.get("parent")
        return Path(p) if p else None

    def chain(self) -> list[LoadedFit]:
        """This fit and its ancestors (``--p0`` fit folders), oldest first."""
        out, seen, cur = [self], {self.folder.resolve()}, self
        while cur.parent is not None and (cur.parent / "fit.json").exists():
            if cur.parent.resolve() in seen:
                break
            seen.add(cur.parent.resolve())
            cur = load_fit(cur.parent)
            out.append(cur)
        return out[::-1]


def fit_json_path(spec: str | Path) -> Path:
    p = Path(spec)
    if p.is_dir():
        p = p / "fit.json"
    if not p.exists():
        raise ResultError(f"{p}: not found; give a folder written by `rotorbayes fit` "
                          "(it holds fit.json)")
    return p


def load_fit(spec: str | Path) -> LoadedFit:
    """Rebuild the problem and the fitted point of a fit folder (or its fit.json)."""
    from .inference import Problem

    path = fit_json_path(spec)
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise ResultError(f"{path}: cannot read it ({exc})") from None
    need = ("config", "data", "free", "params", "estimates", "channels")
    missing = [k for k in need if k not in doc]
    if missing:
        raise ResultError(f"{path}: lacks {', '.join(missing)}; it was written by an older "
                          "rotorbayes: fit again to make a folder this version can read")
    config = doc["config"]
    base_on = set(CONFIGURATIONS[config].base_effects)
    without = sorted(base_on - set(doc.get("effects", [])))
    model = Model(config, doc.get("added_effects", []), without=without,
                  prescribed_upper=bool(doc.get("prescribed_upper", False)))
    exps = [_load(p, config, path) for p in doc["data"]]
    val = [_load(p, config, path) for p in doc.get("validation", [])]
    base = {k: (math.nan if v is None else float(v)) for k, v in doc["params"].items()}
    names_base: list[str] = []
    for n in doc["free"]:
        b = n.split("[")[0]
        if b not in names_base:
            names_base.append(b)
    prob = Problem(model, exps, free=names_base, base=base,
                   channels=tuple(doc["channels"]), weights=doc.get("weights"))
    x = np.array([float(doc["estimates"][n]["value"]) for n in prob.names])
    return LoadedFit(path.parent, doc, prob, x, val)


def _load(p: str, config: str, where: Path):
    if not Path(p).exists():
        raise ResultError(f"{where}: its data file {p} is gone; restore it or fit again")
    return load_experiment(p, expect_lower=config != "upper")


def diagnosis_starts(spec: str | Path | None, effects) -> dict[str, float]:
    """Start values for effects being added, from the diagnosis beside a --p0 fit: the
    one-step estimates of their parameters and the best grid point of their nuisance
    parameters (so the refit starts in the basin the score test saw)."""
    if spec is None:
        return {}
    p = Path(spec)
    folder = p if p.is_dir() else p.parent
    path = folder / "diagnosis.json"
    if not path.exists():
        return {}
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    wanted = set(effects)
    out: dict[str, float] = {}
    for row in doc.get("ranking", []):
        if row.get("effect") not in wanted:
            continue
        for n, v in row.get("parameters", {}).items():
            val = v.get("one_step_estimate")
            if val is not None and math.isfinite(val):
                out[n] = float(val)
        for n, val in (row.get("nuisance_best_grid_point") or {}).items():
            out[n] = float(val)
    return out

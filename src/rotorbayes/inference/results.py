"""Result folders: read a fit back as the problem and point it came from.

``rotorbayes fit`` writes ``fit.json`` with everything needed to rebuild its
:class:`~rotorbayes.inference.Problem`: configuration, effects (catalogue names and user
files), data files, free parameters, channels, weights, the full parameter set and the
parent fit it started from.  :func:`load_fit` rebuilds it; ``diagnose``, ``compare`` and
``sample`` start from there.

* Data files are recorded by absolute path, by a path relative to the fit folder and by
  SHA-256, so a fit folder works from any working folder, and a project folder moved whole
  (data and results together) still finds its data.  A data file whose SHA-256 no longer
  matches (edited, re-exported or replaced since the fit) is refused by every command that
  reads the fit again, naming the file and both hashes, unless the user says
  ``--accept-changed-data`` (:data:`CHANGED_DATA_OPTION`).
* Effect files are code.  A fit records the SHA-256 of every user effect file it ran;
  opening the folder again (``compare``, ``diagnose``, ``sample``, ``identify``, ``fit
  --p0``) refuses to import an effect file that is gone or has changed since, or one named
  by a fit.json this user did not write here (another owner, writable by others, unpacked
  from an archive), unless the user says ``--trust-effects`` (:func:`check_effect_files`).
"""

from __future__ import annotations

import hashlib
import math
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..io.measurements import DataFileError, load_experiment, measurement_sha256
from ..model.configurations import CONFIGURATIONS, Model

if TYPE_CHECKING:
    from .problem import Problem, ValidationTorsion


class ResultError(ValueError):
    """A result folder is missing, incomplete or from an incompatible version."""


#: The one option of every command that reads a fit again (diagnose, compare, sample,
#: identify, design) that lets it use data files changed since the fit.
CHANGED_DATA_OPTION = "--accept-changed-data"


@dataclass
class LoadedFit:
    """A fit read back from its folder.

    ``validation_alpha0`` holds, per validation experiment, the initial torsion the fit
    decided for it (a :class:`~rotorbayes.inference.problem.ValidationTorsion`, from
    fit.json's ``validation_alpha0``), or None where the fit recorded none (an older fit:
    :meth:`~rotorbayes.inference.Problem.validation_params` decides it again, the same way).
    """

    folder: Path
    doc: dict
    problem: Problem
    x: np.ndarray
    validation: list
    validation_alpha0: list = field(default_factory=list)
    #: The data files used although their SHA-256 changed since the fit (with
    #: ``accept_changed_data``): ``{"file", "recorded", "now"}`` each.
    changed_data: list = field(default_factory=list)

    def validation_quality(self) -> list[dict]:
        """:func:`~rotorbayes.inference.quality` rows of the validation data, each run with
        the alpha0 the fit decided for it: the figures ``fit`` printed."""
        from . import quality

        if not self.validation:
            return []
        return quality(
            self.problem, self.x, self.validation, validation_alpha0=self.validation_alpha0 or None
        )

    def validation_summary(self) -> dict | None:
        """The validation data's headline as ``fit`` gives it -- the worst fitted channel's
        RMS over its noise floor, each run with the initial torsion the fit decided for it
        -- with those records and a text to print; None without validation data."""
        from .assess import channel_rows

        rows = self.validation_quality()
        if not rows:
            return None
        floors, _ = self.problem.noise_floors()
        ratios = [
            c["ratio"]
            for c in channel_rows(self.problem, rows, "validation", floors)
            if c["fitted"]
        ]
        v = max(ratios) if ratios else math.nan
        recs = [r.get("validation_alpha0") for r in rows]
        figure = f"{v:.3g}x" if v < 1000 else f"{v:.0f}x"
        text = "\n".join(
            [
                f"validation data: {figure} the floor (worst fitted channel; each "
                "run with its own initial torsion)"
            ]
            + ["  " + t.words(v) for t in recs if t is not None]
        )
        return {
            "worst_ratio_to_floor": v,
            "text": text,
            "alpha0": [None if t is None else t.as_dict() for t in recs],
        }

    @property
    def parent(self) -> Path | None:
        p = self.doc.get("parent")
        return Path(p) if p else None

    def chain(
        self, *, trust_effects: bool = False, accept_changed_data: bool = False
    ) -> list[LoadedFit]:
        """This fit and its ancestors (``--p0`` fit folders), oldest first."""
        out, seen, cur = [self], {self.folder.resolve()}, self
        while cur.parent is not None and (cur.parent / "fit.json").exists():
            if cur.parent.resolve() in seen:
                break
            seen.add(cur.parent.resolve())
            cur = load_fit(
                cur.parent, trust_effects=trust_effects, accept_changed_data=accept_changed_data
            )
            out.append(cur)
        return out[::-1]


def fit_json_path(spec: str | Path) -> Path:
    p = Path(spec)
    if p.is_dir():
        p = p / "fit.json"
    if not p.exists():
        raise ResultError(
            f"{p}: not found; give a folder written by `rotorbayes fit` (it holds fit.json)"
        )
    return p


def file_sha256(path: str | Path) -> str:
    """SHA-256 (hex) of the file ``path`` as it is now, read in blocks."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


TRUST_HINT = (
    "effect files are Python code that runs when a result is opened: read the file, "
    "and only if you trust it pass --trust-effects (or fit again)"
)

#: Seconds by which a fit.json's modification time may precede its change time (the time
#: its inode last changed) for it to count as written here: rotorbayes writes it and
#: renames it into place within seconds; unpacking an archive or copying with the times
#: kept (tar, unzip, cp -p, rsync -a) sets an older modification time.
KEPT_TIMES_S = 120.0


def foreign_reason(fit_json: Path) -> tuple[str, str] | None:
    """Why ``fit_json`` may not be a result this user wrote here, and what to do; None when
    it is (or where the system cannot tell: not POSIX, not found).

    A fit.json records the SHA-256 of the effect files it ran; a forged one can record the
    right SHA-256 of any file. It is taken as written by this user only when it belongs
    to them (not to another user), no other user may change it (not writable by all, nor
    by a group other than the user's own), and its modification time is not older than
    the file itself by more than :data:`KEPT_TIMES_S` (not unpacked from an archive or
    copied with its times kept).
    """
    if os.name != "posix":
        return None
    try:
        st = fit_json.stat()
    except OSError:
        return None
    if st.st_uid != os.geteuid():
        try:
            import pwd

            owner = f"{pwd.getpwuid(st.st_uid).pw_name}, uid {st.st_uid}"
        except (ImportError, KeyError):
            owner = f"uid {st.st_uid}"
        return (f"it belongs to another user ({owner})", "pass --trust-effects (or fit again)")
    if st.st_mode & 0o002 or (st.st_mode & 0o020 and st.st_gid != os.getegid()):
        if st.st_mode & 0o002:
            who = "every user"
        else:
            try:
                import grp

                who = f"the members of group {grp.getgrgid(st.st_gid).gr_name}"
            except (ImportError, KeyError):
                who = f"the members of group {st.st_gid}"
        return (
            f"{who} may change it",
            f"if the folder is yours, `chmod go-w {fit_json}`; else pass --trust-effects",
        )
    if st.st_ctime - st.st_mtime > KEPT_TIMES_S:
        return (
            "its modification time is older than the file itself (unpacked from an "
            "archive, or copied with its times kept)",
            f"if the folder is yours, `touch {fit_json}` makes it count as yours again; "
            "else pass --trust-effects",
        )
    return None


def check_effect_files(doc: dict, where: Path, trust: bool = False) -> list[str]:
    """The ``added_effects`` of a fit.json, with user effect files checked before any import.

    Each ``FILE.py:NAME`` must exist and have the SHA-256 the fit recorded, and the fit.json
    ``where`` must be this user's own (:func:`foreign_reason`: a folder from another user,
    or from an archive, may record the right SHA-256 of a file it brought along); otherwise
    :class:`ResultError` naming the file and why (accepted with ``trust``, with a warning
    on stderr). Relative paths of older results are tried from the working folder and from
    the fit folder. Returns the specs to build the model from.
    """
    recorded = doc.get("effect_files") or {}
    if not isinstance(recorded, dict):
        recorded = {}
    out = []
    foreign = None
    for spec in doc.get("added_effects", []):
        if not isinstance(spec, str):
            raise ResultError(f"{where}: added_effects holds {spec!r}, not an effect name")
        path_s, sep, name = spec.rpartition(":")
        if not (sep and path_s.endswith(".py")):
            out.append(spec)
            continue
        p = Path(path_s)
        if not p.is_absolute() and not p.is_file():
            p = where.parent / p
        if not p.is_file():
            raise ResultError(
                f"{where}: its effect file {path_s} is gone; restore it (the fit "
                "cannot be rebuilt without it) or fit again"
            )
        sha = file_sha256(p)
        then = recorded.get(path_s) or recorded.get(str(p.resolve()))
        if then != sha:
            what = (
                "changed since the fit"
                if then
                else "has no SHA-256 recorded with the result (an older rotorbayes, or not "
                "written by rotorbayes)"
            )
            if not trust:
                raise ResultError(f"{where}: the effect file {p} {what}; {TRUST_HINT}")
            print(
                f"warning: {where}: the effect file {p} {what}; importing it because of "
                "--trust-effects",
                file=sys.stderr,
            )
        else:
            foreign = foreign or foreign_reason(Path(where))
            if foreign is not None:
                why, fix = foreign
                if not trust:
                    raise ResultError(
                        f"{where}: it names the effect file {p} (Python code, run when it is "
                        f"imported), but {Path(where).name} may not be a result you wrote "
                        f"here: {why}. A result folder you did not write can record the "
                        "SHA-256 of any file it brings along: read the effect file, and only "
                        f"if you trust it and the folder, {fix}"
                    )
                print(
                    f"warning: {where}: {why}; importing its effect file {p} because of "
                    "--trust-effects",
                    file=sys.stderr,
                )
        out.append(f"{p.resolve()}:{name}")
    return out


def data_path(spec: str, doc: dict, index: int, key: str, fit_json: Path) -> Path:
    """Find a data file of a fit: as recorded (absolute), relative to the fit folder, then
    relative to the working folder; ResultError naming the places tried."""
    tried = [Path(spec)]
    rel = None
    with_meta = doc.get(f"{key}_files")
    if (
        isinstance(with_meta, list)
        and index < len(with_meta)
        and isinstance(with_meta[index], dict)
    ):
        rel = with_meta[index].get("relative")
    if isinstance(rel, str):
        tried.append(fit_json.parent / rel)
    if not Path(spec).is_absolute():
        tried.append(fit_json.parent / spec)
    for p in tried:
        # Any kind of file: a pipe or a device is then refused by load_experiment, by
        # name, without being opened.
        if os.path.exists(p) and not p.is_dir():
            return p
    places = ", ".join(dict.fromkeys(str(p) for p in tried))
    raise ResultError(
        f"{fit_json}: its data file {spec} is gone (looked for {places}); restore it or fit again"
    )


def data_record(paths: list, fit_folder: Path, read=None) -> list[dict]:
    """What a fit records of its data files: absolute path, path relative to the fit
    folder, SHA-256, and how it was read (``read``, a :class:`~rotorbayes.io.rigfiles.ReadSpec`:
    the file's names of the signals and its units; a bundled example is a plain CSV).
    ``paths`` holds paths or the experiments read from them
    (:class:`~rotorbayes.io.measurements.Experiment`): then the SHA-256 is that of the bytes
    that were read and fitted (a .mat file's bytes, as a CSV's), not of the file as it may
    be now."""
    from ..io.examples import EXAMPLES

    out = []
    for p in paths:
        sha = getattr(p, "sha256", None)
        ap = Path(getattr(p, "path", p)).absolute()
        rec = {
            "path": str(ap),
            "relative": os.path.relpath(ap, fit_folder.absolute()),
            "sha256": sha or file_sha256(ap),
        }
        if read is not None and not read.is_default and ap.parent != EXAMPLES.absolute():
            rec["read"] = read.as_dict()
        out.append(rec)
    return out


def recorded_read(doc: dict, key: str, index: int, where: Path):
    """How data file ``index`` of ``key`` ("data" or "validation") was read by the fit
    (its :class:`~rotorbayes.io.rigfiles.ReadSpec`; the plain CSV where none is recorded)."""
    from ..io.rigfiles import FormatProblem, ReadSpec

    recs = doc.get(f"{key}_files")
    rec = recs[index] if isinstance(recs, list) and index < len(recs) else None
    try:
        return ReadSpec.from_record(rec.get("read") if isinstance(rec, dict) else None)
    except (FormatProblem, TypeError, AttributeError) as exc:
        raise ResultError(
            f"{where}: the way {key} file {index + 1} was read is damaged ({exc}); fit again"
        ) from None


def _recorded_sha256(doc: dict, key: str, index: int) -> str | None:
    """The SHA-256 fit.json recorded for data file ``index`` of ``key`` ("data" or
    "validation"); None where it recorded none (an older rotorbayes)."""
    recs = doc.get(f"{key}_files")
    rec = recs[index] if isinstance(recs, list) and index < len(recs) else None
    sha = rec.get("sha256") if isinstance(rec, dict) else None
    return sha.lower() if isinstance(sha, str) and len(sha) == 64 else None


def _changed_words(fit_json: Path, p: Path, recorded: str, now: str) -> str:
    return (
        f"{fit_json}: its data file {p} has changed since the fit (SHA-256 recorded "
        f"{recorded}, now {now}): the fit's estimates and figures describe the file as "
        "it was"
    )


def _load_recorded(
    doc: dict,
    key: str,
    index: int,
    fit_json: Path,
    config: str,
    keep: bool,
    accept_changed: bool,
    changed: list,
):
    """Data file ``index`` of ``key`` of a fit, checked against the SHA-256 the fit
    recorded: a changed file is refused (:class:`ResultError`) unless ``accept_changed``,
    then named on stderr and in ``changed``."""
    spec = doc[key][index]
    p = data_path(spec, doc, index, key, fit_json)
    recorded = _recorded_sha256(doc, key, index)
    fix = (
        f"restore the file the fit was made from, fit the changed file again, or pass "
        f"{CHANGED_DATA_OPTION} to use it with this fit anyway"
    )
    try:
        ex = _load(p, config, keep, recorded_read(doc, key, index, fit_json))
    except DataFileError as exc:
        # Say first that the file is not the one fitted (when it is a file we may read).
        if recorded and not accept_changed:
            try:
                now = measurement_sha256(p)
            except DataFileError:  # not a file we read: its own message says why
                now = recorded
            if now != recorded:
                raise ResultError(
                    f"{_changed_words(fit_json, p, recorded, now)}, and it no "
                    f"longer reads as a measurement ({exc.problem}); restore "
                    "the file the fit was made from, or fit again"
                ) from None
        raise ResultError(f"{fit_json}: its data file {exc}") from None
    if recorded and ex.sha256 != recorded:
        if not accept_changed:
            raise ResultError(
                f"{_changed_words(fit_json, p, recorded, ex.sha256)}; {fix} (nothing was written)"
            )
        print(
            f"warning: {_changed_words(fit_json, p, recorded, ex.sha256)}; using it "
            f"because of {CHANGED_DATA_OPTION}",
            file=sys.stderr,
        )
        changed.append({"file": str(p), "recorded": recorded, "now": ex.sha256})
    return ex


FIX_OR_REFIT = (
    "the file was edited or damaged: correct the value in it, or fit again (a "
    "fit writes only values inside the bounds)"
)


def read_fit_json(path: str | Path) -> dict:
    """The JSON object in a fit.json (or a file given as one), its nesting checked before
    it is parsed (:func:`rotorbayes.io.tomlfile.check_nesting`); :class:`ResultError` naming
    the file for anything else."""
    from ..io.tomlfile import loads_json

    path = Path(path)
    try:
        doc = loads_json(path.read_text(encoding="utf-8"), path, ResultError, "fit.json")
    except OSError as exc:
        raise ResultError(f"{path}: cannot read it ({exc})") from None
    except ValueError as exc:
        if isinstance(exc, ResultError):
            raise
        what = "a data file" if path.suffix.lower() in (".csv", ".txt", ".mat") else "not JSON"
        raise ResultError(
            f"{path}: not a fit ({what}); give the folder `rotorbayes fit --out` "
            "wrote, or its fit.json"
        ) from None
    if not isinstance(doc, dict):
        raise ResultError(f"{path}: not a fit written by `rotorbayes fit` (not a JSON object)")
    return doc


def _checked_value(v, name: str, info, path: Path, where: str) -> float | None:
    """One number of a fit.json, checked: finite and inside its parameter's bounds (``info``;
    None: finite only).  ``None`` (JSON's null) and NaN stand for "no value" and are
    accepted only where the parameter's null value is NaN (``Ts_l``: no Stribeck peak)."""
    unit = f" {info.unit}" if info is not None and info.unit != "-" else ""
    bounds = (
        f" ({info.description}: between {info.lower:g} and {info.upper:g}{unit})"
        if info is not None
        else ""
    )
    if v is None or (isinstance(v, float) and math.isnan(v)):
        if info is not None and math.isnan(info.null) and name == "Ts_l":
            return None
        shown = "null" if v is None else "NaN"
        raise ResultError(
            f"{path}: {name} = {shown} ({where}) is not a number{bounds}; {FIX_OR_REFIT}"
        )
    if not isinstance(v, int | float) or isinstance(v, bool):
        raise ResultError(
            f"{path}: {name} = {v!r} ({where}) is not a number{bounds}; {FIX_OR_REFIT}"
        )
    v = float(v)
    if not math.isfinite(v):
        raise ResultError(
            f"{path}: {name} = {v!r} ({where}) is not a finite number{bounds}; {FIX_OR_REFIT}"
        )
    if info is not None and not info.lower <= v <= info.upper:
        raise ResultError(
            f"{path}: {name} = {v:g}{unit} ({where}) lies outside its "
            f"bounds{bounds}; {FIX_OR_REFIT}"
        )
    return v


def fit_values(doc: dict, path: str | Path, info=None) -> dict[str, float | None]:
    """fit.json's ``params`` (every parameter's value at the fit), each checked: a finite
    number inside its parameter's bounds (``info``: the model's parameter metadata; the
    built-in parameters' when None, a user effect's parameters then only finite), ``None``
    for ``Ts_l`` without a Stribeck peak.  :class:`ResultError` names the file, the
    parameter and the value, and says what to do."""
    from ..model.parameters import INFO

    path = Path(path)
    params = doc.get("params")
    if not isinstance(params, dict):
        raise ResultError(
            f"{path}: params is not a table of parameter values: damaged, or "
            "not written by `rotorbayes fit`; fit again"
        )
    info = INFO if info is None else info
    return {
        str(k): _checked_value(v, str(k), info.get(k), path, "its value in params")
        for k, v in params.items()
    }


def fit_estimates(doc: dict, path: str | Path, names, info=None) -> list[float]:
    """The estimates of the free parameters ``names`` (``alpha0[1]`` included) from
    fit.json's ``estimates``, checked as :func:`fit_values` checks values."""
    from ..model.parameters import INFO

    path = Path(path)
    est = doc.get("estimates")
    info = INFO if info is None else info
    out = []
    for n in names:
        rec = est.get(n) if isinstance(est, dict) else None
        if not isinstance(rec, dict) or "value" not in rec:
            raise ResultError(
                f"{path}: estimates lack a value for the free parameter {n}: "
                "damaged, or written by another rotorbayes; fit again"
            )
        v = _checked_value(rec["value"], n, info.get(n.split("[")[0]), path, "its estimate")
        if v is None:
            raise ResultError(f"{path}: {n} = null (its estimate) is not a number; {FIX_OR_REFIT}")
        out.append(v)
    return out


def load_fit(
    spec: str | Path, *, trust_effects: bool = False, accept_changed_data: bool = False
) -> LoadedFit:
    """Rebuild the problem and the fitted point of a fit folder (or its fit.json).

    User effect files are checked first (:func:`check_effect_files`).  Every data file is
    read once and its SHA-256 compared with the one the fit recorded: a file changed since
    the fit is refused (:class:`ResultError` naming it and both hashes) unless
    ``accept_changed_data`` (then it is used, said on stderr and listed in
    :attr:`LoadedFit.changed_data`).
    """
    from . import Problem

    path = fit_json_path(spec)
    doc = read_fit_json(path)
    need = ("config", "data", "free", "params", "estimates", "channels")
    missing = [k for k in need if k not in doc]
    if missing:
        raise ResultError(
            f"{path}: lacks {', '.join(missing)}; it was written by an older "
            "rotorbayes: fit again to make a folder this version can read"
        )
    shapes = {
        "data": list,
        "validation": list,
        "free": list,
        "channels": list,
        "params": dict,
        "estimates": dict,
        "effects": list,
        "added_effects": list,
    }
    bad = [k for k, t in shapes.items() if k in doc and not isinstance(doc[k], t)]
    bad += [
        k
        for k in ("data", "validation", "free", "channels", "added_effects")
        if isinstance(doc.get(k), list) and not all(isinstance(v, str) for v in doc[k])
    ]
    if bad:
        raise ResultError(
            f"{path}: {', '.join(sorted(set(bad)))} of the wrong type: damaged, or "
            "not written by `rotorbayes fit`; fit again"
        )
    config = doc["config"]
    if not isinstance(config, str) or config not in CONFIGURATIONS:
        raise ResultError(f"{path}: config {config!r} is not a configuration of the rig")
    base_on = set(CONFIGURATIONS[config].base_effects)
    without = sorted(base_on - set(doc.get("effects", [])))
    added = check_effect_files(doc, path, trust_effects)
    model = Model(
        config, added, without=without, prescribed_upper=bool(doc.get("prescribed_upper", False))
    )
    # Every number is checked before any data are read (a hand-edited NaN, -5 or 1e300
    # is named here, not met later as a simulation that fails).
    base = {
        k: (math.nan if v is None else float(v))
        for k, v in fit_values(doc, path, model.info).items()
    }
    estimates = dict(
        zip(doc["free"], fit_estimates(doc, path, doc["free"], model.info), strict=True)
    )
    # A fit made with --keep-glitches is read back with them kept (the same data).
    keep = bool((doc.get("glitches") or {}).get("kept"))
    changed: list[dict] = []
    exps = [
        _load_recorded(doc, "data", i, path, config, keep, accept_changed_data, changed)
        for i in range(len(doc["data"]))
    ]
    val = [
        _load_recorded(doc, "validation", i, path, config, keep, accept_changed_data, changed)
        for i in range(len(doc.get("validation", [])))
    ]
    try:
        names_base: list[str] = []
        for n in doc["free"]:
            b = n.split("[")[0]
            if b not in names_base:
                names_base.append(b)
        step = doc.get("step")
        prob = Problem(
            model,
            exps,
            free=names_base,
            base=base,
            channels=tuple(doc["channels"]),
            weights=doc.get("weights"),
            step=None if step is None else float(step),
        )
    except (KeyError, TypeError, AttributeError) as exc:
        raise ResultError(
            f"{path}: cannot rebuild the fit from it ({type(exc).__name__}: "
            f"{exc}): damaged, or written by another rotorbayes; fit again"
        ) from None
    except ValueError as exc:  # a value the problem refuses (a step, a weight, a channel)
        raise ResultError(f"{path}: {exc}") from None
    missing = [n for n in prob.names if n not in estimates]
    if missing:
        raise ResultError(
            f"{path}: estimates lack a value for the free parameter "
            f"{missing[0]}: damaged, or written by another rotorbayes; fit again"
        )
    x = np.array([estimates[n] for n in prob.names])
    return LoadedFit(path.parent, doc, prob, x, val, _validation_alpha0(doc, path, val), changed)


def _validation_alpha0(doc: dict, path: Path, val: list) -> list:
    """fit.json's ``validation_alpha0``, checked: one record per validation file (or none
    at all, from an older rotorbayes)."""
    from .problem import ValidationTorsion

    recs = doc.get("validation_alpha0")
    if recs is None or recs == []:
        return []
    if not isinstance(recs, list) or len(recs) != len(val):
        raise ResultError(
            f"{path}: validation_alpha0 must hold one record per validation "
            f"file ({len(val)}): damaged, or not written by `rotorbayes fit`; "
            "fit again"
        )
    out: list[ValidationTorsion | None] = []
    for r, ex in zip(recs, val, strict=True):
        if r is None:
            out.append(None)
            continue
        if not isinstance(r, dict):
            raise ResultError(
                f"{path}: validation_alpha0 holds {r!r}, not a record: damaged, "
                "or not written by `rotorbayes fit`; fit again"
            )
        try:
            out.append(
                ValidationTorsion.from_dict(
                    r, experiment=str(ex.name or ex.path), file=str(ex.path)
                )
            )
        except ValueError as exc:
            raise ResultError(
                f"{path}: {exc}: damaged, or not written by `rotorbayes fit`; fit again"
            ) from None
    return out


def _load(p: Path, config: str, keep_glitches: bool = False, read=None):
    return load_experiment(
        p, expect_lower=config != "upper", keep_glitches=keep_glitches, read=read
    )


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
    from ..io.tomlfile import loads_json

    try:
        doc = loads_json(path.read_text(), path, ResultError, "diagnosis.json")
    except (OSError, ValueError):  # unreadable: the refit starts without its estimates
        return {}
    if not isinstance(doc, dict):
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

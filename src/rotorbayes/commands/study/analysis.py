"""A whole study from one file: ``rotorbayes run analysis.toml`` (and ``rotorbayes demo``).

The analysis file (TOML; reference in ``docs/analysis_file.md``) names the data, the
configuration, the fit, the diagnosis loop, the sampler, the identifiability study, the
design of the next experiment and the report.  :func:`load_analysis` validates all of it
before any work starts: unknown tables or keys, unknown parameter names, inconsistent
prior bounds and missing files are errors that name the file and the key.

:func:`run` executes the stages through the same functions as the commands
(:mod:`rotorbayes.commands`; the log shows each stage as its command line), writes every
stage into its folder under
``out``, a log of everything printed to ``out/log.txt``, and ``out/run.json`` with package
versions, seeds, the analysis text, the data's SHA-256 and each stage's input hash and time.
Re-running skips a stage whose input hash (its part of the analysis file, the data, and
the output of the stage before it) is unchanged and whose output is still there.
"""

from __future__ import annotations

import contextlib
import datetime
import hashlib
import io
import json
import math
import shlex
import sys
import time
import typing
from dataclasses import dataclass, field
from pathlib import Path

from ...io.outputs import write_text_atomic
from ...model import effects as _effects
from ...model.parameters import INFO, ParameterError

#: Tables and keys the analysis file may hold (key -> expected type(s)).
SCHEMA: dict[str, dict[str, tuple]] = {
    "analysis": {
        "name": (str,),
        "out": (str,),
        "config": (str,),
        "data": (list,),
        "validate": (list,),
        "validate_alpha0": (list,),
        "seed": (int,),
        "columns": (dict,),
        "time_unit": (str,),
        "angle_unit": (str,),
        "counts_per_rev": (int, float, dict),
    },
    "fit": {
        "p0": (str,),
        "free": (list,),
        "fixed": (list,),
        "effects": (list,),
        "channels": (list,),
        "max_nfev": (int,),
        "jacobian": (str,),
        "step": (int, float),
        "keep_glitches": (bool,),
        "search": (bool,),
    },
    "diagnose": {
        "add_effects": (bool,),
        "max_steps": (int,),
        "noise_std": (int, float),
        "trials": (bool,),
        "proposal": (bool,),
    },
    "sample": {
        "walkers": (int,),
        "steps": (int,),
        "ensembles": (int,),
        "noise": (str,),
        "ar1": (bool,),
        "moves": (str,),
    },
    "priors": {},
    "identify": {"profiles": (list,), "points": (int,)},
    "design": {
        "params": (list,),
        "separate": (list,),
        "duration": (int, float),
        "rate": (int, float),
        "max_volts": (int, float),
        "band_hz": (int, float),
        "family": (str,),
        "starts": (int,),
        "max_evals": (int,),
        "check": (bool,),
    },
    "report": {"html": (bool,)},
    "parallel": {"backend": (str,), "workers": (int,), "scheduler": (str,)},
}


#: Numeric keys and their allowed ranges, checked before any work (beyond them a run would
#: not end, not fit on a disk, or mean nothing).
LIMITS: dict[str, dict[str, tuple[float, float]]] = {
    "analysis": {"seed": (0, 2**31 - 1)},
    "fit": {"max_nfev": (1, 1_000_000), "step": (1e-6, 1.0)},
    "diagnose": {"max_steps": (0, 20), "noise_std": (0.0, 1.0)},
    "sample": {"walkers": (4, 10_000), "steps": (10, 10_000_000), "ensembles": (1, 64)},
    "identify": {"points": (3, 1001)},
    "design": {
        "starts": (1, 256),
        "max_evals": (1, 1_000_000),
        "duration": (0.0, 86_400.0),
        "rate": (0.0, 100_000.0),
    },
    "parallel": {"workers": (1, 256)},
}

#: Keys that must not be empty, and what to write instead.
NON_EMPTY = {
    "out": 'name the output folder (relative to the analysis file), e.g. out = "results"',
    "name": "give the study a name or leave the key out",
    "config": "choose upper, coupled or brake",
    "data": "list at least one measurement file",
    "validate": "list validation files or leave the key out",
    "validate_alpha0": 'give one torsion [rad] or "fit" per validation file, or leave the key out',
    "free": "list parameters or leave the key out (the configuration's default)",
    "fixed": "list parameters or leave the key out",
    "effects": "list effects or leave the key out",
    "channels": "choose theta_u and/or theta_l, or leave the key out (all channels)",
    "profiles": "list parameters or leave the key out",
    "p0": "name a start or leave the key out (a start from the data)",
    "params": "list free parameters or leave the key out (the fit's sloppiest direction)",
    "separate": "list two or more effects or leave the key out",
}


class AnalysisError(ValueError):
    """The analysis file is invalid; the message names the file and the key."""


@dataclass
class Analysis:
    path: Path
    text: str
    doc: dict
    base_dir: Path = field(init=False)

    def __post_init__(self):
        self.base_dir = self.path.resolve().parent

    def table(self, name: str) -> dict:
        return self.doc.get(name, {})

    @property
    def out(self) -> Path:
        p = Path(self.doc["analysis"]["out"])
        return p if p.is_absolute() else self.base_dir / p

    def resolve(self, spec: str) -> str:
        """A data/effect path relative to the analysis file (``example:`` kept)."""
        if spec.startswith(("example:", "thesis:")):
            return spec
        path_part, sep, rest = spec.partition(".py:")
        if sep:
            p = Path(path_part + ".py")
            return str(p if p.is_absolute() else self.base_dir / p) + ":" + rest
        p = Path(spec)
        return str(p if p.is_absolute() else self.base_dir / p)


def read_spec(a: Analysis):
    """How the analysis file's data are read (``columns``, ``time_unit``, ``angle_unit``,
    ``counts_per_rev`` of ``[analysis]``: :class:`~rotorbayes.io.rigfiles.ReadSpec`)."""
    from ...io.rigfiles import FormatProblem, ReadSpec

    an = a.table("analysis")
    try:
        return ReadSpec.from_options(
            an.get("columns"), an.get("time_unit"), an.get("angle_unit"), an.get("counts_per_rev")
        )
    except FormatProblem as exc:
        raise _err(a.path, "analysis", str(exc)) from None


def _err(path, key, text) -> AnalysisError:
    return AnalysisError(f"{path}: [{key}] {text}")


def _check_validate_alpha0(p, an: dict) -> None:
    """``validate_alpha0``: one initial torsion [rad] (or "fit") per validation file."""
    given = an.get("validate_alpha0")
    if given is None:
        return
    n = len(an.get("validate", []))
    if len(given) != n:
        raise _err(
            p,
            "analysis",
            f"validate_alpha0 has {len(given)} entries for {n} "
            "validation files; give one per file in the order of validate (a torsion "
            'in rad, or "fit" to fit it on that run alone)',
        )
    lo, hi = INFO["alpha0"].lower, INFO["alpha0"].upper
    for v in given:
        ok = v == "fit" or (
            isinstance(v, int | float)
            and not isinstance(v, bool)
            and math.isfinite(v)
            and lo <= v <= hi
        )
        if not ok:
            raise _err(
                p,
                "analysis",
                f"validate_alpha0: {v!r} is neither a torsion in rad "
                f'within [{lo:g}, {hi:g}] nor "fit"',
            )


def load_analysis(path: str | Path) -> Analysis:
    """Read and validate an analysis file (see the module docstring)."""
    from ...io.examples import example_path
    from ...io.tomlfile import read_toml, read_toml_text

    p = Path(path)
    doc = read_toml(
        p, AnalysisError, "analysis file", "see docs/analysis_file.md for the tables and keys"
    )
    text = read_toml_text(p, AnalysisError, "analysis file")
    for t, v in doc.items():
        if t not in SCHEMA:
            raise AnalysisError(
                f"{p}: unknown table [{t}]; the tables are {', '.join(f'[{s}]' for s in SCHEMA)}"
            )
        if not isinstance(v, dict):
            raise AnalysisError(f"{p}: {t} must be a table ([{t}]), not a value")
        if t == "priors":
            continue
        for k, val in v.items():
            if k not in SCHEMA[t]:
                raise _err(p, t, f"unknown key {k!r}; valid keys: {', '.join(SCHEMA[t])}")
            if not isinstance(val, SCHEMA[t][k]) or (
                isinstance(val, bool) and bool not in SCHEMA[t][k]
            ):
                want = " or ".join(x.__name__ for x in SCHEMA[t][k])
                raise _err(p, t, f"{k} = {val!r} must be a {want}")
            if (
                isinstance(val, list)
                and k != "validate_alpha0"
                and not all(isinstance(x, str) for x in val)
            ):
                raise _err(p, t, f"{k} = {val!r} must be a list of strings (names in quotes)")
            if k in LIMITS.get(t, {}):
                lo, hi = LIMITS[t][k]
                if isinstance(val, float) and not math.isfinite(val) or not lo <= val <= hi:
                    raise _err(p, t, f"{k} = {val!r} must lie between {lo:g} and {hi:g}")
            if (
                isinstance(val, (str, list))
                and k in NON_EMPTY
                and not (val.strip() if isinstance(val, str) else val)
            ):
                raise _err(p, t, f"{k} is empty; {NON_EMPTY[k]}")
    a = Analysis(p, text, doc)
    an = doc.get("analysis")
    if not an:
        raise AnalysisError(
            f"{p}: the [analysis] table is missing (it names the data, the "
            "configuration and the output folder)"
        )
    for k in ("out", "config", "data"):
        if k not in an:
            raise _err(p, "analysis", f"{k} is missing")
    if an["config"] not in ("upper", "coupled", "brake"):
        raise _err(p, "analysis", f"config = {an['config']!r}; choose upper, coupled or brake")
    if not an["data"]:
        raise _err(p, "analysis", "data is empty; list at least one measurement file")
    for key in ("data", "validate"):
        for f in an.get(key, []):
            if not isinstance(f, str):
                raise _err(p, "analysis", f"{key}: {f!r} must be a file name")
            if f.startswith("example:"):
                try:
                    example_path(f)
                except Exception as exc:  # noqa: BLE001 - reported with the key
                    raise _err(p, "analysis", f"{key}: {exc}") from None
            elif not Path(a.resolve(f)).exists():
                raise _err(
                    p,
                    "analysis",
                    f"{key}: file {f!r} not found (relative paths are relative to {a.base_dir})",
                )
    _check_validate_alpha0(p, an)
    read_spec(a)
    fit = a.table("fit")
    for key in ("free", "fixed"):
        for n in fit.get(key, []):
            b = str(n).split("[")[0]
            if b not in INFO:
                raise _err(
                    p, "fit", f"{key}: unknown parameter {n!r}; valid names are: {', '.join(INFO)}"
                )
    for e in fit.get("effects", []):
        if ".py:" in e:
            # A user effect file is code: validation only checks it is there (it runs when
            # the study's fit imports it).
            f = Path(a.resolve(e).rpartition(":")[0])
            if not f.is_file():
                raise _err(
                    p,
                    "fit",
                    f"effects: effect file {f} not found (relative paths "
                    f"are relative to {a.base_dir})",
                )
            continue
        try:
            _effects.resolve([e])
        except Exception as exc:  # noqa: BLE001 - the effect registry explains
            raise _err(p, "fit", f"effects: {exc}") from None
    for c in fit.get("channels", []):
        if c not in ("theta_u", "theta_l"):
            raise _err(p, "fit", f"channels: {c!r}; choose theta_u and/or theta_l")
    if "jacobian" in fit and fit["jacobian"] not in ("differences", "sensitivity"):
        raise _err(p, "fit", f"jacobian = {fit['jacobian']!r}; choose differences or sensitivity")
    s = a.table("sample")
    if "noise" in s and s["noise"] not in ("robust", "floor", "sampled"):
        raise _err(p, "sample", f"noise = {s['noise']!r}; choose robust, floor or sampled")
    if "moves" in s:
        from ...inference.move_names import MOVES

        if s["moves"] not in MOVES:
            raise _err(p, "sample", f"moves = {s['moves']!r}; choose one of {', '.join(MOVES)}")
    for k in ("walkers", "steps", "ensembles"):
        if k in s and s[k] < 1:
            raise _err(p, "sample", f"{k} = {s[k]} must be >= 1")
    for n, spec in a.table("priors").items():
        if n not in INFO:
            raise _err(p, "priors", f"unknown parameter {n!r}; valid names are: {', '.join(INFO)}")
        if not isinstance(spec, dict):
            raise _err(
                p,
                "priors",
                f'{n} must be a table like {{ dist = "normal", mean = 0.08, sd = 0.004 }}',
            )
        from ...inference.likelihood import check_prior_spec

        try:
            check_prior_spec(spec, n)
        except ParameterError as exc:
            raise _err(p, "priors", str(exc)) from None
        if spec.get("dist", "uniform") not in ("uniform", "loguniform", "normal"):
            raise _err(
                p, "priors", f"{n}: dist {spec['dist']!r}; choose uniform, loguniform or normal"
            )
        lo, hi = spec.get("lower", INFO[n].lower), spec.get("upper", INFO[n].upper)
        if not lo < hi:
            raise _err(p, "priors", f"{n}: lower {lo} must be below upper {hi}")
    for n in a.table("identify").get("profiles", []):
        if n not in INFO:
            raise _err(p, "identify", f"profiles: unknown parameter {n!r}")
    if "design" in doc:
        _check_design(p, a.table("design"), an["config"])
    from ...inference.parallel import BACKENDS

    backend = a.table("parallel").get("backend")
    if backend is not None and backend not in BACKENDS:
        raise _err(p, "parallel", f"backend {backend!r}; choose one of {', '.join(BACKENDS)}")
    return a


def _check_design(p: Path, d: dict, config: str) -> None:
    """The ``[design]`` table's values, checked like ``rotorbayes design``'s options."""
    from ...design.inputs import FAMILIES, MAX_BAND_HZ
    from ...model.signals import MAX_VOLTAGE

    if d.get("params") and d.get("separate"):
        raise _err(
            p,
            "design",
            "give either params or separate, not both (neither: the fit's sloppiest direction)",
        )
    for n in d.get("params", []):
        if n.split("[")[0] not in INFO:
            raise _err(
                p, "design", f"params: unknown parameter {n!r}; valid names are: {', '.join(INFO)}"
            )
    sep = d.get("separate")
    if sep is not None:
        repeated = sorted({e for e in sep if sep.count(e) > 1})
        if len(sep) < 2 or repeated:
            why = f" ({', '.join(repeated)} given twice)" if repeated else ""
            raise _err(
                p,
                "design",
                f"separate = {sep!r}: give two or more different "
                f'effects{why}, e.g. separate = ["lower_asymmetric_coulomb", '
                '"string_damping"]',
            )
        for e in sep:
            if ".py:" in e:  # validation runs no code
                raise _err(
                    p,
                    "design",
                    f"separate: {e!r}: name catalogue effects (`rotorbayes "
                    "effects` lists them); an effect file's effect is designed for with "
                    "`rotorbayes design FIT --separate ...`",
                )
            try:
                eff = _effects.get(e)
            except Exception as exc:  # noqa: BLE001 - the effect registry explains
                raise _err(p, "design", f"separate: {exc}") from None
            if config not in eff.configs:
                raise _err(
                    p,
                    "design",
                    f"separate: effect {e!r} does not apply to the "
                    f"{config} configuration (it applies to {', '.join(eff.configs)})",
                )
    if "family" in d and d["family"] not in FAMILIES:
        raise _err(p, "design", f"family = {d['family']!r}; choose {' or '.join(FAMILIES)}")
    for k, hi, why in (
        ("max_volts", MAX_VOLTAGE, " V, the amplifier's limit"),
        ("band_hz", MAX_BAND_HZ, " Hz, the rig's band"),
        ("duration", None, ""),
        ("rate", None, ""),
    ):
        if k in d:
            v = d[k]
            if not (math.isfinite(v) and v > 0) or (hi is not None and v > hi):
                raise _err(
                    p,
                    "design",
                    f"{k} = {v!r} must be positive"
                    + (f" and at most {hi:g}{why}" if hi is not None else "")
                    + "; leave it out for the default",
                )


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _file_sha(spec: str) -> str:
    from ...io.examples import example_path
    from ...io.measurements import measurement_sha256

    path = example_path(spec) if spec.startswith("example:") else Path(spec)
    # Read in blocks, a regular file only (a pipe or /dev/zero is refused by name).
    return measurement_sha256(path)


def _versions() -> dict:
    import importlib.metadata as md

    from ...util import __version__

    out = {"python": sys.version.split()[0], "rotorbayes": __version__}
    for pkg in ("numpy", "scipy", "numba", "emcee", "arviz", "corner", "h5py", "matplotlib"):
        try:
            out[pkg] = md.version(pkg)
        except md.PackageNotFoundError:
            out[pkg] = "not installed"
    return out


class _Tee(io.TextIOBase):
    def __init__(self, log, echo):
        self.log, self.echo = log, echo

    def write(self, s):
        self.log.write(s)
        if self.echo is not None:
            self.echo.write(s)
        return len(s)

    def flush(self):
        # Also called when the tee is collected (IOBase closes itself), maybe after the
        # study has closed its log: nothing left to flush then.
        for stream in (self.log, self.echo):
            if stream is not None and not getattr(stream, "closed", False):
                try:
                    stream.flush()
                except ValueError:  # a wrapper whose own stream was closed underneath
                    pass


def run(
    path: str | Path, *, quiet: bool = False, force: bool = False, out: str | Path | None = None
) -> dict:
    """Run the study an analysis file describes; returns the run record (run.json).

    ``out`` overrides the file's output folder (the demo writes into the current folder);
    ``force`` reruns every stage even if its inputs are unchanged.
    """
    from ...io.outputs import clean_stale, folder_lock

    a = load_analysis(path)
    out = Path(out) if out is not None else a.out
    _check_out(a, out, force)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        from ...util.exitcodes import EnvironmentFailure, describe_environment

        raise EnvironmentFailure(
            f"{a.path}: [analysis] out: cannot create {out.parent} ("
            f"{describe_environment(exc, '')})"
        ) from None
    with folder_lock(out, flag=f"{a.path}: [analysis] out =", other=f"[analysis] out in {a.path}"):
        _check_out(a, out, force)  # again, under the lock
        clean_stale(out)
        return _run_locked(a, path, out, quiet=quiet, force=force)


def _owner_matches(a: Analysis, out: Path) -> tuple[bool, str]:
    """Whether ``out/run.json`` was written by this analysis (the same file, or the same
    text), and what wrote it, in words."""
    try:
        rec = json.loads((out / "run.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False, "an unreadable run.json"
    if not isinstance(rec, dict):
        return False, "a run.json that is not a study's record"
    same_file = rec.get("analysis_file") == str(a.path.resolve())
    same_text = rec.get("analysis_text") == a.text
    return same_file or same_text, f"the analysis {rec.get('analysis_file')!r}"


def _check_out(a: Analysis, out: Path, force: bool) -> None:
    """Refuse an output folder that holds anything but this analysis's own earlier run
    (recognised by its run.json), unless ``force``."""
    if out.exists() and not out.is_dir():
        raise AnalysisError(
            f"{a.path}: [analysis] out = {str(out)!r} is a file, not a folder; name a new folder"
        )
    if force or not out.is_dir() or not any(out.iterdir()):
        return
    if not (out / "run.json").exists():
        raise AnalysisError(
            f"{a.path}: [analysis] out: {out}/ already holds files that no study wrote (no "
            "run.json); choose another out, or pass --force to write the study into it "
            "(its fit0/, posterior/, ... folders would be replaced)"
        )
    ok, who = _owner_matches(a, out)
    if not ok:
        raise AnalysisError(
            f"{a.path}: [analysis] out: {out}/ holds the results of another analysis "
            f"({who}); choose another out, or pass --force to replace them"
        )


def _run_locked(a: Analysis, path, out: Path, *, quiet: bool, force: bool) -> dict:
    an = a.table("analysis")
    data = [a.resolve(f) for f in an["data"]]
    val = [a.resolve(f) for f in an.get("validate", [])]
    # Hashed first: a data file refused (a pipe, a device, too large) leaves no folder.
    data_hashes = [{"path": f, "sha256": _file_sha(f)} for f in data + val]
    out.mkdir(exist_ok=True)
    record_path = out / "run.json"
    old = {}
    if record_path.exists() and not force:
        try:
            old = {s["name"]: s for s in json.loads(record_path.read_text()).get("stages", [])}
        except Exception:  # noqa: BLE001 - an unreadable record: every stage runs again
            old = {}
    seed = an.get("seed", 0)
    record = {
        "analysis_file": str(Path(path).resolve()),
        "analysis_text": a.text,
        "versions": _versions(),
        "seeds": {"analysis": seed, "sample": seed},
        "data": data_hashes,
        "stages": [],
        "started": datetime.datetime.now().isoformat(timespec="seconds"),
    }
    log = (out / "log.txt").open("a", encoding="utf-8")
    try:
        return _stages(
            StudyRun(
                analysis=a,
                path=path,
                out=out,
                record=record,
                record_path=record_path,
                old=old,
                log=log,
                quiet=quiet,
                data=data,
                validate=val,
                data_hashes=data_hashes,
                seed=seed,
            )
        )
    finally:
        log.close()


@dataclass(frozen=True)
class StudyRun:
    """One run of a study, as its stages see it: the analysis and its file's ``path``, the
    output folder ``out``, the run record being written (``record``, kept in
    ``record_path``) and the stages of the run before (``old``, by name), the log stream,
    whether the console stays ``quiet``, the data and validation files (resolved), their
    hashes and the analysis's seed."""

    analysis: Analysis
    path: str | Path
    out: Path
    record: dict
    record_path: Path
    old: dict
    log: typing.TextIO
    quiet: bool
    data: list[str]
    validate: list[str]
    data_hashes: list[dict]
    seed: int


#: Options of the stage commands given without their flag (positional arguments).
_POSITIONAL = ("data", "fit", "fits", "source")


#: Options whose command-line form is a ``--no-...`` switch (False spelled as it).
_NEGATED = ("trials", "proposal")


def _command_line(command: str, options: dict) -> str:
    """The ``rotorbayes`` command line that does what ``command(**options)`` does."""
    words = [command]
    for k, v in options.items():
        flag = "--" + k.replace("_", "-")
        if k in _POSITIONAL:
            words += [str(x) for x in v] if isinstance(v, list) else [str(v)]
        elif v is True:
            words.append(flag)
        elif v is False and k in _NEGATED:
            words.append("--no-" + k.replace("_", "-"))
        elif isinstance(v, list):
            for x in v:
                words += [flag, str(x)]
        elif v is not None and v is not False:
            words += [flag, str(v)]
    # Quoted for a shell where needed (a path with a space, a column "data(:,1)").
    return " ".join(shlex.quote(w) for w in words)


def _stage_functions() -> dict:
    """Each stage command's function of its keywords: the commands with typed options are
    run from their options object (:mod:`rotorbayes.commands.config`), built from the
    same keywords the stage's command line shows."""
    from .. import config
    from .. import fit as fit_command
    from .. import identify as identify_command
    from .. import sample as sample_command
    from ..compare import compare as compare_command
    from ..design import design as design_command
    from ..diagnose import diagnose as diagnose_command

    def typed(module, cls):
        return lambda **options: module.execute(config.from_keywords(cls, **options))

    return {
        "fit": typed(fit_command, config.FitOptions),
        "sample": typed(sample_command, config.SampleOptions),
        "identify": typed(identify_command, config.IdentifyOptions),
        "diagnose": diagnose_command,
        "compare": compare_command,
        "design": design_command,
    }


def _stages(run: StudyRun) -> dict:  # noqa: C901
    from ...util.exitcodes import Interrupted

    a, path, out, record, old, log = (run.analysis, run.path, run.out, run.record, run.old, run.log)
    data, val, seed, an = run.data, run.validate, run.seed, run.analysis.table("analysis")
    functions = _stage_functions()

    tee = _Tee(log, None if run.quiet else sys.stdout)
    print(f"\n==== rotorbayes run {path} ({record['started']})", file=tee)

    def stage(name: str, folder: Path, inputs: str, command: str, options: dict, done_file: str):
        h = _sha(inputs.encode())
        prev = old.get(name)
        if prev and prev.get("input_hash") == h and (folder / done_file).exists():
            print(f"\n---- {name}: inputs unchanged, kept {folder}/", file=tee)
            record["stages"].append({**prev, "skipped": True})
            return True
        print(f"\n---- {name}: rotorbayes {_command_line(command, options)}", file=tee, flush=True)
        t0 = time.perf_counter()
        try:
            with contextlib.redirect_stdout(tee):
                code = functions[command](**options).exit_code
        except (KeyboardInterrupt, Interrupted) as exc:
            kept = [s["name"] for s in record["stages"]]
            said = f" ({exc})" if isinstance(exc, Interrupted) else ""
            raise Interrupted(
                f"interrupted (Ctrl-C) in stage {name}{said}. The stages finished before it "
                f"are kept in {out}/ ({', '.join(kept) or 'none'}; run.json records them); "
                f"run the same command again to go on: unchanged finished stages are "
                "skipped"
            ) from None
        sec = time.perf_counter() - t0
        record["stages"].append(
            {
                "name": name,
                "folder": str(folder),
                "seconds": sec,
                "input_hash": h,
                "skipped": False,
                "exit_code": code,
            }
        )
        _write_record(run.record_path, record)
        if code not in (0, 1):
            raise AnalysisError(f"stage {name} failed (exit code {code}); see {out}/log.txt")
        return code == 0

    def digest(folder: Path, *names) -> str:
        return "".join(_sha((folder / n).read_bytes()) for n in names if (folder / n).exists())

    base = "\n".join(json.dumps(a.table(t), sort_keys=True) for t in ("analysis", "fit"))
    base += json.dumps(run.data_hashes)
    # A user effect file is part of the model: a changed file reruns the fits.
    effect_files = sorted(
        {a.resolve(e).rpartition(":")[0] for e in a.table("fit").get("effects", []) if ".py:" in e}
    )
    record["effect_files"] = {f: _file_sha(f) for f in effect_files}
    base += json.dumps(record["effect_files"], sort_keys=True)
    fit_t = a.table("fit")
    fit_args: dict = {"model": an["config"], "data": list(data)}
    if val:
        fit_args["validate"] = list(val)
    if an.get("validate_alpha0"):
        fit_args["validate_alpha0"] = [str(v) for v in an["validate_alpha0"]]
    for k in ("free", "fixed", "channels"):
        if fit_t.get(k):
            fit_args[k] = ",".join(fit_t[k])
    if fit_t.get("max_nfev"):
        fit_args["max_nfev"] = fit_t["max_nfev"]
    if fit_t.get("jacobian"):
        fit_args["jacobian"] = fit_t["jacobian"]
    if fit_t.get("step") is not None:
        fit_args["step"] = float(fit_t["step"])
    if fit_t.get("keep_glitches"):
        fit_args["keep_glitches"] = True
    read = read_spec(a)
    if not read.is_default or read.counts_per_rev:
        # In the options' own forms, so the stage's command line reads as one to type.
        fit_args.update(
            columns=",".join(f"{k}={v}" for k, v in read.columns.items()) or None,
            time_unit=read.time_unit,
            angle_unit=read.angle_unit,
            counts_per_rev=",".join(f"{k}={v!r}" for k, v in read.counts_per_rev.items()) or None,
        )
    if fit_t.get("effects"):
        fit_args["add"] = [a.resolve(e) if ".py:" in e else e for e in fit_t["effects"]]
    first = out / "fit0"
    p0 = (
        {"p0": a.resolve(fit_t["p0"]) if not fit_t["p0"].startswith("thesis:") else fit_t["p0"]}
        if fit_t.get("p0")
        else {}
    )
    stage(
        "fit0", first, base, "fit", {**fit_args, **p0, "out": str(first), "force": True}, "fit.json"
    )
    fit = first
    dg = a.table("diagnose")
    added: list[str] = []
    rejected: list[dict] = []
    if "diagnose" in a.doc:
        noise = {"noise": float(dg["noise_std"])} if dg.get("noise_std") else {}
        tried = None  # (effect, worst RMS/floor before it, the fit before it): a candidate
        escaped = False  # refitted once from a better basin the trial refits found
        retry = None  # (the proposal, the effect dropped): tried from the fit before it
        for k in range(1, dg.get("max_steps", 3) + 2):
            if retry is None:  # (a retry goes on from a fit diagnosed already)
                stage(
                    f"diagnose{k - 1}",
                    fit,
                    digest(fit, "fit.json") + json.dumps(dg),
                    "diagnose",
                    {
                        "fit": str(fit),
                        **noise,
                        **({"trials": False} if dg.get("trials") is False else {}),
                        **({"proposal": False} if dg.get("proposal") is False else {}),
                    },
                    "diagnosis.json",
                )
            d = json.loads((fit / "diagnosis.json").read_text())
            worst = max(d["rms_over_floor"].values())
            if tried is not None:
                # A candidate (worth trying, not claimed) stays only if it lowered the error
                # materially; else the study goes on from the fit before it.
                eff0, before, prev, claimed0 = tried
                tried = None
                # ... and only if the validation runs do not get materially worse with it
                # (a cogging torque the catalogue lacks: upper_stribeck lowered the
                # estimation figure 449x -> 424x and raised the validation one 5695x ->
                # 6791x, and was kept).
                # A claimed effect answers to the validation runs alike (two pre-wound runs
                # with a motor torque sagging with speed: lower_asymmetric_viscous was
                # claimed, p 0.0069, took the validation run 9464x -> 10106x, and ended
                # the study as its final model).
                why = drop_reason(
                    before,
                    worst,
                    _validation_ratio(prev),
                    _validation_ratio(fit),
                    claimed=claimed0,
                )
                if why:
                    print(
                        f"\n{eff0} was {'claimed' if claimed0 else 'worth trying'} but "
                        f"{why}: dropped; the study goes on from {prev.name}/",
                        file=tee,
                    )
                    rejected.append(
                        {"effect": eff0, "before": before, "after": worst, "fit": str(fit)}
                    )
                    added.pop()
                    fit = prev
                    # The term the diagnosis proposed there, if it was not the one tried,
                    # gets its turn (a stiffening string: the claimed motor_deadzone was
                    # dropped and the study ended at 712x the floor, where the proposal
                    # printed beside it reached 0.93x).
                    alt = _proposal_spec(prev, json.loads((prev / "diagnosis.json").read_text()))
                    if alt and alt != eff0 and k <= dg.get("max_steps", 3):
                        retry = (alt, eff0)
                        continue
                    break
            # A trial that switched its effect off ended lower: the fit is in a local minimum
            # of the model as it is.  Refit the model from that basin once, then diagnose
            # again (two pre-wound runs, a motor torque sagging with speed: the study had
            # added three effects none of which is in the data).
            esc = (d.get("trials") or {}).get("escape")
            if (
                esc
                and retry is None
                and not escaped
                and not d["adequate"]
                and k <= dg.get("max_steps", 3)
            ):
                escaped = True
                from ...io.outputs import write_text_atomic

                at = out / "escape.json"
                write_text_atomic(at, json.dumps(esc["params"], indent=1))
                print(
                    f"\nthe trial refit with {esc['effect']} switched it off and ended at "
                    f"{esc['rms_over_floor']:.3g}x (from {worst:.3g}x): a better basin of the "
                    f"model as it is; refitting from there ({at.name})",
                    file=tee,
                )
                nxt = out / f"fit{k}"
                prev_doc = json.loads((fit / "fit.json").read_text())
                stage(
                    f"fit{k}",
                    nxt,
                    digest(fit, "fit.json", "diagnosis.json") + base,
                    "fit",
                    {
                        **fit_args,
                        "p0": str(at),
                        "add": list(prev_doc.get("added_effects") or fit_args.get("add", [])),
                        "out": str(nxt),
                        "force": True,
                    },
                    "fit.json",
                )
                fit = nxt
                continue
            # Far from the floor the trial refits decide (diagnose ran one per candidate).
            eff = d.get("refit_choice") or d.get("claimed_effect") or d.get("candidate_effect")
            # Where nothing is claimed and the diagnosis proposed a term of its own (it does
            # only when no catalogue effect's trial refit comes near the floor), that term
            # is tried first: a hidden cogging torque went 746x -> 0.864x with it, while the
            # trial refits' choice, lower_stribeck, stopped at 449x.
            proposed = _proposal_spec(fit, d)
            dropped = retry[1] if retry else None
            if proposed and (retry or not d.get("claimed_effect")):
                eff = proposed
            retry = None
            if d["adequate"] or not eff or not dg.get("add_effects", True):
                break
            if k > dg.get("max_steps", 3):
                print(
                    f"\nmax_steps = {dg.get('max_steps', 3)} reached; the model is still "
                    "inadequate",
                    file=tee,
                )
                break
            tried = (eff, worst, fit, eff == d.get("claimed_effect"))
            if eff != d.get("claimed_effect"):
                why = (
                    "the term the diagnosis proposed from the missing torque (proposal.py)"
                    if eff == proposed
                    else "its trial refit lowered the worst RMS/floor most"
                    if eff == d.get("refit_choice")
                    else "predicted to lower the worst RMS/floor materially"
                )
                lead = (
                    f"{dropped} was dropped"
                    if dropped
                    else "no effect claimed"
                    if not d.get("claimed_effect")
                    else "the trial refits overrule the claim"
                )
                print(f"\n{lead}; trying {eff}, {why} (kept only if it does)", file=tee)
            added.append(eff)
            nxt = out / f"fit{k}"
            stage(
                f"fit{k}",
                nxt,
                digest(fit, "fit.json", "diagnosis.json") + base,
                "fit",
                {
                    **fit_args,
                    "p0": str(fit),
                    "add": [*fit_args.get("add", []), eff],
                    **({"search": False} if fit_t.get("search") is False else {}),
                    "out": str(nxt),
                    "force": True,
                },
                "fit.json",
            )
            fit = nxt
        stage(
            "compare",
            out / "compare",
            digest(fit, "fit.json"),
            "compare",
            {"fits": [str(fit)], "out": str(out / "compare"), "force": True},
            "compare.json",
        )
    if "sample" in a.doc:
        s = a.table("sample")
        opts = {
            "source": str(fit),
            "out": str(out / "posterior"),
            "force": True,
            "walkers": s.get("walkers", 32),
            "steps": s.get("steps", 2000),
            "ensembles": s.get("ensembles", 2),
            "seed": seed,
            "noise": s.get("noise", "robust"),
        }
        if s.get("ar1"):
            opts["ar1"] = True
        if "moves" in s:
            opts["moves"] = s["moves"]
        if a.table("priors"):
            pri = out / "priors.toml"
            write_text_atomic(
                pri,
                "[priors]\n"
                + "".join(
                    f"{n} = {{ {', '.join(f'{k} = {json.dumps(v)}' for k, v in spec.items())} }}\n"
                    for n, spec in a.table("priors").items()
                ),
            )
            opts["priors"] = str(pri)
        if run.quiet:
            opts["quiet"] = True
        stage(
            "sample",
            out / "posterior",
            digest(fit, "fit.json") + json.dumps(s) + json.dumps(a.table("priors"), sort_keys=True),
            "sample",
            opts,
            "posterior.nc",
        )
    if "identify" in a.doc:
        i = a.table("identify")
        opts = {
            "fit": str(fit),
            "out": str(out / "identify"),
            "force": True,
            "points": i.get("points", 11),
        }
        if i.get("profiles"):
            opts["profiles"] = ",".join(i["profiles"])
        post = ""
        if "sample" in a.doc and (out / "posterior" / "posterior.nc").exists():
            opts["posterior"] = str(out / "posterior")
            post = digest(out / "posterior", "summary.csv")
        stage(
            "identify",
            out / "identify",
            digest(fit, "fit.json") + json.dumps(i) + post,
            "identify",
            opts,
            "identify.json",
        )
    if "design" in a.doc:
        d = a.table("design")
        opts = {"fit": str(fit), "out": str(out / "design"), "force": True, "seed": seed}
        for k in ("params", "separate"):
            if d.get(k):
                opts[k] = ",".join(d[k])
        for k in ("duration", "rate", "max_volts", "band_hz", "family", "starts", "max_evals"):
            if k in d:
                opts[k] = d[k]
        if not d.get("check", True):
            opts["no_check"] = True
        record["seeds"]["design"] = seed
        stage(
            "design",
            out / "design",
            digest(fit, "fit.json") + json.dumps(d, sort_keys=True) + json.dumps({"seed": seed}),
            "design",
            opts,
            "design.json",
        )
    record["added_effects"] = added
    record["rejected_effects"] = rejected
    record["final_fit"] = str(fit)
    record["finished"] = datetime.datetime.now().isoformat(timespec="seconds")
    _write_record(run.record_path, record)
    if a.table("report").get("html", True):
        try:
            from ...report.html import build_report
        except ImportError:
            print("\n(report: the HTML report module is not available in this version)", file=tee)
        else:
            with contextlib.redirect_stdout(tee):
                rp = build_report(out)
            record["report"] = str(rp)
            _write_record(run.record_path, record)
            print(f"\nreport: {rp}", file=tee)
    return record


def _write_record(path: Path, record: dict) -> None:
    write_text_atomic(path, json.dumps(record, indent=2))


__all__ = ["Analysis", "AnalysisError", "ParameterError", "load_analysis", "run"]


def _validation_ratio(fit: Path) -> float | None:
    """The fit's worst validation RMS/floor (fit.json), or None without validation data."""
    try:
        v = json.loads((fit / "fit.json").read_text())["assessment"][
            "worst_ratio_to_floor_validation"
        ]
    except (KeyError, OSError, TypeError, ValueError):
        return None
    return float(v) if isinstance(v, (int, float)) and math.isfinite(v) else None


def drop_reason(
    before: float, after: float, val_before, val_after, *, claimed: bool = False
) -> str:
    """Why an effect the study added is dropped again, or "" to keep it: one it only tried
    (worth trying, not claimed) must lower the worst RMS/floor on the estimation data
    materially (``before`` -> ``after``); any (``claimed`` too) must not raise the
    validation runs' materially (``val_before`` -> ``val_after``; None: no validation
    data), and far from the floor there (above :data:`TRIAL_ABOVE`) must lower it
    materially."""
    from ...diagnosis.diagnose import is_material
    from ...diagnosis.trials import TRIAL_ABOVE

    if not claimed and not is_material(before, after):
        return f"did not lower the worst RMS/floor materially ({before:.3g}x -> {after:.3g}x)"
    if val_before is None or val_after is None:
        return ""
    if is_material(val_after, val_before):
        return f"made the validation data materially worse ({val_before:.3g}x -> {val_after:.3g}x)"
    if val_before > TRIAL_ABOVE and not is_material(val_before, val_after):
        # Far from the floor any freedom lowers the estimation error a little; an effect
        # added there must lower the validation runs' too (a motor torque sagging with
        # speed: lower_asymmetric_viscous took the estimation run 2659x -> 2513x and the
        # validation run 9710x -> 10021x, and was kept; a motor that saturates:
        # upper_stribeck, claimed, took them 1120x -> 897x and 73009x -> 75330x, and
        # ended the study as its final model).
        return (
            f"did not lower the validation data's error materially ({val_before:.3g}x -> "
            f"{val_after:.3g}x)"
        )
    return ""


def _proposal_spec(fit: Path, d: dict) -> str | None:
    """``FILE.py:NAME`` of the term the diagnosis of ``fit`` proposed (its proposal.py in
    the fit folder), or None."""
    prop = d.get("proposal") or {}
    if not prop.get("proposed") or not prop.get("effect") or not prop.get("file"):
        return None
    path = fit / Path(prop["file"]).name
    name = str(prop["effect"]).rsplit(":", 1)[-1]  # "FILE.py:NAME" as the diagnosis wrote it
    return f"{path.resolve()}:{name}" if path.is_file() else None

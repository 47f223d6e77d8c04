"""What several commands share: their result, data and parameter sets given by name, the
executor of their parallel tasks, and strict JSON."""

from __future__ import annotations

import contextlib
import json
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..io.examples import example_path
from ..io.measurements import Experiment, load_experiment
from ..io.tomlfile import loads_json
from ..model import parameters as _params
from ..util import exitcodes as EXIT
from ..util.exitcodes import Refused


@dataclass
class Outcome:
    """What a command did.

    Attributes
    ----------
    exit_code : int
        The command's exit code (:mod:`rotorbayes.util.exitcodes`): 0 done, 1 ran but the fit
        did not converge.
    folder : Path or None
        The result folder the command wrote (the command line appends what it printed to
        its ``log.txt``); None when it wrote none or only single files.
    doc : dict or None
        The command's main document (e.g. the fit.json of ``fit``).
    """

    exit_code: int = EXIT.DONE
    folder: Path | None = None
    doc: dict | None = None


def data_path(name: str) -> str:
    """Resolve ``example:NAME`` to a bundled data file; other names are paths."""
    if name.startswith("example:"):
        return str(example_path(name))
    return name


def load_experiments(
    paths: Sequence[str], config: str, *, keep_glitches: bool = False, read=None
) -> list[Experiment]:
    """The measurement files (or ``example:NAME``), checked, their glitches left out
    (kept with ``keep_glitches``; :func:`rotorbayes.io.measurements.leave_out_glitches`), read as
    ``read`` says (:class:`~rotorbayes.io.rigfiles.ReadSpec`; a bundled example is always a
    plain CSV); a file whose header names another configuration gets a warning."""
    exps = []
    for p in paths:
        ex = load_experiment(
            data_path(p),
            expect_lower=config != "upper",
            keep_glitches=keep_glitches,
            read=None if p.startswith("example:") else read,
        )
        said = str((ex.meta or {}).get("config", "")).strip()
        if said in ("upper", "coupled", "brake") and said != config:
            print(
                f"warning: {p} says it holds {said}-configuration data (its header), but "
                f"--model is {config}; check --model",
                file=sys.stderr,
            )
        exps.append(ex)
    return exps


def say_glitches(estimation: Sequence[Experiment], validation: Sequence[Experiment] = ()) -> None:
    """Print the glitches found in the data (each named; left out or kept), if any."""
    from ..io.glitches import glitch_lines

    for line in glitch_lines(
        [("estimation", e) for e in estimation] + [("validation", e) for e in validation]
    ):
        print(line)


def glitch_record(estimation: Sequence[Experiment], validation: Sequence[Experiment] = ()) -> dict:
    """The glitches found in the data, for a result document (fit.json's ``"glitches"``)."""
    from ..io.glitches import glitch_record as record

    return record([("estimation", e) for e in estimation] + [("validation", e) for e in validation])


def fit_json(spec: str | None) -> dict | None:
    """The fit.json an argument points to (a file or a fit folder), else None."""
    if spec is None:
        return None
    p = Path(spec)
    if p.is_dir() and (p / "fit.json").exists():
        p = p / "fit.json"
    if p.suffix != ".json":
        return None
    try:
        return loads_json(p.read_text(), p, Refused, "fit.json")
    except Refused:
        raise
    except (OSError, ValueError) as exc:
        raise Refused(
            f"{p}: cannot read it ({exc}); give a fit.json written by "
            "`rotorbayes fit`, a TOML file or a named set"
        ) from None


def fit_effects(spec: str | None, config: str | None, trust: bool = False) -> list[str]:
    """The effects switched on in the fit a ``--p0``/``--params``/``--around`` value
    ``spec`` points to (a fit folder or its fit.json) -- catalogue names and user effect
    files, the files checked before any import
    (:func:`rotorbayes.inference.results.check_effect_files`:
    gone, changed or unrecorded files are refused unless ``trust``) -- when it is a fit of
    ``config``; empty for anything else (a named set, a TOML file, another configuration)."""
    doc = fit_json(spec)
    if doc is None or not isinstance(doc, dict) or doc.get("config") != config:
        return []
    from ..inference.results import check_effect_files

    where = Path(spec) / "fit.json" if Path(spec).is_dir() else Path(spec)
    return check_effect_files(doc, where, trust)


def param_spec(spec: str | None):
    """A ``--params``/``--p0`` value: named set, TOML file or a fit.json from an earlier fit
    (then its values, as a dict)."""
    if spec is None:
        return None
    if spec.endswith(".json"):
        from ..inference.results import ResultError, fit_values

        p = Path(spec)
        if p.is_dir():
            p = p / "fit.json"
        try:
            data = loads_json(p.read_text(), p, Refused, "fit.json")
        except Refused:
            raise
        except (OSError, ValueError) as exc:
            raise Refused(
                f"{p}: cannot read parameters from it ({exc}); give a fit.json "
                "written by `rotorbayes fit`, a TOML file or a named set"
            ) from None
        if isinstance(data, dict) and "params" not in data:
            data = {"params": data}  # a flat {name: value} mapping
        if not isinstance(data, dict):
            raise Refused(
                f"{p}: holds no parameter values (not a JSON object); give a "
                "fit.json written by `rotorbayes fit`, a TOML file or a named set"
            )
        # Every value checked (finite, inside its bounds): the message names the file, the
        # parameter and the value.
        try:
            values = fit_values(data, p)
        except ResultError as exc:
            raise Refused(str(exc)) from None
        return {k: v for k, v in values.items() if v is not None}
    if Path(spec).is_dir() and (Path(spec) / "fit.json").exists():
        return param_spec(str(Path(spec) / "fit.json"))
    if Path(spec).is_dir() and (Path(spec) / "multistart.json").exists():
        return _best_of_multistart(Path(spec) / "multistart.json")
    return spec


def _best_of_multistart(path: Path) -> dict[str, float]:
    """The end point of a multistart's best fit (smallest SSR) as parameter values: a
    multistart folder works as ``--p0``."""
    try:
        d = loads_json(path.read_text(), path, Refused, "multistart.json")
        ok = [
            i
            for i, (s, e) in enumerate(zip(d["ssr"], d["ends"], strict=True))
            if s is not None and math.isfinite(s) and e is not None
        ]
        if not ok:
            raise Refused(
                f"{path}: no start of this multistart ended in a fit; give another "
                "start (a fit folder, a TOML file or a named set)"
            )
        best = min(ok, key=lambda i: d["ssr"][i])
        return {n: float(v) for n, v in zip(d["names"], d["ends"][best], strict=True)}
    except Refused:
        raise
    except (OSError, KeyError, TypeError, ValueError) as exc:
        raise Refused(
            f"{path}: cannot read the best start from it ({exc}); give a fit "
            "folder, a TOML file or a named set"
        ) from None


def resolve_values(spec, model) -> dict[str, float]:
    """A complete value set for ``model`` from a named set, TOML file or fit.json."""
    raw = param_spec(spec)
    if isinstance(raw, dict):
        builtin = {k: v for k, v in raw.items() if k in _params.INFO}
        user = {k: v for k, v in raw.items() if k not in _params.INFO and k in model.info}
        out = _params.resolve(builtin, config=model.config)
        out.update(user)
        return out
    return _params.resolve(raw, config=model.config)


def run_values(spec: str | None) -> dict[str, float]:
    """The per-experiment values of an earlier fit (``{"alpha0[1]": -0.2}``, from a fit.json
    or fit folder's estimates): the next fit of the same experiments starts each one at its
    own value (fit.json's ``params`` holds only ``alpha0[0]`` as ``alpha0``).  Empty for a
    named set, a TOML file or a multistart folder."""
    doc = fit_json(spec)
    if doc is None:
        return {}
    out = {}
    est = doc.get("estimates")
    for n, e in est.items() if isinstance(est, dict) else ():
        v = e.get("value") if isinstance(e, dict) else None
        if (
            "[" in n
            and n.split("[")[0] in _params.INFO
            and isinstance(v, int | float)
            and not isinstance(v, bool)
            and math.isfinite(v)
        ):
            out[n] = float(v)
    return out


def csv_list(text: str | Sequence[str] | None, flag: str) -> list[str] | None:
    """Names given as ``"a,b"`` (the command line's form) or as a list; None stays None."""
    if text is None:
        return None
    if not isinstance(text, str):
        text = ",".join(text)
    items = [x.strip() for x in text.split(",") if x.strip()]
    if not items:
        raise Refused(f"{flag} needs a comma-separated list of names, got {text!r}")
    return items


def finite_or_none(o):
    """JSON cannot hold NaN or infinity: they become null."""
    if isinstance(o, dict):
        return {k: finite_or_none(v) for k, v in o.items()}
    if isinstance(o, list | tuple):
        return [finite_or_none(v) for v in o]
    if isinstance(o, np.ndarray):
        return finite_or_none(o.tolist())
    if isinstance(o, np.generic):
        o = o.item()
    if isinstance(o, float) and not math.isfinite(o):
        return None
    return o


def strict_json(doc) -> str:
    """``doc`` as strict JSON (no NaN/Infinity tokens)."""
    return json.dumps(finite_or_none(doc), indent=2, allow_nan=False)


def json_default(o):
    """``json.dumps``'s ``default`` for numpy scalars and arrays."""
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(type(o))


@contextlib.contextmanager
def executor(
    backend: str | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    *,
    file: dict | None = None,
):
    """Open the executor the options, DASK_SCHEDULER_ADDRESS or an analysis file's
    [parallel] table (``file``) choose, for the length of a command.  A command run inside
    ``run`` (a study stage) without options of its own uses the study's executor."""
    from ..inference import parallel

    opts = (backend, workers, scheduler)
    if parallel.current_executor() is not None and opts == (None, None, None):
        yield parallel.current_executor()
        return
    try:
        spec = parallel.choose(*opts, file=file)
    except ValueError as exc:
        raise Refused(str(exc)) from None
    with parallel.use_executor(spec, say=lambda line: print(line, flush=True)) as ex:
        # Said once the executor is there (a scheduler answered and has workers); the
        # default says itself which back-end it takes and why (on a small machine at the
        # first batch of tasks, whose size decides it).
        if not spec.auto:
            print(f"parallel tasks run {spec.describe()}", flush=True)
        yield ex

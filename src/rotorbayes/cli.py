"""The ``rotorbayes`` command line: simulate, fit, multistart, demo, params, effects.

A thin layer: it parses arguments, calls the library and prints; the knowledge lives in
:mod:`rotorbayes.model` and :mod:`rotorbayes.inference`.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

from . import exitcodes as EXIT
from .data import DataFileError, Experiment, load_experiment, save_experiment
from .examples import example_path
from .model import SimulationError
from .model import effects as _effects
from .model import parameters as _params
from .outputs import (
    InterruptGuard,
    OutputError,
    check_output_file,
    output_folder,
    save_figure_atomic,
    write_text_atomic,
)
from .results import ResultError

DESCRIPTION = (
    "Bayesian parameter inference for the TU Eindhoven drill-string rig. The loop: fit "
    "(a start from the data), compare and diagnose (is the error noise? which effect is "
    "missing?), fit --add EFFECT, sample and identify, report; or all of it from one "
    "analysis file with run, or on the bundled data with demo."
)


class CLIError(Exception):
    """A user error: printed without a traceback, exit code 2."""


def _out_dir(path: str, force: bool) -> Path:
    """An output folder that does not hold earlier results (unless ``--force``).

    Created at once; the commands use :func:`rotorbayes.outputs.output_folder` instead, which
    moves a finished folder into place only when the run succeeds.
    """
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise CLIError(f"--out {out}: is a file, not a folder; give a new folder name")
    if out.exists() and any(out.iterdir()) and not force:
        raise CLIError(f"{out}/ already holds results; choose another --out or pass --force "
                       "to overwrite them")
    out.mkdir(parents=True, exist_ok=True)
    return out


# ------------------------------------------------------------------ checked option values
#: Sampling rates a simulated measurement may have (Hz). Below 100 Hz the samples cannot
#: follow the rig: the inputs have content up to 5 Hz, the stick-slip switches of the lower
#: disc last milliseconds and the encoders' steps (1e-4 rad) are crossed many times per
#: sample; the thesis's rig is sampled at 1 kHz. Above 100 kHz no encoder of the rig is read.
MIN_RATE, MAX_RATE = 100.0, 1e5
#: Upper limits of sample's sizes: beyond them a run would not end or fit on a disk.
MAX_WALKERS, MAX_STEPS = 10_000, 10_000_000


def _number(text: str, kind=float) -> float:
    try:
        v = kind(text)
    except ValueError:
        what = "a whole number" if kind is int else "a number"
        raise argparse.ArgumentTypeError(f"{text!r} is not {what}") from None
    if kind is float and not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"{text!r}: give a finite number")
    return v


def _ranged(kind=float, *, gt: float | None = None, ge: float | None = None,
            le: float | None = None, why: str = ""):
    """An argparse ``type``: a finite number with ``> gt``, ``>= ge`` and ``<= le``; the
    message names the value given, the allowed range and ``why`` it is needed."""

    def parse(text: str):
        v = _number(text, kind)
        if (gt is not None and v <= gt) or (ge is not None and v < ge) or (
                le is not None and v > le):
            cond = " and ".join(c for c in (
                f"> {gt:g}" if gt is not None else "", f">= {ge:g}" if ge is not None else "",
                f"<= {le:g}" if le is not None else "") if c)
            what = "a whole number" if kind is int else "a number"
            raise argparse.ArgumentTypeError(f"got {text}; give {what} {cond}{why}")
        return v

    parse.__name__ = "number"  # argparse names the type in its own messages
    return parse


def _rate(text: str) -> float:
    v = _number(text)
    if v < MIN_RATE:
        raise argparse.ArgumentTypeError(
            f"got {text} Hz, too slow for the rig: the stick-slip switches of the lower disc "
            f"last milliseconds and the inputs have content up to 5 Hz, so the encoders must be "
            f"sampled at {MIN_RATE:g} Hz or more (the rig uses 1000 Hz, the default; the "
            "bundled examples 200 Hz); give --rate 100 or more")
    if v > MAX_RATE:
        raise argparse.ArgumentTypeError(
            f"got {text} Hz, faster than the rig's encoders are ever read ({MAX_RATE:g} Hz at "
            "most; it also makes huge files); give --rate between 100 and 100000")
    return v


class _Formatter(argparse.HelpFormatter):
    """Help that shows each option's default (unless it is None/False or already named)."""

    def _get_help_string(self, action):
        text = action.help or ""
        if ("%(default)" in text or "default" in text or action.default is None
                or action.default is False or action.default is argparse.SUPPRESS
                or not action.option_strings or not text):
            return text
        return f"{text} (default: %(default)s)"


class _Parser(argparse.ArgumentParser):
    """One-line usage errors: ``rotorbayes CMD: error: ...`` and exit code 2; help that
    shows the defaults (also for the subcommands, which are made with this class)."""

    def __init__(self, *args, **kw):
        kw.setdefault("formatter_class", _Formatter)
        super().__init__(*args, **kw)

    def add_argument(self, *args, **kw):
        # An option without help text would hide its default; give it one that shows it.
        default = kw.get("default")
        if (kw.get("help") is None and args and str(args[0]).startswith("-")
                and default is not None and default is not False):
            kw["help"] = "(default: %(default)s)"
        return super().add_argument(*args, **kw)

    def error(self, message):
        sys.stderr.write(f"{self.prog}: error: {message} (see `{self.prog} --help`)\n")
        sys.exit(2)


def _example_path(name: str) -> str:
    """Resolve ``example:NAME`` to a bundled data file."""
    if name.startswith("example:"):
        return str(example_path(name))
    return name


def _load(paths, config: str) -> list[Experiment]:
    exps = []
    for p in paths:
        ex = load_experiment(_example_path(p), expect_lower=config != "upper")
        said = str((ex.meta or {}).get("config", "")).strip()
        if said in ("upper", "coupled", "brake") and said != config:
            print(f"warning: {p} says it holds {said}-configuration data (its header), but "
                  f"--model is {config}; check --model", file=sys.stderr)
        exps.append(ex)
    return exps


def _read_input_file(path: str) -> tuple[np.ndarray, np.ndarray]:
    """Read ``t,u`` (and possibly more columns) from a CSV file.

    The time column gets the checks of a measurement file (:mod:`rotorbayes.data`): finite,
    strictly increasing, uniformly sampled, in seconds (a step of ``MAX_SAMPLE_INTERVAL``
    or more, or a record longer than ``MAX_DURATION``, is refused), and a last line without
    its line break (a truncated file) is refused; messages name the file and the line.
    """
    from .data import RowProblem, check_time_unit

    p = Path(path)
    try:
        with open(p, encoding="utf-8-sig", newline=None) as fh:
            lines = fh.read().split("\n")
    except FileNotFoundError:
        raise CLIError(f"--input-file {p}: file not found (looked in "
                       f"{p.resolve().parent}); check the path") from None
    except IsADirectoryError:
        raise CLIError(f"--input-file {p}: is a folder; give the CSV file inside it") from None
    except UnicodeDecodeError:
        raise CLIError(f"--input-file {p}: not a UTF-8 text file; export the input as "
                       "plain-text CSV with columns t,u") from None
    except OSError as exc:
        raise CLIError(f"--input-file {p}: cannot be read ({exc.strerror})") from None
    numbered = [(k, ln) for k, ln in enumerate(lines, start=1)
                if ln.strip() and not ln.lstrip().startswith("#")]
    if not numbered:
        raise CLIError(f"{p}: the file is empty; it needs a header 't,u' and rows of numbers")
    hline, htext = numbered[0]
    header = [h.strip() for h in htext.split(",")]
    if "t" not in header or "u" not in header:
        raise CLIError(f"{p}, line {hline}: the header {htext!r} must contain the columns t "
                       "and u (comma-separated)")
    it, iu = header.index("t"), header.index("u")
    # A complete file ends with a line break; without one the last number may be cut.
    if lines[-1].strip() and len(numbered) > 1 and not lines[-1].lstrip().startswith("#"):
        raise CLIError(f"{p}, line {len(lines)}: the last line {lines[-1].strip()[:80]!r} "
                       "does not end with a line break: the file looks truncated (cut while "
                       "being written or copied), so its last number may be incomplete; copy "
                       "the file again, or delete the last line (if it is complete, end it "
                       "with a line break)")
    t, u, rows = [], [], []
    for k, ln in numbered[1:]:
        f = ln.split(",")
        try:
            if len(f) != len(header):
                raise ValueError
            tk, uk = float(f[it]), float(f[iu])
        except ValueError:
            raise CLIError(f"{p}, line {k}: {ln.strip()!r} is not a row of {len(header)} numbers "
                           f"matching the header {htext.strip()!r}") from None
        t.append(tk)
        u.append(uk)
        rows.append(k)
    if len(t) < 3:
        raise CLIError(f"{p}: only {len(t)} data row(s); an input needs at least 3")
    t, u = np.array(t), np.array(u)
    for name, col in (("t", t), ("u", u)):
        bad = np.flatnonzero(~np.isfinite(col))
        if bad.size:
            raise CLIError(f"{p}, line {rows[bad[0]]}: {name} is {col[bad[0]]!r}; every value "
                           "must be a finite number")
    from .data import MAX_ABS_INPUT

    bad = np.flatnonzero(np.abs(u) > MAX_ABS_INPUT)
    if bad.size:
        raise CLIError(f"{p}, line {rows[bad[0]]}: u is {float(u[bad[0]])!r} V: no amplifier "
                       f"of the rig gives more than {MAX_ABS_INPUT:g} V; the value is corrupt "
                       "or not in volts -- repair the file")
    d = np.diff(t)
    bad = np.flatnonzero(d <= 0)
    if bad.size:
        raise CLIError(f"{p}, line {rows[bad[0] + 1]}: time {t[bad[0] + 1]!r} is not after "
                       f"{t[bad[0]]!r}; time must increase from row to row")
    try:
        check_time_unit(t, d)
    except RowProblem as exc:
        raise CLIError(f"{p}, line {rows[exc.row]}: {exc.problem}") from None
    step = float(np.median(d))
    dev = np.abs(d - step) / step
    bad = np.flatnonzero(dev > 1e-6)
    if bad.size:
        raise CLIError(f"{p}, line {rows[bad[0] + 1]}: time step {d[bad[0]]:.9g} s differs "
                       f"from the median step {step:.9g} s; time must be uniformly sampled -- "
                       "resample the input first")
    if not MIN_RATE <= 1.0 / step <= MAX_RATE:
        raise CLIError(f"{p}: sampled at {1.0 / step:.6g} Hz (step {step:.6g} s); simulate "
                       f"needs {MIN_RATE:g} Hz to {MAX_RATE:g} Hz (the rig's encoders are read "
                       "at 1 kHz); resample the input")
    return t - t[0], u


def _fit_json(spec: str | None) -> dict | None:
    """The fit.json an argument points to (a file or a fit folder), else None."""
    if spec is None:
        return None
    p = Path(spec)
    if p.is_dir() and (p / "fit.json").exists():
        p = p / "fit.json"
    if p.suffix != ".json":
        return None
    try:
        return json.loads(p.read_text())
    except (OSError, ValueError) as exc:
        raise CLIError(f"{p}: cannot read it ({exc}); give a fit.json written by "
                       "`rotorbayes fit`, a TOML file or a named set") from None


def _param_spec(spec: str | None):
    """A ``--params``/``--p0`` value: named set, TOML file or a fit.json from an earlier fit."""
    if spec is None:
        return None
    if spec.endswith(".json"):
        p = Path(spec)
        if p.is_dir():
            p = p / "fit.json"
        try:
            data = json.loads(p.read_text())
            if isinstance(data, dict) and "params" not in data:
                data = {"params": data}  # a flat {name: value} mapping
            return {k: float(v) for k, v in data["params"].items() if v is not None and not (
                isinstance(v, float) and math.isnan(v))}
        except (OSError, KeyError, ValueError) as exc:
            raise CLIError(f"{p}: cannot read parameters from it ({exc}); give a fit.json "
                           "written by `rotorbayes fit`, a TOML file or a named set") from None
    if Path(spec).is_dir() and (Path(spec) / "fit.json").exists():
        return _param_spec(str(Path(spec) / "fit.json"))
    return spec


# ------------------------------------------------------------------------------- simulate
def _plot_format(path: Path) -> None:
    """Refuse a figure file name whose format matplotlib cannot write."""
    from matplotlib.backend_bases import FigureCanvasBase

    kinds = FigureCanvasBase.get_supported_filetypes()
    ext = path.suffix[1:].lower()
    if ext and ext not in kinds:
        raise CLIError(f"--plot {path}: cannot write a .{ext} figure; use one of "
                       f"{', '.join('.' + k for k in sorted(kinds))} (e.g. --plot "
                       f"{path.with_suffix('.png')})")


def cmd_simulate(a) -> int:
    from .model import Model, simulate
    from .outputs import tmp_name
    from .signals import make_signal

    # Everything the user can get wrong is checked before the simulation.
    if a.input_file:
        ignored = [flag for flag, v in (("--duration", a.duration), ("--rate", a.rate),
                                        ("--input", a.input)) if v is not None]
        if ignored:
            raise CLIError(
                f"--input-file {a.input_file} gives the input, its duration and its sampling "
                f"rate (the t column), so {' and '.join(ignored)} would be ignored; leave "
                f"{'it' if len(ignored) == 1 else 'them'} out (resample the file to change the "
                "rate)")
    out = check_output_file(a.out, flag="--out", force=a.force, example="sim.csv")
    plot = None
    if a.plot:
        plot = check_output_file(a.plot, flag="--plot", force=a.force, example="sim.png")
        _plot_format(plot)
        if plot.resolve() == out.resolve():
            raise CLIError(f"--plot {plot} is the --out file; give the figure another name")
    model = Model(a.model, a.add or ())
    try:
        params = _resolve_values(a.params, model)
    except _params.ParameterError as exc:
        raise CLIError(f"--params {a.params}: {exc}" if a.params and str(a.params) not in
                       str(exc) else str(exc)) from None
    if a.input_file:
        t, u = _read_input_file(a.input_file)
        source = a.input_file
    else:
        a.input = a.input or "est"
        a.duration = 30.0 if a.duration is None else a.duration
        a.rate = 1000.0 if a.rate is None else a.rate
        t, u = make_signal(a.input, a.duration, rate=a.rate, seed=a.seed)
        source = f"{a.input} seed={a.seed}"
    dt = float(t[1] - t[0])
    t0 = time.perf_counter()
    try:
        sim = simulate(params, u, dt=dt, config=a.model, alpha0=a.alpha0,
                       effects=a.add or (), quantize_angles=a.quantize,
                       noise_std=a.noise, seed=a.seed)
    except SimulationError as exc:
        where = f"the values of --params {a.params}" if a.params else "these parameter values"
        raise CLIError(f"{exc} ({where}); change the value named") from None
    el = time.perf_counter() - t0
    # The header records everything needed to make the file again.
    meta = {"source": "rotorbayes simulate (synthetic)", "config": a.model,
            "input": source, "rate_hz": f"{1 / dt:.10g}", "duration_s": f"{t[-1]:.10g}",
            "params": a.params or f"default ({_params.DEFAULT_SET[a.model]})",
            "effects": ", ".join(model.effect_names) or "none",
            "added_effects": ", ".join(a.add or ()) or "none",
            "alpha0": sim.params["alpha0"], "quantized": a.quantize, "noise_std": a.noise,
            "seed": a.seed}
    meta.update({f"param.{n}": repr(float(v)) for n, v in sim.params.items()})
    fig_tmp = None
    try:
        if plot is not None:
            import matplotlib.pyplot as plt

            from .plots import plot_simulation

            fig, _ = plot_simulation(sim)
            fig_tmp = tmp_name(plot)
            fig.savefig(fig_tmp, dpi=110, format=plot.suffix[1:] or None)
            plt.close(fig)
        save_experiment(sim.to_experiment(), out, overwrite=a.force, meta=meta)
        if fig_tmp is not None:
            os.replace(fig_tmp, plot)
    except FileExistsError:
        raise
    except OSError as exc:
        target = plot if fig_tmp is not None and out.exists() else out
        raise CLIError(f"cannot write {target} ({exc.strerror or exc}); check that its folder "
                       "is writable and has space, or choose another path") from None
    finally:
        if fig_tmp is not None and fig_tmp.exists():
            fig_tmp.unlink()
    n_stick = int(np.sum(sim.events[:, 2] == 0)) if sim.events.size else 0
    print(f"simulated {a.model} configuration, {sim.t[-1]:.1f} s at {1 / dt:.0f} Hz in "
          f"{1e3 * el:.1f} ms; {len(sim.events)} stick/slip switches ({n_stick} stick onsets)")
    if sim.theta_l is not None:
        print(f"lower disc sticks {100 * sim.stick_fraction('l'):.1f} % of the time; "
              f"string torsion {sim.alpha.min():.3f} .. {sim.alpha.max():.3f} rad")
    print(f"wrote {out}")
    if plot is not None:
        print(f"wrote {plot}")
    return 0


# ------------------------------------------------------------------------------------ fit
def _csv_list(text: str | None, flag: str) -> list[str] | None:
    if text is None:
        return None
    items = [x.strip() for x in text.split(",") if x.strip()]
    if not items:
        raise CLIError(f"{flag} needs a comma-separated list of names, got {text!r}")
    return items


def _model_from_args(a, n_experiments: int):
    """The model: configuration, base effects minus --without, effects inherited from a
    --p0 fit.json, plus --add."""
    from .model import Model

    added = list(a.add or [])
    inherited: list[str] = []
    doc = _fit_json(getattr(a, "p0", None))
    if doc is not None and doc.get("config") == a.model:
        from .results import check_effect_files

        where = Path(a.p0) / "fit.json" if Path(a.p0).is_dir() else Path(a.p0)
        specs = check_effect_files(doc, where, getattr(a, "trust_effects", False))
        inherited = [e for e in specs if e not in added]
    if (n_experiments > 1 and a.model != "upper" and "initial_torsion" not in added
            and "initial_torsion" not in inherited):
        added.append("initial_torsion")
    model = Model(a.model, [*inherited, *added], without=a.without or (),
                  prescribed_upper=a.prescribed_upper)
    if inherited:
        print(f"effects carried over from {a.p0}: {', '.join(inherited)}")
    return model, added


def _problem_from_args(a, exps, start_spec=None):
    """The estimation problem of the fit/multistart arguments.

    ``--add`` frees the effect's parameters, also when ``--free`` is given.
    """
    from .inference import Problem

    model, added = _model_from_args(a, len(exps))
    free = _csv_list(a.free, "--free")
    fixed = _csv_list(a.fixed, "--fixed") or []
    # Chaining the thesis's steps: a start from an upper-configuration fit fixes the motor
    # and upper-disc parameters it estimated (unless --free says otherwise).
    from_upper: dict[str, float] = {}
    doc = _fit_json(getattr(a, "p0", None))
    if doc is not None and doc.get("config") == "upper" and a.model != "upper" and free is None:
        est = doc.get("estimates", {})
        from_upper = {n: v["value"] for n, v in est.items() if n in model.active}
        fixed += [n for n in from_upper if n not in fixed]
    if free is not None:
        clash = [n for n in fixed if n in free]
        if clash:
            raise CLIError(f"{', '.join(clash)} is both --fixed and --free; remove it from one")
        for e in _effects.resolve(added):
            free += [p for p in e.names if p not in free and p not in fixed]
    for n in fixed:
        if n.split("[")[0] not in model.info:
            raise CLIError("--fixed: " + _params.unknown_name_message(n))
    base_spec = a.base or start_spec
    base = _resolve_values(base_spec, model) if base_spec else None
    channels = tuple(_csv_list(a.channels, "--channels")) if a.channels else None
    weights = _parse_weights(a.weights, a.model, channels, a.prescribed_upper) \
        if a.weights is not None else None
    prob = Problem(model, exps, free=free, base=base, channels=channels, weights=weights,
                   fixed=fixed)
    return prob, from_upper


def _parse_weights(text: str, config: str, channels, prescribed_upper: bool) -> dict:
    """``--weights theta_l=1,theta_u=0.1``: channel names and positive finite weights."""
    if config == "upper":
        valid = ("theta_u",)
    elif prescribed_upper:
        valid = ("theta_l",)
    else:
        valid = ("theta_u", "theta_l")
    if channels:
        valid = tuple(c for c in valid if c in channels) or valid
    example = ",".join(f"{c}={w}" for c, w in zip(valid, ("1", "0.1"), strict=False))
    form = (f"write CHANNEL=WEIGHT pairs separated by commas, e.g. --weights {example} "
            f"(channels of this fit: {', '.join(valid)})")
    weights: dict[str, float] = {}
    items = [x.strip() for x in text.split(",")]
    if not any(items):
        raise CLIError(f"--weights {text!r} is empty; {form}")
    for item in items:
        if not item:
            raise CLIError(f"--weights {text!r}: an empty entry (two commas?); {form}")
        name, eq, value = item.partition("=")
        name, value = name.strip(), value.strip()
        if not eq:
            sep = next((c for c in ":; " if c in item), None)
            hint = f"use '=' instead of {sep!r}; " if sep else ""
            raise CLIError(f"--weights: {item!r} has no '='; {hint}{form}")
        if name not in valid:
            what = ("not a channel of this fit" if name in ("theta_u", "theta_l", "alpha")
                    else "an unknown channel")
            raise CLIError(f"--weights: {name!r} is {what}; {form}")
        if name in weights:
            raise CLIError(f"--weights: {name} is given twice; give each channel once")
        try:
            w = float(value)
        except ValueError:
            raise CLIError(f"--weights: the weight {value!r} of {name} is not a number; "
                           f"{form}") from None
        if not (math.isfinite(w) and w > 0):
            raise CLIError(f"--weights: the weight of {name} is {value}; it must be a finite "
                           "number > 0 (a channel you do not want to fit is left out with "
                           "--channels instead)")
        weights[name] = w
    return weights


def _resolve_values(spec, model) -> dict[str, float]:
    """A complete value set for ``model`` from a named set, TOML file or fit.json."""
    raw = _param_spec(spec)
    if isinstance(raw, dict):
        builtin = {k: v for k, v in raw.items() if k in _params.INFO}
        user = {k: v for k, v in raw.items() if k not in _params.INFO and k in model.info}
        out = _params.resolve(builtin, config=model.config)
        out.update(user)
        return out
    return _params.resolve(raw, config=model.config)


def _fmt_params(prob, names, x, se=None, x0=None, at_bound=()) -> str:
    rows = [f"{'parameter':<12} {'estimate':>12} {'std. error':>12} {'start':>12}  unit"]
    for i, n in enumerate(names):
        if n in at_bound:
            s = f"{'AT BOUND':>12}"
        else:
            s = f"{se[i]:12.4g}" if se is not None and np.isfinite(se[i]) else f"{'—':>12}"
        st = f"{x0[i]:12.5g}" if x0 is not None else ""
        rows.append(f"{n:<12} {x[i]:12.5g} {s} {st}  {prob.info(n).unit}")
    return "\n".join(rows)


def _uncertainty_words(res) -> str:
    """What the standard errors mean, in a few lines (inference.uncertainty)."""
    u = res.uncertainty
    infl = u.inflation()
    ok = np.isfinite(infl)
    lines = ["std. errors: honest — rounding to encoder counts simulated as it is, model "
             "error from the residuals' time blocks, an allowance for the input between "
             "samples"]
    if ok.any():
        j = int(np.nanargmax(np.where(ok, infl, -np.inf)))
        lines.append(
            f"  they are {np.median(infl[ok]):.2g}x (median; {u.names[j]} {infl[j]:.2g}x) the "
            f"ones independent noise at the floor would give; the rounding alone leaves "
            f"the information of about {u.n_eff:.3g} independent samples of {u.n_samples}")
    sh = u.shares()
    tot = {k: np.nanmean([v[k] for v in sh.values()]) for k in ("noise", "model_error",
                                                                   "input_hold")}
    lines.append(f"  variance, mean over parameters: noise {100 * tot['noise']:.0f} %, model "
                 f"error {100 * tot['model_error']:.0f} %, input between samples "
                 f"{100 * tot['input_hold']:.0f} %")
    if u.warning():
        lines.append("  warning: " + u.warning())
    return "\n".join(lines)


def _quality_table(rows, label: str) -> str:
    from .metrics import ChannelFit, fit_table

    out = []
    for r in rows:
        fits = [ChannelFit(**{k: v for k, v in c.items() if k in ChannelFit.__dataclass_fields__})
                for c in r["channels"].values()]
        out.append(fit_table(fits, title=f"{label}: {r['experiment']}"))
    return "\n\n".join(out)


def _sources(a, prob, fixed_from_upper: dict) -> dict[str, str]:
    """Where the value of every parameter that is not estimated came from."""
    default = _params.DEFAULT_SET[a.model]
    src = {}
    for n in prob.model.active:
        if n == "J_u":
            src[n] = "eq. 5.4 (disc geometry)" if not (a.base or a.p0) else None
        src[n] = src.get(n) or (
            f"upper-disc fit {a.p0}" if n in fixed_from_upper
            else f"--base {a.base}" if a.base
            else f"--p0 {a.p0}" if a.p0
            else f"default set {default}"
        )
    return src


def run_fit(a, out: Path, guard=None) -> dict:  # noqa: C901 - one linear report
    """Fit, print and write fit.json + figures; returns the JSON document.

    ``guard`` (an :class:`~rotorbayes.outputs.InterruptGuard`) is started once the fit has
    finished: a Ctrl-C after that keeps the result.
    """
    from . import inference as E
    from .plots import plot_fit, plot_friction
    from .results import data_record

    exps = _load(a.data, a.model)
    val = _load(a.validate, a.model) if a.validate else []
    # The start set also fixes the values of the parameters that are not estimated.
    prob, fixed_from_upper = _problem_from_args(a, exps, start_spec=a.p0)
    sources = _sources(a, prob, fixed_from_upper)
    print(f"model: {a.model} configuration with "
          f"{', '.join(prob.model.effect_names) or 'no effects'}")
    print(f"fitting {len(prob.names)} parameters ({', '.join(prob.names)}) of the {a.model} "
          f"configuration to {len(exps)} experiment(s), channels {', '.join(prob.channels)}")
    if fixed_from_upper:
        print(f"fixed from the upper-disc fit {a.p0}: {', '.join(fixed_from_upper)}")
    fit_kw = dict(max_nfev=a.max_nfev, ftol=a.ftol, xtol=a.xtol, gtol=a.gtol)
    start_source: dict[str, str] = {}
    if a.p0 and not fixed_from_upper:
        start = dict(prob.base)
        if a.base:
            start.update(_resolve_values(a.p0, prob.model))
        x0 = prob.start_vector(start)
        # A parameter the --p0 fit did not have (its effect was off there, or it is a user
        # effect's) starts at its effect's default, not at a value of that fit.
        p0_params = (_fit_json(a.p0) or {}).get("parameters") or {}
        start_source = {n: f"--p0 {a.p0}" if not p0_params or (
            (p0_params.get(n) or {"status": "off"}).get("status") != "off")
            else "the effect's default" for n in prob.names}
        from .results import diagnosis_starts

        added_names = [e.name for e in prob.model.added]
        for n, v in diagnosis_starts(a.p0, added_names).items():
            if n in prob.names:
                j = prob.names.index(n)
                if prob.lower[j] < v < prob.upper[j]:
                    x0[j] = v
                    start_source[n] = "the diagnosis of the --p0 fit (one-step estimate)"
        if prob.model.added:
            print("start of the added effects' parameters: " + ", ".join(
                f"{n} = {x0[prob.names.index(n)]:.4g} ({start_source[n]})"
                for e in prob.model.added for n in e.names if n in prob.names))
        print(f"start: --p0 {a.p0}")
        res = E.fit(prob, x0, verbose=True, **fit_kw)
        chose = f"--p0 {a.p0}"
    else:
        print("start: computed from the data (the equations of motion as a regression on "
              "smoothed derivatives of the measured angles; give --p0 to choose one)")
        ff = E.fit_from_data(prob, restarts=a.restarts, verbose=True, **fit_kw)
        res, chose = ff.result, ff.chose
        start_source = {n: ff.start.source.get(n, ff.start.source.get(
            E.local_name(n)[0], "")) for n in prob.names}
        if ff.restarts:
            print(f"{len(ff.restarts)} restarts tried; kept {ff.chose}")
    if guard is not None:
        guard.start()  # the work is done: from here on Ctrl-C must not throw it away
    status = "" if res.success else "DID NOT CONVERGE: "
    print(f"\n{status}{res.message} ({res.nfev} evaluations, {res.njev} Jacobians, "
          f"{res.seconds:.1f} s)\n")
    q_est = E.quality(prob, res.x)
    q_val = E.quality(prob, res.x, val) if val else []
    assessment = E.assess(res, q_est, q_val, sources=sources)
    print(_fmt_params(prob, res.names, res.x, res.stderr, res.x0, assessment.at_bound))
    if res.uncertainty is not None:
        print(_uncertainty_words(res))
    print()
    print(_quality_table(q_est, "estimation data"))
    if q_val:
        print()
        print(_quality_table(q_val, "validation data"))
    print("\nresidual RMS against the encoder quantisation floor (resolution/sqrt(12)):")
    print(assessment.table())
    print(f"verdict: {assessment.verdict}")
    w, V = res.sloppy_directions()
    sloppy = {n: float(c) for n, c in zip(res.names, V[:, 0], strict=True)}
    ratio = float(w[-1] / max(w[0], 1e-300))
    # Only positive parameters: a common scaling "in log scale" means nothing for signed ones.
    positive = {n for n, v, lo in zip(res.names, res.x, prob.lower, strict=True)
                if v > 0 and lo >= 0}
    movers = [n for n, c in sloppy.items() if abs(c) > 0.3 and n in positive]
    if len(movers) >= 2 and ratio > 1e4:
        print(f"\nIdentifiability: the least-determined direction (Fisher eigenvalue ratio "
              f"{ratio:.1e}) moves {', '.join(movers)} together "
              f"({', '.join(f'{n} {sloppy[n]:+.2f}' for n in movers)} in log scale); the data "
              "fix their ratios far better than their values.")
    free_base = {E.local_name(n)[0] for n in res.names}
    parameters = {}
    for n in prob.model.info:
        if n in free_base:
            continue
        on = n in prob.model.active
        parameters[n] = {
            "value": prob.base.get(n) if on else prob.model.info[n].null,
            "unit": prob.model.info[n].unit,
            "status": "fixed" if on else "off",
            "source": sources.get(n) if on else
            f"effect {getattr(_effects.effect_of(n), 'name', '?')} is off",
        }
    for i, n in enumerate(res.names):
        parameters[n] = {
            "value": float(res.x[i]), "unit": prob.info(n).unit, "status": "free",
            "stderr": float(res.stderr[i]), "start": float(res.x0[i]),
            "source": "estimated", "start_source": start_source.get(n, ""),
            "at_bound": n in assessment.at_bound,
        }
    doc = {
        "config": a.model, "effects": list(prob.effects),
        "added_effects": [e.name if e.source == "catalogue" else f"{e.source}:{e.name}"
                          for e in prob.model.added],
        "channels": list(prob.channels),
        # Absolute paths (a fit folder works from any working folder), paths relative to the
        # fit folder (a project moved whole) and hashes; effect files' hashes (they are code).
        "data": [str(Path(e.path).absolute()) for e in exps],
        "validation": [str(Path(e.path).absolute()) for e in val],
        "data_files": data_record([e.path for e in exps], Path(a.out)),
        "validation_files": data_record([e.path for e in val], Path(a.out)),
        "effect_files": {e.source: _effects.file_sha256(e.source) for e in prob.model.added
                         if e.source != "catalogue"},
        "success": res.success, "message": res.message, "nfev": res.nfev,
        "seconds": res.seconds, "ssr": res.ssr, "n_residuals": res.n_residuals,
        "start": chose,
        "free": list(res.names),
        "prescribed_upper": bool(prob.prescribed_upper),
        "weights": dict(prob.weights),
        "parent": _parent_of(a.p0),
        "assessment": assessment.as_dict(),
        "parameters": parameters,
        "estimates": {n: {"value": float(v), "stderr": float(s), "stderr_iid": float(si),
                          "start": float(s0), "unit": prob.info(n).unit}
                      for n, v, s, si, s0 in zip(res.names, res.x, res.stderr, res.stderr_iid,
                                                 res.x0, strict=True)},
        "uncertainty": res.uncertainty.as_dict() if res.uncertainty is not None else None,
        "params": res.params,
        "quality": {"estimation": [{k: v for k, v in r.items() if k != "simulation"}
                                   for r in q_est],
                    "validation": [{k: v for k, v in r.items() if k != "simulation"}
                                   for r in q_val]},
        "fisher": {"eigenvalues_log": [float(v) for v in w], "sloppiest_direction": sloppy},
        "correlation": res.correlation().tolist(),
    }
    (out / "fit.json").write_text(strict_json(doc))
    for label, rows, exs in (("est", q_est, exps), ("val", q_val, val)):
        for i, (r, ex) in enumerate(zip(rows, exs, strict=True)):
            s = r["simulation"]
            meas, simd, txt = {}, {}, {}
            for c, st in r["channels"].items():
                simc = {"theta_u": s.theta_u, "theta_l": s.theta_l, "alpha": s.alpha}[c]
                measc = {"theta_u": ex.theta_u, "theta_l": ex.theta_l,
                         "alpha": None if ex.theta_l is None else
                         ex.theta_l - ex.theta_u + s.params["alpha0"]}[c]
                meas[c], simd[c] = measc, simc
                txt[c] = (f"R² {st['r2']:.4f}, fit {st['nrmse_fit']:.2f} %, "
                          f"max |e| {st['max_abs_error']:.3g} rad")
            fig, _ = plot_fit(ex.t, meas, simd, mode=s.mode_l, metrics=txt,
                              title=f"{a.model}: {label} data {Path(str(ex.path)).name}")
            save_figure_atomic(fig, out / f"fit_{label}_{i}.png")
    shape_discs = ("u",) if a.model == "upper" else ("u", "l")
    fig, _ = plot_friction(res.params, discs=shape_discs, shape=prob.shape,
                           title=f"fitted friction, {a.model} configuration")
    save_figure_atomic(fig, out / "friction.png")
    print(f"\nwrote {Path(a.out) / 'fit.json'} and figures in {a.out}/")
    for wtxt in assessment.warnings:
        print(f"warning: {wtxt}", file=sys.stderr)
    return doc


def _parent_of(p0: str | None) -> str | None:
    """The fit folder a --p0 fit.json belongs to (the chain of fits), else None."""
    if not p0:
        return None
    p = Path(p0)
    if p.is_dir() and (p / "fit.json").exists():
        return str(p.resolve())
    if p.name == "fit.json" and p.exists():
        return str(p.parent.resolve())
    return None


def _finite_or_none(o):
    """JSON cannot hold NaN or infinity: they become null."""
    if isinstance(o, dict):
        return {k: _finite_or_none(v) for k, v in o.items()}
    if isinstance(o, list | tuple):
        return [_finite_or_none(v) for v in o]
    if isinstance(o, np.ndarray):
        return _finite_or_none(o.tolist())
    if isinstance(o, np.generic):
        o = o.item()
    if isinstance(o, float) and not math.isfinite(o):
        return None
    return o


def strict_json(doc) -> str:
    """``doc`` as strict JSON (no NaN/Infinity tokens)."""
    return json.dumps(_finite_or_none(doc), indent=2, allow_nan=False)


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(type(o))


class Interrupted(Exception):
    """Ctrl-C, reported in one message (what was kept, how to continue); exit code 130."""


def _fit_interrupted(exc: KeyboardInterrupt, out: str) -> Interrupted:
    """The message for Ctrl-C during a fit: nothing written, the best point so far."""
    from .inference.least_squares import FitInterrupted

    text = f"interrupted (Ctrl-C); nothing was written to {out}/"
    if isinstance(exc, FitInterrupted):
        vals = "\n".join(f"{n} = {float(v)!r}" for n, v in zip(exc.names, exc.x, strict=True)
                         if "[" not in n)
        text += (f". The best point after {exc.nfev} evaluations (SSR {exc.ssr:.6g} rad²) "
                 f"was:\n{vals}\nTo continue from it, save these lines in a file such as "
                 "best.toml and run the fit again with --p0 best.toml")
    else:
        text += " (no fit evaluation had finished yet)"
    return Interrupted(text)


def cmd_fit(a) -> int:
    guard = InterruptGuard()
    try:
        with output_folder(a.out, a.force) as out:
            doc = run_fit(a, out, guard)
    except KeyboardInterrupt as exc:
        raise _fit_interrupted(exc, a.out) from None
    except SimulationError as exc:
        from .inference import StartError

        if isinstance(exc, StartError) and a.p0 and a.p0 not in str(exc):
            raise CLIError(f"--p0 {a.p0}: {exc}") from None
        raise
    finally:
        guard.stop()
    if guard.hit:
        raise Interrupted(f"interrupted (Ctrl-C) after the fit had finished; its results were "
                          f"kept, complete, in {a.out}/ (fit.json and the figures)")
    return EXIT.DONE if doc["success"] else EXIT.NOT_CONVERGED


def cmd_multistart(a) -> int:
    from . import inference as E
    from .inference.taskstore import remove_store, store_path
    from .plots import plot_parameter_spread, plot_waterfall, quantisation_floor_ssr

    guard = InterruptGuard()
    with guard, output_folder(a.out, a.force) as out:
        exps = _load(a.data, a.model)
        prob, _ = _problem_from_args(a, exps)
        around = None
        if a.around:
            around = _params.resolve(_param_spec(a.around), config=a.model)
        how = (f"log-normal spread {a.spread:.2f} around {a.around}" if around
               else "Latin hypercube over the bounds")
        print(f"multistart: {a.starts} fits of {', '.join(prob.names)} ({how})")
        with _executor(a) as ex:
            # Each finished start is kept beside --out: a re-run after a kill skips it.
            ms = E.multistart(prob, a.starts, seed=a.seed, around=around, spread=a.spread,
                              executor=ex, max_nfev=a.max_nfev, ftol=a.ftol, xtol=a.xtol,
                              gtol=a.gtol, resume=store_path(a.out))
        guard.start()  # the starts are done: from here on Ctrl-C must not throw them away
        n_done = int(ms.ssr.size) + len(ms.failed)
        if ms.interrupted and n_done == 0:
            raise Interrupted(f"interrupted (Ctrl-C) before any start had finished; nothing "
                              f"was written to {a.out}/")
        order = np.argsort(ms.ssr)
        print("\nbest end points:")
        print(" rank  cluster        SSR   " + " ".join(f"{n:>10}" for n in ms.names))
        for r, i in enumerate(order[: min(10, len(order))]):
            print(f" {r + 1:4d}  {ms.clusters[i]:7d}  {ms.ssr[i]:9.4g}   "
                  + " ".join(f"{v:10.4g}" for v in ms.ends[i]))
        summary = ms.summary()
        print("\n" + summary)
        doc = {"config": a.model, "names": ms.names, "starts": ms.starts, "ends": ms.ends,
               "ssr": ms.ssr, "success": ms.success, "clusters": ms.clusters,
               "summary": summary, "data": [str(e.path) for e in exps],
               "n_requested": a.starts, "n_finished": n_done, "interrupted": ms.interrupted,
               "start_index": ms.start_index, "failed": {str(k): v for k, v in
                                                         ms.failed.items()}}
        (out / "multistart.json").write_text(json.dumps(doc, indent=2, default=_json_default))
        written = ["multistart.json"]
        if ms.ssr.size:
            floor = quantisation_floor_ssr(prob)
            fig, _ = plot_waterfall(ms.ssr, labels=ms.clusters, n_failed=len(ms.failed),
                                    noise_floor_ssr=floor,
                                    title=f"multistart, {a.model}: sorted final SSR")
            save_figure_atomic(fig, out / "waterfall.png")
            fig, _ = plot_parameter_spread(
                ms.names, ms.ends, ms.ssr, clusters=ms.clusters, noise_floor_ssr=floor,
                units={n: prob.info(n).unit for n in ms.names},
                title=f"multistart, {a.model}: end points")
            save_figure_atomic(fig, out / "parameter_spread.png")
            written += ["waterfall.png", "parameter_spread.png"]
        (out / "summary.txt").write_text(summary + "\n")
        written.append("summary.txt")
    print(f"\nwrote {a.out}/: {', '.join(written)}")
    if not ms.interrupted:
        remove_store(a.out)  # the result is complete: nothing left to resume
    if ms.interrupted:
        rest = a.starts - n_done
        raise Interrupted(
            f"interrupted (Ctrl-C) after {n_done} of {a.starts} starts; the finished ones are in "
            f"{a.out}/ (multistart.json, summary.txt). For the other {rest}, run again with "
            f"--starts {rest} --seed {a.seed + 1} and another --out (a new seed gives new "
            "starts), or repeat the whole command with --force")
    if guard.hit:
        raise Interrupted(f"interrupted (Ctrl-C) after all {n_done} starts had finished; the "
                          f"results were kept, complete, in {a.out}/")
    return 0


def cmd_demo(a) -> int:
    """The whole story on the bundled hidden-effect data (the bundled analysis file)."""
    from importlib.resources import files

    from .study import run

    path = files("rotorbayes") / "data" / "demo.toml"
    out = Path(a.out)
    if out.exists() and not out.is_dir():
        raise CLIError(f"--out {out}: is a file; give a folder name")
    print(f"rotorbayes demo: the bundled (synthetic) coupled data with a hidden physical "
          f"effect: first fit from the data, diagnosis, effects added one at a time, the "
          f"posterior, identifiability and an HTML report, into {out}/\n"
          f"(the analysis file: {path}; rerunning skips the stages whose inputs did not "
          "change; --force reruns all)")
    t0 = time.perf_counter()
    rec = run(path, quiet=a.quiet, force=a.force, out=out)
    print(f"\ndemo done in {time.perf_counter() - t0:.0f} s; effects added: "
          f"{', '.join(rec.get('added_effects', [])) or 'none'}")
    if rec.get("report"):
        print(f"open the report: {rec['report']}")
    return 0


def cmd_run(a) -> int:
    """A whole study from an analysis file."""
    from .study import load_analysis, run

    t0 = time.perf_counter()
    with _executor(a, load_analysis(a.analysis).table("parallel")):
        rec = run(a.analysis, quiet=a.quiet, force=a.force)
    print(f"\nstudy done in {time.perf_counter() - t0:.0f} s; outputs and run.json in "
          f"{Path(rec['final_fit']).parent}/")
    if rec.get("report"):
        print(f"report: {rec['report']}")
    return 0


def cmd_diagnose(a) -> int:
    """Verdict, ranking of missing effects and missing-torque map of a fit folder."""
    from .diagnosis import diagnose
    from .diagnosis.figures import plot_candidates, plot_torque_map
    from .results import load_fit

    fit = load_fit(a.fit, trust_effects=a.trust_effects)
    if a.noise is not None and not (a.noise >= 0 and math.isfinite(a.noise)):
        raise CLIError(f"--noise {a.noise}: give the Gaussian noise std in rad (>= 0)")
    print(f"diagnosing {fit.folder}/ ({fit.doc['config']} configuration, "
          f"{len(fit.problem.names)} free parameters, effects: "
          f"{', '.join(fit.problem.model.effect_names) or 'none'})")
    d = diagnose(fit.problem, fit.x, noise_std=a.noise or 0.0)
    print()
    print(d.text())
    doc = d.as_dict()
    doc["fit"] = str(fit.folder)
    from .outputs import folder_lock

    # The three files go together: one lock on the fit folder, and Ctrl-C waits for them.
    with folder_lock(fit.folder, flag="diagnose"), InterruptGuard().start() as guard:
        figs = [(plot_candidates(fit.problem, fit.x, d)[0], "diagnosis_candidates.png"),
                (plot_torque_map(d)[0], "missing_torque.png")]
        for fig, name in figs:
            save_figure_atomic(fig, fit.folder / name)
        write_text_atomic(fit.folder / "diagnosis.json", strict_json(doc))
    if guard.hit:
        raise Interrupted(f"interrupted (Ctrl-C) after the diagnosis had finished; it was "
                          f"kept, complete, in {fit.folder}/ (diagnosis.json and figures)")
    print(f"\nwrote {fit.folder}/diagnosis.json, diagnosis_candidates.png, missing_torque.png "
          f"({d.seconds:.1f} s)")
    return 0


def cmd_compare(a) -> int:
    """Where the model fails (one fit) and how the error fell (several, or a chain)."""
    from .diagnosis import compare as C
    from .diagnosis import figures as F
    from .results import load_fit

    fits = [load_fit(f, trust_effects=a.trust_effects) for f in a.fits]
    if len(fits) == 1:
        fits = fits[0].chain(trust_effects=a.trust_effects)
        if len(fits) > 1:
            print(f"comparing the chain of {len(fits)} fits that led to {a.fits[0]}")
    last = fits[-1]
    out = Path(a.out) if a.out else last.folder / "compare"
    # FIT/compare (the default) is derived from the fits: it is simply made again.
    with output_folder(out, a.force or not a.out) as tmp:
        written = _compare_into(fits, last, tmp, C, F)
    print(f"\nwrote {', '.join(written)} in {out}/")
    return 0


def _compare_into(fits, last, out: Path, C, F) -> list[str]:
    doc = C.compare_fits(fits)
    print(C.table(doc))
    views = C.residual_views(last.problem, last.x)
    for name, (fig, _) in (("error_vs_state.png", F.plot_error_vs_state(views)),
                           ("residual_correlation.png", F.plot_residual_correlation(views))):
        save_figure_atomic(fig, out / name)
    written = ["compare.json", "error_vs_state.png", "residual_correlation.png"]
    if len(fits) > 1:
        fig, _ = F.plot_chain(doc)
        save_figure_atomic(fig, out / "chain.png")
        written.append("chain.png")
    for c, v in views["channels"].items():
        lags, acf = v["acf"]
        outside = float(np.mean(np.abs(acf[lags > 0]) > v["band"]))
        floor_ratio = max(last.doc.get("assessment", {}).get("worst_ratio_to_floor") or 0, 0)
        note = ""
        if outside > 0.05:
            note = (" (structured; at the floor this is the encoder's own quantisation error, "
                    "which is correlated while a disc moves slowly or rests — see diagnose)"
                    if floor_ratio and floor_ratio <= 1.5 else
                    " (the error is structured, not noise)")
        print(f"{c}: {100 * outside:.0f} % of autocorrelation lags 1..{lags.max()} outside the "
              "99 % band of a white residual" + note)
    write_text_atomic(out / "compare.json", strict_json(doc))
    return written


#: Files ``sample`` derives from chain.h5 (rewritten by every run, --resume included).
SAMPLE_OUTPUTS = ("posterior.nc", "summary.md", "summary.csv", "corner.png", "trace.png",
                  "predictive.png", "correlation.png", "warnings.txt")


def _read_settings(src: Path) -> dict:
    """settings.json of a sample folder, checked; refused (CLIError) when absent or damaged."""
    path = src / "settings.json"
    if not src.is_dir():
        raise CLIError(f"{src}: no such folder; --resume needs a folder written by "
                       "`rotorbayes sample`")
    if not path.exists():
        raise CLIError(f"{src}: no settings.json; --resume needs a folder written by "
                       "`rotorbayes sample`")
    try:
        settings = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise CLIError(f"{path}: cannot be read ({exc}): damaged; --resume cannot continue "
                       "this run. Start again with `rotorbayes sample FIT --out "
                       f"{src} --force`") from None
    need = {"fit": str, "walkers": int, "steps": int, "ensembles": int, "seed": int,
            "noise": str, "ar1": bool}
    bad = [k for k, t in need.items() if not isinstance(settings.get(k) if isinstance(
        settings, dict) else None, t)]
    if bad:
        raise CLIError(f"{path}: {', '.join(bad)} missing or of the wrong type: damaged or "
                       "not written by `rotorbayes sample`; start again with `rotorbayes "
                       f"sample FIT --out {src} --force`")
    return settings


def cmd_sample(a) -> int:
    """emcee from a least-squares fit, checkpointed; --resume continues the same chains."""
    from .outputs import clean_stale, folder_lock

    src = Path(a.source)
    if a.resume:
        if a.out and Path(a.out).absolute() != src.absolute():
            raise CLIError(f"--resume continues {src}/ in place; leave out --out {a.out}")
        out = src
    else:
        if a.steps is None:
            a.steps = 2000
        if not a.out:
            raise CLIError("give --out FOLDER for the posterior (or --resume FOLDER)")
        out = Path(a.out)
        if out.exists() and not out.is_dir():
            raise CLIError(f"--out {out}: is a file, not a folder; give a new folder name")
        if not out.parent.is_dir():
            raise CLIError(f"--out {out}: the folder {out.parent}/ does not exist; create it "
                           "first or choose another --out")
    _check_sample_target(a, out)
    with folder_lock(out):
        _check_sample_target(a, out)  # again, under the lock
        clean_stale(out)
        return _sample_locked(a, src, out)


def _check_sample_target(a, out: Path) -> None:
    if not a.resume and out.is_dir() and any(out.iterdir()) and not a.force:
        raise CLIError(f"{out}/ already holds results; continue them with "
                       f"`rotorbayes sample {out} --resume --steps N`, choose another "
                       "--out or pass --force")


def _sample_locked(a, src: Path, out: Path) -> int:
    import shutil

    from .inference import sampling as S
    from .inference.likelihood import LogPosterior, load_priors
    from .outputs import check_free_space
    from .results import load_fit

    if a.resume:
        settings = _read_settings(src)
        if a.steps is not None:
            settings["steps"] = a.steps  # checked against the steps held, below
    else:
        settings = {"fit": str(Path(a.source).resolve()), "walkers": a.walkers,
                    "steps": a.steps, "ensembles": a.ensembles, "seed": a.seed,
                    "noise": a.noise, "ar1": a.ar1,
                    "priors": str(Path(a.priors).resolve()) if a.priors else None}
    fit = load_fit(settings["fit"], trust_effects=a.trust_effects)
    priors = load_priors(settings["priors"], fit.problem) if settings.get("priors") else None
    lp = LogPosterior(fit.problem, fit.x, priors=priors, noise=settings["noise"],
                      ar1=settings["ar1"])
    if settings["walkers"] < 2 * lp.ndim:
        raise CLIError(f"--walkers {settings['walkers']}: emcee needs at least twice the "
                       f"{lp.ndim} sampled coordinates; give --walkers {2 * lp.ndim} or more")
    if not a.resume:
        # The walkers start around the fit: a prior that excludes it cannot be sampled.
        z0 = np.asarray(lp.to_z(fit.x), float)[None, :]
        if not np.isfinite(lp.log_prior(z0)[0]):
            where = f"--priors {a.priors}" if a.priors else "the priors"
            raise CLIError(f"{where} give zero probability to the fit's point in "
                           f"{fit.folder}/ (a value outside a prior's lower..upper); widen "
                           "that prior or fit again (nothing was written)")
    n_res = int(fit.doc.get("n_residuals") or 0)
    # Room for posterior.nc (pointwise log-likelihood of the kept draws) and the figures.
    from .inference.posterior import LOGLIK_BYTES

    outputs = min(8 * a.max_draws * settings["ensembles"] * settings["walkers"]
                  * max(n_res, 1) // 4, 2 * LOGLIK_BYTES) + 2_000_000  # the group's cap
    need = S.chain_bytes(settings["walkers"], lp.ndim, settings["steps"],
                         settings["ensembles"]) + outputs
    chain = out / "chain.h5"
    # A reserve file left by a killed run is free space, not a result.
    (out / ".chain.h5.reserve").unlink(missing_ok=True)
    if a.resume:
        held = S.check_checkpoint(chain, n_walkers=settings["walkers"], ndim=lp.ndim,
                                  n_ensembles=settings["ensembles"])
        most = max(held.values(), default=0)
        if settings["steps"] < most:
            raise CLIError(f"--steps {settings['steps']} is below the {most} steps {chain} "
                           "already holds; give the new total (at least that many)")
        have = chain.stat().st_size if chain.exists() else 0
        check_free_space(out, max(need - have, 2_000_000), what=f"sample {out}")
        if not held and not chain.exists():
            print(f"{out}/ holds no finished step yet (the run was stopped before its first "
                  "step): sampling starts at step 0")
    else:
        check_free_space(out.parent, need, what=f"--out {out}")
    created = not out.exists()
    if not a.resume and not created:
        # --force: the new run's checkpoint must live in OUT to be resumable, so the old
        # results go now (after every check has passed).
        for p in out.iterdir():
            if p.name == "log.txt":
                continue
            shutil.rmtree(p) if p.is_dir() else p.unlink()
    out.mkdir(exist_ok=True)
    S.save_settings(out, settings)
    print(f"sampling {lp.ndim} coordinates ({', '.join(lp.coord_names)}) of {fit.folder}/ "
          f"with {settings['walkers']} walkers x {settings['steps']} steps x "
          f"{settings['ensembles']} independent ensembles; noise: "
          f"{'AR(1), sampled' if lp.ar1 else settings['noise']}; checkpoint {out}/chain.h5 "
          "(every step: a kill loses nothing, --resume continues)", flush=True)
    stale = [n for n in SAMPLE_OUTPUTS if (out / n).exists()]
    guard = InterruptGuard().start()  # Ctrl-C: stop between two steps, never inside one
    try:
        try:
            runs = S.sample(lp, fit.x, out, n_walkers=settings["walkers"],
                            n_steps=settings["steps"], n_ensembles=settings["ensembles"],
                            seed=settings["seed"], progress=not a.quiet and sys.stderr.isatty(),
                            should_stop=lambda: guard.hit > 0, keep_free=outputs)
        except RuntimeError as exc:
            if "cannot place the walkers" not in str(exc):
                raise
            raise CLIError(f"{fit.folder}/: {exc}") from None
        except S.SamplingStopped as exc:
            earlier = (f" ({', '.join(stale)} still describe the earlier, shorter run "
                       "until then)") if stale else ""
            raise Interrupted(
                f"interrupted (Ctrl-C): {exc.ensemble} stopped after step {exc.step} of "
                f"{exc.total}; every finished step is kept in {out}/chain.h5 (settings in "
                f"settings.json). Continue with `rotorbayes sample {out} --resume`{earlier}"
            ) from None
        except BaseException as exc:
            if created and not S.steps_held(chain):
                shutil.rmtree(out, ignore_errors=True)  # nothing done: leave no folder
            if EXIT.is_disk_full(exc) and not isinstance(exc, EXIT.EnvironmentFailure):
                _die_disk_full(out, exc)
            raise
        try:
            written = _write_sample_outputs(a, out, lp, fit, runs, guard)
        except OSError as exc:
            if not EXIT.is_disk_full(exc):
                raise
            raise EXIT.EnvironmentFailure(
                f"{out}/: the disk filled up while the summary files were written; the chains "
                f"are complete in {out}/chain.h5. Free some space and run `rotorbayes sample "
                f"{out} --resume` to write them (no new steps)") from None
    finally:
        guard.stop()
    return written


def _die_disk_full(out: Path, exc: BaseException) -> None:
    """The disk filled up in the middle of an HDF5 write. h5py's objects are then in a state
    in which tearing them down can crash the interpreter, so say what happened and leave at
    once (the lock goes with the process)."""
    print(f"rotorbayes sample: error: {out}/chain.h5: the disk is full (no space left on the "
          "device) while a step was being written; the steps finished before it are in the "
          f"checkpoint. Free some space and continue with `rotorbayes sample {out} "
          "--resume` (if the checkpoint is refused as damaged, start again with --force)",
          file=sys.__stderr__, flush=True)
    with contextlib.suppress(Exception):
        sys.__stdout__.flush()
    os._exit(EXIT.ENVIRONMENT)


def _write_sample_outputs(a, out: Path, lp, fit, runs, guard) -> int:
    """The summary, InferenceData and figures from finished chains; Ctrl-C between two
    files stops with a true account of what is on disk."""
    from . import posterior_figures as PF
    from .inference import arviz_compat as AZ
    from .inference import posterior as PO
    from .inference import sampling as S

    names = lp.coord_names
    done: list[str] = []

    def checkpoint() -> None:
        if guard.hit:
            left = [n for n in SAMPLE_OUTPUTS if n not in done]
            raise Interrupted(
                f"interrupted (Ctrl-C) after the sampling had finished; the chains are "
                f"complete in {out}/chain.h5"
                + (f"; written: {', '.join(done)}" if done else "")
                + f"; not yet rewritten: {', '.join(left)}. `rotorbayes sample {out} "
                "--resume` writes them from the chains (no new steps)")

    warnings = S.convergence(runs, names)
    if lp.n_failed:
        warnings.append(f"{lp.n_failed} proposals could not be simulated (counted in "
                        "sample_stats.failed_simulations; they got -inf)")
    idata = PO.inference_data(lp, runs, max_draws=a.max_draws)
    rows = PO.summary_table(idata, lp, runs)
    if len(runs) >= 2:
        bad = [r["parameter"] for r in rows if not r["r_hat"] < 1.01]
        if bad:
            warnings.append(f"R-hat across the {len(runs)} ensembles is >= 1.01 for "
                            f"{', '.join(bad)}: they have not converged to one distribution")
    else:
        warnings.append("one ensemble: no R-hat (the walkers of an ensemble are not "
                        "independent chains); use --ensembles 2 or more")
    unc = lp.uncertainty
    if unc is not None and unc.warning():
        warnings.append(unc.warning())
    if lp.noise == "floor":
        warnings.append("--noise floor counts every sample as independent: on data where a "
                        "disc sticks or turns slowly the intervals are too narrow (the "
                        "default, --noise robust, widens them to what the errors support)")
    md = PO.table_markdown(rows, assumptions=unc.assumptions() if unc is not None else None)
    print("\n" + md)
    checkpoint()
    tmp = out / ".posterior.nc.tmp"
    try:
        AZ.save(idata, tmp)
        tmp.replace(out / "posterior.nc")
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
    done.append("posterior.nc")
    for name, write in (
            ("summary.md", lambda p: write_text_atomic(p, md + "\n")),
            ("summary.csv", lambda p: write_text_atomic(p, PO.table_csv(rows))),
            ("corner.png", lambda p: save_figure_atomic(PF.plot_corner(idata, fit.problem), p)),
            ("trace.png", lambda p: save_figure_atomic(PF.plot_trace(runs, names)[0], p)),
            ("predictive.png",
             lambda p: save_figure_atomic(PF.plot_predictive(idata, fit.problem)[0], p)),
            ("correlation.png",
             lambda p: save_figure_atomic(PF.plot_correlation(idata, fit.problem)[0], p)),
            ("warnings.txt", lambda p: write_text_atomic(p, "\n".join(warnings) + "\n"))):
        checkpoint()
        write(out / name)
        done.append(name)
    for w in warnings:
        print(f"warning: {w}", file=sys.stderr)
    print(f"\nwrote posterior.nc, summary.md/.csv, corner.png, trace.png, predictive.png, "
          f"correlation.png in {out}/ ({lp.n_calls} log-posterior evaluations)")
    if guard.hit:
        raise Interrupted(f"interrupted (Ctrl-C) as the last file was written; the results "
                          f"were kept, complete, in {out}/")
    return EXIT.DONE


def cmd_identify(a) -> int:
    """Fisher eigen-analysis in words, profile likelihoods, multistart on the corner plot."""
    from .results import load_fit

    fit = load_fit(a.fit, trust_effects=a.trust_effects)
    prob = fit.problem
    profiles = _csv_list(a.profiles, "--profiles") or []
    for n in profiles:
        if n not in prob.names:
            raise CLIError(f"--profiles: {n} is not a free parameter of {fit.folder}/; the "
                           f"free ones are {', '.join(prob.names)}")
    if a.points < 3:
        raise CLIError(f"--points {a.points}: give at least 3 grid points")
    if a.posterior and not (Path(a.posterior) / "posterior.nc").exists():
        raise CLIError(f"--posterior {a.posterior}: no posterior.nc there; give a folder "
                       "written by `rotorbayes sample`")
    if a.multistart and not (Path(a.multistart) / "multistart.json").exists():
        raise CLIError(f"--multistart {a.multistart}: no multistart.json there; give a folder "
                       "written by `rotorbayes multistart`")
    with output_folder(a.out, a.force) as out:
        written = _identify_into(a, fit, prob, profiles, out)
    from .inference.taskstore import remove_store

    remove_store(a.out)  # complete: no profile point left to resume
    print(f"\nwrote {', '.join(written)} in {a.out}/")
    return 0


def _profiles_into(a, I, prob, fit, profiles, se, ex, doc) -> None:
    """Each profile's grid points on the executor ``ex``; printed and added to ``doc``."""
    from .inference.taskstore import store_path

    for n in profiles:
        t0 = time.perf_counter()
        pr = I.profile(prob, fit.x, n, n_points=a.points, stderr=se.get(n), executor=ex,
                       resume=store_path(a.out))  # finished points kept: a re-run skips them
        doc["profiles"].append(pr)
        inside = [g for g, d in zip(pr["grid"], pr["delta_chi2"], strict=True)
                  if d is not None and math.isfinite(d) and d < 3.84]
        print(f"profile of {n}: {a.points} points in {time.perf_counter() - t0:.1f} s; "
              + (f"95 % interval (Δχ² < 3.84) within [{min(inside):.7g}, {max(inside):.7g}] "
                 f"{pr['unit']}" if inside else "no grid point within Δχ² < 3.84")
              + ("; the interval reaches the grid's edge: widen it" if inside and (
                  min(inside) == pr["grid"][0] or max(inside) == pr["grid"][-1]) else ""))


def _identify_into(a, fit, prob, profiles, out: Path) -> list[str]:
    from .inference import identify as I

    F = I.fisher(prob, fit.x)
    words = I.describe(F)
    print(f"Fisher information of {fit.folder}/ at the fit (noise at each channel's floor; "
          "log coordinates for positive parameters):")
    print("  eigenvalues " + ", ".join(f"{v:.3g}" for v in F.eigenvalues))
    for w in words:
        print("  " + w)
    doc = {"fit": str(fit.folder), "fisher": F.as_dict(), "words": words, "profiles": []}
    from . import posterior_figures as PF

    save_figure_atomic(PF.plot_fisher(F)[0], out / "fisher.png")
    written = ["identify.json", "fisher.png"]
    if profiles:
        se = dict(zip(prob.names, fit.doc and [fit.doc["estimates"][n]["stderr"] or 0.0
                                               for n in prob.names], strict=True))
        with _executor(a) as ex:  # one executor (one cluster, if any) for every profile
            _profiles_into(a, I, prob, fit, profiles, se, ex, doc)
        save_figure_atomic(PF.plot_profiles(doc["profiles"])[0], out / "profiles.png")
        written.append("profiles.png")
    if a.posterior:
        from .inference import arviz_compat as AZ

        idata = AZ.load(Path(a.posterior) / "posterior.nc")
        overlay = None
        if a.multistart:
            ms = json.loads((Path(a.multistart) / "multistart.json").read_text())
            if ms.get("names") != list(prob.names):
                raise CLIError(f"{a.multistart}: its free parameters {ms.get('names')} "
                               f"differ from the fit's {list(prob.names)}")
            overlay = np.array(ms["ends"])
        save_figure_atomic(PF.plot_corner(idata, prob, overlay=overlay), out / "corner.png")
        written.append("corner.png")
    write_text_atomic(out / "identify.json", strict_json(doc))
    write_text_atomic(out / "summary.txt", "\n".join(words) + "\n")
    return [*written, "summary.txt"]


def cmd_report(a) -> int:
    """report.html: one self-contained page for a study or any result folder."""
    from .report import ReportError, write_report

    try:
        rep = write_report(a.folder, a.out, force=a.force)
    except ReportError as exc:
        raise CLIError(str(exc)) from None
    size = rep.size
    human = f"{size / 1e6:.1f} MB" if size >= 1e6 else f"{size / 1e3:.0f} kB"
    print(f"wrote {rep.path} ({human}, {size} bytes)")
    print(f"sections: {', '.join(rep.sections)}")
    if rep.absent:
        print(f"absent (not in {a.folder}): {', '.join(rep.absent)}")
    for p in rep.problems:
        print(f"warning: section {p}", file=sys.stderr)
    return 0


def cmd_params(a) -> int:
    if a.name:
        p = _params.resolve(_param_spec(a.name))
        for n in _params.NAMES:
            print(f"{n:<12} {p[n]:12.6g}  {_params.INFO[n].unit}")
        return 0
    print(_params.table_markdown())
    print("\nnamed sets: " + ", ".join(_params.named_sets()))
    return 0


def cmd_effects(a) -> int:
    if a.name:
        for spec in a.name:
            print(_effects.resolve([spec])[0].describe())
        return 0
    print("The catalogue of physical effects (switch one on with --add NAME; a user effect "
          "with --add FILE.py:NAME, see docs/effects.md).\n")
    for e in _effects.CATALOGUE.values():
        print(e.describe() + "\n")
    from .model import CONFIGURATIONS

    print("Base models (on unless --without NAME):")
    for c in CONFIGURATIONS.values():
        print(f"    {c.name:<8} {', '.join(c.base_effects) or '(none)'}")
    return 0


def _add_fit_args(p, *, multi=False):
    p.add_argument("--model", required=True, choices=["upper", "coupled", "brake"],
                   help="rig configuration")
    p.add_argument("data", nargs="+", help="measurement CSV file(s), or example:NAME")
    p.add_argument("--out", required=True,
                   help="output folder (created, with missing parent folders; it appears only "
                   "when the run succeeds)")
    p.add_argument("--free", help="comma-separated parameters to estimate (default: the "
                   "configuration's, plus alpha0 per experiment with several experiments)")
    p.add_argument("--fixed", help="comma-separated parameters to keep fixed")
    p.add_argument("--base", help="values of all parameters not estimated (named set, TOML "
                   "or fit.json); default: --p0, else the configuration's P_ref")
    p.add_argument("--add", action="append", metavar="EFFECT",
                   help="switch an effect on and free its parameters (repeatable): a catalogue "
                   "name (see `rotorbayes effects`) or FILE.py:NAME for your own effect")
    p.add_argument("--without", action="append", metavar="EFFECT",
                   help="switch off an effect of the configuration's base model (repeatable)")
    p.add_argument("--channels", help="theta_l, theta_u or theta_l,theta_u")
    p.add_argument("--weights", metavar="CHANNEL=W,...",
                   help="channel weights (> 0), e.g. theta_l=1,theta_u=0.1 (default: 1 each)")
    p.add_argument("--prescribed-upper", action="store_true",
                   help="drive the lower disc with the measured theta_u")
    p.add_argument("--max-nfev", type=_ranged(int, ge=1, why=" (residual evaluations)"),
                   default=200, metavar="N", help="evaluation budget per fit")
    for tol in ("ftol", "xtol", "gtol"):
        p.add_argument(f"--{tol}", type=_ranged(gt=0, why=" (a convergence tolerance)"),
                       default=1e-10, help=f"{tol} of scipy.optimize.least_squares")
    p.add_argument("--force", action="store_true",
                   help="replace the results in --out (only once the new run has succeeded)")
    _add_trust(p)


def _add_parallel(p, what: str) -> None:
    """Where the independent tasks run (rotorbayes.inference.parallel)."""
    from .inference.parallel import BACKENDS, DEFAULT_BACKEND, SCHEDULER_ENV

    p.add_argument("--backend", choices=BACKENDS, default=None,
                   help=f"where the {what} run: serial, local threads (default "
                   f"{DEFAULT_BACKEND!r}), local processes, or dask (a local Dask cluster of "
                   "--workers processes, or the scheduler given by --scheduler or "
                   f"{SCHEDULER_ENV})")
    p.add_argument("--workers", type=_ranged(int, ge=1, le=256, why=" (parallel workers)"),
                   default=None, metavar="N",
                   help=f"parallel {what} (threads, processes or local Dask workers; default "
                   "the number of cores)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help=f"run the {what} on this Dask scheduler (e.g. tcp://host:8786; "
                   f"default ${SCHEDULER_ENV} if set); see the README on starting one")


@contextlib.contextmanager
def _executor(a, file: dict | None = None):
    """Open the executor the options, DASK_SCHEDULER_ADDRESS or the analysis file's
    [parallel] table choose, for the length of a command.  A command run inside `run`
    (a study stage) without options of its own uses the study's executor."""
    from .inference import parallel as P

    opts = (getattr(a, "backend", None), getattr(a, "workers", None),
            getattr(a, "scheduler", None))
    if P.current_executor() is not None and opts == (None, None, None):
        yield P.current_executor()
        return
    try:
        spec = P.choose(*opts, file=file)
    except ValueError as exc:
        raise CLIError(str(exc)) from None
    if spec.backend != P.DEFAULT_BACKEND or spec.source != "default":
        print(f"parallel tasks run {spec.describe()}", flush=True)
    with P.use_executor(spec) as ex:
        yield ex


def _add_trust(p) -> None:
    p.add_argument("--trust-effects", action="store_true",
                   help="import user effect files a result names even when they changed "
                   "since the result was made, or it recorded no hash of them (effect files "
                   "are Python code: read them first)")


def build_parser() -> argparse.ArgumentParser:
    from . import __version__

    ap = _Parser(prog="rotorbayes", description=DESCRIPTION)
    ap.add_argument("--version", action="version", version=f"%(prog)s {__version__}",
                    help="print the version and exit")
    sub = ap.add_subparsers(dest="cmd", required=True)

    s = sub.add_parser("simulate", help="simulate an experiment and write a measurement CSV")
    s.add_argument("--model", default="brake", choices=["upper", "coupled", "brake"],
                   help="rig configuration")
    s.add_argument("--input", choices=["est", "val"],
                   help="generated input: est (quasi-random levels) or val (multisine) "
                   "(default: est)")
    s.add_argument("--input-file", help="CSV with columns t,u in s and V, uniformly sampled; "
                   "gives the input, duration and rate (so not with --input, --duration, "
                   "--rate)")
    s.add_argument("--duration", type=_ranged(gt=0, le=7200, why=" seconds (experiments on "
                   "the rig last seconds to about an hour)"),
                   help="seconds of generated input, > 0 and <= 7200 (default: 30)")
    s.add_argument("--rate", type=_rate, help=f"samples per second, {MIN_RATE:g} to "
                   f"{MAX_RATE:g} (default: 1000)")
    s.add_argument("--seed", type=_ranged(int, ge=0), default=0,
                   help="seed of the input and the noise")
    s.add_argument("--params", help="named set (thesis:4.3:P_ref), TOML file or fit.json "
                   "(default: the configuration's P_ref)")
    s.add_argument("--alpha0", type=_ranged(ge=-10, le=10, why=" rad (the bounds of alpha0)"),
                   help="initial string torsion [rad] (default: from --params)")
    s.add_argument("--add", action="append", metavar="EFFECT",
                   help="switch an effect on (repeatable): a catalogue name or FILE.py:NAME; "
                   "its parameters come from --params (null values otherwise)")
    s.add_argument("--quantize", action="store_true", help="round to encoder counts")
    s.add_argument("--noise", type=_ranged(ge=0, why=" rad (a standard deviation)"),
                   default=0.0, help="Gaussian noise std [rad]")
    s.add_argument("--out", required=True, help="output CSV (its folder must exist)")
    s.add_argument("--plot", help="also save a figure (.png, .pdf, .svg, ...; its folder "
                   "must exist)")
    s.add_argument("--force", action="store_true", help="overwrite --out and --plot")
    s.set_defaults(func=cmd_simulate)

    f = sub.add_parser("fit", help="least squares from a start P0")
    _add_fit_args(f)
    f.add_argument("--validate", action="append", metavar="FILE",
                   help="a validation CSV file or example:NAME; repeat the option for several "
                   "(--validate a.csv --validate b.csv)")
    f.add_argument("--p0", help="start: named set (thesis:4.2:P0), TOML or fit.json "
                   "(default: a start computed from the data); a fit.json of an upper-"
                   "configuration fit also fixes the upper-disc parameters it estimated")
    f.add_argument("--restarts", type=_ranged(int, ge=0), default=6,
                   help="without --p0: extra fits around the data start when the first one "
                   "ends above 3x the encoder floor")
    f.set_defaults(func=cmd_fit)

    m = sub.add_parser("multistart", help="many fits from spread starts; waterfall and spread")
    _add_fit_args(m)
    m.add_argument("--starts", type=_ranged(int, ge=1, why=" (one fit per start)"),
                   default=32, metavar="N", help="number of fits from different starts")
    m.add_argument("--around", help="spread starts around this set (named set, TOML or "
                   "fit.json) instead of over the bounds")
    m.add_argument("--spread", type=_ranged(gt=0, le=5, why=" (the log-sd of the start "
                   "factors; 0.3 spreads by about ±30 %)"), default=0.3,
                   help="log-sd of the spread around --around")
    m.add_argument("--seed", type=_ranged(int, ge=0), default=0, help="seed of the starts")
    _add_parallel(m, "fits")
    m.set_defaults(func=cmd_multistart)

    d = sub.add_parser("demo", help="the whole story on the bundled hidden-effect data: "
                       "fit, diagnose, add effects, sample, identify, HTML report")
    d.add_argument("--out", default="rotorbayes-demo", help="output folder")
    d.add_argument("--force", action="store_true", help="rerun every stage")
    d.add_argument("--quiet", action="store_true", help="print only the summary (the log "
                   "file in the output folder has everything)")
    d.set_defaults(func=cmd_demo)

    r = sub.add_parser("run", help="a whole study from an analysis file (TOML; see "
                       "docs/analysis_file.md)")
    r.add_argument("analysis", help="the analysis file")
    r.add_argument("--force", action="store_true", help="rerun every stage")
    r.add_argument("--quiet", action="store_true", help="print only the summary")
    _add_parallel(r, "independent fits (restarts, profile points)")
    r.set_defaults(func=cmd_run)

    g = sub.add_parser("diagnose", help="is the remaining error noise? which effect is "
                       "missing? (writes diagnosis.json and figures into the fit folder)")
    g.add_argument("fit", help="a folder written by `rotorbayes fit`")
    g.add_argument("--noise", type=_ranged(ge=0, le=1, why=" rad (a standard deviation)"),
                   default=None,
                   help="Gaussian measurement noise std [rad] besides encoder quantisation "
                   "(default 0)")
    _add_trust(g)
    g.set_defaults(func=cmd_diagnose)

    c = sub.add_parser("compare", help="where the model fails (error against the state, "
                       "residual correlation) and, for several fits or a chain, how the error "
                       "fell")
    c.add_argument("fits", nargs="+", help="fit folders (one: its chain of --p0 parents)")
    c.add_argument("--out", help="output folder (default: FIT/compare/ of the last fit)")
    c.add_argument("--force", action="store_true", help="overwrite results in --out")
    _add_trust(c)
    c.set_defaults(func=cmd_compare)

    sp = sub.add_parser("sample", help="posterior sampling with emcee from a fit "
                        "(checkpointed; --resume continues)")
    sp.add_argument("source", help="a fit folder, or with --resume a sample folder")
    sp.add_argument("--out", help="output folder (new runs)")
    sp.add_argument("--resume", action="store_true",
                    help="continue the chains in SOURCE (a folder written by sample)")
    sp.add_argument("--walkers", type=_ranged(int, ge=4, le=MAX_WALKERS,
                                              why=" (walkers per ensemble)"),
                    default=32, help="walkers per ensemble")
    sp.add_argument("--steps", type=_ranged(int, ge=10, le=MAX_STEPS, why=" (steps per "
                                            "ensemble)"), default=None,
                    help="total steps per ensemble (default 2000; with --resume the new "
                    "total)")
    sp.add_argument("--ensembles", type=_ranged(int, ge=1, le=64, why=" (independent "
                                                "ensembles)"), default=2,
                    help="independent ensembles (>= 2 for R-hat)")
    sp.add_argument("--seed", type=_ranged(int, ge=0, le=2**31 - 1), default=0)
    sp.add_argument("--noise", choices=["robust", "floor", "sampled"], default="robust",
                    help="robust: floor noise widened to the fit's honest covariance "
                    "(correlated rounding while a disc sticks, model error, the input "
                    "between samples); floor: i.i.d. at the encoder floor (too narrow on "
                    "stick-slip data; to compare); sampled: σ sampled (prior 1/σ)")
    sp.add_argument("--ar1", action="store_true", help="AR(1) errors per channel")
    sp.add_argument("--priors", help="TOML with a [priors] table (default: uniform within "
                    "the physical bounds)")
    sp.add_argument("--max-draws", type=_ranged(int, ge=1, le=100_000, why=" (draws kept "
                                                "per ensemble)"), default=100,
                    help="draws per ensemble kept in posterior.nc (with the pointwise "
                    "log-likelihood of every sample: about 2 x draws x samples x channels x "
                    "4 bytes)")
    sp.add_argument("--quiet", action="store_true", help="no progress bar")
    sp.add_argument("--force", action="store_true", help="overwrite results in --out")
    _add_trust(sp)
    sp.set_defaults(func=cmd_sample)

    i = sub.add_parser("identify", help="which parameter combinations the data fix: "
                       "Fisher directions in words, profile likelihoods")
    i.add_argument("fit", help="a folder written by `rotorbayes fit`")
    i.add_argument("--out", required=True, help="output folder")
    i.add_argument("--profiles", help="comma-separated free parameters to profile")
    i.add_argument("--points", type=_ranged(int, ge=3, le=1001, why=" (grid points)"),
                   default=11, help="grid points per profile")
    _add_parallel(i, "profile fits")
    i.add_argument("--posterior", help="a sample folder: corner plot of its posterior")
    i.add_argument("--multistart", help="a multistart folder: its end points on the corner")
    i.add_argument("--force", action="store_true", help="overwrite results in --out")
    _add_trust(i)
    i.set_defaults(func=cmd_identify)

    rp = sub.add_parser("report", help="report.html: one self-contained HTML page (figures "
                        "embedded) for a study folder or any fit/compare/sample/identify folder")
    rp.add_argument("folder", help="a folder written by run, demo, fit, compare, sample or "
                    "identify")
    rp.add_argument("--out", help="the HTML file to write, ending in .html (default: "
                    "FOLDER/report.html); an existing file is replaced only if it is a report "
                    "rotorbayes wrote")
    rp.add_argument("--force", action="store_true",
                    help="replace an existing .html file that is not a rotorbayes report")
    rp.set_defaults(func=cmd_report)

    p = sub.add_parser("params", help="list parameters and named sets, or show one set")
    p.add_argument("name", nargs="?", help="a named set (thesis:4.2:P0), TOML file or "
                   "fit.json")
    p.set_defaults(func=cmd_params)

    e = sub.add_parser("effects", help="list the catalogue of physical effects")
    e.add_argument("name", nargs="*", help="show these effects only (NAME or FILE.py:NAME)")
    e.set_defaults(func=cmd_effects)
    return ap


class _Capture:
    """A stream that writes through and keeps a copy (for the output folder's log)."""

    def __init__(self, stream):
        self.stream, self.parts = stream, []

    def write(self, text):
        self.parts.append(text)
        return self.stream.write(text)

    def flush(self):
        self.stream.flush()

    def isatty(self):
        return self.stream.isatty()

    def fileno(self):
        return self.stream.fileno()


def _log_folder(a) -> Path | None:
    """The folder a command's results went to (its log.txt goes there too)."""
    if a.cmd in ("fit", "multistart", "sample", "identify") and getattr(a, "out", None):
        return Path(a.out)
    if a.cmd == "sample" and getattr(a, "resume", False):
        return Path(a.source)
    if a.cmd == "diagnose":
        return Path(a.fit)
    if a.cmd == "compare":
        return Path(a.out) if a.out else Path(a.fits[-1]) / "compare"
    return None


class _logged:
    """Keep what a command prints and append it to ``log.txt`` in its output folder."""

    def __init__(self, a):
        self.a = a

    def __enter__(self):
        self.out, self.err = sys.stdout, sys.stderr
        self.cap_out, self.cap_err = _Capture(sys.stdout), _Capture(sys.stderr)
        sys.stdout, sys.stderr = self.cap_out, self.cap_err
        return self

    def __exit__(self, *exc):
        sys.stdout, sys.stderr = self.out, self.err
        folder = _log_folder(self.a)
        # Only a command that ran to its end logs: a refused one must not touch a folder.
        if exc[0] is None and folder is not None and folder.is_dir():
            import datetime

            stamp = datetime.datetime.now().isoformat(timespec="seconds")
            text = "".join(self.cap_out.parts)
            # Progress bars (carriage returns) are for the terminal, not the log.
            err = "".join(p for p in self.cap_err.parts if "\r" not in p and "it/s" not in p)
            try:
                with (folder / "log.txt").open("a") as fh:
                    fh.write(f"==== {stamp} rotorbayes {' '.join(self.a._argv)}\n{text}")
                    if err:
                        fh.write(f"---- stderr\n{err}")
            except OSError:
                pass
        return False


def main(argv=None) -> int:
    ap = build_parser()
    try:
        a = ap.parse_args(argv)
    except SystemExit as exc:  # --help, --version (0) or a usage error (2), already printed
        return exc.code if isinstance(exc.code, int) else 2
    a._argv = list(sys.argv[1:] if argv is None else argv)
    if isinstance(getattr(a, "out", None), str) and len(a.out) > 1:
        a.out = a.out.rstrip("/")  # messages add their own "/": "fit0/", never "fit0//"
    try:
        with _logged(a):
            code = a.func(a)
        sys.stdout.flush()  # a closed pipe shows here, not at exit
        return code
    except Interrupted as exc:
        print(f"rotorbayes {a.cmd}: {exc}", file=sys.stderr)
        return EXIT.INTERRUPTED
    except KeyboardInterrupt:
        # Every command builds its results whole or not at all (a partial folder, atomic
        # files), and keeps work that was done (InterruptGuard): what is left is true.
        print(f"rotorbayes {a.cmd}: interrupted (Ctrl-C) before its results were complete; "
              "it wrote nothing new (earlier results, if any, are unchanged)", file=sys.stderr)
        return EXIT.INTERRUPTED
    except BrokenPipeError:
        # The reader (e.g. `| head`) stopped reading: not an error of ours. Python's recipe:
        # point stdout at devnull so the flush at exit does not fail again.
        try:
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
        except (OSError, ValueError):
            pass
        return EXIT.BROKEN_PIPE
    except EXIT.Busy as exc:
        print(f"rotorbayes {a.cmd}: busy: {exc}", file=sys.stderr)
        return EXIT.BUSY
    except EXIT.EnvironmentFailure as exc:
        print(f"rotorbayes {a.cmd}: error: {exc}", file=sys.stderr)
        return EXIT.ENVIRONMENT
    except (CLIError, DataFileError, _params.ParameterError, ValueError, FileExistsError,
            SimulationError, ResultError, OutputError) as exc:
        print(f"rotorbayes {a.cmd}: error: {exc}", file=sys.stderr)
        return EXIT.REFUSED
    except (OSError, RuntimeError, MemoryError) as exc:
        if isinstance(exc, MemoryError) or EXIT.is_disk_full(exc) or (
                isinstance(exc, OSError) and exc.errno in EXIT.ENVIRONMENT_ERRNOS):
            print(f"rotorbayes {a.cmd}: error: {EXIT.describe_environment(exc)}",
                  file=sys.stderr)
            return EXIT.ENVIRONMENT
        if not isinstance(exc, OSError) or exc.filename is None:
            raise  # not about a path the user gave: a bug, show it
        what = exc.strerror or type(exc).__name__
        print(f"rotorbayes {a.cmd}: error: {exc.filename}: {what}; check the path and its "
              "permissions", file=sys.stderr)
        return EXIT.REFUSED


if __name__ == "__main__":
    sys.exit(main())

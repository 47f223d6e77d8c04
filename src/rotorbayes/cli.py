"""The ``rotorbayes`` command line: simulate, fit, multistart, demo, params, effects.

A thin layer: it parses arguments, calls the library and prints; the knowledge lives in
:mod:`rotorbayes.model` and :mod:`rotorbayes.inference`.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from .data import DataFileError, Experiment, load_experiment, save_experiment
from .examples import example_path
from .model import SimulationError
from .model import effects as _effects
from .model import parameters as _params
from .results import ResultError


class CLIError(Exception):
    """A user error: printed without a traceback, exit code 2."""


def _out_dir(path: str, force: bool) -> Path:
    """An output folder that does not hold earlier results (unless ``--force``)."""
    out = Path(path)
    if out.exists() and any(out.iterdir()) and not force:
        raise CLIError(f"{out}/ already holds results; choose another --out or pass --force "
                       "to overwrite them")
    out.mkdir(parents=True, exist_ok=True)
    return out


def _example_path(name: str) -> str:
    """Resolve ``example:NAME`` to a bundled data file."""
    if name.startswith("example:"):
        return str(example_path(name))
    return name


def _load(paths, config: str) -> list[Experiment]:
    exps = []
    for p in paths:
        ex = load_experiment(_example_path(p), expect_lower=config != "upper")
        exps.append(ex)
    return exps


def _read_input_file(path: str) -> tuple[np.ndarray, np.ndarray]:
    """Read ``t,u`` (and possibly more columns) from a CSV file."""
    p = Path(path)
    if not p.exists():
        raise CLIError(f"{p}: input file not found")
    lines = [ln for ln in p.read_text().splitlines() if ln.strip() and not ln.startswith("#")]
    if not lines:
        raise CLIError(f"{p}: the file is empty; it needs a header 't,u' and rows of numbers")
    header = [h.strip() for h in lines[0].split(",")]
    if "t" not in header or "u" not in header:
        raise CLIError(f"{p}: line 1: the header {lines[0]!r} must contain the columns t and u")
    it, iu = header.index("t"), header.index("u")
    t, u = [], []
    for k, ln in enumerate(lines[1:], start=2):
        f = ln.split(",")
        try:
            t.append(float(f[it]))
            u.append(float(f[iu]))
        except (ValueError, IndexError):
            raise CLIError(f"{p}: row {k}: {ln!r} is not a row of numbers matching the header"
                           ) from None
    t, u = np.array(t), np.array(u)
    if not np.all(np.isfinite(u)) or not np.all(np.isfinite(t)):
        raise CLIError(f"{p}: the t and u columns must be finite numbers")
    d = np.diff(t)
    if t.size < 2 or np.any(d <= 0):
        raise CLIError(f"{p}: time must increase from row to row")
    if np.max(np.abs(d - np.median(d))) > 1e-6 * np.median(d):
        raise CLIError(f"{p}: time must be uniformly sampled; resample the input first")
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
def cmd_simulate(a) -> int:
    from .model import simulate
    from .signals import make_signal

    if a.input_file:
        t, u = _read_input_file(a.input_file)
    else:
        t, u = make_signal(a.input, a.duration, rate=a.rate, seed=a.seed)
    dt = float(t[1] - t[0])
    out = Path(a.out)
    if out.exists() and not a.force:
        raise CLIError(f"{out} exists; choose another --out or pass --force to overwrite it")
    from .model import Model

    params = _resolve_values(a.params, Model(a.model, a.add or ()))
    t0 = time.perf_counter()
    sim = simulate(params, u, dt=dt, config=a.model, alpha0=a.alpha0,
                   effects=a.add or (), quantize_angles=a.quantize,
                   noise_std=a.noise, seed=a.seed)
    el = time.perf_counter() - t0
    meta = {"source": "rotorbayes simulate (synthetic)", "config": a.model,
            "input": a.input_file or f"{a.input} seed={a.seed}",
            "params": a.params or f"default ({_params.DEFAULT_SET[a.model]})",
            "alpha0": sim.params["alpha0"], "quantized": a.quantize, "noise_std": a.noise}
    save_experiment(sim.to_experiment(), out, overwrite=a.force, meta=meta)
    n_stick = int(np.sum(sim.events[:, 2] == 0)) if sim.events.size else 0
    print(f"simulated {a.model} configuration, {sim.t[-1]:.1f} s at {1 / dt:.0f} Hz in "
          f"{1e3 * el:.1f} ms; {len(sim.events)} stick/slip switches ({n_stick} stick onsets)")
    if sim.theta_l is not None:
        print(f"lower disc sticks {100 * sim.stick_fraction('l'):.1f} % of the time; "
              f"string torsion {sim.alpha.min():.3f} .. {sim.alpha.max():.3f} rad")
    print(f"wrote {out}")
    if a.plot:
        from .plots import plot_simulation

        fig, _ = plot_simulation(sim)
        fig.savefig(a.plot, dpi=110)
        print(f"wrote {a.plot}")
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
        inherited = [e for e in doc.get("added_effects", []) if e not in added]
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
    weights = None
    if a.weights:
        weights = {}
        for item in a.weights.split(","):
            k, eq, v = item.partition("=")
            try:
                weights[k.strip()] = float(v)
            except ValueError:
                raise CLIError(f"--weights: {item!r} must look like theta_l=1 (channel=weight)"
                               ) from None
            if not eq:
                raise CLIError(f"--weights: {item!r} must look like theta_l=1 (channel=weight)")
    prob = Problem(model, exps, free=free, base=base, channels=channels, weights=weights,
                   fixed=fixed)
    return prob, from_upper


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


def run_fit(a, out: Path) -> dict:
    """Fit, print and write fit.json + figures; returns the JSON document."""
    from . import inference as E
    from .plots import plot_fit, plot_friction

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
        start_source = {n: f"--p0 {a.p0}" for n in prob.names}
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
    status = "" if res.success else "DID NOT CONVERGE: "
    print(f"\n{status}{res.message} ({res.nfev} evaluations, {res.njev} Jacobians, "
          f"{res.seconds:.1f} s)\n")
    q_est = E.quality(prob, res.x)
    q_val = E.quality(prob, res.x, val) if val else []
    assessment = E.assess(res, q_est, q_val, sources=sources)
    print(_fmt_params(prob, res.names, res.x, res.stderr, res.x0, assessment.at_bound))
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
    movers = [n for n, c in sloppy.items() if abs(c) > 0.3]
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
        "data": [str(e.path) for e in exps], "validation": [str(e.path) for e in val],
        "success": res.success, "message": res.message, "nfev": res.nfev,
        "seconds": res.seconds, "ssr": res.ssr, "n_residuals": res.n_residuals,
        "start": chose,
        "free": list(res.names),
        "prescribed_upper": bool(prob.prescribed_upper),
        "weights": dict(prob.weights),
        "parent": _parent_of(a.p0),
        "assessment": assessment.as_dict(),
        "parameters": parameters,
        "estimates": {n: {"value": float(v), "stderr": float(s), "start": float(s0),
                          "unit": prob.info(n).unit}
                      for n, v, s, s0 in zip(res.names, res.x, res.stderr, res.x0, strict=True)},
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
            fig.savefig(out / f"fit_{label}_{i}.png", dpi=100)
    shape_discs = ("u",) if a.model == "upper" else ("u", "l")
    fig, _ = plot_friction(res.params, discs=shape_discs,
                           title=f"fitted friction, {a.model} configuration")
    fig.savefig(out / "friction.png", dpi=100)
    print(f"\nwrote {out / 'fit.json'} and figures in {out}/")
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


def cmd_fit(a) -> int:
    out = _out_dir(a.out, a.force)
    doc = run_fit(a, out)
    return 0 if doc["success"] else 1


def cmd_multistart(a) -> int:
    from . import inference as E
    from .plots import plot_parameter_spread, plot_waterfall

    out = _out_dir(a.out, a.force)
    exps = _load(a.data, a.model)
    prob, _ = _problem_from_args(a, exps)
    around = None
    if a.around:
        around = _params.resolve(_param_spec(a.around), config=a.model)
    how = (f"log-normal spread {a.spread:.2f} around {a.around}" if around
           else "Latin hypercube over the bounds")
    print(f"multistart: {a.starts} fits of {', '.join(prob.names)} ({how})")
    ms = E.multistart(prob, a.starts, seed=a.seed, around=around, spread=a.spread,
                      workers=a.workers, max_nfev=a.max_nfev, ftol=a.ftol, xtol=a.xtol,
                      gtol=a.gtol)
    order = np.argsort(ms.ssr)
    print("\nbest end points:")
    print(" rank  cluster        SSR   " + " ".join(f"{n:>10}" for n in ms.names))
    for r, i in enumerate(order[: min(10, len(order))]):
        print(f" {r + 1:4d}  {ms.clusters[i]:7d}  {ms.ssr[i]:9.4g}   "
              + " ".join(f"{v:10.4g}" for v in ms.ends[i]))
    summary = ms.summary()
    print("\n" + summary)
    doc = {"config": a.model, "names": ms.names, "starts": ms.starts, "ends": ms.ends,
           "ssr": ms.ssr, "success": ms.success, "clusters": ms.clusters, "summary": summary,
           "data": [str(e.path) for e in exps]}
    (out / "multistart.json").write_text(json.dumps(doc, indent=2, default=_json_default))
    fig, _ = plot_waterfall(ms.ssr, title=f"multistart, {a.model}: sorted final SSR")
    fig.savefig(out / "waterfall.png", dpi=100)
    fig, _ = plot_parameter_spread(ms.names, ms.ends, ms.ssr,
                                   title="end points (colour: log10 SSR above best)")
    fig.savefig(out / "parameter_spread.png", dpi=100)
    (out / "summary.txt").write_text(summary + "\n")
    print(f"\nwrote {out}/multistart.json, waterfall.png, parameter_spread.png, summary.txt")
    return 0


def cmd_demo(a) -> int:
    """The main job on bundled data: the thesis's coupled step from P0, with validation."""
    out = _out_dir(a.out, a.force)
    ns = argparse.Namespace(
        model="coupled", data=["example:coupled_est"], validate=["example:coupled_val"],
        p0="thesis:5.2:P0", base=None, free=None, fixed=None, add=None, without=None,
        channels=None, restarts=6,
        weights=None, prescribed_upper=False, max_nfev=100, ftol=1e-10, xtol=1e-10,
        gtol=1e-10)
    print("rotorbayes demo: least squares on the bundled (synthetic) coupled-configuration "
          "data, from the thesis's P0 (table 5.2)\n")
    doc = run_fit(ns, out)
    return 0 if doc["success"] else 1


def cmd_diagnose(a) -> int:
    """Verdict, ranking of missing effects and missing-torque map of a fit folder."""
    from .diagnosis import diagnose
    from .diagnosis.figures import plot_candidates, plot_torque_map
    from .results import load_fit

    fit = load_fit(a.fit)
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
    _write_text(fit.folder / "diagnosis.json", strict_json(doc))
    fig, _ = plot_candidates(fit.problem, fit.x, d)
    _save_fig(fig, fit.folder / "diagnosis_candidates.png")
    fig, _ = plot_torque_map(d)
    _save_fig(fig, fit.folder / "missing_torque.png")
    print(f"\nwrote {fit.folder}/diagnosis.json, diagnosis_candidates.png, missing_torque.png "
          f"({d.seconds:.1f} s)")
    return 0


def cmd_compare(a) -> int:
    """Where the model fails (one fit) and how the error fell (several, or a chain)."""
    from .diagnosis import compare as C
    from .diagnosis import figures as F
    from .results import load_fit

    fits = [load_fit(f) for f in a.fits]
    if len(fits) == 1:
        fits = fits[0].chain()
        if len(fits) > 1:
            print(f"comparing the chain of {len(fits)} fits that led to {a.fits[0]}")
    last = fits[-1]
    out = Path(a.out) if a.out else last.folder / "compare"
    if out.exists() and any(out.iterdir()) and not a.force and a.out:
        raise CLIError(f"{out}/ already holds results; choose another --out or pass --force")
    out.mkdir(parents=True, exist_ok=True)
    doc = C.compare_fits(fits)
    print(C.table(doc))
    views = C.residual_views(last.problem, last.x)
    for name, (fig, _) in (("error_vs_state.png", F.plot_error_vs_state(views)),
                           ("residual_correlation.png", F.plot_residual_correlation(views))):
        _save_fig(fig, out / name)
    written = ["compare.json", "error_vs_state.png", "residual_correlation.png"]
    if len(fits) > 1:
        fig, _ = F.plot_chain(doc)
        _save_fig(fig, out / "chain.png")
        written.append("chain.png")
    for c, v in views["channels"].items():
        lags, acf = v["acf"]
        outside = float(np.mean(np.abs(acf[lags > 0]) > v["band"]))
        print(f"{c}: {100 * outside:.0f} % of autocorrelation lags 1..{lags.max()} outside the "
              "99 % band of a white residual" + (" (the error is structured, not noise)"
                                                 if outside > 0.05 else ""))
    _write_text(out / "compare.json", strict_json(doc))
    print(f"\nwrote {', '.join(written)} in {out}/")
    return 0


def _write_text(path: Path, text: str) -> None:
    """Write a file atomically (a temporary file beside it, then a rename)."""
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    tmp.replace(path)


def _save_fig(fig, path: Path, dpi: int = 100) -> None:
    import matplotlib.pyplot as plt

    tmp = path.with_name(f".{path.stem}.tmp{path.suffix}")
    fig.savefig(tmp, dpi=dpi)
    plt.close(fig)
    tmp.replace(path)


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
    p.add_argument("--out", required=True, help="output folder")
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
    p.add_argument("--weights", help="channel weights, e.g. theta_l=1,theta_u=0.1")
    p.add_argument("--prescribed-upper", action="store_true",
                   help="drive the lower disc with the measured theta_u")
    p.add_argument("--max-nfev", type=int, default=200, help="evaluation budget per fit")
    p.add_argument("--ftol", type=float, default=1e-10)
    p.add_argument("--xtol", type=float, default=1e-10)
    p.add_argument("--gtol", type=float, default=1e-10)
    p.add_argument("--force", action="store_true", help="overwrite results in --out")


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="rotorbayes", description=__doc__)
    sub = ap.add_subparsers(dest="cmd", required=True)

    s = sub.add_parser("simulate", help="simulate an experiment and write a measurement CSV")
    s.add_argument("--model", default="brake", choices=["upper", "coupled", "brake"])
    s.add_argument("--input", default="est", choices=["est", "val"],
                   help="generated input: est (quasi-random levels) or val (multisine)")
    s.add_argument("--input-file", help="CSV with columns t,u (overrides --input)")
    s.add_argument("--duration", type=float, default=30.0, help="seconds (generated input)")
    s.add_argument("--rate", type=float, default=1000.0, help="samples per second")
    s.add_argument("--seed", type=int, default=0, help="seed of the input and the noise")
    s.add_argument("--params", help="named set (thesis:4.3:P_ref), TOML file or fit.json")
    s.add_argument("--alpha0", type=float, help="initial string torsion [rad]")
    s.add_argument("--add", action="append", metavar="EFFECT",
                   help="switch an effect on (repeatable): a catalogue name or FILE.py:NAME; "
                   "its parameters come from --params (null values otherwise)")
    s.add_argument("--quantize", action="store_true", help="round to encoder counts")
    s.add_argument("--noise", type=float, default=0.0, help="Gaussian noise std [rad]")
    s.add_argument("--out", required=True, help="output CSV")
    s.add_argument("--plot", help="also save a figure (PNG)")
    s.add_argument("--force", action="store_true", help="overwrite --out")
    s.set_defaults(func=cmd_simulate)

    f = sub.add_parser("fit", help="least squares from a start P0")
    _add_fit_args(f)
    f.add_argument("--validate", nargs="*", help="validation CSV file(s)")
    f.add_argument("--p0", help="start: named set (thesis:4.2:P0), TOML or fit.json "
                   "(default: a start computed from the data); a fit.json of an upper-"
                   "configuration fit also fixes the upper-disc parameters it estimated")
    f.add_argument("--restarts", type=int, default=6,
                   help="without --p0: extra fits around the data start when the first one "
                   "ends above 3x the encoder floor")
    f.set_defaults(func=cmd_fit)

    m = sub.add_parser("multistart", help="many fits from spread starts; waterfall and spread")
    _add_fit_args(m)
    m.add_argument("--starts", type=int, default=32)
    m.add_argument("--around", help="spread starts around this set instead of the bounds")
    m.add_argument("--spread", type=float, default=0.3, help="log-sd of the spread")
    m.add_argument("--seed", type=int, default=0)
    m.add_argument("--workers", type=int, default=2, help="parallel fits")
    m.set_defaults(func=cmd_multistart)

    d = sub.add_parser("demo", help="the main job on the bundled example data")
    d.add_argument("--out", default="demo_out")
    d.add_argument("--force", action="store_true")
    d.set_defaults(func=cmd_demo)

    g = sub.add_parser("diagnose", help="is the remaining error noise? which effect is "
                       "missing? (writes diagnosis.json and figures into the fit folder)")
    g.add_argument("fit", help="a folder written by `rotorbayes fit`")
    g.add_argument("--noise", type=float, default=None,
                   help="Gaussian measurement noise std [rad] besides encoder quantisation "
                   "(default 0)")
    g.set_defaults(func=cmd_diagnose)

    c = sub.add_parser("compare", help="where the model fails (error against the state, "
                       "residual correlation) and, for several fits or a chain, how the error "
                       "fell")
    c.add_argument("fits", nargs="+", help="fit folders (one: its chain of --p0 parents)")
    c.add_argument("--out", help="output folder (default: FIT/compare/ of the last fit)")
    c.add_argument("--force", action="store_true", help="overwrite results in --out")
    c.set_defaults(func=cmd_compare)

    p = sub.add_parser("params", help="list parameters and named sets, or show one set")
    p.add_argument("name", nargs="?")
    p.set_defaults(func=cmd_params)

    e = sub.add_parser("effects", help="list the catalogue of physical effects")
    e.add_argument("name", nargs="*", help="show these effects only (NAME or FILE.py:NAME)")
    e.set_defaults(func=cmd_effects)
    return ap


def main(argv=None) -> int:
    ap = build_parser()
    a = ap.parse_args(argv)
    try:
        return a.func(a)
    except (CLIError, DataFileError, _params.ParameterError, ValueError, FileExistsError,
            SimulationError, ResultError) as exc:
        print(f"rotorbayes {a.cmd}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())

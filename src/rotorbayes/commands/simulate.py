"""``rotorbayes simulate``: simulate an experiment and write a measurement CSV."""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from ..io.measurements import save_experiment
from ..io.outputs import check_output_file
from ..model import SimulationError
from ..model import parameters as _params
from ..util.exitcodes import Refused
from .common import Outcome, fit_effects, resolve_values
from .options import (
    CONFIGS,
    MAX_RATE,
    MIN_RATE,
    add_read_options,
    add_trust_option,
    ranged,
    read_spec,
)
from .options import rate as rate_type

HELP = "simulate an experiment and write a measurement CSV"


def add_arguments(s) -> None:
    s.add_argument("--model", default="brake", choices=CONFIGS, help="rig configuration")
    s.add_argument(
        "--input",
        choices=["est", "val"],
        help="generated input: est (quasi-random levels) or val (multisine) (default: est)",
    )
    s.add_argument(
        "--input-file",
        help="CSV or MATLAB .mat file with t [s] and u [V] "
        "(other names and ms: --columns, --time-unit), uniformly sampled; "
        "gives the input, duration and rate (so not with --input, --duration, "
        "--rate)",
    )
    add_read_options(s, angles=False)
    s.add_argument(
        "--duration",
        type=ranged(
            gt=0, le=7200, why=" seconds (experiments on the rig last seconds to about an hour)"
        ),
        help="seconds of generated input, > 0 and <= 7200 (default: 30)",
    )
    s.add_argument(
        "--rate",
        type=rate_type,
        help=f"samples per second, {MIN_RATE:g} to {MAX_RATE:g} (default: 1000)",
    )
    s.add_argument(
        "--seed", type=ranged(int, ge=0), default=0, help="seed of the input and the noise"
    )
    s.add_argument(
        "--params",
        help="named set (thesis:4.3:P_ref), TOML file or fit.json "
        "(default: the configuration's P_ref); a fit of the same --model also "
        "switches on the effects it ran with, user effect files included",
    )
    s.add_argument(
        "--alpha0",
        type=ranged(ge=-10, le=10, why=" rad (the bounds of alpha0)"),
        help="initial string torsion [rad] (default: from --params)",
    )
    s.add_argument(
        "--add",
        action="append",
        metavar="EFFECT",
        help="switch an effect on (repeatable): a catalogue name or FILE.py:NAME; "
        "its parameters come from --params (null values otherwise)",
    )
    s.add_argument("--quantize", action="store_true", help="round to encoder counts")
    s.add_argument(
        "--noise",
        type=ranged(ge=0, why=" rad (a standard deviation)"),
        default=0.0,
        help="Gaussian noise std [rad]",
    )
    s.add_argument("--out", required=True, help="output CSV (its folder must exist)")
    s.add_argument(
        "--plot", help="also save a figure (.png, .pdf, .svg, ...; its folder must exist)"
    )
    s.add_argument("--force", action="store_true", help="overwrite --out and --plot")
    add_trust_option(s)


def read_input_file(path: str, read=None) -> tuple[np.ndarray, np.ndarray]:
    """Read ``t,u`` (and possibly more columns) from a CSV or MATLAB ``.mat`` file.

    ``read`` (a :class:`~rotorbayes.io.rigfiles.ReadSpec`) names the file's columns of t and
    u and the unit of t (s or ms), as for measurement files; a CSV may be separated by
    commas, semicolons or tabs (then with decimal commas).  The time column gets the
    checks of a measurement file (:mod:`rotorbayes.io.measurements`): finite, strictly increasing,
    uniformly sampled, in seconds (a step of ``MAX_SAMPLE_INTERVAL`` or more, or a record
    longer than ``MAX_DURATION``, is refused), and a last line without its line break (a
    truncated file) is refused; messages name the file and the line (a .mat file: the
    sample).
    """
    from ..io import rigfiles
    from ..io.measurements import (
        MAX_ABS_INPUT,
        DataFileError,
        RowProblem,
        check_data_file,
        check_time_unit,
    )

    read = rigfiles.ReadSpec() if read is None else read
    p = Path(path)
    try:
        # A regular file within the size limit, before it is opened (a pipe would wait
        # for a writer, /dev/zero never end); a folder is named below.
        if not p.is_dir():
            check_data_file(p)
    except DataFileError as exc:
        raise Refused(f"--input-file {exc}") from None
    try:
        with open(p, "rb") as fh:
            head = fh.read(520)
        if rigfiles.is_mat_file(head, p.suffix):
            try:
                cols, _ = rigfiles.read_mat(p.read_bytes(), read, ("t", "u"))
            except rigfiles.FormatProblem as exc:
                raise Refused(f"--input-file {p}: {exc}") from None
            t, u = cols["t"], cols["u"]
            rows = list(range(1, t.size + 1))
            unit = "sample"
        else:
            with open(p, encoding="utf-8-sig", newline=None) as fh:
                lines = fh.read().split("\n")
            t, u, rows = _input_csv(p, lines, read)
            unit = "line"
    except FileNotFoundError:
        raise Refused(
            f"--input-file {p}: file not found (looked in {p.resolve().parent}); check the path"
        ) from None
    except IsADirectoryError:
        raise Refused(f"--input-file {p}: is a folder; give the CSV file inside it") from None
    except UnicodeDecodeError:
        raise Refused(
            f"--input-file {p}: not a UTF-8 text file; export the input as "
            "plain-text CSV with columns t,u"
        ) from None
    except OSError as exc:
        raise Refused(f"--input-file {p}: cannot be read ({exc.strerror})") from None
    if len(t) < 3:
        raise Refused(f"{p}: only {len(t)} data row(s); an input needs at least 3")
    t, u = np.asarray(t, float), np.asarray(u, float)
    t = read.to_si({"t": t})["t"]
    for name, col in (("t", t), ("u", u)):
        bad = np.flatnonzero(~np.isfinite(col))
        if bad.size:
            raise Refused(
                f"{p}, {unit} {rows[bad[0]]}: {name} is {col[bad[0]]!r}; every value "
                "must be a finite number"
            )
    bad = np.flatnonzero(np.abs(u) > MAX_ABS_INPUT)
    if bad.size:
        raise Refused(
            f"{p}, {unit} {rows[bad[0]]}: u is {float(u[bad[0]])!r} V: no amplifier "
            f"of the rig gives more than {MAX_ABS_INPUT:g} V; the value is corrupt "
            "or not in volts -- repair the file"
        )
    d = np.diff(t)
    bad = np.flatnonzero(d <= 0)
    if bad.size:
        raise Refused(
            f"{p}, {unit} {rows[bad[0] + 1]}: time {t[bad[0] + 1]!r} is not after "
            f"{t[bad[0]]!r}; time must increase from row to row"
        )
    try:
        check_time_unit(t, d)
    except RowProblem as exc:
        raise Refused(f"{p}, {unit} {rows[exc.row]}: {exc.problem}") from None
    step = float(np.median(d))
    dev = np.abs(d - step) / step
    bad = np.flatnonzero(dev > 1e-6)
    if bad.size:
        raise Refused(
            f"{p}, {unit} {rows[bad[0] + 1]}: time step {d[bad[0]]:.9g} s differs "
            f"from the median step {step:.9g} s; time must be uniformly sampled -- "
            "resample the input first"
        )
    if not MIN_RATE <= 1.0 / step <= MAX_RATE:
        raise Refused(
            f"{p}: sampled at {1.0 / step:.6g} Hz (step {step:.6g} s); simulate "
            f"needs {MIN_RATE:g} Hz to {MAX_RATE:g} Hz (the rig's encoders are read "
            "at 1 kHz); resample the input"
        )
    return t - t[0], u


def _input_csv(p: Path, lines: list[str], read) -> tuple[list, list, list]:
    """t, u and their line numbers from the lines of a CSV input file."""
    from ..io import rigfiles

    numbered = [
        (k, ln)
        for k, ln in enumerate(lines, start=1)
        if ln.strip() and not ln.lstrip().startswith("#")
    ]
    if not numbered:
        raise Refused(f"{p}: the file is empty; it needs a header 't,u' and rows of numbers")
    hline, htext = numbered[0]
    sep = ";" if ";" in htext else "\t" if "\t" in htext else ","
    comma = sep != ","
    header = [h.strip().strip('"').strip() for h in htext.split(sep)]
    nt, nu = read.name_of("t"), read.name_of("u")
    if nt not in header or nu not in header:
        raise Refused(
            f"{p}, line {hline}: the header {htext!r} must contain the columns "
            f"{nt} and {nu}"
            + (" (comma-separated)" if not read.columns else "")
            + "; name the file's columns with --columns t=NAME,u=NAME"
        )
    it, iu = header.index(nt), header.index(nu)
    # A complete file ends with a line break; without one the last number may be cut.
    if lines[-1].strip() and len(numbered) > 1 and not lines[-1].lstrip().startswith("#"):
        raise Refused(
            f"{p}, line {len(lines)}: the last line {lines[-1].strip()[:80]!r} "
            "does not end with a line break: the file looks truncated (cut while "
            "being written or copied), so its last number may be incomplete; copy "
            "the file again, or delete the last line (if it is complete, end it "
            "with a line break)"
        )
    t, u, rows = [], [], []
    for k, ln in numbered[1:]:
        f = ln.split(sep)
        try:
            if len(f) != len(header):
                raise ValueError
            tk = rigfiles.parse_number(f[it].strip().strip('"'), comma)
            uk = rigfiles.parse_number(f[iu].strip().strip('"'), comma)
        except ValueError:
            raise Refused(
                f"{p}, line {k}: {ln.strip()!r} is not a row of {len(header)} numbers "
                f"matching the header {htext.strip()!r}"
            ) from None
        t.append(tk)
        u.append(uk)
        rows.append(k)
    return t, u, rows


def check_plot_format(path: Path) -> None:
    """Refuse a figure file name whose format matplotlib cannot write."""
    from matplotlib.backend_bases import FigureCanvasBase

    kinds = FigureCanvasBase.get_supported_filetypes()
    ext = path.suffix[1:].lower()
    if ext and ext not in kinds:
        raise Refused(
            f"--plot {path}: cannot write a .{ext} figure; use one of "
            f"{', '.join('.' + k for k in sorted(kinds))} (e.g. --plot "
            f"{path.with_suffix('.png')})"
        )


def simulate(
    out: str,
    *,
    model: str = "brake",
    input: str | None = None,
    input_file: str | None = None,
    duration: float | None = None,
    rate: float | None = None,
    seed: int = 0,
    params: str | None = None,
    alpha0: float | None = None,
    add: list[str] | None = None,
    quantize: bool = False,
    noise: float = 0.0,
    plot: str | None = None,
    force: bool = False,
    trust_effects: bool = False,
    columns=None,
    time_unit: str | None = None,
) -> Outcome:
    """Simulate one experiment of the ``model`` configuration and write it to the CSV file
    ``out`` (a measurement file whose header records how to make it again).

    The input is generated (``input`` "est" or "val", ``duration`` s at ``rate`` Hz,
    ``seed``) or read from ``input_file`` (columns t,u, or those ``columns`` names, e.g.
    "t=Time,u=Volt"; time in ``time_unit``, s or ms; a CSV or MATLAB .mat file). ``params``
    is a named set, TOML file or fit.json (default: the configuration's P_ref; a fit of the
    same configuration brings the effects it ran with, its user effect files checked as
    every command checks them: ``trust_effects`` imports one that changed since); ``add``
    switches effects on; ``quantize`` rounds to encoder counts, ``noise`` adds Gaussian
    noise [rad]; ``plot`` also saves a figure. ``Outcome.doc`` holds the file's header.
    """
    from ..io.outputs import tmp_name
    from ..model import Model
    from ..model import simulate as run_simulation
    from ..model.signals import make_signal

    # Everything the user can get wrong is checked before the simulation.
    if not input_file and (columns or time_unit):
        raise Refused(
            "--columns and --time-unit say how to read --input-file; give the "
            "file, or leave them out"
        )
    if input_file:
        ignored = [
            flag
            for flag, v in (("--duration", duration), ("--rate", rate), ("--input", input))
            if v is not None
        ]
        if ignored:
            raise Refused(
                f"--input-file {input_file} gives the input, its duration and its sampling "
                f"rate (the t column), so {' and '.join(ignored)} would be ignored; leave "
                f"{'it' if len(ignored) == 1 else 'them'} out (resample the file to change the "
                "rate)"
            )
    out = check_output_file(out, flag="--out", force=force, example="sim.csv")
    fig_path = None
    if plot:
        fig_path = check_output_file(plot, flag="--plot", force=force, example="sim.png")
        check_plot_format(fig_path)
        if fig_path.resolve() == out.resolve():
            raise Refused(f"--plot {fig_path} is the --out file; give the figure another name")
    # A fit's effects travel with its values (as with fit --p0): without them its user
    # effect's parameters would be dropped and the simulation would not be the fit's.
    inherited = [e for e in fit_effects(params, model, trust_effects) if e not in (add or ())]
    effects = [*inherited, *(add or ())]
    m = Model(model, effects)
    try:
        values = resolve_values(params, m)
    except _params.ParameterError as exc:
        raise Refused(
            f"--params {params}: {exc}" if params and str(params) not in str(exc) else str(exc)
        ) from None
    if input_file:
        read = read_spec(columns, time_unit)
        t, u = read_input_file(input_file, read)
        # How it was read is part of making the file again (its names, its time unit).
        source = " ".join([input_file, read.options()]).strip()
    else:
        input = input or "est"
        duration = 30.0 if duration is None else duration
        rate = 1000.0 if rate is None else rate
        t, u = make_signal(input, duration, rate=rate, seed=seed)
        source = f"{input} seed={seed}"
    dt = float(t[1] - t[0])
    t0 = time.perf_counter()
    try:
        sim = run_simulation(
            values,
            u,
            dt=dt,
            config=model,
            alpha0=alpha0,
            effects=effects,
            quantize_angles=quantize,
            noise_std=noise,
            seed=seed,
        )
    except SimulationError as exc:
        where = f"the values of --params {params}" if params else "these parameter values"
        raise Refused(f"{exc} ({where}); change the value named") from None
    el = time.perf_counter() - t0
    # The header records everything needed to make the file again.
    meta = {
        "source": "rotorbayes simulate (synthetic)",
        "config": model,
        "input": source,
        "rate_hz": f"{1 / dt:.10g}",
        "duration_s": f"{t[-1]:.10g}",
        "params": params or f"default ({_params.DEFAULT_SET[model]})",
        "effects": ", ".join(m.effect_names) or "none",
        "added_effects": ", ".join(effects) or "none",
        "alpha0": sim.params["alpha0"],
        "quantized": quantize,
        "noise_std": noise,
        "seed": seed,
    }
    meta.update({f"param.{n}": repr(float(v)) for n, v in sim.params.items()})
    fig_tmp = None
    try:
        if fig_path is not None:
            import matplotlib.pyplot as plt

            from ..figures.plots import plot_simulation

            fig, _ = plot_simulation(sim)
            fig_tmp = tmp_name(fig_path)
            fig.savefig(fig_tmp, dpi=110, format=fig_path.suffix[1:] or None)
            plt.close(fig)
        save_experiment(sim.to_experiment(), out, overwrite=force, meta=meta)
        if fig_tmp is not None:
            os.replace(fig_tmp, fig_path)
    except FileExistsError:
        raise
    except OSError as exc:
        target = fig_path if fig_tmp is not None and out.exists() else out
        raise Refused(
            f"cannot write {target} ({exc.strerror or exc}); check that its folder "
            "is writable and has space, or choose another path"
        ) from None
    finally:
        if fig_tmp is not None and fig_tmp.exists():
            fig_tmp.unlink()
    if inherited:
        print(f"effects carried over from {params}: {', '.join(inherited)}")
    n_stick = int(np.sum(sim.events[:, 2] == 0)) if sim.events.size else 0
    print(
        f"simulated {model} configuration, {sim.t[-1]:.1f} s at {1 / dt:.0f} Hz in "
        f"{1e3 * el:.1f} ms; {len(sim.events)} stick/slip switches ({n_stick} stick onsets)"
    )
    if sim.theta_l is not None:
        print(
            f"lower disc sticks {100 * sim.stick_fraction('l'):.1f} % of the time; "
            f"string torsion {sim.alpha.min():.3f} .. {sim.alpha.max():.3f} rad"
        )
    print(f"wrote {out}")
    if fig_path is not None:
        print(f"wrote {fig_path}")
    return Outcome(doc=meta)

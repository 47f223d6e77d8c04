"""Command-line options shared by several commands: checked number types and option
groups (the fit options, where parallel tasks run, trusting effect files)."""

from __future__ import annotations

import argparse
import math

from ..model.simulate import default_step

#: Sampling rates a simulated measurement may have (Hz). Below 100 Hz the samples cannot
#: follow the rig: the inputs have content up to 5 Hz, the stick-slip switches of the lower
#: disc last milliseconds and the encoders' steps (1e-4 rad) are crossed many times per
#: sample; the thesis's rig is sampled at 1 kHz. Above 100 kHz no encoder of the rig is read.
MIN_RATE, MAX_RATE = 100.0, 1e5
#: Upper limits of sample's sizes: beyond them a run would not end or fit on a disk.
MAX_WALKERS, MAX_STEPS = 10_000, 10_000_000
#: Most residual evaluations of one fit (as an analysis file's [fit] max_nfev), most
#: restarts of a fit from the data and most starts of a multistart: beyond them a run
#: would not end.
MAX_NFEV, MAX_RESTARTS, MAX_STARTS = 1_000_000, 100, 100_000
#: Range of the convergence tolerances (relative changes): below 1e-15 a tolerance is
#: under the machine's precision (scipy disables it, and refuses when all three are), above
#: 0.1 a fit stops before it has moved.
MIN_TOL, MAX_TOL = 1e-15, 0.1
#: The rig's configurations (``--model``).
CONFIGS = ["upper", "coupled", "brake"]
#: How a fit's Jacobian may be computed (``--jacobian``; the analysis file's [fit] jacobian).
JACOBIAN_METHODS = ["differences", "sensitivity"]


def number(text: str, kind=float) -> float:
    """``text`` as a finite number (or a whole number when ``kind`` is int)."""
    try:
        v = kind(text)
    except ValueError:
        what = "a whole number" if kind is int else "a number"
        raise argparse.ArgumentTypeError(f"{text!r} is not {what}") from None
    if kind is float and not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"{text!r}: give a finite number")
    return v


def ranged(
    kind=float,
    *,
    gt: float | None = None,
    ge: float | None = None,
    le: float | None = None,
    why: str = "",
):
    """An argparse ``type``: a finite number with ``> gt``, ``>= ge`` and ``<= le``; the
    message names the value given, the allowed range and ``why`` it is needed."""

    def parse(text: str):
        v = number(text, kind)
        if (
            (gt is not None and v <= gt)
            or (ge is not None and v < ge)
            or (le is not None and v > le)
        ):
            cond = " and ".join(
                c
                for c in (
                    f"> {gt:g}" if gt is not None else "",
                    f">= {ge:g}" if ge is not None else "",
                    f"<= {le:g}" if le is not None else "",
                )
                if c
            )
            what = "a whole number" if kind is int else "a number"
            raise argparse.ArgumentTypeError(f"got {text}; give {what} {cond}{why}")
        return v

    parse.__name__ = "number"  # argparse names the type in its own messages
    return parse


def rate(text: str) -> float:
    """An argparse ``type``: a sampling rate the rig's encoders can have (Hz)."""
    v = number(text)
    if v < MIN_RATE:
        raise argparse.ArgumentTypeError(
            f"got {text} Hz, too slow for the rig: the stick-slip switches of the lower disc "
            f"last milliseconds and the inputs have content up to 5 Hz, so the encoders must be "
            f"sampled at {MIN_RATE:g} Hz or more (the rig uses 1000 Hz, the default; the "
            "bundled examples 200 Hz); give --rate 100 or more"
        )
    if v > MAX_RATE:
        raise argparse.ArgumentTypeError(
            f"got {text} Hz, faster than the rig's encoders are ever read ({MAX_RATE:g} Hz at "
            "most; it also makes huge files); give --rate between 100 and 100000"
        )
    return v


def add_fit_options(p) -> None:
    """The options of ``fit`` and ``multistart``: model, data, what is free, the budget."""
    p.add_argument("--model", required=True, choices=CONFIGS, help="rig configuration")
    p.add_argument(
        "data",
        nargs="+",
        help="measurement file(s): CSV (commas, or semicolons "
        "or tabs with decimal commas), MATLAB .mat (v5 or v7.3), or example:NAME",
    )
    p.add_argument(
        "--out",
        required=True,
        help="output folder (created, with missing parent folders; it appears only "
        "when the run succeeds)",
    )
    p.add_argument(
        "--free",
        help="comma-separated parameters to estimate (default: the "
        "configuration's, plus alpha0 per experiment with several experiments)",
    )
    p.add_argument("--fixed", help="comma-separated parameters to keep fixed")
    p.add_argument(
        "--base",
        help="values of all parameters not estimated (named set, TOML "
        "or fit.json); default: --p0, else the configuration's P_ref",
    )
    p.add_argument(
        "--add",
        action="append",
        metavar="EFFECT",
        help="switch an effect on and free its parameters (repeatable): a catalogue "
        "name (see `rotorbayes effects`) or FILE.py:NAME for your own effect",
    )
    p.add_argument(
        "--without",
        action="append",
        metavar="EFFECT",
        help="switch off an effect of the configuration's base model (repeatable)",
    )
    p.add_argument("--channels", help="theta_l, theta_u or theta_l,theta_u")
    p.add_argument(
        "--weights",
        metavar="CHANNEL=W,...",
        help="channel weights (> 0), e.g. theta_l=1,theta_u=0.1 (default: 1 each)",
    )
    p.add_argument(
        "--prescribed-upper",
        action="store_true",
        help="drive the lower disc with the measured theta_u",
    )
    p.add_argument(
        "--max-nfev",
        type=ranged(int, ge=1, le=MAX_NFEV, why=" (residual evaluations)"),
        default=200,
        metavar="N",
        help="evaluation budget per fit",
    )
    for tol in ("ftol", "xtol", "gtol"):
        p.add_argument(
            f"--{tol}",
            type=ranged(
                ge=MIN_TOL,
                le=MAX_TOL,
                why=" (a relative "
                "convergence tolerance: below 1e-15 it is under the machine's "
                "precision, above 0.1 the fit stops before it has moved)",
            ),
            default=1e-10,
            help=f"{tol} of scipy.optimize.least_squares",
        )
    p.add_argument(
        "--jacobian",
        choices=JACOBIAN_METHODS,
        default=None,
        help="how each fit's Jacobian is computed: 'differences' (forward differences, "
        "the default) or 'sensitivity' (the kernel's forward sensitivities, exact, each "
        "step's rows reduced for the optimiser: a 48-start brake multistart in about a "
        "third of the CPU time; the first use compiles them once, about 30 s); models the "
        "kernel cannot differentiate use differences and say so",
    )
    p.add_argument(
        "--step",
        type=ranged(gt=0, why=" (seconds)"),
        default=None,
        metavar="SECONDS",
        help="largest Runge-Kutta step of the simulation (default: "
        f"{1e3 * default_step(1e-3):.0f} ms at 1 kHz, "
        "shorter over fast input transitions), from a hundredth of the sample "
        "interval to the record's length; give it when the fit's integration "
        "check says the integrator's own error is material; kept in fit.json",
    )
    p.add_argument(
        "--keep-glitches",
        action="store_true",
        help="fit samples that jump against their neighbours by far more than "
        "the discs can move (encoder spikes) as measured; by default each is "
        "named and left out (replaced by the cubic through its neighbours)",
    )
    add_read_options(p)
    p.add_argument(
        "--force",
        action="store_true",
        help="replace the results in --out (only once the new run has succeeded)",
    )
    add_trust_option(p)


def add_read_options(p, *, angles: bool = True) -> None:
    """How to read a rig's own data files (:class:`rotorbayes.io.rigfiles.ReadSpec`): the
    file's names of the signals and their units; ``angles=False`` for a file of t and u."""
    sigs = "t=NAME,u=NAME" + (",theta_u=NAME,theta_l=NAME" if angles else "")
    p.add_argument(
        "--columns",
        metavar=sigs,
        help="the data file's names of the signals, e.g. t=Time,u=Volt"
        + (",theta_u=Enc1,theta_l=Enc2" if angles else "")
        + " (CSV columns; in a .mat file MATLAB names such as ScopeData.time, "
        "ScopeData.signals(2).values or data(:,3)); the file's other columns are "
        "ignored (default: the signals' own names)",
    )
    p.add_argument(
        "--time-unit", choices=["s", "ms"], default=None, help="unit of the data's time (default s)"
    )
    if angles:
        p.add_argument(
            "--angle-unit",
            choices=["rad", "deg", "counts"],
            default=None,
            help="unit of the data's angles: rad, deg, or encoder counts (see "
            "--counts-per-rev) (default rad)",
        )
        p.add_argument(
            "--counts-per-rev",
            metavar="theta_u=N,theta_l=N",
            help="encoder counts per revolution for --angle-unit counts (one "
            "number for both encoders; default the rig's: theta_u=54934.256, "
            "theta_l=40000)",
        )


def read_spec(columns=None, time_unit=None, angle_unit=None, counts_per_rev=None):
    """The :class:`~rotorbayes.io.rigfiles.ReadSpec` the read options give; Refused naming
    the option for a bad value."""
    from ..io.rigfiles import FormatProblem, ReadSpec
    from ..util.exitcodes import Refused

    try:
        return ReadSpec.from_options(columns, time_unit, angle_unit, counts_per_rev)
    except FormatProblem as exc:
        text = str(exc)
        opt = (
            "--columns"
            if text.startswith("columns")
            else "--counts-per-rev"
            if text.startswith("counts")
            else "--time-unit"
            if text.startswith("time")
            else "--angle-unit"
        )
        raise Refused(f"{opt}: {text}") from None


def add_parallel_options(p, what: str, backend_help: str | None = None) -> None:
    """Where the independent tasks run (rotorbayes.inference.parallel); ``backend_help``
    replaces the ``--backend`` help for a command whose default differs."""
    from ..inference.parallel import (
        BACKENDS,
        DEFAULT_BACKEND,
        PROCESSES_FROM_RESIDUALS,
        SCHEDULER_ENV,
        default_backend,
    )

    # A small machine's default takes processes for long work (parallel.DefaultPool).
    long = (
        ", processes for long work"
        if DEFAULT_BACKEND == "threads"
        and default_backend(None, 1, PROCESSES_FROM_RESIDUALS) == "processes"
        else ""
    )
    p.add_argument(
        "--backend",
        choices=BACKENDS,
        default=None,
        help=backend_help
        or f"where the {what} run: serial, local threads "
        f"(default {DEFAULT_BACKEND!r}{long}; the command says which), local "
        "processes, or dask (a local Dask "
        "cluster of --workers processes, or the scheduler given by --scheduler or "
        f"{SCHEDULER_ENV})",
    )
    p.add_argument(
        "--workers",
        type=ranged(int, ge=1, le=256, why=" (parallel workers)"),
        default=None,
        metavar="N",
        help=f"parallel {what} (threads, processes or local Dask workers; default "
        "the number of cores)",
    )
    p.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help=f"run the {what} on this Dask scheduler (e.g. tcp://host:8786; "
        f"default ${SCHEDULER_ENV} if set); see the README on starting one",
    )


def add_changed_data_option(p) -> None:
    """``--accept-changed-data``: for commands that read a fit's data files again."""
    p.add_argument(
        "--accept-changed-data",
        action="store_true",
        help="use the fit's data files even where one changed since the fit (its "
        "SHA-256 no longer matches the one fit.json recorded; without this such a "
        "file is refused, naming it and both hashes)",
    )


def add_trust_option(p) -> None:
    """``--trust-effects``: for commands that read results naming user effect files."""
    p.add_argument(
        "--trust-effects",
        action="store_true",
        help="import user effect files a result names even when they changed "
        "since the result was made, or it recorded no hash of them (effect files "
        "are Python code: read them first)",
    )

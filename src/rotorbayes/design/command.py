"""``rotorbayes design FIT --out next/``: the command-line face of :func:`.design_input`.

:func:`add_parser` declares the options on a subparser, :func:`run` is the command; the
command table in :mod:`rotorbayes.cli` registers both.  Errors a user can fix are
``ValueError`` subclasses (:class:`.DesignError`, :class:`~rotorbayes.outputs.OutputError`,
:class:`~rotorbayes.results.ResultError`): exit code 2, one line, nothing written.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import sys

from ..signals import MAX_VOLTAGE
from .core import DEFAULT_EVALS, NO_INPUT
from .inputs import FAMILIES, MAX_BAND_HZ

HELP = ("design the next experiment: the input that pins the fit's sloppiest direction "
        "(or --params, or that separates two --separate effects), checked by simulation "
        "and refit; u.csv, design.json, design.txt and a figure in --out")


def _positive(kind=float, *, le: float | None = None, what: str = ""):
    def parse(text: str):
        try:
            v = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        if not (math.isfinite(v) and v > 0) or (le is not None and v > le):
            rng = f"between 0 and {le:g}" if le is not None else "above 0"
            raise argparse.ArgumentTypeError(f"got {text}; give a number {rng}{what}")
        return v

    parse.__name__ = "number"
    return parse


def add_parser(sub, *, parallel=None, trust=None):
    """Declare ``design`` on the subparsers ``sub``; ``parallel(p, what)`` and ``trust(p)``
    add the shared executor and --trust-effects options."""
    p = sub.add_parser("design", help=HELP, description=HELP)
    p.add_argument("fit", help="a folder written by `rotorbayes fit` (the existing data)")
    p.add_argument("--out", required=True, help="folder for u.csv, design.json, design.txt "
                   "and design.png (refused if it holds results, unless --force)")
    p.add_argument("--separate", metavar="EFFECT_A,EFFECT_B",
                   help="design to tell two catalogue effects apart (each fitted to the "
                   "existing data first); when the registry says no input can, say why "
                   "and what can")
    p.add_argument("--params", metavar="NAME,...",
                   help="design to pin these free parameters (default: the fit's sloppiest "
                   "Fisher direction)")
    p.add_argument("--duration", type=_positive(what=" seconds"), default=None,
                   help="length of the new experiment [s] (default: the data's)")
    p.add_argument("--rate", type=_positive(what=" Hz"), default=None,
                   help="sampling rate [Hz] (default: the data's)")
    p.add_argument("--max-volts", type=_positive(), default=MAX_VOLTAGE,
                   help=f"largest |u| [V]; the amplifier allows at most {MAX_VOLTAGE:g} V")
    p.add_argument("--band-hz", type=_positive(), default=MAX_BAND_HZ,
                   help="band limit of the input [Hz] (no energy above it; the thesis's "
                   f"signals stay below {MAX_BAND_HZ:g} Hz)")
    p.add_argument("--family", choices=FAMILIES, default="steps",
                   help="input family: Hann-smoothed steps (like the estimation signal) or "
                   "a faded multisine")
    p.add_argument("--starts", type=_positive(int, le=256), default=4,
                   help="optimisation starts (one is the standard estimation input's levels)")
    p.add_argument("--max-evals", type=_positive(int), default=DEFAULT_EVALS,
                   help="evaluations per start (each one Jacobian on the new input)")
    p.add_argument("--seed", type=int, default=0, help="seed of the random starts and of "
                   "the estimation input compared against")
    p.add_argument("--no-check", action="store_true",
                   help="skip the self-check (simulate the design, refit with the data)")
    p.add_argument("--force", action="store_true",
                   help="replace the results in --out (only once the new design is done)")
    if parallel is not None:
        parallel(p, "optimisation starts")
    if trust is not None:
        trust(p)
    p.set_defaults(func=run, cmd="design")
    return p


def _csv(text: str | None) -> list[str] | None:
    if text is None:
        return None
    return [x.strip() for x in text.split(",") if x.strip()]


def run(a) -> int:
    """The ``design`` command."""
    from ..inference import parallel as P
    from ..outputs import output_folder
    from .core import design_input
    from .output import write_into

    opts = (getattr(a, "backend", None), getattr(a, "workers", None),
            getattr(a, "scheduler", None))
    with output_folder(a.out, a.force) as tmp:
        if P.current_executor() is not None and opts == (None, None, None):
            ctx = contextlib.nullcontext()  # inside a study: its executor
        else:
            spec = P.choose(*opts)
            if spec.backend != P.DEFAULT_BACKEND or spec.source != "default":
                print(f"parallel tasks run {spec.describe()}", flush=True)
            ctx = P.use_executor(spec)
        with ctx:
            res = design_input(
                a.fit, params=_csv(a.params), separate=_csv(a.separate),
                duration=a.duration, rate=a.rate, max_volts=a.max_volts,
                band_hz=a.band_hz, family=a.family, starts=int(a.starts), seed=a.seed,
                max_evals=int(a.max_evals), check=not a.no_check,
                trust_effects=getattr(a, "trust_effects", False))
        print(res.text())
        write_into(res, tmp, command="rotorbayes " + " ".join(getattr(a, "_argv", [])))
    print(f"wrote u.csv, design.json, design.txt, design.png in {a.out}/")
    if res.status == NO_INPUT:
        print("no input was designed: follow the procedure above", file=sys.stderr)
    return 0

"""``rotorbayes design FIT --out next/``: the next experiment's input (issue 20).

The command-line face of :func:`rotorbayes.design.design_input`: the input that pins the
fit's sloppiest direction (or ``--params``), or that separates two or more ``--separate``
effects (every pair; the worst-separated pair limits the design), checked by simulation
and refit; ``u.csv``, ``design.json``, ``design.txt`` and
``design.png`` in ``--out`` (refused if it holds results, unless ``--force``).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

from ..design.core import DEFAULT_EVALS, NO_INPUT
from ..design.inputs import FAMILIES, MAX_BAND_HZ
from ..model.signals import MAX_VOLTAGE
from .common import Outcome, csv_list
from .config import ExecutorOptions
from .options import add_changed_data_option, add_parallel_options, add_trust_option, ranged

HELP = (
    "design the next experiment: the input that pins the fit's sloppiest direction (or "
    "--params), or that separates two or more --separate effects, checked by "
    "simulation and refit; u.csv, design.json, design.txt, design.png"
)


def add_arguments(p) -> None:
    p.add_argument("fit", help="a folder written by `rotorbayes fit` (the existing data)")
    p.add_argument(
        "--out",
        required=True,
        help="folder for u.csv, design.json, design.txt "
        "and design.png (refused if it holds results, unless --force)",
    )
    p.add_argument(
        "--separate",
        metavar="EFFECT_A,EFFECT_B[,...]",
        help="design to tell two or more catalogue effects apart (each fitted to "
        "the existing data first; the smallest gap over every pair is "
        "maximised); for a pair the registry says no input can separate, say why "
        "and what can",
    )
    p.add_argument(
        "--params",
        metavar="NAME,...",
        help="design to pin these free parameters (default: the fit's sloppiest Fisher direction)",
    )
    p.add_argument(
        "--duration",
        type=ranged(gt=0, why=" seconds"),
        default=None,
        help="length of the new experiment [s] (default: the data's)",
    )
    p.add_argument(
        "--rate",
        type=ranged(gt=0, why=" Hz"),
        default=None,
        help="sampling rate [Hz] (default: the data's)",
    )
    p.add_argument(
        "--max-volts",
        type=ranged(gt=0, why=" volts"),
        default=MAX_VOLTAGE,
        help=f"largest |u| [V]; the amplifier allows at most {MAX_VOLTAGE:g} V",
    )
    p.add_argument(
        "--band-hz",
        type=ranged(gt=0, why=" Hz"),
        default=MAX_BAND_HZ,
        help="band limit of the input [Hz] (no energy above it; the thesis's "
        f"signals stay below {MAX_BAND_HZ:g} Hz)",
    )
    p.add_argument(
        "--family",
        choices=FAMILIES,
        default="steps",
        help="input family: Hann-smoothed steps (like the estimation signal) or a faded multisine",
    )
    p.add_argument(
        "--starts",
        type=ranged(int, ge=1, le=256, why=" (optimisation starts)"),
        default=4,
        help="optimisation starts (for steps, one is the standard estimation input's levels)",
    )
    p.add_argument(
        "--max-evals",
        type=ranged(int, ge=1, why=" (evaluations per start)"),
        default=DEFAULT_EVALS,
        help="evaluations per start (each one Jacobian on the new input)",
    )
    p.add_argument(
        "--seed",
        type=int,
        default=0,
        help="seed of the random starts and of the estimation input compared against",
    )
    p.add_argument(
        "--no-check",
        action="store_true",
        help="skip the self-check (simulate the design at the fit, refit with the data)",
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="replace the results in --out (only once the new design is done)",
    )
    add_parallel_options(p, "optimisation starts")
    add_trust_option(p)
    add_changed_data_option(p)


def design(
    fit: str,
    *,
    out: str,
    separate: str | None = None,
    params: str | None = None,
    duration: float | None = None,
    rate: float | None = None,
    max_volts: float = MAX_VOLTAGE,
    band_hz: float = MAX_BAND_HZ,
    family: str = "steps",
    starts: int = 4,
    max_evals: int = DEFAULT_EVALS,
    seed: int = 0,
    no_check: bool = False,
    force: bool = False,
    backend: str | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    trust_effects: bool = False,
    accept_changed_data: bool = False,
) -> Outcome:
    """Design the next experiment for the fit folder ``fit`` and write ``out``
    (:func:`rotorbayes.design.design_input`, :func:`rotorbayes.design.write_into`).
    ``Outcome.doc`` is design.json."""
    from ..design import design_input, write_into
    from ..io.outputs import output_folder

    for name, v in (("--duration", duration), ("--rate", rate)):
        if v is not None and not (math.isfinite(v) and v > 0):
            raise ValueError(f"{name} {v}: give a positive number")
    with output_folder(out, force, inputs=[fit]) as tmp:
        with ExecutorOptions(backend=backend, workers=workers, scheduler=scheduler).open():
            res = design_input(
                fit,
                params=csv_list(params, "--params"),
                separate=csv_list(separate, "--separate"),
                duration=duration,
                rate=rate,
                max_volts=max_volts,
                band_hz=band_hz,
                family=family,
                starts=int(starts),
                seed=seed,
                max_evals=int(max_evals),
                check=not no_check,
                trust_effects=trust_effects,
                accept_changed_data=accept_changed_data,
            )
        print(res.text())
        write_into(res, tmp, command="rotorbayes design " + str(fit))
    print(f"wrote u.csv, design.json, design.txt, design.png in {out}/")
    if res.status == NO_INPUT:
        print("no input was designed: follow the procedure above", file=sys.stderr)
    from ..design.output import design_document

    return Outcome(folder=Path(out), doc=design_document(res))

"""Design the next experiment (issue 20): the input that pins what the data leave loose,
or that separates candidate effects — and, when no input can, the procedure that can.

* :mod:`.inputs` — the input families (smoothed steps, a faded multisine) within the rig's
  limits (``|u| <= 5 V``, band <= 5 Hz, at rest at both ends);
* :mod:`.information` — what a new experiment adds: Fisher information along a direction,
  the separation gap between two candidate models (linearised);
* :mod:`.ties` — the registry's exact equivalences that no input breaks;
* :mod:`.core` — :func:`design_input`: target, search over several starts through the
  executor layer, prediction, and the self-check by simulation and refit;
* :mod:`.output` — the ``next/`` folder (``u.csv``, ``design.json``, ``design.txt``, a figure);
  the command itself is :mod:`rotorbayes.commands.design`.

Example::

    from rotorbayes.design import design_input, write_design
    res = design_input("fit/", starts=4)
    print(res.text())
    write_design(res, "next/")
"""

from .core import DESIGNED, LITTLE_GAIN, NO_INPUT, DesignError, DesignResult, design_input
from .inputs import FAMILIES, MAX_BAND_HZ, DesignInputError, Multisine, Steps, make_family
from .output import design_document, input_csv, plot_design, write_design, write_into

__all__ = [
    "DESIGNED", "LITTLE_GAIN", "design_document", "NO_INPUT", "DesignError", "DesignInputError",
    "DesignResult", "FAMILIES", "MAX_BAND_HZ", "Multisine", "Steps", "design_input",
    "input_csv", "make_family", "plot_design", "write_design", "write_into",
]  # fmt: skip

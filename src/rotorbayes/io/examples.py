"""The bundled synthetic example data (see docs/example_data.md)."""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

from .measurements import Experiment, load_experiment

#: Folder of the bundled example CSV files: the package data, found through
#: importlib.resources (an installed rotorbayes is a folder on disk, as numba's cache needs).
EXAMPLES = Path(str(files("rotorbayes") / "data" / "examples"))


def example_names() -> list[str]:
    """Names of the bundled example files (``'coupled_est'``, ...)."""
    return sorted(p.stem for p in EXAMPLES.glob("*.csv"))


def example_path(name: str) -> Path:
    """Path of a bundled example file; ``name`` may carry an ``example:`` prefix."""
    stem = name.split(":", 1)[1] if name.startswith("example:") else name
    p = EXAMPLES / f"{stem}.csv"
    if not p.exists():
        raise ValueError(f"no bundled example {stem!r}; available: {', '.join(example_names())}")
    return p


def load_example(name: str) -> Experiment:
    """Load a bundled example as an :class:`~rotorbayes.io.measurements.Experiment`."""
    p = example_path(name)
    return load_experiment(p, expect_lower=not p.stem.startswith("upper"))

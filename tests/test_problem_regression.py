"""The numbers of estimation problems and log posteriors stay the same, bit for bit.

``tests/data/problem_regression.npz`` holds a few synthetic experiments and what
:class:`~rotorbayes.inference.Problem` and
:class:`~rotorbayes.inference.likelihood.LogPosterior` computed from them when it was
recorded (``tests/data/make_problem_regression.py``): free names, bounds, start and kernel
vectors, residuals, a short least-squares fit, and the log posterior under every noise
model (floor, sampled sigma, AR(1), the curvature-adjusted default), with log coordinates
and several experiments with an ``alpha0[i]`` each.  A reorganisation of the code must not
move any of them by a single bit.
"""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

DATA = Path(__file__).resolve().parent / "data"
_spec = importlib.util.spec_from_file_location(
    "make_problem_regression", DATA / "make_problem_regression.py"
)
maker = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(maker)


@pytest.fixture(scope="module")
def stored():
    with np.load(maker.FILE) as d:
        return {k: d[k] for k in d.files}


@pytest.fixture(scope="module")
def recorded_now(stored):
    return maker.record(maker.stored_experiments(stored))


def _same(a, b) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    if a.dtype.kind in "US" or b.dtype.kind in "US":
        return a.shape == b.shape and str(a) == str(b)
    return a.shape == b.shape and a.dtype == b.dtype and np.array_equal(a, b, equal_nan=True)


def test_the_file_holds_every_problem_and_posterior(stored):
    names = json.loads(str(stored["experiment_names"]))
    assert len(names) == 5
    for key in ("brake", "brake_two", "coupled_two", "coupled_asym", "upper"):
        assert f"{key}/r0" in stored
    for key, _, _ in maker.POSTERIORS:
        assert np.all(np.isfinite(stored[f"lp/{key}/logpost"]))
    assert json.loads(str(stored["brake_two/names"]))[-2:] == ["alpha0[0]", "alpha0[1]"]
    assert "adjust" in "".join(k for k in stored if k.startswith("lp/brake/robust/"))


def test_every_number_is_the_recorded_one(stored, recorded_now):
    assert set(recorded_now) <= set(stored)
    assert set(k for k in stored if not k.startswith("ex/") and k != "experiment_names") == set(
        recorded_now
    )
    differ = [k for k, v in recorded_now.items() if not _same(v, stored[k])]
    assert not differ, f"changed: {differ}"

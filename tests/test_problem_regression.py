"""The numbers of estimation problems and log posteriors stay the same, bit for bit.

``tests/data/problem_regression.npz`` holds a few synthetic experiments and what
:class:`~rotorbayes.inference.Problem` and
:class:`~rotorbayes.inference.likelihood.LogPosterior` computed from them when it was
recorded (``tests/data/make_problem_regression.py``): free names, bounds, start and kernel
vectors, residuals, a short least-squares fit, and the log posterior under every noise
model (floor, sampled sigma, AR(1), the curvature-adjusted default), with log coordinates
and several experiments with an ``alpha0[i]`` each.  A reorganisation of the code must not
move any of them by a single bit.

Bit for bit under the libraries and on the kind of processor that recorded them
(``tests/recorded.py``: CI's Python 3.11 run on a processor with AVX-512).  Under another
numpy or scipy (the newer interpreter's), or on a processor without AVX-512, the last bits
move: the numbers are held to :data:`RTOL`, the 8-evaluation fit (not converged, so
sensitive) to :data:`FIT_RTOL`, and the walkers' random start balls (drawn through the
covariance's decomposition) only to their shape and finiteness.
"""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest
from recorded import recording_machine

DATA = Path(__file__).resolve().parent / "data"
_spec = importlib.util.spec_from_file_location(
    "make_problem_regression", DATA / "make_problem_regression.py"
)
maker = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(maker)


#: Relative agreement required under other libraries than the recording ones (measured on
#: Python 3.13 with numpy 2.5.5: every number within 1.0e-7 but the short fit, 3.1e-5) ...
RTOL = 1e-6
#: ... and of the short least-squares fit.
FIT_RTOL = 1e-4


@pytest.fixture(scope="module")
def stored():
    with np.load(maker.FILE) as d:
        return {k: d[k] for k in d.files}


@pytest.fixture(scope="module")
def recorded_now(stored):
    return maker.record(maker.stored_experiments(stored))


def _same(a, b, exact: bool = True, key: str = "") -> bool:
    a, b = np.asarray(a), np.asarray(b)
    if a.dtype.kind in "US" or b.dtype.kind in "US":
        return a.shape == b.shape and str(a) == str(b)
    if a.shape != b.shape or a.dtype != b.dtype:
        return False
    if exact or a.dtype.kind not in "fc":
        return np.array_equal(a, b, equal_nan=True)
    if key.endswith("/start"):
        return bool(np.all(np.isfinite(a)))
    rtol = FIT_RTOL if key.startswith("fit/") else RTOL
    return np.allclose(a, b, rtol=rtol, atol=0.0, equal_nan=True)


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
    exact = recording_machine()
    differ = [k for k, v in recorded_now.items() if not _same(v, stored[k], exact, k)]
    assert not differ, f"changed ({'bit for bit' if exact else f'rtol {RTOL:g}'}): {differ}"

"""Property-based tests (hypothesis) of the readers users feed by hand (issue 17).

Whatever bytes a measurement CSV or a TOML file holds, the reader returns a valid object or
raises its own error with a message naming the file -- never another exception (a
traceback for the user), never a value that breaks later.
"""

from __future__ import annotations

import math
import os
import warnings
from pathlib import Path

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from rotorbayes.commands.study.analysis import AnalysisError, load_analysis  # noqa: E402
from rotorbayes.io.measurements import DataFileError, DataWarning, load_experiment  # noqa: E402
from rotorbayes.model.parameters import INFO, ParameterError, load_toml  # noqa: E402

# CI explores the same examples on every run (a red CI is a change's fault, not a new
# draw); a developer's run explores new ones each time and hypothesis keeps what failed.
SETTINGS = settings(
    max_examples=120,
    deadline=None,
    derandomize=os.environ.get("CI") == "true",
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)


# ----------------------------------------------------------------------------- CSV loader
def _number_text():
    return st.one_of(
        st.floats(allow_nan=True, allow_infinity=True).map(repr),
        st.integers(-(10**30), 10**30).map(str),
        st.sampled_from(
            [
                "",
                " ",
                "nan",
                "inf",
                "-inf",
                "1e308",
                "-1e308",
                "1e-320",
                "0x10",
                "1,5",
                "1.2.3",
                "e5",
                "--1",
                "١٢٣",
                "\x00",
                "3 4",
            ]
        ),
    )


@st.composite
def csv_texts(draw):
    """Mostly well-formed measurement files with one or more things broken."""
    n = draw(st.integers(0, 40))
    lower = draw(st.booleans())
    header = ["t", "u", "theta_u"] + (["theta_l"] if lower else [])
    header = draw(
        st.one_of(
            st.just(header),
            st.permutations(header),
            st.lists(st.sampled_from(["t", "u", "theta_u", "theta_l", "x", "", "T"]), max_size=5),
        )
    )
    step = draw(st.sampled_from([0.001, 0.005, 0.5, 1.0, 1e-9]))
    rows = []
    for k in range(n):
        vals = [repr(k * step), repr(draw(st.floats(-6, 6))), "0", "0"][: len(header)]
        if draw(st.integers(0, 9)) == 0:  # a broken field here and there
            j = draw(st.integers(0, max(0, len(vals) - 1)))
            if vals:
                vals[j] = draw(_number_text())
        if draw(st.integers(0, 19)) == 0:  # a row of the wrong length
            vals = vals[:-1]
        rows.append(",".join(vals))
    comments = draw(
        st.lists(st.text(max_size=20).map(lambda s: "# " + s.replace("\n", " ")), max_size=2)
    )
    lines = comments + [",".join(header)] + rows
    sep = draw(st.sampled_from(["\n", "\r\n"]))
    text = sep.join(lines) + draw(st.sampled_from([sep, "", sep + sep]))
    prefix = draw(st.sampled_from(["", "\ufeff"]))
    return prefix + text


def _check_experiment(ex) -> None:
    assert ex.t.size >= 3 and np.all(np.isfinite(ex.t)) and np.all(np.diff(ex.t) > 0)
    for v in (ex.u, ex.theta_u) + ((ex.theta_l,) if ex.theta_l is not None else ()):
        assert v.shape == ex.t.shape and np.all(np.isfinite(v))
        assert np.max(np.abs(v)) < 1e6


@SETTINGS
@given(text=csv_texts())
def test_the_csv_loader_returns_data_or_its_own_error(tmp_path, text):
    p = tmp_path / "m.csv"
    p.write_text(text, encoding="utf-8", newline="")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataWarning)
        try:
            ex = load_experiment(p)
        except DataFileError as exc:
            assert "m.csv" in str(exc)
            return
    _check_experiment(ex)


@SETTINGS
@given(raw=st.binary(max_size=400))
def test_the_csv_loader_on_arbitrary_bytes(tmp_path, raw):
    p = tmp_path / "b.csv"
    p.write_bytes(raw)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataWarning)
        try:
            ex = load_experiment(p)
        except DataFileError as exc:
            assert "b.csv" in str(exc)
            return
    _check_experiment(ex)


# ---------------------------------------------------------------------------- TOML readers
KEYS = st.sampled_from(
    [
        *list(INFO)[:6],
        "base",
        "parameters",
        "priors",
        "analysis",
        "fit",
        "sample",
        "diagnose",
        "out",
        "data",
        "config",
        "steps",
        "walkers",
        "max_steps",
        "channels",
        "lowr",
        "dist",
        "lower",
        "upper",
        "mean",
        "sd",
        "k m",
        "é",
    ]
)
SCALARS = st.one_of(
    st.integers(-(2**63), 2**63 - 1),
    st.floats(allow_nan=True, allow_infinity=True),
    st.booleans(),
    st.text(max_size=12),
    st.sampled_from(
        [
            "thesis:4.2:P0",
            "self.toml",
            "other.toml",
            "example:upper_est",
            "upper",
            "normal",
            "loguniform",
            "",
            "x.py:e",
        ]
    ),
)
VALUES = st.recursive(
    SCALARS,
    lambda inner: st.one_of(st.lists(inner, max_size=3), st.dictionaries(KEYS, inner, max_size=3)),
    max_leaves=8,
)
DOCS = st.dictionaries(KEYS, VALUES, max_size=6)


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return (
            "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
        )
    if isinstance(v, str):
        return (
            '"'
            + v.replace("\\", "\\\\")
            .replace('"', '\\"')
            .replace("\n", "\\n")
            .encode("unicode_escape")
            .decode()
            .replace("\\\\", "\\")
            + '"'
            if v.isprintable()
            else '"'
            + "".join(c if c.isprintable() and c not in '"\\' else f"\\u{ord(c):04x}" for c in v)
            + '"'
        )
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return "{ " + ", ".join(f'"{k}" = {_toml_value(x)}' for k, x in v.items()) + " }"


def toml_text(doc: dict) -> str:
    """A TOML document for ``doc``: scalars first, then tables (``[name]``)."""
    lines = [f'"{k}" = {_toml_value(v)}' for k, v in doc.items() if not isinstance(v, dict)]
    for k, v in doc.items():
        if isinstance(v, dict):
            lines.append(f'["{k}"]')
            lines += [f'"{kk}" = {_toml_value(vv)}' for kk, vv in v.items()]
    return "\n".join(lines) + "\n"


def _write(tmp_path: Path, name: str, doc: dict, bom: bool) -> Path:
    p = tmp_path / name
    p.write_bytes((("\ufeff" if bom else "") + toml_text(doc)).encode("utf-8"))
    return p


@SETTINGS
@given(doc=DOCS, bom=st.booleans())
def test_the_parameter_file_reader(tmp_path, doc, bom):
    p = _write(tmp_path, "self.toml", doc, bom)
    (tmp_path / "other.toml").write_text('base = "self.toml"\n')
    try:
        out = load_toml(p)
    except ParameterError as exc:
        assert "toml" in str(exc)
        return
    for n, v in out.items():
        assert n in INFO and isinstance(v, float)
        assert INFO[n].lower <= v <= INFO[n].upper or (n == "Ts_l" and math.isnan(v))


@pytest.fixture(scope="module")
def upper_problem():
    import rotorbayes as rb
    from rotorbayes.inference import Problem

    return Problem("upper", [rb.load_example("upper_est")])


@SETTINGS
@given(doc=DOCS, bom=st.booleans(), wrap=st.booleans())
def test_the_priors_reader(tmp_path, upper_problem, doc, bom, wrap):
    from rotorbayes.inference.likelihood import load_priors

    p = _write(tmp_path, "pr.toml", {"priors": doc} if wrap else doc, bom)
    try:
        priors = load_priors(p, upper_problem)
    except ParameterError as exc:
        assert "pr.toml" in str(exc)
        return
    for n, pr in priors.items():
        assert n in upper_problem.names_base() and pr.lower < pr.upper
        assert pr.kind in ("uniform", "loguniform", "normal")


@SETTINGS
@given(doc=DOCS, bom=st.booleans(), base=st.booleans())
def test_the_analysis_file_reader(tmp_path, doc, bom, base):
    if base:  # mostly valid files with random changes reach the deeper checks
        doc = {
            "analysis": {
                "out": "o",
                "config": "upper",
                "data": ["example:upper_est"],
                **{k: v for k, v in doc.items() if not isinstance(v, dict)},
            },
            **{k: v for k, v in doc.items() if isinstance(v, dict)},
        }
    p = _write(tmp_path, "a.toml", doc, bom)
    try:
        a = load_analysis(p)
    except AnalysisError as exc:
        assert "a.toml" in str(exc)
        return
    an = a.table("analysis")
    assert an["out"].strip() and an["data"] and an["config"] in ("upper", "coupled", "brake")
    s = a.table("sample")
    assert all(4 <= s.get(k, 4) for k in ("walkers",)) and 10 <= s.get("steps", 10) <= 10**7

"""Contract tests for rotorbayes.io.measurements: file format, every refusal, round-trip,
synthetic noise."""

import math
import os
import pickle
import re
import warnings
from pathlib import Path

import numpy as np
import pytest

from rotorbayes.io import measurements as data
from rotorbayes.io.measurements import (
    LOWER_COUNTS_PER_REV,
    UPPER_COUNTS_PER_REV,
    DataFileError,
    DataWarning,
    Experiment,
    add_noise,
    load_experiment,
    quantize,
    save_experiment,
)

HEADER = "t,u,theta_u,theta_l"


def rows(n: int = 10, dt: float = 0.01, lower: bool = True) -> list[str]:
    """Valid data rows: slow motion (< 2 rad/s) starting at zero."""
    out = []
    for i in range(n):
        t = i * dt
        values = [t, 0.5 * math.sin(t), 0.2 * t, 0.1 * t * t]
        out.append(",".join(repr(v) for v in (values if lower else values[:3])))
    return out


def timed_rows(times: list[float]) -> list[str]:
    """Data rows at the given times (any unit), with the encoders at rest."""
    return [f"{t!r},0.5,0.0,0.0" for t in times]


def write(tmp_path: Path, lines: list[str], name: str = "exp.csv") -> Path:
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def make_experiment(n: int = 2001, lower: bool = True, seed: int = 0) -> Experiment:
    """A synthetic measurement: quantised, slightly noisy angles, like the rig produces."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 1000.0
    u = 3.0 * np.sin(2 * np.pi * 0.5 * t)
    theta_u = quantize(2.0 * (1 - np.cos(t)), UPPER_COUNTS_PER_REV)
    theta_l = quantize(add_noise(1.5 * (1 - np.cos(t)), 1e-5, rng), LOWER_COUNTS_PER_REV)
    return Experiment(
        t,
        u,
        theta_u,
        theta_l if lower else None,
        name="synthetic",
        meta={"source": "synthetic", "seed": str(seed)},
    )


# ------------------------------------------------------------------------------------------
# Loading valid files


def test_load_valid_file(tmp_path):
    path = write(
        tmp_path,
        ["# source: synthetic", "# free-form note without a colon", "#rig:TU/e", HEADER, *rows()],
        name="run_07.csv",
    )
    exp = load_experiment(path)
    expected = np.array([[float(v) for v in r.split(",")] for r in rows()])
    np.testing.assert_array_equal(exp.t, expected[:, 0])
    np.testing.assert_array_equal(exp.u, expected[:, 1])
    np.testing.assert_array_equal(exp.theta_u, expected[:, 2])
    np.testing.assert_array_equal(exp.theta_l, expected[:, 3])
    assert exp.meta == {"source": "synthetic", "rig": "TU/e"}
    assert exp.name == "run_07"
    assert exp.path == str(path)
    assert exp.n == 10
    assert exp.dt == pytest.approx(0.01, rel=1e-12)
    assert exp.duration == pytest.approx(0.09, rel=1e-12)
    assert exp.has_lower


def test_load_upper_configuration(tmp_path):
    exp = load_experiment(write(tmp_path, ["t,u,theta_u", *rows(lower=False)]), expect_lower=False)
    assert exp.theta_l is None
    assert not exp.has_lower
    assert list(exp.columns()) == ["t", "u", "theta_u"]


def test_load_reordered_columns_crlf_and_bom(tmp_path):
    # Spreadsheet exports: byte-order mark, CRLF line ends, columns in another order.
    lines = ["theta_l,t,theta_u,u"]
    for r in rows():
        t, u, tu, tl = r.split(",")
        lines.append(",".join([tl, t, tu, u]))
    path = tmp_path / "excel.csv"
    path.write_bytes(("\ufeff" + "\r\n".join(lines) + "\r\n").encode("utf-8"))
    exp = load_experiment(path)
    reference = load_experiment(write(tmp_path, [HEADER, *rows()]))
    for key in ("t", "u", "theta_u", "theta_l"):
        np.testing.assert_array_equal(getattr(exp, key), getattr(reference, key))


# ------------------------------------------------------------------------------------------
# Every refusal: (lines of the file, expected line number or None, regex the message must match)

GOOD = rows()
#: How a refusal of time in milliseconds ends: the fix, and the option that declares ms.
MS_OPTION = r", or declare the unit: --time-unit ms \(analysis file: time_unit = \"ms\"\)$"

BAD_FILES = {
    "empty": ([], None, r"empty"),
    "blank only": (["", "   ", ""], None, r"empty"),
    "comments only": (["# source: rig"], None, r"no header.*only comment"),
    "no header": (GOOD, 1, r"no header.*add the header line 't,u,theta_u,theta_l'"),
    "missing column": (
        ["t,u,theta_l", *GOOD],
        1,
        r"missing column\(s\) theta_u.*must be 't,u,theta_u,theta_l'",
    ),
    "unknown column": (
        ["time,u,theta_u,theta_l", *GOOD],
        1,
        r"missing column\(s\) t;.*unknown column\(s\) 'time'.*"
        r"must be 't,u,theta_u,theta_l'",
    ),
    "extra column": (
        ["t,u,theta_u,theta_l,omega_l", *[r + ",0.0" for r in GOOD]],
        1,
        r"unknown column\(s\) 'omega_l'.*must be 't,u,theta_u,theta_l'",
    ),
    "trailing comma": (["t,u,theta_u,theta_l,", *GOOD], 1, r"empty name: trailing comma"),
    "repeated column": (["t,u,theta_u,theta_u", *GOOD], 1, r"repeated column\(s\) theta_u"),
    # Semicolons are a separator (issue 36), but not mixed with commas.
    "semicolons": (
        ["t;u;theta_u;theta_l", *GOOD],
        2,
        r"header is separated by semicolons but this row by commas",
    ),
    "short row": (
        ["# a: b", HEADER, *GOOD[:4], "0.04,0.1,0.2", *GOOD[5:]],
        7,
        r"3 field\(s\) '0\.04,0\.1,0\.2' but the header .* has 4; fix or delete",
    ),
    "long row": ([HEADER, *GOOD[:4], GOOD[4] + ",1.0", *GOOD[5:]], 6, r"5 field\(s\)"),
    "truncated last line": ([HEADER, *GOOD, "0.1,0.4"], 12, r"2 field\(s\).*last line.*truncated"),
    "truncated last number": (
        [HEADER, *GOOD, "0.1,0.4,0.02,1e"],
        12,
        r"'1e' in column theta_l is not a number.*truncated",
    ),
    "non-numeric": (
        [HEADER, *GOOD[:3], "0.03,abc,0.006,0.00009", *GOOD[4:]],
        5,
        r"'abc' in column u is not a number; write plain decimal",
    ),
    "empty value": (
        [HEADER, *GOOD[:3], "0.03,,0.006,0.00009", *GOOD[4:]],
        5,
        r"empty in column u is not a number",
    ),
    "nan": ([HEADER, *GOOD[:5], "0.05,nan,0.01,0.00025", *GOOD[6:]], 7, r"u is nan.*finite"),
    "inf": ([HEADER, *GOOD[:5], "0.05,0.1,0.01,-inf", *GOOD[6:]], 7, r"theta_l is -inf.*finite"),
    "too few rows": ([HEADER, *GOOD[:2]], None, r"only 2 data row\(s\).*at least 3"),
    "header only": ([HEADER], None, r"only 0 data row\(s\)"),
    "blank line inside": ([HEADER, *GOOD[:3], "", *GOOD[3:]], 5, r"empty line inside the data"),
    "comment after header": (
        [HEADER, *GOOD[:3], "# note", *GOOD[3:]],
        5,
        r"comment line '# note' after the header",
    ),
    "time repeated": (
        [HEADER, *GOOD[:6], GOOD[5], *GOOD[7:]],
        8,
        r"t = 0\.05 s is not after the previous time 0\.05 s.*strictly increasing",
    ),
    "time decreasing": ([HEADER, *GOOD[:3], GOOD[1], *GOOD[4:]], 5, r"strictly increasing"),
    "missing row": (
        [HEADER, *GOOD[:4], *GOOD[5:]],
        6,
        r"time step 0\.02 s .* expected step 0\.01 s.*uniform",
    ),
    "jittered time": (
        [HEADER, *GOOD[:4], "0.0401,0.0,0.008,0.00016", *GOOD[5:]],
        6,
        r"time step 0\.0101 s .* expected step 0\.01 s.*relative 0\.01",
    ),
    "time in milliseconds, 1 kHz": (
        [HEADER, *timed_rows([float(i) for i in range(10)])],
        3,
        r"time step 1 \(from t = 0\.0 to 1\.0\) looks like milliseconds: read as seconds, this "
        r"is a 9 s experiment sampled at 1 Hz, but the rig is sampled at tens of Hz to tens of "
        r"kHz.*in milliseconds it is a 0\.009 s experiment at 1000 Hz\. The t column must be "
        r"in seconds -- divide it by 1000" + MS_OPTION,
    ),
    "time in milliseconds, 200 Hz": (
        ["# rate: 200 Hz", HEADER, *timed_rows([5.0 * i for i in range(10)])],
        4,
        r"time step 5 .*looks like milliseconds.*at 200 Hz\. .*divide it by 1000" + MS_OPTION,
    ),
    "time in milliseconds, step 0.5 (2 kHz)": (
        [HEADER, *timed_rows([0.5 * i for i in range(10)])],
        3,
        r"time step 0\.5 .*looks like milliseconds.*at 2000 Hz\. .*divide it by 1000" + MS_OPTION,
    ),
    "time in milliseconds, not starting at zero": (
        [HEADER, *timed_rows([1000.0 + i for i in range(10)])],
        3,
        r"from t = 1000\.0 to 1001\.0\) looks like milliseconds.*divide it by 1000" + MS_OPTION,
    ),
    "time in microseconds, 1 kHz": (
        [HEADER, *timed_rows([1000.0 * i for i in range(10)])],
        3,
        r"time step 1000 .*looks like microseconds.*at 1000 Hz\. .*divide it by 1000000$",
    ),
    "time in milliseconds after a short first step": (
        # The median step decides; the line named is the first step of 0.5 s or more.
        [HEADER, *timed_rows([0.0, 0.25, *[float(i) for i in range(1, 10)]])],
        4,
        r"time step 0\.75 \(from t = 0\.25 to 1\.0\) looks like milliseconds",
    ),
    "not zeroed upper": (
        [
            HEADER,
            *[f"{r.rsplit(',', 2)[0]},{0.5 + 0.2 * i * 0.01!r},0.0" for i, r in enumerate(GOOD)],
        ],
        2,
        r"theta_u starts at 0\.5 rad.*zeroed.*subtract the first value",
    ),
}


@pytest.mark.parametrize("case", list(BAD_FILES))
def test_refusals(tmp_path, case):
    lines, line, pattern = BAD_FILES[case]
    path = tmp_path / "bad.csv"
    path.write_text("\n".join(lines) + ("\n" if lines else ""), encoding="utf-8")
    with pytest.raises(DataFileError, match=pattern) as info:
        load_experiment(path)
    err = info.value
    assert err.line == line
    assert err.path == str(path)
    prefix = f"{path}, line {line}: " if line is not None else f"{path}: "
    assert str(err).startswith(prefix)


# ------------------------------------------------------------------------------------------
# Time in seconds


@pytest.mark.parametrize(
    ("t0", "step"),
    [
        (0.0, 0.1),  # 10 Hz, the slowest sampling used on the rig
        (0.0, 0.4),  # still below MAX_SAMPLE_INTERVAL
        (0.0, 1e-5),  # 100 kHz
        (12.5, 0.001),  # time need not start at zero ...
        (-0.2, 0.005),  # ... nor be positive (a pre-trigger)
        (1.7e9, 0.01),  # Unix time stamps in seconds: only the differences matter
    ],
)
def test_time_in_seconds_accepted(tmp_path, t0, step):
    times = [t0 + i * step for i in range(20)]
    exp = load_experiment(write(tmp_path, [HEADER, *timed_rows(times)]))
    assert exp.t[0] == t0
    assert exp.dt == pytest.approx(step, rel=1e-3)
    assert exp.duration == pytest.approx(19 * step, rel=1e-3)


def test_max_sample_interval_is_the_limit(tmp_path):
    assert data.MAX_SAMPLE_INTERVAL == 0.5
    below = [i * 0.499 for i in range(10)]
    assert load_experiment(write(tmp_path, [HEADER, *timed_rows(below)], name="ok.csv")).n == 10
    at = [i * 0.5 for i in range(10)]
    with pytest.raises(DataFileError, match="looks like milliseconds"):
        load_experiment(write(tmp_path, [HEADER, *timed_rows(at)], name="bad.csv"))


def test_absurd_time_step_has_no_unit_guess(tmp_path):
    path = write(tmp_path, [HEADER, *timed_rows([1e10 * i for i in range(10)])])
    with pytest.raises(
        DataFileError,
        match=r"line 3: time step 1e\+10 .*is far too long: .*must be in seconds -- convert "
        r"it \(a time in ms is read with --time-unit ms.*\)$",
    ):
        load_experiment(path)


def test_fast_data_in_milliseconds_refused_by_duration(tmp_path):
    # 10 kHz data in ms has the step 0.1 of a legitimate 10 Hz file; only its length (8 "s" of
    # data lasting 8000 "s") gives it away. Time starts at 50 ms: only differences count.
    assert data.MAX_DURATION == 7200.0
    times = [50.0 + i / 10 for i in range(80_001)]
    path = write(tmp_path, [HEADER, *timed_rows(times)])
    with pytest.raises(DataFileError) as info:
        load_experiment(path)
    err = info.value
    # The first sample more than 7200 s after the first one: index 72001, line 72003.
    assert err.line == 72_003
    assert str(err).startswith(f"{path}, line 72003: time t = 7250.1 is more than 7200 s (2 h)")
    assert re.search(
        r"the record lasts 8000 s \(2\.22 h\).*looks like milliseconds \(then a 8 s experiment "
        r"at 10000 Hz\): the t column must be in seconds -- divide it by 1000 or declare the "
        r"unit, --time-unit ms .*\(if the record "
        r"really is this long, split it into files of at most 7200 s\)$",
        str(err),
    )
    # Exactly two hours is accepted.
    ok = write(tmp_path, [HEADER, *timed_rows(times[:72_001])], name="two_hours.csv")
    assert load_experiment(ok).duration == pytest.approx(7200.0)


def test_save_refuses_time_not_in_seconds(tmp_path):
    t = np.arange(100, dtype=float)  # 1 kHz in milliseconds
    with pytest.raises(
        ValueError, match=r"sample 1 \(line 3 of the file\).*looks like milliseconds"
    ):
        save_experiment(Experiment(t, np.zeros(100), np.zeros(100)), tmp_path / "ms.csv")
    # Three hours at 200 Hz in seconds: too fast for milliseconds, so no unit is suggested.
    n = 3 * 3600 * 200 + 1
    long = Experiment(np.arange(n) / 200.0, np.zeros(n), np.zeros(n))
    with pytest.raises(
        ValueError,
        match=r"line 1440003 of the file\).*lasts 10800 s \(3 h\).*if t is not in seconds, "
        r"convert it; if the record really is this long, split it into files of at most 7200 s$",
    ):
        save_experiment(long, tmp_path / "long.csv")
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------------------
# Truncated files


@pytest.mark.parametrize(
    ("last", "newline"),
    [
        (GOOD[-1][:-3], "\n"),  # cut in the middle of its last number
        (GOOD[-1], "\n"),  # complete last line, but no line break after it
        (GOOD[-1][:-3], "\r\n"),  # a CRLF file cut the same way
    ],
)
def test_truncated_file_refused(tmp_path, last, newline):
    path = tmp_path / "cut.csv"
    path.write_bytes(newline.join(["# source: rig", HEADER, *GOOD[:-1], last]).encode())
    with pytest.raises(DataFileError) as info:
        load_experiment(path)
    err = info.value
    assert (err.path, err.line) == (str(path), 12)
    assert str(err).startswith(f"{path}, line 12: the last line {last!r} does not end")
    assert re.search(
        r"looks truncated \(cut while being written or copied\).*re-export or copy the file "
        r"again, or delete this last line",
        str(err),
    )
    # Deleting the last line makes it loadable.
    path.write_bytes((newline.join(["# source: rig", HEADER, *GOOD[:-1]]) + newline).encode())
    assert load_experiment(path).n == 9


@pytest.mark.parametrize("ending", ["\n", "\r\n", "\n\n\n", "\n  \n", "\n   ", "\r\n\r\n"])
def test_line_break_and_blank_lines_at_end_accepted(tmp_path, ending):
    path = tmp_path / "ok.csv"
    path.write_bytes(("\n".join([HEADER, *GOOD]) + ending).encode())
    assert load_experiment(path).n == 10


def test_truncated_long_last_line_is_shortened_in_message(tmp_path):
    path = tmp_path / "cut.csv"
    path.write_text("\n".join([HEADER, *GOOD, "0.1,0.2,0.3," + "1" * 200]), encoding="utf-8")
    with pytest.raises(
        DataFileError, match=r"line 12: the last line '0\.1,0\.2,0\.3,1{68}\.\.\.' does not end"
    ):
        load_experiment(path)


def test_header_without_line_break_is_not_called_truncated(tmp_path):
    path = tmp_path / "header.csv"
    path.write_text(HEADER, encoding="utf-8")
    with pytest.raises(DataFileError, match=r"only 0 data row\(s\)"):
        load_experiment(path)


def test_bundled_examples_end_with_a_line_break():
    from rotorbayes.io.examples import EXAMPLES

    files = sorted(EXAMPLES.glob("*.csv"))
    assert files
    for path in files:
        assert path.read_bytes().endswith(b"\n"), path
        exp = load_experiment(path)
        assert exp.dt < data.MAX_SAMPLE_INTERVAL and exp.duration <= data.MAX_DURATION


def test_missing_file(tmp_path):
    with pytest.raises(DataFileError, match=r"nope\.csv: file not found") as info:
        load_experiment(tmp_path / "nope.csv")
    assert isinstance(info.value, ValueError)


def test_directory_and_binary_files(tmp_path):
    with pytest.raises(DataFileError, match="is a directory"):
        load_experiment(tmp_path)
    binary = tmp_path / "scope.csv"
    binary.write_bytes(b"t,u\xff\xfe\x00\x01")
    with pytest.raises(DataFileError, match="not a UTF-8 text file"):
        load_experiment(binary)


def test_line_numbers_count_comment_lines(tmp_path):
    lines = ["# a: 1", "# b: 2", "", "# c: 3", HEADER, *GOOD[:2], "0.02,x,0.004,0.00004"]
    with pytest.raises(DataFileError) as info:
        load_experiment(write(tmp_path, lines + GOOD[3:]))
    assert info.value.line == 8


def counts_file(tmp_path, column: str) -> Path:
    # 1 rad/s written as raw counts: thousands of counts per second.
    lines = [HEADER]
    for i in range(20):
        t = i * 0.01
        theta = round(t * UPPER_COUNTS_PER_REV / (2 * math.pi))
        theta_u, theta_l = (float(theta), 0.0) if column == "theta_u" else (0.0, float(theta))
        lines.append(f"{t!r},1.0,{theta_u!r},{theta_l!r}")
    return write(tmp_path, lines)


@pytest.mark.parametrize(
    ("column", "counts_per_rev"),
    [("theta_u", UPPER_COUNTS_PER_REV), ("theta_l", LOWER_COUNTS_PER_REV)],
)
def test_encoder_counts_detected(tmp_path, column, counts_per_rev):
    factor = f"{counts_per_rev / (2 * math.pi):.6f}"
    with pytest.raises(
        DataFileError,
        match=rf"{column} .*encoder counts; declare them with --angle-unit counts "
        rf".*divide by "
        rf"counts_per_rev/\(2π\) = {re.escape(factor)}",
    ):
        load_experiment(counts_file(tmp_path, column))


def test_degrees_detected(tmp_path):
    lines = [HEADER]
    for i in range(20):
        t = i * 0.01
        lines.append(f"{t!r},1.0,{math.degrees(2.0 * t)!r},0.0")
    with pytest.raises(
        DataFileError,
        match=r"theta_u .*looks like degrees; declare them with "
        r"--angle-unit deg .*multiply by π/180",
    ):
        load_experiment(write(tmp_path, lines))
    # The same motion in radians (2 rad/s) is accepted.
    radians = [HEADER] + [f"{i * 0.01!r},1.0,{2.0 * i * 0.01!r},0.0" for i in range(20)]
    assert load_experiment(write(tmp_path, radians, name="ok.csv")).n == 20


def test_fast_but_plausible_motion_accepted(tmp_path):
    # 50 rad/s with noise at 10 kHz: single-sample differences exceed 60 rad/s, the 10 ms
    # baseline does not.
    rng = np.random.default_rng(1)
    t = np.arange(2001) / 10000.0
    theta = 50.0 * t + np.concatenate(([0.0], rng.normal(0, 2e-3, t.size - 1)))
    exp = Experiment(t, np.zeros_like(t), theta, theta)
    assert np.max(np.abs(np.diff(theta) / np.diff(t))) > 60
    path = save_experiment(exp, tmp_path / "fast.csv")
    assert load_experiment(path).n == t.size


def test_expect_lower(tmp_path):
    upper = write(tmp_path, ["t,u,theta_u", *rows(lower=False)], name="upper.csv")
    lower = write(tmp_path, [HEADER, *rows()], name="lower.csv")
    with pytest.raises(DataFileError, match=r"upper\.csv, line 1: .*upper-configuration file"):
        load_experiment(upper, expect_lower=True)
    with pytest.raises(DataFileError, match=r"lower\.csv, line 1: .*has a theta_l column"):
        load_experiment(lower, expect_lower=False)
    assert load_experiment(upper, expect_lower=False).theta_l is None
    assert load_experiment(lower, expect_lower=True).theta_l is not None


def test_voltage_above_limit_warns(tmp_path):
    lines = [HEADER, *GOOD[:4], "0.04,5.5,0.008,0.00016", "0.05,-7.25,0.01,0.00025", *GOOD[6:]]
    path = write(tmp_path, lines)
    with pytest.warns(
        DataWarning,
        match=r"line 6: u = 5\.5 V exceeds ±5 V \(2 sample\(s\), "
        r"largest \|u\| = 7\.25 V on line 7\)",
    ) as record:
        exp = load_experiment(path)
    assert str(path) in str(record[0].message)
    assert issubclass(DataWarning, UserWarning)
    assert exp.u[5] == -7.25
    # A higher limit silences it; a file within ±5 V never warns.
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_experiment(path, max_abs_u=8.0)
        load_experiment(write(tmp_path, [HEADER, *GOOD], name="fine.csv"))


def test_voltage_at_the_limit_up_to_rounding_does_not_warn(tmp_path):
    """A generator's arithmetic leaves -5.000000000000009 V where it meant the limit."""
    lines = [HEADER, *GOOD[:4], "0.04,-5.000000000000009,0.008,0.00016", *GOOD[5:]]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_experiment(write(tmp_path, lines))
    lines[5] = "0.04,-5.00001,0.008,0.00016"
    with pytest.warns(DataWarning, match=r"u = -5\.00001 V exceeds ±5 V"):
        load_experiment(write(tmp_path, lines, name="over.csv"))


def test_data_file_error_pickles():
    err = DataFileError("x.csv", 3, "bad")
    clone = pickle.loads(pickle.dumps(err))
    assert (str(clone), clone.path, clone.line) == ("x.csv, line 3: bad", "x.csv", 3)


# ------------------------------------------------------------------------------------------
# Saving


@pytest.mark.parametrize("lower", [True, False])
def test_round_trip_is_exact(tmp_path, lower):
    exp = make_experiment(lower=lower)
    path = save_experiment(exp, tmp_path / "rt.csv", meta={"configuration": "brake"})
    assert path == tmp_path / "rt.csv"
    back = load_experiment(path)
    for key in exp.columns():
        np.testing.assert_array_equal(getattr(back, key), getattr(exp, key))
    assert back.theta_l is None if not lower else back.has_lower
    assert back.meta == {"source": "synthetic", "seed": "0", "configuration": "brake"}
    text = path.read_text(encoding="utf-8").splitlines()
    assert text[:4] == [
        "# source: synthetic",
        "# seed: 0",
        "# configuration: brake",
        HEADER if lower else "t,u,theta_u",
    ]
    # Saving the loaded experiment again reproduces the file byte for byte.
    again = save_experiment(back, tmp_path / "rt2.csv")
    assert again.read_bytes() == path.read_bytes()


@pytest.mark.parametrize("block", [1, 7, 2000, 2001])
def test_rows_written_in_blocks_give_the_same_file(tmp_path, monkeypatch, block):
    """Long data are written a block of rows at a time (memory); block edges anywhere,
    including one row per block and the last row alone, change no byte."""
    exp = make_experiment()
    whole = save_experiment(exp, tmp_path / "whole.csv", meta={"k": "v"}).read_bytes()
    monkeypatch.setattr(data, "_WRITE_BLOCK", block)
    parts = save_experiment(exp, tmp_path / f"b{block}.csv", meta={"k": "v"})
    assert parts.read_bytes() == whole
    assert whole.count(b"\n") == exp.n + 4  # 3 comment lines, the header, the rows
    np.testing.assert_array_equal(load_experiment(parts).theta_l, exp.theta_l)


def test_quantised_values_round_trip_below_1e_12(tmp_path):
    exp = make_experiment()
    back = load_experiment(save_experiment(exp, tmp_path / "q.csv"))
    q = 2 * math.pi / UPPER_COUNTS_PER_REV
    assert np.max(np.abs(back.theta_u - exp.theta_u)) < 1e-12
    counts = back.theta_u / q
    assert np.max(np.abs(counts - np.round(counts))) < 1e-9


def test_save_refuses_to_overwrite(tmp_path):
    exp = make_experiment()
    path = tmp_path / "exp.csv"
    path.write_text("precious\n", encoding="utf-8")
    with pytest.raises(
        FileExistsError,
        match=r"exp\.csv already exists; pass overwrite=True "
        r"\(--force",
    ):
        save_experiment(exp, path)
    assert path.read_text(encoding="utf-8") == "precious\n"
    save_experiment(exp, path, overwrite=True)
    assert load_experiment(path).n == exp.n
    assert sorted(p.name for p in tmp_path.iterdir()) == ["exp.csv"]


def test_save_is_atomic(tmp_path, monkeypatch):
    path = tmp_path / "exp.csv"
    path.write_text("precious\n", encoding="utf-8")

    def crash(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(data.os, "replace", crash)
    with pytest.raises(OSError, match="disk full"):
        save_experiment(make_experiment(), path, overwrite=True)
    # The old file is intact and no temporary file is left behind.
    assert path.read_text(encoding="utf-8") == "precious\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["exp.csv"]


def test_save_file_permissions_follow_umask(tmp_path):
    path = save_experiment(make_experiment(), tmp_path / "perm.csv")
    umask = os.umask(0)
    os.umask(umask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~umask


def test_save_refuses_what_load_would_reject(tmp_path):
    exp = make_experiment()
    t = exp.t.copy()
    t[100] += 0.0005
    bad = Experiment(t, exp.u, exp.theta_u, exp.theta_l)
    with pytest.raises(ValueError, match=r"sample 100 \(line 102 of the file\).*uniform"):
        save_experiment(bad, tmp_path / "bad.csv")
    shifted = Experiment(exp.t, exp.u, exp.theta_u + 1.0, exp.theta_l)
    with pytest.raises(ValueError, match=r"theta_u starts at 1\.0 rad"):
        save_experiment(shifted, tmp_path / "bad.csv")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("meta", [{"a:b": "x"}, {"": "x"}, {"note": "two\nlines"}])
def test_save_rejects_unwritable_meta(tmp_path, meta):
    with pytest.raises(ValueError, match="metadata"):
        save_experiment(make_experiment(), tmp_path / "m.csv", meta=meta)


def test_save_into_missing_directory(tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist; create it first"):
        save_experiment(make_experiment(), tmp_path / "nowhere" / "x.csv")


# ------------------------------------------------------------------------------------------
# Experiment, quantize, add_noise


def test_experiment_validates_and_copies():
    t = np.arange(5) / 10.0
    theta = np.zeros(5)
    exp = Experiment(t, [0, 1, 2, 3, 4], theta, None)
    theta[0] = 99.0  # the caller's later edits must not reach the experiment
    assert exp.theta_u[0] == 0.0
    assert exp.u.dtype == np.float64
    assert exp.dt == pytest.approx(0.1)
    with pytest.raises(ValueError, match=r"Experiment\.u has 4 samples but t has 5"):
        Experiment(t, np.zeros(4), theta, None)
    with pytest.raises(ValueError, match=r"Experiment\.theta_l must be a 1-D array"):
        Experiment(t, t, theta, np.zeros((5, 2)))
    with pytest.raises(ValueError, match="at least 2 samples"):
        Experiment(t[:1], t[:1], t[:1])
    with pytest.raises(AttributeError):
        exp.name = "changed"


@pytest.mark.parametrize("counts_per_rev", [UPPER_COUNTS_PER_REV, LOWER_COUNTS_PER_REV])
def test_quantize(counts_per_rev):
    q = 2 * math.pi / counts_per_rev
    theta = np.random.default_rng(0).uniform(-50.0, 50.0, 10_000)
    quantised = quantize(theta, counts_per_rev)
    assert np.max(np.abs(quantised - theta)) <= q / 2 * (1 + 1e-9)
    counts = quantised / q
    assert np.max(np.abs(counts - np.round(counts))) < 1e-9
    # The error is spread over the whole half-count range, so rounding really happened.
    assert np.max(np.abs(quantised - theta)) > 0.45 * q
    np.testing.assert_array_equal(quantize(quantised, counts_per_rev), quantised)
    assert quantize(np.zeros(3), counts_per_rev).tolist() == [0.0, 0.0, 0.0]
    # A resting encoder reads 0, never -0 (which would be written as "-0.0").
    assert not np.signbit(quantize(np.array([-1e-9]), counts_per_rev)[0])


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan")])
def test_quantize_rejects_bad_resolution(bad):
    with pytest.raises(ValueError, match="counts_per_rev"):
        quantize(np.zeros(3), bad)


def test_add_noise():
    theta = np.linspace(0.0, 1.0, 200_000)
    original = theta.copy()
    noisy = add_noise(theta, 1e-3, np.random.default_rng(42))
    np.testing.assert_array_equal(theta, original)
    assert np.std(noisy - theta) == pytest.approx(1e-3, rel=0.01)
    assert abs(np.mean(noisy - theta)) < 1e-5
    np.testing.assert_array_equal(noisy, add_noise(theta, 1e-3, np.random.default_rng(42)))
    assert not np.array_equal(noisy, add_noise(theta, 1e-3, np.random.default_rng(43)))
    np.testing.assert_array_equal(add_noise(theta, 0.0, np.random.default_rng(0)), theta)
    with pytest.raises(ValueError, match="std"):
        add_noise(theta, -1.0, np.random.default_rng(0))
    with pytest.raises(TypeError, match="default_rng"):
        add_noise(theta, 1e-3, 42)


# ------------------------------------------------------------- long files, read in blocks
def _long_rows(n: int, seed: int = 3) -> list[str]:
    """``n`` data rows (1 kHz) written in the forms loggers use: shortest repr, fixed and
    exponent notation, integers, a '+' sign, spaces around the numbers; angles that start
    at zero and move by a few encoder counts a sample."""
    rng = np.random.default_rng(seed)
    forms = [repr, "{:.6e}".format, "{:.9f}".format, lambda v: f" {v!r} ", "{:+.17g}".format]
    u = np.clip(rng.normal(0.0, 1.0, n), -4.0, 4.0)
    walk = np.cumsum(rng.normal(0.0, 2e-4, (n, 2)), axis=0)
    walk -= walk[0]
    rows = []
    for k in range(n):
        cells = [repr(k * 1e-3)]
        cells += [forms[(k + j) % len(forms)](float(v)) for j, v in enumerate((u[k], *walk[k]))]
        if k % 97 == 0:
            cells[1] = str(int(k % 5) - 2)  # an integer voltage
        rows.append(",".join(cells))
    return rows


#: Characters decoded at once in the long-file tests: the reader's own (the whole file in
#: one chunk) and 997 (chunks end inside lines, numbers and line breaks).
CHUNKS = [None, 997]


def _chunk(monkeypatch, chunk):
    if chunk is not None:
        monkeypatch.setattr(data, "_CHUNK", chunk)


@pytest.mark.parametrize("chunk", CHUNKS)
def test_a_long_file_reads_the_same_numbers_as_float_does(tmp_path, monkeypatch, chunk):
    # More rows than one block (4096): the rows after the first block are parsed by NumPy a
    # chunk at a time; every value must be the double Python's float() gives for its text,
    # bit for bit.
    _chunk(monkeypatch, chunk)
    rows = _long_rows(10_000)
    path = tmp_path / "long.csv"
    path.write_text("t,u,theta_u,theta_l\n" + "\n".join(rows) + "\n", encoding="utf-8")
    exp = load_experiment(path, keep_glitches=True)
    want = np.array([[float(c) for c in r.split(",")] for r in rows])
    got = np.column_stack([exp.t, exp.u, exp.theta_u, exp.theta_l])
    assert got.shape == want.shape
    assert np.array_equal(got.view(np.int64), want.view(np.int64))


@pytest.mark.parametrize(
    "bad, message",
    [
        ("", r"line 7002: empty line inside the data"),
        ("# note", r"line 7002: comment line"),
        ("0.1,0.2,0.3", r"line 7002: 3 field\(s\)"),
        ("7.0,0.1,x,0.3", r"line 7002: value 'x' in column theta_u is not a number"),
        ("1_0e-1", None),  # a voltage Python's float reads: so does the file
    ],
)
@pytest.mark.parametrize("chunk", CHUNKS)
def test_a_bad_row_deep_in_a_long_file_is_named_by_its_line(
    tmp_path, monkeypatch, chunk, bad, message
):
    _chunk(monkeypatch, chunk)
    rows = _long_rows(9_000)
    if message is None:
        cells = rows[7000].split(",")
        rows[7000] = ",".join([cells[0], bad, *cells[2:]])
    else:
        rows[7000] = bad
    path = tmp_path / "bad.csv"
    path.write_text("t,u,theta_u,theta_l\n" + "\n".join(rows) + "\n", encoding="utf-8")
    if message is None:
        exp = load_experiment(path, keep_glitches=True)
        assert exp.u[7000] == 1.0
        return
    with pytest.raises(DataFileError, match=message):
        load_experiment(path)


@pytest.mark.parametrize("chunk", CHUNKS)
def test_the_row_limit_holds_inside_a_block(tmp_path, monkeypatch, chunk):
    _chunk(monkeypatch, chunk)
    rows = _long_rows(6_000)
    path = tmp_path / "many.csv"
    path.write_text("t,u,theta_u,theta_l\n" + "\n".join(rows) + "\n", encoding="utf-8")
    with pytest.raises(DataFileError, match=r"line 5002: more than 5,000 data rows"):
        load_experiment(path, max_rows=5_000)


@pytest.mark.parametrize("chunk", CHUNKS)
@pytest.mark.parametrize(
    "tail, message",
    [
        ("\n\n\n", None),  # an editor's blank lines after the data: harmless
        ("\r\n", None),  # (with CRLF line breaks throughout, below)
        ("", r"line 9001: the last line .* does not end with a line break"),
        ("\n" + "0\0\0\0" * 10 + "\n", r"line 9002: holds NUL bytes"),
        ("\n" + "1" * 70_000 + "\n", r"line 9002: longer than 65536 characters"),
        ("\n\n8.99,0.1,0.2,0.3\n", r"line 9002: empty line inside the data"),
    ],
)
def test_the_end_of_a_long_file_is_judged_as_a_short_ones(
    tmp_path, monkeypatch, chunk, tail, message
):
    _chunk(monkeypatch, chunk)
    rows = _long_rows(9_000)
    path = tmp_path / "end.csv"
    if tail == "\r\n":
        path.write_bytes(("t,u,theta_u,theta_l\r\n" + "\r\n".join(rows) + "\r\n").encode())
    else:
        path.write_text("t,u,theta_u,theta_l\n" + "\n".join(rows) + tail, encoding="utf-8")
    if message is None:
        exp = load_experiment(path, keep_glitches=True)
        assert exp.n == 9_000
        assert exp.theta_l[-1] == float(rows[-1].split(",")[3])
        return
    with pytest.raises(DataFileError, match=message):
        load_experiment(path)

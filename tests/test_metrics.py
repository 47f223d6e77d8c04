"""Contract tests for rotorbayes.util.metrics: hand-computed values, §6.2's point, refusals."""

import math
import re

import numpy as np
import pytest

from rotorbayes.util.metrics import (
    ChannelFit,
    aicc,
    bic,
    channel_fit,
    fit_table,
    max_abs_error,
    nrmse_fit,
    r_squared,
    ssr,
)

# A four-sample example small enough to check by hand:
# residuals (0, 0, 0, -1) -> SSR = 1; mean(y) = 2.5 -> SST = 2.25 + 0.25 + 0.25 + 2.25 = 5.
Y = np.array([1.0, 2.0, 3.0, 4.0])
YHAT = np.array([1.0, 2.0, 3.0, 5.0])


def test_hand_computed_values():
    assert ssr(Y, YHAT) == pytest.approx(1.0)
    assert r_squared(Y, YHAT) == pytest.approx(0.8)
    assert nrmse_fit(Y, YHAT) == pytest.approx(100.0 * (1.0 - math.sqrt(0.2)))
    assert nrmse_fit(Y, YHAT) == pytest.approx(55.27864045)
    assert max_abs_error(Y, YHAT) == pytest.approx(1.0)


def test_perfect_fit():
    y = np.sin(np.linspace(0.0, 10.0, 500))
    assert r_squared(y, y) == 1.0
    assert nrmse_fit(y, y) == 100.0
    assert max_abs_error(y, y) == 0.0
    assert ssr(y, y) == 0.0


def test_fit_percent_is_sqrt_transform_of_r2():
    rng = np.random.default_rng(3)
    y = np.cumsum(rng.normal(size=300))
    yhat = y + rng.normal(scale=0.5, size=300)
    assert nrmse_fit(y, yhat) == pytest.approx(100.0 * (1.0 - math.sqrt(1.0 - r_squared(y, yhat))))


def test_worse_than_mean_is_negative():
    y = np.array([0.0, 1.0, 2.0])
    yhat = np.array([2.0, 1.0, 0.0])  # SSR = 8, SST = 2
    assert r_squared(y, yhat) == pytest.approx(-3.0)
    assert nrmse_fit(y, yhat) == pytest.approx(100.0 * (1.0 - 2.0))


def test_shifted_ramp_r2_hides_the_error():
    """Thesis §6.2: R² near 1 while the error is large; the fit % shows it."""
    y = np.linspace(0.0, 100.0, 101)  # a ramp 0..100 rad, 1 rad per sample
    yhat = y + 1.0  # constant 1 rad error
    # SSR = 101 * 1²; SST = sum_{i=-50}^{50} i² = 2 * (50 * 51 * 101 / 6) = 85850.
    r2_exact = 1.0 - 101.0 / 85850.0
    fit_exact = 100.0 * (1.0 - math.sqrt(101.0 / 85850.0))
    assert r_squared(y, yhat) == pytest.approx(r2_exact, rel=1e-12)
    assert nrmse_fit(y, yhat) == pytest.approx(fit_exact, rel=1e-12)
    assert r2_exact == pytest.approx(0.998824, abs=1e-6)
    assert fit_exact == pytest.approx(96.570, abs=1e-3)
    # The point: R² rounds to 0.9988 ("excellent"), the fit is 3.4 points below 100 %.
    assert f"{r_squared(y, yhat):.4f}" == "0.9988"
    assert 100.0 - nrmse_fit(y, yhat) > 3.0
    assert max_abs_error(y, yhat) == pytest.approx(1.0)


def test_constant_measurement_gives_nan():
    y = np.full(10, 2.5)
    yhat = y + 0.1
    assert math.isnan(r_squared(y, yhat))
    assert math.isnan(nrmse_fit(y, yhat))
    # The error measures are still defined.
    assert max_abs_error(y, yhat) == pytest.approx(0.1)
    f = channel_fit("flat", y, yhat)
    assert math.isnan(f.r2) and math.isnan(f.nrmse_fit)
    assert f.rmse == pytest.approx(0.1)


@pytest.mark.parametrize("func", [r_squared, nrmse_fit, max_abs_error, ssr])
def test_shape_mismatch_refused(func):
    with pytest.raises(ValueError, match="shape mismatch"):
        func(np.zeros(5), np.zeros(4))


@pytest.mark.parametrize("func", [r_squared, nrmse_fit, max_abs_error, ssr])
def test_empty_refused(func):
    with pytest.raises(ValueError, match="empty"):
        func([], [])


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("which", ["y", "yhat"])
def test_non_finite_refused(bad, which):
    y = np.arange(6.0)
    yhat = np.arange(6.0) + 0.1
    (y if which == "y" else yhat)[3] = bad
    with pytest.raises(ValueError, match=rf"{which} contains 1 non-finite .* index 3"):
        channel_fit("theta_l", y, yhat)


def test_channel_fit_fields_and_dict():
    f = channel_fit("theta_l", Y, YHAT)
    assert f == ChannelFit(
        "theta_l", 4, pytest.approx(0.8), pytest.approx(55.27864045), 1.0, 0.5, 1.0
    )
    d = f.as_dict()
    assert set(d) == {"name", "n", "r2", "nrmse_fit", "max_abs_error", "rmse", "ssr"}
    assert d["rmse"] == pytest.approx(0.5)
    with pytest.raises(AttributeError):
        f.r2 = 1.0  # frozen


def test_information_criteria_formulas():
    n, k, s = 100, 3, 2.0
    assert aicc(s, n, k) == pytest.approx(
        n * math.log(s / n) + 2 * k + 2 * k * (k + 1) / (n - k - 1)
    )
    assert bic(s, n, k) == pytest.approx(n * math.log(s / n) + k * math.log(n))


def test_aicc_infinite_without_degrees_of_freedom():
    assert aicc(1.0, 5, 4) == math.inf  # n - k - 1 = 0
    assert aicc(1.0, 5, 6) == math.inf
    assert math.isfinite(aicc(1.0, 6, 4))


@pytest.mark.parametrize("criterion", [aicc, bic])
def test_criteria_rank_models(criterion):
    n = 1000
    small = criterion(10.0, n, 3)
    # Two more parameters that barely lower SSR: not worth it.
    assert criterion(9.99, n, 5) > small
    # Two more parameters that halve SSR: clearly worth it.
    assert criterion(5.0, n, 5) < small


@pytest.mark.parametrize("criterion", [aicc, bic])
@pytest.mark.parametrize(
    ("s", "n", "k"), [(-1.0, 10, 1), (math.nan, 10, 1), (1.0, 0, 1), (1.0, 10, -1), (1.0, 10.5, 1)]
)
def test_criteria_refuse_bad_arguments(criterion, s, n, k):
    with pytest.raises(ValueError):
        criterion(s, n, k)


def test_perfect_fit_criteria_are_minus_infinity():
    assert aicc(0.0, 10, 2) == -math.inf
    assert bic(0.0, 10, 2) == -math.inf


def test_fit_table_contains_names_and_numbers():
    rng = np.random.default_rng(0)
    y = np.cumsum(rng.normal(size=200))
    fits = [
        channel_fit("theta_l", y, y + rng.normal(scale=0.01, size=200)),
        channel_fit("alpha (exp. 4)", Y, YHAT),
    ]
    text = fit_table(fits, title="brake, estimation input")
    lines = text.splitlines()
    assert lines[0] == "brake, estimation input"
    assert "R²" in lines[1] and "fit %" in lines[1] and "max |e| [rad]" in lines[1]
    assert "RMSE [rad]" in lines[1] and "SSR" in lines[1]
    assert len(lines) == 2 + 1 + len(fits)  # title, header, rule, rows
    for f in fits:
        assert f.name in text
        assert f"{f.r2:.4f}" in text
        assert f"{f.nrmse_fit:.2f}" in text
        assert f"{f.max_abs_error:.3e}" in text
        assert f"{f.rmse:.3e}" in text
        assert f"{f.ssr:.3e}" in text
    row = lines[-1]
    assert row.startswith("alpha (exp. 4)")
    assert "0.8000" in row and "55.28" in row and "1.000e+00" in row and "5.000e-01" in row
    # Columns line up: every separator sits at the same position in header and rows.
    # (" | " is the column separator; the "|e|" inside a header is not surrounded by spaces.)
    seps = [[m.start() for m in re.finditer(" [|] ", ln)] for ln in (lines[1], *lines[3:])]
    assert len(seps[0]) == 5
    assert all(s == seps[0] for s in seps)


def test_fit_table_without_title_and_nan():
    f = channel_fit("flat", np.ones(3), np.zeros(3))
    text = fit_table([f])
    assert text.splitlines()[0].startswith("channel")
    # A constant measurement has no R² or fit %: said in words, never "nan".
    assert "nan" not in text and "n/a" in text
    assert "the measured signal is constant" in text.splitlines()[-1]


def test_fit_table_refusals():
    with pytest.raises(ValueError, match="at least one"):
        fit_table([])
    with pytest.raises(ValueError, match="not a ChannelFit"):
        fit_table([{"name": "theta_l"}])

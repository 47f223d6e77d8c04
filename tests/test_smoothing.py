"""rotorbayes.util.smoothing against scipy.signal's Savitzky-Golay filter, and the tail
probabilities taken from scipy.special against scipy.stats (the independent references:
scipy's own implementations)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from rotorbayes.util.smoothing import lowpass, savgol_coeffs, savgol_filter


@pytest.mark.parametrize("window", [5, 7, 11, 151])
@pytest.mark.parametrize("deriv", [0, 1, 2])
def test_filter_matches_scipy(window, deriv):
    rng = np.random.default_rng(window + deriv)
    t = np.arange(3000) * 1e-3
    x = 3.0 * np.sin(2.1 * t) + 0.5 * t**2 + 1e-3 * rng.standard_normal(t.size)
    ours = savgol_filter(x, window, 3, deriv=deriv, delta=1e-3)
    ref = signal.savgol_filter(x, window, 3, deriv=deriv, delta=1e-3)
    scale = np.abs(ref).max()
    assert np.abs(ours - ref).max() <= 1e-9 * scale
    # The edges (within half a window of the ends) are the fitted polynomial's.
    h = window // 2
    assert np.abs(ours[:h] - ref[:h]).max() <= 1e-9 * scale
    assert np.abs(ours[-h:] - ref[-h:]).max() <= 1e-9 * scale


def test_coefficients_match_scipy():
    for window, order, deriv in [(11, 3, 0), (7, 2, 1), (151, 3, 2)]:
        ours = savgol_coeffs(window, order, deriv=deriv, delta=0.5)
        ref = signal.savgol_coeffs(window, order, deriv=deriv, delta=0.5, use="dot")
        assert np.abs(ours - ref).max() <= 1e-10 * np.abs(ref).max()


def test_bad_windows_say_why():
    with pytest.raises(ValueError, match="odd"):
        savgol_filter(np.zeros(50), 10, 3)
    with pytest.raises(ValueError, match="order"):
        savgol_filter(np.zeros(50), 5, 5)
    with pytest.raises(ValueError, match="fewer"):
        savgol_filter(np.zeros(4), 5, 3)


def test_tail_probabilities_from_scipy_special_match_scipy_stats():
    """The score tests' and the likelihood-ratio test's p-values, taken from scipy.special
    (scipy.stats is not imported by fit and diagnose), against scipy.stats."""
    from scipy import stats

    from rotorbayes.diagnosis import compare, score

    for t in (-3.0, -0.2, 0.0, 1.7, 6.0):
        for df in (3, 19, 200):
            assert score._t_sf(t, df) == pytest.approx(stats.t.sf(t, df), rel=1e-12, abs=1e-300)
    rng = np.random.default_rng(0)
    S = rng.standard_normal((20, 3)) + 0.4
    F, p = score._stat(S, None)  # Hotelling's T² as an F statistic, (3, 17) degrees
    assert p == pytest.approx(stats.f.sf(F, 3, 17), rel=1e-12)
    T, p1 = score._stat(S[:, :1], True)
    assert p1 == pytest.approx(stats.t.sf(T, 19), rel=1e-12)
    from types import SimpleNamespace

    a = SimpleNamespace(k=5, rho=0.0, n=1000, ssr=1.00)
    b = SimpleNamespace(k=7, rho=0.2, n=1000, ssr=0.99)
    lr = compare.lr_test(a, b)
    assert lr["p_value"] == pytest.approx(stats.chi2.sf(lr["statistic"], 2), rel=1e-12)


def test_fit_and_diagnose_do_not_import_scipy_stats():
    import subprocess
    import sys

    code = (
        "import sys, rotorbayes.cli, rotorbayes.commands.fit, rotorbayes.commands.diagnose, "
        "rotorbayes.diagnosis.score, rotorbayes.diagnosis.compare, rotorbayes.inference.starts;"
        # the missing-torque map's input history, which used scipy.signal's lfilter
        "import numpy; from rotorbayes.diagnosis import torque;"
        "torque._history(numpy.ones(9), 1e-3);"
        "print(sorted(m for m in ('scipy.stats', 'scipy.signal') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


@pytest.mark.parametrize("tau_over_dt", [0.5, 20.0, 5000.0])
def test_lowpass_is_lfilter_bit_for_bit(tau_over_dt):
    rng = np.random.default_rng(3)
    v = np.cumsum(rng.normal(size=20_000)) + 3.0
    a = float(np.exp(-1.0 / tau_over_dt))
    want, _ = signal.lfilter([1.0 - a], [1.0, -a], v, zi=[a * v[0]])
    got = lowpass(v, a)
    assert np.array_equal(got, want)
    # Held first value: a constant input passes unchanged.
    assert np.array_equal(lowpass(np.full(50, 2.5), a), np.full(50, 2.5))

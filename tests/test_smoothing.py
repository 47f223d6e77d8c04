"""rotorbayes.util.smoothing against scipy.signal's Savitzky-Golay filter (the independent
reference: scipy's own implementation)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from rotorbayes.util.smoothing import savgol_coeffs, savgol_filter


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

"""Savitzky-Golay smoothing and differentiation (a least-squares polynomial over a sliding
window of samples), in NumPy; and a first-order low-pass filter (compiled).

The start from the data differentiates the measured angles this way, and the jitter check
fits local cubics.  scipy.signal does the same, but importing it brings scipy.stats along
(a third of a second on these machines, in every ``fit`` from the data); tests/
test_smoothing.py checks these against scipy.signal's ``savgol_coeffs`` and
``savgol_filter`` (mode ``'interp'``), and :func:`lowpass` against ``lfilter`` (the
missing-torque map's input history used it: importing scipy.signal cost ``diagnose`` 0.76 s).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


def _fit_matrix(window: int, order: int) -> tuple[np.ndarray, int]:
    """The pseudo-inverse of the window's Vandermonde matrix in ``s = z / half``
    (``z = -half .. half`` samples; scaled so its powers stay of order one), and ``half``."""
    if window % 2 != 1 or window < 1:
        raise ValueError(f"window = {window}: the window must be an odd number of samples")
    if not 0 <= order < window:
        raise ValueError(f"order = {order}: the polynomial order must be below the window")
    half = window // 2
    s = np.arange(-half, half + 1, dtype=float) / max(half, 1)
    A = s[:, None] ** np.arange(order + 1)[None, :]
    return np.linalg.pinv(A), half


def savgol_coeffs(window: int, order: int, deriv: int = 0, delta: float = 1.0) -> np.ndarray:
    """Weights ``h`` with ``y[i] = sum_j h[j] x[i - window // 2 + j]``: the ``deriv``-th
    derivative at the window's centre of the order-``order`` polynomial fitted to the
    window (samples ``delta`` apart).  (scipy.signal's default order is the reverse.)"""
    P, half = _fit_matrix(window, order)
    if deriv > order:
        return np.zeros(window)
    return math.factorial(deriv) * P[deriv] / (max(half, 1) * delta) ** deriv


def _edge(x: np.ndarray, P: np.ndarray, half: int, order: int, deriv: int, delta: float,
          at: np.ndarray) -> np.ndarray:  # fmt: skip
    """The ``deriv``-th derivative at the window positions ``at`` (in ``s``) of the
    polynomial fitted to the window ``x``."""
    c = P @ x
    out = np.zeros(at.size)
    for p in range(deriv, order + 1):
        out += c[p] * (math.factorial(p) // math.factorial(p - deriv)) * at ** (p - deriv)
    return out / (max(half, 1) * delta) ** deriv


def savgol_filter(
    x: np.ndarray, window: int, order: int, deriv: int = 0, delta: float = 1.0
) -> np.ndarray:
    """``x`` smoothed (``deriv`` 0) or differentiated by a sliding least-squares polynomial
    of order ``order`` over ``window`` samples (odd), samples ``delta`` apart.  Within
    half a window of either end, the polynomial fitted to the first (last) window is
    evaluated at each sample instead (scipy.signal's mode ``'interp'``)."""
    x = np.asarray(x, dtype=float)
    n = x.size
    if n < window:
        raise ValueError(f"{n} samples are fewer than the window of {window}")
    P, half = _fit_matrix(window, order)
    if deriv > order:
        return np.zeros(n)
    h = math.factorial(deriv) * P[deriv] / (max(half, 1) * delta) ** deriv
    y = np.empty(n)
    y[half : n - half] = np.correlate(x, h, mode="valid")
    if half:
        s = np.arange(-half, 0, dtype=float) / half
        y[:half] = _edge(x[:window], P, half, order, deriv, delta, s)
        y[n - half :] = _edge(x[n - window :], P, half, order, deriv, delta, -s[::-1])
    return y


@njit(cache=True, error_model="numpy")
def _lowpass(v, a, z):  # pragma: no cover - compiled
    y = np.empty(v.shape[0])
    b = 1.0 - a
    for i in range(v.shape[0]):
        y[i] = b * v[i] + z
        z = a * y[i]
    return y


def lowpass(v: np.ndarray, a: float) -> np.ndarray:
    """``y[i] = (1 - a) v[i] + a y[i - 1]``, starting as if ``v[0]`` had been held
    forever (``y[-1] = v[0]``): a first-order low-pass of pole ``a`` (``exp(-dt/tau)``),
    the same operations in the same order as scipy.signal's ``lfilter([1 - a], [1, -a],
    v, zi=[a v[0]])``."""
    v = np.ascontiguousarray(v, dtype=float)
    if v.size == 0:
        return v.copy()
    return _lowpass(v, float(a), float(a) * float(v[0]))


__all__ = ["lowpass", "savgol_coeffs", "savgol_filter"]

"""The solver's exponential Stribeck decay, ``exp(-x**delta) = G(delta * log x)`` with
``G(v) = exp(-exp(v))`` from a table of cubic Hermite pieces (model/friction.py), against
NumPy's exponentials: its error, its ends, and that its pieces join with equal values
and slopes (so the simulation stays continuously differentiable in the parameters)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from rotorbayes.model import friction


@njit(cache=True)
def _g_many(v):
    out = np.empty_like(v)
    for i in range(v.size):
        out[i] = friction.stribeck_g(v[i])
    return out


@njit(cache=True)
def _s_many(x, delta, x_cut):
    out = np.empty_like(x)
    for i in range(x.size):
        out[i] = friction.stribeck(x[i], delta, friction.SHAPE_EXP, x_cut)
    return out


def test_the_table_is_within_2e_11_of_the_function_everywhere():
    hi = math.log(friction.EXP_NEGLIGIBLE)
    v = np.linspace(friction.G_LO - 2.0, hi + 1.0, 3_000_001)
    err = np.abs(_g_many(v) - np.exp(-np.exp(v)))
    assert err.max() < 2e-11  # measured 1.09e-11 (at v = 0.97)
    # Halfway between nodes, where a cubic piece is furthest from its ends.
    mid = friction.G_LO + (np.arange(friction.G_TABLE.shape[0]) + 0.5) / friction.G_PER_UNIT
    assert np.abs(_g_many(mid) - np.exp(-np.exp(mid))).max() < 2e-11


def test_the_decay_for_several_shapes_and_its_ends():
    for delta in (0.5, 1.0, 1.75, 2.0575, 3.0):
        x_cut = friction.negligible_x(delta)
        x = np.concatenate([np.geomspace(1e-12, x_cut * 0.999999, 200_000), [0.0, x_cut]])
        ref = np.exp(-(x**delta))
        ref[-1] = 0.0  # at x_cut and beyond the decay (< 1.2e-17) is dropped
        assert np.abs(_s_many(x, delta, x_cut) - ref).max() < 2e-11, delta
    assert math.isnan(friction.stribeck(math.nan, 2.0, friction.SHAPE_EXP, 5.0))
    assert friction.stribeck(1e-300, 2.0, friction.SHAPE_EXP, 5.0) == 1.0


def test_pieces_join_with_equal_values_and_slopes():
    """Left and right one-sided slopes at interior nodes agree to what the step's own
    error allows; values agree to rounding.  (A table of straight lines between the
    nodes, continuous but not C1, differs by up to 6e-3 here.)"""
    k = np.arange(40, friction.G_TABLE.shape[0] - 1, 37)
    v = friction.G_LO + k / friction.G_PER_UNIT
    eps = 1e-6
    at = _g_many(v)
    left = (at - _g_many(v - eps)) / eps
    right = (_g_many(v + eps) - at) / eps
    # |G'| <= 0.37, so 2e-13 apart the values may differ by 7.4e-14, no more.
    assert np.abs(_g_many(v - 1e-13) - _g_many(v + 1e-13)).max() < 1e-13
    assert np.abs(left - right).max() < 5e-6
    # The control: chords between the same nodes change slope by much more.
    nodes = np.arange(friction.G_TABLE.shape[0] + 1) / friction.G_PER_UNIT
    g = np.exp(-np.exp(friction.G_LO + nodes))
    chord = np.diff(g) * friction.G_PER_UNIT
    assert np.abs(np.diff(chord)[k - 1]).max() > 1e-3

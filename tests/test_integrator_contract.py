"""Contracts of the integrator: continuity in the parameters, failure statuses, batches."""

from __future__ import annotations

import numpy as np
import pytest

import rotorbayes as rb
from rotorbayes.kernel import layout as integrator
from rotorbayes.model.parameters import thesis_set


@pytest.fixture(scope="module")
def brake_case():
    t, u = rb.signals.estimation_signal(20.0, seed=5)
    p = thesis_set("4.3", "P_ref")
    meas = rb.simulate(p, u, dt=1e-3, config="brake", alpha0=0.4)
    sim = rb.Simulator("brake", u, 1e-3, effects=["initial_torsion"])
    return p, meas, sim


def _sse(sim, p, meas, name, value):
    q = dict(p, alpha0=0.4)
    q[name] = value
    st, thu, thl = sim.angles(sim.kernel_vector(q))
    assert st == 0
    return float(np.sum((thl - meas.theta_l) ** 2))


@pytest.mark.parametrize(
    "name,rel", [("Ts_l", 0.05), ("k_alpha", 0.05), ("b_l", 0.2), ("ws_l", 0.05)]
)
def test_sse_scan_has_no_jumps(brake_case, name, rel):
    """A fine 1-D scan of the SSE is smooth: second differences stay small compared with
    the curvature scale, i.e. no jumps from step-size or band decisions (``ws_l`` sets the
    Stribeck substeps, see rotorbayes.kernel.terms.stribeck_step)."""
    p, meas, sim = brake_case
    grid = p[name] * (1 + np.linspace(-rel, rel, 201))
    f = np.array([_sse(sim, p, meas, name, v) for v in grid])
    d1 = np.diff(f)
    d2 = np.diff(f, 2)
    # A jump of size J would show up as |d2| ~ J; a smooth curve has |d2| ~ |d1| * h.
    assert np.max(np.abs(d2)) < 0.05 * np.max(np.abs(d1)) + 1e-12
    # The minimum lies at the true value (the data are noise-free).
    assert abs(grid[np.argmin(f)] - p[name]) <= 2 * (grid[1] - grid[0])


@pytest.mark.parametrize("name", ["Ts_l", "ws_l", "delta_l", "k_alpha", "Tc_u", "alpha0"])
def test_finite_differences_agree_at_two_steps(brake_case, name):
    """Derivatives of the simulated angle by central differences at relative steps 1e-4
    and 1e-6 agree: the output is smooth well below the step (no solver jitter)."""
    p, meas, sim = brake_case
    base = dict(p, alpha0=0.4)
    x = base[name]

    def thl(v):
        q = dict(base)
        q[name] = v
        return sim.angles(sim.kernel_vector(q))[2]

    ders = []
    for rel in (1e-4, 1e-6):
        h = rel * (abs(x) if x != 0 else 1.0)
        ders.append((thl(x + h) - thl(x - h)) / (2 * h))
    scale = np.max(np.abs(ders[0]))
    assert scale > 0
    assert np.max(np.abs(ders[0] - ders[1])) < 1e-3 * scale


def test_invalid_parameters_give_a_status_not_a_crash():
    u = np.full(1001, 1.0)
    sim = rb.Simulator("brake", u, 1e-3)
    p = dict(thesis_set("4.3", "P_ref"))
    for bad in ({"J_l": -1.0}, {"ws_l": 0.0}, {"Tc_u": 0.01, "dTc_u": 0.5}, {"b_l": np.nan}):
        q = dict(p, **bad)
        st, thu, thl = sim.angles(sim.kernel_vector(q))
        assert st == integrator.BAD_PARAMETERS
    with pytest.raises(rb.SimulationError, match="J_l = -1"):
        rb.simulate(dict(p, J_l=-1.0), u, dt=1e-3, config="brake")


def test_blow_up_is_reported():
    # Negative friction is refused; a huge motor constant with a tiny inertia runs away
    # past the velocity guard instead of returning silent inf/NaN.
    u = np.full(2001, 5.0)
    p = dict(thesis_set("4.1", "P_ref"), k_m=1e9, J_u=1e-3, b_u=0.0, db_u=0.0)
    sim = rb.Simulator("upper", u, 1e-3)
    st, thu, _ = sim.angles(sim.kernel_vector(p))
    assert st == integrator.BLOW_UP
    with pytest.raises(rb.SimulationError, match="blew up"):
        sim.simulate(p)


def test_batch_equals_single_runs():
    t, u = rb.signals.estimation_signal(10.0, seed=2)
    sim = rb.Simulator("brake", u, 1e-3)
    rng = np.random.default_rng(0)
    base, q = sim.kernel_vector(thesis_set("4.3", "P_ref"))
    KV = base * (1 + 0.1 * rng.standard_normal((6, base.size)) * (base != 0))
    KV[:, rb.parameters.INDEX["Ts_l"]] = np.maximum(KV[:, rb.parameters.INDEX["Ts_l"]], 0.1)
    st, thu, thl = sim.run_batch(KV)
    for i in range(len(KV)):
        s1, a, b = sim.angles((KV[i], q))
        assert s1 == st[i]
        np.testing.assert_array_equal(a, thu[i])
        np.testing.assert_array_equal(b, thl[i])


def test_rest_stays_at_rest():
    # Below the upper disc's static band nothing moves (u * k_m < Tc_u - |dTc_u|).
    u = np.full(3001, 0.05)
    s = rb.simulate(None, u, dt=1e-3, config="brake")
    assert np.all(s.theta_u == 0) and np.all(s.theta_l == 0)
    assert np.all(s.mode_u == 0) and np.all(s.mode_l == 0)


def test_pre_wound_string_unwinds_in_the_coupled_configuration():
    # alpha0 beyond Tc_l / k_alpha releases the lower disc at t = 0.
    u = np.zeros(5001)
    s = rb.simulate("thesis:4.2:P_ref", u, dt=1e-3, config="coupled", alpha0=0.8)
    assert s.theta_l.min() < -0.3
    assert abs(s.alpha[-1]) < 0.8


def test_step_choice_converges():
    """Default 5 ms steps and exact 1-sample steps agree far below the encoder floor."""
    t, u = rb.signals.estimation_signal(30.0, seed=3)
    a = rb.simulate("thesis:4.3:P_ref", u, dt=1e-3, config="brake")
    b = rb.simulate("thesis:4.3:P_ref", u, dt=1e-3, config="brake", step=1e-3)
    assert np.max(np.abs(a.theta_l - b.theta_l)) < 1e-5

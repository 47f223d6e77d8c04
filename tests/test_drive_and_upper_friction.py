"""Two catalogue effects beyond the thesis (issue 32, point 2): ``upper_stribeck`` (the
lower disc's Stribeck law on the upper disc) and ``drive_lag`` (the command through a
first-order lag before the motor).

Accuracy tests compare with ``tests/reference.py`` (scipy DOP853, exact switching; the
lag there is :class:`refdata.LaggedInput`, the lag's recurrence on a 0.1 ms grid with a
Hermite interpolant -- not rotorbayes's closed form).  The hidden-effect tests are in
``tests/test_diagnosis_reference.py`` (ranked first, claimed, fixed) and
``analyses/reference_loop.py`` (the printed loop).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from refdata import LaggedInput
from reference import reference_simulate

import rotorbayes as rb
from rotorbayes.model import CATALOGUE, Model
from rotorbayes.model.parameters import thesis_set

TOL = 1.5e-5


def test_registry_entries():
    lag, stri = CATALOGUE["drive_lag"], CATALOGUE["upper_stribeck"]
    assert lag.names == ("tau_drive",) and lag.motor and lag.resolution.kind == "sample"
    assert stri.names == ("dTs_u", "ws_u", "delta_u") and stri.motor
    assert [p.nuisance for p in stri.parameters] == [False, True, True]
    assert stri.parameters[0].null == 0.0 == stri.parameters[0].lower  # one-sided
    assert "input_history" in lag.explains and "velocity" in stri.explains
    m = Model("coupled").with_effects(["drive_lag", "upper_stribeck"])
    assert {"tau_drive", "dTs_u", "ws_u", "delta_u"} <= set(m.active)


def test_a_vanishing_lag_is_the_plain_input():
    t, u = rb.signals.estimation_signal(5.0, seed=2)
    p = thesis_set("4.3", "P_ref")
    plain = rb.simulate(p, u, dt=1e-3, config="brake")
    tiny = rb.simulate(dict(p, tau_drive=1e-12), u, dt=1e-3, config="brake", effects=["drive_lag"])
    assert np.max(np.abs(tiny.theta_u - plain.theta_u)) < 1e-9
    assert np.max(np.abs(tiny.theta_l - plain.theta_l)) < 1e-9
    off = rb.simulate(dict(p, dTs_u=0.0), u, dt=1e-3, config="brake", effects=["upper_stribeck"])
    assert np.array_equal(off.theta_u, plain.theta_u)


def _sticking_input(t, p):
    """A slow sine whose motor torque peaks at 1.3 times the upper static level: the upper
    disc sticks at every reversal for a good part of the time."""
    a = 1.3 * (p["Tc_u"] + p["dTs_u"]) / p["k_m"]
    return a * (np.sin(2 * np.pi * 0.4 * t) + 0.15 * np.sin(2 * np.pi * 1.3 * t)) / 1.15


def _stribeck_cases():
    coupled, brake, upper = (thesis_set(c, "P_ref") for c in ("4.2", "4.3", "4.1"))
    return [
        ("coupled", dict(coupled, dTs_u=0.15, ws_u=0.7, delta_u=1.6), "estimation"),
        ("brake", dict(brake, dTs_u=0.1, ws_u=1.0, delta_u=2.0), "estimation"),
        ("upper", dict(upper, dTs_u=0.2, ws_u=0.4, delta_u=2.2), "sticking"),
    ]


@pytest.mark.slow
@pytest.mark.parametrize(
    "config,params,signal", _stribeck_cases(), ids=[c[0] + "-" + c[2] for c in _stribeck_cases()]
)
def test_upper_stribeck_matches_the_reference(config, params, signal):
    if signal == "sticking":
        t = np.arange(30001) * 1e-3
        u = _sticking_input(t, params)
    else:
        t, u = rb.signals.estimation_signal(30.0, seed=3)
    sim = rb.simulate(params, u, dt=1e-3, config=config, effects=["upper_stribeck"])
    plain = rb.simulate(
        {k: v for k, v in params.items() if k not in ("dTs_u", "ws_u", "delta_u")},
        u,
        dt=1e-3,
        config=config,
    )
    q = dict(params)
    if config == "coupled":
        q["Ts_l"] = q["Tc_l"]
    ref = reference_simulate(q, t, u, config)
    assert np.max(np.abs(sim.theta_u - ref["theta_u"])) < TOL
    assert np.max(np.abs(sim.theta_u - plain.theta_u)) > 1e-2  # the effect matters
    if config != "upper":
        assert np.max(np.abs(sim.theta_l - ref["theta_l"])) < TOL
    else:
        assert 0.05 < float(np.mean(ref["mode_u"] == 0)) < 0.9  # the upper disc sticks


def _lag_cases():
    brake, coupled = thesis_set("4.3", "P_ref"), thesis_set("4.2", "P_ref")
    return [
        ("brake", dict(brake, tau_drive=0.008)),
        ("coupled", dict(coupled, tau_drive=0.02, t_delay=0.005)),
        ("brake", dict(brake, tau_drive=0.004, u_deadzone=0.3, u_offset=0.05)),
    ]


_EFFECT_OF = {
    "tau_drive": "drive_lag",
    "t_delay": "input_delay",
    "u_deadzone": "motor_deadzone",
    "u_offset": "voltage_offset",
}


@pytest.mark.slow
@pytest.mark.parametrize(
    "config,params", _lag_cases(), ids=[f"{c[0]}-{len(c[1])}" for c in _lag_cases()]
)
def test_drive_lag_matches_the_reference(config, params):
    # 12 s (was 30): the reference integrates each of the input's samples as a segment of
    # its own (about 100 s a case for 30 s on these 2 cores); 12 s of the estimation input
    # still hold its steps, reversals and the lower disc's sticking.
    t, u = rb.signals.estimation_signal(12.0, seed=3)
    effects = [e for k, e in _EFFECT_OF.items() if k in params]
    sim = rb.simulate(params, u, dt=1e-3, config=config, effects=effects)
    q = dict(params)
    tau = q.pop("tau_drive")
    if config == "coupled":
        q["Ts_l"] = q["Tc_l"]

    def linear(tq):
        return np.interp(tq, t, u)

    ref = reference_simulate(q, t, None, config, u_func=LaggedInput(linear, tau, 13.0), u_breaks=t)
    assert np.max(np.abs(sim.theta_u - ref["theta_u"])) < TOL
    assert np.max(np.abs(sim.theta_l - ref["theta_l"])) < TOL
    without = rb.simulate(
        q, u, dt=1e-3, config=config, effects=[e for e in effects if e != "drive_lag"]
    )
    assert np.max(np.abs(sim.theta_u - without.theta_u)) > 1e-2


@pytest.mark.parametrize(
    "effect,name,value", [("drive_lag", "tau_drive", 0.008), ("upper_stribeck", "dTs_u", 0.1)]
)
def test_smooth_in_the_new_parameters(effect, name, value):
    """The squared error is smooth in the parameter, and central differences at two
    steps agree (no jitter from the solver's decisions)."""
    t, u = rb.signals.estimation_signal(15.0, seed=5)
    sim = rb.Simulator("brake", u, 1e-3, effects=[effect])
    p = dict(thesis_set("4.3", "P_ref"), **sim.model.null_values())
    p[name] = value
    meas = sim.simulate(p).theta_u

    def thu(v):
        st, out, _ = sim.angles(sim.kernel_vector(dict(p, **{name: v})))
        assert st == 0
        return out

    grid = value * (1 + np.linspace(-0.05, 0.05, 101))
    f = np.array([np.sum((thu(v) - meas) ** 2) for v in grid])
    d1, d2 = np.diff(f), np.diff(f, 2)
    assert np.max(np.abs(d2)) < 0.05 * np.max(np.abs(d1)) + 1e-12
    ders = [(thu(value * (1 + r)) - thu(value * (1 - r))) / (2 * r * value) for r in (1e-4, 1e-6)]
    scale = np.max(np.abs(ders[0]))
    assert scale > 0 and math.isfinite(scale)
    assert np.max(np.abs(ders[0] - ders[1])) < 1e-3 * scale

"""Self-checks of the independent reference integrator in ``tests/reference.py``.

These tests validate the reference against published benchmark numbers and analytic
solutions, so that it can in turn be trusted to validate the production integrator.
"""

from __future__ import annotations

import math
import os
import sys

import numpy as np
import pytest
from scipy.optimize import brentq

sys.path.insert(0, os.path.dirname(__file__))
from reference import reference_simulate  # noqa: E402

# thesis values (brake configuration)
BRAKE = dict(
    k_m=4.3228,
    J_u=0.4765,
    Tc_u=0.3798,
    dTc_u=-0.0058,
    b_u=2.4245,
    db_u=-0.0084,
    J_l=0.0414,
    k_alpha=0.0775,
    Tc_l=0.0473,
    b_l=0.0105,
    Ts_l=0.2781,
    ws_l=1.4302,
    delta_l=2.0575,
)


def _brake_input(T: float, dt: float = 1e-3):
    t = np.arange(0.0, T + 0.5 * dt, dt)
    return t, 0.8 + 0.6 * np.sin(0.4 * t)


# --------------------------------------------------------------------------------------
# 1. Leine's belt benchmark (switch model) through config "prescribed"
# --------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def belt_run():
    params = dict(J_l=1.0, k_alpha=1.0, Tc_l=0.0, Ts_l=1.0, ws_l=1.0 / 3.0, delta_l=1.0, b_l=0.0)
    t = np.arange(0.0, 100.0 + 0.005, 0.01)
    res = reference_simulate(
        params,
        t,
        None,
        "prescribed",
        theta_u_prescribed=0.2 * t,
        stribeck_shape="rational",
        dense_output=True,
    )
    return t, res


def test_belt_friction_law_is_leines(belt_run):
    # sanity: the lower disc starts at rest and breaks away when x = 0.2 t reaches 1
    _, res = belt_run
    t0, disc, kind = res["events"][0]
    assert disc == "l" and kind == "slip+"
    assert t0 == pytest.approx(5.0, abs=1e-12)


def test_belt_benchmark_limit_cycle(belt_run):
    _, res = belt_run
    sol = res["sol"]
    stick_t = np.array([ev[0] for ev in res["events"] if ev[1] == "l" and ev[2] == "stick"])
    assert stick_t.size >= 5

    def x_of(tt):
        return 0.2 * np.atleast_1d(tt) - sol(tt)[2]

    periods = np.diff(stick_t)
    assert periods[-1] == pytest.approx(12.00103, abs=1e-4)
    assert periods[-2] == pytest.approx(12.00103, abs=1e-4)
    x_stick = float(x_of(stick_t[-1])[0])
    assert x_stick == pytest.approx(-0.541006, abs=1e-4)

    # extrema of x over the last full cycle: x' = 0.2 - omega_l = 0 (dense output + root)
    a, b = stick_t[-2], stick_t[-1]
    tt = np.arange(a, b, 1e-3)
    xg = x_of(tt)
    xdot = 0.2 - sol(tt)[3]
    roots = []
    for i in np.nonzero(np.sign(xdot[:-1]) * np.sign(xdot[1:]) < 0)[0]:
        roots.append(brentq(lambda s: 0.2 - sol(s)[3][0], tt[i], tt[i + 1], xtol=1e-14))
    xr = x_of(np.array(roots))
    x_max = max(xg.max(), xr.max())
    x_min = min(xg.min(), xr.min())
    assert x_max == pytest.approx(1.133945, abs=1e-4)
    assert x_min == pytest.approx(-0.555433, abs=1e-4)
    # stick phase: omega_l == 0 exactly, x rises from the stick-onset value to 1
    ts = np.linspace(a, a + 0.99 * (1.0 - x_stick) / 0.2, 50)
    assert np.all(sol(ts)[3] == 0.0)


# --------------------------------------------------------------------------------------
# 2. analytic pure-slip / break-away / stick cases of the upper disc
# --------------------------------------------------------------------------------------
def test_upper_viscous_only_analytic():
    km, J, b, u0 = 4.3228, 0.4765, 2.4245, 0.7
    params = dict(k_m=km, J_u=J, Tc_u=0.0, b_u=b)
    t = np.arange(0.0, 10.0 + 5e-4, 1e-3)
    res = reference_simulate(params, t, np.full(t.shape, u0), "upper")
    w_inf = km * u0 / b
    tau = J / b
    w_exact = w_inf * (1.0 - np.exp(-t / tau))
    th_exact = w_inf * (t - tau * (1.0 - np.exp(-t / tau)))
    assert res["theta_l"] is None and res["omega_l"] is None
    assert np.max(np.abs(res["omega_u"] - w_exact)) < 1e-9
    assert np.max(np.abs(res["theta_u"] - th_exact)) < 1e-9
    assert res["events"][0][1:] == ("u", "slip+")


def test_upper_ramp_breakaway_analytic():
    # u = r t: the disc sticks until k_m r t = Tc_u + dTc_u, then
    # J w' = k_m r (t - t*) - (b_u + db_u) w  (linear, analytic)
    km, J, Tc, dTc, b, db, r = 4.3228, 0.4765, 0.3798, -0.0058, 2.4245, -0.0084, 0.05
    params = dict(k_m=km, J_u=J, Tc_u=Tc, dTc_u=dTc, b_u=b, db_u=db)
    t = np.arange(0.0, 8.0 + 5e-4, 1e-3)
    res = reference_simulate(params, t, r * t, "upper")
    t_star = (Tc + dTc) / (km * r)
    assert res["events"][0][1:] == ("u", "slip+")
    assert res["events"][0][0] == pytest.approx(t_star, abs=1e-10)
    c = b + db
    tau = np.clip(t - t_star, 0.0, None)
    g = km * r / c
    w_exact = g * (tau - (J / c) * (1.0 - np.exp(-c * tau / J)))
    th_exact = g * (0.5 * tau**2 - (J / c) * (tau - (J / c) * (1.0 - np.exp(-c * tau / J))))
    assert np.all(res["omega_u"][t < t_star] == 0.0)
    assert np.max(np.abs(res["omega_u"] - w_exact)) < 1e-9
    assert np.max(np.abs(res["theta_u"] - th_exact)) < 1e-9


def test_upper_stop_and_stick_time_analytic():
    # constant drive, then the voltage drops to 0 within one sample; after that
    # J w' = -(Tc + dTc) - (b + db) w  until w = 0 at an analytic time, then stick.
    km, J, Tc, dTc, b, db = 4.3228, 0.4765, 0.3798, -0.0058, 2.4245, -0.0084
    params = dict(k_m=km, J_u=J, Tc_u=Tc, dTc_u=dTc, b_u=b, db_u=db)
    dt = 1e-3
    t = np.arange(0.0, 6.0 + 0.5 * dt, dt)
    k_off = 3000
    u = np.where(np.arange(t.size) < k_off, 1.0, 0.0)
    res = reference_simulate(params, t, u, "upper")
    w0 = res["omega_u"][k_off]
    A, c = Tc + dTc, b + db
    t_stick = t[k_off] + (J / c) * math.log(1.0 + c * w0 / A)
    sticks = [ev for ev in res["events"] if ev[2] == "stick"]
    assert len(sticks) == 1
    assert sticks[0][0] == pytest.approx(t_stick, abs=1e-9)
    after = t > t_stick
    assert np.all(res["omega_u"][after] == 0.0)
    assert np.all(res["theta_u"][after] == res["theta_u"][-1])
    # below the band the disc never moves
    res0 = reference_simulate(params, t, np.full(t.shape, 0.9 * A / km), "upper")
    assert np.all(res0["theta_u"] == 0.0) and not res0["events"]


# --------------------------------------------------------------------------------------
# 3. stick consistency in the brake configuration
# --------------------------------------------------------------------------------------
@pytest.mark.slow
def test_brake_lower_stick_consistency():
    t, u = _brake_input(30.0)
    res = reference_simulate(BRAKE, t, u, "brake", dense_output=True)
    ka, Ts = BRAKE["k_alpha"], BRAKE["Ts_l"]
    lower = [ev for ev in res["events"] if ev[1] == "l"]
    kinds = [ev[2] for ev in lower]
    assert kinds.count("stick") >= 2 and kinds.count("slip+") >= 2
    # modes alternate slip / stick for the lower disc
    assert all((k1 == "stick") != (k2 == "stick") for k1, k2 in zip(kinds, kinds[1:], strict=False))

    alpha = res["theta_l"] - res["theta_u"]
    stuck = res["mode_l"] == 0
    assert stuck.sum() > 1000 and (~stuck).sum() > 1000
    # in stick: exactly at rest, no kinetic energy, string torque inside the static band
    assert np.all(res["omega_l"][stuck] == 0.0)
    assert np.all(np.abs(ka * alpha[stuck]) <= Ts + 1e-12)
    # theta_l frozen during each stick interval
    edges = np.flatnonzero(np.diff(stuck.astype(int)))
    for s0, s1 in zip(edges[:-1], edges[1:], strict=True):
        if stuck[s0 + 1]:
            seg = res["theta_l"][s0 + 1 : s1 + 1]
            assert np.all(seg == seg[0])
    # break-away happens exactly when the string torque reaches the static friction
    sol = res["sol"]
    for tev, _, kind in lower:
        y = sol(tev)[:, 0]
        if kind.startswith("slip"):
            assert abs(ka * (y[2] - y[0])) == pytest.approx(Ts, abs=1e-9)
        else:
            assert y[3] == pytest.approx(0.0, abs=1e-9)
    # the upper disc keeps slipping forward for this input
    assert np.all(res["omega_u"][1:] > 0.0)


# --------------------------------------------------------------------------------------
# 4. tolerance convergence
# --------------------------------------------------------------------------------------
@pytest.mark.slow
def test_brake_tolerance_convergence():
    t, u = _brake_input(10.0)
    r9 = reference_simulate(BRAKE, t, u, "brake", rtol=1e-9, atol=1e-11)
    r11 = reference_simulate(BRAKE, t, u, "brake", rtol=1e-11, atol=1e-12)
    for key in ("theta_u", "theta_l"):
        assert np.max(np.abs(r9[key] - r11[key])) < 1e-7
    for key in ("omega_u", "omega_l"):
        assert np.max(np.abs(r9[key] - r11[key])) < 1e-7
    assert len(r9["events"]) == len(r11["events"])
    for e9, e11 in zip(r9["events"], r11["events"], strict=True):
        assert e9[1:] == e11[1:] and abs(e9[0] - e11[0]) < 1e-7


# --------------------------------------------------------------------------------------
# 5. input handling: kinks, offset, delay
# --------------------------------------------------------------------------------------
def test_input_is_piecewise_linear_and_offset_delay_exact():
    params = dict(BRAKE, c_alpha=0.003, alpha0=0.05)
    dt = 1e-3
    t = np.arange(0.0, 3.0 + 0.5 * dt, dt)
    rng = np.random.default_rng(1)
    u = 1.5 + 0.5 * rng.standard_normal(t.size)  # rough input, a kink at every sample
    base = reference_simulate(params, t, u, "coupled")
    # same piecewise-linear input on a finer grid -> same solution
    t2 = np.arange(0.0, 3.0 + 0.25 * dt, dt / 2)
    fine = reference_simulate(params, t2, np.interp(t2, t, u), "coupled")
    for key in ("theta_u", "omega_u", "theta_l", "omega_l"):
        assert np.max(np.abs(fine[key][::2] - base[key])) < 1e-9
    # u_offset is the same as adding the offset to u
    off = reference_simulate(dict(params, u_offset=0.2), t, u, "coupled")
    ref = reference_simulate(params, t, u + 0.2, "coupled")
    assert np.max(np.abs(off["theta_u"] - ref["theta_u"])) < 1e-10
    # a delay of n samples is the same as shifting the samples by n (holding u[0])
    n = 7
    dl = reference_simulate(dict(params, t_delay=n * dt), t, u, "coupled")
    us = np.concatenate([np.full(n, u[0]), u[:-n]])
    sh = reference_simulate(params, t, us, "coupled")
    for key in ("theta_u", "theta_l"):
        assert np.max(np.abs(dl[key] - sh[key])) < 1e-9


# --------------------------------------------------------------------------------------
# 6. user-effect hooks: extra_torque and friction_shift
# --------------------------------------------------------------------------------------
STATES = ("theta_u", "omega_u", "theta_l", "omega_l")


def _max_diff(r1: dict, r2: dict, keys=STATES) -> float:
    return max(float(np.max(np.abs(r1[k] - r2[k]))) for k in keys if r1[k] is not None)


def _same_events(r1: dict, r2: dict, tol: float) -> bool:
    e1, e2 = r1["events"], r2["events"]
    return len(e1) == len(e2) and all(
        a[1:] == b[1:] and abs(a[0] - b[0]) < tol for a, b in zip(e1, e2, strict=True)
    )


def _kinds(res: dict, disc: str) -> list[str]:
    return [e[2] for e in res["events"] if e[1] == disc]


def _upper_stick_slip_input(T: float, dt: float = 1e-2):
    # k_m |u| crosses the static band (Tc_u +- dTc_u ~ 0.37 N m) in both directions, so the
    # upper disc alternates slip+ / stick / slip- / stick
    t = np.arange(0.0, T + 0.5 * dt, dt)
    return t, 0.2 * np.sin(0.8 * t)


def test_zero_hooks_change_nothing():
    t, u = _brake_input(12.0, 1e-2)
    base = reference_simulate(BRAKE, t, u, "brake")
    hooked = reference_simulate(
        BRAKE, t, u, "brake",
        extra_torque=lambda *a: (0.0, 0.0), friction_shift=lambda *a: (0.0, 0.0),
    )  # fmt: skip
    for key in STATES:
        assert np.array_equal(base[key], hooked[key])
    assert base["events"] == hooked["events"]


def test_constant_extra_torque_on_upper_is_a_voltage_offset():
    c = 0.04
    km = BRAKE["k_m"]
    for config, (t, u) in (
        ("upper", _upper_stick_slip_input(16.0)),
        ("brake", _brake_input(12.0, 1e-2)),
    ):
        torque = reference_simulate(BRAKE, t, u, config, extra_torque=lambda *a: (km * c, 0.0))
        offset = reference_simulate(dict(BRAKE, u_offset=c), t, u, config)
        assert _max_diff(torque, offset) < 1e-9
        assert _same_events(torque, offset, 1e-9)
        # the extra torque enters the stick test: the runs really do stick and slip
        disc = "u" if config == "upper" else "l"
        assert "stick" in _kinds(torque, disc) and len(_kinds(torque, disc)) >= 3
        assert _max_diff(torque, reference_simulate(BRAKE, t, u, config)) > 1e-3


def test_constant_friction_shift_is_a_change_of_both_levels():
    d = 0.01
    t, u = _brake_input(12.0, 1e-2)
    shifted = reference_simulate(BRAKE, t, u, "brake", friction_shift=lambda *a: (0.0, d))
    levels = reference_simulate(
        dict(BRAKE, Tc_l=BRAKE["Tc_l"] + d, Ts_l=BRAKE["Ts_l"] + d), t, u, "brake"
    )
    assert _max_diff(shifted, levels) < 1e-9
    assert _same_events(shifted, levels, 1e-9)
    assert _kinds(shifted, "l").count("stick") >= 1 and _kinds(shifted, "l").count("slip+") >= 2
    assert _max_diff(shifted, reference_simulate(BRAKE, t, u, "brake")) > 1e-3
    # upper disc (Ts = Tc): a shift of its level, with stick-slip in both directions
    du = 0.03
    t, u = _upper_stick_slip_input(16.0)
    shifted = reference_simulate(BRAKE, t, u, "upper", friction_shift=lambda *a: (du, 0.0))
    levels = reference_simulate(dict(BRAKE, Tc_u=BRAKE["Tc_u"] + du), t, u, "upper")
    assert _max_diff(shifted, levels) < 1e-9
    assert _same_events(shifted, levels, 1e-9)
    kinds = _kinds(shifted, "u")
    assert {"stick", "slip+", "slip-"} <= set(kinds)


def test_damping_torque_hook_is_c_alpha():
    ca = 0.003
    t, u = _brake_input(12.0, 1e-2)

    def damping(t_, thu, wu, thl, wl, v):
        tq = ca * (wl - wu)
        return tq, -tq

    hooked = reference_simulate(BRAKE, t, u, "brake", extra_torque=damping)
    built = reference_simulate(dict(BRAKE, c_alpha=ca), t, u, "brake")
    assert _max_diff(hooked, built) < 1e-9
    assert _same_events(hooked, built, 1e-9)
    assert "stick" in _kinds(hooked, "l")


def test_hook_arguments_voltage_and_absent_disc():
    # v is the effective voltage (delay, offset, dead zone applied): k_m v as an extra
    # upper torque doubles k_m; in config "upper" the lower-disc arguments are 0
    params = dict(BRAKE, u_offset=0.03, t_delay=0.0123, u_deadzone=0.05)
    t, u = _upper_stick_slip_input(12.0)
    seen = []

    def motor_again(t_, thu, wu, thl, wl, v):
        seen.append((t_, thl, wl, v))
        return params["k_m"] * v, 0.0

    hooked = reference_simulate(params, t, u, "upper", extra_torque=motor_again)
    double = reference_simulate(dict(params, k_m=2 * params["k_m"]), t, u, "upper")
    assert _max_diff(hooked, double) < 1e-9
    assert _same_events(hooked, double, 1e-9)
    ts, thl, wl, v = np.array(seen).T
    assert np.all(thl == 0.0) and np.all(wl == 0.0)
    ve = np.interp(ts - params["t_delay"], t, u) + params["u_offset"]
    ve = np.where(np.abs(ve) <= params["u_deadzone"], 0.0,
                  ve - params["u_deadzone"] * np.sign(ve))  # fmt: skip
    assert np.max(np.abs(v - ve)) < 1e-12


def test_hook_arguments_prescribed_upper_motion():
    # in config "prescribed" theta_u / omega_u are the prescribed motion: a string torque
    # written as a hook adds to k_alpha and c_alpha (Leine's belt system, stick-slip)
    params = dict(J_l=1.0, k_alpha=1.0, Tc_l=0.0, Ts_l=1.0, ws_l=1.0 / 3.0, delta_l=1.0, b_l=0.0)
    t = np.arange(0.0, 30.0 + 0.005, 0.01)
    thp = 0.2 * t + 0.05 * np.sin(1.3 * t)
    k2, c2 = 0.5, 0.1

    def string(t_, thu, wu, thl, wl, v):
        assert v == 0.0
        return 0.0, -k2 * (thl - thu) - c2 * (wl - wu)

    kw = dict(theta_u_prescribed=thp, stribeck_shape="rational")
    hooked = reference_simulate(params, t, None, "prescribed", extra_torque=string, **kw)
    built = reference_simulate(dict(params, k_alpha=1.0 + k2, c_alpha=c2), t, None,
                               "prescribed", **kw)  # fmt: skip
    assert _max_diff(hooked, built) < 1e-9
    assert _same_events(hooked, built, 1e-9)
    assert _kinds(hooked, "l").count("stick") >= 2


def test_time_dependent_band_breakaway_analytic():
    # a sticking disc breaks loose when its band, shrinking with time, reaches the
    # external torque: the band must be evaluated at the current time.
    # upper: constant u0 inside the band, dT_u = -r t  ->  break-away at
    # t* = (Tc + dTc - k_m u0) / r, then J w' = r (t - t*) - (b + db) w  (analytic)
    km, J, Tc, dTc, b, db = 4.3228, 0.4765, 0.3798, -0.0058, 2.4245, -0.0084
    u0, r = 0.05, 0.05
    params = dict(k_m=km, J_u=J, Tc_u=Tc, dTc_u=dTc, b_u=b, db_u=db)
    t = np.arange(0.0, 6.0 + 5e-3, 1e-2)
    res = reference_simulate(params, t, np.full(t.shape, u0), "upper",
                             friction_shift=lambda t_, *a: (-r * t_, 0.0))  # fmt: skip
    t_star = (Tc + dTc - km * u0) / r
    assert [e[1:] for e in res["events"]] == [("u", "slip+")]
    assert res["events"][0][0] == pytest.approx(t_star, abs=1e-10)
    c = b + db
    tau = np.clip(t - t_star, 0.0, None)
    g = r / c
    w_exact = g * (tau - (J / c) * (1.0 - np.exp(-c * tau / J)))
    th_exact = g * (0.5 * tau**2 - (J / c) * (tau - (J / c) * (1.0 - np.exp(-c * tau / J))))
    assert np.max(np.abs(res["omega_u"] - w_exact)) < 1e-9
    assert np.max(np.abs(res["theta_u"] - th_exact)) < 1e-9
    # lower (prescribed theta_u = 0, pre-wound string): T_e = -k_alpha alpha0 is fixed,
    # the lower band edge -(Ts + dT - dTc) rises to it at t* = (Ts - dTc - k_alpha alpha0)/r
    pl = dict(J_l=0.0414, k_alpha=0.0775, Tc_l=0.0473, dTc_l=0.004, b_l=0.0105,
              Ts_l=0.2781, ws_l=1.4302, delta_l=2.0575, alpha0=3.3)  # fmt: skip
    r = 0.02
    t = t[t <= 2.0]  # keeps the shifted Coulomb level Tc_l - r t positive
    res = reference_simulate(pl, t, None, "prescribed", theta_u_prescribed=np.zeros(t.size),
                             friction_shift=lambda t_, *a: (0.0, -r * t_))  # fmt: skip
    t_star = (pl["Ts_l"] - pl["dTc_l"] - pl["k_alpha"] * pl["alpha0"]) / r
    assert 0.5 < t_star < 1.5
    assert res["events"][0][1:] == ("l", "slip-")
    assert res["events"][0][0] == pytest.approx(t_star, abs=1e-10)
    assert np.all(res["theta_l"][t <= t_star] == 0.0) and res["theta_l"][-1] < -1e-3


def _angle_ripple(a: float, phi: float):
    def shift(t_, thu, wu, thl, wl, v):
        return 0.0, BRAKE["Tc_l"] * a * math.sin(thl + phi)

    return shift


def test_angle_dependent_friction_shift_is_converged_and_consistent():
    t, u = _brake_input(20.0, 1e-2)
    shift = _angle_ripple(0.3, 0.7)
    r11 = reference_simulate(BRAKE, t, u, "brake", friction_shift=shift, dense_output=True)
    r13 = reference_simulate(BRAKE, t, u, "brake", friction_shift=shift, rtol=1e-13,
                             atol=1e-14)  # fmt: skip
    plain = reference_simulate(BRAKE, t, u, "brake")
    assert np.max(np.abs(r11["theta_l"] - plain["theta_l"])) > 1e-3  # the shift matters
    assert _max_diff(r11, r13) < 1e-8
    assert _same_events(r11, r13, 1e-8)
    kinds = _kinds(r11, "l")
    assert kinds.count("stick") >= 2 and kinds.count("slip+") >= 2
    # break-away exactly where the string torque reaches the shifted static level, which
    # depends on the (frozen) angle of the sticking disc; at rest inside the band
    ka, Ts = BRAKE["k_alpha"], BRAKE["Ts_l"]
    sol = r11["sol"]
    for tev, disc, kind in r11["events"]:
        if disc != "l":
            continue
        y = sol(tev)[:, 0]
        if kind.startswith("slip"):
            level = Ts + shift(tev, *y, 0.0)[1]
            assert abs(ka * (y[2] - y[0])) == pytest.approx(level, abs=1e-9)
        else:
            assert y[3] == pytest.approx(0.0, abs=1e-9)
    stuck = r11["mode_l"] == 0
    alpha = r11["theta_l"] - r11["theta_u"]
    band = Ts + BRAKE["Tc_l"] * 0.3 * np.sin(r11["theta_l"] + 0.7)
    assert np.all(r11["omega_l"][stuck] == 0.0)
    assert np.all(np.abs(ka * alpha[stuck]) <= band[stuck] + 1e-12)


# --------------------------------------------------------------------------------------
# 7. continuous input functions (u_func)
# --------------------------------------------------------------------------------------
def _smooth_steps(T: float):
    # levels joined by raised-cosine transitions, with reversals and a hold at 0 V
    knots = [(0.5, 0.8, 2.5), (2.5, 2.8, 0.0), (3.5, 3.6, -2.8), (5.5, 5.9, 1.0),
             (7.0, 7.2, -0.3)]  # fmt: skip
    levels = [0.0] + [k[2] for k in knots]

    def f(tau):
        tau = np.asarray(tau, dtype=float)
        v = np.full(tau.shape, levels[0])
        for (s, e, _), a, b in zip(knots, levels[:-1], levels[1:], strict=True):
            x = np.clip((tau - s) / (e - s), 0.0, 1.0)
            v = np.where(tau >= s, a + (b - a) * 0.5 * (1 - np.cos(np.pi * x)), v)
        return float(v) if v.ndim == 0 else v

    breaks = np.array([k[0] for k in knots] + [k[1] for k in knots])
    return f, breaks[breaks < T]


@pytest.mark.parametrize("config", ["upper", "brake"])
def test_continuous_input_equal_to_the_interpolant_matches_the_sample_path(config):
    # u_func = the linear interpolant of the samples (kinks at the sample times, listed as
    # u_breaks): the continuous path must reproduce the sample path, with delay, offset and
    # a dead zone whose edges the input crosses inside samples.
    params = dict(BRAKE, u_offset=0.03, t_delay=0.0123, u_deadzone=0.11, c_alpha=0.002)
    dt = 1e-2
    t = np.arange(0.0, 9.0 + 0.5 * dt, dt)
    f, _ = _smooth_steps(9.0)
    u = f(t) * 1.0
    lin = reference_simulate(params, t, u, config)
    cont = reference_simulate(params, t, None, config, u_func=lambda s: np.interp(s, t, u),
                              u_breaks=t)  # fmt: skip
    assert _max_diff(lin, cont) < 1e-8
    assert _same_events(lin, cont, 1e-8)
    assert len(lin["events"]) >= 4 and "stick" in _kinds(lin, "u")


@pytest.mark.slow
def test_continuous_input_is_converged_and_differs_from_the_interpolant():
    params = dict(BRAKE, t_delay=0.0077, u_deadzone=0.2)
    dt = 1e-2
    t = np.arange(0.0, 9.0 + 0.5 * dt, dt)
    f, breaks = _smooth_steps(9.0)
    kw = dict(u_func=f, u_breaks=breaks)
    r9 = reference_simulate(params, t, None, "brake", rtol=1e-9, atol=1e-11, **kw)
    r11 = reference_simulate(params, t, None, "brake", **kw)
    r13 = reference_simulate(params, t, None, "brake", rtol=1e-13, atol=1e-14, **kw)
    assert _max_diff(r11, r13) < 1e-9 and _same_events(r11, r13, 1e-9)
    assert _max_diff(r9, r13) < 1e-7
    # the output grid does not change the solution (only where it is reported)
    t2 = np.arange(0.0, 9.0 + 0.25 * dt, dt / 2)
    fine = reference_simulate(params, t2, None, "brake", **kw)
    for key in STATES:
        assert np.max(np.abs(fine[key][::2] - r11[key])) < 1e-9
    # and the continuous input is not the interpolant: at 100 Hz the paths differ
    lin = reference_simulate(params, t, f(t), "brake")
    assert _max_diff(lin, r11, ("theta_u",)) > 1e-6
    assert {"slip+", "slip-"} <= set(_kinds(r11, "l")) and "stick" in _kinds(r11, "u")


def test_continuous_input_hold_before_start_and_refusals():
    params = dict(BRAKE, t_delay=0.3)
    t = np.arange(0.0, 3.0 + 5e-3, 1e-2)
    seen = []

    def f(tau):
        seen.append(np.min(tau))
        return 0.8 + 0.5 * np.sin(2.0 * np.asarray(tau))

    reference_simulate(params, t, None, "upper", u_func=f)
    assert min(seen) >= 0.0  # never asked before t[0]: the value at t[0] is held
    # delayed by d: the same as the input shifted by d and held at its start
    r = reference_simulate(params, t, None, "upper", u_func=f)
    g = reference_simulate(dict(params, t_delay=0.0), t, None, "upper",
                           u_func=lambda s: f(np.maximum(np.asarray(s) - 0.3, 0.0)),
                           u_breaks=[0.3])  # fmt: skip
    assert _max_diff(r, g) < 1e-9
    with pytest.raises(ValueError, match="not both"):
        reference_simulate(params, t, f(t), "upper", u_func=f)

"""The reference's effect state (``state_rate``, ``state_z0``, ``state_reset``): a state
that does nothing changes nothing, the version without it is unchanged bit for bit, a
state with a known solution (a lagged voltage) is followed, a reset at stick is exact,
and refdata's "warming lower friction" (``warm_k``/``warm_tau``) matters."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys

import numpy as np
import pytest

sys.path.insert(0, os.path.dirname(__file__))
import refdata  # noqa: E402
from reference import reference_simulate  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
#: the last commit of tests/reference.py before the effect state was added
BEFORE = "382643a"

UPPER = refdata.SETS["upper"][0]
BRAKE = refdata.SETS["brake"][0]


def _input(T: float, dt: float = 1e-3):
    t = np.arange(0.0, T + 0.5 * dt, dt)
    return t, 0.8 + 0.6 * np.sin(2.0 * t) + 0.3 * np.sin(7.0 * t)


def _extra6(t, thu, wu, thl, wl, v):
    return 0.01 * np.sin(3.0 * t), -0.002 * np.cos(2.0 * t)


def _shift6(t, thu, wu, thl, wl, v):
    return 0.005 * t, -0.003 * t


def _old_reference():
    try:
        src = subprocess.run(
            ["git", "-C", HERE, "show", f"{BEFORE}:tests/reference.py"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("git history not available")
    spec = importlib.util.spec_from_loader("reference_before_state", loader=None)
    mod = importlib.util.module_from_spec(spec)
    exec(compile(src, "reference_before_state.py", "exec"), mod.__dict__)
    return mod.reference_simulate


@pytest.mark.parametrize("hooks", [False, True])
def test_without_a_state_the_results_are_bitwise_unchanged(hooks):
    old = _old_reference()
    t, u = _input(3.0)
    kw = dict(extra_torque=_extra6, friction_shift=_shift6) if hooks else {}
    a = reference_simulate(BRAKE, t, u, "brake", **kw)
    b = old(BRAKE, t, u, "brake", **kw)
    for key in ("theta_u", "omega_u", "theta_l", "omega_l", "mode_l", "mode_u"):
        assert np.array_equal(a[key], b[key]), key
    assert a["events"] == b["events"]
    assert a["z"] is None


@pytest.mark.parametrize("config", ["upper", "brake", "coupled"])
def test_a_state_that_does_nothing_changes_nothing(config):
    p = refdata.SETS[config][0]
    t, u = _input(2.0)

    def rate(t, thu, wu, thl, wl, v, z):
        return 0.0

    def extra7(t, thu, wu, thl, wl, v, z):
        return _extra6(t, thu, wu, thl, wl, v)

    def shift7(t, thu, wu, thl, wl, v, z):
        return _shift6(t, thu, wu, thl, wl, v)

    a = reference_simulate(p, t, u, config, extra_torque=_extra6, friction_shift=_shift6)
    b = reference_simulate(
        p,
        t,
        u,
        config,
        extra_torque=extra7,
        friction_shift=shift7,
        state_rate=rate,
        state_z0=0.0,
        state_reset="l",
    )
    assert np.max(np.abs(a["theta_u"] - b["theta_u"])) < 1e-12
    if config != "upper":
        assert np.max(np.abs(a["theta_l"] - b["theta_l"])) < 1e-12
    assert np.all(b["z"] == 0.0)


def test_a_state_that_does_nothing_with_a_continuous_input_and_prescribed_motion():
    t, u = _input(1.5)
    f = lambda tq: 0.8 + 0.6 * np.sin(2.0 * np.asarray(tq))  # noqa: E731
    rate = lambda *a: 0.0  # noqa: E731
    a = reference_simulate(BRAKE, t, None, "brake", u_func=f)
    b = reference_simulate(BRAKE, t, None, "brake", u_func=f, state_rate=rate)
    assert np.max(np.abs(a["theta_l"] - b["theta_l"])) < 1e-12
    thp = 0.5 * t**2
    a = reference_simulate(BRAKE, t, None, "prescribed", theta_u_prescribed=thp)
    b = reference_simulate(BRAKE, t, None, "prescribed", theta_u_prescribed=thp, state_rate=rate)
    assert np.max(np.abs(a["theta_l"] - b["theta_l"])) < 1e-12


@pytest.mark.parametrize("cont", [False, True])
def test_a_lagged_voltage_as_a_state_matches_the_lagged_input(cont):
    """z' = (v - z)/tau with the torque k_m (z - v) added: the motor sees k_m lag(v),
    which is what refdata.LaggedInput of the same (linear) input gives."""
    p = UPPER
    km, tau, T = p["k_m"], 0.05, 3.0
    t = np.arange(0.0, T + 0.5e-3, 1e-3)
    u = np.where(t < 1.0, 0.5, 0.5 + 2.0 * (t - 1.0))  # a ramp after a hold
    u = np.minimum(u, 3.0)

    def f_lin(tq):
        return np.interp(tq, t, u)

    f_lin.breaks = np.array([1.0, 2.25])
    lagged = refdata.LaggedInput(f_lin, tau, T + 1.0)
    ref = reference_simulate(p, t, None, "upper", u_func=lagged, u_breaks=f_lin.breaks)

    def rate(t_, thu, wu, thl, wl, v, z):
        return (v - z) / tau

    def extra(t_, thu, wu, thl, wl, v, z):
        return km * (z - v), 0.0

    if cont:
        st = reference_simulate(
            p,
            t,
            None,
            "upper",
            u_func=f_lin,
            u_breaks=f_lin.breaks,
            state_rate=rate,
            extra_torque=extra,
            state_z0=u[0],
        )
    else:
        st = reference_simulate(
            p, t, u, "upper", state_rate=rate, extra_torque=extra, state_z0=u[0]
        )
    assert np.max(np.abs(st["theta_u"] - ref["theta_u"])) < 1e-8
    assert np.max(np.abs(st["z"] - lagged(t))) < 1e-8
    assert np.max(np.abs(st["theta_u"])) > 1.0  # it moved


def test_a_reset_at_stick_is_exact():
    t = np.arange(0.0, 6.0 + 0.5e-3, 1e-3)
    u = np.full(t.size, 0.8)  # stick-slip: the lower disc stops again and again
    p = refdata.SETS["brake"][1]

    def rate(t_, thu, wu, thl, wl, v, z):
        return abs(wl)

    def shift(t_, thu, wu, thl, wl, v, z):
        return 0.0, -0.02 * z / (1.0 + z)

    res = reference_simulate(
        p, t, u, "brake", state_rate=rate, friction_shift=shift, state_reset="l"
    )
    sticks = [e[0] for e in res["events"] if e[1] == "l" and e[2] == "stick"]
    assert len(sticks) >= 2
    z, ml = res["z"], res["mode_l"]
    checked = 0
    for te in sticks:
        k = int(np.searchsorted(t, te, side="right"))
        while k < t.size and ml[k] == 0:
            assert z[k] == 0.0, (te, t[k], z[k])
            k += 1
            checked += 1
    assert checked > 10
    assert np.max(z) > 0.1
    never = reference_simulate(p, t, u, "brake", state_rate=rate, friction_shift=shift)
    assert np.max(np.abs(never["theta_l"] - res["theta_l"])) > 1e-3


def test_warming_lower_friction_through_make_experiment():
    pytest.importorskip("rotorbayes")
    BRAKE = refdata.SETS["brake"][1]  # stick-slip
    kw = dict(duration=4.0, signal="multisine", seed=0, quantize_angles=False, cache=False)
    plain = refdata.make_experiment("brake", BRAKE, **kw)
    warm = refdata.make_experiment("brake", dict(BRAKE, warm_k=0.02, warm_tau=1.0), **kw)
    both = refdata.make_experiment(
        "brake", dict(BRAKE, warm_k=0.02, warm_tau=1.0, drift_Tc_l=0.002), **kw
    )
    d = np.max(np.abs(np.asarray(warm.theta_l) - np.asarray(plain.theta_l)))
    assert d > 1e-2, d
    assert np.max(np.abs(np.asarray(both.theta_l) - np.asarray(warm.theta_l))) > 1e-4

"""The reference's LuGre lower disc (``lower_law="lugre"``), checked on the reference alone:
steady sliding puts the bristles at z = sgn(w) g(w)/sigma0; a slowly ramped string
torque below break-away makes the disc creep like a spring with a hysteresis loop (the
switch model keeps it still); stiff bristles approach the switch model; two tolerances
agree; misuse is refused; without the option the reference is unchanged bit for bit.

Solver choice (measured on the shared 2-core machine, one process, 30 s coupled run at
1 kHz, the input ``_u``, sigma1_l 0.6, rtol 1e-10 / atol 1e-12): LSODA 1.1 s (sigma0_l
100; 82 lower reversals) and 2.4 s (1000; 252 reversals), Radau 9.2 s and 17.8 s; with
another job on the machine 2.8 / 3.9 s and 25 / 35 s.  BDF took ~5x and DOP853 ~12x
LSODA's time on a 5 s run at sigma0_l 300 (DOP853 is held to steps of the bristles' time
constant while sliding).  LSODA against Radau: 1.9e-10 / 6.8e-10 rad in theta_l; LSODA
at rtol 1e-10 against 1e-8: 2.9e-8 / 2.5e-8 rad (and no faster: the cost is the
Python right-hand side and the restarts).  LSODA is the default: it steps with Adams
while the disc rests or turns slowly and switches to BDF where the bristles are stiff,
and with a Python right-hand side its steps are the cheapest.
"""

from __future__ import annotations

import importlib.util
import math
import os
import subprocess
import sys
import time
from functools import cache

import numpy as np
import pytest

sys.path.insert(0, os.path.dirname(__file__))
import refdata  # noqa: E402
from reference import reference_simulate  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
#: the last commit of tests/reference.py before the LuGre lower disc was added
BEFORE = "ea7d230"

#: unlike the thesis tables; the upper disc is refdata's coupled set 0
UPPER = dict(k_m=2.7, J_u=0.4765, Tc_u=0.61, dTc_u=0.035, b_u=1.4, db_u=0.06)
LOWER = dict(
    J_l=0.03,
    k_alpha=0.11,
    Tc_l=0.035,
    dTc_l=0.004,
    b_l=0.006,
    db_l=0.0015,
    Ts_l=0.12,
    ws_l=0.8,
    delta_l=1.7,
)
BRISTLE = dict(sigma0_l=300.0, sigma1_l=0.6)
LUGRE = {**UPPER, **LOWER, **BRISTLE}
SWITCH = {**UPPER, **LOWER}

DURATION = 12.0
DT = 1e-3


def _u(tt):
    """A few-volt smooth input: the upper disc sticks and slips, the lower disc slides
    both ways (|w_l| up to ~2 rad/s) and reverses many times."""
    tt = np.asarray(tt, dtype=float)
    v = 0.6 * np.sin(0.6 * tt) + 0.2 * np.sin(2.3 * tt + 1.0)
    return float(v) if v.ndim == 0 else v


def _grid(T: float, dt: float = DT) -> np.ndarray:
    return np.arange(int(round(T / dt)) + 1) * dt


def _g(w, p=LUGRE):
    """g(w) of the law, sgn(0) = 0."""
    s = np.sign(w)
    return (
        p["Tc_l"]
        + s * p["dTc_l"]
        + (p["Ts_l"] - p["Tc_l"]) * np.exp(-((np.abs(w) / p["ws_l"]) ** p["delta_l"]))
    )


@cache
def _coupled(sigma0: float | None, sigma1: float | None, rtol: float = 1e-11, atol: float = 1e-12):
    t = _grid(DURATION)
    t0 = time.perf_counter()
    if sigma0 is None:
        res = reference_simulate(SWITCH, t, None, "coupled", u_func=_u, rtol=rtol, atol=atol)
    else:
        res = reference_simulate(
            {**SWITCH, "sigma0_l": sigma0, "sigma1_l": sigma1},
            t,
            None,
            "coupled",
            u_func=_u,
            rtol=rtol,
            atol=atol,
            lower_law="lugre",
        )
    res["seconds"] = time.perf_counter() - t0
    return res


# ----------------------------------------------------------------------------------------
# 1. steady sliding
# ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("v", [1.5, -1.5])
def test_steady_sliding_bristles_at_g_over_sigma0(v):
    """theta_u = v t: after the transients the disc slides at w_l = v, the bristles sit
    at z = sgn(w) g(w)/sigma0 and the string torque equals the slip friction
    g(w) + (b_l + sgn(w) db_l) w (of the switch model: LuGre's steady state)."""
    dt, T = 0.01, 10.0
    t = _grid(T, dt)
    p = {**LUGRE, "c_alpha": 0.12}  # string damping ~critical: transients gone early
    res = reference_simulate(p, t, None, "prescribed", theta_u_prescribed=v * t, lower_law="lugre")
    late = t >= 8.0
    w, z = res["omega_l"][late], res["z_bristle"][late]
    assert np.max(np.abs(w - v)) < 1e-4  # measured: 1e-6 and 2e-6
    g = _g(w)
    zs = np.sign(w) * g / p["sigma0_l"]
    # measured: 4e-10 and 1e-10 (relative)
    assert np.max(np.abs(z - zs)) / np.max(np.abs(zs)) < 1e-7
    s = np.sign(w)
    te = -(p["k_alpha"] * (res["theta_l"][late] - res["theta_u"][late]) + p["c_alpha"] * (w - v))
    slip = s * g + (p["b_l"] + s * p["db_l"]) * w
    # measured: 8e-8 N m (J_l w' is what is left of the transient)
    assert np.max(np.abs(te - slip)) < 1e-6
    # and the modes: one direction, no rest, after the break-away
    assert np.all(res["mode_l"][late] == np.sign(v))


# ----------------------------------------------------------------------------------------
# 2. pre-sliding
# ----------------------------------------------------------------------------------------
def test_presliding_spring_with_hysteresis_where_the_switch_model_sticks():
    """A string torque ramped slowly to T_max = Ts_l/2 and back: the disc creeps by
    about T/sigma0.  Quasi-statically (T = sigma0 z, w tiny so g = Ts_l + s dTc_l):
    loading dz/dtheta = 1 - sigma0 z/g+ gives theta = -(g+/sigma0) ln(1 - T/g+);
    unloading dz/dtheta = 1 + sigma0 z/g- gives back only
    (g-/sigma0) ln((g- + T_max)/(g- + T)), so a displacement remains at T = 0
    (hysteresis).  The switch-model reference keeps the disc exactly still."""
    dt, T = 0.01, 10.0
    t = _grid(T, dt)
    p = LUGRE
    tmax = 0.5 * p["Ts_l"]
    thu = (tmax / p["k_alpha"]) * 0.5 * (1.0 - np.cos(2.0 * np.pi * t / T))
    res = reference_simulate(p, t, None, "prescribed", theta_u_prescribed=thu, lower_law="lugre")
    thl = res["theta_l"]
    torque = -p["k_alpha"] * (thl - thu)  # the string torque on the lower disc
    s0 = p["sigma0_l"]
    gp, gm = p["Ts_l"] + p["dTc_l"], p["Ts_l"] - p["dTc_l"]
    k = int(np.argmax(torque))
    tpk = torque[k]
    assert abs(tpk - tmax) < 1e-3 * tmax
    up = -(gp / s0) * math.log(1.0 - tpk / gp)
    assert tpk / s0 < thl.max()  # a softening spring of initial stiffness sigma0
    # measured: 5e-5 relative (sigma1 z', b w and J w' are the dynamic corrections)
    assert abs(thl[k] - up) < 1e-3 * up
    end = up - (gm / s0) * math.log((gm + tpk) / (gm + torque[-1]))
    # measured: 2e-5 relative
    assert abs(thl[-1] - end) < 1e-3 * up
    assert thl[-1] > 0.3 * up  # a real loop, not a reversible spring
    # loading and unloading branches differ at the same torque (the loop)
    th_up = np.interp(0.5 * tmax, torque[: k + 1], thl[: k + 1])
    th_dn = np.interp(0.5 * tmax, torque[k:][::-1], thl[k:][::-1])
    assert th_dn - th_up > 0.2 * up  # measured 0.32
    # one reversal, at the peak (t = 5 s)
    assert [e[2] for e in res["events"]] == ["slip+", "slip-"]
    # z is the spring's deflection: sigma0 z carries the torque
    assert np.max(np.abs(s0 * res["z_bristle"] - torque)) < 0.01 * tmax  # measured 6e-4
    sw = reference_simulate(SWITCH, t, None, "prescribed", theta_u_prescribed=thu)
    assert np.all(sw["theta_l"] == 0.0) and np.all(sw["mode_l"] == 0)


# ----------------------------------------------------------------------------------------
# 3. stiff bristles approach the switch model
# ----------------------------------------------------------------------------------------
#: measured max |lugre - switch| on the 12 s run (the switch model: lower disc sticks 64 %
#: of the samples, upper 19 %), critically damped bristles:
#:   sigma0_l 1e3: theta_l 3.4e-2, theta_u 2.1e-3 rad
#:   sigma0_l 1e4: theta_l 1.16e-2, theta_u 6.8e-4 rad
#:   sigma0_l 1e5: theta_l 3.7e-3, theta_u 2.1e-4 rad
#: i.e. about sigma0_l**-0.5 (x3.1 per decade), the largest difference at t = 9.05 s
#: (after a stick phase: the break-away time shifts); pre-sliding alone (T/sigma0,
#: ~1e-5 rad) is far smaller.
STIFF_TOL_L = 2e-2
STIFF_TOL_U = 1.5e-3


def test_stiff_bristles_approach_the_switch_model():
    """sigma0_l 1e4, sigma1_l = 2 sqrt(sigma0_l J_l) (critically damped bristles) on the
    stick-slip coupled run is close to the switch model, and closer than sigma0_l 1e3."""
    sw = _coupled(None, None)
    diffs = {}
    for s0 in (1e3, 1e4):
        lg = _coupled(s0, 2.0 * math.sqrt(s0 * LOWER["J_l"]))
        diffs[s0] = (
            np.max(np.abs(lg["theta_l"] - sw["theta_l"])),
            np.max(np.abs(lg["theta_u"] - sw["theta_u"])),
        )
    print("max |lugre - switch| (theta_l, theta_u) [rad]:", diffs)
    assert diffs[1e4][0] < STIFF_TOL_L
    assert diffs[1e4][1] < STIFF_TOL_U
    assert diffs[1e4][0] < 0.5 * diffs[1e3][0]  # measured ratio 0.34
    assert np.mean(sw["mode_l"] == 0) > 0.3  # the switch run does stick


# ----------------------------------------------------------------------------------------
# 4. self-consistency
# ----------------------------------------------------------------------------------------
def test_two_tolerances_agree_on_a_stick_slip_run_with_reversals():
    fine = _coupled(300.0, 0.6)
    coarse = _coupled(300.0, 0.6, 1e-9, 1e-11)
    # the case is the intended one: the upper disc sticks and slips, the lower slides
    # both ways and reverses many times
    assert 0.05 < np.mean(fine["mode_u"] == 0) < 0.6
    assert fine["omega_l"].min() < -1.0 and fine["omega_l"].max() > 1.0
    rev = [e for e in fine["events"] if e[1] == "l"]
    assert len(rev) >= 20  # measured 51
    d = {
        k: float(np.max(np.abs(fine[k] - coarse[k])))
        for k in ("theta_u", "theta_l", "omega_l", "z_bristle")
    }
    print("rtol 1e-11 vs 1e-9:", d, "seconds", fine["seconds"], coarse["seconds"])
    # measured: theta_u 2.7e-10, theta_l 8.6e-10, omega_l 2.8e-9, z 2.3e-11; 0.7 s each
    assert d["theta_u"] < 1e-8 and d["theta_l"] < 1e-8
    assert d["z_bristle"] < 2e-10


def test_a_second_stiff_method_agrees():
    """Radau (implicit Runge-Kutta, a method unlike LSODA's multistep ones) on the same run."""
    t = _grid(6.0)
    a = reference_simulate(LUGRE, t, None, "coupled", u_func=_u, lower_law="lugre")
    b = reference_simulate(
        LUGRE, t, None, "coupled", u_func=_u, lower_law="lugre", lugre_method="Radau"
    )
    d = {k: float(np.max(np.abs(a[k] - b[k]))) for k in ("theta_u", "theta_l", "z_bristle")}
    print("LSODA vs Radau:", d)
    # measured: theta_u 8e-13, theta_l 8.5e-12, z 1.9e-12 (Radau 3 s of the 4 s)
    assert d["theta_u"] < 1e-9 and d["theta_l"] < 1e-9 and d["z_bristle"] < 1e-10


# ----------------------------------------------------------------------------------------
# misuse, bitwise unchanged, refdata
# ----------------------------------------------------------------------------------------
def test_misuse_is_refused():
    t = _grid(0.1)
    u = np.zeros_like(t)
    with pytest.raises(ValueError, match="config 'upper'"):
        reference_simulate(UPPER, t, u, "upper", lower_law="lugre")
    with pytest.raises(ValueError, match="state_rate"):
        reference_simulate(LUGRE, t, u, "coupled", lower_law="lugre", state_rate=lambda *a: 0.0)
    with pytest.raises(KeyError, match="sigma1_l"):
        reference_simulate({**SWITCH, "sigma0_l": 300.0}, t, u, "coupled", lower_law="lugre")
    with pytest.raises(ValueError, match="sigma0_l must be positive"):
        reference_simulate({**LUGRE, "sigma0_l": 0.0}, t, u, "coupled", lower_law="lugre")
    with pytest.raises(ValueError, match="lower_law"):
        reference_simulate(LUGRE, t, u, "coupled", lower_law="LuGre")


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
    spec = importlib.util.spec_from_loader("reference_before_lugre", loader=None)
    mod = importlib.util.module_from_spec(spec)
    exec(compile(src, "reference_before_lugre.py", "exec"), mod.__dict__)
    return mod.reference_simulate


def test_without_lugre_the_results_are_bitwise_unchanged():
    old = _old_reference()
    t = _grid(3.0)
    u = _u(t) + 0.3  # samples: the restart-at-every-sample path
    for kw in ({}, {"lower_law": "switch"}):
        a = reference_simulate(LUGRE, t, u, "coupled", **kw)  # sigma*_l simply ignored
        b = old(LUGRE, t, u, "coupled")
        for key in ("theta_u", "omega_u", "theta_l", "omega_l", "mode_u", "mode_l"):
            assert np.array_equal(a[key], b[key]), key
        assert a["events"] == b["events"] and a["n_solve_ivp"] == b["n_solve_ivp"]
        assert a["z_bristle"] is None


def test_lugre_on_the_sample_path():
    """The sample path (restart at every sample) runs, and the bristles stay inside
    their steady-state envelope max g / sigma0."""
    t = _grid(2.0)
    u = _u(t)
    res = reference_simulate(LUGRE, t, u, "coupled", lower_law="lugre")
    assert np.all(np.isfinite(res["z_bristle"]))
    assert np.max(np.abs(res["z_bristle"])) <= (LUGRE["Ts_l"] + LUGRE["dTc_l"]) / 300.0 * 1.001


def test_refdata_lugre_case():
    c = refdata.CASES["lugre"]
    run = refdata.simulate_reference(c["config"], c["params"], cache=False, **c["make"])
    wl = np.gradient(run.theta_l, run.t)
    assert wl.min() < -1.0 and wl.max() > 1.0  # slides both ways
    assert np.mean(np.abs(wl) < 0.01) > 0.1  # and rests between levels
    # the same run without bristles differs by more than the lower encoder's resolution
    p = {k: v for k, v in c["params"].items() if not k.startswith("sigma")}
    sw = refdata.simulate_reference(c["config"], p, cache=False, **c["make"])
    assert np.max(np.abs(sw.theta_l - run.theta_l)) > 2 * np.pi / refdata.LOWER_COUNTS

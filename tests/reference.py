"""Independent, slow but accurate reference integrator for the drill-string rig switch model.

This module is used only by the test suite.  It is deliberately written from the model
equations alone (it does not import anything from ``rotorbayes``) so that comparisons
between the production integrator and this reference are meaningful.

Method
------
Event-driven integration with exact mode switching.  Every disc is either in STICK
(omega held exactly at 0) or in SLIP with a fixed direction s = +1 / -1.  For every mode
combination the smooth ODE is integrated with ``scipy.integrate.solve_ivp`` (DOP853) and
terminal events:

* slipping disc:  s * omega crossing 0 (downwards),
* sticking disc:  external torque T_e leaving the static band
  ``[-(Ts + dT - dTc), Ts + dT + dTc]`` (upper edge upwards, lower edge downwards).

T_e includes the optional user torque ``extra_torque`` and dT is the optional user
``friction_shift`` (0 without it); both are evaluated inside the event functions with the
current time and state, so a band that moves during stick is handled exactly.

At every event the modes are updated (stick / pass-through / break-away) and the
integration restarts from the event time.

Kinks of the input: the linearly interpolated voltage has a slope jump at every (delayed)
sample time, the dead zone adds slope jumps where ``|v| = u_deadzone`` and the prescribed
upper angle (config "prescribed") has velocity jumps at every sample time.  The
integration is therefore restarted at *every* such breakpoint (and at every output sample
time), so that each ``solve_ivp`` call only ever sees an analytic right-hand side.  Within
a segment the effective voltage is an exact linear function of time.

Continuous input (``u_func``): instead of samples, the voltage may be given as a function
of time evaluated exactly wherever the solver needs it (an amplifier that follows a smooth
command, not a line between samples).  The delay, offset and dead zone still apply:
``v(t) = deadzone(u_func(max(t - t_delay, t[0])) + u_offset)``.  Breakpoints are then the
sample times, ``t[0] + t_delay`` (end of the held start), the caller's ``u_breaks``
(times where ``u_func`` is not smooth, shifted by the delay) and the dead-zone crossings
(located by root finding); within a segment the right-hand side and the stick-band event
functions evaluate ``u_func`` itself.

Inside a slip mode the friction law is extended smoothly across omega = 0 (the Stribeck
power is continued as an odd function, ``x**delta -> sign(x)*|x|**delta``) so that the
DOP853 steps that overshoot the zero crossing before the event is located see a smooth
right-hand side; the extension is only ever evaluated within a single step of the event.

LuGre lower disc (``lower_law="lugre"``)
----------------------------------------
The lower disc then has no stick mode.  With its bristle deflection z as a fifth state
(z(0) = 0) it obeys, always,

    J_l w' = T_e - F,            F  = sigma0 z + sigma1 z' + (b_l + sgn(w) db_l) w
    z'     = w - sigma0 |w| z / g(w)
    g(w)   = Tc_l + sgn(w) dTc_l + (Ts_l - Tc_l) exp(-(|w|/ws_l)^delta_l),  sgn(0) = 0

(sigma0 = ``sigma0_l``, sigma1 = ``sigma1_l``; Ts_l = Tc_l without Stribeck; a
``friction_shift`` dT_l adds to g; T_e is the lower disc's external torque as in the
switch model, string plus ``extra_torque``).  In steady sliding z = sgn(w) g(w) / sigma0
and F is the switch model's slip friction; at small torques the disc creeps like a
spring of stiffness sigma0 (pre-sliding).  The upper disc keeps its switch model.

The right-hand side has kinks at w = 0 (|w| in z' and sgn(w) in the viscous and Coulomb
terms), so it is integrated in pieces of fixed direction s = sgn(w): on a piece |w| is
replaced by s w (and the Stribeck power continued as above), a terminal event on s w
crossing 0 ends the piece, w is set to exactly 0 and the next direction is the sign of
the acceleration there, (T_e - sigma0 z)/J_l (z' = 0 at w = 0).  If that is 0 to within
rounding (``_LUGRE_REST``; at rest with nothing pushing, e.g. at t[0], or a disc
settling on its bristles, where choosing a direction from a net torque of 1e-14 N m made
the next piece reverse at once, again and again) the piece has s = 0 (the law's value
at w = 0, exact to O(|w|)) and ends when |w| reaches ``_LUGRE_EPS``.  No mode changes
at these events: they only keep every solver call on an analytic right-hand side.

The bristle dynamics are stiff while sliding (time constant g / (sigma0 |w|), 1e-5 s for
sigma0 = 1000 at 5 rad/s), so every solver call then uses ``lugre_method`` (default
LSODA, see the measurements in ``tests/test_reference_lugre.py``) instead of DOP853.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from scipy.integrate import solve_ivp

__all__ = ["reference_simulate"]

_TINY = 1e-300  # value returned by event functions at the start of a mode (see _events)
_MAX_STALLED_EVENTS = 200
_LUGRE_EPS = 1e-12  # [rad/s] speed at which a LuGre lower disc at rest is said to move
_LUGRE_REST = 1e-9  # net torque at rest, relative to Ts_l + |dTc_l|, taken as zero

_CONFIGS = ("upper", "coupled", "brake", "prescribed")


# --------------------------------------------------------------------------------------
# parameters
# --------------------------------------------------------------------------------------
def _get(params: dict, key: str, default=None, required: bool = False) -> float:
    if key in params and params[key] is not None:
        return float(params[key])
    if required:
        raise KeyError(f"reference_simulate: parameter {key!r} is required")
    return float(default)


def _resolve_params(params: dict, config: str) -> dict:
    has_upper = config in ("upper", "coupled", "brake")
    has_lower = config in ("coupled", "brake", "prescribed")
    p: dict[str, float] = {}
    # effects that default to zero
    for key in (
        "c_alpha",
        "u_offset",
        "t_delay",
        "u_deadzone",
        "alpha0",
        "dTc_u",
        "db_u",
        "dTc_l",
        "db_l",
    ):
        p[key] = _get(params, key, 0.0)
    if has_upper:
        for key in ("k_m", "J_u", "Tc_u", "b_u"):
            p[key] = _get(params, key, required=True)
        # Stribeck friction of the upper disc: its static level Tc_u + dTs_u
        p["dTs_u"] = _get(params, "dTs_u", 0.0)
        p["ws_u"] = _get(params, "ws_u", 1.0)
        p["delta_u"] = _get(params, "delta_u", 2.0)
        if p["ws_u"] <= 0.0 or p["dTs_u"] < 0.0:
            raise ValueError("ws_u must be positive and dTs_u non-negative")
    if has_lower:
        for key in ("J_l", "k_alpha", "Tc_l", "b_l"):
            p[key] = _get(params, key, required=True)
        p["Ts_l"] = _get(params, "Ts_l", p["Tc_l"])
        p["ws_l"] = _get(params, "ws_l", 1.0)
        p["delta_l"] = _get(params, "delta_l", 1.0)
        if p["ws_l"] <= 0.0:
            raise ValueError("ws_l must be positive")
    return p


# --------------------------------------------------------------------------------------
# breakpoints and piecewise-linear inputs
# --------------------------------------------------------------------------------------
def _unique_with_tol(x: np.ndarray, tol: float) -> np.ndarray:
    if x.size == 0:
        return x
    x = np.sort(x)
    keep = np.ones(x.size, dtype=bool)
    keep[1:] = np.diff(x) > tol
    return x[keep]


def _breakpoints(
    t: np.ndarray, u: np.ndarray | None, p: dict, config: str, tol: float
) -> np.ndarray:
    """All sample times plus every time at which the input (or the prescribed motion)
    has a kink.  Extra points closer than ``tol`` to a sample time are dropped."""
    t0, t1 = t[0], t[-1]
    extra = []
    if config != "prescribed":
        d = p["t_delay"]
        if d != 0.0:
            extra.append(t + d)
        dz = p["u_deadzone"]
        if dz > 0.0 and t.size > 1:
            tk = t[:-1] + d
            tk1 = t[1:] + d
            v0 = u[:-1] + p["u_offset"]
            v1 = u[1:] + p["u_offset"]
            dv = v1 - v0
            with np.errstate(divide="ignore", invalid="ignore"):
                for level in (dz, -dz):
                    frac = (level - v0) / dv
                    ok = (dv != 0.0) & (frac > 0.0) & (frac < 1.0)
                    extra.append(tk[ok] + frac[ok] * (tk1[ok] - tk[ok]))
    if not extra:
        return t.copy()
    e = np.concatenate(extra)
    e = e[(e > t0 + tol) & (e < t1 - tol)]
    if e.size:
        # drop points that (almost) coincide with a sample time
        idx = np.searchsorted(t, e)
        lo = np.abs(e - t[np.clip(idx - 1, 0, t.size - 1)])
        hi = np.abs(t[np.clip(idx, 0, t.size - 1)] - e)
        e = e[np.minimum(lo, hi) > tol]
        e = _unique_with_tol(e, tol)
    return np.union1d(t, e)


def _piece_coeffs(ts: np.ndarray, vs: np.ndarray, tau: np.ndarray):
    """For the linear interpolant of (ts, vs) (constant extrapolation), return for each
    query time ``tau`` the value at ``tau`` and the slope of the piece containing it."""
    n = ts.size
    if n == 1:
        return np.full(tau.shape, vs[0]), np.zeros(tau.shape)
    k = np.clip(np.searchsorted(ts, tau, side="right") - 1, 0, n - 2)
    slope = (vs[k + 1] - vs[k]) / (ts[k + 1] - ts[k])
    outside = (tau < ts[0]) | (tau > ts[-1])
    slope = np.where(outside, 0.0, slope)
    val = np.where(
        tau < ts[0], vs[0], np.where(tau > ts[-1], vs[-1], vs[k] + slope * (tau - ts[k]))
    )
    return val, slope


def _input_segments(bp: np.ndarray, t: np.ndarray, u: np.ndarray, p: dict):
    """Coefficients of the effective voltage on each segment [bp[i], bp[i+1]]:
    u_eff(t) = ua[i] + ub[i] * (t - bp[i]) exactly (input kinks are breakpoints)."""
    a = bp[:-1]
    mid = 0.5 * (bp[:-1] + bp[1:])
    d = p["t_delay"]
    vmid, slope = _piece_coeffs(t, u, mid - d)
    vmid = vmid + p["u_offset"]
    va = vmid + slope * (a - mid)  # value of the same linear piece at the segment start
    dz = p["u_deadzone"]
    if dz > 0.0:
        inside = np.abs(vmid) <= dz
        ua = np.where(inside, 0.0, va - dz * np.sign(vmid))
        ub = np.where(inside, 0.0, slope)
    else:
        ua, ub = va, slope
    return ua, ub


def _held(u_func: Callable, t0: float) -> Callable:
    """``u_func`` with its value at ``t0`` held before ``t0`` (scalar or array times)."""

    def f(tau):
        if np.ndim(tau) == 0:
            return float(u_func(tau if tau > t0 else t0))
        return np.asarray(u_func(np.maximum(np.asarray(tau, dtype=float), t0)), dtype=float)

    return f


def _snap(e: np.ndarray, t: np.ndarray, tol: float) -> np.ndarray:
    """Times ``e`` within ``tol`` of a sample time replaced by that sample time."""
    if e.size == 0:
        return e
    idx = np.clip(np.searchsorted(t, e), 1, t.size - 1) if t.size > 1 else np.zeros(e.size, int)
    lo, hi = t[idx - 1] if t.size > 1 else t[idx], t[idx]
    e = np.where(np.abs(e - lo) <= tol, lo, e)
    return np.where(np.abs(hi - e) <= tol, hi, e)


def _breakpoints_func(
    t: np.ndarray, u_func: Callable, u_breaks, p: dict, tol: float, n_probe: int = 8
) -> np.ndarray:
    """Breakpoints of a continuous input: the first and last sample time, the end of the
    held start (``t[0] + t_delay``), the delayed non-smooth times of ``u_func`` and the
    times where the dead zone's edges are crossed (sign changes on a probe grid of
    ``n_probe`` points per sample interval, then brentq).  Points within ``tol`` of a
    sample time become that sample time.  Other sample times are *not* breakpoints: the
    input is smooth there, and the solution is read from the solver's dense output."""
    from scipy.optimize import brentq

    t0, t1 = t[0], t[-1]
    d = p["t_delay"]
    extra = [np.array([t0 + d])] if d != 0.0 else []
    if u_breaks is not None:
        extra.append(np.asarray(u_breaks, dtype=float).ravel() + d)
    dz = p["u_deadzone"]
    if dz > 0.0 and t.size > 1:
        uf = _held(u_func, t0)
        off = p["u_offset"]
        grid = np.union1d(t, np.concatenate(extra)) if extra else t
        grid = grid[(grid >= t0) & (grid <= t1)]
        frac = np.linspace(0.0, 1.0, n_probe + 1)
        tp = np.union1d((grid[:-1, None] + frac[None, :] * np.diff(grid)[:, None]).ravel(), grid)
        vp = uf(tp - d) + off
        roots = []
        for level in (dz, -dz):
            g = vp - level
            for k in np.flatnonzero(g[:-1] * g[1:] < 0.0):
                roots.append(
                    brentq(
                        lambda s, lv=level: uf(s - d) + off - lv,
                        tp[k],
                        tp[k + 1],
                        xtol=1e-15,
                        rtol=4 * np.finfo(float).eps,
                    )
                )
        extra.append(np.asarray(roots, dtype=float))
    e = np.concatenate(extra) if extra else np.zeros(0)
    e = _snap(e[(e > t0 - tol) & (e < t1 + tol)], t, tol)
    e = e[(e > t0) & (e < t1)]
    return np.union1d(np.array([t0, t1]) if t.size > 1 else t[:1], _unique_with_tol(e, tol))


def _input_functions(bp: np.ndarray, t: np.ndarray, u_func: Callable, p: dict) -> list:
    """The effective voltage on each segment [bp[i], bp[i+1]] as a function of time:
    ``u_func`` delayed (held before t[0]), offset, and on the segment's side of the dead
    zone (dead-zone crossings are breakpoints, so the side is the midpoint's)."""
    uf = _held(u_func, float(t[0]))
    d, off, dz = p["t_delay"], p["u_offset"], p["u_deadzone"]
    mid = 0.5 * (bp[:-1] + bp[1:])
    vmid = uf(mid - d) + off if mid.size else np.zeros(0)

    def plain(t_):
        return uf(t_ - d) + off

    out = []
    for vm in vmid:
        if dz > 0.0 and abs(vm) <= dz:
            out.append(_zero)
        elif dz > 0.0:
            shift = dz * (1.0 if vm > 0 else -1.0)
            out.append(lambda t_, s=shift: uf(t_ - d) + off - s)
        else:
            out.append(plain)
    return out


def _zero(t_: float) -> float:
    return 0.0


# --------------------------------------------------------------------------------------
# model pieces
# --------------------------------------------------------------------------------------
def _make_friction_lower(p: dict, shape: str):
    Tc, dTc, b, db = p["Tc_l"], p["dTc_l"], p["b_l"], p["db_l"]
    Ts, ws, delta = p["Ts_l"], p["ws_l"], p["delta_l"]
    dS = Ts - Tc
    exp = math.exp
    if shape == "exp":

        def S(x: float) -> float:
            pw = x**delta if x >= 0.0 else -((-x) ** delta)
            return exp(-pw)
    elif shape == "rational":

        def S(x: float) -> float:
            pw = x**delta if x >= 0.0 else -((-x) ** delta)
            return 1.0 / (1.0 + pw)
    else:
        raise ValueError("stribeck_shape must be 'exp' or 'rational'")

    def fric(w: float, s: int) -> float:
        # s * [Tc + s dTc + (b + s db)|w| + (Ts - Tc) S(|w|/ws)] with |w| -> s*w
        return s * Tc + dTc + (b + s * db) * w + s * dS * S(s * w / ws)

    return fric


def _make_friction_upper(p: dict, shape: str = "exp"):
    Tc, dTc, b, db = p["Tc_u"], p["dTc_u"], p["b_u"], p["db_u"]
    dS, ws, delta = p["dTs_u"], p["ws_u"], p["delta_u"]
    if dS == 0.0:

        def fric(w: float, s: int) -> float:
            return s * Tc + dTc + (b + s * db) * w

        return fric
    exp = math.exp

    def S(x: float) -> float:
        pw = x**delta if x >= 0.0 else -((-x) ** delta)
        return exp(-pw) if shape == "exp" else 1.0 / (1.0 + pw)

    def fric(w: float, s: int) -> float:
        # the upper disc's static friction above its Coulomb level: Tc_u + dTs_u at rest
        return s * Tc + dTc + (b + s * db) * w + s * dS * S(s * w / ws)

    return fric


def _sgn(x: float) -> int:
    return 1 if x > 0.0 else (-1 if x < 0.0 else 0)


# --------------------------------------------------------------------------------------
# main entry point
# --------------------------------------------------------------------------------------
def reference_simulate(
    params: dict,
    t: np.ndarray,
    u: np.ndarray | None,
    config: str = "brake",
    *,
    theta_u_prescribed: np.ndarray | None = None,
    stribeck_shape: str = "exp",
    rtol: float = 1e-11,
    atol: float = 1e-12,
    dense_output: bool = False,
    extra_torque: Callable | None = None,
    friction_shift: Callable | None = None,
    u_func: Callable | None = None,
    u_breaks: np.ndarray | None = None,
    state_rate: Callable | None = None,
    state_z0: float = 0.0,
    state_reset: str | None = None,
    lower_law: str = "switch",
    lugre_method: str = "LSODA",
) -> dict:
    """Reference (event-driven, exact switching) simulation of the rig.

    Parameters
    ----------
    params : dict of model parameters (SI units), see module docstring of the project.
    t : uniform (any strictly increasing grid works) sample times; the motion starts at
        rest with theta = 0 at ``t[0]``.
    u : voltage samples at ``t`` (linearly interpolated, held at ``u[0]`` before
        ``t[0]``).  Ignored (may be None) for ``config="prescribed"``.
    config : "upper", "coupled", "brake" or "prescribed".
    theta_u_prescribed : samples of theta_u at ``t`` (config "prescribed" only).
    stribeck_shape : "exp" or "rational".
    rtol, atol : tolerances passed to every ``solve_ivp(method="DOP853")`` call.
    extra_torque : optional ``f(t, theta_u, omega_u, theta_l, omega_l, v) -> (T_u, T_l)``,
        extra external torques [N m] on the upper and lower disc.  They add to each
        disc's external torque (k_m v + string torque, resp. -string torque), so they
        enter the stick test too: a sticking disc breaks loose when its external torque
        including T_u / T_l leaves the static band.
    friction_shift : optional ``g(t, theta_u, omega_u, theta_l, omega_l, v) -> (dT_u, dT_l)``,
        additive change [N m] of each disc's friction levels: added to the Coulomb level
        Tc and to the static level Ts alike (upper disc: Ts = Tc_u + dTs_u).  In slip (s = sign w)
        the friction magnitude is ``Tc + dT + s dTc + (b + s db)|w| + (Ts - Tc) S(|w|/ws)``
        (Stribeck part unchanged); the static band is ``[-(Ts + dT - dTc), Ts + dT + dTc]``,
        evaluated with the current time and state.
        Arguments of both callables: t [s]; theta/omega [rad, rad/s] of both discs (config
        "prescribed": theta_u, omega_u are the prescribed motion, omega_u the slope of its
        linear piece; config "upper": theta_l = omega_l = 0); v [V] the effective motor
        voltage at t after delay, offset and dead zone (0 in config "prescribed").  Both
        must be smooth in time and state (no kinks; kinks of v are breakpoints already)
        and keep the friction levels non-negative.  Without them (None) the results are
        bitwise those of the version without hooks.
    u_func : optional continuous input ``u_func(tau) -> V`` used instead of ``u`` (give
        ``u=None``): called with a float or a float array of times in ``[t[0], t[-1]]``
        (before ``t[0]`` the value at ``t[0]`` is held); it must be smooth between the
        times listed in ``u_breaks``.  Without it the samples ``u`` are interpolated
        linearly (the results are bitwise those of the version without this option).
    u_breaks : times [s] at which ``u_func`` is not smooth (e.g. the ends of a transition);
        they are delayed like the input and become breakpoints of the integration.
    state_rate : optional ``r(t, theta_u, omega_u, theta_l, omega_l, v, z) -> dz/dt``:
        an extra effect state z (a float) integrated by DOP853 together with the rig in
        every mode (also while a disc sticks).  When given, ``extra_torque`` and
        ``friction_shift`` are called with z as a 7th argument
        ``(t, theta_u, omega_u, theta_l, omega_l, v, z)`` (also inside the event
        functions, so the stick band moves with z).  Without it (None) the hooks keep
        their 6-argument form and the results are bitwise those of the version without
        this option.
    state_z0 : z at ``t[0]``.
    state_reset : 'u' or 'l': z is set to exactly 0 at every event at which that disc
        starts to stick (slip -> stick); None: never reset.
    lower_law : "switch" (default: the switch model above) or "lugre": the lower disc has
        no stick mode and obeys the LuGre law (module docstring, "LuGre lower disc")
        with the parameters ``sigma0_l``
        [N m/rad] and ``sigma1_l`` [N m s/rad] (both required).  Configs "coupled",
        "brake" and "prescribed" only; not together with ``state_rate``.  With
        "switch" the results are bitwise those of the version without this option.
    lugre_method : the ``solve_ivp`` method used for *every* call when
        ``lower_law="lugre"`` ("LSODA" by default; "Radau", "BDF" or "DOP853" also
        work, the explicit one slowly: the bristle state is stiff while sliding).
    dense_output : if True, the result also contains ``"sol"``, a callable mapping an
        array of times in [t[0], t[-1]] to a (4, n) array
        [theta_u, omega_u, theta_l, omega_l] (rows of absent discs are NaN).

    Returns
    -------
    dict with "theta_u", "omega_u", "theta_l", "omega_l" (arrays at ``t``; the lower
    entries are None for config "upper"), "events" (list of (time, disc, kind) with
    disc in {'u', 'l'} and kind in {'stick', 'slip+', 'slip-'}), "mode_u"/"mode_l"
    (int arrays at ``t``: 0 stick, +1/-1 slip direction, mode valid just after each
    sample time; None for absent discs), "z" (the state at ``t``, after a reset at a
    sample time; None without ``state_rate``) and "n_solve_ivp" (number of solver calls).
    With ``lower_law="lugre"`` also "z_bristle" (the bristle deflection z [rad] at ``t``;
    None otherwise); "mode_l" is then the direction of the lower disc's current smooth
    piece (+1/-1, 0 only while it is exactly at rest) and the lower disc's "events" are its
    reversals ('slip+' / 'slip-'; 'stick' when it comes exactly to rest).
    """
    if config not in _CONFIGS:
        raise ValueError(f"config must be one of {_CONFIGS}, got {config!r}")
    if stribeck_shape not in ("exp", "rational"):
        raise ValueError("stribeck_shape must be 'exp' or 'rational'")
    t = np.asarray(t, dtype=float).ravel()
    if t.size < 1 or (t.size > 1 and np.any(np.diff(t) <= 0.0)):
        raise ValueError("t must be non-empty and strictly increasing")
    p = _resolve_params(params, config)

    has_upper = config != "prescribed"  # upper disc is a dynamic state
    has_lower = config != "upper"

    if config == "prescribed":
        if theta_u_prescribed is None:
            raise ValueError("config 'prescribed' needs theta_u_prescribed")
        thp = np.asarray(theta_u_prescribed, dtype=float).ravel()
        if thp.shape != t.shape:
            raise ValueError("theta_u_prescribed must have the same shape as t")
        u_arr = None
    elif u_func is not None:
        if u is not None:
            raise ValueError("give the input as samples u or as u_func, not both")
        u_arr = None
        thp = None
    else:
        if u is None:
            raise ValueError("u is required for this config")
        u_arr = np.asarray(u, dtype=float).ravel()
        if u_arr.shape != t.shape:
            raise ValueError("u must have the same shape as t")
        thp = None
    if u_func is not None and config == "prescribed":
        raise ValueError("u_func has no meaning for config 'prescribed'")
    cont = u_func is not None
    has_z = state_rate is not None
    if state_reset not in (None, "u", "l"):
        raise ValueError("state_reset must be None, 'u' or 'l'")
    if lower_law not in ("switch", "lugre"):
        raise ValueError(f"lower_law must be 'switch' or 'lugre', got {lower_law!r}")
    lugre = lower_law == "lugre"
    if lugre:
        if config == "upper":
            raise ValueError("lower_law='lugre' needs a lower disc (config 'upper' has none)")
        if has_z:
            raise ValueError(
                "lower_law='lugre' cannot be combined with state_rate "
                "(the bristle deflection is the reference's only extra state)"
            )
        s0 = _get(params, "sigma0_l", required=True)
        s1 = _get(params, "sigma1_l", required=True)
        if not (s0 > 0.0 and s1 >= 0.0):
            raise ValueError("lugre: sigma0_l must be positive and sigma1_l non-negative")
        if not (p["Tc_l"] > abs(p["dTc_l"]) and p["Ts_l"] > abs(p["dTc_l"])):
            raise ValueError("lugre: Tc_l and Ts_l must exceed |dTc_l| (g(omega) > 0)")
    NY = 5 if (has_z or lugre) else 4

    dt_min = float(np.min(np.diff(t))) if t.size > 1 else 1.0
    tol_bp = 1e-9 * dt_min
    if cont:
        bp = _breakpoints_func(t, u_func, u_breaks, p, tol_bp)
    else:
        bp = _breakpoints(t, u_arr, p, config, tol_bp)
    is_sample = np.isin(bp, t)  # exact, because sample times are kept verbatim
    # Continuous input: sample times strictly inside a segment are read from the dense
    # output of the solver call that covers them.
    next_sample = 1
    # Steps no longer than a sample interval, as on the sample path (a slip mode's smooth
    # extension across omega = 0 is then only ever evaluated close to the event).
    step_cap = {"max_step": dt_min} if cont else {}
    nseg = bp.size - 1

    if config == "prescribed":
        mid = 0.5 * (bp[:-1] + bp[1:])
        thm, pslope = _piece_coeffs(t, thp, mid) if nseg else (np.zeros(0), np.zeros(0))
        pa = thm + pslope * (bp[:-1] - mid)
        pb = pslope
        ua = ub = np.zeros(nseg)
    elif cont:
        ua = ub = pa = pb = np.zeros(nseg)
        vfs = _input_functions(bp, t, u_func, p)
    else:
        ua, ub = _input_segments(bp, t, u_arr, p) if nseg else (np.zeros(0), np.zeros(0))
        pa = pb = np.zeros(nseg)

    # ---- constants ------------------------------------------------------------------
    km = p.get("k_m", 0.0)
    iJu = 1.0 / p["J_u"] if has_upper else 0.0
    iJl = 1.0 / p["J_l"] if has_lower else 0.0
    ka = p.get("k_alpha", 0.0) if has_lower else 0.0
    ca = p["c_alpha"] if has_lower else 0.0
    a0 = p["alpha0"] if has_lower else 0.0
    fr_u = _make_friction_upper(p, stribeck_shape) if has_upper else None
    fr_l = _make_friction_lower(p, stribeck_shape) if has_lower else None
    if has_upper:
        hi_u = p["Tc_u"] + p["dTs_u"] + p["dTc_u"]
        lo_u = -(p["Tc_u"] + p["dTs_u"] - p["dTc_u"])
    if has_lower:
        hi_l = p["Ts_l"] + p["dTc_l"]
        lo_l = -(p["Ts_l"] - p["dTc_l"])

    # ---- state & torques ----------------------------------------------------------------
    # y = [theta_u, omega_u, theta_l, omega_l]; for "prescribed" y[0:2] are unused (the
    # upper motion is pa + pb*(t - a)); for "upper" y[2:4] stay 0.
    seg = {"a": bp[0], "ua": 0.0, "ub": 0.0, "pa": 0.0, "pb": 0.0, "vf": None}

    def upper_kin(t_: float, y: list) -> tuple[float, float]:
        if config == "prescribed":
            return seg["pa"] + seg["pb"] * (t_ - seg["a"]), seg["pb"]
        return y[0], y[1]

    def string_torque(t_: float, y: list) -> float:
        if not has_lower or config == "upper":
            return 0.0
        thu, wu = upper_kin(t_, y)
        return ka * (y[2] - thu + a0) + ca * (y[3] - wu)

    def hook_args(t_: float, y: list) -> tuple:
        thu, wu = upper_kin(t_, y) if has_upper or config == "prescribed" else (0.0, 0.0)
        v = seg["vf"](t_) if cont else seg["ua"] + seg["ub"] * (t_ - seg["a"])
        thl, wl = (y[2], y[3]) if has_lower else (0.0, 0.0)
        if has_z:
            return t_, thu, wu, thl, wl, v, y[4]
        return t_, thu, wu, thl, wl, v

    def zdot(t_: float, y: list) -> float:
        return float(state_rate(*hook_args(t_, y)))

    def extra(t_: float, y: list) -> tuple[float, float]:
        if extra_torque is None:
            return 0.0, 0.0
        a_, b_ = extra_torque(*hook_args(t_, y))
        return float(a_), float(b_)

    def shift(t_: float, y: list) -> tuple[float, float]:
        if friction_shift is None:
            return 0.0, 0.0
        a_, b_ = friction_shift(*hook_args(t_, y))
        return float(a_), float(b_)

    def te_upper(t_: float, y: list) -> float:
        ue = seg["vf"](t_) if cont else seg["ua"] + seg["ub"] * (t_ - seg["a"])
        return km * ue + string_torque(t_, y) + extra(t_, y)[0]

    def te_lower(t_: float, y: list) -> float:
        return -string_torque(t_, y) + extra(t_, y)[1]

    if lugre:
        sig0, sig1 = s0, s1
        Tc_l, dTc_l, dS_l = p["Tc_l"], p["dTc_l"], p["Ts_l"] - p["Tc_l"]
        b_l, db_l, iws_l, dl_l = p["b_l"], p["db_l"], 1.0 / p["ws_l"], p["delta_l"]
        exp_ = math.exp

        def g_lugre(w: float, sl: int, dT: float) -> float:
            """g(omega) on a piece of direction sl: |omega| -> sl*omega, the Stribeck power
            continued as an odd function (smooth across 0, used only near an event)."""
            if dS_l == 0.0:
                return Tc_l + sl * dTc_l + dT
            x = sl * w * iws_l
            pw = x**dl_l if x >= 0.0 else -((-x) ** dl_l)
            return Tc_l + sl * dTc_l + dT + dS_l * exp_(-pw)

        def lugre_lower(t_: float, yl: list, sl: int, te: float) -> tuple[float, float]:
            """(d omega_l/dt, dz/dt) of the LuGre lower disc on a piece of direction sl,
            given its external torque te (string + extra)."""
            w, z = yl[3], yl[4]
            dT = shift(t_, yl)[1] if friction_shift is not None else 0.0
            zd = w - sig0 * (sl * w) * z / g_lugre(w, sl, dT)
            f = sig0 * z + sig1 * zd + (b_l + sl * db_l) * w
            return (te - f) * iJl, zd

        # below this net torque [N m] at omega_l == 0 the direction is left open (s = 0)
        lugre_thr = _LUGRE_REST * (p["Ts_l"] + abs(p["dTc_l"]))

        def lugre_direction(t_: float, yl: list) -> int:
            """Direction of the next smooth piece: sgn(omega_l), or at omega_l == 0 the
            sign of its acceleration there, (T_e - sigma0 z)/J_l (dz/dt = 0 at rest),
            and 0 if that net torque is within rounding of 0 (a disc settling on its
            bristles: its direction is then decided by the _LUGRE_EPS events)."""
            if yl[3] != 0.0:
                return _sgn(yl[3])
            net = te_lower(t_, yl) - sig0 * yl[4]
            return 0 if abs(net) <= lugre_thr else _sgn(net)

    def make_rhs_lugre(mu: int, sl: int) -> Callable:
        a = seg["a"]
        sua, sub = seg["ua"], seg["ub"]
        spa, spb = seg["pa"], seg["pb"]
        vf = seg["vf"]
        if config == "prescribed":

            def rhs(t_, yy):
                yl = yy.tolist()
                thu = spa + spb * (t_ - a)
                Tsr = ka * (yl[2] - thu + a0) + ca * (yl[3] - spb)
                te = -Tsr + (extra(t_, yl)[1] if extra_torque is not None else 0.0)
                dwl, zd = lugre_lower(t_, yl, sl, te)
                return [0.0, 0.0, yl[3], dwl, zd]
        else:

            def rhs(t_, yy):
                yl = yy.tolist()
                y0, y1, y2, y3 = yl[:4]
                Tsr = ka * (y2 - y0 + a0) + ca * (y3 - y1)
                exu, exl = extra(t_, yl)
                if mu != 0:
                    ue = vf(t_) if cont else sua + sub * (t_ - a)
                    dwu = (km * ue - fr_u(y1, mu) - mu * shift(t_, yl)[0] + Tsr + exu) * iJu
                else:
                    dwu = 0.0
                dwl, zd = lugre_lower(t_, yl, sl, -Tsr + exl)
                return [y1, dwu, y3, dwl, zd]

        return rhs

    def make_rhs(mu: int, ml: int) -> Callable:
        if lugre:
            return make_rhs_lugre(mu, ml)
        a = seg["a"]
        sua, sub = seg["ua"], seg["ub"]
        spa, spb = seg["pa"], seg["pb"]
        vf = seg["vf"]
        if config == "upper":

            def rhs(t_, yy):
                yv = yy.tolist()
                y0, y1 = yv[0], yv[1]
                yl = [y0, y1, 0.0, 0.0] + yv[4:]
                if mu == 0:
                    return [0.0, 0.0, 0.0, 0.0] + ([zdot(t_, yl)] if has_z else [])
                ue = vf(t_) if cont else sua + sub * (t_ - a)
                f = fr_u(y1, mu) + mu * shift(t_, yl)[0]
                out = [y1, (km * ue - f + extra(t_, yl)[0]) * iJu, 0.0, 0.0]
                return out + [zdot(t_, yl)] if has_z else out
        elif config == "prescribed":

            def rhs(t_, yy):
                yv = yy.tolist()
                y2, y3 = yv[2], yv[3]
                yl = [0.0, 0.0, y2, y3] + yv[4:]
                if ml == 0:
                    return [0.0, 0.0, 0.0, 0.0] + ([zdot(t_, yl)] if has_z else [])
                thu = spa + spb * (t_ - a)
                Tsr = ka * (y2 - thu + a0) + ca * (y3 - spb)
                f = fr_l(y3, ml) + ml * shift(t_, yl)[1]
                out = [0.0, 0.0, y3, (-f - Tsr + extra(t_, yl)[1]) * iJl]
                return out + [zdot(t_, yl)] if has_z else out
        else:

            def rhs(t_, yy):
                yl = yy.tolist()
                y0, y1, y2, y3 = yl[:4]
                Tsr = ka * (y2 - y0 + a0) + ca * (y3 - y1)
                shu, shl = shift(t_, yl)
                exu, exl = extra(t_, yl)
                if mu != 0:
                    ue = vf(t_) if cont else sua + sub * (t_ - a)
                    dwu = (km * ue - fr_u(y1, mu) - mu * shu + Tsr + exu) * iJu
                else:
                    dwu = 0.0
                dwl = (-fr_l(y3, ml) - ml * shl - Tsr + exl) * iJl if ml != 0 else 0.0
                if has_z:
                    return [y1, dwu, y3, dwl, zdot(t_, yl)]
                return [y1, dwu, y3, dwl]

        return rhs

    def make_events(mu: int, ml: int, t0: float):
        """Terminal events for the current modes.  At t == t0 each event function
        returns a tiny value on the 'inside' side, so that a mode that starts exactly on
        its boundary (e.g. slip starting from omega = 0) is not reported at t0 itself."""
        evs, meta = [], []

        def add(fun, direction, disc, kind):
            fun.terminal = True
            fun.direction = direction
            evs.append(fun)
            meta.append((disc, kind))

        if has_upper:
            if mu != 0:

                def ev_u0(t_, yy, s=mu):
                    return _TINY if t_ == t0 else s * yy[1]

                add(ev_u0, -1, "u", "zero")
            else:

                def ev_uhi(t_, yy):
                    return (
                        -_TINY
                        if t_ == t0
                        else te_upper(t_, yy.tolist()) - (hi_u + shift(t_, yy.tolist())[0])
                    )

                def ev_ulo(t_, yy):
                    return (
                        _TINY
                        if t_ == t0
                        else te_upper(t_, yy.tolist()) - (lo_u - shift(t_, yy.tolist())[0])
                    )

                add(ev_uhi, +1, "u", "hi")
                add(ev_ulo, -1, "u", "lo")
        if lugre:
            if ml != 0:
                # a reversal: the right-hand side has a kink at omega_l = 0

                def ev_lz(t_, yy, s=ml):
                    return _TINY if t_ == t0 else s * yy[3]

                add(ev_lz, -1, "l", "zero")
            else:
                # exactly at rest, nothing pushing: leaves rest when |omega_l| reaches
                # _LUGRE_EPS (the piece's right-hand side is the law's value at omega = 0)

                def ev_lp(t_, yy):
                    return yy[3] - _LUGRE_EPS

                def ev_lm(t_, yy):
                    return yy[3] + _LUGRE_EPS

                add(ev_lp, +1, "l", "leave")
                add(ev_lm, -1, "l", "leave")
        elif has_lower:
            if ml != 0:

                def ev_l0(t_, yy, s=ml):
                    return _TINY if t_ == t0 else s * yy[3]

                add(ev_l0, -1, "l", "zero")
            else:

                def ev_lhi(t_, yy):
                    return (
                        -_TINY
                        if t_ == t0
                        else te_lower(t_, yy.tolist()) - (hi_l + shift(t_, yy.tolist())[1])
                    )

                def ev_llo(t_, yy):
                    return (
                        _TINY
                        if t_ == t0
                        else te_lower(t_, yy.tolist()) - (lo_l - shift(t_, yy.tolist())[1])
                    )

                add(ev_lhi, +1, "l", "hi")
                add(ev_llo, -1, "l", "lo")
        return evs, meta

    # ---- bookkeeping --------------------------------------------------------------------
    events: list[tuple[float, str, str]] = []
    n_out = t.size
    Y = np.zeros((NY, n_out))
    MU = np.zeros(n_out, dtype=int)
    ML = np.zeros(n_out, dtype=int)
    pieces: list[tuple[float, float, object]] = []  # (t_start, t_end, OdeSolution)

    def band_mode(te: float, lo: float, hi: float) -> int:
        if lo <= te <= hi:
            return 0
        return _sgn(te)

    def kind_of(m: int) -> str:
        return "stick" if m == 0 else ("slip+" if m > 0 else "slip-")

    # ---- initial state and modes ----------------------------------------------------
    y = [0.0, 0.0, 0.0, 0.0] + ([float(state_z0)] if has_z else ([0.0] if lugre else []))
    modes = {"u": 0, "l": 0}

    def set_segment(i: int) -> None:
        seg["a"] = bp[i]
        seg["ua"] = float(ua[i])
        seg["ub"] = float(ub[i])
        seg["pa"] = float(pa[i])
        seg["pb"] = float(pb[i])
        if cont:
            seg["vf"] = vfs[i]

    if nseg:
        set_segment(0)
    elif config == "prescribed":
        seg["pa"] = float(thp[0])
    elif cont:
        seg["vf"] = _input_functions(np.array([t[0], t[0] + 1.0]), t, u_func, p)[0]
    else:
        seg["ua"] = float(_input_segments(np.array([t[0], t[0] + 1.0]), t, u_arr, p)[0][0])

    def restick_check(t_: float) -> None:
        """A sticking disc whose external torque is (strictly) outside the band starts
        to slip (only relevant after input jumps, e.g. prescribed velocity jumps)."""
        if has_upper and modes["u"] == 0:
            m = band_mode(te_upper(t_, y), lo_u - shift(t_, y)[0], hi_u + shift(t_, y)[0])
            if m != 0:
                modes["u"] = m
                events.append((t_, "u", kind_of(m)))
        if has_lower and not lugre and modes["l"] == 0:
            m = band_mode(te_lower(t_, y), lo_l - shift(t_, y)[1], hi_l + shift(t_, y)[1])
            if m != 0:
                modes["l"] = m
                events.append((t_, "l", kind_of(m)))

    restick_check(float(t[0]))
    if lugre:
        modes["l"] = lugre_direction(float(t[0]), y)
        if modes["l"] != 0:
            events.append((float(t[0]), "l", kind_of(modes["l"])))

    out_i = 0
    Y[:, 0] = y
    MU[0], ML[0] = modes["u"], modes["l"]
    out_i = 1
    n_calls = 0
    h_hint: float | None = None
    stalled = 0

    for i in range(nseg):
        a_i, b_i = float(bp[i]), float(bp[i + 1])
        set_segment(i)
        if i > 0:
            restick_check(a_i)
        tc = a_i
        while tc < b_i:
            if lugre:
                m = lugre_direction(tc, y)
                if m != modes["l"]:
                    modes["l"] = m
                    events.append((tc, "l", kind_of(m)))
            mu, ml = modes["u"], modes["l"]
            rhs = make_rhs(mu, ml)
            span = b_i - tc
            if span <= 1e-14 * max(1.0, abs(b_i)):
                f = rhs(tc, np.asarray(y))
                y = [y[k] + f[k] * span for k in range(NY)]
                if cont:
                    k1 = int(np.searchsorted(t, b_i, side="left"))
                    for k in range(next_sample, k1):
                        Y[:, k] = y
                        MU[k], ML[k] = mu, ml
                    next_sample = max(next_sample, k1)
                    out_i = max(out_i, k1)
                if dense_output:
                    pieces.append((tc, b_i, _ConstPiece(np.asarray(y))))
                tc = b_i
                break
            evs, meta = make_events(mu, ml, tc)
            first = span if h_hint is None else min(span, h_hint)
            sol = solve_ivp(
                rhs,
                (tc, b_i),
                np.asarray(y),
                method=lugre_method if lugre else "DOP853",
                rtol=rtol,
                atol=atol,
                events=evs,
                first_step=first,
                dense_output=dense_output or cont,
                **step_cap,
            )
            n_calls += 1
            if sol.status < 0:
                raise RuntimeError(f"solve_ivp failed at t={tc}: {sol.message}")
            if sol.t.size >= 2:
                # step-size hint for the next call (performance only; error control
                # still applies to every step)
                h_max = float(np.max(np.diff(sol.t)))
                if h_max > 0.0:
                    h_hint = 4.0 * h_max
            y_new = sol.y[:, -1].tolist()
            t_new = float(sol.t[-1])
            if cont:
                k1 = int(np.searchsorted(t, t_new, side="left"))
                if k1 > next_sample:
                    ks = np.arange(next_sample, k1)
                    Y[:, ks] = np.asarray(sol.sol(t[ks])).reshape(NY, -1)
                    MU[ks], ML[ks] = mu, ml
                    next_sample = k1
                    out_i = k1
            if dense_output:
                pieces.append((tc, t_new, sol.sol))
            if sol.status == 1:
                fired = [meta[j] for j in range(len(evs)) if sol.t_events[j].size]
                if t_new - tc <= 1e-13 * max(1.0, abs(t_new)):
                    stalled += 1
                    if stalled > _MAX_STALLED_EVENTS:
                        raise RuntimeError(f"reference_simulate: event chattering at t={t_new}")
                else:
                    stalled = 0
                y = y_new
                tc = t_new
                for disc, kind in fired:
                    if kind == "zero":
                        iw = 1 if disc == "u" else 3
                        y[iw] = 0.0
                for disc, kind in fired:
                    if lugre and disc == "l":
                        m = lugre_direction(tc, y)
                    elif kind == "zero":
                        if disc == "u":
                            m = band_mode(
                                te_upper(tc, y), lo_u - shift(tc, y)[0], hi_u + shift(tc, y)[0]
                            )
                        else:
                            m = band_mode(
                                te_lower(tc, y), lo_l - shift(tc, y)[1], hi_l + shift(tc, y)[1]
                            )
                    elif kind == "hi":
                        m = 1
                    else:
                        m = -1
                    if has_z and disc == state_reset and m == 0 and modes[disc] != 0:
                        y[4] = 0.0
                    modes[disc] = m
                    events.append((tc, disc, kind_of(m)))
                restick_check(tc)
                if tc >= b_i:
                    break
            else:
                y = y_new
                tc = b_i
        if is_sample[i + 1]:
            Y[:, out_i] = y
            MU[out_i], ML[out_i] = modes["u"], modes["l"]
            out_i += 1
            next_sample = out_i

    assert out_i == n_out, (out_i, n_out)

    res: dict = {"events": events, "n_solve_ivp": n_calls}
    if config == "prescribed":
        res["theta_u"] = thp.copy()
        if t.size > 1:
            sl = np.diff(thp) / np.diff(t)
            res["omega_u"] = np.append(sl, sl[-1])  # right-sided slope, last: left
        else:
            res["omega_u"] = np.zeros(1)
        res["mode_u"] = None
    else:
        res["theta_u"] = Y[0].copy()
        res["omega_u"] = Y[1].copy()
        res["mode_u"] = MU
    if has_lower:
        res["theta_l"] = Y[2].copy()
        res["omega_l"] = Y[3].copy()
        res["mode_l"] = ML
    else:
        res["theta_l"] = None
        res["omega_l"] = None
        res["mode_l"] = None

    res["z"] = Y[4].copy() if has_z else None
    res["z_bristle"] = Y[4].copy() if lugre else None
    if dense_output:
        res["sol"] = _DenseSolution(pieces, config, t, thp, has_lower)
    return res


class _ConstPiece:
    def __init__(self, y: np.ndarray):
        self.y = np.asarray(y, dtype=float)

    def __call__(self, tq):
        tq = np.atleast_1d(tq)
        return np.repeat(self.y[:, None], tq.size, axis=1)


class _DenseSolution:
    """Piecewise dense output of the reference solution."""

    def __init__(self, pieces, config, t, thp, has_lower):
        pieces = [pc for pc in pieces if pc[1] > pc[0]]
        self._starts = np.array([pc[0] for pc in pieces])
        self._ends = np.array([pc[1] for pc in pieces])
        self._sols = [pc[2] for pc in pieces]
        self._config = config
        self._t = t
        self._thp = thp
        self._has_lower = has_lower

    def __call__(self, tq) -> np.ndarray:
        tq = np.atleast_1d(np.asarray(tq, dtype=float))
        out = np.empty((4, tq.size))
        idx = np.clip(np.searchsorted(self._starts, tq, side="right") - 1, 0, len(self._sols) - 1)
        for j in np.unique(idx):
            sel = idx == j
            out[:, sel] = np.asarray(self._sols[j](tq[sel]))[:4].reshape(4, -1)
        if self._config == "prescribed":
            out[0] = np.interp(tq, self._t, self._thp)
            k = np.clip(np.searchsorted(self._t, tq, side="right") - 1, 0, self._t.size - 2)
            out[1] = (self._thp[k + 1] - self._thp[k]) / (self._t[k + 1] - self._t[k])
        if not self._has_lower:
            out[2:] = np.nan
        return out

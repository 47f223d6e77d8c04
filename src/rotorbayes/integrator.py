"""Compiled switch-model integrator of the rig (thesis §2.3, Leine et al. 1998).

Each disc is in one of three modes: slip in the positive direction (+1), slip in the
negative direction (-1) or stick (0, velocity held at exactly zero, friction equal to
the external torque).  Inside a mode the equations of motion are smooth, so they are
integrated with the classical fourth-order Runge-Kutta method on a *fixed* grid that is
aligned with the input samples (the linearly interpolated input is then smooth inside
every step).  A mode ends at an *event*, located inside the step by regula falsi on the
Runge-Kutta map itself:

* slip -> zero velocity: ``s * omega`` reaches 0; the disc sticks if its external
  torque lies in the static band, else it passes through zero into the other direction;
* stick -> slip: the external torque leaves the static band ``[-(Ts - dTc), Ts + dTc]``.

This is the limit of Leine's switch model as the stick band ``eta`` shrinks to zero:
the band is entered exactly at ``omega = 0`` so no velocity drift of order ``eta``
accumulates during stick.  Because the grid is fixed and every event time is a root of
a smooth function, the simulated angles are continuous (and piecewise smooth) in the
parameters: no step-size controller introduces jitter that least squares or a sampler
would see as noise.

The kernel never raises: it returns a status code (see :data:`STATUS_MESSAGES`) so a
likelihood can turn a failure into ``-inf``; :func:`rotorbayes.model.simulate` raises
with the offending values.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .friction import slip_torque

#: Configuration codes of the kernel.
CFG_UPPER = 0  # string removed: upper disc only
CFG_COUPLED = 1  # both discs, motor-driven
CFG_PRESCRIBED = 2  # lower disc only, driven by a prescribed upper-disc angle

OK = 0
BAD_PARAMETERS = 1
BLOW_UP = 2
TOO_MANY_EVENTS = 3

STATUS_MESSAGES = {
    OK: "ok",
    BAD_PARAMETERS: "invalid parameters (non-positive inertia, negative friction level, "
    "non-positive Stribeck velocity or shape, negative dead zone or delay)",
    BLOW_UP: "the solution blew up (non-finite or |omega| > 1e6 rad/s)",
    TOO_MANY_EVENTS: "more than 50 stick/slip events inside one step (Zeno behaviour)",
}

#: Velocity band of Leine's switch model [rad/s]; used to classify a disc as at rest.
ETA = 1e-6
#: Largest internal step [s] used when the input is sampled more coarsely.
H_MAX = 1e-3
_MAX_EVENTS_PER_STEP = 50
_VMAX = 1e6

# Indices of the derived-constant vector built by _derived().
_KM, _IJU, _TCU, _DTCU, _BU, _DBU, _IJL, _KA, _TCL, _DTCL, _BL, _DBL = range(12)
_DSL, _IWSL, _DL, _A0, _CA, _UOFF, _TDEL, _UDZ, _HIU, _LOU, _HIL, _LOL = range(12, 24)
_IDT = 24
_ND = 25


@njit(cache=True, error_model="numpy")
def _derived(p, dt):
    """Constants used in the inner loop, from the parameter vector ``p`` and step ``dt``.

    Returns ``(c, ok)``; ``ok`` is False for parameters that make the model
    meaningless (which the kernel reports as :data:`BAD_PARAMETERS`).
    """
    c = np.empty(_ND)
    k_m, J_u, Tc_u, dTc_u, b_u, db_u = p[0], p[1], p[2], p[3], p[4], p[5]
    J_l, k_a, Tc_l, dTc_l, b_l, db_l = p[6], p[7], p[8], p[9], p[10], p[11]
    Ts_l, ws_l, d_l, a0, c_a, u_off, t_del, u_dz = (
        p[12],
        p[13],
        p[14],
        p[15],
        p[16],
        p[17],
        p[18],
        p[19],
    )
    ok = True
    for i in range(p.shape[0]):
        if not math.isfinite(p[i]):
            ok = False
    if J_u <= 0.0 or J_l <= 0.0 or ws_l <= 0.0 or d_l <= 0.0:
        ok = False
    if Tc_u - abs(dTc_u) < 0.0 or Tc_l - abs(dTc_l) < 0.0 or Ts_l - abs(dTc_l) < 0.0:
        ok = False
    if b_u - abs(db_u) < 0.0 or b_l - abs(db_l) < 0.0:
        ok = False
    if u_dz < 0.0 or t_del < 0.0 or k_a < 0.0 or c_a < 0.0:
        ok = False
    c[_KM] = k_m
    c[_IJU] = 1.0 / J_u if J_u > 0.0 else 0.0
    c[_TCU], c[_DTCU], c[_BU], c[_DBU] = Tc_u, dTc_u, b_u, db_u
    c[_IJL] = 1.0 / J_l if J_l > 0.0 else 0.0
    c[_KA], c[_TCL], c[_DTCL], c[_BL], c[_DBL] = k_a, Tc_l, dTc_l, b_l, db_l
    c[_DSL] = Ts_l - Tc_l
    c[_IWSL] = 1.0 / ws_l if ws_l > 0.0 else 0.0
    c[_DL], c[_A0], c[_CA], c[_UOFF], c[_TDEL], c[_UDZ] = d_l, a0, c_a, u_off, t_del, u_dz
    # Static bands: the stick friction can balance external torques in [lo, hi].
    c[_HIU] = Tc_u + dTc_u
    c[_LOU] = -(Tc_u - dTc_u)
    c[_HIL] = Ts_l + dTc_l
    c[_LOL] = -(Ts_l - dTc_l)
    c[_IDT] = 1.0 / dt if dt > 0.0 else 0.0
    return c, ok


@njit(cache=True, error_model="numpy", inline="always")
def _interp(t, y, inv_dt):
    """Linear interpolation of samples ``y`` (spacing ``1/inv_dt``, start 0) and its slope."""
    n = y.shape[0]
    x = t * inv_dt
    if x <= 0.0:
        return y[0], 0.0
    if x >= n - 1:
        return y[n - 1], 0.0
    i = int(x)
    if i > n - 2:
        i = n - 2
    dy = y[i + 1] - y[i]
    return y[i] + (x - i) * dy, dy * inv_dt


@njit(cache=True, error_model="numpy", inline="always")
def _voltage(t, c, u):
    """Effective motor voltage: delayed, offset and through the dead zone [V]."""
    v, _ = _interp(t - c[_TDEL], u, c[_IDT])
    v += c[_UOFF]
    dz = c[_UDZ]
    if dz > 0.0:
        if v > dz:
            v -= dz
        elif v < -dz:
            v += dz
        else:
            v = 0.0
    return v


@njit(cache=True, error_model="numpy", inline="always")
def _drive(t, c, cfg, u, thp):
    """What drives the system at time ``t``: (voltage, upper angle, upper velocity).

    The prescribed upper-disc motion is only used in :data:`CFG_PRESCRIBED`.
    Evaluated once per Runge-Kutta stage time, outside the right-hand side, so the
    right-hand side works on scalars only.
    """
    if cfg == CFG_PRESCRIBED:
        th, w = _interp(t, thp, c[_IDT])
        return 0.0, th, w
    return _voltage(t, c, u), 0.0, 0.0


@njit(cache=True, error_model="numpy", inline="always")
def _torques(thu, wu, thl, wl, d, c, cfg):
    """External (non-friction) torques on the upper and lower disc [N m]."""
    v, thp, wp = d
    if cfg == CFG_PRESCRIBED:
        thu = thp
        wu = wp
    ts = 0.0
    if cfg != CFG_UPPER:
        ts = c[_KA] * (thl - thu + c[_A0]) + c[_CA] * (wl - wu)
    te_u = c[_KM] * v + ts
    return te_u, -ts


@njit(cache=True, error_model="numpy", inline="always")
def _rhs(thu, wu, thl, wl, mu, ml, d, c, cfg, shape):
    """Time derivatives of (theta_u, omega_u, theta_l, omega_l) in modes (mu, ml)."""
    te_u, te_l = _torques(thu, wu, thl, wl, d, c, cfg)
    dthu = 0.0
    dwu = 0.0
    if mu != 0 and cfg != CFG_PRESCRIBED:
        f = slip_torque(wu, mu, c[_TCU], c[_DTCU], c[_BU], c[_DBU], 0.0, 1.0, 1.0, shape)
        dthu = wu
        dwu = (te_u - f) * c[_IJU]
    dthl = 0.0
    dwl = 0.0
    if ml != 0 and cfg != CFG_UPPER:
        f = slip_torque(
            wl, ml, c[_TCL], c[_DTCL], c[_BL], c[_DBL], c[_DSL], c[_IWSL], c[_DL], shape
        )
        dthl = wl
        dwl = (te_l - f) * c[_IJL]
    return dthu, dwu, dthl, dwl


@njit(cache=True, error_model="numpy", inline="always")
def _rk4(h, thu, wu, thl, wl, mu, ml, k1, dm, d1, c, cfg, shape):
    """One classical Runge-Kutta step of size ``h`` in fixed modes.

    ``k1`` is the right-hand side at the start (shared with the dense output of the
    previous step); ``dm`` and ``d1`` are the drives at the middle and end of the step.
    """
    a1, a2, a3, a4 = k1
    hh = 0.5 * h
    b1, b2, b3, b4 = _rhs(
        thu + hh * a1, wu + hh * a2, thl + hh * a3, wl + hh * a4, mu, ml, dm, c, cfg, shape
    )
    c1, c2, c3, c4 = _rhs(
        thu + hh * b1, wu + hh * b2, thl + hh * b3, wl + hh * b4, mu, ml, dm, c, cfg, shape
    )
    e1, e2, e3, e4 = _rhs(
        thu + h * c1, wu + h * c2, thl + h * c3, wl + h * c4, mu, ml, d1, c, cfg, shape
    )
    k = h / 6.0
    return (
        thu + k * (a1 + 2.0 * (b1 + c1) + e1),
        wu + k * (a2 + 2.0 * (b2 + c2) + e2),
        thl + k * (a3 + 2.0 * (b3 + c3) + e3),
        wl + k * (a4 + 2.0 * (b4 + c4) + e4),
    )


@njit(cache=True, error_model="numpy", inline="always")
def _hermite(s, h, ya, fa, yb, fb):
    """Cubic Hermite interpolant at fraction ``s`` of a step of size ``h``."""
    s2 = s * s
    s3 = s2 * s
    h00 = 2.0 * s3 - 3.0 * s2 + 1.0
    h10 = s3 - 2.0 * s2 + s
    h01 = -2.0 * s3 + 3.0 * s2
    h11 = s3 - s2
    return h00 * ya + h * (h10 * fa + h11 * fb) + h01 * yb


@njit(cache=True, error_model="numpy", inline="always")
def _guards(thu, wu, thl, wl, mu, ml, d, c, cfg):
    """Event functions of both discs; a mode stays valid while its guard is >= 0.

    Slip: ``s * omega``.  Stick: the distance of the external torque to the nearer
    edge of the static band (continuous, so one root finder serves both edges).
    """
    te_u, te_l = _torques(thu, wu, thl, wl, d, c, cfg)
    gu = 1.0
    if cfg != CFG_PRESCRIBED:
        gu = mu * wu if mu != 0 else min(c[_HIU] - te_u, te_u - c[_LOU])
    gl = 1.0
    if cfg != CFG_UPPER:
        gl = ml * wl if ml != 0 else min(c[_HIL] - te_l, te_l - c[_LOL])
    return gu, gl


@njit(cache=True, error_model="numpy", inline="always")
def _mode_at_rest(te, lo, hi):
    """Mode of a disc at zero velocity with external torque ``te``."""
    if te > hi:
        return 1
    if te < lo:
        return -1
    return 0


@njit(cache=True, error_model="numpy")
def _step_to(t, x, thu, wu, thl, wl, mu, ml, k1, c, cfg, shape, u, thp):
    """Runge-Kutta step of arbitrary size ``x`` from ``t``; returns state and end drive."""
    dm = _drive(t + 0.5 * x, c, cfg, u, thp)
    d1 = _drive(t + x, c, cfg, u, thp)
    y1, y2, y3, y4 = _rk4(x, thu, wu, thl, wl, mu, ml, k1, dm, d1, c, cfg, shape)
    return y1, y2, y3, y4, d1


@njit(cache=True, error_model="numpy")
def _locate(t, h, g0, g1, disc, thu, wu, thl, wl, mu, ml, k1, c, cfg, shape, u, thp):
    """Time ``tau`` in (0, h] at which the guard of ``disc`` crosses zero.

    Illinois regula falsi on ``tau -> guard(RK4 step of size tau)``.  Returns the
    right end of the final bracket, where the guard is already violated, so the new
    mode starts on the correct side of the switching surface.
    """
    a, fa = 0.0, g0
    b, fb = h, g1
    side = 0
    tol = 1e-13 * h + 1e-16
    for _ in range(100):
        if b - a <= tol:
            break
        x = b - fb * (b - a) / (fb - fa)
        if not (a < x < b):
            x = 0.5 * (a + b)
        y1, y2, y3, y4, d = _step_to(t, x, thu, wu, thl, wl, mu, ml, k1, c, cfg, shape, u, thp)
        gu, gl = _guards(y1, y2, y3, y4, mu, ml, d, c, cfg)
        fx = gu if disc == 0 else gl
        if fx < 0.0:
            b, fb = x, fx
            if side == -1:
                fa *= 0.5
            side = -1
        else:
            a, fa = x, fx
            if side == 1:
                fb *= 0.5
            side = 1
    return b


@njit(cache=True, error_model="numpy", nogil=True)
def simulate_into(
    p,
    u,
    dt,
    cfg,
    shape,
    stride,
    substeps,
    thp,
    out_thu,
    out_wu,
    out_thl,
    out_wl,
    out_mu,
    out_ml,
    events,
):
    """Integrate one experiment and write the result into preallocated arrays.

    Parameters
    ----------
    p : float64[20]
        Parameters in :data:`rotorbayes.parameters.NAMES` order (``Ts_l`` resolved).
    u : float64[n]
        Input voltage samples [V] at times ``k*dt``.
    dt : float
        Sample interval [s].
    cfg : int
        :data:`CFG_UPPER`, :data:`CFG_COUPLED` or :data:`CFG_PRESCRIBED`.
    shape : int
        Stribeck shape code (see :mod:`rotorbayes.friction`).
    stride, substeps : int
        The Runge-Kutta step is ``dt * stride / substeps``; one of the two must be 1.
        Samples inside a step come from the cubic Hermite interpolant of the
        single-mode segment they fall in.
    thp : float64[n]
        Prescribed upper-disc angle [rad] (only read for ``CFG_PRESCRIBED``).
    out_* : arrays of length n
        Angles [rad], velocities [rad/s] and modes (-1, 0, +1) at the samples.
    events : float64[m, 3]
        Rows ``(time, disc, new_mode)`` of the first ``m`` mode switches.

    Returns
    -------
    status, n_events : int, int
    """
    n = u.shape[0]
    c, ok = _derived(p, dt)
    if not ok or substeps < 1 or stride < 1 or (stride > 1 and substeps > 1) or not dt > 0.0:
        out_thu[:] = np.nan
        out_wu[:] = np.nan
        out_thl[:] = np.nan
        out_wl[:] = np.nan
        return BAD_PARAMETERS, 0
    max_ev = events.shape[0]
    ratio = stride / substeps  # step length in samples
    n_steps = int(math.ceil((n - 1) / ratio - 1e-9))
    thu = 0.0
    wu = 0.0
    thl = 0.0
    wl = 0.0
    # The rig starts at rest; each disc sticks unless its torque breaks it loose.
    d1 = _drive(0.0, c, cfg, u, thp)
    te_u, te_l = _torques(thu, wu, thl, wl, d1, c, cfg)
    mu = _mode_at_rest(te_u, c[_LOU], c[_HIU]) if cfg != CFG_PRESCRIBED else 0
    ml = _mode_at_rest(te_l, c[_LOL], c[_HIL]) if cfg != CFG_UPPER else 0
    if cfg == CFG_PRESCRIBED:
        thu, wu = d1[1], d1[2]
    f = _rhs(thu, wu, thl, wl, mu, ml, d1, c, cfg, shape)
    n_ev = 0
    status = OK
    out_thu[0], out_wu[0], out_thl[0], out_wl[0] = thu, wu, thl, wl
    out_mu[0], out_ml[0] = mu, ml
    kout = 1
    t_end = 0.0
    for j in range(n_steps):
        t = t_end
        t_end = min((j + 1) * ratio, n - 1.0) * dt
        rem = t_end - t
        n_step_ev = 0
        dm = _drive(t + 0.5 * rem, c, cfg, u, thp)
        d1 = _drive(t_end, c, cfg, u, thp)
        while True:
            y1, y2, y3, y4 = _rk4(rem, thu, wu, thl, wl, mu, ml, f, dm, d1, c, cfg, shape)
            gu1, gl1 = _guards(y1, y2, y3, y4, mu, ml, d1, c, cfg)
            seg = rem
            ok_step = gu1 >= 0.0 and gl1 >= 0.0
            disc = -1
            if not ok_step:
                # Locate the earliest event among the violated guards.
                gu0, gl0 = _guards_now(thu, wu, thl, wl, mu, ml, t, c, cfg, u, thp)
                for dsc in range(2):
                    g1 = gu1 if dsc == 0 else gl1
                    if g1 < 0.0:
                        g0 = gu0 if dsc == 0 else gl0
                        tl = _locate(t, rem, max(g0, 0.0), g1, dsc, thu, wu, thl, wl, mu, ml,
                                     f, c, cfg, shape, u, thp)  # fmt: skip
                        if disc < 0 or tl < seg:
                            seg = tl
                            disc = dsc
                y1, y2, y3, y4, de = _step_to(
                    t, seg, thu, wu, thl, wl, mu, ml, f, c, cfg, shape, u, thp
                )
            else:
                de = d1
            fe = _rhs(y1, y2, y3, y4, mu, ml, de, c, cfg, shape)
            # Samples inside this single-mode segment, from its Hermite interpolant.
            t_seg = t + seg
            while kout < n and kout * dt <= t_seg + 1e-9 * dt:
                sfrac = (kout * dt - t) / seg if seg > 0.0 else 1.0
                if sfrac > 1.0:
                    sfrac = 1.0
                out_thu[kout] = _hermite(sfrac, seg, thu, f[0], y1, fe[0])
                out_wu[kout] = _hermite(sfrac, seg, wu, f[1], y2, fe[1])
                out_thl[kout] = _hermite(sfrac, seg, thl, f[2], y3, fe[2])
                out_wl[kout] = _hermite(sfrac, seg, wl, f[3], y4, fe[3])
                out_mu[kout], out_ml[kout] = mu, ml
                kout += 1
            thu, wu, thl, wl = y1, y2, y3, y4
            f = fe
            if ok_step:
                break
            t = t_seg
            rem = t_end - t
            # Switch the disc whose guard fired: it is at zero velocity now.
            if disc == 0:
                wu = 0.0
            else:
                wl = 0.0
            te_u, te_l = _torques(thu, wu, thl, wl, de, c, cfg)
            if disc == 0:
                mu = _mode_at_rest(te_u, c[_LOU], c[_HIU])
                new = mu
            else:
                ml = _mode_at_rest(te_l, c[_LOL], c[_HIL])
                new = ml
            f = _rhs(thu, wu, thl, wl, mu, ml, de, c, cfg, shape)
            if n_ev < max_ev:
                events[n_ev, 0] = t
                events[n_ev, 1] = disc
                events[n_ev, 2] = new
            n_ev += 1
            n_step_ev += 1
            if n_step_ev > _MAX_EVENTS_PER_STEP:
                status = TOO_MANY_EVENTS
                break
            if rem <= 1e-12 * dt:
                break
            dm = _drive(t + 0.5 * rem, c, cfg, u, thp)
        if status == OK and not (
            abs(wu) < _VMAX and abs(wl) < _VMAX and math.isfinite(thu) and math.isfinite(thl)
        ):
            status = BLOW_UP
        if status != OK:
            out_thu[kout:] = np.nan
            out_wu[kout:] = np.nan
            out_thl[kout:] = np.nan
            out_wl[kout:] = np.nan
            break
    if cfg == CFG_PRESCRIBED and status == OK:
        out_thu[:] = thp
        for k in range(n):
            out_wu[k] = _interp(k * dt, thp, c[_IDT])[1]
    return status, n_ev


@njit(cache=True, error_model="numpy")
def _guards_now(thu, wu, thl, wl, mu, ml, t, c, cfg, u, thp):
    """Guards at the current state and time (start of a segment)."""
    return _guards(thu, wu, thl, wl, mu, ml, _drive(t, c, cfg, u, thp), c, cfg)


@njit(cache=True, parallel=True, error_model="numpy")
def simulate_batch_into(P, u, dt, cfg, shape, stride, substeps, thp, out_thu, out_thl, status):
    """Integrate one experiment for every row of ``P`` in parallel (numba ``prange``).

    ``out_thu`` and ``out_thl`` have shape ``(len(P), len(u))``; ``status`` ``len(P)``.
    """
    m = P.shape[0]
    n = u.shape[0]
    for i in prange(m):
        wu = np.empty(n)
        wl = np.empty(n)
        mu = np.empty(n, dtype=np.int8)
        ml = np.empty(n, dtype=np.int8)
        ev = np.empty((0, 3))
        s, _ = simulate_into(
            P[i],
            u,
            dt,
            cfg,
            shape,
            stride,
            substeps,
            thp,
            out_thu[i],
            wu,
            out_thl[i],
            wl,
            mu,
            ml,
            ev,
        )
        status[i] = s

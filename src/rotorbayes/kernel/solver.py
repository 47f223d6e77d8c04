"""Compiled switch-model solver (thesis §2.3, Leine et al. 1998).

Each disc is in one of three modes: slip in the positive direction (+1), slip in the
negative direction (-1) or stick (0, velocity held at exactly zero, friction equal to the
external torque).  Inside a mode the equations of motion are smooth, so they are integrated
with Butcher's fifth-order Runge-Kutta method (:func:`_rk5`) on a *fixed* grid aligned
with the (delayed) input samples and chosen from the input alone (:func:`step_grid`: long
steps where the input is smooth, short ones over its fast transitions): a step is an odd
number of samples, so none of its stages (quarters, middle) falls on a sample, where the
linearly interpolated input has a kink, and with an input delay
the grid is shifted by the delay (:func:`rotorbayes.kernel.terms.delay_samples`), so the
delayed samples and the end of the held start are step points too.  A step ends early at

* an **event**, located inside the step by regula falsi on the Runge-Kutta map itself:
  slip -> zero velocity (``s * omega`` reaches 0; the disc sticks if its external torque
  lies in the static band, else it passes into the other direction), or stick -> slip
  (the external torque leaves the static band);
* a **kink** of the effective input (a dead-zone edge), found exactly by
  :func:`rotorbayes.kernel.terms.next_kink`; the
  step continues from there in the same mode, so every Runge-Kutta stage sees a smooth
  right-hand side;
* a **substep**: while the lower disc slips through the Stribeck band, a step is no
  longer than :func:`rotorbayes.kernel.terms.stribeck_step` allows from the state at its
  start (the friction there moves between Tc and Ts within a fraction of ws; at 55 ms
  steps without substeps the accuracy suite's worst case was 3.4e-5 rad), and while a
  disc decelerates, no longer than :func:`rotorbayes.kernel.terms.approach_step` allows
  (twice its time to stop: a stop between two step points was otherwise not seen).

Events are located from a seed on the step's Hermite interpolant (:func:`_locate`), and
the located step's own state is the event state.

This is the limit of Leine's switch model as the stick band shrinks to zero.  Because the
grid is fixed (moving only continuously with the delay), every event or kink time is a
root of a smooth function and every substep a continuous function of the state, the
simulated angles are continuous (and piecewise smooth) in
the parameters: no step-size controller introduces jitter that least squares or a sampler
would see as noise.

Between step points the angles come from the quintic Hermite interpolant of each segment
(angle, velocity and acceleration at both ends), so the samples inside a step are as
accurate as the step points: with a cubic one the interpolation, not the method, set the
error of long steps.

The physics lives in :mod:`rotorbayes.kernel.terms`; this module only integrates, locates
and interpolates.  The kernel never raises: it returns a status code
(:data:`rotorbayes.kernel.layout.STATUS_MESSAGES`).
"""

from __future__ import annotations

import math
from functools import partial

import numpy as np
from numba import njit, prange, types

from .calls import address, caller
from .layout import (
    BAD_EFFECT,
    BAD_PARAMETERS,
    BLOW_UP,
    CFG_PRESCRIBED,
    CFG_UPPER,
    OK,
    TOO_MANY_EVENTS,
)  # fmt: skip
from .numerics import fma
from .terms import (
    FULL,
    HOOK_TYPE,
    approach_step,
    delay_samples,
    derived,
    drive,
    effect_state_ok,
    guards,
    has_kinks,
    hook_array,
    input_source,
    interp,
    is_full_kernel,
    kink_in_step,
    modes_at_rest,
    needs_full_kernel,
    prescribed_velocity,
    rhs,
    state_fma,
    state_step,
    state_value,
    stribeck_step,
    violations,
)  # fmt: skip

#: Velocity band of Leine's switch model [rad/s]; used to classify a disc as at rest.
ETA = 1e-6
_MAX_EVENTS_PER_STEP = 50
_VMAX = 1e6


# Compiled as a function of its own, called once per step (and per trial step of an event
# location), with the right-hand side inlined by numba into its six stages: inlined into
# the solver as well, the step made the solver's first compilation 27 s instead of 16 s
# (2 cores), for the same numbers bit for bit and the same speed (a 30 s brake residual
# 0.196-0.200 ms either way, measured side by side) once the model tuple carries no arrays
# in the plain kernel (terms.hook_array; with them the calls cost 3-4 %).
@njit(cache=True, error_model="numpy")
def _rk5(t, h, y, mu, ml, k1, m, src):
    """One step of size ``h`` from ``t`` in fixed modes by Butcher's six-stage
    fifth-order Runge-Kutta method; returns the state and the drive at the end.

    ``k1`` is the right-hand side at the start (shared with the interpolant of the
    previous segment).  The stages sit at the start, the quarters, the middle and the end
    of the step: the input is read there (:func:`rotorbayes.kernel.terms.drive`), and the
    weights on those points are Boole's rule's (see :func:`_input_defect`).
    """
    c, cfg = m[0], m[1]
    thu, wu, thl, wl, z = y
    a1, a2, a3, a4, a5 = k1
    d_q = drive(t + 0.25 * h, c, cfg, src, m[6])
    d_m = drive(t + 0.5 * h, c, cfg, src, m[6])
    d_3q = drive(t + 0.75 * h, c, cfg, src, m[6])
    d_1 = drive(t + h, c, cfg, src, m[6])
    q = 0.25 * h
    b1, b2, b3, b4, b5 = rhs(fma(q, a1, thu), fma(q, a2, wu), fma(q, a3, thl), fma(q, a4, wl),
                             state_fma(m[6], q, a5, z), mu, ml, d_q, m)  # fmt: skip
    e = 0.125 * h
    c1, c2, c3, c4, c5 = rhs(
        fma(e, a1 + b1, thu), fma(e, a2 + b2, wu), fma(e, a3 + b3, thl), fma(e, a4 + b4, wl),
        state_fma(m[6], e, a5 + b5, z), mu, ml, d_q, m,
    )  # fmt: skip
    hh = 0.5 * h
    e1, e2, e3, e4, e5 = rhs(
        fma(h, c1, fma(-hh, b1, thu)), fma(h, c2, fma(-hh, b2, wu)),
        fma(h, c3, fma(-hh, b3, thl)), fma(h, c4, fma(-hh, b4, wl)),
        state_fma(m[6], h, c5, state_fma(m[6], -hh, b5, z)), mu, ml, d_m, m,
    )  # fmt: skip
    r = 0.1875 * h
    zz = 0.5625 * h
    f1, f2, f3, f4, f5 = rhs(
        fma(zz, e1, fma(r, a1, thu)), fma(zz, e2, fma(r, a2, wu)),
        fma(zz, e3, fma(r, a3, thl)), fma(zz, e4, fma(r, a4, wl)),
        state_fma(m[6], zz, e5, state_fma(m[6], r, a5, z)), mu, ml, d_3q, m,
    )  # fmt: skip
    s = h / 7.0
    g1, g2, g3, g4, g5 = rhs(
        fma(s * 8.0, f1, fma(s, 2.0 * b1 + 12.0 * (c1 - e1) - 3.0 * a1, thu)),
        fma(s * 8.0, f2, fma(s, 2.0 * b2 + 12.0 * (c2 - e2) - 3.0 * a2, wu)),
        fma(s * 8.0, f3, fma(s, 2.0 * b3 + 12.0 * (c3 - e3) - 3.0 * a3, thl)),
        fma(s * 8.0, f4, fma(s, 2.0 * b4 + 12.0 * (c4 - e4) - 3.0 * a4, wl)),
        state_fma(m[6], s * 8.0, f5,
                  state_fma(m[6], s, 2.0 * b5 + 12.0 * (c5 - e5) - 3.0 * a5, z)),
        mu, ml, d_1, m,
    )  # fmt: skip
    k = h / 90.0
    return (
        fma(k * 7.0, g1, fma(k, 7.0 * a1 + 32.0 * (c1 + f1) + 12.0 * e1, thu)),
        fma(k * 7.0, g2, fma(k, 7.0 * a2 + 32.0 * (c2 + f2) + 12.0 * e2, wu)),
        fma(k * 7.0, g3, fma(k, 7.0 * a3 + 32.0 * (c3 + f3) + 12.0 * e3, thl)),
        fma(k * 7.0, g4, fma(k, 7.0 * a4 + 32.0 * (c4 + f4) + 12.0 * e4, wl)),
        state_fma(
            m[6], k * 7.0, g5, state_fma(m[6], k, 7.0 * a5 + 32.0 * (c5 + f5) + 12.0 * e5, z)
        ),
    ), d_1


@njit(cache=True, error_model="numpy")
def _rates(y, mu, ml, d, m):
    """:func:`rotorbayes.kernel.terms.rhs` at state ``y``, compiled once as a function of
    its own for the solver's calls at the start and after an event: numba-inlined at
    each, they were two more copies of the right-hand side to type in the first
    compilation.  (The one after every step stays inlined: as a call it cost a 30 s brake
    residual 1-3 %.)"""
    return rhs(y[0], y[1], y[2], y[3], y[4], mu, ml, d, m)


@njit(cache=True, error_model="numpy", inline="always")
def _cubic(h, ya, fa, yb, fb):
    """Coefficients (in powers of the fraction ``s``) of the cubic Hermite interpolant of
    a segment of length ``h`` with values ``ya, yb`` and derivatives ``fa, fb``."""
    ha = h * fa
    hb = h * fb
    dy = yb - ya
    return ya, ha, 3.0 * dy - 2.0 * ha - hb, ha + hb - 2.0 * dy


@njit(cache=True, error_model="numpy", inline="always")
def _quintic(h, ya, va, aa, yb, vb, ab):
    """Coefficients (in powers of the fraction ``s``) of the quintic Hermite interpolant
    of a segment of length ``h`` with values ``ya, yb``, first derivatives ``va, vb`` and
    second derivatives ``aa, ab`` at its ends."""
    d0 = h * va
    a0 = 0.5 * h * h * aa
    big_d = yb - ya - d0 - a0
    big_e = h * vb - d0 - 2.0 * a0
    big_f = h * h * ab - 2.0 * a0
    return (
        ya, d0, a0,
        10.0 * big_d - 4.0 * big_e + 0.5 * big_f,
        -15.0 * big_d + 7.0 * big_e - big_f,
        6.0 * big_d - 3.0 * big_e + 0.5 * big_f,
    )  # fmt: skip


@njit(cache=True, error_model="numpy", inline="always")
def _horner5(s, c):
    """The quintic with coefficients ``c`` (from :func:`_quintic`) at fraction ``s``."""
    return fma(s, fma(s, fma(s, fma(s, fma(s, c[5], c[4]), c[3]), c[2]), c[1]), c[0])


@njit(cache=True, error_model="numpy", inline="always")
def _horner(s, c):
    """The cubic with coefficients ``c`` (from :func:`_cubic`) at fraction ``s``."""
    return fma(s, fma(s, fma(s, c[3], c[2]), c[1]), c[0])


@njit(cache=True, error_model="numpy", inline="always")
def _last_sample(k, lim, dt, inv_dt, n):
    """The last sample ``j >= k`` (below ``n``) with ``j * dt <= lim``, given that ``k``
    is one: the same test the samples are put to one by one."""
    j = int(lim * inv_dt)
    if j > n - 1:
        j = n - 1
    if j < k:
        j = k
    while j + 1 < n and (j + 1) * dt <= lim:
        j += 1
    while j > k and j * dt > lim:
        j -= 1
    return j


@njit(cache=True, error_model="numpy")
def _guard_on_interpolant(sf, t, h, cu, cwu, cl, cwl, cz, disc, mu, ml, m, src):
    """The guard of ``disc`` at fraction ``sf`` of a step, on the step's Hermite
    interpolant (coefficients from :func:`_quintic` and :func:`_cubic`): no Runge-Kutta
    map, so a few dozen operations."""
    d = drive(t + sf * h, m[0], m[1], src, m[6])
    gu, gl = guards(_horner5(sf, cu), _horner(sf, cwu), _horner5(sf, cl), _horner(sf, cwl),
                    _horner(sf, cz), mu, ml, d, m)  # fmt: skip
    return gu if disc == 0 else gl


@njit(cache=True, error_model="numpy")
def _locate(t, h, g0, g1, disc, y, mu, ml, k1, y1, d1, k_end, m, src):
    """Time ``tau`` in (0, h] at which the guard of ``disc`` crosses zero, with the state
    and drive there: ``(tau, y(tau), d(tau))``.

    The root is that of ``tau -> guard(Runge-Kutta step of size tau)``; the state returned
    is that step's, where the guard is already violated (the right end of the final
    bracket, at most ``1e-13 h`` from the root), so the new mode starts on the correct
    side of the switching surface.  ``y1, d1, k_end`` are the full step's end, drive and
    right-hand side there.

    The search starts where the guard crosses zero on the full step's Hermite interpolant
    (:func:`_guard_on_interpolant`; cheap) and goes on by secant steps on the map itself,
    kept inside the bracket; once they stall, it closes the bracket with a last point
    half a tolerance beyond; a secant step that would leave the bracket is replaced by
    regula falsi on it.  Three to five maps per event on a 30 s brake run, against
    fourteen for Illinois regula falsi from the bare bracket (the method before).
    """
    a, fa = 0.0, g0
    b, fb = h, g1
    yb, db = y1, d1
    # 1. The seed: Illinois on the interpolant, to 1e-5 of the step.
    cu = _quintic(h, y[0], k1[0], k1[1], y1[0], k_end[0], k_end[1])
    cl = _quintic(h, y[2], k1[2], k1[3], y1[2], k_end[2], k_end[3])
    cwu = _cubic(h, y[1], k1[1], y1[1], k_end[1])
    cwl = _cubic(h, y[3], k1[3], y1[3], k_end[3])
    cz = _cubic(h, y[4], k1[4], y1[4], k_end[4])
    sa, pa, sb, pb = 0.0, g0, 1.0, g1
    side = 0
    for _ in range(60):
        if sb - sa <= 1e-5:
            break
        sx = sb - pb * (sb - sa) / (pb - pa)
        if not (sa < sx < sb):
            sx = 0.5 * (sa + sb)
        px = _guard_on_interpolant(sx, t, h, cu, cwu, cl, cwl, cz, disc, mu, ml, m, src)
        if px < 0.0:
            sb, pb = sx, px
            if side == -1:
                pa *= 0.5
            side = -1
        else:
            sa, pa = sx, px
            if side == 1:
                pb *= 0.5
            side = 1
    seed = 0.5 * (sa + sb)
    lo = max(seed - 1e-4, 0.0)
    hi = min(seed + 1e-4, 1.0)
    slope = (_guard_on_interpolant(hi, t, h, cu, cwu, cl, cwl, cz, disc, mu, ml, m, src)
             - _guard_on_interpolant(lo, t, h, cu, cwu, cl, cwl, cz, disc, mu, ml, m, src)) / (
        (hi - lo) * h)  # fmt: skip
    # 2. Secant steps on the map from the seed, inside the bracket [a, b].
    tol = 1e-13 * h + 1e-16
    x = seed * h
    xp = -1.0
    fp = 0.0
    for _ in range(100):
        if not (a < x < b):
            x = b - fb * (b - a) / (fb - fa)
            if not (a < x < b):
                x = 0.5 * (a + b)
        yx, d = _rk5(t, x, y, mu, ml, k1, m, src)
        gu, gl = guards(yx[0], yx[1], yx[2], yx[3], yx[4], mu, ml, d, m)
        fx = gu if disc == 0 else gl
        if fx < 0.0:
            b, fb = x, fx
            yb, db = yx, d
        else:
            a, fa = x, fx
        if b - a <= tol:
            break
        if xp >= 0.0 and fx != fp:
            xn = x - fx * (x - xp) / (fx - fp)
        elif slope < 0.0:
            xn = x - fx / slope
        else:
            xn = -1.0  # no usable slope: regula falsi on the bracket
        xp, fp = x, fx
        if abs(xn - x) <= 0.5 * tol:  # converged: close the bracket on the other side
            xn = x + 0.5 * tol if fx >= 0.0 else x - 0.5 * tol
        x = xn
    return b, yb, db


@njit(cache=True, error_model="numpy")
def _input_defect(u, k, m):
    """How far the Runge-Kutta stages of a step over samples ``k .. k + m`` misjudge the
    linearly interpolated input ``u``: the largest of Boole's rule's errors in the
    integral of ``u`` and in its first and second moments about the middle (the rule uses
    the values the stages see, at the ends, quarters and middle), in volts times samples.
    Zero wherever the input is a polynomial of low degree over the step; large over a fast
    transition between levels."""
    c = k + 0.5 * m
    i0 = 0.0
    i1 = 0.0
    i2 = 0.0
    for i in range(k, k + m):
        a = u[i]
        b = u[i + 1]
        d = i - c
        i0 += 0.5 * (a + b)
        i1 += a * (0.5 + d) + (b - a) * (1.0 / 3.0 + 0.5 * d)
        i2 += a * (1.0 / 3.0 + d + d * d) + (b - a) * (0.25 + 2.0 * d / 3.0 + 0.5 * d * d)
    q = 0.25 * m
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    for j in range(5):
        w = (7.0, 32.0, 12.0, 32.0, 7.0)[j]
        x = (j - 2) * q
        v = w * interp(k + j * q, u, 1.0)[0]  # at a fractional sample
        s0 += v
        s1 += v * x
        s2 += v * x * x
    s0 *= m / 90.0
    s1 *= m / 90.0
    s2 *= m / 90.0
    hm = 0.5 * m
    return max(abs(i0 - s0), abs(i1 - s1) / hm, abs(i2 - s2) / (hm * hm))


@njit(cache=True, error_model="numpy")
def step_grid(u, max_stride, tol):
    """The Runge-Kutta step points [samples] for the input ``u``: from each point the
    longest step of an odd number of samples, at most ``max_stride``, whose
    :func:`_input_defect` is at most ``tol`` [V samples] (one sample always passes: the
    input is linear there); the last step ends at ``n - 1``.

    The grid depends on the input alone, never on the parameters, so the simulated
    angles stay continuous in the parameters.  Long steps where the input is smooth,
    short ones over fast transitions, where a long step would see the transition at only
    five points.
    """
    n = u.shape[0]
    last = n - 1
    out = np.empty(n)
    out[0] = 0.0
    j = 1
    k = 0
    while k < last:
        rem = last - k
        m = rem if rem <= max_stride else max_stride
        while m > 1 and _input_defect(u, k, m) > tol:
            m = m - 1 if m % 2 == 0 else m - 2
        if m < 1:
            m = 1
        k += m
        out[j] = k
        j += 1
    return out[:j].copy()


# The fills below are loops, not slice assignments: a slice assignment brings numba's
# general broadcasting setitem (and its error messages) into the first compilation.
@njit(cache=True, error_model="numpy")
def _fail_residuals(r, row, col_u, col_l, n):
    """A failed experiment: every residual of its channels is NaN."""
    for k in range(n):
        if col_u >= 0:
            r[row, col_u + k] = np.nan
        if col_l >= 0:
            r[row, col_l + k] = np.nan


@njit(cache=True, error_model="numpy")
def _fill_from(a, start, v):
    """``a[start:] = v``."""
    for k in range(start, a.shape[0]):
        a[k] = v


@njit(cache=True, error_model="numpy")
def _fail_outputs(out_thu, out_wu, out_thl, out_wl, start):
    """A failed simulation: angles and velocities NaN from sample ``start`` on."""
    _fill_from(out_thu, start, np.nan)
    _fill_from(out_wu, start, np.nan)
    _fill_from(out_thl, start, np.nan)
    _fill_from(out_wl, start, np.nan)


# Not inlined by numba (nor are the rig's terms, see terms.py): numba-level inlining copied
# the whole right-hand side into every entry point and made the first compilation take
# 248 s on 2 cores; compiled as functions (LLVM still inlines what pays) it takes 38 s and
# gives the same numbers bit for bit (residuals, batch and simulation checked).
# The exceptions are terms.drive and terms.rhs (numba-inlined, see there; the rhs into
# the Runge-Kutta step, _rk5, and after each step).
@njit(cache=True, error_model="numpy")
def _integrate(
    p, q, u, dt, cfg, shape, grid, h0, thp, use_hooks, hook_torque, hook_shift, hook_rate,
    state_reset, full, out_thu, out_wu, out_thl, out_wl, out_mu, out_ml, events,
    meas_u, meas_l, w_u, w_l, r, row, col_u, col_l,
):  # fmt: skip
    """The solver: one experiment, either every output (``full``) or only residuals.

    With ``full`` the angles, velocities and modes go to ``out_*`` and the first events to
    ``events``.  Otherwise nothing but the residuals is written: ``r[row, col_u + k] =
    w_u * (meas_u[k] - theta_u[k])`` (and the same for theta_l at ``col_l``; a column
    below 0 skips the channel), from the very interpolant the full output uses, so both
    paths give the same numbers.  A failed run writes NaN residuals.
    """
    n = u.shape[0]
    bad = violations(p, cfg)
    if (
        bad.any()
        or grid.shape[0] < 2
        or not grid[0] == 0.0
        or not grid[-1] >= n - 1.0
        or not h0 > 0.0
        or not dt > 0.0
    ):
        if full:
            _fail_outputs(out_thu, out_wu, out_thl, out_wl, 0)
        else:
            _fail_residuals(r, row, col_u, col_l, n)
        return BAD_PARAMETERS, 0
    c = derived(p, dt)
    m = (
        c,
        cfg,
        shape,
        hook_array(hook_torque, p),
        hook_array(hook_torque, q),
        use_hooks,
        hook_torque,
        hook_shift,
        hook_rate,
    )
    if needs_full_kernel(c) and not is_full_kernel(hook_torque):
        # The plain kernel has no code for the lag (terms.full_kernel_only): refuse, never
        # simulate without it.  rotorbayes.model.simulate picks the full kernel for it.
        if full:
            _fail_outputs(out_thu, out_wu, out_thl, out_wl, 0)
        else:
            _fail_residuals(r, row, col_u, col_l, n)
        return BAD_PARAMETERS, 0
    max_ev = events.shape[0]
    last = n - 1.0
    inv_dt = 1.0 / dt
    # The step grid: the input's own grid (`grid`, in samples, from step_grid) shifted by
    # the input delay, so the delayed input's kinks -- its sample times and the end of its
    # held start, t_delay -- sit on step points as the undelayed samples do; before the
    # held start's end, steps of `h0` samples counted back from it.  Only dead-zone edges
    # remain to be located inside a step (next_kink).  The grid moves continuously with
    # the delay: where the held start gains a step, that step has zero length.
    dly = delay_samples(c, cfg)
    n_hold = int(math.floor(dly / h0))
    jj = 0 if dly - n_hold * h0 > 1e-9 else 1
    kinks = has_kinks(c)
    src = input_source(c, cfg, u, thp)
    # The state: both discs' angles and velocities and the effect state z (a stateful user
    # effect's; in the plain kernel nothing reads it, and the compiler drops it).
    y = (0.0, 0.0, 0.0, 0.0, 0.0)
    # The rig starts at rest; each disc sticks unless its torque breaks it loose.
    d1 = drive(0.0, c, cfg, src, hook_torque)
    if cfg == CFG_PRESCRIBED:
        y = (d1[2], d1[3], 0.0, 0.0, 0.0)
    mu, ml = modes_at_rest(y[0], y[1], y[2], y[3], y[4], d1, m)
    f = _rates(y, mu, ml, d1, m)
    n_ev = 0
    status = OK
    if use_hooks and not effect_state_ok(y[0], y[1], y[2], y[3], y[4], d1, m):
        status = BAD_EFFECT
    if full:
        out_thu[0], out_wu[0], out_thl[0], out_wl[0] = y[0], y[1], y[2], y[3]
        out_mu[0], out_ml[0] = mu, ml
    else:
        if col_u >= 0:
            r[row, col_u] = w_u * (meas_u[0] - y[0])
        if col_l >= 0:
            r[row, col_l] = w_l * (meas_l[0] - y[2])
    kout = 1
    ou = np.uint64(col_u if col_u > 0 else 0)
    ol = np.uint64(col_l if col_l > 0 else 0)
    t_end = 0.0
    s_end = 0.0
    while s_end < last:
        if status != OK:
            break
        t = t_end
        if jj <= n_hold:
            s_end = min(dly - (n_hold - jj) * h0, last)
        else:
            s_end = min(dly + grid[jj - n_hold], last)
        jj += 1
        t_end = s_end * dt
        n_step_ev = 0
        while True:
            t_tgt = kink_in_step(hook_torque, t, t_end, c, src) if kinks else t_end
            t_sub = t + min(stribeck_step(y[1], f[1], mu, y[3], f[3], ml, c, cfg,
                                          hook_torque),
                            approach_step(y[1], f[1], mu, y[3], f[3], ml, c, cfg,
                                          t_tgt - t))  # fmt: skip
            t_sub = state_step(hook_rate, state_reset, t, t_sub, y, f, src, m)
            if t_sub < t_tgt:
                t_tgt = t_sub  # a substep through the Stribeck band or towards an event
            rem = t_tgt - t
            y1, d1 = _rk5(t, rem, y, mu, ml, f, m, src)
            gu1, gl1 = guards(y1[0], y1[1], y1[2], y1[3], y1[4], mu, ml, d1, m)
            seg = rem
            ok_step = gu1 >= 0.0 and gl1 >= 0.0
            disc = -1
            de = d1
            if not ok_step:
                # Locate the earliest event among the violated guards.
                d0 = drive(t, c, cfg, src, hook_torque)
                gu0, gl0 = guards(y[0], y[1], y[2], y[3], y[4], mu, ml, d0, m)
                f1 = rhs(y1[0], y1[1], y1[2], y1[3], y1[4], mu, ml, d1, m)
                y_ev, d_ev = y1, d1
                for dsc in range(2):
                    g1 = gu1 if dsc == 0 else gl1
                    if g1 < 0.0:
                        g0 = gu0 if dsc == 0 else gl0
                        tl, yl, dl = _locate(t, rem, max(g0, 0.0), g1, dsc, y, mu, ml, f,
                                             y1, d1, f1, m, src)  # fmt: skip
                        if disc < 0 or tl < seg:
                            seg = tl
                            disc = dsc
                            y_ev, d_ev = yl, dl
                # (the state as the plain kernel knows it: a constant 0, see terms.state_fma)
                y1 = (y_ev[0], y_ev[1], y_ev[2], y_ev[3], state_value(m[6], y_ev[4]))
                de = d_ev
            fe = rhs(y1[0], y1[1], y1[2], y1[3], y1[4], mu, ml, de, m)  # every step: inlined
            t_seg = t + seg
            lim = t_seg + 1e-9 * dt
            if kout < n and kout * dt <= lim:
                # Samples kout .. k1 lie inside this single-mode segment: angles from its
                # quintic Hermite interpolant (angle, velocity and acceleration at both
                # ends), velocities from the cubic one.
                k1 = _last_sample(kout, lim, dt, inv_dt, n)
                cu = _quintic(seg, y[0], f[0], f[1], y1[0], fe[0], fe[1])
                cl = _quintic(seg, y[2], f[2], f[3], y1[2], fe[2], fe[3])
                inv = 1.0 / seg if seg > 0.0 else 0.0
                if full:
                    cwu = _cubic(seg, y[1], f[1], y1[1], fe[1])
                    cwl = _cubic(seg, y[3], f[3], y1[3], fe[3])
                    # Unsigned indices, as below: no negative-index wraparound per store.
                    for k in range(np.uint64(kout), np.uint64(k1 + 1)):
                        sfrac = (k * dt - t) * inv if seg > 0.0 else 1.0
                        if sfrac > 1.0:
                            sfrac = 1.0
                        out_thu[k] = _horner5(sfrac, cu)
                        out_wu[k] = _horner(sfrac, cwu)
                        out_thl[k] = _horner5(sfrac, cl)
                        out_wl[k] = _horner(sfrac, cwl)
                        out_mu[k], out_ml[k] = mu, ml
                else:
                    for k in range(np.uint64(kout), np.uint64(k1 + 1)):
                        sfrac = (k * dt - t) * inv if seg > 0.0 else 1.0
                        if sfrac > 1.0:
                            sfrac = 1.0
                        if col_u >= 0:
                            r[row, ou + k] = w_u * (meas_u[k] - _horner5(sfrac, cu))
                        if col_l >= 0:
                            r[row, ol + k] = w_l * (meas_l[k] - _horner5(sfrac, cl))
                kout = k1 + 1
            y = y1
            f = fe
            if use_hooks and not effect_state_ok(y[0], y[1], y[2], y[3], y[4], de, m):
                status = BAD_EFFECT
                break
            t = t_seg
            if ok_step:
                if t_tgt >= t_end:
                    break
                continue  # a kink of the input: same modes, new segment
            # Switch the disc whose guard fired: it is at zero velocity now.
            if disc == 0:
                y = (y[0], 0.0, y[2], y[3], y[4])
            else:
                y = (y[0], y[1], y[2], 0.0, y[4])
            new_u, new_l = modes_at_rest(y[0], y[1], y[2], y[3], y[4], de, m)
            if disc == 0:
                mu = new_u
                new = mu
            else:
                ml = new_l
                new = ml
            if new == 0 and state_reset == disc:  # a stateful effect reset as the disc sticks
                y = (y[0], y[1], y[2], y[3], 0.0)
            f = _rates(y, mu, ml, de, m)
            if n_ev < max_ev:
                events[n_ev, 0] = t
                events[n_ev, 1] = disc
                events[n_ev, 2] = new
            n_ev += 1
            n_step_ev += 1
            if n_step_ev > _MAX_EVENTS_PER_STEP:
                status = TOO_MANY_EVENTS
                break
            if t_end - t <= 1e-12 * dt:
                break
        if status == OK and not (
            abs(y[1]) < _VMAX and abs(y[3]) < _VMAX and math.isfinite(y[0])
            and math.isfinite(y[2]) and math.isfinite(y[4])
        ):  # fmt: skip
            status = BLOW_UP
        if status != OK:
            break
    if not full:
        if status != OK:
            _fail_residuals(r, row, col_u, col_l, n)
        return status, n_ev
    if status != OK:
        _fail_outputs(out_thu, out_wu, out_thl, out_wl, kout)
    elif cfg == CFG_PRESCRIBED:
        for k in range(n):
            out_thu[k] = thp[k]
            out_wu[k] = prescribed_velocity(k * dt, c, thp)
    if cfg == CFG_UPPER:
        _fill_from(out_thl, 0, 0.0 if status == OK else np.nan)
    return status, n_ev


# The entry points pass _integrate's flags and channel columns as run-time values
# (np.bool_(True), np.int64(-1)), not as literals: numba compiles a callee once per literal
# argument value, so `True` and `False` made the simulation and the residuals two
# compilations of the whole solver (about 20 s each on 2 cores, issue 33); now a command
# that simulates and fits compiles it once per kernel (plain, full, with hooks).
_F1 = types.float64[::1]
_SIMULATE_SIGNATURE = types.UniTuple(types.int64, 2)(
    _F1, _F1, _F1, types.float64, types.int64, types.int64, _F1, types.float64, _F1,
    types.boolean, HOOK_TYPE, HOOK_TYPE, HOOK_TYPE, types.int64,
    _F1, _F1, _F1, _F1, types.int8[::1], types.int8[::1], types.float64[:, ::1],
)  # fmt: skip


@njit(cache=True, error_model="numpy", nogil=True)
def simulate_into(
    p, q, u, dt, cfg, shape, grid, h0, thp, use_hooks, hook_torque, hook_shift, hook_rate,
    state_reset, out_thu, out_wu, out_thl, out_wl, out_mu, out_ml, events,
):  # fmt: skip
    """Integrate one experiment and write the result into preallocated arrays.

    Parameters
    ----------
    p : float64[N_PARAMS]
        Built-in parameters in :data:`rotorbayes.kernel.layout.NAMES` order.
    q : float64[k]
        Parameters of the user-defined effects (read only by the hooks).
    u : float64[n]
        Input voltage samples [V] at times ``k*dt``.
    dt : float
        Sample interval [s].
    cfg : int
        :data:`CFG_UPPER`, :data:`CFG_COUPLED` or :data:`CFG_PRESCRIBED`.
    shape : int
        Stribeck shape code (see :mod:`rotorbayes.kernel.friction`).
    grid : float64[k]
        The Runge-Kutta step points in samples, from 0 to at least ``n - 1``, before the
        input delay's shift (:func:`step_grid`).
    h0 : float
        The step [samples] while the delayed input is held at ``u[0]`` (before
        ``t_delay``).
    thp : float64[n]
        Prescribed upper-disc angle [rad] (only read for ``CFG_PRESCRIBED``).
    use_hooks, hook_torque, hook_shift, hook_rate
        Whether to call the user-effect hooks: extra torques on the discs, shifts of
        their friction levels, and the rate of the effect state ``z`` (see
        :data:`rotorbayes.kernel.terms.HOOK_SIGNATURE`).
    state_reset : int
        The disc (0 upper, 1 lower) at whose sticking ``z`` is set to 0; -1: never; -2: no
        effect has a state.
    out_* : arrays of length n
        Angles [rad], velocities [rad/s] and modes (-1, 0, +1) at the samples.
    events : float64[m, 3]
        Rows ``(time, disc, new_mode)`` of the first ``m`` mode switches.

    Returns
    -------
    status, n_events : int, int
    """
    no_f = np.empty(0)
    return _integrate(
        p, q, u, dt, cfg, shape, grid, h0, thp, use_hooks, hook_torque, hook_shift,
        hook_rate, state_reset, np.bool_(True), out_thu, out_wu, out_thl, out_wl, out_mu,
        out_ml, events,
        no_f, no_f, 1.0, 1.0, np.empty((0, 0)), np.int64(0), np.int64(-1),
        np.int64(-1),
    )  # fmt: skip


_SIMULATE_PLAIN_SIGNATURE = types.UniTuple(types.int64, 2)(
    _F1, _F1, _F1, types.float64, types.int64, types.int64, _F1, types.float64, _F1,
    _F1, _F1, _F1, _F1, types.int8[::1], types.int8[::1], types.float64[:, ::1],
)  # fmt: skip


@njit(cache=True, error_model="numpy", nogil=True)
def simulate_into_plain(
    p, q, u, dt, cfg, shape, grid, h0, thp, out_thu, out_wu, out_thl, out_wl, out_mu,
    out_ml, events,
):  # fmt: skip
    """:func:`simulate_into` for a model without user-defined effects: no hooks at all, as
    :func:`residuals_into_plain` (a 30 s brake simulation from Python: 0.40 ms with
    the hooks, 0.13 ms without; the same numbers bit for bit)."""
    no_f = np.empty(0)
    return _integrate(
        p, q, u, dt, cfg, shape, grid, h0, thp, False, None, None, None, -2,
        np.bool_(True), out_thu, out_wu, out_thl, out_wl, out_mu, out_ml, events,
        no_f, no_f, 1.0, 1.0, np.empty((0, 0)), np.int64(0), np.int64(-1),
        np.int64(-1),
    )  # fmt: skip


_RESIDUALS_SIGNATURE = types.int64(
    _F1, _F1, _F1, types.float64, types.int64, types.int64, _F1, types.float64, _F1,
    types.boolean, HOOK_TYPE, HOOK_TYPE, HOOK_TYPE, types.int64,
    _F1, _F1, types.float64, types.float64, types.float64[:, ::1], types.int64, types.int64,
    types.int64,
)  # fmt: skip


@njit(cache=True, error_model="numpy", nogil=True)
def residuals_into(
    p, q, u, dt, cfg, shape, grid, h0, thp, use_hooks, hook_torque, hook_shift, hook_rate,
    state_reset, meas_u, meas_l, w_u, w_l, r, row, col_u, col_l,
):  # fmt: skip
    """Integrate one experiment and write only its weighted residuals (no output arrays).

    ``r[row, col_u + k] = w_u * (meas_u[k] - theta_u(k dt))`` for every sample ``k`` and
    likewise ``theta_l`` at ``col_l``; a negative column leaves that channel out (its
    measurement array may then be empty).  The numbers are those of :func:`simulate_into`
    followed by the same subtraction.  A failed experiment has NaN residuals.

    Returns the status code.
    """
    no_f = np.empty(0)
    no_i = np.empty(0, dtype=np.int8)
    status, _ = _integrate(
        p, q, u, dt, cfg, shape, grid, h0, thp, use_hooks, hook_torque, hook_shift,
        hook_rate, state_reset, np.bool_(False), no_f, no_f, no_f, no_f, no_i, no_i,
        np.empty((0, 3)),
        meas_u, meas_l, w_u, w_l, r, row, col_u, col_l,
    )  # fmt: skip
    return status


_PLAIN_SIGNATURE = types.int64(
    _F1, _F1, _F1, types.float64, types.int64, types.int64, _F1, types.float64, _F1,
    _F1, _F1, types.float64, types.float64, types.float64[:, ::1], types.int64, types.int64,
    types.int64,
)  # fmt: skip


@njit(cache=True, error_model="numpy", nogil=True)
def residuals_into_plain(
    p, q, u, dt, cfg, shape, grid, h0, thp, meas_u, meas_l, w_u, w_l, r, row, col_u,
    col_l,
):  # fmt: skip
    """:func:`residuals_into` for a model without user-defined effects.

    The same solver with no hooks at all (``None``, see :func:`terms.call_hook`) instead of
    function values: a call from Python then costs a few microseconds instead of about
    0.1 ms (numba types and unboxes a function argument on every call).
    """
    no_f = np.empty(0)
    no_i = np.empty(0, dtype=np.int8)
    status, _ = _integrate(
        p, q, u, dt, cfg, shape, grid, h0, thp, False, None, None, None, -2,
        np.bool_(False), no_f, no_f, no_f, no_f, no_i, no_i, np.empty((0, 3)),
        meas_u, meas_l, w_u, w_l, r, row, col_u, col_l,
    )  # fmt: skip
    return status


# ------------------------------------------------------------------ the full kernel
# The entry points for a model that needs the full kernel's physics (drive lag, upper
# Stribeck curve; see terms.lag_of) but has no user effects: the plain entry points'
# arguments, the marker FULL instead of hook functions (an integer: nothing to unbox per
# call, where a function argument costs 0.1-0.27 ms).
@njit(cache=True, error_model="numpy", nogil=True)
def simulate_into_full(
    p, q, u, dt, cfg, shape, grid, h0, thp, out_thu, out_wu, out_thl, out_wl, out_mu,
    out_ml, events,
):  # fmt: skip
    """:func:`simulate_into_plain` on the full kernel."""
    no_f = np.empty(0)
    return _integrate(
        p, q, u, dt, cfg, shape, grid, h0, thp, False, FULL, FULL, FULL, -2,
        np.bool_(True), out_thu, out_wu, out_thl, out_wl, out_mu, out_ml, events,
        no_f, no_f, 1.0, 1.0, np.empty((0, 0)), np.int64(0), np.int64(-1),
        np.int64(-1),
    )  # fmt: skip


@njit(cache=True, error_model="numpy", nogil=True)
def residuals_into_full(
    p, q, u, dt, cfg, shape, grid, h0, thp, meas_u, meas_l, w_u, w_l, r, row, col_u,
    col_l,
):  # fmt: skip
    """:func:`residuals_into_plain` on the full kernel."""
    no_f = np.empty(0)
    no_i = np.empty(0, dtype=np.int8)
    status, _ = _integrate(
        p, q, u, dt, cfg, shape, grid, h0, thp, False, FULL, FULL, FULL, -2,
        np.bool_(False), no_f, no_f, no_f, no_f, no_i, no_i, np.empty((0, 3)),
        meas_u, meas_l, w_u, w_l, r, row, col_u, col_l,
    )  # fmt: skip
    return status


# ------------------------------------------------------------------ parallel batches
# A batch calls its row's entry point through the address of the row's compiled code
# (calls.caller), passed in as its first argument `row_fn` by entry(): a direct call would
# link the whole solver into the batch and have LLVM optimise and translate it again, 3.0-
# 3.3 CPU s on 2 cores of a first fit's 20 (now 0.4 s).  The plain and the full kernel's
# rows have one signature, so one compiled batch serves both.  Called through the public
# functions below (or entry()), which pass the right address.
_BATCH_SIGNATURE = types.void(
    types.int64,
    types.float64[:, ::1], types.float64[:, ::1], _F1, types.float64, types.int64,
    types.int64, _F1, types.float64, _F1, types.boolean, HOOK_TYPE, HOOK_TYPE, HOOK_TYPE,
    types.int64,
    types.float64[:, ::1], types.float64[:, ::1], types.int64[::1],
)  # fmt: skip
_SIMULATE_PLAIN_BATCH_SIGNATURE = types.void(
    types.int64,
    types.float64[:, ::1], types.float64[:, ::1], _F1, types.float64, types.int64,
    types.int64, _F1, types.float64, _F1, types.float64[:, ::1], types.float64[:, ::1],
    types.int64[::1],
)  # fmt: skip
_RESIDUALS_BATCH_SIGNATURE = types.void(
    types.int64,
    types.float64[:, ::1], types.float64[:, ::1], _F1, types.float64, types.int64,
    types.int64, _F1, types.float64, _F1, types.boolean, HOOK_TYPE, HOOK_TYPE, HOOK_TYPE,
    types.int64,
    _F1, _F1, types.float64, types.float64, types.float64[:, ::1], types.int64, types.int64,
    types.int64[::1],
)  # fmt: skip
_PLAIN_BATCH_SIGNATURE = types.void(
    types.int64,
    types.float64[:, ::1], types.float64[:, ::1], _F1, types.float64, types.int64,
    types.int64, _F1, types.float64, _F1, _F1, _F1, types.float64, types.float64,
    types.float64[:, ::1], types.int64, types.int64, types.int64[::1],
)  # fmt: skip

_call_simulate = caller(_SIMULATE_SIGNATURE)
_call_simulate_plain = caller(_SIMULATE_PLAIN_SIGNATURE)
_call_residuals = caller(_RESIDUALS_SIGNATURE)
_call_residuals_plain = caller(_PLAIN_SIGNATURE)


@njit(cache=True)
def _batch_scratch(n):
    """What one row of a batched simulation writes and nobody reads: velocities, modes
    (``n`` samples each) and no events."""
    return (np.empty(n), np.empty(n), np.empty(n, dtype=np.int8), np.empty(n, dtype=np.int8),
            np.empty((0, 3)))  # fmt: skip


@njit(cache=True, parallel=True, error_model="numpy")
def _simulate_batch(
    row_fn, P, Q, u, dt, cfg, shape, grid, h0, thp, use_hooks, hook_torque, hook_shift,
    hook_rate, state_reset, out_thu, out_thl, status,
):  # fmt: skip
    """:func:`simulate_batch_into` with the address of :func:`simulate_into`'s code."""
    m = P.shape[0]
    n = u.shape[0]
    for i in prange(m):
        wu, wl, mu, ml, ev = _batch_scratch(n)
        s, _ = _call_simulate(row_fn, (
            P[i], Q[i], u, dt, cfg, shape, grid, h0, thp, use_hooks, hook_torque,
            hook_shift, hook_rate, state_reset, out_thu[i], wu, out_thl[i], wl, mu, ml, ev,
        ))  # fmt: skip
        status[i] = s


@njit(cache=True, parallel=True, error_model="numpy")
def _simulate_batch_plain(row_fn, P, Q, u, dt, cfg, shape, grid, h0, thp, out_thu, out_thl,
                          status):  # fmt: skip
    """:func:`simulate_batch_into_plain` (or ``_full``) with the address of the row's code."""
    m = P.shape[0]
    n = u.shape[0]
    for i in prange(m):
        wu, wl, mu, ml, ev = _batch_scratch(n)
        s, _ = _call_simulate_plain(row_fn, (
            P[i], Q[i], u, dt, cfg, shape, grid, h0, thp, out_thu[i], wu, out_thl[i], wl,
            mu, ml, ev,
        ))  # fmt: skip
        status[i] = s


@njit(cache=True, parallel=True, error_model="numpy")
def _residuals_batch(
    row_fn, P, Q, u, dt, cfg, shape, grid, h0, thp, use_hooks, hook_torque, hook_shift,
    hook_rate, state_reset, meas_u, meas_l, w_u, w_l, R, col_u, col_l, status,
):  # fmt: skip
    """:func:`residuals_batch_into` with the address of :func:`residuals_into`'s code."""
    m = P.shape[0]
    for i in prange(m):
        status[i] = _call_residuals(row_fn, (
            P[i], Q[i], u, dt, cfg, shape, grid, h0, thp, use_hooks, hook_torque,
            hook_shift, hook_rate, state_reset, meas_u, meas_l, w_u, w_l, R, i, col_u, col_l,
        ))  # fmt: skip


@njit(cache=True, parallel=True, error_model="numpy")
def _residuals_batch_plain(
    row_fn, P, Q, u, dt, cfg, shape, grid, h0, thp, meas_u, meas_l, w_u, w_l, R, col_u,
    col_l, status,
):  # fmt: skip
    """:func:`residuals_batch_into_plain` (or ``_full``) with the address of the row's
    code."""
    m = P.shape[0]
    for i in prange(m):
        status[i] = _call_residuals_plain(row_fn, (
            P[i], Q[i], u, dt, cfg, shape, grid, h0, thp, meas_u, meas_l, w_u, w_l, R,
            i, col_u, col_l,
        ))  # fmt: skip


def simulate_batch_into(
    P, Q, u, dt, cfg, shape, grid, h0, thp, use_hooks, hook_torque, hook_shift, hook_rate,
    state_reset, out_thu, out_thl, status,
):  # fmt: skip
    """Integrate one experiment for every row of ``P`` (and ``Q``) in parallel threads
    (numba ``prange``; :func:`simulate_into` per row).

    ``out_thu`` and ``out_thl`` have shape ``(len(P), len(u))``; ``status`` ``len(P)``.
    """
    entry("simulate_batch_into")(
        P, Q, u, dt, cfg, shape, grid, h0, thp, use_hooks, hook_torque, hook_shift,
        hook_rate, state_reset, out_thu, out_thl, status,
    )  # fmt: skip


def simulate_batch_into_plain(P, Q, u, dt, cfg, shape, grid, h0, thp, out_thu, out_thl, status):
    """:func:`simulate_batch_into` for a model without user-defined effects (see
    :func:`simulate_into_plain`)."""
    entry("simulate_batch_into_plain")(P, Q, u, dt, cfg, shape, grid, h0, thp, out_thu,
                                       out_thl, status)  # fmt: skip


def simulate_batch_into_full(P, Q, u, dt, cfg, shape, grid, h0, thp, out_thu, out_thl, status):
    """:func:`simulate_batch_into_plain` on the full kernel."""
    entry("simulate_batch_into_full")(P, Q, u, dt, cfg, shape, grid, h0, thp, out_thu,
                                      out_thl, status)  # fmt: skip


def residuals_batch_into(
    P, Q, u, dt, cfg, shape, grid, h0, thp, use_hooks, hook_torque, hook_shift, hook_rate,
    state_reset, meas_u, meas_l, w_u, w_l, R, col_u, col_l, status,
):  # fmt: skip
    """:func:`residuals_into` for every row of ``P`` (and ``Q``) in parallel threads:
    row ``i`` of ``R`` receives the residuals of parameter row ``i``, ``status[i]`` its
    status.  Nothing is allocated per row."""
    entry("residuals_batch_into")(
        P, Q, u, dt, cfg, shape, grid, h0, thp, use_hooks, hook_torque, hook_shift,
        hook_rate, state_reset, meas_u, meas_l, w_u, w_l, R, col_u, col_l, status,
    )  # fmt: skip


def residuals_batch_into_plain(
    P, Q, u, dt, cfg, shape, grid, h0, thp, meas_u, meas_l, w_u, w_l, R, col_u, col_l,
    status,
):  # fmt: skip
    """:func:`residuals_batch_into` for a model without user-defined effects (see
    :func:`residuals_into_plain`)."""
    entry("residuals_batch_into_plain")(
        P, Q, u, dt, cfg, shape, grid, h0, thp, meas_u, meas_l, w_u, w_l, R, col_u, col_l,
        status,
    )  # fmt: skip


def residuals_batch_into_full(
    P, Q, u, dt, cfg, shape, grid, h0, thp, meas_u, meas_l, w_u, w_l, R, col_u, col_l,
    status,
):  # fmt: skip
    """:func:`residuals_batch_into_plain` on the full kernel."""
    entry("residuals_batch_into_full")(
        P, Q, u, dt, cfg, shape, grid, h0, thp, meas_u, meas_l, w_u, w_l, R, col_u, col_l,
        status,
    )  # fmt: skip


# ------------------------------------------------------------------ compiled on request
#: Every entry point and the one signature its compiled function is compiled for.  None is
#: compiled when this module is imported: :func:`entry` compiles one (or loads it from
#: numba's cache) when it is first asked for, so a command compiles only what it uses (all
#: of them at import took 121 s on 2 cores with a cold cache).  The hooked ones need their
#: signature (it turns a hook, a numba dispatcher, into a function value of ``HOOK_TYPE``);
#: the others get it so that each is compiled exactly once, for the types Python passes.
#: A batch's signature starts with its row's address (see :data:`BATCHES`).
SIGNATURES = {
    "simulate_into": _SIMULATE_SIGNATURE,
    "simulate_into_plain": _SIMULATE_PLAIN_SIGNATURE,
    "simulate_into_full": _SIMULATE_PLAIN_SIGNATURE,
    "residuals_into": _RESIDUALS_SIGNATURE,
    "residuals_into_plain": _PLAIN_SIGNATURE,
    "residuals_into_full": _PLAIN_SIGNATURE,
    "simulate_batch_into": _BATCH_SIGNATURE,
    "simulate_batch_into_plain": _SIMULATE_PLAIN_BATCH_SIGNATURE,
    "simulate_batch_into_full": _SIMULATE_PLAIN_BATCH_SIGNATURE,
    "residuals_batch_into": _RESIDUALS_BATCH_SIGNATURE,
    "residuals_batch_into_plain": _PLAIN_BATCH_SIGNATURE,
    "residuals_batch_into_full": _PLAIN_BATCH_SIGNATURE,
}

#: Each batch entry point: its compiled function and its row's entry point.
BATCHES = {
    "simulate_batch_into": (_simulate_batch, "simulate_into"),
    "simulate_batch_into_plain": (_simulate_batch_plain, "simulate_into_plain"),
    "simulate_batch_into_full": (_simulate_batch_plain, "simulate_into_full"),
    "residuals_batch_into": (_residuals_batch, "residuals_into"),
    "residuals_batch_into_plain": (_residuals_batch_plain, "residuals_into_plain"),
    "residuals_batch_into_full": (_residuals_batch_plain, "residuals_into_full"),
}

#: The batch entry points ready in this process, bound to their row's address.
_BOUND: dict = {}


def compiled(name: str):
    """The numba function that entry point ``name`` compiles (a batch's is shared by the
    plain and the full kernel)."""
    return BATCHES[name][0] if name in BATCHES else globals()[name]


def is_ready(name: str) -> bool:
    """Whether entry point ``name`` is compiled (or loaded from the cache) in this process."""
    if name in BATCHES and not is_ready(BATCHES[name][1]):
        return False
    return SIGNATURES[name].args in compiled(name).overloads


def entry(name: str):
    """The compiled entry point ``name`` (a key of :data:`SIGNATURES`), compiled for its
    signature, or loaded from numba's cache, on the first request in this process.  A
    batch's comes with its row's address bound: it takes the arguments of the public
    function of its name."""
    bound = _BOUND.get(name)
    if bound is not None:
        return bound
    fn = compiled(name)
    if name in BATCHES:
        row = BATCHES[name][1]
        row_fn = address(entry(row), SIGNATURES[row])
    sig = SIGNATURES[name]
    if sig.args not in fn.overloads:
        fn.compile(sig)
        fn.disable_compile()  # as with an eager signature: other types are refused
    if name in BATCHES:
        fn = _BOUND.setdefault(name, partial(fn, row_fn))
    return fn

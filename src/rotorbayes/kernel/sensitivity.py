"""Forward sensitivities of the plain kernel's residuals (issue 33, first stage).

The derivative of the computed residuals by chosen built-in parameters, integrated with
the state by the solver's own scheme: every Runge-Kutta stage of
:func:`rotorbayes.kernel.solver._rk5` is differentiated (the stage's state sensitivity
``dY_i = S + h sum_j a_ij dK_j``, its rate ``dK_i = f_x(Y_i) dY_i + f_p(Y_i)``), and the
samples come from the derivative of the same quintic Hermite interpolant (linear in its
end values, so its derivative is the interpolant of the end sensitivities).  For a fixed
step grid this is the exact derivative of the computed residuals, with no step-size
error.

At an event (a disc stops, reverses, or its torque leaves the static band) the event
time ``tau`` moves with the parameters.  From the guard ``g(x(tau), tau, p) = 0``::

    dtau/dp = -(g_x S- + g_p) / (g_x f- + g_t)
    S+      = S- + (f- - f+) dtau/dp

(``f-`` the right-hand side in the old modes, ``f+`` in the new ones, both at the event
state); a disc that sticks has velocity sensitivity exactly 0.

What is not differentiated: the lengths of the Stribeck and approach substeps (continuous
functions of the state and the parameters, :func:`rotorbayes.kernel.terms.stribeck_step`),
and the segment ends of an event inside the interpolant (the samples of a segment that
ends at an event are interpolated from the sensitivities at fixed time).  So on stretches
with Stribeck substeps these are the derivatives of the model's solution rather than of
the computed residuals: measured against central differences of the kernel itself, they
differ by below 1e-6 of a column without the Stribeck curve and up to 4e-4 with it (where
the sensitivities agree with the reference's differences to 1e-5), and
on the 30 s brake bench by 1.4e-3 of a column at one place (near t = 7.9 s, a smooth
stretch) -- where they agree with central differences of the independent reference
(tests/reference.py) to 3e-7 to 1.4e-6, and the kernel's own differences do not (the
substep rule's dependence on the parameters).

Scope: the plain kernel (no user effects, not the full kernel), the upper and coupled
(motor-driven: coupled and brake) configurations, no dead zone; parameters
:data:`SUPPORTED`.  :meth:`rotorbayes.Problem.jacobian` falls back to finite differences
for anything else, and says so.

The state part of every step is the solver's own arithmetic operation for operation, so
the residuals written beside the Jacobian are those of
:func:`rotorbayes.kernel.solver.residuals_into_plain`, bit for bit (tested).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .friction import SHAPE_EXP, stribeck_g_slope
from .layout import (
    ALPHA0,
    B_L,
    B_U,
    BAD_PARAMETERS,
    BLOW_UP,
    C_ALPHA,
    CFG_COUPLED,
    CFG_UPPER,
    DB_L,
    DB_U,
    DELTA_L,
    DTC_L,
    DTC_U,
    J_L,
    J_U,
    K_ALPHA,
    K_M,
    N_PARAMS,
    OK,
    TC_L,
    TC_U,
    TOO_MANY_EVENTS,
    TS_L,
    U_OFFSET,
    WS_L,
)  # fmt: skip
from .numerics import fma
from .solver import _MAX_EVENTS_PER_STEP, _VMAX, _horner5, _last_sample, _locate, _quintic
from .terms import (
    _A0,
    _BL,
    _BU,
    _CA,
    _DBL,
    _DBU,
    _DL,
    _DSL,
    _DTCL,
    _DTCU,
    _IDT,
    _IJL,
    _IJU,
    _IWSL,
    _KA,
    _KM,
    _TCL,
    _TCU,
    _TDEL,
    _TSL,
    _XCUT,
    approach_step,
    delay_samples,
    derived,
    drive,
    guards,
    has_kinks,
    interp,
    modes_at_rest,
    needs_full_kernel,
    stribeck_step,
    violations,
)  # fmt: skip

#: The built-in parameters the kernel differentiates by (positions in
#: :data:`rotorbayes.kernel.layout.NAMES`): the base model, the lower Stribeck curve, the
#: asymmetries, the string's pre-torsion and damping, and the voltage offset.
SUPPORTED = (K_M, J_U, TC_U, DTC_U, B_U, DB_U, J_L, K_ALPHA, TC_L, DTC_L, B_L, DB_L, TS_L,
             WS_L, DELTA_L, ALPHA0, C_ALPHA, U_OFFSET)  # fmt: skip


@njit(cache=True, error_model="numpy", inline="always")
def _stribeck_d(x, delta, shape, x_cut):
    """``S(x)`` as :func:`rotorbayes.kernel.friction.stribeck` computes it (the same
    operations), with ``dS/dx`` and ``dS/ddelta`` of that computation (the table's cubic
    differentiated for the exponential shape)."""
    if x <= 0.0:
        return 1.0, 0.0, 0.0
    if shape == SHAPE_EXP:
        if x >= x_cut:
            return 0.0, 0.0, 0.0
        lx = math.log(x)
        g, dg = stribeck_g_slope(delta * lx)
        return g, dg * delta / x, dg * lx
    lx = math.log(x)
    e = math.exp(delta * lx)
    g = 1.0 / (1.0 + e)
    q = -g * g * e
    return g, q * delta / x, q * lx


# Inlined by numba into the five stages of _rk5_sens: called there, each call passed the
# constants' tuple by value and cost the integration 15 % (measured side by side, 30 s
# brake, 13 parameters).  _rhs_d, which the integrator calls between steps, is a function
# of its own: inlined at its five sites it made the first compilation 28 s instead of 20 s
# (2 cores) for the same speed.
@njit(cache=True, error_model="numpy", inline="always")
def _rhs_lin(thu, wu, thl, wl, mu, ml, d, c, cfg, shape, idx, tsf, pu, pl, P):
    """The right-hand side (as :func:`rotorbayes.kernel.terms.rhs` computes it in the plain
    kernel, operation for operation) and its linearisation: the rates, the coefficients
    of ``d f / d x`` (``cu`` and ``cl`` 1 for a slipping disc, 0 for a sticking one; the
    rows of the angle rates are copies of the velocity sensitivities), and
    ``d f / d p`` in ``pu`` (the upper velocity's row) and ``pl`` (the lower one's), both
    indexed by parameter (length N_PARAMS, zero outside the entries set here), and
    gathered by column into ``P`` (2 x k: the loops over the columns read them in order,
    which LLVM vectorises; a gather ``pu[idx[a]]`` inside them it does not)."""
    v = d[1]
    ts = 0.0
    da = 0.0
    dw = 0.0
    if cfg != CFG_UPPER:
        da = thl - thu + c[_A0]
        dw = wl - wu
        ts = fma(c[_KA], da, c[_CA] * dw)
    te_u = fma(c[_KM], v, ts)
    te_l = -ts
    dthu = 0.0
    dwu = 0.0
    cu = cl = 0.0
    a_thu = a_wu = a_thl = a_wl = 0.0
    b_thu = b_wu = b_thl = b_wl = 0.0
    if mu != 0:
        s = float(mu)
        bu = c[_BU] + s * c[_DBU]
        T = fma(bu, s * wu, c[_TCU] + 0.0 + s * c[_DTCU])
        f = s * T
        dthu = wu
        dwu = (te_u - f) * c[_IJU]
        iju = c[_IJU]
        ka = c[_KA] * iju if cfg != CFG_UPPER else 0.0
        ca = c[_CA] * iju if cfg != CFG_UPPER else 0.0
        cu = 1.0
        a_thu, a_wu, a_thl, a_wl = -ka, -ca - bu * iju, ka, ca
        pu[K_M] = v * iju
        pu[J_U] = -dwu * iju
        pu[TC_U] = -s * iju
        pu[DTC_U] = -iju
        pu[B_U] = -wu * iju
        pu[DB_U] = -s * wu * iju
        pu[K_ALPHA] = da * iju
        pu[ALPHA0] = ka
        pu[C_ALPHA] = dw * iju
        pu[U_OFFSET] = c[_KM] * iju
    else:  # a sticking disc: no rate, no sensitivity rate
        pu[K_M] = pu[J_U] = pu[TC_U] = pu[DTC_U] = pu[B_U] = pu[DB_U] = 0.0
        pu[K_ALPHA] = pu[ALPHA0] = pu[C_ALPHA] = pu[U_OFFSET] = 0.0
    dthl = 0.0
    dwl = 0.0
    if ml != 0 and cfg != CFG_UPPER:
        s = float(ml)
        bl = c[_BL] + s * c[_DBL]
        T = fma(bl, s * wl, c[_TCL] + 0.0 + s * c[_DTCL])
        ds = c[_DSL]
        x = abs(wl) * c[_IWSL]
        g, gx, gd = _stribeck_d(x, c[_DL], shape, c[_XCUT])
        if ds != 0.0:
            T = fma(ds, g, T)
        f = s * T
        dthl = wl
        dwl = (te_l - f) * c[_IJL]
        ijl = c[_IJL]
        sw = 1.0 if wl > 0.0 else (-1.0 if wl < 0.0 else 0.0)
        fw = bl + s * ds * gx * sw * c[_IWSL]
        ka = c[_KA] * ijl
        ca = c[_CA] * ijl
        cl = 1.0
        b_thu, b_wu, b_thl, b_wl = ka, ca, -ka, -ca - fw * ijl
        pl[J_L] = -dwl * ijl
        pl[K_ALPHA] = -da * ijl
        pl[ALPHA0] = -ka
        pl[C_ALPHA] = -dw * ijl
        pl[TC_L] = -s * (1.0 - g) * ijl
        pl[DTC_L] = -ijl
        pl[B_L] = -wl * ijl
        pl[DB_L] = -s * wl * ijl
        pl[TS_L] = -s * g * ijl
        pl[WS_L] = s * ds * gx * x * c[_IWSL] * ijl
        pl[DELTA_L] = -s * ds * gd * ijl
        if tsf:  # Ts_l follows Tc_l (no Stribeck effect): one parameter
            pl[TC_L] += pl[TS_L]
    else:
        pl[J_L] = pl[K_ALPHA] = pl[ALPHA0] = pl[C_ALPHA] = pl[TC_L] = pl[DTC_L] = 0.0
        pl[B_L] = pl[DB_L] = pl[TS_L] = pl[WS_L] = pl[DELTA_L] = 0.0
    for a in range(idx.shape[0]):
        i = idx[a]
        P[0, a] = pu[i]
        P[1, a] = pl[i]
    return (dthu, dwu, dthl, dwl), (cu, a_thu, a_wu, a_thl, a_wl, cl, b_thu, b_wu, b_thl, b_wl)


# The sensitivities' rates at the stages of rotorbayes.kernel.solver._rk5,
# ``out = f_x Y + f_p`` with ``Y = S + sum_j h a_ij K_j`` (``K0`` the rates at the start,
# ``K[a, j - 2]`` stage j's in column a), in fused multiply-adds (the products' roundings
# left out: the same derivatives to rounding, a third of the operations).  One pass over
# the columns per stage, the combination and the rates together (no stage state stored
# and read back), over unsigned indices (no negative-index wraparound per access), the
# parameter terms read in column order from ``P``.  LLVM vectorises these loops, but
# behind a run-time check that the arrays do not overlap, worth it from about 40 columns
# on: with 13 the scalar loop runs (a loop over the 4 k entries of a combination,
# vectorised, was no faster).  ``co``, ``P``: the linearisation (:func:`_rhs_lin`).


@njit(cache=True, error_model="numpy", inline="always")
def _rates_at(Y, out, co, P):
    """The rates of the sensitivities ``Y`` (4 x k) into ``out``."""
    cu, a0, a1, a2, a3, cl, b0, b1, b2, b3 = co
    for a in range(np.uint64(Y.shape[1])):
        y0 = Y[0, a]
        y1 = Y[1, a]
        y2 = Y[2, a]
        y3 = Y[3, a]
        out[0, a] = cu * y1
        out[1, a] = fma(a3, y3, fma(a2, y2, fma(a1, y1, fma(a0, y0, P[0, a]))))
        out[2, a] = cl * y3
        out[3, a] = fma(b3, y3, fma(b2, y2, fma(b1, y1, fma(b0, y0, P[1, a]))))


@njit(cache=True, error_model="numpy", inline="always")
def _stage2(h, S, K0, K, co, P):
    cu, a0, a1, a2, a3, cl, b0, b1, b2, b3 = co
    w0 = 0.25 * h
    for a in range(np.uint64(S.shape[1])):
        y0 = fma(w0, K0[0, a], S[0, a])
        y1 = fma(w0, K0[1, a], S[1, a])
        y2 = fma(w0, K0[2, a], S[2, a])
        y3 = fma(w0, K0[3, a], S[3, a])
        K[a, 0, 0] = cu * y1
        K[a, 0, 1] = fma(a3, y3, fma(a2, y2, fma(a1, y1, fma(a0, y0, P[0, a]))))
        K[a, 0, 2] = cl * y3
        K[a, 0, 3] = fma(b3, y3, fma(b2, y2, fma(b1, y1, fma(b0, y0, P[1, a]))))


@njit(cache=True, error_model="numpy", inline="always")
def _stage3(h, S, K0, K, co, P):
    cu, a0, a1, a2, a3, cl, b0, b1, b2, b3 = co
    w0 = 0.125 * h
    for a in range(np.uint64(S.shape[1])):
        y0 = fma(w0, K[a, 0, 0], fma(w0, K0[0, a], S[0, a]))
        y1 = fma(w0, K[a, 0, 1], fma(w0, K0[1, a], S[1, a]))
        y2 = fma(w0, K[a, 0, 2], fma(w0, K0[2, a], S[2, a]))
        y3 = fma(w0, K[a, 0, 3], fma(w0, K0[3, a], S[3, a]))
        K[a, 1, 0] = cu * y1
        K[a, 1, 1] = fma(a3, y3, fma(a2, y2, fma(a1, y1, fma(a0, y0, P[0, a]))))
        K[a, 1, 2] = cl * y3
        K[a, 1, 3] = fma(b3, y3, fma(b2, y2, fma(b1, y1, fma(b0, y0, P[1, a]))))


@njit(cache=True, error_model="numpy", inline="always")
def _stage4(h, S, K0, K, co, P):
    cu, a0, a1, a2, a3, cl, b0, b1, b2, b3 = co
    w1 = -0.5 * h
    for a in range(np.uint64(S.shape[1])):
        y0 = fma(h, K[a, 1, 0], fma(w1, K[a, 0, 0], S[0, a]))
        y1 = fma(h, K[a, 1, 1], fma(w1, K[a, 0, 1], S[1, a]))
        y2 = fma(h, K[a, 1, 2], fma(w1, K[a, 0, 2], S[2, a]))
        y3 = fma(h, K[a, 1, 3], fma(w1, K[a, 0, 3], S[3, a]))
        K[a, 2, 0] = cu * y1
        K[a, 2, 1] = fma(a3, y3, fma(a2, y2, fma(a1, y1, fma(a0, y0, P[0, a]))))
        K[a, 2, 2] = cl * y3
        K[a, 2, 3] = fma(b3, y3, fma(b2, y2, fma(b1, y1, fma(b0, y0, P[1, a]))))


@njit(cache=True, error_model="numpy", inline="always")
def _stage5(h, S, K0, K, co, P):
    cu, a0, a1, a2, a3, cl, b0, b1, b2, b3 = co
    w0 = 0.1875 * h
    w3 = 0.5625 * h
    for a in range(np.uint64(S.shape[1])):
        y0 = fma(w3, K[a, 2, 0], fma(w0, K0[0, a], S[0, a]))
        y1 = fma(w3, K[a, 2, 1], fma(w0, K0[1, a], S[1, a]))
        y2 = fma(w3, K[a, 2, 2], fma(w0, K0[2, a], S[2, a]))
        y3 = fma(w3, K[a, 2, 3], fma(w0, K0[3, a], S[3, a]))
        K[a, 3, 0] = cu * y1
        K[a, 3, 1] = fma(a3, y3, fma(a2, y2, fma(a1, y1, fma(a0, y0, P[0, a]))))
        K[a, 3, 2] = cl * y3
        K[a, 3, 3] = fma(b3, y3, fma(b2, y2, fma(b1, y1, fma(b0, y0, P[1, a]))))


@njit(cache=True, error_model="numpy", inline="always")
def _stage6_end(h, S, K0, K, co, P, S1):
    """The last stage, and the step's end ``S1`` from all six."""
    cu, a0, a1, a2, a3, cl, b0, b1, b2, b3 = co
    w0 = -3.0 / 7.0 * h
    w1 = 2.0 / 7.0 * h
    w2 = 12.0 / 7.0 * h
    w3 = -12.0 / 7.0 * h
    w4 = 8.0 / 7.0 * h
    v0 = 7.0 / 90.0 * h
    v2 = 32.0 / 90.0 * h
    v3 = 12.0 / 90.0 * h
    for a in range(np.uint64(S.shape[1])):
        y0 = fma(w2, K[a, 1, 0], fma(w1, K[a, 0, 0], fma(w0, K0[0, a], S[0, a])))
        y0 = fma(w4, K[a, 3, 0], fma(w3, K[a, 2, 0], y0))
        y1 = fma(w2, K[a, 1, 1], fma(w1, K[a, 0, 1], fma(w0, K0[1, a], S[1, a])))
        y1 = fma(w4, K[a, 3, 1], fma(w3, K[a, 2, 1], y1))
        y2 = fma(w2, K[a, 1, 2], fma(w1, K[a, 0, 2], fma(w0, K0[2, a], S[2, a])))
        y2 = fma(w4, K[a, 3, 2], fma(w3, K[a, 2, 2], y2))
        y3 = fma(w2, K[a, 1, 3], fma(w1, K[a, 0, 3], fma(w0, K0[3, a], S[3, a])))
        y3 = fma(w4, K[a, 3, 3], fma(w3, K[a, 2, 3], y3))
        g0 = cu * y1
        g1 = fma(a3, y3, fma(a2, y2, fma(a1, y1, fma(a0, y0, P[0, a]))))
        g2 = cl * y3
        g3 = fma(b3, y3, fma(b2, y2, fma(b1, y1, fma(b0, y0, P[1, a]))))
        S1[0, a] = fma(v0, g0, fma(v2, K[a, 3, 0], fma(v3, K[a, 2, 0],
                         fma(v2, K[a, 1, 0], fma(v0, K0[0, a], S[0, a])))))  # fmt: skip
        S1[1, a] = fma(v0, g1, fma(v2, K[a, 3, 1], fma(v3, K[a, 2, 1],
                         fma(v2, K[a, 1, 1], fma(v0, K0[1, a], S[1, a])))))  # fmt: skip
        S1[2, a] = fma(v0, g2, fma(v2, K[a, 3, 2], fma(v3, K[a, 2, 2],
                         fma(v2, K[a, 1, 2], fma(v0, K0[2, a], S[2, a])))))  # fmt: skip
        S1[3, a] = fma(v0, g3, fma(v2, K[a, 3, 3], fma(v3, K[a, 2, 3],
                         fma(v2, K[a, 1, 3], fma(v0, K0[3, a], S[3, a])))))  # fmt: skip


@njit(cache=True, error_model="numpy")
def _rk5_sens(t, h, y, mu, ml, k1, dF, S, S1, K, c, cfg, shape, src, idx, tsf, pu, pl, P):
    """:func:`rotorbayes.kernel.solver._rk5` (the same operations in the plain kernel)
    and its sensitivities: ``dF`` holds the rates' sensitivities at the start (in),
    ``K`` (k x 4 x 4: column, stage 2-5, state) and ``P`` (2 x k) are scratch; ``S1`` receives the
    sensitivities at the end.  Returns the state and drive at the end."""
    thu, wu, thl, wl = y
    a1, a2, a3, a4 = k1
    d_q = drive(t + 0.25 * h, c, cfg, src, None)
    d_m = drive(t + 0.5 * h, c, cfg, src, None)
    d_3q = drive(t + 0.75 * h, c, cfg, src, None)
    d_1 = drive(t + h, c, cfg, src, None)
    q = 0.25 * h
    (b1, b2, b3, b4), co = _rhs_lin(fma(q, a1, thu), fma(q, a2, wu), fma(q, a3, thl),
                                    fma(q, a4, wl), mu, ml, d_q, c, cfg, shape, idx, tsf, pu,
                                    pl, P)  # fmt: skip
    _stage2(h, S, dF, K, co, P)
    e = 0.125 * h
    (c1, c2, c3, c4), co = _rhs_lin(
        fma(e, a1 + b1, thu), fma(e, a2 + b2, wu), fma(e, a3 + b3, thl), fma(e, a4 + b4, wl),
        mu, ml, d_q, c, cfg, shape, idx, tsf, pu, pl, P,
    )  # fmt: skip
    _stage3(h, S, dF, K, co, P)
    hh = 0.5 * h
    (e1, e2, e3, e4), co = _rhs_lin(
        fma(h, c1, fma(-hh, b1, thu)), fma(h, c2, fma(-hh, b2, wu)),
        fma(h, c3, fma(-hh, b3, thl)), fma(h, c4, fma(-hh, b4, wl)),
        mu, ml, d_m, c, cfg, shape, idx, tsf, pu, pl, P,
    )  # fmt: skip
    _stage4(h, S, dF, K, co, P)
    r = 0.1875 * h
    zz = 0.5625 * h
    (f1, f2, f3, f4), co = _rhs_lin(
        fma(zz, e1, fma(r, a1, thu)), fma(zz, e2, fma(r, a2, wu)),
        fma(zz, e3, fma(r, a3, thl)), fma(zz, e4, fma(r, a4, wl)),
        mu, ml, d_3q, c, cfg, shape, idx, tsf, pu, pl, P,
    )  # fmt: skip
    _stage5(h, S, dF, K, co, P)
    s = h / 7.0
    (g1, g2, g3, g4), co = _rhs_lin(
        fma(s * 8.0, f1, fma(s, 2.0 * b1 + 12.0 * (c1 - e1) - 3.0 * a1, thu)),
        fma(s * 8.0, f2, fma(s, 2.0 * b2 + 12.0 * (c2 - e2) - 3.0 * a2, wu)),
        fma(s * 8.0, f3, fma(s, 2.0 * b3 + 12.0 * (c3 - e3) - 3.0 * a3, thl)),
        fma(s * 8.0, f4, fma(s, 2.0 * b4 + 12.0 * (c4 - e4) - 3.0 * a4, wl)),
        mu, ml, d_1, c, cfg, shape, idx, tsf, pu, pl, P,
    )  # fmt: skip
    _stage6_end(h, S, dF, K, co, P, S1)
    k = h / 90.0
    return (
        fma(k * 7.0, g1, fma(k, 7.0 * a1 + 32.0 * (c1 + f1) + 12.0 * e1, thu)),
        fma(k * 7.0, g2, fma(k, 7.0 * a2 + 32.0 * (c2 + f2) + 12.0 * e2, wu)),
        fma(k * 7.0, g3, fma(k, 7.0 * a3 + 32.0 * (c3 + f3) + 12.0 * e3, thl)),
        fma(k * 7.0, g4, fma(k, 7.0 * a4 + 32.0 * (c4 + f4) + 12.0 * e4, wl)),
    ), d_1


@njit(cache=True, error_model="numpy")
def _rhs_d(thu, wu, thl, wl, mu, ml, d, c, cfg, shape, idx, tsf, Y, out, pu, pl, P):
    """The right-hand side at a state (:func:`_rhs_lin`) and the rates of the
    sensitivities ``Y`` (4 x k) there: ``out[r, a] = sum_j d f_r / d x_j Y[j, a] + d f_r /
    d p_idx[a]``.  ``pu``, ``pl``, ``P``: scratch (:func:`_rhs_lin`)."""
    f, co = _rhs_lin(thu, wu, thl, wl, mu, ml, d, c, cfg, shape, idx, tsf, pu, pl, P)
    _rates_at(Y, out, co, P)
    return f


@njit(cache=True, error_model="numpy")
def _guard_grad(disc, mode, y, fm, d, c, cfg, src, idx, tsf, gp):
    """The guard of ``disc`` (mode ``mode`` before the event) at the event state ``y``:
    its gradient in the state ``(gx0..gx3)``, its time derivative along the old motion
    ``g_x f- + g_t``, and its parameter derivatives into ``gp`` (one per ``idx``)."""
    k = idx.shape[0]
    for a in range(k):
        gp[a] = 0.0
    if mode != 0:  # a slipping disc: g = mode * omega
        s = float(mode)
        if disc == 0:
            return 0.0, s, 0.0, 0.0, s * fm[1]
        return 0.0, 0.0, 0.0, s, s * fm[3]
    # A sticking disc: the distance of its external torque to the nearer band edge.
    ka = c[_KA] if cfg != CFG_UPPER else 0.0
    ca = c[_CA] if cfg != CFG_UPPER else 0.0
    da = y[2] - y[0] + c[_A0] if cfg != CFG_UPPER else 0.0
    dw = y[3] - y[1] if cfg != CFG_UPPER else 0.0
    v = d[1]
    ts = fma(ka, da, ca * dw) if cfg != CFG_UPPER else 0.0
    sg = 1.0 if disc == 0 else -1.0  # te = k_m v + ts (upper), -ts (lower)
    te = fma(c[_KM], v, ts) if disc == 0 else -ts
    if disc == 0:
        hi = c[_TCU] + c[_DTCU]
        lo = -(c[_TCU] - c[_DTCU])
    else:
        hi = c[_TSL] + c[_DTCL]
        lo = -(c[_TSL] - c[_DTCL])
    upper_edge = hi - te < te - lo
    e = -1.0 if upper_edge else 1.0  # g = e * te + (hi or -lo)
    tx0, tx1, tx2, tx3 = -sg * ka, -sg * ca, sg * ka, sg * ca
    tt = 0.0
    if disc == 0:
        dv = interp(d[0] - c[_TDEL], src, c[_IDT])[1]
        tt = c[_KM] * dv
    gdot = e * (tx0 * fm[0] + tx1 * fm[1] + tx2 * fm[2] + tx3 * fm[3] + tt)
    for a in range(k):
        i = idx[a]
        te_p = 0.0
        if i == K_ALPHA:
            te_p = sg * da
        elif i == ALPHA0:
            te_p = sg * ka
        elif i == C_ALPHA:
            te_p = sg * dw
        elif disc == 0 and i == K_M:
            te_p = v
        elif disc == 0 and i == U_OFFSET:
            te_p = c[_KM]
        edge_p = 0.0  # d(hi)/dp on the upper edge, d(-lo)/dp on the lower one
        if disc == 0:
            if i == TC_U:
                edge_p = 1.0
            elif i == DTC_U:
                edge_p = 1.0 if upper_edge else -1.0
        else:
            if i == TS_L or (tsf and i == TC_L):
                edge_p = 1.0
            elif i == DTC_L:
                edge_p = 1.0 if upper_edge else -1.0
        gp[a] = e * te_p + edge_p
    return e * tx0, e * tx1, e * tx2, e * tx3, gdot


@njit(cache=True, error_model="numpy", inline="always")
def _hermite_weights(sf, X, i):
    """The six quintic Hermite weights at the fraction ``sf`` of a step into column ``i``
    of ``X``, in units of the step: of the start's value, rate and acceleration, then the
    end's (the rate's times the step and the acceleration's times its square are the
    interpolant's)."""
    s2 = sf * sf
    s3 = s2 * sf
    s4 = s3 * sf
    s5 = s4 * sf
    X[0, i] = 1.0 - 10.0 * s3 + 15.0 * s4 - 6.0 * s5
    X[1, i] = sf - 6.0 * s3 + 8.0 * s4 - 3.0 * s5
    X[2, i] = 0.5 * s2 - 1.5 * s3 + 1.5 * s4 - 0.5 * s5
    X[3, i] = 10.0 * s3 - 15.0 * s4 + 6.0 * s5
    X[4, i] = -4.0 * s3 + 7.0 * s4 - 3.0 * s5
    X[5, i] = 0.5 * s3 - s4 + 0.5 * s5


@njit(cache=True, error_model="numpy", inline="always")
def _end_values(S, dF, S1, dFe, i0, a, w, hs, h2):
    """Column ``a``'s six end values of a segment for the channel of state row ``i0``
    (times the channel's weight ``w``; the rates times the step ``hs``, the accelerations
    times its square ``h2``): what :func:`_hermite_weights`' weights multiply."""
    return (w * S[i0, a], w * hs * dF[i0, a], w * h2 * dF[i0 + 1, a], w * S1[i0, a],
            w * hs * dFe[i0, a], w * h2 * dFe[i0 + 1, a])  # fmt: skip


@njit(cache=True, error_model="numpy", inline="always")
def _write_samples(kout, k1, t, seg, dt, y, f, y1, fe, S, dF, S1, dFe, meas_u, meas_l, w_u,
                   w_l, r, JT, jcol, col_u, col_l, X, Xc, known):  # fmt: skip
    """Residuals and their derivatives at samples ``kout .. k1`` of a segment: the
    solver's quintic Hermite interpolant, and the same interpolant of the sensitivities.

    The six Hermite weights of each sample go to the scratch ``X`` first (6 x at least
    the segment's samples); then each column of ``J`` is written down the samples, one
    sum of six products per entry, into ``JT`` (the transposed Jacobian: a row per
    column of ``J``).  With ``J`` in Fortran order, as :meth:`rotorbayes.Problem.jacobian`
    allocates it, ``JT`` is contiguous along the samples, the loop is vectorised and the
    stores are sequential (row by row, 13 scattered stores per sample, writing ``J`` took
    twice as long as integrating the sensitivities).

    The weights are in units of the step (``X[1]`` times ``seg`` and ``X[2]`` times
    ``seg²`` are the interpolant's, the factors go with the end values).  Those of a
    segment of whole samples (``ns`` of them at fractions ``1/ns .. 1``: the grid's
    ordinary step) are computed once per ``ns`` into ``Xc[ns]`` (``known[ns]`` 1);
    others each time into ``X``.  (Computed at every sample they were a tenth of a
    Jacobian.)"""
    k = S.shape[1]
    hs = seg
    h2 = seg * seg
    inv = 1.0 / seg if seg > 0.0 else 0.0
    cu = _quintic(seg, y[0], f[0], f[1], y1[0], fe[0], fe[1])
    cl = _quintic(seg, y[2], f[2], f[3], y1[2], fe[2], fe[3])
    ns = k1 + 1 - kout
    regular = ns < Xc.shape[0]
    for i in range(ns):
        kk = kout + i
        sf = (kk * dt - t) * inv if seg > 0.0 else 1.0
        if sf > 1.0:
            sf = 1.0
        if col_u >= 0:
            r[0, col_u + kk] = w_u * (meas_u[kk] - _horner5(sf, cu))
        if col_l >= 0:
            r[0, col_l + kk] = w_l * (meas_l[kk] - _horner5(sf, cl))
        if abs(sf * ns - (i + 1)) > 1e-9:
            regular = False
    if not (regular and known[ns] == 1):
        for i in range(ns):
            sf = ((kout + i) * dt - t) * inv if seg > 0.0 else 1.0
            if sf > 1.0:
                sf = 1.0
            _hermite_weights(sf, X, i)
        if regular:
            for i in range(ns):
                for j in range(_HERMITE):
                    Xc[ns, j, i] = X[j, i]
            known[ns] = 1
    else:
        X = Xc[ns]
    for ch in range(2):
        col = col_u if ch == 0 else col_l
        if col < 0:
            continue
        w = -(w_u if ch == 0 else w_l)
        i0 = 2 * ch
        # Unsigned indices (as the solver's): no negative-index wraparound per store, so
        # the loop down the samples is vectorised.
        row = np.uint64(col + kout)
        # Four columns per pass down the samples: each sample's six weights are read once
        # for the four (one column per pass: the loop's set-up and the weights' loads
        # were most of the time, 42 samples a step).
        a = 0
        while a + 4 <= k:
            p0, p1, p2, p3, p4, p5 = _end_values(S, dF, S1, dFe, i0, a, w, hs, h2)
            q0, q1, q2, q3, q4, q5 = _end_values(S, dF, S1, dFe, i0, a + 1, w, hs, h2)
            u0, u1, u2, u3, u4, u5 = _end_values(S, dF, S1, dFe, i0, a + 2, w, hs, h2)
            v0, v1, v2, v3, v4, v5 = _end_values(S, dF, S1, dFe, i0, a + 3, w, hs, h2)
            ca = jcol[a]
            cb = jcol[a + 1]
            cc = jcol[a + 2]
            cd = jcol[a + 3]
            for i in range(np.uint64(ns)):
                x0, x1, x2, x3, x4, x5 = X[0, i], X[1, i], X[2, i], X[3, i], X[4, i], X[5, i]
                JT[ca, row + i] = (p0 * x0 + p1 * x1 + p2 * x2
                                   + p3 * x3 + p4 * x4 + p5 * x5)  # fmt: skip
                JT[cb, row + i] = (q0 * x0 + q1 * x1 + q2 * x2
                                   + q3 * x3 + q4 * x4 + q5 * x5)  # fmt: skip
                JT[cc, row + i] = (u0 * x0 + u1 * x1 + u2 * x2
                                   + u3 * x3 + u4 * x4 + u5 * x5)  # fmt: skip
                JT[cd, row + i] = (v0 * x0 + v1 * x1 + v2 * x2
                                   + v3 * x3 + v4 * x4 + v5 * x5)  # fmt: skip
            a += 4
        while a < k:
            v0, v1, v2, v3, v4, v5 = _end_values(S, dF, S1, dFe, i0, a, w, hs, h2)
            c = jcol[a]
            for i in range(np.uint64(ns)):
                JT[c, row + i] = (v0 * X[0, i] + v1 * X[1, i] + v2 * X[2, i]
                                  + v3 * X[3, i] + v4 * X[4, i] + v5 * X[5, i])  # fmt: skip
            a += 1


@njit(cache=True, error_model="numpy", inline="always")
def _dot_at(a, ao, b, bo, n):
    """``sum a[ao + i] b[bo + i]`` for ``i < n``, in four interleaved partial sums (the
    code's order, so the same bits anywhere; four chains, not one, so it is not bound by
    the addition's latency); unsigned indices (vectorised)."""
    s0 = s1 = s2 = s3 = 0.0
    u = np.uint64
    a0 = u(ao)
    b0 = u(bo)
    i = u(0)
    m = u(n)
    while i + u(4) <= m:
        s0 += a[a0 + i] * b[b0 + i]
        s1 += a[a0 + i + u(1)] * b[b0 + i + u(1)]
        s2 += a[a0 + i + u(2)] * b[b0 + i + u(2)]
        s3 += a[a0 + i + u(3)] * b[b0 + i + u(3)]
        i += u(4)
    while i < m:
        s0 += a[a0 + i] * b[b0 + i]
        i += u(1)
    return (s0 + s1) + (s2 + s3)


@njit(cache=True, error_model="numpy", inline="always")
def _qt_r(Qt, r, ro, n, out, oo):
    """``out[oo + b] = sum_i Qt[b, i] r[ro + i]`` for the six rows ``b`` of ``Qt`` and ``i <
    n``: one pass over ``r``, six sums side by side (independent chains: six passes of a
    dot product each were twice the time)."""
    s0 = s1 = s2 = s3 = s4 = s5 = 0.0
    u = np.uint64
    b = u(ro)
    for i in range(u(n)):
        x = r[b + i]
        s0 += Qt[0, i] * x
        s1 += Qt[1, i] * x
        s2 += Qt[2, i] * x
        s3 += Qt[3, i] * x
        s4 += Qt[4, i] * x
        s5 += Qt[5, i] * x
    o = u(oo)
    out[o] = s0
    out[o + u(1)] = s1
    out[o + u(2)] = s2
    out[o + u(3)] = s3
    out[o + u(4)] = s4
    out[o + u(5)] = s5


#: Samples of a segment above which its rows are handed on reduced to six (fewer: the
#: samples' own rows, unreduced).
_HERMITE = 6


@njit(cache=True, error_model="numpy")
def _hermite_qr(X, ns, Qt, R):
    """``Xᵀ = Q R`` for the first ``ns`` columns of ``X`` (6 x ns, the Hermite weights of a
    segment's samples): Gram-Schmidt twice per column (orthogonal to rounding), ``Qt``
    (6 x ns) receives ``Qᵀ``, ``R`` (6 x 6) the triangle.  False where a weight column is
    (nearly) a combination of the others: the segment's rows are then handed on whole."""
    for b in range(_HERMITE):
        for c in range(_HERMITE):
            R[b, c] = 0.0
    for b in range(_HERMITE):
        xb = X[b]
        qb = Qt[b]
        for i in range(ns):
            qb[i] = xb[i]
        nrm0 = _dot_at(qb, 0, qb, 0, ns)
        for _ in range(2):
            for c in range(b):
                qc = Qt[c]
                d = _dot_at(qc, 0, qb, 0, ns)
                R[c, b] += d
                for i in range(ns):
                    qb[i] -= d * qc[i]
        nrm = _dot_at(qb, 0, qb, 0, ns)
        if not nrm > 1e-24 * nrm0 or nrm0 == 0.0:
            return False
        nrm = math.sqrt(nrm)
        R[b, b] = nrm
        inv = 1.0 / nrm
        for i in range(ns):
            qb[i] *= inv
    return True


@njit(cache=True, error_model="numpy")
def _write_rows(kout, k1, t, seg, dt, y, f, y1, fe, S, dF, S1, dFe, meas_u, meas_l, w_u, w_l,
                r, Wt, info, jcol, col_u, col_l, X, Qc, Rc, known, V):  # fmt: skip
    """The rows of ``[J | r]`` of samples ``kout .. k1`` of a segment, reduced: the
    residuals go to ``r`` whole, and the segment's rows (per channel ``Xᵀ V`` for the
    Hermite weights ``X`` and the six end values' sensitivities ``V``; ``r_s`` beside)
    go to ``Wt`` (a column per row: ``Wt[jcol[a], row]``, ``Wt[-1, row]`` the residual)
    as the six rows ``[R V | Qᵀ r_s]`` of ``Xᵀ = Q R``: the same ``Jᵀ J`` and ``Jᵀ r``
    (what is left of ``r_s``, ``|r_s|² - |Qᵀ r_s|²``, is the caller's to add: it knows
    ``|r|²``).  ``info[0]`` counts the rows written.  The factors of a segment of whole
    samples (``ns`` of them, the grid's ordinary step) are computed once per ``ns`` into
    ``Qc``/``Rc`` (``known[ns]``: 1 done, 2 not reducible); others each time.  ``V``:
    scratch (6 x k).  Where ``Wt`` has no room left, ``info[1]`` is set and nothing is
    written."""
    k = S.shape[1]
    m1 = Wt.shape[0]
    hs = seg
    h2 = seg * seg
    inv = 1.0 / seg if seg > 0.0 else 0.0
    cu = _quintic(seg, y[0], f[0], f[1], y1[0], fe[0], fe[1])
    cl = _quintic(seg, y[2], f[2], f[3], y1[2], fe[2], fe[3])
    ns = k1 + 1 - kout
    regular = ns > _HERMITE and ns < Qc.shape[0]
    for i in range(ns):
        kk = kout + i
        sf = (kk * dt - t) * inv if seg > 0.0 else 1.0
        if sf > 1.0:
            sf = 1.0
        if col_u >= 0:
            r[0, col_u + kk] = w_u * (meas_u[kk] - _horner5(sf, cu))
        if col_l >= 0:
            r[0, col_l + kk] = w_l * (meas_l[kk] - _horner5(sf, cl))
        if abs(sf * ns - (i + 1)) > 1e-9:
            regular = False
    Qt = Qc[0]
    R = Rc[0]
    reduced = False
    if regular and known[ns] == 1:
        Qt = Qc[ns]
        R = Rc[ns]
        reduced = True
    else:
        # The Hermite weights of the samples, in units of the step (X[1] times seg and
        # X[2] times seg² are the interpolant's).
        for i in range(ns):
            sf = ((kout + i) * dt - t) * inv if seg > 0.0 else 1.0
            if sf > 1.0:
                sf = 1.0
            _hermite_weights(sf, X, i)
        if regular and known[ns] == 0:
            known[ns] = 1 if _hermite_qr(X, ns, Qc[ns], Rc[ns]) else 2
            if known[ns] == 1:
                Qt = Qc[ns]
                R = Rc[ns]
                reduced = True
        elif ns > _HERMITE and not regular:
            reduced = _hermite_qr(X, ns, Qt, R)
    row = info[0]
    nrow = _HERMITE if reduced else ns
    if row + 2 * nrow > Wt.shape[1]:
        info[1] = 1
        return
    for ch in range(2):
        col = col_u if ch == 0 else col_l
        if col < 0:
            continue
        w = -(w_u if ch == 0 else w_l)
        i0 = 2 * ch
        for a in range(k):
            V[0, a] = w * S[i0, a]
            V[1, a] = w * hs * dF[i0, a]
            V[2, a] = w * h2 * dF[i0 + 1, a]
            V[3, a] = w * S1[i0, a]
            V[4, a] = w * hs * dFe[i0, a]
            V[5, a] = w * h2 * dFe[i0 + 1, a]
        if k < m1 - 1:  # columns of other experiments' parameters: zero in these rows
            for b in range(nrow):
                for c in range(m1):
                    Wt[c, row + b] = 0.0
        if reduced:
            # R is upper triangular: its 21 entries, a column's six rows written together
            # (next to each other in Wt's row of that column; by rows of R, six passes
            # over the columns, they cost twice as much).
            r00, r01, r02, r03, r04, r05 = R[0, 0], R[0, 1], R[0, 2], R[0, 3], R[0, 4], R[0, 5]
            r11, r12, r13, r14, r15 = R[1, 1], R[1, 2], R[1, 3], R[1, 4], R[1, 5]
            r22, r23, r24, r25 = R[2, 2], R[2, 3], R[2, 4], R[2, 5]
            r33, r34, r35 = R[3, 3], R[3, 4], R[3, 5]
            r44, r45 = R[4, 4], R[4, 5]
            r55 = R[5, 5]
            for a in range(k):
                c = jcol[a]
                v0, v1, v2, v3, v4, v5 = V[0, a], V[1, a], V[2, a], V[3, a], V[4, a], V[5, a]
                Wt[c, row] = r00 * v0 + r01 * v1 + r02 * v2 + r03 * v3 + r04 * v4 + r05 * v5
                Wt[c, row + 1] = r11 * v1 + r12 * v2 + r13 * v3 + r14 * v4 + r15 * v5
                Wt[c, row + 2] = r22 * v2 + r23 * v3 + r24 * v4 + r25 * v5
                Wt[c, row + 3] = r33 * v3 + r34 * v4 + r35 * v5
                Wt[c, row + 4] = r44 * v4 + r45 * v5
                Wt[c, row + 5] = r55 * v5
            _qt_r(Qt, r[0], col + kout, ns, Wt[m1 - 1], row)
        else:
            for i in range(ns):
                x0, x1, x2, x3, x4, x5 = X[0, i], X[1, i], X[2, i], X[3, i], X[4, i], X[5, i]
                for a in range(k):
                    Wt[jcol[a], row + i] = (x0 * V[0, a] + x1 * V[1, a] + x2 * V[2, a]
                                            + x3 * V[3, a] + x4 * V[4, a]
                                            + x5 * V[5, a])  # fmt: skip
                Wt[m1 - 1, row + i] = r[0, col + kout + i]
        row += nrow
    info[0] = row


@njit(cache=True, error_model="numpy", nogil=True)
def sensitivities_into(p, u, dt, cfg, shape, grid, h0, idx, tsf, meas_u, meas_l, w_u, w_l,
                       r, J, jcol, col_u, col_l, Wt, info):  # fmt: skip
    """Residuals of one experiment and their derivatives by the parameters ``p[idx]``.

    The arguments are :func:`rotorbayes.kernel.solver.residuals_into_plain`'s (``r`` of
    shape ``(1, n_residuals)``, row 0) and: ``idx`` (int64) the positions in ``p`` to
    differentiate by, each one of :data:`SUPPORTED`; ``tsf`` whether ``Ts_l`` follows
    ``Tc_l`` (no Stribeck effect: the derivative by ``Tc_l`` moves both); ``J``
    (n_residuals x m) receives ``d r / d p[idx[a]]`` in column ``jcol[a]`` (rows as
    ``r``'s columns; rows of samples only, other rows untouched); any memory order, the
    fastest Fortran order (a column contiguous).  ``Wt`` (m + 1 x capacity, C order) and
    ``info`` (int64, 2): where ``Wt`` has columns, ``J`` is not written (pass any
    Fortran-order array) and the rows of ``[J | r]`` go to ``Wt`` reduced instead
    (:func:`_write_rows`, from column ``info[0]`` on; ``info[0]`` ends as the count,
    ``info[1]`` is 1 where they did not fit); ``r`` is written whole either way.

    Returns the status code (:data:`rotorbayes.kernel.layout.STATUS_MESSAGES`); the plain
    kernel's code for a model it cannot differentiate is ``BAD_PARAMETERS`` (a dead zone,
    a configuration other than upper or coupled, the full kernel's physics).
    """
    n = u.shape[0]
    k = idx.shape[0]
    bad = violations(p, cfg)
    c = derived(p, dt)
    if (bad.any() or grid.shape[0] < 2 or not grid[0] == 0.0 or not grid[-1] >= n - 1.0
            or not h0 > 0.0 or not dt > 0.0 or needs_full_kernel(c) or has_kinks(c)
            or not (cfg == CFG_UPPER or cfg == CFG_COUPLED)):  # fmt: skip
        return BAD_PARAMETERS
    for a in range(k):
        if idx[a] < 0 or idx[a] >= N_PARAMS:
            return BAD_PARAMETERS
    # The most samples a segment holds: a step of the grid (or of the held start).
    cap = h0
    for j in range(1, grid.shape[0]):
        cap = max(cap, grid[j] - grid[j - 1])
    X = np.empty((6, min(int(cap) + 2, n)))
    JT = J.T
    rows = Wt.shape[1] > 0
    nq = min(int(cap) + 2, n) + 1
    Qc = np.empty((nq, _HERMITE, nq))  # with rows Q's factors, without them X's weights
    Rc = np.empty((nq, _HERMITE, _HERMITE))
    known = np.zeros(nq, dtype=np.int8)
    Vs = np.empty((_HERMITE, k))
    q = np.empty(0)
    m = (c, cfg, shape, p, q, False, None, None, None)
    last = n - 1.0
    inv_dt = 1.0 / dt
    dly = delay_samples(c, cfg)
    n_hold = int(math.floor(dly / h0))
    jj = 0 if dly - n_hold * h0 > 1e-9 else 1
    src = u
    pu = np.zeros(N_PARAMS)
    pl = np.zeros(N_PARAMS)
    S = np.zeros((4, k))
    S1 = np.zeros((4, k))
    Sev = np.zeros((4, k))
    dF = np.zeros((4, k))
    dFe = np.zeros((4, k))
    K = np.zeros((k, 4, 4))
    gp = np.zeros(k)
    P = np.zeros((2, k))
    y = (0.0, 0.0, 0.0, 0.0)
    d1 = drive(0.0, c, cfg, src, None)
    mu, ml = modes_at_rest(y[0], y[1], y[2], y[3], 0.0, d1, m)
    f = _rhs_d(y[0], y[1], y[2], y[3], mu, ml, d1, c, cfg, shape, idx, tsf, S, dF, pu, pl,
              P)  # fmt: skip
    status = OK
    # The first sample's rows of J are zero (the start is fixed): in the reduced rows
    # their residual is part of what the caller adds.
    if col_u >= 0:
        r[0, col_u] = w_u * (meas_u[0] - y[0])
        for a in range(k):
            if not rows:
                JT[jcol[a], col_u] = 0.0
    if col_l >= 0:
        r[0, col_l] = w_l * (meas_l[0] - y[2])
        for a in range(k):
            if not rows:
                JT[jcol[a], col_l] = 0.0
    kout = 1
    t_end = 0.0
    s_end = 0.0
    while s_end < last:
        t = t_end
        if jj <= n_hold:
            s_end = min(dly - (n_hold - jj) * h0, last)
        else:
            s_end = min(dly + grid[jj - n_hold], last)
        jj += 1
        t_end = s_end * dt
        n_step_ev = 0
        while True:
            t_tgt = t_end
            t_sub = t + min(stribeck_step(y[1], f[1], mu, y[3], f[3], ml, c, cfg, None),
                            approach_step(y[1], f[1], mu, y[3], f[3], ml, c, cfg,
                                          t_tgt - t))  # fmt: skip
            if t_sub < t_tgt:
                t_tgt = t_sub
            rem = t_tgt - t
            y1, d1 = _rk5_sens(t, rem, y, mu, ml, f, dF, S, S1, K, c, cfg, shape, src, idx,
                               tsf, pu, pl, P)  # fmt: skip
            gu1, gl1 = guards(y1[0], y1[1], y1[2], y1[3], 0.0, mu, ml, d1, m)
            seg = rem
            ok_step = gu1 >= 0.0 and gl1 >= 0.0
            disc = -1
            de = d1
            if not ok_step:
                d0 = drive(t, c, cfg, src, None)
                gu0, gl0 = guards(y[0], y[1], y[2], y[3], 0.0, mu, ml, d0, m)
                f1 = _rhs_d(y1[0], y1[1], y1[2], y1[3], mu, ml, d1, c, cfg, shape, idx, tsf,
                            S1, dFe, pu, pl, P)  # fmt: skip
                y5 = (y[0], y[1], y[2], y[3], 0.0)
                y15 = (y1[0], y1[1], y1[2], y1[3], 0.0)
                f5 = (f[0], f[1], f[2], f[3], 0.0)
                f15 = (f1[0], f1[1], f1[2], f1[3], 0.0)
                y_ev, d_ev = y15, d1
                for dsc in range(2):
                    g1 = gu1 if dsc == 0 else gl1
                    if g1 < 0.0:
                        g0 = gu0 if dsc == 0 else gl0
                        tl, yl, dl = _locate(t, rem, max(g0, 0.0), g1, dsc, y5, mu, ml, f5,
                                             y15, d1, f15, m, src)  # fmt: skip
                        if disc < 0 or tl < seg:
                            seg = tl
                            disc = dsc
                            y_ev, d_ev = yl, dl
                # The sensitivities at the event: the step of the located length again.
                y1, de = _rk5_sens(t, seg, y, mu, ml, f, dF, S, S1, K, c, cfg, shape, src,
                                   idx, tsf, pu, pl, P)  # fmt: skip
                y1 = (y_ev[0], y_ev[1], y_ev[2], y_ev[3])
                de = d_ev
            fe = _rhs_d(y1[0], y1[1], y1[2], y1[3], mu, ml, de, c, cfg, shape, idx, tsf, S1,
                        dFe, pu, pl, P)  # fmt: skip
            t_seg = t + seg
            lim = t_seg + 1e-9 * dt
            if kout < n and kout * dt <= lim:
                k1 = _last_sample(kout, lim, dt, inv_dt, n)
                if rows:
                    _write_rows(kout, k1, t, seg, dt, y, f, y1, fe, S, dF, S1, dFe, meas_u,
                                meas_l, w_u, w_l, r, Wt, info, jcol, col_u, col_l, X, Qc,
                                Rc, known, Vs)  # fmt: skip
                else:
                    _write_samples(kout, k1, t, seg, dt, y, f, y1, fe, S, dF, S1, dFe,
                                   meas_u, meas_l, w_u, w_l, r, JT, jcol, col_u, col_l,
                                   X, Qc, known)  # fmt: skip
                kout = k1 + 1
            y = y1
            f = fe
            S, S1 = S1, S
            dF, dFe = dFe, dF
            t = t_seg
            if ok_step:
                if t_tgt >= t_end:
                    break
                continue
            # The event: the disc whose guard fired is at zero velocity now.
            old = mu if disc == 0 else ml
            gx0, gx1, gx2, gx3, gdot = _guard_grad(disc, old, y, f, de, c, cfg, src, idx,
                                                   tsf, gp)  # fmt: skip
            if disc == 0:
                y = (y[0], 0.0, y[2], y[3])
            else:
                y = (y[0], y[1], y[2], 0.0)
            new_u, new_l = modes_at_rest(y[0], y[1], y[2], y[3], 0.0, de, m)
            if disc == 0:
                mu = new_u
                new = mu
            else:
                ml = new_l
                new = ml
            fm = f
            for rr in range(4):  # (a slice assignment compiled its shape-error message: 3 s)
                for a in range(k):
                    Sev[rr, a] = S[rr, a]
            f = _rhs_d(y[0], y[1], y[2], y[3], mu, ml, de, c, cfg, shape, idx, tsf, Sev, dF,
                       pu, pl, P)  # fmt: skip
            # S+ = S- + (f- - f+) dtau/dp,  dtau/dp = -(g_x S- + g_p) / (g_x f- + g_t).
            if gdot != 0.0:
                for a in range(k):
                    num = gx0 * S[0, a] + gx1 * S[1, a] + gx2 * S[2, a] + gx3 * S[3, a] + gp[a]
                    dtau = -num / gdot
                    S[0, a] += (fm[0] - f[0]) * dtau
                    S[1, a] += (fm[1] - f[1]) * dtau
                    S[2, a] += (fm[2] - f[2]) * dtau
                    S[3, a] += (fm[3] - f[3]) * dtau
            if new == 0:  # a sticking disc's velocity is held: so is its sensitivity
                wr = 1 if disc == 0 else 3
                for a in range(k):
                    S[wr, a] = 0.0
            f = _rhs_d(y[0], y[1], y[2], y[3], mu, ml, de, c, cfg, shape, idx, tsf, S, dF,
                       pu, pl, P)  # fmt: skip
            n_step_ev += 1
            if n_step_ev > _MAX_EVENTS_PER_STEP:
                status = TOO_MANY_EVENTS
                break
            if t_end - t <= 1e-12 * dt:
                break
        if status == OK and not (
            abs(y[1]) < _VMAX and abs(y[3]) < _VMAX and math.isfinite(y[0])
            and math.isfinite(y[2])
        ):  # fmt: skip
            status = BLOW_UP
        if status != OK:
            break
    return status

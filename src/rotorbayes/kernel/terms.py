"""The rig's terms for the compiled solver: torques, friction, static bands and guards.

Everything the solver (:mod:`rotorbayes.kernel.solver`) needs to know about the physics
is here, as small numba functions (compiled apart, inlined by LLVM) of the state
``(theta_u, omega_u, theta_l, omega_l)``, the modes of the discs and the *drive*
``d = (t, v, theta_p, omega_p)`` (time, effective motor voltage, prescribed upper-disc
motion).  The solver itself only knows how to integrate, locate events and interpolate.

Effects plug in at three places:

* the **input** (:func:`drive`): delay, offset and dead zone of the motor voltage.  Their
  kinks are reported by :func:`next_kink` so the solver can end a step on them;
* the **torques** (:func:`torques`): the string (stiffness, pre-torsion ``alpha0``,
  damping) and, for user-defined effects, an extra torque on either disc;
* the **friction levels**: user-defined effects may shift a disc's Coulomb and static
  levels together, which moves the static band as well.

The model vector ``m = (c, cfg, shape, p, q, use_hooks, torque_hook, shift_hook)``
bundles the derived constants, configuration code, Stribeck shape, the raw parameter
vectors of the built-in model (``p``) and of the user effects (``q``) and the two hooks.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, types
from numba.extending import overload

from .friction import negligible_x, slip_torque
from .layout import (
    ALPHA0,
    B_L,
    B_U,
    C_ALPHA,
    CFG_PRESCRIBED,
    CFG_UPPER,
    DB_L,
    DB_U,
    DELTA_L,
    DELTA_U,
    DTC_L,
    DTC_U,
    DTS_U,
    J_L,
    J_U,
    K_ALPHA,
    K_M,
    N_PARAMS,
    T_DELAY,
    TAU_DRIVE,
    TC_L,
    TC_U,
    TS_L,
    U_DEADZONE,
    U_OFFSET,
    WS_L,
    WS_U,
)  # fmt: skip
from .numerics import fma

# ------------------------------------------------------------------------------- hooks
#: Signature of a hook of the user effects: ``(t, theta_u, omega_u, theta_l, omega_l, v,
#: z, p, q)`` -> ``(upper, lower)`` [N m] (the torque and friction-shift hooks), or
#: ``(dz/dt, 0)`` (the state-rate hook).  ``z`` is the effect state (0 without a stateful
#: effect), ``p`` the built-in parameter vector (positions in
#: :mod:`rotorbayes.kernel.layout`), ``q`` the effects' own parameters.  A user's
#: stateless functions take no ``z``: :mod:`rotorbayes.model.configurations` wraps them.
HOOK_SIGNATURE = types.UniTuple(types.float64, 2)(
    types.float64, types.float64, types.float64, types.float64, types.float64,
    types.float64, types.float64, types.float64[::1], types.float64[::1],
)  # fmt: skip
HOOK_TYPE = types.FunctionType(HOOK_SIGNATURE)


@njit(HOOK_SIGNATURE, cache=True)
def null_hook(t, thu, wu, thl, wl, v, z, p, q):
    """The hook of a model without user-defined effects: nothing on either disc."""
    return 0.0, 0.0


def call_hook(hook, t, thu, wu, thl, wl, v, z, p, q):
    """``hook(t, ...)``, or ``(0.0, 0.0)`` when ``hook`` is ``None`` (compiled code only)."""
    if hook is None:
        return 0.0, 0.0
    return hook(t, thu, wu, thl, wl, v, z, p, q)


@overload(call_hook, inline="always")
def _call_hook_impl(hook, t, thu, wu, thl, wl, v, z, p, q):
    # Chosen when the kernel is typed: a model without user effects passes None for its
    # hooks and gets no function values at all (a function argument costs about 0.1 ms per
    # call from Python to type and unbox, and a function constant cannot be cached).
    if isinstance(hook, (types.NoneType, types.Integer)):  # plain or full without hooks
        return lambda hook, t, thu, wu, thl, wl, v, z, p, q: (0.0, 0.0)
    return lambda hook, t, thu, wu, thl, wl, v, z, p, q: hook(t, thu, wu, thl, wl, v, z, p, q)


def hook_array(hook, a):
    """``a`` (a parameter vector) in the kernel with hooks, ``None`` in the plain and the
    full one, where only hooks read it (compiled code only; see the overload)."""
    return a


@overload(hook_array, inline="always")
def _hook_array_impl(hook, a):
    # The model tuple is passed to every term the solver calls; without arrays in it there
    # is nothing to reference-count at those calls.
    if isinstance(hook, (types.NoneType, types.Integer)):
        return lambda hook, a: None
    return lambda hook, a: a


# ------------------------------------------------------------------------ validity
#: The constraints a parameter vector must meet, in the order of :func:`violations`:
#: ``(parameters involved, what must hold, configurations it applies to)``.  The kernel
#: refuses a vector that breaks one; :func:`rotorbayes.model.configurations.problems`
#: turns the same flags into sentences.  One list, so Python and the kernel agree.
CONSTRAINTS: tuple[tuple[tuple[str, ...], str, str], ...] = (
    (("*",), "every parameter must be a finite number", "all"),
    (("J_u",), "J_u must be > 0", "motor"),
    (("Tc_u", "dTc_u"), "Tc_u must be >= |dTc_u| (friction may not push along the motion)",
     "motor"),
    (("b_u", "db_u"), "b_u must be >= |db_u|", "motor"),
    (("J_l",), "J_l must be > 0", "lower"),
    (("k_alpha",), "k_alpha must be >= 0", "lower"),
    (("c_alpha",), "c_alpha must be >= 0", "lower"),
    (("Tc_l", "dTc_l"), "Tc_l must be >= |dTc_l| (friction may not push along the motion)",
     "lower"),
    (("Ts_l", "dTc_l"), "Ts_l must be >= |dTc_l|", "lower"),
    (("b_l", "db_l"), "b_l must be >= |db_l|", "lower"),
    (("ws_l",), "ws_l must be > 0", "lower"),
    (("delta_l",), "delta_l must be > 0", "lower"),
    (("t_delay",), "t_delay must be >= 0 (the motor cannot act before it is commanded)",
     "motor"),
    (("u_deadzone",), "u_deadzone must be >= 0", "motor"),
    (("dTs_u",), "dTs_u must be >= 0 (static friction at least the Coulomb level)", "motor"),
    (("ws_u",), "ws_u must be > 0", "motor"),
    (("delta_u",), "delta_u must be > 0", "motor"),
    (("tau_drive",), "tau_drive must be >= 0", "motor"),
)  # fmt: skip
N_CONSTRAINTS = len(CONSTRAINTS)


@njit(cache=True)
def violations(p, cfg):
    """Flags (1 = broken) of the :data:`CONSTRAINTS` for parameter vector ``p``.

    ``motor`` constraints apply when the motor drives the upper disc (not with a
    prescribed upper-disc motion), ``lower`` ones when the lower disc is present.
    """
    bad = np.zeros(N_CONSTRAINTS, dtype=np.int8)
    for i in range(p.shape[0]):
        if not math.isfinite(p[i]):
            bad[0] = 1
    motor = cfg != CFG_PRESCRIBED
    lower = cfg != CFG_UPPER
    if motor:
        bad[1] = p[J_U] <= 0.0
        bad[2] = p[TC_U] < abs(p[DTC_U])
        bad[3] = p[B_U] < abs(p[DB_U])
        bad[12] = p[T_DELAY] < 0.0
        bad[13] = p[U_DEADZONE] < 0.0
        bad[14] = p[DTS_U] < 0.0
        bad[15] = p[WS_U] <= 0.0
        bad[16] = p[DELTA_U] <= 0.0
        bad[17] = p[TAU_DRIVE] < 0.0
    if lower:
        bad[4] = p[J_L] <= 0.0
        bad[5] = p[K_ALPHA] < 0.0
        bad[6] = p[C_ALPHA] < 0.0
        bad[7] = p[TC_L] < abs(p[DTC_L])
        bad[8] = p[TS_L] < abs(p[DTC_L])
        bad[9] = p[B_L] < abs(p[DB_L])
        bad[10] = p[WS_L] <= 0.0
        bad[11] = p[DELTA_L] <= 0.0
    return bad


# ------------------------------------------------------------------ derived constants
_KM, _IJU, _TCU, _DTCU, _BU, _DBU, _IJL, _KA, _TCL, _DTCL, _BL, _DBL = range(12)
_DSL, _IWSL, _DL, _A0, _CA, _UOFF, _TDEL, _UDZ, _TSL, _IDT, _DT, _XCUT = range(12, 24)
_DSU, _IWSU, _DU, _XCUTU, _TAU, _ITAU = range(24, 30)
_ND = 30


@njit(cache=True, error_model="numpy")
def derived(p, dt):
    """Constants used in the inner loop (a tuple indexed by the ``_KM`` ... ``_DT`` positions
    above), from the parameter vector ``p`` and the sample interval ``dt``."""
    c = np.zeros(_ND)
    c[_KM] = p[K_M]
    c[_IJU] = 1.0 / p[J_U] if p[J_U] > 0.0 else 0.0
    c[_TCU], c[_DTCU], c[_BU], c[_DBU] = p[TC_U], p[DTC_U], p[B_U], p[DB_U]
    c[_IJL] = 1.0 / p[J_L] if p[J_L] > 0.0 else 0.0
    c[_KA], c[_TCL], c[_DTCL], c[_BL], c[_DBL] = p[K_ALPHA], p[TC_L], p[DTC_L], p[B_L], p[DB_L]
    c[_TSL] = p[TS_L]
    c[_DSL] = p[TS_L] - p[TC_L]
    c[_IWSL] = 1.0 / p[WS_L] if p[WS_L] > 0.0 else 0.0
    c[_DL], c[_A0], c[_CA] = p[DELTA_L], p[ALPHA0], p[C_ALPHA]
    c[_UOFF], c[_TDEL], c[_UDZ] = p[U_OFFSET], p[T_DELAY], p[U_DEADZONE]
    c[_IDT] = 1.0 / dt if dt > 0.0 else 0.0
    c[_DT] = dt
    c[_XCUT] = negligible_x(p[DELTA_L])
    c[_DSU] = p[DTS_U]
    c[_IWSU] = 1.0 / p[WS_U] if p[WS_U] > 0.0 else 0.0
    c[_DU] = p[DELTA_U]
    c[_XCUTU] = negligible_x(p[DELTA_U])
    c[_TAU] = p[TAU_DRIVE]
    c[_ITAU] = 1.0 / p[TAU_DRIVE] if p[TAU_DRIVE] > 0.0 else 0.0
    # A tuple, not an array: the inner loop passes the constants through every inlined
    # term, and an array would be reference-counted (atomic increments and decrements)
    # at each pass -- measured at 30 % of the kernel's time.
    return (
        c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7], c[8], c[9], c[10], c[11], c[12],
        c[13], c[14], c[15], c[16], c[17], c[18], c[19], c[20], c[21], c[22], c[23],
        c[24], c[25], c[26], c[27], c[28], c[29],
    )  # fmt: skip


# ----------------------------------------------------------------------------- input
@njit(cache=True, error_model="numpy")
def interp(t, y, inv_dt):
    """Linear interpolation of samples ``y`` (spacing ``1/inv_dt``, start 0) and its slope.

    Before the first sample the value is held at ``y[0]`` (a file says nothing about the
    input before t = 0), after the last at ``y[-1]``.
    """
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
    return fma(x - i, dy, y[i]), dy * inv_dt


@njit(cache=True, error_model="numpy", inline="always")
def lagged(s, src, c):
    """The command through the drive's first-order lag ``tau_drive`` at time ``s`` [s]
    (before the delay): ``x' = (u(s) - x) / tau``, ``x = u[0]`` up to ``s = 0`` (at rest
    before).  ``src`` is :func:`input_source`'s array: the samples ``u`` (``n`` of them)
    and then ``x`` at the sample times.  Exact for the linearly interpolated input: on a
    sample interval with slope ``g`` the lag's solution is ``u_i + g (r - tau) + (x_i -
    u_i + g tau) exp(-r / tau)``, ``r`` the time since sample ``i``; after the last
    sample ``u`` is held.  It tends to the input as ``tau -> 0``."""
    n = src.shape[0] // 2
    dt = c[_DT]
    x = s * c[_IDT]
    if x <= 0.0:
        return src[0]
    i = int(x)
    if i >= n - 1:
        r = s - (n - 1) * dt
        ul = src[n - 1]
        return fma(src[2 * n - 1] - ul, math.exp(-r * c[_ITAU]), ul)
    r = s - i * dt
    ui = src[i]
    g = (src[i + 1] - ui) * c[_IDT]
    tau = c[_TAU]
    return fma(fma(g, tau, src[n + i] - ui), math.exp(-r * c[_ITAU]), fma(g, r - tau, ui))


@njit(cache=True, error_model="numpy")
def input_source(c, cfg, u, thp):
    """The array :func:`drive` reads: the prescribed upper-disc angle ``thp`` for
    :data:`CFG_PRESCRIBED` (the voltage is not read then); with a drive lag (``tau_drive >
    0``) the samples ``u`` followed by the lagged command at the sample times (see
    :func:`lagged`; computed once per run by the lag's exact recurrence); else ``u``."""
    if cfg == CFG_PRESCRIBED:
        return thp
    if c[_TAU] <= 0.0:
        return u
    n = u.shape[0]
    out = np.empty(2 * n)
    for i in range(n):
        out[i] = u[i]
    tau = c[_TAU]
    e = math.exp(-c[_DT] * c[_ITAU])
    x = u[0]
    out[n] = x
    for i in range(n - 1):
        g = (u[i + 1] - u[i]) * c[_IDT]
        x = fma(fma(g, tau, x - u[i]), e, u[i + 1] - g * tau)
        out[n + i + 1] = x
    return out


@njit(cache=True, error_model="numpy")
def delay_samples(c, cfg):
    """The input delay in samples, ``t_delay / dt``: the solver's step grid is the input's
    grid shifted by it, so that the delayed sample times and the end of the held start,
    ``t = t_delay`` (before it the delayed input is held at ``u[0]``), are step points.
    The input's kinks then sit on step points whatever the delay, as the samples do
    without one, and the grid moves continuously with the delay.  0 without a delay and
    for a prescribed upper-disc motion (which is not delayed).
    """
    d = c[_TDEL]
    if d <= 0.0 or cfg == CFG_PRESCRIBED:
        return 0.0
    return d * c[_IDT]


@njit(cache=True, error_model="numpy")
def next_kink(t, t1, c, u):
    """The first time in ``(t, t1)`` at which the effective voltage has a slope jump that
    falls inside a Runge-Kutta step, or ``t1`` if there is none: where the offset, delayed
    input crosses ``±u_deadzone``.  ``u`` is :func:`input_source`'s array.  (The delayed
    sample times and the end of the held start are step points already, see
    :func:`delay_samples`.)

    Kinks closer than ``1e-9`` samples to either end are ignored, so the result moves
    continuously with the parameters: a kink that reaches a step boundary leaves a segment
    of zero length, which is no segment at all.
    """
    if c[_TAU] > 0.0:
        return _next_kink_lagged(t, t1, c, u)
    return _next_kink_linear(t, t1, c, u)


@njit(cache=True, error_model="numpy")
def _next_kink_linear(t, t1, c, u):
    """:func:`next_kink` without a drive lag (the input linear between samples)."""
    dt = c[_DT]
    d = c[_TDEL]
    dz = c[_UDZ]
    n = u.shape[0]
    tiny = 1e-9 * dt
    best = t1
    if dz > 0.0:
        off = c[_UOFF]
        s0 = (t - d) / dt
        s1 = (best - d) / dt
        if s1 > 0.0 and s0 < n - 1.0:
            a = max(s0, 0.0)
            while a < s1 and a < n - 1.0:
                i = int(math.floor(a))
                if i > n - 2:
                    i = n - 2
                b = min(float(i + 1), s1)
                wa = u[i] + (a - i) * (u[i + 1] - u[i]) + off
                wb = u[i] + (b - i) * (u[i + 1] - u[i]) + off
                hit = 2.0
                for lev in (dz, -dz):
                    if (wa - lev) * (wb - lev) < 0.0:
                        fr = (lev - wa) / (wb - wa)
                        if fr < hit:
                            hit = fr
                if hit <= 1.0:
                    tk = d + (a + hit * (b - a)) * dt
                    if t + tiny < tk < best - tiny:
                        return tk
                a = b
    return best


@njit(cache=True, error_model="numpy")
def _next_kink_lagged(t, t1, c, src):
    """:func:`next_kink` with a drive lag: the lagged command is not linear between
    samples, so each sample interval whose ends lie on both sides of a dead-zone edge
    has its crossing found by Illinois regula falsi (to 1e-13 of the interval) on
    :func:`lagged` itself.  A crossing and a return within one sample interval are not
    seen (the lag is smooth there; the step's error stays that of a smooth kink)."""
    dt = c[_DT]
    d = c[_TDEL]
    dz = c[_UDZ]
    off = c[_UOFF]
    n = src.shape[0] // 2
    tiny = 1e-9 * dt
    best = t1
    a = max(t - d, 0.0)
    s1 = best - d
    while a < s1:
        i = int(math.floor(a * c[_IDT]))
        b = min((i + 1) * dt, s1) if i < n - 1 else s1
        if b <= a:
            b = min(a + dt, s1)
        wa = lagged(a, src, c) + off
        wb = lagged(b, src, c) + off
        hit = math.inf
        for lev in (dz, -dz):
            fa = wa - lev
            fb = wb - lev
            if fa * fb < 0.0:
                lo, hi, flo, fhi = a, b, fa, fb
                side = 0
                for _ in range(200):
                    if hi - lo <= 1e-13 * dt:
                        break
                    m = hi - fhi * (hi - lo) / (fhi - flo)
                    if not (lo < m < hi):
                        m = 0.5 * (lo + hi)
                    fm = lagged(m, src, c) + off - lev
                    if fm * flo < 0.0:
                        hi, fhi = m, fm
                        if side == -1:
                            flo *= 0.5
                        side = -1
                    else:
                        lo, flo = m, fm
                        if side == 1:
                            fhi *= 0.5
                        side = 1
                hit = min(hit, 0.5 * (lo + hi))
        if hit < math.inf:
            tk = d + hit
            if t + tiny < tk < best - tiny:
                return tk
        a = b
    return best


def kink_in_step(hook, t, t1, c, src):
    """:func:`next_kink` as the kernel built for ``hook`` needs it (compiled code only; see
    the overload): the plain kernel has no drive lag (it refuses one), so only the linear
    search is compiled into it."""
    return next_kink(t, t1, c, src)


@overload(kink_in_step, inline="always")
def _kink_in_step_impl(hook, t, t1, c, src):
    if isinstance(hook, types.NoneType):
        return lambda hook, t, t1, c, src: _next_kink_linear(t, t1, c, src)
    return lambda hook, t, t1, c, src: next_kink(t, t1, c, src)


@njit(cache=True, error_model="numpy")
def has_kinks(c):
    """Whether :func:`next_kink` can find anything for these constants."""
    return c[_UDZ] > 0.0


@njit(cache=True, error_model="numpy")
def prescribed_velocity(t, c, thp):
    """Velocity [rad/s] of the prescribed upper-disc motion at ``t``."""
    return interp(t, thp, c[_IDT])[1]


# Inlined by numba (a small function).  Compiled apart, LLVM kept it a call, and every call
# took and released references to the input arrays (atomic operations, twice per step: a
# tenth of a 30 s brake residual).  It reads one array, with no branch before the read, so
# that numba's reference-count pruning removes the pair inside the solver's loop.
@njit(cache=True, error_model="numpy", inline="always")
def drive(t, c, cfg, src, hook):
    """What drives the system at ``t``: ``(t, voltage, upper angle, upper velocity)``.

    ``c`` and ``cfg`` are the constants and the configuration, ``hook`` the model's torque
    hook (``None`` in the plain kernel; not the model tuple, whose arrays would be
    reference-counted at every call); ``src`` the input voltage ``u`` (samples), or for
    :data:`CFG_PRESCRIBED` the prescribed upper-disc angle, or with a drive lag the
    samples and the lagged command (see :func:`input_source`).  Evaluated once per
    Runge-Kutta stage time, so the right-hand side works on scalars only.  The command
    passes the drive's lag ``tau_drive`` (:func:`lagged`; only in the full kernel, see
    :func:`lag_of`), is delayed by ``t_delay`` (held at ``u[0]`` before the first
    sample), offset by ``u_offset``, then through the dead zone ``±u_deadzone``.
    """
    presc = cfg == CFG_PRESCRIBED
    a, da = interp(t if presc else t - c[_TDEL], src, c[_IDT])
    if presc:
        return t, 0.0, a, da
    a = lag_of(hook, t - c[_TDEL], src, c, a)
    return t, dead_zone(a + c[_UOFF], c[_UDZ]), 0.0, 0.0


@njit(cache=True, error_model="numpy", inline="always")
def dead_zone(v, dz):
    """``v`` through the dead zone ``±dz`` (nothing for ``dz = 0``)."""
    if dz > 0.0:
        if v > dz:
            return v - dz
        if v < -dz:
            return v + dz
        return 0.0
    return v


def lag_of(hook, s, src, c, a):
    """The command ``a`` at time ``s``, through the drive's lag where the kernel is the
    full one (compiled code only; see the overload)."""
    return a


# The plain and the full kernel.  Physics whose code would slow every step of every run
# -- the drive's lag (an exponential at each stage), the upper disc's Stribeck curve (a
# branch and the curve in every right-hand side, a third static level, a substep rule)
# -- exists only in the *full* kernel: the one built with hook functions (user effects)
# or with the marker FULL instead of them (model.configurations decides which a model
# needs, from Effect.full_kernel).  The plain kernel (hooks None) has none of their code:
# with runtime switches instead, a 30 s brake residual without either effect took 6-8 %
# longer (0.158 -> 0.169 ms).  The full kernel without user hooks is compiled on first
# use (solver's *_full entry points), so a command that needs neither never compiles it.
#: The hooks' stand-in in the full kernel without user effects.
FULL = 0


@overload(lag_of, inline="always")
def _lag_of_impl(hook, s, src, c, a):
    if isinstance(hook, types.NoneType):
        return lambda hook, s, src, c, a: a

    # A lambda around a compiled function: an inlined overload with branches of its own
    # made numba warn (NumbaIRAssumptionWarning) in every kernel with hooks.
    return lambda hook, s, src, c, a: _lagged_or(s, src, c, a)


@njit(cache=True, error_model="numpy")
def _lagged_or(s, src, c, a):
    """The lagged command at ``s`` with a drive lag, else ``a``."""
    if c[_TAU] > 0.0:
        return lagged(s, src, c)
    return a


def state_fma(hook, a, b, z):
    """``a * b + z`` for the effect state ``z`` in the kernel with hooks, ``z`` itself in
    the plain one (compiled code only; see the overload)."""
    return a * b + z


# The effect state z is carried by every step (terms.rhs gives its rate); in the plain
# kernel its update is z itself, so z stays the constant 0 it starts at and the compiler
# drops every operation on it.  (Updated by fused multiply-adds there as well, z cost a
# 30 s brake residual 1.5 % and a zero-input one 6 %.)
@overload(state_fma, inline="always")
def _state_fma_impl(hook, a, b, z):
    if isinstance(hook, types.NoneType):
        return lambda hook, a, b, z: z
    return lambda hook, a, b, z: fma(a, b, z)


def state_value(hook, z):
    """``z`` in the kernel with hooks, the constant 0 in the plain one (compiled code
    only): for a state that comes back from a function the compiler cannot see into."""
    return z


@overload(state_value, inline="always")
def _state_value_impl(hook, z):
    if isinstance(hook, types.NoneType):
        return lambda hook, z: 0.0
    return lambda hook, z: z


#: State substeps (see :func:`state_step`): a step is at most this multiple of the effect
#: state's time constant, ``1 / |d(dz/dt)/dz|``, and of the period (over 2 pi) of the loop
#: between the state and a disc's velocity, at the step's start and its predicted end ...
STATE_STEP_FACTOR = 1.0
#: ... and never below this fraction of a sample: a state faster than that is not
#: followed (it blows up, and the run stops with BAD_EFFECT or BLOW_UP).  A LuGre
#: bristle at sigma0_l = 2000 N m/rad sliding at 15 rad/s on a 0.016 N m level relaxes in
#: 0.5 us, a ten-thousandth of a 200 Hz sample.
STATE_STEP_MIN = 1e-4


def state_step(hook, reset, t, t_end, y, f, src, m):
    """The end of a step from ``t`` that ends at ``t_end`` or earlier as the effect state
    needs (compiled code only; see the overload): ``t_end`` without a stateful effect
    (``reset`` below -1) and in the plain kernel.  ``f``: the right-hand side at ``t``."""
    return t_end


@overload(state_step, inline="always")
def _state_step_impl(hook, reset, t, t_end, y, f, src, m):
    if isinstance(hook, (types.NoneType, types.Integer)):
        return lambda hook, reset, t, t_end, y, f, src, m: t_end

    return lambda hook, reset, t, t_end, y, f, src, m: _state_limit(
        hook, reset, t, t_end, y, f, src, m
    )


@njit(cache=True, error_model="numpy")
def _state_slope(hook, t, y, src, m):
    """How fast the effect state's part of the dynamics moves [1/s] at time ``t`` and state
    ``y``: the rate's slope in ``z`` plus, where ``z`` acts on a disc (a torque or a
    friction level that depends on it) and the disc's velocity drives ``z``, the frequency
    of that loop, ``sqrt(|d(dw/dt)/dz * d(dz/dt)/dw|)`` (a bristle deflection is a spring on
    the disc while it barely moves).  Forward differences, with the hooks."""
    c, cfg = m[0], m[1]
    d = drive(t, c, cfg, src, m[6])
    presc = cfg == CFG_PRESCRIBED
    thu = d[2] if presc else y[0]
    wu = d[3] if presc else y[1]
    thl, wl, z = y[2], y[3], y[4]
    v, p, q = d[1], m[3], m[4]
    e = 1e-7 * (abs(z) + 1e-3)
    r0 = hook(t, thu, wu, thl, wl, v, z, p, q)[0]
    r1 = hook(t, thu, wu, thl, wl, v, z + e, p, q)[0]
    lam = abs(r1 - r0) / e
    a0u, a0l = m[6](t, thu, wu, thl, wl, v, z, p, q)
    a1u, a1l = m[6](t, thu, wu, thl, wl, v, z + e, p, q)
    s0u, s0l = m[7](t, thu, wu, thl, wl, v, z, p, q)
    s1u, s1l = m[7](t, thu, wu, thl, wl, v, z + e, p, q)
    if cfg != CFG_UPPER:  # the lower disc's loop through z
        ew = 1e-7 * (abs(wl) + 1e-3)
        dzw = (hook(t, thu, wu, thl, wl + ew, v, z, p, q)[0] - r0) / ew
        dwz = (abs(a1l - a0l) + abs(s1l - s0l)) / e * c[_IJL]
        lam += math.sqrt(abs(dzw) * dwz)
    if not presc:  # the upper disc's
        ew = 1e-7 * (abs(wu) + 1e-3)
        dzw = (hook(t, thu, wu + ew, thl, wl, v, z, p, q)[0] - r0) / ew
        dwz = (abs(a1u - a0u) + abs(s1u - s0u)) / e * c[_IJU]
        lam += math.sqrt(abs(dzw) * dwz)
    return lam


@njit(cache=True, error_model="numpy")
def _state_limit(hook, reset, t, t_end, y, f, src, m):
    """:func:`state_step` in the kernel with hooks: an explicit Runge-Kutta step follows a
    state of time constant tau accurately only for steps of about tau -- the rate's slope
    in z, at the step's start and at its end as the rig's present rates predict it (a
    state whose time constant shortens as a disc speeds up, such as a bristle deflection
    after break-away, must not be stepped over by a step chosen at rest)."""
    if reset < -1:  # no effect has a state
        return t_end
    lam = _state_slope(hook, t, y, src, m)
    h = t_end - t
    if lam * h > STATE_STEP_FACTOR:
        h = STATE_STEP_FACTOR / lam
    for _ in range(3):  # the slope where this step would end (z held: it is what is fast)
        ye = (fma(h, f[0], y[0]), fma(h, f[1], y[1]), fma(h, f[2], y[2]), fma(h, f[3], y[3]), y[4])
        lam_e = _state_slope(hook, t + h, ye, src, m)
        if not lam_e * h > STATE_STEP_FACTOR:
            break
        h = STATE_STEP_FACTOR / lam_e
    return min(t_end, t + max(h, STATE_STEP_MIN * m[0][_DT]))


def upper_excess(hook, c):
    """The upper disc's static excess ``dTs_u`` in the full kernel, 0 in the plain one
    (compiled code only; see the overload)."""
    return 0.0


@overload(upper_excess, inline="always")
def _upper_excess_impl(hook, c):
    if isinstance(hook, types.NoneType):
        return lambda hook, c: 0.0
    return lambda hook, c: c[_DSU]


@njit(cache=True, error_model="numpy")
def needs_full_kernel(c):
    """Whether these constants switch on physics only the full kernel has (the drive's
    lag, the upper disc's Stribeck curve)."""
    return c[_TAU] > 0.0 or c[_DSU] != 0.0


def is_full_kernel(hook):
    """Whether the kernel built for ``hook`` is the full one (compiled code only)."""
    return hook is not None


@overload(is_full_kernel, inline="always")
def _is_full_kernel_impl(hook):
    if isinstance(hook, types.NoneType):
        return lambda hook: False
    return lambda hook: True


@njit(cache=True, error_model="numpy")
def voltage_at(times, u, p, dt, cfg):
    """The effective motor voltage [V] at ``times`` [s] as the solver sees it (lag, delay,
    offset, dead zone) -- for the diagnosis's torque balance."""
    c = derived(p, dt)
    src = input_source(c, cfg, u, u)
    out = np.empty(times.shape[0])
    for k in range(times.shape[0]):
        s = times[k] - c[_TDEL]
        a = lagged(s, src, c) if c[_TAU] > 0.0 else interp(s, src, c[_IDT])[0]
        out[k] = dead_zone(a + c[_UOFF], c[_UDZ])
    return out


# ------------------------------------------------------------------------ torques
@njit(cache=True, error_model="numpy")
def torques(thu, wu, thl, wl, z, d, m):
    """External torques on both discs and the user effects' friction-level shifts [N m];
    ``z`` is the effect state."""
    c = m[0]
    cfg = m[1]
    t, v, thp, wp = d
    if cfg == CFG_PRESCRIBED:
        thu = thp
        wu = wp
    ts = 0.0
    if cfg != CFG_UPPER:
        ts = fma(c[_KA], thl - thu + c[_A0], c[_CA] * (wl - wu))
    te_u = fma(c[_KM], v, ts)
    te_l = -ts
    su = 0.0
    sl = 0.0
    if m[5]:  # user effects: only this branch touches p, q and the hooks
        p = m[3]
        q = m[4]
        a, b = call_hook(m[6], t, thu, wu, thl, wl, v, z, p, q)
        te_u += a
        te_l += b
        su, sl = call_hook(m[7], t, thu, wu, thl, wl, v, z, p, q)
    return te_u, te_l, su, sl


@njit(cache=True, error_model="numpy")
def bands(su, sl, c, hook):
    """Static bands ``(lo_u, hi_u, lo_l, hi_l)``: a sticking disc stays at rest while its
    external torque lies inside ``[lo, hi]``."""
    tsu = c[_TCU] + upper_excess(hook, c)
    return (
        -(tsu + su - c[_DTCU]),
        tsu + su + c[_DTCU],
        -(c[_TSL] + sl - c[_DTCL]),
        c[_TSL] + sl + c[_DTCL],
    )


# Inlined by numba, like drive: with the Stribeck table (kernel/friction.py) LLVM stopped
# inlining it into the solver, and the calls, passing the model tuple, made a brake
# residual 0.46 ms instead of 0.32 (first compilation 42 s instead of 37).
@njit(cache=True, error_model="numpy", inline="always")
def rhs(thu, wu, thl, wl, z, mu, ml, d, m):
    """Time derivatives of ``(theta_u, omega_u, theta_l, omega_l, z)`` in modes ``(mu,
    ml)``; ``z`` is the effect state (its rate from the state hook ``m[8]``; in the plain
    kernel 0, and nothing reads ``z``)."""
    c = m[0]
    cfg = m[1]
    shape = m[2]
    te_u, te_l, su, sl = torques(thu, wu, thl, wl, z, d, m)
    dthu = 0.0
    dwu = 0.0
    if mu != 0 and cfg != CFG_PRESCRIBED:
        f = slip_torque(
            wu,
            mu,
            c[_TCU] + su,
            c[_DTCU],
            c[_BU],
            c[_DBU],
            upper_excess(m[6], c),
            c[_IWSU],
            c[_DU],
            shape,
            c[_XCUTU],
        )
        dthu = wu
        dwu = (te_u - f) * c[_IJU]
    dthl = 0.0
    dwl = 0.0
    if ml != 0 and cfg != CFG_UPPER:
        f = slip_torque(
            wl,
            ml,
            c[_TCL] + sl,
            c[_DTCL],
            c[_BL],
            c[_DBL],
            c[_DSL],
            c[_IWSL],
            c[_DL],
            shape,
            c[_XCUT],
        )
        dthl = wl
        dwl = (te_l - f) * c[_IJL]
    dz = 0.0
    if m[5]:
        presc = cfg == CFG_PRESCRIBED
        dz = call_hook(
            m[8], d[0], d[2] if presc else thu, d[3] if presc else wu, thl, wl, d[1], z, m[3], m[4]
        )[0]
    return dthu, dwu, dthl, dwl, dz


#: Stribeck substeps (see :func:`stribeck_step`): at most this change of ``x = |omega_l| / ws``
#: per step, as a fraction of ``1 + x`` (for ``delta_l`` above 2, of ``(1 + x) * 2 / delta``)
#: ...
STRIBECK_STEP_FRACTION = 0.1
#: ... and at most ``STRIBECK_START + x``: from a reversal through zero velocity the steps
#: grow geometrically, from about a hundredth of ws at the present acceleration.
STRIBECK_START = 0.01
#: A weak Stribeck term, ``|Ts_l - Tc_l|`` below this fraction of ``Ts_l``, gets
#: proportionally longer substeps (its share of the error is proportionally smaller), and
#: none in the limit ``Ts_l -> Tc_l``: the angles stay continuous there, where a score
#: test or a Jacobian steps ``Ts_l`` off ``Tc_l`` by 1e-6 of its scale.  (With substeps
#: switched on by ``Ts_l != Tc_l`` alone, that step changed the solver's grid, and the
#: score of lower_stribeck on reference data fell behind string_damping's.)
STRIBECK_WEAK = 0.01


@njit(cache=True, error_model="numpy", inline="always")
def _stribeck_limit(w, a, ds, iws, delta, tc, dt):
    """:func:`stribeck_step`'s limit for one disc (velocity ``w``, acceleration ``a != 0``,
    Stribeck excess ``ds > 0``, ``1/ws``, shape, Coulomb level, sample interval)."""
    x = abs(w) * iws
    dx = min(STRIBECK_STEP_FRACTION * (1.0 + x) * min(1.0, 2.0 / delta), STRIBECK_START + x)
    weak = max(1.0, STRIBECK_WEAK * (tc + ds) / ds)
    return max(weak * dx / (abs(a) * iws), 0.5 * dt)


@njit(cache=True, error_model="numpy")
def stribeck_step(wu, au, mu, wl, al, ml, c, cfg, hook):
    """The longest Runge-Kutta step [s] the discs' Stribeck curves allow from velocities
    ``wu, wl``, accelerations ``au, al`` and modes ``mu, ml``: the lower disc's (``Ts_l``, ``ws_l``,
    ``delta_l``) and the upper disc's (``dTs_u``, ``ws_u``, ``delta_u``), by one rule.

    For each disc: ``inf`` unless it slips with a Stribeck term (``Ts_l != Tc_l``, ``dTs_u
    != 0``); else the time in which ``x = |w| / ws`` changes, at its present rate
    ``|a| / ws``, by

        min(STRIBECK_STEP_FRACTION * (1 + x) * min(1, 2 / delta_l), STRIBECK_START + x)

    -- a few milliseconds while the disc passes through the band (where the friction
    moves between Ts and Tc within a fraction of ws, the faster the larger ``delta_l``),
    steps growing geometrically after a reversal (``exp(-x**delta)`` is not smooth at
    ``x = 0`` unless ``delta`` is an even integer), the full step far outside the band.
    Divided by ``min(1, |Ts_l - Tc_l| / (STRIBECK_WEAK * Ts_l))`` (see
    :data:`STRIBECK_WEAK`); never below half a sample, which bounds the number of
    substeps.  A continuous function of the state and the parameters, so the steps, and
    the angles, stay continuous in the parameters (it tends to ``inf`` as ``al`` or
    ``Ts_l - Tc_l`` tends to 0).

    Measured against tests/reference.py at 55 ms steps: the accuracy suite's worst case
    3.4e-5 rad without substeps, 1.6e-6 with; 24 random brake rigs (0.6-1.5x the thesis,
    ``delta_l`` 0.8-3.0, multisines and staircases) at most 5.9e-6.
    """
    best = math.inf
    dsl = abs(c[_DSL])
    if ml != 0 and cfg != CFG_UPPER and dsl != 0.0 and al != 0.0:
        best = _stribeck_limit(wl, al, dsl, c[_IWSL], c[_DL], c[_TCL], c[_DT])
    dsu = upper_excess(hook, c)
    if mu != 0 and cfg != CFG_PRESCRIBED and dsu != 0.0 and au != 0.0:
        best = min(best, _stribeck_limit(wu, au, dsu, c[_IWSU], c[_DU], c[_TCU], c[_DT]))
    return best


#: Approach substeps (see :func:`approach_step`): a step is at most this multiple of the
#: time a slipping disc's velocity needs to reach zero at its present deceleration.
APPROACH_STEP_FACTOR = 2.0


@njit(cache=True, error_model="numpy")
def approach_step(wu, au, mu, wl, al, ml, c, cfg, room):
    """The longest Runge-Kutta step [s] from velocities ``wu, wl`` and accelerations
    ``au, al`` (scalars, not the state tuples) that goes at
    most :data:`APPROACH_STEP_FACTOR` times as far as a slipping disc needs to stop at its
    present deceleration; ``room`` (the step the grid allows) if that is shorter or no
    disc decelerates.

    Without it a velocity that dips to zero and back between two step points is not seen:
    the disc slips on where it should have stuck or reversed.  A 6 Hz sine about 0.5 V
    brought the upper disc's velocity to within 0.01 rad/s of zero each period; at 25 and
    55 ms steps one such stop was missed (3.9e-2 rad from the reference; 2.6e-5 with
    this).  With the factor 2 a step ends inside a parabolic dip below zero, or beyond one
    that stays above it.  A continuous function of the state, so the angles stay
    continuous in the parameters (it tends to ``room`` as the deceleration tends to 0).
    Never below half a sample.

    A sticking disc whose torque leaves its static band and returns between two step
    points is still not seen: the same rule for the torque's approach to the band's edge
    cost 10 % of a brake residual and changed no case measured.
    """
    k = APPROACH_STEP_FACTOR
    best = room
    # A limit k |w| / |a| binds where k |w| < |a| * best (no division otherwise: the
    # step's length is on the solver's critical path).
    if mu != 0 and cfg != CFG_PRESCRIBED and mu * au < 0.0 and k * abs(wu) < -mu * au * best:
        best = k * abs(wu) / abs(au)
    if ml != 0 and cfg != CFG_UPPER and ml * al < 0.0 and k * abs(wl) < -ml * al * best:
        best = k * abs(wl) / abs(al)
    return max(best, min(0.5 * c[_DT], room))


@njit(cache=True, error_model="numpy")
def guards(thu, wu, thl, wl, z, mu, ml, d, m):
    """Event functions of both discs; a mode stays valid while its guard is >= 0.

    Slip: ``s * omega``.  Stick: the distance of the external torque to the nearer
    edge of the static band (continuous, so one root finder serves both edges).
    """
    c, cfg = m[0], m[1]
    te_u, te_l, su, sl = torques(thu, wu, thl, wl, z, d, m)
    lo_u, hi_u, lo_l, hi_l = bands(su, sl, c, m[6])
    gu = 1.0
    if cfg != CFG_PRESCRIBED:
        gu = mu * wu if mu != 0 else min(hi_u - te_u, te_u - lo_u)
    gl = 1.0
    if cfg != CFG_UPPER:
        gl = ml * wl if ml != 0 else min(hi_l - te_l, te_l - lo_l)
    return gu, gl


@njit(cache=True, error_model="numpy")
def mode_at_rest(te, lo, hi):
    """Mode of a disc at zero velocity with external torque ``te``."""
    if te > hi:
        return 1
    if te < lo:
        return -1
    return 0


@njit(cache=True, error_model="numpy")
def modes_at_rest(thu, wu, thl, wl, z, d, m):
    """Modes of both discs if they were at rest now."""
    c, cfg = m[0], m[1]
    te_u, te_l, su, sl = torques(thu, wu, thl, wl, z, d, m)
    lo_u, hi_u, lo_l, hi_l = bands(su, sl, c, m[6])
    mu = mode_at_rest(te_u, lo_u, hi_u) if cfg != CFG_PRESCRIBED else 0
    ml = mode_at_rest(te_l, lo_l, hi_l) if cfg != CFG_UPPER else 0
    return mu, ml


@njit(cache=True, error_model="numpy")
def effect_state_ok(thu, wu, thl, wl, z, d, m):
    """False if a user effect shifted a friction level below its asymmetry (or to NaN), or
    its state ``z`` is not finite."""
    c = m[0]
    te_u, te_l, su, sl = torques(thu, wu, thl, wl, z, d, m)
    if not math.isfinite(z):
        return False
    if not (math.isfinite(te_u) and math.isfinite(te_l)):
        return False
    if not (math.isfinite(su) and math.isfinite(sl)):
        return False
    if c[_TCU] + su < abs(c[_DTCU]) or c[_TCL] + sl < abs(c[_DTCL]):
        return False
    return c[_TSL] + sl >= abs(c[_DTCL])


__all__ = ["HOOK_SIGNATURE", "HOOK_TYPE", "CONSTRAINTS", "N_PARAMS", "null_hook", "violations"]

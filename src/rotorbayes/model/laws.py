"""The physics of the friction laws shipped to hold against the switch model (their
registry entries, :data:`rotorbayes.model.effects.LAWS`, sit beside the catalogue's).

The model's friction is a *static* switch law: a disc sticks exactly while its torque lies
in the static band and slips with a friction that depends on its velocity alone.  A
dynamic law gives the friction a memory.  Each law here is one :class:`Effect` that
*replaces* the lower disc's dry friction (``Effect.replaces``): switched on with ``--add
NAME``, the lower disc never sticks, its friction comes from the law's state, and the
switch model's parameters keep their meaning (``Tc_l``, ``dTc_l``, ``Ts_l``, ``ws_l``,
``delta_l``, ``b_l``, ``db_l``), so one fit of each model on the same data compares them.

They are not nested in the switch model (no value of their parameters gives it back
exactly), so the diagnosis's score tests and trial refits leave them out: a law is a
hypothesis to fit and judge on validation data, side by side with the switch model.

**LuGre** (Canudas de Wit, Olsson, Astrom & Lischinsky, IEEE TAC 1995), chosen over a
generalized Maxwell-slip model because it needs one state (the kernel integrates one
effect state), its two new parameters have a physical reading a user can check against
the encoder (the bristle stiffness ``sigma0_l`` sets the pre-sliding displacement
``Ts_l / sigma0_l`` before break-away; ``sigma1_l`` damps it), and in steady sliding it
gives back exactly the switch model's Stribeck curve.  Maxwell-slip's several elements
(several states) would buy hysteresis with non-local memory, which the rig's encoders
resolve only where the pre-sliding displacement is many counts.

    dz/dt = omega_l - sigma0_l |omega_l| z / g(omega_l)
    T_f   = sigma0_l z + sigma1_l dz/dt + (b_l + sgn(omega_l) db_l) omega_l
    g(w)  = Tc_l + sgn(w) dTc_l + (Ts_l - Tc_l) exp(-(|w| / ws_l)^delta_l)

**Stiffness.** While the disc slides, ``z`` relaxes with the time constant ``g /
(sigma0_l |omega_l|)`` -- 0.05 N m / (300 N m/rad * 5 rad/s) = 33 us, thirty times shorter
than a 1 kHz sample.  The kernel's substep rule for an effect state
(:func:`rotorbayes.kernel.terms.state_step`) follows it, so a simulation costs more the
stiffer the bristles and the faster the slide (docs/effects.md has the figures,
``benchmarks/bench_lugre.py`` measures them).  The bound of ``sigma0_l`` (700 N m/rad) is
the stiffest at which the kernel was measured within its accuracy target of the
reference; the creep before break-away there is about one lower-encoder count.
"""

from __future__ import annotations

import math

from numba import njit

from ..kernel.layout import DELTA_L, WS_L

# The law's slice of q: its own parameters, then the lower disc's levels (Effect.replaces).
_S0, _S1, _TC, _DTC, _TS = range(5)


@njit(cache=True, error_model="numpy")
def lugre_level(w, p, q):
    """``g(w)`` [N m]: the steady sliding friction at velocity ``w`` without the viscous
    part (the switch model's Coulomb level, asymmetry and exponential Stribeck excess)."""
    s = 1.0 if w > 0.0 else (-1.0 if w < 0.0 else 0.0)
    g = q[_TC] + s * q[_DTC]
    ds = q[_TS] - q[_TC]
    if ds != 0.0:
        g += ds * math.exp(-((abs(w) / p[WS_L]) ** p[DELTA_L]))
    return g


@njit(cache=True, error_model="numpy")
def lugre_bristle_rate(w, z, p, q):
    """``dz/dt`` [rad/s] of the bristle deflection ``z`` at velocity ``w``."""
    return w - q[_S0] * abs(w) * z / lugre_level(w, p, q)


def lugre_rate(t, theta_u, omega_u, theta_l, omega_l, v, z, p, q):
    """The effect state's rate: the bristles' deflection rate."""
    return lugre_bristle_rate(omega_l, z, p, q)


def lugre_torque(t, theta_u, omega_u, theta_l, omega_l, v, z, p, q):
    """The bristles' torque on the lower disc (the viscous part stays in the kernel)."""
    zd = lugre_bristle_rate(omega_l, z, p, q)
    return 0.0, -(q[_S0] * z + q[_S1] * zd)


__all__ = ["lugre_bristle_rate", "lugre_level", "lugre_rate", "lugre_torque"]

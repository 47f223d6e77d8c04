"""Friction laws of the rig (thesis eqs. 2.4-2.6, 4.2-4.3, 5.13-5.14, 5.18).

For slip in direction ``s = sign(omega)`` the friction torque is ``s * T(|omega|)`` with

    T = Tc + s*dTc + (b + s*db)*|omega| + (Ts - Tc) * S(|omega| / ws)

and ``S(x) = exp(-x**delta)`` (the thesis's Stribeck curve, shape ``"exp"``) or
``S(x) = 1 / (1 + x**delta)`` (shape ``"rational"``; with ``delta = 1`` it is the
friction law of Leine's belt benchmark).  At ``omega = 0`` friction is set-valued:
the disc sticks while the external torque stays inside ``[-(Ts - dTc), Ts + dTc]``.

The compiled functions here are called from the integrator's inner loop; the NumPy
function :func:`friction_curve` evaluates the same law for plots and reports.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
from numba import njit

SHAPE_EXP = 0
SHAPE_RATIONAL = 1
SHAPES = {"exp": SHAPE_EXP, "rational": SHAPE_RATIONAL}


def shape_code(shape: str) -> int:
    """Integer code of a Stribeck shape name (``'exp'`` or ``'rational'``)."""
    try:
        return SHAPES[shape]
    except KeyError:
        raise ValueError(
            f"unknown Stribeck shape {shape!r}; choose one of {', '.join(SHAPES)}"
        ) from None


@njit(cache=True, error_model="numpy")
def stribeck(x, delta, shape):
    """Stribeck decay ``S(x)`` for ``x = |omega| / ws`` (``S(0) = 1``)."""
    if x <= 0.0:
        return 1.0
    p = math.exp(delta * math.log(x))
    if shape == SHAPE_EXP:
        # exp(-p) underflows to 0 beyond p ~ 745; skipping it saves a call.
        return math.exp(-p) if p < 740.0 else 0.0
    return 1.0 / (1.0 + p)


@njit(cache=True, error_model="numpy")
def slip_torque(w, s, Tc, dTc, b, db, dS, inv_ws, delta, shape):
    """Signed friction torque of a disc slipping in direction ``s`` at velocity ``w``.

    Inside an integration step the velocity may pass zero before the event is
    located; the law is continued smoothly there (``s*w`` in the viscous part,
    ``|w|`` in the Stribeck part) so the event function stays smooth in time.
    """
    T = Tc + s * dTc + (b + s * db) * (s * w)
    if dS != 0.0:
        T += dS * stribeck(abs(w) * inv_ws, delta, shape)
    return s * T


def friction_curve(
    omega: np.ndarray, params: Mapping[str, float], disc: str = "l", *, shape: str = "exp"
) -> np.ndarray:
    """Friction torque [N m] against velocity [rad/s] for plots.

    Parameters
    ----------
    omega : array
        Angular velocities [rad/s]; ``omega = 0`` returns ``nan`` (set-valued there).
    params : mapping
        Parameter values by name.
    disc : {'u', 'l'}
        Upper or lower disc.  The upper disc has no Stribeck part.
    shape : {'exp', 'rational'}
        Stribeck shape of the lower disc.
    """
    w = np.asarray(omega, dtype=float)
    s = np.sign(w)
    a = np.abs(w)
    if disc == "u":
        T = params["Tc_u"] + s * params["dTc_u"] + (params["b_u"] + s * params["db_u"]) * a
    elif disc == "l":
        Tc = params["Tc_l"]
        Ts = params.get("Ts_l", Tc)
        Ts = Tc if Ts is None or math.isnan(Ts) else Ts
        T = Tc + s * params["dTc_l"] + (params["b_l"] + s * params["db_l"]) * a
        if Ts != Tc:
            x = a / params["ws_l"]
            S = (
                np.exp(-(x ** params["delta_l"]))
                if shape == "exp"
                else 1 / (1 + x ** params["delta_l"])
            )
            T = T + (Ts - Tc) * S
    else:
        raise ValueError(f"disc must be 'u' or 'l', not {disc!r}")
    out = s * T
    return np.where(s == 0, np.nan, out)

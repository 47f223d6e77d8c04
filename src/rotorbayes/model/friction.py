"""Friction laws of the rig (thesis eqs. 2.4-2.6, 4.2-4.3, 5.13-5.14, 5.18).

For slip in direction ``s = sign(omega)`` the friction torque is ``s * T(|omega|)`` with

    T = Tc + s*dTc + (b + s*db)*|omega| + (Ts - Tc) * S(|omega| / ws)

and ``S(x) = exp(-x**delta)`` (the thesis's Stribeck curve, shape ``"exp"``) or
``S(x) = 1 / (1 + x**delta)`` (shape ``"rational"``; with ``delta = 1`` it is the
friction law of Leine's belt benchmark).  At ``omega = 0`` friction is set-valued:
the disc sticks while the external torque stays inside ``[-(Ts - dTc), Ts + dTc]``.

The compiled law the integrator's inner loop evaluates lives in the kernel
(:mod:`rotorbayes.kernel.friction`: ``exp(-x**delta)`` from a table of a single function,
error below 1.1e-11) and is re-exported here; the NumPy function :func:`friction_curve`
evaluates the same law exactly for plots and reports.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from ..kernel.friction import (
    EXP_NEGLIGIBLE,
    G_LO,
    G_PER_UNIT,
    G_TABLE,
    SHAPE_EXP,
    SHAPE_RATIONAL,
    negligible_x,
    slip_torque,
    stribeck,
    stribeck_g,
    stribeck_g_slope,
)

SHAPES = {"exp": SHAPE_EXP, "rational": SHAPE_RATIONAL}


def shape_code(shape: str) -> int:
    """Integer code of a Stribeck shape name (``'exp'`` or ``'rational'``)."""
    try:
        return SHAPES[shape]
    except KeyError:
        raise ValueError(
            f"unknown Stribeck shape {shape!r}; choose one of {', '.join(SHAPES)}"
        ) from None


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
        Upper or lower disc.  The upper disc's Stribeck part is ``dTs_u`` (its excess
        over ``Tc_u``; absent or 0 without the ``upper_stribeck`` effect).
    shape : {'exp', 'rational'}
        Stribeck shape of both discs.
    """
    w = np.asarray(omega, dtype=float)
    s = np.sign(w)
    a = np.abs(w)
    if disc == "u":
        T = params["Tc_u"] + s * params["dTc_u"] + (params["b_u"] + s * params["db_u"]) * a
        dS = params.get("dTs_u", 0.0) or 0.0
        if dS != 0.0:
            x = a / params["ws_u"]
            d = params["delta_u"]
            T = T + dS * (np.exp(-(x**d)) if shape == "exp" else 1 / (1 + x**d))
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


__all__ = [
    "EXP_NEGLIGIBLE", "G_LO", "G_PER_UNIT", "G_TABLE", "SHAPES", "SHAPE_EXP", "SHAPE_RATIONAL",
    "friction_curve", "negligible_x", "shape_code", "slip_torque", "stribeck", "stribeck_g",
    "stribeck_g_slope",
]  # fmt: skip

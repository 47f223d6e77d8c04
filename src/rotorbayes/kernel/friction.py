"""Compiled friction laws of the rig (thesis eqs. 2.4-2.6, 4.2-4.3, 5.13-5.14, 5.18), as
the solver (:mod:`rotorbayes.kernel.solver`) and the sensitivities evaluate them.

For slip in direction ``s = sign(omega)`` the friction torque is ``s * T(|omega|)`` with

    T = Tc + s*dTc + (b + s*db)*|omega| + (Ts - Tc) * S(|omega| / ws)

and ``S(x) = exp(-x**delta)`` (shape :data:`SHAPE_EXP`, the thesis's Stribeck curve) or
``S(x) = 1 / (1 + x**delta)`` (:data:`SHAPE_RATIONAL`; with ``delta = 1`` the friction law
of Leine's belt benchmark).  The inner loop takes ``exp(-x**delta)`` from a table of a
single function (:data:`G_TABLE`, error below 1.1e-11).  The model layer
(:mod:`rotorbayes.model.friction`) names the shapes and evaluates the same law exactly for
plots and reports; it imports this module, never the reverse.
"""

from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

from .numerics import fma

#: Stribeck shape codes of the kernel (:mod:`rotorbayes.model.friction` maps names to them).
SHAPE_EXP = 0
SHAPE_RATIONAL = 1

#: Where the exponential decay stops mattering: ``exp(-x**delta) < 1.2e-17`` once ``x**delta``
#: exceeds this.  Added to a friction torque it then changes it by less than 1.2e-17 of
#: ``Ts - Tc``, below the rounding of the torque itself, so the solver skips its logarithm
#: and two exponentials there (a fast-slipping disc: 15 % of the slip evaluations of a
#: 30 s brake run).
EXP_NEGLIGIBLE = 39.0


@njit(cache=True, error_model="numpy")
def negligible_x(delta):
    """The ``x`` beyond which the exponential Stribeck decay is negligible
    (:data:`EXP_NEGLIGIBLE`), for shape ``delta > 0``."""
    return math.exp(math.log(EXP_NEGLIGIBLE) / delta) if delta > 0.0 else math.inf


# The exponential decay is G(delta * log(x)) with G(v) = exp(-exp(v)), one function for
# every parameter set.  The solver takes G from a table of cubic Hermite pieces on
# [G_LO, log(EXP_NEGLIGIBLE)] (values and slopes exact at nodes 1/128 apart; largest error
# 1.1e-11, tests/test_friction_table.py); below G_LO, exp(v) < 4.3e-18 and G rounds to 1.
# A logarithm, a look-up and a cubic instead of a logarithm and two exponentials (a brake
# residual: kernel 0.353 -> 0.318 ms).  The table is the same for every parameter set and
# its pieces join with equal values and slopes, so the decay stays continuously
# differentiable in the parameters and in omega.
G_LO = -40.0
G_PER_UNIT = 128


def _g_table() -> np.ndarray:
    """Rows ``(g_k, h g'_k, ...)``: the cubic of interval ``k`` in its fraction ``s``."""
    n = int(math.ceil((math.log(EXP_NEGLIGIBLE) - G_LO) * G_PER_UNIT))
    v = G_LO + np.arange(n + 1) / G_PER_UNIT
    g = np.exp(-np.exp(v))
    h = 1.0 / G_PER_UNIT
    slope = -h * np.exp(v) * g
    ha, hb, dy = slope[:-1], slope[1:], np.diff(g)
    return np.ascontiguousarray(np.stack([g[:-1], ha, 3 * dy - 2 * ha - hb, ha + hb - 2 * dy], 1))


G_TABLE = _g_table()
_G_N = G_TABLE.shape[0]


@intrinsic
def _g_row(typingctx, k):
    """Row ``k`` of :data:`G_TABLE`, read from a constant in the compiled code itself.

    A NumPy array read in the solver's inner terms is reference-counted at every call
    (a global one too: a brake residual took 0.47 ms instead of 0.29 ms); a constant of the
    module is plain memory, and it is cached with the code."""
    sig = types.UniTuple(types.float64, 4)(types.intp)

    def codegen(context, builder, signature, args):
        data = ir.Constant(ir.ArrayType(ir.DoubleType(), G_TABLE.size), list(G_TABLE.ravel()))
        table = cgutils.global_constant(builder, "rotorbayes_stribeck_g", data, "linkonce_odr")
        i64 = ir.IntType(64)
        first = builder.mul(args[0], ir.Constant(i64, 4))
        vals = []
        for j in range(4):
            idx = builder.add(first, ir.Constant(i64, j))
            vals.append(builder.load(builder.gep(table, [ir.Constant(i64, 0), idx])))
        return context.make_tuple(builder, signature.return_type, vals)

    return sig, codegen


@njit(cache=True, error_model="numpy")
def stribeck_g(v):
    """``exp(-exp(v))`` as the solver computes it (see :data:`G_TABLE`)."""
    f = (v - G_LO) * G_PER_UNIT
    if f < 0.0:  # exp(v) < 4.3e-18: G rounds to 1 (also v = -inf, i.e. x = 0)
        return 1.0
    if f < _G_N:
        k = int(f)
        s = f - k
        c0, c1, c2, c3 = _g_row(k)
        return fma(s, fma(s, fma(s, c3, c2), c1), c0)
    if f >= _G_N:  # beyond EXP_NEGLIGIBLE (the solver stops at x_cut before)
        return 0.0
    return v  # NaN stays NaN


# Inlined by numba (only the sensitivities call it): a call left in the integrator's loop
# kept numba from pairing off the reference counts of the arrays around it.
@njit(cache=True, error_model="numpy", inline="always")
def stribeck_g_slope(v):
    """:func:`stribeck_g` (the same operations) and its derivative by ``v``: the table's
    cubic differentiated, so the forward sensitivities
    (:mod:`rotorbayes.kernel.sensitivity`) differentiate what the solver computes."""
    f = (v - G_LO) * G_PER_UNIT
    if f < 0.0:
        return 1.0, 0.0
    if f < _G_N:
        k = int(f)
        s = f - k
        c0, c1, c2, c3 = _g_row(k)
        g = fma(s, fma(s, fma(s, c3, c2), c1), c0)
        return g, (c1 + s * (2.0 * c2 + 3.0 * s * c3)) * G_PER_UNIT
    if f >= _G_N:
        return 0.0, 0.0
    return v, v  # NaN stays NaN


@njit(cache=True, error_model="numpy")
def stribeck(x, delta, shape, x_cut):
    """Stribeck decay ``S(x)`` for ``x = |omega| / ws`` (``S(0) = 1``); ``x_cut`` is
    :func:`negligible_x` of ``delta`` (``inf`` to evaluate it everywhere)."""
    if x <= 0.0:
        return 1.0
    if shape == SHAPE_EXP:
        if x >= x_cut:
            return 0.0
        return stribeck_g(delta * math.log(x))
    return 1.0 / (1.0 + math.exp(delta * math.log(x)))


@njit(cache=True, error_model="numpy")
def slip_torque(w, s, Tc, dTc, b, db, dS, inv_ws, delta, shape, x_cut):
    """Signed friction torque of a disc slipping in direction ``s`` at velocity ``w``.

    Inside an integration step the velocity may pass zero before the event is
    located; the law is continued smoothly there (``s*w`` in the viscous part,
    ``|w|`` in the Stribeck part) so the event function stays smooth in time.
    """
    T = fma(b + s * db, s * w, Tc + s * dTc)
    if dS != 0.0:
        T = fma(dS, stribeck(abs(w) * inv_ws, delta, shape, x_cut), T)
    return s * T

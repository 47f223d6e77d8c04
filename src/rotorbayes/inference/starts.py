"""Starts from the data: the equations of motion as a linear regression (equation error).

Least squares on a stick-slip model has many basins; a start from a thesis table lands in
the wrong one when the rig differs from the thesis's.  The rig's equations are linear in
most parameters once the angles' derivatives are known::

    J_u θu'' = k_m u − Tc_u s_u − dTc_u − b_u ωu − db_u |ωu| + k_alpha α          (upper)
    0        = J_l θl'' + Tc_l s_l + dTc_l + b_l ωl + db_l |ωl|
               + (Ts_l − Tc_l) s_l S(|ωl|/ws_l) + k_alpha α                         (lower)

with ``s = sign(ω)`` and ``α = θl − θu + alpha0``.  Smoothed derivatives of the measured
angles (Savitzky-Golay) turn every slip sample into one row; the rows of both discs are
stacked (they share ``k_alpha``, which with the fixed ``J_u`` sets the scale of the lower
disc's parameters) and solved by weighted linear least squares.  The Stribeck velocity and
shape enter nonlinearly: a small grid over them keeps the best linear solution.

The start is an *equation-error* estimate: biased by the smoothing and by samples near
switches, but in the right basin, which is all the output-error fit needs.  Parameters the
regression cannot reach (effects' parameters other than friction levels, ``alpha0``) keep
their start values; every value says where it came from.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np

from ..util.smoothing import savgol_filter
from .problem import Problem, local_name

#: Parameters the regression estimates, with the equation they enter.
UPPER_TERMS = ("k_m", "Tc_u", "dTc_u", "b_u", "db_u")
LOWER_TERMS = ("J_l", "Tc_l", "dTc_l", "b_l", "db_l", "dS_l")
#: Grid of the Stribeck velocity [rad/s] and shape exponent tried when they are free.
WS_GRID = tuple(np.geomspace(0.1, 8.0, 13))
DELTA_GRID = (0.7, 1.0, 1.4, 2.0, 2.8)


@dataclass
class DataStart:
    """A start computed from the data, and where each value came from."""

    values: dict[str, float]
    source: dict[str, str]
    notes: list[str] = field(default_factory=list)
    rows: dict[str, int] = field(default_factory=dict)

    def describe(self, names) -> str:
        lines = []
        for n in names:
            b, _ = local_name(n)
            v = self.values.get(n, self.values.get(b, math.nan))
            lines.append(f"  {n:<12} {v:12.5g}  {self.source.get(n, self.source.get(b, ''))}")
        return "\n".join(lines + [f"  note: {t}" for t in self.notes])


#: Most rows of the start's regression: longer data use every k-th row (a start needs far
#: fewer; 500 000 rows is 500 s of coupled data at 1 kHz).
REGRESSION_ROWS = 500_000


def derivatives(theta: np.ndarray, dt: float, window: float = 0.15):
    """Smoothed angle, velocity and acceleration (Savitzky-Golay, cubic, ``window`` s)."""
    n = max(7, int(round(window / dt)) | 1)
    n = min(n, (theta.size - 1) | 1 if theta.size % 2 == 0 else theta.size)
    if n < 5:
        raise ValueError("the experiment is too short for derivatives of its angles")
    th = savgol_filter(theta, n, 3)
    w = savgol_filter(theta, n, 3, deriv=1, delta=dt)
    a = savgol_filter(theta, n, 3, deriv=2, delta=dt)
    return th, w, a, n


def slip_mask(w: np.ndarray, n: int, w_min: float) -> np.ndarray:
    """Samples clearly in slip: ``|w|`` above ``w_min`` and at least a window from any
    sign change or rest, and from the record's ends (where the filter is one-sided)."""
    moving = np.abs(w) > w_min
    s = np.sign(w)
    change = np.r_[False, s[1:] != s[:-1]] | ~moving
    near = np.convolve(change.astype(float), np.ones(n), mode="same") > 0
    ok = moving & ~near
    ok[:n] = False
    ok[-n:] = False
    return ok


def _stribeck(x, delta, shape):
    x = np.maximum(x, 0.0)
    if shape == "rational":
        return 1.0 / (1.0 + x**delta)
    return np.exp(-(x**delta))


#: Relative margin above the least projected cost within which a Stribeck grid point is
#: solved as a regression (the projection agrees with the regression's cost to ~1e-12).
GRID_NEAR = 1e-3


def _near_best(costs: np.ndarray) -> np.ndarray:
    """Grid points to solve: within :data:`GRID_NEAR` of the least cost, or not known."""
    ok = np.isfinite(costs)
    if not ok.any():
        return np.ones(costs.size, bool)
    return ~ok | (costs <= costs[ok].min() * (1 + GRID_NEAR) + 1e-300)


def data_start(problem: Problem, base: dict[str, float] | None = None) -> DataStart:
    """Start values for ``problem``'s free parameters from its experiments.

    Parameters
    ----------
    problem : Problem
    base : mapping, optional
        Values of the parameters not estimated by the regression (default
        ``problem.base``).

    Returns
    -------
    DataStart
        ``values`` is a complete parameter set; ``source[name]`` says "data: ...",
        "fixed" or "start value".
    """
    base = dict(problem.base if base is None else base)
    free = {local_name(n)[0] for n in problem.names}
    active = problem.model.active
    has_lower = problem.model.configuration.has_lower
    stribeck_on = "Ts_l" in active
    upper_free = [n for n in UPPER_TERMS if n in free and n in active]
    # Upper rows need the motor model: not with the measured theta_u prescribed.
    use_upper = not problem.prescribed_upper
    unknown = list(upper_free) if use_upper else []
    if has_lower:
        for n in ("k_alpha", *LOWER_TERMS):
            if n == "dS_l":
                if stribeck_on and "Ts_l" in free:
                    unknown.append(n)
            elif n in free and n in active:
                unknown.append(n)
    out = DataStart(values=dict(base), source={})
    for n in problem.names:
        out.source[local_name(n)[0]] = "start value (not reached by the regression)"
    if not unknown:
        out.notes.append("no parameter the regression can estimate is free")
        return out

    def val(name):
        v = base[name]
        if name == "Ts_l" and math.isnan(v):
            return base["Tc_l"]
        return v

    # Each further experiment's initial torsion adds a constant string torque
    # c_i = k_alpha * alpha0[i] to both discs' equations (the first experiment's alpha0
    # is its start value: it cannot be told from the friction asymmetries' constants).
    torsion_offsets = (
        [i for i in range(1, len(problem.experiments)) if f"alpha0[{i}]" in problem.names]
        if has_lower
        else []
    )
    # The rows of every experiment, as (A columns dict, lhs) per equation.
    Au, yu, Al_parts, yl = [], [], [], []
    lower_feats = []  # (ωl, s_l) of the lower rows, for the Stribeck grid
    J_u = val("J_u")
    for i, ex in enumerate(problem.experiments):
        a0 = base.get(f"alpha0[{i}]", base.get("alpha0", 0.0))
        thu, wu, au, n = derivatives(ex.theta_u, ex.dt)
        if has_lower:
            assert ex.theta_l is not None  # Problem refuses a lower-disc model without it
            thl, wl, al, _ = derivatives(ex.theta_l, ex.dt)
            alpha = thl - thu + a0
        if use_upper and (upper_free or "k_alpha" in unknown):
            m = slip_mask(wu, n, 0.02)
            su = np.sign(wu[m])
            cols = {
                "k_m": ex.u[m],
                "Tc_u": -su,
                "dTc_u": -np.ones(m.sum()),
                "b_u": -wu[m],
                "db_u": -np.abs(wu[m]),
            }
            y = J_u * au[m]
            for nm, c in cols.items():
                if nm not in unknown and nm in active:
                    y = y - val(nm) * c
            ucols = {nm: c for nm, c in cols.items() if nm in unknown}
            if has_lower:
                if "k_alpha" in unknown:
                    ucols["k_alpha"] = alpha[m]
                else:
                    y = y - val("k_alpha") * alpha[m]
            if i in torsion_offsets:
                ucols[f"c{i}"] = np.ones(y.size)
            Au.append(ucols)
            yu.append(y)
        if has_lower:
            m = slip_mask(wl, n, 0.02)
            sl = np.sign(wl[m])
            cols = {
                "J_l": al[m],
                "Tc_l": sl,
                "dTc_l": np.ones(m.sum()),
                "b_l": wl[m],
                "db_l": np.abs(wl[m]),
                "k_alpha": alpha[m],
            }
            y = np.zeros(m.sum())
            for nm, c in cols.items():
                if nm not in unknown and nm in active:
                    y = y - val(nm) * c
            lcols = {nm: c for nm, c in cols.items() if nm in unknown}
            if i in torsion_offsets:
                lcols[f"c{i}"] = np.ones(y.size)
            Al_parts.append(lcols)
            yl.append(y)
            lower_feats.append((wl[m], sl))

    names = [n for n in unknown] + [f"c{i}" for i in torsion_offsets]
    # The lower equation alone is homogeneous in (J_l, k_alpha, friction): without upper
    # rows that share k_alpha, fix the scale by J_l's start value.
    scale_note = None
    if not Au and "J_l" in names and "k_alpha" in names:
        names.remove("J_l")
        for part, y in zip(Al_parts, yl, strict=True):
            y -= val("J_l") * part.pop("J_l")
        scale_note = (
            f"the lower disc's equation fixes only ratios; its scale is set by J_l = "
            f"{val('J_l'):g} (start value)"
        )

    # Long data: every stride-th row is plenty for a start (and the regression's matrix,
    # its weighted copy and lstsq's own copy of all rows would take GBs).
    n_rows = sum(y.size for y in yu) + sum(y.size for y in yl)
    stride = max(1, math.ceil(n_rows / REGRESSION_ROWS))
    take = slice(None, None, stride)

    # The rows and columns that do not depend on the Stribeck grid point, once: every grid
    # point then only writes its Stribeck column (or right-hand side) into a copy.
    A_rows, y_rows, group, lower_at = [], [], [], []
    row = 0
    for cols, y in zip(Au, yu, strict=True):
        y = y[take]
        A_rows.append(
            np.column_stack([cols[nm][take] if nm in cols else np.zeros(y.size) for nm in names])
        )
        y_rows.append(y)
        group.append(np.zeros(y.size, int))
        row += y.size
    for cols, y, (wl, sl) in zip(Al_parts, yl, lower_feats, strict=True):
        cols = {k: v[take] for k, v in cols.items()}
        y = y[take]
        A_rows.append(np.column_stack([cols.get(nm, np.zeros(y.size)) for nm in names]))
        y_rows.append(y)
        group.append(np.ones(y.size, int))
        lower_at.append((row, row + y.size, np.abs(wl[take]), sl[take]))
        row += y.size
    A_fixed, y_fixed, g_fixed = np.vstack(A_rows), np.concatenate(y_rows), np.concatenate(group)
    del A_rows, y_rows, group
    j_ds = names.index("dS_l") if "dS_l" in names else None

    def assemble(ws, delta):
        A, y = A_fixed, y_fixed
        if stribeck_on:
            A, y = (A.copy(), y) if j_ds is not None else (A, y.copy())
            for a, b, awl, sl in lower_at:
                S = sl * _stribeck(awl / ws, delta, problem.shape)
                if j_ds is not None:
                    A[a:b, j_ds] = S
                else:
                    y[a:b] = y[a:b] - (val("Ts_l") - val("Tc_l")) * S
        return A, y, g_fixed

    def solve(ws, delta, w=None):
        """Weighted linear least squares; the weights (one per disc's equation, the
        inverse RMS of its residual) are iterated unless given, so grid points are
        compared under the same weights."""
        A, y, g = assemble(ws, delta)
        if A.shape[0] < 3 * len(names):
            return None
        iterate = w is None
        w = np.ones(y.size) if iterate else w
        for _ in range(3 if iterate else 1):
            sol, *_ = np.linalg.lstsq(A * w[:, None], y * w, rcond=None)
            if not iterate:
                break
            r = y - A @ sol
            for k in (0, 1):
                sel = g == k
                if sel.any():
                    w[sel] = 1.0 / max(np.sqrt(np.mean(r[sel] ** 2)), 1e-12)
        cost = float(np.sum((w * (y - A @ sol)) ** 2))
        return sol, cost, {k: int(np.sum(g == k)) for k in (0, 1)}, w

    def grid_costs(grid, w) -> np.ndarray:
        """Weighted cost of the regression at every grid point ``(ws, delta)`` with the
        weights ``w``: the right-hand side and the Stribeck column projected out of the
        span of the other columns (``nan``: not computed, solve there)."""
        if A_fixed.shape[0] < 3 * len(names) or len(grid) < 2:
            return np.full(len(grid), np.nan)
        keep = [j for j in range(len(names)) if j != j_ds]
        B = A_fixed[:, keep] * w[:, None]
        U, sv, _ = np.linalg.svd(B, full_matrices=False)
        # lstsq's rank rule (rcond=None)
        Q = U[:, sv > np.finfo(float).eps * max(B.shape) * (sv[0] if sv.size else 0.0)]
        out = np.empty(len(grid))
        for k, (ws, delta) in enumerate(grid):
            A, y, _ = assemble(ws, delta)
            r = y * w
            r = r - Q @ (Q.T @ r)
            if j_ds is not None:
                c = A[:, j_ds] * w
                c = c - Q @ (Q.T @ c)
                cc = float(c @ c)
                if cc > 1e-24 * max(float(np.dot(A[:, j_ds], A[:, j_ds])), 1e-300):
                    r = r - (float(c @ r) / cc) * c
            out[k] = float(r @ r)
        return out

    grid_ws = WS_GRID if ("ws_l" in free and stribeck_on) else (val("ws_l"),)
    grid_delta = DELTA_GRID if ("delta_l" in free and stribeck_on) else (val("delta_l"),)
    if not stribeck_on:
        grid_ws, grid_delta = (1.0,), (1.0,)
    ref = solve(grid_ws[len(grid_ws) // 2], grid_delta[len(grid_delta) // 2])
    best = None
    if ref is not None:
        grid = list(itertools.product(grid_ws, grid_delta))
        # Every grid point's cost by projection (one SVD of the columns they share); the
        # regression itself only at those within GRID_NEAR of the least: the same choice
        # as solving at every point (the projection's error is far below GRID_NEAR).
        near = _near_best(grid_costs(grid, ref[3]))
        for (ws, delta), ok in zip(grid, near, strict=True):
            if not ok:
                continue
            got = solve(ws, delta, ref[3])
            if got is not None and (best is None or got[1] < best[1]):
                best = (*got[:3], ws, delta)
    if best is None:
        out.notes.append("too few slip samples for a regression; the start values are used instead")
        return out
    sol, _, counts, ws, delta = best
    out.rows = {"upper": counts[0], "lower": counts[1]}
    how = {n: "data: equation of the upper disc" for n in UPPER_TERMS} | {
        n: "data: equation of the lower disc" for n in LOWER_TERMS
    }
    how["k_alpha"] = "data: string torque in both discs' equations" if Au else "data: lower disc"
    est = dict(zip(names, map(float, sol), strict=True))
    k_alpha = est.get("k_alpha", val("k_alpha"))
    for i in torsion_offsets:
        a0 = est.pop(f"c{i}") / k_alpha + base.get("alpha0", 0.0)
        out.values[f"alpha0[{i}]"] = float(a0)
        out.source[f"alpha0[{i}]"] = "data: constant string torque in both discs' equations"
    if "dS_l" in est:
        tc = est.get("Tc_l", val("Tc_l"))
        est["Ts_l"] = tc + est.pop("dS_l")
        how["Ts_l"] = "data: friction at low slip speed (lower disc)"
    if stribeck_on and "ws_l" in free:
        est["ws_l"], how["ws_l"] = float(ws), "data: best of a grid (lower disc)"
    if stribeck_on and "delta_l" in free:
        est["delta_l"], how["delta_l"] = float(delta), "data: best of a grid (lower disc)"

    def finish(est: dict, how: dict) -> tuple[dict, dict]:
        """Values and their sources from regression estimates, moved inside the bounds."""
        values, source = dict(out.values), dict(out.source)
        for n, v in est.items():
            info = problem.model.info[n]
            lo, hi = info.lower, info.upper
            margin = 1e-3 * (hi - lo)
            note = how[n]
            if not math.isfinite(v):
                continue
            if v < lo + margin or v > hi - margin:
                clipped = min(max(v, lo + margin), hi - margin)
                if info.lower >= 0 and v <= 0 and n != "J_l":
                    # A friction level the regression sends below zero is small: start it
                    # at a few percent of the bound's width instead of on the bound.
                    clipped = lo + 0.01 * min(hi - lo, 1.0)
                note += f" (regression gave {v:.3g}, outside the bounds; moved inside)"
                v = clipped
            values[n] = float(v)
            source[n] = note
        if "Ts_l" in values and stribeck_on:
            tc = values["Tc_l"]
            if not values["Ts_l"] > tc:
                values["Ts_l"] = tc * 1.5 + 1e-3
                source["Ts_l"] += " (raised above Tc_l)"
        return values, source

    out.values, out.source = finish(est, how)
    info_j, info_k = (problem.model.info.get(n) for n in ("J_l", "k_alpha"))
    if (
        info_j is not None
        and info_k is not None
        and {"J_l", "k_alpha"} <= set(names)
        and not torsion_offsets
        and Au
        and (
            est["J_l"] <= info_j.lower + 1e-3 * (info_j.upper - info_j.lower)
            or est["k_alpha"] <= info_k.lower + 1e-3 * (info_k.upper - info_k.lower)
        )
    ):
        # The lower disc's equation is homogeneous: when the string torque is too weak in
        # the upper disc's equation to set its scale, the joint regression drops the lower
        # disc to nothing.  Its ratios still come from its own equation; the scale is then
        # the one whose simulation fits the data best.
        rescued = _rescale_lower(problem, names, assemble(ws, delta), est, how, finish)
        if rescued is not None:
            out.values, out.source, note = rescued
            out.notes.append(note)
    if scale_note:
        out.notes.append(scale_note)
    return out


def _rescale_lower(problem: Problem, names: list, rows, est: dict, how: dict, finish):
    """The lower disc's parameters as ratios to J_l from its own equation, their common
    scale from a scan (geometric, across J_l's bounds) of the simulated fit, the upper
    disc's parameters re-regressed at each scale.  None when it does not fit better than
    ``est``."""
    A, y, g = rows
    lower = [j for j, n in enumerate(names) if n in LOWER_TERMS or n == "k_alpha"]
    upper = [j for j, n in enumerate(names) if j not in lower]
    jJ, jk = names.index("J_l"), names.index("k_alpha")
    Al, yl = A[g == 1], y[g == 1]
    others = [j for j in lower if j != jJ]
    if Al.shape[0] < 3 * len(lower) or not others:
        return None
    ratios, *_ = np.linalg.lstsq(Al[:, others], yl - Al[:, jJ], rcond=None)
    ratio = dict(zip(others, ratios, strict=True))
    if not ratio[jk] > 0:
        return None
    Au_, yu_ = A[g == 0], y[g == 0]

    def candidate(s: float) -> dict:
        e = dict(est)
        e["J_l"] = s
        for j, r in ratio.items():
            e[names[j]] = s * float(r)
        if upper:
            rhs = yu_ - e["k_alpha"] * Au_[:, jk]
            sol, *_ = np.linalg.lstsq(Au_[:, upper], rhs, rcond=None)
            e.update({names[j]: float(v) for j, v in zip(upper, sol, strict=True)})
        if "dS_l" in e:
            e["Ts_l"] = e.get("Tc_l", 0.0) + e.pop("dS_l")
        return e

    def cost(values: dict) -> float:
        try:
            r = problem.residuals(problem.x_from(values))
        except Exception:  # noqa: BLE001 - an unsimulable candidate is just a bad one
            return math.inf
        return float(r @ r) if np.all(np.isfinite(r)) else math.inf

    info = problem.model.info["J_l"]
    lo, hi = info.lower, info.upper
    scales = np.geomspace(max(lo, 1e-9) * 1.01, hi * 0.99, 25)
    base_values, _ = finish(est, how)
    best: tuple[float, tuple[dict, dict, float] | None] = (cost(base_values), None)
    for s in scales:
        values, source = finish(candidate(float(s)), how)
        c = cost(values)
        if c < best[0]:
            best = (c, (values, source, float(s)))
    if best[1] is None:
        return None
    values, source, scale = best[1]
    for n in [names[j] for j in lower] + ["Ts_l"] * ("dS_l" in names):
        if n in source and not source[n].startswith("data: lower disc's ratios"):
            source[n] = (
                "data: lower disc's ratios from its equation, scale from a scan "
                "of the simulated fit"
            )
    note = (
        f"the string torque was too weak in the upper disc's equation to set the lower "
        f"disc's scale (the joint regression dropped it to nothing); the lower disc's "
        f"parameters are its own equation's ratios at the scale J_l = {scale:.3g} that fits "
        "the data best of a scan of 25"
    )
    return values, source, note

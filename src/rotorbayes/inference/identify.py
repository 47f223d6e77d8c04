"""Identifiability: which parameter combinations the data fix, and which they do not.

* :func:`fisher` — the Fisher information ``F = Jᵀ W J`` of the likelihood (``W`` = 1/σ²
  per channel, σ the noise floor) in *relative* coordinates: ``log θ`` for positive
  parameters, ``θ / scale`` for signed ones (an asymmetry, ``alpha0``: a log makes no sense
  there); its eigenvectors are the stiff (large eigenvalue) and sloppy (small) directions,
  and ``1/√λ`` is the 1-σ width along one, in relative units.
* :func:`describe` — the directions in plain words ("scaling J_l, k_alpha, Tc_l and b_l
  together by 1.2 costs less than one standard deviation of noise: only their ratios are
  determined").
* :func:`profile` — profile likelihoods: one parameter held at each value of a grid, all
  others refitted, ``Δχ² = ΔSSR / σ²``; points run in parallel through the executor layer
  (local threads or processes, or Dask: :mod:`rotorbayes.inference.parallel`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .least_squares import fit
from .parallel import progress, run_tasks
from .problem import Problem, local_name


@dataclass
class Fisher:
    names: list[str]
    log: np.ndarray  # which coordinates are log θ
    scale: np.ndarray  # θ for log coordinates, the scale of signed ones
    eigenvalues: np.ndarray  # ascending
    vectors: np.ndarray  # columns

    def width(self, i: int) -> float:
        """1-σ width along eigenvector ``i`` in relative units."""
        return 1.0 / math.sqrt(max(self.eigenvalues[i], 1e-300))

    def as_dict(self) -> dict:
        return {
            "names": self.names,
            "log_coordinates": self.log.tolist(),
            "eigenvalues": self.eigenvalues.tolist(),
            "eigenvectors": self.vectors.T.tolist(),
            "widths_1sigma": [self.width(i) for i in range(len(self.names))],
        }


def _weights(problem: Problem) -> np.ndarray:
    floors, _ = problem.noise_floors()
    w = []
    for ex in problem.experiments:
        for c in problem.channels:
            w.append(np.full(ex.n, 1.0 / floors[c]))
    return np.concatenate(w)


def fisher(problem: Problem, x: np.ndarray, *, J: np.ndarray | None = None) -> Fisher:
    x = np.asarray(x, float)
    if J is None:
        J, _ = problem.jacobian(x)
    log = np.array([problem.lower[j] >= 0 and x[j] > 0 for j in range(x.size)])
    width = problem.upper - problem.lower
    scale = np.where(log, x, np.maximum(np.abs(x), 1e-3 * width))
    Js = J * scale[None, :] * _weights(problem)[:, None]
    w, V = np.linalg.eigh(Js.T @ Js)
    return Fisher(list(problem.names), log, scale, w, V)


def describe(F: Fisher, *, n: int = 2) -> list[str]:
    """The ``n`` sloppiest and the stiffest direction in words."""
    out = []
    k = len(F.names)
    for i in list(range(min(n, k))) + [k - 1]:
        v = F.vectors[:, i]
        v = v * np.sign(v[np.argmax(np.abs(v))])
        movers = [(F.names[j], v[j]) for j in np.argsort(-np.abs(v)) if abs(v[j]) > 0.25]
        wdt = F.width(i)
        kind = "stiffest" if i == k - 1 else ("sloppiest" if i == 0 else "next sloppiest")
        coords = ", ".join(f"{nm} {c:+.2f}" for nm, c in movers)
        logs = all(F.log[F.names.index(nm)] for nm, _ in movers)
        same = all(c > 0 for _, c in movers)
        if len(movers) >= 2 and logs and same:
            pct = 100 * (math.exp(min(wdt, 50.0)) - 1)
            txt = (
                f"{kind} direction ({coords}; relative units): scaling "
                f"{', '.join(nm for nm, _ in movers)} together by {pct:.3g} % "
                f"changes the fit by one standard deviation of the noise — "
                + (
                    "only their ratios are determined by these data"
                    if wdt > 0.05
                    else "their common scale is determined too"
                )
            )
        elif len(movers) >= 2 and kind == "stiffest":
            txt = (
                f"{kind} direction ({coords}): this combination is the best determined; "
                f"1-σ width {wdt:.3g} in relative units"
            )
        elif len(movers) >= 2:
            txt = (
                f"{kind} direction ({coords}): these trade off against each other; "
                f"1-σ width {wdt:.3g} in relative units"
            )
        else:
            nm = movers[0][0] if movers else F.names[int(np.argmax(np.abs(v)))]
            txt = f"{kind} direction is {nm} alone: 1-σ relative width {wdt:.3g}"
        out.append(txt)
    return out


def _profile_point(shared: tuple, v: float) -> float:
    """One grid point of a profile, as a task: ``name`` held at ``v``, the others refitted
    from ``x`` (only the SSR is used: no honest-uncertainty pass); the weighted SSR (χ²),
    NaN where the point cannot be simulated."""
    problem, x, name, max_nfev, w = shared
    others = [n for n in problem.names_base() if n != local_name(name)[0]]
    base = dict(problem.params_for(x, 0))
    base[local_name(name)[0]] = float(v)
    sub = problem.like(free=others, base=base)
    start = sub.x_from({**base, **problem.values(x)})
    try:
        r = fit(sub, start, parallel=False, max_nfev=max_nfev, uncertainty=False)
    except Exception:  # noqa: BLE001 - an unsimulable grid point: no value
        return math.nan
    res = sub.residuals(r.x)
    return float(np.sum((res * w) ** 2))


def _point_index(key: str) -> int:
    """A profile point's file number in the task store, from its hash."""
    return int(key[:12], 16)


def profile(
    problem: Problem,
    x: np.ndarray,
    name: str,
    *,
    n_points: int = 11,
    span: float | None = None,
    stderr: float | None = None,
    workers: int = 2,
    max_nfev: int = 100,
    executor=None,
    resume=None,
) -> dict:
    """Profile likelihood of ``name``: Δχ² over a grid, the others refitted.

    The grid points are independent fits; they run on ``executor`` (default: the current
    one, else ``workers`` local threads) and give the same values on every back-end.
    ``resume``: a task store folder (:mod:`.taskstore`) that keeps every finished point and
    gives back those an earlier run of the same problem and point finished.
    """
    j = problem.names.index(name)
    x = np.asarray(x, float)
    v0 = x[j]
    info = problem.info(name)
    if span is None:
        rel = (stderr or abs(v0) * 0.01) / max(abs(v0), 1e-12)
        span = float(np.clip(5 * rel, 1e-6, 0.5))
    if v0 > 0 and problem.lower[j] >= 0:
        grid = v0 * np.exp(np.linspace(-span, span, n_points))
    else:
        s = max(abs(v0), 1e-3 * (info.upper - info.lower))
        grid = v0 + s * np.linspace(-span, span, n_points)
    grid = np.clip(grid, problem.lower[j], problem.upper[j])
    w = _weights(problem)
    values: dict[int, float] = {}
    store = None
    keys = [""] * len(grid)
    if resume is not None:
        from .taskstore import TaskStore, fingerprint, problem_fingerprint

        # One store for every profile of a command: a point is known by its own hash.
        store = TaskStore(
            resume, fingerprint("profiles", problem_fingerprint(problem), x), "profile point"
        )
        for i, v in enumerate(grid):
            keys[i] = fingerprint(name, float(v), max_nfev)
            hit, rec = store.get(_point_index(keys[i]), keys[i])
            if hit and rec is not None:
                values[i] = float(rec["chi2"])
    todo = [i for i in range(len(grid)) if i not in values]
    tasks = run_tasks(
        _profile_point,
        [grid[i] for i in todo],
        shared=(problem, x, name, max_nfev, w),
        executor=executor,
        workers=workers,
    )
    for j, v in progress(tasks, len(todo), f"profile {name}"):
        i = todo[j]
        if store is not None:
            store.put(_point_index(keys[i]), keys[i], {"chi2": float(v)})
        values[i] = v
    chi2 = np.array([values[i] for i in range(len(grid))])
    r0 = problem.residuals(x)
    chi2_min = float(np.sum((r0 * w) ** 2))
    return {
        "parameter": name,
        "unit": info.unit,
        "grid": grid.tolist(),
        "delta_chi2": (chi2 - min(chi2_min, np.nanmin(chi2))).tolist(),
        "estimate": float(v0),
    }


#: Δχ² of a 95 % profile-likelihood interval (one parameter).
PROFILE_LEVEL = 3.84


def profile_interval(pr: dict, level: float = PROFILE_LEVEL) -> dict:
    """Where a profile (:func:`profile`) stays below ``level``, in words and numbers.

    The ends are interpolated linearly in Δχ² between the last grid point inside and the
    first outside. ``{"lo", "hi"}`` (None when no grid point is inside), ``"inside"`` (grid
    points below the level) and ``"note"``: what to distrust - an end at the grid's edge
    (the interval may be wider), or fewer than 3 points inside (the grid is too coarse for
    the interval's shape)."""
    g = [float(v) for v in pr.get("grid") or []]
    d = [float(v) if v is not None else math.nan for v in pr.get("delta_chi2") or []]
    ok = [i for i in range(min(len(g), len(d))) if math.isfinite(d[i]) and d[i] < level]
    if not ok:
        return {
            "lo": None,
            "hi": None,
            "inside": 0,
            "note": "no grid point within the interval: the grid is too coarse; give more points",
        }
    k = min(ok, key=lambda i: d[i])
    a = b = k
    while a - 1 in ok:
        a -= 1
    while b + 1 in ok:
        b += 1

    def cross(i_in: int, i_out: int) -> float:
        if not math.isfinite(d[i_out]):
            return g[i_in]
        t = (level - d[i_in]) / (d[i_out] - d[i_in])
        return g[i_in] + t * (g[i_out] - g[i_in])

    lo = cross(a, a - 1) if a > 0 else g[0]
    hi = cross(b, b + 1) if b < len(g) - 1 else g[-1]
    notes = []
    if a == 0 or b == len(g) - 1:
        notes.append("the interval reaches the grid's edge: widen it")
    if b - a + 1 < 3:
        notes.append(
            f"only {b - a + 1} grid point(s) inside: the ends are rough "
            "interpolations; give more points"
        )
    return {"lo": lo, "hi": hi, "inside": b - a + 1, "note": "; ".join(notes)}

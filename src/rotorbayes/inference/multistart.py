"""Multistart: many least-squares fits from spread starts, end points clustered and
explained in words (which parameters the data do not identify, which starts stop in other
minima or on plateaus).  Fits run through the executor layer
(:mod:`rotorbayes.inference.parallel`): serially, in local threads or processes, or on Dask."""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..model.parameters import ParameterError
from .assess import NEAR_FLOOR, floor_ratio
from .least_squares import COMPRESS_BYTES, FitResult, StartError, check_fittable, fit
from .parallel import run_tasks
from .problem import Problem


@dataclass
class MultistartResult:
    """End points of many fits from different starts."""

    names: list[str]
    starts: np.ndarray
    ends: np.ndarray
    ssr: np.ndarray
    success: np.ndarray
    clusters: np.ndarray
    #: The fits (of long data without their Jacobian: ``jac`` None, see ensure_jacobian).
    fits: list[FitResult] = field(repr=False)
    start_index: np.ndarray | None = None
    failed: dict[int, str] = field(default_factory=dict)
    interrupted: bool = False

    @property
    def best(self) -> FitResult:
        """The fit with the lowest SSR."""
        return self.fits[int(np.argmin(self.ssr))]

    def summary(self, *, flat: float = 0.05) -> str:
        """Plain words: which parameters spread while the cost stays flat, and whether
        starts end in other (local) minima or on plateaus.

        ``flat`` is the relative SSR margin above the best that still counts as
        "as good" (default 5 %).
        """
        if self.ssr.size == 0:
            return (
                f"all {len(self.failed)} finished starts failed; the first reason: "
                f"{next(iter(self.failed.values()), '')}"
            )
        text = describe_spread(self.names, self.ends, self.ssr, flat=flat)
        ratio = floor_ratio(self.best.problem, self.best.x)
        if ratio > NEAR_FLOOR:
            text = text.replace("Well determined:", "Alike across starts:")
            text += (
                f"\nThe best fit is {ratio:.3g}x the encoder floor, so no estimate here is "
                "well determined: the model (or a fixed value) does not fit the data; "
                "agreement between starts only says they reach the same wrong optimum."
            )
        else:
            text += f"\nThe best fit is {ratio:.2f}x the encoder floor."
        if self.failed:
            text += (
                f"\n{len(self.failed)} start(s) failed and count as no minimum (e.g. "
                f"{next(iter(self.failed.values()))})."
            )
        if self.interrupted:
            text += "\nInterrupted: only the starts finished before Ctrl-C are included."
        best = float(np.min(self.ssr))
        worse = self.ssr > best * (1 + flat) + 1e-300
        if worse.any():
            n_cl = len(set(self.clusters[worse].tolist()))
            stuck = [f for f, w in zip(self.fits, worse, strict=True) if w and f.nfev <= 2]
            text += (
                f"\n{int(worse.sum())} start{'s' if worse.sum() != 1 else ''} stopped "
                f"elsewhere, in {n_cl} other "
                f"cluster(s) with SSR {np.min(self.ssr[worse]) / max(best, 1e-300):.3g}x to "
                f"{np.max(self.ssr[worse]) / max(best, 1e-300):.3g}x the best: the cost has "
                "local minima, so the estimate depends on the start P0 (thesis §4.3)."
            )
            if stuck:
                text += (
                    f" {len(stuck)} of them did not move at all: their start lies on a "
                    "plateau of the cost (e.g. the lower disc never breaks loose, so the "
                    "friction parameters do not change the response)."
                )
        return text


def describe_spread(
    names: Sequence[str], ends: np.ndarray, ssr: np.ndarray, *, flat: float = 0.05
) -> str:
    """Explain the spread of near-optimal end points in words (see :class:`MultistartResult`)."""
    ssr = np.asarray(ssr, float)
    best = float(np.min(ssr))
    good = ssr <= best * (1 + flat) + 1e-300
    lines = [
        f"{int(good.sum())} of {ssr.size} starts end within {100 * flat:.0f} % of the best "
        f"SSR ({best:.4g} rad²)."
    ]
    if good.sum() < 3:
        lines.append("Too few equally good end points to judge the spread; run more starts.")
        return "\n".join(lines)
    E = ends[good]
    pos = np.all(E > 0, axis=0)
    spread = []
    for j, n in enumerate(names):
        col = E[:, j]
        if pos[j]:
            rel = float(np.std(np.log(col)))
            spread.append((n, rel, f"±{100 * rel:.1f} %"))
        else:
            spread.append(
                (
                    n,
                    float(np.std(col)) / (abs(float(np.mean(col))) + 1e-12),
                    f"sd {np.std(col):.3g}",
                )
            )
    loose = [s for s in spread if s[1] > 0.02]
    tight = [s for s in spread if s[1] <= 0.02]
    if loose:
        lines.append(
            "These parameters spread although the cost stays flat (not identified "
            "one by one): " + ", ".join(f"{n} {txt}" for n, _, txt in loose) + "."
        )
    if tight:
        lines.append("Well determined: " + ", ".join(f"{n} {txt}" for n, _, txt in tight) + ".")
    # The ridge: leading principal direction of the log end points of the positive ones.
    idx = [j for j in range(len(names)) if pos[j]]
    if len(idx) >= 2 and loose:
        L = np.log(E[:, idx])
        L = L - L.mean(axis=0)
        _, sv, Vt = np.linalg.svd(L, full_matrices=False)
        v = Vt[0] * np.sign(Vt[0][np.argmax(np.abs(Vt[0]))])
        share = sv[0] ** 2 / max(float(np.sum(sv**2)), 1e-300)
        movers = [(names[idx[j]], v[j]) for j in range(len(idx)) if abs(v[j]) > 0.25]
        if share > 0.8 and len(movers) >= 2:
            same = all(np.sign(c) == np.sign(movers[0][1]) for _, c in movers)
            desc = " and ".join(n for n, _ in movers)
            lines.append(
                f"They move together along one ridge ({100 * share:.0f} % of the spread): "
                + (
                    f"scaling {desc} by a common factor leaves the fit almost unchanged, so only "
                    "their ratios are determined by these data."
                    if same
                    else f"{desc} trade off against each other (log-direction "
                    + ", ".join(f"{n} {c:+.2f}" for n, c in movers)
                    + ")."
                )
            )
            if same:
                ref = movers[0][0]
                rat = []
                for n, _ in movers[1:]:
                    r = E[:, names.index(n)] / E[:, names.index(ref)]
                    rat.append(f"{n}/{ref} ±{100 * np.std(np.log(r)):.1f} %")
                lines.append("Their ratios vary much less: " + ", ".join(rat) + ".")
    return "\n".join(lines)


def latin_hypercube(
    problem: Problem,
    n: int,
    rng: np.random.Generator,
    *,
    around: np.ndarray | None = None,
    spread: float = 0.3,
) -> np.ndarray:
    """Start points: a Latin hypercube within the bounds, or (``around`` given) a
    Latin hypercube of log-normal factors ``exp(spread * N(0,1))`` around a point."""
    from scipy.stats import qmc  # here: scipy.stats takes a quarter second to import

    k = len(problem.names)
    U = qmc.LatinHypercube(d=k, seed=rng).random(n)
    if around is None:
        lo, hi = problem.lower, problem.upper
        # Positive parameters spanning decades are sampled log-uniformly.
        X = np.empty_like(U)
        for j in range(k):
            if lo[j] > 0 and hi[j] / lo[j] > 100:
                X[:, j] = np.exp(np.log(lo[j]) + U[:, j] * (np.log(hi[j]) - np.log(lo[j])))
            else:
                X[:, j] = lo[j] + U[:, j] * (hi[j] - lo[j])
        return _within_constraints(problem, X, U)
    from scipy.stats import norm

    fac = np.exp(spread * norm.ppf(np.clip(U, 1e-9, 1 - 1e-9)))
    X = np.where(around != 0, around * fac, spread * (U - 0.5) * (problem.upper - problem.lower))
    return np.clip(X, problem.lower, problem.upper)


def _within_constraints(problem: Problem, X: np.ndarray, U: np.ndarray) -> np.ndarray:
    """Asymmetries drawn over their whole bounds mostly break ``Tc >= |dTc|``: draw them
    as a fraction of their (drawn) mean level instead, so every start can be simulated."""
    from ..kernel.terms import CONSTRAINTS

    pos = {n: j for j, n in enumerate(problem.names)}
    for names, _, _ in CONSTRAINTS:
        if len(names) == 2 and all(n in pos for n in names):
            a, b = pos[names[0]], pos[names[1]]
            X[:, b] = (2 * U[:, b] - 1) * 0.9 * X[:, a]
    return np.clip(X, problem.lower, problem.upper)


def fit_or_reason(problem: Problem, x0, **fit_kw) -> tuple[FitResult | None, str]:
    """One fit of a multistart or restart: ``(result, "")``, or ``(None, why)`` when the
    start cannot be fitted (outside the bounds, not simulable): a failure, not a minimum."""
    # Many starts: the i.i.d. standard errors only; the caller attaches honest ones to the
    # fit it keeps (attach_uncertainty).
    fit_kw.setdefault("uncertainty", False)
    try:
        return fit(problem, x0, parallel=False, **fit_kw), ""
    except StartError as exc:
        return None, exc.reason  # a start of the search's own: no advice about --p0
    except (ParameterError, ValueError, RuntimeError) as exc:
        return None, str(exc)


def _fit_start(shared: tuple, x0: np.ndarray) -> tuple[FitResult | None, str]:
    """One start of a multistart, as a task: ``shared`` is ``(problem, fit_kw)``.

    A fit of long data comes back without its Jacobian (``jac`` None: above
    :data:`~.least_squares.COMPRESS_BYTES`, hundreds of MB per start, sent back and kept
    for every start); whoever keeps the fit computes it again (:func:`ensure_jacobian`)."""
    problem, fit_kw = shared
    r, why = fit_or_reason(problem, x0, **fit_kw)
    # FitResult declares jac and problem as always set; a start's result travels without them
    # (ensure_jacobian and the caller put them back).
    if r is not None and r.jac is not None and r.jac.nbytes > COMPRESS_BYTES:
        r.jac = None  # type: ignore[assignment]
    if r is not None:
        # the caller has it: not sent back from a process or Dask worker
        r.problem = None  # type: ignore[assignment]
    return r, why


def ensure_jacobian(r: FitResult) -> FitResult:
    """Give a fit that came back without its Jacobian (long data) the Jacobian at its end
    point again."""
    if r.jac is None:
        r.jac, _ = r.problem.jacobian(r.x)
    return r


def multistart(
    problem: Problem,
    n_starts: int = 32,
    *,
    seed: int = 0,
    around=None,
    spread: float = 0.3,
    workers: int = 2,
    executor=None,
    progress: bool = True,
    resume=None,
    **fit_kw,
) -> MultistartResult:
    """Fit from ``n_starts`` start points in parallel and cluster the end points.

    Parameters
    ----------
    around : array or mapping, optional
        Centre of a log-normal spread of starts (``spread`` is its log-sd); default a
        Latin hypercube over the parameter bounds.
    workers : int
        Parallel fits in local threads when no ``executor`` is given and none is current.
    executor : concurrent.futures.Executor, optional
        Where the fits run (:mod:`rotorbayes.inference.parallel`); the starts and so the
        results depend on ``seed`` alone, not on the executor.
    resume : path, optional
        A task store (:mod:`.taskstore`): every finished start is kept there as it
        finishes, and starts it already holds for the same problem, settings and start
        vector are read instead of fitted again (a re-run after a kill gives the result of
        an uninterrupted run).
    """
    check_fittable(problem)  # nothing free, or too few samples: said before any work
    rng = np.random.default_rng(seed)
    if isinstance(around, Mapping):
        around = problem.x_from({**problem.base, **around})
    starts = latin_hypercube(problem, n_starts, rng, around=around, spread=spread)
    t0 = time.perf_counter()

    results: dict[int, tuple] = {}
    store = None
    if resume is not None:
        from .taskstore import TaskStore, fingerprint, problem_fingerprint

        store = TaskStore(
            resume,
            fingerprint(
                "multistart",
                problem_fingerprint(problem),
                seed,
                n_starts,
                around,
                spread,
                {k: v for k, v in sorted(fit_kw.items())},
            ),
            "start",
        )
        results = kept_fits(store, starts, problem)
        if results and progress:
            print(
                f"  {len(results)} of {n_starts} starts had finished in an earlier run: "
                f"read from {store.folder}",
                flush=True,
            )
    todo = [i for i in range(n_starts) if i not in results]
    interrupted = False
    try:
        for j, (r, why) in run_tasks(
            _fit_start,
            [starts[i] for i in todo],
            shared=(problem, fit_kw),
            executor=executor,
            workers=workers,
        ):
            i = todo[j]
            if r is not None:
                r.problem = problem  # a process or Dask worker sent back its own copy
            if store is not None:
                store.put(i, fingerprint(starts[i]), _fit_record(r, why))
            results[i] = (r, why)
            if progress:
                el = time.perf_counter() - t0
                k = len(results)
                new = k - (n_starts - len(todo))  # fitted in this run
                print(
                    f"  start {k:3d}/{n_starts} done "
                    f"({el:.0f} s elapsed, ~{el / new * (n_starts - k):.0f} s left)",
                    flush=True,
                )
    except KeyboardInterrupt:
        interrupted = True
    idx = sorted(results)
    good = [i for i in idx if results[i][0] is not None and _usable(results[i][0])]
    failed = {i: (results[i][1] or results[i][0].message) for i in idx if i not in good}
    ok = [results[i][0] for i in good]
    ends = np.array([f.x for f in ok]).reshape(len(ok), len(problem.names))
    ssr = np.array([f.ssr for f in ok])
    succ = np.array([f.success for f in ok], dtype=bool)
    clusters = cluster_ends(ends, ssr, problem) if ok else np.zeros(0, int)
    return MultistartResult(
        names=list(problem.names),
        starts=starts,
        ends=ends,
        ssr=ssr,
        success=succ,
        clusters=clusters,
        fits=ok,
        start_index=np.array(good, dtype=int),
        failed=failed,
        interrupted=interrupted,
    )


#: The fields of a FitResult a task store keeps (all but the problem and uncertainty).
_RECORD_FIELDS = (
    "names",
    "x",
    "x0",
    "stderr",
    "jac",
    "ssr",
    "n_residuals",
    "success",
    "message",
    "nfev",
    "njev",
    "seconds",
)


def _fit_record(r: FitResult | None, why: str) -> dict:
    """One finished start as a task-store record."""
    rec: dict = {"ok": r is not None, "why": why}
    if r is not None:
        for k in _RECORD_FIELDS:
            v = getattr(r, k)
            if v is None:  # a long-data fit's Jacobian (see _fit_start)
                continue
            rec[k] = (
                v
                if isinstance(v, np.ndarray | list | str | bool)
                else (float(v) if isinstance(v, float | np.floating) else int(v))
            )
    return rec


def _fit_from_record(rec: dict, problem: Problem) -> tuple[FitResult | None, str]:
    if not rec["ok"]:
        return None, str(rec["why"])
    kw: dict[str, Any] = {k: rec.get(k) for k in _RECORD_FIELDS}
    for k in ("success",):
        kw[k] = bool(kw[k])
    for k in ("n_residuals", "nfev", "njev"):
        kw[k] = int(kw[k])
    kw["names"] = list(kw["names"])
    return FitResult(problem=problem, **kw), str(rec["why"])


def kept_fits(store, starts, problem: Problem, first: int = 0) -> dict[int, tuple]:
    """The fits a task store holds for ``starts`` (start ``i`` under index ``first + i``,
    checked by the start's hash), as ``{i: (FitResult or None, why)}``."""
    from .taskstore import fingerprint

    found = {}
    for i, s in enumerate(starts):
        hit, rec = store.get(first + i, fingerprint(s))
        if hit:
            found[i] = _fit_from_record(rec, problem)
    return found


def _usable(f: FitResult) -> bool:
    """A fit whose end point can be simulated (a failed start is not a minimum)."""
    return "cannot be simulated" not in f.message and np.isfinite(f.ssr)


def cluster_ends(
    ends: np.ndarray,
    ssr: np.ndarray,
    problem: Problem,
    *,
    cost_tol: float = 0.01,
    x_tol: float = 0.05,
) -> np.ndarray:
    """Group end points whose SSR agree within ``cost_tol`` (relative) and whose
    parameters agree within ``x_tol`` (relative to the bounds' width); label 0 is the
    cluster of the best end point."""
    order = np.argsort(ssr)
    width = problem.upper - problem.lower
    labels = np.full(ssr.size, -1)
    reps: list[int] = []
    for i in order:
        for lab, r in enumerate(reps):
            if abs(ssr[i] - ssr[r]) <= cost_tol * max(ssr[r], 1e-300) and np.all(
                np.abs(ends[i] - ends[r]) <= x_tol * width
            ):
                labels[i] = lab
                break
        else:
            labels[i] = len(reps)
            reps.append(i)
    return labels

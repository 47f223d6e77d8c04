"""The first fit a newcomer can trust: a start from the data, least squares, and a small
automatic multistart when the result is not at the encoder floor.

:func:`fit_from_data` is what ``rotorbayes fit`` runs when no ``--p0`` is given:

1. :func:`~rotorbayes.inference.starts.data_start` — the equations of motion as a linear
   regression on smoothed derivatives of the measured angles;
2. :func:`~rotorbayes.inference.least_squares.fit` from there;
3. if a fitted channel stays above ``NEAR_FLOOR`` times its quantisation floor, a few more
   fits from log-normal spreads around the data start (through the executor layer),
   keeping the best.

The result carries where its start came from and how many restarts it took.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .assess import NEAR_FLOOR, floor_ratio
from .least_squares import FitResult, attach_uncertainty, check_fittable, fit
from .multistart import (
    _fit_from_record,
    _fit_record,
    _fit_start,
    ensure_jacobian,
    kept_fits,
    latin_hypercube,
)
from .parallel import DefaultPool, SerialExecutor, current_executor, progress, run_tasks
from .problem import Problem
from .starts import DataStart, data_start

#: Jacobians larger than this [bytes] (long data) make the restarts run one at a time on
#: local threads: each running fit holds its own (and the residual rows it is made from).
LOCAL_PARALLEL_BYTES = 128 * 2**20


@dataclass
class FirstFit:
    """A fit from a data-driven start, with the restarts it needed."""

    result: FitResult
    start: DataStart
    restarts: list[dict] = field(default_factory=list)
    chose: str = "the start from the data"


#: Friction levels and the asymmetries they bound (a friction may not push along the motion).
_LEVELS = (
    ("Tc_u", "dTc_u"),
    ("b_u", "db_u"),
    ("Tc_l", "dTc_l"),
    ("b_l", "db_l"),
    ("Ts_l", "dTc_l"),
)


def _within_constraints(problem: Problem, x0: np.ndarray) -> np.ndarray:
    """The data start with every asymmetry inside its level (``|dTc| <= Tc`` ...).

    The regression fits each direction's friction apart; when an effect it cannot
    represent is in the data (a hidden viscous asymmetry, say) an asymmetry can come out
    larger than its level, a start the model refuses.  The asymmetry is shrunk to 0.9 of
    the level (or, if only the level is free, the level raised to 1.1 of it).
    """
    x = np.array(x0, float)
    vals = problem.params_for(x, 0)
    for level, asym in _LEVELS:
        lv, a = vals.get(level), vals.get(asym)
        if lv is None or a is None or not (math.isfinite(lv) and math.isfinite(a)):
            continue
        if abs(a) <= lv:
            continue
        if asym == "dTc_u" and "u_offset" in problem.names and vals.get("k_m"):
            # A motor voltage offset is exactly a change of dTc_u by -k_m*u_offset: an
            # upper asymmetry beyond the level is an offset when the model has one.
            j = problem.names.index("u_offset")
            u_off = -a / vals["k_m"]
            if problem.lower[j] <= u_off <= problem.upper[j]:
                x[j] = u_off
                x[problem.names.index(asym)] = 0.0
                vals = problem.params_for(x, 0)
                continue
        if asym in problem.names:
            x[problem.names.index(asym)] = math.copysign(0.9 * lv, a)
        elif level in problem.names:
            j = problem.names.index(level)
            x[j] = min(1.1 * abs(a), problem.upper[j])
        vals = problem.params_for(x, 0)
    return x


def fit_from_data(
    problem: Problem,
    *,
    restarts: int = 6,
    spread: float = 0.4,
    seed: int = 0,
    workers: int = 2,
    executor=None,
    verbose: bool = False,
    resume=None,
    **fit_kw,
) -> FirstFit:
    """Least squares from a start computed from the data, restarted if needed.

    Parameters
    ----------
    restarts : int
        Extra fits tried when the first one ends above ``NEAR_FLOOR`` x the floor.
    spread : float
        Log-sd of the restarts' spread around the data start.
    workers, executor
        Where the restarts run (:func:`rotorbayes.inference.parallel.run_tasks`).
    resume : path, optional
        A task store (:mod:`.taskstore`): the fit from the data start and every finished
        restart are kept there as they finish, and what it already holds for the same
        problem, settings and start is read instead of fitted again (a re-run after a kill
        ends as an uninterrupted run).
    """
    check_fittable(problem)  # nothing free, or too few samples: said before any work
    ds = data_start(problem)
    x0 = problem.x_from(ds.values)
    x0 = _within_constraints(problem, np.clip(x0, problem.lower, problem.upper))
    if verbose:
        print("start from the data:\n" + ds.describe(problem.names), flush=True)
    from .taskstore import TaskStore, fingerprint, problem_fingerprint

    def open_store():  # made only when restarts are needed: a fit without them leaves none
        return TaskStore(
            resume,
            fingerprint(
                "first fit",
                problem_fingerprint(problem),
                seed,
                restarts,
                spread,
                x0,
                {k: v for k, v in sorted(fit_kw.items())},
            ),
            "fit",
        )

    use = resume is not None and restarts > 0
    store = open_store() if use and Path(resume).is_dir() else None
    res = _kept(store, 0, x0, problem, "the fit from the data start", verbose)
    kept = res is not None
    if res is None:
        res = fit(problem, x0, verbose=verbose, **fit_kw)
    out = FirstFit(res, ds)
    if restarts <= 0 or floor_ratio(problem, res.x) <= NEAR_FLOOR:
        _complete(res, fit_kw)
        return out
    if use:
        store = store or open_store()
        if not kept:
            store.put(0, fingerprint(x0), _fit_record(res, ""))
    if verbose:
        print(
            f"the fit from the data start ends {floor_ratio(problem, res.x):.3g}x the floor; "
            f"trying {restarts} more starts around it",
            flush=True,
        )
    rng = np.random.default_rng(seed)
    starts = latin_hypercube(problem, restarts, rng, around=x0, spread=spread)

    best = res
    if 8 * problem.n_residuals * len(problem.names) > LOCAL_PARALLEL_BYTES and isinstance(
        executor if executor is not None else current_executor(),
        ThreadPoolExecutor | DefaultPool | type(None),
    ):
        # Long data on this machine: one restart at a time (each holds its own Jacobian).
        executor, workers = SerialExecutor(), 1
        res.jac = None  # not held while the restarts run theirs; computed again if kept
        if verbose:
            print(
                "long data: the restarts run one at a time (each fit's Jacobian is "
                "large); --backend dask spreads them over other machines",
                flush=True,
            )
    found: dict[int, tuple] = {}
    if store is not None:
        found = kept_fits(store, starts, problem, first=1)  # 0: the data start's fit
        if found and verbose:
            print(
                f"{len(found)} of {restarts} restarts had finished in an earlier run: read "
                f"from {store.folder}",
                flush=True,
            )
    todo = [i for i in range(restarts) if i not in found]
    tasks = run_tasks(
        _fit_start,
        [starts[i] for i in todo],
        shared=(problem, fit_kw),
        executor=executor,
        workers=workers,
    )
    for j, (r, why) in progress(tasks, len(todo), "restarts", enabled=verbose):
        if r is not None:
            r.problem = problem  # a process or Dask worker sent back its own copy
        if store is not None:
            store.put(todo[j] + 1, fingerprint(starts[todo[j]]), _fit_record(r, why))
        found[todo[j]] = (r, why)
    for i in range(restarts):  # in start order: the choice does not depend on who finished
        r, why = found[i]
        row = {
            "start": starts[i].tolist(),
            "ssr": r.ssr if r else None,
            "success": bool(r and r.success),
            "failed": why,
        }
        out.restarts.append(row)
        if r is not None and r.ssr < best.ssr:
            best = r
            out.chose = f"restart {i + 1} of {restarts} (spread {spread} around the data start)"
    _complete(best, fit_kw)
    out.result = best
    return out


def _kept(store, index: int, start, problem: Problem, what: str, verbose: bool):
    """The fit the task store holds for ``start`` (None when it holds none)."""
    if store is None:
        return None
    from .taskstore import fingerprint

    hit, rec = store.get(index, fingerprint(start))
    if not hit or not rec["ok"]:
        return None
    if verbose:
        print(f"{what} had finished in an earlier run: read from {store.folder}", flush=True)
    return _fit_from_record(rec, problem)[0]


def _complete(res: FitResult, fit_kw: dict) -> None:
    """The kept fit's Jacobian and uncertainty (a fit read from a task store, or a restart
    fitted without them, has none)."""
    ensure_jacobian(res)
    if res.uncertainty is None and fit_kw.get("uncertainty", True):
        attach_uncertainty(res)

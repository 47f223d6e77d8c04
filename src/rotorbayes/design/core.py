"""Design the next experiment: the input that pins what the data leave loose, or that
separates candidate effects (issue 20).

:func:`design_input` takes a fit (a folder written by ``rotorbayes fit``, a
:class:`~rotorbayes.inference.results.LoadedFit`, a :class:`~rotorbayes.inference.FitResult` or a
``(problem, x)`` pair) and a target:

* ``"sloppiest"`` (default) — the fit's sloppiest Fisher direction: minimise the predicted
  1-σ width along it when the new experiment is fitted together with the existing data;
* ``params=[...]`` — named free parameters: minimise the sum of their predicted relative
  variances;
* ``separate=[A, B, ...]`` — two or more candidate effects, each fitted to the existing
  data as the diagnosis would (``fit --add``): maximise the smallest expected SSR gap
  (:func:`.information.separation_gap`) over every pair, so the worst-separated pair
  limits the design; pairs the registry ties exactly are left to the procedure that
  breaks the tie.

It searches an input family (:mod:`.inputs`) from several starts through the executor layer
(:func:`rotorbayes.inference.parallel.run_tasks`), compares the best input with the standard
estimation input of equal length and limits, and checks itself: the designed experiment is
simulated at the fit (quantised like the data), fitted together with the existing data, and
the achieved gain is reported beside the predicted one.  When the registry says no input can
help (:mod:`.ties`), it says so with the procedure that can, and searches nothing.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..inference.least_squares import fit as _fit
from ..inference.parallel import run_tasks
from ..inference.problem import Problem, local_name
from ..io.measurements import (
    LOWER_COUNTS_PER_REV,
    UPPER_COUNTS_PER_REV,
    Experiment,
    quantisation_floor,
)
from ..io.measurements import quantize as _quantize
from ..model import effects as _effects
from ..model.signals import MAX_VOLTAGE, estimation_signal
from ..model.simulate import SimulationError
from . import ties as _ties
from .information import Frame, separation_gap
from .inputs import FAMILIES, MAX_BAND_HZ, DesignInputError, make_family

#: Status words of a design.
DESIGNED, NO_INPUT, LITTLE_GAIN = "designed", "no input can help", "little to gain"
#: A design whose predicted width (or gap) improves on the existing data's by less than
#: this factor is reported as little to gain.
MIN_GAIN = 1.05
#: A ``--separate`` candidate whose fit to the existing data is above this many times the
#: encoder floor (worst channel) is said not to fit them.
POOR_FIT = 5.0
#: Function evaluations per optimisation start (each one a Jacobian on the new input).
DEFAULT_EVALS = 400
#: Local optimiser of each start: 'powell' (derivative-free) or 'lbfgsb' (forward
#: differences).
METHOD = "powell"


class DesignError(DesignInputError):
    """A design request that cannot be served; the message names the value and the fix."""


@dataclass
class DesignResult:
    """A designed input, what it is predicted to gain and what the self-check achieved."""

    status: str
    target: dict
    words: str
    t: np.ndarray
    u: np.ndarray
    baseline: np.ndarray | None
    input_family: dict
    predicted: dict
    achieved: dict | None
    starts: list[dict]
    settings: dict
    seconds: dict
    procedure: str = ""
    responses: dict = field(default_factory=dict, repr=False)

    def as_dict(self) -> dict:
        return {
            "status": self.status,
            "target": self.target,
            "words": self.words,
            "procedure": self.procedure or None,
            "input": self.input_family,
            "predicted": self.predicted,
            "achieved": self.achieved,
            "starts": self.starts,
            "settings": self.settings,
            "seconds": self.seconds,
        }

    def text(self) -> str:
        lines = [
            f"status: {self.status}",
            f"target: {self.target.get('words', '')}",
            "",
            self.words,
        ]
        if self.procedure and self.procedure not in self.words:
            lines += ["", f"procedure: {self.procedure}"]
        if self.input_family:
            lines += ["", f"input: {self.input_family.get('description', '')}"]
        return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------ inputs
def _as_fit(
    fit, trust_effects: bool = False, accept_changed_data: bool = False
) -> tuple[Problem, np.ndarray, str]:
    from ..inference.results import LoadedFit, load_fit

    if isinstance(fit, (str, Path)):
        lf = load_fit(fit, trust_effects=trust_effects, accept_changed_data=accept_changed_data)
        return lf.problem, lf.x, str(lf.folder)
    if isinstance(fit, LoadedFit):
        return fit.problem, fit.x, str(fit.folder)
    if isinstance(fit, tuple) and len(fit) == 2 and isinstance(fit[0], Problem):
        return fit[0], np.asarray(fit[1], float), "(problem, x)"
    if hasattr(fit, "problem") and hasattr(fit, "x"):
        return fit.problem, np.asarray(fit.x, float), "FitResult"
    raise DesignError(
        f"cannot design from {type(fit).__name__}: give a fit folder, a "
        "LoadedFit, a FitResult or a (problem, x) pair"
    )


def _grid_defaults(problem: Problem, duration, rate) -> tuple[float, float]:
    ex = problem.experiments[0]
    rate = float(rate) if rate is not None else round(1.0 / ex.dt, 9)
    if duration is None:
        duration = round(float(ex.t[-1] - ex.t[0]) * rate) / rate
    return float(duration), rate


# -------------------------------------------------------------------------- objectives
class _Objective:
    """The number a start minimises, as a picklable object (process and Dask workers)."""

    def __init__(self, kind: str, family, frames: list[Frame], v=None, idx=None):
        self.kind, self.family, self.frames, self.v, self.idx = kind, family, frames, v, idx

    def value(self, u: np.ndarray) -> float:
        t = self.family.t
        if self.kind == "sloppiest":
            f = self.frames[0]
            Jn = f.new_rows(t, u)
            return math.log(max(f.sd_along(f.F_old + Jn.T @ Jn, self.v), 1e-300))
        if self.kind == "params":
            f = self.frames[0]
            Jn = f.new_rows(t, u)
            return math.log(max(float(np.sum(f.variances(f.F_old + Jn.T @ Jn, self.idx))), 1e-300))
        g = self.gaps(u, self.idx)
        return -math.log1p(min(g[d] for d in self.idx))

    def gaps(self, u: np.ndarray, directions=None) -> dict[tuple[int, int], float]:
        """Expected SSR gap of each direction ``(i, j)`` (candidate ``i`` true, ``j``
        refitted) on input ``u``; every direction of every pair unless ``directions``."""
        t = self.family.t
        rows = [f.new_rows(t, u, with_prediction=True) for f in self.frames]
        if directions is None:
            n = len(self.frames)
            directions = [(i, j) for i in range(n) for j in range(n) if i != j]
        return {
            (i, j): separation_gap(
                self.frames[i], self.frames[j], rows[i][1], rows[j][1], rows[j][0]
            )
            for i, j in directions
        }

    def __call__(self, z: np.ndarray) -> float:
        try:
            return self.value(self.family(z))
        except (SimulationError, np.linalg.LinAlgError, FloatingPointError):
            return 1e3  # an input the model cannot simulate: the worst possible value


def _run_start(objective: _Objective, item) -> dict:
    """One optimisation start (a task of the executor layer)."""
    from scipy import optimize  # here: diagnose imports this module, never optimises

    i, z0, max_evals = item
    t0 = time.perf_counter()
    fam = objective.family
    f0 = objective(z0)
    bounds = list(zip(fam.lower, fam.upper, strict=True))
    if METHOD == "powell":
        res = optimize.minimize(
            objective,
            z0,
            method="Powell",
            bounds=bounds,
            options={"maxfev": int(max_evals), "xtol": 1e-3, "ftol": 1e-4},
        )
    else:
        # Forward differences over a step the input can feel (a hundredth of a volt).
        res = optimize.minimize(
            objective,
            z0,
            method="L-BFGS-B",
            bounds=bounds,
            options={"maxfun": int(max_evals), "eps": 2e-3, "ftol": 1e-6},
        )
    z = np.clip(res.x, fam.lower, fam.upper)
    val = float(res.fun)
    if not val <= f0:  # never worse than the start
        z, val = np.asarray(z0, float), f0
    return {
        "start": int(i),
        "z": z,
        "value": val,
        "start_value": float(f0),
        "evaluations": int(res.nfev),
        "seconds": time.perf_counter() - t0,
    }


# ------------------------------------------------------------------------------ checks
def _simulate_data(frame: Frame, t, u, seed: int) -> Experiment:
    """The new experiment simulated at ``frame``'s fit, quantised like the data (and with
    Gaussian noise where the data's floor is above the quantisation)."""
    p = frame.new_problem(t, u)
    sim = p.simulate(p.x_from(frame.params_new))
    if sim.meta.get("status", "ok") != "ok":
        raise SimulationError(
            f"the designed experiment cannot be simulated at the fit: {sim.meta['status']}"
        )
    rng = np.random.default_rng(seed)
    out = {}
    for c, counts in (("theta_u", UPPER_COUNTS_PER_REV), ("theta_l", LOWER_COUNTS_PER_REV)):
        th = getattr(sim, c)
        if th is None:
            out[c] = None
            continue
        q = quantisation_floor(c)
        extra = math.sqrt(max(frame.floors.get(c, q) ** 2 - q**2, 0.0))
        if extra > 0:
            th = th + extra * rng.standard_normal(th.size)
        out[c] = _quantize(th, counts)
    return Experiment(t, u, out["theta_u"], out["theta_l"], name="designed (simulated)")


def _combined(frame: Frame, new_ex: Experiment) -> tuple[Problem, np.ndarray, np.ndarray]:
    """Old data plus ``new_ex``: the problem, its start (the fit) and, per free name, the
    index in the frame's coordinates."""
    prob0 = frame.problem
    prob = prob0.like(
        model=frame.model,
        experiments=list(prob0.experiments) + [new_ex],
        free=frame.names_base,
        base=frame.params_new,
    )
    pos = [frame.names.index(n) for n in prob.names]
    return prob, frame.x_comb[pos], np.array(pos)


def _fisher_at(frame: Frame, prob: Problem, J: np.ndarray, pos: np.ndarray) -> np.ndarray:
    Js = frame._scaled_rows(prob, J) * frame.scale[pos][None, :]
    F = np.zeros((len(frame.names),) * 2)
    F[np.ix_(pos, pos)] = Js.T @ Js
    return F


def _check_information(frame: Frame, t, u, kind: str, v, idx, seed: int, max_nfev: int) -> dict:
    """Simulate, refit old + new, and measure the width(s) the target asks for."""
    t0 = time.perf_counter()
    new_ex = _simulate_data(frame, t, u, seed)
    prob, x0, pos = _combined(frame, new_ex)
    res = _fit(prob, x0, uncertainty=True, max_nfev=max_nfev, parallel=True)
    F = _fisher_at(frame, prob, res.jac, pos)
    cov = np.full((len(frame.names),) * 2, np.nan)
    if res.uncertainty is not None:
        cov[np.ix_(pos, pos)] = res.uncertainty.cov / np.outer(frame.scale[pos], frame.scale[pos])
    out = {
        "converged": bool(res.success),
        "fit_seconds": time.perf_counter() - t0,
        "rms_over_floor": prob.rms_over_floor(prob.residuals(res.x)),
    }
    if kind == "sloppiest":
        out["sd_white"] = frame.sd_along(F, v)
        vp = v[pos]
        out["sd_honest"] = math.sqrt(max(float(vp @ cov[np.ix_(pos, pos)] @ vp), 0.0))
        out["error_along_direction"] = float(v[pos] @ _relative_step(frame, res.x, x0, pos))
    else:
        out["sd_white"] = {
            frame.names[j]: math.sqrt(x) for j, x in zip(idx, frame.variances(F, idx), strict=True)
        }
        out["sd_honest"] = {frame.names[j]: math.sqrt(max(cov[j, j], 0.0)) for j in idx}
    return out


def _relative_step(frame: Frame, x: np.ndarray, x0: np.ndarray, pos: np.ndarray):
    """``x - x0`` in the frame's relative coordinates (log where the scale is the value)."""
    out = np.empty(len(pos))
    for k, j in enumerate(pos):
        if x0[k] > 0 and x[k] > 0 and frame.scale[j] == x0[k]:
            out[k] = math.log(x[k] / x0[k])
        else:
            out[k] = (x[k] - x0[k]) / frame.scale[j]
    return out


def _direction_key(labels: Sequence[str], i: int, j: int) -> str:
    """The name of direction ``(i, j)``: candidate ``i`` true, ``j`` refitted (with two
    candidates the other is implied: ``"A true"``)."""
    return f"{labels[i]} true" if len(labels) == 2 else f"{labels[i]} true, {labels[j]} refitted"


def _check_separation(
    frames: list[Frame], labels, t, u, seed: int, max_nfev: int, used: Sequence[int] | None = None
) -> dict:
    """For each candidate as the truth: simulate, refit every candidate to old + new, and
    the SSR gap of each other candidate over the true one (one entry per direction).
    ``used``: the candidates that take part (default all)."""
    used = list(range(len(frames))) if used is None else list(used)
    out = {}
    for k in used:
        new_ex = _simulate_data(frames[k], t, u, seed + k)
        ssr = {}
        for m in used:
            f = frames[m]
            prob, x0, _ = _combined(f, new_ex)
            res = _fit(prob, x0, uncertainty=False, max_nfev=max_nfev, parallel=True)
            r = f._scaled_rows(prob, prob.residuals(res.x)[:, None])[:, 0]
            ssr[m] = float(r @ r)
        for other in used:
            if other == k:
                continue
            entry = {
                "ssr_gap": ssr[other] - ssr[k],
                "ssr_true_model": ssr[k],
                "ssr_other_model": ssr[other],
                "n_residuals": int(new_ex.n * len(frames[0].problem.channels)),
            }
            if len(labels) != 2:
                entry = {"true": labels[k], "refitted": labels[other], **entry}
            out[_direction_key(labels, k, other)] = entry
    return out


# ---------------------------------------------------------------------------- separate
def _candidate(problem: Problem, x: np.ndarray, name: str, max_nfev: int):
    """A candidate model: the fit's model with effect ``name`` on and its parameters
    freed, fitted to the existing data from the diagnosis's one-step estimate."""
    from ..diagnosis.score import score_tests

    eff = _effects.resolve([name])[0]
    m = problem.model
    if m.config not in eff.configs:
        raise DesignError(
            f"effect {eff.name!r} does not apply to the {m.config} configuration "
            f"(it applies to {', '.join(eff.configs)})"
        )
    names = problem.names_base()
    base = dict(problem.params_for(x, 0))
    if eff.name in m.effect_names:
        cand = problem
        return cand, x, eff, "already on in the fit"
    free = names + [p for p in eff.names if p not in names]
    cand = problem.like(model=m.with_effects([eff]), free=free, base=base)
    vals = dict(base)
    vals.update({n: v for n, v in problem.values(x).items()})
    x0 = cand.start_vector(vals)
    try:
        s = score_tests(problem, x, effects=[eff])
        if s:
            for n, val in {**s[0].step, **s[0].nuisance}.items():
                if n in cand.names and math.isfinite(val):
                    j = cand.names.index(n)
                    if cand.lower[j] < val < cand.upper[j]:
                        x0[j] = val
    except Exception:  # noqa: BLE001 - no one-step estimate: the effect's typical start
        pass
    res = _fit(cand, x0, uncertainty=False, max_nfev=max_nfev)
    return cand, res.x, eff, f"fitted to the existing data ({res.nfev} evaluations)"


def _at_null(problem: Problem, x: np.ndarray, eff, frame: Frame | None = None) -> bool:
    """Whether the fit put every switch parameter of ``eff`` at its null value: within a
    millionth of its bounds' width, or (``frame`` given: the fit's information) within one
    standard deviation the existing data leave it.  A switch the data do not determine
    (e.g. an offset that is exactly a change of another parameter) moves from its null
    start by rounding alone; the data do not show that effect either way."""
    vals = problem.values(x)
    for p in eff.switches:
        names = [n for n in vals if local_name(n)[0] == p.name]
        null = vals.get("Tc_l", 0.0) if p.name == "Ts_l" else p.null
        if not names:
            return False
        for n in names:
            tol = 1e-6 * (p.upper - p.lower)
            if frame is not None and n in problem.names:
                j = problem.names.index(n)
                var = frame.variances(frame.F_fit, [j])[0]
                if math.isfinite(var) and var >= 0:
                    tol = max(tol, frame.scale_old[j] * math.sqrt(var))
            if abs(vals[n] - null) > tol:
                return False
    return True


# ------------------------------------------------------------------------------- design
def design_input(
    fit,
    *,
    params: Sequence[str] | None = None,
    separate: Sequence[str] | None = None,
    duration: float | None = None,
    rate: float | None = None,
    max_volts: float = MAX_VOLTAGE,
    band_hz: float = MAX_BAND_HZ,
    family: str = "steps",
    starts: int = 4,
    seed: int = 0,
    max_evals: int = DEFAULT_EVALS,
    check: bool = True,
    check_nfev: int = 60,
    executor=None,
    workers: int = 2,
    trust_effects: bool = False,
    accept_changed_data: bool = False,
) -> DesignResult:
    """Design the next experiment's input for a fit (see the module docstring).

    Parameters
    ----------
    fit : str, Path, LoadedFit, FitResult or tuple
        The fit on the existing data (a tuple: a Problem and its parameter vector).
    params : sequence of str, optional
        Target these free parameters instead of the sloppiest direction.
    separate : sequence of str, optional
        Target the discrimination between these two or more catalogue effects: the
        smallest expected SSR gap over every pair (the worst-separated pair) is maximised.
    duration, rate : float, optional
        Length [s] and sampling rate [Hz] of the new experiment (default: the first
        experiment's).
    max_volts : float
        Largest ``|u|`` [V], at most 5 (the amplifier).
    band_hz : float
        Band limit [Hz], at most 5 (thesis §3.2).
    family : {'steps', 'multisine'}
        The input family searched.
    starts, seed : number of optimisation starts, and the seed of their random levels.
    max_evals : evaluations per start (each one Jacobian on the new input).
    check : simulate the designed experiment, refit and measure the achieved gain.
    executor, workers : where the starts run (default: the current executor, else
        ``workers`` local threads; serial for one).
    trust_effects, accept_changed_data : for a fit folder, as
        :func:`rotorbayes.inference.results.load_fit` (its effect files, its changed data files).

    Returns
    -------
    DesignResult

    Raises
    ------
    DesignError
        For a request that cannot be served (unknown effect or parameter, limits outside
        the rig's, both ``params`` and ``separate``).
    """
    t_all = time.perf_counter()
    if params and separate:
        raise DesignError("give either --params or --separate, not both")
    if family not in FAMILIES:
        raise DesignError(f"unknown input family {family!r}; choose from {', '.join(FAMILIES)}")
    if int(starts) < 1:
        raise DesignError(f"--starts {starts}: give at least 1 start")
    if separate is not None:
        separate = [s.strip() for s in separate if s.strip()]
        repeated = sorted({s for s in separate if separate.count(s) > 1})
        if len(separate) < 2 or repeated:
            why = f" ({', '.join(repeated)} given twice)" if repeated else ""
            raise DesignError(
                f"--separate {','.join(separate)}: give two or more different "
                f"effects{why}, e.g. --separate "
                "lower_asymmetric_coulomb,string_damping,lower_stribeck"
            )
        for s in separate:  # unknown names: the registry's own message, before any work
            try:
                _effects.resolve([s])
            except _effects.EffectError as exc:
                raise DesignError(f"--separate: {exc}") from None
    problem, x, source = _as_fit(fit, trust_effects, accept_changed_data)
    duration, rate = _grid_defaults(problem, duration, rate)
    fam = make_family(family, duration, rate, max_volts, band_hz)
    t = fam.t
    settings = {
        "fit": source,
        "duration_s": duration,
        "rate_hz": rate,
        "max_volts": max_volts,
        "band_hz": band_hz,
        "family": family,
        "starts": int(starts),
        "seed": int(seed),
        "max_evals": int(max_evals),
        "noise": "encoder floor per channel (quantisation q/sqrt(12), or the data's "
        "jitter where larger), i.i.d. in the prediction",
        "new_experiment_alpha0": "0 (the string unwound before the new run)",
    }
    seconds: dict[str, float] = {}
    plan = None
    # ------------------------------------------------------------------ the target
    t0 = time.perf_counter()
    if separate:
        labels = list(separate)
        effs = [_effects.resolve([s])[0] for s in labels]
        for eff in effs:
            if problem.model.config not in eff.configs:
                raise DesignError(
                    f"--separate: effect {eff.name!r} does not apply to the "
                    f"{problem.model.config} configuration (it applies to "
                    f"{', '.join(eff.configs)})"
                )
        effects = [e.name for e in effs]
        n_c = len(effects)
        pairs = [(i, j) for i in range(n_c) for j in range(i + 1, n_c)]
        # The ties are read before any fit: a pair's candidates' free sets are the fit's
        # plus each effect's parameters.
        ties = {}
        for i, j in pairs:
            free_ij = set(problem.names_base()) | set(effs[i].names) | set(effs[j].names)
            tie = _ties.tie_between(
                [effects[i], effects[j]],
                free_ij,
                n_experiments=len(problem.experiments),
                prescribed_upper=problem.prescribed_upper,
            )
            if tie is not None:
                ties[(i, j)] = tie
        words = (
            f"tell {effects[0]} from {effects[1]}"
            if n_c == 2
            else f"tell {', '.join(effects[:-1])} and {effects[-1]} apart, every pair"
        )
        target = {"kind": "separate", "effects": effects, "words": words}
        if ties:
            target["tied_pairs"] = [
                {"effects": [effects[i], effects[j]], "tie": str(tie), "procedure": tie.procedure}
                for (i, j), tie in ties.items()
            ]
        separable = [ij for ij in pairs if ij not in ties]
        if not separable:
            return _no_input(problem, list(ties.values()), target, settings, t_all)
        cands = [_candidate(problem, x, s, max_nfev=100) for s in labels]
        frames = [Frame(c[0], c[1]) for c in cands]
        target["candidates"] = {
            lab: {
                "how": c[3],
                "rms_over_floor": c[0].rms_over_floor(c[0].residuals(c[1])),
                "estimates": c[0].values(c[1]),
            }
            for lab, c in zip(labels, cands, strict=True)
        }
        # A candidate whose effect the existing data put at its null value is the fit's
        # own model, which every other candidate contains (its effect at null too): data
        # from it are fitted by the other exactly, whatever the input.  Only the other
        # direction of such a pair can be separated.  Two candidates both at null are
        # both the fit's model: with more than two candidates such a pair is left out of
        # the design (it would hold every input's worst gap at zero) and said so.
        at_null = [_at_null(c[0], c[1], c[2], f) for c, f in zip(cands, frames, strict=True)]
        target["at_null"] = {lab: z for lab, z in zip(labels, at_null, strict=True)}
        designed_pairs, dirs = [], []
        for i, j in separable:
            d = [(a, b) for a, b in ((i, j), (j, i)) if not at_null[a]]
            if d or n_c == 2:
                designed_pairs.append((i, j))
                dirs += d or [(i, j), (j, i)]
        if not designed_pairs:  # every separable pair at null on both sides
            designed_pairs = list(separable)
            dirs = [d for i, j in separable for d in ((i, j), (j, i))]
        target["pairs"] = {
            "designed_for": [[effects[i], effects[j]] for i, j in designed_pairs],
            "both_at_null": [
                [effects[i], effects[j]] for i, j in separable if (i, j) not in designed_pairs
            ],
            "tied": [[effects[i], effects[j]] for i, j in ties],
        }
        plan = _Plan(effects, designed_pairs, separable, ties, at_null)
        objective = _Objective("separate", fam, frames, idx=dirs)
        v = idx = None
    else:
        frame = Frame(problem, x)
        frames = [frame]
        if params:
            idx = []
            for n in params:
                want = [
                    j
                    for j, m in enumerate(frame.names)
                    if m == n
                    or (
                        local_name(m)[0] == n
                        and local_name(m)[1] is not None
                        and local_name(m)[1] < frame.k_old
                    )
                ]
                if not want:
                    raise DesignError(
                        f"--params: {n!r} is not a free parameter of this fit; its free "
                        f"parameters are {', '.join(problem.names)}"
                    )
                idx += [j for j in want if j not in idx]
            v = None
            target = {
                "kind": "params",
                "parameters": [frame.names[j] for j in idx],
                "words": "pin "
                + ", ".join(frame.names[j] for j in idx)
                + " (sum of relative variances)",
            }
            objective = _Objective("params", fam, frames, idx=idx)
        else:
            v, width = frame.sloppiest()
            idx = None
            movers = [
                (frame.names[j], float(v[j])) for j in np.argsort(-np.abs(v)) if abs(v[j]) > 0.25
            ]
            target = {
                "kind": "sloppiest",
                "direction": {n: float(c) for n, c in zip(frame.names, v, strict=True) if c != 0.0},
                "coordinates": "log of each positive parameter, value/scale of signed "
                "ones (as rotorbayes identify)",
                "words": "the fit's sloppiest direction ("
                + ", ".join(f"{n} {c:+.2f}" for n, c in movers)
                + ")",
            }
            tie = _ties.tie_in_direction(
                frame.names[: len(problem.names)],
                v[: len(problem.names)],
                problem.model.effect_names,
                n_experiments=len(problem.experiments),
                prescribed_upper=problem.prescribed_upper,
            )
            if tie is not None:
                return _no_input(problem, [tie], target, settings, t_all)
            objective = _Objective("sloppiest", fam, frames, v=v)
    seconds["target"] = time.perf_counter() - t0
    # ------------------------------------------------------------------ the search
    t0 = time.perf_counter()
    _, u_base = estimation_signal(
        duration, rate=rate, seed=seed, amplitude=max_volts, bandwidth=band_hz
    )
    rng = np.random.default_rng(seed)
    z_starts = [fam.random(rng) for _ in range(int(starts))]
    if family == "steps":
        # One start is the estimation input seen through the family (its levels sampled
        # in the middle of each hold): the search begins where the standard input is.
        mids = np.searchsorted(t, 0.5 * (2.0 / band_hz) + fam.hold * (np.arange(fam.size) + 0.5))
        z_starts[0] = np.clip(u_base[np.minimum(mids, t.size - 1)] / max_volts, -1, 1)
    items = [(i, z, max_evals) for i, z in enumerate(z_starts)]
    runs = dict(run_tasks(_run_start, items, shared=objective, executor=executor, workers=workers))
    runs = [runs[i] for i in range(len(items))]
    best = min(runs, key=lambda r: r["value"])
    u = fam(best["z"])
    seconds["search"] = time.perf_counter() - t0
    # ------------------------------------------------------------------ predictions
    predicted, status, words = _predict(objective, frames, u, u_base, target, plan)
    responses = _responses(objective, frames, t, u, target, v, plan)
    achieved = None
    if check and status != NO_INPUT:
        t0 = time.perf_counter()
        achieved = _achieve(
            objective, frames, t, u, u_base, target, v, idx, seed, check_nfev, predicted, plan
        )
        seconds["check"] = time.perf_counter() - t0
        words += "\n" + achieved.pop("words")
    seconds["total"] = time.perf_counter() - t_all
    return DesignResult(
        status=status,
        target=target,
        words=words,
        t=t,
        u=u,
        baseline=u_base,
        input_family={"description": fam.describe(), **fam.settings(best["z"])},
        predicted=predicted,
        achieved=achieved,
        starts=[
            {
                k: (v_.tolist() if isinstance(v_, np.ndarray) else v_)
                for k, v_ in r.items()
                if k != "z"
            }
            for r in runs
        ],
        settings=settings,
        seconds=seconds,
        responses=responses,
        procedure=plan.procedure() if plan is not None else "",
    )


@dataclass
class _Plan:
    """Which pairs of ``--separate`` candidates the design serves (indices into
    ``effects``): ``designed`` (in the objective), ``separable`` (not tied by the
    registry), ``ties`` (pair -> the registry's Equivalence), ``at_null`` per candidate."""

    effects: list[str]
    designed: list[tuple[int, int]]
    separable: list[tuple[int, int]]
    ties: dict
    at_null: list[bool]

    def names(self, ij) -> str:
        return f"{self.effects[ij[0]]} / {self.effects[ij[1]]}"

    def directions(self, ij) -> list[tuple[int, int]]:
        i, j = ij
        d = [(a, b) for a, b in ((i, j), (j, i)) if not self.at_null[a]]
        return d or [(i, j), (j, i)]

    def procedure(self) -> str:
        return "; ".join(dict.fromkeys(t.procedure for t in self.ties.values()))


def _no_input(problem: Problem, ties: list, target: dict, settings: dict, t_all) -> DesignResult:
    """The registry says no input can help: the words, the procedure, and the existing
    input to repeat after re-zeroing (u.csv).  ``ties``: the registry entries that apply
    (one for a sloppiest direction or two candidates; one per tied pair otherwise)."""
    ex = problem.experiments[0]
    ties = list({str(q): q for q in ties}.values())
    tie = ties[0]
    target = {**target, "tie": str(tie), "tie_effects": list(tie.effects)}
    if len(ties) > 1:
        target["ties"] = [str(q) for q in ties]
    words = " ".join(_ties.no_input_words(q) for q in ties)
    label = ex.name or ex.path or "the first experiment"
    words += (
        f" u.csv holds the existing experiment's input ({label}, "
        f"{ex.t[-1] - ex.t[0]:g} s) to run again: with the same input, what differs "
        "between the two runs is what the procedure changed."
    )
    return DesignResult(
        status=NO_INPUT,
        target=target,
        words=words,
        t=np.asarray(ex.t - ex.t[0]),
        u=np.asarray(ex.u),
        baseline=None,
        input_family={
            "description": "the existing experiment's input, to run again after the procedure",
            "family": "repeat",
        },
        predicted={},
        achieved=None,
        starts=[],
        settings=settings,
        seconds={"total": time.perf_counter() - t_all},
        procedure="; ".join(dict.fromkeys(q.procedure for q in ties)),
    )


def _predict(objective: _Objective, frames, u, u_base, target, plan=None):
    f = frames[0]
    t = objective.family.t
    kind = target["kind"]
    if kind == "sloppiest":
        v = objective.v
        _, sd_old = f.sloppiest()
        Jn, Jb = f.new_rows(t, u), f.new_rows(t, u_base)
        sd_new = f.sd_along(f.F_old + Jn.T @ Jn, v)
        sd_base = f.sd_along(f.F_old + Jb.T @ Jb, v)
        pred = {
            "sd_existing_data": sd_old,
            "sd_with_design": sd_new,
            "sd_with_estimation_input": sd_base,
            "gain_vs_existing": sd_old / sd_new,
            "gain_vs_estimation_input": sd_base / sd_new,
            "units": "1-sigma width along the direction, relative units (white noise at the floor)",
        }
        gain = sd_old / sd_new
        words = (
            f"Target: {target['words']}. Its predicted 1-sigma width falls from "
            f"{sd_old:.3g} (existing data) to {sd_new:.3g} with the designed input, "
            f"against {sd_base:.3g} with the standard estimation input of the same "
            f"length and limits: {sd_base / sd_new:.2f}x narrower than that input, "
            f"{gain:.2f}x narrower than now."
        )
    elif kind == "params":
        idx = objective.idx
        old = {
            f.names[j]: math.sqrt(max(float(s), 0.0))
            for j, s in zip(
                idx, f.variances(f.F_old + 1e-300 * np.eye(len(f.names)), idx), strict=True
            )
        }
        Jn, Jb = f.new_rows(t, u), f.new_rows(t, u_base)
        new = {
            f.names[j]: math.sqrt(s)
            for j, s in zip(idx, f.variances(f.F_old + Jn.T @ Jn, idx), strict=True)
        }
        base = {
            f.names[j]: math.sqrt(s)
            for j, s in zip(idx, f.variances(f.F_old + Jb.T @ Jb, idx), strict=True)
        }
        pred = {
            "sd_existing_data": old,
            "sd_with_design": new,
            "sd_with_estimation_input": base,
            "gain_vs_existing": {n: old[n] / new[n] for n in new},
            "gain_vs_estimation_input": {n: base[n] / new[n] for n in new},
            "units": "relative 1-sigma widths (white noise at the floor)",
        }
        gain = min(old[n] / new[n] for n in new)
        words = (
            "Target: "
            + target["words"]
            + ". Predicted relative 1-sigma widths: "
            + "; ".join(
                f"{n} {old[n]:.3g} -> {new[n]:.3g} (estimation input: {base[n]:.3g})" for n in new
            )
            + "."
        )
    else:
        return _predict_separation(objective, u, u_base, target, plan)
    status = DESIGNED if gain >= MIN_GAIN else LITTLE_GAIN
    if status == LITTLE_GAIN:
        words += (
            " The best input found narrows the target by less than "
            f"{100 * (MIN_GAIN - 1):.0f} %: one more experiment of this length and "
            "these limits adds little; the existing data already hold what such an "
            "input can tell."
        )
    return pred, status, words


def _predict_separation(objective: _Objective, u, u_base, target, plan: _Plan):
    """Predicted gaps of every separable pair, with the design and the estimation input;
    the pair whose gap is smallest limits the design."""
    labels = plan.effects
    gd = objective.gaps(u)
    gb = objective.gaps(u_base)
    key = {d: _direction_key(labels, *d) for d in gd}
    shown = [d for ij in plan.separable for d in (ij, ij[::-1])]
    use = objective.idx
    pairs = []
    for ij in plan.separable:
        dd = plan.directions(ij)
        pairs.append(
            {
                "effects": [labels[ij[0]], labels[ij[1]]],
                "directions_designed_for": [key[d] for d in dd],
                "designed_for": ij in plan.designed,
                "ssr_gap_with_design": min(gd[d] for d in dd),
                "ssr_gap_with_estimation_input": min(gb[d] for d in dd),
            }
        )
    designed = [p for p in pairs if p["designed_for"]]
    limit = min(designed, key=lambda p: p["ssr_gap_with_design"])
    gain = min(gd[d] for d in use)
    base = min(gb[d] for d in use)
    pred = {
        "ssr_gap_with_design": {key[d]: gd[d] for d in shown},
        "ssr_gap_with_estimation_input": {key[d]: gb[d] for d in shown},
        "gain_vs_estimation_input": gain / max(base, 1e-12),
        "directions_designed_for": [key[d] for d in use],
        "pairs": pairs,
        "limiting_pair": limit["effects"],
        "units": "expected SSR gap in noise variances (floor^2): the part of the "
        "prediction difference the other model cannot absorb by refitting",
    }
    nulls = [lab for lab, z in target.get("at_null", {}).items() if z]
    if len(labels) == 2:
        a, b = labels
        words = (
            f"Target: {target['words']}. Expected SSR gap between the two models' best "
            f"fits to old and new data (noise variances, linearised): {gain:.3g} with the "
            f"designed input ({a} true {gd[(0, 1)]:.3g}, {b} true {gd[(1, 0)]:.3g}), "
            f"{base:.3g} with the standard estimation input."
        )
        if len(nulls) == 1:
            other = b if nulls[0] == a else a
            words += (
                f" The existing data put {nulls[0]}'s parameters at their null value: "
                f"that candidate is the fit's own model, which {other} contains, so "
                f"data from it are fitted by {other} exactly whatever the input; the "
                f"design shows whether {other} is needed ({other} true)."
            )
        elif len(nulls) == 2:
            words += (
                " The existing data put both effects at their null values: neither is "
                "supported by them, and either candidate fits data from the other."
            )
        both_null = len(nulls) == 2
    else:
        words = (
            f"Target: {target['words']}. The design maximises the smallest expected SSR "
            "gap over the pairs (noise variances, linearised; a pair's gap is the "
            "smaller of its two directions, each candidate true in turn with the other "
            "refitted to old and new data): "
            f"{gain:.3g} with the designed input, {base:.3g} with the standard "
            f"estimation input; the pair that limits the design is "
            f"{' / '.join(limit['effects'])}. Per pair, design (estimation input): "
            + "; ".join(
                f"{' / '.join(p['effects'])} {p['ssr_gap_with_design']:.3g} "
                f"({p['ssr_gap_with_estimation_input']:.3g})"
                + ("" if p["designed_for"] else " [not designed for]")
                for p in pairs
            )
            + "."
        )
        if nulls:
            words += (
                " The existing data put "
                + ", ".join(nulls)
                + " at "
                + ("its" if len(nulls) == 1 else "their")
                + " null value: such a "
                "candidate is the fit's own model, which every other candidate "
                "contains, so only the other candidate's direction of its pairs is "
                "designed for (does the other effect show?)."
            )
        left = target.get("pairs", {}).get("both_at_null", [])
        if left:
            words += (
                " Left out of the design: "
                + "; ".join(" / ".join(p) for p in left)
                + " (both at their null values: both are the fit's own model, no "
                "data can tell them apart at these fits)."
            )
        both_null = not any(
            p["designed_for"] and not all(target["at_null"][e] for e in p["effects"]) for p in pairs
        )
    poor = {
        lab: max(
            (r for r in c["rms_over_floor"].values() if r is not None and math.isfinite(r)),
            default=0.0,
        )
        for lab, c in target.get("candidates", {}).items()
    }
    poor = {lab: r for lab, r in poor.items() if r > POOR_FIT}
    if poor:
        words += (
            " The candidates do not all fit the existing data: "
            + ", ".join(f"{lab} {r:.0f}x the floor" for lab, r in poor.items())
            + ". The gaps assume "
            "each candidate sits at its best fit; far from it the refits of the check move "
            "the old data's misfit too, and the achieved gaps need not follow the predicted "
            "ones. Fit the data well first (diagnose, restarts), then design."
        )
    if plan.ties:
        words += " " + " ".join(
            f"No input can tell {plan.names(ij)} apart: {tie}. This holds in {tie.scope}, "
            f"whatever the input. What separates them: {tie.procedure} (a second experiment;"
            " the designed input serves the other pairs)."
            for ij, tie in plan.ties.items()
        )
    status = DESIGNED if gain >= 9.0 and not both_null else LITTLE_GAIN
    if status == LITTLE_GAIN:
        words += (
            " Even the best input found leaves a gap below 9 noise variances "
            "(3 sd): these effects cannot be told apart reliably by one more "
            "experiment of this length and these limits."
        )
    return pred, status, words


def _responses(objective, frames, t, u, target, v, plan=None) -> dict:
    """Predicted angles on the designed input (for the figure) and what tells the target."""
    out = {}
    for k, f in enumerate(frames):
        p = f.new_problem(t, u)
        sim = p.simulate(p.x_from(f.params_new))
        label = target["effects"][k] if target["kind"] == "separate" else "fit"
        out[label] = {"theta_u": sim.theta_u, "theta_l": sim.theta_l}
    if target["kind"] == "separate":
        # The pair that limits the design (with two candidates, the pair).
        i, j = (0, 1)
        if len(frames) > 2:
            g = objective.gaps(u, objective.idx)
            i, j = min(plan.designed, key=lambda ij: min(g[d] for d in plan.directions(ij)))
        Ja, ya = frames[i].new_rows(t, u, with_prediction=True)
        Jb, yb = frames[j].new_rows(t, u, with_prediction=True)
        what = "prediction difference / floor"
        if len(frames) > 2:
            what += f" ({plan.effects[i]} - {plan.effects[j]}, the limiting pair)"
        out["difference"] = (what, ya - yb)
    elif target["kind"] == "sloppiest":
        f = frames[0]
        Jn = f.new_rows(t, u)
        sd_old = 1.0 / math.sqrt(max(np.linalg.eigvalsh(f.F_fit)[0], 1e-300))
        out["difference"] = (
            "change / floor for one existing-data sd along the direction",
            Jn @ (sd_old * v),
        )
    out["channels"] = frames[0].problem.channels
    return out


def _achieve(
    objective, frames, t, u, u_base, target, v, idx, seed, nfev, predicted, plan=None
) -> dict:
    kind = target["kind"]
    if kind == "separate":
        labels = target["effects"]
        d = _check_separation(frames, labels, t, u, seed, nfev)
        b = _check_separation(frames, labels, t, u_base, seed, nfev)
        keys = predicted["directions_designed_for"]
        gd = min(d[k]["ssr_gap"] for k in keys)
        gb = min(b[k]["ssr_gap"] for k in keys)
        pred = min(predicted["ssr_gap_with_design"][k] for k in keys)
        out = {
            "design": d,
            "estimation_input": b,
            "ssr_gap_with_design": gd,
            "ssr_gap_with_estimation_input": gb,
        }
        if len(labels) == 2:
            words = (
                f"Check (each model's simulated data fitted by both, old and new data "
                f"together): achieved SSR gap {gd:.3g} noise variances with the design "
                f"(predicted {pred:.3g}), {gb:.3g} with the estimation input."
            )
        else:
            ppred = {tuple(q["effects"]): q for q in predicted["pairs"]}
            pairs = []
            for ij in list(plan.separable) + list(plan.ties):
                ks = [_direction_key(labels, *dd) for dd in plan.directions(ij)]
                names = (labels[ij[0]], labels[ij[1]])
                q = ppred.get(names, {})
                pairs.append(
                    {
                        "effects": list(names),
                        "tied": ij in plan.ties,
                        "designed_for": ij in plan.designed,
                        "predicted_with_design": q.get("ssr_gap_with_design"),
                        "ssr_gap_with_design": min(d[k]["ssr_gap"] for k in ks),
                        "ssr_gap_with_estimation_input": min(b[k]["ssr_gap"] for k in ks),
                    }
                )
            designed = [q for q in pairs if q["designed_for"]]
            limit = min(designed, key=lambda q: q["ssr_gap_with_design"])
            out["pairs"] = pairs
            out["limiting_pair"] = limit["effects"]
            words = (
                "Check (each candidate's simulated data fitted by every candidate, old "
                f"and new data together): achieved smallest gap {gd:.3g} noise "
                f"variances with the design (predicted {pred:.3g}), {gb:.3g} with the "
                "estimation input; the pair that limits it is "
                f"{' / '.join(limit['effects'])}. Per pair, achieved with the design "
                "(predicted; estimation input): "
                + "; ".join(
                    f"{' / '.join(q['effects'])} {q['ssr_gap_with_design']:.3g} ("
                    + (
                        "tied, no input separates it"
                        if q["tied"]
                        else f"{q['predicted_with_design']:.3g}"
                    )
                    + f"; {q['ssr_gap_with_estimation_input']:.3g})"
                    for q in pairs
                )
                + "."
            )
        if gd < 0.5 * pred:
            words += (
                " The achieved gap is far below the linearised prediction: the "
                "refitted model moved further than one linear step reaches, so the "
                "prediction does not hold for this input; trust the achieved number."
            )
        out["words"] = words
        return out
    f = frames[0]
    d = _check_information(f, t, u, kind, v, idx, seed, nfev)
    b = _check_information(f, t, u_base, kind, v, idx, seed, nfev)
    if kind == "sloppiest":
        from ..inference.uncertainty import fit_uncertainty

        unc = fit_uncertainty(f.problem, f.x, f.J_old)
        vv = v[: len(f.problem.names)]
        C = unc.cov / np.outer(f.scale_old, f.scale_old)
        sd_old_honest = math.sqrt(max(float(vv @ C @ vv), 0.0))
        out = {
            "design": d,
            "estimation_input": b,
            "sd_existing_data_honest": sd_old_honest,
            "gain_vs_existing": predicted["sd_existing_data"] / d["sd_white"],
            "gain_vs_existing_honest": sd_old_honest / d["sd_honest"],
            "gain_vs_estimation_input": b["sd_white"] / d["sd_white"],
            "gain_vs_estimation_input_honest": b["sd_honest"] / d["sd_honest"],
        }
        words = (
            f"Check (the designed experiment simulated at the fit, quantised, fitted "
            f"together with the existing data): width {d['sd_white']:.3g} (white noise)"
            f" / {d['sd_honest']:.3g} (honest errors) with the design against "
            f"{b['sd_white']:.3g} / {b['sd_honest']:.3g} with the estimation input: "
            f"achieved {out['gain_vs_estimation_input']:.2f}x / "
            f"{out['gain_vs_estimation_input_honest']:.2f}x narrower (predicted "
            f"{predicted['gain_vs_estimation_input']:.2f}x); against the existing data "
            f"alone {out['gain_vs_existing']:.2f}x / {out['gain_vs_existing_honest']:.2f}x"
            f" (predicted {predicted['gain_vs_existing']:.2f}x)."
        )
    else:
        out = {
            "design": d,
            "estimation_input": b,
            "gain_vs_estimation_input": {
                n: b["sd_white"][n] / d["sd_white"][n] for n in d["sd_white"]
            },
            "gain_vs_estimation_input_honest": {
                n: b["sd_honest"][n] / max(d["sd_honest"][n], 1e-300) for n in d["sd_honest"]
            },
        }
        words = (
            "Check (simulated, quantised, refitted with the existing data): relative "
            "widths with the design / the estimation input: "
            + "; ".join(
                f"{n} {d['sd_white'][n]:.3g} / {b['sd_white'][n]:.3g} (honest "
                f"{d['sd_honest'][n]:.3g} / {b['sd_honest'][n]:.3g})"
                for n in d["sd_white"]
            )
            + "."
        )
    out["words"] = words
    return out

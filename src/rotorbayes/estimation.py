"""Least-squares estimation (the thesis's lsqnonlin method), several experiments at once,
and multistart.

A :class:`Problem` binds a configuration, its active effects, one or more experiments,
the free parameters and the fitted channels.  Its residual vector is

    r = concat over experiments e and channels c of  w_c * (y_e,c - yhat_e,c(P))

(thesis eqs. 4.4, 4.10, 5.19).  ``alpha0`` is a per-experiment nuisance parameter: with
several experiments each gets its own (the thesis's own recommendation, §5.3.2).

The optimiser works on scaled variables ``z = x / scale`` so parameters from 1e-3 to 1e1
are treated alike; the Jacobian is computed by forward differences with all perturbed
parameter sets simulated in one parallel batch, and kept with the result (standard
errors, Fisher information, later the sampler's starting covariance).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares
from scipy.stats import qmc

from . import metrics as _metrics
from .data import Experiment
from .effects import BASE_PARAMETERS
from .effects import get as get_effect
from .model import DEFAULT_STEP, Simulator, check_config
from .parameters import INFO, NAMES, ParameterError, check_names, resolve

CHANNELS = ("theta_u", "theta_l")
#: Penalty residual [rad] returned for parameter sets the integrator rejects.
FAIL_RESIDUAL = 1e3


def _local_name(name: str) -> tuple[str, int | None]:
    """Split ``'alpha0[2]'`` into ``('alpha0', 2)``."""
    if name.endswith("]") and "[" in name:
        base, idx = name[:-1].split("[", 1)
        return base, int(idx)
    return name, None


@dataclass
class Problem:
    """A least-squares problem over one or more experiments.

    Parameters
    ----------
    config : {'upper', 'coupled', 'brake'}
    experiments : sequence of Experiment
    free : sequence of str, optional
        Parameters to estimate.  Default: the configuration's parameters (thesis
        tables 4.1-4.3 columns) plus those of the active effects; ``J_u`` stays fixed
        at eq. 5.4's value unless named.  ``alpha0`` may be listed: with several
        experiments it becomes one parameter per experiment (``alpha0[0]``, ...).
    base : mapping, str or None
        The starting / fixed values of all parameters (a named set, TOML file or
        mapping; default the configuration's P_ref set).
    effects : iterable of str
        Catalogue effects whose physics is switched on.
    channels : sequence of str
        Fitted channels, ``'theta_u'`` and/or ``'theta_l'``.  Default ``theta_u`` for
        the upper configuration, ``theta_l`` otherwise (thesis eqs. 4.4, 4.10).
    weights : mapping, optional
        Weight per channel (default 1).
    prescribed_upper : bool
        Drive the lower disc with the measured upper angle instead of the motor model.
    """

    config: str
    experiments: Sequence[Experiment]
    free: Sequence[str] | None = None
    base: object = None
    effects: Iterable[str] = ()
    channels: Sequence[str] | None = None
    weights: Mapping[str, float] | None = None
    prescribed_upper: bool = False
    shape: str = "exp"
    step: float = DEFAULT_STEP
    fixed: Sequence[str] = ()
    names: list[str] = field(init=False)

    def __post_init__(self):
        check_config(self.config)
        self.effects = tuple(self.effects)
        for e in self.effects:
            get_effect(e)
        if isinstance(self.experiments, Experiment):
            self.experiments = [self.experiments]
        if not self.experiments:
            raise ValueError("give at least one experiment")
        self.base = (
            resolve(self.base, config=self.config)
            if not isinstance(self.base, dict) or set(self.base) != set(NAMES)
            else dict(self.base)
        )
        for i, ex in enumerate(self.experiments):
            where = ex.path or ex.name or f"experiment {i}"
            if self.config == "upper" and ex.has_lower:
                raise ValueError(
                    f"{where}: has a theta_l column but the configuration is "
                    "'upper' (string removed); use --model coupled or brake"
                )
            if self.config != "upper" and not ex.has_lower:
                raise ValueError(
                    f"{where}: has no theta_l column, so it is an upper-"
                    f"configuration file; use --model upper, not {self.config!r}"
                )
        if self.channels is None:
            self.channels = ("theta_u",) if self.config == "upper" else ("theta_l",)
        for c in self.channels:
            if c not in CHANNELS:
                raise ValueError(f"unknown channel {c!r}; choose from {', '.join(CHANNELS)}")
        if self.prescribed_upper and "theta_u" in self.channels:
            raise ValueError(
                "with the measured theta_u as input, theta_u cannot also be fitted; "
                "use channels=('theta_l',)"
            )
        self.weights = {c: float((self.weights or {}).get(c, 1.0)) for c in self.channels}
        if self.free is None:
            free = list(BASE_PARAMETERS[self.config])
            for e in self.effects:
                free += [p for p in get_effect(e).parameters if p not in free]
            if self.config != "upper" and len(self.experiments) > 1:
                free.append("alpha0")
        else:
            free = list(self.free)
        check_names([_local_name(n)[0] for n in free], where="free parameters")
        for n in self.fixed:
            if n in free:
                raise ParameterError(
                    f"{n} is both fixed and free; remove it from one of the two lists"
                )
        if self.config == "upper":
            bad = [
                n
                for n in free
                if n
                in (
                    "J_l",
                    "k_alpha",
                    "Tc_l",
                    "dTc_l",
                    "b_l",
                    "db_l",
                    "Ts_l",
                    "ws_l",
                    "delta_l",
                    "alpha0",
                    "c_alpha",
                )
            ]
            if bad:
                raise ParameterError(
                    f"{', '.join(bad)} do not enter the upper configuration "
                    "(string removed); remove them from the free list"
                )
        names: list[str] = []
        for n in free:
            if n == "alpha0" and len(self.experiments) > 1:
                names += [f"alpha0[{i}]" for i in range(len(self.experiments))]
            else:
                names.append(n)
        if len(set(names)) != len(names):
            raise ParameterError(f"a free parameter is listed twice: {names}")
        self.names = names
        self.sims = [self.simulator_for(ex) for ex in self.experiments]
        self.lower = np.array([INFO[_local_name(n)[0]].lower for n in names])
        self.upper = np.array([INFO[_local_name(n)[0]].upper for n in names])
        self.n_residuals = sum(ex.n for ex in self.experiments) * len(self.channels)

    def simulator_for(self, ex: Experiment) -> Simulator:
        """A :class:`~rotorbayes.Simulator` of this problem's model for experiment ``ex``."""
        return Simulator(
            self.config,
            ex.u,
            ex.dt,
            effects=self.effects,
            shape=self.shape,
            step=self.step,
            theta_u=ex.theta_u if self.prescribed_upper else None,
        )

    # ----------------------------------------------------------------------------- maps
    def x_from(self, params: Mapping[str, float]) -> np.ndarray:
        """Free-parameter vector from a mapping (``alpha0[i]`` falls back to ``alpha0``)."""
        out = []
        for n in self.names:
            base, _ = _local_name(n)
            out.append(float(params[n] if n in params else params[base]))
        return np.array(out)

    def params_for(self, x: np.ndarray, i: int) -> dict[str, float]:
        """The full parameter set of experiment ``i`` at free vector ``x``."""
        p = dict(self.base)
        for n, v in zip(self.names, x, strict=True):
            base, idx = _local_name(n)
            if idx is None or idx == i:
                p[base] = float(v)
        return p

    def values(self, x: np.ndarray) -> dict[str, float]:
        """``{name: value}`` of the free parameters."""
        return {n: float(v) for n, v in zip(self.names, x, strict=True)}

    def check_start(self, x: np.ndarray) -> None:
        """Raise :class:`ParameterError` if a start value lies outside its bounds."""
        for n, v, lo, hi in zip(self.names, x, self.lower, self.upper, strict=True):
            if not (lo <= v <= hi):
                unit = INFO[_local_name(n)[0]].unit
                raise ParameterError(
                    f"start value {n} = {v:g} {unit} lies outside the bounds "
                    f"[{lo:g}, {hi:g}]; choose a start inside them"
                )

    # ------------------------------------------------------------------------ residuals
    def _channel_residual(self, ex: Experiment, thu, thl) -> np.ndarray:
        parts = []
        for c in self.channels:
            sim = thu if c == "theta_u" else thl
            meas = ex.theta_u if c == "theta_u" else ex.theta_l
            parts.append(self.weights[c] * (meas - sim))
        return np.concatenate(parts)

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """Weighted residual vector [rad]; failed simulations give a large penalty."""
        out = []
        for i, (ex, sim) in enumerate(zip(self.experiments, self.sims, strict=True)):
            kv = sim.kernel_vector(self.params_for(x, i))
            st, thu, thl = sim.angles(kv)
            if st != 0:
                out.append(np.full(ex.n * len(self.channels), FAIL_RESIDUAL))
            else:
                out.append(self._channel_residual(ex, thu, thl))
        return np.concatenate(out)

    def residuals_batch(self, X: np.ndarray) -> np.ndarray:
        """Residual vectors of many free vectors (rows), simulated in parallel."""
        X = np.atleast_2d(X)
        R = np.empty((X.shape[0], self.n_residuals))
        off = 0
        for i, (ex, sim) in enumerate(zip(self.experiments, self.sims, strict=True)):
            KV = np.array([sim.kernel_vector(self.params_for(x, i)) for x in X])
            st, thu, thl = sim.run_batch(KV)
            m = ex.n * len(self.channels)
            for j in range(X.shape[0]):
                if st[j] != 0:
                    R[j, off : off + m] = FAIL_RESIDUAL
                else:
                    R[j, off : off + m] = self._channel_residual(ex, thu[j], thl[j])
            off += m
        return R

    def simulate(self, x: np.ndarray, i: int = 0):
        """Full :class:`~rotorbayes.Simulation` of experiment ``i`` at ``x``."""
        return self.sims[i].simulate(self.params_for(x, i), raise_on_failure=False)


@dataclass
class FitResult:
    """Outcome of :func:`fit`.

    Attributes
    ----------
    names, x, x0 : list, arrays
        Free parameter names, estimates and start values.
    stderr : array
        Standard errors from the Gauss-Newton covariance ``s² (JᵀJ)⁻¹`` (``nan`` where
        the information matrix is singular).
    jac : array (n_residuals, k)
        Jacobian of the residuals at the solution (in parameter units).
    ssr, cost : float
        Sum of squared residuals [rad²] and ``ssr / 2``.
    success : bool
        The optimiser met a convergence criterion; ``message`` says which, or why not.
    """

    names: list[str]
    x: np.ndarray
    x0: np.ndarray
    stderr: np.ndarray
    jac: np.ndarray
    ssr: float
    n_residuals: int
    success: bool
    message: str
    nfev: int
    njev: int
    seconds: float
    problem: Problem = field(repr=False)

    @property
    def values(self) -> dict[str, float]:
        """``{name: estimate}``."""
        return dict(zip(self.names, map(float, self.x), strict=True))

    @property
    def params(self) -> dict[str, float]:
        """Complete parameter set of the first experiment at the estimate."""
        return self.problem.params_for(self.x, 0)

    def correlation(self) -> np.ndarray:
        """Parameter correlation matrix from the Gauss-Newton covariance."""
        cov = self.covariance()
        d = np.sqrt(np.abs(np.diag(cov)))
        with np.errstate(invalid="ignore", divide="ignore"):
            return cov / np.outer(d, d)

    def covariance(self) -> np.ndarray:
        """Gauss-Newton covariance ``s² (JᵀJ)⁻¹`` with ``s² = SSR / (n - k)``."""
        k = len(self.names)
        s2 = self.ssr / max(self.n_residuals - k, 1)
        return s2 * np.linalg.pinv(self.jac.T @ self.jac, rcond=1e-13)

    def sloppy_directions(self) -> tuple[np.ndarray, np.ndarray]:
        """Eigenvalues (ascending) and eigenvectors of the Fisher information in
        relative (log-parameter) coordinates: small eigenvalues are directions along
        which the fit barely changes."""
        Jr = self.jac * np.where(self.x != 0, self.x, 1.0)
        w, V = np.linalg.eigh(Jr.T @ Jr)
        return w, V


def _scale(problem: Problem, x0: np.ndarray) -> np.ndarray:
    """Typical magnitudes of the free parameters (for the optimiser's variables)."""
    width = problem.upper - problem.lower
    return np.maximum(np.abs(x0), 1e-3 * width)


def fit(
    problem: Problem,
    x0=None,
    *,
    ftol: float = 1e-10,
    xtol: float = 1e-10,
    gtol: float = 1e-10,
    max_nfev: int = 200,
    fd_step: float = 1e-6,
    verbose: bool = False,
    parallel: bool = True,
    callback: Callable[[int, float], None] | None = None,
) -> FitResult:
    """Least squares from a start (thesis: MATLAB ``lsqnonlin``; here scipy's
    trust-region-reflective ``least_squares`` with bounds).

    Parameters
    ----------
    problem : Problem
    x0 : array or mapping, optional
        Start values (default: the problem's base set).
    ftol, xtol, gtol : float
        Convergence tolerances of :func:`scipy.optimize.least_squares`.
    max_nfev : int
        Largest number of residual evaluations (Jacobians not counted).
    fd_step : float
        Forward-difference step in scaled variables (relative to each parameter's
        magnitude).
    parallel : bool
        Simulate the Jacobian's perturbed sets in one parallel batch.
    callback : callable, optional
        Called as ``callback(n_evaluations, ssr)`` after each residual evaluation.

    Returns
    -------
    FitResult
        Also when the optimiser did not converge (``success`` False; ``message`` why).
    """
    if x0 is None:
        x0 = problem.x_from(problem.base)
    elif isinstance(x0, Mapping):
        x0 = problem.x_from({**problem.base, **x0})
    x0 = np.asarray(x0, float)
    problem.check_start(x0)
    scale = _scale(problem, x0)
    lo, hi = problem.lower / scale, problem.upper / scale
    counter = {"n": 0, "best": math.inf}

    last: dict = {}

    def fun(z):
        r = problem.residuals(z * scale)
        # The optimiser asks for the Jacobian at the point it just evaluated.
        last["z"], last["r"] = z.copy(), r
        counter["n"] += 1
        s = float(r @ r)
        counter["best"] = min(counter["best"], s)
        if verbose and counter["n"] % 10 == 0:
            print(
                f"  evaluation {counter['n']:4d}  SSR {s:.6e}  best {counter['best']:.6e}",
                flush=True,
            )
        if callback is not None:
            callback(counter["n"], s)
        return r

    def jac(z):
        if "z" in last and np.array_equal(z, last["z"]):
            r0 = last["r"]
        else:
            r0 = problem.residuals(z * scale)
        k = z.size
        Z = np.repeat(z[None, :], k, axis=0)
        steps = np.empty(k)
        for j in range(k):
            # Step inwards at an upper bound so perturbed sets stay feasible.
            h = fd_step * (1.0 if z[j] + fd_step <= hi[j] else -1.0)
            Z[j, j] += h
            steps[j] = h
        if parallel:
            R = problem.residuals_batch(Z * scale)
        else:
            R = np.array([problem.residuals(zz * scale) for zz in Z])
        return ((R - r0[None, :]) / steps[:, None]).T

    t0 = time.perf_counter()
    res = least_squares(
        fun,
        x0 / scale,
        jac=jac,
        bounds=(lo, hi),
        method="trf",
        x_scale=1.0,
        ftol=ftol,
        xtol=xtol,
        gtol=gtol,
        max_nfev=max_nfev,
    )
    seconds = time.perf_counter() - t0
    x = res.x * scale
    J = jac(res.x) / scale[None, :]
    r = problem.residuals(x)
    ssr_val = float(r @ r)
    out = FitResult(
        names=list(problem.names),
        x=x,
        x0=x0,
        stderr=np.full(x.size, np.nan),
        jac=J,
        ssr=ssr_val,
        n_residuals=r.size,
        success=bool(res.status > 0),
        message=_explain(res),
        nfev=int(res.nfev),
        njev=int(res.njev or 0),
        seconds=seconds,
        problem=problem,
    )
    cov = out.covariance()
    with np.errstate(invalid="ignore"):
        out.stderr = np.sqrt(np.diag(cov))
    return out


def _explain(res) -> str:
    """Plain-words reason the optimiser stopped."""
    reasons = {
        -1: "improper input parameters",
        0: "stopped: the maximum number of evaluations was reached before convergence "
        "(raise max_nfev or start closer)",
        1: "converged: gradient small (gtol)",
        2: "converged: cost change small (ftol)",
        3: "converged: step small (xtol)",
        4: "converged: cost change and step small (ftol and xtol)",
    }
    return reasons.get(res.status, res.message)


# --------------------------------------------------------------------------- quality
def quality(
    problem: Problem,
    x: np.ndarray,
    experiments: Sequence[Experiment] | None = None,
    *,
    k: int | None = None,
) -> list[dict]:
    """Per experiment and channel (theta_l, theta_u, alpha as in the thesis): R², NRMSE
    fit %, max |error|, SSR, plus AICc and BIC of the fitted channels.

    ``experiments`` default to the problem's own (estimation data); pass validation
    experiments to evaluate the same parameters on other inputs (``alpha0`` of a
    validation experiment is taken from ``problem.base``).
    """
    exps = problem.experiments if experiments is None else experiments
    k = len(problem.names) if k is None else k
    rows = []
    for i, ex in enumerate(exps):
        own = experiments is None
        p = problem.params_for(x, i if own else 0)
        if not own and "alpha0" not in problem.names:
            p["alpha0"] = problem.base["alpha0"]
        sim = problem.sims[i] if own else problem.simulator_for(ex)
        s = sim.simulate(p, raise_on_failure=False)
        chans = {"theta_u": (ex.theta_u, s.theta_u)}
        if ex.has_lower:
            chans["theta_l"] = (ex.theta_l, s.theta_l)
            a0 = p["alpha0"]
            chans["alpha"] = (ex.theta_l - ex.theta_u + a0, s.theta_l - s.theta_u + a0)
        fits = {}
        for c, (y, yh) in chans.items():
            if problem.prescribed_upper and c == "theta_u":
                continue
            if not np.all(np.isfinite(yh)):
                continue
            fits[c] = _metrics.channel_fit(c, y, yh)
        fitted_ssr = sum(fits[c].ssr for c in problem.channels if c in fits)
        n = ex.n * len(problem.channels)
        rows.append(
            {
                "experiment": ex.name or (ex.path or f"experiment {i}"),
                "channels": {c: f.as_dict() for c, f in fits.items()},
                "aicc": _metrics.aicc(fitted_ssr, n, k) if fitted_ssr > 0 else -math.inf,
                "bic": _metrics.bic(fitted_ssr, n, k) if fitted_ssr > 0 else -math.inf,
                "simulation": s,
            }
        )
    return rows


# ------------------------------------------------------------------------- multistart
@dataclass
class MultistartResult:
    """End points of many fits from different starts."""

    names: list[str]
    starts: np.ndarray
    ends: np.ndarray
    ssr: np.ndarray
    success: np.ndarray
    clusters: np.ndarray
    fits: list[FitResult] = field(repr=False)

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
        text = describe_spread(self.names, self.ends, self.ssr, flat=flat)
        best = float(np.min(self.ssr))
        worse = self.ssr > best * (1 + flat) + 1e-300
        if worse.any():
            n_cl = len(set(self.clusters[worse].tolist()))
            stuck = [f for f, w in zip(self.fits, worse, strict=True) if w and f.nfev <= 2]
            text += (
                f"\n{int(worse.sum())} starts stopped elsewhere, in {n_cl} other "
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
        return X
    from scipy.stats import norm

    fac = np.exp(spread * norm.ppf(np.clip(U, 1e-9, 1 - 1e-9)))
    X = np.where(around != 0, around * fac, spread * (U - 0.5) * (problem.upper - problem.lower))
    return np.clip(X, problem.lower, problem.upper)


def multistart(
    problem: Problem,
    n_starts: int = 32,
    *,
    seed: int = 0,
    around=None,
    spread: float = 0.3,
    workers: int = 2,
    progress: bool = True,
    **fit_kw,
) -> MultistartResult:
    """Fit from ``n_starts`` start points in parallel threads and cluster the end points.

    Parameters
    ----------
    around : array or mapping, optional
        Centre of a log-normal spread of starts (``spread`` is its log-sd); default a
        Latin hypercube over the parameter bounds.
    workers : int
        Parallel fits (the integrator releases the GIL).
    """
    rng = np.random.default_rng(seed)
    if isinstance(around, Mapping):
        around = problem.x_from({**problem.base, **around})
    starts = latin_hypercube(problem, n_starts, rng, around=around, spread=spread)
    done = {"n": 0}
    t0 = time.perf_counter()

    def one(i):
        try:
            r = fit(problem, starts[i], parallel=False, **fit_kw)
        except ParameterError:
            r = None
        done["n"] += 1
        if progress:
            el = time.perf_counter() - t0
            print(
                f"  start {done['n']:3d}/{n_starts} done "
                f"({el:.0f} s elapsed, ~{el / done['n'] * (n_starts - done['n']):.0f} s left)",
                flush=True,
            )
        return r

    with ThreadPoolExecutor(max_workers=max(1, workers)) as pool:
        fits = list(pool.map(one, range(n_starts)))
    ok = [f for f in fits if f is not None]
    ends = np.array([f.x for f in ok])
    ssr = np.array([f.ssr for f in ok])
    succ = np.array([f.success for f in ok])
    clusters = cluster_ends(ends, ssr, problem)
    return MultistartResult(
        names=list(problem.names),
        starts=starts,
        ends=ends,
        ssr=ssr,
        success=succ,
        clusters=clusters,
        fits=ok,
    )


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

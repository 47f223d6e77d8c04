"""The posterior: priors from physics, a Gaussian likelihood, and coordinates to sample in.

:class:`LogPosterior` maps sampling coordinates ``z`` (one row per walker) to the
log-posterior, all rows in one parallel kernel batch (emcee's ``vectorize=True``):

* **coordinates**: a free parameter whose lower bound is ≥ 0 and whose value at the fit is
  > 0 is sampled as ``log θ`` (the log-Jacobian is added, so the prior stays the one
  declared on θ); signed parameters (asymmetries, ``alpha0``, offsets) are sampled as they
  are; the noise scale of a channel, when sampled, as ``log σ``.
* **priors** (:class:`Prior`): uniform on θ within its physical bounds by default; log-
  uniform or normal per parameter from a config; an impossible point (outside the bounds,
  a broken validity constraint) returns ``-inf`` before any simulation.
* **likelihood** (``noise``):

  - ``"robust"`` (default): Gaussian at the floors, weighted as the fit weighs the
    channels (so that it peaks at the fit), *curvature-adjusted* so that
    the posterior is as wide as the errors really make the estimate — rounding that is
    constant while a disc sticks, errors correlated for as long as the motion that causes
    them, the input's unknown behaviour between samples (:mod:`.uncertainty`).  The
    log-likelihood at ``z`` is the Gaussian one at ``ẑ + C (z − ẑ)``, with ``C`` chosen so
    that its curvature at the fit ``ẑ`` is the inverse of the fit's honest covariance
    (an open-faced sandwich adjustment: the shape away from the fit, ridges and bounds
    included, stays the model's own; the prior is untouched);
  - ``"floor"``: the plain i.i.d. Gaussian at the floor.  It counts every sample as
    independent and is too narrow on stick-slip data (kept to compare);
  - ``"sampled"``: σ per channel with the scale-invariant prior ``p(σ) ∝ 1/σ``;
    optionally AR(1) errors ``e_t = φ e_{t-1} + ε_t`` with ``φ`` sampled on (−1, 1).
* a parameter set the integrator cannot simulate gives ``-inf`` and is counted
  (``n_failed``), never a plausible number.

Each of these is a piece of its own, and :class:`LogPosterior` composes them (as PINTS
composes ``LogPosterior(log_likelihood, log_prior)``): the log-likelihood, one class per
noise model (:mod:`.noise_models`), the prior (:class:`LogPrior`), the coordinates
(:class:`~.coordinates.LogCoordinates`) and the curvature adjustment
(:class:`~.coordinates.CurvatureAdjustment`).  ``LogPosterior(problem, x_fit, noise=...)``
chooses the pieces for a fit as above.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..model.parameters import ParameterError
from .coordinates import CurvatureAdjustment, LogCoordinates
from .noise_models import (
    AR1LogLikelihood,
    GaussianLogLikelihood,
    SampledSigmaLogLikelihood,
)
from .problem import Problem, local_name

#: The likelihoods :class:`LogPosterior` offers (module docstring).
NOISE_MODELS = ("robust", "floor", "sampled")
#: Residual memory of one kernel batch of walkers [bytes]: long data are simulated a few
#: walkers at a time, short data all at once.
BATCH_BYTES = 64 * 2**20


def batch_rows(n_residuals: int, budget: int = BATCH_BYTES) -> int:
    """Parameter sets per kernel batch whose residual rows fit in ``budget`` bytes, never
    fewer than the kernel's threads (each thread simulates one row)."""
    import numba

    return max(1, int(numba.get_num_threads()), budget // max(8 * int(n_residuals), 1))


@dataclass(frozen=True)
class Prior:
    """Prior of one parameter: ``uniform`` / ``loguniform`` on [lower, upper], or
    ``normal`` (mean, sd) truncated to the physical bounds."""

    kind: str = "uniform"
    lower: float = -math.inf
    upper: float = math.inf
    mean: float = math.nan
    sd: float = math.nan

    def logpdf(self, v: np.ndarray) -> np.ndarray:
        out = np.where((v >= self.lower) & (v <= self.upper), 0.0, -np.inf)
        if self.kind == "loguniform":
            with np.errstate(divide="ignore", invalid="ignore"):
                out = out - np.log(np.where(v > 0, v, np.nan))
            out = np.where(np.isnan(out), -np.inf, out)
        elif self.kind == "normal":
            out = out - 0.5 * ((v - self.mean) / self.sd) ** 2
        return out

    def describe(self, unit: str = "") -> str:
        if self.kind == "normal":
            return f"normal({self.mean:g}, {self.sd:g}) {unit} in [{self.lower:g}, {self.upper:g}]"
        return f"{self.kind} on [{self.lower:g}, {self.upper:g}] {unit}"


#: The keys of one prior's table and their types.
PRIOR_KEYS = {
    "dist": (str,),
    "lower": (int, float),
    "upper": (int, float),
    "mean": (int, float),
    "sd": (int, float),
}


def check_prior_spec(spec: Mapping, where: str) -> None:
    """Refuse unknown keys, wrong types and non-finite numbers in one prior's table
    (``ParameterError`` starting with ``where``); the analysis file uses it too."""
    for k, v in spec.items():
        if k not in PRIOR_KEYS:
            raise ParameterError(f"{where}: unknown key {k!r}; a prior has {', '.join(PRIOR_KEYS)}")
        if not isinstance(v, PRIOR_KEYS[k]) or isinstance(v, bool):
            want = "a string" if k == "dist" else "a number"
            raise ParameterError(f"{where}: {k} = {v!r} must be {want}")
        if not isinstance(v, str) and not math.isfinite(v):
            raise ParameterError(f"{where}: {k} = {v!r} must be a finite number")


def load_priors(path: str | Path, problem: Problem) -> dict[str, Prior]:
    """Priors from a TOML file: one table per parameter, e.g.

    .. code-block:: toml

        [priors]
        k_alpha = { dist = "normal", mean = 0.080, sd = 0.004 }
        J_l = { dist = "loguniform", lower = 0.01, upper = 0.2 }
    """
    from ..io.tomlfile import read_toml

    p = Path(path)
    doc = read_toml(
        p,
        ParameterError,
        "priors file",
        'write a [priors] table, e.g. k_alpha = { dist = "normal", mean = 0.08, sd = 0.004 }',
    )
    table = doc.get("priors", doc)
    if not isinstance(table, Mapping):
        raise ParameterError(
            f"{p}: priors = {table!r} must be a table: write [priors] on its "
            "own line, then one line per parameter"
        )
    out = {}
    names = problem.names_base()
    for name, spec in table.items():
        if name not in names:
            raise ParameterError(
                f"{p}: [priors] {name}: not a free parameter of this fit; the free ones are "
                f"{', '.join(names)}"
            )
        if not isinstance(spec, Mapping):
            raise ParameterError(
                f"{p}: [priors] {name} must be a table like "
                '{ dist = "normal", mean = 0.08, sd = 0.004 }'
            )
        check_prior_spec(spec, f"{p}: [priors] {name}")
        info = problem.info(name)
        kind = spec.get("dist", "uniform")
        if kind not in ("uniform", "loguniform", "normal"):
            raise ParameterError(
                f"{p}: [priors] {name}: dist {kind!r}; choose uniform, loguniform or normal"
            )
        lo = float(spec.get("lower", info.lower))
        hi = float(spec.get("upper", info.upper))
        lo, hi = max(lo, info.lower), min(hi, info.upper)
        if not lo < hi:
            raise ParameterError(
                f"{p}: [priors] {name}: lower {lo:g} must be below upper "
                f"{hi:g} (within the physical bounds [{info.lower:g}, "
                f"{info.upper:g}] {info.unit})"
            )
        if kind == "loguniform" and lo <= 0:
            raise ParameterError(f"{p}: [priors] {name}: a log-uniform prior needs lower > 0")
        mean = float(spec.get("mean", math.nan))
        sd = float(spec.get("sd", math.nan))
        if kind == "normal" and not (math.isfinite(mean) and sd > 0):
            raise ParameterError(f"{p}: [priors] {name}: a normal prior needs mean and sd > 0")
        out[name] = Prior(kind, lo, hi, mean, sd)
    return out


class LogPrior:
    """The prior of a problem's free parameters: independent priors (:class:`Prior`,
    uniform within the physical bounds unless given) and the validity constraints between
    parameters (a point that breaks one is impossible).

    Parameters
    ----------
    problem : Problem
    priors : mapping, optional
        ``{name: Prior}`` by parameter (``alpha0`` for every ``alpha0[i]``) or free name.
    """

    def __init__(self, problem: Problem, priors: Mapping[str, Prior] | None = None):
        self.problem = problem
        self.priors: dict[str, Prior] = {}
        for j, n in enumerate(problem.names):
            b, _ = local_name(n)
            pr = (priors or {}).get(b) or (priors or {}).get(n)
            self.priors[n] = pr or Prior("uniform", problem.lower[j], problem.upper[j])

    def density(self, X: np.ndarray) -> np.ndarray:
        """The sum of the parameters' log priors per row of free vectors ``X``."""
        lp = np.zeros(X.shape[0])
        for j, n in enumerate(self.problem.names):
            lp += self.priors[n].logpdf(X[:, j])
        return lp

    def constrained(self, X: np.ndarray, lp: np.ndarray) -> np.ndarray:
        """``lp`` with ``-inf`` for every finite row whose parameters break a validity
        constraint (checked before any simulation)."""
        ok = np.isfinite(lp)
        for i in np.flatnonzero(ok):
            if self.problem.model.problems(self.problem.params_for(X[i], 0)):
                lp[i] = -np.inf
        return lp

    def __call__(self, X: np.ndarray) -> np.ndarray:
        return self.constrained(X, self.density(X))


#: The noise model of each ``noise`` name (AR(1) errors: :class:`AR1LogLikelihood`).
NOISE_CLASSES = {
    "robust": GaussianLogLikelihood,
    "floor": GaussianLogLikelihood,
    "sampled": SampledSigmaLogLikelihood,
}


class LogPosterior:
    """Vectorised log-posterior over sampling coordinates (see the module docstring),
    composed of a log-likelihood (one class per noise model, :mod:`.noise_models`), a
    log prior (:class:`LogPrior`), the coordinates (:class:`.coordinates.LogCoordinates`)
    and, optionally, the curvature adjustment
    (:class:`.coordinates.CurvatureAdjustment`).

    Two ways to build one:

    * ``LogPosterior(problem, x_fit, *, priors=None, noise="robust", ar1=False,
      uncertainty=None)`` — the posterior of a fit, every piece chosen as the module
      docstring says (:meth:`for_fit`);
    * ``LogPosterior(log_likelihood, log_prior=None, *, transform=None, adjustment=None)``
      — composed from pieces (defaults: uniform priors within the bounds, no log
      coordinates, no adjustment).

    Parameters
    ----------
    problem : Problem
    x_fit : array
        The least-squares point (sets which positive parameters are sampled in log).
    priors : mapping, optional
        ``{name: Prior}``; default uniform within the physical bounds.
    noise : {'robust', 'floor', 'sampled'}
        ``robust``: floor noise, curvature-adjusted to the fit's honest covariance (module
        docstring); ``floor``: i.i.d. at the floor; ``sampled``: log σ, prior 1/σ.
    uncertainty : Uncertainty, optional
        The fit's honest covariance for ``robust`` (computed here if not given).
    ar1 : bool
        AR(1) errors per channel (then σ is the innovation scale and is sampled).
    """

    def __init__(
        self,
        log_likelihood,
        log_prior=None,
        *,
        transform=None,
        adjustment=None,
        priors=None,
        noise: str | None = None,
        ar1: bool = False,
        uncertainty=None,
    ):
        if isinstance(log_likelihood, Problem):
            if transform is not None or adjustment is not None:
                raise TypeError(
                    "the posterior of a fit, LogPosterior(problem, x_fit, ...), "
                    "chooses its coordinates and adjustment itself; to give "
                    "them, compose it: LogPosterior(log_likelihood, log_prior, "
                    "transform=..., adjustment=...)"
                )
            self._init_for_fit(
                log_likelihood,
                log_prior,
                priors=priors,
                noise="robust" if noise is None else noise,
                ar1=ar1,
                uncertainty=uncertainty,
            )
            return
        if priors is not None or noise is not None or ar1 or uncertainty is not None:
            raise TypeError(
                "priors, noise, ar1 and uncertainty choose the pieces of a fit's "
                "posterior, LogPosterior(problem, x_fit, ...); a posterior "
                "composed of pieces takes the pieces themselves"
            )
        self._compose(log_likelihood, log_prior, transform, adjustment)
        self.noise = (
            "sampled"
            if isinstance(log_likelihood, SampledSigmaLogLikelihood)
            else "robust"
            if adjustment is not None
            else "floor"
        )
        self.z_fit = None if adjustment is None else adjustment.z_fit

    def _compose(self, log_likelihood, log_prior, transform, adjustment) -> None:
        problem = log_likelihood.problem
        self.likelihood: GaussianLogLikelihood = log_likelihood
        self.prior: LogPrior = LogPrior(problem) if log_prior is None else log_prior
        k = len(problem.names)
        self.transform: LogCoordinates = (
            LogCoordinates(np.zeros(k, bool)) if transform is None else transform
        )
        self.adjustment: CurvatureAdjustment | None = adjustment
        if self.prior.problem is not problem:
            raise ValueError(
                "the log prior and the log-likelihood belong to different "
                "problems; build both from the same Problem"
            )
        if len(self.transform) != k:
            raise ValueError(
                f"the coordinates have {len(self.transform)} entries, the "
                f"problem {k} free parameters"
            )
        if adjustment is not None and adjustment.z_fit.size != k:
            raise ValueError(
                f"the adjustment has {adjustment.z_fit.size} coordinates, the "
                f"problem {k} free parameters"
            )
        self.problem = problem
        self.k: int = k
        floor, notes = problem.noise_floors()
        self.floor: dict[str, float] = floor
        self.floor_notes: list[str] = notes
        self.coord_names = self.transform.names(problem.names) + log_likelihood.noise_names()
        self.ndim = len(self.coord_names)
        self.n_failed = 0
        self.n_calls = 0
        self.uncertainty: Any = None  # the fit's honest covariance, robust noise only

    @classmethod
    def for_fit(
        cls,
        problem: Problem,
        x_fit,
        *,
        priors=None,
        noise: str = "robust",
        ar1: bool = False,
        uncertainty=None,
    ) -> LogPosterior:
        """The posterior of the fit ``x_fit`` of ``problem`` (the class docstring's
        first form)."""
        return cls(problem, x_fit, priors=priors, noise=noise, ar1=ar1, uncertainty=uncertainty)

    def _init_for_fit(
        self, problem: Problem, x_fit, *, priors, noise: str, ar1: bool, uncertainty
    ) -> None:
        if noise not in NOISE_MODELS:
            raise ValueError(f"noise must be one of {', '.join(NOISE_MODELS)}, not {noise!r}")
        x_fit = np.asarray(x_fit, float)
        # The noise floor of each channel (quantisation, or the data's jitter if larger).
        floor, _ = problem.noise_floors()
        # The σ of each channel in the Gaussian that is evaluated (fixed σ, no AR(1)): the
        # floor; for ``robust`` noise one scale for every *weighted* residual, so that the
        # Gaussian peaks where the fit does.  The honest covariance is that of the fit's
        # estimator (the problem's channel weights); the adjustment ẑ + C (z − ẑ) is only
        # centred on the fit if the adjusted likelihood's maximum is the fit's minimum.
        # With the floors instead (unequal floors, unit weights) its maximum sat elsewhere
        # and C⁻¹ moved it further: 2-9 honest sd from the fit on reference data.
        sigma = dict(floor)
        if noise == "robust" and not ar1:
            w = problem.weights
            common = math.exp(float(np.mean([math.log(floor[c] * w[c]) for c in problem.channels])))
            sigma = {c: common / w[c] for c in problem.channels}
        kind = AR1LogLikelihood if ar1 else NOISE_CLASSES[noise]
        self._compose(
            kind(problem, sigma),
            LogPrior(problem, priors),
            LogCoordinates.for_fit(problem.lower, x_fit),
            None,
        )
        self.noise = "sampled" if ar1 else noise
        self.z_fit = self.to_z(x_fit)[: self.k]
        if self.noise == "robust":
            self.uncertainty = uncertainty or self._fit_uncertainty(x_fit)
            self.adjustment = CurvatureAdjustment.matching(
                self.z_fit, self._precision_iid(x_fit), self.target_cov_z(x_fit)
            )

    # ------------------------------------------------------------ the pieces' words
    @property
    def ar1(self) -> bool:
        """Whether the errors are AR(1)."""
        return isinstance(self.likelihood, AR1LogLikelihood)

    @property
    def log(self) -> np.ndarray:
        """Which free parameters are sampled as their logarithm."""
        return self.transform.log

    @property
    def priors(self) -> dict[str, Prior]:
        """The prior of every free parameter."""
        return self.prior.priors

    @property
    def channels(self) -> list[str]:
        return self.likelihood.channels

    @property
    def segments(self) -> list[tuple[str, int, int]]:
        """``(channel, first, end)`` of every experiment's and channel's residuals."""
        return self.likelihood.segments

    @property
    def sigma(self) -> dict[str, float]:
        """The σ per channel of the Gaussian evaluated (the start where σ is sampled)."""
        return self.likelihood.sigma

    @property
    def adjust(self) -> np.ndarray | None:
        """``C`` of the curvature adjustment (k x k), None without one."""
        return None if self.adjustment is None else self.adjustment.C

    # ------------------------------------------------------------ robust adjustment
    def _fit_uncertainty(self, x_fit):
        from .uncertainty import fit_uncertainty

        J, _ = self.problem.jacobian(x_fit)
        return fit_uncertainty(self.problem, x_fit, J)

    def _precision_iid(self, x_fit):
        """Fisher information of the i.i.d. likelihood in sampling coordinates (one
        Jacobian per point, kept; segment by segment, no weighted copy of it: long data)."""
        x_fit = np.asarray(x_fit, float)
        key = x_fit.tobytes()
        cached = self.__dict__.get("_precision_cache")
        if cached is not None and cached[0] == key:
            return cached[1].copy()
        J, _ = self.problem.jacobian(x_fit)
        H = np.zeros((J.shape[1], J.shape[1]))
        for c, a, b in self.segments:
            Js = J[a:b]
            H += (Js.T @ Js) / (self.sigma[c] * self.problem.weights[c]) ** 2
        del J
        d = self.transform.derivative(x_fit)  # dθ/dz
        H *= np.outer(d, d)
        self._precision_cache = (key, H)
        return H.copy()

    def target_cov_z(self, x_fit) -> np.ndarray:
        """The honest covariance in sampling coordinates (``inf`` where undetermined)."""
        d = self.transform.derivative(x_fit)
        return self.uncertainty.cov / np.outer(d, d)

    def evaluation_points(self, Z: np.ndarray) -> np.ndarray:
        """Where the likelihood is evaluated for coordinates ``Z`` (the adjustment)."""
        if self.adjustment is None:
            return Z
        return self.adjustment.points(Z)

    # ------------------------------------------------------------------ coordinates
    def to_z(self, x: np.ndarray, sigma: Mapping | None = None, phi: Mapping | None = None):
        """The coordinates of the free vector ``x`` (and of the noise parameters ``sigma``,
        ``phi`` per channel where they are sampled; default the floor and 0)."""
        return np.array(self.transform.to_z(x) + self.likelihood.noise_z(sigma, phi))

    def split(self, Z: np.ndarray):
        """Parameters, σ per channel and φ per channel of coordinate rows ``Z``."""
        Z = np.atleast_2d(Z)
        X = self.transform.to_x(Z[:, : self.k])
        S, P = self.likelihood.noise_of(Z[:, self.k :])
        return X, S, P

    def log_prior(self, Z: np.ndarray) -> np.ndarray:
        """The log prior of coordinate rows ``Z``: the parameters' prior, the coordinates'
        log-Jacobian and the noise parameters' prior; ``-inf`` for an impossible point."""
        X, S, P = self.split(Z)
        lp = self.prior.density(X)
        lp += self.transform.log_jacobian(Z[:, : self.k])
        lp += self.likelihood.noise_log_prior(S, P)
        return self.prior.constrained(X, lp)

    def row_chunk(self) -> int:
        """Rows (walkers, draws) simulated in one kernel batch: as many as keep their
        residuals within :data:`BATCH_BYTES`, never fewer than the kernel's threads."""
        return batch_rows(self.problem.n_residuals)

    def pointwise_of(self, R: np.ndarray, S: np.ndarray, P: np.ndarray) -> np.ndarray:
        """Pointwise log-likelihood rows of the residual rows ``R`` (``nan`` where the
        simulation failed)."""
        return self.likelihood.pointwise_of(R, S, P)

    def pointwise(self, X: np.ndarray, S: np.ndarray, P: np.ndarray):
        """Pointwise log-likelihood rows (n, n_residuals) and a failed mask (all rows at
        once: for few rows; :meth:`loglik` sums without keeping them)."""
        return self.likelihood.pointwise(X, S, P)

    def loglik(self, X: np.ndarray, S: np.ndarray, P: np.ndarray):
        """Log-likelihood per row and a failed mask; the rows are simulated a few at a time
        (:meth:`row_chunk`) and only their sums of squares are kept, so the memory does not
        grow with the number of walkers."""
        return self.likelihood.loglik(X, S, P, self.row_chunk())

    def __call__(self, Z: np.ndarray) -> np.ndarray:
        Z = np.atleast_2d(Z)
        lp = self.log_prior(Z)
        out = np.full(Z.shape[0], -np.inf)
        ok = np.isfinite(lp)
        self.n_calls += int(ok.sum())
        if ok.any():
            X, S, P = self.split(self.evaluation_points(Z[ok]))
            ll, failed = self.loglik(X, S, P)
            ll = np.where(failed, -np.inf, ll)
            self.n_failed += int(failed.sum())
            out[ok] = lp[ok] + ll
        return out

    def start_ball(self, x_fit, n_walkers: int, rng, *, scale: float = 0.1):
        """Walkers in a small ball around the fit shaped by the Gauss-Newton covariance
        (σ of the likelihood), each with a finite log-posterior."""
        x_fit = np.asarray(x_fit, float)
        Hz = self._precision_iid(x_fit)
        if self.adjustment is not None:
            # The adjusted likelihood's curvature: Cᵀ H C.
            Hz = self.adjustment.curvature(Hz)
        lam, V = np.linalg.eigh(0.5 * (Hz + Hz.T))
        # Directions the data do not determine (an exact symmetry) get a 1 % spread, so
        # the ensemble's stretch moves can travel along them.
        var = np.where(
            lam > 1e-10 * max(lam.max(), 1e-300), 1.0 / np.maximum(lam, 1e-300), 1e-4 / scale**2
        )
        cov_z = (V * var) @ V.T
        z0 = self.to_z(x_fit)
        out = np.empty((n_walkers, self.ndim))
        evals = np.linalg.eigvalsh(cov_z)
        if not np.all(np.isfinite(evals)) or evals.max() <= 0:
            cov_z = np.diag(np.full(self.k, 1e-6))
        tries = 0
        i = 0
        while i < n_walkers:
            tries += 1
            if tries > 50 * n_walkers:
                raise RuntimeError(
                    "cannot place the walkers: the posterior is -inf all "
                    "around the fit (check the priors and bounds)"
                )
            zz = z0.copy()
            zz[: self.k] = rng.multivariate_normal(z0[: self.k], scale**2 * cov_z, method="eigh")
            zz[self.k :] = z0[self.k :] + 0.01 * rng.standard_normal(self.ndim - self.k)
            if np.isfinite(self(zz[None, :])[0]):
                out[i] = zz
                i += 1
        return out

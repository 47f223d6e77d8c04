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
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..model.parameters import ParameterError
from .problem import Problem, local_name

LOG_2PI = math.log(2 * math.pi)
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
PRIOR_KEYS = {"dist": (str,), "lower": (int, float), "upper": (int, float),
              "mean": (int, float), "sd": (int, float)}


def check_prior_spec(spec: Mapping, where: str) -> None:
    """Refuse unknown keys, wrong types and non-finite numbers in one prior's table
    (``ParameterError`` starting with ``where``); the analysis file uses it too."""
    for k, v in spec.items():
        if k not in PRIOR_KEYS:
            raise ParameterError(f"{where}: unknown key {k!r}; a prior has "
                                 f"{', '.join(PRIOR_KEYS)}")
        if not isinstance(v, PRIOR_KEYS[k]) or isinstance(v, bool):
            want = "a string" if k == "dist" else "a number"
            raise ParameterError(f"{where}: {k} = {v!r} must be {want}")
        if k != "dist" and not math.isfinite(v):
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
    doc = read_toml(p, ParameterError, "priors file",
                    'write a [priors] table, e.g. k_alpha = { dist = "normal", mean = 0.08, '
                    'sd = 0.004 }')
    table = doc.get("priors", doc)
    if not isinstance(table, Mapping):
        raise ParameterError(f"{p}: priors = {table!r} must be a table: write [priors] on its "
                             "own line, then one line per parameter")
    out = {}
    names = problem.names_base()
    for name, spec in table.items():
        if name not in names:
            raise ParameterError(
                f"{p}: [priors] {name}: not a free parameter of this fit; the free ones are "
                f"{', '.join(names)}"
            )
        if not isinstance(spec, Mapping):
            raise ParameterError(f"{p}: [priors] {name} must be a table like "
                                 "{ dist = \"normal\", mean = 0.08, sd = 0.004 }")
        check_prior_spec(spec, f"{p}: [priors] {name}")
        info = problem.info(name)
        kind = spec.get("dist", "uniform")
        if kind not in ("uniform", "loguniform", "normal"):
            raise ParameterError(f"{p}: [priors] {name}: dist {kind!r}; choose uniform, "
                                 "loguniform or normal")
        lo = float(spec.get("lower", info.lower))
        hi = float(spec.get("upper", info.upper))
        lo, hi = max(lo, info.lower), min(hi, info.upper)
        if not lo < hi:
            raise ParameterError(f"{p}: [priors] {name}: lower {lo:g} must be below upper "
                                 f"{hi:g} (within the physical bounds [{info.lower:g}, "
                                 f"{info.upper:g}] {info.unit})")
        if kind == "loguniform" and lo <= 0:
            raise ParameterError(f"{p}: [priors] {name}: a log-uniform prior needs lower > 0")
        mean = float(spec.get("mean", math.nan))
        sd = float(spec.get("sd", math.nan))
        if kind == "normal" and not (math.isfinite(mean) and sd > 0):
            raise ParameterError(f"{p}: [priors] {name}: a normal prior needs mean and sd > 0")
        out[name] = Prior(kind, lo, hi, mean, sd)
    return out


class LogPosterior:
    """Vectorised log-posterior over sampling coordinates (see the module docstring).

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

    def __init__(self, problem: Problem, x_fit, *, priors=None, noise: str = "robust",
                 ar1: bool = False, uncertainty=None):
        if noise not in NOISE_MODELS:
            raise ValueError(f"noise must be one of {', '.join(NOISE_MODELS)}, not {noise!r}")
        self.problem = problem
        self.noise = "sampled" if ar1 else noise
        self.ar1 = ar1
        x_fit = np.asarray(x_fit, float)
        self.k = len(problem.names)
        self.log = np.array([
            problem.lower[j] >= 0 and x_fit[j] > 0 for j in range(self.k)
        ])
        self.priors = {}
        for j, n in enumerate(problem.names):
            b, _ = local_name(n)
            pr = (priors or {}).get(b) or (priors or {}).get(n)
            self.priors[n] = pr or Prior("uniform", problem.lower[j], problem.upper[j])
        self.channels = list(problem.channels)
        # The noise floor of each channel (quantisation, or the data's jitter if larger).
        self.floor, self.floor_notes = problem.noise_floors()
        # The σ of each channel in the Gaussian that is evaluated (fixed σ, no AR(1)): the
        # floor; for ``robust`` noise one scale for every *weighted* residual, so that the
        # Gaussian peaks where the fit does.  The honest covariance is that of the fit's
        # estimator (the problem's channel weights); the adjustment ẑ + C (z − ẑ) is only
        # centred on the fit if the adjusted likelihood's maximum is the fit's minimum.
        # With the floors instead (unequal floors, unit weights) its maximum sat elsewhere
        # and C⁻¹ moved it further: 2-9 honest sd from the fit on reference data.
        self.sigma = dict(self.floor)
        if self.noise == "robust":
            w = problem.weights
            common = math.exp(float(np.mean([math.log(self.floor[c] * w[c])
                                             for c in self.channels])))
            self.sigma = {c: common / w[c] for c in self.channels}
        names = [f"log_{n}" if lg else n for n, lg in zip(problem.names, self.log, strict=True)]
        if self.noise == "sampled":
            names += [f"log_sigma_{c}" for c in self.channels]
        if ar1:
            names += [f"phi_{c}" for c in self.channels]
        self.coord_names = names
        self.ndim = len(names)
        # Residual index ranges per experiment and channel.
        self.segments = []
        off = 0
        for ex in problem.experiments:
            for c in problem.channels:
                self.segments.append((c, off, off + ex.n))
                off += ex.n
        self.n_failed = 0
        self.n_calls = 0
        self.uncertainty = None
        self.z_fit = self.to_z(x_fit)[: self.k]
        self.adjust = None  # C of the curvature adjustment (k x k), robust noise only
        if self.noise == "robust":
            self.uncertainty = uncertainty or self._fit_uncertainty(x_fit)
            self.adjust = self._adjustment(x_fit)

    # ------------------------------------------------------------ robust adjustment
    def _fit_uncertainty(self, x_fit):
        from .uncertainty import fit_uncertainty

        J, _ = self.problem.jacobian(x_fit)
        return fit_uncertainty(self.problem, x_fit, J)

    def _precision_iid(self, x_fit):
        """Fisher information of the i.i.d. floor likelihood in sampling coordinates (one
        Jacobian per point, kept; segment by segment, no weighted copy of it: long data)."""
        x_fit = np.asarray(x_fit, float)
        key = x_fit.tobytes()
        cached = self.__dict__.get("_precision_cache")
        if cached is not None and cached[0] == key:
            return cached[1].copy()
        J, _ = self.problem.jacobian(x_fit)
        H = np.zeros((J.shape[1], J.shape[1]))
        for (c, a, b) in self.segments:
            Js = J[a:b]
            H += (Js.T @ Js) / (self.sigma[c] * self.problem.weights[c]) ** 2
        del J
        d = np.where(self.log, x_fit, 1.0)  # dθ/dz
        H *= np.outer(d, d)
        self._precision_cache = (key, H)
        return H.copy()

    def target_cov_z(self, x_fit) -> np.ndarray:
        """The honest covariance in sampling coordinates (``inf`` where undetermined)."""
        x = np.asarray(x_fit, float)
        d = np.where(self.log, x, 1.0)
        return self.uncertainty.cov / np.outer(d, d)

    def _adjustment(self, x_fit):
        """``C`` with ``Cᵀ H C = V⁻¹``: H the i.i.d. precision, V the honest covariance,
        both in sampling coordinates.  Directions the data do not determine (or whose honest
        variance is not finite) keep ``C = I``."""
        x_fit = np.asarray(x_fit, float)
        H = self._precision_iid(x_fit)
        V = self.target_cov_z(x_fit)
        k = self.k
        bad = ~np.all(np.isfinite(V), axis=0) | ~np.isfinite(np.diag(V))
        C = np.eye(k)
        ok = ~bad
        if ok.sum() == 0:
            return C
        Hs = H[np.ix_(ok, ok)]
        Vs = V[np.ix_(ok, ok)]
        lam, U = np.linalg.eigh(0.5 * (Hs + Hs.T))
        good = lam > 1e-12 * max(lam.max(), 1e-300)
        if not good.all():
            return C  # an exact symmetry among the determined ones: leave the model's shape
        W = (U * np.sqrt(lam)).T  # H = WᵀW
        Wi = U / np.sqrt(lam)  # W⁻¹
        S = W @ Vs @ W.T  # target in the frame where the i.i.d. posterior is N(0, I)
        mu, Q = np.linalg.eigh(0.5 * (S + S.T))
        mu = np.maximum(mu, 1e-300)
        Cw = (Q / np.sqrt(mu)) @ Q.T  # S^(-1/2)
        C[np.ix_(ok, ok)] = Wi @ Cw @ W
        return C

    def evaluation_points(self, Z: np.ndarray) -> np.ndarray:
        """Where the likelihood is evaluated for coordinates ``Z`` (the adjustment)."""
        if self.adjust is None:
            return Z
        Z = np.array(Z, float, copy=True)
        Z[:, : self.k] = self.z_fit + (Z[:, : self.k] - self.z_fit) @ self.adjust.T
        return Z

    # ------------------------------------------------------------------ coordinates
    def to_z(self, x: np.ndarray, sigma: Mapping | None = None, phi: Mapping | None = None):
        x = np.asarray(x, float)
        z = [math.log(v) if lg else float(v) for v, lg in zip(x, self.log, strict=True)]
        if self.noise == "sampled":
            z += [math.log((sigma or self.floor)[c]) for c in self.channels]
        if self.ar1:
            z += [float((phi or {}).get(c, 0.0)) for c in self.channels]
        return np.array(z)

    def split(self, Z: np.ndarray):
        """Parameters, σ per channel and φ per channel of coordinate rows ``Z``."""
        Z = np.atleast_2d(Z)
        X = Z[:, : self.k].copy()
        X[:, self.log] = np.exp(X[:, self.log])
        k = self.k
        if self.noise == "sampled":
            S = np.exp(Z[:, k : k + len(self.channels)])
            k += len(self.channels)
        else:
            S = np.tile([self.sigma[c] for c in self.channels], (Z.shape[0], 1))
        P = Z[:, k : k + len(self.channels)] if self.ar1 else np.zeros_like(S)
        return X, S, P

    def log_prior(self, Z: np.ndarray) -> np.ndarray:
        X, S, P = self.split(Z)
        lp = np.zeros(X.shape[0])
        for j, n in enumerate(self.problem.names):
            lp += self.priors[n].logpdf(X[:, j])
        # Log coordinates: p(z) = p(θ) |dθ/dz| = p(θ) θ.
        lp += np.sum(Z[:, : self.k][:, self.log], axis=1)
        if self.noise == "sampled":
            # p(σ) ∝ 1/σ is uniform in log σ (within a wide physical range).
            ls = np.log(S)
            lp += np.where(np.all((ls > math.log(1e-8)) & (ls < math.log(10.0)), axis=1),
                           0.0, -np.inf)
        if self.ar1:
            lp += np.where(np.all(np.abs(P) < 0.999, axis=1), 0.0, -np.inf)
        # Validity constraints between parameters, before any simulation.
        ok = np.isfinite(lp)
        for i in np.flatnonzero(ok):
            if self.problem.model.problems(self.problem.params_for(X[i], 0)):
                lp[i] = -np.inf
        return lp

    def row_chunk(self) -> int:
        """Rows (walkers, draws) simulated in one kernel batch: as many as keep their
        residuals within :data:`BATCH_BYTES`, never fewer than the kernel's threads."""
        return batch_rows(self.problem.n_residuals)

    def pointwise_of(self, R: np.ndarray, S: np.ndarray, P: np.ndarray) -> np.ndarray:
        """Pointwise log-likelihood rows of the residual rows ``R`` (``nan`` where the
        simulation failed)."""
        L = np.empty_like(R)
        for (c, a, b) in self.segments:
            j = self.channels.index(c)
            w = self.problem.weights[c]
            e = R[:, a:b] / w
            s = S[:, j : j + 1]
            if self.ar1:
                phi = P[:, j : j + 1]
                innov = e.copy()
                innov[:, 1:] = e[:, 1:] - phi * e[:, :-1]
                # The first sample from the stationary distribution.
                innov[:, :1] = e[:, :1] * np.sqrt(1 - phi**2)
                L[:, a:b] = -0.5 * LOG_2PI - np.log(s) - 0.5 * (innov / s) ** 2
                L[:, a : a + 1] += 0.5 * np.log(1 - phi**2)
            else:
                L[:, a:b] = -0.5 * LOG_2PI - np.log(s) - 0.5 * (e / s) ** 2
        return L

    def pointwise(self, X: np.ndarray, S: np.ndarray, P: np.ndarray):
        """Pointwise log-likelihood rows (n, n_residuals) and a failed mask (all rows at
        once: for few rows; :meth:`loglik` sums without keeping them)."""
        R = self.problem.residuals_batch(X)
        failed = ~np.all(np.isfinite(R), axis=1)
        return self.pointwise_of(R, S, P), failed

    def _loglik_of(self, R: np.ndarray, S: np.ndarray, P: np.ndarray) -> np.ndarray:
        """The log-likelihood of each residual row, from sums of squares per segment (no
        pointwise array)."""
        ll = np.zeros(R.shape[0])
        for (c, a, b) in self.segments:
            j = self.channels.index(c)
            e = R[:, a:b] / self.problem.weights[c]
            s = S[:, j]
            n = b - a
            if self.ar1:
                phi = P[:, j]
                d = e[:, 1:] - phi[:, None] * e[:, :-1]
                q = 1.0 - phi**2
                ssr = np.einsum("ij,ij->i", d, d) + e[:, 0] ** 2 * q
                ll += 0.5 * np.log(q)
            else:
                ssr = np.einsum("ij,ij->i", e, e)
            ll += n * (-0.5 * LOG_2PI - np.log(s)) - 0.5 * ssr / s**2
        return ll

    def loglik(self, X: np.ndarray, S: np.ndarray, P: np.ndarray):
        """Log-likelihood per row and a failed mask; the rows are simulated a few at a time
        (:meth:`row_chunk`) and only their sums of squares are kept, so the memory does not
        grow with the number of walkers."""
        n = X.shape[0]
        ll = np.empty(n)
        failed = np.zeros(n, bool)
        step = self.row_chunk()
        for a in range(0, n, step):
            b = min(n, a + step)
            R = self.problem.residuals_batch(X[a:b])
            failed[a:b] = ~np.all(np.isfinite(R), axis=1)
            ll[a:b] = self._loglik_of(R, S[a:b], P[a:b])
            del R
        return ll, failed

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
        if self.adjust is not None:
            # The adjusted likelihood's curvature: Cᵀ H C.
            Hz = self.adjust.T @ Hz @ self.adjust
        lam, V = np.linalg.eigh(0.5 * (Hz + Hz.T))
        # Directions the data do not determine (an exact symmetry) get a 1 % spread, so
        # the ensemble's stretch moves can travel along them.
        var = np.where(lam > 1e-10 * max(lam.max(), 1e-300), 1.0 / np.maximum(lam, 1e-300),
                       1e-4 / scale**2)
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
                raise RuntimeError("cannot place the walkers: the posterior is -inf all "
                                   "around the fit (check the priors and bounds)")
            zz = z0.copy()
            zz[: self.k] = rng.multivariate_normal(z0[: self.k], scale**2 * cov_z,
                                                   method="eigh")
            zz[self.k :] = z0[self.k :] + 0.01 * rng.standard_normal(self.ndim - self.k)
            if np.isfinite(self(zz[None, :])[0]):
                out[i] = zz
                i += 1
        return out

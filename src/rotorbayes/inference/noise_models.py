"""Log-likelihoods of a problem's residuals, one class per noise model.

Each takes residual rows ``R`` (as :meth:`~rotorbayes.inference.Problem.residuals_batch`
lays them out: experiment by experiment, channel by channel, weighted) with the noise
scale ``S`` and the AR(1) coefficient ``P`` of every channel (one row per point) and gives
the log-likelihood of each row, or of each sample (``pointwise_of``).  The noise
parameters a model samples (log σ, φ) are coordinates of their own, after the model
parameters; the class names them, reads them from a row of coordinates and holds their
prior:

* :class:`GaussianLogLikelihood` — i.i.d. Gaussian errors with a known σ per channel
  (nothing sampled);
* :class:`SampledSigmaLogLikelihood` — i.i.d. Gaussian with σ per channel sampled as
  ``log σ``, prior ``p(σ) ∝ 1/σ`` (uniform in log σ within a wide physical range);
* :class:`AR1LogLikelihood` — AR(1) errors ``e_t = φ e_{t-1} + ε_t`` per channel, the
  innovation scale σ sampled as above and ``φ`` on (−1, 1), the first sample from the
  stationary distribution.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from .problem import Problem

LOG_2PI = math.log(2 * math.pi)
#: The range of a sampled noise scale σ [rad] (its prior is 1/σ within it).
SIGMA_RANGE = (1e-8, 10.0)
#: The largest ``|φ|`` of an AR(1) coefficient (its prior is uniform within it).
PHI_LIMIT = 0.999


def segments(problem: Problem) -> list[tuple[str, int, int]]:
    """``(channel, first, end)`` of every experiment's and channel's residuals."""
    out = []
    off = 0
    for ex in problem.experiments:
        for c in problem.channels:
            out.append((c, off, off + ex.n))
            off += ex.n
    return out


class GaussianLogLikelihood:
    """I.i.d. Gaussian errors of the unweighted residuals with the known scale ``sigma``
    [rad] per channel.

    Parameters
    ----------
    problem : Problem
    sigma : mapping
        σ of every fitted channel.
    """

    def __init__(self, problem: Problem, sigma: Mapping[str, float]):
        self.problem = problem
        self.channels = list(problem.channels)
        self.sigma = {c: sigma[c] for c in self.channels}
        self.segments = segments(problem)

    # ------------------------------------------------------- the noise coordinates
    def noise_names(self) -> list[str]:
        """Names of the noise coordinates this model samples (none)."""
        return []

    def noise_z(self, sigma: Mapping | None = None, phi: Mapping | None = None) -> list:
        """The noise coordinates at ``sigma`` and ``phi`` (none)."""
        return []

    def noise_of(self, W: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """σ and φ per channel (rows) of the noise coordinates ``W`` (one row per point)."""
        S = np.tile([self.sigma[c] for c in self.channels], (W.shape[0], 1))
        return S, np.zeros_like(S)

    def noise_log_prior(self, S: np.ndarray, P: np.ndarray) -> np.ndarray:
        """The log prior of the noise parameters per row (nothing sampled: 0)."""
        return np.zeros(S.shape[0])

    # ------------------------------------------------------------- the likelihood
    def pointwise_of(self, R: np.ndarray, S: np.ndarray, P: np.ndarray) -> np.ndarray:
        """Pointwise log-likelihood rows of the residual rows ``R`` (``nan`` where the
        simulation failed)."""
        L = np.empty_like(R)
        for c, a, b in self.segments:
            j = self.channels.index(c)
            w = self.problem.weights[c]
            e = R[:, a:b] / w
            s = S[:, j : j + 1]
            L[:, a:b] = self._pointwise_segment(e, s, P[:, j : j + 1])
        return L

    def _pointwise_segment(self, e, s, phi):
        """Pointwise log-likelihood of one segment's errors ``e`` (rows) at scale ``s``."""
        return -0.5 * LOG_2PI - np.log(s) - 0.5 * (e / s) ** 2

    def loglik_of(self, R: np.ndarray, S: np.ndarray, P: np.ndarray) -> np.ndarray:
        """The log-likelihood of each residual row, from sums of squares per segment (no
        pointwise array)."""
        ll = np.zeros(R.shape[0])
        for c, a, b in self.segments:
            j = self.channels.index(c)
            e = R[:, a:b] / self.problem.weights[c]
            s = S[:, j]
            n = b - a
            ssr, extra = self._sum_of_squares(e, P[:, j])
            if extra is not None:
                ll += extra
            ll += n * (-0.5 * LOG_2PI - np.log(s)) - 0.5 * ssr / s**2
        return ll

    def _sum_of_squares(self, e, phi):
        """The sum of squared innovations of one segment's errors ``e`` per row, and the
        log-likelihood's term that does not scale with σ (None: none)."""
        return np.einsum("ij,ij->i", e, e), None

    def loglik(
        self, X: np.ndarray, S: np.ndarray, P: np.ndarray, rows: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """Log-likelihood per row of free vectors ``X`` and a failed mask; the rows are
        simulated ``rows`` at a time and only their sums of squares are kept, so the
        memory does not grow with the number of rows."""
        n = X.shape[0]
        ll = np.empty(n)
        failed = np.zeros(n, bool)
        for a in range(0, n, rows):
            b = min(n, a + rows)
            R = self.problem.residuals_batch(X[a:b])
            failed[a:b] = ~np.all(np.isfinite(R), axis=1)
            ll[a:b] = self.loglik_of(R, S[a:b], P[a:b])
            del R
        return ll, failed

    def pointwise(
        self, X: np.ndarray, S: np.ndarray, P: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Pointwise log-likelihood rows (n, n_residuals) and a failed mask (all rows at
        once: for few rows)."""
        R = self.problem.residuals_batch(X)
        failed = ~np.all(np.isfinite(R), axis=1)
        return self.pointwise_of(R, S, P), failed


class SampledSigmaLogLikelihood(GaussianLogLikelihood):
    """I.i.d. Gaussian errors with σ per channel sampled as ``log σ`` (coordinates
    ``log_sigma_<channel>``), prior ``p(σ) ∝ 1/σ`` within :data:`SIGMA_RANGE`; ``sigma``
    is the scale it starts from (the floor)."""

    def noise_names(self) -> list[str]:
        return [f"log_sigma_{c}" for c in self.channels]

    def noise_z(self, sigma: Mapping | None = None, phi: Mapping | None = None) -> list:
        return [math.log((sigma or self.sigma)[c]) for c in self.channels]

    def noise_of(self, W: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        S = np.exp(W[:, : len(self.channels)])
        return S, np.zeros_like(S)

    def noise_log_prior(self, S: np.ndarray, P: np.ndarray) -> np.ndarray:
        # p(σ) ∝ 1/σ is uniform in log σ (within a wide physical range).
        ls = np.log(S)
        lo, hi = SIGMA_RANGE
        return np.where(np.all((ls > math.log(lo)) & (ls < math.log(hi)), axis=1), 0.0, -np.inf)


class AR1LogLikelihood(SampledSigmaLogLikelihood):
    """AR(1) errors per channel, ``e_t = φ e_{t-1} + ε_t``: the innovation scale σ sampled
    as in :class:`SampledSigmaLogLikelihood`, ``φ`` (coordinates ``phi_<channel>``) uniform
    on (−:data:`PHI_LIMIT`, :data:`PHI_LIMIT`); the first sample of each segment from the
    stationary distribution."""

    def noise_names(self) -> list[str]:
        return super().noise_names() + [f"phi_{c}" for c in self.channels]

    def noise_z(self, sigma: Mapping | None = None, phi: Mapping | None = None) -> list:
        return super().noise_z(sigma) + [float((phi or {}).get(c, 0.0)) for c in self.channels]

    def noise_of(self, W: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        nc = len(self.channels)
        return np.exp(W[:, :nc]), W[:, nc : nc + nc]

    def noise_log_prior(self, S: np.ndarray, P: np.ndarray) -> np.ndarray:
        return super().noise_log_prior(S, P) + np.where(
            np.all(np.abs(P) < PHI_LIMIT, axis=1), 0.0, -np.inf
        )

    def _pointwise_segment(self, e, s, phi):
        innov = e.copy()
        innov[:, 1:] = e[:, 1:] - phi * e[:, :-1]
        # The first sample from the stationary distribution.
        innov[:, :1] = e[:, :1] * np.sqrt(1 - phi**2)
        out = -0.5 * LOG_2PI - np.log(s) - 0.5 * (innov / s) ** 2
        out[:, :1] += 0.5 * np.log(1 - phi**2)
        return out

    def _sum_of_squares(self, e, phi):
        d = e[:, 1:] - phi[:, None] * e[:, :-1]
        q = 1.0 - phi**2
        return np.einsum("ij,ij->i", d, d) + e[:, 0] ** 2 * q, 0.5 * np.log(q)

"""The sampler's moves (``sample --moves``) and the fit proposal they may use.

emcee's stretch move alone, or mixtures with differential-evolution moves and
:class:`FitProposalMove` (independence proposals from the least-squares fit); the default
:data:`DEFAULT_MOVES` was chosen by the effective samples per second measured side by side
(``benchmarks/bench_sampler_moves.py``). The fit proposal's centre and width come from the
fit (:func:`fit_proposal`: :func:`fit_covariance` for the parameters, :func:`noise_start`
for the noise coordinates), and it is re-centred once on the ensemble's own draws at
:data:`ADAPT_AT` (:func:`adapted`).
"""

from __future__ import annotations

import math

import emcee
import numpy as np

from ..likelihood import LogPosterior
from ..move_names import ACCEPTANCE, DEFAULT_MOVES, LEGACY_MOVES, MOVES  # noqa: F401

#: Step after which the fit proposal (``fit-de``) is re-centred, once, on the mean and
#: covariance of the ensemble's draws of the steps since ADAPT_AT/2, and then kept fixed: the
#: least-squares point is not exactly the posterior's centre, nor its curvature the
#: posterior's covariance, and in 15 dimensions small differences cost most acceptances.
#: Each step's kernel keeps the posterior (the proposal never depends on the current walkers).
ADAPT_AT = 150


class FitProposalMove(emcee.moves.MHMove):
    """Independence proposals from the least-squares fit: every walker proposes a point drawn
    from a multivariate Student t (``nu`` degrees of freedom) centred on the fit with
    ``scale`` squared times the fit's covariance, accepted by Metropolis-Hastings with the
    proposal's density ratio. The proposal does not depend on the walkers, so the chain keeps
    the posterior exactly whatever the fit's quality; where the posterior is close to the
    fit's Gaussian (much data, as here) most proposals are accepted and a walker's next
    position is nearly independent of its last. The t's heavy tails keep the tails of a
    wider posterior reachable. Its random numbers come from the sampler's random state
    (resumed bit for bit)."""

    def __init__(self, mean, cov, nu: float = 5.0, scale: float = 1.2):
        self.nu, self.scale = float(nu), float(scale)
        self._centre(mean, cov)
        super().__init__(self._propose, ndim=self.mean.size)

    def _centre(self, mean, cov) -> None:
        self.mean = np.asarray(mean, float)
        lam, V = np.linalg.eigh(0.5 * (np.asarray(cov, float) + np.asarray(cov, float).T))
        lam = np.maximum(lam, 1e-300)
        self.root = V * (self.scale * np.sqrt(lam))  # cov * scale² = root rootᵀ
        self.inv_root = (V / (self.scale * np.sqrt(lam))).T

    def set(self, mean, cov) -> None:
        """Another centre and covariance (the same ``nu`` and ``scale``)."""
        self._centre(mean, cov)
        super().__init__(self._propose, ndim=self.mean.size)

    def _log_q(self, x: np.ndarray) -> np.ndarray:
        y = (x - self.mean) @ self.inv_root.T
        m = np.einsum("ij,ij->i", y, y)
        return -0.5 * (self.nu + self.mean.size) * np.log1p(m / self.nu)

    def _propose(self, x0: np.ndarray, random):
        n, d = x0.shape
        g = random.randn(n, d)
        w = np.sqrt(random.chisquare(self.nu, n) / self.nu)
        q = self.mean + (g / w[:, None]) @ self.root.T
        return q, self._log_q(x0) - self._log_q(q)


def emcee_moves(name: str, proposal: tuple[np.ndarray, np.ndarray] | None = None) -> list:
    """The emcee move objects, with weights, of :data:`MOVES` ``name`` (``proposal``: the
    mean and covariance of :class:`FitProposalMove`, for moves that use it)."""
    if name not in MOVES:
        raise ValueError(f"moves {name!r}: choose one of {', '.join(MOVES)}")

    def fit_move():
        if proposal is None:
            raise ValueError(f"moves {name!r}: the fit proposal needs a mean and covariance")
        return FitProposalMove(*proposal)

    make = {
        "stretch": emcee.moves.StretchMove,
        "de": emcee.moves.DEMove,
        "snooker": emcee.moves.DESnookerMove,
        "fit": fit_move,
    }
    return [(make[kind](), weight) for kind, weight in MOVES[name][0]]


def uses_fit_proposal(name: str) -> bool:
    return any(kind == "fit" for kind, _ in MOVES[name][0])


def fit_proposal(logpost: LogPosterior, x_fit) -> tuple[np.ndarray, np.ndarray]:
    """Mean and covariance of every sampling coordinate at the fit: the parameters'
    :func:`fit_covariance`, the noise coordinates' :func:`noise_start` (independent)."""
    nc, ns = noise_start(logpost, x_fit)
    mean = np.concatenate([logpost.to_z(np.asarray(x_fit, float))[: logpost.k], nc])
    cov = np.zeros((logpost.ndim, logpost.ndim))
    cov[: logpost.k, : logpost.k] = fit_covariance(logpost, x_fit)
    cov[logpost.k :, logpost.k :] = np.diag(ns**2)
    return mean, cov


def noise_start(logpost: LogPosterior, x_fit) -> tuple[np.ndarray, np.ndarray]:
    """Centre and spread of the noise coordinates (``log σ``, ``φ``) from the residuals at
    the fit: σ the residual's RMS per channel (with AR(1) errors the innovations' RMS, φ
    the lag-1 autocorrelation), spreads their large-sample posterior standard deviations."""
    n_noise = logpost.ndim - logpost.k
    if n_noise == 0:
        return np.zeros(0), np.zeros(0)
    r = np.asarray(logpost.problem.residuals(np.asarray(x_fit, float)), float)
    parts: dict[str, list[np.ndarray]] = {}
    for c, a, b in logpost.segments:  # several experiments: pooled per channel
        parts.setdefault(c, []).append(r[a:b] / logpost.problem.weights[c])
    logs, phis, sd_s, sd_p = {}, {}, {}, {}
    for c, pieces in parts.items():
        e = np.concatenate(pieces)
        n = max(e.size, 2)
        phi = 0.0
        if logpost.ar1:
            den = float(e[:-1] @ e[:-1])
            phi = float(np.clip((e[1:] @ e[:-1]) / den, -0.99, 0.99)) if den > 0 else 0.0
            e = e[1:] - phi * e[:-1]
        rms = math.sqrt(float(e @ e) / max(e.size, 1))
        s = rms if rms > 0 and math.isfinite(rms) else logpost.floor[c]
        logs[c] = math.log(min(max(s, 2e-8), 5.0))  # inside the prior's 1e-8..10 rad
        sd_s[c] = 1.0 / math.sqrt(2 * n)
        phis[c], sd_p[c] = phi, math.sqrt(max(1 - phi**2, 1e-4) / n)
    centre = [logs[c] for c in logpost.channels]
    spread = [sd_s[c] for c in logpost.channels]
    if logpost.ar1:
        centre += [phis[c] for c in logpost.channels]
        spread += [sd_p[c] for c in logpost.channels]
    return np.array(centre), np.array(spread)


def fit_covariance(logpost: LogPosterior, x_fit) -> np.ndarray:
    """Covariance of the parameter coordinates at the fit: the inverse curvature of the
    likelihood being sampled (with ``robust`` noise the fit's honest covariance). A
    direction the data do not determine at all (an exact symmetry) gets a 1 % spread."""
    x_fit = np.asarray(x_fit, float)
    if logpost.noise == "sampled":
        # The residuals' own scale (σ's start), not the floor: σ² scales the covariance.
        nc, _ = noise_start(logpost, x_fit)
        sig = {c: math.exp(v) for c, v in zip(logpost.channels, nc, strict=False)}
        J, _ = logpost.problem.jacobian(x_fit)
        w = np.empty(J.shape[0])
        for c, a, b in logpost.segments:
            w[a:b] = 1.0 / (sig[c] * logpost.problem.weights[c])
        Jz = J * w[:, None] * np.where(logpost.log, x_fit, 1.0)[None, :]
        Hz = Jz.T @ Jz
    else:
        Hz = logpost._precision_iid(x_fit)
    if logpost.adjust is not None:
        Hz = logpost.adjust.T @ Hz @ logpost.adjust
    lam, V = np.linalg.eigh(0.5 * (Hz + Hz.T))
    var = np.where(lam > 1e-10 * max(lam.max(), 1e-300), 1.0 / np.maximum(lam, 1e-300), 1e-4)
    cov = (V * var) @ V.T
    evals = np.linalg.eigvalsh(cov)
    if not np.all(np.isfinite(evals)) or evals.max() <= 0:
        cov = np.diag(np.full(logpost.k, 1e-6))
    return cov


def adapted(chain: np.ndarray, proposal):
    """Mean and covariance of the draws of steps ADAPT_AT/2 .. ADAPT_AT - 1 (every walker);
    the previous proposal where they cannot give a positive definite covariance."""
    z = np.asarray(chain[ADAPT_AT // 2 : ADAPT_AT], float).reshape(-1, chain.shape[-1])
    if z.shape[0] < 10 * z.shape[1]:
        return proposal
    cov = np.cov(z.T)
    if not np.all(np.isfinite(cov)) or float(np.min(np.linalg.eigvalsh(cov))) <= 0:
        return proposal
    return z.mean(axis=0), cov

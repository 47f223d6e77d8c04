"""Where the walkers of a new ensemble start: drawn from the least-squares fit's covariance
in sampling coordinates at its full width (:data:`STARTS` ``fit``), or in the former small
ball around the fit (``ball``); every start has a finite log-posterior."""

from __future__ import annotations

import numpy as np

from ..likelihood import LogPosterior
from .moves import fit_covariance, noise_start

#: How the walkers start: ``fit`` draws them from the fit's covariance at full width (noise
#: coordinates from the residuals); ``ball`` is the former small ball (0.1 of that width,
#: noise coordinates at the floor ± 1 %).
STARTS = ("fit", "ball")


def start_walkers(
    logpost: LogPosterior, x_fit, n_walkers: int, rng, *, start: str = "fit"
) -> np.ndarray:
    """Starting positions of ``n_walkers``, each with a finite log-posterior.

    ``fit``: drawn from :func:`fit_covariance` at full width around the fit, the noise
    coordinates from :func:`noise_start`, so the ensemble starts where the posterior is
    (when it is near Gaussian) instead of spending its first hundreds of steps expanding;
    ``ball``: :meth:`LogPosterior.start_ball` (0.1 of the width, the former start).
    """
    if start == "ball":
        return logpost.start_ball(x_fit, n_walkers, rng)
    if start != "fit":
        raise ValueError(f"start {start!r}: choose one of {', '.join(STARTS)}")
    x_fit = np.asarray(x_fit, float)
    cov = fit_covariance(logpost, x_fit)
    z0 = logpost.to_z(x_fit)[: logpost.k]
    nc, ns = noise_start(logpost, x_fit)
    out = np.empty((n_walkers, logpost.ndim))
    i = tries = 0
    while i < n_walkers:
        tries += 1
        if tries > 50 * n_walkers:
            raise RuntimeError(
                "cannot place the walkers: the posterior is -inf all around "
                "the fit (check the priors and bounds)"
            )
        zz = np.empty(logpost.ndim)
        zz[: logpost.k] = rng.multivariate_normal(z0, cov, method="eigh")
        zz[logpost.k :] = nc + ns * rng.standard_normal(nc.size)
        if np.isfinite(logpost(zz[None, :])[0]):
            out[i] = zz
            i += 1
    return out

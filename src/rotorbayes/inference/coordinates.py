"""The coordinates a posterior is sampled in, and the curvature adjustment.

* :class:`LogCoordinates` — the transformation: a free parameter whose lower bound is ≥ 0
  and whose value at the fit is > 0 is sampled as ``z = log θ``, the others as they are;
  the log-Jacobian ``log |dθ/dz| = Σ z`` over the log coordinates keeps the prior the one
  declared on θ.
* :class:`CurvatureAdjustment` — where the likelihood is evaluated for coordinates ``z``:
  at ``ẑ + C (z − ẑ)``, with ``C`` chosen so that the curvature of the i.i.d. likelihood at
  the fit ``ẑ`` becomes the inverse of the fit's honest covariance (an open-faced sandwich
  adjustment: the shape away from the fit, ridges and bounds included, stays the model's
  own; the prior is untouched).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np


class LogCoordinates:
    """``z = log θ`` where ``log`` is true, ``z = θ`` elsewhere (one flag per free
    parameter)."""

    def __init__(self, log):
        self.log = np.asarray(log, dtype=bool)

    @classmethod
    def for_fit(cls, lower: np.ndarray, x_fit) -> LogCoordinates:
        """Log coordinates for every parameter with ``lower >= 0`` that is positive at the
        fit ``x_fit``."""
        x_fit = np.asarray(x_fit, float)
        return cls(np.array([lower[j] >= 0 and x_fit[j] > 0 for j in range(len(x_fit))]))

    def __len__(self) -> int:
        return len(self.log)

    def names(self, names: Sequence[str]) -> list[str]:
        """Coordinate names: ``log_<name>`` for a log coordinate."""
        return [f"log_{n}" if lg else n for n, lg in zip(names, self.log, strict=True)]

    def to_z(self, x) -> list[float]:
        """The coordinates of the free vector ``x``."""
        x = np.asarray(x, float)
        return [math.log(v) if lg else float(v) for v, lg in zip(x, self.log, strict=True)]

    def to_x(self, Z: np.ndarray) -> np.ndarray:
        """The free vectors of coordinate rows ``Z`` (a copy)."""
        X = Z.copy()
        X[:, self.log] = np.exp(X[:, self.log])
        return X

    def log_jacobian(self, Z: np.ndarray) -> np.ndarray:
        """``log |dθ/dz|`` per row of ``Z``: ``p(z) = p(θ) |dθ/dz| = p(θ) θ``."""
        return np.sum(Z[:, self.log], axis=1)

    def derivative(self, x) -> np.ndarray:
        """``dθ/dz`` at the free vector ``x`` (diagonal)."""
        return np.where(self.log, np.asarray(x, float), 1.0)


class CurvatureAdjustment:
    """Evaluation at ``z_fit + C (z − z_fit)`` (the first ``len(z_fit)`` coordinates)."""

    def __init__(self, z_fit: np.ndarray, C: np.ndarray):
        self.z_fit = np.asarray(z_fit, float)
        self.C = np.asarray(C, float)
        k = self.z_fit.size
        if self.C.shape != (k, k):
            raise ValueError(
                f"C has shape {self.C.shape}; give a ({k}, {k}) matrix for {k} coordinates"
            )

    @classmethod
    def matching(cls, z_fit: np.ndarray, H: np.ndarray, V: np.ndarray) -> CurvatureAdjustment:
        """``C`` with ``Cᵀ H C = V⁻¹``: ``H`` the i.i.d. precision, ``V`` the honest
        covariance, both in sampling coordinates.  Directions the data do not determine
        (or whose honest variance is not finite) keep ``C = I``; so does everything when the
        determined ones have an exact symmetry (the model's shape is left as it is)."""
        k = len(z_fit)
        bad = ~np.all(np.isfinite(V), axis=0) | ~np.isfinite(np.diag(V))
        C = np.eye(k)
        ok = ~bad
        if ok.sum() == 0:
            return cls(z_fit, C)
        Hs = H[np.ix_(ok, ok)]
        Vs = V[np.ix_(ok, ok)]
        lam, U = np.linalg.eigh(0.5 * (Hs + Hs.T))
        good = lam > 1e-12 * max(lam.max(), 1e-300)
        if not good.all():
            return cls(z_fit, C)
        W = (U * np.sqrt(lam)).T  # H = WᵀW
        Wi = U / np.sqrt(lam)  # W⁻¹
        S = W @ Vs @ W.T  # target in the frame where the i.i.d. posterior is N(0, I)
        mu, Q = np.linalg.eigh(0.5 * (S + S.T))
        mu = np.maximum(mu, 1e-300)
        Cw = (Q / np.sqrt(mu)) @ Q.T  # S^(-1/2)
        C[np.ix_(ok, ok)] = Wi @ Cw @ W
        return cls(z_fit, C)

    def points(self, Z: np.ndarray) -> np.ndarray:
        """Where the likelihood is evaluated for coordinate rows ``Z`` (a copy; columns
        after the first ``len(z_fit)``, the noise coordinates, as they are)."""
        k = self.z_fit.size
        Z = np.array(Z, float, copy=True)
        Z[:, :k] = self.z_fit + (Z[:, :k] - self.z_fit) @ self.C.T
        return Z

    def curvature(self, H: np.ndarray) -> np.ndarray:
        """The adjusted likelihood's curvature ``Cᵀ H C`` from the unadjusted ``H``."""
        return self.C.T @ H @ self.C

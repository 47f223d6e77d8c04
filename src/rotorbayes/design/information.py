"""What a new experiment would add: Fisher information and separation gaps, linearised.

A :class:`Frame` is one fitted model on the existing data, extended by a new experiment.
Its coordinates are the fit's free parameters in *relative* units (``log θ`` for positive
ones, ``θ / scale`` for signed ones, as :func:`rotorbayes.inference.identify.fisher`), plus
the new experiment's own string torsion ``alpha0[k]`` when the fit estimates one per
experiment.  Residuals are in noise units: divided by the channel's floor (the encoder
quantisation ``q/√12``, or the data's jitter where it is larger) times its weight.

* ``F_old = J_oldᵀ J_old`` at the fit; a candidate input ``u`` adds ``F_new(u)``; the
  predicted covariance with both experiments is ``(F_old + F_new)⁻¹`` (the new torsion
  marginalised by the inverse);
* for two candidate models A and B fitted to the existing data, the expected SSR gap when A
  is true and B is refitted to old and new data together is, to first order,
  ``gap(A→B) = |d|² − gᵀ (F_B,old + F_B,new)⁻¹ g`` with ``d = ŷ_A(u) − ŷ_B(u)``
  and ``g = J_B,newᵀ d``
  (B's parameters may move by δ; the old data charge ``δᵀ F_B,old δ`` for it, the new data
  keep ``|d − J_B,new δ|²``; the minimum over δ is the formula).  It is in noise-variance
  units (Δχ²): the part of the prediction difference B cannot absorb by refitting.
"""

from __future__ import annotations

import math

import numpy as np

from ..inference.problem import Problem, local_name
from ..io.measurements import Experiment


def _relative_scale(problem: Problem, names: list[str], x: np.ndarray) -> np.ndarray:
    """The scale of each coordinate: ``θ`` where the coordinate is ``log θ``, else a size."""
    out = np.empty(len(names))
    for j, n in enumerate(names):
        info = problem.info(n)
        if info.lower >= 0 and x[j] > 0:
            out[j] = x[j]
        else:
            out[j] = max(abs(x[j]), 1e-3 * (info.upper - info.lower))
    return out


def _solve_pd(F: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``F⁻¹ v`` for a symmetric positive semi-definite ``F`` (a tiny ridge where singular)."""
    ridge = 1e-13 * max(float(np.trace(F)) / max(F.shape[0], 1), 1e-300)
    return np.linalg.solve(F + ridge * np.eye(F.shape[0]), v)


class Frame:
    """A fit on the existing data, ready to weigh a new experiment (module docstring).

    Parameters
    ----------
    problem : Problem
        The fitted problem (its experiments are the existing data).
    x : array
        The fitted free vector.
    alpha0_new : float
        Initial torsion of the new experiment in the predictions [rad] (0: the string is
        unwound before it is run).
    J : array, optional
        The fit's Jacobian, if already known.
    """

    def __init__(
        self,
        problem: Problem,
        x: np.ndarray,
        *,
        alpha0_new: float = 0.0,
        J: np.ndarray | None = None,
    ):
        if problem.prescribed_upper:
            raise ValueError(
                "this fit drives the lower disc with the measured upper angle, so it cannot "
                "predict a new input's response; design from a fit with the motor model "
                "(fit without --prescribed-upper)"
            )
        self.problem = problem
        self.x = np.asarray(x, float)
        self.model = problem.model
        self.k_old = len(problem.experiments)
        floors, _ = problem.noise_floors()
        self.floors = floors
        self.sigma = {c: problem.weights[c] * floors[c] for c in problem.channels}
        self.names_base = problem.names_base()
        self.per_exp = "alpha0" in self.names_base
        # Combined coordinates: the fit's names ('alpha0' -> 'alpha0[0]' for one
        # experiment), then the new experiment's torsion.
        self.names = [self._old_name(n) for n in problem.names]
        if self.per_exp:
            self.names.append(f"alpha0[{self.k_old}]")
        self.new_index = {}
        for j, n in enumerate(self.names):
            b, idx = local_name(n)
            if idx is None:
                self.new_index[n] = j
            elif idx == self.k_old:
                self.new_index["alpha0"] = j
        self.alpha0_new = float(alpha0_new)
        self.x_comb = np.r_[self.x, [self.alpha0_new] if self.per_exp else []]
        scale_old = _relative_scale(problem, problem.names, self.x)
        self.scale = np.r_[scale_old, [0.02] if self.per_exp else []]
        self.scale_old = scale_old
        if J is None:
            J, _ = problem.jacobian(self.x)
        self.J_old = J
        Js = self._scaled_rows(problem, J) * scale_old[None, :]
        F = Js.T @ Js
        self.F_fit = F  # the fit's own coordinates
        n = len(self.names)
        self.F_old = np.zeros((n, n))
        self.F_old[: F.shape[0], : F.shape[0]] = F
        self.params_new = dict(problem.params_for(self.x, 0))
        if "alpha0" in self.model.active:
            self.params_new["alpha0"] = (
                self.alpha0_new
                if self.per_exp
                else problem.params_for(self.x, 0).get("alpha0", 0.0)
            )

    def _old_name(self, n: str) -> str:
        if n == "alpha0" and self.k_old == 1:
            return "alpha0[0]"
        return n

    def _scaled_rows(self, problem: Problem, J: np.ndarray) -> np.ndarray:
        """Rows of ``J`` divided by each residual's noise sd (weight x floor)."""
        s = []
        for ex in problem.experiments:
            for c in problem.channels:
                s.append(np.full(ex.n, 1.0 / self.sigma[c]))
        return J * np.concatenate(s)[:, None]

    # ------------------------------------------------------------------ a new experiment
    def new_problem(self, t: np.ndarray, u: np.ndarray) -> Problem:
        """A one-experiment problem of this model on input ``u`` (measurements zero, so
        the residual is minus the weighted prediction)."""
        lower = self.model.config != "upper"
        z = np.zeros_like(u)
        ex = Experiment(t, u, z, z.copy() if lower else None, name="designed")
        return self.problem.like(
            model=self.model, experiments=[ex], free=self.names_base, base=self.params_new
        )

    def new_rows(self, t: np.ndarray, u: np.ndarray, *, with_prediction: bool = False):
        """The new experiment's Jacobian in combined relative coordinates and noise units
        (and its weighted prediction in noise units); raises SimulationError."""
        p = self.new_problem(t, u)
        x1 = p.x_from(self.params_new)
        r0 = p.residuals(x1) if with_prediction else None
        if r0 is not None and not np.all(np.isfinite(r0)):
            from ..model.simulate import SimulationError

            raise SimulationError("the model cannot be simulated on this input")
        J1, _ = p.jacobian(x1, r0=r0)
        J1 = self._scaled_rows(p, J1)
        Jc = np.zeros((J1.shape[0], len(self.names)))
        for j, n in enumerate(p.names):
            Jc[:, self.new_index[n]] = J1[:, j]
        Jc *= self.scale[None, :]
        if with_prediction:
            return Jc, -self._scaled_rows(p, r0[:, None])[:, 0]
        return Jc

    # ------------------------------------------------------------------------ criteria
    def sd_along(self, F: np.ndarray, v: np.ndarray) -> float:
        """1-σ width along ``v`` (combined coordinates) for information ``F``."""
        return math.sqrt(max(float(v @ _solve_pd(F, v)), 0.0))

    def sloppiest(self) -> tuple[np.ndarray, float]:
        """The fit's sloppiest direction (unit vector, combined coordinates) and its width."""
        w, V = np.linalg.eigh(self.F_fit)
        v = V[:, 0] * np.sign(V[np.argmax(np.abs(V[:, 0])), 0])
        return np.r_[v, [0.0] if self.per_exp else []], 1.0 / math.sqrt(max(w[0], 1e-300))

    def variances(self, F: np.ndarray, idx: list[int]) -> np.ndarray:
        """Relative variances of coordinates ``idx`` for information ``F``."""
        out = []
        for j in idx:
            e = np.zeros(F.shape[0])
            e[j] = 1.0
            out.append(float(e @ _solve_pd(F, e)))
        return np.array(out)


def separation_gap(a: Frame, b: Frame, ya: np.ndarray, yb: np.ndarray, Jb: np.ndarray) -> float:
    """Expected SSR gap [noise variances] when ``a`` is true and ``b`` is refitted to the
    old and new data (module docstring); ``ya``, ``yb`` predictions in noise units."""
    d = ya - yb
    g = Jb.T @ d
    F = b.F_old + Jb.T @ Jb
    return max(float(d @ d - g @ _solve_pd(F, g)), 0.0)

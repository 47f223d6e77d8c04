"""Which missing effect? Score (Lagrange-multiplier) tests of catalogue effects at a fit.

For an effect that is off, with parameters ψ at their null value ψ0, the residual's
sensitivity ``J_ψ = ∂r/∂ψ`` at the fit (:meth:`Problem.jacobian`, one batch of
simulations, no refit) tells how much switching it on would lower the SSR:

* project out what the free parameters can already do: ``J̃ = (I − Q Qᵀ) J_ψ`` with ``Q``
  an orthonormal basis of the free parameters' Jacobian;
* one Gauss-Newton step ``δ = −(J̃ᵀJ̃)⁻¹ J̃ᵀ r`` is the one-step estimate of ψ − ψ0, and
  ``rᵀ J̃ (J̃ᵀJ̃)⁻¹ J̃ᵀ r`` the predicted fall of the SSR;
* the test: the score ``J̃ᵀ r`` summed over contiguous time blocks (B of them) gives B
  block scores that are nearly independent even when the residuals are autocorrelated;
  their studentised mean is a t (one parameter) or Hotelling (several) statistic.  Where
  the null is on a bound (damping, delay, dead zone ≥ 0; static ≥ Coulomb friction) the
  test is one-sided: a step out of the physical range is no evidence.  Effects with
  nuisance parameters that vanish under the null (the Stribeck velocity and shape) take
  the supremum of the statistic over a grid, with a p-value from a block multiplier
  bootstrap.  Holm's method corrects for testing many effects.

An effect whose ``J̃`` is small against ``J_ψ`` lies in the span of the free parameters
(*equivalent* to them on these data); two effects whose ``J̃`` are nearly parallel cannot
be told apart by this input.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import special

from ..inference.problem import Problem, local_name
from ..io.measurements import quantisation_floor
from ..model import effects as _effects


def _t_sf(t: float, df: int) -> float:
    """Student's t upper tail, ``P(T > t)`` (scipy.stats' ``t.sf``, from scipy.special:
    scipy.stats costs a third of a second to import)."""
    return float(special.stdtr(df, -t))


#: Stribeck grid (velocity rad/s, shape) of the sup-score test.
WS_GRID = tuple(np.geomspace(0.1, 10.0, 9))
DELTA_GRID = (0.7, 1.0, 1.5, 2.0, 3.0)
#: ``|J̃| / |J|`` below which an effect counts as inside the free parameters' span.
EQUIVALENT_RATIO = 1e-3
#: ``|cos|`` between two candidates' J̃ above which they cannot be told apart.
ALIKE_COSINE = 0.98


@dataclass
class EffectScore:
    """The score test of one effect that is off."""

    effect: str
    physics: str
    parameters: list[str]
    units: list[str]
    statistic: float
    p_value: float
    p_adjusted: float = math.nan
    one_sided: bool = False
    step: dict[str, float] = field(default_factory=dict)
    size: dict[str, float] = field(default_factory=dict)
    predicted_ssr: float = math.nan
    predicted_rms_ratio: dict[str, float] = field(default_factory=dict)
    distinct_ratio: float = math.nan
    equivalent_to_free: bool = False
    #: A user's effect with no first-order response at its null (its torque quadratic in
    #: its parameter there): the derivative the test uses is ~0, so the test cannot see
    #: it, while a finite step of it changes the residuals in a way of its own.
    blind: bool = False
    alike: list[str] = field(default_factory=list)
    equivalences: list[str] = field(default_factory=list)
    nuisance: dict[str, float] = field(default_factory=dict)
    correction: np.ndarray | None = field(default=None, repr=False)
    Jt: np.ndarray | None = field(default=None, repr=False)

    def as_dict(self) -> dict:
        d = {
            "effect": self.effect,
            "physics": self.physics,
            "parameters": {
                n: {"one_step_estimate": v, "unit": u}
                for n, v, u in zip(self.parameters, self.step.values(), self.units, strict=True)
            },
            "statistic": self.statistic,
            "p_value": self.p_value,
            "p_adjusted": self.p_adjusted,
            "one_sided": self.one_sided,
            "predicted_ssr": self.predicted_ssr,
            "predicted_rms_over_floor": self.predicted_rms_ratio,
            "distinct_from_free_parameters": self.distinct_ratio,
            "equivalent_to_free_parameters": self.equivalent_to_free,
            "blind_at_null": self.blind,
            "indistinguishable_from": self.alike,
            "equivalences": self.equivalences,
        }
        if self.nuisance:
            d["nuisance_best_grid_point"] = self.nuisance
        return d


def candidates(problem: Problem) -> list[_effects.Effect]:
    """Catalogue effects that apply to the problem's model and are off."""
    m = problem.model
    on = {e.name for e in m.effects}
    out = []
    for e in _effects.CATALOGUE.values():
        if e.name in on or m.config not in e.configs:
            continue
        if m.prescribed_upper and e.motor:
            continue
        out.append(e)
    return out


def block_ids(problem: Problem, n_blocks: int) -> np.ndarray:
    """Block label of every residual: contiguous time blocks, the same for all channels
    of an experiment, about ``n_blocks`` in all."""
    total = sum(ex.n for ex in problem.experiments)
    length = max(1, int(math.ceil(total / n_blocks)))
    ids, start = [], 0
    for ex in problem.experiments:
        b = start + np.arange(ex.n) // length
        ids += [b] * len(problem.channels)
        start = int(b[-1]) + 1
    return np.concatenate(ids)


def _test_params(effect, problem) -> list[str]:
    names = [p.name for p in effect.switches]
    if effect.per_experiment and len(problem.experiments) > 1:
        return [f"{n}[{i}]" for n in names for i in range(len(problem.experiments))]
    return names


def _blind(pe, x, r, Q, e, names, values) -> bool:
    """Whether a user's effect that the derivative calls equivalent to the free parameters
    is only blind at its null: a secant over a fifth of its parameters' typical sizes
    changes the residuals in a direction of its own.  Measured (a fresh-eyes trial): a
    saturating motor written as ``k_m v - tanh(s k_m v) / s``, whose torque is cubic in
    ``s`` at 0, was tagged "equivalent to the free parameters: cannot be told apart", yet
    its refit took the fit from 1120x the floor to 0.957x."""
    secant = {
        p.name: 0.2 * (p.start - p.null)
        for p in e.parameters
        if p.name in names
        and math.isfinite(p.start)
        and math.isfinite(p.null)
        and p.start != p.null
    }
    if not secant:
        return False
    try:
        Js, _ = pe.jacobian(x, names, r0=r, values=values or None, secant=secant)
    except Exception:  # noqa: BLE001 - an unsimulable step: no verdict beyond the derivative's
        return False
    Jt = Js - Q @ (Q.T @ Js)
    size = float(np.linalg.norm(Js))
    return bool(size > 0 and float(np.linalg.norm(Jt)) >= EQUIVALENT_RATIO * size)


def _one_sided(effect) -> bool:
    """The null value is on a bound (or Ts_l = Tc_l): only one direction is physical."""
    sw = effect.switches
    if len(sw) != 1:
        return False
    p = sw[0]
    return p.name == "Ts_l" or p.null == p.lower or p.null == p.upper


def _orth(J):
    if J.size == 0:
        return np.zeros((J.shape[0], 0))
    scale = np.linalg.norm(J, axis=0)
    scale[scale == 0] = 1.0
    Q, R = np.linalg.qr(J / scale)
    keep = np.abs(np.diag(R)) > 1e-10
    return Q[:, keep]


def _stat(S_blocks: np.ndarray, one_sided_up: bool | None):
    """Studentised block-score statistic and its p-value.

    ``S_blocks`` (B, q).  For q = 1, ``one_sided_up`` says the physical direction is
    a *decrease* of the score's mean (δ > 0 ⇔ mean < 0); None means two-sided.
    """
    B, q = S_blocks.shape
    m = S_blocks.mean(axis=0)
    C = np.cov(S_blocks, rowvar=False, ddof=1).reshape(q, q)
    if q == 1:
        sd = math.sqrt(max(C[0, 0], 1e-300))
        t = math.sqrt(B) * m[0] / sd
        if one_sided_up is None:
            return abs(t), 2 * _t_sf(abs(t), B - 1)
        return -t, _t_sf(-t, B - 1)
    try:
        T2 = B * float(m @ np.linalg.solve(C, m))
    except np.linalg.LinAlgError:
        T2 = B * float(m @ np.linalg.pinv(C) @ m)
    if B <= q:
        return T2, math.nan
    F = (B - q) / (q * (B - 1)) * T2
    return F, float(special.fdtrc(q, B - q, F))  # F's upper tail (scipy.stats' f.sf)


def robust_standard_errors(
    Jf: np.ndarray,
    r: np.ndarray,
    blocks: np.ndarray,
    names: Sequence[str],
    noise_ssr: float | None = None,
) -> dict[str, float]:
    """Autocorrelation-robust standard errors of the free parameters at a fit.

    The sandwich ``A⁻¹ B A⁻¹`` with ``A = JᵀJ`` and ``B`` the covariance of the block
    scores ``J_bᵀ r_b`` over contiguous time blocks: the encoder's rounding error is not
    white (constant while a disc sticks), so the i.i.d. formula ``σ² A⁻¹`` is far too
    small; block sums stay nearly independent.

    ``noise_ssr``: the SSR that noise alone would leave.  Far above the floor the residual
    is model error, not noise; ``B`` is then scaled down by ``noise_ssr / SSR`` so that the
    errors say what the *data* can resolve, not how wrong the model is.
    """
    k = Jf.shape[1]
    if k == 0:
        return {}
    B = int(blocks.max()) + 1
    S = np.zeros((B, k))
    np.add.at(S, blocks, Jf * r[:, None])
    S -= S.mean(axis=0)
    meat = S.T @ S * B / max(B - 1, 1)
    ssr = float(r @ r)
    if noise_ssr is not None and ssr > noise_ssr > 0:
        meat *= noise_ssr / ssr
    Ainv = np.linalg.pinv(Jf.T @ Jf)
    cov = Ainv @ meat @ Ainv
    return {n: float(math.sqrt(max(cov[i, i], 0.0))) for i, n in enumerate(names)}


def score_tests(
    problem: Problem,
    x: np.ndarray,
    *,
    effects: Sequence | None = None,
    n_blocks: int = 30,
    n_boot: int = 2000,
    seed: int = 0,
    floor: dict[str, float] | None = None,
    context: dict | None = None,
    extra: Mapping[str, Problem] | None = None,
) -> list[EffectScore]:
    """Score tests of every effect that is off (or of ``effects``), best first.

    Parameters
    ----------
    problem, x : the fitted problem and its free vector at the fit.
    n_blocks : number of time blocks for the autocorrelation-robust variance.
    n_boot : bootstrap draws for effects tested over a grid of nuisance values.
    floor : noise RMS per channel (default: the encoder quantisation floor).
    context : dict, optional
        Filled with ``robust_se`` (:func:`robust_standard_errors` of the free parameters
        by name), for judging the candidates' sizes.
    extra : mapping, optional
        Effects outside the catalogue (a user's own) to test as well: effect name -> the
        problem with that effect switched on at its null (:meth:`Problem.with_effects`),
        whose free set is ``problem``'s.  Their nuisance parameters are scanned over
        eight points of their range.
    """
    r = problem.residuals(x)
    if not np.all(np.isfinite(r)):
        raise ValueError("the model cannot be simulated at the fit; nothing to diagnose")
    Jf, _ = problem.jacobian(x, r0=r)
    Q = _orth(Jf)
    blocks = block_ids(problem, n_blocks)
    B = int(blocks.max()) + 1
    ssr = float(r @ r)
    if context is not None:
        n_per = {c: sum(ex.n for ex in problem.experiments) for c in problem.channels}
        noise_ssr = sum(n_per[c] * (problem.weights[c] * floor[c]) ** 2 for c in problem.channels)
        context["robust_se"] = robust_standard_errors(Jf, r, blocks, problem.names, noise_ssr)
    floor = floor or {c: quantisation_floor(c) for c in problem.channels}
    rng = np.random.default_rng(seed)
    cands = list(effects) if effects is not None else candidates(problem)
    extra = dict(extra or {})
    for name, pe in extra.items():
        cands += [e for e in pe.model.effects if e.name == name]
    out: list[EffectScore] = []
    for e in cands:
        e = _effects.resolve([e])[0] if isinstance(e, str) else e
        pe = extra.get(e.name, problem)  # the problem that knows the effect's parameters
        names = _test_params(e, problem)
        one_sided = _one_sided(e)
        # A switch whose response is not differentiable at its null (a dead zone: nothing
        # happens while |u| < width) is probed by a secant over a fifth of its typical size.
        secant = {
            p.name: 0.2 * p.start
            for p in e.switches
            if p.name == "u_deadzone" and math.isfinite(p.start)
        }
        nuis = [p for p in e.parameters if p.nuisance]
        if nuis:
            grids = [
                dict(zip([p.name for p in nuis], vals, strict=True))
                for vals in itertools.product(
                    *[
                        WS_GRID
                        if p.name == "ws_l"
                        else DELTA_GRID
                        if p.name == "delta_l"
                        else _user_grid(p)
                        if e.name in extra
                        else (p.start,)
                        for p in nuis
                    ]
                )
            ]
        else:
            grids = [{}]
        best = None
        per_grid = []
        for g in grids:
            try:
                Jp, _ = pe.jacobian(x, names, r0=r, values=g or None, secant=secant)
            except Exception:  # noqa: BLE001 - an unsimulable perturbation: skip the point
                continue
            Jt = Jp - Q @ (Q.T @ Jp)
            S_blocks = np.zeros((B, len(names)))
            np.add.at(S_blocks, blocks, Jt * r[:, None])
            stat, p = _stat(S_blocks, True if one_sided else None)
            per_grid.append((S_blocks, stat))
            if best is None or stat > best[0]:
                best = (stat, p, g, Jp, Jt, S_blocks)
        if best is None:
            continue
        stat, p, g, Jp, Jt, S_blocks = best
        if len(grids) > 1:
            # Sup over the grid: multiplier bootstrap of the block scores.
            sds = [np.std(Sb[:, 0], ddof=1) for Sb, _ in per_grid]
            cents = [Sb[:, 0] - Sb[:, 0].mean() for Sb, _ in per_grid]
            G = rng.standard_normal((n_boot, B))
            sup = np.full(n_boot, -np.inf)
            for c, sd in zip(cents, sds, strict=True):
                t_star = math.sqrt(B) * (G @ c) / B / max(sd, 1e-300)
                sup = np.maximum(sup, -t_star if one_sided else np.abs(t_star))
            p = float((1 + np.sum(sup >= stat)) / (n_boot + 1))
        JtJ = Jt.T @ Jt
        g_r = Jt.T @ r
        try:
            delta = -np.linalg.solve(JtJ, g_r)
        except np.linalg.LinAlgError:
            delta = -np.linalg.pinv(JtJ) @ g_r
        if one_sided and delta[0] < 0:
            delta = np.zeros_like(delta)
        corr = Jt @ delta
        r_new = r + corr
        pred_ssr = float(r_new @ r_new)
        ratio = float(np.linalg.norm(Jt) / max(np.linalg.norm(Jp), 1e-300))
        blind = (
            ratio < EQUIVALENT_RATIO and _blind(pe, x, r, Q, e, names, g)
            if e.name in extra
            else False
        )
        if blind:
            ratio = math.nan  # the derivative's ratio is of rounding, not of the effect
        base_vals = problem.params_for(x, 0)
        step = {}
        for n, d in zip(names, delta, strict=True):
            b, idx = local_name(n)
            null = base_vals["Tc_l"] if b == "Ts_l" else pe.model.info[b].null
            step[n] = float(null + d)
        size = {n: float(d) for n, d in zip(names, delta, strict=True)}
        out.append(
            EffectScore(
                effect=e.name,
                physics=e.physics,
                parameters=names,
                units=[pe.model.info[local_name(n)[0]].unit for n in names],
                statistic=float(stat),
                p_value=float(p),
                one_sided=one_sided,
                step=step,
                size=size,
                predicted_ssr=pred_ssr,
                predicted_rms_ratio=problem.rms_over_floor(r_new, floor),
                distinct_ratio=ratio,
                equivalent_to_free=ratio < EQUIVALENT_RATIO,
                blind=blind,
                equivalences=list(e.equivalences),
                nuisance={k: float(v) for k, v in g.items()},
                correction=corr,
                Jt=Jt,
            )
        )
    _holm(out)
    _alike(out)
    for s in out:
        if s.equivalent_to_free:
            # Inside the free parameters' span the step is ill-posed: no estimate to quote.
            s.step = {n: math.nan for n in s.step}
            s.size = {n: math.nan for n in s.size}
            s.predicted_ssr = ssr
    order = list(_effects.CATALOGUE)

    def key(s):
        # Ties (alike effects give the same p and SSR to rounding) fall back to the
        # catalogue's order, so the ranking does not depend on the last digits.
        idx = order.index(s.effect) if s.effect in order else len(order)
        return (
            s.equivalent_to_free,
            float(f"{s.p_adjusted:.3g}"),
            float(f"{s.predicted_ssr - ssr:.3g}"),
            idx,
        )

    out.sort(key=key)
    return out


def _user_grid(p) -> tuple[float, ...]:
    """Eight values of a user effect's nuisance parameter (a phase, say) across its range,
    its declared start among them: the score test takes the best, with a bootstrap for
    the search, as it does for the Stribeck shape."""
    lo, hi = float(p.lower), float(p.upper)
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
        return (p.start,)
    pts = lo + (hi - lo) * np.arange(8) / 8.0
    start = p.start if math.isfinite(p.start) else None
    if start is not None and lo <= start <= hi:
        pts = pts + (start - lo) % ((hi - lo) / 8.0)
    return tuple(float(v) for v in pts)


def _holm(scores: list[EffectScore]) -> None:
    """Holm-Bonferroni adjusted p-values (family: all effects tested)."""
    m = len(scores)
    order = sorted(range(m), key=lambda i: scores[i].p_value)
    running = 0.0
    for rank, i in enumerate(order):
        adj = min(1.0, (m - rank) * scores[i].p_value)
        running = max(running, adj)
        scores[i].p_adjusted = running


def _alike(scores: list[EffectScore]) -> None:
    """Mark pairs of candidates whose corrections are nearly parallel."""
    for a, b in itertools.combinations(scores, 2):
        if a.Jt is None or b.Jt is None:
            continue
        va, vb = a.Jt.reshape(a.Jt.shape[0], -1), b.Jt.reshape(b.Jt.shape[0], -1)
        for i in range(va.shape[1]):
            for j in range(vb.shape[1]):
                na, nb = np.linalg.norm(va[:, i]), np.linalg.norm(vb[:, j])
                if na == 0 or nb == 0:
                    continue
                cos = abs(float(va[:, i] @ vb[:, j])) / (na * nb)
                if cos > ALIKE_COSINE:
                    if b.effect not in a.alike:
                        a.alike.append(b.effect)
                    if a.effect not in b.alike:
                        b.alike.append(a.effect)

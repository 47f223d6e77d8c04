"""The rounding simulation of the honest standard errors, computed for all draws at once,
against the draw-by-draw simulation it replaces: every draw's encoder error rounded with
:func:`rotorbayes.io.measurements.quantize` sample by sample and multiplied into ``J``."""

from __future__ import annotations

import math

import numpy as np

import rotorbayes as rb
from rotorbayes import inference
from rotorbayes.inference import uncertainty
from rotorbayes.io.measurements import LOWER_COUNTS_PER_REV, UPPER_COUNTS_PER_REV, quantize

#: Largest difference allowed, relative to the quantity's own scale: the two differ only
#: in the order of the sums (measured: 3e-11 on a 30 s brake fit).
RTOL = 1e-8


def _angle_with_holds(rng, n: int) -> np.ndarray:
    """A disc angle [rad] that starts at rest, turns at varying speed and sticks (holds
    its value) in stretches, like a lower disc in stick-slip."""
    w = np.cumsum(rng.normal(size=n)) * 1e-3
    w[rng.uniform(size=n) < 0.3] = 0.0
    w[: n // 10] = 0.0  # at rest at first: the encoder reads 0
    w[n // 3 : n // 2] = 0.0  # a long stick
    return np.cumsum(w) * 1e-2


def test_scores_of_every_phase_match_rounding_sample_by_sample():
    rng = np.random.default_rng(7)
    n, k = 5000, 4
    q = 2 * math.pi / LOWER_COUNTS_PER_REV
    sim = _angle_with_holds(rng, n)
    J = np.asfortranarray(rng.normal(size=(n, k)))
    first = int(np.argmax(np.abs(sim) >= q / 2))
    assert 0 < first < n
    phase = rng.uniform(-q / 2, q / 2, size=40)
    got = uncertainty.rounding_scores(sim, J, q, first, phase)
    want = np.empty_like(got)
    for b, phi in enumerate(phase):
        e = quantize(sim + phi, LOWER_COUNTS_PER_REV) - sim - phi
        e[:first] = -sim[:first]
        want[b] = e @ J
    scale = q * np.sqrt(n) * np.abs(J).max()
    assert np.max(np.abs(got - want)) <= RTOL * scale
    # Not trivially equal: the phases move the scores by more than the tolerance.
    assert np.ptp(want, axis=0).min() > 1e3 * RTOL * scale
    # A disc that never leaves its first count: the error is the angle itself.
    still = np.full(50, 0.1 * q)
    np.testing.assert_allclose(
        uncertainty.rounding_scores(still, J[:50], q, 50, phase[:3]),
        np.tile(-(still @ J[:50]), (3, 1)),
    )


def _draw_by_draw(problem, J, r, floors, n_boot, seed):
    """The rounding covariance as a simulation of each draw in turn (the definition)."""
    counts = {"theta_u": UPPER_COUNTS_PER_REV, "theta_l": LOWER_COUNTS_PER_REV}
    rng = np.random.default_rng(seed)
    d = np.sqrt(np.einsum("ij,ij->j", J, J))
    d = np.where(d > 0, d, 1.0)  # a parameter these data do not see
    A = (J.T @ J) / np.outer(d, d)
    w, V = np.linalg.eigh(A)  # the same pseudo-inverse: only the draws are compared
    small = w <= 1e-12 * w.max()
    Apinv = (V * np.where(small, 0.0, 1.0 / np.where(small, 1.0, w))) @ V.T
    segs, off = [], 0
    for ex in problem.experiments:
        for c in problem.channels:
            meas = ex.theta_u if c == "theta_u" else ex.theta_l
            sim = meas - r[off : off + ex.n] / problem.weights[c]
            q = 2 * math.pi / counts[c]
            moved = np.abs(sim) >= q / 2
            segs.append((c, off, ex.n, sim, int(np.argmax(moved)) if moved.any() else ex.n))
            off += ex.n
    D = np.empty((n_boot, J.shape[1]))
    for b in range(n_boot):
        E = np.empty(r.size)
        for c, o, n, sim, first in segs:
            q = 2 * math.pi / counts[c]
            phi = rng.uniform(-q / 2, q / 2)
            err = quantize(sim + phi, counts[c]) - sim - phi
            err[:first] = -sim[:first]
            extra = floors[c] ** 2 - q * q / 12
            if extra > 0:
                err = err + math.sqrt(extra) * rng.standard_normal(n)
            E[o : o + n] = problem.weights[c] * err
        D[b] = ((E @ J) / d) @ Apinv
    return np.cov(D.T) / np.outer(d, d)


def _brake_fit_8s():
    p = rb.parameters.thesis_set("4.3", "P_ref")
    t, u = rb.signals.estimation_signal(8.0, rate=1000.0, seed=2, hold=(0.5, 1.5))
    sim = rb.simulate(p, u, dt=1e-3, config="brake", quantize_angles=True)
    prob = inference.Problem("brake", [sim.to_experiment("b")], base=p)
    x = prob.x_from(p)
    J, _ = prob.jacobian(x)
    r = prob.residuals(x)
    # Both channels at their quantisation floor (a hair below, so no rounding of the
    # square leaves noise beyond it): rounding alone.
    q = {"theta_u": UPPER_COUNTS_PER_REV, "theta_l": LOWER_COUNTS_PER_REV}
    floors = {c: 2 * math.pi / q[c] / math.sqrt(12.0) * (1 - 1e-9) for c in prob.channels}
    return prob, x, J, r, floors


def _whitened_spread(got, want, seen):
    """Eigenvalues of ``want^-½ got want^-½`` on the parameters ``seen``: all 1 where the
    two covariances agree in every direction."""
    W = uncertainty._sym_sqrt(want[np.ix_(seen, seen)], inverse=True)
    return np.linalg.eigvalsh(W @ got[np.ix_(seen, seen)] @ W)


def test_rounding_covariance_is_the_draw_by_draw_simulation():
    """Brake stick-slip, 8 s at 1 kHz, two channels at their quantisation floor: the same
    phases, the same covariance to the order of the sums."""
    prob, x, J, r, floors = _brake_fit_8s()
    for seed in (0, 3):
        got = uncertainty.rounding_covariance(prob, x, J, r, floors, n_boot=60, seed=seed)
        want = _draw_by_draw(prob, J, r, floors, 60, seed)
        se = np.sqrt(np.diag(want))
        seen = se > 1e-6 * se.max()  # parameters these 8 s determine
        assert seen.sum() >= 8
        scale = np.outer(se, se)[np.ix_(seen, seen)]
        assert np.max(np.abs(got - want)[np.ix_(seen, seen)] / scale) <= RTOL
    # Another seed is another simulation: the comparison above is not of equal constants.
    other = _draw_by_draw(prob, J, r, floors, 60, 1)
    assert np.max(np.abs(other - want)[np.ix_(seen, seen)] / scale) > 1e-3


def test_gaussian_noise_beyond_the_rounding_has_the_draw_by_draw_covariance():
    """The lower channel carries Gaussian noise beyond its rounding (floor x 1.5: more
    variance than the rounding's own).  Its scores are drawn as ``k`` normals through
    ``(JᵀJ)^½`` instead of ``n`` normals through ``J``: the same distribution, other
    random numbers, so the two simulations (3000 draws each) agree to their Monte Carlo
    error: the 13 whitened eigenvalues spread over 0.87-1.18 for three pairs of seeds
    (0.75-1.3 allowed), while the rounding alone gives 0.08 in one direction."""
    prob, x, J, r, floors = _brake_fit_8s()
    noisy = dict(floors, theta_l=1.5 * floors["theta_l"])  # variance 2.25x the rounding's
    got = uncertainty.rounding_covariance(prob, x, J, r, noisy, n_boot=3000, seed=4)
    want = _draw_by_draw(prob, J, r, noisy, 3000, 5)
    se = np.sqrt(np.diag(want))
    seen = se > 1e-6 * se.max()
    assert seen.sum() >= 8
    lam = _whitened_spread(got, want, seen)
    assert lam.min() >= 0.75 and lam.max() <= 1.3, lam
    # The noise matters: the rounding alone is narrower than either in some direction.
    alone = uncertainty.rounding_covariance(prob, x, J, r, floors, n_boot=3000, seed=4)
    assert _whitened_spread(alone, want, seen).min() < 0.5


def test_the_input_hold_shift_is_the_inputs_and_not_two_grids():
    """The estimate's shift between a linear and a smooth input between samples, computed on
    the fit's own Runge-Kutta steps (the smooth input's simulation takes them, at 8 times
    the samples), against the same shift with both inputs integrated at a quarter of a
    sample (converged: an eighth changes it by 4e-11 of it, measured).  30 s brake stick-slip at
    1 kHz, in the data's metric ``|v|_A = sqrt(vᵀ JᵀJ v)``: measured 0.39 of the shift's
    size on the fit's steps; each input on a step grid of its own was 1.02 (all error)."""
    p = rb.parameters.thesis_set("4.3", "P_ref")
    t, u = rb.signals.estimation_signal(30.0, rate=1000.0, seed=1)
    dt = float(t[1] - t[0])
    ex = rb.simulate(p, u, dt=dt, config="brake", quantize_angles=True).to_experiment("b")
    prob = inference.Problem("brake", [ex], base=p)
    x = prob.x_from(p) * 1.01
    J, _ = prob.jacobian(x)
    shift, ssr_lin, ssr_smooth = uncertainty.hold_shift(prob, x, J, prob.residuals(x))
    fine = inference.Problem("brake", [ex], base=p, step=dt / 4)
    want, *_ = uncertainty.hold_shift(fine, x, J, fine.residuals(x))
    A = J.T @ J

    def size(v):
        return float(np.sqrt(v @ A @ v))

    assert size(want) > 0
    assert size(shift - want) <= 0.6 * size(want)
    assert ssr_smooth > ssr_lin > 0

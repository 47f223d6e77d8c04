"""The pieces of the log posterior: each noise model against an independent Gaussian
density (scipy), and a posterior composed of pieces against the one built for a fit."""

from __future__ import annotations

import math
import pickle

import numpy as np
import pytest
from scipy import stats
from scipy.linalg import toeplitz

import rotorbayes as rb
from rotorbayes import inference as inf
from rotorbayes.inference.coordinates import CurvatureAdjustment, LogCoordinates
from rotorbayes.inference.likelihood import LogPosterior, LogPrior, Prior
from rotorbayes.inference.noise_models import (
    AR1LogLikelihood,
    GaussianLogLikelihood,
    SampledSigmaLogLikelihood,
)
from rotorbayes.model.parameters import thesis_set


def _data(seed: int, seconds: float = 1.0):
    t, u = rb.signals.estimation_signal(seconds, seed=seed)
    sim = rb.simulate(
        thesis_set("4.3", "P_ref"),
        u,
        dt=t[1] - t[0],
        config="brake",
        alpha0=0.1 * seed,
        quantize_angles=True,
    )
    return sim.to_experiment(f"brake_{seed}")


@pytest.fixture(scope="module")
def prob():
    return inf.Problem(
        "brake",
        [_data(2), _data(3, 0.9)],
        channels=("theta_u", "theta_l"),
        weights={"theta_u": 2.0, "theta_l": 0.5},
    )


def _rows(prob, n=3, seed=0):
    rng = np.random.default_rng(seed)
    R = 1e-3 * rng.standard_normal((n, prob.n_residuals))
    S = np.exp(rng.uniform(-8, -6, (n, len(prob.channels))))
    P = rng.uniform(-0.9, 0.9, (n, len(prob.channels)))
    return R, S, P


def _reference(prob, R, S, P, ar1: bool) -> np.ndarray:
    """The log density of the unweighted errors, segment by segment, from scipy's
    multivariate normal (AR(1): the stationary covariance s² φ^|i-j| / (1 - φ²))."""
    out = np.zeros(R.shape[0])
    off = 0
    for ex in prob.experiments:
        for j, c in enumerate(prob.channels):
            for r in range(R.shape[0]):
                e = R[r, off : off + ex.n] / prob.weights[c]
                s, phi = S[r, j], P[r, j] if ar1 else 0.0
                if ar1:
                    cov = s**2 / (1 - phi**2) * toeplitz(phi ** np.arange(ex.n))
                    out[r] += stats.multivariate_normal(np.zeros(ex.n), cov).logpdf(e)
                else:
                    out[r] += stats.norm(0.0, s).logpdf(e).sum()
            off += ex.n
    return out


@pytest.mark.parametrize(
    "kind", [GaussianLogLikelihood, SampledSigmaLogLikelihood, AR1LogLikelihood]
)
def test_each_noise_model_is_the_gaussian_density_of_its_errors(prob, kind):
    R, S, P = _rows(prob)
    floor, _ = prob.noise_floors()
    lik = kind(prob, floor)
    ar1 = kind is AR1LogLikelihood
    if kind is GaussianLogLikelihood:  # σ known: the fixed scale, whatever S says
        S = np.tile([floor[c] for c in prob.channels], (R.shape[0], 1))
    ref = _reference(prob, R[:, :], S, P, ar1)
    np.testing.assert_allclose(lik.loglik_of(R, S, P), ref, rtol=1e-9)
    np.testing.assert_allclose(lik.pointwise_of(R, S, P).sum(axis=1), ref, rtol=1e-9)


def test_the_noise_coordinates_and_their_prior():
    prob = inf.Problem("brake", [_data(2)], channels=("theta_l",))
    floor, _ = prob.noise_floors()
    plain = GaussianLogLikelihood(prob, floor)
    sampled = SampledSigmaLogLikelihood(prob, floor)
    ar1 = AR1LogLikelihood(prob, floor)
    assert plain.noise_names() == [] and plain.noise_z() == []
    assert sampled.noise_names() == ["log_sigma_theta_l"]
    assert ar1.noise_names() == ["log_sigma_theta_l", "phi_theta_l"]
    assert ar1.noise_z(phi={"theta_l": 0.3}) == [math.log(floor["theta_l"]), 0.3]
    W = np.array([[math.log(2e-4), 0.5], [math.log(20.0), 0.5], [math.log(2e-4), 0.9995]])
    S, P = ar1.noise_of(W)
    np.testing.assert_allclose(S[:, 0], [2e-4, 20.0, 2e-4])
    np.testing.assert_array_equal(ar1.noise_log_prior(S, P), [0.0, -np.inf, -np.inf])
    np.testing.assert_array_equal(sampled.noise_log_prior(S, P), [0.0, -np.inf, 0.0])
    S0, P0 = plain.noise_of(np.empty((2, 0)))
    assert np.all(S0 == floor["theta_l"]) and np.all(P0 == 0.0)


def test_log_coordinates_and_the_adjustment():
    tr = LogCoordinates([True, False])
    Z = np.array([[math.log(2.0), -1.5]])
    np.testing.assert_allclose(tr.to_x(Z), [[2.0, -1.5]])
    np.testing.assert_allclose(tr.to_z([2.0, -1.5]), Z[0])
    np.testing.assert_allclose(tr.log_jacobian(Z), [math.log(2.0)])
    assert tr.names(["J_l", "alpha0"]) == ["log_J_l", "alpha0"]
    # Cᵀ H C = V⁻¹ on an arbitrary pair of positive definite matrices.
    rng = np.random.default_rng(4)
    A, B = rng.standard_normal((2, 3, 3))
    H, V = A @ A.T + np.eye(3), B @ B.T + 0.1 * np.eye(3)
    adj = CurvatureAdjustment.matching(np.zeros(3), H, V)
    np.testing.assert_allclose(adj.curvature(H), np.linalg.inv(V), rtol=1e-9, atol=1e-12)
    # An undetermined direction keeps C = I there.
    V2 = V.copy()
    V2[2, :] = V2[:, 2] = np.inf
    C2 = CurvatureAdjustment.matching(np.zeros(3), H, V2).C
    np.testing.assert_array_equal(C2[2], [0.0, 0.0, 1.0])
    pts = CurvatureAdjustment(np.ones(2), 2 * np.eye(2)).points(np.array([[2.0, 1.0, 7.0]]))
    np.testing.assert_array_equal(pts, [[3.0, 1.0, 7.0]])
    with pytest.raises(ValueError, match="shape"):
        CurvatureAdjustment(np.zeros(2), np.eye(3))


@pytest.mark.parametrize("noise", ["floor", "sampled", "ar1", "robust"])
def test_a_posterior_composed_of_pieces_is_the_fit_posterior(prob, noise):
    x = prob.start_vector(prob.base)
    kw = {"ar1": True} if noise == "ar1" else {"noise": noise}
    fit_post = LogPosterior(prob, x, priors={"J_l": Prior("normal", 0.0, 1.0, 0.05, 0.02)}, **kw)
    lik = {
        "floor": GaussianLogLikelihood,
        "sampled": SampledSigmaLogLikelihood,
        "ar1": AR1LogLikelihood,
        "robust": GaussianLogLikelihood,
    }[noise](prob, fit_post.sigma)
    parts = LogPosterior(
        lik,
        LogPrior(prob, {"J_l": Prior("normal", 0.0, 1.0, 0.05, 0.02)}),
        transform=LogCoordinates.for_fit(prob.lower, x),
        adjustment=fit_post.adjustment,
    )
    assert parts.coord_names == fit_post.coord_names and parts.ndim == fit_post.ndim
    assert parts.noise == fit_post.noise and parts.ar1 == fit_post.ar1
    rng = np.random.default_rng(7)
    z0 = fit_post.to_z(x)
    Z = z0 + 1e-6 * rng.standard_normal((3, z0.size))
    np.testing.assert_array_equal(parts(Z), fit_post(Z))
    assert np.all(np.isfinite(parts(Z)))


def test_composition_checks_its_pieces(prob):
    other = inf.Problem("brake", [_data(4)])
    floor, _ = prob.noise_floors()
    lik = GaussianLogLikelihood(prob, floor)
    with pytest.raises(ValueError, match="different problems"):
        LogPosterior(lik, LogPrior(other))
    with pytest.raises(ValueError, match="free parameters"):
        LogPosterior(lik, transform=LogCoordinates([True]))
    with pytest.raises(TypeError, match="pieces"):
        LogPosterior(lik, noise="floor")
    with pytest.raises(TypeError, match="compose it"):
        LogPosterior(prob, prob.start_vector(prob.base), transform=LogCoordinates([]))
    lp = LogPosterior(lik)  # defaults: uniform priors, no log coordinates
    assert lp.coord_names == prob.names and lp.noise == "floor" and lp.adjust is None


def test_a_problem_travels_to_a_process_whole(prob):
    x = prob.start_vector(prob.base)
    copy = pickle.loads(pickle.dumps(prob))
    assert copy.names == prob.names and copy.parameters.names == prob.names
    np.testing.assert_array_equal(copy.residuals(x), prob.residuals(x))

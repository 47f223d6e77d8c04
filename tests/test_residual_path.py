"""The residual-only kernel path (``Problem.evaluate`` / ``residuals`` / ``residuals_batch``)
gives the numbers of the full simulation followed by ``w * (measured - simulated)``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import rotorbayes as rb
from rotorbayes import inference
from rotorbayes.kernel import layout
from rotorbayes.model.parameters import thesis_set


def _by_simulation(prob: inference.Problem, x: np.ndarray) -> tuple[np.ndarray, list[int]]:
    """The residual vector the slow way: full simulations, then the subtraction."""
    parts, status = [], []
    for i, (ex, sim) in enumerate(zip(prob.experiments, prob.sims, strict=True)):
        st, thu, thl = sim.angles(sim.kernel_vector(prob.params_for(x, i)))
        status.append(st)
        for c in prob.channels:
            s = thu if c == "theta_u" else thl
            m = ex.theta_u if c == "theta_u" else ex.theta_l
            parts.append(prob.weights[c] * (m - s) if st == layout.OK else np.full(ex.n, np.nan))
    return np.concatenate(parts), status


def _data(config, params, seconds=6.0, seed=2, alpha0=None, rate=1000.0):
    t, u = rb.signals.estimation_signal(seconds, seed=seed, rate=rate)
    sim = rb.simulate(params, u, dt=t[1] - t[0], config=config, alpha0=alpha0,
                      quantize_angles=True)  # fmt: skip
    return sim.to_experiment(f"{config}_{seed}")


ROOT = Path(__file__).resolve().parents[1]
USER = str(ROOT / "examples" / "angle_friction.py") + ":angle_friction"


def _problems():
    brake = thesis_set("4.3", "P_ref")
    coupled = thesis_set("4.2", "P_ref")
    upper = thesis_set("4.1", "P_ref")
    ex_b1 = _data("brake", brake, seed=2, alpha0=0.4)
    ex_b2 = _data("brake", brake, seed=5, alpha0=-0.3)
    ex_c = _data("coupled", coupled, rate=200.0)
    return {
        "brake-two-experiments-both-channels": inference.Problem(
            "brake", [ex_b1, ex_b2], base=brake, channels=("theta_u", "theta_l"),
            weights={"theta_u": 2.5, "theta_l": 0.7},
        ),
        "brake-lower-channel-then-upper": inference.Problem(
            "brake", [ex_b1], base=brake, channels=("theta_l", "theta_u")
        ),
        "coupled-200Hz-delay-deadzone": inference.Problem(
            "coupled", [ex_c], base=coupled, effects=["input_delay", "motor_deadzone"],
        ),
        "upper": inference.Problem("upper", [_data("upper", upper)], base=upper),
        # A user effect: the kernel entry point with function arguments (the others use
        # the one without).
        "brake-user-effect": inference.Problem(
            "brake", [ex_b2], base=dict(brake, a_fric=0.2, phi_fric=0.5), effects=[USER],
            free=["J_l", "Tc_l", "a_fric"],
        ),
        "prescribed-upper": inference.Problem(
            "brake", [ex_b1], base=dict(brake, alpha0=0.4), prescribed_upper=True,
            effects=["initial_torsion"],
        ),
    }  # fmt: skip


PROBLEMS = _problems()


@pytest.mark.parametrize("name", list(PROBLEMS))
def test_residual_path_equals_simulation_then_subtraction(name):
    prob = PROBLEMS[name]
    x0 = prob.x_from(prob.base)
    rng = np.random.default_rng(1)
    X = x0 * (1 + 0.03 * rng.uniform(-1, 1, size=(5, x0.size)))
    X = np.clip(X, prob.lower, prob.upper)
    for x in X:
        ev = prob.evaluate(x)
        slow, status = _by_simulation(prob, x)
        assert list(ev.status) == status
        assert ev.residuals.shape == slow.shape
        np.testing.assert_array_equal(ev.residuals, slow)
        np.testing.assert_array_equal(prob.residuals(x), slow)
    R = prob.residuals_batch(X)
    for j, x in enumerate(X):
        np.testing.assert_array_equal(R[j], _by_simulation(prob, x)[0])


@pytest.mark.parametrize("name", list(PROBLEMS))
def test_kernel_vectors_from_the_template_equal_the_long_way(name):
    """Problem.kernel_vectors puts x into a copy of the base vectors; the numbers must be
    those of Simulator.kernel_vector(params_for(x, i)), also at NaN and after the base
    values are changed in place."""
    prob = PROBLEMS[name]
    x0 = prob.x_from(prob.base)
    rng = np.random.default_rng(4)
    X = list(x0 * (1 + 0.05 * rng.uniform(-1, 1, size=(4, x0.size))))
    X.append(np.full(x0.size, np.nan))
    old = dict(prob.base)
    try:
        for _round in range(2):
            for x in X:
                for i, sim in enumerate(prob.sims):
                    fast = prob.kernel_vectors(x, i)
                    slow = sim.kernel_vector(prob.params_for(x, i))
                    for a, b in zip(fast, slow, strict=True):
                        np.testing.assert_array_equal(a, b)
            assert all(f[1] is not None for f in prob._fills.values())  # the fast way ran
            prob.base["J_l"] = prob.base["J_l"] * 1.5  # a fixed value changed in place
            prob.base["J_u"] = prob.base["J_u"] * 0.8
    finally:
        prob.base.clear()
        prob.base.update(old)


def test_failed_experiments_give_nan_residuals_and_the_others_stay():
    prob = PROBLEMS["brake-two-experiments-both-channels"]
    x = prob.x_from(prob.base)
    bad = prob.x_from(dict(prob.base, J_l=-0.01))
    ev = prob.evaluate(bad)
    assert not ev.ok and np.all(np.isnan(ev.residuals))
    assert list(ev.status) == [layout.BAD_PARAMETERS] * 2
    R = prob.residuals_batch(np.array([x, bad, x]))
    assert np.all(np.isfinite(R[0])) and np.all(np.isnan(R[1]))
    np.testing.assert_array_equal(R[0], R[2])
    np.testing.assert_array_equal(prob.residuals(bad, penalty=7.0), np.full(R.shape[1], 7.0))


def test_a_derived_problem_keeps_every_setting_it_is_not_told_to_change():
    """Problem.like is where derived problems (an effect added, a parameter profiled, a
    designed experiment) copy their settings: channels, weights, friction shape and step
    survive, the free set and base change as asked, and an unknown setting is refused."""
    brake = thesis_set("4.3", "P_ref")
    prob = inference.Problem("brake", [_data("brake", brake, seconds=2.0)], base=brake,
                     channels=("theta_l", "theta_u"), weights={"theta_u": 2.5},
                     shape="rational", step=0.009)  # fmt: skip
    sub = prob.like(free=["J_l", "Tc_l"], base=dict(brake, k_m=3.0))
    assert (sub.channels, sub.weights, sub.shape, sub.step) == (
        prob.channels,
        prob.weights,
        "rational",
        0.009,
    )
    assert sub.names == ["J_l", "Tc_l"] and sub.base["k_m"] == 3.0
    eff = prob.with_effects(["input_delay"])
    assert "input_delay" in eff.effects and eff.names == prob.names
    assert (eff.shape, eff.step, eff.weights) == ("rational", 0.009, prob.weights)
    with pytest.raises(TypeError, match="no setting stepsize"):
        prob.like(stepsize=0.01)

"""Least squares, multi-experiment alpha0, prescribed upper motion, errors, multistart.

The data are simulated from known thesis parameter sets (the truth is independent of the
fitting code); thresholds are explicit.
"""

from __future__ import annotations

import numpy as np
import pytest

import rotorbayes as rb
from rotorbayes import inference
from rotorbayes.model.parameters import ParameterError, thesis_set


def _short(ex: rb.Experiment, seconds: float) -> rb.Experiment:
    n = int(round(seconds / ex.dt)) + 1
    return rb.Experiment(
        t=ex.t[:n],
        u=ex.u[:n],
        theta_u=ex.theta_u[:n],
        theta_l=None if ex.theta_l is None else ex.theta_l[:n],
        name=ex.name,
        path=ex.path,
    )


LOWER4 = ["J_l", "k_alpha", "Tc_l", "b_l"]


def test_default_free_set_is_what_the_data_determine(coupled_est):
    # theta_u measured: the motor and upper friction are fitted too, from both channels;
    # J_u stays fixed (eq. 5.4) and sets the scale.
    prob = inference.Problem("coupled", [coupled_est])
    assert set(prob.names) == {"k_m", "Tc_u", "dTc_u", "b_u", "db_u", *LOWER4}
    assert prob.channels == ("theta_u", "theta_l")
    brake = inference.Problem("brake", [rb.load_example("brake_est")])
    assert set(brake.names) == {
        "k_m",
        "Tc_u",
        "dTc_u",
        "b_u",
        "db_u",
        *LOWER4,
        "db_l",
        "Ts_l",
        "ws_l",
        "delta_l",
    }
    # With the measured theta_u as input only the lower disc is left, fitted on theta_l.
    pres = inference.Problem("coupled", [coupled_est], prescribed_upper=True)
    assert pres.names == LOWER4 and pres.channels == ("theta_l",)


@pytest.fixture(scope="module")
def coupled_est():
    return rb.load_example("coupled_est")


def test_fit_from_thesis_p0_recovers_the_truth(coupled_est):
    truth = thesis_set("5.2", "P")
    # The thesis's coupled step: the lower disc's four, upper disc fixed, theta_l fitted.
    prob = inference.Problem("coupled", [coupled_est], base=truth, free=LOWER4)
    assert prob.channels == ("theta_l",)
    res = inference.fit(prob, thesis_set("4.2", "P0"))  # 20-40 % away from the truth
    assert res.success, res.message
    for n, v in res.values.items():
        assert abs(v / truth[n] - 1) < 1e-3, (n, v, truth[n])
    # Standard errors are positive and small relative to the values.
    assert np.all(res.stderr > 0) and np.all(res.stderr / np.abs(res.x) < 1e-2)
    # The least determined Fisher direction is the common scaling of the four (thesis
    # table 4.2): all components of one sign and comparable size.
    w, V = res.sloppy_directions()
    v = V[:, 0] * np.sign(V[0, 0])
    assert np.all(v > 0.3), v
    assert w[-1] / w[0] > 1e3


def test_quality_reports_channels_and_validation(coupled_est):
    val = rb.load_example("coupled_val")
    truth = thesis_set("5.2", "P")
    prob = inference.Problem("coupled", [coupled_est], base=truth)
    x = prob.x_from(truth)
    est_rows = inference.quality(prob, x)
    val_rows = inference.quality(prob, x, [val])
    for rows in (est_rows, val_rows):
        ch = rows[0]["channels"]
        assert set(ch) == {"theta_u", "theta_l", "alpha"}
        # At the truth only the encoder quantisation is left: R² = 1 to 6 digits and
        # errors below two lower-encoder counts (2 * 2*pi/40000 = 3.1e-4 rad).
        assert ch["theta_l"]["r2"] > 1 - 1e-6
        assert ch["theta_l"]["max_abs_error"] < 3.2e-4
        assert np.isfinite(rows[0]["aicc"]) and np.isfinite(rows[0]["bic"])


def test_several_experiments_with_alpha0_each():
    reps = [_short(rb.load_example(f"brake_rep{i}"), 15.0) for i in range(1, 5)]
    truth = thesis_set("5.4", "P")
    prob = inference.Problem("brake", reps, free=["Ts_l", "alpha0"], base=truth)
    assert prob.names == ["Ts_l", "alpha0[0]", "alpha0[1]", "alpha0[2]", "alpha0[3]"]
    start = dict(truth, Ts_l=0.26, alpha0=0.0)
    res = inference.fit(prob, start)
    got = [res.values[f"alpha0[{i}]"] for i in range(4)]
    np.testing.assert_allclose(got, [0.0, 0.9, -1.4, 2.1], atol=2e-3)
    assert abs(res.values["Ts_l"] / truth["Ts_l"] - 1) < 1e-3
    # One shared alpha0 (the thesis's averaged experiment) fits much worse.
    shared = inference.fit(
        inference.Problem("brake", reps, free=["Ts_l"], base=dict(truth, alpha0=0.0)),
        {"Ts_l": 0.26},
    )
    assert shared.ssr > 100 * res.ssr


def test_lower_disc_with_measured_upper_angle_as_input(coupled_est):
    truth = thesis_set("5.2", "P")
    prob = inference.Problem(
        "coupled", [_short(coupled_est, 15.0)], base=truth, prescribed_upper=True
    )
    res = inference.fit(prob, thesis_set("5.2", "P0"))
    v = res.values
    # With theta_u prescribed the lower equation is exactly invariant under scaling
    # J_l, k_alpha, Tc_l, b_l together: only the ratios are identified ...
    for n in ("k_alpha", "Tc_l", "b_l"):
        assert abs((v[n] / v["J_l"]) / (truth[n] / truth["J_l"]) - 1) < 5e-3, n
    # ... and the Fisher information says so: one direction is (numerically) singular.
    w, V = res.sloppy_directions()
    assert w[0] / w[-1] < 1e-8
    assert np.all(np.abs(V[:, 0]) > 0.4)


def test_channel_weights_and_both_channels(coupled_est):
    prob = inference.Problem(
        "coupled",
        [coupled_est],
        channels=("theta_l", "theta_u"),
        weights={"theta_u": 0.5},
        base=thesis_set("5.2", "P"),
    )
    assert prob.n_residuals == 2 * coupled_est.n
    r = prob.residuals(prob.x_from(prob.base))
    # theta_u residual carries the weight 0.5: its quantisation error (half a count) and
    # the integrator's difference from the kernel that made the example (at most the
    # accuracy target, 1.5e-5 rad; 3e-8 here) are halved.  Unweighted it is 5.7e-5.
    count = 2 * np.pi / 54934.256
    assert np.max(np.abs(r[coupled_est.n :])) <= 0.5 * (0.5 * count + 1.5e-5)


def test_clear_errors(coupled_est):
    upper = rb.load_example("upper_est")
    with pytest.raises(ParameterError, match="valid names are: k_m"):
        inference.Problem("coupled", [coupled_est], free=["J_lower"])
    with pytest.raises(ValueError, match="no theta_l column"):
        inference.Problem("coupled", [upper])
    with pytest.raises(ValueError, match="has a theta_l column"):
        inference.Problem("upper", [coupled_est])
    with pytest.raises(ParameterError, match="both fixed and free"):
        inference.Problem("coupled", [coupled_est], free=["J_l", "b_l"], fixed=["b_l"])
    prob = inference.Problem("coupled", [coupled_est])
    with pytest.raises(ParameterError, match="outside the bounds"):
        inference.fit(prob, {"J_l": 5.0})
    with pytest.raises(ParameterError, match="does not enter the upper configuration"):
        inference.Problem("upper", [upper], free=["k_m", "J_l"])


def test_non_convergence_is_reported_and_results_kept(coupled_est):
    prob = inference.Problem("coupled", [_short(coupled_est, 10.0)], base=thesis_set("5.2", "P"))
    res = inference.fit(prob, thesis_set("4.2", "P0"), max_nfev=2)
    assert not res.success
    assert "maximum number of evaluations" in res.message
    assert np.all(np.isfinite(res.x)) and res.ssr > 0


@pytest.mark.slow
def test_multistart_finds_local_minima_in_the_brake_step():
    """Thesis §4.3: far from P_ref the brake fit stops elsewhere; multistart shows it."""
    ex = _short(rb.load_example("brake_est"), 20.0)
    prob = inference.Problem(
        "brake",
        [ex],
        base=thesis_set("5.4", "P"),
        free=["Tc_l", "b_l", "db_l", "Ts_l", "ws_l", "delta_l"],
    )
    ms = inference.multistart(prob, 8, seed=2, progress=False, max_nfev=40)
    assert len(ms.ssr) + len(ms.failed) == 8 and len(ms.ssr) >= 5
    best = ms.best
    truth = prob.x_from(thesis_set("5.4", "P"))
    assert np.max(np.abs(best.x / truth - 1)) < 1e-2
    assert len(set(ms.clusters.tolist())) >= 2
    text = ms.summary()
    assert "local minima" in text and f"of {len(ms.ssr)} starts end within" in text
    # Starts are drawn inside the validity constraints (|db_l| < b_l), so none fails.
    assert not ms.failed


def test_describe_spread_names_a_scaling_ridge():
    rng = np.random.default_rng(0)
    lam = np.exp(rng.normal(0, 0.15, 20))
    ends = np.c_[
        0.04 * lam, 0.08 * lam * (1 + 1e-4 * rng.normal(size=20)), 0.017 * lam, np.full(20, 4.3)
    ]
    text = inference.describe_spread(["J_l", "k_alpha", "Tc_l", "k_m"], ends, np.full(20, 1.0))
    assert "scaling J_l and k_alpha and Tc_l by a common factor" in text
    assert "Well determined: k_m" in text
    assert "k_alpha/J_l ±0.0 %" in text

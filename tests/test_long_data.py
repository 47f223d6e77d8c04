"""Long data stay lean (issue 18 item 5): the optimiser gets the problem compressed to k + 1
rows, walkers are simulated a few at a time with only their sums of squares kept, and the
stored pointwise log-likelihood is summed in blocks beyond a budget — each the same numbers
as the plain way, on short data here (the memory itself: benchmarks/bench_long_data.py).
"""

from __future__ import annotations

import numpy as np

import rotorbayes as rb
from rotorbayes import inference
from rotorbayes.inference import least_squares, likelihood, posterior


def test_compress_keeps_the_cost_gradient_and_curvature():
    rng = np.random.default_rng(0)
    n, k = 5003, 6
    J = rng.standard_normal((n, k)) * np.logspace(0, 5, k)  # badly scaled columns
    r = rng.standard_normal(n) + J @ rng.standard_normal(k) * 1e-3
    old = least_squares._QR_CHUNK_BYTES
    least_squares._QR_CHUNK_BYTES = 8 * 7 * 300  # many row blocks
    try:
        C = least_squares.compress(J, r)
    finally:
        least_squares._QR_CHUNK_BYTES = old
    f = np.zeros(k + 1)
    f[0] = np.linalg.norm(r)
    assert C.shape == (k + 1, k)
    np.testing.assert_allclose(C.T @ C, J.T @ J, rtol=1e-10, atol=1e-10 * np.abs(J.T @ J).max())
    np.testing.assert_allclose(C.T @ f, J.T @ r, rtol=1e-9)
    # The Gauss-Newton model at any step is the same.
    for _ in range(3):
        p = rng.standard_normal(k) / np.logspace(0, 5, k)
        a, b = np.sum((J @ p + r) ** 2), np.sum((C @ p + f) ** 2)
        assert abs(a - b) <= 1e-9 * a
    # A zero residual (a perfect fit) is no division by zero.
    C0 = least_squares.compress(J, np.zeros(n))
    np.testing.assert_allclose(C0.T @ C0, J.T @ J, rtol=1e-10, atol=1e-10 * np.abs(J.T @ J).max())


def _short(name="coupled_est", seconds=6.0):
    ex = rb.load_example(name)
    n = int(round(seconds / ex.dt)) + 1
    return rb.Experiment(
        t=ex.t[:n],
        u=ex.u[:n],
        theta_u=ex.theta_u[:n],
        theta_l=ex.theta_l[:n],
        name=f"{name} {seconds:g} s",
        path=ex.path,
    )


def test_compressed_fit_ends_where_the_plain_fit_ends():
    # The friction asymmetries fixed: with them free the upper disc's friction has a flat
    # valley (equal SSR to 1e-6), where rounding alone decides where a fit stops.
    prob = inference.Problem(
        "coupled", [_short()], free=["k_m", "Tc_u", "b_u", "J_l", "k_alpha", "Tc_l", "b_l"]
    )
    x0 = prob.x_from(rb.parameters.thesis_set("4.2", "P0"))
    a = inference.fit(prob, x0, max_nfev=40, uncertainty=False, compressed=False)
    b = inference.fit(prob, x0, max_nfev=40, uncertainty=False, compressed=True)
    assert a.success and b.success
    assert abs(b.ssr - a.ssr) <= 1e-8 * a.ssr
    np.testing.assert_allclose(b.x, a.x, rtol=1e-6)
    # The Jacobian kept with the result is the full one either way.
    assert b.jac.shape == a.jac.shape == (prob.n_residuals, len(prob.names))


def test_walkers_in_small_batches_give_the_one_batch_log_posterior(monkeypatch):
    prob = inference.Problem("coupled", [_short(seconds=3.0)])
    x = prob.x_from(prob.base)
    for kw in ({"noise": "floor"}, {"ar1": True}):
        lp = likelihood.LogPosterior(prob, x, **kw)
        rng = np.random.default_rng(1)
        Z = lp.to_z(x)[None, :] + 1e-4 * rng.standard_normal((7, lp.ndim))
        X, S, P = lp.split(Z)
        L, failed = lp.pointwise(X, S, P)
        whole = L.sum(axis=1)
        monkeypatch.setattr(likelihood, "BATCH_BYTES", 1)  # one row (one thread's worth) at a time
        ll, failed2 = lp.loglik(X, S, P)
        assert not failed.any() and not failed2.any()
        np.testing.assert_allclose(ll, whole, rtol=1e-12)
        monkeypatch.undo()


def test_stored_log_likelihood_is_summed_in_blocks_beyond_the_budget():
    assert posterior.loglik_block(200, 60_000) == 1  # 30 s at 1 kHz, one channel: pointwise
    # 600 s coupled at 1 kHz, two channels, 200 draws: 960 MB as float32 -> blocks of 4.
    assert posterior.loglik_block(200, 1_200_000) == 4
    assert 4 * 200 * 1_200_000 / posterior.loglik_block(200, 1_200_000) <= posterior.LOGLIK_BYTES


def test_inference_data_in_blocks_holds_the_pointwise_sums(monkeypatch):
    from rotorbayes.inference import arviz_compat
    from rotorbayes.inference.sampling import EnsembleRun

    prob = inference.Problem("coupled", [_short(seconds=2.0)])
    x = prob.x_from(prob.base)
    lp = likelihood.LogPosterior(prob, x, noise="floor")
    rng = np.random.default_rng(2)
    runs = []
    for e in range(2):
        chain = lp.to_z(x)[None, None, :] + 1e-5 * rng.standard_normal((6, 4, lp.ndim))
        runs.append(
            EnsembleRun(
                f"ensemble{e}", chain, np.zeros((6, 4)), np.full(4, 0.3), np.full(lp.ndim, np.nan)
            )
        )
    plain = posterior.inference_data(lp, runs, max_draws=5)
    monkeypatch.setattr(posterior, "LOGLIK_BYTES", 4 * 10 * prob.n_residuals // 7)  # blocks of 7
    monkeypatch.setattr(likelihood, "BATCH_BYTES", 1)  # and the draws one batch at a time
    blocked = posterior.inference_data(lp, runs, max_draws=5)
    a = arviz_compat.group(plain, "log_likelihood")["theta_l_exp0"].values
    b = arviz_compat.group(blocked, "log_likelihood")["theta_l_exp0"].values
    block = posterior.loglik_block(a.shape[0] * a.shape[1], prob.n_residuals)
    assert block in (7, 8)
    assert b.shape[-1] == -(-a.shape[-1] // block)
    np.testing.assert_allclose(b.sum(axis=-1), a.sum(axis=-1), rtol=1e-5)
    np.testing.assert_allclose(b[..., 0], a[..., :block].sum(axis=-1), rtol=1e-5)
    pa = arviz_compat.group(plain, "posterior_predictive")["theta_l_exp0"].values
    pb = arviz_compat.group(blocked, "posterior_predictive")["theta_l_exp0"].values
    assert pa.tobytes() == pb.tobytes()


def test_long_lines_are_drawn_as_their_envelope():
    from rotorbayes.figures.plots import MAX_LINE_POINTS, envelope

    t = np.arange(600_001) * 1e-3
    y = np.sin(t) + np.random.default_rng(0).normal(size=t.size)
    tt, yy = envelope(t, y)
    assert tt.size <= MAX_LINE_POINTS
    assert yy.max() == y.max() and yy.min() == y.min()
    assert np.all(np.diff(tt) >= 0)
    np.testing.assert_array_equal(yy, np.interp(tt, t, y))  # points of the line itself
    ts, ys = envelope(t[:100], y[:100])
    assert ts.size == 100


def test_a_long_fit_task_comes_back_without_its_jacobian(monkeypatch, tmp_path):
    import importlib

    from rotorbayes.inference import parallel

    MS = importlib.import_module("rotorbayes.inference.multistart")  # the module, not the function

    prob = inference.Problem("coupled", [_short(seconds=2.0)])
    monkeypatch.setattr(MS, "COMPRESS_BYTES", 1)  # as if the data were long
    with parallel.use_executor(parallel.ExecutorSpec("serial")):
        ms = inference.multistart(
            prob, 2, seed=0, max_nfev=5, progress=False, resume=tmp_path / ".ms.tasks"
        )
        again = inference.multistart(
            prob, 2, seed=0, max_nfev=5, progress=False, resume=tmp_path / ".ms.tasks"
        )
    assert all(f.jac is None for f in ms.fits + again.fits)
    assert again.ends.tobytes() == ms.ends.tobytes()
    best = MS.ensure_jacobian(ms.best)
    assert best.jac.shape == (prob.n_residuals, len(prob.names))

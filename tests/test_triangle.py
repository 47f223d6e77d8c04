"""The least-squares iteration's linear algebra on the kernel's threads.

``kernel.triangle.triangle`` against LAPACK's QR (NumPy: an independent implementation),
the same bits on any thread count, the difference quotients against NumPy's, and the
compressed optimiser against the one handed the whole Jacobian.
"""

from __future__ import annotations

import numba
import numpy as np
import pytest

import rotorbayes as rb
from rotorbayes import inference
from rotorbayes.inference import least_squares as L
from rotorbayes.kernel.triangle import BLOCK_ROWS, difference_quotients, triangle

NO_BASE = np.empty(0)


def _matrix(n: int, k: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    D = rng.standard_normal((k, n)) * np.logspace(2, -9, k)[:, None]
    D[3] = D[2] * (1 + 1e-9) + 1e-12 * D[4]  # nearly collinear columns (a sloppy pair)
    D[5] = 0.0  # a parameter that does nothing here
    D[6] *= 1e-160  # and one that barely does: its squares underflow unscaled
    return D, rng.standard_normal(n) * 3.0


def _norms(A: np.ndarray) -> np.ndarray:
    """Column norms without underflow (each column in units of its largest entry)."""
    m = np.abs(A).max(axis=0)
    m1 = np.where(m > 0, m, 1.0)
    return m * np.linalg.norm(A / m1, axis=0)


@pytest.mark.parametrize("n", [2 * 14, BLOCK_ROWS - 1, 3 * BLOCK_ROWS + 17, 60_002])
def test_triangle_holds_the_gram_matrix_of_lapacks_qr(n):
    D, r = _matrix(n, 13, seed=n)
    T = triangle(D, r, np.ones(13), NO_BASE)
    A = np.column_stack([D.T, r])
    R = np.linalg.qr(A, mode="r")
    assert np.all(np.isfinite(T))
    assert np.array_equal(T, np.triu(T))
    # Row j of a triangle is unique up to its sign where the columns are independent; the
    # Gram matrix is unique: compared entry by entry in units of the columns' norms (taken
    # so that no square underflows).
    c = _norms(A)
    assert np.all(T[:, c == 0] == 0.0)
    c[c == 0] = 1.0
    G, G_ref = (T / c).T @ (T / c), (R / c).T @ (R / c)
    assert np.max(np.abs(G - G_ref)) < 1e-13
    # The diagonal (|T_jj| = |R_jj|) before the nearly collinear pair (after it, the
    # columns' distances from the span of the earlier ones are not determined in doubles).
    for j in (0, 1, 2):
        assert abs(abs(T[j, j]) - abs(R[j, j])) <= 1e-12 * abs(R[j, j])


def test_triangle_and_quotients_give_the_same_bits_on_any_thread_count():
    D, r = _matrix(60_002, 13, seed=7)
    R = np.vstack([r, D])
    steps = np.linspace(1e-6, 3e-6, 13)
    before = numba.get_num_threads()
    out = []
    try:
        for threads in (1, max(2, before)):
            numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
            Q = R[1:].copy()
            difference_quotients(Q, R[0], steps)
            out.append((triangle(D, r, np.ones(13), NO_BASE), Q))
    finally:
        numba.set_num_threads(before)
    assert np.array_equal(out[0][0], out[1][0])
    assert np.array_equal(out[0][1], out[1][1])
    # And the quotients are NumPy's, bit for bit.
    Q = R[1:].copy()
    Q -= R[0][None, :]
    Q /= steps[:, None]
    assert np.array_equal(out[0][1], Q)


def test_columns_scaled_on_the_way_in_are_the_scaled_copys_bits():
    D, r = _matrix(20_000, 13, seed=11)
    scale = np.geomspace(1e-3, 10.0, 13)
    assert np.array_equal(
        triangle(D, r, scale, NO_BASE), triangle(D * scale[:, None], r, np.ones(13), NO_BASE)
    )


def test_difference_quotients_formed_on_the_way_in():
    """compress of forward differences given as perturbed residuals and steps (the
    quotients and the scaling folded into the triangle's copy) holds the same Gauss-Newton
    model as compress of the quotients formed first."""
    D, r = _matrix(20_000, 13, seed=5)
    steps = np.geomspace(1e-7, 1e-3, 13) * np.where(np.arange(13) % 3 == 0, -1.0, 1.0)
    R = r[None, :] + D * steps[:, None]  # the perturbed residuals of quotients D
    scale = np.geomspace(1e-2, 10.0, 13)
    J = ((R - r[None, :]) / steps[:, None]).T
    a = L.compress_differences(R, r, steps, scale)
    b = L.compress(J, r, scale)
    G = b.T @ b
    assert np.abs(a.T @ a - G).max() <= 1e-12 * np.abs(G).max()
    assert np.abs(a[0] - b[0]).max() <= 1e-12 * np.abs(b[0]).max()
    # Short data: the same through NumPy's QR.
    a6 = L.compress_differences(R[:, :20], r[:20], steps, scale)
    b6 = L.compress(J[:20], r[:20], scale)
    assert np.abs(a6.T @ a6 - b6.T @ b6).max() <= 1e-12 * np.abs(b6.T @ b6).max()


def test_compress_keeps_the_gauss_newton_model():
    D, r = _matrix(9_001, 13, seed=3)
    J = D.T
    C = L.compress(J, r)
    f = np.zeros(14)
    f[0] = np.linalg.norm(r)
    c = _norms(J)
    c[c == 0] = 1.0
    G, G_ref = (C / c).T @ (C / c), (J / c).T @ (J / c)
    assert np.max(np.abs(G - G_ref)) < 1e-12
    g, g_ref = C.T @ f, J.T @ r
    assert np.allclose(g, g_ref, rtol=1e-10, atol=1e-12 * np.abs(g_ref).max())


@pytest.fixture(scope="module")
def brake_problem():
    p = rb.parameters.thesis_set("4.3", "P_ref")
    t, u = rb.signals.estimation_signal(6.0, seed=2)
    sim = rb.simulate(p, u, dt=float(t[1] - t[0]), config="brake", alpha0=0.0)
    free = ["k_m", "Tc_u", "b_u", "dTc_u", "db_u"]
    return inference.Problem("brake", [sim.to_experiment("b")], base=p, free=free), p


def test_scipys_step_routine_decides_rank_on_the_fits_row_count():
    from scipy.optimize._lsq import trf

    assert L._count_true_rows()
    # Singular values 1 and 1e-14: full rank on 3 rows (threshold eps * 3), rank-deficient
    # on 100 000 (eps * 1e5 = 2.2e-11): Gauss-Newton (no root-finding) only in the first.
    s, uf, V = np.array([1.0, 1e-14]), np.array([1.0, 1.0]), np.eye(2)
    _, alpha, n_iter = trf.solve_lsq_trust_region(2, 3, uf, s, V, 1e20)
    assert (alpha, n_iter) == (0.0, 0)
    L._ROWS.n = 100_000
    try:
        _, alpha_c, n_iter_c = trf.solve_lsq_trust_region(2, 3, uf, s, V, 1e20)
    finally:
        L._ROWS.n = None
    assert n_iter_c > 0 or alpha_c > 0.0


def test_compressed_fit_ends_where_the_whole_one_does(brake_problem):
    prob, truth = brake_problem
    x0 = prob.x_from({**truth, "k_m": 3.0, "Tc_u": 0.5, "b_u": 1.5, "dTc_u": 0.01, "db_u": -0.02})
    whole = inference.fit(prob, x0, uncertainty=False, compressed=False)
    comp = inference.fit(prob, x0, uncertainty=False)  # compressed: the default
    assert L._ROWS.n is None  # reset after the fit
    assert whole.success and comp.success
    # A well-posed problem (5 free, data from the model): both paths end at the minimum.
    assert comp.ssr <= whole.ssr * (1 + 1e-6) + 1e-20
    assert np.allclose(comp.x, whole.x, rtol=1e-6, atol=0)
    assert np.allclose(comp.x, [truth[n] for n in prob.names], rtol=1e-6)

"""Cost of one Jacobian against one residual evaluation (issue 33, point 1).

The 30 s brake experiment at 1 kHz of ``bench_residual_breakdown.py`` (thesis table 4.3
P_ref, ``estimation_signal(30.0, seed=1)``, quantised; 13 free parameters).  Measured in
one process, the three calls alternating for ``--rounds`` rounds of ``--repeats`` calls
each (minimum and median per call):

* ``Problem.residuals``;
* ``Problem.jacobian(method="sensitivity")``: the kernel's forward sensitivities;
* ``Problem.jacobian(method="differences")``: forward differences (14 residual vectors);
* the sensitivity kernel with nothing written (no residual, no Jacobian entry): its
  integration alone;
* ``Problem.jacobian_rows``: the same kernel writing each step's rows reduced (the
  ``Jᵀ J`` and ``Jᵀ r`` least squares needs, a few rows per step instead of every
  sample's);
* what a compressed least-squares iteration needs, the Jacobian and the ``(k + 1) x k``
  matrix of :func:`rotorbayes.inference.least_squares.compress`: from the reduced rows,
  from the whole sensitivity Jacobian, and from forward differences (the default).

It also prints how far the two Jacobians differ, column by column (relative to the
column's largest entry; the differences carry their own step error, so this is a sanity
check, not the accuracy test: see tests/test_sensitivity.py).

Usage::

    OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1 python benchmarks/bench_sensitivity.py \
        [--rounds 5] [--repeats 20]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--repeats", type=int, default=20)
    a = ap.parse_args()
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    import numpy as np

    import rotorbayes as rb
    from rotorbayes import inference

    p = rb.parameters.thesis_set("4.3", "P_ref")
    t, u = rb.signals.estimation_signal(30.0, seed=1)
    dt = float(t[1] - t[0])
    ex = rb.simulate(p, u, dt=dt, config="brake", alpha0=0.0, quantize_angles=True)
    prob = inference.Problem("brake", [ex.to_experiment("brake_1khz")], base=p)
    x = prob.x_from(p)
    # The sensitivity kernel alone, with no residual and no Jacobian entry written (both
    # channels' columns -1): the integration's share of a Jacobian.
    from rotorbayes.inference.problem import local_name
    from rotorbayes.kernel import layout
    from rotorbayes.kernel.sensitivity import sensitivities_into

    sim = prob.sims[0]
    kp = np.ascontiguousarray(prob.kernel_vectors(x, 0)[0], dtype=float)
    idx = np.array([layout.INDEX[local_name(n)[0]] for n in prob.names], dtype=np.int64)
    J0 = np.zeros((idx.size, prob.n_residuals)).T
    r0 = np.empty((1, prob.n_residuals))

    def integration_only():
        sensitivities_into(kp, sim.u, sim.dt, sim.cfg, sim.shape, sim.grid, sim.h0, idx,
                           not prob.model.stribeck, np.empty(0), np.empty(0), 1.0, 1.0, r0,
                           J0, np.arange(idx.size, dtype=np.int64), -1, -1,
                           np.empty((idx.size + 1, 0)), np.zeros(2, dtype=np.int64))  # fmt: skip

    from rotorbayes.inference.least_squares import compress

    r_x = prob.residuals(x)
    sc = np.abs(x)

    def rows_compressed():
        A, b, r = prob.jacobian_rows(x)
        return compress(A, b, sc, norm=float(np.sqrt(r @ r)))

    calls = {
        "residuals": lambda: prob.residuals(x),
        "jacobian (sensitivity)": lambda: prob.jacobian(x, method="sensitivity"),
        "jacobian (differences)": lambda: prob.jacobian(x, method="differences"),
        "sensitivities, no output": integration_only,
        "jacobian rows (reduced)": lambda: prob.jacobian_rows(x),
        "rows + compress": rows_compressed,
        "sensitivity + compress": lambda: compress(
            prob.jacobian(x, method="sensitivity")[0], r_x, sc
        ),
        "differences + compress": lambda: compress(
            prob.jacobian(x, method="differences")[0], r_x, sc
        ),
    }
    for f in calls.values():  # compile and warm up
        f()
    times: dict[str, list[float]] = {k: [] for k in calls}
    for _ in range(a.rounds):
        for k, f in calls.items():
            for _ in range(a.repeats):
                t0 = time.perf_counter()
                f()
                times[k].append(time.perf_counter() - t0)
    base = min(times["residuals"])
    base_med = statistics.median(times["residuals"])
    print(
        f"30 s brake at 1 kHz, {len(prob.names)} free parameters, {prob.n_residuals} "
        f"residuals; {a.rounds} x {a.repeats} calls each, alternating"
    )
    for k, v in times.items():
        med = statistics.median(v)
        print(
            f"  {k:<26} min {1e3 * min(v):8.3f} ms  median {1e3 * med:8.3f} ms  = "
            f"{min(v) / base:5.2f} x residuals (median {med / base_med:5.2f})"
        )
    Js, _ = prob.jacobian(x, method="sensitivity")
    Jd, _ = prob.jacobian(x, method="differences")
    rel = np.abs(Js - Jd).max(axis=0) / np.abs(Jd).max(axis=0)
    print(
        "  sensitivity vs forward differences (rel_step 1e-6), largest column difference "
        "/ column's largest entry:"
    )
    print("   " + ", ".join(f"{n} {e:.1e}" for n, e in zip(prob.names, rel, strict=True)))
    A, b, r = prob.jacobian_rows(x)
    G = Js.T @ Js
    print(
        f"  reduced rows: {A.shape[0]} instead of {prob.n_residuals}; their JᵀJ against the "
        f"whole Jacobian's: {np.abs(A.T @ A - G).max() / np.abs(G).max():.1e} (relative)"
    )


if __name__ == "__main__":
    main()

"""Speed of the posterior: log-posterior throughput, one residual evaluation, and (with
``--ess``) the wall time of a brake posterior to ESS >= 1000 for every parameter.

One run measures, side by side, on the 30 s brake experiment at 1 kHz (thesis table 4.3
P_ref, ``estimation_signal(30.0, seed=1)``, quantised; the brake's default free set of 13
parameters):

1. log-posterior evaluations per second for 32 walkers in one vectorised call (all walkers
   in one parallel kernel batch), with numba's threads at 1 and at 2;
2. one residual evaluation (``Problem.residuals``: default step, residuals straight from
   the kernel) beside the path before issue 19 (full simulation at a 5 ms step, then the
   subtraction), timed in turn -- alternating single calls (each starts with cold caches)
   and alternating blocks of 10 calls (calls in a row, as a finite-difference Jacobian
   makes them) -- each with its largest angle distance from the independent
   event-driven reference integrator (``tests/reference.py``), and the plain-Python
   ``solve_ivp`` switch model of ``bench_integrator.py`` (best of 3; ratios);
3. with ``--ess``: emcee (2 ensembles x 32 walkers) from the least-squares point on the
   200 Hz bundled brake data until every parameter's ESS (walkers x steps / τ, summed over
   the ensembles) is >= 1000; wall time and ESS per minute.

Targets (issue 19): one 30 s brake residual about 0.5 ms within 1.5e-5 rad of the
reference, >= 400x faster than the Python switch model.

Usage::

    python benchmarks/bench_sampling.py [--ess] [--json out.json]
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import statistics
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numba  # noqa: E402
import numpy as np  # noqa: E402

import rotorbayes as rb  # noqa: E402
from rotorbayes import inference  # noqa: E402
from rotorbayes.inference import sampling  # noqa: E402
from rotorbayes.inference.likelihood import LogPosterior  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def _load(path: Path, name: str):
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--ess", action="store_true", help="also sample a brake posterior to ESS >= 1000 (minutes)"
    )
    ap.add_argument("--json")
    a = ap.parse_args()
    out: dict = {"cores": os.cpu_count()}
    p = rb.parameters.thesis_set("4.3", "P_ref")
    t, u = rb.signals.estimation_signal(30.0, seed=1)
    dt = float(t[1] - t[0])
    sim = rb.simulate(p, u, dt=dt, config="brake", alpha0=0.0, quantize_angles=True)
    ex = sim.to_experiment("brake_1khz")
    prob = inference.Problem("brake", [ex], base=p)
    x = prob.x_from(p)
    lp = LogPosterior(prob, x)
    rng = np.random.default_rng(0)
    z0 = lp.to_z(x)
    Z = z0[None, :] + 1e-7 * rng.standard_normal((32, lp.ndim))
    lp(Z)  # warm-up
    rates = {}
    for th in (1, 2):
        numba.set_num_threads(th)
        lp(Z)
        times = []
        for _ in range(7):
            t0 = time.perf_counter()
            lp(Z)
            times.append(time.perf_counter() - t0)
        rates[th] = 32 / statistics.median(times)
    numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
    out["logpost_evals_per_s"] = rates
    # One residual evaluation, before (the full simulation at the former 5 ms step, then
    # the subtraction) and now (Problem.residuals: the default step, residuals straight
    # from the kernel), timed in turn, and the accuracy of each against the reference.
    sim5 = rb.Simulator("brake", u, dt, step=5e-3)
    kv = sim5.kernel_vector(p)

    def before():
        _, thu, thl = sim5.angles(kv)
        return prob._channel_residual(ex, thu, thl)

    before()
    prob.residuals(x)
    # (a) Alternating single calls: each one starts after the other path has gone through
    # its arrays (1.2 MB for now, more before; each core has 512 kB of L2), so its data
    # comes from L3 or memory.  (b) Alternating blocks of 10 calls of each, every call
    # timed: calls in a row, as a finite-difference Jacobian (one per free parameter)
    # or a line search makes them; the first of each block is cold.
    t_before, t_now = [], []
    for _ in range(30):
        t0 = time.perf_counter()
        before()
        t_before.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        prob.residuals(x)
        t_now.append(time.perf_counter() - t0)
    b_before, b_now = [], []
    for _ in range(6):
        for fn, acc in ((before, b_before), (lambda: prob.residuals(x), b_now)):
            for _ in range(10):
                t0 = time.perf_counter()
                fn()
                acc.append(time.perf_counter() - t0)
    t_res = statistics.median(t_now)
    t_old = statistics.median(t_before)
    t_res_row = statistics.median(b_now)
    t_old_row = statistics.median(b_before)
    ref = _load(ROOT / "tests" / "reference.py", "rb_reference")
    r = ref.reference_simulate(dict(p, alpha0=0.0), t, u, config="brake")
    now = prob.sims[0].simulate(p)
    old = sim5.simulate(p)
    err = max(
        float(np.max(np.abs(now.theta_l - r["theta_l"]))),
        float(np.max(np.abs(now.theta_u - r["theta_u"]))),
    )
    err_old = max(
        float(np.max(np.abs(old.theta_l - r["theta_l"]))),
        float(np.max(np.abs(old.theta_u - r["theta_u"]))),
    )
    bench = _load(ROOT / "benchmarks" / "bench_integrator.py", "rb_bench_integrator")
    py = []
    for _ in range(3):
        t0 = time.perf_counter()
        bench.python_simulate(p, t, u)
        py.append(time.perf_counter() - t0)
    t_py = min(py)
    out.update(residual_ms=1e3 * t_res, residual_min_ms=1e3 * min(t_now),
               residual_before_ms=1e3 * t_old, residual_before_min_ms=1e3 * min(t_before),
               residual_in_a_row_ms=1e3 * t_res_row, residual_before_in_a_row_ms=1e3 * t_old_row,
               residual_max_error_rad=err, residual_before_max_error_rad=err_old,
               python_s=t_py, ratio=t_py / t_res, ratio_before=t_py / t_old,
               ratio_in_a_row=t_py / t_res_row, step_s=prob.sims[0].step)  # fmt: skip
    print(
        f"brake, 30 s at 1 kHz, {prob.n_residuals} residuals, {len(prob.names)} free "
        f"parameters, {os.cpu_count()} cores, 1-min load average {os.getloadavg()[0]:.1f}"
    )
    print(
        f"log-posterior, 32 walkers in one call: {rates[1]:.0f} evaluations/s on 1 thread, "
        f"{rates[2]:.0f}/s on 2 threads (x{rates[2] / rates[1]:.2f})"
    )
    print(
        f"one residual, before (5 ms step, full simulation, then subtraction): median "
        f"{1e3 * t_old:.2f} ms, min {1e3 * min(t_before):.2f} ms; max |angle - reference| "
        f"{err_old:.2g} rad"
    )
    print(
        f"one residual, now (Problem.residuals, {1e3 * prob.sims[0].step:g} ms step, "
        f"residual-only kernel): median {1e3 * t_res:.2f} ms, min {1e3 * min(t_now):.2f} ms "
        f"(x{t_old / t_res:.2f} faster; target <= 0.5 ms: "
        f"{'PASS' if t_res <= 5e-4 else 'FAIL'}); max |angle - reference| {err:.2g} rad "
        f"(target 1.5e-5: {'PASS' if err <= 1.5e-5 else 'FAIL'})"
    )
    print(
        f"one residual in a row (blocks of 10 calls, first of each cold): now median "
        f"{1e3 * t_res_row:.3f} ms, before {1e3 * t_old_row:.2f} ms"
    )
    print(
        f"plain-Python solve_ivp switch model: best of 3 {t_py:.3f} s; / residual median: "
        f"alternating calls now {t_py / t_res:.0f}x (before {t_py / t_old:.0f}x), in a row "
        f"now {t_py / t_res_row:.0f}x (before {t_py / t_old_row:.0f}x); target >= 400x: "
        f"alternating {'PASS' if t_py / t_res >= 400 else 'FAIL'}, in a row "
        f"{'PASS' if t_py / t_res_row >= 400 else 'FAIL'}"
    )
    if a.ess:
        exb = rb.load_example("brake_est")
        pb = inference.Problem("brake", [exb])
        res = inference.fit_from_data(pb).result
        lpb = LogPosterior(pb, res.x)
        t0 = time.perf_counter()
        steps, runs = 500, []
        import tempfile

        with tempfile.TemporaryDirectory() as tmp:
            while True:
                runs = sampling.sample(
                    lpb,
                    res.x,
                    Path(tmp),
                    n_walkers=32,
                    n_steps=steps,
                    n_ensembles=2,
                    progress=False,
                )
                ess = np.zeros(lpb.ndim)
                for r_ in runs:
                    ess += (
                        r_.chain.shape[0]
                        * r_.chain.shape[1]
                        / np.where(np.isfinite(r_.tau), r_.tau, np.inf)
                    )
                if np.all(ess >= 1000) or steps >= 20000:
                    break
                steps = int(steps * 1.6)
        wall = time.perf_counter() - t0
        out.update(
            ess_min=float(ess.min()),
            ess_wall_s=wall,
            ess_steps=steps,
            ess_per_minute=float(ess.min() / (wall / 60)),
        )
        print(
            f"brake posterior (200 Hz bundled data, {lpb.ndim} coordinates, 2 x 32 "
            f"walkers): {steps} steps, min ESS {ess.min():.0f} in {wall:.0f} s "
            f"({ess.min() / (wall / 60):.0f} ESS per minute for the slowest parameter)"
        )
    if a.json:
        Path(a.json).write_text(json.dumps(out, indent=2, default=float))


if __name__ == "__main__":
    main()

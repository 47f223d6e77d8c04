"""Where one residual's time goes, for the kernel now and at an earlier commit, side by side.

The 30 s brake experiment at 1 kHz of ``bench_sampling.py`` (thesis table 4.3 P_ref,
``estimation_signal(30.0, seed=1)``, quantised; 13 free parameters).  The earlier kernel is
taken from git (``--before``) into a temporary directory; each version runs in its own
child process (so each imports its own ``rotorbayes``), the two alternating for
``--rounds`` rounds.  Per version, the minimum and median over ``--repeats`` calls of:

* ``Problem.residuals`` (what least squares and the sampler call);
* the compiled residual kernel alone (``residuals_into_plain``), and variants of it on the
  same data: no output (both channel columns -1), no Stribeck term (``Ts_l = Tc_l``), a
  45-sample step, and a zero input (both discs stuck: the per-step bookkeeping alone).

The variants change the work done, not the code: "no Stribeck" also changes the motion
(the same 20 events here), so differences between rows are estimates of a part's cost.

Usage::

    python benchmarks/bench_residual_breakdown.py [--before COMMIT] [--rounds 3]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from io import BytesIO
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BEFORE = "86d7e7f"  # the kernel before the reference-count fixes of issue 19 goal 1
VARIANTS = ("Problem.residuals", "kernel", "no output", "no Stribeck", "45-sample step",
            "zero input")  # fmt: skip


def child(repeats: int) -> dict:
    """Measure every variant with the ``rotorbayes`` this process imports."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    import numpy as np

    import rotorbayes as rb
    from rotorbayes import inference
    from rotorbayes.kernel import solver
    from rotorbayes.kernel.layout import TC_L, TS_L

    p = rb.parameters.thesis_set("4.3", "P_ref")
    t, u = rb.signals.estimation_signal(30.0, seed=1)
    dt = float(t[1] - t[0])
    ex = rb.simulate(p, u, dt=dt, config="brake", alpha0=0.0, quantize_angles=True)
    ex = ex.to_experiment("brake_1khz")
    prob = inference.Problem("brake", [ex], base=p)
    x = prob.x_from(p)
    sim = prob.sims[0]
    kp, kq = (np.ascontiguousarray(v, dtype=float) for v in sim.kernel_vector(p))
    no_strib = kp.copy()
    no_strib[TS_L] = no_strib[TC_L]
    n = sim.n
    r = np.empty((1, 2 * n))
    mu = np.ascontiguousarray(ex.theta_u)
    ml = np.ascontiguousarray(ex.theta_l)
    zero = np.zeros_like(sim.u)

    def kernel(pp, cols, stride=sim.stride, uu=sim.u):
        if hasattr(solver, "step_grid"):  # the kernel's grid follows the input (since 2026-11-24)
            from rotorbayes.model.simulate import INPUT_TOLERANCE

            grid = solver.step_grid(uu, stride, INPUT_TOLERANCE / sim.dt)
            a = (uu, sim.dt, sim.cfg, sim.shape, grid, float(stride), sim.theta_u)
        else:  # an older kernel: a uniform grid of `stride` samples
            a = (uu, sim.dt, sim.cfg, sim.shape, stride, 1, sim.theta_u)
        return lambda: solver.residuals_into_plain(pp, kq, *a, mu, ml, 1.0, 1.0, r, 0, *cols)

    fns = {
        "Problem.residuals": lambda: prob.residuals(x),
        "kernel": kernel(kp, (0, n)),
        "no output": kernel(kp, (-1, -1)),
        "no Stribeck": kernel(no_strib, (0, n)),
        "45-sample step": kernel(kp, (0, n), stride=45),
        "zero input": kernel(kp, (0, n), uu=zero),
    }
    out = {}
    for name, fn in fns.items():
        fn()
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t0)
        out[name] = (1e3 * min(times), 1e3 * statistics.median(times))
    out["load"] = os.getloadavg()[0]
    out["steps"] = sim.stride
    return out


def export(commit: str) -> Path:
    """``src`` of ``commit`` in a temporary directory."""
    tmp = Path(tempfile.mkdtemp(prefix="rb_before_"))
    data = subprocess.run(["git", "archive", commit, "src"], cwd=ROOT, capture_output=True,
                          check=True).stdout  # fmt: skip
    with tarfile.open(fileobj=BytesIO(data)) as tar:
        tar.extractall(tmp, filter="data")
    return tmp / "src"


def run_child(src: Path, repeats: int) -> dict:
    env = dict(os.environ, PYTHONPATH=str(src), NUMBA_NUM_THREADS="1")
    res = subprocess.run([sys.executable, __file__, "--child", str(repeats)], env=env,
                         capture_output=True, text=True, check=True)  # fmt: skip
    return json.loads(res.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", default=BEFORE)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=300)
    ap.add_argument("--child", type=int, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        print(json.dumps(child(a.child)))
        return
    versions = {f"before ({a.before})": export(a.before), "now": ROOT / "src"}
    for src in versions.values():  # compile (or load from the cache) outside the timing
        run_child(src, 1)
    res: dict[str, list[dict]] = {k: [] for k in versions}
    for _ in range(a.rounds):
        for name, src in versions.items():
            res[name].append(run_child(src, a.repeats))
    loads = [r["load"] for rs in res.values() for r in rs]
    print(
        f"30 s brake residual at 1 kHz, {os.cpu_count()} cores, {a.rounds} alternating rounds"
        f" x {a.repeats} calls, 1-min load average {min(loads):.1f}-{max(loads):.1f}; "
        f"min / median [ms], best round"
    )
    print("| variant | " + " | ".join(versions) + " | now / before (min) |")
    print("|---|" + "---|" * (len(versions) + 1))
    for v in VARIANTS:
        cells = []
        mins = []
        for name in versions:
            lo = min(r[v][0] for r in res[name])
            med = min(r[v][1] for r in res[name])
            mins.append(lo)
            cells.append(f"{lo:.3f} / {med:.3f}")
        print(f"| {v} | " + " | ".join(cells) + f" | {mins[-1] / mins[0]:.2f} |")


if __name__ == "__main__":
    main()

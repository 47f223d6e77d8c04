"""64-start multistart on the default back-end and on local Dask clusters of 1 and 2 workers.

The problem is small (upper configuration, 5 s at 200 Hz, 5 free parameters), so the figures
show the executor's overhead as much as its speed-up.  Every back-end must give the serial
results bit for bit; the script checks it.  Run it as

    NUMBA_NUM_THREADS=1 python benchmarks/bench_dask.py [--starts 64]

and read the load average it prints: on a machine shared with other jobs the ratios say
less than on an idle one.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

import rotorbayes as rb
from rotorbayes import inference
from rotorbayes.inference import parallel


def small_problem() -> inference.Problem:
    ex = rb.load_example("upper_est")
    n = int(round(5.0 / ex.dt)) + 1
    short = rb.Experiment(
        t=ex.t[:n], u=ex.u[:n], theta_u=ex.theta_u[:n], theta_l=None, name="upper 5 s", path=ex.path
    )
    return inference.Problem("upper", [short])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--starts", type=int, default=64)
    a = ap.parse_args()
    prob = small_problem()
    print(
        f"{a.starts}-start multistart, upper, 5 s at 200 Hz ({prob.names}); "
        f"{os.cpu_count()} cores, load average before: "
        + " ".join(f"{v:.1f}" for v in os.getloadavg())
    )
    specs = [
        ("serial (reference)", parallel.ExecutorSpec("serial")),
        (
            f"default ({parallel.DEFAULT_BACKEND}, 2)",
            parallel.ExecutorSpec(parallel.DEFAULT_BACKEND, 2),
        ),
        ("dask LocalCluster, 1 worker", parallel.ExecutorSpec("dask", 1)),
        ("dask LocalCluster, 2 workers", parallel.ExecutorSpec("dask", 2)),
    ]
    rows, ref = [], None
    for label, spec in specs:
        t0 = time.perf_counter()
        with parallel.open_executor(spec) as ex:
            t1 = time.perf_counter()
            ms = inference.multistart(prob, a.starts, seed=0, progress=False, executor=ex)
            t2 = time.perf_counter()
        t3 = time.perf_counter()
        if ref is None:
            ref = ms
        same = ms.ends.tobytes() == ref.ends.tobytes() and ms.ssr.tobytes() == ref.ssr.tobytes()
        rows.append((label, t1 - t0, t2 - t1, t3 - t2, same))
    base = rows[1][2]
    print(
        f"\n{'back-end':32s} {'start s':>8s} {'run s':>8s} {'stop s':>7s} "
        f"{'run/default':>11s} {'bit-identical':>14s}"
    )
    for label, up, run, down, same in rows:
        print(f"{label:32s} {up:8.2f} {run:8.2f} {down:7.2f} {run / base:11.2f} {str(same):>14s}")
    print("load average after: " + " ".join(f"{v:.1f}" for v in os.getloadavg()))
    assert all(r[4] for r in rows), "a back-end gave other results than the serial one"
    assert np.isfinite(ref.ssr).all()


if __name__ == "__main__":
    main()

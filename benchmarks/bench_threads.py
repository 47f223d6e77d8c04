"""Do numba's threads pay, and do they leave anything behind?  Measured side by side in one
run on the 30 s brake experiment at 1 kHz (thesis table 4.3 ``P_ref``, quantised, the
brake's default free set), a batch of 32 walkers (parameters spread by +-1 %):

1. ``Problem.residuals_batch`` of the 32 walkers on 1 and on 2 numba threads, timed in
   turn (1, 2, 1, 2, ...) so a passing load hits both alike; min and median of each, the
   speed-up of the medians and the CPU time / wall time of the 2-thread calls (close to 2
   when nothing else ran on the machine);
2. what a call leaves behind: the process's CPU time during 0.2 s of sleep right after a
   batch call (a thread pool that spins while it waits burns CPU here), and the wall time
   of a plain-Python loop (about 20 ms) right after a batch call against the same loop
   with no batch call for 0.5 s before it.

Usage::

    python benchmarks/bench_threads.py [--rounds 15] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numba  # noqa: E402
import numpy as np  # noqa: E402

import rotorbayes as rb  # noqa: E402
from rotorbayes import inference  # noqa: E402


def python_loop() -> float:
    """Plain-Python work (no NumPy): about 20 ms on the development machine."""
    s = 0.0
    for i in range(400_000):
        s += (i % 7) * 0.5
    return s


def cpu_during_sleep(seconds: float) -> float:
    """CPU seconds this process uses while its main thread sleeps."""
    c0 = time.process_time()
    time.sleep(seconds)
    return time.process_time() - c0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=15)
    ap.add_argument("--walkers", type=int, default=32)
    ap.add_argument("--json")
    a = ap.parse_args()
    p = rb.parameters.thesis_set("4.3", "P_ref")
    t, u = rb.signals.estimation_signal(30.0, seed=1)
    sim = rb.simulate(p, u, dt=float(t[1] - t[0]), config="brake", quantize_angles=True)
    prob = inference.Problem("brake", [sim.to_experiment("brake_1khz")], base=p)
    x0 = prob.x_from(p)
    rng = np.random.default_rng(0)
    X = x0 * (1 + 0.01 * rng.uniform(-1, 1, size=(a.walkers, x0.size)))
    X = np.clip(X, prob.lower, prob.upper)
    max_threads = numba.config.NUMBA_NUM_THREADS
    load = os.getloadavg()[0]
    print(
        f"rotorbayes {rb.__version__} thread benchmark, os.cpu_count() = {os.cpu_count()}, "
        f"numba threads available = {max_threads}, threading layer = ",
        end="",
    )
    prob.residuals_batch(X)  # compile / load the cache, start the pool
    print(numba.threading_layer())
    print(f"1-min load average before the run: {load:.2f}")
    print(
        f"brake, 30 s at 1 kHz, {prob.n_residuals} residuals, {len(prob.names)} free "
        f"parameters, {a.walkers} walkers per call, {a.rounds} rounds"
    )

    # 1. Scaling.
    times: dict[int, list[float]] = {1: [], 2: []}
    cpu2: list[float] = []
    for _ in range(a.rounds):
        for th in (1, 2):
            if th > max_threads:
                continue
            numba.set_num_threads(th)
            c0, w0 = time.process_time(), time.perf_counter()
            prob.residuals_batch(X)
            w = time.perf_counter() - w0
            times[th].append(w)
            if th == 2:
                cpu2.append((time.process_time() - c0) / w)
    numba.set_num_threads(max_threads)
    out: dict = {
        "cores": os.cpu_count(),
        "load_before": load,
        "threading_layer": numba.threading_layer(),
    }
    print("\n1. residuals_batch of the walkers")
    for th, v in times.items():
        if v:
            med = statistics.median(v)
            print(
                f"  {th} thread(s): min {1e3 * min(v):7.2f} ms  median {1e3 * med:7.2f} ms  "
                f"({1e3 * med / a.walkers:.3f} ms per walker)"
            )
            out[f"batch_{th}_threads_ms"] = {
                "min": 1e3 * min(v),
                "median": 1e3 * statistics.median(v),
            }
    if times[2]:
        sp_med = statistics.median(times[1]) / statistics.median(times[2])
        sp_min = min(times[1]) / min(times[2])
        pairs = [a_ / b_ for a_, b_ in zip(times[1], times[2], strict=True)]
        print(
            f"  speed-up from 2 threads: {sp_med:.2f}x (medians), {sp_min:.2f}x (minima), "
            f"pairwise median {statistics.median(pairs):.2f}x   target >= 1.8x"
        )
        print(
            f"  cores kept busy by the 2-thread calls (CPU / wall): "
            f"{statistics.median(cpu2):.2f} of 2"
        )
        out.update(
            speedup_median=sp_med,
            speedup_min=sp_min,
            speedup_pairwise=statistics.median(pairs),
            busy_cores_2_threads=statistics.median(cpu2),
        )

    # 2. What a call leaves behind.
    print("\n2. after a call")
    idle_before = []
    idle_after = []
    loop_quiet = []
    loop_after = []
    for _ in range(5):
        time.sleep(0.5)
        idle_before.append(cpu_during_sleep(0.2))
        time.sleep(0.5)
        w0 = time.perf_counter()
        python_loop()
        loop_quiet.append(time.perf_counter() - w0)
        prob.residuals_batch(X)
        idle_after.append(cpu_during_sleep(0.2))
        prob.residuals_batch(X)
        w0 = time.perf_counter()
        python_loop()
        loop_after.append(time.perf_counter() - w0)
    print(
        f"  CPU used while sleeping 0.2 s, no call before: median "
        f"{1e3 * statistics.median(idle_before):.1f} ms"
    )
    print(
        f"  CPU used while sleeping 0.2 s right after a call: median "
        f"{1e3 * statistics.median(idle_after):.1f} ms  (threads that spin while they wait "
        f"show here)"
    )
    print(
        f"  plain-Python loop, quiet: median {1e3 * statistics.median(loop_quiet):.1f} ms; "
        f"right after a call: median {1e3 * statistics.median(loop_after):.1f} ms "
        f"(ratio {statistics.median(loop_after) / statistics.median(loop_quiet):.2f})"
    )
    out.update(
        idle_cpu_ms_before=1e3 * statistics.median(idle_before),
        idle_cpu_ms_after=1e3 * statistics.median(idle_after),
        loop_ms_quiet=1e3 * statistics.median(loop_quiet),
        loop_ms_after=1e3 * statistics.median(loop_after),
    )
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(out, fh, indent=2)


if __name__ == "__main__":
    main()

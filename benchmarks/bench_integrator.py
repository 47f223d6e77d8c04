"""Speed of rotorbayes's compiled switch-model integrator, side by side with plain Python.

One run measures, on the 30 s brake experiment (thesis table 4.3 P_ref, 1 kHz samples):

1. one simulation with ``Simulator.angles`` at the default step and with ``step=1e-3``;
2. the same switch model written as a plain-Python right-hand side for
   ``scipy.integrate.solve_ivp`` (RK45, rtol 1e-8, Leine's stick band eta = 1e-6 rad/s),
   its time and its distance from rotorbayes's ``step=1e-3`` result;
3. ``Simulator.run_batch`` on 64 perturbed parameter vectors against 64 sequential calls,
   with numba's default number of threads and with one thread.

Usage::

    python benchmarks/bench_integrator.py            # full run (under 10 s on 2 cores)
    python benchmarks/bench_integrator.py --quick    # fewer repeats, baseline once
    python benchmarks/bench_integrator.py --json out.json

Targets (DESIGN.md): median time of one simulation <= 2 ms; plain-Python baseline at
least 150 times slower (best baseline time / median rotorbayes time at the default step).
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable

import numba
import numpy as np
import scipy
from scipy.integrate import solve_ivp

import rotorbayes as rb
from rotorbayes.model.parameters import INDEX

DURATION = 30.0  # s
DT = 1e-3  # s, 1 kHz output
SEED = 1
TABLE, ROW = "4.3", "P_ref"  # the brake configuration's reference parameters
ETA = 1e-6  # rad/s, Leine's stick band for the baseline
BASELINE_RTOL = 1e-8
N_BATCH = 64
PERTURBED = ("k_alpha", "Ts_l", "b_l")
PERTURBATION = 0.05  # relative half-width of the uniform perturbation

TARGET_SINGLE = 2e-3  # s, median time of one simulation
TARGET_RATIO = 150.0  # baseline time / rotorbayes time


# --------------------------------------------------------------------------------------
# timing helpers
# --------------------------------------------------------------------------------------
def time_calls(fn: Callable[[], object], repeats: int) -> list[float]:
    """Wall-clock seconds of ``repeats`` calls of ``fn`` (time.perf_counter)."""
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return out


def summary(times: list[float]) -> dict[str, float]:
    """Median, minimum and number of timings."""
    return {"median_s": statistics.median(times), "min_s": min(times), "n": len(times)}


def check_ok(status, what: str) -> None:
    """Stop the benchmark if a simulation did not succeed."""
    bad = np.flatnonzero(np.atleast_1d(status) != 0)
    if bad.size:
        sys.exit(f"{what}: simulation failed with status {np.atleast_1d(status)[bad[0]]}")


# --------------------------------------------------------------------------------------
# the plain-Python baseline: Leine's switch model in solve_ivp
# --------------------------------------------------------------------------------------
def friction(w, Tc, dTc, b, db, Ts, ws, delta):
    """Slip friction torque for velocity ``w`` (|w| > 0), slip direction s = sign(w)."""
    s = 1.0 if w > 0.0 else -1.0
    a = abs(w)
    torque = Tc + s * dTc + (b + s * db) * a
    if Ts != Tc:
        torque += (Ts - Tc) * math.exp(-((a / ws) ** delta))
    return s * torque


def switch_friction(w, t_ext, Tc, dTc, b, db, Ts, ws, delta):
    """Friction torque of one disc in Leine's switch model.

    Slip for |w| > eta; stick (friction balances the external torque, so the
    acceleration is zero) while the external torque lies in the static band
    [-(Ts - dTc), Ts + dTc]; otherwise transition (friction at the static level,
    opposing the external torque).
    """
    if abs(w) > ETA:
        return friction(w, Tc, dTc, b, db, Ts, ws, delta)
    if -(Ts - dTc) <= t_ext <= Ts + dTc:
        return t_ext
    return Ts + dTc if t_ext > 0.0 else -(Ts - dTc)


def python_rhs(params: dict[str, float], t_grid: np.ndarray, u: np.ndarray):
    """Right-hand side f(t, y), y = (theta_u, omega_u, theta_l, omega_l), of the brake rig."""
    k_m, J_u = params["k_m"], params["J_u"]
    Tc_u, dTc_u, b_u, db_u = params["Tc_u"], params["dTc_u"], params["b_u"], params["db_u"]
    J_l, k_alpha, alpha0 = params["J_l"], params["k_alpha"], params["alpha0"]
    Tc_l, dTc_l, b_l, db_l = params["Tc_l"], params["dTc_l"], params["b_l"], params["db_l"]
    Ts_l, ws_l, delta_l = params["Ts_l"], params["ws_l"], params["delta_l"]

    def rhs(t, y):
        theta_u, omega_u, theta_l, omega_l = y
        v = np.interp(t, t_grid, u)  # input voltage, linear between samples
        T_s = k_alpha * (theta_l - theta_u + alpha0)  # string torque
        ext_u = k_m * v + T_s
        ext_l = -T_s
        # The upper disc has no Stribeck part: Ts = Tc_u.
        T_fu = switch_friction(omega_u, ext_u, Tc_u, dTc_u, b_u, db_u, Tc_u, 1.0, 1.0)
        T_fl = switch_friction(omega_l, ext_l, Tc_l, dTc_l, b_l, db_l, Ts_l, ws_l, delta_l)
        return [omega_u, (ext_u - T_fu) / J_u, omega_l, (ext_l - T_fl) / J_l]

    return rhs


def python_simulate(params, t_grid, u, *, rtol=BASELINE_RTOL, atol=None):
    """The baseline: solve_ivp (RK45) from rest, output at the sample times."""
    kw = {} if atol is None else {"atol": atol}
    sol = solve_ivp(
        python_rhs(params, t_grid, u),
        (t_grid[0], t_grid[-1]),
        [0.0, 0.0, 0.0, 0.0],
        method="RK45",
        rtol=rtol,
        t_eval=t_grid,
        **kw,
    )
    if not sol.success:
        sys.exit(f"baseline solve_ivp failed: {sol.message}")
    return sol


# --------------------------------------------------------------------------------------
# the benchmark
# --------------------------------------------------------------------------------------
def run(quick: bool) -> dict:
    reps_single = 10 if quick else 30
    reps_baseline = 1 if quick else 3
    reps_batch = 3 if quick else 9

    t, u = rb.signals.estimation_signal(DURATION, seed=SEED)
    params = rb.parameters.thesis_set(TABLE, ROW)
    sim = rb.Simulator("brake", u, DT)
    sim_exact = rb.Simulator("brake", u, DT, step=DT)
    kv = sim.kernel_vector(params)
    res: dict = {"quick": quick, "n_samples": int(u.size), "default_step_s": sim.step}

    # 1. One simulation ------------------------------------------------------------------
    t0 = time.perf_counter()
    check_ok(sim.angles(kv)[0], "first call")
    res["first_call_s"] = time.perf_counter() - t0  # includes loading numba's cache
    for _ in range(3):
        sim.angles(kv)
        sim_exact.angles(kv)
    res["single_default"] = summary(time_calls(lambda: sim.angles(kv), reps_single))
    res["single_exact"] = summary(time_calls(lambda: sim_exact.angles(kv), reps_single))
    st, thu_d, thl_d = sim.angles(kv)
    st_x, thu_x, thl_x = sim_exact.angles(kv)
    check_ok(st, "default step")
    check_ok(st_x, "step=1e-3")
    res["default_vs_exact_max_dtheta_l"] = float(np.max(np.abs(thl_d - thl_x)))

    # 2. Plain-Python baseline -----------------------------------------------------------
    times, sol = [], None
    for _ in range(reps_baseline):
        t0 = time.perf_counter()
        sol = python_simulate(params, t, u)
        times.append(time.perf_counter() - t0)
    res["baseline"] = {
        "best_s": min(times),
        "n": len(times),
        "nfev": int(sol.nfev),
        "max_err_theta_l": float(np.max(np.abs(sol.y[2] - thl_x))),
        "max_err_theta_u": float(np.max(np.abs(sol.y[0] - thu_x))),
    }
    # The same baseline with a tighter absolute tolerance (closer to rotorbayes's accuracy).
    t0 = time.perf_counter()
    sol8 = python_simulate(params, t, u, atol=1e-8)
    res["baseline_atol1e-8"] = {
        "best_s": time.perf_counter() - t0,
        "n": 1,
        "nfev": int(sol8.nfev),
        "max_err_theta_l": float(np.max(np.abs(sol8.y[2] - thl_x))),
        "max_err_theta_u": float(np.max(np.abs(sol8.y[0] - thu_x))),
    }
    med = res["single_default"]["median_s"]
    res["ratio_baseline_vs_default"] = res["baseline"]["best_s"] / med
    res["ratio_baseline_vs_exact"] = res["baseline"]["best_s"] / res["single_exact"]["median_s"]

    # 3. Batched evaluation --------------------------------------------------------------
    rng = np.random.default_rng(0)
    KV = np.tile(kv[0], (N_BATCH, 1))
    for name in PERTURBED:
        KV[:, INDEX[name]] *= 1.0 + rng.uniform(-PERTURBATION, PERTURBATION, N_BATCH)

    def sequential():
        return [sim.angles((row, kv[1])) for row in KV]

    n_threads = numba.get_num_threads()
    res["numba_threads"] = n_threads
    st_b, _, thl_b = sim.run_batch(KV)  # warm-up (loads the parallel kernel)
    for _ in range(3):  # the thread pool needs a few calls to reach full speed
        sim.run_batch(KV)
    check_ok(st_b, "run_batch")
    seq = sequential()
    check_ok(np.array([s[0] for s in seq]), "sequential")
    res["batch_vs_sequential_max_diff"] = float(
        max(np.max(np.abs(thl_b[i] - seq[i][2])) for i in range(N_BATCH))
    )
    # The three variants are timed in turn, round after round, so that a passing load
    # from other processes affects all of them alike.
    t_batch, t_one, t_seq, cpu_batch = [], [], [], []
    try:
        for _ in range(reps_batch):
            numba.set_num_threads(n_threads)
            sim.run_batch(KV)  # one untimed call after each change of thread count
            c0 = time.process_time()
            t_batch += time_calls(lambda: sim.run_batch(KV), 1)
            cpu_batch.append(time.process_time() - c0)
            numba.set_num_threads(1)
            sim.run_batch(KV)
            t_one += time_calls(lambda: sim.run_batch(KV), 1)
            t_seq += time_calls(sequential, 1)
    finally:
        numba.set_num_threads(n_threads)
    res["batch"] = summary(t_batch)
    # CPU time of all threads / wall time: near the thread count when the threads really
    # ran in parallel, near 1 when other processes held the other cores.
    res["batch_cores_used"] = sum(cpu_batch) / sum(t_batch)
    res["batch_1thread"] = summary(t_one)
    res["sequential"] = summary(t_seq)
    res["batch_speedup_vs_sequential"] = res["sequential"]["median_s"] / res["batch"]["median_s"]
    res["batch_speedup_threads"] = res["batch_1thread"]["median_s"] / res["batch"]["median_s"]

    # Targets --------------------------------------------------------------------------
    res["targets"] = {
        "single_median_s": {"value": med, "target": TARGET_SINGLE, "pass": med <= TARGET_SINGLE},
        "speed_ratio": {
            "value": res["ratio_baseline_vs_default"],
            "target": TARGET_RATIO,
            "pass": res["ratio_baseline_vs_default"] >= TARGET_RATIO,
        },
    }
    return res


def load_average() -> float | None:
    """1-minute load average of the machine (None where the OS has none)."""
    return os.getloadavg()[0] if hasattr(os, "getloadavg") else None


def machine(load_before: float | None) -> dict:
    return {
        "date": datetime.date.today().isoformat(),
        "cpu_count": os.cpu_count(),
        "python": platform.python_version(),
        "platform": platform.platform(),
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "numba": numba.__version__,
        "rotorbayes": rb.__version__,
        "load_average_1min_before": load_before,
    }


# --------------------------------------------------------------------------------------
# printing
# --------------------------------------------------------------------------------------
def ms(x: float) -> str:
    return f"{x * 1e3:9.2f} ms"


def verdict(ok: bool) -> str:
    return "PASS" if ok else "FAIL"


def report(res: dict, mach: dict) -> str:
    w = 58
    lines = []

    def row(label: str, value: str, note: str = "") -> None:
        lines.append(f"  {label:<{w}}{value:>14}  {note}".rstrip())

    def head(text: str) -> None:
        lines.append("")
        lines.append(text)
        lines.append("  " + "-" * (w + 16))

    lines.append(
        f"rotorbayes {mach['rotorbayes']} integrator benchmark - {mach['date']}, "
        f"os.cpu_count() = {mach['cpu_count']}, numba threads = {res['numba_threads']}"
    )
    load = mach["load_average_1min_before"]
    if load is not None:
        lines.append(
            f"1-min load average before the run: {load:.2f} (it lags; 'cores kept busy' "
            "in part 3 shows whether other processes competed during the run)"
        )
    lines.append(
        f"python {mach['python']}, numpy {mach['numpy']}, scipy {mach['scipy']}, "
        f"numba {mach['numba']}{'  [--quick]' if res['quick'] else ''}"
    )
    lines.append(
        f"brake configuration, thesis {TABLE} {ROW}, estimation_signal({DURATION:g} s, "
        f"seed={SEED}), {res['n_samples']} samples at {1 / DT:g} Hz"
    )

    sd, sx = res["single_default"], res["single_exact"]
    head("1. One 30 s simulation, Simulator.angles (after warm-up)")
    row("first call (loads numba's compiled cache)", ms(res["first_call_s"]))
    step_ms = res["default_step_s"] * 1e3
    row(f"default step ({step_ms:g} ms): median", ms(sd["median_s"]), f"n = {sd['n']}")
    row(f"default step ({step_ms:g} ms): minimum", ms(sd["min_s"]))
    row("step=1e-3 (1 RK4 step per sample): median", ms(sx["median_s"]), f"n = {sx['n']}")
    row("step=1e-3 (1 RK4 step per sample): minimum", ms(sx["min_s"]))
    row(
        "max |theta_l(default) - theta_l(step=1e-3)|",
        f"{res['default_vs_exact_max_dtheta_l']:.2e}",
        "rad",
    )
    row("target: median (default step) <= 2 ms", verdict(sd["median_s"] <= TARGET_SINGLE))

    b, b8 = res["baseline"], res["baseline_atol1e-8"]
    head("2. Plain-Python switch model in solve_ivp(RK45, rtol=1e-8), eta = 1e-6 rad/s")
    row(f"time, default atol (1e-6), best of {b['n']}", ms(b["best_s"]), f"nfev = {b['nfev']}")
    row("  max |theta_l error| vs rotorbayes step=1e-3", f"{b['max_err_theta_l']:.2e}", "rad")
    row("  max |theta_u error| vs rotorbayes step=1e-3", f"{b['max_err_theta_u']:.2e}", "rad")
    row("time, atol=1e-8 (for comparison), single run", ms(b8["best_s"]), f"nfev = {b8['nfev']}")
    row("  max |theta_l error| vs rotorbayes step=1e-3", f"{b8['max_err_theta_l']:.2e}", "rad")
    row(
        "speed ratio baseline / rotorbayes default step",
        f"{res['ratio_baseline_vs_default']:.0f} x",
        "(baseline best / rotorbayes median)",
    )
    row("speed ratio baseline / rotorbayes step=1e-3", f"{res['ratio_baseline_vs_exact']:.0f} x")
    row(
        "speed ratio baseline(atol 1e-8) / rotorbayes default",
        f"{b8['best_s'] / sd['median_s']:.0f} x",
    )
    row(
        "target: baseline / rotorbayes default >= 150 x",
        verdict(res["targets"]["speed_ratio"]["pass"]),
    )

    bt, bs, b1 = res["batch"], res["sequential"], res["batch_1thread"]
    head(f"3. Batch of {N_BATCH} perturbed parameter sets ({', '.join(PERTURBED)} +-5 %)")
    row(
        f"run_batch, {res['numba_threads']} numba threads: median",
        ms(bt["median_s"]),
        f"n = {bt['n']}",
    )
    row("run_batch, 1 numba thread: median", ms(b1["median_s"]), f"n = {b1['n']}")
    row(
        f"{N_BATCH} sequential Simulator.angles calls: median", ms(bs["median_s"]), f"n = {bs['n']}"
    )
    row(
        f"cores kept busy by run_batch (CPU / wall time, of {res['numba_threads']})",
        f"{res['batch_cores_used']:.2f}",
    )
    row("per parameter set in the batch", ms(bt["median_s"] / N_BATCH))
    row("speed-up batch vs sequential", f"{res['batch_speedup_vs_sequential']:.2f} x")
    row("speed-up from threads alone (1 thread / all)", f"{res['batch_speedup_threads']:.2f} x")
    row(
        "max |theta_l(batch) - theta_l(sequential)|",
        f"{res['batch_vs_sequential_max_diff']:.1e}",
        "rad",
    )

    head("Targets")
    tg = res["targets"]
    s, r = tg["single_median_s"], tg["speed_ratio"]
    lines.append(
        f"  single 30 s simulation (median): {s['value'] * 1e3:7.2f} ms   target <= "
        f"{s['target'] * 1e3:g} ms   {verdict(s['pass'])}"
    )
    lines.append(
        f"  speed ratio vs plain Python:     {r['value']:7.0f} x    target >= "
        f"{r['target']:g} x     {verdict(r['pass'])}"
    )
    lines.append(f"  machine: os.cpu_count() = {mach['cpu_count']}")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer repeats; baseline run once")
    ap.add_argument("--json", metavar="PATH", help="also write the figures to this JSON file")
    args = ap.parse_args(argv)
    load_before = load_average()
    t0 = time.perf_counter()
    res = run(args.quick)
    mach = machine(load_before)
    res["total_runtime_s"] = time.perf_counter() - t0
    print(report(res, mach))
    print(f"\n(total benchmark time {res['total_runtime_s']:.1f} s)")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"machine": mach, "results": res}, fh, indent=2)
            fh.write("\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

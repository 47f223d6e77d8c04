"""What the LuGre law's stiffness costs the integrator, measured side by side in one run.

A 30 s coupled experiment at 1 kHz (a smooth input with steps, the lower disc sliding up
to ~13 rad/s and reversing; parameters unlike the thesis tables) simulated with the
switch model and with the ``lugre`` law at bristle stiffnesses from 30 to 2000 N m/rad (the
bound is 700; 1000 and 2000 show the trend).
For each: the time per simulation (median of ``--repeats``, the runs interleaved), its
ratio to the switch model, and the kernel's self-consistency (the default steps against
steps of at most 0.25 ms; the accuracy against the independent reference is tested in
tests/test_lugre.py).

The cost has two sources: the effect's functions are called through the hooked kernel
(first-class function calls, about 3 per right-hand side), and the bristles are stiff --
while the disc slides, ``z`` relaxes in ``g / (sigma0_l |omega_l|)``, and at rest the
bristles are a spring of frequency ``sqrt(sigma0_l / J_l)``; the kernel's substep rule
for an effect state (:func:`rotorbayes.kernel.terms.state_step`) follows both.

Usage::

    python benchmarks/bench_lugre.py [--repeats 3] [--seconds 30]
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from rotorbayes.model.simulate import simulate  # noqa: E402

BASE = dict(
    J_l=0.03, k_alpha=0.11, Tc_l=0.035, Ts_l=0.12, ws_l=0.8, delta_l=1.7, b_l=0.006, dTc_l=0.004
)
EFFECTS = ["lower_stribeck", "lower_asymmetric_coulomb"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=30.0)
    a = ap.parse_args()
    dt = 1e-3
    t = np.arange(0.0, a.seconds, dt)
    u = 2.0 + 1.5 * np.sin(2 * np.pi * 0.13 * t) + 0.8 * np.sign(np.sin(2 * np.pi * 0.05 * t))
    stiff = (30.0, 100.0, 300.0, 1000.0, 2000.0)
    cases = [("switch", BASE, EFFECTS, {})]
    for s0 in stiff:
        p = dict(BASE, sigma0_l=s0, sigma1_l=np.sqrt(s0 * BASE["J_l"]))
        cases.append((f"lugre {s0:g}", p, EFFECTS + ["lugre"], {}))
    for _name, p, eff, kw in cases:  # compile and warm
        simulate(p, u, dt=dt, config="coupled", effects=eff, **kw)
    times = {name: [] for name, *_ in cases}
    for _ in range(a.repeats):
        for name, p, eff, kw in cases:
            t0 = time.perf_counter()
            simulate(p, u, dt=dt, config="coupled", effects=eff, **kw)
            times[name].append(time.perf_counter() - t0)
    base = float(np.median(times["switch"]))
    print(f"{a.seconds:g} s coupled at 1 kHz, {os.cpu_count()} cores; median of {a.repeats}")
    print(f"{'model':<14} {'ms/sim':>10} {'x switch':>9} {'self-consistency [rad]':>24}")
    for name, p, eff, _ in cases:
        med = float(np.median(times[name])) * 1e3
        cons = ""
        if name != "switch":
            s1 = simulate(p, u, dt=dt, config="coupled", effects=eff)
            s2 = simulate(p, u, dt=dt, config="coupled", effects=eff, step=2.5e-4)
            cons = f"{np.max(np.abs(s1.theta_l - s2.theta_l)):.2e}"
        print(f"{name:<14} {med:10.1f} {med / (base * 1e3):9.0f} {cons:>24}")


if __name__ == "__main__":
    main()

"""Accuracy on random brake rigs unlike the thesis, against the independent reference.

Each rig draws the brake's parameters from 0.6-1.5 times thesis table 4.3 P_ref
(``Ts_l`` at least 1.5 ``Tc_l``), ``delta_l`` from 0.8-3.0, and is driven for 20 s at 1 kHz
by a multisine (``estimation_signal``) or a staircase of twelve levels in -3..3 V joined by
30 ms moving-average ramps, in turn.  Each is run through the event-driven reference
(tests/reference.py) and through the kernel at a 25 ms step and at the default step; the
largest angle distance of either disc is printed.  The tests' limit is 1.5e-5 rad.

    python benchmarks/bench_random_rigs.py [--seeds 1 2] [--rigs 8]

About ten seconds per rig.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

import rotorbayes as rb  # noqa: E402
from rotorbayes.model.parameters import thesis_set  # noqa: E402

SCALED = ["k_m", "J_u", "Tc_u", "b_u", "J_l", "k_alpha", "Tc_l", "b_l", "Ts_l", "ws_l"]


def rigs(seed: int, count: int):
    """``(label, params, t, u)`` of ``count`` random rigs drawn with ``seed``."""
    rng = np.random.default_rng(seed)
    base = thesis_set("4.3", "P_ref")
    for k in range(count):
        p = dict(base)
        for n in SCALED + ["delta_l"]:  # delta_l's draw is replaced below (same stream)
            p[n] = base[n] * rng.uniform(0.6, 1.5)
        p["Ts_l"] = max(p["Ts_l"], 1.5 * p["Tc_l"])
        p["delta_l"] = rng.uniform(0.8, 3.0)
        t, u = rb.signals.estimation_signal(20.0, seed=100 + k)
        kind = "multisine"
        if k % 2:
            kind = "staircase"
            levels = rng.uniform(-3.0, 3.0, 12)
            idx = np.minimum((t / (20.0 / 12)).astype(int), 11)
            u = np.convolve(levels[idx], np.ones(30) / 30, mode="same")
        yield f"seed {seed} rig {k} {kind}, delta_l {p['delta_l']:.2f}", p, t, u


def main(argv: list[str]) -> None:
    from reference import reference_simulate

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--rigs", type=int, default=8)
    a = ap.parse_args(argv)
    worst = [0.0, 0.0]
    print(f"{'rig':<44}{'stick':>7}{'25 ms':>10}{'default':>10}")
    for seed in a.seeds:
        for label, p, t, u in rigs(seed, a.rigs):
            ref = reference_simulate(p, t, u, "brake")
            row = []
            for i, kw in enumerate(({"step": 0.025}, {})):
                sim = rb.simulate(p, u, dt=t[1] - t[0], config="brake", **kw)
                e = max(float(np.max(np.abs(sim.theta_u - ref["theta_u"]))),
                        float(np.max(np.abs(sim.theta_l - ref["theta_l"]))))  # fmt: skip
                row.append(e)
                worst[i] = max(worst[i], e)
            stick = sim.stick_fraction("l")
            print(f"{label:<44}{stick:7.2f}" + "".join(f"{e:10.2e}" for e in row), flush=True)
    print(f"{'worst':<44}{'':7}" + "".join(f"{e:10.2e}" for e in worst))


if __name__ == "__main__":
    main(sys.argv[1:])

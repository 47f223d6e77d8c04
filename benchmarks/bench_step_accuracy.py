"""Largest error against the independent reference, per accuracy-suite case and step.

The cases are those of tests/test_integrator_accuracy.py, tests/test_effects.py and
tests/test_input_delay.py (every configuration and catalogue effect, stick-slip, fast
input transitions, an 18 ms input delay); each is run once through the event-driven
reference (tests/reference.py) and then through the kernel at every step asked for.

    python benchmarks/bench_step_accuracy.py            # the default step
    python benchmarks/bench_step_accuracy.py d 0.015 0.025 0.035

``d`` is the default step (``rotorbayes.model.simulate.default_step``); numbers are the
largest step in seconds.  Prints a row per case and the worst of each column; the tests'
limit is 1.5e-5 rad.  About a minute for the references.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

import rotorbayes as rb  # noqa: E402
from rotorbayes.model import Model  # noqa: E402
from rotorbayes.model.parameters import thesis_set  # noqa: E402


def cases():
    """``(label, params, config, effects, t, u, reference params, simulate keywords)``."""
    import test_effects as ef
    import test_input_delay as dl
    import test_integrator_accuracy as acc

    out = []
    t3, u3 = rb.signals.estimation_signal(30.0, seed=3)
    for label, config, params, alpha0, effects in acc._cases():
        out.append(
            (
                label,
                params,
                config,
                effects,
                t3,
                u3,
                acc._ref_params(params, config, alpha0),
                {"alpha0": alpha0},
            )
        )
    f = acc._fast_steps(10.0, seed=1)
    tf = np.arange(10001) * 1e-3
    out.append(
        (
            "fast transitions",
            acc.FAST_RIG,
            "brake",
            ("upper_asymmetric_coulomb", "upper_asymmetric_viscous", "lower_stribeck"),
            tf,
            np.asarray(f(tf), float),
            dict(acc.FAST_RIG),
            {},
        )
    )
    for effect, config, params, rate in ef._accuracy_cases():
        t, u = rb.signals.estimation_signal(30.0, seed=3, rate=rate)
        effects = [] if effect in Model(config).effect_names else [effect]
        q = dict(params)
        if config == "coupled" and effect != "lower_stribeck":
            q["Ts_l"] = q["Tc_l"]
        out.append((f"{effect}, {config}, {rate} Hz", params, config, effects, t, u, q, {}))
    t, u = dl._sine_input(5.0)
    p = dict(thesis_set("4.2", "P_ref"), t_delay=dl.DELAY)
    out.append(
        ("18 ms delay, coupled", p, "coupled", ["input_delay"], t, u, dict(p, Ts_l=p["Tc_l"]), {})
    )
    for effect in dl._catalogue_cases():
        t, u = dl._swinging_input(10.0)
        config = dl._config_for(effect)
        base = thesis_set({"upper": "4.1", "coupled": "4.2", "brake": "4.3"}[config], "P_ref")
        p = dict(base, t_delay=dl.DELAY)
        p.update(dl._effect_value(effect))
        effects = list(
            dict.fromkeys(e for e in (effect, "input_delay") if e not in Model(config).effect_names)
        )
        q = dict(p)
        if config == "coupled" and "lower_stribeck" not in effects:
            q["Ts_l"] = q["Tc_l"]
        out.append((f"18 ms delay + {effect}", p, config, effects, t, u, q, {}))
    return out


def main(argv: list[str]) -> None:
    from reference import reference_simulate

    steps = [None if a == "d" else float(a) for a in (argv or ["d"])]
    names = ["default" if s is None else f"{s * 1e3:g} ms" for s in steps]
    print(f"{'case':<44}" + "".join(f"{n:>10}" for n in names))
    worst = [0.0] * len(steps)
    for label, params, config, effects, t, u, q, kw in cases():
        ref = reference_simulate(q, t, u, config)
        row = []
        for i, st in enumerate(steps):
            extra = dict(kw) if st is None else dict(kw, step=st)
            sim = rb.simulate(params, u, dt=t[1] - t[0], config=config, effects=effects, **extra)
            e = float(np.max(np.abs(sim.theta_u - np.asarray(ref["theta_u"], float))))
            if config != "upper":
                e = max(e, float(np.max(np.abs(sim.theta_l - np.asarray(ref["theta_l"], float)))))
            row.append(e)
            worst[i] = max(worst[i], e)
        print(f"{label:<44}" + "".join(f"{e:10.2e}" for e in row), flush=True)
    print(f"{'worst':<44}" + "".join(f"{e:10.2e}" for e in worst))


if __name__ == "__main__":
    main(sys.argv[1:])

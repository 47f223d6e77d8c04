"""Simulation-based calibration: do the credible intervals cover the truth as often as they
claim?

Many synthetic data sets are made with known truth: the truth is drawn from the prior
(normal, 5 % wide), simulated, and quantised like the encoders (the only noise, as on the
rig).  Each data set is fitted by least squares and sampled with emcee under the same prior.
If the likelihood and the sampler are honest, the central 50 % and 90 % intervals contain
the truth in 50 % and 90 % of the data sets, within the binomial sampling error of the
check itself, and the rank of the truth among the draws is uniform.

Two set-ups (``--case``):

* ``upper``: the upper disc alone, k_m and b_u free, 2 s of the estimation signal at 200 Hz
  (a busy input; the disc rarely sticks);
* ``brake`` (the hard one): the brake configuration with stick-slip, the lower friction
  (Tc_l, b_l, Ts_l) free, 6 s at 1 kHz of a step-like input whose levels are held 1-4 s,
  so the discs stick and the encoders' rounding error is constant for long stretches.

``--noise`` chooses the likelihood (``robust``, the default, or the i.i.d. ``floor`` to
see it fail on the brake case).

The data sets are independent: they run through rotorbayes's executor layer (local threads
by default; ``--backend serial|threads|processes|dask``, ``--workers N``, ``--scheduler
ADDRESS`` or ``DASK_SCHEDULER_ADDRESS`` as for ``rotorbayes multistart``), with the same
results on every back-end (each data set has its own seed).

Run from the repository root::

    python analyses/sbc.py [--case brake] [--datasets 60] [--noise floor] [--out DIR]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

import rotorbayes as rb
from rotorbayes import inference
from rotorbayes.inference import parallel, sampling
from rotorbayes.inference.likelihood import LogPosterior, Prior
from rotorbayes.model.parameters import resolve

CASES = {
    "upper": dict(
        config="upper",
        centre=dict(k_m=3.1, Tc_u=0.62, dTc_u=0.03, b_u=1.7, db_u=0.05),
        free=("k_m", "b_u"),
        duration=2.0,
        rate=200.0,
        hold=None,
    ),
    "brake": dict(
        config="brake",
        centre=dict(
            k_m=3.1,
            Tc_u=0.62,
            dTc_u=0.03,
            b_u=1.7,
            db_u=0.05,
            J_l=0.062,
            k_alpha=0.118,
            Tc_l=0.071,
            b_l=0.0150,
            db_l=0.0012,
            Ts_l=0.36,
            ws_l=0.95,
            delta_l=1.5,
        ),
        free=("Tc_l", "b_l", "Ts_l"),
        duration=6.0,
        rate=1000.0,
        hold=(1.0, 4.0),
    ),
}
REL_SD = 0.05


def one(
    seed: int, case: dict, u, dt, folder: Path | None, *, walkers: int, steps: int, noise: str
) -> dict:
    rng = np.random.default_rng(seed)
    centre, free, config = case["centre"], case["free"], case["config"]
    truth = dict(centre)
    for n in free:
        truth[n] = centre[n] * (1 + REL_SD * rng.standard_normal())
    p = resolve(truth, config=config)
    sim = rb.simulate(p, u, dt=dt, config=config, quantize_angles=True)
    prob = inference.Problem(config, [sim.to_experiment(f"sbc{seed}")], free=list(free), base=p)
    res = inference.fit(prob, {n: centre[n] for n in free})
    priors = {
        n: Prior("normal", prob.lower[j], prob.upper[j], centre[n], REL_SD * centre[n])
        for j, n in enumerate(free)
    }
    lp = LogPosterior(
        prob,
        res.x,
        priors=priors,
        noise=noise,
        uncertainty=res.uncertainty if noise == "robust" else None,
    )
    runs = sampling.sample(
        lp,
        res.x,
        folder / f"sbc{seed}" if folder else None,
        n_walkers=walkers,
        n_steps=steps,
        n_ensembles=1,
        seed=seed,
        progress=False,
    )
    burn, thin = sampling.burn_thin(runs)
    Z = runs[0].chain[burn::thin].reshape(-1, lp.ndim)
    X, _, _ = lp.split(Z)
    out = {"seed": seed}
    for j, n in enumerate(free):
        x = X[:, j]
        t = truth[n]
        out[n] = {
            "truth": t,
            "rank": float(np.mean(x < t)),
            "in50": bool(np.quantile(x, 0.25) <= t <= np.quantile(x, 0.75)),
            "in90": bool(np.quantile(x, 0.05) <= t <= np.quantile(x, 0.95)),
            "tau": float(np.nanmax(runs[0].tau)),
        }
    return out


def _one_task(shared: tuple, seed: int) -> dict:
    """One data set as a task of the executor layer: ``shared`` is what every data set
    needs, sent once per worker."""
    case, u, dt, folder, kw = shared
    return one(seed, case, u, dt, folder, **kw)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", choices=sorted(CASES), default="upper")
    ap.add_argument("--datasets", type=int, default=60)
    ap.add_argument("--walkers", type=int, default=12)
    ap.add_argument("--steps", type=int, default=400)
    ap.add_argument("--noise", choices=["robust", "floor"], default="robust")
    ap.add_argument("--out", help="keep the chains here (default: in memory)")
    ap.add_argument(
        "--backend",
        choices=parallel.BACKENDS,
        help=f"where the data sets run (default {parallel.DEFAULT_BACKEND})",
    )
    ap.add_argument("--workers", type=int, help="parallel data sets (default: the cores)")
    ap.add_argument("--scheduler", help="a Dask scheduler's address")
    a = ap.parse_args(argv)
    case = CASES[a.case]
    if case["hold"] is None:
        t, u = rb.signals.make_signal("est", case["duration"], rate=case["rate"], seed=8)
    else:
        t, u = rb.signals.estimation_signal(
            case["duration"], rate=case["rate"], seed=8, hold=case["hold"]
        )
    t0 = time.perf_counter()
    folder = Path(a.out) if a.out else None
    shared = (case, u, t[1] - t[0], folder, dict(walkers=a.walkers, steps=a.steps, noise=a.noise))
    with parallel.open_executor(parallel.choose(a.backend, a.workers, a.scheduler)) as ex:
        done = dict(
            parallel.run_tasks(_one_task, list(range(a.datasets)), shared=shared, executor=ex)
        )
    rows = [done[s] for s in range(a.datasets)]
    n = len(rows)
    result = {"datasets": n, "seconds": time.perf_counter() - t0, "case": a.case, "noise": a.noise}
    for name in case["free"]:
        c50 = float(np.mean([r[name]["in50"] for r in rows]))
        c90 = float(np.mean([r[name]["in90"] for r in rows]))
        ranks = np.array([r[name]["rank"] for r in rows])
        # Rank uniformity: Kolmogorov-Smirnov against U(0, 1).
        from scipy import stats

        ks = stats.kstest(ranks, "uniform")
        result[name] = {
            "cover50": c50,
            "cover90": c90,
            "sd50": math.sqrt(0.25 / n),
            "sd90": math.sqrt(0.09 / n),
            "ks_p": float(ks.pvalue),
            "ranks": ranks.tolist(),
        }
        print(
            f"{name}: 50 % intervals cover the truth in {100 * c50:.0f} % of {n} data sets "
            f"(sampling sd {100 * math.sqrt(0.25 / n):.1f} %), 90 % intervals in "
            f"{100 * c90:.0f} % (sd {100 * math.sqrt(0.09 / n):.1f} %); ranks uniform: "
            f"KS p {ks.pvalue:.2f}"
        )
    print(f"SBC ({a.case}, noise {a.noise}) done in {result['seconds']:.0f} s")
    return result


if __name__ == "__main__":
    sys.exit(0 if main() else 1)

"""Simulation-based calibration: do the credible intervals cover the truth as often as they
claim?

On a small configuration (the upper disc alone, k_m and b_u free, 2 s of the estimation
signal at 200 Hz), many synthetic data sets are made with known truth: the truth is drawn
from the prior (normal, 5 % wide, around a motor unlike the thesis's), simulated, and
quantised like the encoder (the only noise, as on the rig).  Each data set is fitted by
least squares and sampled with emcee under the same prior and the Gaussian likelihood at
the quantisation floor.  If the likelihood and the sampler are honest, the central 50 % and
90 % intervals contain the truth in 50 % and 90 % of the data sets, within the binomial
sampling error of the check itself; the rank of the truth among the draws is uniform.

Run from the repository root::

    python analyses/sbc.py [--datasets 60] [--out DIR]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

import rotorbayes as rb
from rotorbayes import inference as E
from rotorbayes.inference import sampling as S
from rotorbayes.inference.likelihood import LogPosterior, Prior
from rotorbayes.model.parameters import resolve

CENTRE = dict(k_m=3.1, Tc_u=0.62, dTc_u=0.03, b_u=1.7, db_u=0.05)
FREE = ("k_m", "b_u")
REL_SD = 0.05


def one(seed: int, u, dt, folder: Path | None, *, walkers: int, steps: int) -> dict:
    rng = np.random.default_rng(seed)
    truth = dict(CENTRE)
    for n in FREE:
        truth[n] = CENTRE[n] * (1 + REL_SD * rng.standard_normal())
    p = resolve(truth, config="upper")
    sim = rb.simulate(p, u, dt=dt, config="upper", quantize_angles=True)
    prob = E.Problem("upper", [sim.to_experiment(f"sbc{seed}")], free=list(FREE), base=p)
    res = E.fit(prob, {n: CENTRE[n] for n in FREE})
    priors = {n: Prior("normal", prob.lower[j], prob.upper[j], CENTRE[n], REL_SD * CENTRE[n])
              for j, n in enumerate(FREE)}
    lp = LogPosterior(prob, res.x, priors=priors)
    runs = S.sample(lp, res.x, folder / f"sbc{seed}" if folder else None,
                    n_walkers=walkers, n_steps=steps,
                    n_ensembles=1, seed=seed, progress=False)
    burn, thin = S.burn_thin(runs)
    Z = runs[0].chain[burn::thin].reshape(-1, lp.ndim)
    X, _, _ = lp.split(Z)
    out = {"seed": seed}
    for j, n in enumerate(FREE):
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


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--datasets", type=int, default=60)
    ap.add_argument("--walkers", type=int, default=12)
    ap.add_argument("--steps", type=int, default=400)
    ap.add_argument("--out", help="keep the chains here (default: in memory)")
    a = ap.parse_args(argv)
    t, u = rb.signals.make_signal("est", 2.0, rate=200.0, seed=8)
    t0 = time.perf_counter()
    folder = Path(a.out) if a.out else None
    rows = [one(s, u, t[1] - t[0], folder, walkers=a.walkers, steps=a.steps)
            for s in range(a.datasets)]
    n = len(rows)
    result = {"datasets": n, "seconds": time.perf_counter() - t0}
    for name in FREE:
        c50 = float(np.mean([r[name]["in50"] for r in rows]))
        c90 = float(np.mean([r[name]["in90"] for r in rows]))
        ranks = np.array([r[name]["rank"] for r in rows])
        # Rank uniformity: Kolmogorov-Smirnov against U(0, 1).
        from scipy import stats

        ks = stats.kstest(ranks, "uniform")
        result[name] = {"cover50": c50, "cover90": c90,
                        "sd50": math.sqrt(0.25 / n), "sd90": math.sqrt(0.09 / n),
                        "ks_p": float(ks.pvalue)}
        print(f"{name}: 50 % intervals cover the truth in {100 * c50:.0f} % of {n} data sets "
              f"(sampling sd {100 * math.sqrt(0.25 / n):.1f} %), 90 % intervals in "
              f"{100 * c90:.0f} % (sd {100 * math.sqrt(0.09 / n):.1f} %); ranks uniform: "
              f"KS p {ks.pvalue:.2f}")
    print(f"SBC done in {result['seconds']:.0f} s")
    return result


if __name__ == "__main__":
    sys.exit(0 if main() else 1)

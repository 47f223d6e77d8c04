"""What the honest standard errors cost, side by side with the fit they belong to.

30 s brake experiment at 1 kHz (kernel data, step-like input, quantised), fitted from the
truth: the least-squares fit alone (i.i.d. standard errors) against the honest uncertainty
(:mod:`rotorbayes.inference.uncertainty`: rounding simulated 200 times, block jackknife,
one smooth-input simulation at 8x the rate), each the best of ``--repeat`` runs, and the
ratio.  BLAS is kept to one thread (rotorbayes does that on import).

    python benchmarks/bench_uncertainty.py [--repeat 3]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import rotorbayes as rb
from rotorbayes import inference
from rotorbayes.model.parameters import resolve

BRAKE = dict(
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
)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args(argv)
    full = resolve(BRAKE, config="brake")
    t, u = rb.signals.estimation_signal(30.0, rate=1000.0, seed=11)
    sim = rb.simulate(full, u, dt=1e-3, config="brake", quantize_angles=True)
    prob = inference.Problem("brake", [sim.to_experiment("brake")])
    x0 = prob.x_from(full)
    inference.fit(prob, x0, uncertainty=False)  # compile and warm
    fit_s, unc_s = [], []
    for _ in range(a.repeat):
        t0 = time.perf_counter()
        res = inference.fit(prob, x0, uncertainty=False)
        fit_s.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        inference.attach_uncertainty(res)
        unc_s.append(time.perf_counter() - t0)
    f, s = min(fit_s), min(unc_s)
    infl = np.nanmedian(res.uncertainty.inflation())
    print(f"30 s brake at 1 kHz, {len(prob.names)} free parameters, {res.n_residuals} residuals")
    print(f"  least-squares fit (from the truth):   {f:7.3f} s (best of {a.repeat})")
    print(f"  honest uncertainty (attach):          {s:7.3f} s (best of {a.repeat})")
    print(f"  ratio uncertainty / fit:              {s / f:7.2f}")
    print(f"  honest / white-noise standard errors: {infl:7.2f}x (median over parameters)")
    return {"fit_s": f, "uncertainty_s": s, "ratio": s / f, "inflation": float(infl)}


if __name__ == "__main__":
    main()

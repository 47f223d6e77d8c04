"""Generate the bundled example data (synthetic, documented as such).

Every file is simulated with rotorbayes from one of the thesis's chapter-5 parameter
sets, sampled at 200 Hz over 30 s and quantised like the encoders (54 934.256 and
40 000 counts/rev).  The ground truth of each file is in ``truth.json`` beside them,
except the hidden effect of the tutorial files, which is revealed only in
docs/example_data.md (so a tutorial can find it from the residuals first).

Run from the repository root:  python analyses/make_example_data.py [--force]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import rotorbayes as rb
from rotorbayes.model.parameters import thesis_set

OUT = Path(__file__).resolve().parents[1] / "src" / "rotorbayes" / "data" / "examples"
RATE = 200.0
DURATION = 30.0

# (file stem, configuration, parameter set, input kind, input seed, alpha0)
FILES = [
    ("upper_est", "upper", "5.1:P", "est", 11, 0.0),
    ("upper_val", "upper", "5.1:P", "val", 12, 0.0),
    ("coupled_est", "coupled", "5.2:P", "est", 21, 0.0),
    ("coupled_val", "coupled", "5.2:P", "val", 22, 0.0),
    ("brake_est", "brake", "5.4:P", "est", 31, 0.0),
    ("brake_val", "brake", "5.4:P", "val", 32, 0.0),
    # Four repeats of one input with different initial torsion (thesis fig. 5.13).
    ("brake_rep1", "brake", "5.4:P", "est", 33, 0.0),
    ("brake_rep2", "brake", "5.4:P", "est", 33, 0.9),
    ("brake_rep3", "brake", "5.4:P", "est", 33, -1.4),
    ("brake_rep4", "brake", "5.4:P", "est", 33, 2.1),
    # Tutorial: asymmetric lower Coulomb/viscous friction (thesis §5.2.3, table 5.3).
    ("coupled_hidden_est", "coupled", "5.3:P", "est", 41, 0.0),
    ("coupled_hidden_val", "coupled", "5.3:P", "val", 42, 0.0),
]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--force", action="store_true", help="overwrite existing files")
    a = ap.parse_args()
    OUT.mkdir(parents=True, exist_ok=True)
    truth = {}
    for stem, config, pset, kind, seed, alpha0 in FILES:
        params = thesis_set(*pset.split(":"))
        t, u = rb.signals.make_signal(kind, DURATION, rate=RATE, seed=seed)
        sim = rb.simulate(
            params, u, dt=1 / RATE, config=config, alpha0=alpha0, quantize_angles=True
        )
        meta = {
            "source": "synthetic (rotorbayes simulate), not a measurement",
            "config": config,
            "input": f"{kind} seed={seed}",
            "rate_hz": RATE,
        }
        hidden = "hidden" in stem
        if not hidden:
            meta["params"] = f"thesis:{pset}"
            meta["alpha0"] = alpha0
        rb.save_experiment(
            sim.to_experiment(stem), OUT / f"{stem}.csv", overwrite=a.force, meta=meta
        )
        if not hidden:
            truth[stem] = {
                "config": config,
                "params": f"thesis:{pset}",
                "alpha0": alpha0,
                "input": kind,
                "seed": seed,
                "stick_fraction_lower": sim.stick_fraction("l")
                if sim.theta_l is not None
                else None,
            }
        print(
            f"{stem:20s} {config:8s} thesis:{pset:6s} alpha0={alpha0:+.1f}  "
            f"events={len(sim.events)}"
        )
    (OUT / "truth.json").write_text(json.dumps(truth, indent=2) + "\n")


if __name__ == "__main__":
    main()

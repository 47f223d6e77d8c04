"""The identifiability showcase: the near scale symmetry of (J_l, k_alpha, Tc_l, b_l).

Thesis table 4.2 found the lower disc's four parameters 17-20 % above their reference values
while the fit stayed excellent.  The reason is a symmetry: the lower disc's equation divided
by J_l depends only on k_alpha/J_l, Tc_l/J_l and b_l/J_l, so only the string's reaction on
the upper disc can tell the scale.  Three studies on the bundled coupled data (simulated
from the thesis's chapter-5 values, quantised like the encoders):

A. the thesis's coupled step: J_l, k_alpha, Tc_l, b_l free, upper disc fixed, theta_l
   fitted (eq. 4.10).  The posterior's main axis, the sloppiest Fisher direction and the
   thesis's step from P_ref to its P (table 4.2) are compared as unit vectors in log space.
B. the measured theta_u prescribed: the symmetry is exact, the Fisher information singular,
   and the posterior runs along the ridge to the prior bounds.
C. rotorbayes's default: the upper disc fitted too, on both channels, with J_u fixed by its
   geometry (eq. 5.4): the upper disc's reaction pins the scale.

Then the same Fisher analysis for the upper and the brake configurations.  Every number
printed is measured in the run; a copy goes to ``report.txt`` in ``--out``.

Run from the repository root::

    python analyses/identifiability.py [--quick] [--out DIR] [--force]
"""

from __future__ import annotations

import argparse
import io
import shutil
import sys
import time
from pathlib import Path

import numpy as np

import rotorbayes as rb
from rotorbayes import inference
from rotorbayes.inference import identify, posterior, sampling
from rotorbayes.inference.likelihood import LogPosterior
from rotorbayes.model.parameters import thesis_set

LOWER4 = ["J_l", "k_alpha", "Tc_l", "b_l"]


def _short(ex, seconds):
    n = int(round(seconds / ex.dt)) + 1
    if n >= ex.n:
        return ex
    return rb.Experiment(
        t=ex.t[:n],
        u=ex.u[:n],
        theta_u=ex.theta_u[:n],
        theta_l=None if ex.theta_l is None else ex.theta_l[:n],
        name=ex.name,
        path=ex.path,
    )


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def _posterior(prob, x, folder, *, walkers, steps, seed=0, noise="floor"):
    lp = LogPosterior(prob, x, noise=noise)
    runs = sampling.sample(
        lp, x, folder, n_walkers=walkers, n_steps=steps, n_ensembles=2, seed=seed, progress=False
    )
    burn, thin = sampling.burn_thin(runs)
    Z = np.concatenate([r.chain[burn::thin].reshape(-1, lp.ndim) for r in runs])
    return lp, runs, Z


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(Path(__file__).parent / "out" / "identifiability"))
    ap.add_argument("--quick", action="store_true", help="10 s of data, short chains (tests)")
    ap.add_argument("--force", action="store_true")
    a = ap.parse_args(argv)
    out = Path(a.out)
    if out.exists() and any(out.iterdir()):
        if not a.force:
            raise SystemExit(f"{out}/ already holds results; pass --force to replace them")
        shutil.rmtree(out)
    out.mkdir(parents=True, exist_ok=True)
    buf = io.StringIO()

    def say(*args):
        text = " ".join(str(x) for x in args)
        print(text, flush=True)
        buf.write(text + "\n")

    t_start = time.perf_counter()
    seconds = 10.0 if a.quick else 30.0
    walkers, steps = (24, 300) if a.quick else (32, 1500)
    ex = _short(rb.load_example("coupled_est"), seconds)
    truth = thesis_set("5.2", "P")
    d_thesis = _unit(
        np.log([thesis_set("4.2", "P")[n] / thesis_set("4.2", "P_ref")[n] for n in LOWER4])
    )
    result: dict = {}

    # ---------------------------------------------------------------- A: thesis step
    say(
        f"A. thesis step (table 4.2): {', '.join(LOWER4)} free, theta_l fitted, "
        f"{seconds:.0f} s of coupled data"
    )
    prob = inference.Problem("coupled", [ex], free=LOWER4, base=truth)
    res = inference.fit(prob, thesis_set("4.2", "P0"))
    F = identify.fisher(prob, res.x)
    v_f = F.vectors[:, 0] * np.sign(F.vectors[0, 0])
    lp, runs, Z = _posterior(prob, res.x, out / "A", walkers=walkers, steps=steps)
    Zl = Z[:, :4] - Z[:, :4].mean(axis=0)
    _, sv, Vt = np.linalg.svd(Zl, full_matrices=False)
    v_p = Vt[0] * np.sign(Vt[0][0])
    share = float(sv[0] ** 2 / np.sum(sv**2))
    cos = {
        "posterior_vs_fisher": abs(float(v_p @ v_f)),
        "posterior_vs_thesis_step": abs(float(v_p @ d_thesis)),
        "fisher_vs_thesis_step": abs(float(v_f @ d_thesis)),
    }
    sd_log = Z[:, :4].std(axis=0)
    ratios = np.log(np.exp(Z[:, 1:4]) / np.exp(Z[:, [0]]))
    say(
        "  least squares from table 4.2's P0: "
        + ", ".join(f"{n} {v:.5g}" for n, v in zip(LOWER4, res.x, strict=True))
    )
    say(
        "  sloppiest Fisher direction (log): "
        + ", ".join(f"{n} {c:+.2f}" for n, c in zip(LOWER4, v_f, strict=True))
        + f"; 1-sigma width {100 * F.width(0):.3g} % along it, stiffest "
        f"{100 * F.width(3):.2g} %"
    )
    say(
        "  posterior main axis (log):        "
        + ", ".join(f"{n} {c:+.2f}" for n, c in zip(LOWER4, v_p, strict=True))
        + f"; {100 * share:.1f} % of the posterior variance"
    )
    say(
        "  thesis step P_ref -> P (log):      "
        + ", ".join(f"{n} {c:+.2f}" for n, c in zip(LOWER4, d_thesis, strict=True))
    )
    say(
        "  |cos| posterior axis vs Fisher {posterior_vs_fisher:.4f}, vs the thesis step "
        "{posterior_vs_thesis_step:.4f}; Fisher vs thesis step {fisher_vs_thesis_step:.4f}".format(
            **cos
        )
    )
    say(
        "  posterior sd in log: "
        + ", ".join(f"{n} {100 * s:.3g} %" for n, s in zip(LOWER4, sd_log, strict=True))
        + "; of the ratios to J_l: "
        + ", ".join(
            f"{n}/J_l {100 * s:.3g} %" for n, s in zip(LOWER4[1:], ratios.std(axis=0), strict=True)
        )
    )
    result["A"] = {
        "cosines": cos,
        "share": share,
        "sd_log": sd_log.tolist(),
        "sd_log_ratios": ratios.std(axis=0).tolist(),
        "rhat_max": float(
            max(
                posterior.summary_table(
                    posterior.inference_data(lp, runs, max_draws=200, predictive=False), lp, runs
                )[i]["r_hat"]
                for i in range(4)
            )
        ),
    }

    # ------------------------------------------------------ B: theta_u prescribed
    say("\nB. the measured theta_u prescribed (the lower disc alone): the symmetry is exact")
    probB = inference.Problem("coupled", [ex], free=LOWER4, base=truth, prescribed_upper=True)
    resB = inference.fit(probB, thesis_set("4.2", "P0"))
    FB = identify.fisher(probB, resB.x)
    say(
        f"  Fisher eigenvalues: smallest/largest {FB.eigenvalues[0] / FB.eigenvalues[-1]:.2e}"
        " (singular to rounding); sloppiest direction "
        + ", ".join(
            f"{n} {c:+.2f}"
            for n, c in zip(LOWER4, FB.vectors[:, 0] * np.sign(FB.vectors[0, 0]), strict=True)
        )
    )
    lpB, runsB, ZB = _posterior(probB, resB.x, out / "B", walkers=walkers, steps=steps)
    XB = np.exp(ZB[:, :4])
    span = XB.max(axis=0) / XB.min(axis=0)
    say(
        "  posterior range (max/min over the draws): "
        + ", ".join(f"{n} x{s:.3g}" for n, s in zip(LOWER4, span, strict=True))
    )
    lo_j, hi_j, hi_k = XB[:, 0].min(), XB[:, 0].max(), XB[:, 1].max()
    say(
        f"  J_l drawn from {lo_j:.4g} to {hi_j:.4g} kg m^2, k_alpha up to {hi_k:.4g} N m/rad "
        f"(its prior bound {probB.upper[1]:g}): the posterior runs along the ridge to the "
        "prior's bounds"
    )
    rB = np.log(XB[:, 1:] / XB[:, [0]])
    say(
        "  while the ratios stay fixed: "
        + ", ".join(
            f"{n}/J_l sd {100 * s:.2g} %" for n, s in zip(LOWER4[1:], rB.std(axis=0), strict=True)
        )
    )
    result["B"] = {
        "eig_ratio": float(FB.eigenvalues[0] / FB.eigenvalues[-1]),
        "k_alpha_max_over_bound": float(XB[:, 1].max() / probB.upper[1]),
        "span": span.tolist(),
        "sd_log_ratios": rB.std(axis=0).tolist(),
    }

    # ---------------------------------------------------------- C: rotorbayes default
    say("\nC. rotorbayes's default: upper disc fitted too, both channels, J_u fixed (eq. 5.4)")
    probC = inference.Problem("coupled", [ex])
    resC = inference.fit_from_data(probC).result
    FC = identify.fisher(probC, resC.x)
    for w in identify.describe(FC):
        say("  " + w)
    se = dict(zip(probC.names, resC.stderr / np.abs(resC.x), strict=True))
    say("  relative standard errors: " + ", ".join(f"{n} {100 * se[n]:.2g} %" for n in LOWER4))
    result["C"] = {
        "rel_stderr": {n: float(se[n]) for n in LOWER4},
        "recovered": {n: float(resC.values[n] / truth[n]) for n in LOWER4},
    }

    say(
        "\nIn words: with the thesis's procedure only the ratios k_alpha/J_l, Tc_l/J_l and "
        "b_l/J_l are determined; their common scale moves along the sloppiest direction, "
        "the posterior's main axis and the thesis's own step from P_ref to P alike. With the "
        "upper disc prescribed the scale is free to the prior's bounds. What pins it: fixing "
        "k_alpha from the string's geometry (eq. 5.11: "
        f"{rb.parameters.K_ALPHA_EQ_5_11:.4f} N m/rad) or a prior on it, fitting the upper "
        "disc's angle too (its reaction to the string torque, with J_u from eq. 5.4: study "
        "C), or an input that excites the string more."
    )

    # ----------------------------------------------------- upper and brake configurations
    for config, name in (("upper", "upper_est"), ("brake", "brake_est")):
        exc = _short(rb.load_example(name), seconds)
        p = inference.Problem(config, [exc])
        r = inference.fit_from_data(p).result
        Fx = identify.fisher(p, r.x)
        say(
            f"\n{config} configuration ({len(p.names)} free parameters, default set): "
            f"Fisher condition number {Fx.eigenvalues[-1] / Fx.eigenvalues[0]:.3g}"
        )
        for w in identify.describe(Fx):
            say("  " + w)
        result[config] = {"condition": float(Fx.eigenvalues[-1] / Fx.eigenvalues[0])}
    result["seconds"] = time.perf_counter() - t_start
    say(f"\nidentifiability study done in {result['seconds']:.0f} s")
    (out / "report.txt").write_text(buf.getvalue())
    return result


if __name__ == "__main__":
    sys.exit(0 if main() else 1)

"""Reproduce thesis chapter 5 (Wegman 2006) on the bundled example data.

The bundled files are synthetic (see docs/example_data.md): they were simulated from the
thesis's chapter-5 estimates, so the thesis's P of each table is also the truth behind the
corresponding files, and a good estimate must recover it. The steps are chained as in the
thesis, each starting from the previous step's result:

* §5.1 upper part (``upper_est`` / ``upper_val``): k_m, Tc_u, dTc_u, b_u, db_u from table
  5.1's P0 (table 5.1).
* §5.2 lower part without brake (``coupled_est`` / ``coupled_val``): J_l, k_alpha, Tc_l,
  b_l from table 5.2's P0 with the upper part from our 5.1 result (table 5.2).
* §5.2.3 on the files with a hidden effect (``coupled_hidden_est`` / ``_val``): first
  the symmetric model, whose largest error the thesis found too large, then the
  asymmetric lower friction (catalogue effects ``lower_asymmetric_coulomb`` and
  ``lower_asymmetric_viscous``), showing how the error falls (R², fit %, max error, SSR,
  AICc) and the recovered Tc_lp, Tc_ln, b_lp, b_ln beside table 5.3.
* §5.3.2 lower part with brake on the four repeats ``brake_rep1`` ... ``brake_rep4`` at
  once (same input, different initial string torsion), with one alpha0 per experiment,
  beside tables 5.4 and 5.5, and contrasted with the thesis's approach of one shared
  alpha0 = 0 for all four ("estimating alpha0 per experiment is the better model").

Figures and a copy of the printed report go to ``--out`` (default
``analyses/out/chapter5``).

Run from the repository root::

    python analyses/chapter5.py            # full run (30 s files)
    python analyses/chapter5.py --quick    # first 10 s of each file (tests)
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import rotorbayes as rb
from rotorbayes import inference
from rotorbayes.figures import plots
from rotorbayes.model.parameters import INFO, TABLE_FREE, thesis_set
from rotorbayes.util.metrics import aicc, channel_fit

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _report import (  # noqa: E402
    Report,
    channels_of,
    plot_fit,
    prepare_out,
    save,
    score,
    text_table,
)

DEFAULT_OUT = Path(__file__).resolve().parent / "out" / "chapter5"
QUICK_SECONDS = 10.0
ASYM_EFFECTS = ("lower_asymmetric_coulomb", "lower_asymmetric_viscous")
TRUE_ALPHA0 = (0.0, 0.9, -1.4, 2.1)

# R² printed in the thesis (sections 5.1-5.3, figure captions 5.1-5.17, table 5.5).
THESIS_R2 = {
    "5.1": {"est": {"theta_u": 1.0000}, "val": {"theta_u": 0.9993}},
    "5.2": {
        "est": {"theta_l": 0.9996, "alpha": 0.9987},
        "val": {"theta_l": 0.9991, "alpha": 0.9981},
    },
    "5.3": {
        "est": {"theta_l": 0.9996, "alpha": 0.9990},
        "val": {"theta_l": 0.9989, "alpha": 0.9978},
    },
    "5.4": {"val": {"theta_l": 0.9869, "alpha": 0.9757}},
}
THESIS_T55 = {
    "theta_l": (0.9957, 0.9945, 0.9973, 0.9992),
    "alpha": (0.9716, 0.9651, 0.9685, 0.9905),
}

FIGURES = [
    "report.txt",
    "step5_1_fit_est.png",
    "step5_1_fit_val.png",
    "step5_1_friction.png",
    "step5_2_fit_est.png",
    "step5_2_fit_val.png",
    "step5_2_friction.png",
    "step5_3_symmetric_fit_est.png",
    "step5_3_asymmetric_fit_est.png",
    "step5_3_asymmetric_fit_val.png",
    "step5_3_friction.png",
    "step5_4_repeats.png",
    "step5_4_fit_rep4.png",
    "step5_4_fit_rep4_shared_alpha0.png",
    "step5_4_fit_val.png",
    "step5_4_friction.png",
]


# ----------------------------------------------------------------------------- output
def column(name: str):
    """A parameter-table column: header and value function (also derived pairs)."""
    derived = {
        "Tc_up": ("N m", lambda p: p["Tc_u"] + p["dTc_u"]),
        "Tc_un": ("N m", lambda p: p["Tc_u"] - p["dTc_u"]),
        "b_up": ("N m s/rad", lambda p: p["b_u"] + p["db_u"]),
        "b_un": ("N m s/rad", lambda p: p["b_u"] - p["db_u"]),
        "Tc_lp": ("N m", lambda p: p["Tc_l"] + p["dTc_l"]),
        "Tc_ln": ("N m", lambda p: p["Tc_l"] - p["dTc_l"]),
        "b_lp": ("N m s/rad", lambda p: p["b_l"] + p["db_l"]),
        "b_ln": ("N m s/rad", lambda p: p["b_l"] - p["db_l"]),
    }
    if name in derived:
        unit, f = derived[name]
        return f"{name} [{unit}]", f
    return f"{name} [{INFO[name].unit}]", lambda p: p[name]


def param_table(names, rows) -> str:
    """Rows ``(label, full parameter dict)``, one column per (possibly derived) name."""
    cols = [column(n) for n in names]
    body = [[lab, *(f"{f(vals):.5f}" for _, f in cols)] for lab, vals in rows]
    return text_table(["", *(h for h, _ in cols)], body)


def quality_table(rows) -> str:
    """Rows ``(data, channel, ChannelFit, thesis R² or None)``."""
    heads = ["data", "channel", "R²", "R² thesis", "fit %", "max|e| [rad]", "SSR [rad²]"]
    body = [
        [
            exp,
            ch,
            f"{f.r2:.4f}",
            "" if r2t is None else f"{r2t:.4f}",
            f"{f.nrmse_fit:.2f}",
            f"{f.max_abs_error:.3e}",
            f"{f.ssr:.3e}",
        ]
        for exp, ch, f, r2t in rows
    ]
    return text_table(heads, body, n_left=2)


# ------------------------------------------------------------------------- computation
def load(name: str, seconds: float | None) -> rb.Experiment:
    """A bundled example, optionally cut to its first ``seconds``."""
    ex = rb.load_example(name)
    if seconds is None:
        return ex
    m = int(round(seconds / ex.dt)) + 1
    return rb.Experiment(
        t=ex.t[:m],
        u=ex.u[:m],
        theta_u=ex.theta_u[:m],
        theta_l=None if ex.theta_l is None else ex.theta_l[:m],
        name=ex.name,
    )


def fit_and_report(
    rep,
    tag,
    config,
    est,
    val,
    free,
    base,
    start,
    out,
    effects=(),
    title="",
    thesis_key=None,
    figure=None,
):
    """Fit ``free`` on ``est`` from ``start``; print and plot estimation/validation."""
    prob = inference.Problem(config, [est], free=list(free), base=base, effects=effects)
    rep.step(f"{tag}: least squares, free {', '.join(free)}")
    res = inference.fit(prob, {n: start[n] for n in free}, max_nfev=200)
    rep.step(
        f"{tag}: {res.message}; {res.nfev} evaluations, {res.seconds:.1f} s, SSR {res.ssr:.4e} rad²"
    )
    q = inference.quality(prob, res.x)[0]
    rows, fits = [], {}
    for kind, ex in (("est", est), ("val", val)):
        if ex is None:
            continue
        f, sim = score(config, res.params, ex, effects)
        fits[kind] = f
        thesis = THESIS_R2.get(thesis_key, {}).get(kind, {}) if thesis_key else {}
        for c in channels_of(config):
            rows.append((kind, c, f[c], thesis.get(c)))
        if figure:
            plot_fit(
                config,
                ex,
                sim,
                f,
                f"{title}: {'estimation' if kind == 'est' else 'validation'}",
                out / f"{figure}_fit_{kind}.png",
            )
    return {"fit": res, "problem": prob, "fits": fits, "rows": rows, "aicc": q["aicc"]}


def step_upper(rep, a, quick_s):
    rep.header("§5.1 upper part (string removed): upper_est / upper_val, table 5.1")
    est, val = load("upper_est", quick_s), load("upper_val", quick_s)
    free = list(TABLE_FREE["5.1"])
    p0, pt = thesis_set("5.1", "P0"), thesis_set("5.1", "P")
    r = fit_and_report(
        rep,
        "5.1",
        "upper",
        est,
        val,
        free,
        p0,
        p0,
        a.out,
        title="§5.1 upper part",
        thesis_key="5.1",
        figure="step5_1",
    )
    res = r["fit"]
    rep()
    rows = [("P0 (thesis)", p0), ("P (thesis) = truth", pt), ("P (rotorbayes)", res.params)]
    rep(param_table(free, rows))
    rep()
    rep("  the same as friction levels per direction (thesis text: Tc_up 0.3752, Tc_un 0.3902,")
    rep("  b_up 2.4427, b_un 2.4585):")
    rep(param_table(["Tc_up", "Tc_un", "b_up", "b_un"], rows))
    rep()
    rep(quality_table(r["rows"]))
    fig, _ = plots.plot_friction(
        res.params,
        discs=("u",),
        reference=pt,
        title="§5.1: upper friction, ours (solid) vs table 5.1 P (dashed)",
    )
    save(fig, a.out / "step5_1_friction.png")
    return r


def step_coupled(rep, a, quick_s, upper):
    rep.header("§5.2 lower part without brake: coupled_est / coupled_val, table 5.2")
    est, val = load("coupled_est", quick_s), load("coupled_val", quick_s)
    free = list(TABLE_FREE["5.2"])
    p0, pt = thesis_set("5.2", "P0"), thesis_set("5.2", "P")
    base = dict(p0)
    base.update({n: upper[n] for n in TABLE_FREE["5.1"]})
    rep("  start: table 5.2 P0, upper part from our 5.1 result")
    r = fit_and_report(
        rep,
        "5.2",
        "coupled",
        est,
        val,
        free,
        base,
        base,
        a.out,
        title="§5.2 lower part, symmetric friction",
        thesis_key="5.2",
        figure="step5_2",
    )
    res = r["fit"]
    rep()
    rep(
        param_table(
            free, [("P0 (thesis)", p0), ("P (thesis) = truth", pt), ("P (rotorbayes)", res.params)]
        )
    )
    rep()
    rep(quality_table(r["rows"]))
    fig, _ = plots.plot_friction(
        res.params,
        discs=("l",),
        reference=pt,
        title="§5.2: lower friction, ours (solid) vs table 5.2 P (dashed)",
    )
    save(fig, a.out / "step5_2_friction.png")
    return r


def step_hidden(rep, a, quick_s, coupled):
    rep.header("§5.2.3 the hidden effect: coupled_hidden_est / coupled_hidden_val, table 5.3")
    est, val = load("coupled_hidden_est", quick_s), load("coupled_hidden_val", quick_s)
    free = list(TABLE_FREE["5.2"])
    start = dict(coupled)
    rep("  (a) symmetric lower friction (the default coupled model), start: our 5.2 result")
    sym = fit_and_report(
        rep,
        "5.2.3 symmetric",
        "coupled",
        est,
        val,
        free,
        start,
        start,
        a.out,
        title="§5.2.3 symmetric model on the hidden-effect data",
        thesis_key="5.2",
        figure=None,
    )
    ps = sym["fit"].params
    fs, sim_s = score("coupled", ps, est)
    plot_fit(
        "coupled",
        est,
        sim_s,
        fs,
        "§5.2.3 symmetric model on the hidden-effect data: estimation",
        a.out / "step5_3_symmetric_fit_est.png",
    )
    rep(quality_table(sym["rows"]))
    e_s = sym["fits"]["est"]["theta_l"].max_abs_error
    rep(f"  largest theta_l error of the symmetric model: {e_s:.3f} rad")
    rep("  (thesis §5.2.3: 'almost 0.6 radians' on its measurement; R² thesis above is its")
    rep("  symmetric fit, table 5.2)")

    rep()
    rep("  (b) asymmetric lower friction: add the catalogue effects")
    rep("      " + ", ".join(ASYM_EFFECTS) + " (free dTc_l, db_l);")
    rep("      start: the symmetric result with dTc_l = db_l = 0")
    free_a = [*free, "dTc_l", "db_l"]
    start_a = dict(ps)
    start_a.update(dTc_l=0.0, db_l=0.0)
    asym = fit_and_report(
        rep,
        "5.2.3 asymmetric",
        "coupled",
        est,
        val,
        free_a,
        start_a,
        start_a,
        a.out,
        effects=ASYM_EFFECTS,
        title="§5.2.3 asymmetric model on the hidden-effect data",
        thesis_key="5.3",
        figure="step5_3_asymmetric",
    )
    pa = asym["fit"].params
    rep(quality_table(asym["rows"]))

    rep()
    rep("  Before / after adding the asymmetric friction (theta_l; AICc on the estimation")
    rep("  data, k = number of fitted parameters):")
    heads = [
        "model",
        "k",
        "R² est",
        "fit % est",
        "max|e| est",
        "SSR est",
        "AICc est",
        "R² val",
        "fit % val",
        "max|e| val",
    ]
    body = []
    for lab, r in (("symmetric", sym), ("asymmetric", asym)):
        fe, fv = r["fits"]["est"]["theta_l"], r["fits"]["val"]["theta_l"]
        body.append(
            [
                lab,
                str(len(r["fit"].names)),
                f"{fe.r2:.6f}",
                f"{fe.nrmse_fit:.3f}",
                f"{fe.max_abs_error:.3e}",
                f"{fe.ssr:.3e}",
                f"{r['aicc']:.0f}",
                f"{fv.r2:.6f}",
                f"{fv.nrmse_fit:.3f}",
                f"{fv.max_abs_error:.3e}",
            ]
        )
    rep(text_table(heads, body))
    e_a = asym["fits"]["est"]["theta_l"].max_abs_error
    ssr_s, ssr_a = sym["fit"].ssr, asym["fit"].ssr
    rep(
        f"  max error falls {e_s / e_a:.3g}x ({e_s:.3g} -> {e_a:.3g} rad), SSR "
        f"{ssr_s / ssr_a:.3g}x; AICc falls by {sym['aicc'] - asym['aicc']:.0f}"
    )
    rep("  (thesis: R²(theta_l) unchanged at 0.9996, R²(alpha) 0.9987 -> 0.9990,")
    rep("  'the maximum error is lower')")

    rep()
    pt0, pt = thesis_set("5.3", "P0"), thesis_set("5.3", "P")
    cols = ["J_l", "k_alpha", "Tc_lp", "Tc_ln", "b_lp", "b_ln"]
    rep(
        param_table(
            cols,
            [
                ("P0 (thesis)", pt0),
                ("P (thesis, table 5.3)*", pt),
                ("symmetric (rotorbayes)", ps),
                ("asymmetric (rotorbayes)", pa),
            ],
        )
    )
    rep("  Tc_lp = Tc_l + dTc_l, Tc_ln = Tc_l - dTc_l, b_lp = b_l + db_l, b_ln = b_l - db_l")
    rep("  * table 5.3's P is also the truth behind the coupled_hidden_* files (the spoiler")
    rep("    of docs/example_data.md)")
    rep(
        f"  the symmetric fit compensates on the ridge: J_l x{ps['J_l'] / pt['J_l']:.3f}, "
        f"k_alpha x{ps['k_alpha'] / pt['k_alpha']:.3f} relative to table 5.3"
    )
    fig, _ = plots.plot_friction(
        pa,
        discs=("l",),
        reference=ps,
        title="§5.2.3: lower friction, asymmetric (solid) vs symmetric (dashed) fit",
    )
    save(fig, a.out / "step5_3_friction.png")
    return {
        "symmetric": sym,
        "asymmetric": asym,
        "max_error_symmetric": e_s,
        "max_error_asymmetric": e_a,
    }


def step_brake(rep, a, quick_s, upper, coupled):
    rep.header("§5.3.2 lower part with brake: brake_rep1..4 at once, tables 5.4 and 5.5")
    reps = [load(f"brake_rep{i}", quick_s) for i in range(1, 5)]
    val = load("brake_val", quick_s)
    free = list(TABLE_FREE["5.4"])
    p0, pt = thesis_set("5.4", "P0"), thesis_set("5.4", "P")
    base = dict(p0)
    base.update({n: upper[n] for n in TABLE_FREE["5.1"]})
    base.update(J_l=coupled["J_l"], k_alpha=coupled["k_alpha"])
    rep("  start: table 5.4 P0, upper part from our 5.1 result, J_l and k_alpha from our")
    rep("  5.2 result, alpha0 = 0")

    prob_e = inference.Problem("brake", reps, free=[*free, "alpha0"], base=base)
    rep.step(f"per-experiment alpha0: least squares, free {', '.join(free)}, alpha0[0..3]")
    res_e = inference.fit(prob_e, {n: base[n] for n in free}, max_nfev=200)
    rep.step(
        f"per-experiment alpha0: {res_e.message}; {res_e.nfev} evaluations, "
        f"{res_e.seconds:.1f} s, SSR {res_e.ssr:.4e} rad²"
    )

    prob_s = inference.Problem("brake", reps, free=free, base=base)
    rep.step("shared alpha0 = 0 (the thesis's eq. 5.19): least squares, free " + ", ".join(free))
    res_s = inference.fit(prob_s, {n: base[n] for n in free}, max_nfev=200)
    rep.step(
        f"shared alpha0 = 0: {res_s.message}; {res_s.nfev} evaluations, "
        f"{res_s.seconds:.1f} s, SSR {res_s.ssr:.4e} rad²"
    )

    rep()
    cols = ["Tc_l", "b_lp", "b_ln", "Ts_l", "ws_l", "delta_l"]
    rep(
        param_table(
            cols,
            [
                ("P0 (thesis)", p0),
                ("P (thesis) = truth", pt),
                ("per-exp. alpha0 (rotorbayes)", res_e.params),
                ("shared alpha0=0 (rotorbayes)", res_s.params),
            ],
        )
    )

    rep()
    rep("  Initial string torsion, estimated per experiment:")
    body = []
    for i, a0 in enumerate(TRUE_ALPHA0):
        j = res_e.names.index(f"alpha0[{i}]")
        body.append(
            [
                f"brake_rep{i + 1}",
                f"{a0:+.4f}",
                f"{res_e.x[j]:+.5f}",
                f"{res_e.stderr[j]:.1e}",
                f"{res_e.x[j] - a0:+.1e}",
            ]
        )
    rep(
        text_table(
            ["experiment", "true alpha0 [rad]", "estimate [rad]", "std. error", "error [rad]"], body
        )
    )

    q_e, q_s = inference.quality(prob_e, res_e.x), inference.quality(prob_s, res_s.x)
    rep()
    rep("  Fit quality per experiment (R² thesis: table 5.5, the thesis's shared-alpha0")
    rep("  fit of its measurements):")
    heads = [
        "experiment",
        "channel",
        "R² thesis",
        "R² per-exp",
        "max|e| per-exp",
        "R² shared",
        "fit % shared",
        "max|e| shared",
    ]
    body = []
    for i in range(4):
        for c in ("theta_l", "alpha"):
            ce, cs = q_e[i]["channels"][c], q_s[i]["channels"][c]
            body.append(
                [
                    f"brake_rep{i + 1}",
                    c,
                    f"{THESIS_T55[c][i]:.4f}",
                    f"{ce['r2']:.4f}",
                    f"{ce['max_abs_error']:.2e}",
                    f"{cs['r2']:.4f}",
                    f"{cs['nrmse_fit']:.2f}",
                    f"{cs['max_abs_error']:.2e}",
                ]
            )
    rep(text_table(heads, body, n_left=2))

    n = prob_e.n_residuals
    k_e, k_s = len(res_e.names), len(res_s.names)
    aic_e, aic_s = aicc(res_e.ssr, n, k_e), aicc(res_s.ssr, n, k_s)
    rep()
    rep("  Per-experiment alpha0 against one shared alpha0 = 0 (all four experiments, theta_l):")
    rep(
        text_table(
            ["model", "k", "SSR [rad²]", "RMSE [rad]", "AICc"],
            [
                [
                    "per-experiment alpha0",
                    str(k_e),
                    f"{res_e.ssr:.4e}",
                    f"{math.sqrt(res_e.ssr / n):.3e}",
                    f"{aic_e:.0f}",
                ],
                [
                    "shared alpha0 = 0",
                    str(k_s),
                    f"{res_s.ssr:.4e}",
                    f"{math.sqrt(res_s.ssr / n):.3e}",
                    f"{aic_s:.0f}",
                ],
            ],
        )
    )
    rep(
        f"  the shared alpha0 leaves {res_s.ssr / res_e.ssr:.3g}x the SSR "
        f"(AICc {aic_s - aic_e:+.0f}):"
    )
    rep("  estimating alpha0 per experiment is the better model, and only it recovers the")
    rep("  brake friction of the data (the shared fit is the thesis's 'averaged experiment').")

    # Validation on brake_val (alpha0 = 0 there).
    rows = []
    fits_val = {}
    for lab, res in (("per-exp", res_e), ("shared", res_s)):
        p = dict(res.params)
        p["alpha0"] = 0.0
        f, sim = score("brake", p, val)
        fits_val[lab] = (f, sim)
        for c in ("theta_l", "alpha"):
            rows.append((f"val ({lab})", c, f[c], THESIS_R2["5.4"]["val"][c]))
    rep()
    rep("  Validation on brake_val (alpha0 = 0):")
    rep(quality_table(rows))

    # Figures.
    f4e = {
        c: channel_fit(c, **_meas_sim(reps[3], q_e[3]["simulation"], c))
        for c in ("theta_l", "alpha")
    }
    f4s = {
        c: channel_fit(c, **_meas_sim(reps[3], q_s[3]["simulation"], c))
        for c in ("theta_l", "alpha")
    }
    plot_fit(
        "brake",
        reps[3],
        q_e[3]["simulation"],
        f4e,
        "§5.3.2 experiment 4, per-experiment alpha0",
        a.out / "step5_4_fit_rep4.png",
    )
    plot_fit(
        "brake",
        reps[3],
        q_s[3]["simulation"],
        f4s,
        "§5.3.2 experiment 4, shared alpha0 = 0 (thesis figs. 5.14-5.15)",
        a.out / "step5_4_fit_rep4_shared_alpha0.png",
    )
    f, sim = fits_val["per-exp"]
    plot_fit(
        "brake",
        val,
        sim,
        f,
        "§5.3.2 validation (per-experiment alpha0 fit, alpha0 = 0)",
        a.out / "step5_4_fit_val.png",
    )
    plot_repeats(reps, q_e, q_s, a.out / "step5_4_repeats.png")
    fig, _ = plots.plot_friction(
        res_e.params,
        discs=("l",),
        reference=pt,
        title="§5.3.2: brake friction, ours (solid) vs table 5.4 P (dashed)",
    )
    save(fig, a.out / "step5_4_friction.png")
    return {
        "per_experiment": res_e,
        "shared": res_s,
        "quality_per_experiment": q_e,
        "quality_shared": q_s,
        "aicc_per_experiment": aic_e,
        "aicc_shared": aic_s,
    }


def _meas_sim(ex, sim, c):
    a0 = sim.params["alpha0"]
    if c == "theta_l":
        return {"y": ex.theta_l, "yhat": sim.theta_l}
    return {"y": ex.theta_l - ex.theta_u + a0, "yhat": sim.alpha}


def plot_repeats(reps, q_e, q_s, path: Path) -> None:
    """The four repeats (thesis fig. 5.13) and the theta_l errors of both models."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(3, 1, figsize=(10, 8), sharex=True)
    for i, ex in enumerate(reps):
        ax[0].plot(ex.t, ex.theta_l, lw=1, label=f"brake_rep{i + 1}")
        ax[1].plot(ex.t, ex.theta_l - q_s[i]["simulation"].theta_l, lw=0.8)
        ax[2].plot(ex.t, ex.theta_l - q_e[i]["simulation"].theta_l, lw=0.8)
    ax[0].set_ylabel("measured theta_l [rad]")
    ax[0].legend(fontsize=8, ncol=4)
    ax[0].set_title(
        "same input, different initial string torsion (thesis fig. 5.13)", fontsize=9, loc="left"
    )
    ax[1].set_ylabel("error [rad]")
    ax[1].set_title(
        "theta_l error, one shared alpha0 = 0 (thesis eq. 5.19)", fontsize=9, loc="left"
    )
    ax[2].set_ylabel("error [rad]")
    ax[2].set_title("theta_l error, alpha0 estimated per experiment", fontsize=9, loc="left")
    ax[2].set_xlabel("t [s]")
    fig.tight_layout()
    save(fig, path)


# ------------------------------------------------------------------------------- main
def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(
        description="Reproduce thesis chapter 5 (tables 5.1-5.5) on the bundled data."
    )
    ap.add_argument(
        "--out",
        type=Path,
        default=DEFAULT_OUT,
        help=f"output folder for figures and report (default {DEFAULT_OUT})",
    )
    ap.add_argument("--force", action="store_true", help="overwrite existing output files")
    ap.add_argument(
        "--quick",
        action="store_true",
        help=f"use only the first {QUICK_SECONDS:g} s of each file (for tests)",
    )
    a = ap.parse_args(argv)
    prepare_out(a.out, FIGURES, a.force)
    quick_s = QUICK_SECONDS if a.quick else None

    rep = Report()
    rep(
        f"rotorbayes {rb.__version__}: thesis chapter 5 on the bundled synthetic example data"
        f"{f' (quick: first {QUICK_SECONDS:g} s of each file)' if a.quick else ''}"
    )
    rep("The files were simulated from the thesis's chapter-5 estimates, so the thesis's P")
    rep("is the truth a good fit must recover; the thesis's R² are for its real measurements.")
    upper = step_upper(rep, a, quick_s)
    coupled = step_coupled(rep, a, quick_s, upper["fit"].params)
    hidden = step_hidden(rep, a, quick_s, coupled["fit"].params)
    brake = step_brake(rep, a, quick_s, upper["fit"].params, coupled["fit"].params)
    rep()
    rep(f"Figures and report written to {a.out}")
    rep(f"Total runtime {rep.elapsed:.1f} s")
    (a.out / "report.txt").write_text("\n".join(rep.lines) + "\n")
    return {
        "out": a.out,
        "upper": upper,
        "coupled": coupled,
        "hidden": hidden,
        "brake": brake,
        "runtime": rep.elapsed,
    }


if __name__ == "__main__":
    main()

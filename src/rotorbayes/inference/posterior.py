"""From chains to results: arviz InferenceData, the credible-interval table, warnings.

The posterior draws are the thinned, burnt-in steps of every walker; arviz's ``chain``
dimension is the *ensemble* (independent runs with their own seeds), ``draw`` the steps
and walkers of one ensemble in step order, so ``arviz.rhat`` compares independent
ensembles (not walkers, which are not independent) and split-R-hat sees a drift in time.
ESS and τ in the table are emcee's (walkers × steps / τ per ensemble, summed), beside
arviz's bulk ESS.
"""

from __future__ import annotations

import math

import numpy as np

from ..util.numformat import fmt_interval_at, mean_sd, sd_place
from . import arviz_compat
from .likelihood import LogPosterior
from .sampling import EnsembleRun, burn_thin

#: Time points per experiment kept in the posterior-predictive group.
PREDICTIVE_POINTS = 1500
#: How the posterior predictive is stored: at the precision its band needs.
PREDICTIVE_DTYPE = np.float64
#: Largest pointwise log-likelihood group kept in memory and in posterior.nc [bytes, as
#: float32]: beyond it, consecutive samples are summed in blocks (long data).
LOGLIK_BYTES = 256 * 2**20


def loglik_block(n_draws: int, n_residuals: int, budget: int | None = None) -> int:
    """Samples per stored log-likelihood value: 1 (pointwise) unless the draws' pointwise
    values would exceed ``budget`` bytes as float32 (default :data:`LOGLIK_BYTES`)."""
    return max(1, math.ceil(4 * n_draws * n_residuals / (budget or LOGLIK_BYTES)))


def draws(logpost: LogPosterior, runs: list[EnsembleRun], max_draws: int = 100):
    """Thinned draws per ensemble in parameter units: ``X (chains, draws, k)``, the
    coordinates ``Z``, log-posterior and the (burn, thin) used."""
    burn, thin = burn_thin(runs)
    Zs, lps = [], []
    for r in runs:
        z = r.chain[burn::thin]  # (steps, walkers, ndim)
        lp = r.log_prob[burn::thin]
        z = z.reshape(-1, z.shape[-1])
        lp = lp.reshape(-1)
        if z.shape[0] > max_draws:
            keep = np.linspace(0, z.shape[0] - 1, max_draws).astype(int)
            z, lp = z[keep], lp[keep]
        Zs.append(z)
        lps.append(lp)
    n = min(z.shape[0] for z in Zs)
    Z = np.stack([z[:n] for z in Zs])
    LP = np.stack([lp[:n] for lp in lps])
    return Z, LP, burn, thin


def inference_data(
    logpost: LogPosterior, runs: list[EnsembleRun], *, max_draws: int = 100, predictive: bool = True
):
    """The posterior container of the installed arviz line (InferenceData on 0.2x, a
    DataTree on 1.x; see :mod:`.arviz_compat`) with posterior, sample_stats, pointwise
    log_likelihood per experiment and channel, observed_data, constant_data (u) and
    posterior_predictive (noise-free simulations)."""
    prob = logpost.problem
    Z, LP, burn, thin = draws(logpost, runs, max_draws)
    C, D, _ = Z.shape
    flat = Z.reshape(C * D, -1)
    X, S, P = logpost.split(flat)
    posterior = {n: X[:, j].reshape(C, D) for j, n in enumerate(prob.names)}
    for j, c in enumerate(logpost.channels):
        if logpost.noise == "sampled":
            posterior[f"sigma_{c}"] = S[:, j].reshape(C, D)
        if logpost.ar1:
            posterior[f"phi_{c}"] = P[:, j].reshape(C, D)
    n_rows = X.shape[0]
    block = loglik_block(n_rows, prob.n_residuals)
    loglik, observed, constant, pp, dims, coords, dims_pp = {}, {}, {}, {}, {}, {}, {}
    cuts = {}  # per segment: the first sample of every stored block
    for (c, a, b), ex_i in zip(logpost.segments, _exp_index(prob), strict=True):
        ex = prob.experiments[ex_i]
        key = f"{c}_exp{ex_i}"
        meas = ex.theta_u if c == "theta_u" else ex.theta_l
        observed[key] = meas
        dims[key] = [f"time_exp{ex_i}"]
        coords[f"time_exp{ex_i}"] = ex.t
        constant[f"u_exp{ex_i}"] = ex.u
        dims[f"u_exp{ex_i}"] = [f"time_exp{ex_i}"]
        cuts[key] = np.arange(0, b - a, block)
        loglik[key] = np.empty((n_rows, cuts[key].size), np.float32)
        if block > 1:
            dims_ll = f"block_exp{ex_i}"
            coords[dims_ll] = ex.t[cuts[key]]
        if predictive:
            # The predictive bands need far fewer time points than the fit: at most
            # PREDICTIVE_POINTS per experiment, on their own time axis.
            step = max(1, int(np.ceil(ex.n / PREDICTIVE_POINTS)))
            # float64: the band is the parameters' effect on the angle, often 1e-6 rad on
            # angles of tens of rad, where float32's spacing is 1.9e-6 to 7.6e-6 rad (stored
            # as float32 the band was that rounding: issue 36).
            pp[key] = np.empty((n_rows, len(range(0, ex.n, step))), PREDICTIVE_DTYPE)
            dims_pp[key] = [f"time_pred_exp{ex_i}"]
            coords[f"time_pred_exp{ex_i}"] = ex.t[::step]
    # The draws are simulated a few at a time (long data: the residuals of every draw at
    # once would not fit in memory); only what is stored is kept.
    chunk = logpost.row_chunk()
    for r0 in range(0, n_rows, chunk):
        r1 = min(n_rows, r0 + chunk)
        R = prob.residuals_batch(X[r0:r1])
        L = logpost.pointwise_of(R, S[r0:r1], P[r0:r1])
        for (c, a, b), ex_i in zip(logpost.segments, _exp_index(prob), strict=True):
            key = f"{c}_exp{ex_i}"
            seg = L[:, a:b]
            loglik[key][r0:r1] = seg if block == 1 else np.add.reduceat(seg, cuts[key], axis=1)
            if predictive:
                ex = prob.experiments[ex_i]
                meas = ex.theta_u if c == "theta_u" else ex.theta_l
                step = max(1, int(np.ceil(ex.n / PREDICTIVE_POINTS)))
                pp[key][r0:r1] = meas[None, ::step] - R[:, a:b][:, ::step] / prob.weights[c]
        del R, L
    for key in list(loglik):
        loglik[key] = loglik[key].reshape(C, D, -1)
        if key in pp:
            pp[key] = pp[key].reshape(C, D, -1)
    dims_loglik = {
        k: ([f"block_exp{k.rsplit('_exp', 1)[1]}"] if block > 1 else v)
        for k, v in dims.items()
        if k in loglik
    }
    acc = np.stack([np.full(D, float(np.mean(r.acceptance))) for r in runs])
    stats = {
        "lp": LP,
        "acceptance_rate": acc,
        "failed_simulations": np.full((C, D), logpost.n_failed),
    }
    groups = {
        "posterior": posterior,
        "sample_stats": stats,
        "log_likelihood": loglik,
        "observed_data": observed,
        "constant_data": constant,
    }
    if pp:
        groups["posterior_predictive"] = pp
    group_dims = {
        "log_likelihood": dims_loglik,
        "observed_data": dims,
        "constant_data": dims,
        "posterior_predictive": dims_pp,
    }
    attrs = {
        "posterior": {
            "burn_in_steps": burn,
            "thin": thin,
            "ensembles": C,
            "walkers_steps_note": "chain = independent ensemble; draw = steps x walkers",
        },
        "log_likelihood": {
            "samples_per_point": block,
            "note": (
                "pointwise: one value per sample"
                if block == 1
                else f"one value per block of {block} consecutive samples (their sum): the "
                f"pointwise values of every sample would exceed {LOGLIK_BYTES // 2**20} MiB; "
                "the block_exp coordinates are each block's first time"
            ),
        },
    }
    return arviz_compat.from_groups(groups, dims=group_dims, coords=coords, attrs=attrs)


def file_bytes(logpost: LogPosterior, n_rows: int) -> int:
    """A generous bound on the size of posterior.nc [bytes] for ``n_rows`` kept draws (all
    ensembles together), before any draw exists: the pointwise log-likelihood (float32;
    in blocks beyond :data:`LOGLIK_BYTES`), the posterior predictive (float64, at most
    :data:`PREDICTIVE_POINTS` + 1 per experiment and channel), the data with their time
    axes, the draws and sample statistics (float64), a quarter on top and 1 MB for the
    file's own structure. Compression makes the file smaller, never larger."""
    prob = logpost.problem
    n_res = prob.n_residuals
    block = loglik_block(n_rows, n_res)
    ll = 4 * n_rows * sum(math.ceil((b - a) / block) for _, a, b in logpost.segments)
    pp = (
        np.dtype(PREDICTIVE_DTYPE).itemsize
        * n_rows
        * sum(min(b - a, PREDICTIVE_POINTS + 1) for _, a, b in logpost.segments)
    )
    data = 16 * n_res + 32 * sum(ex.n for ex in prob.experiments)
    draws_ = 8 * n_rows * (logpost.ndim + 4)
    return int(1.25 * (ll + pp + data + draws_)) + 1_000_000


def _exp_index(prob):
    out = []
    for i, _ in enumerate(prob.experiments):
        out += [i] * len(prob.channels)
    return out


def ess_all_draws(logpost: LogPosterior, runs: list[EnsembleRun]):
    """arviz's bulk ESS and R-hat per sampling coordinate over *every* thinned draw after
    burn-in (``draws`` without the ``--max-draws`` cap; ranks make them the same for θ and
    log θ): the bulk ESS that posterior.nc would show if it kept all draws."""
    Z, _, _, _ = draws(logpost, runs, max_draws=2**62)
    post = {f"c{j}": Z[:, :, j] for j in range(Z.shape[2])}
    summ = arviz_compat.summary(arviz_compat.from_groups({"posterior": post}))
    return (
        np.array([float(summ.loc[f"c{j}", "ess_bulk"]) for j in range(Z.shape[2])]),
        np.array([float(summ.loc[f"c{j}", "r_hat"]) for j in range(Z.shape[2])]),
    )


def speed(runs: list[EnsembleRun]) -> dict:
    """Wall and CPU time of the sampling (summed over ensembles and ``--resume`` sessions),
    log-posterior evaluations (walkers × steps) and the moves; times are nan when the
    checkpoint does not hold them (written before they were stored)."""
    wall = float(sum(r.seconds for r in runs))
    cpu = float(sum(r.cpu_seconds for r in runs))
    evals = int(sum(r.chain.shape[0] * r.chain.shape[1] for r in runs))
    return {
        "seconds": wall,
        "cpu_seconds": cpu,
        "evaluations": evals,
        "moves": runs[0].moves if runs else "",
    }


def summary_table(idata, logpost: LogPosterior, runs: list[EnsembleRun], hdi: float = 0.94):
    """Rows: mean, sd, HDI, bulk ESS (arviz), ESS from τ (emcee), R-hat, τ, unit, and the
    speed: the conservative ESS (the lower of arviz's bulk ESS over every thinned draw and
    the τ-based one) per second and per minute of sampling."""
    prob = logpost.problem
    summ = arviz_compat.summary(idata, hdi_prob=hdi)
    # R-hat, like the conservative ESS, from every thinned draw after burn-in: from the
    # --max-draws kept in posterior.nc (a few hundred) it scattered by +-0.02 about 1 and
    # the demo's chains, at 3300-4000 ESS each, were said not to have converged (1.018,
    # 1.023; 0.992 for another coordinate).
    ess_all, rhat_all = ess_all_draws(logpost, runs)
    sp = speed(runs)
    rows = []
    for j, n in enumerate(logpost.coord_names):
        pname = n[4:] if n.startswith("log_") and n[4:] in prob.names else n
        var = (
            pname
            if pname in summ.index
            else ("sigma_" + n[10:] if n.startswith("log_sigma_") else pname)
        )
        if var not in summ.index:
            continue
        s = summ.loc[var]
        taus = [r.tau[j] for r in runs]
        steps = [r.chain.shape[0] for r in runs]
        walkers = runs[0].chain.shape[1]
        ess_tau = sum(
            st * walkers / t for st, t in zip(steps, taus, strict=True) if np.isfinite(t) and t > 0
        )
        unit = prob.info(var).unit if var in prob.names else "rad" if "sigma" in var else "-"
        rows.append(
            {
                "parameter": var,
                "mean": float(s["mean"]),
                "sd": float(s["sd"]),
                "hdi_low": float(s["hdi_low"]),
                "hdi_high": float(s["hdi_high"]),
                "ess_bulk": float(s["ess_bulk"]),
                "ess_tail": float(s["ess_tail"]),
                "ess_tau": float(ess_tau),
                "r_hat": float(rhat_all[j]),
                "r_hat_kept": float(s["r_hat"]),
                "tau": float(np.nanmax(taus)) if np.any(np.isfinite(taus)) else math.nan,
                "unit": unit,
            }
        )
        ess = min(float(ess_all[j]), float(ess_tau))
        rows[-1].update(
            {
                "ess_bulk_all": float(ess_all[j]),
                "ess": ess,
                "ess_per_s": ess / sp["seconds"] if sp["seconds"] > 0 else math.nan,
                "ess_per_min": 60 * ess / sp["seconds"] if sp["seconds"] > 0 else math.nan,
                "sampling_s": sp["seconds"],
                "cpu_s": sp["cpu_seconds"],
                "evaluations": sp["evaluations"],
                "moves": sp["moves"],
            }
        )
    _add_honesty_columns(rows, logpost)
    return rows


def _add_honesty_columns(rows, logpost: LogPosterior) -> None:
    """Per parameter: the posterior sd against what i.i.d. noise at the floor would give,
    and the shares of the fit's honest variance that are noise, model error shown by the
    residuals, and the input-hold allowance (:mod:`.uncertainty`)."""
    unc = logpost.uncertainty
    if unc is None:
        return
    sh = unc.shares()
    white = dict(zip(unc.names, unc.stderr_white, strict=True))
    for r in rows:
        n = r["parameter"]
        if n not in sh:
            continue
        w = float(white[n])
        r["sd_iid"] = w
        r["sd_over_iid"] = r["sd"] / w if w > 0 and math.isfinite(w) else math.nan
        r["share_noise"] = sh[n]["noise"]
        r["share_model_error"] = sh[n]["model_error"]
        r["share_input_hold"] = sh[n]["input_hold"]


def table_markdown(rows, hdi: float = 0.94, *, assumptions: str | None = None) -> str:
    pct = f"{100 * hdi:.0f} % HDI"
    honest = any("share_noise" in r for r in rows)
    extra_h = " sd / i.i.d. sd | noise / model error / input hold |" if honest else ""
    extra_s = "---|---|" if honest else ""
    head = (
        f"| parameter | mean | sd | {pct} | ESS (arviz bulk) | ESS (walkers × steps / τ) "
        f"| R-hat | τ [steps] | unit |{extra_h}\n|---|---|---|---|---|---|---|---|---|" + extra_s
    )
    lines = [head]
    for r in rows:
        # The sd to two significant digits, the mean and the interval to its last place.
        mean, sd = mean_sd(r["mean"], r["sd"])
        hdi_text = (
            fmt_interval_at(r["hdi_low"], r["hdi_high"], r["sd"])
            if sd_place(r["sd"]) is not None
            else _hdi_fmt(r["hdi_low"], r["hdi_high"])
        )
        line = (
            f"| {r['parameter']} | {mean} | {sd} | "
            f"[{hdi_text}] | {r['ess_bulk']:.0f} | "
            f"{r['ess_tau']:.0f} | {r['r_hat']:.3f} | {r['tau']:.1f} | {r['unit']} |"
        )
        if honest:
            if "share_noise" in r and math.isfinite(r.get("share_noise", math.nan)):
                line += (
                    f" {r['sd_over_iid']:.2g} | {100 * r['share_noise']:.0f} / "
                    f"{100 * r['share_model_error']:.0f} / "
                    f"{100 * r['share_input_hold']:.0f} % |"
                )
            else:
                line += " — | — |"
        lines.append(line)
    lines.append("")
    sp = speed_line(rows)
    if sp:
        lines.append(sp)
        lines.append("")
    lines.append(ESS_NOTE)
    if honest:
        lines.append("")
        lines.append(
            "sd / i.i.d. sd: how much wider the interval is than independent noise at the "
            "encoder floor would make it (rounding is constant while a disc sticks; model "
            "error lasts as long as the motion that causes it). The last column splits the "
            "fit's variance into noise, model error the residuals show, and the allowance "
            "for the input between samples."
        )
        if assumptions:
            lines.append(f"The intervals assume: {assumptions}.")
    return "\n".join(lines)


#: Why the two ESS columns differ (printed under the table).
ESS_NOTE = (
    "The two ESS columns count different things. ESS (arviz bulk) is arviz's rank-normalised "
    "effective sample size of the draws kept in posterior.nc (at most --max-draws per "
    "ensemble, thinned), so it can never exceed their number. ESS (walkers × steps / τ) is "
    "emcee's: every post-burn-in step of every walker divided by the integrated "
    "autocorrelation time τ, summed over the ensembles. The second is the one to compare "
    "with the 50 τ rule; the first says how well posterior.nc alone represents the posterior."
)


def speed_line(rows) -> str:
    """One line on how fast the run mixed: the slowest parameter's conservative ESS per
    second and per minute of sampling, the evaluations, the time and the CPU it had."""
    rows = [r for r in rows if "ess" in r and math.isfinite(r["ess"])]
    if not rows:
        return ""
    slow = min(rows, key=lambda r: r["ess"])
    secs, cpu, n = slow["sampling_s"], slow["cpu_s"], slow["evaluations"]
    head = (
        f"Speed (moves {slow['moves']}): slowest parameter {slow['parameter']}, ESS "
        f"{slow['ess']:.0f} (the lower of arviz's bulk ESS over all post-burn-in draws, "
        "thinned -- not only those kept in posterior.nc, as in the table -- "
        f"{slow['ess_bulk_all']:.0f}, and walkers × steps / τ, {slow['ess_tau']:.0f})"
    )
    if not (math.isfinite(secs) and secs > 0):
        return head + f"; {n} log-posterior evaluations (no sampling time recorded)."
    busy = f", {cpu / secs:.2f} cores busy" if math.isfinite(cpu) else ""
    return (
        head + f": {slow['ess_per_s']:.3g} ESS/s, {slow['ess_per_min']:.0f} ESS/min; "
        f"{n} log-posterior evaluations in {secs:.1f} s of sampling "
        f"({n / secs:.0f}/s{busy})."
    )


def _hdi_fmt(lo: float, hi: float) -> str:
    """Both ends with enough significant digits that they differ where they differ."""
    digits = 6
    if math.isfinite(lo) and math.isfinite(hi) and hi != lo:
        scale = max(abs(lo), abs(hi))
        digits = max(6, int(math.ceil(math.log10(scale / abs(hi - lo)))) + 3) if scale else 6
    return f"{lo:.{digits}g}, {hi:.{digits}g}"


def table_csv(rows) -> str:
    keys = list(rows[0]) if rows else []
    out = [",".join(keys)]
    for r in rows:
        out.append(",".join(str(r[k]) for k in keys))
    return "\n".join(out) + "\n"

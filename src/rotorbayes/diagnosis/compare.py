"""Compare a model with the measurements, and fits with each other.

* :func:`residual_views` — the error of every fitted channel against time, the lower disc's
  velocity (binned, stick and slip apart), the direction of rotation, the string torsion
  and the discs' angles within a revolution; the residual autocorrelation and its
  cross-correlation with the input, with 99 % bands (as MATLAB's ``resid``);
* :func:`compare_fits` — for two or more fits of the same data (e.g. a chain of fits, each
  adding an effect): SSR, RMS as a multiple of the noise floor, NRMSE fit %, max error,
  ΔAICc, ΔBIC on estimation and validation data, and a likelihood-ratio test between
  consecutive fits whose p-value accounts for autocorrelated residuals (the sample size is
  deflated to ``n (1 − ρ) / (1 + ρ)``, ρ the lag-1 autocorrelation of the richer model's
  residual).

Every step is also weighed by its size, with the diagnosis's rule
(:data:`rotorbayes.diagnosis.diagnose.MATERIAL_FRACTION`, ``MATERIAL_FLOOR_UNITS``): the
change of the worst channel's RMS/floor (on validation data when there are some, else on
the estimation data) is *material* when it falls by at least that fraction of its value and
that many floor units.  With tens of thousands of samples an LR test finds any change
"significant"; the step's ``verdict`` says "significant and material", "detectable but
immaterial" (with the numbers), "not significant" or "worse", so a test is never read as
an improvement that is not one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import special

from ..inference.assess import NEAR_FLOOR
from ..inference.least_squares import quality
from ..inference.problem import ValidationTorsion
from ..inference.starts import derivatives
from ..io.measurements import quantisation_floor
from ..util import metrics as _metrics
from .diagnose import LEVEL, MATERIAL_FLOOR_UNITS, MATERIAL_FRACTION, is_material

#: z of the two-sided 99 % band of a white residual's correlations.
Z99 = 2.5758


def correlation(a: np.ndarray, b: np.ndarray, max_lag: int) -> tuple[np.ndarray, np.ndarray]:
    """Normalised cross-correlation ``corr(a_t, b_{t-lag})`` for lags ``-max_lag..max_lag``
    (autocorrelation when ``a is b``)."""
    a = (a - a.mean()) / max(a.std(), 1e-300)
    b = (b - b.mean()) / max(b.std(), 1e-300)
    n = a.size
    lags = np.arange(-max_lag, max_lag + 1)
    out = np.empty(lags.size)
    for i, k in enumerate(lags):
        out[i] = np.dot(a[k:], b[: n - k]) / n if k >= 0 else np.dot(a[: n + k], b[-k:]) / n
    return lags, out


def cross_band(a: np.ndarray, b: np.ndarray) -> float:
    """Half-width of the 99 % band of the sample cross-correlation of two series that are
    unrelated but each autocorrelated (Bartlett: its variance is ``sum_k rho_a(k) rho_b(k)
    / n``, with a triangular taper over lags up to ``n / 4``).  For a white ``a`` this is
    the white band ``Z99 / sqrt(n)``; for a residual correlated by encoder rounding and a
    smooth input it is several times wider, and only a correlation beyond it says that
    the residual depends on the input."""
    n = a.size
    if n < 8:
        return Z99 / math.sqrt(max(n, 1))
    m = 1 << int(math.ceil(math.log2(2 * n)))

    def acf(x):
        x = x - x.mean()
        f = np.fft.rfft(x, m)
        r = np.fft.irfft(f * np.conj(f), m)[:n]
        return r / r[0] if r[0] > 0 else np.zeros(n)

    ra, rb = acf(np.asarray(a, float)), acf(np.asarray(b, float))
    k = n // 4
    w = 1.0 - np.arange(k) / k
    s = ra[0] * rb[0] + 2.0 * float(np.sum(w[1:] * ra[1:k] * rb[1:k]))
    return Z99 * math.sqrt(max(s, 1.0) / n)


def lag1(r: np.ndarray) -> float:
    """Lag-1 autocorrelation of a residual."""
    r = r - r.mean()
    d = float(r @ r)
    return float(r[1:] @ r[:-1]) / d if d > 0 else 0.0


@dataclass
class FitSummary:
    """The measures of one fit on one data set."""

    label: str
    data: str
    k: int
    n: int
    ssr: float
    rms_over_floor: dict[str, float]
    nrmse_fit: dict[str, float]
    max_error: dict[str, float]
    aicc: float
    bic: float
    rho: float
    residual: np.ndarray
    #: The validation runs' alpha0 records (:class:`~rotorbayes.inference.problem.
    #: ValidationTorsion`); empty on estimation data.
    validation_alpha0: list = field(default_factory=list)


def summarise(
    label: str, problem, x, experiments=None, data: str = "estimation", *, validation_alpha0=None
):
    """:class:`FitSummary` of ``problem`` at ``x`` on its data or on ``experiments``
    (validation data: each run with the alpha0 ``validation_alpha0`` holds -- the fit's
    stored records -- or, without it, decided by
    :meth:`~rotorbayes.inference.Problem.validation_params`, as the fit decided it)."""
    rows = quality(problem, x, experiments, validation_alpha0=validation_alpha0)
    res, rms, fit, mx = [], {}, {}, {}
    ssr = n = 0
    for r in rows:
        for c in problem.channels:
            st = r["channels"].get(c)
            if st is None:
                return None
            ssr += st["ssr"]
            n += st["n"]
            rms.setdefault(c, []).append(st["ssr"] / st["n"])
            fit.setdefault(c, []).append(st["nrmse_fit"])
            mx.setdefault(c, []).append(st["max_abs_error"])
        s = r["simulation"]
        ex = (experiments or problem.experiments)[rows.index(r)]
        for c in problem.channels:
            meas = ex.theta_u if c == "theta_u" else ex.theta_l
            sim = s.theta_u if c == "theta_u" else s.theta_l
            res.append(meas - sim)
    k = len(problem.names)
    resid = np.concatenate(res)
    floors, _ = problem.noise_floors()
    return FitSummary(
        label=label,
        data=data,
        k=k,
        n=n,
        ssr=ssr,
        # The problem's noise floors, as fit and diagnose divide by (the encoders' rounding,
        # or the data's own jitter where it is larger): one figure in every command.
        # The worst run per channel, as fit's headline takes it (a run far off is not
        # averaged away by a good one; several validation runs give fit's figure).
        rms_over_floor={
            c: math.sqrt(max(v)) / floors.get(c, quantisation_floor(c)) for c, v in rms.items()
        },
        nrmse_fit={c: float(np.mean(v)) for c, v in fit.items()},
        max_error={c: float(np.max(v)) for c, v in mx.items()},
        aicc=_metrics.aicc(ssr, n, k),
        bic=_metrics.bic(ssr, n, k),
        rho=lag1(resid),
        residual=resid,
        validation_alpha0=[r.get("validation_alpha0") for r in rows]
        if experiments is not None
        else [],
    )


def lr_test(a: FitSummary, b: FitSummary) -> dict:
    """Likelihood-ratio test of fit ``b`` (more parameters) against ``a`` on the same data,
    with the sample size deflated for autocorrelated residuals."""
    df = b.k - a.k
    rho = min(max(b.rho, 0.0), 0.999)
    n_eff = b.n * (1 - rho) / (1 + rho)
    if df <= 0 or b.ssr <= 0 or a.ssr <= 0:
        return {"df": df, "statistic": math.nan, "p_value": math.nan, "n_effective": n_eff}
    lr = n_eff * math.log(a.ssr / b.ssr)
    return {
        "df": df,
        "statistic": lr,
        "p_value": float(special.chdtrc(df, max(lr, 0.0))),  # chi² upper tail
        "n_effective": n_eff,
        "rho": rho,
    }


def weigh_step(step: dict) -> dict:
    """Size and significance of one step, in one word and a sentence (see the module
    docstring): ``{"material": bool, "verdict": str, "words": str}``."""
    est = step.get("estimation") or {}
    val = step.get("validation")
    on = val if val else est
    if not on:
        return {"material": False, "verdict": "not compared", "words": "no common data"}
    before, after = on["worst_rms_over_floor"]
    material = is_material(before, after)
    lr = est.get("lr_test") or {}
    p = lr.get("p_value", math.nan)
    significant = bool(math.isfinite(p) and p < LEVEL)
    where = "validation" if val else "estimation"
    nums = (
        f"worst RMS/floor {before:.4g} -> {after:.4g} ({where}); SSR "
        f"{on['ssr_change_percent']:+.3g} % ({where})"
    )
    if val and est:
        nums += f", {est['ssr_change_percent']:+.3g} % (estimation)"
    if math.isfinite(p):
        nums += f"; LR test p {p:.2g}"
    nested = step.get("nested", True)
    if after > before and not material and on["ssr_change_percent"] > 0:
        verdict = "worse"
    elif not nested:
        # No likelihood-ratio test between fits that are not nested (trial 12: a user effect
        # replaced by another of the same size had been called "significant").
        verdict = "material, not nested" if material else "immaterial, not nested"
    elif material and (significant or not math.isfinite(p)):
        verdict = "significant and material"
    elif material:
        verdict = "material but not significant"
    elif significant:
        verdict = "detectable but immaterial"
    else:
        verdict = "not significant"
    rule = (
        f"material = the worst RMS/floor falls by at least {100 * MATERIAL_FRACTION:g} % "
        f"and {MATERIAL_FLOOR_UNITS:g} floor units"
    )
    words = f"{verdict}: {nums} ({rule})"
    if not nested:
        words += (
            "; the second fit is not the first with parameters added, so no test says "
            "whether the difference is more than chance: compare their AICc and BIC"
        )
    if material and after > NEAR_FLOOR:
        # An added effect absorbs part of any missing one; far from the floor its fall
        # does not show that it is the physics (trial 12: a spurious asymmetric Coulomb
        # level, "significant and material" at 20x -> 17.8x the floor).
        words += (
            f"; after it the error is still {after:.3g}x the floor, where an added "
            "effect can absorb part of a different missing one: judge it again once "
            "the error is near the floor"
        )
    return {"material": material, "verdict": verdict, "words": words}


def compare_fits(fits) -> dict:
    """Before/after table of loaded fits (:class:`rotorbayes.inference.results.LoadedFit`),
    in order."""
    out = {"fits": [], "steps": []}
    prev = {}
    for f in fits:
        label = f.folder.name
        entry = {
            "fit": str(f.folder),
            "label": label,
            "k": len(f.problem.names),
            "effects": list(f.problem.model.effect_names),
        }
        cur = {}
        for data, exps in (("estimation", None), ("validation", f.validation or None)):
            if data == "validation" and exps is None:
                continue
            given = (f.validation_alpha0 or None) if data == "validation" else None
            s = summarise(label, f.problem, f.x, exps, data, validation_alpha0=given)
            if s is None:
                continue
            cur[data] = s
            entry[data] = {
                "ssr": s.ssr,
                "rms_over_floor": s.rms_over_floor,
                "nrmse_fit_percent": s.nrmse_fit,
                "max_error_rad": s.max_error,
                "aicc": s.aicc,
                "bic": s.bic,
                "lag1_autocorrelation": s.rho,
            }
            if data == "validation" and s.validation_alpha0:
                entry["validation_alpha0"] = [
                    t.as_dict() for t in s.validation_alpha0 if t is not None
                ]
        out["fits"].append(entry)
        if prev:
            nested = (
                f.problem.config == prev["config"]
                and set(prev["names"]) <= set(f.problem.names)
                and set(prev["effects"]) <= set(entry["effects"])
                and len(f.problem.names) > len(prev["names"])
            )
            step = {"from": prev["label"], "to": label, "nested": nested}
            for data in ("estimation", "validation"):
                if data in prev["s"] and data in cur:
                    a, b = prev["s"][data], cur[data]
                    step[data] = {
                        "ssr_ratio": b.ssr / a.ssr if a.ssr > 0 else math.nan,
                        "ssr_change_percent": 100 * (b.ssr / a.ssr - 1) if a.ssr > 0 else math.nan,
                        "worst_rms_over_floor": [
                            max(a.rms_over_floor.values()),
                            max(b.rms_over_floor.values()),
                        ],
                        "delta_aicc": b.aicc - a.aicc,
                        "delta_bic": b.bic - a.bic,
                        "lr_test": lr_test(a, b) if data == "estimation" and nested else None,
                    }
            step.update(weigh_step(step))
            out["steps"].append(step)
        prev = {
            "label": label,
            "s": cur,
            "names": list(f.problem.names),
            "effects": entry["effects"],
            "config": f.problem.config,
        }
    return out


def table(doc: dict) -> str:
    """The before/after table in plain text."""
    # The whole label: the folder names the diagnosis suggests ("fit0_motor_deadzone")
    # differ at their ends, and a cut one reads as another fit.
    w = max([18] + [len(f["label"]) for f in doc["fits"]])
    lines = [
        f"{'fit':<{w}} {'data':<10} {'k':>3} {'SSR [rad²]':>11} {'RMS/floor':>22} "
        f"{'fit %':>14} {'max |e|':>9} {'AICc':>11} {'BIC':>11}"
    ]
    for f in doc["fits"]:
        for data in ("estimation", "validation"):
            if data not in f:
                continue
            d = f[data]
            rms = " ".join(f"{c[6:]} {v:.3g}" for c, v in d["rms_over_floor"].items())
            fit = " ".join(f"{v:.2f}" for v in d["nrmse_fit_percent"].values())
            mx = max(d["max_error_rad"].values())
            lines.append(
                f"{f['label']:<{w}} {data:<10} {f['k']:3d} {d['ssr']:11.4g} "
                f"{rms:>22} {fit:>14} {mx:9.3g} {d['aicc']:11.5g} {d['bic']:11.5g}"
            )
    for f in doc["fits"]:
        for t in f.get("validation_alpha0") or []:
            lines.append(f"  {f['label']}: " + ValidationTorsion.from_dict(t).words())
    if doc["steps"]:
        lines.append("")
        lines.append("step by step:")
    for s in doc["steps"]:
        e = s.get("estimation", {})
        v = s.get("validation")
        lr = e.get("lr_test") or {}
        txt = f"  {s['from']} -> {s['to']}: SSR x{e.get('ssr_ratio', math.nan):.3g} (estimation)"
        if v:
            txt += f", x{v['ssr_ratio']:.3g} (validation)"
        txt += (
            f"; ΔAICc {e.get('delta_aicc', math.nan):.4g}, ΔBIC {e.get('delta_bic', math.nan):.4g}"
        )
        if lr and math.isfinite(lr.get("statistic", math.nan)):
            txt += (
                f"; LR test {lr['statistic']:.3g} on {lr['df']} df, p {lr['p_value']:.2g} "
                f"(effective n {lr['n_effective']:.0f} for lag-1 autocorrelation "
                f"{lr['rho']:.3f})"
            )
        lines.append(txt)
        if "words" in s:
            lines.append(f"    -> {s['words']}")
    return "\n".join(lines)


def residual_views(problem, x, i: int = 0) -> dict:
    """Error of each fitted channel of experiment ``i`` against the candidate variables,
    and the correlation analysis (for :func:`rotorbayes.diagnosis.figures.plot_residuals`)."""
    ex = problem.experiments[i]
    sim = problem.simulate(x, i)
    views = {"t": ex.t, "u": ex.u, "channels": {}, "mode_l": sim.mode_l}
    _, wl, _, _ = derivatives(ex.theta_l, ex.dt) if ex.theta_l is not None else (0, None, 0, 0)
    for c in problem.channels:
        meas = ex.theta_u if c == "theta_u" else ex.theta_l
        e = meas - (sim.theta_u if c == "theta_u" else sim.theta_l)
        max_lag = min(200, e.size // 4)
        lags, acf = correlation(e, e, max_lag)
        lags_u, ccf = correlation(e, ex.u, max_lag)
        views["channels"][c] = {
            "error": e,
            "acf": (lags, acf),
            "ccf": (lags_u, ccf),
            "band": Z99 / math.sqrt(e.size),
            "band_u": cross_band(e, ex.u),
        }
    if ex.theta_l is not None:
        views["omega_l"] = wl
        views["alpha"] = ex.theta_l - ex.theta_u + problem.params_for(x, i).get("alpha0", 0.0)
        views["angle_l"] = np.mod(ex.theta_l, 2 * np.pi)
    views["angle_u"] = np.mod(ex.theta_u, 2 * np.pi)
    return views

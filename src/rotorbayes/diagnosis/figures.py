"""Figures of a diagnosis: the residual with each top candidate's predicted correction, and
the missing-torque map against its strongest variables."""

from __future__ import annotations

import numpy as np

from ..figures.plots import envelope, envelope_index, legend_outside, margins_inches, pyplot
from .diagnose import LEVEL
from .torque import ANGLE_VARIABLES, SHORT

_LABEL = {
    "velocity": "velocity [rad/s]",
    "direction": "direction of rotation",
    "torsion": "string torsion α [rad]",
    "torsion_rate": "twist rate dα/dt [rad/s]",
    "input": "input voltage [V]",
    "input_rate": "input rate [V/s]",
    "time": "time [s]",
    "input_history": "filtered inputs − input, fitted [N m]",
}
#: Panel titles of the map's variables (the names in diagnosis.json are terse).
_TITLE = {
    "torsion_rate": "twist rate",
    "input_rate": "input rate",
    "input_history": "input's recent history",
}


_LABEL.update(dict.fromkeys(ANGLE_VARIABLES, "angle within a revolution [rad]"))
_TITLE.update({v: SHORT[v].replace("its angle (", "angle, ").rstrip(")") for v in ANGLE_VARIABLES})

#: Colours of the top candidates' corrections (the residual is grey).

_CAND_COLORS = ("tab:blue", "tab:orange", "tab:green")


def plot_candidates(problem, x, diagnosis, *, top: int = 3):
    """Residual of every fitted channel of the first experiment, and the part of it each
    of the ``top`` ranked effects would remove (its one-step correction)."""
    plt = pyplot()
    ex = problem.experiments[0]
    r = problem.residuals(x)
    chans = list(problem.channels)
    shown = [s for s in diagnosis.ranking if s.correction is not None and not s.equivalent_to_free][
        :top
    ]
    # Below the panels: the time axis, then the legend (one line per curve).
    below = 0.5 + 0.18 * (len(shown) + 1) + 0.2
    fig, axes = plt.subplots(
        len(chans), 1, figsize=(10, 2.8 * len(chans) + below), sharex=True, squeeze=False
    )
    margins_inches(fig, left=1.15, right=0.1, top=0.6, bottom=below, hspace=0.3)
    for k, c in enumerate(chans):
        ax = axes[k, 0]
        seg = slice(k * ex.n, (k + 1) * ex.n)
        # The residual is drawn last, thin and dark, so that a candidate that explains it
        # (a thick curve on the same path) does not hide it.
        ax.plot(
            *envelope(ex.t, r[seg]),
            color="0.15",
            lw=0.6,
            zorder=3,
            label="residual (measured − simulated)",
        )
        # Candidates' corrections can coincide (an exact tie such as initial_torsion and
        # lower_asymmetric_coulomb): wide to narrow lines, own dashes and markers at shifted
        # samples, and a word in the legend when one lies on another.
        every = max(1, ex.n // 10)
        for i, s in enumerate(shown):
            y = -s.correction[seg]
            same = [
                o.effect
                for o in shown[:i]
                if np.allclose(
                    -o.correction[seg], y, rtol=0.02, atol=0.02 * float(np.max(np.abs(y))) + 1e-300
                )
            ]
            # A long record drawn as its envelope, with the marked samples kept.
            marked = np.arange(i * every // 3, ex.n, every)
            keep = envelope_index(y)
            keep = np.arange(ex.n) if keep is None else np.union1d(keep, marked)
            ax.plot(
                ex.t[keep],
                y[keep],
                color=_CAND_COLORS[i % 3],
                lw=(3.2, 2.0, 1.0)[i % 3],
                alpha=0.8,
                ls=("-", "--", ":")[i % 3],
                marker=("o", "s", "^")[i % 3],
                ms=5,
                markevery=list(np.searchsorted(keep, marked)),
                label=f"{s.effect}: its one-step correction (p adj. {s.p_adjusted:.2g}"
                + ("; not significant" if s.p_adjusted >= LEVEL else "")
                + ")"
                + (f" — the same curve as {', '.join(same)}" if same else ""),
            )
        ax.set_ylabel(f"{c} error [rad]")
    axes[-1, 0].set_xlabel("time [s]")
    # One legend for all panels, below them: inside, it would cover the curves.
    axes[-1, 0].legend(
        loc="lower left",
        bbox_to_anchor=(axes[-1, 0].get_position().x0, 0.1 / fig.get_size_inches()[1]),
        bbox_transform=fig.transFigure,
        borderaxespad=0.0,
        ncol=1,
        fontsize=8,
    )
    fig.suptitle(
        "residual and the predicted corrections of the top-ranked effects "
        f"(experiment {ex.name or 0})"
    )
    return fig, axes


def _distinct(ranking):
    """The ranking with one angle variable only (its best harmonic): every harmonic is
    drawn against the same angle within a revolution, so three of them were one picture
    three times, in place of the next variables."""
    out, angle = [], False
    for var, r2 in ranking:
        if var.startswith("angle_"):
            if angle:
                continue
            angle = True
        out.append((var, r2))
    return out


def plot_torque_map(diagnosis, *, top: int = 3):
    """Missing torque of each disc against its ``top`` strongest variables."""
    plt = pyplot()
    maps = diagnosis.maps
    if not maps:
        fig, ax = plt.subplots(figsize=(6, 2))
        ax.text(0.5, 0.5, "no missing-torque map (too few slip samples)", ha="center")
        ax.axis("off")
        return fig, np.array([[ax]])
    fig, axes = plt.subplots(
        len(maps), top, figsize=(4 * top, 3.2 * len(maps) + 0.6), squeeze=False
    )
    # Each panel's own tick and axis labels, and its title above it.
    margins_inches(fig, left=0.85, right=0.1, top=0.62, bottom=0.55, hspace=0.9, wspace=0.9)
    for i, m in enumerate(maps):
        disc = "upper" if m.disc == "u" else "lower"
        shown = _distinct(m.ranking)
        # Where the map holds the disc's own terms, what is left beyond them (what the
        # ranking measured), so the picture shows what the words name.
        y = m.beyond_own
        what_y = (
            f"{disc} missing torque [N m]" if m.own is None else f"{disc}, beyond own terms [N m]"
        )
        for j in range(top):
            ax = axes[i, j]
            if j >= len(shown):
                ax.axis("off")
                continue
            var, r2 = shown[j]
            xv = m.features[var]
            if np.ndim(xv) == 2:
                # Several columns (the filtered inputs): the torque against the part of
                # it their least-squares mix explains.
                X = np.column_stack([np.ones(len(xv)), xv])
                beta, *_ = np.linalg.lstsq(X, y, rcond=None)
                xv = X[:, 1:] @ beta[1:]
            s = m.features.get("direction")
            if s is not None and var != "direction":
                # By direction of rotation: friction changes sign with it (mirrored
                # bands), a load does not (one band).
                for sign, colour, what in (
                    (1.0, "tab:blue", "turning +"),
                    (-1.0, "tab:orange", "turning −"),
                ):
                    k = s == sign
                    if np.any(k):
                        ax.plot(xv[k], y[k], ".", ms=1.5, alpha=0.4, color=colour, label=what)
                if j == 0:
                    ax.legend(fontsize=7, markerscale=5, loc="upper right")
            else:
                ax.plot(xv, y, ".", ms=1.5, alpha=0.4, color="tab:blue")
            ax.axhline(0, color="k", lw=0.6)
            ax.set_xlabel(_LABEL.get(var, var))
            ax.set_ylabel(what_y)
            ax.set_title(f"{disc}: {_TITLE.get(var, var)} (adj. R² {r2:.2f})", fontsize=9)
    fig.suptitle(
        "missing torque (the data's balance minus the fit's own simulation, slip samples) "
        "against candidate variables"
    )
    return fig, axes


def _binned_mean(x, y, n_bins=24):
    edges = np.quantile(x, np.linspace(0, 1, n_bins + 1))
    edges = np.unique(edges)
    idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, len(edges) - 2)
    mids, mean, sd = [], [], []
    for k in range(len(edges) - 1):
        sel = idx == k
        if sel.sum() >= 5:
            mids.append(float(np.mean(x[sel])))
            mean.append(float(np.mean(y[sel])))
            sd.append(float(np.std(y[sel])))
    return np.array(mids), np.array(mean), np.array(sd)


def plot_error_vs_state(views):
    """Error of every fitted channel against the lower disc's velocity (binned, stick
    samples apart), the direction of rotation, the string torsion and the angles."""
    plt = pyplot()
    chans = list(views["channels"])
    lower = "omega_l" in views
    cols = ["velocity", "direction", "torsion", "angle"] if lower else ["angle"]
    fig, axes = plt.subplots(
        len(chans),
        len(cols),
        figsize=(3.6 * len(cols), 2.9 * len(chans) + 0.7),
        squeeze=False,
        constrained_layout=True,
    )
    for i, c in enumerate(chans):
        e = views["channels"][c]["error"]
        for j, col in enumerate(cols):
            ax = axes[i, j]
            if col == "velocity":
                w = views["omega_l"]
                stick = (
                    np.asarray(views["mode_l"]) == 0
                    if views["mode_l"] is not None
                    else np.zeros(w.size, bool)
                )
                m, mu, sd = _binned_mean(w[~stick], e[~stick])
                ax.fill_between(m, mu - sd, mu + sd, color="tab:blue", alpha=0.2, lw=0)
                ax.plot(m, mu, "o-", ms=3, color="tab:blue", label="slip (bin mean ± sd)")
                if stick.any():
                    ax.plot(
                        np.zeros(1),
                        [np.mean(e[stick])],
                        "s",
                        color="tab:red",
                        label=f"stick ({100 * stick.mean():.0f} % of samples)",
                    )
                ax.set_xlabel("lower disc velocity [rad/s]")
                ax.legend(fontsize=7, loc="best")
            elif col == "direction":
                w = views["omega_l"]
                groups = [e[w > 0.02], e[np.abs(w) <= 0.02], e[w < -0.02]]
                ax.boxplot([g if g.size else np.zeros(1) for g in groups], showfliers=False)
                ax.set_xticks([1, 2, 3], ["ω>0", "rest", "ω<0"])
                ax.set_xlabel("lower disc direction")
            elif col == "torsion":
                m, mu, sd = _binned_mean(views["alpha"], e)
                ax.fill_between(m, mu - sd, mu + sd, color="tab:purple", alpha=0.2, lw=0)
                ax.plot(m, mu, "o-", ms=3, color="tab:purple")
                ax.set_xlabel("string torsion α [rad]")
            else:
                ang = views["angle_l"] if lower else views["angle_u"]
                m, mu, sd = _binned_mean(ang, e)
                ax.fill_between(m, mu - sd, mu + sd, color="tab:green", alpha=0.2, lw=0)
                ax.plot(m, mu, "o-", ms=3, color="tab:green")
                ax.set_xlabel(f"{'lower' if lower else 'upper'} disc angle mod 2π [rad]")
            ax.axhline(0, color="k", lw=0.6)
            if j == 0:
                ax.set_ylabel(f"{c} error [rad]")
    fig.suptitle("where the model fails: error against the state (estimation data)")
    return fig, axes


def plot_residual_correlation(views):
    """Residual autocorrelation with the 99 % band of a white residual (MATLAB's
    ``resid``), and cross-correlation with the input with the 99 % band of a residual
    unrelated to it but autocorrelated as it is (:func:`~rotorbayes.diagnosis.compare.
    cross_band`): the white band is far too narrow for a smooth input."""
    plt = pyplot()
    chans = list(views["channels"])
    fig, axes = plt.subplots(
        len(chans), 2, figsize=(10, 2.8 * len(chans) + 0.6), squeeze=False, constrained_layout=True
    )
    for i, c in enumerate(chans):
        v = views["channels"][c]
        for j, (key, title) in enumerate(
            (("acf", "autocorrelation"), ("ccf", "cross-correlation with u"))
        ):
            lags, val = v[key]
            ax = axes[i, j]
            ax.plot(lags, val, color="tab:blue", lw=1)
            if key == "acf":
                ax.axhspan(
                    -v["band"],
                    v["band"],
                    color="0.8",
                    alpha=0.6,
                    label="99 % band of a white residual",
                )
            else:
                bu = v.get("band_u", v["band"])
                ax.axhspan(
                    -bu,
                    bu,
                    color="0.8",
                    alpha=0.6,
                    label="99 % band of a residual unrelated to u\n"
                    "(its own and u's autocorrelation)",
                )
            ax.set_xlabel("lag [samples]")
            ax.set_ylabel(f"{c}")
            ax.set_title(f"{c}: {title}", fontsize=9)
            ax.legend(fontsize=7, loc="upper right")
    fig.suptitle("residual correlation (estimation data)")
    return fig, axes


def plot_chain(doc):
    """RMS over the noise floor of each fit of a comparison, estimation and validation."""
    plt = pyplot()
    fits = doc["fits"]
    labels = [f["label"] for f in fits]
    fig, ax = plt.subplots(figsize=(max(6.5, 1.6 * len(fits) + 3.5), 3.6), constrained_layout=True)
    width = 0.2
    series = []
    for data in ("estimation", "validation"):
        chans = sorted({c for f in fits if data in f for c in f[data]["rms_over_floor"]})
        for c in chans:
            series.append((data, c))
    for k, (data, c) in enumerate(series):
        vals = [f[data]["rms_over_floor"].get(c, np.nan) if data in f else np.nan for f in fits]
        ax.bar(
            np.arange(len(fits)) + (k - (len(series) - 1) / 2) * width,
            vals,
            width,
            label=f"{c}, {data}",
        )
    ax.axhline(1.0, color="k", ls="--", lw=1, label="encoder floor")
    ax.set_yscale("log")
    ax.set_xticks(np.arange(len(fits)), labels, rotation=15)
    ax.set_ylabel("residual RMS / floor")
    legend_outside(ax)  # beside the bars: a tall bar is never covered
    ax.set_title("how the error fell, fit by fit")
    return fig, ax

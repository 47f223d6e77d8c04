"""Figures of a posterior: corner plot (with multistart end points if given), traces,
posterior-predictive bands over the data, and the correlation matrix."""

from __future__ import annotations

import numpy as np

from ..inference import arviz_compat
from .plots import pyplot


def _labels(prob, names):
    out = []
    for n in names:
        try:
            unit = prob.info(n).unit
        except KeyError:
            unit = "rad" if n.startswith("sigma") else "-"
        out.append(f"{n} [{unit}]")
    return out


def corner_bins(n_draws: int) -> int:
    """Histogram bins per axis for ``n_draws`` draws.

    corner's default of 20 bins puts 200 draws into 400 cells of a 2-D histogram: most
    cells hold 0 or 1 draw, the density levels of the contours coincide and the contours
    are noise. About 0.7 √n bins per axis leaves a few draws in each occupied cell.
    """
    return int(np.clip(round(0.7 * np.sqrt(max(n_draws, 1))), 6, 30))


#: Fewer draws than this: points only, no density contours (they would be noise).
MIN_DRAWS_FOR_CONTOURS = 60
#: corner's density levels (0.5, 1, 1.5 and 2 sigma of a 2-D Gaussian).
_LEVELS = 1.0 - np.exp(-0.5 * np.arange(0.5, 2.1, 0.5) ** 2)


def _levels_coincide(H: np.ndarray) -> bool:
    """Whether two of corner's contour levels fall on the same histogram value (corner
    then logs "Too few points to create valid contours" and draws a nudged, ragged line)."""
    flat = np.sort(H.ravel())[::-1]
    cum = np.cumsum(flat)
    if cum[-1] <= 0:
        return True
    cum /= cum[-1]
    V = np.sort([flat[cum <= v][-1] if np.any(cum <= v) else flat[0] for v in _LEVELS])
    return bool(np.any(np.diff(V) == 0))


def contour_settings(X: np.ndarray, ranges) -> tuple[int, float | None, bool]:
    """(bins, smooth, contours) such that every pair's density levels are distinct.

    Tried in order: the bins of :func:`corner_bins` unsmoothed, then smoothed more and
    more, then fewer bins; when no setting gives every pair valid levels, no contours
    (points and the 1-D histograms only).
    """
    from scipy.ndimage import gaussian_filter

    n, k = X.shape
    if n < MIN_DRAWS_FOR_CONTOURS or k < 2:
        return corner_bins(n), None, False
    b = corner_bins(n)
    for bins, smooth in ((b, None), (b, 0.7), (b, 1.2), (max(6, 2 * b // 3), 1.2)):
        ok = True
        for i in range(k):
            for j in range(i):
                H, _, _ = np.histogram2d(X[:, j], X[:, i], bins=bins, range=[ranges[j], ranges[i]])
                if smooth is not None:
                    H = gaussian_filter(H, smooth)
                if _levels_coincide(H):
                    ok = False
                    break
            if not ok:
                break
        if ok:
            return bins, smooth, True
    return b, None, False


def _inner_ticks(lo: float, hi: float):
    """At most three round ticks, none within 12 % of the ends of [lo, hi]."""
    from matplotlib.ticker import FixedLocator, MaxNLocator

    w = hi - lo
    ticks = [t for t in MaxNLocator(4).tick_values(lo, hi) if lo + 0.12 * w <= t <= hi - 0.12 * w]
    return FixedLocator(ticks[:3] if len(ticks) <= 3 else ticks[::2])


def plot_corner(idata, prob, *, overlay: np.ndarray | None = None, truth=None):
    """Corner plot of the free parameters; ``overlay`` (m, k) marks e.g. multistart end
    points.

    Each diagonal panel is titled with the median and sd, with as many digits as the sd
    resolves; tick labels are full numbers (no offset text, which corner would otherwise
    draw over the neighbouring panel's labels).
    """
    import corner
    from matplotlib.ticker import ScalarFormatter

    from ..util.numformat import fmt_value

    names = list(prob.names)
    post = arviz_compat.group(idata, "posterior")
    X = np.column_stack([post[n].values.reshape(-1) for n in names])
    X = X[np.all(np.isfinite(X), axis=1)]
    n = X.shape[0]
    ranges, degenerate = [], False
    for j in range(X.shape[1]):
        lo, hi = float(X[:, j].min()), float(X[:, j].max())
        if not hi - lo > 1e-12 * max(abs(lo), abs(hi), 1e-300):
            # Every draw has the same value (a parameter pinned at a bound, say): give the
            # axis a width so corner can draw it, and draw no contours across it.
            pad = 1e-9 * max(abs(lo), 1e-12)
            lo, hi, degenerate = lo - pad, hi + pad, True
        ranges.append((lo, hi))
    labels = _labels(prob, names)
    bins, smooth, contours = contour_settings(X, ranges)
    contours = contours and not degenerate
    fig = corner.corner(
        X,
        bins=bins,
        smooth=smooth,
        range=ranges,
        labels=labels,
        quantiles=[0.03, 0.5, 0.97],
        show_titles=False,
        plot_contours=contours,
        plot_density=contours,
        max_n_ticks=3,
        label_kwargs={"fontsize": 8},
        labelpad=0.12,
        truths=truth,
    )
    k = len(names)
    axes = np.array(fig.axes).reshape(k, k)
    for i in range(k):
        for j in range(i + 1):
            ax = axes[i, j]
            # No tick near a panel's edge: there its label would meet the next panel's.
            ax.xaxis.set_major_locator(_inner_ticks(*ranges[j]))
            if j < i:
                ax.yaxis.set_major_locator(_inner_ticks(*ranges[i]))
            for axis in (ax.xaxis, ax.yaxis):
                f = axis.get_major_formatter()
                if isinstance(f, ScalarFormatter):
                    f.set_useOffset(False)
                    f.set_scientific(False)
            ax.tick_params(labelsize=7)
        med, sd = float(np.median(X[:, i])), float(np.std(X[:, i]))
        unit = labels[i][len(names[i]) + 1 :]
        axes[i, i].set_title(f"{names[i]} = {fmt_value(med, sd)}\n± {sd:.2g} {unit}", fontsize=8)
    if overlay is not None and len(overlay):
        for i in range(k):
            for j in range(i):
                axes[i, j].plot(
                    overlay[:, j],
                    overlay[:, i],
                    "x",
                    color="tab:red",
                    ms=4,
                    label="multistart end points" if (i, j) == (1, 0) else None,
                )
        axes[1, 0].legend(fontsize=7, loc="best")
    fig.suptitle(
        f"posterior, {n} draws (dashed: 3 %, 50 %, 97 % quantiles; title: median ± sd)", fontsize=10
    )
    return fig


def plot_trace(runs, coord_names):
    """Walker traces per coordinate and ensemble (sampling coordinates)."""
    plt = pyplot()
    k = len(coord_names)
    fig, axes = plt.subplots(
        k, 1, figsize=(10, 1.5 * k + 0.8), sharex=True, squeeze=False, constrained_layout=True
    )
    colors = ["tab:blue", "tab:orange", "tab:green", "tab:red"]
    for j, n in enumerate(coord_names):
        ax = axes[j, 0]
        for e, r in enumerate(runs):
            ax.plot(r.chain[:, :, j], color=colors[e % 4], alpha=0.15, lw=0.5)
        ax.set_ylabel(n, fontsize=8)
        ax.ticklabel_format(axis="y", useOffset=False)
    axes[-1, 0].set_xlabel("step (colour: ensemble)")
    fig.suptitle("walker traces in sampling coordinates (log_ = natural log of the parameter)")
    return fig, axes


#: A band is drawn where it is wider than this many spacings of its stored numbers (each
#: stored end is off by up to half a spacing, so the width is then known to about 10 %).
RESOLVED_SPACINGS = 10


def band_resolution(lo, hi, dtype) -> tuple[np.ndarray, np.ndarray]:
    """The spacing of numbers of ``dtype`` at each point of a band ``[lo, hi]`` [rad], and
    where the band is resolved: wider than :data:`RESOLVED_SPACINGS` spacings (a band of
    exactly known zeros, the encoders at rest, counts as resolved)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    big = np.maximum(np.abs(lo), np.abs(hi))
    spacing = np.spacing(big.astype(dtype)).astype(float)
    resolved = (hi - lo > RESOLVED_SPACINGS * spacing) | (big == 0)
    return spacing, resolved


def plot_predictive(idata, prob, *, i: int = 0):
    """Measured angles with the posterior's noise-free simulations, per channel in three
    panels: the angle with the median simulation; the error of the median; and the 94 %
    predictive band around the median on its own scale.

    The band holds the parameters' uncertainty only (noise-free simulations). It is often
    a thousand times narrower than the angle and much narrower than the encoder noise, so
    drawn over the angle or the error it would be invisible; its own panel shows its width.

    A band is drawn only where it is resolved: wider than :data:`RESOLVED_SPACINGS` times
    the spacing of the stored numbers at the angle (float32's is 1.9e-6 to 7.6e-6 rad at
    16-64 rad; a posterior.nc written before predictions were stored as float64 has such
    bands).  Narrower, the band would show the storage's rounding as parameter
    uncertainty: the panel says it is unresolved there, and how fine the storage is.
    """
    plt = pyplot()
    chans = list(prob.channels)
    ex = prob.experiments[i]
    pp = arviz_compat.group(idata, "posterior_predictive")
    obs = arviz_compat.group(idata, "observed_data")
    fig, axes = plt.subplots(
        3 * len(chans),
        1,
        figsize=(10, 1.9 * 3 * len(chans) + 0.8),
        sharex=True,
        squeeze=False,
        constrained_layout=True,
    )
    for k, c in enumerate(chans):
        key = f"{c}_exp{i}"
        da = pp[key]
        tp = da[da.dims[-1]].values  # the predictive group's own (decimated) time axis
        stored = da.values.reshape(-1, tp.size)
        lo, med, hi = np.percentile(stored.astype(np.float64), [3, 50, 97], axis=0)
        spacing, resolved = band_resolution(lo, hi, stored.dtype)
        full = obs[key].values
        meas = np.interp(tp, ex.t, full)
        width = float(np.max(hi - lo, where=resolved, initial=0.0))
        finest = float(np.max(spacing))
        band_words = (
            f"94 % band (≤ {width:.2g} rad wide: see the third panel)"
            if resolved.any()
            else f"94 % band unresolved (narrower than {RESOLVED_SPACINGS}x the "
            f"storage spacing, ≤ {finest:.2g} rad)"
        )
        ax = axes[3 * k, 0]
        ax.plot(ex.t, full, color="k", lw=1.2, label="measured")
        ax.plot(tp, med, color="tab:orange", lw=1.2, ls="--", label="posterior median")
        ax.fill_between(tp, lo, hi, where=resolved, color="tab:orange", alpha=0.5, label=band_words)
        ax.set_ylabel(f"{c} [rad]")
        ax.legend(loc="upper left", fontsize=8)
        ax2 = axes[3 * k + 1, 0]
        ax2.plot(tp, meas - med, color="0.35", lw=0.7, label="measured − median")
        ax2.axhline(0, color="k", lw=0.5)
        ax2.set_ylabel(f"{c} error [rad]")
        ax2.legend(loc="upper left", fontsize=8)
        ax3 = axes[3 * k + 2, 0]
        if resolved.any():
            gaps = (
                ""
                if resolved.all()
                else (
                    f"; not drawn at {int(np.count_nonzero(~resolved))} of {resolved.size} "
                    f"points, where narrower than {RESOLVED_SPACINGS}x the storage spacing "
                    f"({finest:.2g} rad)"
                )
            )
            ax3.fill_between(
                tp,
                lo - med,
                hi - med,
                where=resolved,
                color="tab:orange",
                alpha=0.6,
                label=f"94 % predictive band − median (parameter uncertainty){gaps}",
            )
        else:
            ax3.text(
                0.5,
                0.5,
                f"94 % predictive band unresolved: narrower than "
                f"{RESOLVED_SPACINGS}x the spacing of the stored predictions "
                f"({np.dtype(stored.dtype).name}: {finest:.2g} rad at these angles), so "
                "not drawn",
                transform=ax3.transAxes,
                ha="center",
                va="center",
                fontsize=9,
            )
        ax3.axhline(0, color="k", lw=0.5)
        ax3.set_ylabel(f"{c} band [rad]")
        if resolved.any():
            ax3.legend(loc="upper left", fontsize=8)
    axes[-1, 0].set_xlabel("time [s]")
    fig.suptitle(
        f"posterior predictive (noise-free simulations of the draws), experiment {ex.name or i}"
    )
    return fig, axes


def plot_correlation(idata, prob):
    """Posterior correlation matrix of the free parameters."""
    plt = pyplot()
    names = list(prob.names)
    post = arviz_compat.group(idata, "posterior")
    X = np.column_stack([post[n].values.reshape(-1) for n in names])
    C = np.corrcoef(X, rowvar=False)
    fig, ax = plt.subplots(
        figsize=(1.0 + 0.6 * len(names), 0.8 + 0.6 * len(names)), constrained_layout=True
    )
    im = ax.imshow(C, vmin=-1, vmax=1, cmap="RdBu_r")
    ax.set_xticks(range(len(names)), names, rotation=60, fontsize=8)
    ax.set_yticks(range(len(names)), names, fontsize=8)
    for i in range(len(names)):
        for j in range(len(names)):
            ax.text(j, i, f"{C[i, j]:.2f}", ha="center", va="center", fontsize=6)
    fig.colorbar(im, ax=ax, label="posterior correlation")
    ax.set_title("posterior correlation")
    return fig, ax


def plot_fisher(F):
    """Eigenvalues of the Fisher information and the eigenvectors' components."""
    plt = pyplot()
    k = len(F.names)
    fig, (a1, a2) = plt.subplots(
        1,
        2,
        figsize=(5 + 0.5 * k, 0.6 * k + 2.2),
        constrained_layout=True,
        gridspec_kw={"width_ratios": [1, 1.6]},
    )
    a1.semilogy(range(k), F.eigenvalues, "o-")
    a1.set_xlabel("direction (sloppiest first)")
    a1.set_ylabel("eigenvalue (1/relative units²)")
    a1.set_title("Fisher information spectrum", fontsize=9)
    im = a2.imshow(F.vectors, cmap="RdBu_r", vmin=-1, vmax=1, aspect="auto")
    a2.set_yticks(
        range(k),
        [f"{'log ' if lg else ''}{n}" for n, lg in zip(F.names, F.log, strict=True)],
        fontsize=8,
    )
    a2.set_xticks(range(k), [f"{i}" for i in range(k)])
    a2.set_xlabel("direction (sloppiest first)")
    a2.set_title("eigenvector components", fontsize=9)
    fig.colorbar(im, ax=a2)
    return fig, (a1, a2)


def plot_profiles(profiles):
    """Profile likelihoods: Δχ² against each profiled parameter, the 95 % line."""
    plt = pyplot()
    n = len(profiles)
    fig, axes = plt.subplots(1, n, figsize=(4 * n, 3.2), squeeze=False, constrained_layout=True)
    for ax, pr in zip(axes[0], profiles, strict=True):
        g = np.array(pr["grid"], float)
        d = np.array([np.nan if v is None else v for v in pr["delta_chi2"]], float)
        ax.plot(g, d, "o-")
        ax.axhline(3.84, color="tab:red", ls="--", lw=1, label="95 % (Δχ² = 3.84)")
        ax.axvline(pr["estimate"], color="k", lw=0.6)
        ax.set_xlabel(f"{pr['parameter']} [{pr['unit']}]")
        # Full numbers on the ticks: an offset text ("1e-6+4.14e-2") would sit on the label.
        ax.ticklabel_format(axis="x", useOffset=False, style="plain")
        ax.xaxis.set_major_locator(_inner_ticks(*ax.get_xlim()))
        ax.tick_params(axis="x", labelrotation=30, labelsize=8)
        ax.set_ylabel("Δχ² (others refitted)")
        ax.legend(fontsize=7)
    fig.suptitle("profile likelihoods")
    return fig, axes

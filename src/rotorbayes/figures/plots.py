"""Figures: simulations, fits (measured vs simulated with the error below), friction
curves, multistart waterfalls and parameter spreads.

Each function imports matplotlib inside (so the package imports without a display),
returns ``(fig, axes)`` and draws nothing on screen; save with ``fig.savefig``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np


def pyplot():
    """matplotlib.pyplot on the file-only Agg backend (unless the user chose another)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


#: Axis names of the measured channels.
CHANNEL_LABELS = {
    "theta_u": r"$\theta_u$",
    "theta_l": r"$\theta_l$",
    "alpha": r"$\alpha$",
}
#: Words for the measured channels (panel titles).
CHANNEL_WORDS = {
    "theta_u": "upper disc angle",
    "theta_l": "lower disc angle",
    "alpha": "string torsion",
}
#: Words for the discs (legends, titles).
DISC_NAMES = {"u": "upper disc", "l": "lower disc"}
#: Colour of the stick shading.
STICK_COLOR = "tab:red"


def unit_of(name: str, units: Mapping[str, str] | None = None) -> str:
    """Unit of a parameter for axis labels: from ``units`` if given there, else from
    :data:`rotorbayes.model.parameters.INFO` (per-experiment names such as ``alpha0[1]``
    take their base name's unit); ``''`` if unknown."""
    from ..model.parameters import INFO

    if units and name in units:
        return units[name]
    base = name.split("[", 1)[0]
    info = INFO.get(name) or INFO.get(base)
    return info.unit if info is not None else ""


def _with_unit(label: str, unit: str) -> str:
    """``'k_m [N m/V]'``; ``'delta_l [-]'`` for dimensionless; no brackets if unknown."""
    return f"{label} [{unit}]" if unit else label


def legend_outside(ax, **kw):
    """Legend to the right of the axes, so it never covers data."""
    return ax.legend(
        loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, fontsize=8, **kw
    )


#: Points drawn per line at most.  A long record is drawn as the minimum and maximum of
#: each of ``(MAX_LINE_POINTS - 2) / 2`` time buckets, and its first and last sample.  The
#: figures are 10 inches wide at 100 dpi and their axes narrower, so a bucket is at most
#: about a third of a pixel column: every pixel column's lowest and highest sample is
#: drawn, the picture is the one of every sample (600 s at 1 kHz drawn whole took hundreds
#: of MB in matplotlib; 30 s drawn as 20 000 points cost a tenth of a second per figure).
MAX_LINE_POINTS = 4_002


def envelope(t, y, max_points: int | None = None):
    """``(t, y)`` thinned to at most ``max_points`` (default :data:`MAX_LINE_POINTS`) points:
    the first and the last sample and each time bucket's minimum and maximum, in time order
    (unchanged when already short)."""
    t, y = np.asarray(t), np.asarray(y)
    idx = envelope_index(y, max_points)
    return (t, y) if idx is None else (t[idx], y[idx])


def envelope_index(y, max_points: int | None = None) -> np.ndarray | None:
    """The samples :func:`envelope` keeps, ascending; ``None`` when it keeps them all."""
    y = np.asarray(y)
    if max_points is None:
        max_points = MAX_LINE_POINTS
    n = y.size
    if n <= max_points:
        return None
    bucket = -(-n // ((max_points - 2) // 2))  # samples per bucket, rounded up
    nb = -(-n // bucket)
    yy = np.empty(nb * bucket, y.dtype)
    yy[:n] = y
    yy[n:] = y[-1]  # the last bucket padded with its own last value
    yy = yy.reshape(nb, bucket)
    base = np.arange(nb) * bucket
    i_lo = base + np.argmin(yy, axis=1)
    i_hi = base + np.argmax(yy, axis=1)
    idx = np.empty(2 * nb + 2, int)
    idx[0], idx[-1] = 0, n - 1
    idx[1:-1:2] = np.minimum(i_lo, i_hi)
    idx[2:-1:2] = np.maximum(i_lo, i_hi)
    return np.minimum(idx, n - 1)


def margins_inches(fig, *, left, right, top, bottom, hspace=0.0, wspace=0.0):
    """Place the subplot grid by margins and gaps given in inches (a fixed layout: the
    figures whose texts are known ahead need no layout engine, which measures every text
    several times per figure)."""
    w, h = fig.get_size_inches()
    gs = fig.axes[0].get_subplotspec().get_gridspec()
    nrows, ncols = gs.get_geometry()
    ah = (h - top - bottom - hspace * (nrows - 1)) / nrows
    aw = (w - left - right - wspace * (ncols - 1)) / ncols
    fig.subplots_adjust(
        left=left / w,
        right=1 - right / w,
        top=1 - top / h,
        bottom=bottom / h,
        hspace=hspace / ah,
        wspace=wspace / aw,
    )


def margins_for_legends(fig, *, left, top, bottom, hspace=0.0, wspace=0.0):
    """:func:`margins_inches` with the right margin as wide as the widest legend of the axes
    (drawn by :func:`legend_outside`), measured: a few texts, not every tick label as a
    layout engine would."""
    r = fig.canvas.get_renderer()
    legends = [ax.get_legend() for ax in fig.axes if ax.get_legend() is not None]
    wide = max((leg.get_window_extent(r).width / fig.dpi for leg in legends), default=0.0)
    # the legend starts 1 % of the axes' width right of them
    w = fig.get_size_inches()[0]
    right = min(wide + 0.02 * (w - left - wide) + 0.15, 0.6 * w)
    margins_inches(
        fig, left=left, right=right, top=top, bottom=bottom, hspace=hspace, wspace=wspace
    )


def _shade_stick(ax, t, mode, color=STICK_COLOR, label="lower disc sticks"):
    """Shade the time intervals in which a disc sticks (``mode == 0``).

    The first span carries ``label``, so a legend drawn on ``ax`` *after* this call
    lists the shading.  Returns the number of spans drawn.
    """
    if mode is None:
        return 0
    t = np.asarray(t, float)
    stick = np.asarray(mode) == 0
    if not stick.any():
        return 0
    edges = np.flatnonzero(np.diff(np.r_[0, stick.astype(int), 0]))
    starts, stops = edges[::2], edges[1::2]
    for k, (a, b) in enumerate(zip(starts, stops, strict=True)):
        ax.axvspan(
            t[a],
            t[min(b, len(t) - 1)],
            color=color,
            alpha=0.12,
            lw=0,
            label=label if k == 0 else None,
        )
    return len(starts)


GLITCH_COLOR = "tab:purple"


def _mark_glitches(ax, glitches) -> int:
    """A dotted vertical line at each glitch, the first of each kind labelled for the
    legend ("3 glitches left out").  Lines, not points: a glitch of a thousand
    counts drawn at its value would squash the trace.  Returns the number drawn."""
    for left_out in (True, False):
        these = [g for g in glitches if bool(g.left_out) == left_out]
        for k, g in enumerate(these):
            n = len(these)
            label = f"{n} glitch{'es' if n > 1 else ''} " + ("left out" if left_out else "kept")
            ax.axvline(
                g.time,
                color=GLITCH_COLOR,
                lw=0.9,
                ls=":" if left_out else "-",
                alpha=0.8,
                label=label if k == 0 else None,
            )
    return len(glitches)


def plot_simulation(sim, *, title: str | None = None):
    """Input, angles, string torsion and velocities of a :class:`~rotorbayes.Simulation`.

    Intervals in which the lower disc sticks (upper disc, in the upper configuration) are
    shaded, and each shaded panel's legend says so.
    """
    plt = pyplot()
    lower = sim.theta_l is not None
    n = 4 if lower else 3
    fig, axes = plt.subplots(
        n, 1, figsize=(10, 2.0 * n + 0.6), sharex=True, constrained_layout=True
    )
    t = sim.t
    axes[0].plot(*envelope(t, sim.u), color="k", lw=1)
    axes[0].set_ylabel("u [V]")
    axes[1].plot(*envelope(t, sim.theta_u), label=r"$\theta_u$ upper disc")
    if lower:
        axes[1].plot(*envelope(t, sim.theta_l), label=r"$\theta_l$ lower disc")
    axes[1].set_ylabel("angle [rad]")
    k = 2
    if lower:
        axes[2].plot(*envelope(t, sim.alpha), color="tab:purple", label=r"$\alpha$ string torsion")
        axes[2].set_ylabel(r"$\alpha$ [rad]")
        k = 3
    axes[k].plot(*envelope(t, sim.omega_u), label=r"$\omega_u$ upper disc")
    if lower:
        axes[k].plot(*envelope(t, sim.omega_l), label=r"$\omega_l$ lower disc")
    axes[k].set_ylabel(r"$\omega$ [rad/s]")
    disc = "lower disc" if lower else "upper disc"
    for ax in axes[1:]:
        _shade_stick(ax, t, sim.mode_l if lower else sim.mode_u, label=f"{disc} sticks")
        legend_outside(ax)
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(title or f"simulation, {sim.config} configuration")
    return fig, axes


def plot_fit(
    t,
    measured: Mapping[str, np.ndarray],
    simulated: Mapping[str, np.ndarray],
    *,
    mode=None,
    title: str = "",
    metrics: Mapping[str, str] | None = None,
    glitches=(),
):
    """Measured vs simulated channels with the error below each (thesis figs. 4.1-5.17).

    Parameters
    ----------
    t : array
        Time [s].
    measured, simulated : mapping channel -> array
        Channels such as ``'theta_l'`` and ``'alpha'`` [rad].
    mode : array, optional
        Lower-disc mode (0 stick) to shade stick intervals (listed in each panel's
        legend as "lower disc sticks").
    metrics : mapping channel -> str, optional
        Text (e.g. ``'R² 0.9996, fit 97.1 %'``) shown in each panel's title.
    glitches : sequence of :class:`~rotorbayes.io.glitches.Glitch`, optional
        The encoder glitches the loader found: each is marked by a dotted vertical line in
        the panels of its channel (and of the torsion, which both angles make), labelled
        "left out" (the curve holds the cubic through its neighbours there) or "kept".

    Legends sit to the right of the panels so they never cover the data.
    """
    plt = pyplot()
    chans = [
        c
        for c in measured
        if c in simulated and measured[c] is not None and simulated[c] is not None
    ]
    if not chans:
        raise ValueError("plot_fit needs at least one channel in both measured and simulated")
    fig, axes = plt.subplots(
        2 * len(chans),
        1,
        figsize=(10, 3.0 * len(chans) + 0.8),
        sharex=True,
        gridspec_kw={"height_ratios": [2, 1] * len(chans)},
    )
    axes = np.atleast_1d(axes)
    # Room for the tick labels and axis labels on the left, the legends on the right, the
    # panel titles between the pairs.
    margins_inches(fig, left=0.95, right=1.85, top=0.62 if title else 0.32, bottom=0.5, hspace=0.34)
    for i, c in enumerate(chans):
        a, b = axes[2 * i], axes[2 * i + 1]
        sym = CHANNEL_LABELS.get(c, c)
        a.plot(*envelope(t, measured[c]), color="k", lw=1.2, label="measured")
        a.plot(*envelope(t, simulated[c]), color="tab:orange", lw=1, ls="--", label="simulated")
        a.set_ylabel(f"{sym} [rad]")
        head = f"{CHANNEL_WORDS[c]} {sym}" if c in CHANNEL_WORDS else c
        if metrics and c in metrics:
            head += f": {metrics[c]}"
        a.set_title(head, fontsize=9, loc="left")
        b.plot(
            *envelope(t, np.asarray(measured[c]) - np.asarray(simulated[c])),
            color="tab:red",
            lw=0.8,
            label="measured − simulated",
        )
        b.axhline(0, color="0.5", lw=0.5)
        b.set_ylabel(f"{sym} error [rad]", fontsize=9)
        for ax in (a, b):
            _shade_stick(ax, t, mode)
            _mark_glitches(ax, [g for g in glitches if c in (g.channel, "alpha")])
            legend_outside(ax)
    axes[-1].set_xlabel("t [s]")
    if title:
        fig.suptitle(title)
    return fig, axes


def _friction_params(params: Mapping[str, float]) -> dict[str, float]:
    """Complete a parameter mapping for :func:`friction_curve` (effects that are off
    at their null value)."""
    from ..model.parameters import INFO

    out = {
        n: INFO[n].null
        for n in (
            "dTc_u",
            "db_u",
            "dTc_l",
            "db_l",
            "Ts_l",
            "ws_l",
            "delta_l",
            "dTs_u",
            "ws_u",
            "delta_u",
        )
    }
    out.update({k: float(v) for k, v in params.items() if isinstance(v, (int, float, np.number))})
    return out


def _break_away(p: Mapping[str, float], disc: str) -> tuple[float, float]:
    """Friction torques that bound sticking: ``(-(Ts - dTc), Ts + dTc)``."""
    if disc == "u":
        ts = p["Tc_u"] + (p.get("dTs_u", 0.0) or 0.0)
        return -(ts - p["dTc_u"]), ts + p["dTc_u"]
    Ts = p["Ts_l"]
    Ts = p["Tc_l"] if Ts is None or not np.isfinite(Ts) else Ts
    return -(Ts - p["dTc_l"]), Ts + p["dTc_l"]


def plot_friction(
    params: Mapping[str, float],
    *,
    discs: Sequence[str] = ("u", "l"),
    omega_max: float = 8.0,
    omega_zoom: float = 0.1,
    shape: str = "exp",
    reference=None,
    label: str = "fitted",
    reference_label: str = "reference",
    title: str = "",
    note: str = "",
):
    """Friction torque against angular velocity (thesis figs. 5.3, 5.12, 5.18).

    One row per disc: the full range ``|omega| <= omega_max`` and a zoom into
    ``|omega| <= omega_zoom`` where the Coulomb and static levels and their asymmetry
    show.  At ``omega = 0`` friction is set-valued; the vertical segment there spans
    the torques a sticking disc can take, ``[-(Ts - dTc), Ts + dTc]``.

    Legend entries name the disc and the set (``label``, e.g. ``"lower disc, fitted"``);
    ``reference`` is an optional second parameter set drawn dashed (``reference_label``).
    The default figure title is ``"<label> friction"``; give ``title`` (e.g. ``"fitted
    friction, coupled configuration"``) to name the configuration as well; ``note``, a
    line under it (what the curves leave out).
    """
    from matplotlib.ticker import MaxNLocator

    from ..model.friction import friction_curve

    plt = pyplot()
    sets = [(label, _friction_params(params), "-", "tab:blue")]
    if reference is not None:
        sets.append((reference_label, _friction_params(reference), "--", "tab:orange"))
    fig, axes = plt.subplots(len(discs), 2, figsize=(10, 3.0 * len(discs) + 0.6), squeeze=False)
    # Room for the tick labels and axis labels of every panel and its title.
    top = 0.85 if note else 0.55
    margins_inches(fig, left=0.8, right=0.1, top=top, bottom=0.55, hspace=0.85, wspace=0.9)
    for i, d in enumerate(discs):
        if d not in DISC_NAMES:
            raise ValueError(f"disc must be 'u' or 'l', not {d!r}")
        name = DISC_NAMES[d]
        for j, wmax in enumerate((omega_max, min(omega_zoom, omega_max))):
            w = np.r_[np.linspace(-wmax, -wmax * 1e-9, 400), np.linspace(wmax * 1e-9, wmax, 400)]
            ax = axes[i, j]
            for what, p, ls, color in sets:
                T = friction_curve(w, p, d, shape=shape)
                neg, pos = w < 0, w > 0
                ax.plot(w[neg], T[neg], ls=ls, color=color, label=f"{name}, {what}")
                ax.plot(w[pos], T[pos], ls=ls, color=color)
                lo, hi = _break_away(p, d)
                ax.plot([0, 0], [lo, hi], ls=ls, color=color, lw=1)
            ax.axhline(0, color="0.6", lw=0.5, zorder=0)
            ax.axvline(0, color="0.6", lw=0.5, zorder=0)
            ax.xaxis.set_major_locator(MaxNLocator(nbins=5, symmetric=True))
            ax.set_xlabel(r"angular velocity $\omega$ [rad/s]")
            ax.set_ylabel("friction torque [N m]")
            ax.set_title(f"{name}, |ω| ≤ {wmax:g} rad/s", fontsize=9)
            ax.legend(fontsize=8, loc="upper left")
    fig.suptitle(title or f"{label} friction")
    if note:
        fig.text(0.5, 1.0 - 0.5 / fig.get_figheight(), note, ha="center", va="top",
                 fontsize=8, color="tab:red", wrap=True)  # fmt: skip
    return fig, axes


def _decade_limits(*values) -> tuple[float, float] | None:
    """Log-axis limits on whole decades around the positive finite ``values`` (at least
    one decade, so tick labels never repeat one rounded number)."""
    v = np.concatenate([np.atleast_1d(np.asarray(x, float)) for x in values if x is not None])
    v = v[np.isfinite(v) & (v > 0)]
    if not v.size:
        return None
    a, b = np.log10(v.min()), np.log10(v.max())
    lo, hi = np.floor(a + 1e-9), np.ceil(b - 1e-9)
    # keep points off the frame (markers would be cut in half)
    lo -= a - lo < 0.15
    hi += hi - b < 0.15
    return float(10.0**lo), float(10.0**hi)


def _cluster_colors(labels, n):
    """Colour per point by cluster label (tab10), or one colour."""
    if labels is None:
        return ["tab:blue"] * n
    import matplotlib

    cmap = matplotlib.colormaps["tab10"]
    return [cmap(int(lab) % 10) for lab in labels]


def plot_waterfall(
    costs: Sequence[float],
    *,
    labels=None,
    n_failed: int = 0,
    noise_floor_ssr: float | None = None,
    near: float = 0.01,
    title: str = "multistart: final SSR of each start, sorted",
):
    """Sorted final SSRs of a multistart (pyPESTO-style waterfall) on a log axis.

    Parameters
    ----------
    costs : sequence of float
        Final SSR [rad²] of each start.  Non-finite values (``inf``/``nan``) are failed
        starts; they are drawn as red crosses on the top frame after the finite ones
        (in a faint red band) and counted in the legend, not dropped.
    labels : sequence of int, optional
        Cluster label of each start (same order as ``costs``); points are coloured by it.
    n_failed : int
        Further failed starts that have no entry in ``costs`` (e.g.
        ``len(MultistartResult.failed)``).
    noise_floor_ssr : float, optional
        The SSR that encoder quantisation alone leaves (sum over residuals of the squared
        weighted floor, see :func:`rotorbayes.io.measurements.quantisation_floor`), drawn as a
        labelled horizontal line.
    near : float
        Relative margin above the best SSR counted as "as good" in the legend (1 %).

    The y data of the plotted points are the absolute SSRs, sorted ascending.
    """
    from matplotlib.transforms import blended_transform_factory

    plt = pyplot()
    c = np.asarray(costs, float).ravel()
    bad = ~np.isfinite(c)
    lab = None if labels is None else np.asarray(labels).ravel()[~bad]
    ok = c[~bad]
    order = np.argsort(ok, kind="stable")
    ok = ok[order]
    lab = None if lab is None else lab[order]
    nfail = int(bad.sum()) + int(n_failed)
    total = ok.size + nfail
    fig, ax = plt.subplots(figsize=(9.5, 4.2))
    x = np.arange(1, ok.size + 1)
    if ok.size:
        best = ok[0]
        good = ok <= best * (1 + near) + 1e-300
        colors = np.array(_cluster_colors(lab, ok.size), dtype=object)
        ax.plot(x, ok, "-", color="0.7", lw=1, zorder=1)
        ax.scatter(
            x[good],
            ok[good],
            c=list(colors[good]),
            s=30,
            zorder=3,
            label=f"{int(good.sum())} of {total} starts within {100 * near:g} % "
            f"of the best ({best:.3g} rad²)",
        )
        if (~good).any():
            ax.scatter(
                x[~good],
                ok[~good],
                c=list(colors[~good]),
                s=18,
                marker="s",
                zorder=3,
                label=f"{int((~good).sum())} other end points",
            )
    if noise_floor_ssr is not None and np.isfinite(noise_floor_ssr) and noise_floor_ssr > 0:
        ax.axhline(
            noise_floor_ssr,
            color="tab:green",
            ls="--",
            lw=1.2,
            label=f"encoder quantisation floor ({noise_floor_ssr:.3g} rad²)",
        )
    if nfail:
        xf = np.arange(ok.size + 1, total + 1)
        tr = blended_transform_factory(ax.transData, ax.transAxes)
        # off the SSR scale: on the top frame, in a faint band of their own
        ax.axvspan(ok.size + 0.5, total + 0.5, color="tab:red", alpha=0.06, lw=0)
        ax.scatter(
            xf,
            np.ones(xf.size),
            transform=tr,
            marker="x",
            color="tab:red",
            s=40,
            zorder=4,
            clip_on=False,
            label=f"{nfail} failed start{'s' if nfail != 1 else ''} (no SSR)",
        )
    ax.set_yscale("log")
    ax.set_ylim(*(_decade_limits(ok, noise_floor_ssr) or (1e-6, 1.0)))
    ax.set_xlim(0.5, max(total, 1) + 0.5)
    ax.xaxis.get_major_locator().set_params(integer=True)
    ax.set_xlabel("start, sorted by final SSR")
    ax.set_ylabel("final SSR [rad²]")
    ax.set_title(title, fontsize=10)
    leg = legend_outside(ax)
    # Room on the right for the legend as wide as its lines are (measured: a few texts, not
    # every tick label as a layout engine would).
    wide = leg.get_window_extent(fig.canvas.get_renderer()).width / fig.dpi
    fig.subplots_adjust(
        left=0.75 / 9.5,
        right=max(1 - (wide + 0.2) / 9.5, 0.4),
        top=1 - 0.35 / 4.2,
        bottom=0.5 / 4.2,
    )
    return fig, ax


def plot_parameter_spread(
    names: Sequence[str],
    values: np.ndarray,
    costs: np.ndarray,
    *,
    reference: Mapping[str, float] | None = None,
    units: Mapping[str, str] | None = None,
    clusters=None,
    noise_floor_ssr: float | None = None,
    title: str = "",
):
    """End points of a multistart: one panel per parameter, its value [unit] against
    the final SSR [rad²] (log axis, shared).

    Parameters
    ----------
    names : sequence of str
        Parameter names (columns of ``values``).
    values : array (n_starts, n_names)
        End points.
    costs : array (n_starts,)
        Final SSR of each end point; non-finite ones are left out (their count is said
        in the legend).
    reference : mapping, optional
        Values drawn as dashed vertical lines (e.g. the truth).
    units : mapping, optional
        Units for names not in :data:`rotorbayes.model.parameters.INFO` (user effects) or
        to override it; ``alpha0[1]`` takes ``alpha0``'s unit by default.
    clusters : sequence of int, optional
        Cluster label of each end point; points are coloured by it.
    noise_floor_ssr : float, optional
        Encoder quantisation floor of the SSR, drawn as a horizontal line.
    """
    from matplotlib.lines import Line2D
    from matplotlib.ticker import MaxNLocator

    plt = pyplot()
    names = list(names)
    values = np.asarray(values, float).reshape(-1, len(names))
    costs = np.asarray(costs, float).ravel()
    fin = np.isfinite(costs)
    k = len(names)
    rows = int(np.ceil(k / 4))
    cols = int(np.ceil(k / rows))
    fig, axes = plt.subplots(
        rows, cols, figsize=(2.9 * cols + 0.4, 2.3 * rows + 1.0), squeeze=False, sharey=True
    )
    # The shared SSR axis labelled on the left; each panel's parameter below it; the legend
    # in one row at the bottom.
    margins_inches(fig, left=0.75, right=0.15, top=0.4, bottom=0.85, hspace=0.6, wspace=0.2)
    colors = np.array(_cluster_colors(clusters, costs.size), dtype=object)
    v, y, col = values[fin], costs[fin], list(colors[fin])
    floor_ok = noise_floor_ssr is not None and np.isfinite(noise_floor_ssr) and noise_floor_ssr > 0
    for i, n in enumerate(names):
        ax = axes[i // cols, i % cols]
        ax.scatter(v[:, i], y, c=col, s=16, zorder=3)
        if reference is not None and n in reference:
            ax.axvline(reference[n], color="tab:red", lw=1, ls="--")
        if floor_ok:
            ax.axhline(noise_floor_ssr, color="tab:green", lw=1, ls=":")
        ax.set_yscale("log")
        ax.margins(x=0.12)
        ax.set_xlabel(_with_unit(n, unit_of(n, units)), fontsize=9)
        ax.xaxis.set_major_locator(MaxNLocator(nbins=3))
        ax.tick_params(labelsize=8)
        if i % cols == 0:
            ax.set_ylabel("final SSR [rad²]", fontsize=9)
    for j in range(k, rows * cols):
        axes[j // cols, j % cols].axis("off")
    lims = _decade_limits(y, noise_floor_ssr if floor_ok else None)
    if lims:
        axes[0, 0].set_ylim(*lims)
    handles = [
        Line2D(
            [],
            [],
            ls="",
            marker="o",
            color="tab:blue" if clusters is None else "0.4",
            label=f"end points ({int(fin.sum())}"
            + (f"; {int((~fin).sum())} failed not shown)" if (~fin).any() else ")")
            + (", colour: cluster" if clusters is not None else ""),
        )
    ]
    if reference is not None and any(n in reference for n in names):
        handles.append(Line2D([], [], color="tab:red", ls="--", label="reference"))
    if floor_ok:
        handles.append(
            Line2D(
                [],
                [],
                color="tab:green",
                ls=":",
                label=f"encoder quantisation floor ({noise_floor_ssr:.3g} rad²)",
            )
        )
    fig.legend(
        handles=handles,
        loc="lower center",
        bbox_to_anchor=(0.5, 0.05 / fig.get_size_inches()[1]),
        ncol=len(handles),
        fontsize=8,
        frameon=False,
    )
    fig.suptitle(title or "multistart end points", fontsize=11)
    return fig, axes


def quantisation_floor_ssr(problem) -> float:
    """SSR [rad²] that encoder quantisation alone would leave in ``problem``'s residuals:
    for each experiment and fitted channel, ``n × (weight × q/√12)²`` (thesis §2.2;
    ``q`` the encoder step).  For :func:`plot_waterfall` and
    :func:`plot_parameter_spread`."""
    from ..io.measurements import quantisation_floor

    return float(
        sum(
            ex.n * (problem.weights[c] * quantisation_floor(c)) ** 2
            for ex in problem.experiments
            for c in problem.channels
        )
    )

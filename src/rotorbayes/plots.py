"""Figures: simulations, fits (measured vs simulated with the error below), friction
curves, multistart waterfalls and parameter spreads.

Each function imports matplotlib inside (so the package imports without a display),
returns ``(fig, axes)`` and draws nothing on screen; save with ``fig.savefig``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np


def _plt():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def _shade_stick(ax, t, mode, color="tab:red", label="lower disc sticks"):
    """Shade the time intervals in which a disc sticks."""
    if mode is None:
        return
    stick = np.asarray(mode) == 0
    if not stick.any():
        return
    edges = np.flatnonzero(np.diff(np.r_[0, stick.astype(int), 0]))
    for k, (a, b) in enumerate(zip(edges[::2], edges[1::2], strict=True)):
        ax.axvspan(
            t[a],
            t[min(b, len(t) - 1)],
            color=color,
            alpha=0.12,
            lw=0,
            label=label if k == 0 else None,
        )


def plot_simulation(sim, *, title: str | None = None):
    """Input, angles, string torsion and velocities of a :class:`~rotorbayes.Simulation`."""
    plt = _plt()
    lower = sim.theta_l is not None
    n = 4 if lower else 3
    fig, axes = plt.subplots(n, 1, figsize=(10, 2.2 * n + 0.5), sharex=True)
    t = sim.t
    axes[0].plot(t, sim.u, color="k", lw=1)
    axes[0].set_ylabel("u [V]")
    axes[1].plot(t, sim.theta_u, label=r"$\theta_u$")
    if lower:
        axes[1].plot(t, sim.theta_l, label=r"$\theta_l$")
    axes[1].set_ylabel("angle [rad]")
    axes[1].legend(loc="best")
    k = 2
    if lower:
        axes[2].plot(t, sim.alpha, color="tab:purple")
        axes[2].set_ylabel(r"$\alpha$ [rad]")
        k = 3
    axes[k].plot(t, sim.omega_u, label=r"$\omega_u$")
    if lower:
        axes[k].plot(t, sim.omega_l, label=r"$\omega_l$")
    axes[k].set_ylabel("velocity [rad/s]")
    for ax in axes[1:]:
        _shade_stick(
            ax,
            t,
            sim.mode_l if lower else sim.mode_u,
            label="lower disc sticks" if lower else "upper disc sticks",
        )
    axes[k].legend(loc="best")
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(title or f"simulation, {sim.config} configuration")
    fig.tight_layout()
    return fig, axes


def plot_fit(
    t,
    measured: Mapping[str, np.ndarray],
    simulated: Mapping[str, np.ndarray],
    *,
    mode=None,
    title: str = "",
    metrics: Mapping[str, str] | None = None,
):
    """Measured vs simulated channels with the error below each (thesis figs. 4.1-5.17).

    Parameters
    ----------
    t : array
        Time [s].
    measured, simulated : mapping channel -> array
        Channels such as ``'theta_l'`` and ``'alpha'`` [rad].
    mode : array, optional
        Lower-disc mode (0 stick) to shade stick intervals.
    metrics : mapping channel -> str, optional
        Text (e.g. ``'R² 0.9996, fit 97.1 %'``) shown in each panel's title.
    """
    plt = _plt()
    chans = [c for c in measured if c in simulated]
    fig, axes = plt.subplots(
        2 * len(chans),
        1,
        figsize=(10, 3.2 * len(chans) + 0.6),
        sharex=True,
        gridspec_kw={"height_ratios": [2, 1] * len(chans)},
    )
    axes = np.atleast_1d(axes)
    for i, c in enumerate(chans):
        a, b = axes[2 * i], axes[2 * i + 1]
        a.plot(t, measured[c], color="k", lw=1.2, label="measured")
        a.plot(t, simulated[c], color="tab:orange", lw=1, ls="--", label="simulated")
        a.set_ylabel(f"{c} [rad]")
        if metrics and c in metrics:
            a.set_title(f"{c}: {metrics[c]}", fontsize=9, loc="left")
        a.legend(loc="best", fontsize=8)
        b.plot(t, measured[c] - simulated[c], color="tab:red", lw=0.8)
        b.axhline(0, color="0.5", lw=0.5)
        b.set_ylabel("error [rad]")
        _shade_stick(a, t, mode)
        _shade_stick(b, t, mode)
    axes[-1].set_xlabel("t [s]")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig, axes


def plot_friction(
    params: Mapping[str, float],
    *,
    discs: Sequence[str] = ("u", "l"),
    omega_max: float = 8.0,
    shape: str = "exp",
    reference=None,
    title: str = "",
):
    """Friction torque against velocity (thesis figs. 5.3, 5.12, 5.18).

    ``reference`` is an optional second parameter set drawn dashed for comparison.
    The inset-free second panel zooms into |omega| < 0.1 rad/s where the static level
    and the Stribeck curve show.
    """
    from .model.friction import friction_curve

    plt = _plt()
    fig, axes = plt.subplots(len(discs), 2, figsize=(10, 3.2 * len(discs)), squeeze=False)
    names = {"u": "upper disc", "l": "lower disc"}
    for i, d in enumerate(discs):
        for j, wmax in enumerate((omega_max, 0.1)):
            w = np.r_[np.linspace(-wmax, -1e-9, 400), np.linspace(1e-9, wmax, 400)]
            ax = axes[i, j]
            ax.plot(w, friction_curve(w, params, d, shape=shape), label="estimated")
            if reference is not None:
                ax.plot(w, friction_curve(w, reference, d, shape=shape), ls="--", label="reference")
            ax.axhline(0, color="0.6", lw=0.5)
            ax.axvline(0, color="0.6", lw=0.5)
            ax.set_xlabel(r"$\omega$ [rad/s]")
            ax.set_ylabel("friction torque [N m]")
            ax.set_title(f"{names[d]}" + (" (zoom)" if j else ""), fontsize=9)
            if reference is not None:
                ax.legend(fontsize=8)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig, axes


def plot_waterfall(costs: Sequence[float], *, labels=None, title: str = "multistart"):
    """Sorted final costs of a multistart (pyPESTO-style waterfall), clusters coloured."""
    plt = _plt()
    c = np.sort(np.asarray(costs, float))
    fig, ax = plt.subplots(figsize=(7, 4))
    best = c[0]
    ax.plot(np.arange(1, c.size + 1), c - best + 1e-12 * max(abs(best), 1.0), "o-", ms=4)
    ax.set_yscale("log")
    ax.set_xlabel("start, sorted by final cost")
    ax.set_ylabel("final cost − best cost")
    ax.set_title(title)
    fig.tight_layout()
    return fig, ax


def plot_parameter_spread(
    names: Sequence[str],
    values: np.ndarray,
    costs: np.ndarray,
    *,
    reference: Mapping[str, float] | None = None,
    title: str = "",
):
    """End points of a multistart, one panel per parameter, coloured by final cost."""
    plt = _plt()
    values = np.asarray(values, float)
    k = len(names)
    cols = min(k, 4)
    rows = int(np.ceil(k / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 2.6 * rows), squeeze=False)
    order = np.argsort(costs)
    rel = np.log10(np.maximum(np.asarray(costs)[order] - np.min(costs), 0) + 1e-16)
    for i, n in enumerate(names):
        ax = axes[i // cols, i % cols]
        sc = ax.scatter(values[order, i], np.arange(len(order)), c=rel, cmap="viridis_r", s=14)
        if reference is not None and n in reference:
            ax.axvline(reference[n], color="tab:red", lw=1, ls="--", label="reference")
        ax.set_title(n, fontsize=9)
        ax.set_yticks([])
    for j in range(k, rows * cols):
        axes[j // cols, j % cols].axis("off")
    fig.colorbar(sc, ax=axes.ravel().tolist(), label="log10(cost − best)")
    if title:
        fig.suptitle(title)
    return fig, axes

"""Figures of a diagnosis: the residual with each top candidate's predicted correction, and
the missing-torque map against its strongest variables."""

from __future__ import annotations

import numpy as np

from ..plots import _plt

_LABEL = {
    "velocity": "velocity [rad/s]", "direction": "direction of rotation",
    "angle_1": "angle within a revolution [rad]", "angle_2": "angle within a revolution [rad]",
    "torsion": "string torsion α [rad]", "input": "input voltage [V]",
    "input_rate": "input rate [V/s]", "time": "time [s]",
}


def plot_candidates(problem, x, diagnosis, *, top: int = 3):
    """Residual of every fitted channel of the first experiment, and the part of it each
    of the ``top`` ranked effects would remove (its one-step correction)."""
    plt = _plt()
    ex = problem.experiments[0]
    r = problem.residuals(x)
    chans = list(problem.channels)
    fig, axes = plt.subplots(len(chans), 1, figsize=(10, 2.8 * len(chans) + 0.6),
                             sharex=True, squeeze=False, constrained_layout=True)
    shown = [s for s in diagnosis.ranking if s.correction is not None and not
             s.equivalent_to_free][:top]
    for k, c in enumerate(chans):
        ax = axes[k, 0]
        seg = slice(k * ex.n, (k + 1) * ex.n)
        ax.plot(ex.t, r[seg], color="0.3", lw=1, label="residual (measured − simulated)")
        for s in shown:
            ax.plot(ex.t, -s.correction[seg], lw=1,
                    label=f"{s.effect} would remove this (p adj. {s.p_adjusted:.2g})")
        ax.set_ylabel(f"{c} error [rad]")
        ax.legend(loc="upper left", fontsize=8)
    axes[-1, 0].set_xlabel("time [s]")
    fig.suptitle("residual and the predicted corrections of the top-ranked effects "
                 f"(experiment {ex.name or 0})")
    return fig, axes


def plot_torque_map(diagnosis, *, top: int = 3):
    """Missing torque of each disc against its ``top`` strongest variables."""
    plt = _plt()
    maps = diagnosis.maps
    if not maps:
        fig, ax = plt.subplots(figsize=(6, 2))
        ax.text(0.5, 0.5, "no missing-torque map (too few slip samples)", ha="center")
        ax.axis("off")
        return fig, np.array([[ax]])
    fig, axes = plt.subplots(len(maps), top, figsize=(4 * top, 3.2 * len(maps) + 0.6),
                             squeeze=False, constrained_layout=True)
    for i, m in enumerate(maps):
        disc = "upper" if m.disc == "u" else "lower"
        for j in range(top):
            ax = axes[i, j]
            if j >= len(m.ranking):
                ax.axis("off")
                continue
            var, r2 = m.ranking[j]
            xv = m.features[var]
            ax.plot(xv, m.torque, ".", ms=1.5, alpha=0.4, color="tab:blue")
            ax.axhline(0, color="k", lw=0.6)
            ax.set_xlabel(_LABEL.get(var, var))
            ax.set_ylabel(f"{disc} disc missing torque [N m]")
            ax.set_title(f"{disc}: {var} (adj. R² {r2:.2f})", fontsize=9)
    fig.suptitle("missing torque (measured angles, slip samples) against candidate variables")
    return fig, axes

"""Helpers shared by the thesis-reproduction scripts: progress report, output folder,
figures and plain-text tables."""

from __future__ import annotations

import time
from pathlib import Path

import rotorbayes as rb
from rotorbayes.figures import plots
from rotorbayes.util.metrics import channel_fit


class Report:
    """Prints progress and results, keeps a copy for ``report.txt``."""

    def __init__(self):
        self.t0 = time.perf_counter()
        self.lines: list[str] = []

    def __call__(self, text: str = "") -> None:
        print(text, flush=True)
        self.lines.append(text)

    def step(self, text: str) -> None:
        self(f"[{time.perf_counter() - self.t0:6.1f} s] {text}")

    def header(self, text: str) -> None:
        self()
        self("=" * 96)
        self(text)
        self("=" * 96)

    @property
    def elapsed(self) -> float:
        return time.perf_counter() - self.t0


def prepare_out(out: Path, names, force: bool) -> None:
    """Create ``out``; refuse (SystemExit) if a file would be overwritten without force."""
    out.mkdir(parents=True, exist_ok=True)
    clash = [n for n in names if (out / n).exists()]
    if clash and not force:
        raise SystemExit(
            f"error: {out} already holds {', '.join(clash[:4])}"
            f"{' ...' if len(clash) > 4 else ''}; pass --force to overwrite or choose "
            "another --out"
        )


def save(fig, path: Path) -> None:
    import matplotlib.pyplot as plt

    fig.savefig(path, dpi=110)
    plt.close(fig)


def text_table(heads, body, n_left: int = 1) -> str:
    """An aligned plain-text table; the first ``n_left`` columns are left-aligned."""
    rows = [list(heads), *[list(r) for r in body]]
    widths = [max(len(r[j]) for r in rows) for j in range(len(heads))]
    lines = []
    for k, r in enumerate(rows):
        cells = [
            c.ljust(w) if j < n_left else c.rjust(w)
            for j, (c, w) in enumerate(zip(r, widths, strict=True))
        ]
        lines.append(("  " + "  ".join(cells)).rstrip())
        if k == 0:
            lines.append("  " + "  ".join("-" * w for w in widths))
    return "\n".join(lines)


def channels_of(config: str):
    return ("theta_u",) if config == "upper" else ("theta_l", "alpha")


def score(config: str, params, ex, effects=()):
    """Simulate ``params`` on ``ex``'s input; channel fits and the simulation."""
    sim = rb.simulate(params, ex.u, dt=ex.dt, config=config, effects=effects)
    fits = {"theta_u": channel_fit("theta_u", ex.theta_u, sim.theta_u)}
    if ex.has_lower:
        fits["theta_l"] = channel_fit("theta_l", ex.theta_l, sim.theta_l)
        a0 = params["alpha0"]
        fits["alpha"] = channel_fit("alpha", ex.theta_l - ex.theta_u + a0, sim.alpha)
    return fits, sim


def plot_fit(config, ex, sim, fits, title, path) -> None:
    chans = channels_of(config)
    measured = {"theta_u": ex.theta_u}
    simulated = {"theta_u": sim.theta_u}
    if ex.has_lower:
        a0 = sim.params["alpha0"]
        measured.update(theta_l=ex.theta_l, alpha=ex.theta_l - ex.theta_u + a0)
        simulated.update(theta_l=sim.theta_l, alpha=sim.alpha)
    metrics = {
        c: f"R² {fits[c].r2:.4f}, fit {fits[c].nrmse_fit:.2f} %, "
        f"max|e| {fits[c].max_abs_error:.2e} rad"
        for c in chans
    }
    fig, _ = plots.plot_fit(
        ex.t,
        {c: measured[c] for c in chans},
        {c: simulated[c] for c in chans},
        mode=sim.mode_l,
        metrics=metrics,
        title=title,
    )
    save(fig, path)

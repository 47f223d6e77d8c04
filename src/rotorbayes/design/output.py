"""The ``next/`` folder of a design: ``u.csv``, ``design.json``, ``design.txt``, a figure.

Written like every result folder (:func:`rotorbayes.io.outputs.output_folder`): built in a
hidden temporary sibling under the folder's lock and moved into place whole; a folder that
holds results is refused unless ``force``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ..io.outputs import output_folder, save_figure_atomic, write_text_atomic
from .core import DesignResult


def _clean(o):
    """JSON-safe: arrays to lists, non-finite numbers to None."""
    if isinstance(o, dict):
        return {str(k): _clean(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_clean(v) for v in o]
    if isinstance(o, np.ndarray):
        return _clean(o.tolist())
    if isinstance(o, (np.floating, float)):
        return float(o) if math.isfinite(float(o)) else None
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, (np.bool_,)):
        return bool(o)
    return o


def input_csv(t: np.ndarray, u: np.ndarray) -> str:
    """``t,u`` CSV text (what ``rotorbayes simulate --input-file`` reads)."""
    rows = ["t,u"] + [f"{ti:.9g},{ui:.9g}" for ti, ui in zip(t, u, strict=True)]
    return "\n".join(rows) + "\n"


def plot_design(res: DesignResult):
    """Input (designed and the estimation input), predicted angles, and what the new
    experiment would see of the target, in floor units.  Returns ``(fig, axes)``."""
    from ..figures.plots import envelope, margins_for_legends, pyplot
    from ..figures.plots import legend_outside as _legend_outside

    plt = pyplot()
    resp = {k: v for k, v in res.responses.items() if k not in ("difference", "channels")}
    diff = res.responses.get("difference")
    n = 1 + (1 if resp else 0) + (1 if diff is not None else 0)
    fig, axes = plt.subplots(n, 1, figsize=(10, 2.2 * n + 0.6), sharex=True, squeeze=False)
    axes = axes[:, 0]
    ax = axes[0]
    if res.baseline is not None:
        ax.plot(
            *envelope(res.t, res.baseline),
            color="0.6",
            lw=0.8,
            ls="--",
            label="standard estimation input",
        )
    ax.plot(
        *envelope(res.t, res.u),
        color="k",
        lw=1.0,
        label="designed input" if res.status != "no input can help" else "input to repeat",
    )
    ax.set_ylabel("u [V]")
    _legend_outside(ax)
    k = 1
    if resp:
        ax = axes[k]
        for label, r in resp.items():
            ax.plot(*envelope(res.t, r["theta_u"]), lw=1.0, label=rf"$\theta_u$ ({label})")
            if r.get("theta_l") is not None:
                ax.plot(
                    *envelope(res.t, r["theta_l"]),
                    lw=1.0,
                    ls="-" if label == "fit" else "--",
                    label=rf"$\theta_l$ ({label})",
                )
        ax.set_ylabel("predicted angle [rad]")
        _legend_outside(ax)
        k += 1
    if diff is not None:
        ax = axes[k]
        what, y = diff
        channels = res.responses.get("channels", ("theta_l",))
        m = len(res.t)
        for j, c in enumerate(channels):  # the prediction is laid out channel by channel
            ax.plot(*envelope(res.t, y[j * m : (j + 1) * m]), lw=0.9, label=c)
        ax.axhline(1.0, color="0.5", lw=0.6, ls=":")
        ax.axhline(-1.0, color="0.5", lw=0.6, ls=":", label="one floor")
        ax.set_ylabel("[floor units]")
        ax.set_title(what, fontsize=9)
        _legend_outside(ax)
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(f"next experiment: {res.target.get('words', '')} — {res.status}", fontsize=10)
    margins_for_legends(fig, left=0.8, top=0.35, bottom=0.5, hspace=0.35)
    return fig, axes


def design_document(res: DesignResult, command: str = "") -> dict:
    """design.json's content: JSON-safe (no arrays, no NaN)."""
    return _clean(
        {
            **res.as_dict(),
            "command": command or None,
            "files": {
                "u.csv": "the input, columns t [s], u [V]",
                "design.txt": "the account in words",
                "design.png": "input, predicted responses, what tells the target",
            },
        }
    )


def write_into(res: DesignResult, folder: Path, *, command: str = "") -> None:
    """Write the files of a design into ``folder`` (each one atomically)."""
    folder = Path(folder)
    doc = design_document(res, command)
    write_text_atomic(folder / "u.csv", input_csv(res.t, res.u))
    write_text_atomic(folder / "design.json", json.dumps(doc, indent=2, allow_nan=False) + "\n")
    write_text_atomic(folder / "design.txt", res.text())
    fig, _ = plot_design(res)
    save_figure_atomic(fig, folder / "design.png", dpi=100)


def write_design(
    res: DesignResult, out: str | Path, *, force: bool = False, command: str = ""
) -> Path:
    """Write the ``next/`` folder (module docstring); returns its path.  A folder that holds
    results is refused (:class:`~rotorbayes.io.outputs.OutputError`) unless ``force``."""
    out = Path(out)
    with output_folder(out, force) as tmp:
        write_into(res, tmp, command=command)
    return out

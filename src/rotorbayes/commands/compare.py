"""``rotorbayes compare``: where the model fails, and how the error fell along a chain."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..io.outputs import output_folder, save_figure_atomic, write_text_atomic
from .common import Outcome, strict_json
from .options import add_changed_data_option, add_trust_option

HELP = (
    "where the model fails (error against the state, residual correlation) and, for "
    "several fits or a chain, how the error fell"
)


def add_arguments(c) -> None:
    c.add_argument("fits", nargs="+", help="fit folders (one: its chain of --p0 parents)")
    c.add_argument("--out", help="output folder (default: FIT/compare/ of the last fit)")
    c.add_argument("--force", action="store_true", help="overwrite results in --out")
    add_trust_option(c)
    add_changed_data_option(c)


def compare(
    fits,
    *,
    out: str | None = None,
    force: bool = False,
    trust_effects: bool = False,
    accept_changed_data: bool = False,
) -> Outcome:
    """Where the model fails (one fit) and how the error fell (several fit folders, or
    the chain of --p0 parents of one): compare.json and figures in ``out`` (default: the
    last fit's compare/ folder, made again each time).  ``Outcome.doc`` is compare.json's
    document."""
    from ..inference.results import load_fit

    fits = [fits] if isinstance(fits, str) else list(fits)
    given = fits
    fits = [
        load_fit(f, trust_effects=trust_effects, accept_changed_data=accept_changed_data)
        for f in given
    ]
    if len(fits) == 1:
        fits = fits[0].chain(trust_effects=trust_effects, accept_changed_data=accept_changed_data)
        if len(fits) > 1:
            print(f"comparing the chain of {len(fits)} fits that led to {given[0]}")
    last = fits[-1]
    folder = Path(out) if out else last.folder / "compare"
    # FIT/compare (the default) is derived from the fits: it is simply made again.
    with output_folder(folder, force or not out, inputs=given) as tmp:
        written, doc = _compare_into(fits, last, tmp)
    print(f"\nwrote {', '.join(written)} in {folder}/")
    return Outcome(folder=Path(out) if out else Path(given[-1]) / "compare", doc=doc)


def _compare_into(fits, last, out: Path) -> tuple[list[str], dict]:
    from ..diagnosis import compare as diagnosis_compare
    from ..diagnosis import figures

    doc = diagnosis_compare.compare_fits(fits)
    print(diagnosis_compare.table(doc))
    views = diagnosis_compare.residual_views(last.problem, last.x)
    for name, (fig, _) in (
        ("error_vs_state.png", figures.plot_error_vs_state(views)),
        ("residual_correlation.png", figures.plot_residual_correlation(views)),
    ):
        save_figure_atomic(fig, out / name)
    written = ["compare.json", "error_vs_state.png", "residual_correlation.png"]
    if len(fits) > 1:
        fig, _ = figures.plot_chain(doc)
        save_figure_atomic(fig, out / "chain.png")
        written.append("chain.png")
    for c, v in views["channels"].items():
        lags, acf = v["acf"]
        outside = float(np.mean(np.abs(acf[lags > 0]) > v["band"]))
        floor_ratio = max(last.doc.get("assessment", {}).get("worst_ratio_to_floor") or 0, 0)
        note = ""
        if outside > 0.05:
            note = (
                " (structured; at the floor this is the encoder's own quantisation error, "
                "which is correlated while a disc moves slowly or rests — see diagnose)"
                if floor_ratio and floor_ratio <= 1.5
                else " (the error is structured, not noise)"
            )
        print(
            f"{c}: {100 * outside:.0f} % of autocorrelation lags 1..{lags.max()} outside the "
            "99 % band of a white residual" + note
        )
        lags_u, ccf = v["ccf"]
        peak = float(np.max(np.abs(ccf)))
        out_u = float(np.mean(np.abs(ccf) > v["band_u"]))
        print(
            f"{c}: cross-correlation with u at most {peak:.3f}, "
            f"{100 * out_u:.0f} % of lags outside +-{v['band_u']:.3f}, the 99 % band of a "
            "residual unrelated to u but as correlated in time"
            + (" (the error depends on the input)" if out_u > 0.05 else "")
        )
    write_text_atomic(out / "compare.json", strict_json(doc))
    return written, doc

"""``report.html``: one self-contained page for a study or a single result folder.

Sections (each a ``<section id=...>``; see :data:`SECTIONS`): the verdict first, then the
data, the fit, compare and residual diagnostics, the diagnosis, the effect chain, the
posterior, identifiability and reproducibility.  A section whose results are not in the
folder is not rendered; the page lists it under "not in this report" with the command that
makes it.  Figures are embedded as base64 data URIs; the CSS is inline; the page loads
nothing (no fonts, scripts or styles from elsewhere).
"""

from __future__ import annotations

import datetime
import math
import sys
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from ..inference.identify import profile_interval
from ..inference.problem import ValidationTorsion
from ..inference.results import file_sha256
from ..io.outputs import write_text_atomic
from ..util.numformat import fmt_interval_at, mean_sd, sd_place
from .discover import FitInfo, Found, ReportError, discover, read_json
from .markup import (
    CSS,
    Raw,
    digits,
    esc,
    figure,
    figure_store,
    kv,
    markdown_table,
    num,
    pre,
    pval,
    table,
    ul,
)

#: Section ids and titles, in page order.
SECTIONS: dict[str, str] = {
    "verdict": "Verdict",
    "data": "Data and configuration",
    "fit": "The fit",
    "compare": "Compare and residual diagnostics",
    "diagnosis": "Diagnosis: missing effects and the missing-torque map",
    "chain": "The effect chain: before and after",
    "posterior": "Posterior",
    "identifiability": "Identifiability",
    "reproducibility": "Reproducibility",
}

#: How to make a section that is absent.
HINTS: dict[str, str] = {
    "data": "no fit here: `rotorbayes fit --model CONFIG DATA --out FIT` makes one",
    "fit": "no fit.json here: `rotorbayes fit --model CONFIG DATA --out FIT` makes one",
    "compare": "no compare.json: `rotorbayes compare FIT` writes FIT/compare/",
    "diagnosis": "no diagnosis.json beside the fit: `rotorbayes diagnose FIT` writes it",
    "chain": "a single fit with no --p0 parent: add an effect with `rotorbayes fit ... --p0 "
    "FIT --add EFFECT --out FIT2`, then `rotorbayes compare FIT2`",
    "posterior": "no posterior: `rotorbayes sample FIT --out POST` samples it",
    "identifiability": "no identify.json: `rotorbayes identify FIT --out ID` writes it",
}

#: Packages whose versions the reproducibility section lists for a single folder.
VERSION_PACKAGES = ("rotorbayes", "numpy", "scipy", "numba", "emcee", "arviz")

CHANNEL_NAMES = {
    "theta_u": "θ_u (upper disc)",
    "theta_l": "θ_l (lower disc)",
    "alpha": "α (string torsion)",
}


@dataclass
class Report:
    """A rendered report: the page, the sections it holds and those that are absent."""

    folder: Path
    html: str
    sections: list[str]
    absent: dict[str, str]
    problems: list[str] = field(default_factory=list)
    path: Path | None = None

    @property
    def size(self) -> int:
        return len(self.html.encode("utf-8"))


# --------------------------------------------------------------------------------- helpers
def _floors():
    from ..inference.assess import AT_FLOOR, NEAR_FLOOR

    return AT_FLOOR, NEAR_FLOOR


def _ratio_cls(r) -> str:
    at, near = _floors()
    if r is None or not isinstance(r, int | float) or math.isnan(r):
        return ""
    return "good" if r <= near else "bad"


def _short_hash(stage: dict) -> str:
    """The first 16 characters of a stage's input hash, escaped for HTML."""
    return esc(str(stage.get("input_hash", ""))[:16])


def _path(p) -> Raw:
    """A file path, breakable after its slashes."""
    return Raw(f'<span class="path">{esc(p).replace("/", "/<wbr>")}</span>')


def _hint(text: str) -> Raw:
    """Plain text with `commands` in backticks shown as code."""
    parts = text.split("`")
    return Raw("".join(f"<code>{esc(p)}</code>" if i % 2 else esc(p) for i, p in enumerate(parts)))


def _unit(u) -> Raw:
    return Raw(f'<span class="nw">{esc(u or "")}</span>')


def _fixed(x, decimals: int) -> Raw:
    """R² and fit % near their maximum: fixed decimals show how close (0.9999963)."""
    if not isinstance(x, int | float) or not math.isfinite(x):
        return num(None)
    return Raw(f"{x:.{decimals}f}".replace("-", "−"))


def _int(x) -> Raw:
    """A large number whose differences matter (AICc, BIC): no exponent."""
    if not isinstance(x, int | float) or not math.isfinite(x):
        return num(None)
    return Raw(f"{x:.0f}".replace("-", "−"))


def _code(text) -> Raw:
    return Raw(f"<code>{esc(text)}</code>")


def _figs(*items) -> Raw:
    """Figures side by side when the page is wide enough."""
    got = [str(figure(p, c)) for p, c in items]
    return Raw(f'<div class="figs">{"".join(got)}</div>') if got else Raw("")


def _warnings(items, title: str = "Warnings") -> Raw:
    items = [w for w in items if str(w).strip()]
    if not items:
        return Raw(f'<p class="note">{esc(title)}: none.</p>')
    return Raw(f'<div class="warn"><strong>{esc(title)} ({len(items)})</strong>{ul(items)}</div>')


def _immaterial(entries) -> Raw:
    """diagnosis.json's `immaterial` list as notes: detectable, but no reason for a verdict."""
    words = [
        e.get("words") or e.get("effect") or str(e) if isinstance(e, dict) else str(e)
        for e in entries
    ]
    return Raw(
        '<span class="note">Detectable but immaterial (a note, not a failure): '
        + esc("; ".join(str(w) for w in words))
        + "</span>"
    )


def _worst(doc: dict) -> float | None:
    return (doc.get("assessment") or {}).get("worst_ratio_to_floor")


def _example_or_path(spec: str) -> Path:
    if spec.startswith("example:"):
        from ..io.examples import example_path

        return Path(example_path(spec))
    return Path(spec)


def _analysis_name(run: dict | None) -> str | None:
    if not run or not run.get("analysis_text"):
        return None
    try:
        return tomllib.loads(run["analysis_text"]).get("analysis", {}).get("name")
    except (tomllib.TOMLDecodeError, AttributeError):
        return None


def _versions_now() -> dict[str, str]:
    import importlib.metadata as md

    out = {"python": sys.version.split()[0]}
    for pkg in VERSION_PACKAGES:
        try:
            out[pkg] = md.version(pkg)
        except md.PackageNotFoundError:
            out[pkg] = "not installed"
    return out


def _added_between(prev: list[str], cur: list[str]) -> list[str]:
    return [e for e in cur if e not in prev]


# -------------------------------------------------------------------------------- sections
def _verdict(f: Found) -> Raw:
    items: list = []
    cls, headline = "", ""
    fit = f.final
    if fit is not None:
        w = _worst(fit.doc)
        at, near = _floors()
        good = w is not None and w <= near
        if fit.diagnosis is not None:
            # The box and the badge below say the same thing: diagnosis.json's `adequate`.
            good = bool(fit.diagnosis.get("adequate"))
        cls = "good" if good else "bad"
        which = (
            f"The final model ({fit.label}, "
            if f.kind == "study"
            else f"The model of {fit.label} ("
        )
        headline = (
            f"{which}{fit.doc.get('config', '?')} configuration"
            f"{', ' + str(len(fit.doc.get('free', []))) + ' free parameters'}) is "
            + ((fit.doc.get("assessment") or {}).get("verdict") or "not assessed")
        )
        if not fit.doc.get("success", True):
            items.append(
                Raw(
                    f"<strong>The least-squares fit did not converge:</strong> "
                    f"{esc(fit.doc.get('message', ''))}"
                )
            )
        d = fit.diagnosis
        if d is not None:
            tag = (
                '<span class="tag good">adequate</span>'
                if d.get("adequate")
                else '<span class="tag bad">inadequate</span>'
            )
            items.append(
                Raw(
                    f"Diagnosis of {esc(fit.label)}: {tag} {esc(d.get('verdict', ''))}"
                    + (
                        f"; most likely missing: <strong>{esc(d['claimed_effect'])}</strong>"
                        if d.get("claimed_effect")
                        else f"; worth trying first: <strong>{esc(d['candidate_effect'])}"
                        "</strong> (material, not significant)"
                        if d.get("candidate_effect")
                        else ""
                    )
                )
            )
            if d.get("immaterial"):
                items.append(_immaterial(d["immaterial"]))
        if len(f.chain) > 1:
            steps = []
            for a, b in zip(f.chain, f.chain[1:], strict=False):
                added = _added_between(a.doc.get("effects", []), b.doc.get("effects", []))
                ra, rb = _worst(a.doc), _worst(b.doc)
                steps.append(
                    f"{a.label} → {b.label} (+{', '.join(added) or 'no effect'}): "
                    f"worst RMS {_plain(ra)}× → {_plain(rb)}× the floor"
                )
            items.append(Raw("The effect chain: " + esc("; ".join(steps)) + "."))
        n_warn = len((fit.doc.get("assessment") or {}).get("warnings") or [])
        if n_warn:
            items.append(Raw(f'{n_warn} warning(s) on the fit: see <a href="#fit">the fit</a>.'))
    elif f.compare is not None:
        doc = read_json(f.compare / "compare.json") or {}
        fits = doc.get("fits", [])
        headline = f"Comparison of {len(fits)} fit(s): " + ", ".join(
            x.get("label", "?") for x in fits
        )
        if fits:
            last = fits[-1]
            rms = (last.get("estimation") or {}).get("rms_over_floor") or {}
            w = max(rms.values()) if rms else None
            cls = _ratio_cls(w)
            items.append(
                Raw(
                    f"Last fit {esc(last.get('label', ''))}: worst RMS "
                    f"{num(w, 3)}× the encoder floor on its estimation data."
                )
            )
    elif f.posterior is not None:
        headline = "Posterior sample"
        warns = _read_lines(f.posterior / "warnings.txt")
        cls = "bad" if warns else "good"
        items.append(f"{len(warns)} convergence warning(s)" if warns else "no convergence warnings")
    elif f.identify is not None:
        doc = read_json(f.identify / "identify.json") or {}
        headline = "Identifiability of " + str(doc.get("fit", "a fit"))
        items += doc.get("words", [])[:1]
    if f.posterior is not None and f.final is not None:
        warns = _read_lines(f.posterior / "warnings.txt")
        items.append(
            Raw(
                f"Posterior: {len(warns)} convergence warning(s); see "
                '<a href="#posterior">the posterior</a>.'
                if warns
                else "Posterior: no convergence warnings."
            )
        )
    if f.identify is not None and f.final is not None:
        doc = read_json(f.identify / "identify.json") or {}
        if doc.get("words"):
            items.append("Identifiability: " + doc["words"][0])
    return Raw(
        f'<div class="verdict {cls}"><p class="headline">{esc(headline)}</p>{ul(items)}</div>'
    )


def _plain(x) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "—"
    if abs(x) >= 1000:
        return f"{x:,.0f}"
    return f"{x:.3g}"


def _read_lines(path: Path) -> list[str]:
    if not path.exists():
        return []
    return [ln.strip() for ln in path.read_text().splitlines() if ln.strip()]


def _owned_data(fit, spec: str, sha: str) -> bool:
    """Whether the report may read a data file a fit.json names: its SHA-256 is the one the
    fit recorded, or (older fits record none) it is a .csv file."""
    recorded = [
        d.get("sha256")
        for key in ("data_files", "validation_files")
        for d in (fit.doc.get(key) or [])
        if isinstance(d, dict) and d.get("path") == spec
    ]
    if recorded:
        return sha in recorded
    return str(spec).lower().endswith(".csv")


def _recorded_read(fit, spec: str):
    """How the fit read the data file ``spec`` (its recorded names and units)."""
    from ..io.rigfiles import ReadSpec

    if fit is None:
        return None
    for key in ("data_files", "validation_files"):
        for d in fit.doc.get(key) or []:
            if isinstance(d, dict) and d.get("path") == spec:
                return ReadSpec.from_record(d.get("read"))
    return None


def _data(f: Found) -> Raw | None:
    from ..io.measurements import load_experiment

    run = f.run or {}
    fit = f.final
    if fit is None and not run.get("data"):
        return None
    hashes: dict[str, str] = {}
    for d in run.get("data") or []:
        try:
            hashes[str(_example_or_path(d["path"]).resolve())] = d.get("sha256", "")
        except Exception:  # noqa: BLE001 - an unknown example name: keep the path
            hashes[str(d.get("path"))] = d.get("sha256", "")
    files: list[tuple[str, str]] = []
    if fit is not None:
        files += [("estimation", p) for p in fit.doc.get("data", [])]
        files += [("validation", p) for p in fit.doc.get("validation", [])]
    else:
        files += [("data", d["path"]) for d in run.get("data", [])]
    config = fit.doc.get("config") if fit else None
    rows, computed = [], False
    for role, spec in files:
        try:
            p = _example_or_path(spec)
        except Exception:  # noqa: BLE001
            p = Path(spec)
        sha = hashes.get(str(p.resolve()))
        name = Raw(f"{esc(p.name)}<br>{_path(p.parent)}")
        if not p.is_file():  # (a device such as /dev/zero is never read)
            rows.append(
                [
                    role,
                    name,
                    Raw('<span class="tag bad">file not found</span>'),
                    None,
                    None,
                    None,
                    "",
                    Raw(f'<span class="hash">{esc(sha or "")}</span>'),
                ]
            )
            continue
        if not sha:
            sha, computed = file_sha256(p), True
        owned = _owned_data(fit, spec, sha) if fit is not None else True
        if not owned:
            # A result folder may come from anyone: read only files the result vouches for.
            rows.append(
                [
                    role,
                    name,
                    "not read: not the file the fit recorded (another SHA-256, or not a .csv file)",
                    None,
                    None,
                    None,
                    "",
                    Raw(f'<span class="hash">{esc(sha)}</span>'),
                ]
            )
            continue
        try:
            ex = load_experiment(p, expect_lower=config != "upper", read=_recorded_read(fit, spec))
        except Exception:  # noqa: BLE001 - said, never quoted (the file may not be ours)
            rows.append(
                [
                    role,
                    name,
                    "unreadable as a measurement file (`rotorbayes fit` names the problem)",
                    None,
                    None,
                    None,
                    "",
                    Raw(f'<span class="hash">{esc(sha)}</span>'),
                ]
            )
            continue
        dur = float(ex.t[-1] - ex.t[0])
        rate = (len(ex.t) - 1) / dur if dur > 0 else math.nan
        channels = "u, θ_u" + (", θ_l" if ex.theta_l is not None else "")
        src = ex.meta.get("source", "")
        rows.append(
            [
                role,
                name,
                len(ex.t),
                dur,
                rate,
                Raw(
                    f'<span class="nw">{num(float(ex.u.min()), 3)} … '
                    f"{num(float(ex.u.max()), 3)}</span>"
                ),
                Raw(esc(channels) + (f'<br><span class="path">{esc(src)}</span>' if src else "")),
                Raw(f'<span class="hash">{esc(sha)}</span>'),
            ]
        )
    out = [
        table(
            [
                "role",
                "file",
                "samples",
                "duration [s]",
                "rate [Hz]",
                "input u [V]",
                "channels / source",
                "SHA-256" + (" (computed now)" if computed else " (run.json)"),
            ],
            rows,
            numeric=(2, 3, 4),
        )
    ]
    if fit is not None:
        d = fit.doc
        pairs = [
            ("configuration", d.get("config")),
            ("effects on", ", ".join(d.get("effects", [])) or "none"),
            ("effects added", ", ".join(d.get("added_effects", [])) or "none"),
            ("fitted channels", ", ".join(CHANNEL_NAMES.get(c, c) for c in d.get("channels", []))),
            (
                "channel weights",
                ", ".join(f"{k} = {v:g}" for k, v in (d.get("weights") or {}).items()) or "1 each",
            ),
            ("upper disc prescribed", bool(d.get("prescribed_upper"))),
            ("free parameters", ", ".join(d.get("free", []))),
        ]
        name = _analysis_name(f.run)
        if name:
            pairs.insert(0, ("study", name))
        out.append(Raw("<h3>Configuration of the final model</h3>"))
        out.append(kv(pairs))
    return Raw("".join(out))


def _fit(f: Found) -> Raw | None:
    fit = f.final
    if fit is None:
        return None
    d = fit.doc
    a = d.get("assessment") or {}
    cls = _ratio_cls(a.get("worst_ratio_to_floor"))
    where = "" if str(fit.folder).rstrip("/") == fit.label else f" ({_path(fit.folder)})"
    out = [
        Raw(
            f"<p>Fit {_code(fit.label)}{where}: "
            f'<strong class="{cls}">{esc(a.get("verdict", "not assessed"))}</strong></p>'
        )
    ]
    out.append(
        kv(
            [
                (
                    "converged",
                    Raw(
                        ("yes" if d.get("success") else '<span class="tag bad">no</span>')
                        + f" — {esc(d.get('message', ''))}"
                    ),
                ),
                ("start", d.get("start")),
                ("evaluations", d.get("nfev")),
                ("time [s]", d.get("seconds")),
                ("SSR [rad²]", d.get("ssr")),
                ("residuals", d.get("n_residuals")),
            ]
        )
    )
    chan = a.get("channels") or []
    if chan:
        out.append(
            Raw(
                "<h3>Residual RMS against the encoder floor</h3>"
                '<p class="note">The floor is the RMS of the encoders\' quantisation '
                "(resolution/√12); a model that explains the data ends near 1×.</p>"
            )
        )
        out.append(
            table(
                [
                    "data",
                    "experiment",
                    "channel",
                    "RMS [rad]",
                    "floor [rad]",
                    "RMS / floor",
                    "fitted",
                ],
                [
                    [
                        c.get("data"),
                        c.get("experiment"),
                        CHANNEL_NAMES.get(c.get("channel"), c.get("channel")),
                        c.get("rms"),
                        c.get("floor"),
                        c.get("ratio"),
                        "yes" if c.get("fitted") else "no (derived)",
                    ]
                    for c in chan
                ],
                numeric=(3, 4, 5),
                row_cls=lambda k: (
                    _ratio_cls(chan[k].get("ratio")) if chan[k].get("fitted") else "muted"
                ),
            )
        )
    torsion = _validation_torsion(d)
    if torsion:
        out.append(
            Raw(
                '<p class="note">Each validation run starts with its own string '
                "torsion: " + "; ".join(esc(w) for w in torsion) + ".</p>"
            )
        )
    q = d.get("quality") or {}
    qrows = []
    for data in ("estimation", "validation"):
        for r in q.get(data) or []:
            for c, st in (r.get("channels") or {}).items():
                qrows.append(
                    [
                        data,
                        r.get("experiment"),
                        CHANNEL_NAMES.get(c, c),
                        _fixed(st.get("r2"), 7),
                        _fixed(st.get("nrmse_fit"), 4),
                        st.get("max_abs_error"),
                        st.get("rmse"),
                    ]
                )
    if qrows:
        out.append(Raw("<h3>Fit quality</h3>"))
        out.append(
            table(
                [
                    "data",
                    "experiment",
                    "channel",
                    "R²",
                    "NRMSE fit [%]",
                    "max |error| [rad]",
                    "RMSE [rad]",
                ],
                qrows,
                numeric=(3, 4, 5, 6),
            )
        )
    out.append(Raw("<h3>Parameters</h3>"))
    params = d.get("parameters") or {}
    free = [n for n in d.get("free", []) if n in params] + [
        n for n, p in params.items() if p.get("status") == "free" and n not in d.get("free", [])
    ]
    fixed = [n for n, p in params.items() if p.get("status") == "fixed"]
    off = [n for n, p in params.items() if p.get("status") == "off"]

    def prow(n):
        p = params[n]
        v, se = p.get("value"), p.get("stderr")
        rel = (
            abs(se / v) * 100
            if isinstance(se, int | float) and isinstance(v, int | float) and v
            else None
        )
        if p.get("status") == "free":
            status = Raw(
                '<span class="tag bad">free, AT BOUND</span>'
                if p.get("at_bound")
                else '<span class="tag bad">free, NEAR A BOUND</span>'
                if p.get("near_bound")
                else "free"
            )
            src = "estimated" + (
                f"; start {_plain(p.get('start'))} from {p['start_source']}"
                if p.get("start_source")
                else ""
            )
        else:
            status, src = p.get("status"), p.get("source") or ""
        if (
            isinstance(v, int | float)
            and isinstance(se, int | float)
            and se > 0
            and math.isfinite(se)
        ):
            # The error to two significant digits, the value to the same decimal place.
            v, se = (digits(t) for t in mean_sd(float(v), float(se)))
        return [Raw(f"<code>{esc(n)}</code>"), v, se, rel, _unit(p.get("unit")), status, src]

    heads = ["parameter", "value", "std. error", "rel. s.e. [%]", "unit", "status", "source"]
    out.append(
        table(
            heads,
            [prow(n) for n in free + fixed],
            numeric=(1, 2, 3),
            row_cls=lambda k: "" if k < len(free) else "muted",
            caption=f"{len(free)} free, {len(fixed)} fixed (grey); standard errors "
            "as fit.json gives them: honest (rounding simulated as it is, model "
            "error from the residuals' time blocks, an allowance for the input "
            "between samples; docs/uncertainty.md)",
        )
    )
    if off:
        out.append(
            Raw(f"<details><summary>{len(off)} parameters of effects that are off</summary>")
        )
        out.append(table(heads, [prow(n) for n in off], numeric=(1, 2, 3)))
        out.append(Raw("</details>"))
    out.append(_warnings(a.get("warnings") or [], "Warnings on the fit"))
    figs = [
        (
            fit.folder / p.name,
            f"{'estimation' if '_est_' in p.name else 'validation'} data "
            f"{p.stem.rsplit('_', 1)[-1]}: measured and simulated angles",
        )
        for p in sorted(fit.folder.glob("fit_est_*.png")) + sorted(fit.folder.glob("fit_val_*.png"))
    ]
    figs.append((fit.folder / "friction.png", "fitted friction curves"))
    out.append(_figs(*figs))
    return Raw("".join(out))


def _validation_torsion(doc: dict) -> list[str]:
    """How each validation run's alpha0 was chosen, in words (fit.json's
    ``validation_alpha0``; nothing for an older fit or a damaged record)."""
    out = []
    for t in doc.get("validation_alpha0") or []:
        if isinstance(t, dict):
            try:
                out.append(ValidationTorsion.from_dict(t).words())
            except ValueError:
                continue
    return out


def _compare(f: Found) -> Raw | None:
    if f.compare is None:
        return None
    doc = read_json(f.compare / "compare.json") or {}
    fits = doc.get("fits", [])
    out = [
        Raw(
            f"<p>From {_path(f.compare)}: the error of the last fit "
            f"({esc(fits[-1]['label']) if fits else '?'}) against the state, and its "
            "autocorrelation (99 % band of a white residual) and cross-correlation with "
            "the input (99 % band of a residual unrelated to the input but correlated in "
            "time as this one is). Far above the floor, a structured error (many lags "
            "outside the band, a pattern against velocity or angle) means missing "
            "physics; at the floor the autocorrelation is the encoder's own rounding.</p>"
        )
    ]
    if len(fits) == 1:
        out.append(_fits_table(fits))
    out.append(
        _figs(
            (f.compare / "error_vs_state.png", "error against the state"),
            (f.compare / "residual_correlation.png", "residual correlation"),
        )
    )
    return Raw("".join(out))


def _fits_table(fits: list[dict]) -> Raw:
    """The measures of each fit on its estimation and validation data (compare.json)."""
    rows: list[list] = []
    group: list[int] = []  # the fit of each row (alternate shading per fit)
    prev: list[str] | None = None
    for gi, x in enumerate(fits):
        added = _added_between(prev, x.get("effects", [])) if prev is not None else []
        prev = x.get("effects", [])
        first = True
        for data in ("estimation", "validation"):
            m = x.get(data)
            if not m:
                continue
            rms = m.get("rms_over_floor") or {}
            fitp = m.get("nrmse_fit_percent") or {}
            mx = m.get("max_error_rad") or {}
            group.append(gi)
            rows.append(
                [
                    Raw(f"<code>{esc(x.get('label'))}</code>") if first else "",
                    _effects_added(added) if first else "",
                    data[:3] + ".",
                    x.get("k"),
                    num(m.get("ssr"), 4),
                    Raw(" / ".join(str(num(v, 3)) for v in rms.values())),
                    Raw(" / ".join(str(_fixed(v, 4)) for v in fitp.values())),
                    num(max(mx.values()), 3) if mx else None,
                    _int(m.get("aicc")),
                    _int(m.get("bic")),
                    _fixed(m.get("lag1_autocorrelation"), 4),
                ]
            )
            first = False
    chans = next((list((x.get("estimation") or {}).get("rms_over_floor", {})) for x in fits), [])
    ch = " / ".join(c.replace("theta_", "θ_") for c in chans)
    shade = ["grp-a" if g % 2 == 0 else "grp-b" for g in group]
    return table(
        [
            "fit",
            "effect added",
            "data",
            "k",
            "SSR [rad²]",
            f"RMS/floor ({ch})",
            f"fit % ({ch})",
            "max |e| [rad]",
            "AICc",
            "BIC",
            "lag-1 ρ",
        ],
        rows,
        numeric=(3, 4, 5, 6, 7, 8, 9, 10),
        cls="grouped",
        row_cls=lambda k: shade[k],
    )


def _effects_added(added: list[str]) -> Raw:
    """Effect names that may wrap after their underscores (a narrow column)."""
    if not added:
        return Raw("")
    return Raw("+" + ", ".join(esc(e).replace("_", "_<wbr>") for e in added))


def _diagnosis(f: Found) -> Raw | None:
    diag = [x for x in f.chain if x.diagnosis is not None]
    if not diag:
        return None
    out = []
    last = diag[-1]
    failing = next((x for x in diag[:-1] if not x.diagnosis.get("adequate")), None)
    if failing is not None:
        # Where the model fails is seen on the first inadequate fit, not on the final one.
        out.append(Raw(f"<h3>Where the first model fails: {esc(failing.label)}</h3>"))
        out.append(_one_diagnosis(failing, open_=False))
        out.append(
            _figs(
                *(
                    (failing.folder / n, c)
                    for n, c in (
                        (
                            "fit_est_0.png",
                            f"{failing.label}: measured and simulated angles, and the error",
                        ),
                        ("friction.png", f"{failing.label}: fitted friction"),
                    )
                    if (failing.folder / n).exists()
                )
            )
        )
    out.append(_one_diagnosis(last, open_=True))
    earlier = [x for x in diag[:-1] if x is not failing]
    if earlier:
        out.append(Raw(f"<h3>Other diagnoses along the chain ({len(earlier)})</h3>"))
        for x in earlier:
            d = x.diagnosis
            what = (
                f"claimed {d['claimed_effect']}"
                if d.get("claimed_effect")
                else "adequate"
                if d.get("adequate")
                else f"no effect claimed; worth trying {d['candidate_effect']}"
                if d.get("candidate_effect")
                else "no effect claimed"
            )
            out.append(
                Raw(
                    f"<details><summary>{esc(x.label)}: {esc(what)} — "
                    f"{esc(d.get('verdict', ''))}</summary>"
                )
            )
            out.append(_one_diagnosis(x, open_=False))
            out.append(Raw("</details>"))
    return Raw("".join(out))


def _one_diagnosis(x: FitInfo, open_: bool) -> Raw:
    d = x.diagnosis or {}
    tag = (
        '<span class="tag good">adequate</span>'
        if d.get("adequate")
        else '<span class="tag bad">inadequate</span>'
    )
    out = [
        Raw(f"<h3>Diagnosis of {esc(x.label)}</h3>" if open_ else ""),
        Raw(f"<p>{tag} {esc(d.get('verdict', ''))}</p>"),
    ]
    if d.get("evidence"):
        out.append(ul(d["evidence"]))
    if d.get("immaterial"):
        out += [Raw("<p>"), _immaterial(d["immaterial"]), Raw("</p>")]
    if d.get("advice"):
        out.append(Raw(f'<div class="advice">{esc(d["advice"])}</div>'))
    rank = d.get("ranking") or []
    if rank:
        rows = []
        for s in rank:
            est = ", ".join(
                f"{n} ≈ {_plain(v['one_step_estimate'])}\u00a0"
                + str(v.get("unit", "")).replace(" ", "\u00a0")
                if isinstance(v.get("one_step_estimate"), int | float)
                else f"{n}: —"
                for n, v in (s.get("parameters") or {}).items()
            )
            pred = s.get("predicted_rms_over_floor") or {}
            notes = []
            if s.get("equivalent_to_free_parameters"):
                notes.append("equivalent to the free parameters: cannot be told apart")
            elif s.get("indistinguishable_from"):
                notes.append(
                    "indistinguishable here from " + ", ".join(s["indistinguishable_from"])
                )
            rows.append(
                [
                    Raw(
                        f"<code>{esc(s.get('effect'))}</code><br>"
                        f'<span class="small">{esc(s.get("physics", ""))}</span>'
                    ),
                    pval(s.get("p_value")),
                    pval(s.get("p_adjusted")),
                    Raw(" / ".join(str(num(v, 3)) for v in pred.values())),
                    est,
                    "; ".join(notes),
                ]
            )
        level = d.get("level")
        chans = " / ".join(
            c.replace("theta_", "θ_") for c in (rank[0].get("predicted_rms_over_floor") or {})
        )
        out.append(
            table(
                [
                    "effect (off)",
                    "p",
                    "p adj. (Holm)",
                    f"predicted RMS/floor ({chans})",
                    "one-step estimate",
                    "notes",
                ],
                rows,
                numeric=(1, 2, 3),
                row_cls=lambda k: (
                    "good" if (rank[k].get("effect") == d.get("claimed_effect")) else ""
                ),
                caption="catalogue effects that are off, best first: score tests at "
                f"the fit (level {level if level is not None else '?'}); the claimed "
                "effect is highlighted",
            )
        )
    tr = d.get("trials") or {}
    if tr.get("trials"):
        # Far from the floor: one refit per candidate decided (diagnosis.trials).
        out.append(Raw("<h4>Trial refits</h4>"))
        rows = []
        for t in tr["trials"]:
            vals = ", ".join(f"{n} = {_plain(v)}" for n, v in (t.get("values") or {}).items())
            notes = []
            if t.get("on_bound"):
                notes.append("on a bound: " + ", ".join(t["on_bound"]))
            if t.get("validation_rms_over_floor") is not None:
                v = float(t["validation_rms_over_floor"])
                notes.append(f"validation {v:.3g}x" if v < 1000 else f"validation {v:.0f}x")
            if t.get("failed"):
                notes.append("failed: " + str(t["failed"]))
            rows.append(
                [
                    Raw(f"<code>{esc(t.get('effect'))}</code>"),
                    num(t.get("rms_over_floor"), 3),
                    vals,
                    "; ".join(notes),
                ]
            )
        out.append(
            table(
                ["effect added", "worst RMS/floor after the refit", "its parameters", "notes"],
                rows,
                numeric=(1,),
                row_cls=lambda k: (
                    "good" if (tr["trials"][k].get("effect") == tr.get("choice")) else ""
                ),
                caption="each candidate refitted, its parameters searched (from "
                f"{tr.get('before', math.nan):.3g}x the floor); the choice is "
                "highlighted",
            )
        )
        if tr.get("words"):
            out.append(Raw(f'<div class="advice">{esc(tr["words"])}</div>'))
    maps = d.get("missing_torque") or []
    if maps:
        out.append(Raw("<h4>Missing-torque map</h4>"))
        rows = []
        for m in maps:
            top = m.get("ranking") or []
            rows.append(
                [
                    {"l": "lower", "u": "upper"}.get(m.get("disc"), m.get("disc")),
                    m.get("rms_N_m"),
                    m.get("noise_rms_N_m"),
                    ", ".join(
                        f"{r['variable']} {r['adjusted_r2']:.2f}"
                        for r in top[:4]
                        if r.get("adjusted_r2") is not None
                    ),
                    m.get("words", ""),
                ]
            )
        out.append(
            table(
                [
                    "disc",
                    "missing torque RMS [N m]",
                    "noise RMS [N m]",
                    "explained by (adjusted R²)",
                    "in words",
                ],
                rows,
                numeric=(1, 2),
            )
        )
    out.append(
        _figs(
            (x.folder / "diagnosis_candidates.png", "candidate effects"),
            (x.folder / "missing_torque.png", "missing-torque map"),
        )
    )
    return Raw("".join(out))


def _chain(f: Found) -> Raw | None:
    doc = read_json(f.compare / "compare.json") if f.compare is not None else None
    out = []
    if doc and len(doc.get("fits", [])) > 1:
        out.append(
            Raw(
                f"<p>From {_path(f.compare / 'compare.json')}: each fit adds one effect "
                "to the one before (its --p0 parent).</p>"
            )
        )
        out.append(_fits_table(doc["fits"]))
        srows = []
        for s in doc.get("steps", []):
            e, v = s.get("estimation") or {}, s.get("validation") or {}
            lr = e.get("lr_test") or {}
            srows.append(
                [
                    f"{s.get('from')} → {s.get('to')}",
                    e.get("ssr_ratio"),
                    v.get("ssr_ratio"),
                    e.get("delta_aicc"),
                    e.get("delta_bic"),
                    lr.get("statistic"),
                    lr.get("df"),
                    pval(lr.get("p_value")),
                    lr.get("n_effective"),
                    lr.get("rho"),
                ]
            )
        if srows:
            out.append(Raw("<h3>Step by step</h3>"))
            out.append(
                table(
                    [
                        "step",
                        "SSR ratio (est.)",
                        "SSR ratio (val.)",
                        "ΔAICc",
                        "ΔBIC",
                        "LR statistic",
                        "df",
                        "p",
                        "effective n",
                        "lag-1 ρ",
                    ],
                    srows,
                    numeric=tuple(range(1, 10)),
                    caption="the likelihood-ratio test deflates the sample size for "
                    "the residual's autocorrelation (n (1 − ρ)/(1 + ρ))",
                )
            )
        out.append(_figs((f.compare / "chain.png", "the error along the chain")))
    elif len(f.chain) > 1:
        out.append(
            Raw(
                "<p>No compare.json: the table is built from the fits' own "
                "fit.json files, following their --p0 parent links.</p>"
            )
        )
        rows, prev = [], None
        for x in f.chain:
            d = x.doc
            added = (
                _added_between(prev.doc.get("effects", []), d.get("effects", [])) if prev else []
            )
            chans = (d.get("assessment") or {}).get("channels") or []
            est = [c["ratio"] for c in chans if c.get("fitted") and c.get("data") == "estimation"]
            val = [c["ratio"] for c in chans if c.get("fitted") and c.get("data") == "validation"]
            ssr_ratio = (
                d.get("ssr") / prev.doc["ssr"]
                if prev and prev.doc.get("ssr") and d.get("ssr") is not None
                else None
            )
            rows.append(
                [
                    Raw(f"<code>{esc(x.label)}</code>"),
                    ", ".join(added),
                    len(d.get("free", [])),
                    d.get("ssr"),
                    ssr_ratio,
                    max(est) if est else None,
                    max(val) if val else None,
                ]
            )
            prev = x
        out.append(
            table(
                [
                    "fit",
                    "effect added",
                    "k",
                    "SSR [rad²]",
                    "SSR ratio",
                    "worst RMS/floor (est.)",
                    "worst RMS/floor (val.)",
                ],
                rows,
                numeric=(2, 3, 4, 5, 6),
            )
        )
    else:
        return None
    claims = [(x.label, x.diagnosis) for x in f.chain if x.diagnosis]
    if claims:
        items = []
        for label, d in claims:
            items.append(
                f"{label}: "
                + (
                    f"claimed {d['claimed_effect']}"
                    if d.get("claimed_effect")
                    else "adequate"
                    if d.get("adequate")
                    else f"no effect claimed; worth trying {d['candidate_effect']}"
                    if d.get("candidate_effect")
                    else "no effect claimed"
                )
                + f" — {d.get('verdict', '')}"
            )
        out.append(Raw("<h3>What each diagnosis said</h3>"))
        out.append(ul(items))
    return Raw("".join(out))


def _posterior(f: Found) -> Raw | None:
    p = f.posterior
    if p is None:
        return None
    out = []
    settings = read_json(p / "settings.json") or {}
    if settings:
        out.append(
            kv(
                [
                    ("from the fit", _path(settings.get("fit", "?"))),
                    (
                        "walkers × steps × ensembles",
                        f"{settings.get('walkers')} × {settings.get('steps')} × "
                        f"{settings.get('ensembles')}",
                    ),
                    (
                        "noise model",
                        f"{settings.get('noise')}"
                        + (", AR(1) errors" if settings.get("ar1") else ""),
                    ),
                    ("priors", settings.get("priors") or "uniform within the physical bounds"),
                    ("seed", settings.get("seed")),
                ]
            )
        )
    md = p / "summary.md"
    if md.exists():
        t = markdown_table(md.read_text())
        out.append(t if t is not None else pre(md.read_text()))
        if t is not None:
            # The notes under the table (what the columns mean, what the intervals assume).
            notes = [
                ln.strip()
                for ln in md.read_text().splitlines()
                if ln.strip() and not ln.strip().startswith("|")
            ]
            out += [Raw(f'<p class="note">{esc(n)}</p>') for n in notes]
    else:
        out.append(
            Raw(
                '<p class="note">No summary.md: the sampling did not finish; continue '
                f"it with {_code(f'rotorbayes sample {p} --resume')}.</p>"
            )
        )
    if (p / "warnings.txt").exists():
        out.append(_warnings(_read_lines(p / "warnings.txt"), "Convergence warnings"))
    out.append(
        _figs(
            (p / "corner.png", "corner plot of the posterior"),
            (p / "trace.png", "trace of the walkers"),
        )
    )
    out.append(
        _figs(
            (p / "predictive.png", "posterior predictive"),
            (p / "correlation.png", "posterior correlation"),
        )
    )
    return Raw("".join(out))


def _identify(f: Found) -> Raw | None:
    p = f.identify
    if p is None:
        return None
    doc = read_json(p / "identify.json") or {}
    out = [
        Raw(
            f"<p>Fisher information of {_path(doc.get('fit', '?'))} at the fit (noise at the "
            "encoder floor; log coordinates for positive parameters), in words:</p>"
        )
    ]
    out.append(ul(doc.get("words") or ["(no words in identify.json)"]))
    fi = doc.get("fisher") or {}
    names, ev = fi.get("names") or [], fi.get("eigenvalues") or []
    vecs, widths = fi.get("eigenvectors") or [], fi.get("widths_1sigma") or []
    if names and ev:
        rows = []
        for i, lam in enumerate(ev):
            v = vecs[i] if i < len(vecs) else []
            movers = sorted(zip(names, v, strict=False), key=lambda t: -abs(t[1]))
            rows.append(
                [
                    i + 1,
                    lam,
                    widths[i] if i < len(widths) else None,
                    ", ".join(f"{n} {c:+.2f}" for n, c in movers if abs(c) > 0.25),
                ]
            )
        out.append(Raw("<details><summary>All Fisher directions</summary>"))
        out.append(
            table(
                ["direction", "eigenvalue", "1σ width (relative)", "main components"],
                rows,
                numeric=(0, 1, 2),
                caption="sloppiest first; a width above 1 means the data do not fix "
                "that combination to better than a factor e",
            )
        )
        out.append(Raw("</details>"))
    prof = doc.get("profiles") or []
    if prof:
        rows = []
        for pr in prof:
            grid = pr.get("grid") or []
            iv = profile_interval(pr)
            est, ends = pr.get("estimate"), "no grid point"
            if iv["lo"] is not None:
                # The 95 % interval's half-width over 1.96 is the sd its digits follow.
                sd = (iv["hi"] - iv["lo"]) / 3.92
                lo, hi = fmt_interval_at(iv["lo"], iv["hi"], sd).split(", ")
                ends = Raw(f"{digits(lo)} … {digits(hi)}")
                if isinstance(est, int | float) and sd_place(sd) is not None:
                    est = digits(mean_sd(float(est), sd)[0])
            rows.append(
                [
                    Raw(f"<code>{esc(pr.get('parameter'))}</code>"),
                    est,
                    ends,
                    _unit(pr.get("unit")),
                    Raw(f"{num(grid[0], 7)} … {num(grid[-1], 7)}") if grid else None,
                    iv["note"],
                ]
            )
        out.append(Raw("<h3>Profile likelihoods</h3>"))
        out.append(
            table(
                ["parameter", "estimate", "95 % interval (Δχ² < 3.84)", "unit", "grid", "note"],
                rows,
                numeric=(1, 2, 4),
            )
        )
    out.append(
        _figs(
            (p / "fisher.png", "Fisher directions"),
            *(
                (p / n, c)
                for n, c in (
                    ("profiles.png", "profile likelihoods"),
                    ("corner.png", "posterior corner"),
                )
                if (p / n).exists()
            ),
        )
    )
    return Raw("".join(out))


def _reproducibility(f: Found) -> Raw:
    out = []
    run = f.run
    if run:
        out.append(
            kv(
                [
                    ("analysis file", _path(run.get("analysis_file", "?"))),
                    ("started", run.get("started")),
                    ("finished", run.get("finished")),
                    ("log", _path(f.root / "log.txt")),
                ]
            )
        )
        out.append(Raw("<h3>Package versions</h3>"))
        out.append(table(["package", "version"], sorted((run.get("versions") or {}).items())))
        out.append(Raw("<h3>Seeds</h3>"))
        out.append(table(["stage", "seed"], sorted((run.get("seeds") or {}).items()), numeric=(1,)))
        if run.get("data"):
            out.append(Raw("<h3>Data hashes</h3>"))
            out.append(
                table(
                    ["file", "SHA-256"],
                    [
                        [
                            d.get("path"),
                            Raw(f'<span class="hash">{esc(d.get("sha256", ""))}</span>'),
                        ]
                        for d in run["data"]
                    ],
                )
            )
        if run.get("stages"):
            out.append(Raw("<h3>Stages</h3>"))
            out.append(
                table(
                    ["stage", "folder", "time [s]", "input hash", "skipped"],
                    [
                        [
                            s.get("name"),
                            _path(s.get("folder", "")),
                            s.get("seconds"),
                            Raw(f'<span class="hash">{_short_hash(s)}…</span>'),
                            "yes (inputs unchanged)" if s.get("skipped") else "no",
                        ]
                        for s in run["stages"]
                    ],
                    numeric=(2,),
                    caption="a stage is skipped on a rerun when its input hash is unchanged",
                )
            )
        out.append(Raw("<h3>The analysis file</h3>"))
        out.append(pre(run.get("analysis_text") or "(not recorded)"))
    else:
        out.append(
            Raw(
                '<p class="note">This folder has no run.json (it was not written by '
                "<code>rotorbayes run</code>), so the versions below are those at the "
                "time of this report, not necessarily those that made the results."
                "</p>"
            )
        )
        out.append(table(["package", "version at report time"], list(_versions_now().items())))
        seeds = []
        if f.posterior is not None:
            s = read_json(f.posterior / "settings.json") or {}
            if "seed" in s:
                seeds.append(["sample", s["seed"]])
        if seeds:
            out.append(Raw("<h3>Seeds</h3>"))
            out.append(table(["stage", "seed"], seeds, numeric=(1,)))
        fit = f.final
        if fit is not None and (fit.doc.get("data") or fit.doc.get("validation")):
            rows = []
            for spec in fit.doc.get("data", []) + fit.doc.get("validation", []):
                p = Path(spec)
                rows.append(
                    [
                        spec,
                        Raw(f'<span class="hash">{esc(file_sha256(p))}</span>')
                        if p.is_file()
                        else "file not found",
                    ]
                )
            out.append(Raw("<h3>Data hashes (computed now)</h3>"))
            out.append(table(["file", "SHA-256"], rows))
    return Raw("".join(out))


RENDER = {
    "data": _data,
    "fit": _fit,
    "compare": _compare,
    "diagnosis": _diagnosis,
    "chain": _chain,
    "posterior": _posterior,
    "identifiability": _identify,
}


# ------------------------------------------------------------------------------------ page
def render_report(folder: str | Path, *, compact: bool = True) -> Report:
    """The report of ``folder`` (not written; see :func:`write_report`).

    ``compact`` re-encodes the PNG figures with a 256-colour palette (a third of the size,
    the same look for line art); identical figures are embedded once either way.
    """
    found = discover(folder)
    with figure_store(compact):
        return _render(found)


def _render(found: Found) -> Report:
    bodies: dict[str, Raw] = {}
    absent: dict[str, str] = {}
    problems: list[str] = []
    bodies["verdict"] = _verdict(found)
    for sid, fn in RENDER.items():
        try:
            body = fn(found)
        except ReportError as exc:
            problems.append(f"{sid}: {exc}")
            body = Raw(f'<p class="warn">This section could not be made: {esc(exc)}</p>')
        except (KeyError, TypeError, ValueError, IndexError, AttributeError, OSError) as exc:
            problems.append(f"{sid}: {type(exc).__name__}: {exc}")
            body = Raw(
                f'<p class="warn">This section could not be made from the files '
                f"(they may come from another rotorbayes version): "
                f"{esc(type(exc).__name__)}: {esc(exc)}</p>"
            )
        if body is None:
            absent[sid] = HINTS[sid]
        else:
            bodies[sid] = body
    bodies["reproducibility"] = _reproducibility(found)
    sections = [s for s in SECTIONS if s in bodies]
    return Report(found.root, _page(found, bodies, absent, sections), sections, absent, problems)


def _page(found: Found, bodies: dict[str, Raw], absent: dict[str, str], sections: list[str]) -> str:
    from ..util import __version__

    kinds = {
        "study": "study",
        "fit": "fit folder",
        "compare": "compare folder",
        "sample": "posterior sample folder",
        "identify": "identifiability folder",
    }
    name = _analysis_name(found.run)
    title = name or f"rotorbayes report: {found.root.resolve().name}"
    now = datetime.datetime.now().isoformat(timespec="seconds")
    toc = "".join(f'<li><a href="#{s}">{esc(SECTIONS[s])}</a></li>' for s in sections)
    absent_html = ""
    if absent:
        absent_html = (
            '<div class="absent-list"><strong>Not in this report</strong> (not in '
            "this folder):<ul>"
            + "".join(
                f"<li>{esc(SECTIONS[s].split(':')[0])}: {_hint(h)}</li>" for s, h in absent.items()
            )
            + "</ul></div>"
        )
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        REPORT_MARK,  # `report --out` overwrites only files that carry it
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        # No request may leave the page: everything is inline or a data: URI.
        '<meta http-equiv="Content-Security-Policy" content="default-src \'none\'; '
        "img-src data:; style-src 'unsafe-inline'\">",
        f"<title>{esc(title)}</title>",
        f"<style>{CSS}</style></head><body><main>",
        f'<header class="top"><h1>{esc(title)}</h1>'
        f'<p class="sub">{esc(kinds[found.kind])} {_path(found.root.resolve())} · report '
        f"made {esc(now)} by rotorbayes {esc(__version__)}</p></header>",
        f'<nav class="toc" id="contents"><strong>Contents</strong><ol>{toc}</ol>'
        f"{absent_html}</nav>",
    ]
    for s in sections:
        parts.append(f'<section id="{s}"><h2>{esc(SECTIONS[s])}</h2>{bodies[s]}</section>')
    parts.append(
        f"<footer>Self-contained: figures are embedded, nothing is loaded from "
        f"elsewhere. Made from {_path(found.root.resolve())}.</footer>"
    )
    parts.append("</main></body></html>")
    return "\n".join(parts) + "\n"


#: The tag that marks a page as a report this program wrote.
REPORT_MARK = '<meta name="generator" content="rotorbayes report">'


def is_our_report(path: Path) -> bool:
    """Whether ``path`` is an HTML report written by rotorbayes (its first 4 kB say so)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(4096).decode("utf-8", errors="replace")
    except OSError:
        return False
    return REPORT_MARK in head or (
        "<title>" in head and "rotorbayes" in head and "Content-Security-Policy" in head
    )


def write_report(
    folder: str | Path, out: str | Path | None = None, *, compact: bool = True, force: bool = False
) -> Report:
    """Render the report of ``folder`` and write it atomically to ``out`` (default
    ``folder/report.html``; a folder given as ``out`` gets ``report.html`` inside)."""
    path = Path(out) if out is not None else Path(folder) / "report.html"
    if path.is_dir():
        path = path / "report.html"
    if Path(folder).is_dir():  # (a missing folder is render_report's message)
        _check_report_path(path, force)  # before the work
    rep = render_report(folder, compact=compact)
    _check_report_path(path, force)
    write_text_atomic(path, rep.html)
    rep.path = path
    return rep


def _check_report_path(path: Path, force: bool) -> None:
    """Refuse a report file name that is not .html, or a file that is not our report."""
    if not path.parent.is_dir():
        raise ReportError(
            f"{path}: its folder {path.parent} does not exist; create it or choose another --out"
        )
    if path.suffix.lower() not in (".html", ".htm"):
        raise ReportError(
            f"--out {path}: a report is an HTML file; give a name ending in "
            f".html (e.g. --out {path.with_suffix('.html')})"
        )
    if path.exists() and not path.is_file():
        raise ReportError(f"--out {path}: is not a regular file; choose another --out")
    if path.exists() and not force and not is_our_report(path):
        raise ReportError(
            f"--out {path}: the file exists and is not a report written by "
            "rotorbayes; choose another --out, or pass --force to replace it"
        )


def build_report(
    folder: str | Path, out: str | Path | None = None, *, compact: bool = True
) -> Path:
    """Write ``folder/report.html`` (or ``out``) and return its path."""
    return write_report(folder, out, compact=compact).path

"""Beyond the catalogue: a proposed missing term, written as an effect file to refit.

When the missing-torque map (:mod:`.torque`) shows a torque well above its noise and no
catalogue effect brought the fit near the floor, :func:`propose` fits each disc's missing
torque by sparse regression over a library of candidate terms and keeps the terms that
the regression picks again and again over block-bootstrap resamples.
:func:`write_effect_file` writes them as one user effect (``proposed``) whose parameters
are the kept terms' coefficients; ``rotorbayes fit --p0 FIT/ --add DIAG/proposal.py:proposed``
refits it like any other effect, and the validation data judge it.

The library (:func:`library`), per disc, with ``w`` its velocity, ``s = sign(w)``,
``theta`` its angle, ``alpha`` the string's torsion, ``v`` the motor voltage:

* **friction levels** (a ``friction_shift``: the disc's Coulomb and static levels move by
  ``c g``; the missing torque is ``-s c g``): ``w^2``, ``|w|^3``, ``sqrt|w|``,
  Stribeck-like bumps ``exp(-(|w|/w_k)^2)`` over a grid of ``w_k``, ``cos``/``sin`` of
  ``theta`` once and twice per revolution, and time ``t`` (a drift).  A friction term
  that depends on speed is a level shift, not a torque: a level shift moves the stick band
  and does not push a disc at rest, where an added torque would;
* **torques** (a ``torque``, alike in both directions): ``cos``/``sin`` of the angle once
  and twice per revolution (an uneven load) and at the harmonic the map names (a cogging
  torque), time, ``alpha^2`` and ``alpha^3`` (a string that is not linear: a string term
  acts on both discs, equal and opposite, and is one parameter ``c_s_...``), and ``v^3``
  and ``v w`` on the upper disc (a motor that is not linear, a motor torque that sags
  with speed).

What the fitted parameters already vary (the Coulomb level and its asymmetry, the viscous
coefficient and its asymmetry, the string stiffness, the motor constant) is projected out
of the missing torque and of every column first, so a proposal never repeats the model.
Each friction term enters centred on its estimation-data mean (the constant goes to the
friction level the refit re-estimates anyway), so the refit starts where the parent fit
is; each torque term enters whole (a constant load has no parameter of the model to go
to: a cogging torque's centred term ended its refit at 206x the floor, whole at 0.864x).
The filtered input the map uses (``input_history``) is not in the library: a hook sees the
present state only, so a lag of the drive cannot be written as a user effect.

The regression: scikit-learn's :class:`~sklearn.linear_model.LassoLarsIC` (the lasso path
by LARS, the penalty chosen by BIC).  Chosen over PySINDy's STLSQ because the problem
here is one static regression per disc (no derivatives to take, the map has them), the
lasso path needs no threshold to tune by hand (STLSQ's threshold depends on the columns'
scaling and the noise), and BIC needs no cross-validation folds (folds of autocorrelated
samples would leak).  Over-selection by BIC on correlated samples is checked two ways:
the samples are thinned to one every :data:`THIN` seconds (about the derivative filter's
reach), and a term is kept only if the lasso selects it in at least :data:`KEEP` of
:data:`RESAMPLES` moving-block bootstrap resamples (blocks of :data:`BLOCK` seconds: the
samples are autocorrelated, so single samples must not be resampled).  The kept terms'
coefficients are least squares on all samples; their uncertainty is the spread of the
same least squares over the resamples.

A proposal is made only when the map's torque is :data:`~.torque.NOISE_FACTOR` times its
noise and the regression says something: the kept terms must explain at least
:data:`MIN_R2` of the missing torque and each coefficient must be :data:`MIN_Z` bootstrap
standard deviations from zero; otherwise the words say that the regression explains
little and no file is written.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .torque import NOISE_FACTOR, TorqueMap, harmonic_of, run_offsets

#: The kept samples are thinned to one every THIN seconds (the map's derivative filter
#: makes neighbours share their noise).
THIN = 0.02
#: Bootstrap resamples, block length [s], and the fraction of resamples that must select
#: a term for it to be kept.
RESAMPLES = 40
BLOCK = 1.0
KEEP = 0.8
#: The kept terms together must explain at least this fraction of the missing torque
#: (small: at a fit far from the floor the parameters bend to the missing term, and much
#: of the map is that bending, which the refit undoes: a lower friction drift that ended
#: at the floor when refitted explained 9 % of the parent fit's map on 10 s of data)...
MIN_R2 = 0.05
#: ... each kept coefficient must be this many of its bootstrap standard deviations
#: from zero ...
MIN_Z = 3.0
#: ... and each kept term must explain at least this fraction of what all kept terms explain (RMS).
MIN_SHARE = 0.05
#: Widths [rad/s] of the Stribeck-like bumps.
BUMP_WIDTHS = (0.1, 0.3, 1.0, 3.0)
#: The effect's name in the written file.
EFFECT_NAME = "proposed"
FILE_NAME = "proposal.py"


@dataclass(frozen=True)
class Term:
    """One candidate term of a disc's missing torque."""

    key: str  # short identifier (goes into the parameter name)
    kind: str  # "friction" (a level shift, a friction_shift), "torque", or "string" (a
    #            torque on the lower disc and its reaction on the upper)
    words: str  # what it is, for people
    expr: str  # the term g as Python, in the hook's variables
    unit: str  # the unit of g (the coefficient's is N m / this)


@dataclass
class Kept:
    """A kept term: its coefficient [N m per unit of the term] and what backs it."""

    disc: str
    term: Term
    frequency: float
    value: float
    std: float
    centre: float  # the term's mean on the estimation samples (subtracted in the file)
    part_rms: float  # RMS [N m] of the torque it explains
    tag: str = ""  # "" or "2", "3", ...: tells a second proposal's parameters apart

    @property
    def name(self) -> str:
        return f"c{self.tag}_{_slot(self)}_{self.term.key}"

    @property
    def unit(self) -> str:
        u = self.term.unit
        return "N m" if u == "1" else f"N m/({u})" if " " in u or "^" in u else f"N m/{u}"

    def as_dict(self) -> dict:
        return {
            "parameter": self.name,
            "disc": self.disc,
            "term": self.term.key,
            "kind": self.term.kind,
            "words": self.term.words,
            "expression": self.term.expr,
            "frequency": self.frequency,
            "value": self.value,
            "std": self.std,
            "unit": self.unit,
            "centre": self.centre,
            "explains_rms_N_m": self.part_rms,
        }


@dataclass
class DiscProposal:
    """What the regression found for one disc."""

    disc: str
    kept: list[Kept] = field(default_factory=list)
    r2: float = 0.0  # of the missing torque, by the kept terms (after projection)
    explained_rms: float = 0.0
    noise_rms: float = 0.0
    frequencies: dict[str, float] = field(default_factory=dict)
    reason: str = ""  # why nothing is proposed (empty when something is)

    def as_dict(self) -> dict:
        return {
            "disc": self.disc,
            "kept": [k.as_dict() for k in self.kept],
            "r2": self.r2,
            "explained_rms_N_m": self.explained_rms,
            "noise_rms_N_m": self.noise_rms,
            "selection_frequencies": self.frequencies,
            "reason": self.reason or None,
        }


@dataclass
class Proposal:
    """The proposal over both discs (empty ``kept``: nothing proposed, ``reason`` says
    why)."""

    discs: list[DiscProposal] = field(default_factory=list)
    reason: str = ""
    #: Where the missing torque was mapped, when not at the fit itself (an inverted
    #: trial's point: :func:`rotorbayes.diagnosis.trials.point_without`).
    where: str = ""
    file: str = ""
    command: str = ""
    seconds: float = 0.0
    #: The effect's name in the file (:data:`EFFECT_NAME`, or ``proposed_2``, ... where the
    #: fit has a proposal on already: see :meth:`rename`).
    effect: str = EFFECT_NAME

    def rename(self, taken) -> None:
        """Give the effect and its parameters names that none of ``taken`` (the fit's
        effect and parameter names) has: a fit made with one proposal gets a second one
        named ``proposed_2`` with parameters ``c2_...``."""
        taken = set(taken)
        for i in range(1, 1000):
            effect = EFFECT_NAME if i == 1 else f"{EFFECT_NAME}_{i}"
            tag = "" if i == 1 else str(i)
            names = {f"c{tag}_{_slot(k)}_{k.term.key}" for k in self.kept}
            if effect not in taken and not names & taken:
                self.effect = effect
                for k in self.kept:
                    k.tag = tag
                return
        raise ValueError("no free name for the proposed effect")

    @property
    def kept(self) -> list[Kept]:
        return [k for d in self.discs for k in d.kept]

    def words(self) -> str:
        if not self.kept:
            return f"no missing term is proposed: {self.reason}"
        lines = [
            "proposed missing term (sparse regression of the missing torque, "
            f"terms kept in >= {KEEP:.0%} of {RESAMPLES} block-bootstrap resamples"
            + (f"; mapped {self.where}" if self.where else "")
            + "):"
        ]
        for d in self.discs:
            disc = "upper" if d.disc == "u" else "lower"
            if not d.kept:
                lines.append(f"  {disc} disc: nothing ({d.reason})")
                continue
            lines.append(
                f"  {disc} disc: explains {100 * d.r2:.0f} % of its missing torque "
                f"{'there' if self.where else 'at this fit'} (RMS {d.explained_rms:.2g} "
                f"N m; the map's noise {d.noise_rms:.2g} N m)"
            )
            for k in d.kept:
                lines.append(
                    f"    {k.term.words}: {k.name} = {k.value:.3g} ± {k.std:.2g} "
                    f"{k.unit} (kept in {k.frequency:.0%})"
                )
        if self.file:
            lines.append(
                f"written as {self.file}:{self.effect}; refit it (the validation data judge it):"
            )
            lines.append(f"  {self.command}")
        return "\n".join(lines)

    def as_dict(self) -> dict:
        return {
            "proposed": bool(self.kept),
            "reason": self.reason or None,
            "where": self.where or None,
            "discs": [d.as_dict() for d in self.discs],
            "file": self.file or None,
            "effect": f"{self.file}:{self.effect}" if self.file else None,
            "command": self.command or None,
            "seconds": self.seconds,
            "method": {
                "regression": "sklearn LassoLarsIC (BIC)",
                "resamples": RESAMPLES,
                "block_s": BLOCK,
                "keep": KEEP,
                "thin_s": THIN,
            },
        }


def library(m: TorqueMap) -> list[tuple[Term, np.ndarray]]:
    """The candidate terms of map ``m``'s disc with their values on its samples (the term
    ``g``, not yet signed: see :func:`columns`)."""
    f = m.features
    d = m.disc
    w = f["velocity"]
    aw = np.abs(w)
    th, om = ("theta_l", "omega_l") if d == "l" else ("theta_u", "omega_u")
    out: list[tuple[Term, np.ndarray]] = [
        (
            Term(
                "w2",
                "friction",
                "friction level rising with speed squared",
                f"{om} * {om}",
                "rad^2/s^2",
            ),
            w * w,
        ),
        (
            Term(
                "w3",
                "friction",
                "friction level rising with speed cubed",
                f"abs({om}) ** 3",
                "rad^3/s^3",
            ),
            aw**3,
        ),
        (
            Term(
                "sqrtw",
                "friction",
                "friction level rising with the square root of speed",
                f"math.sqrt(abs({om}))",
                "(rad/s)^0.5",
            ),
            np.sqrt(aw),
        ),
    ]
    for wk in BUMP_WIDTHS:
        key = f"bump{wk:g}".replace(".", "p")
        out.append(
            (
                Term(
                    key,
                    "friction",
                    f"Stribeck-like bump of width {wk:g} rad/s",
                    f"math.exp(-({om} / {wk!r}) ** 2)",
                    "1",
                ),
                np.exp(-((w / wk) ** 2)),
            )
        )
    out.append((Term("t", "friction", "friction level drifting in time", "t", "s"), m.t.copy()))
    out.append((Term("load_t", "torque", "a load drifting in time", "t", "s"), m.t.copy()))
    if "angle_1" in f:
        a = f["angle_1"]
        # Once and twice per revolution, and the harmonic the map names where it names a
        # higher one (a cogging torque: each of the eight would be 32 more terms).
        hs = [1, 2]
        if m.ranking and m.ranking[0][0].startswith("angle_"):
            hs = sorted({*hs, harmonic_of(m.ranking[0][0])})
        for h in hs:
            arg = th if h == 1 else f"{float(h)!r} * {th}"
            for fn in ("cos", "sin"):
                val = getattr(np, fn)(h * a)
                out.append(
                    (
                        Term(
                            f"{fn}{h}",
                            "friction",
                            f"friction level varying as {fn}({'' if h == 1 else f'{h} '}{th})",
                            f"math.{fn}({arg})",
                            "1",
                        ),
                        val,
                    )
                )
                out.append(
                    (
                        Term(
                            f"load_{fn}{h}",
                            "torque",
                            f"a load varying as {fn}({'' if h == 1 else f'{h} '}{th})",
                            f"math.{fn}({arg})",
                            "1",
                        ),
                        val,
                    )
                )
    if "torsion" in f:
        al = f["torsion"]
        alpha = "(theta_l - theta_u + p[ALPHA0])"
        out.append(
            (
                Term(
                    "alpha2",
                    "string",
                    "string torque in torsion squared (on both discs, opposite)",
                    f"{alpha} ** 2",
                    "rad^2",
                ),
                al**2,
            )
        )
        out.append(
            (
                Term(
                    "alpha3",
                    "string",
                    "string torque in torsion cubed (on both discs, opposite)",
                    f"{alpha} ** 3",
                    "rad^3",
                ),
                al**3,
            )
        )
    if d == "u":
        out.append(
            (
                Term("v3", "torque", "motor torque in voltage cubed", "v ** 3", "V^3"),
                f["input"] ** 3,
            )
        )
        # A motor whose torque sags with speed at a given voltage (the model's motor
        # torque k_m v does not depend on the speed; a back-EMF alike at every voltage is
        # the viscous coefficient's, and projected out).
        out.append(
            (
                Term(
                    "v_w",
                    "torque",
                    "motor torque changing with voltage times speed",
                    f"v * {om}",
                    "V rad/s",
                ),
                f["input"] * w,
            )
        )
    return out


def _base(m: TorqueMap) -> np.ndarray:
    """Columns of what the model's own parameters vary (projected out of everything)."""
    f = m.features
    s = f["direction"]
    aw = np.abs(f["velocity"])
    runs = run_offsets(m.runs)  # each run's own constant (its initial torsion), if several
    cols = [np.ones_like(s) if runs is None else runs, s, s * aw, aw]
    if "torsion" in f:
        cols.append(f["torsion"])
    if m.disc == "u":
        cols.append(f["input"])
    if m.own is not None:
        # The balance's own derivatives by the fitted parameters, where the map holds
        # them (see TorqueMap.own): the same directions as above, and the fitted ones
        # exactly (asymmetries, Stribeck shape, the motor constant).
        cols.append(m.own)
    return np.column_stack(cols)


def columns(m: TorqueMap, lib) -> np.ndarray:
    """The regression columns: the missing torque a unit of each term makes (``-s g`` for
    a friction level, ``g`` for a torque; a string torque ``g`` on the lower disc and
    ``-g`` on the upper, so that one coefficient means the same on both), each term
    centred on its mean."""
    s = m.features["direction"]
    out = []
    for term, g in lib:
        gc = g - g.mean()
        if term.kind == "friction":
            out.append(-s * gc)
        elif term.kind == "string" and m.disc == "u":
            out.append(-gc)
        else:
            out.append(gc)
    return np.column_stack(out)


def _slot(k: Kept) -> str:
    """The disc part of a kept term's name: ``s`` for the string's (it acts on both)."""
    return "s" if k.term.kind == "string" else k.disc


def _one_string(p: Proposal) -> None:
    """A string term acts on both discs, equal and opposite (the string pulls both ends):
    kept on both maps, it is one term, kept where its coefficient is surest.  Measured: a
    cubic string stiffness hidden in reference data was proposed on the lower disc alone
    (c_l_alpha3 = -0.000134 for -0.00014): its refit ended at 712x the floor, the upper
    disc still lacking the reaction, which the next diagnosis proposed as a term of its
    own."""
    found: dict[str, list[tuple[DiscProposal, Kept]]] = {}
    for d in p.discs:
        for k in d.kept:
            if k.term.kind == "string":
                found.setdefault(k.term.key, []).append((d, k))
    for pairs in found.values():
        best = max(pairs, key=lambda dk: abs(dk[1].value) / max(dk[1].std, 1e-300))
        for d, k in pairs:
            if k is not best[1]:
                d.kept.remove(k)


def _blocks(n: int, length: int, rng: np.random.Generator) -> np.ndarray:
    """Indices of one moving-block bootstrap resample of ``n`` samples."""
    length = max(1, min(length, n))
    k = math.ceil(n / length)
    starts = rng.integers(0, n - length + 1, size=k)
    return (starts[:, None] + np.arange(length)[None, :]).ravel()[:n]


def _select(X: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The lasso's selection (BIC) on standardised columns: a boolean per column."""
    from sklearn.linear_model import LassoLarsIC

    sd = X.std(axis=0)
    ok = sd > 0
    Z = np.zeros_like(X)
    Z[:, ok] = (X[:, ok] - X[:, ok].mean(axis=0)) / sd[ok]
    ys = y.std()
    if ys <= 0:
        return np.zeros(X.shape[1], bool)
    model = LassoLarsIC(criterion="bic", fit_intercept=True)
    model.fit(Z, (y - y.mean()) / ys)
    return (np.abs(model.coef_) > 0) & ok


def propose_disc(m: TorqueMap, *, seed: int = 0) -> DiscProposal:
    """The sparse regression of one disc's missing torque (see the module docstring)."""
    out = DiscProposal(m.disc, noise_rms=m.noise_rms)
    if not m.above_noise:
        out.reason = (
            f"its missing torque is {m.rms_over_noise:.2g}x the map's noise, below "
            f"{NOISE_FACTOR:g}x"
        )
        return out
    dt = float(np.median(np.diff(m.t))) if m.t.size > 1 else 1.0
    dt = dt if dt > 0 else 1e-3
    step = max(1, int(round(THIN / dt)))
    idx = np.arange(0, m.t.size, step)
    lib = library(m)
    X = columns(m, lib)
    B = _base(m)
    # Project out what the model's own parameters vary (Frisch-Waugh: the same
    # coefficients as with these columns unpenalised in the regression).
    Q, _ = np.linalg.qr(B)
    y_full = m.torque - Q @ (Q.T @ m.torque)
    X_full = X - Q @ (Q.T @ X)
    y, Xs = y_full[idx], X_full[idx]
    n = y.size
    if n < 5 * X.shape[1]:
        out.reason = f"too few samples in slip ({n} after thinning) for {X.shape[1]} terms"
        return out
    rng = np.random.default_rng(seed)
    block = max(1, int(round(BLOCK / (dt * step))))
    counts = np.zeros(X.shape[1])
    picks = []
    for _ in range(RESAMPLES):
        r = _blocks(n, block, rng)
        picks.append(r)
        counts += _select(Xs[r], y[r])
    freq = counts / RESAMPLES
    out.frequencies = {t.key: float(fq) for (t, _), fq in zip(lib, freq, strict=True) if fq > 0}
    keep = np.flatnonzero(freq >= KEEP)
    while keep.size:
        beta, *_ = np.linalg.lstsq(Xs[:, keep], y, rcond=None)
        parts = np.sqrt(np.mean((X_full[:, keep] * beta) ** 2, axis=0))
        total = math.sqrt(float(np.mean((X_full[:, keep] @ beta) ** 2)))
        weak = parts < MIN_SHARE * total
        if not weak.any():
            break
        keep = keep[~weak]
    if not keep.size:
        out.reason = (
            "no term was selected in at least "
            f"{KEEP:.0%} of the resamples (the regression explains little)"
        )
        return out
    fitted = X_full[:, keep] @ beta
    st = float(np.sum(y_full**2))
    r2 = 1.0 - float(np.sum((y_full - fitted) ** 2)) / st if st > 0 else 0.0
    explained = math.sqrt(float(np.mean(fitted**2)))
    out.r2, out.explained_rms = r2, explained
    boot = np.array([np.linalg.lstsq(Xs[r][:, keep], y[r], rcond=None)[0] for r in picks])
    sd = boot.std(axis=0, ddof=1)
    z = np.abs(beta) / np.maximum(sd, 1e-300)
    if r2 < MIN_R2 or (z < MIN_Z).any():
        names = ", ".join(lib[j][0].key for j in keep)
        nz = int(np.sum(z < MIN_Z))
        # Lead with what failed ("explains little" beside "explain 94 %" read as a
        # contradiction where the coefficients were the reason).
        lead = (
            "the regression explains little"
            if r2 < MIN_R2
            else f"{nz} of the terms' coefficients are not told from 0"
        )
        out.reason = (
            f"{lead}: the {keep.size} term(s) it keeps "
            f"({names}) explain {100 * r2:.0f} % of the missing torque (RMS "
            f"{explained:.2g} N m), and {nz} of their "
            f"coefficients lie within {MIN_Z:g} bootstrap standard deviations of 0 "
            f"(a proposal needs {100 * MIN_R2:.0f} % and every coefficient beyond "
            f"{MIN_Z:g}); nothing written"
        )
        return out
    for j, c, e, part in zip(keep, beta, sd, parts, strict=True):
        term, g = lib[j]
        out.kept.append(
            Kept(m.disc, term, float(freq[j]), float(c), float(e), float(g.mean()), float(part))
        )
    return out


def propose(maps, *, catalogue_near_floor: bool, seed: int = 0) -> Proposal:
    """A proposal from the missing-torque ``maps`` (one per disc).  Nothing is proposed
    when ``catalogue_near_floor`` (a catalogue effect's refit, or the fit itself, is near
    the floor) or no map's torque is :data:`~.torque.NOISE_FACTOR` times its noise."""
    import time

    t0 = time.perf_counter()
    p = Proposal()
    if catalogue_near_floor:
        p.reason = "the catalogue brings the fit near the floor"
        return p
    if not any(m.above_noise for m in maps):
        p.reason = (
            f"no disc's missing torque is {NOISE_FACTOR:g}x the map's noise beyond what "
            f"other values of its fitted parameters give ({_below_words(maps)})"
        )
        return p
    p.discs = [propose_disc(m, seed=seed) for m in maps]
    _one_string(p)
    if not p.kept:
        p.reason = "; ".join(
            f"{'upper' if d.disc == 'u' else 'lower'} disc: {d.reason}" for d in p.discs
        )
    p.seconds = time.perf_counter() - t0
    return p


def _below_words(maps) -> str:
    """Per disc, how far its map's torque is above the noise, and what the own terms took
    (a fit far from the floor whose map is all its own terms bent, not nothing missing)."""
    out = []
    for m in maps:
        disc = "upper" if m.disc == "u" else "lower"
        if m.own_notable:
            rest = m.rest_rms / m.noise_rms
            out.append(
                f"{disc} disc: {m.rms_over_noise:.2g}x, of which {100 * m.own_r2:.0f} % its "
                f"own terms at other values, the rest {rest:.2g}x"
            )
        else:
            out.append(f"{disc} disc: {m.rms_over_noise:.2g}x")
    return "; ".join(out) or "no map"


#: A catalogue effect whose refit (or predicted fall) ends within this many floors, or a
#: fit already there, leaves nothing for a proposal to do.
NEAR = 1.5


def catalogue_near_floor(diagnosis, trials: dict | None) -> str:
    """Why the catalogue already brings the fit near the floor (empty: it does not): the
    fit is adequate or within :data:`NEAR` floors, a trial refit ended within it, or (no
    trials run) the effect the score tests claim is predicted to end within it."""
    worst = max(diagnosis.rms_over_floor.values())
    if diagnosis.adequate:
        return "the model is adequate (the remaining error is noise)"
    if worst <= NEAR:
        return f"the fit is within {NEAR:g}x the floor ({worst:.3g}x)"
    # An inverted trial's fall stands in for something else: it is no reason to hold the
    # proposal back (a quadratic drag taken up by an inverted lower_stribeck, 1.28x).
    ends = [
        t.get("rms_over_floor")
        for t in (trials or {}).get("trials") or []
        if not t.get("failed") and not t.get("inverted")
    ]
    ends = [e for e in ends if isinstance(e, (int, float)) and math.isfinite(e)]
    if ends and min(ends) <= NEAR:
        best = min(
            (
                t
                for t in (trials or {}).get("trials") or []
                if t.get("rms_over_floor") == min(ends) and not t.get("inverted")
            ),
            key=lambda t: t["effect"],
        )
        return (
            f"the trial refit with {best['effect']} ends at {min(ends):.3g}x the floor "
            f"(within {NEAR:g}x): add it first"
        )
    if not trials and diagnosis.claimed:
        s = next((r for r in diagnosis.ranking if r.effect == diagnosis.claimed), None)
        pred = max((s.predicted_rms_ratio or {}).values(), default=math.inf) if s else math.inf
        if pred <= NEAR:
            return (
                f"the score tests claim {diagnosis.claimed}, predicted to end at "
                f"{pred:.3g}x the floor: add it first"
            )
    return ""


#: The written parameters' bounds: this many times the estimate (or its bootstrap standard
#: deviation) either side of it.  Wide: at a parent fit in a basin scaled along the lower
#: disc's ridge (J_l, k_alpha, Tc_l, b_l at 0.04x the reference's), the estimates were 25x
#: below what the refit needed, and bounds of 4x held the refit at 948x the floor.
BOUND_FACTOR = 100.0


def _bounds(k: Kept) -> tuple[float, float]:
    """Wide around the estimate (:data:`BOUND_FACTOR`), the null (0) always inside."""
    half = max(BOUND_FACTOR * abs(k.value), BOUND_FACTOR * k.std, 1e-12)
    return k.value - half, k.value + half


def effect_source(p: Proposal, *, header: str = "") -> str:
    """The proposal as the text of a user-effect file (one effect, ``p.effect``)."""
    kept = p.kept
    if not kept:
        raise ValueError("nothing proposed: no effect file to write")
    configs = (
        ("coupled", "brake")
        if any(k.disc == "l" or k.term.key.startswith("alpha") for k in kept)
        else ("upper", "coupled", "brake")
    )

    def body(kind: str) -> list[str]:
        lines = []
        for disc in ("u", "l"):
            acc = []
            for i, k in enumerate(kept):
                if kind == "torque" and k.term.kind == "string":
                    # The string's torque: +q g on the lower disc, its reaction on the upper.
                    acc.append(f"{'-' if disc == 'u' else ''}q[{i}] * {k.term.expr}")
                elif k.disc == disc and k.term.kind == kind:
                    # A friction term centred: its constant is a friction level, which the
                    # refit's Coulomb level takes.  A torque term whole: a constant load
                    # has no parameter of the model to go to (a cogging torque's centred
                    # term ended its refit at 206x the floor, uncentred at 0.864x).
                    acc.append(
                        f"q[{i}] * ({k.term.expr} - {k.centre!r})"
                        if kind == "friction"
                        else f"q[{i}] * {k.term.expr}"
                    )
            lines.append(
                f"    {'upper' if disc == 'u' else 'lower'} = "
                + (" + ".join(acc) if acc else "0.0")
            )
        lines.append("    return upper, lower")
        return lines

    has = {kind: any(k.term.kind == kind for k in kept) for kind in ("friction", "torque")}
    has["torque"] = has["torque"] or any(k.term.kind == "string" for k in kept)
    params = []
    for k in kept:
        lo, hi = _bounds(k)
        params.append(
            f"        Parameter({k.name!r}, {k.unit!r}, {lo!r}, {hi!r}, 0.0,\n"
            f"                  {k.term.words!r}, start={k.value!r}),"
        )
    where = {"u": "upper", "l": "lower", "s": "string"}
    words = "; ".join(f"{where[_slot(k)]}: {k.term.words}" for k in kept)
    src = [
        f'"""{header.strip()}\n"""' if header else '"""A proposed missing term."""',
        "",
        "import math",
        "",
        "from rotorbayes import Effect, Parameter",
        "from rotorbayes.kernel.layout import ALPHA0  # noqa: F401 (torsion terms)",
        "",
    ]
    if has["friction"]:
        src += [
            "",
            "def proposed_friction_shift(t, theta_u, omega_u, theta_l, omega_l, v, p, q):",
            '    """Shift of each disc\'s friction levels [N m] (Coulomb and static)."""',
            *body("friction"),
            "",
        ]
    if has["torque"]:
        src += [
            "",
            "def proposed_torque(t, theta_u, omega_u, theta_l, omega_l, v, p, q):",
            '    """Extra torque on each disc [N m], alike in both directions."""',
            *body("torque"),
            "",
        ]
    src += [
        "",
        f"{p.effect} = Effect(",
        f"    name={p.effect!r},",
        f"    physics={('proposed by rotorbayes diagnose: ' + words)!r},",
        "    parameters=(",
        *params,
        "    ),",
        "    signature='the missing-torque map of the fit this was proposed from',",
        f"    configs={configs!r},",
    ]
    if has["friction"]:
        src.append("    friction_shift=proposed_friction_shift,")
    if has["torque"]:
        src.append("    torque=proposed_torque,")
    src.append(")")
    return "\n".join(src) + "\n"


def header_text(p: Proposal, command: str) -> str:
    """The effect file's docstring: what was kept, how often, and the refit command."""
    lines = [
        "A missing term proposed by `rotorbayes diagnose` (a sparse regression of the",
        "missing torque; edit it as you like, it is your effect file now).",
        "",
    ]
    for d in p.discs:
        disc = "upper" if d.disc == "u" else "lower"
        if d.kept:
            lines.append(
                f"{disc} disc: the kept terms explain {100 * d.r2:.0f} % of its missing torque"
            )
            for k in d.kept:
                lines.append(
                    f"  {k.name}: {k.term.words}, {k.value:.4g} +- {k.std:.2g} "
                    f"{k.unit}, kept in {k.frequency:.0%} of {RESAMPLES} resamples"
                )
        else:
            lines.append(f"{disc} disc: nothing ({d.reason})")
    lines += [
        "",
        "Each friction term enters centred on its mean over the estimation data (the",
        "constant is a friction level the refit re-estimates); each torque term whole (a",
        "constant load has no parameter of the model to go to).  Refit it with:",
        "",
        f"    {command}",
    ]
    return "\n".join(lines)


def write_effect_file(p: Proposal, folder, command: str) -> str:
    """Write the proposal as ``folder/proposal.py`` (atomically) and return its path.

    An existing ``proposal.py`` with other content is never replaced (the user may have
    edited it, and a refit records its SHA-256: replacing it would orphan that refit); the
    proposal then goes to ``proposal_2.py``, ``proposal_3.py``, ... (the first free name,
    or the one already holding the same text).  ``command`` names the file as
    ``proposal.py``; it is rewritten to the name chosen."""
    from pathlib import Path

    from ..io.outputs import write_text_atomic

    folder = Path(folder)
    stem, suffix = FILE_NAME.rsplit(".", 1)
    for i in range(1, 1000):
        name = FILE_NAME if i == 1 else f"{stem}_{i}.{suffix}"
        path = folder / name
        cmd = command.replace(f"{FILE_NAME}:", f"{name}:")
        text = effect_source(p, header=header_text(p, cmd))
        if not path.exists():
            write_text_atomic(path, text)
            return str(path)
        try:
            if path.read_text(encoding="utf-8") == text:
                return str(path)
        except (OSError, UnicodeDecodeError):
            pass
    raise OSError(f"{folder}: proposal.py to proposal_999.py all exist; remove some")

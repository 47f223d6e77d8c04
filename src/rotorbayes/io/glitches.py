"""Glitches: samples an encoder line reports far from where the disc can have been.

Encoder lines pick up spikes: one sample (or a short burst) reads tens to hundreds of
counts off and the next reads right again.  No disc of the rig moves like that, and a fit
that keeps such a sample pays for it with its whole residual (issue 30: a few spikes of tens
to a hundred counts in 30 s of rig data raised the floor 3.3x, where the fit without them
was at 0.995x the encoder floor; a floor raised to match hides a model error of up to 3x).

How a glitch is found (:func:`find_glitches`), in encoder counts of the channel:

1. Every sample is compared with the cubic through its four neighbours (two on each side,
   itself excluded): the departure is the fourth difference over 6.  Rounding to counts
   moves it by at most 1.33 counts; the motion of the rig far less (on exact reference
   data with stick-slip and step inputs at most 0.13 counts at 200 Hz: where a disc
   sticks or slips its acceleration jumps, its velocity does not).  Samples departing by
   more than half the threshold are candidates, taken largest first.
2. Around a candidate, every set of up to :data:`MAX_BURST` samples within
   ``HALF_WINDOW + 2`` (6) samples of it is tried as the glitch, fewest first: a cubic is
   fitted by least squares to the other samples from 6 before the set to 6 after it.  The
   set is a glitch when those other samples lie on the cubic (within half the threshold:
   they move smoothly, so no kink of the motion is inside the stretch) and *every* sample
   of the set departs from it by more than the threshold.  A kink never passes: it bends
   the curve on one side, so either the neighbours miss the cubic or the departure is
   small.  A glitch found is left out before the next candidate is judged.
3. The threshold is :data:`MIN_COUNTS` counts, or :data:`NOISE_FACTOR` times the robust
   spread of step 1's departures where the data carry more noise than the encoder's
   rounding (then a glitch must stand out of that noise).

A glitch is left out by putting the cubic through its neighbours in its place (rounded to
whole counts when the channel's data are encoder counts): the sample then carries no
information of its own, every figure computed from the data (residual RMS against the
floor, metrics, diagnosis maps) stays consistent, and the measured value is kept in the
:class:`Glitch` record.  Near the ends of the record the stretch reaches further inwards
(the first and last samples are judged by a cubic through samples on one side).  Four or
more bad samples within 13 are not a spike: nothing is found there, and they are fitted as
measured.

This module does the arithmetic on one channel's array;
:func:`rotorbayes.io.measurements.leave_out_glitches` applies it to an
:class:`~rotorbayes.io.measurements.Experiment`, and
:func:`rotorbayes.io.measurements.load_experiment` does so by default.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass
from itertools import combinations

import numpy as np

__all__ = [
    "MIN_COUNTS",
    "NOISE_FACTOR",
    "MAX_BURST",
    "HALF_WINDOW",
    "Glitch",
    "find_glitches",
    "threshold",
    "repaired",
    "glitch_lines",
    "glitch_record",
]

#: Smallest departure (encoder counts) a glitch must have from the cubic through its
#: neighbours: far above rounding (at most 1.33 counts of the fourth difference over 6)
#: and above what the motion gives (at most 0.13 counts on exact reference brake data with
#: stick-slip at 200 Hz; 5 counts with rounding, at the record's ends where the cubic
#: extrapolates).
MIN_COUNTS = 15.0
#: With noisier data than the encoder's rounding the threshold is this many times the
#: robust spread (1.4826 x median absolute value) of the departures.
NOISE_FACTOR = 8.0
#: Most bad samples (consecutive or nearby: within 13 samples) treated as one glitch.
MAX_BURST = 3
#: A set tried as a glitch lies within HALF_WINDOW + 2 samples of its candidate, and its
#: cubic is fitted to the samples from HALF_WINDOW + 2 before the set to as many after it.
HALF_WINDOW = 4
#: Fewest samples (not in the glitch) a cubic is fitted to.
_MIN_FIT = 7


@dataclass(frozen=True)
class Glitch:
    """One sample of one channel that departs from its neighbours by far more than the
    motion allows.

    Attributes
    ----------
    channel : str
        ``'theta_u'`` or ``'theta_l'``.
    index : int
        0-based sample number (the data row: file line = header line + 1 + index).
    time : float
        Its time [s].
    counts : float
        How far the measured value lies from the cubic through its neighbours, in encoder
        counts of the channel (signed: positive above).
    measured : float
        The measured angle [rad].
    smooth : float
        The cubic through its neighbours there [rad], rounded to counts for count data:
        what replaces the sample when it is left out.
    left_out : bool
        Whether the experiment holds ``smooth`` (left out) or ``measured`` (kept).
    """

    channel: str
    index: int
    time: float
    counts: float
    measured: float
    smooth: float
    left_out: bool = True

    def words(self) -> str:
        """``'theta_l at t = 3.217 s (sample 3217): +87 counts'``."""
        return (
            f"{self.channel} at t = {self.time:.6g} s (sample {self.index}): "
            f"{self.counts:+.0f} counts"
        )

    def as_dict(self) -> dict:
        """The record as plain JSON types."""
        return {k: (float(v) if isinstance(v, float) else v) for k, v in asdict(self).items()}


def _departures(y: np.ndarray) -> np.ndarray:
    """Departure of each sample from the cubic through its two neighbours on each side
    (the fourth difference over 6); at the two first and two last samples, from the cubic
    through the four next samples on the inner side."""
    n = y.size
    e = np.zeros(n)
    if n < 5:
        return e
    e[2:-2] = (y[:-4] - 4 * y[1:-3] + 6 * y[2:-2] - 4 * y[3:-1] + y[4:]) / 6.0
    # Cubic extrapolation by one sample: y0 ~ 4 y1 - 6 y2 + 4 y3 - y4.
    e[0] = y[0] - (4 * y[1] - 6 * y[2] + 4 * y[3] - y[4])
    e[-1] = y[-1] - (4 * y[-2] - 6 * y[-3] + 4 * y[-4] - y[-5])
    if n >= 6:
        # The second sample: the cubic through samples 0, 2, 3, 4 (x = -1, 1, 2, 3 at 0).
        e[1] = y[1] - (y[0] * 0.25 + y[2] * 1.5 - y[3] + y[4] * 0.25)
        e[-2] = y[-2] - (y[-1] * 0.25 + y[-3] * 1.5 - y[-4] + y[-5] * 0.25)
    return e


def _cubic_at(x_fit: np.ndarray, y_fit: np.ndarray, x_at: np.ndarray):
    """Least-squares cubic through (x_fit, y_fit): its values at x_at and the largest
    |residual| at the fitted points."""
    V = np.vander(x_fit.astype(float), 4)
    coef, *_ = np.linalg.lstsq(V, y_fit, rcond=None)
    worst = float(np.max(np.abs(V @ coef - y_fit)))
    return np.vander(x_at.astype(float), 4) @ coef, worst


def _window(S: tuple, n: int) -> tuple[int, int]:
    """The samples ``[lo, hi)`` whose cubic judges the set ``S``: HALF_WINDOW + 2 beyond it
    on each side, more on one side where the record ends on the other."""
    reach = HALF_WINDOW + 2
    lo, hi = S[0] - reach, S[-1] + reach + 1
    if lo < 0:
        lo, hi = 0, hi - lo
    if hi > n:
        lo, hi = max(0, lo - (hi - n)), n
    return lo, hi


def _test(y: np.ndarray, c: int, thr: float, tried: set):
    """The smallest set of up to MAX_BURST samples within HALF_WINDOW + 2 of ``c`` that is
    a glitch, with its cubic values and departures, or None.  ``tried`` holds the sets
    already refused (a set is judged the same way whichever candidate proposes it)."""
    n = y.size
    reach = HALF_WINDOW + 2
    near = range(max(0, c - reach), min(n, c + reach + 1))
    best = None
    for k in range(1, MAX_BURST + 1):
        for S in combinations(near, k):
            if c not in range(S[0] - 2, S[-1] + 3) or S in tried:
                continue  # a set far from c is some other candidate's
            tried.add(S)
            lo, hi = _window(S, n)
            idx = np.arange(lo, hi)
            clean = idx[~np.isin(idx, S)]
            if clean.size < _MIN_FIT:
                continue
            at, worst = _cubic_at(clean - float(c), y[clean], np.array(S) - float(c))
            dev = y[list(S)] - at
            if not np.all(np.abs(dev) > thr) or worst > 0.5 * thr:
                continue
            if best is None or worst < best[3]:
                best = (S, at, dev, worst)
        if best is not None:
            return best
    return None


def threshold(theta: np.ndarray, q: float) -> float:
    """The departure (counts) above which a sample can be a glitch (see the module)."""
    e = _departures(np.asarray(theta, float) / q)
    spread = 1.4826 * float(np.median(np.abs(e))) if e.size else 0.0
    return max(MIN_COUNTS, NOISE_FACTOR * spread)


def find_glitches(
    t: np.ndarray, theta: np.ndarray, channel: str, counts_per_rev: float
) -> list[Glitch]:
    """The glitches of one channel (see the module for how they are found).

    Parameters
    ----------
    t : array
        Sample times [s].
    theta : array
        The channel's angles [rad].
    channel : str
        Its name, ``'theta_u'`` or ``'theta_l'`` (kept in the records).
    counts_per_rev : float
        The channel's encoder resolution (counts per revolution).

    Returns
    -------
    list of Glitch
        In time order, ``left_out=True``, with the cubic through the neighbours (rounded to
        whole counts when every sample is a whole number of counts) as ``smooth``.
    """
    theta = np.asarray(theta, float)
    t = np.asarray(t, float)
    n = theta.size
    if n < 2 * HALF_WINDOW + 5:
        return []
    q = 2.0 * math.pi / counts_per_rev
    y = theta / q
    on_grid = bool(np.all(np.abs(y - np.round(y)) < 1e-6))
    thr = threshold(theta, q)
    e = _departures(y)
    order = np.flatnonzero(np.abs(e) > 0.5 * thr)
    order = order[np.argsort(-np.abs(e[order]), kind="stable")]
    y = y.copy()
    found: dict[int, tuple[float, float]] = {}
    tried: set = set()
    for c in order:
        a = max(0, c - 4)
        if abs(_departures(y[a : min(n, c + 5)])[c - a]) <= 0.5 * thr:
            continue  # a glitch already left out made this candidate
        hit = _test(y, int(c), thr, tried)
        if hit is None:
            continue
        S, at, dev, _ = hit
        for i, v, d in zip(S, at, dev, strict=True):
            v = float(np.round(v)) if on_grid else float(v)
            found[int(i)] = (float(d), v)
            y[i] = v
        tried.clear()  # the data changed: sets near it may be tried again
    return [
        Glitch(channel, i, float(t[i]), d, float(theta[i]), v * q + 0.0)
        for i, (d, v) in sorted(found.items())
    ]


def repaired(theta: np.ndarray, glitches: Iterable[Glitch], *, keep: bool = False) -> np.ndarray:
    """A copy of ``theta`` with every glitch's sample replaced by its ``smooth`` value (by
    its ``measured`` value with ``keep``)."""
    out = np.array(theta, float, copy=True)
    for g in glitches:
        out[g.index] = g.measured if keep else g.smooth
    return out


def _named(experiments) -> list[tuple[str, str, list[Glitch]]]:
    """``(role, name, glitches)`` of ``(role, experiment)`` pairs."""
    return [
        (
            role,
            str(getattr(ex, "name", "") or getattr(ex, "path", "") or "?"),
            list(getattr(ex, "glitches", None) or ()),
        )
        for role, ex in experiments
    ]


def glitch_lines(experiments: Sequence[tuple[str, object]]) -> list[str]:
    """What to print about the glitches of ``(role, experiment)`` pairs (role e.g.
    ``'estimation'``): a line saying how many there are and whether they were left out,
    then one line per experiment with glitches, each glitch named (channel, time, sample,
    size in counts); nothing when there are none."""
    named = _named(experiments)
    found = [g for _, _, gs in named for g in gs]
    if not found:
        return []
    out = sum(g.left_out for g in found)
    how = []
    if out:
        how.append(
            f"{out} left out (each replaced by the cubic through its neighbours, so "
            "it carries no weight of its own; `fit --keep-glitches` keeps them)"
        )
    if len(found) - out:
        how.append(
            f"{len(found) - out} KEPT as measured (--keep-glitches): they count in "
            "the fit and its residual RMS"
        )
    lines = [
        f"glitches: {len(found)} sample(s) jump against their neighbours by far more "
        f"than the discs can move (encoder spikes); {' and '.join(how)}:"
    ]
    for role, name, gs in named:
        if gs:
            lines.append(f"  {name} ({role} data): " + "; ".join(g.words() for g in gs))
    return lines


def glitch_record(experiments: Sequence[tuple[str, object]]) -> dict:
    """The glitches of ``(role, experiment)`` pairs as a JSON-ready record (fit.json's
    ``"glitches"``): how many were found, left out and kept, and per experiment each
    glitch's channel, sample, time, size in counts, measured and smooth value."""
    named = _named(experiments)
    found = [g for _, _, gs in named for g in gs]
    return {
        "found": len(found),
        "left_out": int(sum(g.left_out for g in found)),
        "kept": int(sum(not g.left_out for g in found)),
        "how": "a glitch left out is replaced by the cubic through its neighbours (the "
        "measured value is in its record); one kept is fitted as measured",
        "experiments": [
            {"role": role, "name": name, "glitches": [g.as_dict() for g in gs]}
            for role, name, gs in named
        ],
    }

"""Measurement files for the drill-string rig: load, validate, save.

File format
-----------
A UTF-8 CSV file in SI units (s, V, rad), uniformly sampled::

    # source: synthetic
    # configuration: brake
    t,u,theta_u,theta_l
    0.0,0.0,0.0,0.0
    0.001,1.4e-07,0.0,0.0
    ...

* Optional comment lines starting with ``#`` may precede the header. Lines of the form
  ``# key: value`` are kept in :attr:`Experiment.meta`; other comment lines are ignored.
* The header names the columns: ``t,u,theta_u,theta_l`` for a configuration with the lower
  disc, ``t,u,theta_u`` for the upper configuration (string removed). Columns may appear in
  any order; :func:`save_experiment` always writes them in this order.
* Both encoders are zeroed at the start of an experiment, so the first angle of each column
  must be 0 within about 1e-2 rad. A pre-wound string is therefore invisible in the angles;
  it belongs in the model's ``alpha0`` parameter.
* Time is in seconds and may start at any value (only differences are used). The rig's
  encoders are sampled at tens of Hz to tens of kHz and an experiment lasts seconds to about
  an hour, so a sample interval of :data:`MAX_SAMPLE_INTERVAL` (0.5 s) or more, or a record
  longer than :data:`MAX_DURATION` (2 h), means the time is in another unit (usually
  milliseconds) and is refused.
* Every line ends with a line break, the last one included. A last line without one is what
  a file cut off while being written or copied looks like (its last number may be
  incomplete), so it is refused. Empty lines after the data are fine.

:func:`load_experiment` checks all of this and raises :class:`DataFileError` naming the file,
the line (1-based, counting every line of the file, comments included), the bad value and what
to do about it.

A rig's own files
-----------------
``load_experiment(path, read=ReadSpec(...))`` reads what a rig records as it is: MATLAB
``.mat`` files (v5 and v7.3, recognised by their content), CSV files separated by
semicolons or tabs with decimal commas, other columns and a logger's units row, with the
file's names of the signals and its units of time (s, ms) and angle (rad, deg, encoder
counts) declared (:mod:`rotorbayes.io.rigfiles`).  The declared conversions are applied
before the checks above, which then hold as for a CSV in SI units; undeclared
milliseconds, degrees or counts are refused, and the message names the option
(``--time-unit``, ``--angle-unit``) that declares them.  A ``.mat`` file's problems name
the sample (1-based) instead of a line.

Glitches
--------
Encoder lines pick up spikes: a sample (or a burst of up to three within 13 samples) that
reads tens to hundreds of counts off while its neighbours read right. :func:`load_experiment`
finds them (:mod:`rotorbayes.io.glitches`), names each in :attr:`Experiment.glitches` (channel,
time, sample, size in counts, the measured value) and leaves it out: the sample then holds
the cubic through its neighbours, so it carries no weight of its own and every figure
computed from the data stays consistent. ``keep_glitches=True`` (``--keep-glitches`` of
``fit`` and ``multistart``) keeps the measured values; either way ``fit`` prints each glitch
and records it in fit.json under ``"glitches"``. :func:`save_experiment` writes the measured
values back. Glitches never raise the noise floor: only jitter through most of the record
does (:func:`jitter_evidence`).
"""

import array
import codecs
import hashlib
import io
import itertools
import math
import os
import secrets
import stat
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import glitches as _glitches
from . import rigfiles as _rig
from .glitches import Glitch
from .rigfiles import FormatProblem, ReadSpec

__all__ = [
    "UPPER_COUNTS_PER_REV",
    "LOWER_COUNTS_PER_REV",
    "quantisation_floor",
    "jitter_rms",
    "JITTER_FACTOR",
    "Jitter",
    "jitter_evidence",
    "COLUMNS",
    "UPPER_COLUMNS",
    "MAX_ANGULAR_RATE",
    "MAX_SAMPLE_INTERVAL",
    "MAX_DURATION",
    "MAX_DATA_BYTES",
    "MAX_DATA_ROWS",
    "MAX_BYTES_ENV",
    "MAX_ROWS_ENV",
    "DataFileError",
    "DataWarning",
    "Experiment",
    "Glitch",
    "leave_out_glitches",
    "load_experiment",
    "measurement_sha256",
    "check_data_file",
    "save_experiment",
    "quantize",
    "add_noise",
]

#: Upper encoder resolution (counts per revolution of the upper disc), thesis §2.2: the encoder
#: sits on the motor axis (1000 lines, x4 quadrature) behind a 3969/289 gear reduction.
UPPER_COUNTS_PER_REV = 54934.256
#: Lower encoder resolution (counts per revolution of the lower disc): 10000 lines, x4.
LOWER_COUNTS_PER_REV = 40000.0


def quantisation_floor(channel: str) -> float:
    """RMS error [rad] that rounding to encoder counts alone leaves in a channel: the step
    ``2π / counts`` over √12 (thesis §2.2).  ``'alpha'`` combines both encoders.

    A fit whose residual RMS is at this floor explains the data to the encoders' resolution;
    a multiple of it is how far the model is from that.
    """
    q = {k: 2 * math.pi / c / math.sqrt(12) for k, c in _COUNTS_PER_REV.items()}
    if channel == "alpha":
        return math.hypot(q["theta_u"], q["theta_l"])
    try:
        return q[channel]
    except KeyError:
        raise ValueError(f"unknown channel {channel!r}; choose theta_u, theta_l or alpha") from None


def jitter_rms(theta: np.ndarray, window: int = 11) -> float:
    """Sample-to-sample noise of a measured angle [rad RMS]: the residual of a local cubic
    fit (Savitzky-Golay, ``window`` samples), corrected for the fit's own leverage.

    For encoder-quantised data of a moving disc it is about the quantisation floor; a
    clearly larger value means the data carry other noise (electrical, or added by a
    simulator), which the noise floor must include.
    """
    from ..util.smoothing import savgol_coeffs, savgol_filter

    theta = np.asarray(theta, float)
    if theta.size < 3 * window:
        return float("nan")
    c0 = float(savgol_coeffs(window, 3)[window // 2])
    r = theta - savgol_filter(theta, window, 3)
    return float(np.sqrt(np.mean(r**2) / (1.0 - c0)))


#: A channel's jitter above this multiple of its quantisation floor, through most of the
#: record, is broad-band noise that the noise floor must include.
JITTER_FACTOR = 1.3


@dataclass(frozen=True)
class Jitter:
    """How much a measured angle jitters from sample to sample, and where: the evidence for
    raising a noise floor above the encoder's (see :func:`jitter_evidence`).

    Attributes
    ----------
    channel : str
    rms : float
        Typical jitter [rad RMS]: the median over the stretches of the local cubic's
        residual, corrected for its leverage (as :func:`jitter_rms`).
    quantisation : float
        The channel's quantisation floor [rad RMS].
    n_samples, n_beyond : int
        Samples judged, and those further from the local cubic than rounding to counts can
        put them (none for a disc whose only noise is the encoder's rounding).
    stretches, stretches_above : int
        Equal stretches of the record, and those whose jitter exceeds
        :data:`JITTER_FACTOR` x the quantisation floor.
    stretch_seconds : float
        Length of a stretch [s].
    band : tuple of float
        The frequencies [Hz] the local cubic's residual passes (above its -3 dB point, up
        to half the sampling rate): the band of the jitter.
    """

    channel: str
    rms: float
    quantisation: float
    n_samples: int
    n_beyond: int
    stretches: int
    stretches_above: int
    stretch_seconds: float
    band: tuple[float, float]

    @property
    def broadband(self) -> bool:
        """Whether the jitter is noise through most of the record, above the encoder's
        rounding: more than half the stretches (so the median) above
        :data:`JITTER_FACTOR` x the quantisation floor.  A few spikes, a short burst of
        vibration or glitches that were kept raise some stretches only."""
        return bool(
            math.isfinite(self.rms)
            and self.rms > JITTER_FACTOR * self.quantisation
            and 2 * self.stretches_above > self.stretches
        )

    def words(self) -> str:
        """The evidence in a sentence."""
        lo, hi = self.band
        return (
            f"the measured {self.channel} jitters at {self.rms:.2g} rad RMS from sample "
            f"to sample ({self.rms / self.quantisation:.2g}x the encoder quantisation, "
            f"{self.quantisation:.2g} rad) in {self.stretches_above} of {self.stretches} "
            f"stretches of {self.stretch_seconds:.3g} s, in the band {lo:.3g}-{hi:.3g} "
            f"Hz; {self.n_beyond} of {self.n_samples} samples lie further from the "
            f"local cubic than rounding to counts can put them"
        )


def jitter_evidence(theta: np.ndarray, dt: float, channel: str, window: int = 11) -> Jitter | None:
    """The jitter of a measured angle, stretch by stretch (see :class:`Jitter`); ``None``
    for records too short to judge (fewer than 3 ``window``-sample stretches' worth).

    The record is cut into about one stretch per second (4 to 60 stretches, each at least
    3 ``window`` samples); each stretch's jitter is the RMS of the residual of a local
    cubic (Savitzky-Golay, ``window`` samples) corrected for the fit's leverage.
    """
    from ..util.smoothing import savgol_coeffs, savgol_filter

    theta = np.asarray(theta, float)
    n = theta.size
    if n < 3 * window or not dt > 0:
        return None
    coeffs = savgol_coeffs(window, 3)
    c0 = float(coeffs[window // 2])
    r = theta - savgol_filter(theta, window, 3)
    h = -coeffs
    h[window // 2] += 1.0  # the residual filter
    q = quantisation_floor(channel)
    step = q * math.sqrt(12.0)  # one count [rad]
    bound = 0.5 * step * float(np.sum(np.abs(h)))
    n_beyond = int(np.count_nonzero(np.abs(r) > bound * (1.0 + 1e-9)))
    duration = n * dt
    k = int(min(60, max(4, round(duration)), n // (3 * window)))
    k = max(k, 1)
    parts = np.array_split(r, k)
    per = np.array([math.sqrt(float(np.mean(p**2)) / (1.0 - c0)) for p in parts])
    freqs = np.linspace(0.0, 0.5, 2001)
    gain = np.abs(np.exp(-2j * np.pi * np.outer(freqs, np.arange(window) - window // 2)) @ h)
    f3 = float(freqs[int(np.argmax(gain >= 1.0 / math.sqrt(2.0)))])
    return Jitter(
        channel,
        float(np.median(per)),
        q,
        n,
        n_beyond,
        k,
        int(np.count_nonzero(per > JITTER_FACTOR * q)),
        duration / k,
        (f3 / dt, 0.5 / dt),
    )


#: Column names of a file with the lower disc, in the order :func:`save_experiment` writes them.
COLUMNS: tuple[str, ...] = ("t", "u", "theta_u", "theta_l")
#: Column names of an upper-configuration file (string removed, no lower encoder).
UPPER_COLUMNS: tuple[str, ...] = ("t", "u", "theta_u")

#: Fastest plausible disc speed (rad/s). The rig's discs never exceed about 60 rad/s, so a
#: faster apparent speed means the angles are not in radians.
MAX_ANGULAR_RATE = 60.0

#: Sample interval (s) from which on the time column is taken to be in another unit than
#: seconds. The rig's encoders are sampled at tens of Hz to tens of kHz (steps of 0.1 s down to
#: tens of microseconds), so a step of 0.5 s or more is 1 kHz data in milliseconds (step 1),
#: 200 Hz data in milliseconds (step 5) and the like -- never a real measurement.
MAX_SAMPLE_INTERVAL = 0.5
#: Longest accepted record ``t[-1] - t[0]`` (s). Experiments on the rig last seconds to about an
#: hour; a longer record with a small step is fast-sampled data in milliseconds (10 kHz data in
#: ms has the step 0.1 of a legitimate 10 Hz file, but 30 s of it "last" 30 000 s).
MAX_DURATION = 7200.0
#: Largest |angle| a file may hold (rad): the fastest turning for the longest record.
MAX_ABS_ANGLE = MAX_ANGULAR_RATE * MAX_DURATION
#: Largest |input voltage| a file may hold (V); beyond ±5 V a file is only warned about.
MAX_ABS_INPUT = 1000.0

_COUNTS_PER_REV = {"theta_u": UPPER_COUNTS_PER_REV, "theta_l": LOWER_COUNTS_PER_REV}
_ENCODER_NAME = {"theta_u": "upper", "theta_l": "lower"}
#: How the guards name the options that declare a file's units (command line; analysis file).
TIME_OPTION = '--time-unit ms (analysis file: time_unit = "ms")'
DEG_OPTION = '--angle-unit deg (analysis file: angle_unit = "deg")'
COUNTS_OPTION = '--angle-unit counts (analysis file: angle_unit = "counts")'
# Encoders read zero at the start; allow a few counts of slack (1e-2 rad ~ 60-90 counts).
_ZERO_START_TOL = 1e-2
# Largest relative deviation of a time step from the median step before we call the sampling
# non-uniform. Timestamps written with 12+ significant digits stay far inside this.
_UNIFORM_TOL = 1e-3
_MIN_ROWS = 3
# Slowest and fastest sampling rates (Hz) that a guessed time unit may imply.
_MIN_RATE = 10.0
_MAX_RATE = 1e5
# Longest line text quoted in a message.
_MAX_QUOTE = 80
#: Largest measurement file read (bytes), checked before a byte is read: the rig's longest
#: record, 2 h at 1 kHz, takes about 600 MB (a row of four shortest round-trip numbers
#: is about 80 characters). ``ROTORBAYES_MAX_DATA_MB`` (:data:`MAX_BYTES_ENV`) raises it.
MAX_DATA_BYTES = 1_000_000_000
#: Most data rows read (2 h at 1 kHz are 7.2 million); reading stops at the first row
#: beyond. ``ROTORBAYES_MAX_DATA_ROWS`` (:data:`MAX_ROWS_ENV`) raises it.
MAX_DATA_ROWS = 10_000_000
#: Environment variables that set the two limits (a size in MB; a number of rows).
MAX_BYTES_ENV = "ROTORBAYES_MAX_DATA_MB"
MAX_ROWS_ENV = "ROTORBAYES_MAX_DATA_ROWS"
# Longest line read (characters): a data row has a few dozen, a comment line a few hundred;
# a longer one (a binary or sparse file without line breaks) is refused as soon as it is met.
_MAX_LINE = 65_536
# What a file that is not a regular file is, by its type (stat.S_IFMT).
_FILE_KINDS = {
    stat.S_IFIFO: "a pipe (a named pipe, or a stream such as <(...) or /dev/stdin)",
    stat.S_IFCHR: "a character device (such as /dev/zero or /dev/urandom)",
    stat.S_IFBLK: "a block device (a disk)",
    stat.S_IFSOCK: "a socket",
}
# Angular rates are measured over about 10 ms rather than one sample so that measurement
# noise at high sampling rates cannot fake a speed above MAX_ANGULAR_RATE.
_RATE_BASELINE = 0.01


class DataFileError(ValueError):
    """A measurement file that cannot be used, with the place and the fix in the message.

    Attributes
    ----------
    path : str or None
        The file concerned.
    line : int or None
        1-based line number in the file (comment lines included), if one line is at fault.
    problem : str
        The message without the ``"<path>, line <n>: "`` prefix.
    """

    def __init__(self, path: str | os.PathLike | None, line: int | None, problem: str) -> None:
        self.path = None if path is None else str(path)
        self.line = line
        self.problem = problem
        where = self.path if self.path is not None else "<data>"
        if line is not None:
            where = f"{where}, line {line}"
        super().__init__(f"{where}: {problem}")

    def __reduce__(self):
        # The default reduction re-calls __init__ with the formatted message only.
        return (type(self), (self.path, self.line, self.problem))


class DataWarning(UserWarning):
    """Suspicious but usable data, e.g. input voltages beyond the amplifier's ±5 V."""


@dataclass(frozen=True, eq=False)
class Experiment:
    """One experiment on the rig: input voltage and measured disc angles.

    The arrays are copied to contiguous ``float64`` on construction (so a caller's later
    edits cannot change the experiment) and are left writeable, because numba kernels with
    explicit signatures reject read-only arrays. Treat them as read-only anyway.

    Equality is identity (``eq=False``): comparing arrays element-wise with ``==`` would be
    ambiguous. Compare fields with :func:`numpy.array_equal` instead.

    Parameters
    ----------
    t : numpy.ndarray
        Sample times (s), uniformly spaced, shape ``(n,)``, ``n >= 2``.
    u : numpy.ndarray
        Motor input voltage (V), shape ``(n,)``.
    theta_u : numpy.ndarray
        Upper disc angle (rad), zero at the start, shape ``(n,)``.
    theta_l : numpy.ndarray or None
        Lower disc angle (rad), zero at the start, shape ``(n,)``; ``None`` for the upper
        configuration (string removed).
    name : str
        Short label, e.g. the file stem.
    path : str or None
        File the experiment was loaded from, if any.
    meta : dict of str to str
        Free-form metadata, written as ``# key: value`` comment lines.
    glitches : tuple of Glitch or None
        The glitches found in the angles (:mod:`rotorbayes.io.glitches`): samples that jump
        against their neighbours by far more than the discs can move.  Each says whether
        it was left out (the arrays hold the cubic through its neighbours there) or kept
        (the arrays hold the measured value).  ``None``: not looked for (an experiment
        made in Python; :func:`leave_out_glitches` looks); ``()``: none found.
    sha256 : str or None
        SHA-256 (hex) of the bytes read from ``path`` (:func:`load_experiment`), so that a
        result can record exactly what it was made from; None when not read from a file.
    """

    t: np.ndarray
    u: np.ndarray
    theta_u: np.ndarray
    theta_l: np.ndarray | None = None
    name: str = ""
    path: str | None = None
    meta: dict[str, str] = field(default_factory=dict)
    glitches: tuple[Glitch, ...] | None = None
    sha256: str | None = None

    def __post_init__(self) -> None:
        arrays = {"t": self.t, "u": self.u, "theta_u": self.theta_u}
        if self.theta_l is not None:
            arrays["theta_l"] = self.theta_l
        n = None
        for key, value in arrays.items():
            array = np.array(value, dtype=np.float64, copy=True, order="C")
            if array.ndim != 1:
                raise ValueError(
                    f"Experiment.{key} must be a 1-D array, got shape {array.shape}; "
                    "pass one value per sample"
                )
            if n is None:
                n = array.size
            elif array.size != n:
                raise ValueError(
                    f"Experiment.{key} has {array.size} samples but t has {n}; all columns "
                    "must have one value per sample time"
                )
            # frozen=True forbids normal assignment; this is the documented way to normalise
            # fields of a frozen dataclass during construction.
            object.__setattr__(self, key, array)
        if n < 2:
            raise ValueError(f"Experiment needs at least 2 samples, got {n}")
        object.__setattr__(self, "meta", {str(k): str(v) for k, v in dict(self.meta).items()})
        if self.path is not None:
            object.__setattr__(self, "path", str(self.path))
        if self.glitches is not None:
            object.__setattr__(self, "glitches", tuple(self.glitches))

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.t.size)

    @property
    def dt(self) -> float:
        """Sampling interval (s), the mean step ``(t[-1] - t[0]) / (n - 1)``."""
        return float((self.t[-1] - self.t[0]) / (self.t.size - 1))

    @property
    def duration(self) -> float:
        """Length of the record ``t[-1] - t[0]`` (s)."""
        return float(self.t[-1] - self.t[0])

    @property
    def has_lower(self) -> bool:
        """Whether the lower disc angle ``theta_l`` was measured."""
        return self.theta_l is not None

    def columns(self) -> dict[str, np.ndarray]:
        """The data columns by name, in file order (``theta_l`` only if measured)."""
        cols = {"t": self.t, "u": self.u, "theta_u": self.theta_u}
        if self.theta_l is not None:
            cols["theta_l"] = self.theta_l
        return cols


# --------------------------------------------------------------------------------------------
# Checks shared by load and save


class RowProblem(Exception):
    """A problem at data row ``row`` (0-based); converted to a file/line error by the caller."""

    def __init__(self, row: int, problem: str) -> None:
        super().__init__(problem)
        self.row = row
        self.problem = problem


def _time_unit_guess(step: float) -> tuple[str, float] | None:
    """The likeliest unit of a time column with the (too long) step ``step``, and its factor.

    The smallest of ms, us and ns in which the step means sampling at :data:`_MIN_RATE` or
    faster; ``None`` if even nanoseconds give slower sampling.
    """
    for unit, factor in (("milliseconds", 1e3), ("microseconds", 1e6), ("nanoseconds", 1e9)):
        if step / factor <= 1.0 / _MIN_RATE:
            return unit, factor
    return None


def check_time_unit(t: np.ndarray, dt: np.ndarray) -> None:
    """Refuse a strictly increasing time column that is not in seconds (:class:`RowProblem`).

    Two rules, both far from any real measurement on the rig: a (median) sample interval of
    :data:`MAX_SAMPLE_INTERVAL` or more, and a record longer than :data:`MAX_DURATION`. The
    first catches milliseconds at up to 2 kHz (and micro-/nanoseconds); the second catches
    faster data in milliseconds, whose step (e.g. 0.1 for 10 kHz) alone looks plausible.
    """
    step = float(np.median(dt))
    duration = float(t[-1] - t[0])
    if step >= MAX_SAMPLE_INTERVAL:
        # At least half the steps are >= the median, so such a step exists.
        k = int(np.flatnonzero(dt >= MAX_SAMPLE_INTERVAL)[0])
        as_seconds = (
            f"read as seconds, this is a {duration:.6g} s experiment sampled at "
            f"{1.0 / step:.3g} Hz, but the rig is sampled at tens of Hz to tens of kHz, so a "
            f"step of {MAX_SAMPLE_INTERVAL:g} s or more is not in seconds"
        )
        guess = _time_unit_guess(step)
        if guess is None:
            raise RowProblem(
                k + 1,
                f"time step {dt[k]:.6g} (from t = {float(t[k])!r} to {float(t[k + 1])!r}) is "
                f"far too long: {as_seconds}; the t column must be in seconds -- convert it "
                f"(a time in ms is read with {TIME_OPTION})",
            )
        unit, factor = guess
        raise RowProblem(
            k + 1,
            f"time step {dt[k]:.6g} (from t = {float(t[k])!r} to {float(t[k + 1])!r}) looks "
            f"like {unit}: {as_seconds}; in {unit} it is a {duration / factor:.6g} s "
            f"experiment at {factor / step:.6g} Hz. The t column must be in seconds -- divide "
            f"it by {factor:.0f}"
            + (f", or declare the unit: {TIME_OPTION}" if factor == 1e3 else ""),
        )
    if duration > MAX_DURATION:
        k = int(np.flatnonzero(t - t[0] > MAX_DURATION)[0])
        if 1e3 / step > _MAX_RATE:
            # In milliseconds this step would be sampling faster than the rig's encoders are
            # ever read, so a genuinely long record in seconds is the likelier explanation.
            fix = (
                f"if t is not in seconds, convert it; if the record really is this long, split "
                f"it into files of at most {MAX_DURATION:g} s"
            )
        else:
            fix = (
                f"it looks like milliseconds (then a {duration / 1e3:.6g} s experiment at "
                f"{1e3 / step:.6g} Hz): the t column must be in seconds -- divide it by 1000 "
                f"or declare the unit, {TIME_OPTION} (if the record really is this long, "
                f"split it into files of at most {MAX_DURATION:g} s)"
            )
        raise RowProblem(
            k,
            f"time t = {float(t[k])!r} is more than {MAX_DURATION:g} s ({MAX_DURATION / 3600:g} "
            f"h) after the first sample (t = {float(t[0])!r}); the record lasts "
            f"{duration:.6g} s ({duration / 3600:.3g} h), but experiments on the rig last "
            f"seconds to about an hour; {fix}",
        )


def _check_columns(cols: Mapping[str, np.ndarray], read: ReadSpec | None = None) -> None:
    """Check finite values, uniform time in s, zeroed angles in rad; raise :class:`RowProblem`.
    ``read``: how the file was read (its declared units are named in the messages)."""
    for key, values in cols.items():
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            row = int(bad[0])
            raise RowProblem(
                row,
                f"{key} is {float(values[row])!r}; every value must be a finite number -- "
                "repair or remove this sample (and keep the sampling uniform)",
            )
    # Magnitudes no experiment can have: corrupt values, before any unit guess.
    for key, limit, why in (
        (
            "u",
            MAX_ABS_INPUT,
            f"no amplifier of the rig gives more than {MAX_ABS_INPUT:g} V "
            "(the thesis's gives ±5 V)",
        ),
        (
            "theta_u",
            MAX_ABS_ANGLE,
            f"no experiment reaches it ({MAX_ANGULAR_RATE:g} rad/s "
            f"for {MAX_DURATION:g} s is {MAX_ABS_ANGLE:g} rad)",
        ),
        (
            "theta_l",
            MAX_ABS_ANGLE,
            f"no experiment reaches it ({MAX_ANGULAR_RATE:g} rad/s "
            f"for {MAX_DURATION:g} s is {MAX_ABS_ANGLE:g} rad)",
        ),
    ):
        if key not in cols:
            continue
        over = np.flatnonzero(np.abs(cols[key]) > limit)
        if over.size:
            row = int(over[0])
            unit = "V" if key == "u" else "rad"
            raise RowProblem(
                row,
                f"{key} is {float(cols[key][row])!r} {unit}: {why}; the value is corrupt or in "
                "another unit -- repair or remove this sample",
            )
    t = cols["t"]
    dt = np.diff(t)
    bad = np.flatnonzero(dt <= 0)
    if bad.size:
        k = int(bad[0])
        raise RowProblem(
            k + 1,
            f"time t = {float(t[k + 1])!r} s is not after the previous time {float(t[k])!r} s; "
            "time must be strictly increasing -- sort the rows or remove the duplicated sample",
        )
    check_time_unit(t, dt)
    step = float(np.median(dt))
    deviation = np.abs(dt - step) / step
    bad = np.flatnonzero(deviation > _UNIFORM_TOL)
    if bad.size:
        k = int(bad[0])
        raise RowProblem(
            k + 1,
            f"time step {dt[k]:.9g} s (from t = {float(t[k])!r} to {float(t[k + 1])!r} s) "
            f"differs from the expected step {step:.9g} s (the median) by a relative "
            f"{deviation[k]:.3g} > {_UNIFORM_TOL:g}; the sampling must be uniform -- check for "
            "missing or repeated rows, time written with too few digits, or resample onto a "
            "uniform grid",
        )
    lag = max(1, min(t.size - 1, round(_RATE_BASELINE / step)))
    for key in ("theta_u", "theta_l"):
        if key not in cols:
            continue
        theta = cols[key]
        rates = np.abs(theta[lag:] - theta[:-lag]) / (t[lag:] - t[:-lag])
        k = int(np.argmax(rates))
        if rates[k] > MAX_ANGULAR_RATE:
            where = (
                f"{key} changes by {theta[k + lag] - theta[k]:.6g} in {t[k + lag] - t[k]:.6g} s "
                f"(from t = {float(t[k]):.6g} to {float(t[k + lag]):.6g} s; a rate of "
                f"{rates[k]:.4g} per s, faster than the rig's discs ever turn, about "
                f"{MAX_ANGULAR_RATE:g} rad/s)"
            )
            declared = read.angle_unit if read is not None else "rad"
            if declared != "rad":
                fix = (
                    f"the file was read with --angle-unit {declared}"
                    + (f" and {read.cpr(key):g} counts/rev" if declared == "counts" else "")
                    + "; check the declared unit (--angle-unit, --counts-per-rev) and the "
                    "column mapping (--columns)"
                )
            elif np.all(np.abs(theta - np.round(theta)) <= 1e-6):
                cpr = _COUNTS_PER_REV[key]
                fix = (
                    f"and all its values are whole numbers: it looks like encoder counts; "
                    f"declare them with {COUNTS_OPTION} (with --counts-per-rev "
                    f"{key}=N if the encoder is not the rig's {cpr:.10g} counts/rev), or divide "
                    f"by counts_per_rev/(2π) = {cpr / (2 * math.pi):.6f} to get rad"
                )
            else:
                fix = (
                    f"it looks like degrees; declare them with {DEG_OPTION}, or multiply "
                    f"by π/180 (= {math.pi / 180:.9f}) to get rad"
                )
            raise RowProblem(k + lag, f"{where}; {fix}")
        if abs(theta[0]) > _ZERO_START_TOL:
            raise RowProblem(
                0,
                f"{key} starts at {float(theta[0])!r} rad, but the encoders are zeroed at the "
                f"start of an experiment (|first value| must be <= {_ZERO_START_TOL:g} rad); "
                "subtract the first value from the whole column (an initial string torsion "
                "belongs in the model's alpha0, not in the angles)",
            )


# --------------------------------------------------------------------------------------------
# Loading


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _parse_header(fields: list[str], path: Path, lineno: int) -> list[str]:
    """Check the header's column names and return them; raise :class:`DataFileError`."""
    expected = f"'{','.join(COLUMNS)}' (or '{','.join(UPPER_COLUMNS)}' without the lower disc)"
    if all(_is_number(f) for f in fields):
        raise DataFileError(
            path,
            lineno,
            f"no header: the first non-comment line {','.join(fields)!r} holds numbers; add the "
            f"header line {expected} above the data",
        )
    duplicates = sorted({f for f in fields if fields.count(f) > 1})
    unknown = [f for f in fields if f not in COLUMNS]
    missing = [c for c in UPPER_COLUMNS if c not in fields]
    if not (duplicates or unknown or missing):
        return fields
    problems = []
    if missing:
        problems.append(f"missing column(s) {', '.join(missing)}")
    if unknown:
        names = ", ".join(repr(f) if f else "'' (an empty name: trailing comma?)" for f in unknown)
        problems.append(f"unknown column(s) {names}")
    if duplicates:
        problems.append(f"repeated column(s) {', '.join(duplicates)}")
    hint = (
        " If the file names its columns otherwise (a logger's or a spreadsheet's names), "
        "map them: --columns t=NAME,u=NAME,theta_u=NAME,theta_l=NAME (the file's other "
        "columns are then ignored)."
    )
    if len(fields) == 1 and " " in fields[0]:
        hint += " Fields must be separated by commas, semicolons or tabs, not spaces."
    raise DataFileError(
        path,
        lineno,
        f"bad header {','.join(fields)!r}: {'; '.join(problems)}. The header must be "
        f"{expected}, with units s, V, rad.{hint}",
    )


def _parse_comment(line: str, meta: dict[str, str]) -> None:
    body = line.lstrip()[1:]
    key, sep, value = body.partition(":")
    key = key.strip()
    # Free-form comments without "key: value" carry no structured metadata; they are skipped.
    if sep and key:
        meta[key] = value.strip()


def _limit(path: Path, given: int | None, env: str, default: int, scale: int, what: str) -> int:
    """A reading limit: ``given``, else the environment variable ``env`` (in units of
    ``scale``), else ``default``."""
    if given is not None:
        if not (isinstance(given, int | float) and given > 0):
            raise ValueError(f"{what} must be a positive number, got {given!r}")
        return int(given)
    text = os.environ.get(env, "").strip()
    if not text:
        return default
    try:
        v = float(text)
    except ValueError:
        v = math.nan
    if not (math.isfinite(v) and v > 0):
        raise DataFileError(
            path,
            None,
            f"the environment variable {env}={text!r} is not a "
            f"positive number; set it to the {what} to allow (or unset it "
            "for the default)",
        )
    return int(v * scale)


def _open_measurement(path: Path, max_bytes: int) -> int:
    """Open ``path`` for reading after checking, before a byte is read, that it is a
    regular file of at most ``max_bytes``; its file descriptor."""
    try:
        # stat() first: a pipe or device is refused without being opened (opening a pipe
        # waits for a writer; a device may do anything).
        st = os.stat(path)
        _check_kind(path, st, max_bytes)
        # O_NONBLOCK: should the path have become a pipe since, the open does not wait.
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except FileNotFoundError:
        raise DataFileError(
            path,
            None,
            f"file not found (looked in {path.resolve().parent}); check the path",
        ) from None
    except OSError as exc:
        raise DataFileError(
            path, None, f"cannot be read ({exc.strerror}); check the permissions"
        ) from None
    try:
        _check_kind(path, os.fstat(fd), max_bytes)  # the file opened is the file checked
        os.set_blocking(fd, True)
    except BaseException:
        os.close(fd)
        raise
    return fd


def _check_kind(path: Path, st: os.stat_result, max_bytes: int) -> None:
    if stat.S_ISDIR(st.st_mode):
        raise DataFileError(path, None, "is a directory; pass the CSV file inside it")
    if not stat.S_ISREG(st.st_mode):
        mode = stat.S_IFMT(st.st_mode)
        kind = _FILE_KINDS.get(mode, "not a regular file")
        why = (
            "a stream can be read only once, and a measurement is read again (the fit "
            "records its SHA-256, later commands read it again)"
            if mode == stat.S_IFIFO
            else "it holds no measurement"
        )
        raise DataFileError(
            path,
            None,
            f"is {kind}, not a regular file: {why}; give a regular file (a measurement "
            "CSV) -- to read a stream, save it first (e.g. `command > data.csv`); nothing "
            "was read",
        )
    if st.st_size > max_bytes:
        raise DataFileError(
            path,
            None,
            f"is {_size(st.st_size)}, more than the {_size(max_bytes)} a "
            "measurement file may have (2 h at 1 kHz, the rig's longest record, take about "
            "600 MB); nothing was read. If it is a measurement, raise the limit: "
            f"{MAX_BYTES_ENV}={math.ceil(st.st_size / 1e6)} (a size in MB)",
        )


def _size(n: int) -> str:
    """A file size in words: "1,074 MB", or "800 bytes" below a megabyte."""
    return f"{n / 1e6:,.0f} MB" if n >= 1_000_000 else f"{n:,} bytes"


class _HashingReader(io.RawIOBase):
    """A file read once: the bytes pass through SHA-256 on their way to the parser."""

    def __init__(self, fd: int) -> None:
        super().__init__()
        self._file = io.FileIO(fd, "rb", closefd=True)
        self.sha256 = hashlib.sha256()

    def readable(self) -> bool:
        return True

    def readinto(self, buffer) -> int:
        n = self._file.readinto(buffer)
        if n:
            self.sha256.update(memoryview(buffer)[:n])
        return n

    def close(self) -> None:
        self._file.close()
        super().close()


def check_data_file(path: str | os.PathLike, *, max_bytes: int | None = None) -> None:
    """Refuse (:class:`DataFileError`), before it is opened, a data file that is missing,
    a folder, not a regular file (a pipe, ``<(...)``, a device) or larger than the size
    limit (``max_bytes``, else ``ROTORBAYES_MAX_DATA_MB``, else :data:`MAX_DATA_BYTES`):
    the checks :func:`load_experiment` makes, for readers of other CSV files."""
    path = Path(path)
    limit = _limit(
        path, max_bytes, MAX_BYTES_ENV, MAX_DATA_BYTES, 1_000_000, "largest file size in MB"
    )
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise DataFileError(
            path,
            None,
            f"file not found (looked in {path.resolve().parent}); check the path",
        ) from None
    except OSError as exc:
        raise DataFileError(
            path, None, f"cannot be read ({exc.strerror}); check the permissions"
        ) from None
    _check_kind(path, st, limit)


def measurement_sha256(path: str | os.PathLike, *, max_bytes: int | None = None) -> str:
    """SHA-256 (hex) of the file ``path``, read in blocks after the checks
    :func:`load_experiment` makes before reading (a regular file, at most ``max_bytes``);
    :class:`DataFileError` otherwise (a pipe is never opened, a device never read)."""
    path = Path(path)
    limit = _limit(
        path, max_bytes, MAX_BYTES_ENV, MAX_DATA_BYTES, 1_000_000, "largest file size in MB"
    )
    raw = _HashingReader(_open_measurement(path, limit))
    try:
        with raw:
            buf = bytearray(1 << 20)
            while raw.readinto(buf):
                pass
    except OSError as exc:
        raise DataFileError(
            path, None, f"cannot be read ({exc.strerror or exc}); check the permissions"
        ) from None
    return raw.sha256.hexdigest()


def _bad_utf8_offset(path: Path) -> int | str:
    """The byte offset of the first byte that is not UTF-8 in ``path`` ("?" if unknown)."""
    decoder = codecs.getincrementaldecoder("utf-8")()
    done = 0
    try:
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 16), b""):
                try:
                    decoder.decode(block)
                except UnicodeDecodeError as exc:
                    return done - len(exc.object) + len(block) + exc.start
                done += len(block)
            decoder.decode(b"", final=True)
    except UnicodeDecodeError as exc:
        return done - len(exc.object) + exc.start
    except OSError:
        pass
    return "?"


#: Characters of a data file decoded at once: the data rows are parsed a chunk at a time
#: where they are plain (:meth:`_Lines.bulk`), everything else line by line.
_CHUNK = 1 << 22


class _Lines:
    """``(line number, line)`` of a text file, each line with its line break; a line with
    NUL characters or longer than :data:`_MAX_LINE` is refused when it is met (a binary or
    sparse file is never read whole).  The file is decoded :data:`_CHUNK` characters at a
    time: the complete lines ahead can be had in one piece (:meth:`bulk`, :meth:`take`)."""

    def __init__(self, fh, path: Path) -> None:
        self.fh = fh
        self.path = path
        self.lineno = 0
        self.buf = ""
        self.pos = 0
        self.eof = False

    def __iter__(self):
        return self

    def _more(self) -> bool:
        if self.eof:
            return False
        chunk = self.fh.read(_CHUNK)
        if not chunk:
            self.eof = True
            return False
        self.buf = self.buf[self.pos :] + chunk
        self.pos = 0
        return True

    def __next__(self) -> tuple[int, str]:
        while True:
            i = self.buf.find("\n", self.pos, self.pos + _MAX_LINE + 1)
            if i >= 0:
                line = self.buf[self.pos : i + 1]
                self.pos = i + 1
                break
            if len(self.buf) - self.pos > _MAX_LINE:
                self._refuse(self.buf[self.pos : self.pos + _MAX_LINE + 1], long=True)
            if not self._more():
                if self.pos >= len(self.buf):
                    raise StopIteration
                line = self.buf[self.pos :]
                self.pos = len(self.buf)
                break
        self.lineno += 1
        if "\0" in line:
            self._refuse(line)
        return self.lineno, line

    def _refuse(self, line: str, long: bool = False) -> None:
        lineno = self.lineno + 1 if long else self.lineno
        if "\0" in line:
            raise DataFileError(
                self.path,
                lineno,
                "holds NUL bytes (binary data, or a sparse or preallocated file that was "
                "never written): not a measurement file; export the measurement as "
                "plain-text CSV",
            )
        raise DataFileError(
            self.path,
            lineno,
            f"longer than {_MAX_LINE} characters (a data row has a few dozen): not a "
            "measurement file; export the measurement as plain-text CSV, one sample a "
            "line",
        )

    def bulk(self) -> str:
        """The complete lines buffered ahead (a chunk more decoded first where less than
        half a chunk is), not yet taken: "" where there are none."""
        if len(self.buf) - self.pos < _CHUNK // 2:
            self._more()
        j = self.buf.rfind("\n", self.pos)
        return self.buf[self.pos : j + 1] if j >= 0 else ""

    def take(self, text: str) -> None:
        """Move past ``text``, what :meth:`bulk` gave."""
        self.pos += len(text)
        self.lineno += text.count("\n")


def _numbered_lines(fh, path: Path) -> _Lines:
    """The lines of ``fh``, numbered (:class:`_Lines`)."""
    return _Lines(fh, path)


def _rest_is_blank(lines) -> bool:
    """Whether every line left in ``lines`` is blank (the line before was the last)."""
    try:
        return not any(line.strip() for _, line in lines)
    except DataFileError:
        return False


def load_experiment(
    path: str | os.PathLike,
    *,
    expect_lower: bool | None = None,
    max_abs_u: float = 5.0,
    keep_glitches: bool = False,
    max_bytes: int | None = None,
    max_rows: int | None = None,
    read: ReadSpec | None = None,
) -> Experiment:
    """Load and validate a measurement file, and leave out its glitches.

    Parameters
    ----------
    path : str or os.PathLike
        CSV file in the format described in the module docstring: a regular file (a pipe,
        a device or a stream such as ``<(...)`` is refused before it is opened).
    expect_lower : bool or None, optional
        ``True`` requires a ``theta_l`` column (coupled or brake configuration), ``False``
        forbids it (upper configuration), ``None`` accepts either. Default ``None``.
    max_abs_u : float, optional
        Voltage (V) above which ``|u|`` triggers a :class:`DataWarning`. The rig's amplifier
        limits the input to ±5 V, so larger values suggest a scaling error. Default 5 V.
    keep_glitches : bool, optional
        Keep the glitches found in the angles as measured. Default ``False``: each is left
        out (:func:`leave_out_glitches`). Either way :attr:`Experiment.glitches` names them.
    max_bytes, max_rows : int, optional
        The largest file (bytes; checked before reading) and the most data rows (checked
        while reading) accepted. Default: the environment variables
        ``ROTORBAYES_MAX_DATA_MB`` (MB) and ``ROTORBAYES_MAX_DATA_ROWS``, else
        :data:`MAX_DATA_BYTES` (1 GB) and :data:`MAX_DATA_ROWS` (10 million).
    read : ReadSpec or mapping, optional
        How to read a rig's own file (:mod:`rotorbayes.io.rigfiles`): the file's names of the
        signals and its units of time (s, ms) and angle (rad, deg, encoder counts).  A
        MATLAB ``.mat`` file (v5 or v7.3) is recognised by its content; a CSV may be
        separated by commas, semicolons or tabs (then a decimal comma is read too).
        Default: the plain measurement CSV (names t,u,theta_u,theta_l; s, V, rad).

    Returns
    -------
    Experiment
        With ``name`` the file stem, ``path`` the file, ``meta`` from the comment lines,
        ``glitches`` the glitches found (see :mod:`rotorbayes.io.glitches`) and ``sha256`` the
        SHA-256 of the bytes read (the file is read once).

    Raises
    ------
    DataFileError
        If the file is missing or unreadable, not a regular file, larger than the limits,
        binary (NUL bytes, lines without end), empty, has no or a wrong header, a row with
        the wrong number of fields, a non-numeric, NaN or infinite value, a last line
        without a line break (a truncated file), fewer than 3 data rows, time not strictly
        increasing, not in seconds (a step of :data:`MAX_SAMPLE_INTERVAL` or more, or a
        record longer than :data:`MAX_DURATION`) or not uniformly sampled, angles that look
        like degrees or encoder counts or that do not start at zero, or a configuration
        that contradicts ``expect_lower``. The message names the file, the line and the
        fix.

    Warns
    -----
    DataWarning
        If ``|u| > max_abs_u`` anywhere (the first such line and the largest value are named).
    """
    if not max_abs_u > 0:
        raise ValueError(f"max_abs_u must be a positive voltage, got {max_abs_u!r}")
    path = Path(path)
    limit_bytes = _limit(
        path, max_bytes, MAX_BYTES_ENV, MAX_DATA_BYTES, 1_000_000, "largest file size in MB"
    )
    limit_rows = _limit(path, max_rows, MAX_ROWS_ENV, MAX_DATA_ROWS, 1, "most data rows")
    if read is None:
        read = ReadSpec()
    elif isinstance(read, Mapping):  # {"columns": {...}, "angle_unit": "deg"}
        read = ReadSpec.from_record(read)
    elif not isinstance(read, ReadSpec):
        raise TypeError(
            f"read must be a rotorbayes.ReadSpec (or a mapping of its fields), "
            f"got {type(read).__name__}; e.g. ReadSpec.from_options("
            "'t=Time,u=Volt', angle_unit='deg')"
        )
    fd = _open_measurement(path, limit_bytes)
    try:
        head = os.pread(fd, 520, 0)
    except OSError:
        head = b""
    if _rig.is_mat_file(head, path.suffix):
        return _load_mat(path, fd, read, expect_lower, max_abs_u, keep_glitches, limit_rows)
    raw = _HashingReader(fd)
    meta: dict[str, str] = {}
    try:
        # utf-8-sig drops the byte-order mark that spreadsheet programs put in front of CSVs;
        # universal newlines make CRLF files count lines exactly like LF files. The file is
        # decoded a few MB at a time: the memory taken is the values' (8 bytes each), not
        # the text's.
        with io.TextIOWrapper(
            io.BufferedReader(raw, 1 << 16), encoding="utf-8-sig", newline=None
        ) as fh:
            names, header_lineno, values = _read_table(
                fh, path, meta, expect_lower, limit_rows, read
            )
    except UnicodeDecodeError:
        raise DataFileError(
            path,
            None,
            f"not a UTF-8 text file (undecodable byte at offset {_bad_utf8_offset(path)}); "
            "export the measurement as plain-text CSV",
        ) from None
    except OSError as exc:
        raise DataFileError(
            path, None, f"cannot be read ({exc.strerror or exc}); check the permissions"
        ) from None
    sha256 = raw.sha256.hexdigest()

    ncols = len(names)
    n_rows = len(values) // ncols
    if n_rows < _MIN_ROWS:
        raise DataFileError(
            path,
            None,
            f"only {n_rows} data row(s) after the header on line {header_lineno}; at "
            f"least {_MIN_ROWS} are needed to check the sampling",
        )
    table = np.frombuffer(values, dtype=np.float64).reshape(n_rows, ncols)

    def linenos(row: int) -> int:
        return header_lineno + 1 + int(row)

    cols = read.to_si({name: np.ascontiguousarray(table[:, j]) for j, name in enumerate(names)})
    try:
        _check_columns(cols, read)
    except RowProblem as exc:
        raise DataFileError(path, linenos(exc.row), exc.problem) from None

    _warn_voltage(path, cols["u"], max_abs_u, lambda k: f"line {linenos(k)}")
    exp = Experiment(
        t=cols["t"],
        u=cols["u"],
        theta_u=cols["theta_u"],
        theta_l=cols.get("theta_l"),
        name=path.stem,
        path=str(path),
        meta=meta,
        sha256=sha256,
    )
    return leave_out_glitches(exp, keep=keep_glitches)


def _warn_voltage(path: Path, u: np.ndarray, max_abs_u: float, where) -> None:
    """A :class:`DataWarning` for voltages beyond ``max_abs_u``; ``where(k)`` names sample k."""
    # A file that reaches the limit exactly may pass it by rounding (5.000000000000009 V
    # from a generator's arithmetic): only more than a billionth above it is reported.
    over = np.flatnonzero(np.abs(u) > max_abs_u * (1.0 + 1e-9))
    if over.size:
        first = int(over[0])
        worst = int(over[np.argmax(np.abs(u[over]))])
        warnings.warn(
            f"{path}, {where(first)}: u = {float(u[first])!r} V exceeds "
            f"±{max_abs_u:g} V ({over.size} sample(s), largest |u| = "
            f"{abs(float(u[worst]))!r} V on {where(worst)}); the rig's amplifier "
            "limits the motor voltage to ±5 V, so check the voltage scaling of this file",
            DataWarning,
            stacklevel=3,
        )


def _load_mat(
    path: Path,
    fd: int,
    read: ReadSpec,
    expect_lower: bool | None,
    max_abs_u: float,
    keep_glitches: bool,
    max_rows: int,
) -> Experiment:
    """A MATLAB file (v5 or v7.3): read whole (its SHA-256 is that of the bytes parsed),
    the signals picked by ``read``, converted and checked as a CSV's columns."""
    raw = _HashingReader(fd)
    try:
        with raw:
            data = io.BufferedReader(raw, 1 << 20).read()
    except OSError as exc:
        raise DataFileError(
            path, None, f"cannot be read ({exc.strerror or exc}); check the permissions"
        ) from None
    wanted = ("t", "u", "theta_u") + (
        () if expect_lower is False and "theta_l" not in read.columns else ("theta_l",)
    )
    try:
        cols, names = _rig.read_mat(data, read, wanted)
    except FormatProblem as exc:
        raise DataFileError(path, None, str(exc)) from None
    if expect_lower is False and "theta_l" in cols:
        raise DataFileError(
            path,
            None,
            f"theta_l is mapped (--columns theta_l={names['theta_l']}), but an "
            "upper-configuration record without the lower disc was expected; leave "
            "theta_l out of --columns, or use --model coupled or brake for this file",
        )
    if expect_lower is True and "theta_l" not in cols:
        raise DataFileError(
            path,
            None,
            "no theta_l (the lower disc's angle) in it: map it with --columns "
            "theta_l=NAME, or use --model upper for an upper-configuration record",
        )
    n = len(cols["t"])
    if n < _MIN_ROWS:
        raise DataFileError(
            path, None, f"only {n} sample(s); at least {_MIN_ROWS} are needed to check the sampling"
        )
    if n > max_rows:
        raise DataFileError(
            path,
            None,
            f"{n:,} samples, more than the {max_rows:,} a "
            "measurement may have (2 h at 1 kHz are 7.2 million); if it is a "
            f"measurement, raise the limit: {MAX_ROWS_ENV}=N (rows)",
        )
    cols = read.to_si(cols)

    def where(k: int) -> str:
        return f"sample {int(k) + 1} (t = {float(cols['t'][int(k)])!r} s)"

    try:
        _check_columns(cols, read)
    except RowProblem as exc:
        raise DataFileError(path, None, f"{where(exc.row)}: {exc.problem}") from None
    _warn_voltage(path, cols["u"], max_abs_u, where)
    meta = {"source_format": "MATLAB", **{f"column_{k}": v for k, v in names.items()}}
    exp = Experiment(
        t=cols["t"],
        u=cols["u"],
        theta_u=cols["theta_u"],
        theta_l=cols.get("theta_l"),
        name=path.stem,
        path=str(path),
        meta=meta,
        sha256=raw.sha256.hexdigest(),
    )
    return leave_out_glitches(exp, keep=keep_glitches)


#: The units a logger's units row may name, by what they mean.
_UNIT_WORDS = {
    "s": "s",
    "sec": "s",
    "seconds": "s",
    "ms": "ms",
    "msec": "ms",
    "v": "V",
    "volt": "V",
    "rad": "rad",
    "deg": "deg",
    "°": "deg",
    "degree": "deg",
    "degrees": "deg",
    "counts": "counts",
    "count": "counts",
    "cnt": "counts",
    "inc": "counts",
    "increments": "counts",
}


def _units_row(
    line: str,
    sep: str,
    idx: list[int],
    names: list[str],
    ncols: int,
    read: ReadSpec,
    path: Path,
    lineno: int,
) -> bool:
    """Whether the line after the header is a logger's units row (``s;V;deg;deg``): no
    number in the signals' columns, and units it knows.  Units that contradict the
    declared ones (``--time-unit``, ``--angle-unit``) are refused."""
    fields = line.rstrip("\n").split(sep)
    if len(fields) != ncols:
        return False
    texts = [fields[j].strip().strip('"').strip() for j in idx]
    if any(_is_number(t.replace(",", ".")) for t in texts):
        return False
    units = {
        n: _UNIT_WORDS.get(t.strip("[]() ").lower()) for n, t in zip(names, texts, strict=True)
    }
    if not any(units.values()):
        return False
    declared = {
        "t": read.time_unit,
        "u": "V",
        "theta_u": read.angle_unit,
        "theta_l": read.angle_unit,
    }
    for n, unit in units.items():
        if unit is not None and unit != declared[n]:
            option = (
                f"--time-unit {unit}" if n == "t" else "" if n == "u" else f"--angle-unit {unit}"
            )
            raise DataFileError(
                path,
                lineno,
                f"the units row gives {n} in {unit}, but it is read in {declared[n]}"
                + (
                    f": declare the unit with {option} (analysis file: "
                    f'{"time_unit" if n == "t" else "angle_unit"} = "{unit}")'
                    if option
                    else "; give the voltage in V"
                ),
            )
    return True


def _delimiter(header: str) -> str:
    """The field separator of a CSV, from its header: a semicolon or a tab where the header
    has one (spreadsheets in locales with a decimal comma, loggers), else a comma."""
    for sep in (";", "\t"):
        if sep in header:
            return sep
    return ","


def _mapped_header(
    fields: list[str], path: Path, lineno: int, read: ReadSpec
) -> tuple[list[str], list[int]]:
    """The signals a mapping (``read.columns``) finds in the header ``fields`` and their
    positions; the file's other columns are ignored."""
    names, idx, missing = [], [], []
    for sig in COLUMNS:
        name = read.name_of(sig)
        hits = [j for j, f in enumerate(fields) if f == name]
        if len(hits) > 1:
            raise DataFileError(
                path,
                lineno,
                f"the column {name!r} ({sig}) appears {len(hits)} times in the header; rename one",
            )
        if hits:
            names.append(sig)
            idx.append(hits[0])
        elif sig != "theta_l" or sig in read.columns:
            missing.append(f"{sig} = {name!r}" if sig in read.columns else sig)
    if missing:
        shown = ", ".join(repr(f) for f in fields[:20])
        raise DataFileError(
            path,
            lineno,
            f"no column for {', '.join(missing)} in the header; "
            f"the file's columns are {shown}: name them with --columns "
            "(e.g. --columns t=Time,u=Volt,theta_u=Enc1,theta_l=Enc2; analysis "
            'file: columns = {t = "Time", ...})',
        )
    return names, idx


#: Data rows read at once: a block of plain rows (commas, no quotes, every column used) is
#: parsed by NumPy in one call (the same string-to-double conversion as ``float``: the same
#: bits); a block with anything else is read line by line, where every refusal is worded.
_BLOCK_ROWS = 4096


def _plain_block(block: list, sep: str, ncols: int) -> np.ndarray | None:
    """The values of ``block`` (``(line number, line)`` pairs) as a ``(rows, ncols)`` array
    when every line is a complete row of ``ncols`` numbers; else None (read it line by line:
    a blank or comment line, a short row, a cut last line, a field NumPy does not read)."""
    lines = [line for _, line in block]
    if not all(line.endswith("\n") and line.strip() for line in lines):
        return None
    if any("#" in line for line in lines):
        return None
    try:
        rows = np.loadtxt(lines, delimiter=sep, dtype=np.float64, ndmin=2, comments=None)
    except ValueError:
        return None
    return rows if rows.shape == (len(lines), ncols) else None


def _plain_text(text: str, sep: str, ncols: int) -> np.ndarray | None:
    """The values of ``text`` (complete lines, each ending in a line break) as a
    ``(lines, ncols)`` array when every line is a complete row of ``ncols`` numbers, as
    :func:`_plain_block` asks of a block; else None."""
    if "#" in text or "\0" in text:
        return None
    try:
        rows = np.loadtxt(
            io.StringIO(text), delimiter=sep, dtype=np.float64, ndmin=2, comments=None
        )
    except ValueError:
        return None
    # NumPy skips blank lines: a row short of the lines' count is one.
    return rows if rows.shape == (text.count("\n"), ncols) else None


@dataclass
class _Rows:
    """The data rows of a text file, read after its header: blocks of plain rows by NumPy,
    anything else line by line, where every refusal is worded."""

    path: Path
    sep: str
    idx: list[int]
    names: list[str]
    file_fields: list[str]
    file_names: list[str]
    read: ReadSpec
    plain: bool
    decimal_comma: bool
    max_rows: int
    header_lineno: int
    #: The values, row after row, as packed doubles (8 bytes each): a list of row lists
    #: would cost about 190 bytes a row, 1.9 GB for 10 million rows.
    values: array.array = field(default_factory=lambda: array.array("d"))
    n_rows: int = 0
    #: The first blank line met: harmless after the data (an editor's final newline), an
    #: error when a line that is not blank follows it (two files pasted together).
    blank: int | None = None
    #: The last data line read, with its line break (or without: truncated).
    last: tuple[int, str] | None = None

    @property
    def ncols(self) -> int:
        return len(self.file_fields)

    def read_all(self, lines: _Lines) -> None:
        """Read every ``(line number, line)`` of ``lines``: plain rows a chunk at a time
        (:func:`_plain_text`), a chunk NumPy does not read whole in blocks of
        :data:`_BLOCK_ROWS` lines, each block's rows at once where they are plain and line
        by line where they are not."""
        slow_until = 0  # the lines of a chunk that was not plain: read in blocks
        while True:
            if self.plain and self.n_rows > 0 and self.blank is None and lines.lineno >= slow_until:
                text = lines.bulk()
                rows = _plain_text(text, self.sep, self.ncols) if text else None
                if rows is not None and self.n_rows + rows.shape[0] <= self.max_rows:
                    lines.take(text)
                    self.values.frombytes(rows.tobytes())
                    self.n_rows += rows.shape[0]
                    self.last = (lines.lineno, text[text.rfind("\n", 0, len(text) - 1) + 1 :])
                    continue
                slow_until = lines.lineno + text.count("\n")
            block = list(itertools.islice(lines, _BLOCK_ROWS))
            if not block:
                return
            if self.plain and self.n_rows > 0 and self.blank is None:
                rows = _plain_block(block, self.sep, self.ncols)
                if rows is not None and self.n_rows + rows.shape[0] <= self.max_rows:
                    self.values.frombytes(rows.tobytes())
                    self.n_rows += rows.shape[0]
                    self.last = block[-1]
                    continue
            pending = iter(block)
            for lineno, line in pending:
                self.row(lineno, line, itertools.chain(pending, lines))

    def row(self, lineno: int, line: str, rest) -> None:
        """One line, read on its own; ``rest``: the lines after it (to tell a truncated
        last line)."""
        if not line.strip():
            self.blank = self.blank or lineno
            return
        if self.blank is not None:
            raise DataFileError(
                self.path,
                self.blank,
                "empty line inside the data; delete it (only comment lines may "
                "precede the header, and data rows must be contiguous)",
            )
        if line.lstrip().startswith("#"):
            raise DataFileError(
                self.path,
                lineno,
                f"comment line {line.strip()!r} after the header; comment lines are "
                "only allowed before the header -- move it there or delete it",
            )
        if (
            self.n_rows == 0
            and lineno == self.header_lineno + 1
            and _units_row(
                line, self.sep, self.idx, self.names, self.ncols, self.read, self.path, lineno
            )
        ):
            self.header_lineno = lineno  # a logger's units under the names: part of the header
            return
        body = line[:-1] if line.endswith("\n") else line
        fields = body.split(self.sep)
        values_of_row = None
        if len(fields) == self.ncols:
            try:
                if self.plain:
                    values_of_row = [float(f) for f in fields]
                else:
                    values_of_row = [
                        _rig.parse_number(fields[j].strip().strip('"'), self.decimal_comma)
                        for j in self.idx
                    ]
            except ValueError:
                pass
        if values_of_row is None:
            truncated = (
                " -- it is the last line, so the file looks truncated (cut while being "
                "written or copied); re-export it or delete the incomplete line"
                if _rest_is_blank(rest)
                else ""
            )
            if len(fields) != self.ncols:
                seps = {",": "commas", ";": "semicolons", "\t": "tabs"}
                other = [w for c, w in seps.items() if c != self.sep and c in body]
                if other and len(fields) == 1 and self.ncols > 1:
                    truncated = (
                        f"; the header is separated by {seps[self.sep]} but this row by "
                        f"{other[0]}: use one separator throughout (export the "
                        "file again)"
                    )
                raise DataFileError(
                    self.path,
                    lineno,
                    f"{len(fields)} field(s) {body.strip()!r} but the header "
                    f"{self.sep.join(self.file_fields)!r} has {self.ncols}"
                    f"{truncated or '; fix or delete this row'}",
                )
            for name, j in zip(self.file_names, self.idx, strict=True):
                text = fields[j]
                clean = text.strip().strip('"')
                if not _is_number(clean.replace(",", ".") if self.decimal_comma else clean):
                    shown = repr(text.strip()) if text.strip() else "empty"
                    raise DataFileError(
                        self.path,
                        lineno,
                        f"value {shown} in column {name} is not a number"
                        + (
                            truncated
                            or "; write plain decimal numbers (e.g. "
                            + ("0,25 or 0.25" if self.decimal_comma else "0.25 or 2.5e-1")
                            + ")"
                        ),
                    )
            # float() failed, so one field must be non-numeric
            raise AssertionError(body)  # pragma: no cover
        self.n_rows += 1
        if self.n_rows > self.max_rows:
            raise DataFileError(
                self.path,
                lineno,
                f"more than {self.max_rows:,} data rows, the most a measurement file may have (2 h "
                "at 1 kHz, the rig's longest record, are 7.2 million); reading stopped here. "
                f"If it is a measurement, raise the limit: {MAX_ROWS_ENV}=N (rows)",
            )
        self.values.extend(values_of_row)
        self.last = (lineno, line)


def _read_table(
    fh,
    path: Path,
    meta: dict[str, str],
    expect_lower: bool | None,
    max_rows: int,
    read: ReadSpec | None = None,
) -> tuple[list[str], int, array.array]:
    """Read the comment lines (into ``meta``), the header and the data rows of the text
    file ``fh``: the column names (the model's), the header's line number and the values
    row by row (the named columns only)."""
    read = ReadSpec() if read is None else read
    lines = _numbered_lines(fh, path)
    seen_text = False
    header = None
    for lineno, line in lines:
        stripped = line.strip()
        if stripped.startswith("#"):
            seen_text = True
            _parse_comment(stripped, meta)
        elif stripped:
            header = (lineno, line)
            break
    if header is None:
        if not seen_text:
            raise DataFileError(
                path,
                None,
                f"the file is empty; it must contain the header '{','.join(COLUMNS)}' and "
                "data rows",
            )
        raise DataFileError(
            path,
            None,
            f"no header: the file has only comment lines; add the header line "
            f"'{','.join(COLUMNS)}' and the data rows after the comments",
        )
    header_lineno, header_line = header
    sep = _delimiter(header_line)
    # A comma is the decimal mark where it does not separate fields ("0,25" in a
    # semicolon-separated file from a German or Dutch spreadsheet).
    decimal_comma = sep != ","
    quoted = '"' in header_line
    file_fields = [f.strip().strip('"').strip() for f in header_line.rstrip("\n").split(sep)]
    if read.columns:
        names, idx = _mapped_header(file_fields, path, header_lineno, read)
        file_names = [file_fields[j] for j in idx]
    else:
        names = _parse_header(file_fields, path, header_lineno)
        idx = list(range(len(names)))
        file_names = names
    has_lower = "theta_l" in names
    if expect_lower is True and not has_lower:
        raise DataFileError(
            path,
            header_lineno,
            f"no theta_l column (header {','.join(names)!r}): this looks like an "
            "upper-configuration file (string removed), but the lower disc's angle was "
            "expected; use --model upper for it (in Python: expect_lower=False), or load "
            "the coupled/brake measurement",
        )
    if expect_lower is False and has_lower:
        raise DataFileError(
            path,
            header_lineno,
            f"the file has a theta_l column (header {','.join(names)!r}), but an "
            "upper-configuration file without the lower disc was expected; load the "
            "upper-configuration measurement, or use --model coupled or brake for this file "
            "(in Python: expect_lower=True)",
        )

    ncols = len(file_fields)
    # Data rows are contiguous (a gap or comment inside them is refused), so row k is on
    # line header_lineno + 1 + k (a units row under the header moves the header's line).
    rows = _Rows(
        path=path,
        sep=sep,
        idx=idx,
        names=names,
        file_fields=file_fields,
        file_names=file_names,
        read=read,
        plain=idx == list(range(ncols)) and not decimal_comma and not quoted,
        decimal_comma=decimal_comma,
        max_rows=max_rows,
        header_lineno=header_lineno,
    )
    rows.read_all(lines)
    header_lineno, values, last = rows.header_lineno, rows.values, rows.last

    # A complete file ends with a line break (every writer, save_experiment included, ends each
    # row with one). Without it the last row was probably cut while the file was written or
    # copied, and a cut number such as "0.0123" from "0.012345" still parses -- so refuse it.
    # Only a data row is judged here; a file ending in its header fails the row count.
    if last is not None and not last[1].endswith("\n"):
        shown = last[1].strip()
        if len(shown) > _MAX_QUOTE:
            shown = shown[:_MAX_QUOTE] + "..."
        raise DataFileError(
            path,
            last[0],
            f"the last line {shown!r} does not end with a line break: the file looks truncated "
            "(cut while being written or copied), so its last number may be incomplete; "
            "re-export or copy the file again, or delete this last line (if you have checked "
            "that the line is complete, end it with a line break)",
        )
    return names, header_lineno, values


def leave_out_glitches(exp: Experiment, *, keep: bool = False) -> Experiment:
    """The experiment with its glitches found and left out (or kept, with ``keep``).

    A glitch is a sample, or a burst of up to three within 13 samples, that jumps against
    its neighbours by far more than the discs can move (encoder lines pick up such spikes;
    :mod:`rotorbayes.io.glitches` says how they are found). Left out, a glitch's sample holds
    the cubic through its neighbours (rounded to whole encoder counts for count data), so
    it carries no information of its own and every figure computed from the data stays
    consistent; the measured value stays in the :class:`Glitch` record.

    Parameters
    ----------
    exp : Experiment
        The experiment. If its glitches were looked for already (``exp.glitches`` is not
        None), those records are used as they are: calling this again with the other
        ``keep`` puts the measured values back, or leaves them out again.
    keep : bool, optional
        Keep the glitches' measured values (their records say ``left_out=False``).

    Returns
    -------
    Experiment
        A new experiment with ``glitches`` set (``()`` when none were found), or ``exp``
        itself when nothing changes.
    """
    if exp.glitches is None:
        found = []
        for key in ("theta_u", "theta_l"):
            theta = getattr(exp, key)
            if theta is not None:
                found += _glitches.find_glitches(exp.t, theta, key, _COUNTS_PER_REV[key])
        found.sort(key=lambda g: (g.index, g.channel))
    else:
        found = list(exp.glitches)
        if all(g.left_out == (not keep) for g in found):
            return exp
    records = tuple(Glitch(**{**g.as_dict(), "left_out": not keep}) for g in found)
    angles = {}
    for key in ("theta_u", "theta_l"):
        theta = getattr(exp, key)
        if theta is not None:
            mine = [g for g in records if g.channel == key]
            angles[key] = _glitches.repaired(theta, mine, keep=keep) if mine else theta
    return Experiment(
        exp.t,
        exp.u,
        angles["theta_u"],
        angles.get("theta_l"),
        name=exp.name,
        path=exp.path,
        meta=exp.meta,
        glitches=records,
        sha256=exp.sha256,
    )


# --------------------------------------------------------------------------------------------
# Saving


def _clean_meta(meta: Mapping[str, object]) -> dict[str, str]:
    """Normalise metadata to what survives a ``# key: value`` line unchanged."""
    clean: dict[str, str] = {}
    for key, value in meta.items():
        k, v = str(key).strip(), str(value).strip()
        if not k or ":" in k or "\n" in k or "\r" in k:
            raise ValueError(
                f"metadata key {key!r} cannot be written as a '# key: value' line; use a "
                "non-empty key without ':' or line breaks"
            )
        if "\n" in v or "\r" in v:
            raise ValueError(
                f"metadata value {value!r} for key {k!r} contains a line break; write it on one "
                "line"
            )
        clean[k] = v
    return clean


#: Rows written per block by :func:`save_experiment`.
_WRITE_BLOCK = 100_000


def save_experiment(
    exp: Experiment,
    path: str | os.PathLike,
    *,
    overwrite: bool = False,
    meta: Mapping[str, object] | None = None,
) -> Path:
    """Write an experiment as a measurement file that :func:`load_experiment` reads back exactly.

    Numbers are written with Python's shortest round-trip representation (``repr``), so every
    value, including encoder-quantised angles, is recovered bit for bit. Glitches that were
    left out (:func:`leave_out_glitches`) are written as measured: a file holds the
    measurement, and loading it finds and leaves them out again. The file is written to
    a temporary file in the same directory and then moved into place, so a crash never leaves
    a half-written measurement under ``path``.

    Parameters
    ----------
    exp : Experiment
        The experiment. It must pass the same checks as a loaded file (finite values, strictly
        increasing uniform time, angles in rad starting at 0).
    path : str or os.PathLike
        Destination ``.csv`` file. Its directory must exist.
    overwrite : bool, optional
        Replace an existing file. Default ``False``: an existing file is an error.
    meta : mapping, optional
        Extra metadata, merged over ``exp.meta`` and written as ``# key: value`` lines before
        the header. Keys must not contain ``:``; keys and values are stripped of surrounding
        whitespace and must fit on one line.

    Returns
    -------
    pathlib.Path
        The path written.

    Raises
    ------
    FileExistsError
        If ``path`` exists and ``overwrite`` is false.
    FileNotFoundError
        If the directory of ``path`` does not exist.
    ValueError
        If the experiment would not load back (the message names the sample and the future
        line) or the metadata cannot be written.
    """
    path = Path(path)
    merged = _clean_meta({**exp.meta, **(meta or {})})
    # A file holds what was measured: glitches left out go back in (a later load finds
    # them again).
    if exp.glitches and any(g.left_out for g in exp.glitches):
        exp = leave_out_glitches(exp, keep=True)
    cols = exp.columns()
    first_data_line = len(merged) + 2
    try:
        _check_columns(cols)
    except RowProblem as exc:
        raise ValueError(
            f"cannot save experiment {exp.name!r} to {path}: sample {exc.row} (line "
            f"{first_data_line + exc.row} of the file) would be rejected when loading: "
            f"{exc.problem}"
        ) from None
    if exp.n < _MIN_ROWS:
        raise ValueError(
            f"cannot save experiment {exp.name!r} to {path}: it has {exp.n} samples, but a "
            f"measurement file needs at least {_MIN_ROWS}"
        )
    if path.exists() and not overwrite:
        raise FileExistsError(
            f"{path} already exists; pass overwrite=True (--force on the command line) to "
            "replace it, or choose another name"
        )
    directory = path.parent
    if not directory.is_dir():
        raise FileNotFoundError(f"directory {directory} does not exist; create it first")

    head = [f"# {k}: {v}" for k, v in merged.items()]
    head.append(",".join(cols))
    n_rows = len(next(iter(cols.values())))

    def chunks():
        # The header, then the rows in blocks: a 10-million-row experiment is never held
        # as one string (about 0.7 GB, and ten times that as Python objects).
        yield "\n".join(head) + "\n"
        for a in range(0, n_rows, _WRITE_BLOCK):
            # repr() of a Python float is the shortest string that parses back to the
            # same double.
            columns = [c[a : a + _WRITE_BLOCK].tolist() for c in cols.values()]
            yield "".join(",".join(map(repr, row)) + "\n" for row in zip(*columns, strict=True))

    # A hidden, unique temporary name in the same directory keeps os.replace atomic (same
    # filesystem) and lets concurrent writers not clobber each other's temporary files.
    tmp = directory / f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp"
    try:
        # os.open with mode 0o666 lets the umask decide the permissions, as for a normal file
        # (tempfile.mkstemp would leave the measurement readable only by its owner).
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        with open(fd, "w", encoding="utf-8", newline="\n") as fh:
            for text in chunks():
                fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        if overwrite:
            os.replace(tmp, path)
        else:
            # link() fails if the target appeared since the check above, so a file created
            # concurrently is never silently replaced.
            try:
                os.link(tmp, path)
            except FileExistsError:
                raise FileExistsError(
                    f"{path} already exists; pass overwrite=True (--force on the command line) "
                    "to replace it, or choose another name"
                ) from None
            except OSError:
                # Some filesystems (FAT, some network mounts) have no hard links.
                os.replace(tmp, path)
    finally:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
    return path


# --------------------------------------------------------------------------------------------
# Synthetic measurements


def quantize(theta: np.ndarray, counts_per_rev: float) -> np.ndarray:
    """Round angles to the nearest encoder count.

    Parameters
    ----------
    theta : array_like
        Angles (rad).
    counts_per_rev : float
        Encoder resolution (counts per revolution), e.g. :data:`UPPER_COUNTS_PER_REV` or
        :data:`LOWER_COUNTS_PER_REV`.

    Returns
    -------
    numpy.ndarray
        ``round(theta / q) * q`` with ``q = 2 pi / counts_per_rev`` (rad); the error is at most
        ``q / 2``. An angle of 0 stays exactly 0, as a zeroed encoder reads.
    """
    if not (np.isfinite(counts_per_rev) and counts_per_rev > 0):
        raise ValueError(
            f"counts_per_rev must be a positive number of encoder counts per revolution, got "
            f"{counts_per_rev!r}; e.g. UPPER_COUNTS_PER_REV or LOWER_COUNTS_PER_REV"
        )
    q = 2.0 * math.pi / counts_per_rev
    # Adding 0.0 turns the -0.0 that tiny negative angles round to into 0.0, so files show a
    # resting encoder as "0.0" rather than "-0.0".
    return np.round(np.asarray(theta, dtype=np.float64) / q) * q + 0.0


def add_noise(theta: np.ndarray, std: float, rng: np.random.Generator) -> np.ndarray:
    """Add independent Gaussian noise to angles.

    Parameters
    ----------
    theta : array_like
        Angles (rad). Not modified.
    std : float
        Noise standard deviation (rad), ``>= 0``. Keep it well below 1e-2 rad, or the first
        sample may violate the zero-start check of :func:`load_experiment`.
    rng : numpy.random.Generator
        Source of randomness, e.g. ``numpy.random.default_rng(seed)``.

    Returns
    -------
    numpy.ndarray
        ``theta + std * N(0, 1)`` as a new array (rad).
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError(
            f"rng must be a numpy.random.Generator, got {type(rng).__name__}; pass "
            "numpy.random.default_rng(seed)"
        )
    if not (np.isfinite(std) and std >= 0):
        raise ValueError(f"std must be a non-negative noise level in rad, got {std!r}")
    theta = np.asarray(theta, dtype=np.float64)
    return theta + rng.normal(0.0, std, size=theta.shape)

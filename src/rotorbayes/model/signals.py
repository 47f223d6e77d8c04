"""Input voltages for the drill-string rig (thesis §3.2).

Two kinds of input drive the DC motor of the upper disc:

* :func:`estimation_signal` (``"est"``) -- quasi-random voltage levels held for random times,
  joined by smooth transitions. It excites the whole operating range: small voltages where the
  lower disc sticks and slips, large ones where friction is in the viscous regime, and
  reversals of direction that reveal friction asymmetry.
* :func:`validation_signal` (``"val"``) -- a sum of slow sines with seeded random phases, used
  to check an estimated parameter set on an input it was not fitted to.

Both signals

* are sampled on ``t = arange(n) / rate`` with ``n = round(duration * rate) + 1``, so
  ``t[0] == 0`` and ``t[-1] == duration``;
* start and end at exactly 0 V with a smooth ramp, because the rig is at rest when a
  measurement starts (and a signal that returns to zero can be repeated or concatenated);
* stay within ``±amplitude`` with ``amplitude <= 5 V``, the limit of the rig's amplifier;
* contain essentially no energy above 5 Hz: the rig's relevant dynamics are below 5 Hz and
  faster inputs risk damaging the set-up (thesis §3.2);
* are reproducible: the same ``seed`` gives identical arrays. The random draws do not depend
  on ``rate``, so the same seed sampled at two rates gives the same continuous signal.
"""

from collections.abc import Callable, Sequence

import numpy as np

__all__ = [
    "MAX_VOLTAGE",
    "DEFAULT_VALIDATION_FREQUENCIES",
    "SIGNAL_KINDS",
    "estimation_signal",
    "validation_signal",
    "make_signal",
]

#: Amplifier limit of the rig (V); the DAC and amplifier clip the motor voltage to ±5 V.
MAX_VOLTAGE = 5.0

#: Default validation frequencies (Hz). Spread roughly logarithmically over 0.05–1 Hz and
#: chosen with no simple ratios between them, so the sum does not repeat within an experiment
#: and no two components excite the same harmonic of a stick-slip cycle.
DEFAULT_VALIDATION_FREQUENCIES: tuple[float, ...] = (0.05, 0.09, 0.17, 0.31, 0.53, 0.97)

# Voltage bands (V) for the estimation levels. Below ~1.5 V the lower disc sticks and slips,
# which is where the friction parameters are identifiable; above it the discs slide
# continuously and the viscous and inertia terms dominate. Both must be present.
_SMALL_BAND = (0.2, 1.5)

# Length (s) of the smooth fade-in and fade-out of the validation multisine. A 1 s fade keeps
# the spectrum of the envelope well inside 5 Hz (energy above 5 Hz ~1e-9 of the total).
_VALIDATION_FADE = 1.0


def smooth_step(x: np.ndarray) -> np.ndarray:
    """Step from 0 to 1 over ``0 <= x <= 1``: the running integral of a Hann window.

    Convolving a staircase with a Hann window of width ``W`` replaces each jump by this curve
    stretched over ``W`` seconds. The Hann window is non-negative and integrates to one, so
    the smoothed signal is a running weighted mean of the levels and can never overshoot
    them; its spectrum has its first zero at ``2 / W`` Hz and sidelobes falling as ``f**-3``.
    Value, slope and curvature are zero at both ends, so the motor voltage starts gently.
    """
    x = np.clip(x, 0.0, 1.0)
    return x - np.sin(2.0 * np.pi * x) / (2.0 * np.pi)


def _as_float(name: str, value: object) -> float:
    """``value`` as a Python float (so messages show ``30.0``, not ``np.float64(30.0)``)."""
    try:
        return float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None


def _time_grid(duration: float, rate: float) -> np.ndarray:
    """Check ``duration`` and ``rate`` and return the sample times ``arange(n) / rate`` (s)."""
    if not np.isfinite(duration) or duration <= 0:
        raise ValueError(f"duration must be a positive number of seconds, got {duration!r}")
    if not np.isfinite(rate) or rate <= 0:
        raise ValueError(f"rate must be a positive sampling rate in Hz, got {rate!r}")
    samples = duration * rate
    n_steps = round(samples)
    # A fractional number of samples would make t[-1] != duration and silently shorten or
    # lengthen the experiment; better to say so than to round behind the user's back.
    if abs(samples - n_steps) > 1e-6 * max(1.0, samples):
        raise ValueError(
            f"duration * rate = {duration!r} s * {rate!r} Hz = {samples!r} samples is not a "
            f"whole number; choose a duration that is a multiple of 1/rate = {1.0 / rate!r} s"
        )
    if n_steps < 1:
        raise ValueError(
            f"duration {duration!r} s is shorter than one sample at rate {rate!r} Hz; "
            "increase the duration or the rate"
        )
    return np.arange(n_steps + 1) / rate


def _check_amplitude(amplitude: float) -> None:
    if not np.isfinite(amplitude) or amplitude <= 0:
        raise ValueError(f"amplitude must be a positive voltage, got {amplitude!r}")
    if amplitude > MAX_VOLTAGE:
        raise ValueError(
            f"amplitude {amplitude!r} V exceeds the rig's amplifier limit of {MAX_VOLTAGE} V; "
            f"pass amplitude <= {MAX_VOLTAGE}"
        )


def _draw_level(rng: np.random.Generator, kind: int, amplitude: float) -> float:
    """One estimation level (V) of ``kind`` 0 = small, 1 = large, 2 = anywhere, random sign."""
    small_lo, small_hi = _SMALL_BAND
    small_hi = min(small_hi, amplitude)
    small_lo = min(small_lo, 0.5 * small_hi)
    if kind == 0 or (kind == 1 and amplitude <= small_hi):
        magnitude = rng.uniform(small_lo, small_hi)
    elif kind == 1:
        magnitude = rng.uniform(small_hi, amplitude)
    else:
        magnitude = rng.uniform(0.0, amplitude)
    # A random sign per level gives a direction reversal at about every second transition,
    # which is what exposes asymmetric friction (thesis §5.2.3).
    return float(magnitude if rng.random() < 0.5 else -magnitude)


def estimation_signal(
    duration: float,
    *,
    rate: float = 1000.0,
    seed: int | np.random.Generator | None = 0,
    amplitude: float = 4.0,
    hold: tuple[float, float] = (0.4, 2.5),
    bandwidth: float = 5.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Quasi-random levels held for random times with smooth transitions.

    The signal is a staircase of random levels, smoothed by a Hann window of width
    ``W = 2 / bandwidth`` s. Each jump thus becomes a smooth transition lasting ``W`` seconds,
    the signal never overshoots its levels, and its spectrum is essentially confined below
    ``bandwidth`` (for the defaults, the energy above 5 Hz is about 2e-6 of the total).

    Levels come in shuffled groups of three: one small (``0.2 <= |u| <= 1.5`` V, the
    stick-slip range of the lower disc), one large (``1.5 <= |u| <= amplitude``) and one
    anywhere in ``[0, amplitude]``, each with a random sign. So at least a third of the levels
    are small, large ones are always present, and the direction reverses often.

    The signal is 0 V at ``t = 0`` and starts its first transition there; it returns to 0 V at
    ``t = duration`` after the last level.

    Parameters
    ----------
    duration : float
        Length of the signal (s). ``duration * rate`` must be a whole number, and the duration
        must hold at least one level: ``duration >= 2 / bandwidth + hold[0]``.
    rate : float, optional
        Sampling rate (Hz). Default 1000 Hz.
    seed : int, numpy.random.Generator or None, optional
        Seed for :func:`numpy.random.default_rng`. A ``Generator`` is used (and advanced) as
        is; ``None`` draws fresh entropy (not reproducible). Default 0.
    amplitude : float, optional
        Largest level magnitude (V), ``0 < amplitude <= 5``. Default 4 V.
    hold : tuple of float, optional
        ``(shortest, longest)`` time between the starts of consecutive transitions (s), drawn
        uniformly. A level is reached fully if its hold time is at least ``2 / bandwidth``.
        The last level is held until the final ramp to zero, which may be longer. Default
        ``(0.4, 2.5)`` s.
    bandwidth : float, optional
        Frequency (Hz) above which the signal has essentially no energy; sets the transition
        time ``2 / bandwidth``. Must be below the Nyquist frequency ``rate / 2``. Default 5 Hz.

    Returns
    -------
    t : numpy.ndarray
        Sample times (s), ``arange(n) / rate``.
    u : numpy.ndarray
        Motor voltage (V), ``|u| <= amplitude``.

    Raises
    ------
    ValueError
        If an argument is out of range; the message names the value and the fix.

    Examples
    --------
    >>> t, u = estimation_signal(30.0, seed=1)
    >>> t[-1], u[0], u[-1]
    (30.0, 0.0, 0.0)
    """
    duration, rate = _as_float("duration", duration), _as_float("rate", rate)
    amplitude, bandwidth = _as_float("amplitude", amplitude), _as_float("bandwidth", bandwidth)
    t = _time_grid(duration, rate)
    _check_amplitude(amplitude)
    try:
        hold_min, hold_max = (float(h) for h in hold)
    except (TypeError, ValueError):
        raise ValueError(
            f"hold must be a pair (shortest, longest) of hold times in s, got {hold!r}"
        ) from None
    if not (np.isfinite(hold_min) and np.isfinite(hold_max) and 0 < hold_min <= hold_max):
        raise ValueError(
            f"hold must satisfy 0 < shortest <= longest (s), got {hold!r}; "
            "pass e.g. hold=(0.4, 2.5)"
        )
    if not np.isfinite(bandwidth) or not 0 < bandwidth < rate / 2:
        raise ValueError(
            f"bandwidth must be between 0 and the Nyquist frequency rate/2 = {rate / 2!r} Hz, "
            f"got {bandwidth!r}"
        )
    width = 2.0 / bandwidth
    if duration < width + hold_min - 1e-12:
        raise ValueError(
            f"duration {duration!r} s is too short for an estimation signal with bandwidth "
            f"{bandwidth!r} Hz and shortest hold {hold_min!r} s: it needs at least "
            f"2/bandwidth + hold[0] = {width + hold_min!r} s (a ramp in, one level, a ramp "
            "out); increase the duration"
        )
    rng = np.random.default_rng(seed)

    # The staircase is 0 until the first jump at W/2 and after the last jump at duration - W/2,
    # so the smoothing window never reaches past t = 0 or t = duration: u(0) = u(end) = 0
    # exactly, and the first transition starts right at t = 0.
    first_jump = 0.5 * width
    last_jump = duration - 0.5 * width
    jumps: list[float] = []
    levels: list[float] = [0.0]
    kinds: list[int] = []
    jump = first_jump
    while jump <= last_jump - hold_min + 1e-12:
        if not kinds:
            kinds = [int(k) for k in rng.permutation(3)]
        jumps.append(jump)
        levels.append(_draw_level(rng, kinds.pop(), amplitude))
        jump += rng.uniform(hold_min, hold_max)
    jumps.append(last_jump)
    levels.append(0.0)

    u = np.zeros_like(t)
    for k, t_jump in enumerate(jumps):
        # Only samples inside the transition window need the smooth step; all later samples
        # get the full jump. This keeps the cost linear in the number of samples.
        start = np.searchsorted(t, t_jump - 0.5 * width, side="left")
        stop = np.searchsorted(t, t_jump + 0.5 * width, side="right")
        step = levels[k + 1] - levels[k]
        u[start:stop] += step * smooth_step((t[start:stop] - t_jump) / width + 0.5)
        u[stop:] += step
    # The sum of steps is exactly 0 in exact arithmetic at both ends; pin the end points so
    # rounding of the accumulated steps cannot leave a 1e-16 V residue there.
    u[0] = 0.0
    u[-1] = 0.0
    return t, u


def validation_signal(
    duration: float,
    *,
    rate: float = 1000.0,
    seed: int | np.random.Generator | None = 0,
    amplitude: float = 3.0,
    frequencies: Sequence[float] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Sum of sines (multisine) with seeded random phases, peak ``|u| <= amplitude``.

    ``u(t) = c * e(t) * sum_k sin(2 pi f_k t + phi_k)`` with phases ``phi_k`` uniform in
    ``[0, 2 pi)``, an envelope ``e(t)`` that rises smoothly from 0 to 1 over the first second
    and falls back to 0 over the last second (so the rig starts from rest), and ``c`` chosen
    so that the continuous signal peaks at ``|u| == amplitude`` (the samples never exceed it).

    Parameters
    ----------
    duration : float
        Length of the signal (s), at least 2 s (the fade-in and fade-out). ``duration * rate``
        must be a whole number.
    rate : float, optional
        Sampling rate (Hz). Default 1000 Hz.
    seed : int, numpy.random.Generator or None, optional
        Seed for :func:`numpy.random.default_rng`, as in :func:`estimation_signal`. Default 0.
    amplitude : float, optional
        Peak voltage (V), ``0 < amplitude <= 5``. Default 3 V.
    frequencies : sequence of float, optional
        Sine frequencies (Hz), each in ``(0, rate / 2)``. Keep them below 5 Hz for the rig.
        Default :data:`DEFAULT_VALIDATION_FREQUENCIES` (0.05–0.97 Hz).

    Returns
    -------
    t : numpy.ndarray
        Sample times (s), ``arange(n) / rate``.
    u : numpy.ndarray
        Motor voltage (V), ``|u| <= amplitude``; the continuous signal peaks at exactly
        ``amplitude``, so the largest sample is within rounding of it at the usual rates.

    Raises
    ------
    ValueError
        If an argument is out of range; the message names the value and the fix.
    """
    duration, rate = _as_float("duration", duration), _as_float("rate", rate)
    amplitude = _as_float("amplitude", amplitude)
    t = _time_grid(duration, rate)
    _check_amplitude(amplitude)
    if frequencies is None:
        frequencies = DEFAULT_VALIDATION_FREQUENCIES
    freqs = np.asarray(frequencies, dtype=float)
    if freqs.ndim != 1 or freqs.size == 0:
        raise ValueError(
            f"frequencies must be a non-empty sequence of frequencies in Hz, got {frequencies!r}"
        )
    bad = ~np.isfinite(freqs) | (freqs <= 0) | (freqs >= rate / 2)
    if bad.any():
        raise ValueError(
            f"frequency {float(freqs[bad][0])!r} Hz is outside (0, rate/2 = {rate / 2!r} Hz); "
            "pass positive frequencies below the Nyquist frequency (below 5 Hz for the rig)"
        )
    if duration < 2 * _VALIDATION_FADE:
        raise ValueError(
            f"duration {duration!r} s is too short for a validation signal: the fade-in and "
            f"fade-out take {2 * _VALIDATION_FADE!r} s; increase the duration"
        )
    rng = np.random.default_rng(seed)
    phases = rng.uniform(0.0, 2.0 * np.pi, size=freqs.size)

    def unscaled(times: np.ndarray) -> np.ndarray:
        u = np.zeros_like(times)
        # One sine at a time rather than an (n, k) matrix: long experiments at high rates
        # would otherwise allocate k times the signal's memory.
        for f, phi in zip(freqs, phases, strict=True):
            u += np.sin(2.0 * np.pi * f * times + phi)
        fade_in = smooth_step(times / _VALIDATION_FADE)
        fade_out = smooth_step((duration - times) / _VALIDATION_FADE)
        return u * fade_in * fade_out

    # Scale by the peak of the continuous signal, not of the samples, so that the same seed
    # gives the same signal at every rate and no sample exceeds the amplitude.
    u = unscaled(t) * (amplitude / _continuous_peak(unscaled, duration, float(freqs.max())))
    # The refined peak is accurate to rounding; clipping removes a possible 1e-16 excess.
    np.clip(u, -amplitude, amplitude, out=u)
    u[0] = 0.0
    u[-1] = 0.0
    return t, u


def _continuous_peak(
    func: Callable[[np.ndarray], np.ndarray], duration: float, f_max: float
) -> float:
    """Largest ``|func(t)|`` for ``0 <= t <= duration``, for a smooth band-limited ``func``.

    A coarse grid (20 points per period of the fastest component) finds the candidate peaks
    to about 1 %; the few highest are then refined by bounded scalar minimisation.
    """
    step = 0.05 / max(f_max, 1.0 / _VALIDATION_FADE)
    grid = np.linspace(0.0, duration, max(3, int(np.ceil(duration / step)) + 1))
    values = np.abs(func(grid))
    # Local maxima only: the top grid values alone could all sit on the shoulders of one peak.
    padded = np.concatenate(([-np.inf], values, [-np.inf]))
    local = np.flatnonzero((values >= padded[:-2]) & (values >= padded[2:]))
    candidates = local[np.argsort(values[local])[-5:]]
    peak = float(values.max())
    for k in candidates:
        lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, grid.size - 1)]
        from scipy import optimize  # here: every command imports this module, few use it

        result = optimize.minimize_scalar(
            lambda x: -abs(float(func(np.array([x]))[0])),
            bounds=(lo, hi),
            method="bounded",
            options={"xatol": 1e-12},
        )
        peak = max(peak, -float(result.fun))
    return peak


#: Signal kinds accepted by :func:`make_signal`.
SIGNAL_KINDS: dict[str, Callable[..., tuple[np.ndarray, np.ndarray]]] = {
    "est": estimation_signal,
    "val": validation_signal,
}


def make_signal(kind: str, duration: float, **kw) -> tuple[np.ndarray, np.ndarray]:
    """Make an input signal by name.

    Parameters
    ----------
    kind : str
        ``"est"`` for :func:`estimation_signal` or ``"val"`` for :func:`validation_signal`.
    duration : float
        Length of the signal (s).
    **kw
        Keyword arguments of the chosen function (``rate``, ``seed``, ``amplitude``, ...).

    Returns
    -------
    t, u : numpy.ndarray
        Sample times (s) and motor voltage (V).

    Raises
    ------
    ValueError
        If ``kind`` is unknown (the message lists the valid kinds) or an argument is invalid.
    """
    try:
        function = SIGNAL_KINDS[kind]
    except (KeyError, TypeError):
        valid = ", ".join(repr(k) for k in SIGNAL_KINDS)
        raise ValueError(f"unknown signal kind {kind!r}; valid kinds are {valid}") from None
    return function(duration, **kw)

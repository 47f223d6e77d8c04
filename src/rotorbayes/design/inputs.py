"""The input families a design searches: smoothed steps and a tapered multisine.

Both respect the rig as :mod:`rotorbayes.model.signals` does: ``|u| <= max_volts <= 5 V`` (the
amplifier), essentially no energy above ``band_hz`` (default 5 Hz, thesis §3.2), exactly
0 V at the first and the last sample with a smooth ramp (the rig starts at rest, and the
experiment ends at rest), and the time grid ``arange(n) / rate`` with ``t[-1] = duration``.

A family maps a vector ``z`` in the box ``[lower, upper]`` to the sampled input ``u``:

* :class:`Steps` — ``m`` levels ``z_k * max_volts`` (``-1 <= z_k <= 1``) held for equal
  times, joined by the Hann-smoothed step of :func:`rotorbayes.model.signals.estimation_signal`
  (a transition of ``2 / band_hz`` s that never overshoots its levels).  ``u = B z``: the
  basis ``B`` is built once, so an input costs one matrix-vector product.
* :class:`Multisine` — ``g * max_volts * e(t) * sum_k a_k sin(2 pi f_k t + phi_k) / peak``
  with ``K`` log-spaced frequencies inside the band, a fade ``e(t)`` in and out, the
  amplitudes ``a_k`` and phases free and an overall gain ``0.1 <= g <= 1``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..model.signals import MAX_VOLTAGE
from ..model.signals import smooth_step as _smooth_step

#: Highest band limit a design may use [Hz]: the thesis's signals stay below 5 Hz, faster
#: inputs risk damaging the set-up (thesis §3.2).
MAX_BAND_HZ = 5.0
#: Default time a level of the step family is held [s] (the estimation signal holds 0.4-2.5 s).
DEFAULT_HOLD_S = 1.5
#: Number of sines of the multisine family.
DEFAULT_SINES = 10
#: Families by name.
FAMILIES = ("steps", "multisine")


class DesignInputError(ValueError):
    """A design setting outside what the rig allows; the message names it and the fix."""


def time_grid(duration: float, rate: float) -> np.ndarray:
    """``arange(n) / rate`` with ``t[-1] == duration`` (a whole number of samples)."""
    if not (math.isfinite(duration) and duration > 0):
        raise DesignInputError(f"duration {duration!r} s: give a positive duration in seconds")
    if not (math.isfinite(rate) and rate > 0):
        raise DesignInputError(f"rate {rate!r} Hz: give a positive sampling rate")
    n = duration * rate
    if abs(n - round(n)) > 1e-6 * max(1.0, n):
        raise DesignInputError(
            f"duration {duration:g} s at {rate:g} Hz is not a whole number of samples; "
            f"choose a multiple of 1/rate = {1 / rate:g} s"
        )
    return np.arange(int(round(n)) + 1) / rate


def check_limits(max_volts: float, band_hz: float, rate: float, duration: float) -> None:
    """Refuse settings the rig does not allow, with the reason and the fix."""
    if not (math.isfinite(max_volts) and max_volts > 0):
        raise DesignInputError(
            f"--max-volts {max_volts:g}: give a positive voltage (at most {MAX_VOLTAGE:g} V)"
        )
    if max_volts > MAX_VOLTAGE:
        raise DesignInputError(
            f"--max-volts {max_volts:g} V exceeds the rig's amplifier limit of "
            f"{MAX_VOLTAGE:g} V; give --max-volts {MAX_VOLTAGE:g} or less"
        )
    if not (math.isfinite(band_hz) and band_hz > 0):
        raise DesignInputError(
            f"--band-hz {band_hz:g}: give a positive frequency (at most {MAX_BAND_HZ:g} Hz)"
        )
    if band_hz > MAX_BAND_HZ:
        raise DesignInputError(
            f"--band-hz {band_hz:g} Hz is above the rig's {MAX_BAND_HZ:g} Hz: the thesis "
            "keeps every input below it (faster inputs risk damaging the set-up, §3.2); "
            f"give --band-hz {MAX_BAND_HZ:g} or less"
        )
    if band_hz >= rate / 2:
        raise DesignInputError(
            f"--band-hz {band_hz:g} Hz is not below the Nyquist frequency "
            f"{rate / 2:g} Hz of the data's rate"
        )
    if duration < 4.0 / band_hz + 1.0:
        raise DesignInputError(
            f"--duration {duration:g} s is too short for an input with band {band_hz:g} Hz "
            f"(a ramp in, levels, a ramp out need at least {4.0 / band_hz + 1.0:g} s); "
            "give a longer duration"
        )


@dataclass
class Steps:
    """Smoothed steps: ``n_levels`` levels held ``hold`` s each, ``|u| <= max_volts``."""

    duration: float
    rate: float
    max_volts: float = MAX_VOLTAGE
    band_hz: float = MAX_BAND_HZ
    n_levels: int | None = None
    name: str = field(default="steps", init=False)

    def __post_init__(self):
        check_limits(self.max_volts, self.band_hz, self.rate, self.duration)
        self.t = time_grid(self.duration, self.rate)
        width = 2.0 / self.band_hz  # the transition, as in signals.estimation_signal
        room = self.duration - width
        if self.n_levels is None:
            self.n_levels = max(1, int(round(room / DEFAULT_HOLD_S)))
        # A level must be reached before the next transition starts.
        self.n_levels = int(max(1, min(self.n_levels, math.floor(room / width))))
        self.hold = room / self.n_levels
        jumps = 0.5 * width + self.hold * np.arange(self.n_levels + 1)
        S = np.stack([_smooth_step((self.t - tj) / width + 0.5) for tj in jumps], axis=1)
        self.basis = (S[:, :-1] - S[:, 1:]) * self.max_volts  # pulse of each level
        self.basis[0] = 0.0
        self.basis[-1] = 0.0
        self.lower = -np.ones(self.n_levels)
        self.upper = np.ones(self.n_levels)

    @property
    def size(self) -> int:
        return self.n_levels

    def __call__(self, z: np.ndarray) -> np.ndarray:
        return self.basis @ np.clip(np.asarray(z, float), -1.0, 1.0)

    def random(self, rng: np.random.Generator) -> np.ndarray:
        """A start: levels uniform in [-1, 1]."""
        return rng.uniform(-1.0, 1.0, self.n_levels)

    def describe(self) -> str:
        return (
            f"smoothed steps: {self.n_levels} levels held {self.hold:.2f} s each, "
            f"transitions of {2.0 / self.band_hz:.2f} s (Hann-smoothed, no overshoot), "
            f"|u| <= {self.max_volts:g} V, no energy above about {self.band_hz:g} Hz, "
            "0 V at both ends"
        )

    def settings(self, z) -> dict:
        return {
            "family": self.name,
            "levels_V": (np.clip(z, -1, 1) * self.max_volts).tolist(),
            "hold_s": self.hold,
            "transition_s": 2.0 / self.band_hz,
        }


@dataclass
class Multisine:
    """A faded multisine with free amplitudes, phases and gain, ``|u| <= max_volts``."""

    duration: float
    rate: float
    max_volts: float = MAX_VOLTAGE
    band_hz: float = MAX_BAND_HZ
    n_sines: int = DEFAULT_SINES
    name: str = field(default="multisine", init=False)

    def __post_init__(self):
        check_limits(self.max_volts, self.band_hz, self.rate, self.duration)
        self.t = time_grid(self.duration, self.rate)
        self.fade = max(1.0, 2.0 / self.band_hz)
        # The fade widens each line by about 1/fade: keep the lines that far inside the band.
        f_hi = self.band_hz - 1.0 / self.fade
        f_lo = min(max(2.0 / self.duration, 0.03), 0.5 * f_hi)
        self.freqs = np.geomspace(f_lo, f_hi, self.n_sines)
        self.envelope = _smooth_step(self.t / self.fade) * _smooth_step(
            (self.duration - self.t) / self.fade
        )
        w = 2 * np.pi * np.multiply.outer(self.t, self.freqs)
        self._sin, self._cos = np.sin(w), np.cos(w)
        k = self.n_sines
        self.lower = np.r_[np.zeros(k), np.zeros(k), 0.1]
        self.upper = np.r_[np.ones(k), np.ones(k), 1.0]

    @property
    def size(self) -> int:
        return 2 * self.n_sines + 1

    def __call__(self, z: np.ndarray) -> np.ndarray:
        z = np.clip(np.asarray(z, float), self.lower, self.upper)
        k = self.n_sines
        a, ph, g = z[:k], 2 * np.pi * z[k : 2 * k], z[-1]
        raw = self.envelope * (self._sin @ (a * np.cos(ph)) + self._cos @ (a * np.sin(ph)))
        peak = float(np.max(np.abs(raw)))
        if peak <= 0:
            return np.zeros_like(self.t)
        u = raw * (g * self.max_volts / peak)
        u[0] = u[-1] = 0.0
        return u

    def random(self, rng: np.random.Generator) -> np.ndarray:
        k = self.n_sines
        return np.r_[rng.uniform(0.2, 1.0, k), rng.uniform(0, 1, k), rng.uniform(0.5, 1.0)]

    def describe(self) -> str:
        return (
            f"multisine: {self.n_sines} sines at {self.freqs[0]:.3g}-{self.freqs[-1]:.3g}"
            f" Hz (log-spaced) with free amplitudes and phases, faded in and out over "
            f"{self.fade:g} s, peak |u| <= {self.max_volts:g} V, band {self.band_hz:g} Hz"
        )

    def settings(self, z) -> dict:
        z = np.clip(np.asarray(z, float), self.lower, self.upper)
        k = self.n_sines
        return {
            "family": self.name,
            "frequencies_hz": self.freqs.tolist(),
            "amplitudes": z[:k].tolist(),
            "phases_rad": (2 * np.pi * z[k : 2 * k]).tolist(),
            "gain": float(z[-1]),
            "fade_s": self.fade,
        }


def make_family(name: str, duration: float, rate: float, max_volts: float, band_hz: float):
    """The family ``name`` ('steps' or 'multisine') on this grid and within these limits."""
    if name == "steps":
        return Steps(duration, rate, max_volts, band_hz)
    if name == "multisine":
        return Multisine(duration, rate, max_volts, band_hz)
    raise DesignInputError(f"unknown input family {name!r}; choose from {', '.join(FAMILIES)}")

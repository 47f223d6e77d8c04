"""Contract tests for rotorbayes.model.signals: grid, reproducibility, bounds, bandwidth, levels."""

import numpy as np
import pytest

from rotorbayes.model import signals
from rotorbayes.model.signals import estimation_signal, make_signal, validation_signal

KINDS = ["est", "val"]


def energy_fraction_above(t: np.ndarray, u: np.ndarray, f0: float) -> float:
    """Fraction of the signal energy at frequencies above ``f0`` (Hz), from an FFT."""
    spectrum = np.abs(np.fft.rfft(u)) ** 2
    freqs = np.fft.rfftfreq(u.size, d=t[1] - t[0])
    return float(spectrum[freqs > f0].sum() / spectrum.sum())


def plateaus(u: np.ndarray, rate: float, min_length: float = 0.05) -> np.ndarray:
    """Values of the flat stretches (levels) of ``u`` lasting at least ``min_length`` s."""
    flat = np.abs(np.diff(u)) < 1e-12
    levels = []
    start = None
    for i, is_flat in enumerate(np.append(flat, False)):
        if is_flat and start is None:
            start = i
        elif not is_flat and start is not None:
            if (i - start) / rate >= min_length:
                levels.append(u[start])
            start = None
    return np.array(levels)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize(("duration", "rate"), [(30.0, 1000.0), (12.5, 200.0), (3.0, 50.0)])
def test_time_grid(kind, duration, rate):
    t, u = make_signal(kind, duration, rate=rate)
    n = round(duration * rate) + 1
    assert t.shape == u.shape == (n,)
    assert t[0] == 0.0
    assert t[-1] == duration
    np.testing.assert_allclose(np.diff(t), 1.0 / rate, rtol=1e-9)


@pytest.mark.parametrize("kind", KINDS)
def test_reproducible_and_seed_dependent(kind):
    t1, u1 = make_signal(kind, 20.0, seed=7)
    t2, u2 = make_signal(kind, 20.0, seed=7)
    _, u3 = make_signal(kind, 20.0, seed=8)
    np.testing.assert_array_equal(t1, t2)
    np.testing.assert_array_equal(u1, u2)
    assert np.max(np.abs(u1 - u3)) > 0.1


@pytest.mark.parametrize("kind", KINDS)
def test_generator_seed_matches_integer_seed(kind):
    _, from_int = make_signal(kind, 10.0, seed=3)
    _, from_rng = make_signal(kind, 10.0, seed=np.random.default_rng(3))
    np.testing.assert_array_equal(from_int, from_rng)


@pytest.mark.parametrize("kind", KINDS)
def test_same_signal_at_any_rate(kind):
    # The random draws must not depend on the rate: the same seed is the same experiment.
    t_fast, u_fast = make_signal(kind, 20.0, rate=1000.0, seed=5)
    t_slow, u_slow = make_signal(kind, 20.0, rate=250.0, seed=5)
    np.testing.assert_array_equal(t_fast[::4], t_slow)
    np.testing.assert_allclose(u_fast[::4], u_slow, rtol=0, atol=1e-12)


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize(
    ("kind", "amplitude"),
    [("est", 4.0), ("est", 5.0), ("val", 3.0), ("val", 5.0), ("est", 1.0), ("val", 0.5)],
)
def test_bounded_by_amplitude_and_uses_it(kind, amplitude, seed):
    _, u = make_signal(kind, 60.0, seed=seed, amplitude=amplitude)
    assert np.max(np.abs(u)) <= amplitude
    assert np.max(np.abs(u)) <= signals.MAX_VOLTAGE
    # The range must actually be used, or a signal of zeros would pass the bound.
    assert np.max(np.abs(u)) >= (0.75 if kind == "est" else 0.9999) * amplitude


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("seed", range(3))
def test_starts_at_rest_and_ramps_smoothly(kind, seed):
    t, u = make_signal(kind, 20.0, seed=seed)
    assert u[0] == 0.0
    assert u[-1] == 0.0
    # Smooth start: tiny during the first 10 ms, no jumps anywhere (slew rate below 50 V/s).
    assert np.max(np.abs(u[t <= 0.01])) < 1e-3
    assert np.max(np.abs(np.diff(u))) * 1000.0 < 50.0
    assert np.max(np.abs(u)) > 0.1


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("seed", range(4))
def test_energy_below_5_hz(kind, seed):
    t, u = make_signal(kind, 60.0, seed=seed)
    assert energy_fraction_above(t, u, 5.0) < 1e-4


def test_energy_metric_detects_fast_content():
    # Guard for the test above: the same metric must flag a signal with hard steps.
    t, u = estimation_signal(60.0, seed=0)
    stepped = np.round(u)
    assert energy_fraction_above(t, stepped, 5.0) > 1e-4


@pytest.mark.parametrize("bandwidth", [1.0, 2.0, 20.0])
def test_bandwidth_argument(bandwidth):
    t, u = estimation_signal(60.0, seed=1, bandwidth=bandwidth, hold=(2.0 / bandwidth, 2.5))
    assert energy_fraction_above(t, u, bandwidth) < 1e-4
    # A higher bandwidth allows faster transitions: the fastest slope scales with it.
    slope = np.max(np.abs(np.diff(u))) * 1000.0
    assert slope <= 2.0 * 2 * 4.0 * bandwidth / 2.0 + 1e-9


@pytest.mark.parametrize("seed", range(5))
def test_estimation_levels_cover_small_and_large(seed):
    _, u = estimation_signal(60.0, seed=seed)
    levels = plateaus(u, 1000.0)
    levels = levels[levels != 0.0]
    assert levels.size >= 15
    small = (np.abs(levels) >= 0.2) & (np.abs(levels) <= 1.5)
    large = np.abs(levels) >= 2.5
    assert small.mean() >= 0.25, levels
    assert large.sum() >= 3, levels
    # Direction reversals: the sign of the level changes several times.
    assert np.count_nonzero(np.diff(np.sign(levels))) >= 4, levels


def test_estimation_hold_times():
    # With a fixed hold of 1 s and 0.4 s transitions, each level is flat for 0.6 s.
    t, u = estimation_signal(20.0, seed=2, hold=(1.0, 1.0))
    for k in range(18):
        start = 0.2 + k + 0.2
        mid = (t >= start + 1e-9) & (t <= start + 0.6 - 1e-9)
        assert np.ptp(u[mid]) == 0.0
        assert u[mid][0] != 0.0
    ramp = (t > 1.2) & (t < 1.6)
    assert np.ptp(u[ramp]) > 0.0


def test_validation_frequencies():
    t, u = validation_signal(40.0, frequencies=[0.5])
    spectrum = np.abs(np.fft.rfft(u))
    freqs = np.fft.rfftfreq(u.size, d=t[1] - t[0])
    assert freqs[np.argmax(spectrum)] == pytest.approx(0.5, abs=0.03)
    # The default set lies between 0.05 and 1 Hz; only the fade's leakage reaches 1.5 Hz.
    assert all(0.04 <= f <= 1.0 for f in signals.DEFAULT_VALIDATION_FREQUENCIES)
    t, u = validation_signal(60.0)
    assert energy_fraction_above(t, u, 1.5) < 1e-3


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"duration": 0.0}, r"duration.*0\.0"),
        ({"duration": -3.0}, r"duration.*-3\.0"),
        ({"rate": 0.0}, r"rate.*0\.0"),
        ({"rate": -100.0}, r"rate.*-100\.0"),
        ({"amplitude": 5.5}, r"amplitude 5\.5 V exceeds .* 5\.0 V"),
        ({"amplitude": 0.0}, r"amplitude.*0\.0"),
        ({"duration": 10.0005}, r"whole number.*0\.001 s"),
        ({"duration": 0.5}, r"too short"),
    ],
)
def test_bad_arguments(kind, kwargs, match):
    args = {"duration": 20.0, **kwargs}
    with pytest.raises(ValueError, match=match):
        make_signal(kind, **args)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"hold": (0.0, 1.0)}, r"hold"),
        ({"hold": (2.0, 1.0)}, r"hold"),
        ({"bandwidth": 0.0}, r"bandwidth.*0\.0"),
        ({"bandwidth": 600.0}, r"bandwidth.*Nyquist.*600\.0"),
    ],
)
def test_bad_estimation_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        estimation_signal(20.0, **kwargs)


@pytest.mark.parametrize("frequencies", [[], [0.0], [-1.0], [500.0], [float("nan")]])
def test_bad_validation_frequencies(frequencies):
    with pytest.raises(ValueError, match="frequenc"):
        validation_signal(20.0, frequencies=frequencies)


def test_make_signal_dispatch_and_unknown_kind():
    np.testing.assert_array_equal(
        make_signal("est", 10.0, seed=4)[1], estimation_signal(10.0, seed=4)[1]
    )
    np.testing.assert_array_equal(
        make_signal("val", 10.0, seed=4)[1], validation_signal(10.0, seed=4)[1]
    )
    with pytest.raises(ValueError, match=r"'chirp'.*'est', 'val'"):
        make_signal("chirp", 10.0)

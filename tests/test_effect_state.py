"""Effects with a state (issue 32, point 1): the kernel integrates one effect state ``z``
with the rig's state.

Accuracy tests compare with ``tests/reference.py`` extended to the same physics (its
``state_rate``/``state_reset``: the state integrated by scipy's DOP853 with the rig, exact
switching), never with the kernel's own output; the self-checks compare the kernel with
itself at much shorter steps, and say so.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from reference import reference_simulate

import rotorbayes as rb
from rotorbayes import Effect, Parameter
from rotorbayes.model import Model
from rotorbayes.model.effects import EffectError
from rotorbayes.model.parameters import thesis_set

TOL = 1.5e-5
ROOT = Path(__file__).resolve().parents[1]
WARM = str(ROOT / "examples" / "friction_warming.py") + ":friction_warming"


def _slide_rate(t, thu, wu, thl, wl, v, z, p, q):
    return abs(wl)


def _slide_shift(t, thu, wu, thl, wl, v, z, p, q):
    return 0.0, -q[0] * z / (1.0 + z)


#: The lower friction level falls with the distance slid since the disc last stuck (a
#: film that builds while sliding and is squeezed out at every stop): a state reset at
#: each stick of the lower disc.
SLIDE = Effect(
    name="slide_memory",
    physics="the lower friction level falls with the distance slid since the last stop.",
    parameters=(
        Parameter("a_slide", "N m", 0.0, 0.05, 0.0, "fall of the friction level", start=0.005),
    ),
    signature="-",
    configs=("coupled", "brake"),
    friction_shift=_slide_shift,
    state="slid",
    state_rate=_slide_rate,
    state_reset="l",
)


def test_a_state_needs_its_rate_and_one_per_model():
    with pytest.raises(ValueError, match="state_rate"):
        Effect("x", "-", (Parameter("a", "-", 0, 1, 0, "-"),), "-", state="s", torque=_slide_shift)
    with pytest.raises(ValueError, match="state_reset"):
        Effect(
            "x",
            "-",
            (Parameter("a", "-", 0, 1, 0, "-"),),
            "-",
            state="s",
            state_rate=_slide_rate,
            state_reset="x",
        )
    other = Effect(
        "other",
        "-",
        (Parameter("b_other", "-", 0, 1, 0, "-"),),
        "-",
        configs=("brake",),
        state="s2",
        state_rate=_slide_rate,
    )
    with pytest.raises(EffectError, match="at most one stateful effect"):
        Model("brake").with_effects([SLIDE, other])
    assert Model("brake").with_effects([WARM]).stateful.name == "friction_warming"
    assert Model("brake").stateful is None


def test_a_state_that_does_nothing_changes_nothing():
    """Kernel against itself: the example at k_warm = 0 gives the plain model's angles bit
    for bit (the state is integrated, and nothing reads it)."""
    t, u = rb.signals.estimation_signal(10.0, seed=3)
    p = thesis_set("4.3", "P_ref")
    plain = rb.simulate(p, u, dt=1e-3, config="brake")
    off = rb.simulate(dict(p, k_warm=0.0, tau_warm=2.0), u, dt=1e-3, config="brake", effects=[WARM])
    assert np.array_equal(off.theta_u, plain.theta_u)
    assert np.array_equal(off.theta_l, plain.theta_l)


@pytest.mark.parametrize("tau", [0.01, 0.002])
def test_a_fast_state_is_followed(tau):
    """Kernel against itself at 0.1 ms steps: the state's own substeps keep a state of
    2-10 ms within the accuracy target at the default step (the steps are 55 ms)."""
    t, u = rb.signals.estimation_signal(30.0, seed=3)
    p = dict(thesis_set("4.3", "P_ref"), k_warm=0.001, tau_warm=tau)
    s = rb.simulate(p, u, dt=1e-3, config="brake", effects=[WARM])
    fine = rb.simulate(p, u, dt=1e-3, config="brake", effects=[WARM], step=1e-4)
    assert np.max(np.abs(s.theta_l - fine.theta_l)) < TOL
    assert np.max(np.abs(s.theta_u - fine.theta_u)) < TOL


def _warm_ref(k, tau):
    def rate(t, thu, wu, thl, wl, v, z):
        return (k * abs(wl) - z) / tau

    def shift(t, thu, wu, thl, wl, v, z):
        return 0.0, -z

    return rate, shift


@pytest.mark.slow
@pytest.mark.parametrize("config,k,tau", [("brake", 0.001, 0.5), ("coupled", 0.0015, 3.0)])
def test_the_example_matches_the_reference(config, k, tau):
    t, u = rb.signals.estimation_signal(30.0, seed=3)
    base = thesis_set("4.3" if config == "brake" else "4.2", "P_ref")
    sim = rb.simulate(dict(base, k_warm=k, tau_warm=tau), u, dt=1e-3, config=config, effects=[WARM])
    plain = rb.simulate(base, u, dt=1e-3, config=config)
    q = dict(base)
    if config == "coupled":
        q["Ts_l"] = q["Tc_l"]
    rate, shift = _warm_ref(k, tau)
    ref = reference_simulate(q, t, u, config, state_rate=rate, friction_shift=shift)
    assert np.max(np.abs(sim.theta_l - ref["theta_l"])) < TOL
    assert np.max(np.abs(sim.theta_u - ref["theta_u"])) < TOL
    assert np.max(np.abs(sim.theta_l - plain.theta_l)) > 1e-2  # the effect matters
    if config == "brake":
        assert 0.05 < sim.stick_fraction("l") < 0.95


@pytest.mark.slow
def test_a_state_reset_at_stick_matches_the_reference():
    t, u = rb.signals.estimation_signal(30.0, seed=3)
    base = thesis_set("4.3", "P_ref")
    sim = rb.simulate(dict(base, a_slide=0.02), u, dt=1e-3, config="brake", effects=[SLIDE])
    assert 0.05 < sim.stick_fraction("l") < 0.95

    def shift(t, thu, wu, thl, wl, v, z):
        return 0.0, -0.02 * z / (1.0 + z)

    def rate(t, thu, wu, thl, wl, v, z):
        return abs(wl)

    ref = reference_simulate(
        base, t, u, "brake", state_rate=rate, friction_shift=shift, state_reset="l"
    )
    assert np.max(np.abs(sim.theta_l - ref["theta_l"])) < TOL
    assert np.max(np.abs(sim.theta_u - ref["theta_u"])) < TOL
    never = reference_simulate(base, t, u, "brake", state_rate=rate, friction_shift=shift)
    assert np.max(np.abs(never["theta_l"] - ref["theta_l"])) > 1e-3  # the reset matters


def test_a_stateful_effect_is_fitted(tmp_path):
    """Recovery (data made by the kernel itself, quantised and noisy): a fit with the
    example frees its parameters and lands near them, at the floor."""
    from rotorbayes import inference

    t, u = rb.signals.estimation_signal(20.0, seed=4)
    truth = dict(thesis_set("4.3", "P_ref"), k_warm=0.0012, tau_warm=1.5)
    ex = rb.simulate(
        truth, u, dt=1e-3, config="brake", effects=[WARM], quantize_angles=True
    ).to_experiment("warm")
    prob = inference.Problem(Model("brake").with_effects([WARM]), [ex], base=truth)
    start = dict(truth, k_warm=0.0008, tau_warm=3.0)
    res = inference.fit(prob, prob.start_vector(start))
    got = prob.params_for(res.x, 0)
    assert abs(got["k_warm"] / truth["k_warm"] - 1) < 0.05, got
    assert abs(got["tau_warm"] / truth["tau_warm"] - 1) < 0.1, got
    assert max(prob.rms_over_floor(prob.residuals(res.x)).values()) < 1.5

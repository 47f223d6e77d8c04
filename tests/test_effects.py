"""The registry of effects: contracts, refusals, accuracy against the independent reference,
smoothness in every effect parameter, Jacobians for effects that are off, and user effects.

Accuracy tests compare with ``tests/reference.py`` (scipy DOP853, exact switching, every input
kink a breakpoint; it does not import rotorbayes).  The recovery test fits data made by the
package's own simulator: it proves recovery of the user effect's parameters, not accuracy.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from reference import reference_simulate

import rotorbayes as rb
from rotorbayes import inference
from rotorbayes.cli import main
from rotorbayes.io.measurements import LOWER_COUNTS_PER_REV
from rotorbayes.model import CATALOGUE, Model
from rotorbayes.model.effects import EffectError
from rotorbayes.model.parameters import INFO, thesis_set

TOL = 1.5e-5
ROOT = Path(__file__).resolve().parents[1]
USER = str(ROOT / "examples" / "angle_friction.py") + ":angle_friction"
FLOOR_L = 2 * math.pi / LOWER_COUNTS_PER_REV / math.sqrt(12)


def _ripple(p, a, phi):
    """The example user effect's physics, written again for the reference."""

    def shift(t, thu, wu, thl, wl, v):
        return 0.0, p["Tc_l"] * a * math.sin(thl + phi)

    return shift


# ------------------------------------------------------------------------- contracts
def test_every_catalogue_effect_declares_its_parameters():
    for e in CATALOGUE.values():
        assert e.physics and e.signature and e.kernel_term
        for p in e.parameters:
            assert INFO[p.name] is p  # one declaration, used everywhere
            assert p.unit and p.lower < p.upper
    names = {p for e in CATALOGUE.values() for p in e.names}
    assert {"dTc_u", "db_u", "dTc_l", "db_l", "Ts_l", "alpha0", "c_alpha", "u_offset",
            "t_delay", "u_deadzone"} <= names  # fmt: skip
    assert any("dTc_u" in q for q in CATALOGUE["voltage_offset"].equivalences)
    assert any("alpha0" in q for q in CATALOGUE["lower_asymmetric_coulomb"].equivalences)


def test_add_frees_exactly_the_effect_parameters():
    ex = rb.load_example("coupled_est")
    base = inference.Problem("coupled", [ex])
    for name in ("string_damping", "input_delay", "lower_stribeck", "lower_asymmetric_coulomb"):
        prob = inference.Problem("coupled", [ex], effects=[name])
        assert prob.names == base.names + list(CATALOGUE[name].names)
    user = inference.Problem("coupled", [ex], effects=[USER])
    assert user.names == base.names + ["a_fric", "phi_fric"]


def test_parameters_of_an_effect_that_is_off_are_refused():
    ex = rb.load_example("coupled_est")
    with pytest.raises(rb.ParameterError, match="string_damping.*is off"):
        inference.Problem("coupled", [ex], free=["J_l", "c_alpha"])
    with pytest.raises(rb.ParameterError, match="--add lower_asymmetric_coulomb"):
        inference.Problem("coupled", [ex], base=thesis_set("5.3", "P"))
    u = np.zeros(100)
    with pytest.raises(rb.ParameterError, match="lower_stribeck"):
        rb.simulate("thesis:4.3:P_ref", u, dt=1e-3, config="coupled")
    p = dict(thesis_set("4.2", "P_ref"), c_alpha=0.01)
    with pytest.raises(rb.ParameterError, match="string_damping"):
        rb.simulate(p, u, dt=1e-3, config="coupled")
    s = rb.simulate(p, u, dt=1e-3, config="coupled", effects=["string_damping"])
    assert s.ok and s.status == 0


def test_cli_add_and_refusals(tmp_path, capsys):
    out = tmp_path / "f"
    code = main(["fit", "--model", "coupled", "example:coupled_est", "--free", "J_l",
                 "--add", "string_damping", "--max-nfev", "3", "--out", str(out)])  # fmt: skip
    text = capsys.readouterr().out
    assert code in (0, 1) and "fitting 2 parameters (J_l, c_alpha)" in text
    assert main(["fit", "--model", "coupled", "example:coupled_est", "--free", "J_l,c_alpha",
                 "--out", str(tmp_path / "g")]) == 2  # fmt: skip
    assert "--add string_damping" in capsys.readouterr().err
    assert main(["fit", "--model", "upper", "example:upper_est", "--add", "string_damping",
                 "--out", str(tmp_path / "h")]) == 2  # fmt: skip
    assert "does not apply to the upper configuration" in capsys.readouterr().err
    assert main(["fit", "--model", "coupled", "example:coupled_est", "--add",
                 "nope.py:x", "--out", str(tmp_path / "i")]) == 2  # fmt: skip
    assert "nope.py: effect file not found" in capsys.readouterr().err
    assert main(["effects"]) == 0
    listing = capsys.readouterr().out
    for name in CATALOGUE:
        assert name in listing
    assert main(["effects", USER]) == 0
    assert "a_fric" in capsys.readouterr().out


def test_bad_user_effect_files_are_refused_with_the_file_named(tmp_path):
    f = tmp_path / "bad.py"
    f.write_text(
        "from rotorbayes import Effect, Parameter\n"
        "def shift(t, a, b, c, d, v, p, q):\n    return 'x', 0.0\n"
        "bad = Effect('bad', 'x', (Parameter('g', '-', 0.0, 1.0, 0.0, 'g'),), 'x',\n"
        "             friction_shift=shift)\n"
        "clash = Effect('clash', 'x', (Parameter('J_l', '-', 0.0, 1.0, 0.0, 'g'),), 'x',\n"
        "               friction_shift=shift)\n"
    )
    with pytest.raises(EffectError, match="does not compile with numba"):
        rb.Simulator("coupled", np.zeros(10), 1e-3, effects=[f"{f}:bad"]).run(
            (np.zeros(20), np.zeros(1))
        )
    with pytest.raises(EffectError, match="built-in parameters"):
        Model("coupled", [f"{f}:clash"])
    with pytest.raises(EffectError, match="defines no effect 'other'; it defines: bad, clash"):
        Model("coupled", [f"{f}:other"])


def test_status_travels_on_the_result():
    u = np.zeros(50)
    s = rb.Simulator("coupled", u, 1e-3).simulate(
        dict(thesis_set("4.2", "P_ref"), J_l=-1.0), raise_on_failure=False
    )
    assert not s.ok and "invalid parameters" in s.status_message
    prob = inference.Problem("coupled", [rb.load_example("coupled_est")])
    x = prob.x_from(dict(prob.base, J_l=-0.01))
    ev = prob.evaluate(x)
    assert not ev.ok and np.all(np.isnan(ev.residuals)) and "invalid" in ev.reasons()[0]


# ---------------------------------------------------------------------- accuracy
def _accuracy_cases():
    brake = thesis_set("4.3", "P_ref")
    coupled = thesis_set("4.2", "P_ref")
    return [
        ("lower_asymmetric_coulomb", "brake", dict(brake, dTc_l=0.004), 1000),
        ("lower_asymmetric_viscous", "coupled", dict(coupled, db_l=0.002), 1000),
        ("lower_stribeck", "coupled", dict(coupled, Ts_l=0.03, ws_l=0.8, delta_l=1.5), 1000),
        ("initial_torsion", "brake", dict(brake, alpha0=-1.1), 1000),
        ("string_damping", "brake", dict(brake, c_alpha=0.002), 1000),
        ("voltage_offset", "brake", dict(brake, u_offset=0.05), 1000),
        ("input_delay", "brake", dict(brake, t_delay=0.0123), 1000),
        ("input_delay", "brake", dict(brake, t_delay=0.0123), 200),
        ("motor_deadzone", "brake", dict(brake, u_deadzone=0.3), 1000),
        ("motor_deadzone", "coupled", dict(coupled, u_deadzone=0.05), 200),
        ("upper_asymmetric_coulomb", "upper", dict(thesis_set("4.1", "P_ref"), dTc_u=0.05),
         1000),
    ]  # fmt: skip


@pytest.mark.slow
@pytest.mark.parametrize(
    "effect,config,params,rate",
    _accuracy_cases(),
    ids=[f"{c[0]}-{c[3]}Hz" for c in _accuracy_cases()],
)
def test_effect_matches_the_reference(effect, config, params, rate):
    t, u = rb.signals.estimation_signal(30.0, seed=3, rate=rate)
    effects = [] if effect in Model(config).effect_names else [effect]
    sim = rb.simulate(params, u, dt=t[1] - t[0], config=config, effects=effects)
    q = dict(params)
    if config == "coupled" and effect != "lower_stribeck":
        q["Ts_l"] = q["Tc_l"]
    ref = reference_simulate(q, t, u, config)
    assert np.max(np.abs(sim.theta_u - ref["theta_u"])) < TOL
    if config != "upper":
        assert np.max(np.abs(sim.theta_l - ref["theta_l"])) < TOL
        if config == "brake":  # the lower-disc effects act with stick-slip present
            assert 0.05 < sim.stick_fraction("l") < 0.95


@pytest.mark.slow
def test_user_effect_matches_the_reference():
    t, u = rb.signals.estimation_signal(30.0, seed=3)
    p = dict(thesis_set("4.3", "P_ref"), a_fric=0.3, phi_fric=0.7)
    sim = rb.simulate(p, u, dt=1e-3, config="brake", effects=[USER])
    plain = rb.simulate(thesis_set("4.3", "P_ref"), u, dt=1e-3, config="brake")
    ref = reference_simulate(
        thesis_set("4.3", "P_ref"), t, u, "brake",
        friction_shift=_ripple(thesis_set("4.3", "P_ref"), 0.3, 0.7),
    )  # fmt: skip
    assert np.max(np.abs(sim.theta_l - ref["theta_l"])) < TOL
    assert np.max(np.abs(sim.theta_u - ref["theta_u"])) < TOL
    assert np.max(np.abs(sim.theta_l - plain.theta_l)) > 1e-2  # the effect matters
    assert 0.05 < sim.stick_fraction("l") < 0.95


# -------------------------------------------------------------------- smoothness
@pytest.fixture(scope="module")
def brake_scan():
    t, u = rb.signals.estimation_signal(15.0, seed=5)
    return u


SMOOTH = [
    ("string_damping", "c_alpha", 0.002),
    ("voltage_offset", "u_offset", 0.05),
    ("input_delay", "t_delay", 0.012),
    ("motor_deadzone", "u_deadzone", 0.2),
    ("lower_asymmetric_coulomb", "dTc_l", 0.004),
    (USER, "a_fric", 0.3),
    (USER, "phi_fric", 0.7),
]


@pytest.mark.parametrize("effect,name,value", SMOOTH, ids=[s[1] for s in SMOOTH])
def test_smooth_in_every_effect_parameter(brake_scan, effect, name, value):
    u = brake_scan
    sim = rb.Simulator("brake", u, 1e-3, effects=[effect])
    p = dict(thesis_set("4.3", "P_ref"), **sim.model.null_values())
    p[name] = value
    if name == "phi_fric":
        p["a_fric"] = 0.3
    meas = sim.simulate(p).theta_l

    def thl(v):
        st, _, out = sim.angles(sim.kernel_vector(dict(p, **{name: v})))
        assert st == 0
        return out

    grid = value * (1 + np.linspace(-0.05, 0.05, 201))
    f = np.array([np.sum((thl(v) - meas) ** 2) for v in grid])
    d1, d2 = np.diff(f), np.diff(f, 2)
    assert np.max(np.abs(d2)) < 0.05 * np.max(np.abs(d1)) + 1e-12
    ders = [(thl(value * (1 + r)) - thl(value * (1 - r))) / (2 * r * value) for r in (1e-4, 1e-6)]
    scale = np.max(np.abs(ders[0]))
    assert scale > 0
    assert np.max(np.abs(ders[0] - ders[1])) < 1e-3 * scale


# ---------------------------------------------------------------------- Jacobian
def test_jacobian_of_effects_that_are_off():
    ex = rb.load_example("coupled_est")
    prob = inference.Problem("coupled", [ex], base=thesis_set("5.2", "P"))
    x = prob.x_from(prob.base)
    J, steps = prob.jacobian(x, ["c_alpha", "t_delay", "Ts_l", "ws_l", "J_l"])
    assert steps[0] > 0 and steps[1] > 0  # one-sided, inwards from the null on a bound
    # Against a direct difference with the effect on.
    on = inference.Problem("coupled", [ex], effects=["string_damping"], base=thesis_set("5.2", "P"))
    x_on = on.x_from(on.base)
    h = 1e-5
    r0 = on.residuals(x_on)
    r1 = on.residuals(on.x_from(dict(on.base, c_alpha=h)))
    direct = (r1 - r0) / h
    assert np.max(np.abs(J[:, 0] - direct)) < 1e-3 * np.max(np.abs(direct))
    assert np.max(np.abs(J[:, 2])) > 0  # a static level above Coulomb matters ...
    assert np.max(np.abs(J[:, 3])) == 0  # ... the Stribeck velocity does not, at the null
    np.testing.assert_allclose(J[:, 4], prob.jacobian(x, ["J_l"])[0][:, 0], rtol=1e-12)


# ---------------------------------------------------------------------- recovery
def _angle_friction_data(tmp_path, a_fric, start):
    """Coupled data with the example's angle friction (``a_fric``), quantised, 30 s at
    200 Hz, in ``est.csv``; a start file with ``start`` = (J_l, k_alpha, Tc_l, b_l).
    Returns the truth, the simulation and the start file."""
    t, u = rb.signals.estimation_signal(30.0, seed=11, rate=200.0)
    truth = dict(thesis_set("4.2", "P_ref"), J_l=0.05, k_alpha=0.06, Tc_l=0.03, b_l=0.012)
    truth.update(a_fric=a_fric, phi_fric=-1.1)
    sim = rb.simulate(truth, u, dt=t[1] - t[0], config="coupled", effects=[USER],
                      quantize_angles=True)  # fmt: skip
    rb.save_experiment(sim.to_experiment(), tmp_path / "est.csv")
    path = tmp_path / "p0.toml"
    path.write_text(
        'base = "thesis:4.2:P_ref"\n'
        + "".join(
            f"{k} = {v!r}\n" for k, v in zip(("J_l", "k_alpha", "Tc_l", "b_l"), start, strict=True)
        )
    )
    return truth, sim, path


@pytest.mark.slow
def test_user_effect_fit_recovers_its_parameters(tmp_path, capsys):
    """Recovery (the package's own simulator made the data), through the CLI."""
    truth, sim, start = _angle_friction_data(tmp_path, 0.35, (0.045, 0.055, 0.033, 0.011))
    out = tmp_path / "fit"
    code = main(["fit", "--model", "coupled", str(tmp_path / "est.csv"), "--p0", str(start),
                 "--add", USER, "--out", str(out)])  # fmt: skip
    capsys.readouterr()
    assert code == 0
    import json

    doc = json.loads((out / "fit.json").read_text())
    est = {k: v["value"] for k, v in doc["estimates"].items()}
    for k in ("J_l", "k_alpha", "Tc_l", "b_l", "a_fric", "phi_fric"):
        assert abs(est[k] / truth[k] - 1) < 0.02, (k, est[k], truth[k])
    rms = math.sqrt(doc["quality"]["estimation"][0]["channels"]["theta_l"]["ssr"] / sim.t.size)
    assert rms < 1.5 * FLOOR_L


@pytest.mark.slow
def test_diagnose_tests_a_user_effect_beside_the_catalogue(tmp_path, capsys):
    """Trial 12: a user effect could not be score-tested before a refit, and the refit
    started it at the file's defaults.  `diagnose --add FILE.py:NAME` tests it with the
    catalogue's rules; the printed refit command adds the file, and `fit --p0` starts the
    effect at the one-step estimate (recovery: the package's own simulator made the data)."""
    import json

    _, _, start = _angle_friction_data(tmp_path, 0.08, (0.05, 0.06, 0.03, 0.012))
    f0 = tmp_path / "f0"
    assert (
        main(
            [
                "fit",
                "--model",
                "coupled",
                str(tmp_path / "est.csv"),
                "--p0",
                str(start),
                "--out",
                str(f0),
            ]
        )
        == 0
    )
    assert main(["diagnose", str(f0)]) == 0
    capsys.readouterr()
    d = json.loads((f0 / "diagnosis.json").read_text())
    assert "angle_friction" not in [row["effect"] for row in d["ranking"]]
    assert main(["diagnose", str(f0), "--add", USER]) == 0
    capsys.readouterr()
    d = json.loads((f0 / "diagnosis.json").read_text())
    rows = {row["effect"]: row for row in d["ranking"]}
    own = rows["angle_friction"]
    # Its one-step estimate is the truth's size (the phase grid may flip its sign), and
    # it predicts the largest fall of the error of all candidates.
    est = own["parameters"]["a_fric"]["one_step_estimate"]
    assert 0.05 < abs(est) < 0.11, est
    worst = {
        k: max(v["predicted_rms_over_floor"].values())
        for k, v in rows.items()
        if v.get("predicted_rms_over_floor")
    }
    assert min(worst, key=worst.get) == "angle_friction", worst
    # (Not claimed: its p is 0.047 before correction.  Measured with a_fric = 0.04 on
    # these data: all 30 time blocks' scores share its sign, but their sizes differ so
    # much that the block t-statistic stays at 2.3.)
    assert (
        main(
            [
                "fit",
                "--model",
                "coupled",
                str(tmp_path / "est.csv"),
                "--p0",
                str(f0),
                "--add",
                USER,
                "--out",
                str(tmp_path / "f1"),
            ]
        )
        == 0
    )
    # The refit searches the user effect's parameters; one start is the diagnosis's
    # one-step estimate.
    assert "the diagnosis's one-step estimate" in capsys.readouterr().out
    doc = json.loads((tmp_path / "f1" / "fit.json").read_text())
    assert max(doc["assessment"]["worst_ratio_to_floor"], 0) < 1.5
    for bad, needle in (
        ("lower_stribeck", "FILE.py:NAME"),
        (str(tmp_path / "none.py") + ":x", "none.py"),
    ):
        assert main(["diagnose", str(f0), "--add", bad]) == 2
        assert needle in capsys.readouterr().err


def test_the_refit_command_adds_a_user_effect_by_its_file():
    from pathlib import Path

    from rotorbayes.commands.diagnose import _with_refit_command
    from rotorbayes.diagnosis.diagnose import REFIT_TOKEN

    advice = f"Add it and refit: {REFIT_TOKEN} --add angle_drag; then diagnose the new fit"
    doc = {"config": "brake", "data_files": [{"path": "/d/est.csv"}]}
    got = _with_refit_command(advice, Path("/f/fit0"), doc, {"angle_drag": "my.py:angle_drag"})
    assert "--add my.py:angle_drag --out fit0_angle_drag/" in got


_BLIND_EFFECTS = """\
import math

from rotorbayes import Effect, Parameter
from rotorbayes.kernel.layout import K_M


def _sat(t, theta_u, omega_u, theta_l, omega_l, v, p, q):
    lin = p[K_M] * v
    s = q[0]
    x = lin * s
    d = lin * x * x / 3.0 if abs(x) < 1e-4 else lin - math.tanh(x) / s
    return -d, 0.0


sat = Effect(
    name="sat",
    physics="a motor torque that saturates, written with a zero slope at its null",
    parameters=(Parameter("s_sat", "1/(N m)", 0.0, 1.0, 0.0, "inverse saturation", start=0.05),),
    signature="",
    configs=("upper", "coupled", "brake"),
    torque=_sat,
)


def _gain(t, theta_u, omega_u, theta_l, omega_l, v, p, q):
    return q[0] * v, 0.0


gain = Effect(
    name="gain",
    physics="a second motor constant: the model's own",
    parameters=(Parameter("g_v", "N m/V", -1.0, 1.0, 0.0, "extra gain", start=0.1),),
    signature="",
    configs=("upper", "coupled", "brake"),
    torque=_gain,
)
"""


def test_a_user_effect_with_no_slope_at_its_null_is_blind_not_equivalent(tmp_path):
    """A saturating motor written as ``k_m v - tanh(s k_m v) / s`` has a torque cubic in
    ``s`` at 0: the score test's derivative is ~0, and it was tagged "equivalent to the
    free parameters: cannot be told apart", though its refit took a fresh user's fit from
    1120x the floor to 0.957x.  A secant tells the two apart: such an effect is blind at
    its null; a second motor constant (``g v``) is the model's own and stays equivalent."""
    from rotorbayes.diagnosis import diagnose

    (tmp_path / "eff.py").write_text(_BLIND_EFFECTS)
    t, u = rb.signals.estimation_signal(8.0, seed=1)
    p = rb.parameters.resolve(
        dict(k_m=3.1, Tc_u=0.62, dTc_u=0.03, b_u=1.7, db_u=0.05), config="upper"
    )
    ex = rb.simulate(p, u, dt=t[1] - t[0], config="upper").to_experiment("up")
    prob = inference.Problem("upper", [ex], base=p)
    x = prob.x_from(p)
    rows = {}
    for name in ("sat", "gain"):
        d = diagnose(prob, x, user_effects=[f"{tmp_path / 'eff.py'}:{name}"])
        rows[name] = (next(s for s in d.ranking if s.effect == name), d.text())
    sat, sat_text = rows["sat"]
    gain, gain_text = rows["gain"]
    assert sat.blind and not sat.equivalent_to_free and sat.as_dict()["blind_at_null"]
    (line,) = [ln for ln in sat_text.splitlines() if ln.startswith("  sat ")]
    assert "no first-order effect at its null" in line and "equivalent" not in line, line
    assert gain.equivalent_to_free and not gain.blind
    (line,) = [ln for ln in gain_text.splitlines() if ln.startswith("  gain ")]
    assert "equivalent to the free parameters" in line, line

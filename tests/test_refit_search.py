"""Adding an effect is a refit that lands (issue 30, point 1).

The hard case is data from the independent reference (``tests/reference.py``: coupled, 30 s
at 1 kHz, encoder-quantised, driven by the continuous step-like input) with a lower Stribeck
curve hidden at parameters unlike the thesis (the static level 2.06x the Coulomb level, the
Stribeck velocity 0.5 rad/s).  The first fit is thousands of times the floor; the diagnosis
names ``lower_stribeck``; from the diagnosis's one-step estimate alone (``--no-search``, the
old behaviour) the refit landed in a wrong basin under the optimiser handed the whole
Jacobian (it reaches the floor under the compressed one); the search's starts disagree.
The search over the added parameters must land at the floor.  This proves the loop, on
data rotorbayes did not make.

The small tests check the search's starts and words without fitting.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from refdata import SETS, make_experiment

from rotorbayes.cli import main
from rotorbayes.inference import Problem
from rotorbayes.inference.refit import (
    added_names,
    diagnosis_prediction,
    prediction_note,
    refit_starts,
)
from rotorbayes.io.measurements import save_experiment

STRIBECK = dict(SETS["coupled"][0], Ts_l=0.07, ws_l=0.5, delta_l=1.6)


def _doc(folder) -> dict:
    return json.loads((folder / "fit.json").read_text())


@pytest.fixture(scope="module")
def stribeck_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("refit")
    for label, seed in (("est", 3), ("val", 4)):
        ex = make_experiment(
            "coupled", STRIBECK, duration=30.0, signal="steps", hold="continuous", seed=seed
        )
        save_experiment(ex, d / f"{label}.csv")
    return d


@pytest.mark.slow
def test_stribeck_refit_lands_where_the_one_step_start_does_not(stribeck_files, capsys):
    d = stribeck_files
    data = [str(d / "est.csv"), "--validate", str(d / "val.csv")]
    assert main(["fit", "--model", "coupled", *data, "--out", str(d / "fit0")]) in (0, 1)
    first = _doc(d / "fit0")["assessment"]["worst_ratio_to_floor"]
    assert first > 100, first  # the model lacks the Stribeck curve: far from the floor
    assert main(["diagnose", str(d / "fit0")]) in (0, 1)
    printed = capsys.readouterr().out
    diag = json.loads((d / "fit0" / "diagnosis.json").read_text())
    named = diag.get("claimed_effect") or diag.get("candidate_effect")
    assert named == "lower_stribeck", named
    assert "--add lower_stribeck" in printed
    refit = ["fit", "--model", "coupled", *data, "--p0", str(d / "fit0"), "--add", "lower_stribeck"]
    # The old refit: the added parameters from the one-step estimate only.
    main([*refit, "--no-search", "--out", str(d / "one")])
    one = _doc(d / "one")["assessment"]["worst_ratio_to_floor"]
    # Under the optimiser handed the whole Jacobian this start ended in a wrong basin (over
    # 10x the floor); under the compressed one (the default now) it reached 0.90x on this
    # data.  The case stays hard all the same: the search's starts disagree (checked below),
    # and the search must do at least as well as the one-step start.
    assert math.isfinite(one), one
    capsys.readouterr()
    assert main([*refit, "--out", str(d / "fit1")]) == 0
    out = capsys.readouterr().out
    doc = _doc(d / "fit1")
    a = doc["assessment"]
    assert a["worst_ratio_to_floor"] <= 1.5, a["worst_ratio_to_floor"]
    assert a["worst_ratio_to_floor"] <= one * 1.05 + 1e-9, (a["worst_ratio_to_floor"], one)
    assert not a["at_bound"] and not a["near_bound"], (a["at_bound"], a["near_bound"])
    # The truth is recovered (recovery on independent data: within 4 honest std. errors).
    for n in ("Tc_l", "Ts_l", "ws_l", "delta_l", "J_l", "k_alpha"):
        e = doc["estimates"][n]
        assert abs(e["value"] - STRIBECK[n]) <= 4 * e["stderr"], (n, e, STRIBECK[n])
    # Every start is recorded and said; the disagreement is said in words.
    rec = doc["refit"]
    assert rec["searched"] == ["Ts_l", "ws_l", "delta_l"]
    assert len(rec["starts"]) >= 5
    labels = [s["start"] for s in rec["starts"]]
    assert "the diagnosis's one-step estimate" in labels
    assert "the effect's typical start" in labels
    assert rec["disagreed"] and "the starts disagreed" in out
    assert "predicted" in out and "the refit ended at" in out
    # Validation: at the floor, or within what the estimates' own uncertainty predicts
    # for that experiment (its 90 % point over parameter draws).
    v = a["worst_ratio_to_floor_validation"]
    spread = a.get("validation_spread") or {}
    assert v <= max(1.5, spread.get("q90", 0.0)), (v, spread)


# ----------------------------------------------------------------- the search, no fitting
def _coupled_problem(effects):
    from rotorbayes.io.measurements import Experiment

    t = np.arange(2001) / 1000.0
    u = 2.0 * np.sin(2 * np.pi * 0.5 * t)
    ex = Experiment(t, u, np.zeros_like(t), np.zeros_like(t), name="zeros")
    return Problem("coupled", [ex], effects=effects, base=dict(SETS["coupled"][0]))


def test_starts_cover_one_step_typical_spread_and_data():
    prob = _coupled_problem(["lower_stribeck"])
    x = prob.start_vector(prob.base)
    starts = refit_starts(prob, x, {"Ts_l": 0.09, "ws_l": 3.0, "delta_l": 0.7}, data_start=False)
    labels = [s.label for s in starts]
    assert labels[0] == "the diagnosis's one-step estimate"
    assert labels[1] == "the effect's typical start"
    assert labels[2] == "the effect off (the parent fit itself)"
    assert starts[2].x0[prob.names.index("Ts_l")] == prob.base["Tc_l"]
    assert sum(lb.startswith("spread: ws_l") for lb in labels) == 6
    j = prob.names.index("ws_l")
    assert starts[0].x0[j] == 3.0
    # Only the added parameters differ between starts; the rest is the parent's.
    others = [k for k, n in enumerate(prob.names) if n not in added_names(prob)]
    for s in starts:
        assert np.array_equal(s.x0[others], x[others])
    # No start twice.
    assert len({tuple(s.x0) for s in starts}) == len(starts)


def test_an_effect_without_a_shape_is_spread_over_its_size():
    prob = _coupled_problem(["string_damping"])
    x = prob.start_vector(prob.base)
    starts = refit_starts(prob, x, {}, data_start=False)
    j = prob.names.index("c_alpha")
    sizes = sorted(s.x0[j] for s in starts)
    # the parent itself (no damping), a tenth of the typical start, it, ten times it
    assert len(sizes) == 4 and sizes[0] == 0.0
    assert math.isclose(sizes[2] / sizes[1], 10.0) and math.isclose(sizes[3] / sizes[2], 10.0)


def test_a_signed_effect_at_zero_is_spread_both_ways():
    prob = _coupled_problem(["voltage_offset"])
    x = prob.start_vector(prob.base)
    starts = refit_starts(prob, x, {}, data_start=False)
    j = prob.names.index("u_offset")
    assert sorted(s.x0[j] for s in starts) == pytest.approx([-0.15, -0.05, 0.0, 0.05, 0.15])


def test_a_start_outside_the_bounds_is_dropped_not_clipped_into_a_lie():
    prob = _coupled_problem(["lower_stribeck"])
    x = prob.start_vector(prob.base)
    starts = refit_starts(prob, x, {"Ts_l": 99.0}, data_start=False)
    assert "the diagnosis's one-step estimate" not in [s.label for s in starts]


def test_words_when_the_refit_ends_above_its_prediction():
    assert prediction_note(0.9, 2790.0, ["lower_stribeck"]) is None
    assert prediction_note(300.0, 290.0, ["lower_stribeck"]) is None  # within 10 %
    note = prediction_note(111.0, 50.0, ["lower_stribeck"], "rotorbayes multistart ...")
    assert note and "above the 50x" in note and "111x" in note and "multistart" in note
    assert prediction_note(5.0, None, ["x"]) is None
    doc = {
        "ranking": [
            {"effect": "lower_stribeck", "judgement": {"predicted_worst_rms_over_floor": 385.0}}
        ]
    }
    assert diagnosis_prediction(doc, ["lower_stribeck"]) == 385.0
    assert diagnosis_prediction(doc, ["string_damping"]) is None
    assert diagnosis_prediction(doc, ["lower_stribeck", "string_damping"]) is None


# ------------------------------------------- trial refits: far from the floor, refits decide
def _loop_files(tmp, params, duration, *, alpha0_est=None):
    for label, seed in (("est", 3), ("val", 4)):
        ex = make_experiment(
            "coupled",
            params,
            duration=duration,
            signal="steps",
            hold="continuous",
            seed=seed,
            alpha0=alpha0_est if label == "est" else None,
        )
        save_experiment(ex, tmp / f"{label}.csv")
    return [str(tmp / "est.csv"), "--validate", str(tmp / "val.csv")]


@pytest.mark.slow
def test_trial_refits_find_a_dead_zone_the_score_tests_miss(tmp_path, capsys):
    """A 0.3 V motor dead zone (30 s): the first fit ends hundreds of times the floor, the
    score tests there name another effect; the trial refits name the dead zone, and the
    printed refit reaches the floor."""
    params = dict(SETS["coupled"][0], u_deadzone=0.3)
    data = _loop_files(tmp_path, params, 30.0)
    main(["fit", "--model", "coupled", *data, "--out", str(tmp_path / "fit0")])
    assert main(["diagnose", str(tmp_path / "fit0")]) in (0, 1)
    out = capsys.readouterr().out
    d = json.loads((tmp_path / "fit0" / "diagnosis.json").read_text())
    named = d.get("claimed_effect") or d.get("candidate_effect")
    assert named != "motor_deadzone", "the score tests found it: the case is not hard"
    assert d["refit_choice"] == "motor_deadzone"
    assert "the trial refits decide: motor_deadzone" in out
    cmd = next(line for line in out.splitlines() if "the trial refits decide" in line)
    assert "--add motor_deadzone" in cmd
    assert (
        main(
            [
                "fit",
                "--model",
                "coupled",
                *data,
                "--p0",
                str(tmp_path / "fit0"),
                "--add",
                "motor_deadzone",
                "--out",
                str(tmp_path / "fit1"),
            ]
        )
        == 0
    )
    doc = _doc(tmp_path / "fit1")
    assert doc["assessment"]["worst_ratio_to_floor"] <= 1.5
    e = doc["estimates"]["u_deadzone"]
    assert abs(e["value"] - 0.3) <= 4 * e["stderr"], e


@pytest.mark.slow
def test_a_tie_on_one_run_is_decided_by_the_validation_run(tmp_path, capsys):
    """A pre-wound string (0.25 rad) in the one estimation run, the validation run unwound:
    on the estimation data initial_torsion and lower_asymmetric_coulomb fit alike (an exact
    tie); the validation run, its torsion fitted on it alone, tells them apart."""
    data = _loop_files(tmp_path, dict(SETS["coupled"][0]), 10.0, alpha0_est=0.25)
    main(["fit", "--model", "coupled", *data, "--out", str(tmp_path / "fit0")])
    assert main(["diagnose", str(tmp_path / "fit0")]) in (0, 1)
    out = capsys.readouterr().out
    d = json.loads((tmp_path / "fit0" / "diagnosis.json").read_text())
    assert d["refit_choice"] == "initial_torsion", d["trials"]
    trials = {t["effect"]: t for t in d["trials"]["trials"]}
    est = [trials[n]["rms_over_floor"] for n in ("initial_torsion", "lower_asymmetric_coulomb")]
    assert est[0] <= 1.5 and est[1] <= 1.5  # tied, both at the floor on estimation data
    assert trials["lower_asymmetric_coulomb"]["validation_rms_over_floor"] > 100
    assert trials["initial_torsion"]["validation_rms_over_floor"] < 20
    assert "validation data decide" in out


def test_long_data_screen_the_starts_and_finish_the_best(monkeypatch, capsys):
    """Above LONG_RESIDUALS every start gets a few evaluations and only the best is fitted
    to the end; on the bundled hidden-effect data (made lowering the limit) it lands where
    the full search lands."""
    from rotorbayes import inference
    from rotorbayes.inference import refit as inference_refit
    from rotorbayes.io.examples import example_path
    from rotorbayes.io.measurements import load_experiment

    ex = load_experiment(example_path("coupled_hidden_est"))
    prob = inference.Problem("coupled", [ex])
    parent = inference.fit_from_data(prob, restarts=0).result
    child = prob.like(
        model=prob.model.with_effects(["lower_asymmetric_coulomb"]), free=[*prob.names, "dTc_l"]
    )
    x0 = child.start_vector({**child.base, **prob.values(parent.x)})
    full = inference_refit.refit_added(
        child, x0, {}, ["lower_asymmetric_coulomb"], uncertainty=False
    )
    monkeypatch.setattr(inference_refit, "LONG_RESIDUALS", 0)
    screened = inference_refit.refit_added(
        child, x0, {}, ["lower_asymmetric_coulomb"], verbose=True, uncertainty=False
    )
    assert "screened" in capsys.readouterr().out
    assert screened.chose.endswith("(screened, then fitted to the end)")
    assert screened.result.ssr <= full.result.ssr * 1.01
    assert np.array_equal(screened.result.x0, screened.starts[screened.kept].x0)

"""Every validation run has its own torsion (issue 30, point 2).

Brake rig from the independent reference (``tests/reference.py`` through :mod:`refdata`,
``SETS["brake"][0]``, 8 s of steps, 1 kHz, quantised): two estimation runs wound at +0.3
and -0.2 rad (``|k_alpha alpha0|`` = 0.048 and 0.032 N m, inside the lower disc's static
band of 0.11 N m: the rig is at rest at t = 0), a validation run unwound and one wound at
+0.1 rad.  With two estimation runs ``initial_torsion`` is on, and a validation run was
simulated with the *first* estimation run's alpha0 (``fit`` with the start's, ``compare``
and ``diagnose`` with fit.json's ``params.alpha0``): the estimation data at 0.92x the floor,
the wound validation run at 1808x (``fit``) or 3580x (``compare``), and "a missing effect
these data do not excite".  Now its alpha0 is fitted on that run alone (or given), stored
in fit.json, and every command shows the same figure.  The next fit's start column showed
alpha0[0]'s value as alpha0[1]'s start.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from refdata import SETS, make_experiment

from rotorbayes import inference
from rotorbayes.cli import main
from rotorbayes.inference.assess import validation_spread
from rotorbayes.inference.problem import FITTED_ALONE, FIXED, GIVEN, ValidationTorsion
from rotorbayes.inference.results import load_fit
from rotorbayes.io.measurements import save_experiment
from rotorbayes.model.parameters import ParameterError, resolve

TRUTH = dict(SETS["brake"][0])
#: (name, input seed, initial torsion [rad]) of the runs.
RUNS = {"est_a": (1, 0.3), "est_b": (2, -0.2), "val_unwound": (3, 0.0), "val_wound": (3, 0.1)}
#: What "at the floor" is allowed to be on a validation run (the estimation runs' worst
#: channel is 0.92x; the validation runs' 1.07-1.09x: their own rounding pattern).
VAL_AT_FLOOR = 1.12


def _run(name: str):
    seed, a0 = RUNS[name]
    return make_experiment(
        "brake",
        TRUTH,
        duration=8,
        signal="steps",
        hold="continuous",
        seed=seed,
        alpha0=a0,
        name=name,
    )


@pytest.fixture(scope="module")
def runs():
    return {n: _run(n) for n in RUNS}


@pytest.fixture(scope="module")
def files(runs, tmp_path_factory) -> dict[str, str]:
    d = tmp_path_factory.mktemp("torsion_data")
    out = {}
    for n, ex in runs.items():
        save_experiment(ex, d / f"{n}.csv")
        out[n] = str(d / f"{n}.csv")
    return out


def _worst(rows, prob) -> float:
    floors, _ = prob.noise_floors()
    return max(
        math.sqrt(st["ssr"] / st["n"]) / floors[c]
        for r in rows
        for c, st in r["channels"].items()
        if c in prob.channels
    )


def test_a_validation_run_is_simulated_with_its_own_torsion(runs):
    prob = inference.Problem("brake", [runs["est_a"], runs["est_b"]])
    assert "initial_torsion" in prob.model.effect_names  # on with two runs
    res = inference.fit_from_data(prob, restarts=0).result
    assert _worst(inference.quality(prob, res.x), prob) <= 1.0  # the estimation data at the floor
    vals = [runs["val_unwound"], runs["val_wound"]]
    rows = inference.quality(prob, res.x, vals)
    for r, truth in zip(rows, (0.0, 0.1), strict=True):
        t = r["validation_alpha0"]
        assert t.how == FITTED_ALONE and abs(t.value - truth) < 2e-4, (t, truth)
        assert "fitted on that run alone" in t.words()
        assert _worst([r], prob) <= VAL_AT_FLOOR, (r["experiment"], _worst([r], prob))
    # Given values are used as they are; a stored record gives the same rows again.
    given = inference.quality(prob, res.x, vals, validation_alpha0=[0.0, 0.1])
    assert [r["validation_alpha0"].how for r in given] == [GIVEN, GIVEN]
    assert [r["validation_alpha0"].value for r in given] == [0.0, 0.1]
    assert _worst(given, prob) <= VAL_AT_FLOOR
    recs = [r["validation_alpha0"].as_dict() for r in rows]
    again = inference.quality(prob, res.x, vals, validation_alpha0=recs)
    assert _worst(again, prob) == _worst(rows, prob)
    # Never another experiment's alpha0: the first run's would be thousands of times off.
    p, _ = prob.validation_params(res.x, runs["val_wound"])
    assert p["alpha0"] != pytest.approx(prob.params_for(res.x, 0)["alpha0"], abs=0.1)
    # The validation spread keeps each run's alpha0: the same with the records as without.
    floors, _ = prob.noise_floors()
    sp = validation_spread(res, vals, floors, draws=8, validation_alpha0=recs)
    assert sp is not None and "q50" in sp and sp["q90"] < 3.0, sp
    assert validation_spread(res, vals, floors, draws=8) == sp


def test_one_run_without_initial_torsion_keeps_the_models_fixed_value(runs):
    truth = resolve(TRUTH, config="brake")
    prob = inference.Problem("brake", [runs["val_unwound"]], base=truth)
    assert "initial_torsion" not in prob.model.effect_names
    x = prob.x_from(truth)
    (row,) = inference.quality(prob, x, [runs["est_a"]])
    t = row["validation_alpha0"]
    assert (t.how, t.value) == (FIXED, 0.0)  # as before: the model has no pre-wound string
    assert "initial_torsion is off" in t.words()
    with pytest.raises(ParameterError, match="no pre-wound string"):
        prob.validation_params(x, runs["est_a"], 0.3)
    with pytest.raises(ValueError, match="not a number"):
        ValidationTorsion.from_dict({"value": "x", "how": GIVEN})


@pytest.fixture(scope="module")
def chain(files, tmp_path_factory):
    """fit -> compare -> diagnose -> fit --p0, through the command line."""
    root = tmp_path_factory.mktemp("torsion_fits")
    data = [files["est_a"], files["est_b"], "--validate", files["val_wound"]]
    out = {}
    for step, argv in (
        ("fit", ["fit", "--model", "brake", *data, "--restarts", "0", "--out", root / "F"]),
        ("compare", ["compare", root / "F"]),
        ("diagnose", ["diagnose", root / "F"]),
        ("refit", ["fit", "--model", "brake", *data, "--p0", root / "F", "--out", root / "F2"]),
    ):
        out[step] = main([str(a) for a in argv])
    out["root"] = root
    return out


def test_fit_compare_and_diagnose_give_the_same_validation_figure(chain):
    root = chain["root"]
    assert chain["fit"] == 0 and chain["compare"] == 0 and chain["diagnose"] == 0
    doc = json.loads((root / "F" / "fit.json").read_text())
    (rec,) = doc["validation_alpha0"]
    assert rec["how"] == FITTED_ALONE and abs(rec["value"] - 0.1) < 2e-4, rec
    v_fit = doc["assessment"]["worst_ratio_to_floor_validation"]
    assert doc["assessment"]["worst_ratio_to_floor"] <= 1.0
    assert v_fit <= VAL_AT_FLOOR
    assert "does not predict others" not in doc["assessment"]["verdict"]
    cmp = json.loads((root / "F" / "compare" / "compare.json").read_text())
    v_cmp = max(cmp["fits"][-1]["validation"]["rms_over_floor"].values())
    assert cmp["fits"][-1]["validation_alpha0"][0]["value"] == rec["value"]
    dg = json.loads((root / "F" / "diagnosis.json").read_text())
    v_dg = dg["validation"]["worst_ratio_to_floor"]
    assert v_cmp == pytest.approx(v_fit, rel=1e-9) and v_dg == pytest.approx(v_fit, rel=1e-9)
    # A fit.json of an older rotorbayes (no records): decided again, the same way.
    old = load_fit(root / "F")
    old.validation_alpha0 = []
    (row,) = old.validation_quality()
    assert row["validation_alpha0"].value == pytest.approx(rec["value"], abs=1e-12)
    # The report says how each validation run's torsion was chosen.
    from rotorbayes.report.html import build_report

    html = build_report(root / "F").read_text()
    assert "Each validation run starts with its own string torsion" in html
    assert "fitted on that run alone" in html


def test_the_next_fit_starts_each_run_at_its_own_torsion(chain):
    root = chain["root"]
    assert chain["refit"] == 0
    first = json.loads((root / "F" / "fit.json").read_text())["estimates"]
    nxt = json.loads((root / "F2" / "fit.json").read_text())
    for n in ("alpha0[0]", "alpha0[1]"):
        assert nxt["estimates"][n]["start"] == first[n]["value"], n
    assert nxt["parameters"]["alpha0[1]"]["start_source"].startswith("--p0")
    assert abs(nxt["estimates"]["alpha0[1]"]["start"] - -0.2) < 1e-3
    (rec,) = nxt["validation_alpha0"]
    assert abs(rec["value"] - 0.1) < 2e-4
    assert nxt["assessment"]["worst_ratio_to_floor_validation"] <= VAL_AT_FLOOR


def test_a_given_torsion_is_used_and_said(files, tmp_path, capsys):
    data = [files["est_a"], files["est_b"], "--validate", files["val_wound"]]
    out = tmp_path / "G"
    assert (
        main(
            [
                "fit",
                "--model",
                "brake",
                *data,
                "--validate-alpha0",
                "0.1",
                "--restarts",
                "0",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    text = capsys.readouterr().out
    assert "validation val_wound: its initial torsion alpha0 = 0.1 rad, given" in text
    doc = json.loads((out / "fit.json").read_text())
    assert doc["validation_alpha0"][0]["how"] == GIVEN
    assert doc["validation_alpha0"][0]["value"] == 0.1
    assert doc["assessment"]["worst_ratio_to_floor_validation"] <= VAL_AT_FLOOR
    assert main(["compare", str(out)]) == 0
    cmp = json.loads((out / "compare" / "compare.json").read_text())
    assert max(cmp["fits"][-1]["validation"]["rms_over_floor"].values()) == pytest.approx(
        doc["assessment"]["worst_ratio_to_floor_validation"], rel=1e-9
    )
    # The refit command a diagnosis prints carries the given torsion with its file.
    from rotorbayes.commands.diagnose import _with_refit_command
    from rotorbayes.diagnosis.diagnose import REFIT_TOKEN

    cmd = _with_refit_command(f"{REFIT_TOKEN} --add string_damping", out, doc)
    assert "--validate-alpha0 0.1" in cmd and "--add string_damping" in cmd


@pytest.mark.parametrize(
    "extra, says",
    [
        (["--validate-alpha0", "0.1", "--validate-alpha0", "0.2"], "given 2 times for 1"),
        (["--validate-alpha0", "wound"], "'wound' is not a number"),
        (["--validate-alpha0", "12"], "alpha0 = 12 rad lies outside alpha0's bounds"),
        (["--validate-alpha0", "inf"], "give a finite torsion"),
    ],
)
def test_bad_validation_torsion_is_refused_before_any_work(files, tmp_path, capsys, extra, says):
    out = tmp_path / "R"
    argv = [
        "fit",
        "--model",
        "brake",
        files["est_a"],
        files["est_b"],
        "--validate",
        files["val_wound"],
        *extra,
        "--out",
        str(out),
    ]
    assert main(argv) == 2
    assert says in capsys.readouterr().err
    assert not out.exists()


def test_a_torsion_the_model_cannot_take_is_refused(files, tmp_path, capsys):
    out = tmp_path / "R"
    # One run, no initial_torsion: the model has no pre-wound string.
    assert (
        main(
            [
                "fit",
                "--model",
                "brake",
                files["est_a"],
                "--validate",
                files["val_wound"],
                "--validate-alpha0",
                "0.1",
                "--out",
                str(out),
            ]
        )
        == 2
    )
    assert "--add initial_torsion" in capsys.readouterr().err
    assert (
        main(
            [
                "fit",
                "--model",
                "brake",
                files["est_a"],
                "--validate-alpha0",
                "0.1",
                "--out",
                str(out),
            ]
        )
        == 2
    )
    assert "there is no --validate file" in capsys.readouterr().err
    assert not out.exists()


def test_an_analysis_file_gives_validation_torsions(files, tmp_path):
    from rotorbayes.commands.study.analysis import AnalysisError, load_analysis

    text = (
        f'[analysis]\nout = "out"\nconfig = "brake"\n'
        f'data = ["{files["est_a"]}", "{files["est_b"]}"]\n'
        f'validate = ["{files["val_wound"]}"]\n'
    )
    good = tmp_path / "good.toml"
    good.write_text(text + "validate_alpha0 = [0.1]\n")
    assert load_analysis(good).doc["analysis"]["validate_alpha0"] == [0.1]
    (tmp_path / "fit.toml").write_text(text + 'validate_alpha0 = ["fit"]\n')
    load_analysis(tmp_path / "fit.toml")
    for bad, says in (("[0.1, 0.2]", "2 entries for 1"), ('["wound"]', "neither a torsion")):
        (tmp_path / "bad.toml").write_text(text + f"validate_alpha0 = {bad}\n")
        with pytest.raises(AnalysisError, match=says):
            load_analysis(tmp_path / "bad.toml")


def test_records_round_trip(runs):
    t = ValidationTorsion("v", -4.5e-6, FITTED_ALONE, "/d/v.csv")
    assert ValidationTorsion.from_dict(t.as_dict()) == t
    assert np.isfinite(t.value) and "-4.5e-06 rad" in t.words()


def test_a_torsion_fitted_far_from_the_floor_is_said_to_be_the_misfits():
    """Two pre-wound runs with a motor torque the catalogue lacks (a fresh-eyes trial):
    the validation run's own alpha0 was fitted as 0.1994 rad (its string not wound) with
    the model 10599x the floor there, and reported like a measurement."""
    t = ValidationTorsion("B_val", 0.1994, FITTED_ALONE)
    far = t.words(10599.0)
    assert "0.1994 rad" in far and "not the string's torsion" in far and "1.06e+04x" in far
    assert "not the string's torsion" not in t.words(1.2)  # at the floor: a measurement
    assert t.words() == t.words(math.nan) == t.words(1.2)
    assert "misfit" not in ValidationTorsion("v", 0.01, GIVEN).words(10599.0)

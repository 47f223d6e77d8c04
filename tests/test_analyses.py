"""The chapter 4 and 5 analysis scripts run end to end (quick mode) and show the thesis's
findings: the asymmetric friction model removes the hidden effect's error, and one
alpha0 per experiment fits the brake repeats better than a shared alpha0."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

# Both scripts together take about 13 s on an idle 2-core machine (up to ~40 s under load).
pytestmark = pytest.mark.slow

ANALYSES = Path(__file__).resolve().parents[1] / "analyses"


def _load(name: str):
    spec = importlib.util.spec_from_file_location(f"analyses_{name}", ANALYSES / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def chapter4_run(tmp_path_factory):
    mod = _load("chapter4")
    out = tmp_path_factory.mktemp("chapter4")
    return mod, out, mod.main(["--quick", "--out", str(out)])


@pytest.fixture(scope="module")
def chapter5_run(tmp_path_factory):
    mod = _load("chapter5")
    out = tmp_path_factory.mktemp("chapter5")
    return mod, out, mod.main(["--quick", "--out", str(out)])


def test_chapter4_writes_figures_and_report(chapter4_run):
    mod, out, summary = chapter4_run
    for name in mod.figure_names(mod.TABLES):
        path = out / name
        assert path.is_file() and path.stat().st_size > 0, name
    report = (out / "report.txt").read_text()
    assert "Total runtime" in report
    assert "Sloppiest direction" in report


def test_chapter4_recovers_p_ref_and_shows_the_ridge(chapter4_run):
    mod, _, summary = chapter4_run
    from rotorbayes.model.parameters import thesis_set

    for tab, r in summary["tables"].items():
        pref = thesis_set(tab, "P_ref")
        for name, value in r["fit"].values.items():
            assert value == pytest.approx(pref[name], rel=0.02), (tab, name)
    # Thesis's 4.2 P (about 1.2 x P_ref) still has R² close to 1 on the simulated data.
    f = summary["tables"]["4.2"]["fits_thesis_est"]["theta_l"]
    assert f.r2 > 0.999 and f.max_abs_error > 1e-3
    # Common scaling along the ridge hurts far less than scaling J_l alone.
    scan = summary["ridge"]
    i = scan["lambda"].index(1.2)
    assert scan["together"][i].max_abs_error < 0.2 * scan["alone"][i].max_abs_error


def test_chapter4_refuses_to_overwrite(chapter4_run):
    mod, out, _ = chapter4_run
    with pytest.raises(SystemExit):
        mod.main(["--quick", "--out", str(out)])


def test_chapter5_writes_figures_and_report(chapter5_run):
    mod, out, _ = chapter5_run
    for name in mod.FIGURES:
        path = out / name
        assert path.is_file() and path.stat().st_size > 0, name
    assert "Total runtime" in (out / "report.txt").read_text()


def test_chapter5_asymmetric_friction_reduces_the_error(chapter5_run):
    _, _, summary = chapter5_run
    hidden = summary["hidden"]
    assert hidden["max_error_asymmetric"] * 2 <= hidden["max_error_symmetric"]
    assert hidden["asymmetric"]["fit"].ssr < hidden["symmetric"]["fit"].ssr


def test_chapter5_alpha0_per_experiment_beats_a_shared_one(chapter5_run):
    mod, _, summary = chapter5_run
    brake = summary["brake"]
    per, shared = brake["per_experiment"], brake["shared"]
    assert per.ssr < shared.ssr
    assert brake["aicc_per_experiment"] < brake["aicc_shared"]
    est = [per.values[f"alpha0[{i}]"] for i in range(4)]
    assert est == pytest.approx(list(mod.TRUE_ALPHA0), abs=0.05)


def test_chapter5_refuses_to_overwrite(chapter5_run):
    mod, out, _ = chapter5_run
    with pytest.raises(SystemExit):
        mod.main(["--quick", "--out", str(out)])


def test_hidden_effect_walkthrough_reaches_the_floor(tmp_path):
    mod = _load("hidden_effect_walkthrough")
    res = mod.main(["--out", str(tmp_path / "walk")])
    assert res["added"] == ["lower_asymmetric_coulomb", "lower_asymmetric_viscous"]
    last = res["chain"][-1]["diagnosis"]
    assert last["adequate"] and max(last["rms_over_floor"].values()) < 1.5
    assert (tmp_path / "walk" / "compare_chain" / "chain.png").exists()
    assert "walk-through done" in (tmp_path / "walk" / "report.txt").read_text()


def test_identifiability_showcase_finds_the_scale_symmetry(tmp_path):
    res = _load("identifiability").main(["--quick", "--out", str(tmp_path / "id")])
    a = res["A"]["cosines"]
    # The posterior's main axis, the sloppiest Fisher direction and the thesis's step from
    # P_ref to P (table 4.2) point the same way in log space.
    assert a["posterior_vs_fisher"] > 0.98 and a["posterior_vs_thesis_step"] > 0.97
    assert a["fisher_vs_thesis_step"] > 0.97
    # Ratios to J_l are far better determined than the scale.
    assert max(res["A"]["sd_log_ratios"]) < min(res["A"]["sd_log"])
    # theta_u prescribed: singular Fisher matrix, posterior spread along the ridge to a bound.
    assert res["B"]["eig_ratio"] < 1e-10 and min(res["B"]["span"]) > 3
    assert res["B"]["k_alpha_max_over_bound"] > 0.8
    assert max(res["B"]["sd_log_ratios"]) < 1e-3
    # The default (upper disc fitted too) recovers the scale.
    assert all(abs(v - 1) < 1e-3 for v in res["C"]["recovered"].values())

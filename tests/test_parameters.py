"""Parameter names, thesis tables, files and bounds."""

from __future__ import annotations

import math

import pytest

from rotorbayes import parameters


def test_geometry_values_from_the_thesis():
    assert parameters.J_U_EQ_5_4 == pytest.approx(0.4765, abs=5e-5)  # eq. 5.4
    assert parameters.K_ALPHA_EQ_5_11 == pytest.approx(0.080, abs=5e-4)  # eq. 5.11


def test_thesis_tables_as_named_sets():
    assert parameters.thesis_set("4.2", "P")["k_alpha"] == 0.0930
    assert parameters.thesis_set("4.3", "P_ref")["delta_l"] == 2.0575
    # Steps are completed from the step before (thesis §3.4).
    assert parameters.thesis_set("4.3", "P0")["J_l"] == 0.0414
    assert parameters.thesis_set("5.2", "P0")["k_m"] == 4.3687
    # Table 5.3 asymmetric pairs: Tc_lp = 0.0139, Tc_ln = 0.0244.
    p = parameters.thesis_set("5.3", "P")
    assert p["Tc_l"] + p["dTc_l"] == pytest.approx(0.0139)
    assert p["Tc_l"] - p["dTc_l"] == pytest.approx(0.0244)
    assert p["b_l"] - p["db_l"] == pytest.approx(0.0079)
    assert math.isnan(parameters.thesis_set("4.2", "P0")["Ts_l"])  # no Stribeck part there
    assert len(parameters.named_sets()) == 17
    with pytest.raises(parameters.ParameterError, match="available"):
        parameters.thesis_set("4.4", "P")


def test_toml_override_and_errors(tmp_path):
    f = tmp_path / "p.toml"
    f.write_text('base = "thesis:4.2:P0"\n[parameters]\nJ_l = 0.05\n')
    p = parameters.load_toml(f)
    assert p["J_l"] == 0.05 and p["k_alpha"] == 0.09
    f.write_text("J_lower = 1\n")
    with pytest.raises(parameters.ParameterError, match="valid names are"):
        parameters.load_toml(f)
    f.write_text('J_l = "heavy"\n')
    with pytest.raises(parameters.ParameterError, match="not a number"):
        parameters.load_toml(f)
    with pytest.raises(parameters.ParameterError, match="not found"):
        parameters.load_toml(tmp_path / "none.toml")


def test_every_parameter_has_unit_and_bounds():
    for n in parameters.NAMES:
        info = parameters.INFO[n]
        assert info.unit and info.lower < info.upper
    for name in parameters.named_sets():
        values = parameters.resolve(name)
        parameters.check_bounds(values, what=name)

"""The arviz seam: the same file, groups and summary columns on arviz 0.2x and 1.x.

CI runs this file on both lines (Python 3.11 gets 0.2x, 3.13 gets 1.x)."""

import re
import warnings
from pathlib import Path

import h5py
import numpy as np
import pytest

from rotorbayes.inference import arviz_compat

ROOT = Path(__file__).resolve().parents[1]


def _groups(rng, C=4, D=500):
    post = {"a": rng.normal(2.0, 0.5, size=(C, D)), "b": rng.normal(size=(C, D))}
    return {
        "posterior": post,
        "sample_stats": {"lp": rng.normal(size=(C, D))},
        "log_likelihood": {"y_exp0": rng.normal(size=(C, D, 7)).astype(np.float32)},
        "posterior_predictive": {"y_exp0": rng.normal(size=(C, D, 3)).astype(np.float32)},
        "observed_data": {"y_exp0": np.arange(7.0)},
        "constant_data": {"u_exp0": np.ones(7)},
    }


DIMS = {
    "log_likelihood": {"y_exp0": ["time_exp0"]},
    "observed_data": {"y_exp0": ["time_exp0"]},
    "constant_data": {"u_exp0": ["time_exp0"]},
    "posterior_predictive": {"y_exp0": ["time_pred_exp0"]},
}
COORDS = {"time_exp0": np.arange(7) * 0.1, "time_pred_exp0": np.array([0.0, 0.3, 0.6])}


def test_round_trip_and_file_layout(tmp_path):
    rng = np.random.default_rng(3)
    g = _groups(rng)
    idata = arviz_compat.from_groups(
        g, dims=DIMS, coords=COORDS, attrs={"posterior": {"burn_in_steps": 40}}
    )
    path = tmp_path / "posterior.nc"
    arviz_compat.save(idata, path)
    back = arviz_compat.load(path)
    assert set(arviz_compat.group_names(back)) == set(g)
    post = arviz_compat.group(back, "posterior")
    assert post.sizes["chain"] == 4 and post.sizes["draw"] == 500
    assert np.array_equal(post["a"].values, g["posterior"]["a"])
    assert post.attrs["burn_in_steps"] == 40
    pp = arviz_compat.group(back, "posterior_predictive")["y_exp0"]
    assert pp.dims == ("chain", "draw", "time_pred_exp0")
    assert np.allclose(pp["time_pred_exp0"].values, [0.0, 0.3, 0.6])
    obs = arviz_compat.group(back, "observed_data")["y_exp0"]
    assert obs.dims == ("time_exp0",) and np.array_equal(obs.values, np.arange(7.0))
    with pytest.raises(KeyError, match="no prior group"):
        arviz_compat.group(back, "prior")
    # The file itself, read without arviz: one netCDF (HDF5) group per arviz group, so a
    # posterior.nc from one arviz line opens on the other.
    with h5py.File(path, "r") as f:
        assert {
            "posterior",
            "sample_stats",
            "log_likelihood",
            "posterior_predictive",
            "observed_data",
            "constant_data",
        } <= set(f.keys())
        assert f["posterior"]["a"].shape == (4, 500)


def test_summary_columns_and_values():
    rng = np.random.default_rng(7)
    idata = arviz_compat.from_groups(_groups(rng), dims=DIMS, coords=COORDS)
    s = arviz_compat.summary(idata, hdi_prob=0.94)
    assert list(s.columns) == list(arviz_compat.SUMMARY_COLUMNS)
    assert set(s.index) == {"a", "b"}
    a = s.loc["a"]
    # Independent normal draws, sd 0.5 around 2: the 94 % HDI is about ±1.88 sd, R-hat about
    # 1 and the ESS about the number of draws (2000).
    assert abs(a["mean"] - 2.0) < 0.03 and abs(a["sd"] - 0.5) < 0.02
    assert abs(a["hdi_low"] - (2.0 - 1.88 * 0.5)) < 0.06
    assert abs(a["hdi_high"] - (2.0 + 1.88 * 0.5)) < 0.06
    assert abs(a["r_hat"] - 1.0) < 0.01
    assert 1500 < a["ess_bulk"] < 2600 and 1200 < a["ess_tail"] < 2600
    only = arviz_compat.summary(idata, var_names=["b"])
    assert list(only.index) == ["b"]


def test_summary_sees_chains_that_disagree():
    rng = np.random.default_rng(11)
    g = _groups(rng)
    g["posterior"]["a"][0] += 3.0  # one chain elsewhere
    s = arviz_compat.summary(arviz_compat.from_groups(g, dims=DIMS, coords=COORDS))
    assert s.loc["a", "r_hat"] > 1.5 and s.loc["b", "r_hat"] < 1.01


def test_import_is_quiet():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        arviz_compat._AZ = None
        arviz_compat.arviz()
    assert not [w for w in caught if "arviz" in str(w.filename) or "ArviZ" in str(w.message)]


def test_nothing_else_imports_arviz():
    pattern = re.compile(r"^\s*(import arviz|from arviz)", re.M)
    offenders = []
    for top in ("src", "analyses", "benchmarks", "tests", "docs"):
        for f in (ROOT / top).rglob("*.py"):
            if f.name == "arviz_compat.py":
                continue
            if pattern.search(f.read_text(encoding="utf-8")):
                offenders.append(str(f.relative_to(ROOT)))
    assert not offenders, f"import arviz outside inference/arviz_compat.py: {offenders}"

"""Figures and tables that keep the precision they show (issue 36, points 2 and 3).

* The posterior-predictive band is the parameters' effect on the angle, often 1e-6 rad on
  angles of tens of rad.  Stored as float32 (spacing 1.9e-6 to 7.6e-6 rad at 16-64 rad) it
  was the storage's rounding; now it is stored as float64, and a band narrower than its
  storage error is said to be unresolved, never drawn.
* Means printed to three or six significant digits beside an sd of 1e-7 of them hid the
  interval: the sd now gets two significant digits and the mean the same decimal place.
"""

from __future__ import annotations

import math

import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402
import pytest  # noqa: E402
from matplotlib.collections import PolyCollection  # noqa: E402

from rotorbayes.inference import Problem, posterior
from rotorbayes.inference.likelihood import LogPosterior  # noqa: E402
from rotorbayes.inference.sampling import EnsembleRun  # noqa: E402
from rotorbayes.io.examples import example_path  # noqa: E402
from rotorbayes.io.measurements import load_experiment  # noqa: E402
from rotorbayes.model import Model, parameters
from rotorbayes.util import numformat  # noqa: E402


@pytest.fixture(scope="module")
def narrow():
    """A posterior a few parts in 1e8 wide around the thesis's brake set, on the bundled
    brake record (angles up to 30 rad): its predictive band is about 1e-6 rad."""
    ex = load_experiment(example_path("example:brake_est"))
    prob = Problem(
        Model("brake"), [ex], free=["Tc_l", "b_l"], base=parameters.resolve(None, config="brake")
    )
    x = prob.start_vector(prob.base)
    lp = LogPosterior(prob, x, noise="floor")
    z0 = lp.to_z(x)
    rng = np.random.default_rng(7)
    chain = z0 + 5e-8 * rng.normal(size=(24, 8, z0.size))
    runs = [
        EnsembleRun("ensemble0", chain, np.zeros((24, 8)), np.full(8, 0.3), np.array([1.0, 1.0]))
    ]
    return prob, lp, runs


def _band(sims):
    lo, med, hi = np.percentile(np.asarray(sims, np.float64), [3, 50, 97], axis=0)
    return lo - med, hi - med


def test_stored_band_is_the_band_of_the_simulations(narrow, monkeypatch):
    from rotorbayes.inference import arviz_compat

    prob, lp, runs = narrow
    idata = posterior.inference_data(lp, runs, max_draws=40)
    da = arviz_compat.group(idata, "posterior_predictive")["theta_l_exp0"]
    stored = da.values.reshape(-1, da.shape[-1])
    assert stored.dtype == np.float64
    # The same draws simulated here, in float64, never stored.
    post = arviz_compat.group(idata, "posterior")
    X = np.column_stack([post[n].values.reshape(-1) for n in prob.names])
    R = prob.residuals_batch(X)
    ex = prob.experiments[0]
    step = max(1, math.ceil(ex.n / posterior.PREDICTIVE_POINTS))
    j = list(prob.channels).index("theta_l")
    seg = R[:, j * ex.n : (j + 1) * ex.n][:, ::step] / prob.weights["theta_l"]
    direct = ex.theta_l[None, ::step] - seg
    lo_s, hi_s = _band(stored)
    lo_d, hi_d = _band(direct)
    width = float(np.max(hi_d - lo_d))
    assert 1e-7 < width < 1e-4  # narrower than float32 resolves at 30 rad by ~ a few steps
    assert np.max(np.abs(lo_s - lo_d)) < 1e-12 * 30 and np.max(np.abs(hi_s - hi_d)) < 1e-12 * 30
    # What float32 storage made of it: steps of its spacing, not the band.
    f32 = direct.astype(np.float32)
    lo_f, hi_f = _band(f32)
    assert np.max(np.abs(hi_f - hi_d)) > 0.2 * width


def _band_panel(fig, chan_index=0):
    ax3 = fig.axes[3 * chan_index + 2]
    polys = [c for c in ax3.collections if isinstance(c, PolyCollection)]
    texts = " ".join(t.get_text() for t in ax3.texts)
    return polys, texts


def test_predictive_figure_draws_a_resolved_band_and_refuses_rounding(narrow, monkeypatch):
    from rotorbayes.figures import posterior as posterior_figures

    prob, lp, runs = narrow
    fig, _ = posterior_figures.plot_predictive(
        posterior.inference_data(lp, runs, max_draws=40), prob
    )
    polys, texts = _band_panel(fig, list(prob.channels).index("theta_l"))
    assert polys and "unresolved" not in texts
    # A posterior.nc written with float32 predictions (as before issue 36): unresolved.
    monkeypatch.setattr(posterior, "PREDICTIVE_DTYPE", np.float32)
    fig, _ = posterior_figures.plot_predictive(
        posterior.inference_data(lp, runs, max_draws=40), prob
    )
    k = list(prob.channels).index("theta_l")
    polys, texts = _band_panel(fig, k)
    # Drawn only early in the record, where the angle is small and float32 fine enough.
    legend = " ".join(t.get_text() for t in fig.axes[3 * k + 2].get_legend().get_texts())
    n_out = int(legend.split("not drawn at ")[1].split(" of ")[0])
    assert n_out > 0.8 * 1201, legend
    assert "narrower than 10x the storage spacing" in legend


def test_a_band_unresolved_everywhere_is_said_not_drawn(narrow, monkeypatch):
    from rotorbayes.figures import posterior as posterior_figures

    prob, lp, runs = narrow
    idata = posterior.inference_data(lp, runs, max_draws=40)
    monkeypatch.setattr(
        posterior_figures,
        "band_resolution",
        lambda lo, hi, dtype: (np.full(np.shape(lo), 2e-6), np.zeros(np.shape(lo), bool)),
    )
    fig, _ = posterior_figures.plot_predictive(idata, prob)
    polys, texts = _band_panel(fig, 0)
    assert not polys and "94 % predictive band unresolved" in texts and "not drawn" in texts
    legend = " ".join(t.get_text() for t in fig.axes[0].get_legend().get_texts())
    assert "94 % band unresolved" in legend


def test_band_resolution_rule():
    from rotorbayes.figures.posterior import RESOLVED_SPACINGS, band_resolution

    lo = np.array([0.0, 30.0, 30.0, 30.0])
    hi = np.array([0.0, 30.0 + 1e-6, 30.0 + 1e-12, 31.0])
    sp, ok = band_resolution(lo, hi, np.float32)
    assert sp[1] == pytest.approx(1.9073486e-06)
    assert ok.tolist() == [True, False, False, True]
    _, ok = band_resolution(lo, hi, np.float64)
    assert ok.tolist() == [True, True, True, True]
    assert RESOLVED_SPACINGS == 10


# ------------------------------------------------------------------------------------------
# Digits


@pytest.mark.parametrize(
    ("mean", "sd", "want"),
    [
        (3.6187654012, 6.9e-7, ("3.61876540", "6.9e-07")),  # the k_m
        (0.0801, 0.0123, ("0.080", "0.012")),
        (4.5, 0.00996, ("4.500", "0.010")),  # rounding the sd moves its place
        (12345.6, 230.0, ("12350", "230")),
        (2.3e-5, 1.1e-8, ("2.3000e-05", "1.1e-08")),
        (-0.2, 0.05, ("-0.200", "0.050")),
        (5.0, math.nan, ("5", "—")),
    ],
)
def test_mean_to_the_place_of_two_digits_of_the_sd(mean, sd, want):
    assert numformat.mean_sd(mean, sd) == want


def test_summary_table_reads_the_interval(narrow):
    row = {
        "parameter": "k_m",
        "mean": 3.6187654012,
        "sd": 6.9e-7,
        "hdi_low": 3.6187641,
        "hdi_high": 3.6187667,
        "ess_bulk": 400.0,
        "ess_tau": 500.0,
        "r_hat": 1.001,
        "tau": 12.0,
        "unit": "N m/V",
    }
    md = posterior.table_markdown([row])
    assert "| k_m | 3.61876540 | 6.9e-07 | [3.61876410, 3.61876670] |" in md


def test_fit_table_prints_the_estimate_to_its_error(narrow):
    from rotorbayes.commands.fit import _fmt_params

    prob = narrow[0]
    text = _fmt_params(
        prob,
        ["Tc_l", "b_l"],
        np.array([0.0373612345, 0.0011]),
        np.array([6.9e-7, math.nan]),
        np.array([0.04, 0.001]),
    )
    lines = text.splitlines()
    assert lines[1].split()[:3] == ["Tc_l", "0.03736123", "6.9e-07"]
    assert lines[2].split()[:3] == ["b_l", "0.0011", "—"]


def test_report_prints_each_estimate_to_its_error(tmp_path, capsys):
    import json

    from rotorbayes.cli import main
    from rotorbayes.report.markup import digits

    fit = tmp_path / "fit"
    assert main(
        [
            "fit",
            "--model",
            "upper",
            "example:upper_est",
            "--p0",
            "thesis:4.1:P_ref",
            "--max-nfev",
            "20",
            "--out",
            str(fit),
        ]
    ) in (0, 1)
    assert main(["report", str(fit)]) == 0
    capsys.readouterr()
    html = (fit / "report.html").read_text()
    doc = json.loads((fit / "fit.json").read_text())
    for n in doc["free"]:
        p = doc["parameters"][n]
        value, err = (digits(t) for t in numformat.mean_sd(p["value"], p["stderr"]))
        assert f'<td class="n">{value}</td><td class="n">{err}</td>' in html, n
    assert '<td class="n">4.3687' in html  # k_m to the place of its error, not 4.369

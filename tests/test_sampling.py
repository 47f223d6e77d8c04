"""Posterior sampling (issue 9): the likelihood, the sampler's checkpoints, and killing a
real process half-way."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time

import h5py
import numpy as np
import pytest

import rotorbayes as rb
from rotorbayes import inference
from rotorbayes.cli import main
from rotorbayes.inference.likelihood import LogPosterior, Prior, load_priors
from rotorbayes.io.measurements import quantisation_floor


def _short_upper(tmp_path, seconds=5.0):
    p = rb.parameters.resolve(
        dict(k_m=3.1, Tc_u=0.62, dTc_u=0.03, b_u=1.7, db_u=0.05), config="upper"
    )
    t, u = rb.signals.make_signal("est", seconds, rate=200.0, seed=4)
    sim = rb.simulate(p, u, dt=1 / 200, config="upper", quantize_angles=True)
    path = tmp_path / "upper.csv"
    rb.save_experiment(sim.to_experiment("upper"), path)
    return p, path


@pytest.fixture(scope="module")
def upper_fit(tmp_path_factory):
    d = tmp_path_factory.mktemp("upper_fit")
    truth, path = _short_upper(d)
    assert main(["fit", "--model", "upper", str(path), "--out", str(d / "fit")]) == 0
    return truth, d / "fit"


def test_log_posterior_is_the_gaussian_likelihood_at_the_floor(upper_fit):
    from rotorbayes.inference.results import load_fit

    fit = load_fit(upper_fit[1])
    lp = LogPosterior(fit.problem, fit.x)
    z = lp.to_z(fit.x)
    r = fit.problem.residuals(fit.x)
    s = quantisation_floor("theta_u")
    expected = -0.5 * r.size * math.log(2 * math.pi * s * s) - 0.5 * float(r @ r) / s**2
    # Uniform priors on θ sampled in log θ: the log-Jacobian is sum(log θ).
    expected += sum(math.log(v) for v, lg in zip(fit.x, lp.log, strict=True) if lg)
    assert lp(z[None, :])[0] == pytest.approx(expected, rel=1e-12)
    # Outside the bounds and through a validity constraint: -inf before any simulation.
    bad = z.copy()
    bad[lp.coord_names.index("dTc_u")] = 5.0  # |dTc_u| > Tc_u
    calls = lp.n_calls
    assert lp(bad[None, :])[0] == -np.inf and lp.n_calls == calls


def test_priors_from_toml_and_their_errors(upper_fit, tmp_path):
    from rotorbayes.inference.results import load_fit

    fit = load_fit(upper_fit[1])
    f = tmp_path / "p.toml"
    f.write_text(
        '[priors]\nk_m = { dist = "normal", mean = 3.0, sd = 0.1 }\n'
        'b_u = { dist = "loguniform", lower = 1.0, upper = 3.0 }\n'
    )
    pri = load_priors(f, fit.problem)
    assert pri["k_m"] == Prior("normal", 0.1, 20.0, 3.0, 0.1)
    assert pri["b_u"].kind == "loguniform"
    f.write_text('[priors]\nJ_l = { dist = "normal", mean = 3.0, sd = 0.1 }\n')
    with pytest.raises(rb.ParameterError, match="not a free parameter.*k_m"):
        load_priors(f, fit.problem)
    f.write_text('[priors]\nk_m = { dist = "uniform", lower = 5, upper = 2 }\n')
    with pytest.raises(rb.ParameterError, match="lower 5 must be below upper 2"):
        load_priors(f, fit.problem)


def test_ar1_likelihood_matches_its_formula():
    ex = rb.load_example("upper_est")
    prob = inference.Problem("upper", [ex])
    x = prob.x_from(rb.parameters.thesis_set("5.1", "P"))
    lp = LogPosterior(prob, x, ar1=True)
    sigma, phi = 2e-5, 0.6
    z = lp.to_z(x, sigma={"theta_u": sigma}, phi={"theta_u": phi})
    e = prob.residuals(x)
    innov = np.r_[e[0] * math.sqrt(1 - phi**2), e[1:] - phi * e[:-1]]
    ll = (
        -0.5 * e.size * math.log(2 * math.pi * sigma**2)
        + 0.5 * math.log(1 - phi**2)
        - 0.5 * float(innov @ innov) / sigma**2
    )
    prior = sum(math.log(v) for v, lg in zip(x, lp.log, strict=True) if lg)
    assert lp(z[None, :])[0] == pytest.approx(ll + prior, rel=1e-10)


def _iteration(path):
    try:
        with h5py.File(path, "r", locking=False) as f:
            return int(f["ensemble0"].attrs["iteration"])
    except (OSError, KeyError):
        return 0


@pytest.mark.slow
@pytest.mark.every_python
def test_a_killed_run_resumes_exactly_as_an_uninterrupted_one(upper_fit, tmp_path):
    fit = upper_fit[1]
    args = [
        "--walkers",
        "10",
        "--steps",
        "600",
        "--ensembles",
        "1",
        "--seed",
        "3",
        "--quiet",
        "--max-draws",
        "50",
    ]
    cmd = [sys.executable, "-m", "rotorbayes.cli", "sample", str(fit)]
    env = dict(os.environ, OMP_NUM_THREADS="1")
    a, b = tmp_path / "a", tmp_path / "b"
    subprocess.run([*cmd, *args, "--out", str(a)], check=True, env=env, capture_output=True)
    proc = subprocess.Popen(
        [*cmd, *args, "--out", str(b)],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    t0 = time.time()
    while _iteration(b / "chain.h5") < 15 and time.time() - t0 < 120:
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    killed_at = _iteration(b / "chain.h5")
    assert 15 <= killed_at < 600, killed_at
    r = subprocess.run([*cmd[:-1], str(b), "--resume"], env=env, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    with h5py.File(a / "chain.h5", "r") as fa, h5py.File(b / "chain.h5", "r") as fb:
        ca, cb = fa["ensemble0"]["chain"][...], fb["ensemble0"]["chain"][...]
        assert fb["ensemble0"].attrs["iteration"] == 600
        assert np.array_equal(ca, cb)
        assert np.array_equal(fa["ensemble0"]["log_prob"][...], fb["ensemble0"]["log_prob"][...])
    for f in (
        "posterior.nc",
        "summary.md",
        "summary.csv",
        "corner.png",
        "trace.png",
        "predictive.png",
        "correlation.png",
    ):
        assert (b / f).stat().st_size > 0
    assert json.loads((b / "settings.json").read_text())["steps"] == 600


def test_sample_command_writes_inference_data(upper_fit, tmp_path, capsys):
    from rotorbayes.inference import arviz_compat

    out = tmp_path / "post"
    assert (
        main(
            [
                "sample",
                str(upper_fit[1]),
                "--walkers",
                "12",
                "--steps",
                "80",
                "--quiet",
                "--out",
                str(out),
                "--max-draws",
                "60",
            ]
        )
        == 0
    )
    text = capsys.readouterr()
    assert "| k_m |" in text.out and "R-hat" in text.out
    # Too short a run says so, loudly.
    assert "not more than 50 τ" in text.err
    idata = arviz_compat.load(out / "posterior.nc")
    for g in (
        "posterior",
        "sample_stats",
        "log_likelihood",
        "observed_data",
        "constant_data",
        "posterior_predictive",
    ):
        assert g in arviz_compat.group_names(idata)
    post = arviz_compat.group(idata, "posterior")
    assert post.sizes["chain"] == 2  # two independent ensembles
    assert post.attrs["ensembles"] == 2
    assert "theta_u_exp0" in arviz_compat.group(idata, "log_likelihood")
    summ = arviz_compat.summary(idata, var_names=["k_m"])
    assert np.isfinite(summ.loc["k_m", "r_hat"])
    assert summ.loc["k_m", "hdi_low"] < summ.loc["k_m", "mean"] < summ.loc["k_m", "hdi_high"]
    truth = upper_fit[0]
    assert abs(float(post["k_m"].mean()) / truth["k_m"] - 1) < 1e-3
    header = (out / "summary.csv").read_text().splitlines()[0].split(",")
    assert {"ess_bulk", "ess_tail", "ess_tau", "r_hat", "r_hat_kept", "hdi_low", "hdi_high"} <= set(
        header
    )
    # The table's R-hat is that of every thinned draw after burn-in, not of the 60 kept.
    from rotorbayes.inference import posterior, sampling

    runs = [sampling.read_ensemble(out / "chain.h5", f"ensemble{i}") for i in range(2)]
    _, rhat_all = posterior.ess_all_draws(None, runs)
    row = dict(
        zip(header, (out / "summary.csv").read_text().splitlines()[1].split(","), strict=True)
    )
    assert row["parameter"] == "k_m"
    assert float(row["r_hat"]) == pytest.approx(rhat_all[0], abs=1e-6)
    # Misuse: an existing folder, too few walkers, --resume on a fit folder.
    assert main(["sample", str(upper_fit[1]), "--out", str(out)]) == 2
    assert main(["sample", str(upper_fit[1]), "--walkers", "4", "--out", str(tmp_path / "x")]) == 2
    assert main(["sample", str(upper_fit[1]), "--resume"]) == 2
    err = capsys.readouterr().err
    assert "already holds results" in err and "--walkers" in err and "settings.json" in err
    assert not (tmp_path / "x").exists()


def test_r_hat_from_every_draw_is_quiet_on_converged_ensembles_and_loud_on_split_ones():
    """The demo's converged chains (3300-4000 ESS a coordinate) were said not to have
    converged: R-hat of the 2 x 200 draws kept in posterior.nc scatters by about +-0.02.
    From every thinned draw it is quiet on independent draws of one distribution and still
    flags two ensembles 0.4 standard deviations apart (R-hat 1.01 is about 0.3)."""
    from rotorbayes.inference import posterior
    from rotorbayes.inference.sampling import EnsembleRun

    def runs(seed, shift=0.0):
        rng = np.random.default_rng(seed)
        return [
            EnsembleRun(
                name=f"ensemble{i}",
                chain=rng.normal(size=(450, 24, 3)) + (shift if i == 1 else 0.0),
                log_prob=np.zeros((450, 24)),
                acceptance=np.full(24, 0.3),
                tau=np.full(3, 2.0),
            )
            for i in range(2)
        ]

    kept, every = [], []
    for seed in range(20):
        r = runs(seed)
        every.append(posterior.ess_all_draws(None, r)[1].max())
        r_kept = [
            EnsembleRun(x.name, x.chain[::40], x.log_prob[::40], x.acceptance, x.tau) for x in r
        ]  # about the 2 x 200 draws posterior.nc keeps
        kept.append(posterior.ess_all_draws(None, r_kept)[1].max())
    assert max(every) < 1.005, max(every)
    assert sum(k >= 1.01 for k in kept) >= 3, kept  # the false alarm the fix removes
    split = [posterior.ess_all_draws(None, runs(seed, shift=0.4))[1].min() for seed in range(5)]
    assert min(split) > 1.01, split


@pytest.mark.slow
def test_simulation_based_calibration_covers_the_truth_at_the_nominal_rates():
    """SBC where it is hard (issue 15): the brake configuration with stick-slip, a step-like
    input whose levels are held 1-4 s, 6 s at 1 kHz, quantised; lower friction (Tc_l, b_l,
    Ts_l) free, truth drawn from the prior.  With the default (robust) likelihood the 50 %
    and 90 % posterior intervals cover the truth at their nominal rates within three
    binomial standard deviations of the check itself, and the truth's ranks are uniform.
    (The i.i.d. likelihood fails this on the same data: see analyses/sbc.py --noise floor.)"""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "analyses" / "sbc.py"
    spec = importlib.util.spec_from_file_location("analyses_sbc", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    res = mod.main(["--case", "brake", "--datasets", "20", "--walkers", "8", "--steps", "250"])
    for name in ("Tc_l", "b_l", "Ts_l"):
        r = res[name]
        assert abs(r["cover50"] - 0.5) <= 3 * r["sd50"], r
        assert abs(r["cover90"] - 0.9) <= 3 * r["sd90"], r
        assert r["ks_p"] > 0.001, r

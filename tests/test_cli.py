"""The command line as a user types it (issue examples), including refusals."""

from __future__ import annotations

import json

import numpy as np
import pytest

import rotorbayes as rb
from rotorbayes.cli import main


def test_simulate_generated_input_with_plot(tmp_path, capsys):
    out, png = tmp_path / "brake_est.csv", tmp_path / "brake_est.png"
    assert (
        main(
            [
                "simulate",
                "--model",
                "brake",
                "--input",
                "est",
                "--duration",
                "30",
                "--out",
                str(out),
                "--plot",
                str(png),
            ]
        )
        == 0
    )
    ex = rb.load_experiment(out, expect_lower=True)
    assert ex.n == 30001 and abs(ex.dt - 1e-3) < 1e-12
    assert png.stat().st_size > 10_000
    assert "lower disc sticks" in capsys.readouterr().out
    # Never overwrite results silently.
    assert main(["simulate", "--model", "brake", "--out", str(out)]) == 2
    assert "pass --force" in capsys.readouterr().err


def test_simulate_with_parameter_file_input_file_alpha0_quantize(tmp_path):
    (tmp_path / "my_params.toml").write_text('base = "thesis:4.2:P_ref"\nk_alpha = 0.07\n')
    t = np.arange(5001) * 1e-3
    np.savetxt(
        tmp_path / "u.csv",
        np.c_[t, 0.8 * np.sin(0.5 * t)],
        delimiter=",",
        header="t,u",
        comments="",
    )
    out = tmp_path / "sim.csv"
    assert (
        main(
            [
                "simulate",
                "--model",
                "coupled",
                "--params",
                str(tmp_path / "my_params.toml"),
                "--input-file",
                str(tmp_path / "u.csv"),
                "--alpha0",
                "0.8",
                "--quantize",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    ex = rb.load_experiment(out)
    q = 2 * np.pi / 40000
    assert np.allclose(ex.theta_l / q, np.round(ex.theta_l / q), atol=1e-6)
    assert ex.meta["alpha0"] == "0.8"
    # The same simulation in Python gives the same (unquantised) angles to a count.
    sim = rb.simulate(
        {**rb.parameters.thesis_set("4.2", "P_ref"), "k_alpha": 0.07},
        0.8 * np.sin(0.5 * t),
        dt=1e-3,
        config="coupled",
        alpha0=0.8,
    )
    assert np.max(np.abs(sim.theta_l - ex.theta_l)) <= q / 2 + 1e-12


def test_fit_writes_json_and_figures(tmp_path, capsys):
    out = tmp_path / "fit_coupled"
    code = main(
        [
            "fit",
            "--model",
            "coupled",
            "example:coupled_est",
            "--validate",
            "example:coupled_val",
            "--p0",
            "thesis:5.2:P0",
            "--free",
            "J_l,k_alpha,Tc_l,b_l",
            "--out",
            str(out),
        ]
    )
    assert code == 0
    doc = json.loads((out / "fit.json").read_text())
    assert doc["success"]
    est = doc["estimates"]
    assert set(est) == {"J_l", "k_alpha", "Tc_l", "b_l"}
    assert est["k_alpha"]["unit"] == "N m/rad" and est["k_alpha"]["stderr"] > 0
    q = doc["quality"]
    assert q["validation"][0]["channels"]["theta_l"]["r2"] > 0.9999
    for f in ("fit_est_0.png", "fit_val_0.png", "friction.png"):
        assert (out / f).stat().st_size > 10_000
    text = capsys.readouterr().out
    assert "R²" in text and "fit %" in text and "Identifiability" in text
    # The result chains into the next step as a start.
    out2 = tmp_path / "fit_brake"
    assert main(
        [
            "fit",
            "--model",
            "brake",
            "example:brake_est",
            "--p0",
            str(out / "fit.json"),
            "--free",
            "Ts_l",
            "--max-nfev",
            "5",
            "--out",
            str(out2),
        ]
    ) in (0, 1)
    assert json.loads((out2 / "fit.json").read_text())["params"]["J_l"] == pytest.approx(
        est["J_l"]["value"]
    )


def test_multistart_command(tmp_path, capsys):
    out = tmp_path / "ms"
    assert (
        main(
            [
                "multistart",
                "--model",
                "coupled",
                "example:coupled_est",
                "--starts",
                "4",
                "--around",
                "thesis:4.2:P0",
                "--free",
                "J_l,k_alpha",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    doc = json.loads((out / "multistart.json").read_text())
    assert len(doc["ssr"]) == 4
    for f in ("waterfall.png", "parameter_spread.png", "summary.txt"):
        assert (out / f).exists()
    assert "starts end within" in capsys.readouterr().out
    # The multistart folder is a start: the fit begins at its best end point.
    best = int(np.nanargmin([np.inf if s is None else s for s in doc["ssr"]]))
    assert main(
        [
            "fit",
            "--model",
            "coupled",
            "example:coupled_est",
            "--free",
            "J_l,k_alpha",
            "--base",
            "thesis:4.2:P0",
            "--p0",
            str(out),
            "--max-nfev",
            "1",
            "--out",
            str(tmp_path / "f"),
        ]
    ) in (0, 1)
    fit = json.loads((tmp_path / "f" / "fit.json").read_text())
    for n, v in zip(doc["names"], doc["ends"][best], strict=True):
        assert fit["estimates"][n]["start"] == pytest.approx(v, rel=1e-12)


@pytest.mark.parametrize(
    "argv,needle",
    [
        (
            ["fit", "--model", "coupled", "example:coupled_est", "--free", "J_lower"],
            "valid names are",
        ),
        (
            [
                "fit",
                "--model",
                "coupled",
                "example:coupled_est",
                "--free",
                "J_l,b_l",
                "--fixed",
                "b_l",
            ],
            "both --fixed and --free",
        ),
        (["fit", "--model", "coupled", "example:upper_est"], "upper"),
        (["fit", "--model", "coupled", "example:nosuch"], "available: brake_est"),
        (
            ["fit", "--model", "upper", "example:upper_est", "--p0", "thesis:9.9:P0"],
            "no thesis set",
        ),
    ],
)
def test_fit_refusals(tmp_path, capsys, argv, needle):
    assert main(argv + ["--out", str(tmp_path / "o")]) == 2
    assert needle in capsys.readouterr().err


def test_p0_outside_bounds_is_refused(tmp_path, capsys):
    (tmp_path / "p0.toml").write_text("J_l = 7.0\n")
    assert (
        main(
            [
                "fit",
                "--model",
                "coupled",
                "example:coupled_est",
                "--p0",
                str(tmp_path / "p0.toml"),
                "--out",
                str(tmp_path / "o"),
            ]
        )
        == 2
    )
    assert "J_l = 7" in capsys.readouterr().err


def test_params_and_effects_listings(capsys):
    assert main(["params"]) == 0
    out = capsys.readouterr().out
    assert "k_alpha" in out and "thesis:4.2:P0" in out
    assert main(["effects"]) == 0
    assert "string_damping" in capsys.readouterr().out

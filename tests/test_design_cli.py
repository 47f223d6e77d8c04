"""``rotorbayes design`` as a user types it (issue 20): the round trip writes next/, simulate
reads its u.csv, an existing folder is refused without --force, bad input is one line."""

from __future__ import annotations

import json

from refdata import SETS

import rotorbayes as rb

COUPLED = dict(SETS["coupled"][0])


def test_cli_round_trip_writes_next_and_refuses_to_overwrite(tmp_path, capsys):
    from rotorbayes.cli import main

    (tmp_path / "truth.toml").write_text(
        "\n".join(f"{k} = {v!r}" for k, v in COUPLED.items()) + "\n"
    )
    data = tmp_path / "est.csv"
    assert (
        main(
            [
                "simulate",
                "--model",
                "coupled",
                "--params",
                str(tmp_path / "truth.toml"),
                "--duration",
                "6",
                "--rate",
                "200",
                "--quantize",
                "--out",
                str(data),
            ]
        )
        == 0
    )
    fit = tmp_path / "fit"
    assert main(
        [
            "fit",
            "--model",
            "coupled",
            str(data),
            "--p0",
            str(tmp_path / "truth.toml"),
            "--max-nfev",
            "30",
            "--out",
            str(fit),
        ]
    ) in (0, 1)
    nxt = tmp_path / "next"
    capsys.readouterr()
    code = main(
        ["design", str(fit), "--out", str(nxt), "--starts", "1", "--max-evals", "20", "--no-check"]
    )
    out = capsys.readouterr().out
    assert code == 0, out
    assert {"u.csv", "design.json", "design.txt", "design.png"} <= {p.name for p in nxt.iterdir()}
    doc = json.loads((nxt / "design.json").read_text())
    assert doc["status"] in ("designed", "little to gain")
    assert doc["target"]["kind"] == "sloppiest" and doc["settings"]["max_volts"] == 5.0
    assert "predicted" in out or "width" in out
    # The input file is what simulate reads.
    prev = tmp_path / "preview.csv"
    assert (
        main(
            [
                "simulate",
                "--model",
                "coupled",
                "--params",
                str(fit),
                "--input-file",
                str(nxt / "u.csv"),
                "--out",
                str(prev),
            ]
        )
        == 0
    )
    ex = rb.load_experiment(prev)
    assert ex.n == 1201 and abs(ex.dt - 1 / 200) < 1e-12
    # Never overwrite silently; --force replaces.
    before = (nxt / "design.json").read_text()
    assert main(["design", str(fit), "--out", str(nxt), "--starts", "1"]) == 2
    assert "pass --force" in capsys.readouterr().err
    assert (nxt / "design.json").read_text() == before
    # Bad input: a clear message and exit code 2, nothing written.
    bad = tmp_path / "bad"
    assert main(["design", str(fit), "--out", str(bad), "--max-volts", "9"]) == 2
    err = capsys.readouterr().err
    assert "5 V" in err and "Traceback" not in err and not bad.exists()
    assert (
        main(["design", str(fit), "--out", str(bad), "--separate", "nonsense,initial_torsion"]) == 2
    )
    assert "unknown effect 'nonsense'" in capsys.readouterr().err and not bad.exists()

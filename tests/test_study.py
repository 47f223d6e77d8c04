"""Analysis files (`rotorbayes run`): validation before any work, a whole study, re-runs that
skip unchanged stages."""

from __future__ import annotations

import json

import pytest

import rotorbayes as rb
from rotorbayes.cli import main
from rotorbayes.model.parameters import resolve


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    d = tmp_path_factory.mktemp("study_data")
    p = resolve(dict(k_m=3.1, Tc_u=0.62, dTc_u=0.03, b_u=1.7, db_u=0.05, J_l=0.062,
                     k_alpha=0.118, Tc_l=0.031, b_l=0.0065), config="coupled")
    p["db_l"] = 0.0015
    for kind, seed in (("est", 5), ("val", 6)):
        t, u = rb.signals.make_signal(kind, 12.0, rate=200.0, seed=seed)
        sim = rb.simulate(p, u, dt=1 / 200, config="coupled",
                          effects=["lower_asymmetric_viscous"], quantize_angles=True)
        rb.save_experiment(sim.to_experiment(kind), d / f"{kind}.csv")
    return d


STUDY = """
[analysis]
name = "test study"
out = "out"
config = "coupled"
data = ["est.csv"]
validate = ["val.csv"]

[diagnose]
add_effects = true
max_steps = 2

[sample]
walkers = 24
steps = {steps}
ensembles = 2

[identify]
profiles = ["J_l"]
points = 3

[report]
html = false
"""


def test_a_study_runs_and_a_rerun_skips_unchanged_stages(data, capsys):
    f = data / "study.toml"
    f.write_text(STUDY.format(steps=40))
    assert main(["run", str(f), "--quiet"]) == 0
    out = data / "out"
    rec = json.loads((out / "run.json").read_text())
    assert rec["added_effects"] == ["lower_asymmetric_viscous"]
    names = [s["name"] for s in rec["stages"]]
    assert names == ["fit0", "diagnose0", "fit1", "diagnose1", "compare", "sample",
                     "identify"]
    assert all(len(d["sha256"]) == 64 for d in rec["data"])
    assert rec["versions"]["numpy"] and "[sample]" in rec["analysis_text"]
    assert json.loads((out / "fit1" / "diagnosis.json").read_text())["adequate"]
    assert (out / "posterior" / "posterior.nc").exists()
    assert "---- fit0" in (out / "log.txt").read_text()
    # Unchanged: everything is kept.
    assert main(["run", str(f), "--quiet"]) == 0
    rec2 = json.loads((out / "run.json").read_text())
    assert all(s["skipped"] for s in rec2["stages"])
    # Only the sampler's settings change: the fits and diagnoses are kept.
    f.write_text(STUDY.format(steps=50))
    assert main(["run", str(f), "--quiet"]) == 0
    rec3 = {s["name"]: s["skipped"] for s in json.loads((out / "run.json").read_text())
            ["stages"]}
    assert rec3["fit0"] and rec3["fit1"] and rec3["diagnose1"] and not rec3["sample"]


@pytest.mark.parametrize("edit,message", [
    ("[analysis]\nout='o'\nconfig='coupled'\ndata=['est.csv']\n[fitt]\n", "unknown table [fitt]"),
    ("[analysis]\nout='o'\nconfig='coupled'\ndata=['est.csv']\nsede=1\n",
     "[analysis] unknown key 'sede'"),
    ("[analysis]\nout='o'\nconfig='coupled'\ndata=['nope.csv']\n",
     "[analysis] data: file 'nope.csv' not found"),
    ("[analysis]\nout='o'\nconfig='coupled'\ndata=['est.csv']\n[fit]\nfree=['J_x']\n",
     "[fit] free: unknown parameter 'J_x'; valid names are: k_m"),
    ("[analysis]\nout='o'\nconfig='coupled'\ndata=['est.csv']\n[priors]\n"
     "J_l = { dist = 'loguniform', lower = 0.5, upper = 0.1 }\n",
     "[priors] J_l: lower 0.5 must be below upper 0.1"),
    ("[analysis]\nout='o'\nconfig='wagon'\ndata=['est.csv']\n", "config = 'wagon'"),
    ("[analysis]\nout='o'\nconfig='coupled'\ndata=['est.csv']\n[sample]\nsteps='many'\n",
     "[sample] steps = 'many' must be a int"),
    ("[analysis]\nout='o'\nconfig='coupled'\ndata=['est.csv']\n[fit]\neffects=['warp']\n",
     "[fit] effects: unknown effect 'warp'"),
    ("[analysis\n", "not valid TOML"),
])
def test_a_bad_analysis_file_is_refused_before_any_work(data, capsys, edit, message):
    f = data / "bad.toml"
    f.write_text(edit)
    assert main(["run", str(f)]) == 2
    err = capsys.readouterr().err
    assert message in err and str(f) in err and "Traceback" not in err
    assert not (data / "o").exists()

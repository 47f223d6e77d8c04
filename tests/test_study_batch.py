"""Several studies in one command (issue 18: "the same study over many data sets"):
``rotorbayes run a.toml b.toml ...`` runs each analysis file as one task on the executor
layer, each study in a process of its own.

Checked: a study run among others gives the fit a single ``run`` gives, bit for bit, on
local threads and on a real two-process Dask ``LocalCluster``; one study refused at run
time leaves the others done and the exit code says so; bad files and two studies writing one
folder are refused before any work; a worker that cannot see an analysis file, or sees
another version, runs nothing; a Ctrl-C stops every study, keeps their finished stages, and
the same command continues.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from rotorbayes.cli import main
from rotorbayes.commands.study.batch import StudyTask, run_one

ENV = {**os.environ, "PYTHONUNBUFFERED": "1"}


def analysis(
    folder: Path, name: str, out: str, data: str = "example:upper_est", extra: str = ""
) -> Path:
    p = folder / name
    p.write_text(f'[analysis]\nout = "{out}"\nconfig = "upper"\ndata = ["{data}"]\n{extra}')
    return p


def estimates(out: Path) -> dict:
    rec = json.loads((out / "run.json").read_text())
    return json.loads((Path(rec["final_fit"]) / "fit.json").read_text())["estimates"]


@pytest.fixture(scope="module")
def single(tmp_path_factory):
    """Each study run alone, the reference."""
    d = tmp_path_factory.mktemp("single")
    ref = {}
    for name, data in (("a", "example:upper_est"), ("b", "example:upper_val")):
        assert main(["run", str(analysis(d, f"{name}.toml", name.upper(), data)), "--quiet"]) == 0
        ref[name] = estimates(d / name.upper())
    return ref


def test_several_studies_match_single_runs_and_a_refused_one_is_reported(single, tmp_path, capsys):
    a = analysis(tmp_path, "a.toml", "A")
    b = analysis(tmp_path, "b.toml", "B", "example:upper_val")
    (tmp_path / "foreign").mkdir()
    (tmp_path / "foreign" / "notes.txt").write_text("mine")
    f = analysis(tmp_path, "f.toml", "foreign")
    capsys.readouterr()
    code = main(["run", str(a), str(b), str(f), "--workers", "2"])
    out = capsys.readouterr().out
    assert code == 2, out  # one study refused at run time: the highest code
    assert estimates(tmp_path / "A") == single["a"]
    assert estimates(tmp_path / "B") == single["b"]
    assert "2 of 3 studies done" in out and "f.toml: exit code 2" in out
    assert "no run.json" in out  # the refused study's own reason
    assert (tmp_path / "foreign" / "notes.txt").read_text() == "mine"
    assert sorted(p.name for p in (tmp_path / "foreign").iterdir()) == ["notes.txt"]


def test_bad_files_and_shared_output_folders_are_refused_before_any_work(tmp_path, capsys):
    a = analysis(tmp_path, "a.toml", "A")
    twin = analysis(tmp_path, "twin.toml", "A", "example:upper_val")
    bad = analysis(tmp_path, "bad.toml", "C", "example:nothing")
    for args, said in (
        ([a, twin], "both write [analysis] out"),
        ([a, a], "is given twice"),
        ([a, bad], "no bundled example 'nothing'"),
    ):
        capsys.readouterr()
        assert main(["run", *map(str, args)]) == 2
        assert said in capsys.readouterr().err
    assert not (tmp_path / "A").exists() and not (tmp_path / "C").exists()


def test_a_worker_that_cannot_see_the_file_or_sees_another_runs_nothing(tmp_path):
    a = analysis(tmp_path, "a.toml", "A")
    row = run_one(StudyTask(str(a), "0" * 64, False, 1))
    assert row["code"] == 2 and "another version" in row["message"], row
    row = run_one(StudyTask(str(tmp_path / "gone.toml"), "0" * 64, False, 1))
    assert row["code"] == 2 and "cannot read" in row["message"], row
    assert "shares" in row["message"]
    assert not (tmp_path / "A").exists()


def test_studies_on_a_local_dask_cluster_match_single_runs(single, tmp_path, capsys):
    pytest.importorskip("distributed")
    a = analysis(tmp_path, "a.toml", "A")
    b = analysis(tmp_path, "b.toml", "B", "example:upper_val")
    code = main(["run", str(a), str(b), "--backend", "dask", "--workers", "2"])
    assert code == 0, capsys.readouterr()
    assert estimates(tmp_path / "A") == single["a"]
    assert estimates(tmp_path / "B") == single["b"]


@pytest.mark.slow
@pytest.mark.every_python
def test_ctrl_c_stops_every_study_and_the_same_command_continues(tmp_path):
    slow = "[sample]\nwalkers = 16\nsteps = 1500\n"
    files = [
        analysis(tmp_path, f"{n}.toml", n.upper(), d, slow)
        for n, d in (("a", "example:upper_est"), ("b", "example:upper_val"))
    ]
    cmd = [sys.executable, "-m", "rotorbayes.cli", "run", *map(str, files)]
    p = subprocess.Popen(
        cmd,
        cwd=tmp_path,
        env=ENV,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    t0 = time.time()
    while not all((tmp_path / n / "fit0" / "fit.json").exists() for n in "AB"):
        assert p.poll() is None and time.time() - t0 < 120
        time.sleep(0.1)
    time.sleep(1.0)  # both studies are sampling now
    os.killpg(p.pid, signal.SIGINT)  # Ctrl-C at a terminal reaches the whole group
    out, err = p.communicate(timeout=120)
    assert p.returncode == 130, (out, err)
    assert "interrupted (Ctrl-C) after 0 of 2 studies" in err and "Traceback" not in err
    assert "Run the same command again" in err
    for n in "AB":
        stages = json.loads((tmp_path / n / "run.json").read_text())["stages"]
        assert stages[0]["name"] == "fit0" and stages[0]["exit_code"] == 0, stages
    # The same command (with a shorter sampling) goes on from the finished fits.
    for f in files:
        f.write_text(f.read_text().replace("steps = 1500", "steps = 60"))
    assert (
        subprocess.run(cmd, cwd=tmp_path, env=ENV, capture_output=True, timeout=300).returncode == 0
    )
    for n in "AB":
        stages = {
            s["name"]: s for s in json.loads((tmp_path / n / "run.json").read_text())["stages"]
        }
        assert stages["fit0"]["skipped"] is True
        assert (tmp_path / n / "posterior" / "summary.md").exists()


WRAPPER = """import os, subprocess, sys, time
env = dict(os.environ, ROTORBAYES_PARENT_PID=str(os.getpid()))
p = subprocess.Popen([sys.executable, "-m", "rotorbayes.cli", "run", sys.argv[1], "--quiet"],
                     env=env, cwd=os.path.dirname(sys.argv[1]))
print(p.pid, flush=True)
time.sleep(600)
"""


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0]
    except OSError:
        return False
    return state != "Z"  # a zombie has ended (its new parent may not reap it)


def test_a_study_ends_when_the_process_that_started_it_is_killed(tmp_path):
    """A study's child process (what a Dask worker or the command starts) must not run on
    after its starter is SIGKILLed: the scheduler gives the task to another worker."""
    f = analysis(tmp_path, "a.toml", "A", extra="[sample]\nwalkers = 16\nsteps = 3000\n")
    w = subprocess.Popen(
        [sys.executable, "-c", WRAPPER, str(f)], stdout=subprocess.PIPE, text=True, env=ENV
    )
    child = int(w.stdout.readline())
    t0 = time.time()
    while not (tmp_path / "A" / "fit0" / "fit.json").exists():
        assert _alive(child) and time.time() - t0 < 120
        time.sleep(0.1)
    w.kill()  # the starter dies by SIGKILL: it can pass nothing on
    w.wait()
    t1 = time.time()
    while _alive(child) and time.time() - t1 < 10:
        time.sleep(0.1)
    assert not _alive(child), "the study ran on after the process that started it was killed"
    # What it had finished is kept; the folder's lock is free for the next run.
    stages = json.loads((tmp_path / "A" / "run.json").read_text())["stages"]
    assert stages[0]["name"] == "fit0" and stages[0]["exit_code"] == 0

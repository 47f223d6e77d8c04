"""Files and folders as a careless or hostile user gives them (issue 31, round two): the red
team's cases, each refused with one clear message and exit code 2 (``rotorbayes.util.exitcodes``)
before anything is read whole, written or lost.

Covered:

* lost -- ``--force`` on a folder of the user's own files, on the working folder (or a
  folder above it), on a folder holding the command's own inputs; a symbolic link as
  ``--out`` (followed, never replaced; no ``.LINK.old-*`` left);
* hang or out of memory -- ``/dev/zero``, ``/dev/urandom``, a FIFO, a ``<(...)`` stream and
  a sparse file of 1 GiB as the data file (each run in a process of its own with bounded
  memory and time, so that a regression ends the test, not the machine), binary files,
  the size and row limits and their environment variables;
* wrong -- a data file changed since the fit, refused by every command that reads the fit
  again unless ``--accept-changed-data``; the SHA-256 fit.json records is that of the
  bytes fitted.

Misuse of the command line in general is in ``test_cli_misuse.py``, faults of the
environment in ``test_faults.py``, other hostile input in ``test_faults_input.py``.
"""

from __future__ import annotations

import hashlib
import json
import os
import resource
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import rotorbayes as rb
from rotorbayes.cli import main
from rotorbayes.io.measurements import DataFileError, load_experiment
from rotorbayes.io.outputs import MARKER, OutputError, output_folder
from rotorbayes.util import exitcodes as EXIT

FAST = ["--max-nfev", "3"]
ENV = {**os.environ, "NUMBA_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}
#: Address space and time a command run in its own process may take: a read of /dev/zero
#: fails at the first limit, a wait on a FIFO at the second.
MEMORY = 4 << 30
TIMEOUT = 90


def refused(capsys, argv, *needles) -> str:
    """Run ``argv`` in-process: exit 2, one line ``rotorbayes CMD: error: ...`` holding
    every needle, no traceback."""
    got = main(argv)
    cap = capsys.readouterr()
    err = cap.err.strip()
    assert got == EXIT.REFUSED, (got, err)
    assert "Traceback" not in cap.err, err
    assert len(err.splitlines()) == 1, err
    assert err.startswith(f"rotorbayes {argv[0]}: error: "), err
    for n in needles:
        assert n in err, (n, err)
    return err


def in_process_of_its_own(args, cwd, *, shell: str | None = None, env=None):
    """``rotorbayes ARGS`` (or the bash line ``shell``) in a process with :data:`MEMORY` of
    address space, ended after :data:`TIMEOUT` s (the test then fails: it hung)."""

    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (MEMORY, MEMORY))

    cmd = ["bash", "-c", shell] if shell else [sys.executable, "-m", "rotorbayes.cli", *args]
    try:
        return subprocess.run(
            cmd,
            cwd=cwd,
            env={**ENV, **(env or {})},
            capture_output=True,
            text=True,
            timeout=TIMEOUT,
            preexec_fn=limit,
        )
    except subprocess.TimeoutExpired:
        pytest.fail(f"{cmd} still ran after {TIMEOUT} s: it hangs")


def listing(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def tree(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` with its bytes (to show nothing changed)."""
    return {
        str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()
    }


def sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _upper_data(path: Path, seconds: float = 2.0) -> Path:
    p = rb.parameters.resolve(
        dict(k_m=3.1, Tc_u=0.62, dTc_u=0.03, b_u=1.7, db_u=0.05), config="upper"
    )
    t, u = rb.signals.make_signal("est", seconds, rate=200.0, seed=4)
    sim = rb.simulate(p, u, dt=1 / 200, config="upper", quantize_angles=True)
    rb.save_experiment(sim.to_experiment("upper"), path)
    return path


def _fit(data: Path, out: Path) -> Path:
    assert main(["fit", "--model", "upper", str(data), "--out", str(out), *FAST]) in (0, 1)
    return out


@pytest.fixture(scope="module")
def proj(tmp_path_factory):
    """d.csv (2 s at 200 Hz, upper configuration) and fit/, a quick fit of it."""
    d = tmp_path_factory.mktemp("proj")
    _fit(_upper_data(d / "d.csv"), d / "fit")
    return d


@pytest.fixture(scope="module")
def changed(tmp_path_factory):
    """A fit whose data file was edited after the fit (one input voltage): the folder."""
    d = tmp_path_factory.mktemp("changed")
    data = _upper_data(d / "d.csv")
    fit = _fit(data, d / "fit")
    lines = data.read_text().splitlines(keepends=True)
    k = next(i for i, line in enumerate(lines) if line.startswith("t,")) + 30
    t, u, th = lines[k].strip().split(",")
    lines[k] = f"{t},{float(u) + 0.01!r},{th}\n"
    data.write_text("".join(lines))
    return fit


@pytest.fixture
def here(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    return tmp_path


# -------------------------------------------------------------- 1. --force loses nothing
def test_force_refuses_a_folder_of_the_users_own_files(here, proj, capsys):
    docs = here / "mydocs"
    (docs / "chapters").mkdir(parents=True)
    (docs / "thesis.tex").write_text("\\chapter{Stick-slip}\n")
    (docs / "chapters" / "one.tex").write_text("text\n")
    before = tree(docs)
    data = str(proj / "d.csv")
    for force in ([], ["--force"]):
        refused(
            capsys,
            ["fit", "--model", "upper", data, "--out", "mydocs", *FAST, *force],
            "--out mydocs",
            "rotorbayes did not write",
            "thesis.tex",
            "chapters/",
        )
    # sample emptied a folder it was given with --force, whatever it held
    refused(
        capsys,
        ["sample", str(proj / "fit"), "--out", "mydocs", "--force"],
        "rotorbayes did not write",
        "thesis.tex",
    )
    assert tree(docs) == before
    assert listing(here) == ["mydocs"]  # no partial folder, no lock file


@pytest.mark.parametrize("out", ["{cwd}", "../{name}", ".", ".."])
def test_force_never_replaces_the_working_folder_or_one_above_it(
    tmp_path, proj, capsys, monkeypatch, out
):
    # The working folder is even a result folder (the user went into it), with the data.
    cwd = tmp_path / "work"
    shutil.copytree(proj / "fit", cwd)
    shutil.copy(proj / "d.csv", cwd / "d.csv")
    monkeypatch.chdir(cwd)
    before = tree(tmp_path)
    out = out.format(cwd=cwd, name=cwd.name)
    refused(
        capsys,
        ["fit", "--model", "upper", "d.csv", "--out", out, "--force", *FAST],
        f"--out {out}",
        "working folder",
    )
    assert tree(tmp_path) == before and listing(tmp_path) == ["work"]


def test_force_never_replaces_a_folder_holding_an_input(here, proj, capsys):
    res = here / "res"
    shutil.copytree(proj / "fit", res)  # a result folder...
    shutil.copy(proj / "d.csv", res / "d.csv")  # ... with the data put into it
    before = tree(here)
    refused(
        capsys,
        ["fit", "--model", "upper", "res/d.csv", "--out", "res", "--force", *FAST],
        "--out res",
        "holds res/d.csv, an input",
    )
    for argv in (
        ["fit", "--model", "upper", str(proj / "d.csv"), "--p0", "res", "--out", "res"],
        ["compare", "res", "--out", "res"],
        ["identify", "res", "--out", "res"],
        ["design", "res", "--out", "res"],
        ["sample", "res", "--out", "res"],
    ):
        refused(capsys, [*argv, "--force"], "--out res", "is res, an input")
    assert tree(here) == before and listing(here) == ["res"]


def test_force_replaces_results_of_this_and_earlier_versions(tmp_path):
    for name, content in (
        ("fit.json", "{}"),
        ("multistart.json", "{}"),
        ("run.json", "{}"),
        (MARKER, ""),
    ):
        old = tmp_path / f"old_{name}"
        old.mkdir()
        (old / name).write_text(content)
        (old / "figure.png").write_bytes(b"png")
        with output_folder(old, force=True) as tmp:
            (tmp / "new.txt").write_text("new")
        assert listing(old) == [MARKER, "new.txt"], name
    empty = tmp_path / "empty"
    empty.mkdir()
    with output_folder(empty) as tmp:
        (tmp / "a.txt").write_text("a")
    assert listing(empty) == [MARKER, "a.txt"]
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("mine")
    with (
        pytest.raises(OutputError, match="did not write .notes.txt."),
        output_folder(mine, force=True),
    ):
        pass
    assert listing(mine) == ["notes.txt"]
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []


def test_files_put_into_an_empty_out_while_the_run_worked_are_kept(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    with (
        pytest.raises(OutputError, match="put there while this run worked"),
        output_folder(out, force=True) as tmp,
    ):
        (tmp / "a.txt").write_text("a")
        (out / "thesis.tex").write_text("mine")
    assert listing(out) == ["thesis.tex"] and listing(tmp_path) == ["out"]


def test_a_symlink_as_out_is_followed_never_replaced(here, proj, capsys):
    (here / "real").mkdir()
    (here / "link").symlink_to("real")
    data = str(proj / "d.csv")
    for force in ([], ["--force"]):
        assert main(["fit", "--model", "upper", data, "--out", "link", *FAST, *force]) in (0, 1)
        capsys.readouterr()
        assert (here / "link").is_symlink() and os.readlink(here / "link") == "real"
        assert {"fit.json", MARKER} <= set(listing(here / "real"))
        assert listing(here) == ["link", "real"]  # no .link.old-*, no .real.partial-*
    # A link to a folder not yet made: made there, the link kept.
    (here / "later").symlink_to("made")
    with output_folder(here / "later") as tmp:
        (tmp / "a.txt").write_text("a")
    assert (here / "later").is_symlink() and listing(here / "made") == [MARKER, "a.txt"]
    (here / "nowhere").symlink_to("no/such/folder")
    with (
        pytest.raises(OutputError, match="is a link to .* whose folder"),
        output_folder(here / "nowhere"),
    ):
        pass


# ------------------------------------------------------------ 2. no hang, no memory blow-up
@pytest.mark.parametrize("device", ["/dev/zero", "/dev/urandom"])
def test_a_device_as_the_data_file_is_refused_before_reading(tmp_path, device):
    if not os.path.exists(device):
        pytest.skip(f"no {device} here")
    r = in_process_of_its_own(["fit", "--model", "upper", device, "--out", "o"], tmp_path)
    assert r.returncode == EXIT.REFUSED, r.stderr[-2000:]
    assert f"{device}: is a character device" in r.stderr and "regular file" in r.stderr
    assert "Traceback" not in r.stderr and listing(tmp_path) == []


def test_a_fifo_as_the_data_file_is_refused_at_once(tmp_path):
    os.mkfifo(tmp_path / "pipe.csv")
    # Nobody writes into it: reading it would wait for ever.
    r = in_process_of_its_own(["fit", "--model", "upper", "pipe.csv", "--out", "o"], tmp_path)
    assert r.returncode == EXIT.REFUSED, r.stderr[-2000:]
    assert "pipe.csv: is a pipe" in r.stderr and "save it first" in r.stderr
    assert listing(tmp_path) == ["pipe.csv"]
    # In an analysis file, the same (and no study folder is left).
    (tmp_path / "a.toml").write_text(
        '[analysis]\nout = "study"\nconfig = "upper"\ndata = ["pipe.csv"]\n'
    )
    r = in_process_of_its_own(["run", "a.toml"], tmp_path)
    assert r.returncode == EXIT.REFUSED and "is a pipe" in r.stderr, r.stderr[-2000:]
    assert listing(tmp_path) == ["a.toml", "pipe.csv"]


def test_an_input_file_that_is_a_device_or_a_fifo_is_refused(tmp_path):
    os.mkfifo(tmp_path / "u.csv")
    for source in ("/dev/zero", "u.csv"):
        r = in_process_of_its_own(
            ["simulate", "--model", "upper", "--input-file", source, "--out", "s.csv"], tmp_path
        )
        assert r.returncode == EXIT.REFUSED, r.stderr[-2000:]
        assert f"--input-file {source}: is a " in r.stderr and "regular file" in r.stderr
    assert listing(tmp_path) == ["u.csv"]


def test_a_process_substitution_stream_is_refused(tmp_path, proj):
    # `<(cat d.csv)` was fitted, then recorded as /dev/fd/63 with the SHA-256 of nothing.
    line = (
        f"'{sys.executable}' -m rotorbayes.cli fit --model upper <(cat '{proj}/d.csv') "
        "--out o --max-nfev 3"
    )
    r = in_process_of_its_own(None, tmp_path, shell=line)
    assert r.returncode == EXIT.REFUSED, r.stderr[-2000:]
    assert "/dev/fd/" in r.stderr and "is a pipe" in r.stderr and "save it first" in r.stderr
    assert listing(tmp_path) == []


def test_a_sparse_file_of_a_gigabyte_is_refused_before_reading(tmp_path):
    big = tmp_path / "big.csv"
    with open(big, "wb") as fh:
        fh.truncate(1 << 30)  # 1 GiB of holes: no disk taken
    r = in_process_of_its_own(["fit", "--model", "upper", "big.csv", "--out", "o"], tmp_path)
    assert r.returncode == EXIT.REFUSED, r.stderr[-2000:]
    assert "big.csv: is 1,074 MB, more than the 1,000 MB" in r.stderr, r.stderr
    assert "ROTORBAYES_MAX_DATA_MB=1074" in r.stderr and "nothing was read" in r.stderr
    # With the limit raised, it is refused at its first line, not read whole.
    r = in_process_of_its_own(
        ["fit", "--model", "upper", "big.csv", "--out", "o"],
        tmp_path,
        env={"ROTORBAYES_MAX_DATA_MB": "2000"},
    )
    assert r.returncode == EXIT.REFUSED, r.stderr[-2000:]
    assert "big.csv, line 1: holds NUL bytes" in r.stderr
    assert listing(tmp_path) == ["big.csv"]


def test_binary_and_endless_lines_are_refused_when_met(tmp_path):
    holes = tmp_path / "holes.csv"
    holes.write_text("t,u,theta_u\n0,0,0\n")
    with open(holes, "r+b") as fh:
        fh.truncate(50_000_000)
    with pytest.raises(DataFileError, match=r"line 3: holds NUL bytes"):
        load_experiment(holes)
    endless = tmp_path / "endless.csv"
    endless.write_text("t,u,theta_u\n" + "1" * 10_000_000)
    with pytest.raises(DataFileError, match=r"line 2: longer than 65536 characters"):
        load_experiment(endless)


def test_the_size_and_row_limits_and_their_variables(tmp_path, proj, monkeypatch, capsys):
    data = proj / "d.csv"
    with pytest.raises(
        DataFileError,
        match=r"more than 100 data rows.*ROTORBAYES_MAX_DATA"
        r"_ROWS",
    ):
        load_experiment(data, max_rows=100)
    with pytest.raises(DataFileError, match=r"more than the 1,000 bytes.*nothing was read"):
        load_experiment(data, max_bytes=1000)
    assert load_experiment(data, max_rows=401, max_bytes=10**6).n == 401
    monkeypatch.setenv("ROTORBAYES_MAX_DATA_ROWS", "100")
    refused(
        capsys,
        ["fit", "--model", "upper", str(data), "--out", str(tmp_path / "o")],
        "more than 100 data rows",
        "ROTORBAYES_MAX_DATA_ROWS",
    )
    monkeypatch.setenv("ROTORBAYES_MAX_DATA_ROWS", "lots")
    refused(
        capsys,
        ["fit", "--model", "upper", str(data), "--out", str(tmp_path / "o")],
        "ROTORBAYES_MAX_DATA_ROWS='lots' is not a positive number",
    )
    assert listing(tmp_path) == []


# ------------------------------------------------------------------ 3. changed data files
@pytest.mark.parametrize(
    "argv",
    [
        ["diagnose"],
        ["compare", "--out", "{tmp}/c"],
        ["identify", "--out", "{tmp}/c"],
        ["design", "--out", "{tmp}/c"],
        ["sample", "--out", "{tmp}/c"],
    ],
)
def test_a_changed_data_file_is_refused_by_every_command_that_reads_the_fit(
    changed, tmp_path, capsys, argv
):
    before = tree(changed)
    doc = json.loads((changed / "fit.json").read_text())
    recorded = doc["data_files"][0]["sha256"]
    now = sha(changed.parent / "d.csv")
    argv = [argv[0], str(changed), *(a.format(tmp=tmp_path) for a in argv[1:])]
    refused(
        capsys,
        argv,
        "d.csv has changed since the fit",
        f"SHA-256 recorded {recorded}",
        f"now {now}",
        "--accept-changed-data",
    )
    assert tree(changed) == before and listing(tmp_path) == []


@pytest.mark.slow
@pytest.mark.every_python
def test_accept_changed_data_says_so_and_the_diagnosis_records_it(changed, tmp_path, capfd):
    fit = tmp_path / "fit"
    shutil.copytree(changed, fit)
    code = main(["diagnose", str(fit), "--no-trials", "--accept-changed-data"])
    err = capfd.readouterr().err
    assert code == 0, err
    assert "has changed since the fit" in err and "because of --accept-changed-data" in err
    rec = json.loads((fit / "diagnosis.json").read_text())["data_changed"]
    assert rec == [
        {
            "file": str(changed.parent / "d.csv"),
            "recorded": json.loads((fit / "fit.json").read_text())["data_files"][0]["sha256"],
            "now": sha(changed.parent / "d.csv"),
        }
    ]


def test_fit_records_the_sha256_of_the_bytes_it_fitted(proj):
    doc = json.loads((proj / "fit" / "fit.json").read_text())
    assert doc["data_files"][0]["sha256"] == sha(proj / "d.csv")
    assert load_experiment(proj / "d.csv").sha256 == sha(proj / "d.csv")

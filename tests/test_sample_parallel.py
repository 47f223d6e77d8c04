"""Independent emcee ensembles on the executor layer (issue 18): ``sample --backend ...``.

The ensembles run concurrently in segments of steps; only the command's process writes
``chain.h5``. Checked: the chains are bit for bit those of the serial loop (fit-de's
re-centring crossed, segments of different lengths) on the serial and thread back-ends and
on a real two-process Dask ``LocalCluster``, where the log-posterior is scattered once; a
run SIGKILLed or stopped on request (Ctrl-C) on the parallel path says where it stopped and
resumes to exactly the chains of an uninterrupted run.
"""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
from test_faults import _short_upper

from rotorbayes.cli import main
from rotorbayes.inference import parallel, sampling
from rotorbayes.inference.likelihood import LogPosterior
from rotorbayes.inference.results import load_fit

ENV = {**os.environ, "NUMBA_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    d = tmp_path_factory.mktemp("sp")
    data = _short_upper(d, seconds=2.0)
    assert main(["fit", "--model", "upper", str(data), "--out", str(d / "fit")]) == 0
    return d / "fit"


def chains(path: Path) -> dict:
    """Every group's chain, log-probabilities, acceptances, random state and proposal."""
    with h5py.File(path, "r") as f:
        out = {}
        for k, g in f.items():
            it = int(g.attrs["iteration"])
            out[k] = (
                np.asarray(g["chain"][:it]).tobytes(),
                np.asarray(g["log_prob"][:it]).tobytes(),
                np.asarray(g["accepted"]).tobytes(),
                sorted(
                    (a, np.asarray(g.attrs[a]).tobytes())
                    for a in g.attrs
                    if a.startswith(("random_state", "proposal"))
                ),
                it,
            )
    return out


def run(fit, folder, executor, monkeypatch, steps=20, **kw):
    # Re-centre the fit proposal early (main process) and cut the runs into segments of
    # 3 steps, then 1: the chains must not depend on either.
    monkeypatch.setattr(sampling.moves, "ADAPT_AT", 12)
    monkeypatch.setattr(sampling.run, "SEGMENT_FIRST", 3)
    monkeypatch.setattr(sampling.run, "SEGMENT_SECONDS", 1e-9)
    f = load_fit(fit)
    lp = LogPosterior(f.problem, f.x)
    sampling.sample(
        lp,
        f.x,
        folder,
        n_walkers=10,
        n_steps=steps,
        n_ensembles=2,
        seed=3,
        progress=False,
        executor=executor,
        **kw,
    )
    return chains(folder / "chain.h5"), lp.n_calls


def test_serial_and_threads_give_the_serial_loop_bit_for_bit(fitted, tmp_path, monkeypatch):
    ref, calls = run(fitted, tmp_path / "ref", None, monkeypatch)
    assert all(v[4] == 20 for v in ref.values()) and len(ref) == 2
    assert any(a.startswith("proposal_adapted") for a, _ in ref["ensemble0"][3])
    got, c1 = run(fitted, tmp_path / "serial", parallel.SerialExecutor(), monkeypatch)
    assert got == ref and c1 == calls
    with parallel.open_executor(parallel.ExecutorSpec("threads", 2)) as ex:
        got, c2 = run(fitted, tmp_path / "threads", ex, monkeypatch)
    assert got == ref and c2 == calls
    # Resumed on the executor from a shorter checkpoint of the serial loop: the same.
    run(fitted, tmp_path / "mixed", None, monkeypatch, steps=7)
    got, _ = run(fitted, tmp_path / "mixed", parallel.SerialExecutor(), monkeypatch)
    assert got == ref


def test_a_local_dask_cluster_gives_the_same_chains_and_gets_the_data_once(
    fitted, tmp_path, monkeypatch
):
    ref, calls = run(fitted, tmp_path / "ref", None, monkeypatch)
    seen: list = []

    def deps(dask_scheduler):
        return [
            sorted(str(d.key) for d in ts.dependencies)
            for k, ts in dask_scheduler.tasks.items()
            if "_run_segment" in str(k)
        ]

    with parallel.open_executor(parallel.ExecutorSpec("dask", 2)) as ex:
        client = ex._client

        def look() -> bool:  # asked between segments: which data the segments name
            seen.extend(client.run_on_scheduler(deps))
            return False

        got, c = run(fitted, tmp_path / "dask", ex, monkeypatch, should_stop=look)
        pids = set(client.run(os.getpid).values())
    assert got == ref and c == calls  # evaluations counted on the workers, added here
    assert len(pids) == 2 and os.getpid() not in pids
    # Every segment names the one scattered log-posterior, nothing else.
    assert seen and {tuple(d) for d in seen} == {tuple(seen[0])} and len(seen[0]) == 1


def reference(fitted: Path, tmp_path: Path, *, steps: int, ensembles: int, seed: int) -> dict:
    """The chains of an uninterrupted serial run of 10 walkers (what the command runs)."""
    f = load_fit(fitted)
    sampling.sample(
        LogPosterior(f.problem, f.x),
        f.x,
        tmp_path / "ref",
        n_walkers=10,
        n_steps=steps,
        n_ensembles=ensembles,
        seed=seed,
        progress=False,
    )
    return chains(tmp_path / "ref" / "chain.h5")


def cli(args, cwd):
    return subprocess.Popen(
        [sys.executable, "-m", "rotorbayes.cli", *args],
        cwd=cwd,
        env=ENV,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


@pytest.mark.slow
@pytest.mark.every_python
def test_parallel_sampling_killed_resumes_to_the_uninterrupted_chains(fitted, tmp_path):
    # 900 steps, not 300: a read of chain.h5 waits for the writer, and a 300-step run once
    # ended during the read that saw the kill's step count (CI on a fast machine).
    args = [
        "--walkers",
        "10",
        "--steps",
        "900",
        "--ensembles",
        "2",
        "--seed",
        "5",
        "--max-draws",
        "5",
        "--quiet",
    ]
    ref = reference(fitted, tmp_path, steps=900, ensembles=2, seed=5)
    out = tmp_path / "S"
    p = cli(
        ["sample", str(fitted), *args, "--backend", "threads", "--workers", "2", "--out", str(out)],
        tmp_path,
    )
    # Killed once the chains hold a random number of steps, not after a random time: on a
    # fast machine the whole run took less than the 0-1 s wait the test had (seen in CI).
    kill_at = random.Random(8).randint(2, 200)
    wait_until_held(out, kill_at, p)
    p.send_signal(signal.SIGKILL)
    _, err = p.communicate(timeout=120)
    assert p.returncode == -signal.SIGKILL, err
    held = [v[4] for v in chains(whole(out)).values()]
    assert min(held) < 900, held  # killed while sampling
    # Resumed on another back-end: the chains of the uninterrupted run, bit for bit.
    assert main(["sample", str(out), "--resume", "--quiet", "--backend", "serial"]) == 0
    got = chains(out / "chain.h5")
    assert got.keys() == ref.keys()
    for name in ref:
        (c, lp, acc, rs, it), (c0, lp0, acc0, rs0, it0) = got[name], ref[name]
        assert (c, lp, rs, it) == (c0, lp0, rs0, it0), name
        # The acceptance counts may count the step being written at the kill twice: emcee's
        # HDF5 checkpoint adds to them and advances the step number separately, and a kill
        # while the file is flushed can keep the one without the other (seen once in CI on
        # 3.13: 3 walkers +1). Known, documented in docs/sampling.md; at most one step.
        extra = np.frombuffer(acc, float) - np.frombuffer(acc0, float)
        assert np.all((extra == 0) | (extra == 1)), (name, extra)


def wait_until_held(out: Path, steps: int, p: subprocess.Popen) -> None:
    """Wait until the run writing ``out`` holds at least ``steps`` steps (all ensembles)."""
    while sampling.steps_held(out / "chain.h5") < steps:
        assert p.poll() is None, "the run ended before the kill was due"
        time.sleep(0.01)
    assert p.poll() is None, "the run ended before the kill was due"


def whole(out: Path) -> Path:
    """chain.h5, or the copy beside it when a kill damaged chain.h5 (HDF5 is not
    crash-consistent; --resume then restores the copy)."""
    chain = out / "chain.h5"
    try:
        chains(chain)
        return chain
    except Exception:  # noqa: BLE001 - h5py raises OSError, KeyError, ValueError...
        return out / sampling.Snapshot.NAME


@pytest.mark.slow
@pytest.mark.every_python
@pytest.mark.parametrize("damage", ["overwritten", "truncated"])
def test_a_checkpoint_damaged_by_a_kill_is_restored_from_its_copy_and_resumes_exactly(
    fitted, tmp_path, damage, capsys
):
    """HDF5 is not crash-consistent: a SIGKILL while it flushes can leave chain.h5
    unreadable (seen in CI). A whole copy taken between steps is put back by --resume;
    the run then ends with the chains of an uninterrupted run, bit for bit, and the damaged
    file is kept. Also checked: a run that ends normally leaves no copy behind."""
    # 900 steps: with 300, in one full-suite run on a fast machine, the copy was gone here,
    # most likely because the run had finished (and removed it) during the read of
    # chain.h5 that saw 30 steps held (a read waits for the writer).
    ref = reference(fitted, tmp_path, steps=900, ensembles=2, seed=7)
    assert not (tmp_path / "ref" / sampling.Snapshot.NAME).exists()
    out = tmp_path / "S"
    p = cli(
        [
            "sample",
            str(fitted),
            "--walkers",
            "10",
            "--steps",
            "900",
            "--ensembles",
            "2",
            "--seed",
            "7",
            "--max-draws",
            "5",
            "--quiet",
            "--out",
            str(out),
        ],
        tmp_path,
    )
    copy = out / sampling.Snapshot.NAME
    while not copy.exists():  # the first step is saved and copied
        assert p.poll() is None, "the run ended before the kill was due"
        time.sleep(0.01)
    wait_until_held(out, 30, p)
    assert copy.exists()
    p.send_signal(signal.SIGKILL)
    _, err = p.communicate(timeout=120)
    assert p.returncode == -signal.SIGKILL, err
    chain = out / "chain.h5"
    b = bytearray(chain.read_bytes())
    if damage == "overwritten":  # what a cut-short metadata flush looks like to a reader
        b[:4096] = random.Random(2).randbytes(4096)
    else:
        b = b[: len(b) // 2]
    chain.write_bytes(bytes(b))
    assert main(["sample", str(out), "--resume", "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "Restored the copy kept beside it" in err and "chain.h5.damaged" in err, err
    assert (out / "chain.h5.damaged").read_bytes() == bytes(b)  # kept, untouched
    assert chains(chain) == ref
    assert not copy.exists()  # finished: chain.h5 is whole, the copy is gone
    # With no copy to fall back on, a damaged file is refused as before.
    chain.write_bytes(bytes(b))
    assert main(["sample", str(out), "--resume", "--quiet", "--steps", "910"]) == 2
    assert "damaged" in capsys.readouterr().err


def test_a_stop_request_ends_between_segments_and_says_where_each_ensemble_is(
    fitted, tmp_path, monkeypatch
):
    ref, _ = run(fitted, tmp_path / "ref", None, monkeypatch)
    # Stop once both ensembles have saved steps (not after a count of asks: on a fast
    # machine one ensemble's segments came back six times before the other's first).
    saved = set()
    save = sampling.run._save

    def saving(store, name, chunk):
        save(store, name, chunk)
        saved.add(name)

    monkeypatch.setattr(sampling.run, "_save", saving)

    def stop() -> bool:
        return len(saved) == 2

    with parallel.open_executor(parallel.ExecutorSpec("threads", 2)) as ex:
        with pytest.raises(sampling.SamplingStopped) as info:
            run(fitted, tmp_path / "S", ex, monkeypatch, should_stop=stop)
    held = chains(tmp_path / "S" / "chain.h5")
    n0, n1 = held["ensemble0"][4], held["ensemble1"][4]
    assert 0 < n0 < 20 and 0 < n1 < 20
    assert str(info.value) == (
        f"ensemble0 stopped after step {n0} of 20, ensemble1 after step {n1}"
    )
    got, _ = run(fitted, tmp_path / "S", parallel.SerialExecutor(), monkeypatch)
    assert got == ref


# A program reading chain.h5 while it is written (emcee's HDFBackend in a notebook, h5py)
# holds HDF5's file lock; a write then fails at once unless it waits.
HOLD = """import sys, time, h5py
while True:
    try:
        f = h5py.File(sys.argv[1], "r")
        break
    except OSError:
        time.sleep(0.005)
print("open", flush=True)
time.sleep(float(sys.argv[2]))
"""


def hold_open(path: Path, seconds: float) -> subprocess.Popen:
    p = subprocess.Popen(
        [sys.executable, "-c", HOLD, str(path), str(seconds)], stdout=subprocess.PIPE, text=True
    )
    assert p.stdout.readline().strip() == "open"
    return p


@pytest.mark.slow
@pytest.mark.every_python
def test_a_reader_of_the_checkpoint_delays_sampling_and_changes_nothing(fitted, tmp_path):
    ref = reference(fitted, tmp_path, steps=150, ensembles=1, seed=4)
    out = tmp_path / "S"
    p = cli(
        [
            "sample",
            str(fitted),
            "--walkers",
            "10",
            "--steps",
            "150",
            "--ensembles",
            "1",
            "--seed",
            "4",
            "--max-draws",
            "5",
            "--quiet",
            "--out",
            str(out),
        ],
        tmp_path,
    )
    while not sampling.steps_held(out / "chain.h5") and p.poll() is None:
        time.sleep(0.02)
    readers = []
    for _ in range(3):  # three readers, each holding the lock for a while mid-run
        readers.append(hold_open(out / "chain.h5", 0.7))
        readers[-1].wait(timeout=60)
    _, err = p.communicate(timeout=300)
    assert p.returncode == 0, err
    held = chains(out / "chain.h5")
    assert held == ref  # the same chains, step for step, as a run nobody looked at


def test_a_reader_that_keeps_the_checkpoint_open_stops_sampling_cleanly(
    fitted, tmp_path, monkeypatch, capsys
):
    out = tmp_path / "S"
    args = ["--walkers", "10", "--ensembles", "1", "--seed", "4", "--max-draws", "5", "--quiet"]
    assert main(["sample", str(fitted), *args, "--steps", "20", "--out", str(out)]) == 0
    before = chains(out / "chain.h5")
    monkeypatch.setattr(sampling.locks, "LOCK_WAIT", 0.5)
    reader = hold_open(out / "chain.h5", 60)
    try:
        capsys.readouterr()
        code = main(["sample", str(out), "--resume", "--steps", "40", "--quiet"])
        err = capsys.readouterr().err
    finally:
        reader.kill()
        reader.wait()
    assert code == 4, err
    assert "held the file open" in err and "--resume" in err and "Traceback" not in err
    assert chains(out / "chain.h5") == before  # nothing written, nothing damaged
    # Once it is closed, --resume goes on: the chains of a 40-step run nobody looked at.
    assert main(["sample", str(out), "--resume", "--steps", "40", "--quiet"]) == 0
    assert (
        main(["sample", str(fitted), *args, "--steps", "40", "--out", str(tmp_path / "ref")]) == 0
    )
    assert chains(out / "chain.h5") == chains(tmp_path / "ref" / "chain.h5")


@pytest.mark.slow
@pytest.mark.every_python
def test_a_lost_scheduler_stops_sampling_cleanly_and_resume_finishes_the_chains(fitted, tmp_path):
    """A real `dask scheduler` and worker; the scheduler is killed while the ensembles run
    on it: exit code 3 with one message, every finished step kept, and --resume on this
    machine ends with the chains of an uninterrupted run."""
    from test_parallel import real_cluster

    args = [
        "--walkers",
        "10",
        "--steps",
        "300",
        "--ensembles",
        "2",
        "--seed",
        "6",
        "--max-draws",
        "5",
        "--quiet",
    ]
    ref = reference(fitted, tmp_path, steps=300, ensembles=2, seed=6)
    out = tmp_path / "S"
    with real_cluster(tmp_path) as (address, sched, procs):
        p = cli(["sample", str(fitted), *args, "--scheduler", address, "--out", str(out)], tmp_path)
        procs.append(p)
        deadline = time.time() + 180
        while not sampling.steps_held(out / "chain.h5") and p.poll() is None:
            assert time.time() < deadline
            time.sleep(0.05)
        sched.kill()
        _, err = p.communicate(timeout=120)
    assert p.returncode == 3, err
    assert "lost the Dask scheduler" in err and "--resume" in err, err
    assert "Traceback" not in err
    held = [v[4] for v in chains(out / "chain.h5").values()]
    assert 0 < sum(held) < 600, held  # stopped while sampling
    assert main(["sample", str(out), "--resume", "--quiet"]) == 0
    got = chains(out / "chain.h5")
    assert got.keys() == ref.keys()
    for name in ref:
        (c, lp, _, rs, it), (c0, lp0, _, rs0, it0) = got[name], ref[name]
        assert (c, lp, rs, it) == (c0, lp0, rs0, it0), name

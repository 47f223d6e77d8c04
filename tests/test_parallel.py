"""The executor layer: one contract (concurrent.futures.Executor), four back-ends, the same
results on each, bit for bit; a worker killed mid-job changes nothing; a lost or absent
scheduler ends the command with exit code 3 and a plain message.

The Dask tests run a real ``LocalCluster`` of two worker processes (and, for the lost
scheduler, real ``dask scheduler`` / ``dask worker`` processes) on a small problem: the upper
configuration, 5 s at 200 Hz.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import rotorbayes as rb
from rotorbayes import inference
from rotorbayes.inference import identify, parallel
from rotorbayes.inference.multistart import _fit_start
from rotorbayes.util import exitcodes as EXIT

distributed = pytest.importorskip("distributed")


def small_problem() -> inference.Problem:
    ex = rb.load_example("upper_est")
    n = int(round(5.0 / ex.dt)) + 1
    assert abs(ex.dt - 0.005) < 1e-12  # 200 Hz
    short = rb.Experiment(
        t=ex.t[:n], u=ex.u[:n], theta_u=ex.theta_u[:n], theta_l=None, name="upper 5 s", path=ex.path
    )
    return inference.Problem("upper", [short])


def same_fits(a: list, b: list) -> None:
    """Every fit identical to the last bit: end point, SSR, Jacobian, evaluations."""
    assert len(a) == len(b)
    for fa, fb in zip(a, b, strict=True):
        assert (fa is None) == (fb is None)
        if fa is None:
            continue
        assert fa.x.tobytes() == fb.x.tobytes()
        assert np.float64(fa.ssr).tobytes() == np.float64(fb.ssr).tobytes()
        assert fa.jac.tobytes() == fb.jac.tobytes()
        assert (fa.nfev, fa.njev, fa.success) == (fb.nfev, fb.njev, fb.success)


# --------------------------------------------------------------------------- choosing


def test_choose_option_then_environment_then_file_then_default():
    env = {parallel.SCHEDULER_ENV: "tcp://env:8786"}
    f = {"scheduler": "tcp://file:8786"}
    assert parallel.choose(scheduler="tcp://opt:1", environ=env, file=f).scheduler == "tcp://opt:1"
    s = parallel.choose(environ=env, file=f)
    assert (s.backend, s.scheduler, s.source) == ("dask", "tcp://env:8786", parallel.SCHEDULER_ENV)
    s = parallel.choose(environ={}, file=f)
    assert (s.backend, s.scheduler) == ("dask", "tcp://file:8786")
    # An explicit local back-end wins over the variable (the user said so on this command).
    assert parallel.choose("serial", environ=env).backend == "serial"
    # dask without an address: a LocalCluster of --workers processes.
    s = parallel.choose("dask", 3, environ={})
    assert (s.backend, s.scheduler, s.n_workers()) == ("dask", None, 3)
    assert "local Dask cluster of 3" in s.describe()
    s = parallel.choose(environ={}, file={"backend": "processes", "workers": 2})
    assert (s.backend, s.n_workers()) == ("processes", 2)
    assert parallel.choose(environ={}).backend == parallel.DEFAULT_BACKEND
    with pytest.raises(ValueError, match="unknown parallel back-end 'gpu'"):
        parallel.choose("gpu", environ={})


def test_analysis_file_refuses_an_unknown_backend(tmp_path):
    from rotorbayes.commands.study.analysis import AnalysisError, load_analysis

    f = tmp_path / "a.toml"
    f.write_text(
        '[analysis]\nout = "o"\nconfig = "upper"\ndata = ["example:upper_est"]\n'
        '[parallel]\nbackend = "gpu"\n'
    )
    with pytest.raises(AnalysisError, match=r"\[parallel\] backend 'gpu'; choose one of"):
        load_analysis(f)


def test_serial_threads_and_processes_agree_bit_for_bit():
    prob = small_problem()
    runs = {}
    for backend in ("serial", "threads", "processes"):
        with parallel.open_executor(parallel.ExecutorSpec(backend, 2)) as ex:
            runs[backend] = inference.multistart(prob, 4, seed=3, progress=False, executor=ex)
    for backend in ("threads", "processes"):
        same_fits(runs["serial"].fits, runs[backend].fits)
        assert np.array_equal(runs["serial"].clusters, runs[backend].clusters)
    # The fits are the problem's own again (not a worker's copy).
    assert all(f.problem is prob for f in runs["processes"].fits)


# --------------------------------------------------------------------------- Dask


@pytest.fixture(scope="module")
def cluster():
    """A real LocalCluster: two worker processes, one thread each, kernel warmed."""
    spec = parallel.ExecutorSpec("dask", 2)
    with parallel.open_executor(spec) as ex:
        yield ex


def test_dask_cluster_gives_the_serial_results_bit_for_bit(cluster):
    prob = small_problem()
    client = cluster._client
    info = client.run(
        lambda: (
            os.environ.get("NUMBA_NUM_THREADS"),
            os.environ.get("OPENBLAS_NUM_THREADS"),
            __import__("numba").get_num_threads(),
        )
    )
    # One BLAS thread; numba one thread outside a task's kernel batches (its threads per
    # core kept for the batches: NUMBA_NUM_THREADS not limited by the cluster).
    assert len(info) == 2 and all(v[0] != "1" and v[1:] == ("1", 1) for v in info.values())
    plugins = client.run(lambda dask_worker: list(dask_worker.plugins))
    assert all(parallel._WarmUp.name in v for v in plugins.values())

    t0 = time.perf_counter()
    ms = inference.multistart(prob, 4, seed=1, progress=False, executor=cluster)
    took = time.perf_counter() - t0
    ref = inference.multistart(prob, 4, seed=1, progress=False, executor=parallel.SerialExecutor())
    same_fits(ref.fits, ms.fits)
    assert np.array_equal(ref.starts, ms.starts) and ms.ssr.size == 4
    assert took < 60

    # Profile-likelihood points: the same Δχ² on the cluster as serially.
    best = ref.best
    pa = identify.profile(prob, best.x, "k_m", n_points=5, span=0.02, executor=cluster)
    pb = identify.profile(
        prob, best.x, "k_m", n_points=5, span=0.02, executor=parallel.SerialExecutor()
    )
    assert np.array(pa["delta_chi2"]).tobytes() == np.array(pb["delta_chi2"]).tobytes()
    assert np.nanmax(pa["delta_chi2"]) > 0


def test_shared_data_is_scattered_once_not_sent_with_every_task(cluster):
    prob = small_problem()
    client = cluster._client
    starts = inference.latin_hypercube(prob, 6, np.random.default_rng(0))

    def deps(dask_scheduler):
        return {
            str(k): (
                [str(d.key) for d in ts.dependencies],
                [str(d.key) for d in ts.dependencies for _ in d.who_has],
            )
            for k, ts in dask_scheduler.tasks.items()
            if "_fit_start" in str(k)
        }

    scattered = []
    scatter = parallel._scatter

    def _scatter(ex, obj):  # who holds the data the moment it is scattered
        fut = scatter(ex, obj)
        scattered.append((str(fut.key), client.who_has([fut])[fut.key]))
        return fut

    seen = None
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(parallel, "_scatter", _scatter)
        for _i, (r, _why) in parallel.run_tasks(
            _fit_start, list(starts), shared=(prob, {"uncertainty": False}), executor=cluster
        ):
            assert r is not None
            if seen is None:
                seen = client.run_on_scheduler(deps)
    assert len(seen) >= 1
    # Every task depends on the one scattered problem, and nothing else ...
    shared = {d for ds, _ in seen.values() for d in ds}
    assert len(shared) == 1 and all(len(ds) == 1 for ds, _ in seen.values())
    # ... which both workers held before the first task ran (read later, Dask's active
    # memory manager may have dropped a replica no waiting task needed: seen in CI).
    assert len(scattered) == 1 and scattered[0][0] in shared
    assert len(scattered[0][1]) == 2


def test_a_worker_killed_mid_job_changes_nothing(cluster):
    """SIGKILL a worker process while it runs a fit: the scheduler reruns its tasks on the
    other worker (the nanny brings a new one up) and every result is the serial one."""
    prob = small_problem()
    client = cluster._client
    starts = inference.latin_hypercube(prob, 16, np.random.default_rng(7))
    shared = (prob, {"uncertainty": False, "max_nfev": 200})
    ref = parallel.map_ordered(
        _fit_start, list(starts), shared=shared, executor=parallel.SerialExecutor()
    )

    pids = client.run(os.getpid)
    got: dict[int, tuple] = {}
    killed = {}
    for i, r in parallel.run_tasks(_fit_start, list(starts), shared=shared, executor=cluster):
        got[i] = r
        if not killed:
            # At the first result that finds a worker busy (on a fast machine the first
            # result once came when the scheduler showed none: CI on 3.13).
            busy = {w: ks for w, ks in client.processing().items() if ks and w in pids}
            if busy:
                w = next(iter(busy))
                killed = {"worker": w, "pid": pids[w], "tasks": len(busy[w])}
                os.kill(pids[w], signal.SIGKILL)
    assert killed, "no task was running at any result: the test proves nothing"
    assert len(got) == 16
    same_fits([r for r, _ in ref], [got[i][0] for i in range(16)])
    # The killed process is gone; the nanny started another in its place.
    deadline = time.time() + 60
    while time.time() < deadline:
        now = client.run(os.getpid)
        if len(now) == 2 and killed["pid"] not in now.values():
            break
        time.sleep(0.5)
    assert killed["pid"] not in client.run(os.getpid).values()


# --------------------------------------------------------------------------- the command


def _cli(args, env=None, **kw):
    return subprocess.Popen(
        [sys.executable, "-m", "rotorbayes.cli", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "NUMBA_NUM_THREADS": "1", **(env or {})},
        **kw,
    )


def test_no_scheduler_at_the_address_is_a_plain_error(tmp_path):
    t0 = time.perf_counter()
    p = _cli(
        [
            "multistart",
            "--model",
            "upper",
            "example:upper_est",
            "--starts",
            "2",
            "--scheduler",
            "tcp://127.0.0.1:9",
            "--out",
            str(tmp_path / "ms"),
        ],
        env={parallel.TIMEOUT_ENV: "2"},
    )
    out, err = p.communicate(timeout=120)
    took = time.perf_counter() - t0
    assert p.returncode == EXIT.ENVIRONMENT, (out, err)
    assert "no Dask scheduler answered at tcp://127.0.0.1:9 (from --scheduler)" in err
    # The variable's wait, not the default 15 s (the rest is the interpreter's start).
    assert "within 2 s" in err and took < 14, (took, err)
    assert "dask scheduler" in err and "Traceback" not in err
    assert not (tmp_path / "ms").exists()


@contextlib.contextmanager
def real_cluster(folder: Path, workers: int = 1):
    """A real `dask scheduler` and ``workers`` `dask worker` processes (0: none), as a user
    starts them; yields ``(address, scheduler process, processes to stop)``."""
    sched_file = folder / "scheduler.json"
    env = {**os.environ, **parallel.WORKER_ENV}
    dask_cli = [sys.executable, "-m", "distributed.cli.dask_scheduler"]
    sched = subprocess.Popen(
        [*dask_cli, "--scheduler-file", str(sched_file), "--port", "0", "--no-dashboard"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env=env,
    )
    procs = [sched]
    try:
        deadline = time.time() + 60
        while not sched_file.exists() and time.time() < deadline:
            time.sleep(0.2)
        import json

        address = json.loads(sched_file.read_text())["address"]
        if workers:
            procs.append(
                subprocess.Popen(
                    [
                        sys.executable,
                        "-m",
                        "distributed.cli.dask_worker",
                        address,
                        "--nworkers",
                        str(workers),
                        "--nthreads",
                        "1",
                        "--no-dashboard",
                    ],
                    stdout=subprocess.DEVNULL,
                    stderr=subprocess.DEVNULL,
                    env=env,
                )
            )
        yield address, sched, procs
    finally:
        for q in procs:
            if q.poll() is None:
                q.kill()
                q.wait(timeout=30)


@pytest.mark.parametrize(
    "address", ["127.0.0.1:8786x", "http://127.0.0.1:8786", "tcp://127.0.0.1:87860"]
)
def test_a_malformed_scheduler_address_is_refused_at_once(tmp_path, address, capsys):
    from rotorbayes.cli import main

    t0 = time.time()
    assert (
        main(
            [
                "multistart",
                "--model",
                "upper",
                "example:upper_est",
                "--starts",
                "2",
                "--scheduler",
                address,
                "--out",
                str(tmp_path / "ms"),
            ]
        )
        == EXIT.REFUSED
    )
    out, err = capsys.readouterr()
    assert f"{address!r} (from --scheduler) is not a Dask scheduler address" in err
    assert "tcp://HOST:PORT" in err and "Traceback" not in err and "Exception" not in err
    assert "parallel tasks run" not in out  # nothing said about a cluster never reached
    assert time.time() - t0 < 10 and not (tmp_path / "ms").exists()


def test_a_scheduler_without_workers_is_a_clear_error_not_a_hang(tmp_path):
    """Workers end when their scheduler is lost; a user who restarts only the scheduler has
    one without workers: the command says so (exit 3) instead of waiting forever. (The
    check is made where every command connects; `run` of several files used to hang.)"""
    a = tmp_path / "a.toml"
    a.write_text('[analysis]\nout = "A"\nconfig = "upper"\ndata = ["example:upper_est"]\n')
    b = tmp_path / "b.toml"
    b.write_text('[analysis]\nout = "B"\nconfig = "upper"\ndata = ["example:upper_val"]\n')
    with real_cluster(tmp_path, workers=0) as (address, _, procs):
        p = _cli(
            ["run", str(a), str(b), "--scheduler", address],
            cwd=tmp_path,
            env={parallel.TIMEOUT_ENV: "3"},
        )
        procs.append(p)
        out, err = p.communicate(timeout=180)
        assert p.returncode == EXIT.ENVIRONMENT, (out, err)
        assert f"the Dask scheduler at {address} (from --scheduler) has no workers" in err
        assert "Traceback" not in err
    assert not any((tmp_path / n).exists() for n in ("A", "B"))


@pytest.mark.parametrize("value", ["abc", "0", "-5", "nan", "inf"])
def test_a_bad_dask_timeout_is_refused_with_its_name(monkeypatch, value):
    monkeypatch.setenv(parallel.TIMEOUT_ENV, value)
    with pytest.raises(
        parallel.ClusterError, match=f"{parallel.TIMEOUT_ENV}='{value}' is not a number"
    ):
        parallel.connect_timeout()
    monkeypatch.setenv(parallel.TIMEOUT_ENV, " 7.5 ")
    assert parallel.connect_timeout() == 7.5
    monkeypatch.delenv(parallel.TIMEOUT_ENV)
    assert parallel.connect_timeout() == parallel.CONNECT_TIMEOUT


@pytest.mark.slow
@pytest.mark.every_python
def test_lost_scheduler_ends_the_command_with_exit_code_3(tmp_path):
    """A real `dask scheduler` and `dask worker`; the scheduler is killed mid-job."""
    with real_cluster(tmp_path) as (address, sched, procs):
        # Through the variable, as a user on a cluster would set it.
        p = _cli(
            [
                "multistart",
                "--model",
                "upper",
                "example:upper_est",
                "--starts",
                "400",
                "--max-nfev",
                "30",
                "--out",
                str(tmp_path / "ms"),
            ],
            env={parallel.SCHEDULER_ENV: address},
        )
        procs.append(p)
        lines = []

        def read():
            for line in p.stdout:
                lines.append(line)

        reader = threading.Thread(target=read, daemon=True)
        reader.start()
        deadline = time.time() + 120
        while not any("done" in s for s in lines) and time.time() < deadline:
            time.sleep(0.2)
        assert any("on the Dask scheduler at" in s and parallel.SCHEDULER_ENV in s for s in lines)
        assert any("start   1/400 done" in s for s in lines), "".join(lines)
        sched.kill()
        err = p.stderr.read()
        p.wait(timeout=120)
        assert p.returncode == EXIT.ENVIRONMENT, err
        assert "lost the Dask scheduler" in err and "Traceback" not in err, err
        assert not (tmp_path / "ms").exists()


@pytest.mark.slow
@pytest.mark.every_python
def test_multistart_command_on_a_local_dask_cluster(tmp_path):
    out = tmp_path / "ms"
    p = _cli(
        [
            "multistart",
            "--model",
            "upper",
            "example:upper_est",
            "--starts",
            "3",
            "--max-nfev",
            "20",
            "--backend",
            "dask",
            "--workers",
            "2",
            "--out",
            str(out),
        ]
    )
    o, e = p.communicate(timeout=300)
    assert p.returncode == 0, e
    assert "parallel tasks run on a local Dask cluster of 2 worker processes" in o
    assert (out / "multistart.json").exists()
    assert Path(out / "summary.txt").read_text()


def test_a_study_stage_without_options_uses_the_study_executor(capsys):
    """`run` opens one executor; each stage's command (parsed without --backend/--workers/
    --scheduler) takes it instead of opening its own; a stage's own option wins."""
    from rotorbayes.commands.common import executor

    with parallel.use_executor(parallel.ExecutorSpec("serial")) as study_ex:
        with executor() as ex:
            assert ex is study_ex
        with executor("threads", 2, None) as ex:
            assert ex is not study_ex and parallel.current_executor() is ex
        assert parallel.current_executor() is study_ex
    assert parallel.current_executor() is None
    with executor(file={"backend": "serial"}) as ex:
        assert isinstance(ex, parallel.SerialExecutor)
    assert "parallel tasks run serially in this process" in capsys.readouterr().out


def test_the_default_back_end_follows_the_cores():
    # Measured (benchmarks/bench_scale.py, issue 34): processes pay from a few cores on.
    import multiprocessing as mp

    assert parallel.default_backend(2) == "threads"
    want = "processes" if "forkserver" in mp.get_all_start_methods() else "threads"
    assert parallel.default_backend(16) == want


def _threads_in_task(_):
    import numba

    outside = numba.get_num_threads()
    parallel.claim_kernel_threads()
    return outside, numba.get_num_threads()


def test_a_lone_task_takes_the_cores_for_its_batches():
    # One task running: its kernel batches get every core; outside them one thread.
    import numba

    with parallel.open_executor(parallel.ExecutorSpec("threads", 2)) as ex:
        outside, inside = ex.submit(_threads_in_task, 0).result()
    assert outside == 1
    assert inside == min(os.cpu_count() or 1, numba.config.NUMBA_NUM_THREADS)


def test_a_lone_task_on_a_dask_worker_takes_the_hosts_cores(cluster):
    """Two one-thread workers on this host: a task running alone gets both cores for its
    kernel batches (the host's share), not its worker's one thread."""
    from rotorbayes.inference.hostshare import usable_cores

    outside, inside = cluster.submit(_threads_in_task, 0).result()
    assert outside == 1
    assert inside == min(2, usable_cores())


def test_host_share_counts_every_workers_tasks(tmp_path):
    """The host's counters, as two workers of one scheduler see them: the threads they
    brought over the tasks running now; the last worker to leave removes the file."""
    import numba

    from rotorbayes.inference.hostshare import HostShare, usable_cores

    path = tmp_path / "cores-x"
    a, b = HostShare(path, 3), HostShare(path, 1)
    cap = min(4, usable_cores(), numba.config.NUMBA_NUM_THREADS)
    a.enter()
    assert a.threads() == b.threads() == cap
    b.enter()
    assert a.threads() == max(1, cap // 2)
    a.leave()
    assert b.threads() == cap
    b.leave()
    a.close()
    assert path.exists()
    b.close()
    assert not path.exists()


def test_host_share_forgets_a_worker_killed_in_a_task(tmp_path):
    """A worker whose process ended in a task (its count never taken back) does not shrink
    the others' share: its slot is dead from the next task on, and reused."""
    import subprocess
    import sys

    import numba

    from rotorbayes.inference.hostshare import HostShare, usable_cores

    if min(usable_cores(), numba.config.NUMBA_NUM_THREADS) < 2:
        pytest.skip("needs two cores to tell the shares apart")
    path = tmp_path / "cores-y"
    code = (
        "import os, sys; from pathlib import Path;"
        "from rotorbayes.inference.hostshare import HostShare;"
        "s = HostShare(Path(sys.argv[1]), 4); s.enter(); os._exit(0)"
    )
    subprocess.run([sys.executable, "-c", code, str(path)], check=True)
    a = HostShare(path, 2)
    a.enter()
    assert a.threads() == 2  # the dead worker's 4 threads and 1 task not counted
    a.leave()
    a.close()
    assert not path.exists()

"""The default back-end picks what pays for the work on the machine, and says which and why;
one BLAS thread in the command's process whatever the import order."""

from __future__ import annotations

import multiprocessing as mp
import os
import subprocess
import sys

import pytest

from rotorbayes.inference import parallel

FORKSERVER = "forkserver" in mp.get_all_start_methods()


def test_the_choice_follows_cores_and_the_size_of_the_work():
    big = parallel.PROCESSES_FROM_RESIDUALS
    assert parallel.default_backend(2) == "threads"  # size not known
    assert parallel.default_backend(2, 64, 1_001) == "threads"  # bench_dask.py's problem
    want = "processes" if FORKSERVER else "threads"
    assert parallel.default_backend(2, 1, big) == want
    assert parallel.default_backend(2, 2, big // 2 - 1) == "threads"
    assert parallel.default_backend(16) == want
    assert parallel.default_backend(16, 1, 10) == want
    why = parallel.default_reason(2, 16, 1_001)
    assert why.startswith("the default on 2 cores for 16 tasks x 1 001 residuals")
    assert "bench_scale.py" in why


class _Sized:
    def __init__(self, n: int):
        self.n_residuals = n


def _pid(shared, item):
    return os.getpid()


def test_a_small_machine_weighs_each_batch_and_says_the_choice_once(monkeypatch):
    monkeypatch.setattr(os, "cpu_count", lambda: 2)
    said: list[str] = []
    spec = parallel.choose(None, 2, None, environ={})
    assert spec.auto and spec.source == "default"
    with parallel.use_executor(spec, say=said.append) as ex:
        assert isinstance(ex, parallel.DefaultPool)
        small = parallel.map_ordered(_pid, range(3), shared=(_Sized(1_001), {}))
        assert set(small) == {os.getpid()}  # threads: this process
        parallel.map_ordered(_pid, range(3), shared=(_Sized(1_001), {}))
        assert said == [
            "parallel tasks run in 2 local threads (" + parallel.default_reason(2, 3, 1_001) + ")"
        ]
        if FORKSERVER:
            large = parallel.map_ordered(
                _pid, range(2), shared=_Sized(parallel.PROCESSES_FROM_RESIDUALS)
            )
            assert os.getpid() not in large  # processes
            assert len(said) == 2 and said[1].startswith(
                "parallel tasks run in 2 local processes (the default on 2 cores for 2 tasks"
            )
    # An explicit choice is taken as it is.
    with parallel.open_executor(parallel.ExecutorSpec("threads", 2)) as ex:
        assert not isinstance(ex, parallel.DefaultPool)


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="one core: one BLAS thread anyway")
def test_one_blas_thread_when_numpy_was_imported_first():
    code = (
        "import numpy, threadpoolctl, rotorbayes; print(sorted({i['num_threads'] for i in "
        "threadpoolctl.threadpool_info() if i['user_api'] == 'blas'}))"
    )
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
    }
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "[1]"
    # A choice of the user's own is kept.
    out = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        env={**env, "OPENBLAS_NUM_THREADS": "2"},
        timeout=300,
    )
    assert out.stdout.strip().splitlines()[-1] == "[2]", out.stderr


def test_a_command_says_the_default_it_took_and_why(tmp_path, capsys):
    from rotorbayes.cli import main

    out = tmp_path / "ms"
    assert main(
        [
            "multistart",
            "--model",
            "upper",
            "example:upper_est",
            "--starts",
            "2",
            "--max-nfev",
            "3",
            "--out",
            str(out),
        ]
    ) in (0, 1)
    said = [
        ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("parallel tasks run")
    ]
    assert len(said) == 1, said
    cores = os.cpu_count() or 1
    assert f"(the default on {cores} core" in said[0] and "bench_scale.py" in said[0]
    if cores < parallel.PROCESSES_FROM_CORES:
        assert " for 2 tasks x " in said[0]  # weighed by the work


@pytest.mark.parametrize(
    "cores, ensembles, pool",
    [(16, 4, FORKSERVER), (16, 1, False), (4, 2, FORKSERVER), (2, 4, False)],
)
def test_sample_runs_its_ensembles_in_the_default_pool_where_it_pays(
    monkeypatch, cores, ensembles, pool
):
    import contextlib

    from rotorbayes.commands import sample as sample_command
    from rotorbayes.commands.config import ExecutorOptions

    opened = []

    @contextlib.contextmanager
    def fake_open(self, file=None):
        opened.append(self)
        yield "the default pool"

    monkeypatch.setattr(ExecutorOptions, "open", fake_open)
    monkeypatch.setattr(sample_command.os, "cpu_count", lambda: cores)
    monkeypatch.delenv(parallel.SCHEDULER_ENV, raising=False)
    with sample_command._ensemble_executor(ExecutorOptions(), ensembles) as ex:
        assert ex == ("the default pool" if pool else None)
    assert len(opened) == (1 if pool else 0)
    # An option given always opens what it names.
    with sample_command._ensemble_executor(ExecutorOptions(backend="threads"), 1) as ex:
        assert ex == "the default pool"

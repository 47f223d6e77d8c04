"""A cluster users already run: workers that join a scheduler the way dask-jobqueue's jobs do.

dask-jobqueue submits a batch script per job; the script runs ``python -m
distributed.cli.dask_worker ADDRESS --name ... --nthreads ... --memory-limit ... --nanny``.
Here a ``SLURMCluster`` (no SLURM needed: it only writes the script and runs the scheduler)
gives the script of a job of 2 cores and 1 process, and the script itself is run with bash,
as SLURM runs it on a node, in an environment without the thread variables rotorbayes sets
for itself (a fresh shell on a node). rotorbayes then reaches the scheduler by its address.

Checked: the worker's tasks run one numba thread outside their kernel batches and a share of
the worker's threads in them, on one BLAS thread; multistart starts, profile-likelihood
points, ``sample``'s ensembles, SBC data sets and a batch of studies give the serial
back-end's results bit for bit.
"""

from __future__ import annotations

import contextlib
import importlib.util
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from test_parallel import same_fits, small_problem
from test_sample_parallel import fitted, run  # noqa: F401 - fitted is a fixture

from rotorbayes import inference
from rotorbayes.inference import identify, parallel

distributed = pytest.importorskip("distributed")
dask_jobqueue = pytest.importorskip("dask_jobqueue")

#: What a fresh shell on a node does not have: the variables rotorbayes sets when imported.
THREAD_VARS = ("NUMBA_NUM_THREADS", "OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


@pytest.fixture(scope="module")
def jobqueue(tmp_path_factory):
    """The scheduler of a ``SLURMCluster`` and one job of its script run by bash: a worker of
    2 threads; yields the scheduler's address."""
    from dask_jobqueue import SLURMCluster

    folder = tmp_path_factory.mktemp("jobqueue")
    cluster = SLURMCluster(
        cores=2,
        processes=1,
        memory="2GiB",
        walltime="00:10:00",
        scheduler_options={"dashboard_address": None, "host": "127.0.0.1"},
    )
    script = folder / "job.sh"
    script.write_text(cluster.job_script().replace("dummy-name", "job-0"))
    assert "-m distributed.cli.dask_worker" in script.read_text()
    env = {k: v for k, v in os.environ.items() if k not in THREAD_VARS}
    # The worker imports this module's task functions, and analyses/sbc.py's, by name, as
    # a site's workers import rotorbayes: from their path (a shared filesystem).
    here = Path(__file__).resolve().parent
    env["PYTHONPATH"] = os.pathsep.join(
        filter(None, [str(here), str(here.parent / "analyses"), env.get("PYTHONPATH")])
    )
    log = open(folder / "job.log", "w")  # noqa: SIM115 - the job's output, closed below
    job = subprocess.Popen(
        ["bash", str(script)], stdout=log, stderr=subprocess.STDOUT, env=env, start_new_session=True
    )
    try:
        yield cluster.scheduler_address
    finally:
        # The whole job (bash, the nanny, the worker), as a batch system ends one.
        with contextlib.suppress(ProcessLookupError):
            os.killpg(job.pid, signal.SIGKILL)
        job.wait(timeout=30)
        log.close()
        with contextlib.suppress(Exception):
            cluster.close()


@contextlib.contextmanager
def on(address: str):
    """rotorbayes's executor on the scheduler at ``address``, as ``--scheduler`` opens it."""
    spec = parallel.choose(None, None, address)
    old = os.environ.get(parallel.TIMEOUT_ENV)
    os.environ[parallel.TIMEOUT_ENV] = "120"  # the job's worker loads the kernel first
    try:
        with parallel.open_executor(spec) as ex:
            yield ex
    finally:
        if old is None:
            os.environ.pop(parallel.TIMEOUT_ENV)
        else:
            os.environ[parallel.TIMEOUT_ENV] = old


def _threads_in_task(_):
    import numba
    from threadpoolctl import threadpool_info

    outside = numba.get_num_threads()
    parallel.claim_kernel_threads()
    blas = sorted({i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"})
    return outside, numba.get_num_threads(), int(numba.config.NUMBA_NUM_THREADS), blas


def test_a_job_worker_shares_its_threads_and_runs_one_blas_thread(jobqueue):
    with on(jobqueue) as ex:
        info = ex._client.scheduler_info()["workers"]
        assert [w["nthreads"] for w in info.values()] == [2]
        assert [w["name"] for w in info.values()] == ["job-0"]
        outside, inside, numba_max, blas = ex.submit(_threads_in_task, 0).result(timeout=120)
    # One task running on a worker of 2 threads: its kernel batches take both, one thread
    # outside them (numba's own default there is a thread per core of the node).
    assert outside == 1
    assert inside == min(2, numba_max)
    assert blas == [1]


def test_multistart_and_profile_points_as_serially(jobqueue):
    prob = small_problem()
    with on(jobqueue) as ex:
        ms = inference.multistart(prob, 4, seed=2, progress=False, executor=ex)
        ref = inference.multistart(
            prob, 4, seed=2, progress=False, executor=parallel.SerialExecutor()
        )
        same_fits(ref.fits, ms.fits)
        pa = identify.profile(prob, ref.best.x, "k_m", n_points=5, span=0.02, executor=ex)
    pb = identify.profile(
        prob, ref.best.x, "k_m", n_points=5, span=0.02, executor=parallel.SerialExecutor()
    )
    assert np.array(pa["delta_chi2"]).tobytes() == np.array(pb["delta_chi2"]).tobytes()
    assert np.nanmax(pa["delta_chi2"]) > 0


def test_sample_ensembles_as_serially(jobqueue, fitted, tmp_path, monkeypatch):  # noqa: F811
    ref, calls = run(fitted, tmp_path / "ref", None, monkeypatch)
    with on(jobqueue) as ex:
        got, c = run(fitted, tmp_path / "cluster", ex, monkeypatch)
    assert got == ref and c == calls
    assert len(ref) == 2 and all(v[4] == 20 for v in ref.values())


def _sbc():
    """analyses/sbc.py as the module ``sbc``, which the job's worker imports from its path."""
    path = Path(__file__).resolve().parents[1] / "analyses" / "sbc.py"
    spec = importlib.util.spec_from_file_location("sbc", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


def test_sbc_data_sets_as_serially(jobqueue, monkeypatch):
    mod = _sbc()
    monkeypatch.setenv(parallel.TIMEOUT_ENV, "120")
    args = ["--case", "upper", "--datasets", "2", "--walkers", "8", "--steps", "20"]
    a = mod.main([*args, "--backend", "serial"])
    b = mod.main([*args, "--scheduler", jobqueue])
    a.pop("seconds")
    b.pop("seconds")
    assert a == b
    assert len(a["k_m"]["ranks"]) == 2


@pytest.mark.slow
def test_a_batch_of_studies_as_single_runs(jobqueue, tmp_path, monkeypatch, capsys):
    from test_study_batch import analysis, estimates

    from rotorbayes.cli import main

    monkeypatch.setenv(parallel.TIMEOUT_ENV, "120")
    one = tmp_path / "one"
    one.mkdir()
    assert main(["run", str(analysis(one, "a.toml", "A")), "--quiet", "--backend", "serial"]) == 0
    a = analysis(tmp_path, "a.toml", "A")
    b = analysis(tmp_path, "b.toml", "B")
    t0 = time.perf_counter()
    code = main(["run", str(a), str(b), "--scheduler", jobqueue])
    assert code == 0, capsys.readouterr()
    assert time.perf_counter() - t0 < 600
    assert estimates(tmp_path / "A") == estimates(one / "A") == estimates(tmp_path / "B")

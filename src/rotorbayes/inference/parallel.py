"""The one executor layer: every batch of independent tasks goes through here.

Two kinds of parallel work exist in rotorbayes:

* **kernel batches** — many parameter sets of one experiment, run by the compiled kernel in
  numba threads (:meth:`rotorbayes.Simulator.run_batch`); used by Jacobians and by the
  vectorised log-posterior;
* **independent tasks** — whole fits (multistart starts, restarts), profile-likelihood
  points; they go through an executor with the :class:`concurrent.futures.Executor`
  contract (``submit`` returning a future), via :func:`run_tasks`.

Back-ends (:data:`BACKENDS`):

``serial``     one task after the other, in this process (the reference for bit identity);
``threads``    a local thread pool (the kernel releases the GIL; scipy's Python does not);
``processes``  a local process pool (no GIL between tasks);
``dask``       Dask distributed: an existing scheduler (``--scheduler ADDRESS``, the
               ``DASK_SCHEDULER_ADDRESS`` variable, or ``[parallel] scheduler`` in the analysis
               file) or a ``LocalCluster`` of ``--workers N`` processes started by the command.

:func:`choose` is the one place that picks the back-end from the option, the environment
and the analysis file; :func:`open_executor` builds it (and tears it down);
:func:`use_executor` makes it the default of every algorithm for the length of a command.
Algorithms take ``executor=None`` (meaning: the current one) and never know where they run.

Every worker runs its tasks with one BLAS thread and one numba thread outside their kernel
batches, a share of its cores inside them (no oversubscription), and warms the compiled
kernel once before its first task.  Data shared by
all tasks (the problem: experiments, model) are sent once per worker (``shared=``): Dask
scatters them, the local pools pass them by reference (threads) or with each task
(processes).
"""

from __future__ import annotations

import contextlib
import contextvars
import math
import os
import re
import threading
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import (
    FIRST_COMPLETED,
    CancelledError,
    Executor,
    Future,
    ProcessPoolExecutor,
    ThreadPoolExecutor,
)
from concurrent.futures import wait as _wait
from dataclasses import dataclass
from typing import Any

from ..util.exitcodes import EnvironmentFailure

#: The back-ends :func:`choose` knows.
BACKENDS = ("serial", "threads", "processes", "dask")

#: From this many cores on, local processes are the default for any work: a 48-start brake
#: multistart on 16 cores took 7.9 s in processes against 20.8 s in threads, whose fits hold
#: the GIL in scipy's optimiser (``benchmarks/bench_scale.py``, benchmarks/README.md).
PROCESSES_FROM_CORES = 4

#: Below :data:`PROCESSES_FROM_CORES` cores, local processes are the default for a batch of
#: tasks that simulate at least this many residuals in all per evaluation (tasks x residuals
#: of each task's problem), threads for less: the fork server's start (2 s on an idle
#: machine, 6 s loaded) is won back only by long work.  Measured on 2 loaded cores with
#: ``benchmarks/bench_scale.py`` (benchmarks/README.md), brake multistarts at 1 kHz:
#: 16 starts of 10 s (16 x 20 002 = 320 000 residuals) threads 5.6 s against processes
#: 7.3 s, and 6.7 s against 9.6 s in a second run; 16 starts of 30 s (960 000) once
#: processes 19.1 s against threads 23.2 s, once threads 18.1 s against processes 25.2 s;
#: 48 starts of 30 s (2 880 000) processes 73.2 s against threads 77.5 s.
PROCESSES_FROM_RESIDUALS = 1_000_000


def default_backend(
    cores: int | None = None, tasks: int | None = None, residuals: int | None = None
) -> str:
    """The local back-end that pays for ``tasks`` tasks of ``residuals`` residuals each on a
    machine of ``cores`` cores (:func:`default_reason` says why): processes forked from a
    fork server from :data:`PROCESSES_FROM_CORES` cores on, or on fewer for work of
    :data:`PROCESSES_FROM_RESIDUALS` residuals or more; threads otherwise (and where the
    size of the work is not known)."""
    return _default_choice(cores, tasks, residuals)[0]


def default_reason(
    cores: int | None = None, tasks: int | None = None, residuals: int | None = None
) -> str:
    """Why :func:`default_backend` picks what it picks, in words for the command's output."""
    return _default_choice(cores, tasks, residuals)[1]


def _default_choice(cores, tasks, residuals) -> tuple[str, str]:
    import multiprocessing as mp

    cores = (os.cpu_count() or 1) if cores is None else cores
    where = f"the default on {cores} core{'s' if cores != 1 else ''}"
    bench = "measured with benchmarks/bench_scale.py"
    if "forkserver" not in mp.get_all_start_methods():
        return "threads", f"{where}: no fork server on this platform"
    if cores >= PROCESSES_FROM_CORES:
        return "processes", (
            f"{where}: processes are the fastest from {PROCESSES_FROM_CORES} cores on, {bench}"
        )
    limit = f"{PROCESSES_FROM_RESIDUALS:,}".replace(",", " ")
    if not tasks or not residuals:
        return "threads", f"{where} where the work's size is not known"
    work = f"{tasks} task{'s' if tasks != 1 else ''} x {residuals:,} residuals".replace(",", " ")
    if tasks * residuals >= PROCESSES_FROM_RESIDUALS:
        return "processes", (
            f"{where} for {work}: processes win back their start from "
            f"{limit} residuals in all, {bench}"
        )
    return "threads", (
        f"{where} for {work}: processes win back their start only from "
        f"{limit} residuals in all, {bench}"
    )


#: The default back-end of a command (no option, no variable, no analysis-file entry) for
#: work of unknown size; :class:`DefaultPool` picks per batch on a small machine.
DEFAULT_BACKEND = default_backend()

#: The environment variable Dask itself reads for the scheduler's address.
SCHEDULER_ENV = "DASK_SCHEDULER_ADDRESS"

#: Seconds to wait for a scheduler to answer, and for its first worker, before giving up;
#: the variable :data:`TIMEOUT_ENV` sets another (a slow cluster queue, or tests).
CONNECT_TIMEOUT = 15.0
TIMEOUT_ENV = "ROTORBAYES_DASK_TIMEOUT"

#: Seconds past the wait after which a Client that has not registered is given up (a peer
#: that passed :func:`probe_scheduler` but never answers the client).
CLIENT_GRACE = 10.0

#: Thread counts every worker runs with: one BLAS thread (the same rounding everywhere);
#: numba keeps its thread per core, of which a task runs one outside its kernel batches and
#: its share of the host's cores inside them (:func:`claim_kernel_threads`).
WORKER_ENV = {
    "OPENBLAS_NUM_THREADS": "1",
    "OMP_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
}


class ClusterError(EnvironmentFailure):
    """The Dask scheduler could not be reached, or was lost during the job (exit code 3:
    the environment failed, not the input).

    ``done`` is the number of tasks that had finished (their results were yielded)."""

    def __init__(self, message: str, done: int = 0):
        super().__init__(message)
        self.done = done


# --------------------------------------------------------------------------- back-ends


class SerialExecutor(Executor):
    """``submit`` runs the task at once in this process and returns a finished future."""

    def submit(self, fn, /, *args, **kwargs) -> Future:
        f: Future = Future()
        try:
            f.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # noqa: BLE001 - handed to the future like a pool would
            if isinstance(exc, KeyboardInterrupt):
                raise
            f.set_exception(exc)
        return f


def prepare_worker() -> None:
    """Make this process a good worker: one numba thread, the kernel loaded (compiled or
    read from numba's cache) once, before the first task, not inside a timed one."""
    import sys

    for k, v in WORKER_ENV.items():
        # numba re-reads NUMBA_NUM_THREADS at every compilation and refuses a value that
        # differs from the one its threads were launched with: once numba is loaded (a
        # process-pool worker imports it while unpickling this function), leave the
        # variable alone and limit the threads with set_num_threads below.
        if k == "NUMBA_NUM_THREADS" and "numba" in sys.modules:
            continue
        os.environ.setdefault(k, v)
    import numba

    # A Dask worker may import numba before the cluster's environment (WORKER_ENV) is set:
    # numba's configuration then holds another thread count than the variable, and every
    # later compilation (unpickling a compiled function, e.g. a model's effect hooks inside
    # scattered data) would refuse it. Agree with the variable while numba's threads are
    # not launched; once they are, the variable follows their count.
    want = os.environ.get("NUMBA_NUM_THREADS")
    if want is not None and want != str(numba.config.NUMBA_NUM_THREADS):
        try:
            numba.config.reload_config()
        except RuntimeError:
            os.environ["NUMBA_NUM_THREADS"] = str(numba.config.NUMBA_NUM_THREADS)
    try:
        numba.set_num_threads(1)
    except ValueError:  # pragma: no cover - numba already limited below 1 cannot happen
        pass
    one_blas_thread()
    warm_kernel()


def one_blas_thread() -> None:
    """Limit the BLAS libraries this process has loaded to one thread.  The variables of
    :data:`WORKER_ENV` only act on a library loaded after them; a Dask worker (and a script
    that imported NumPy before rotorbayes) has OpenBLAS loaded already, with a thread per
    core, and an SVD on several BLAS threads rounds otherwise than on one: the end points
    would then depend on where a fit ran."""
    with contextlib.suppress(ImportError):
        from threadpoolctl import threadpool_limits

        threadpool_limits(limits=1, user_api="blas")


def warm_kernel(parallel_entries: bool = True) -> None:
    """Run the kernel once per configuration on a tiny input (loads numba's cache).
    ``parallel_entries=False`` (a process pool's fork server) loads the serial entry
    points alone: loading a parallel one launches numba's threads, which must not exist in
    a process that forks (GNU OpenMP does not survive a fork); each worker loads them after
    its fork, from the cache, on its first batch."""
    import numpy as np

    from ..model.simulate import simulate

    u = np.linspace(0.0, 1.0, 21)
    for config, pset in (
        ("upper", "thesis:4.1:P_ref"),
        ("coupled", "thesis:4.2:P_ref"),
        ("brake", "thesis:4.3:P_ref"),
    ):
        with contextlib.suppress(Exception):  # a missing table entry must not stop a worker
            simulate(pset, u, dt=0.005, config=config)
    # Entry points are compiled (or loaded) on first use: load the residuals' too, which
    # a worker's fits call, so that no task pays for it.
    from ..util.coldstart import kernel_entry

    names = ["residuals_into_plain"] + (["residuals_batch_into_plain"] if parallel_entries else [])
    for name in names:
        with contextlib.suppress(Exception):
            kernel_entry(name, parallel=parallel_entries)


def _process_initializer(active=None, cap: int = 1) -> None:
    global _POOL_SHARE
    _ignore_ctrl_c()
    prepare_worker()
    if active is not None:
        _POOL_SHARE = _Share(cap, active)


# --------------------------------------------------------------------------- thread shares
#
# A local pool's tasks (whole fits) each run on one numba thread while the pool is full.
# When fewer tasks than cores are left (the tail of a multistart: its slowest starts), the
# cores of the finished ones are idle: every task's kernel batch (its Jacobian's columns)
# then takes a share of the cores, cores // (tasks running), read again before each batch.
# The thread count changes no number: every row of a batch is simulated alone.


class _Share:
    """How many tasks of one local pool run now, and how many cores they share."""

    def __init__(self, cap: int, active=None):
        self.cap = max(1, int(cap))
        self._value = active  # a multiprocessing Value (process pool) or None (threads)
        self._lock = threading.Lock()
        self._n = 0

    def enter(self) -> None:
        if self._value is None:
            with self._lock:
                self._n += 1
        else:
            with self._value.get_lock():
                self._value.value += 1

    def leave(self) -> None:
        if self._value is None:
            with self._lock:
                self._n -= 1
        else:
            with self._value.get_lock():
                self._value.value -= 1

    def threads(self) -> int:
        n = self._n if self._value is None else self._value.value
        return max(1, self.cap // max(1, n))


#: The share of this process-pool or Dask worker (set by its initializer or warm-up), else
#: None.
_POOL_SHARE: Any = None
#: The share of the task this thread runs (a local thread pool's task), else unset.
_TASK = threading.local()


def claim_kernel_threads() -> None:
    """Before a kernel batch inside a pool's task: take this task's share of the cores as
    numba threads (see :class:`_Share`); outside a pool's task nothing changes."""
    share = getattr(_TASK, "share", None)
    if share is None:
        return
    import numba

    n = min(share.threads(), int(numba.config.NUMBA_NUM_THREADS))
    if n != numba.get_num_threads():
        numba.set_num_threads(n)


def _run_shared(share: _Share | None, fn, /, *args, **kwargs):
    """A local pool's task: counted as running while it runs, one numba thread outside its
    kernel batches."""
    share = share if share is not None else _POOL_SHARE
    if share is None:
        return fn(*args, **kwargs)
    import numba

    old = numba.get_num_threads()
    _TASK.share = share
    share.enter()
    try:
        numba.set_num_threads(1)
        return fn(*args, **kwargs)
    finally:
        share.leave()
        _TASK.share = None
        numba.set_num_threads(old)


class _SharingThreadPool(ThreadPoolExecutor):
    """Local threads whose tasks share the cores' numba threads (:class:`_Share`)."""

    def __init__(self, max_workers: int):
        super().__init__(max_workers=max_workers)
        self._share = _Share(os.cpu_count() or max_workers)

    def submit(self, fn, /, *args, **kwargs):
        return super().submit(_run_shared, self._share, fn, *args, **kwargs)


class _SharingProcessPool(ProcessPoolExecutor):
    """Local processes whose tasks share the cores' numba threads (:class:`_Share`)."""

    def submit(self, fn, /, *args, **kwargs):
        return super().submit(_run_shared, None, fn, *args, **kwargs)


#: The module a process pool's fork server imports once (the package, the kernel loaded):
#: every worker is then a fork of it, ready in milliseconds instead of seconds.
FORKSERVER_PRELOAD = "rotorbayes.inference._forkserver"


def process_context():
    """The multiprocessing context of local process pools: a fork server that has loaded
    rotorbayes and the kernel (POSIX), else spawn.  Plain fork of the command's process is
    not used: it has loaded the kernel under GNU OpenMP, which does not survive a fork."""
    import multiprocessing as mp

    if "forkserver" not in mp.get_all_start_methods():
        return mp.get_context("spawn")
    from multiprocessing import forkserver

    ctx = mp.get_context("forkserver")
    ctx.set_forkserver_preload([FORKSERVER_PRELOAD])
    # The server loads the serial entry points alone (no numba thread exists when it
    # forks); each worker launches numba's usual threading layer after its fork.  (The
    # fork-safe ``workqueue`` layer, used here before, made a fit 1.6x slower on one
    # thread and 1.9x on 16: measured on 16 cores, benchmarks/README.md.)
    forkserver.ensure_running()
    return ctx


def _ignore_ctrl_c() -> None:
    """A local worker process ignores Ctrl-C: the terminal sends it to the whole process
    group, but the command's process alone decides what stops (and says what is kept); the
    workers go when it shuts the pool down, without tracebacks of their own."""
    import signal

    with contextlib.suppress(ValueError, OSError):  # not the main thread: leave it
        signal.signal(signal.SIGINT, signal.SIG_IGN)


@contextlib.contextmanager
def _children_ignore_ctrl_c():
    """Processes started in the block ignore Ctrl-C (an ignored signal stays ignored in a
    new process, and Python then installs no handler of its own)."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)


@dataclass(frozen=True)
class ExecutorSpec:
    """Which back-end, how many workers, which scheduler (see :func:`choose`)."""

    backend: str = DEFAULT_BACKEND
    workers: int | None = None
    scheduler: str | None = None
    source: str = "default"
    #: Chosen by nobody (:func:`choose`'s last resort): :func:`open_executor` then picks
    #: threads or processes by the work (:class:`DefaultPool`) on a small machine.
    auto: bool = False

    def n_workers(self) -> int:
        if self.backend == "serial":
            return 1
        return max(1, int(self.workers or os.cpu_count() or 1))

    def describe(self) -> str:
        """In words, for the command's output."""
        if self.backend == "serial":
            return "serially in this process"
        if self.backend == "threads":
            return f"in {self.n_workers()} local threads"
        if self.backend == "processes":
            return f"in {self.n_workers()} local processes"
        if self.scheduler:
            return f"on the Dask scheduler at {self.scheduler} ({self.source})"
        return f"on a local Dask cluster of {self.n_workers()} worker processes"


#: The address forms of a Dask scheduler: [PROTOCOL://]HOST[:PORT].
_ADDRESS = re.compile(
    r"^(?:(?:tcp|tls|ucx|ws|wss)://)?(\[[0-9a-fA-F:.]+\]|[^\s/:\[\]]+)(?::(\d{1,5}))?$"
)


def check_address(address: str, source: str) -> str:
    """``address`` if it is a scheduler address (``tcp://HOST:PORT``), else ValueError
    naming it, where it came from and the form to give; no connection is tried."""
    m = _ADDRESS.match(address.strip())
    if not m or (m.group(2) is not None and not 0 < int(m.group(2)) < 65536):
        raise ValueError(
            f"{address!r} (from {source}) is not a Dask scheduler address; give it as "
            "tcp://HOST:PORT, as `dask scheduler` prints it (e.g. tcp://10.0.0.5:8786)"
        )
    return address.strip()


def choose(
    backend: str | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    *,
    file: dict | None = None,
    environ: dict | None = None,
) -> ExecutorSpec:
    """Pick the back-end: the command's options first, then ``DASK_SCHEDULER_ADDRESS``, then
    the analysis file's ``[parallel]`` table (``backend``, ``workers``, ``scheduler``), then
    :data:`DEFAULT_BACKEND`.

    A scheduler address (from any of them) means Dask; ``backend='dask'`` without one starts
    a ``LocalCluster`` of ``workers`` processes.
    """
    env = os.environ if environ is None else environ
    file = file or {}
    if backend is not None and backend not in BACKENDS:
        raise ValueError(
            f"unknown parallel back-end {backend!r}; choose one of {', '.join(BACKENDS)}"
        )
    if scheduler:
        return ExecutorSpec("dask", workers, check_address(scheduler, "--scheduler"), "--scheduler")
    if backend not in (None, "dask"):
        return ExecutorSpec(backend, workers, None, "--backend")
    if env.get(SCHEDULER_ENV):
        return ExecutorSpec(
            "dask", workers, check_address(env[SCHEDULER_ENV], SCHEDULER_ENV), SCHEDULER_ENV
        )
    if backend == "dask":
        return ExecutorSpec("dask", workers, None, "--backend")
    if file.get("scheduler"):
        return ExecutorSpec(
            "dask",
            workers or file.get("workers"),
            check_address(str(file["scheduler"]), "the analysis file's [parallel] scheduler"),
            "the analysis file",
        )
    if file.get("backend"):
        return ExecutorSpec(
            file["backend"], workers or file.get("workers"), None, "the analysis file"
        )
    return ExecutorSpec(DEFAULT_BACKEND, workers or file.get("workers"), None, "default", auto=True)


class _WarmUp:
    """Dask worker plugin: :func:`prepare_worker` once when a worker joins (also a
    replacement for a worker that died)."""

    name = "rotorbayes-warm-up"

    def setup(self, worker=None):
        prepare_worker()
        _share_worker_cores(worker)

    def teardown(self, worker=None):
        global _POOL_SHARE
        share, _POOL_SHARE = _POOL_SHARE, None
        close = getattr(share, "close", None)
        if close is not None:
            with contextlib.suppress(Exception):
                close()

    def transition(self, *args, **kwargs):
        pass

    def release_key(self, *args, **kwargs):
        pass


def _share_worker_cores(worker) -> None:
    """The tasks of every Dask worker on a host share its cores as a local process pool's
    do: each task runs on one numba thread outside its kernel batches and on
    ``C // (tasks running on the host)`` inside them, ``C`` the threads the host's workers
    of this scheduler brought (``--nthreads``; dask-jobqueue's ``cores / processes``), at
    most the cores the worker may use (:mod:`.hostshare`).  So the last starts of a
    multistart take the cores that other workers left idle.  Where the host's counters
    cannot be kept, a worker shares its own threads (``T // its tasks running``).  Without
    either, a task would run its batches on numba's default, a thread per core, in every
    one of the worker's threads (numba's thread count is per thread, and a worker's tasks
    run in threads the warm-up never sees)."""
    global _POOL_SHARE
    import numba

    from .hostshare import open_host_share

    nthreads = int(
        getattr(getattr(worker, "state", None), "nthreads", None)
        or getattr(worker, "nthreads", None)
        or 1
    )
    scheduler = getattr(getattr(worker, "scheduler", None), "address", None)
    share = open_host_share(str(scheduler), nthreads) if scheduler else None
    if share is None:
        share = _Share(min(nthreads, int(numba.config.NUMBA_NUM_THREADS)))
    _POOL_SHARE = share


def _dask_executor(client) -> Executor:
    """Dask's executor of ``client``, each task run inside :func:`_run_shared` (on the worker:
    its share of the worker's cores), under the key Dask would give the task itself."""
    import uuid

    from dask.utils import funcname
    from distributed.cfexecutor import ClientExecutor

    class SharingClientExecutor(ClientExecutor):
        def submit(self, fn, /, *args, **kwargs):
            key = f"{funcname(fn)}-{uuid.uuid4().hex}"
            return super().submit(_run_shared, None, fn, *args, key=key, **kwargs)

    return SharingClientExecutor(client, pure=False)


class DefaultPool(Executor):
    """The default local executor of a machine with fewer than :data:`PROCESSES_FROM_CORES`
    cores: each batch of tasks (:func:`run_tasks`) runs in threads or processes as
    :func:`default_backend` picks for its size; each pool is opened at its first use, kept
    for the command, and said once (``say``).  A task submitted by hand runs in threads."""

    def __init__(
        self,
        workers: int | None = None,
        say: Callable[[str], None] | None = None,
        cores: int | None = None,
    ):
        self._workers = workers
        self._max_workers = max(1, int(workers or os.cpu_count() or 1))
        self._cores = cores
        self._say = say
        self._pools: dict[str, Executor] = {}
        self._stack = contextlib.ExitStack()

    def pick(self, tasks: int | None = None, residuals: int | None = None) -> Executor:
        """The pool for ``tasks`` tasks of ``residuals`` residuals each (opened, and said,
        the first time)."""
        backend = default_backend(self._cores, tasks, residuals)
        if backend not in self._pools:
            spec = ExecutorSpec(backend, self._workers, None, "default")
            self._pools[backend] = self._stack.enter_context(open_executor(spec))
            if self._say is not None:
                self._say(
                    f"parallel tasks run {spec.describe()} "
                    f"({default_reason(self._cores, tasks, residuals)})"
                )
        return self._pools[backend]

    def submit(self, fn, /, *args, **kwargs) -> Future:
        return self.pick().submit(fn, *args, **kwargs)

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        self._stack.close()


def _residuals_of(shared: Any) -> int | None:
    """Residuals per evaluation of the problem a batch's shared data hold (the problem, or
    a tuple that starts with it), else None."""
    for obj in (shared, *(shared[:1] if isinstance(shared, tuple) else ())):
        n = getattr(obj, "n_residuals", None)
        if isinstance(n, int) and not isinstance(n, bool):
            return n
    return None


@contextlib.contextmanager
def open_executor(
    spec: ExecutorSpec, *, say: Callable[[str], None] | None = None
) -> Iterator[Executor]:
    """The executor for ``spec``, shut down (and a cluster it started, stopped) on exit.
    The default of a machine with fewer than :data:`PROCESSES_FROM_CORES` cores is a
    :class:`DefaultPool` (threads or processes by the size of each batch); ``say`` gets the
    line that names the default back-end and why."""
    if spec.auto and spec.backend in ("threads", "processes"):
        cores = os.cpu_count() or 1
        if cores < PROCESSES_FROM_CORES:
            default = DefaultPool(spec.workers, say, cores)
            try:
                yield default
            finally:
                default.shutdown()
            return
        if say is not None:
            say(f"parallel tasks run {spec.describe()} ({default_reason(cores)})")
    if spec.backend == "serial":
        yield SerialExecutor()
        return
    if spec.backend in ("threads", "processes"):
        pool: Executor
        if spec.backend == "threads":
            pool = _SharingThreadPool(spec.n_workers())
        else:
            # The pool starts its processes lazily, at a submit, with this process's
            # environment (BLAS limited to one thread by rotorbayes's import), forked from
            # a server that loaded the kernel once (process_context); each worker runs
            # one numba thread outside its kernel batches, a share of the cores in them.
            ctx = process_context()
            n = spec.n_workers()
            pool = _SharingProcessPool(
                max_workers=n,
                mp_context=ctx,
                initializer=_process_initializer,
                initargs=(ctx.Value("i", 0), max(n, os.cpu_count() or n)),
            )
        try:
            yield pool
        finally:
            pool.shutdown(wait=True, cancel_futures=True)
        return
    with _dask_client(spec) as client:
        yield _dask_executor(client)


def connect_timeout() -> float:
    """Seconds to wait for a scheduler and its first worker: :data:`TIMEOUT_ENV`, else
    :data:`CONNECT_TIMEOUT`.  A value that is not a positive number is refused."""
    raw = os.environ.get(TIMEOUT_ENV, "").strip()
    if not raw:
        return CONNECT_TIMEOUT
    try:
        value = float(raw)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise ClusterError(
            f"{TIMEOUT_ENV}={raw!r} is not a number of seconds > 0; set it to "
            f"e.g. 60, or unset it for the default {CONNECT_TIMEOUT:.0f} s"
        )
    return value


@contextlib.contextmanager
def _dask_client(spec: ExecutorSpec):
    try:
        from distributed import LocalCluster
    except ImportError as exc:  # pragma: no cover - a declared dependency
        raise ClusterError(
            "the Dask back-end needs dask[distributed]: pip install 'dask[distributed]'"
        ) from exc
    cluster = None
    wait = connect_timeout() if spec.scheduler else CONNECT_TIMEOUT
    quiet = _quiet_dask_logs()
    try:
        if spec.scheduler:
            client = _connect(spec.scheduler, spec.source, wait)
            try:  # a scheduler without workers would take the tasks and never run them
                client.wait_for_workers(1, timeout=wait)
            except Exception:  # noqa: BLE001 - TimeoutError, OSError, a scheduler gone
                _give_up(client)
                raise ClusterError(
                    f"the Dask scheduler at {spec.scheduler} (from {spec.source}) has no "
                    f"workers (none joined within {wait:g} s); start some with "
                    f"`dask worker {spec.scheduler}` (workers end when their scheduler is "
                    "lost: after restarting a scheduler, restart its workers too)"
                ) from None
        else:
            with _children_ignore_ctrl_c():  # the cluster's workers are this command's
                cluster = LocalCluster(
                    n_workers=spec.n_workers(),
                    threads_per_worker=1,
                    processes=True,
                    dashboard_address=None,
                    env=WORKER_ENV,
                )
            client = _client_class()(cluster, set_as_default=False)
        try:
            client.register_plugin(_worker_plugin(), name=_WarmUp.name)
            yield client
        finally:
            _close(client)
    finally:
        if cluster is not None:
            with contextlib.suppress(Exception):
                cluster.close(timeout=10)
        quiet()


#: Dask's port when an address gives none.
DEFAULT_PORT = 8786

#: The largest first message a scheduler's handshake can be (it is about 60 bytes: the
#: compression, Python version and pickle protocol); a longer one is not Dask.
_HANDSHAKE_MAX = 1 << 16


def _start_help(address: str) -> str:
    return (
        f"Start one with `dask scheduler` and workers with `dask worker {address}`, or "
        "drop the address to run locally"
    )


def probe_scheduler(address: str, source: str, wait: float) -> bool:
    """Check within ``wait`` seconds that a Dask scheduler answers at ``address`` (from
    ``source``), speaking Dask's protocol, before a Client is made; :class:`ClusterError`
    naming the address otherwise.

    Dask's own client waits for the first message of a peer without a time limit, so a
    program that accepts the connection and never answers would hang it, and one that
    answers with other bytes (a web server: an HTTP status line) makes it read the first
    8 bytes as a message length (exabytes).  Here the exchange is a plain socket with a
    deadline: the handshake both sides of a Dask connection send first (this one, then the
    peer's: its compression, Python version and pickle protocol), checked for its form.  A
    closed port is tried again until ``wait`` has passed (a scheduler still starting).
    Only ``tcp://`` addresses (and those without a protocol) are checked here (True
    returned); TLS and websocket connections end in Dask's own connect timeout (False).
    """
    import socket
    import struct
    import time

    m = _ADDRESS.match(address.strip())
    scheme = address.split("://", 1)[0] if "://" in address else "tcp"
    if not m or scheme != "tcp":
        return False
    host = m.group(1).strip("[]")
    port = int(m.group(2) or DEFAULT_PORT)
    end = time.monotonic() + wait
    where = f"{address} (from {source})"

    def left() -> float:
        return end - time.monotonic()

    last: OSError | None = None
    sock = None
    while sock is None:
        if left() <= 0:
            why = f": {last}" if last is not None else ""
            raise ClusterError(
                f"no Dask scheduler answered at {where} within {wait:g} s"
                f"{why}. {_start_help(address)}"
            )
        try:
            sock = socket.create_connection((host, port), timeout=max(0.05, left()))
        except OSError as exc:  # refused, unreachable, a name not found: a scheduler may
            last = exc  # still be starting, as Dask's own connect assumes
            time.sleep(max(0.0, min(0.25, left())))
    try:
        with sock:
            sock.settimeout(max(0.05, left()))
            sock.sendall(_handshake_bytes())
            first = _recv_exact(sock, 8, left)
            (n,) = struct.unpack("<Q", first)
            if not 16 <= n <= _HANDSHAKE_MAX:
                raise _NotDask(first + _recv_some(sock, 72))
            body = _recv_exact(sock, n, left)
            if not _is_handshake(body):
                raise _NotDask(first + body[:72])
    except _NotDask as exc:
        said = exc.args[0].split(b"\r\n")[0].split(b"\n")[0][:72]
        text = said.decode("ascii", "replace")
        kind = (
            " (a web server: is it the dashboard's address?)" if said.startswith(b"HTTP/") else ""
        )
        raise ClusterError(
            f"{where} answered, but not as a Dask scheduler: it sent {text!r}{kind}. Give "
            'the address `dask scheduler` prints after "Scheduler at:" (tcp://HOST:8786), '
            "not its dashboard's (http://HOST:8787)"
        ) from None
    except TimeoutError:
        raise ClusterError(
            f"{where} accepted the connection but did not answer as a Dask scheduler within "
            f"{wait:g} s (another program at that port, or a scheduler that is stopped or "
            f"overloaded?). {_start_help(address)}"
        ) from None
    except OSError as exc:  # closed or reset by the peer
        raise ClusterError(
            f"{where} accepted the connection and closed it without answering as a Dask "
            f"scheduler ({exc}). {_start_help(address)}"
        ) from None
    return True


class _NotDask(Exception):
    """The peer's first bytes (in ``args[0]``) are not a Dask handshake."""


def _handshake_bytes() -> bytes:
    """The first message of a Dask TCP connection: one msgpack frame holding this side's
    compression (none), Python version and pickle protocol, behind the frame count, the
    frame's length and the whole message's length (little-endian 64-bit)."""
    import pickle
    import struct
    import sys

    import msgpack

    frame = msgpack.dumps(
        {
            "compression": None,
            "python": list(sys.version_info[:3]),
            "pickle-protocol": pickle.HIGHEST_PROTOCOL,
        }
    )
    body = struct.pack("<QQ", 1, len(frame)) + frame
    return struct.pack("<Q", len(body)) + body


def _is_handshake(body: bytes) -> bool:
    """Whether ``body`` is a Dask handshake: frames (a count, their lengths, the frames)
    whose first is a msgpack map with the pickle protocol Dask's connections agree on."""
    import struct

    import msgpack

    try:
        (k,) = struct.unpack_from("<Q", body)
        if not 1 <= k <= 16:
            return False
        lengths = struct.unpack_from(f"<{k}Q", body, 8)
        if 8 * (1 + k) + sum(lengths) != len(body):
            return False
        start = 8 * (1 + k)
        info = msgpack.loads(body[start : start + lengths[0]])
    except Exception:  # noqa: BLE001 - any malformed content: not Dask
        return False
    return isinstance(info, dict) and "pickle-protocol" in info


def _recv_exact(sock, n: int, left: Callable[[], float]) -> bytes:
    got = bytearray()
    while len(got) < n:
        if left() <= 0:
            raise TimeoutError("timed out")
        sock.settimeout(max(0.05, left()))
        chunk = sock.recv(n - len(got))
        if not chunk:
            if got:
                raise _NotDask(bytes(got))
            raise ConnectionResetError("the connection was closed")
        got += chunk
    return bytes(got)


def _recv_some(sock, n: int) -> bytes:
    """Up to ``n`` more bytes if they come within half a second (for the message)."""
    try:
        sock.settimeout(0.5)
        return sock.recv(n)
    except OSError:
        return b""


_CLIENT_CLASS = None


def _client_class():
    """Dask's Client, failing quietly: a Client whose start failed is closed at once with a
    short wait (otherwise its ``__del__`` tries again at exit, waits twice the connect
    timeout and prints a traceback), and a Client is never closed with an exception."""
    global _CLIENT_CLASS
    if _CLIENT_CLASS is None:
        from distributed import Client

        class QuietClient(Client):
            def __init__(self, *args, **kwargs):
                try:
                    super().__init__(*args, **kwargs)
                except BaseException:
                    _give_up(self)
                    raise

            def __del__(self):
                with contextlib.suppress(BaseException):
                    super().__del__()

        _CLIENT_CLASS = QuietClient
    return _CLIENT_CLASS


def _give_up(client) -> None:
    """Close ``client`` within 2 s whatever state it is in, and mark it closed (so nothing
    tries again at exit)."""
    with contextlib.suppress(BaseException):
        if client.status not in ("closed", "newly-created"):
            client.close(timeout=2)
    with contextlib.suppress(BaseException):
        client.status = "closed"
    with contextlib.suppress(BaseException):
        client._loop_runner.stop()


def _close(client) -> None:
    try:
        client.close(timeout=5)
    except BaseException:  # noqa: BLE001 - a scheduler already gone: close what is ours
        _give_up(client)


def _connect(address: str, source: str, wait: float):
    """A Client of the scheduler at ``address``, or :class:`ClusterError` within about
    ``wait`` seconds (:func:`probe_scheduler` first; the Client is made in a helper thread,
    so that a peer that speaks Dask's protocol but never registers the client cannot hang
    the command)."""
    import threading
    import time

    probed = probe_scheduler(address, source, wait)
    box: dict[str, Any] = {}
    lock = threading.Lock()

    def make() -> None:
        try:
            c = _client_class()(address, timeout=wait, set_as_default=False)
        except BaseException as exc:  # noqa: BLE001 - handed to the command's thread
            box["error"] = exc
            return
        with lock:
            if box.get("abandoned"):
                _give_up(c)
            else:
                box["client"] = c

    th = threading.Thread(target=make, name="rotorbayes-dask-connect", daemon=True)
    t0 = time.monotonic()
    th.start()
    try:
        th.join(wait + CLIENT_GRACE)
    finally:
        with lock:
            if "client" not in box:
                box["abandoned"] = True
    if "client" in box:
        return box["client"]
    where = f"{address} (from {source})"
    exc = box.get("error")
    if exc is None or (probed and isinstance(exc, OSError | TimeoutError)):
        why = f" ({str(exc).splitlines()[0][:160]})" if exc is not None and str(exc) else ""
        raise ClusterError(
            f"{where} speaks Dask's protocol but did not take this client within "
            f"{time.monotonic() - t0:.0f} s{why} (an overloaded scheduler, or another Dask "
            f"process than a scheduler?). {_start_help(address)}"
        )
    if isinstance(exc, OSError | TimeoutError):
        raise ClusterError(
            f"no Dask scheduler answered at {where} within {wait:g} s: "
            f"{exc}. {_start_help(address)}"
        ) from None
    if isinstance(exc, KeyboardInterrupt):
        raise exc
    first = str(exc).splitlines()[0][:160] if str(exc) else ""
    raise ClusterError(
        f"{where} speaks Dask's protocol but is not a scheduler that takes clients "
        f"({type(exc).__name__}: {first}): a worker's address? Give the address `dask "
        'scheduler` prints after "Scheduler at:"'
    ) from None


def _quiet_dask_logs() -> Callable[[], None]:
    """Dask's own log lines (ports, nannies, reconnect attempts with tracebacks) are not the
    user's business: our messages say what happened.  Returns the undo."""
    import logging

    names = ["distributed", "tornado", "asyncio"] + [
        n for n in logging.root.manager.loggerDict if n.startswith(("distributed.", "tornado."))
    ]
    saved = {n: logging.getLogger(n).level for n in names}
    for n in names:
        logging.getLogger(n).setLevel(logging.CRITICAL + 1)

    def undo() -> None:
        for n, level in saved.items():
            logging.getLogger(n).setLevel(level)

    return undo


def _worker_plugin():
    from distributed.diagnostics.plugin import WorkerPlugin

    class WarmUp(_WarmUp, WorkerPlugin):
        pass

    return WarmUp()


# --------------------------------------------------------------------------- the current one

_CURRENT: contextvars.ContextVar[Executor | None] = contextvars.ContextVar(
    "rotorbayes_executor", default=None
)


def current_executor() -> Executor | None:
    """The executor a command opened with :func:`use_executor`, else ``None``."""
    return _CURRENT.get()


@contextlib.contextmanager
def use_executor(
    spec: ExecutorSpec | Executor, *, say: Callable[[str], None] | None = None
) -> Iterator[Executor]:
    """Open ``spec`` (or take an executor as it is) and make it every algorithm's default
    until the block ends (``say``: see :func:`open_executor`)."""
    if isinstance(spec, Executor):
        token = _CURRENT.set(spec)
        try:
            yield spec
        finally:
            _CURRENT.reset(token)
        return
    with open_executor(spec, say=say) as ex:
        token = _CURRENT.set(ex)
        try:
            yield ex
        finally:
            _CURRENT.reset(token)


# --------------------------------------------------------------------------- running tasks

_NOTHING = object()


def _is_dask(executor: Executor) -> bool:
    return hasattr(executor, "_client") and any(
        c.__module__.startswith("distributed") for c in type(executor).__mro__
    )


def run_tasks(
    fn: Callable,
    items: Sequence,
    *,
    shared: Any = _NOTHING,
    executor: Executor | None = None,
    workers: int | None = None,
) -> Iterator[tuple[int, Any]]:
    """Yield ``(index, result)`` as tasks finish, ``result = fn(shared, item)`` (or
    ``fn(item)`` without ``shared``).

    ``executor`` defaults to the current one (:func:`use_executor`), else a local thread
    pool of ``workers`` threads (serial for one).  ``fn`` must be a module-level function
    (process and Dask workers import it).  ``shared`` is sent once per worker where the
    back-end allows it.  Stopping the iteration (Ctrl-C in the consumer) cancels the tasks
    not yet started; results already yielded are the caller's.  A lost Dask scheduler raises
    :class:`ClusterError`.
    """
    items = list(items)
    ex = executor if executor is not None else current_executor()
    if ex is None:
        spec = ExecutorSpec("serial" if (workers or 2) <= 1 else "threads", workers)
        with open_executor(spec) as own:
            yield from run_tasks(fn, items, shared=shared, executor=own)
        return
    args: tuple = () if shared is _NOTHING else (shared,)
    if isinstance(ex, DefaultPool):  # threads or processes by the size of this batch
        ex = ex.pick(len(items), None if shared is _NOTHING else _residuals_of(shared))
    if isinstance(ex, SerialExecutor):  # one at a time, each result as soon as it is there
        for i, it in enumerate(items):
            yield i, fn(*args, it)
        return
    if shared is not _NOTHING:
        if _is_dask(ex):
            args = (_scatter(ex, shared),)
    futures: dict[Future, int] = {}
    done_count = 0
    # A local pool gets a few tasks per worker at a time (a Ctrl-C then has little to
    # cancel, and thousands of queued futures are not held); Dask gets them all at once
    # (its scheduler balances the cluster).
    window = len(items) if _is_dask(ex) else 4 * max(1, getattr(ex, "_max_workers", 2))
    todo = iter(enumerate(items))
    try:
        pending: set[Future] = set()
        for i, it in todo:
            f = ex.submit(fn, *args, it)
            futures[f] = i
            pending.add(f)
            if len(pending) >= window:
                break
        while pending:
            done, pending = _wait(pending, return_when=FIRST_COMPLETED)
            for i, it in todo:
                f = ex.submit(fn, *args, it)
                futures[f] = i
                pending.add(f)
                if len(pending) >= window:
                    break
            for f in sorted(done, key=futures.__getitem__):
                if f.cancelled():
                    raise _lost(ex, done_count, len(items))
                try:
                    r = f.result()
                except CancelledError:
                    raise _lost(ex, done_count, len(items)) from None
                except OSError as exc:
                    if _is_dask(ex) and _client_gone(ex):
                        raise _lost(ex, done_count, len(items)) from exc
                    raise
                done_count += 1
                # Forget the finished future: it holds its result (a fit of long data holds
                # a Jacobian of hundreds of MB), which is now the caller's.
                yield futures.pop(f), r
    finally:
        for f in futures:
            f.cancel()


def share(ex: Executor, obj: Any) -> Any:
    """``obj`` made ready to be named by many tasks submitted to ``ex`` by hand (as the first
    argument of ``ex.submit``): on Dask scattered once to every worker (the tasks carry only
    its key), elsewhere ``obj`` itself (threads share it; a process pool pickles it with each
    task)."""
    return _scatter(ex, obj) if _is_dask(ex) else obj


def is_dask(ex: Executor | None) -> bool:
    """Whether ``ex`` runs its tasks on a Dask cluster."""
    return ex is not None and _is_dask(ex)


def client_gone(ex: Executor) -> bool:
    """Whether ``ex`` is a Dask executor whose scheduler is lost."""
    return _is_dask(ex) and _client_gone(ex)


def lost_scheduler(
    ex: Executor, done: int, total: int, *, unit: str = "tasks", then: str | None = None
) -> ClusterError:
    """The :class:`ClusterError` for a scheduler lost after ``done`` of ``total`` tasks
    (or other ``unit``); ``then`` says what to do (default: run the command again)."""
    return _lost(ex, done, total, unit=unit, then=then)


def _scatter(ex: Executor, obj: Any):
    client = ex._client  # type: ignore[attr-defined]
    try:
        # In a list of one: scatter would split a tuple or dict into one future per part.
        return client.scatter([obj], broadcast=True, hash=False)[0]
    except (OSError, TimeoutError) as exc:
        raise ClusterError(f"the Dask scheduler did not accept the data: {exc}") from None


def _client_gone(ex: Executor) -> bool:
    client = getattr(ex, "_client", None)
    return client is not None and client.status not in ("running", "connecting")


def _lost(
    ex: Executor, done: int, total: int, *, unit: str = "tasks", then: str | None = None
) -> ClusterError:
    where = ""
    client = getattr(ex, "_client", None)
    if client is not None:
        with contextlib.suppress(Exception):
            where = f" at {client.scheduler.address}"
    return ClusterError(
        f"lost the Dask scheduler{where} after {done} of {total} {unit} had finished (it "
        "stopped, or the network to it failed); "
        + (then or "restart the scheduler and its workers and run the command again"),
        done,
    )


def map_ordered(
    fn: Callable,
    items: Iterable,
    *,
    shared: Any = _NOTHING,
    executor: Executor | None = None,
    workers: int | None = None,
) -> list:
    """``[fn(shared, x) for x in items]`` through :func:`run_tasks`, results in input order."""
    items = list(items)
    out: list = [None] * len(items)
    for i, r in run_tasks(fn, items, shared=shared, executor=executor, workers=workers):
        out[i] = r
    return out


def progress(results: Iterator, total: int, desc: str, *, enabled: bool = True) -> Iterator:
    """Wrap a ``(index, result)`` stream with a progress bar (tqdm, on stderr) when
    ``enabled`` and stderr is a terminal; otherwise pass it through unchanged."""
    import sys

    if not enabled or not sys.stderr.isatty():
        yield from results
        return
    from tqdm import tqdm

    with tqdm(total=total, desc=desc, unit="task", leave=False) as bar:
        for item in results:
            bar.update(1)
            yield item

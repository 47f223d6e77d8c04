"""The sampling loop: every ensemble of a run as a chain of segments (:mod:`.segment`) on an
executor, the steps appended to the store (:mod:`.store`) by this process alone.

There is one loop. Without an executor the ensembles run on
:class:`~rotorbayes.inference.parallel.SerialExecutor`: one ensemble after the other, one
step a segment, in this process; a pool or a Dask cluster runs them concurrently in
segments of :data:`SEGMENT_SECONDS` of work. The random state travels whole with each
segment, so the chains do not depend on where or in how many segments they were run.
"""

from __future__ import annotations

import itertools
import os
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from ...util.exitcodes import EnvironmentFailure
from .. import parallel
from ..likelihood import LogPosterior
from . import disk
from . import moves as proposal_moves
from .checkpoint import CheckpointError, Snapshot, recover_checkpoint, stored_moves
from .locks import open_h5
from .moves import DEFAULT_MOVES, MOVES, fit_proposal, uses_fit_proposal
from .segment import _Chunk, _run_segment, _Segment
from .store import EnsembleRun, H5Store, MemoryStore, _Store

#: Steps of an ensemble's first segment on a pool or cluster; later segments aim at
#: :data:`SEGMENT_SECONDS` of work each (at most :data:`SEGMENT_MAX` steps), so a Ctrl-C
#: waits little and the checkpoint is written often. In this process (the serial executor)
#: every segment is one step, as every step is written or a stop may be asked after it; a
#: run in memory that nothing may stop runs in one segment (to the re-centring, then the
#: end), which spares emcee's set-up of every step.
SEGMENT_FIRST, SEGMENT_SECONDS, SEGMENT_MAX = 5, 2.0, 500
#: Seconds between two additions of the sampling's wall and CPU time to a group's totals
#: (and at the end of each ensemble), so a killed run loses at most these few seconds.
CLOCK_EVERY = 10.0


class SamplingStopped(Exception):
    """A run ended between two steps on request; every finished step is saved."""

    def __init__(self, ensemble: str, step: int, total: int, others: dict[str, int] | None = None):
        others = {k: v for k, v in (others or {}).items() if k != ensemble}
        more = "".join(f", {k} after step {v}" for k, v in others.items())
        super().__init__(f"{ensemble} stopped after step {step} of {total}{more}")
        self.ensemble, self.step, self.total = ensemble, step, total


def ensemble_name(e: int) -> str:
    """The HDF5 group (and name) of the ``e``-th ensemble of a run."""
    return f"ensemble{e}"


def ensemble_seed(seed: int, e: int) -> int:
    """The seed of the ``e``-th ensemble of a run with ``seed``: its own stream."""
    return seed + 1000 * e


def sample(
    logpost: LogPosterior,
    x_fit,
    folder: Path | None,
    *,
    n_walkers: int = 32,
    n_steps: int = 2000,
    n_ensembles: int = 2,
    seed: int = 0,
    progress: bool = True,
    should_stop: Callable[[], bool] | None = None,
    keep_free: int = 0,
    moves: str | None = None,
    start: str = "fit",
    executor=None,
) -> list[EnsembleRun]:
    """Run (or continue) ``n_ensembles`` ensembles into ``folder/chain.h5`` (in memory,
    without checkpoints, when ``folder`` is None).

    ``moves`` names the proposals (:data:`MOVES`; None: those the checkpoint holds, else
    :data:`DEFAULT_MOVES`); a checkpoint made with other moves is refused
    (:class:`CheckpointError`), so a resumed run continues exactly as it began. ``start``
    places the walkers of a new run (:func:`start_walkers`). An existing ``chain.h5`` is
    checked first (:func:`check_checkpoint`; a damaged one raises :class:`CheckpointError`);
    ``should_stop`` see :func:`run_ensemble`.

    ``executor`` (:mod:`~rotorbayes.inference.parallel`; None: one ensemble after the other
    in this process) runs the ensembles concurrently, in segments of steps: only this
    process writes ``chain.h5``, step by step, and the chains are bit for bit those of the
    serial run.
    """
    if moves is not None and moves not in MOVES:
        raise ValueError(f"moves {moves!r}: choose one of {', '.join(MOVES)}")
    names = [ensemble_name(e) for e in range(n_ensembles)]
    if folder is None:
        memory = MemoryStore()
        jobs = [_Job(e, name, ensemble_seed(seed, e), 0) for e, name in enumerate(names)]
        _run_ensembles(
            memory,
            logpost,
            x_fit,
            jobs,
            n_walkers=n_walkers,
            n_steps=n_steps,
            moves=moves or DEFAULT_MOVES,
            start=start,
            progress=progress,
        )
        return [memory.run(name) for name in names]
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "chain.h5"
    held, restored = recover_checkpoint(
        path, n_walkers=n_walkers, ndim=logpost.ndim, n_ensembles=n_ensembles
    )
    if restored:
        warnings.warn(restored, RuntimeWarning, stacklevel=2)
    stored = stored_moves(path)
    kinds = set(stored.values())
    if len(kinds) > 1:
        raise CheckpointError(
            f"{path}: its ensembles were sampled with different moves "
            f"({', '.join(sorted(kinds))}); it cannot be continued as one run"
        )
    if kinds and moves is not None and moves not in kinds:
        raise CheckpointError(
            f"{path}: its chains were sampled with --moves "
            f"{next(iter(kinds))}, not {moves}; a resumed run continues "
            "with the moves it began with (leave --moves out, or start a "
            "new run with --out)"
        )
    moves = next(iter(kinds)) if kinds else (moves or DEFAULT_MOVES)
    left = sum(max(0, n_steps - held.get(name, 0)) for name in names)
    owned = False
    if left:
        if not path.exists():
            with open_h5(path, "a"):
                pass  # an empty HDF5 file, to own the blocks of the coming steps
        # Every coming step's blocks, owned by chain.h5 before the first is written.
        owned = disk.preallocate(path, disk.chain_bytes(n_walkers, logpost.ndim, left, 1))
    reserve = disk.DiskReserve(folder, keep_free if left else 0)
    snapshot = Snapshot(path)
    if not held:
        snapshot.discard()  # a copy from an earlier run whose chain.h5 was removed
    try:
        jobs = [
            _Job(e, name, ensemble_seed(seed, e), held.get(name, 0)) for e, name in enumerate(names)
        ]
        _run_ensembles(
            H5Store(path),
            logpost,
            x_fit,
            jobs,
            n_walkers=n_walkers,
            n_steps=n_steps,
            moves=moves,
            start=start,
            progress=progress,
            announce=progress,
            should_stop=should_stop,
            owned=owned,
            snapshot=snapshot if left else None,
            executor=executor,
        )
    except (SamplingStopped, EnvironmentFailure):
        snapshot.discard()  # stopped between two steps: chain.h5 is whole
        raise
    else:
        snapshot.discard()
    finally:
        reserve.close()
        if owned:  # give back the blocks past the end that were not needed
            try:
                os.truncate(path, os.stat(path).st_size)
            except OSError:
                pass
    return [H5Store(path).run(name) for name in names]


def run_ensemble(
    logpost: LogPosterior,
    path: Path | None,
    name: str,
    *,
    n_walkers: int,
    n_steps: int,
    x_fit=None,
    seed: int = 0,
    progress: bool = True,
    done: int = 0,
    should_stop: Callable[[], bool] | None = None,
    owned: bool = False,
    moves: str = DEFAULT_MOVES,
    start: str = "fit",
    snapshot: Snapshot | None = None,
):
    """Run (or continue) one ensemble, in this process, until its HDF5 group holds
    ``n_steps`` steps.

    ``done`` is the number of steps the group already holds (see :func:`check_checkpoint`);
    such a group is continued from its last state and random state (``--resume``). Returns
    the number of steps taken in this call (the :class:`EnsembleRun` when ``path`` is None).
    ``should_stop`` is asked after every saved step; when it says yes,
    :class:`SamplingStopped` is raised. ``owned``: the file already owns the disk blocks of
    these steps (:func:`preallocate`); otherwise the run stops, between two steps, when the
    disk is nearly full. ``moves`` (:data:`MOVES`) is stored with the group; ``start``
    (:data:`STARTS`) places the walkers of a new group (:func:`start_walkers`);
    ``snapshot`` (:class:`Snapshot`) copies the checkpoint between steps now and then.
    """
    store: _Store = MemoryStore() if path is None else H5Store(path)
    done = 0 if path is None else done
    _run_ensembles(
        store,
        logpost,
        x_fit,
        [_Job(0, name, seed, done)],
        n_walkers=n_walkers,
        n_steps=n_steps,
        moves=moves,
        start=start,
        progress=progress,
        should_stop=should_stop,
        owned=owned,
        snapshot=snapshot,
    )
    if path is None:
        return store.run(name)
    return max(0, n_steps - done)


@dataclass
class _Job:
    """An ensemble of a run: its place, name, seed and the steps its group holds."""

    e: int
    name: str
    seed: int
    done: int


@dataclass
class _Ensemble:
    """An ensemble under way in the loop."""

    e: int
    done: int
    seg: _Segment
    adapted: bool
    t0: float = field(default_factory=time.perf_counter)
    taken: int = 0
    per_step: float | None = None
    wall: float = 0.0  # sampling time not yet added to the group's totals
    cpu: float = 0.0
    keep: dict = field(default_factory=dict)  # the emcee sampler, in this process


def _run_ensembles(
    store: _Store,
    logpost: LogPosterior,
    x_fit,
    jobs: list[_Job],
    *,
    n_walkers: int,
    n_steps: int,
    moves: str,
    start: str,
    progress: bool,
    announce: bool = False,
    should_stop: Callable[[], bool] | None = None,
    owned: bool = True,
    snapshot: Snapshot | None = None,
    executor=None,
) -> None:
    """Run ``jobs`` until every group of ``store`` holds ``n_steps`` steps.

    Each ensemble is a chain of tasks: the executor runs a segment of steps from the state
    the task carries and returns the steps; this process appends them to the store step by
    step (the only writer) and sends the ensemble's next segment. A segment never crosses
    :data:`~.moves.ADAPT_AT`, where the fit proposal is re-centred here from the stored
    chain. The serial executor (``executor`` None) runs one ensemble after the other, one
    step a segment (in memory with no ``should_stop``: one segment); any other runs them
    all at once. The log-posterior (the data) goes to
    every worker once (Dask scatters it; threads share it; a process pool gets it with
    each segment, not with each step). ``should_stop`` is asked after every saved segment
    and while waiting: the segments still running are dropped (their steps were never
    written). Without ``owned`` disk blocks (:func:`~.disk.preallocate`) a nearly full disk
    stops the run before a segment's steps are written. ``announce``: a line per finished
    ensemble (steps, seconds, evaluations per second)."""
    from concurrent.futures import FIRST_COMPLETED, CancelledError
    from concurrent.futures import wait as _wait

    if executor is None:
        executor = parallel.SerialExecutor()
    in_process = isinstance(executor, parallel.SerialExecutor)
    todo = [job for job in jobs if job.done < n_steps]
    if not todo:
        return
    total = sum(n_steps - job.done for job in todo)
    path = store.path
    step_bytes = 8 * n_walkers * (logpost.ndim + 1) + 8192
    adapt_at = proposal_moves.ADAPT_AT
    fit_prop: list = []

    def the_fit_proposal():  # computed once, for all the ensembles that begin
        if not fit_prop:
            fit_prop.append(fit_proposal(logpost, x_fit))
        return fit_prop[0]

    active: dict[str, _Ensemble] = {}

    def begin(job: _Job) -> None:
        proposal, adapted = _begin_group(
            store, job.name, job.done, n_walkers, logpost.ndim, moves, the_fit_proposal
        )
        seg = _Segment(job.name, 0, moves, proposal, origin=os.getpid())
        if job.done == 0:
            seg.seed, seg.x_fit, seg.n_walkers, seg.start = job.seed, x_fit, n_walkers, start
        else:
            last = store.last_state(job.name)
            seg.coords, seg.log_prob, seg.random_state = (
                last.coords,
                last.log_prob,
                last.random_state,
            )
        store.grow(job.name, n_steps - job.done)
        active[job.name] = _Ensemble(job.e, job.done, seg, adapted)

    queue = iter(todo)
    for job in itertools.islice(queue, 1 if in_process else len(todo)):
        begin(job)
    shared = parallel.share(executor, logpost)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=total, desc=f"{len(todo)} ensembles", unit="step", leave=False)
    futures: dict = {}
    me = os.getpid()
    clock = time.perf_counter()

    def submit(name: str) -> None:
        a = active[name]
        if in_process:
            # Step by step where something happens between steps (a step written, a stop
            # asked); in memory with nothing to ask, to the re-centring or the end.
            n = 1 if path is not None or should_stop is not None else n_steps
        elif a.per_step is None:
            n = SEGMENT_FIRST
        else:
            n = int(SEGMENT_SECONDS / max(a.per_step, 1e-6))
        n = max(1, min(n, SEGMENT_MAX, n_steps - a.done))
        if a.seg.proposal is not None and not a.adapted and a.done < adapt_at:
            n = min(n, adapt_at - a.done)  # the proposal is re-centred at ADAPT_AT
        a.seg.n = n
        if in_process:
            futures[executor.submit(_run_segment, shared, a.seg, a.keep)] = name
        else:
            futures[executor.submit(_run_segment, shared, a.seg)] = name

    def add_seconds(names) -> None:
        for name in names:
            a = active[name]
            if a.wall or a.cpu:
                store.add_seconds(name, a.wall, a.cpu)
                a.wall = a.cpu = 0.0

    def lost():
        """The error for a Dask scheduler lost while the ensembles ran on it."""
        return parallel.lost_scheduler(
            executor,
            sum(a.taken for a in active.values()),
            total,
            unit="steps",
            then=f"every finished step is kept in {path}. Continue with `rotorbayes sample "
            f"{path.parent} --resume` (on this machine; or with --scheduler once the "
            "scheduler and its workers run again)",
        )

    try:
        for name in list(active):
            submit(name)
        while futures:
            if should_stop is not None and not all(f.done() for f in futures) and should_stop():
                raise _stopped(active, n_steps)
            ready, _ = _wait(list(futures), timeout=0.2, return_when=FIRST_COMPLETED)
            for f in sorted(ready, key=lambda f: active[futures[f]].e):
                name = futures.pop(f)
                a = active[name]
                try:
                    chunk = f.result()
                except CancelledError:
                    raise lost() from None
                except OSError as exc:
                    if parallel.client_gone(executor):
                        raise lost() from exc
                    raise
                n = chunk.chain.shape[0]
                if (
                    path is not None
                    and not owned
                    and disk.free_bytes(path.parent) < step_bytes * n + 100_000
                ):
                    raise disk.disk_full(path, name, a.done, n_steps)
                _save(store, name, chunk)
                if chunk.pid != me:  # counted in another process's copy
                    logpost.n_calls += chunk.calls
                    logpost.n_failed += chunk.failed
                a.done += n
                a.taken += n
                a.per_step = chunk.seconds / n
                a.wall += chunk.seconds
                a.cpu += chunk.cpu_seconds
                seg = a.seg
                seg.coords, seg.log_prob = chunk.chain[-1], chunk.log_prob[-1]
                seg.random_state, seg.x_fit = chunk.random_states[-1], None
                if seg.proposal is not None and not a.adapted and a.done == adapt_at:
                    # The fit's proposal re-centred once on the ensemble's own draws.
                    seg.proposal = proposal_moves.adapted(store.chain(name), seg.proposal)
                    a.adapted = True
                    store.set_attrs(
                        name,
                        proposal_mean=seg.proposal[0],
                        proposal_cov=seg.proposal[1],
                        proposal_adapted=adapt_at,
                    )
                if time.perf_counter() - clock > CLOCK_EVERY:
                    add_seconds(active)
                    clock = time.perf_counter()
                if snapshot is not None:
                    snapshot.take()
                if bar is not None:
                    bar.update(n)
                    bar.set_postfix_str(_where(active, n_steps))
                if a.done < n_steps:
                    if should_stop is not None and should_stop():
                        raise _stopped(active, n_steps)
                    submit(name)
                    continue
                add_seconds([name])
                if announce:
                    dt = time.perf_counter() - a.t0
                    msg = (
                        f"ensemble {a.e}: {a.taken} steps in {dt:.1f} s "
                        f"({a.taken * n_walkers / max(dt, 1e-9):.0f} log-posterior "
                        "evaluations/s)"
                    )
                    (bar.write(msg) if bar is not None else print(msg, flush=True))
                following = next(queue, None)
                if following is not None:
                    begin(following)
                    submit(following.name)
    except (OSError, EnvironmentFailure):
        raise  # a disk in trouble: no further write to the checkpoint
    except BaseException:
        add_seconds(active)
        raise
    finally:
        for f in futures:
            f.cancel()
        if bar is not None:
            bar.close()
    add_seconds(active)


def _save(store: _Store, name: str, chunk: _Chunk) -> None:
    """Append a segment's steps to the ensemble's group."""
    store.save(name, chunk.chain, chunk.log_prob, chunk.accepted, chunk.random_states)


def _begin_group(
    store: _Store,
    name: str,
    done: int,
    n_walkers: int,
    ndim: int,
    moves: str,
    fit_prop: Callable[[], tuple],
) -> tuple:
    """``(proposal, adapted)`` for an ensemble that holds ``done`` steps, with its group
    made ready: a new group (``done`` 0) is reset and records its moves, clocks and
    proposal; a group stopped between step ADAPT_AT and its record of the re-centred
    proposal gets that record now. ``fit_prop()`` gives the fit's proposal when the group
    holds none (moves without one: ``(None, False)``)."""
    adapt_at = proposal_moves.ADAPT_AT
    proposal, adapted = None, False
    if uses_fit_proposal(moves):
        stored = store.proposal(name) if done else None
        proposal, adapted = stored if stored is not None else (fit_prop(), False)
        if done >= adapt_at and not adapted:  # stopped between the step and its record
            proposal, adapted = proposal_moves.adapted(store.chain(name), proposal), True
            store.set_attrs(
                name, proposal_mean=proposal[0], proposal_cov=proposal[1], proposal_adapted=adapt_at
            )
    if done == 0:
        store.reset(name, n_walkers, ndim)
        extra = (
            {} if proposal is None else {"proposal_mean": proposal[0], "proposal_cov": proposal[1]}
        )
        store.set_attrs(name, moves=moves, sampling_seconds=0.0, cpu_seconds=0.0, **extra)
    return proposal, adapted


def _where(active: dict[str, _Ensemble], n_steps: int) -> str:
    """Each ensemble's steps, for the progress bar: ``e0 40/120 e1 35/120``."""
    return " ".join(f"e{a.e} {a.done}/{n_steps}" for a in active.values())


def _stopped(active: dict[str, _Ensemble], n_steps: int) -> SamplingStopped:
    """Stopped on request: where every ensemble under way stands (all saved)."""
    under_way = {name: a.done for name, a in active.items() if a.done < n_steps}
    first = next(iter(under_way))
    return SamplingStopped(first, under_way[first], n_steps, under_way)

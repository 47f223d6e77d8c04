"""The one parallel-map layer: every batch of independent tasks goes through here.

Two kinds of parallel work exist in rotorbayes:

* **kernel batches** — many parameter sets of one experiment, run by the compiled kernel in
  numba threads (:meth:`rotorbayes.Simulator.run_batch`); used by Jacobians and, later,
  by the vectorised log-posterior;
* **independent tasks** — whole fits (multistart), profiles, ensembles; they go through a
  :class:`Mapper` from :func:`get_mapper`.

A mapper is anything with ``map(fn, items)`` yielding ``(index, result)`` pairs as tasks
finish, plus ``workers``.  Threads suit the compiled kernel (it releases the GIL);
processes suit Python-heavy tasks; a cluster backend (Dask) plugs in here later.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Executor, ProcessPoolExecutor, ThreadPoolExecutor
from concurrent.futures import wait as _wait
from typing import Any


class Mapper:
    """Run independent tasks on a pool; results come back as they finish.

    Parameters
    ----------
    kind : {'serial', 'threads', 'processes'}
    workers : int
        Parallel tasks (default: the number of cores).
    """

    def __init__(self, kind: str = "threads", workers: int | None = None):
        if kind not in ("serial", "threads", "processes"):
            raise ValueError(f"unknown parallel backend {kind!r}; choose serial, threads or "
                             "processes")  # fmt: skip
        self.kind = kind
        self.workers = max(1, int(workers or os.cpu_count() or 1))
        if kind == "serial":
            self.workers = 1

    def _pool(self) -> Executor:
        if self.kind == "processes":
            return ProcessPoolExecutor(max_workers=self.workers)
        return ThreadPoolExecutor(max_workers=self.workers)

    def map(self, fn: Callable[[Any], Any], items: Sequence) -> Iterator[tuple[int, Any]]:
        """Yield ``(index, fn(items[index]))`` in order of completion.

        Stopping the iteration (e.g. Ctrl-C in the consumer) cancels the tasks that have
        not started; finished results already yielded are the caller's to keep.
        """
        if self.kind == "serial" or self.workers == 1:
            for i, it in enumerate(items):
                yield i, fn(it)
            return
        pool = self._pool()
        try:
            futures = {pool.submit(fn, it): i for i, it in enumerate(items)}
            pending = set(futures)
            while pending:
                done, pending = _wait(pending, return_when=FIRST_COMPLETED)
                for f in done:
                    yield futures[f], f.result()
        finally:
            pool.shutdown(wait=True, cancel_futures=True)


def get_mapper(kind: str = "threads", workers: int | None = None) -> Mapper:
    """The mapper for ``kind`` (``'serial'``, ``'threads'`` or ``'processes'``)."""
    return Mapper(kind, workers)


def map_ordered(fn: Callable, items: Iterable, mapper: Mapper | None = None) -> list:
    """``[fn(x) for x in items]`` on ``mapper`` (default threads), results in input order."""
    items = list(items)
    out: list = [None] * len(items)
    for i, r in (mapper or get_mapper()).map(fn, items):
        out[i] = r
    return out


def progress(results: Iterator, total: int, desc: str, *, enabled: bool = True) -> Iterator:
    """Wrap a mapper's ``(index, result)`` stream with a progress bar (tqdm, on stderr) when
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

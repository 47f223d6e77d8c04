"""Several studies at once: ``rotorbayes run a.toml b.toml ...`` (e.g. one analysis file
per data set of a campaign).

Each analysis file is one task on the executor layer (:mod:`rotorbayes.inference.parallel`:
local threads by default, processes, or Dask). A task runs its study as a command of its
own (``rotorbayes run FILE --quiet --backend serial`` in a child process), so a study that
fails, is killed or runs out of memory takes no other study with it, and each study keeps
every guarantee of a single ``run``: its folder's lock, stages written whole, and a rerun
that skips the stages whose inputs are unchanged - the same command after a kill or a
Ctrl-C continues where the studies stopped.

The child processes share the cores: with ``k`` studies running at once on ``c`` cores each
gets ``max(1, c // k)`` numba threads and one BLAS thread. On a Dask cluster a study runs on
one worker's machine and writes its output folder there: the analysis files, their data
and the output folders must be on a filesystem every worker shares (a worker that cannot
see an analysis file, or sees another version of it, says so and runs nothing).
"""

from __future__ import annotations

import hashlib
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from ...util.coldstart import PARENT_ENV
from ...util.exitcodes import BUSY, ENVIRONMENT, INTERRUPTED, Interrupted, Refused
from ..common import Outcome, executor


@dataclass(frozen=True)
class StudyTask:
    """One study for a worker: the analysis file (absolute), its SHA-256 as the command
    read it, ``--force``, and the numba threads its process may use."""

    file: str
    sha256: str
    force: bool
    numba_threads: int


#: A study refused as busy this soon after its start is tried again (a moment ago its
#: folder's lock may have been held by the child of a worker that was just killed).
BUSY_RETRIES, BUSY_WAIT = 3, 2.0

#: The studies' child processes running in this process (threads back-end), for Ctrl-C.
_RUNNING: set[subprocess.Popen] = set()
_RUNNING_LOCK = threading.Lock()


def run_one(task: StudyTask) -> dict:
    """Run one study in a child process on this worker; what it printed and its exit code.

    Module-level: process and Dask workers import it."""
    host = socket.gethostname()
    p = Path(task.file)
    row = {"file": task.file, "host": host, "seconds": 0.0, "stdout": "", "stderr": ""}
    shared_fs = (
        "studies of several analysis files on a cluster need the files, their "
        "data and the output folders on a filesystem every worker shares"
    )
    try:
        text = p.read_bytes()
    except OSError as exc:
        return {
            **row,
            "code": 2,
            "message": f"{p}: the worker on {host} cannot read it "
            f"({exc.strerror or type(exc).__name__}); {shared_fs}",
        }
    if hashlib.sha256(text).hexdigest() != task.sha256:
        return {
            **row,
            "code": 2,
            "message": f"{p}: the worker on {host} sees another "
            f"version of the file than the command read; {shared_fs}",
        }
    env = {
        **os.environ,
        "NUMBA_NUM_THREADS": str(task.numba_threads),
        "OPENBLAS_NUM_THREADS": "1",
        "OMP_NUM_THREADS": "1",
        "MKL_NUM_THREADS": "1",
        "PYTHONUNBUFFERED": "1",
    }
    env.pop("DASK_SCHEDULER_ADDRESS", None)  # the study's own tasks run in its process
    env[PARENT_ENV] = str(os.getpid())  # the child ends when this process is gone
    cmd = [
        sys.executable,
        "-m",
        "rotorbayes.cli",
        "run",
        str(p),
        "--quiet",
        "--backend",
        "serial",
        *(["--force"] if task.force else []),
    ]
    t0 = time.perf_counter()
    for attempt in range(BUSY_RETRIES + 1):
        code, out, err = _child(cmd, p.parent, env)
        if code != BUSY or time.perf_counter() - t0 > 10 or attempt == BUSY_RETRIES:
            break
        time.sleep(BUSY_WAIT)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    if code < 0:
        message = (
            f"its process was killed by signal {-code} (out of memory?); rerun the "
            "same command: the stages it finished are kept"
        )
    else:
        message = lines[-1] if code and lines else ""
    return {
        **row,
        "code": code,
        "seconds": time.perf_counter() - t0,
        "stdout": out,
        "stderr": err,
        "message": message,
    }


def _child(cmd: list[str], cwd: Path, env: dict) -> tuple[int, str, str]:
    proc = subprocess.Popen(
        cmd, cwd=cwd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    with _RUNNING_LOCK:
        _RUNNING.add(proc)
    try:
        out, err = proc.communicate()
    finally:
        with _RUNNING_LOCK:
            _RUNNING.discard(proc)
    return proc.returncode, out, err


def _stop_running() -> None:
    """Pass a Ctrl-C on to the studies running in this process's threads (a Ctrl-C at the
    terminal reaches them anyway; a SIGINT sent to the command alone does not)."""
    with _RUNNING_LOCK:
        procs = list(_RUNNING)
    for proc in procs:
        try:
            proc.send_signal(signal.SIGINT)
        except OSError:
            pass


def _headline(out: Path) -> str:
    """The study's final fit's worst RMS/floor and its folder, from its run.json."""
    import json

    try:
        rec = json.loads((out / "run.json").read_text(encoding="utf-8"))
        fit = json.loads((Path(rec["final_fit"]) / "fit.json").read_text(encoding="utf-8"))
        r = fit["assessment"]["worst_ratio_to_floor"]
    except (OSError, ValueError, KeyError, TypeError):
        return f"{out}/"
    return f"final fit {r:.3g}x the floor; {out}/"


def run_studies(
    files: list[str],
    *,
    force: bool = False,
    quiet: bool = False,
    backend: str | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
) -> Outcome:
    """Run the studies of several analysis files, several at a time (module docstring).

    Every file is checked before any work (a bad one is refused, exit code 2, nothing
    run); two files writing one output folder are refused. The exit code is 0 when every
    study ended with 0, 130 after a Ctrl-C, else the highest of the studies' codes
    (a study killed by a signal counts as 3). ``Outcome.doc``: ``{"studies": [...]}``, one
    row per file with its exit code, seconds, host and message."""
    from ...inference import parallel
    from .analysis import load_analysis

    analyses = [load_analysis(f) for f in files]  # AnalysisError: refused, nothing run
    seen: dict[Path, Path] = {}
    for a in analyses:
        out = a.out.resolve()
        if out in seen:
            what = (
                "is given twice"
                if seen[out] == a.path.resolve()
                else f"and {seen[out]} both write [analysis] out = {out}/"
            )
            raise Refused(f"{a.path} {what}; each study needs its own output folder")
        seen[out] = a.path.resolve()
    n = len(analyses)
    with executor(backend, workers, scheduler) as ex:
        at_once = (
            1
            if isinstance(ex, parallel.SerialExecutor)
            else min(n, getattr(ex, "_max_workers", None) or n)
        )
        local = not parallel.is_dask(ex)
        threads = max(1, (os.cpu_count() or 1) // at_once) if local else 1
        tasks = [
            StudyTask(
                str(a.path.resolve()),
                hashlib.sha256(a.path.read_bytes()).hexdigest(),
                force,
                threads,
            )
            for a in analyses
        ]
        each = f", {threads} numba thread{'s' if threads > 1 else ''} each" if local else ""
        print(
            f"{n} studies, {at_once if local else 'as many as the cluster runs'} at a "
            f"time{each}; each study's output in its log.txt",
            flush=True,
        )
        rows: list[dict | None] = [None] * n
        t0 = time.perf_counter()
        try:
            for k, (i, row) in enumerate(parallel.run_tasks(run_one, tasks, executor=ex), 1):
                rows[i] = row
                _say(k, n, analyses[i], row, quiet)
        except KeyboardInterrupt:
            _stop_running()
            done = sum(r is not None for r in rows)
            raise Interrupted(
                f"interrupted (Ctrl-C) after {done} of {n} studies had finished; any study "
                "under way stopped, keeping the stages it had finished. "
                "Run the same command again to continue: finished stages are skipped"
            ) from None
    codes = [r["code"] if r["code"] >= 0 else ENVIRONMENT for r in rows]
    failed = [(a, r) for a, r in zip(analyses, rows, strict=True) if r["code"] != 0]
    print(
        f"\n{n - len(failed)} of {n} studies done in {time.perf_counter() - t0:.0f} s"
        + (f"; {len(failed)} did not end with exit code 0:" if failed else "")
    )
    for a, r in failed:
        print(f"  {a.path}: exit code {r['code']}: {r['message']}")
    code = INTERRUPTED if INTERRUPTED in codes else max(codes)
    return Outcome(
        exit_code=code,
        doc={
            "studies": [{k: v for k, v in r.items() if k not in ("stdout", "stderr")} for r in rows]
        },
    )


def _say(k: int, n: int, a, row: dict, quiet: bool) -> None:
    if row["code"] == 0:
        what = f"done in {row['seconds']:.0f} s: {_headline(a.out)}"
    else:
        what = f"exit code {row['code']} after {row['seconds']:.0f} s: {row['message']}"
    print(f"[{k}/{n}] {a.path}: {what}", flush=True)
    tail = [ln for ln in row["stderr"].strip().splitlines() if ln.strip()][-6:-1]
    if not quiet and row["code"] != 0 and tail:  # what it said before its last line
        print("    " + "\n    ".join(tail), flush=True)

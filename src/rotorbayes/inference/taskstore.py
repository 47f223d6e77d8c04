"""Finished independent tasks kept on disk, so a re-run skips them (multistart starts,
profile points).

A command that runs many independent fits keeps each finished one in a hidden folder beside
its result folder, ``.NAME.tasks/`` (one small file per task, written to a temporary name
and renamed: a kill never leaves half a record). A re-run of the same command with the same
``--out`` after a kill, Ctrl-C or a lost Dask scheduler reads them and runs only the rest;
the result is bit for bit that of an uninterrupted run. The folder is removed once the
result folder is complete.

Nothing stale is reused: the folder holds the hash (:func:`fingerprint`) of everything the
results depend on — the data, the model and its effects (user effect files by their SHA-256),
the free set, the fixed values, the bounds, the settings and the rotorbayes version — and
every record holds the hash of its own task (the start vector, the grid value). A folder
made for another problem or with other settings is emptied, and said so, before the run.
"""

from __future__ import annotations

import hashlib
import io
import json
import math
import os
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

#: Name of the store beside a result folder ``out``: ``.{out.name}{TAG}``.
TAG = ".tasks"


def _update(h, obj) -> None:
    """Feed ``obj`` into the hash ``h`` in a canonical form (arrays by their bytes)."""
    if isinstance(obj, np.ndarray):
        a = np.ascontiguousarray(obj)
        h.update(f"nd{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    elif isinstance(obj, dict):
        h.update(b"{")
        for k in sorted(obj, key=str):
            _update(h, str(k))
            _update(h, obj[k])
        h.update(b"}")
    elif isinstance(obj, list | tuple):
        h.update(b"[")
        for v in obj:
            _update(h, v)
        h.update(b"]")
    elif isinstance(obj, float | np.floating):
        h.update(float(obj).hex().encode())
    else:
        h.update(repr(obj).encode())
    h.update(b";")


def fingerprint(*parts) -> str:
    """SHA-256 of ``parts`` (arrays, numbers, strings, nested lists and dicts)."""
    h = hashlib.sha256()
    for p in parts:
        _update(h, p)
    return h.hexdigest()


def problem_fingerprint(problem) -> str:
    """The hash of everything a fit of ``problem`` depends on: data, model, effects (user
    effect files by their SHA-256), free set, fixed values, bounds, channels, weights, the
    integrator's step and the rotorbayes version."""
    from ..model import effects as _effects
    from ..util import __version__

    m = problem.model
    data = [
        [ex.t, ex.u, ex.theta_u, ex.theta_l if ex.theta_l is not None else "none"]
        for ex in problem.experiments
    ]
    added = [
        [e.name, e.source, _effects.file_sha256(e.source) if e.source != "catalogue" else ""]
        for e in m.added
    ]
    return fingerprint(
        __version__,
        data,
        problem.config,
        list(m.effect_names),
        added,
        bool(problem.prescribed_upper),
        list(problem.names),
        {k: float(v) for k, v in problem.base.items()},
        problem.lower,
        problem.upper,
        list(problem.channels),
        dict(problem.weights),
        problem.shape,
        "none" if problem.step is None else float(problem.step),
    )


def store_path(out: str | os.PathLike) -> Path:
    """The store of the result folder ``out``."""
    out = Path(out)
    return out.parent / f".{out.name}{TAG}"


def remove_store(out: str | os.PathLike) -> None:
    """Remove the store of the result folder ``out`` (its result is complete)."""
    shutil.rmtree(store_path(out), ignore_errors=True)


class TaskStore:
    """Finished tasks of one run, keyed by task index and checked by hash.

    Parameters
    ----------
    folder : path
        The store (:func:`store_path` of the result folder).
    key : str
        :func:`fingerprint` of the problem and settings; a store with another key is
        emptied.
    what : str
        What a task is, for messages ("start", "profile point").
    """

    def __init__(self, folder: str | os.PathLike, key: str, what: str = "task"):
        self.folder = Path(folder)
        self.key = key
        self.what = what
        self.reused = 0
        keyfile = self.folder / "key.json"
        if self.folder.exists():
            try:
                old = json.loads(keyfile.read_text()).get("key")
            except (OSError, ValueError, AttributeError):
                old = None
            if old != key:
                print(
                    f"note: {self.folder} holds {what}s of another problem or other "
                    "settings (or is damaged): not reused, removed",
                    file=sys.stderr,
                )
                shutil.rmtree(self.folder, ignore_errors=True)
        self.folder.mkdir(parents=True, exist_ok=True)
        if not keyfile.exists():
            self._write(keyfile, json.dumps({"key": key, "what": what}).encode())

    def _write(self, path: Path, data: bytes) -> None:
        fd, tmp = tempfile.mkstemp(prefix=".tmp-", dir=self.folder)
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(data)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, path)
        except BaseException:
            try:
                os.unlink(tmp)
            except OSError:
                pass
            raise

    def _file(self, index: int) -> Path:
        return self.folder / f"{int(index):06d}.npz"

    def get(self, index: int, task_key: str) -> tuple[bool, dict | None]:
        """``(True, record)`` if task ``index`` finished with the same ``task_key``."""
        try:
            with np.load(self._file(index), allow_pickle=False) as z:
                rec = {k: z[k] for k in z.files}
            meta = json.loads(str(rec.pop("__meta__")))
        except FileNotFoundError:
            return False, None
        except Exception:  # noqa: BLE001 - a damaged record: run the task again
            return False, None
        if meta.get("task") != task_key:
            return False, None
        self.reused += 1
        rec.update({k: (math.nan if v is None else v) for k, v in meta["values"].items()})
        return True, rec

    def put(self, index: int, task_key: str, record: dict) -> None:
        """Keep the record of task ``index`` (atomically: whole or not at all): arrays and
        plain values (numbers, strings, booleans, None; NaN is kept)."""
        arrays = {k: v for k, v in record.items() if isinstance(v, np.ndarray)}
        values = {
            k: (None if isinstance(v, float) and math.isnan(v) else v)
            for k, v in record.items()
            if k not in arrays
        }
        buf = io.BytesIO()
        # numpy's stub types **kwds as if they could fill allow_pickle (a bool).
        np.savez(buf, __meta__=np.array(json.dumps({"task": task_key, "values": values})), **arrays)  # type: ignore[arg-type]
        self._write(self._file(index), buf.getvalue())

    def remove(self) -> None:
        """The run is complete and its results are in place: the store is not needed."""
        shutil.rmtree(self.folder, ignore_errors=True)

"""The first run compiles the integrator; say so, in one line, with the real wall time.

Nothing is compiled when rotorbayes is imported.  Each of the solver's entry points
(:data:`rotorbayes.kernel.solver.SIGNATURES`: a simulation, the residuals, their parallel
batches; each plain, full or with user hooks) is compiled by numba when a command first
uses it (:func:`kernel_entry`) and kept in numba's on-disk cache, so a command compiles
only what it uses: a simulation alone, or the residuals with what a fit uses with them
(their batch for the Jacobian's columns, the simulation of the result, the least squares'
compiled helpers; :data:`GROUPS`, :data:`FIT_HELPERS`).
With a cold cache (a fresh install, a new Python, an edited kernel) :func:`kernel_entry`
says what is happening before and how long it took after, on stderr, in one line; with a
warm one it says nothing.  Measured with an empty cache (``benchmarks/bench_coldstart.py``;
CPU seconds of the compiling process, one core's time, 2 cores shared with other work,
every numba compilation of the command counted): the first ``rotorbayes simulate``
compiles for 14-14.5 s, the first ``rotorbayes fit`` for 15.2-15.4 s of wall time, its
least squares' helpers compiled meanwhile by a second process on the other core
(:func:`_compile_aside`; 19.5-20.5 s in one process; 17-18.7 s and 26.5-26.8 s, in three
lines for the fit, before a batch called its row by address, the collector paused and the
helpers compiled more cheaply).  Before, every entry point was compiled at import: 121 s.
"""

from __future__ import annotations

import contextlib
import functools
import importlib.util
import os
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

#: Set in a process rotorbayes starts as a child (a study of ``run a.toml b.toml ...``): the
#: pid of the process that started it. The child ends itself when that process is gone (a
#: Dask worker or the command killed), so no study runs on unwatched while the scheduler
#: gives its task to another worker.
PARENT_ENV = "ROTORBAYES_PARENT_PID"

#: The notice's first part (tests look for it); the whole line reads "rotorbayes: compiling
#: the integrator (the residuals, their parallel batches and the simulation, plain kernel),
#: once: numba caches it for later runs ... took 17 s".
MESSAGE = "rotorbayes: compiling the integrator"


def _cache_dirs(kernel_dir: Path) -> list[Path]:
    """Where numba keeps the kernel's cache, in numba's order of precedence: NUMBA_CACHE_DIR
    if set; else beside the source if that folder is writable; else the user-wide cache."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return [Path(os.environ["NUMBA_CACHE_DIR"])]
    if os.access(kernel_dir, os.W_OK):
        return [kernel_dir / "__pycache__"]
    return [Path.home() / ".cache" / "numba"]


def _index_is_current(index: Path, source: Path, numba_version: str | None) -> bool:
    """Whether numba would take the cache entry ``index`` (a ``.nbi`` file) for ``source``.

    An index holds numba's version, then the source's stamp: a SHA-256 of its content in
    numba >= 0.61 (a checkout or a copy that changes only the file's time keeps the cache),
    ``(mtime, size)`` before.  Anything unreadable counts as not current."""
    import hashlib
    import pickle

    try:
        with open(index, "rb") as f:
            version = pickle.load(f)
            stamp, _ = pickle.loads(f.read())
    except Exception:  # noqa: BLE001 -- a damaged or foreign index: numba would recompile
        return False
    if numba_version is not None and version != numba_version:
        return False
    if isinstance(stamp, bytes):
        return stamp == hashlib.sha256(source.read_bytes()).digest()
    st = source.stat()
    return tuple(stamp) == (st.st_mtime, st.st_size)


def _solver_source(module: str = "solver") -> tuple[Path, Path] | None:
    """``(kernel folder, solver.py)`` (or another kernel ``module``'s file) of the installed
    package, or None."""
    spec = importlib.util.find_spec("rotorbayes.kernel")
    if spec is None or not spec.submodule_search_locations:
        return None
    kernel_dir = Path(next(iter(spec.submodule_search_locations)))
    return kernel_dir, kernel_dir / f"{module}.py"


def cache_is_cold(name: str = "*", module: str = "solver") -> bool:
    """True when numba has no cache entry of the solver's function ``name`` (``"*"``: of
    any of its functions; of another kernel ``module``'s) that matches its source for this
    Python and this numba (numba would compile it)."""
    from importlib.metadata import PackageNotFoundError, version

    found_source = _solver_source(module)
    if found_source is None:
        return False
    kernel_dir, source = found_source
    try:
        numba_version = version("numba")
    except PackageNotFoundError:
        numba_version = None
    tag = f"py{sys.version_info.major}{sys.version_info.minor}"
    for d in _cache_dirs(kernel_dir):
        if not d.is_dir():
            continue
        pattern = f"{module}.{name}-*.{tag}.nbi" if name != "*" else f"{module}.*.{tag}.nbi"
        found = d.glob(pattern) if d.name == "__pycache__" else d.rglob(pattern)
        if any(_index_is_current(p, source, numba_version) for p in found):
            return False
    return True


def compile_kernel(stream=None) -> float | None:
    """Import the kernel.  Nothing is compiled at import any more (see
    :func:`kernel_entry`), so this returns None and prints nothing; kept for callers that
    load the package before timing it."""
    if "rotorbayes.kernel.solver" in sys.modules:
        return None
    # The model first: it imports the kernel in the order the package's modules expect.
    importlib.import_module("rotorbayes.model")
    importlib.import_module("rotorbayes.kernel.solver")
    return None


#: What each entry point is, in the compile notice.
_WHAT = {
    "residuals_into": "the residuals",
    "residuals_batch_into": "their parallel batches",
    "simulate_into": "the simulation",
    "simulate_batch_into": "its parallel batches",
}

#: What the first use of an entry point compiles with it, in one go and said in one line
#: (by the entry point without its kernel's suffix): the residuals' first use is a fit's,
#: whose Jacobian's columns are a batch of residuals and whose result is a simulation (a
#: first ``fit`` said three lines, and compiled its least squares' helpers unsaid); a
#: simulation is compiled alone (``simulate``).
GROUPS = {
    "residuals_into": ("residuals_into", "residuals_batch_into", "simulate_into"),
    "residuals_batch_into": ("residuals_into", "residuals_batch_into", "simulate_into"),
    "simulate_into": ("simulate_into",),
    "simulate_batch_into": ("simulate_into", "simulate_batch_into"),
}

#: The compiled helpers outside the solver that a fit's least squares uses with the
#: residuals (all parallel), as ``(kernel module, function, argument types)``: the
#: Jacobian's difference quotients and the QR triangle of ``[J | r]``
#: (:mod:`rotorbayes.kernel.triangle`), for the arrays the least squares passes.
FIT_HELPERS = (
    ("triangle", "difference_quotients", "float64[:, ::1], float64[::1], float64[::1]"),
    ("triangle", "triangle", "float64[:, ::1], float64[::1], float64[::1], float64[::1]"),
)

#: The entry points ready in this process, by name (the hot path looks here first).
_READY: dict = {}
_COMPILING = threading.Lock()

#: Seconds (wall time) each entry point took to compile in this process (a cold cache only)
#: ...
COMPILE_SECONDS: dict[str, float] = {}
#: ... and the CPU seconds of this process meanwhile (numba compiles on one core: on a busy
#: machine this is the figure an idle core would give).
COMPILE_CPU_SECONDS: dict[str, float] = {}


def _split(name: str) -> tuple[str, str]:
    """``(entry point, kernel suffix)``: ``"residuals_into_plain"`` -> ``("residuals_into",
    "_plain")``; the kernel with user effects has no suffix."""
    for suffix in ("_plain", "_full"):
        if name.endswith(suffix):
            return name[: -len(suffix)], suffix
    return name, ""


def group_of(name: str, parallel: bool = True) -> list[str]:
    """The entry points compiled together with ``name`` (``name`` among them): see
    :data:`GROUPS`; without the parallel batches but ``name`` if not ``parallel``."""
    base, suffix = _split(name)
    return [m + suffix for m in GROUPS[base] if m == base or parallel or "batch" not in m]


def _helpers(name: str, parallel: bool) -> list[tuple]:
    """``(module, function name, dispatcher, argument types)`` of the helpers compiled
    with ``name`` (:data:`FIT_HELPERS` with the residuals), not yet compiled."""
    if not parallel or _split(name)[0] not in ("residuals_into", "residuals_batch_into"):
        return []
    from numba.core import sigutils

    out = []
    for module, fn_name, arg_types in FIT_HELPERS:
        fn = getattr(importlib.import_module(f"rotorbayes.kernel.{module}"), fn_name)
        args, _ = sigutils.normalize_signature(f"({arg_types},)")
        if args not in fn.overloads:
            out.append((module, fn_name, fn, args))
    return out


#: Set to ``0`` to compile a fit's helpers in the command's own process, after the solver
#: (see :func:`_compile_aside`).
ASIDE_ENV = "ROTORBAYES_COMPILE_ASIDE"
#: Longest wait for the helpers compiled aside [s]; past it the command compiles them itself.
ASIDE_TIMEOUT = 120.0


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def _compile_aside(helpers: list[tuple]):
    """Start a process that compiles ``helpers`` (:func:`_helpers`' entries) into numba's
    cache while this one compiles the solver (numba compiles one function at a time per
    process, on one core): the first fit's least-squares helpers (3.1 of its 20 CPU s on
    these 2 cores) come off its wall time.  The command loads them from the cache
    afterwards, or compiles them itself where the other process could not.  None (nothing
    started) with one core, with :data:`ASIDE_ENV` ``=0``, or where the cache cannot be
    written."""
    specs = [
        f"{m}:{f}:{types}"
        for m, f, _, _ in helpers
        for mm, ff, types in FIT_HELPERS
        if (mm, ff) == (m, f)
    ]
    return _spawn_aside(specs)


def _spawn_aside(specs: list[str]):
    """The process of :func:`compile_aside_main` for ``specs``, started; or None (see
    :func:`_compile_aside`)."""
    import subprocess

    if not specs or os.environ.get(ASIDE_ENV, "1") == "0" or _cores() < 2:
        return None
    found = _solver_source("triangle")
    if found is None:
        return None
    where = _cache_dirs(found[0])[0]
    if not os.access(where if where.exists() else where.parent, os.W_OK):
        return None
    env = dict(os.environ, **{PARENT_ENV: str(os.getpid())})
    code = "from rotorbayes.util.coldstart import compile_aside_main; compile_aside_main()"
    try:
        return subprocess.Popen(
            [sys.executable, "-c", code, *specs],
            env=env,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
    except OSError:
        return None


def _await_aside(child) -> None:
    """Wait for the process of :func:`_compile_aside` (ended, if it takes too long)."""
    if child is None:
        return
    import subprocess

    try:
        child.wait(timeout=ASIDE_TIMEOUT)
    except subprocess.TimeoutExpired:
        _end_aside(child)


def _end_aside(child) -> None:
    """End the process of :func:`_spawn_aside` (None: nothing to end)."""
    if child is not None:
        child.kill()
        child.wait()


def compile_aside_main() -> None:
    """The process :func:`_compile_aside` starts: compile each ``module:function:types``
    of its arguments (into numba's cache)."""
    from numba.core import sigutils

    end_with_parent()
    for spec in sys.argv[1:]:
        if spec.startswith(CALL):
            module, fn_name = spec[len(CALL) :].split(":", 1)
            getattr(importlib.import_module(module), fn_name)()
            continue
        module, fn_name, arg_types = spec.split(":", 2)
        fn = getattr(importlib.import_module(f"rotorbayes.kernel.{module}"), fn_name)
        args, _ = sigutils.normalize_signature(f"({arg_types},)")
        fn.compile(args)


#: The sensitivity kernel's key in :data:`COMPILE_SECONDS`.
SENSITIVITY = "sensitivity"
#: :func:`compile_aside_main`'s argument for a function to call (``CALL`` +
#: ``"package.module:function"``) rather than a kernel helper to compile.
CALL = "call="
#: The sensitivity kernel in this process: ``ready`` once loaded or compiled, ``child``
#: the process compiling it aside (:func:`sensitivity_aside`).
_SENS: dict = {"ready": False, "child": None}
#: What the notice says the sensitivity kernel is.
_SENS_WHAT = "the sensitivities, for the Jacobian"


def sensitivity_aside(compile_call: str) -> None:
    """A command that will take Jacobians by sensitivities: where numba's cache has no
    sensitivity kernel, start compiling it in a second process now, while this one
    compiles the solver (20-27 CPU s on these 2 cores; the first ``fit --jacobian
    sensitivity`` of a 30 s brake record took 46.1 s of wall time, 26 s of it unsaid inside
    the fit, and takes 31.5 s so).  :func:`first_sensitivities` waits for it.  The process
    calls ``compile_call`` (``"package.module:function"``): a function of the layer that
    knows the kernel's arguments (:func:`rotorbayes.inference.problem.compile_sensitivity_kernel`;
    this module stays below it)."""
    with _COMPILING:
        if _SENS["ready"] or _SENS["child"] is not None:
            return
        if not cache_is_cold("sensitivities_into", "sensitivity"):
            return
        _SENS["child"] = _spawn_aside([CALL + compile_call])


@contextlib.contextmanager
def first_sensitivities(stream=None):
    """Around a call of the sensitivity kernel: on its first use in this process with a
    cold cache, say so in one line with the wall time (the call compiles it, or loads what
    the process of :func:`sensitivity_aside` compiled: waited for here)."""
    if _SENS["ready"]:
        yield
        return
    with _COMPILING:
        if _SENS["ready"]:
            yield
            return
        child, _SENS["child"] = _SENS["child"], None
        cold = child is not None or cache_is_cold("sensitivities_into", "sensitivity")
        stream = sys.stderr if stream is None else stream
        t0 = time.perf_counter()
        if cold:
            print(f"{MESSAGE} ({_SENS_WHAT}), once: numba caches it for later runs ...",
                  end="", file=stream, flush=True)  # fmt: skip
        try:
            _await_aside(child)
            child = None
            yield
            _SENS["ready"] = True
        finally:
            _end_aside(child)  # stopped before the call: the other process goes too
            if cold:
                COMPILE_SECONDS[SENSITIVITY] = time.perf_counter() - t0
                print(f" took {time.perf_counter() - t0:.0f} s", file=stream, flush=True)


def notice(names) -> str:
    """The compile notice's first part for entry points ``names`` (of one kernel): "rotorbayes:
    compiling the integrator (the residuals, their parallel batches and the simulation,
    plain kernel), once: numba caches it for later runs ..."."""
    parts = [_WHAT[_split(n)[0]] for n in names]
    what = parts[0] if len(parts) == 1 else ", ".join(parts[:-1]) + " and " + parts[-1]
    suffix = _split(names[0])[1]
    kernel = f"{suffix[1:]} kernel" if suffix else "kernel with user effects"
    return f"{MESSAGE} ({what}, {kernel}), once: numba caches it for later runs ..."


def kernel_entry(name: str, stream=None, *, parallel: bool = True):
    """The solver's entry point ``name`` (a key of
    :data:`rotorbayes.kernel.solver.SIGNATURES`), compiled or loaded from numba's cache on
    its first use in this process, with what goes with it (:data:`GROUPS`,
    :data:`FIT_HELPERS`; the parallel ones only if ``parallel``: a process that forks
    must not have loaded them, they start numba's threads).  With a cold cache the
    compilation is said on stderr (``stream``), in one line: :data:`MESSAGE` before, the
    wall time of the whole after."""
    fn = _READY.get(name)
    if fn is not None:
        return fn
    with _COMPILING:  # threads of one process (a multistart) compile and say it once
        return _compile_entry(name, stream, parallel)


def _is_cold(solver, name: str) -> bool:
    """Whether entry point ``name`` is neither ready in this process nor in numba's cache
    (its compiled function's, and a batch's row's)."""
    if solver.is_ready(name):
        return False
    names = [name] + ([solver.BATCHES[name][1]] if name in solver.BATCHES else [])
    return any(cache_is_cold(solver.compiled(n).__name__) for n in names)


def _compile_entry(name: str, stream, parallel: bool = True):
    fn = _READY.get(name)
    if fn is not None:
        return fn
    import gc

    from ..kernel import solver

    names = [n for n in group_of(name, parallel) if n not in _READY]
    cold_entries = [n for n in names if _is_cold(solver, n)]
    helpers = _helpers(name, parallel)
    cold = list(cold_entries)
    aside = None
    if cold:  # the helpers are said with the entry points; compiled alone, they are not
        cold_helpers = [h for h in helpers if cache_is_cold(h[1], h[0])]
        cold += [f"{m}.{f}" for m, f, _, _ in cold_helpers]
        if cold_entries:
            aside = _compile_aside(cold_helpers)
    stream = sys.stderr if stream is None else stream
    if cold:
        print(notice(cold_entries), end="", file=stream, flush=True)
    t_all = time.perf_counter()
    # numba makes millions of small objects while it compiles; with the command's modules
    # loaded (a third of a million objects) Python's cyclic collections took 1.5-2 of a
    # first fit's CPU seconds, walking the same old objects again and again.  None while
    # numba compiles, one of the young objects after each entry point (0.1-0.4 s, counted
    # in its time); the command's peak memory is 500 MB instead of 420 MB.
    collecting = gc.isenabled()
    jobs: list[tuple[str, Callable[[], Any]]] = [
        (n, functools.partial(solver.entry, n)) for n in names
    ]
    jobs += [(f"{m}.{f}", functools.partial(fn.compile, args)) for m, f, fn, args in helpers]
    try:
        for n, job in jobs:
            if n not in names:  # a helper: compiled aside meanwhile, or here
                _await_aside(aside)
                aside = None
            t0, c0 = time.perf_counter(), time.process_time()
            gc.disable()
            try:
                done = job()
            finally:
                if collecting:
                    gc.enable()
                    gc.collect(0)
            if n in names:
                _READY[n] = done
            if n in cold:
                COMPILE_SECONDS[n] = time.perf_counter() - t0
                COMPILE_CPU_SECONDS[n] = time.process_time() - c0
    finally:
        _end_aside(aside)  # stopped before the helpers: the other process goes too
        if cold:
            print(f" took {time.perf_counter() - t_all:.0f} s", file=stream, flush=True)
    return _READY[name]


def launched_as_command() -> bool:
    """True when this process is the ``rotorbayes`` command (the console script or
    ``python -m rotorbayes.cli``), not Python code that imports the package."""
    argv = list(getattr(sys, "orig_argv", sys.argv))
    if "-m" in argv[:-1] and argv[argv.index("-m") + 1] == "rotorbayes.cli":
        return True
    return Path(sys.argv[0]).name == "rotorbayes" if sys.argv and sys.argv[0] else False


LOADING_MESSAGE = "\nrotorbayes: interrupted (Ctrl-C) while loading; nothing was written"


def _stop_while_loading(signum, frame) -> None:
    print(LOADING_MESSAGE, file=sys.stderr, flush=True)
    os._exit(130)


def stop_at_once_while_loading() -> None:
    """In the command only: until :func:`loaded`, a Ctrl-C ends the process at once, exit
    code 130 and one line.  Nothing is written while the command loads, so nothing is lost.

    A KeyboardInterrupt raised while numba and the command's modules import lands anywhere:
    inside a callback Python runs on its own (importlib's module-lock weakref callback),
    where Python prints "Exception ignored ... KeyboardInterrupt" and the command goes on
    as if never asked to stop, or in a module's top level outside any handler (a
    traceback); and Python 3.11 sometimes ended such a process by SIGINT (exit -2) after
    the message (measured: 7 of 40 stops 0.1-1.5 s after the start, 5 of 40 at 0.9-1.6 s).
    """
    if not launched_as_command():
        return
    import signal

    try:
        signal.signal(signal.SIGINT, _stop_while_loading)
    except ValueError:  # not the main thread: leave Python's handler
        pass


#: How many Ctrl-Cs the command has been sent since it loaded (see :func:`ctrl_c_seen`).
_CTRL_C = [0]


def _interrupt(signum, frame) -> None:
    _CTRL_C[0] += 1
    raise KeyboardInterrupt


def ctrl_c_seen() -> bool:
    """True once the command (after :func:`loaded`) has been sent a Ctrl-C.

    A KeyboardInterrupt raised while C code calls back into Python can come out as another
    exception: inside numba's unboxing of a function argument it left a NULL in place of
    the signature and surfaced as ``TypeError: _get_jit_address() missing 1 required
    positional argument`` (1 of 6 stops in a CI run).  The command then reports the stop it
    was asked for, not that exception."""
    return _CTRL_C[0] > 0


def loaded() -> None:
    """The command has loaded and parsed its arguments: from here on a Ctrl-C is a
    KeyboardInterrupt again, which each command turns into its own message (and
    :func:`ctrl_c_seen` remembers it)."""
    import signal

    _CTRL_C[0] = 0  # per command (tests run several in one process)
    if signal.getsignal(signal.SIGINT) is _stop_while_loading:
        signal.signal(signal.SIGINT, _interrupt)


def interrupted_while_loading() -> None:
    """Called on a Ctrl-C during the package's import: the command ends with exit code 130
    and one line (nothing has been written yet); imported as a library, nothing happens
    here and the caller re-raises."""
    if launched_as_command():
        _stop_while_loading(None, None)


def end_with_parent() -> None:
    """In a child process (:data:`PARENT_ENV` set): end this process by SIGTERM once the
    process that started it is gone (every result is written whole or not at all, so an
    end at any moment loses only the work under way)."""
    pid = os.environ.pop(PARENT_ENV, None)  # not inherited further
    if not pid or not pid.isdigit():
        return
    import signal
    import threading

    def watch() -> None:
        while True:
            time.sleep(0.5)
            if os.getppid() != int(pid):
                os.kill(os.getpid(), signal.SIGTERM)
                return

    threading.Thread(target=watch, name="rotorbayes-parent-watch", daemon=True).start()

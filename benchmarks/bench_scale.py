"""Scale: one brake fit on 1 and N numba threads, and a multistart per back-end, side by side.

The problem is issue 34's: the 30 s brake experiment at 1 kHz (thesis table 4.3 P_ref,
``estimation_signal(30.0, seed=1)``, quantised angles), its 13 default free parameters.

1. **One fit** from a Latin-hypercube start, on 1 numba thread and on N, best of
   ``--repeat``; the time split into the kernel (residuals at the trial points, the
   Jacobian's batch) and the rest (scipy's trust-region solver: an SVD of the 60 002 x 13
   Jacobian per iteration, on one BLAS thread), so the bound on what threads can give is
   printed beside the figure.
2. **Pool start-up**: N no-op tasks on a fresh process pool, spawned (each worker imports
   rotorbayes and loads the kernel) against forked from the fork server that loaded it once.
3. **A multistart** of ``--starts`` starts (seed 0, Latin hypercube over the bounds) per
   back-end: serial on 1 numba thread (the reference), serial on N, local threads, local
   processes as before (spawned, one numba thread per worker) and as now (fork server, the
   cores shared by the running starts' kernel batches), and a local Dask cluster (``--dask``).
   Wall time includes starting the pool; starts per second, speed-up over the reference,
   core efficiency (speed-up / N), whether the end points equal the reference's bit for bit,
   and the bound the slowest start puts on any back-end (max(sum / N, slowest start)).
4. **sample's ensembles** (``--ensembles``, ``--walkers``, ``--steps``, from the best start's
   end point) per back-end: the serial loop on 1 numba thread (the reference) and on N (the
   command's default: the walkers are one kernel batch), and the ensembles as concurrent
   tasks in threads, processes and on Dask; ensembles per second, walker evaluations per
   second, speed-up, core efficiency and whether the chains equal the reference's bit for
   bit.

Both tables are printed side by side at the end, with the back-end a command's default
would pick for the multistart here and why.  ``--quick`` (about a minute on 2 cores):
the brake experiment cut to 10 s, 16 starts, 2 ensembles of 2 x (coordinates) walkers x 20
steps, one
repeat, no pool start-up and no "before" rows.

    python benchmarks/bench_scale.py [--quick] [--starts 48] [--workers N] [--dask]
        [--jacobian sensitivity]
                                     [--json out.json]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import sys
import time
from concurrent.futures import ProcessPoolExecutor

import numba
import numpy as np

import rotorbayes as rb
from rotorbayes import inference
from rotorbayes.inference import parallel, problem
from rotorbayes.inference.multistart import latin_hypercube, multistart


def brake_problem(seconds: float) -> inference.Problem:
    p = rb.parameters.thesis_set("4.3", "P_ref")
    t, u = rb.signals.estimation_signal(seconds, seed=1)
    sim = rb.simulate(p, u, dt=float(t[1] - t[0]), config="brake", alpha0=0.0, quantize_angles=True)
    return inference.Problem("brake", [sim.to_experiment("brake_1khz")], base=p)


class KernelClock:
    """Seconds spent in the kernel's calls of a fit (residuals and Jacobian batches)."""

    def __init__(self):
        self.t = 0.0
        self._res, self._jac = problem.Problem.residuals, problem.Problem.jacobian

    def __enter__(self):
        clock = self

        def res(self_, *a, **k):
            s = time.perf_counter()
            try:
                return clock._res(self_, *a, **k)
            finally:
                clock.t += time.perf_counter() - s

        def jac(self_, *a, **k):
            s = time.perf_counter()
            try:
                return clock._jac(self_, *a, **k)
            finally:
                clock.t += time.perf_counter() - s

        problem.Problem.residuals, problem.Problem.jacobian = res, jac
        return self

    def __exit__(self, *exc):
        problem.Problem.residuals, problem.Problem.jacobian = self._res, self._jac


#: The Jacobian's method of every fit (``--jacobian``; None: the package's default).
JACOBIAN: str | None = None


def one_fit(prob, x0, threads: int, repeat: int, blas: int = 1, compressed: bool = True) -> dict:
    from threadpoolctl import threadpool_limits

    numba.set_num_threads(threads)
    best = None
    for _ in range(repeat):
        with threadpool_limits(blas), KernelClock() as clock:
            s = time.perf_counter()
            r = inference.fit(prob, x0, uncertainty=False, compressed=compressed, jacobian=JACOBIAN)
            w = time.perf_counter() - s
        if best is None or w < best["wall"]:
            best = {
                "wall": w,
                "kernel": clock.t,
                "rest": w - clock.t,
                "nfev": r.nfev,
                "njev": r.njev,
                "ssr": r.ssr,
                "x": r.x.tolist(),
            }
    return best


def _noop(i):
    return os.getpid()


def startup(pool_factory, n: int) -> float:
    s = time.perf_counter()
    with pool_factory() as ex:
        list(ex.map(_noop, range(n)))
    return time.perf_counter() - s


def old_process_pool(n: int):
    """The process pool before issue 34: spawned workers, one numba thread each."""
    import multiprocessing as mp

    return ProcessPoolExecutor(
        max_workers=n, mp_context=mp.get_context("spawn"), initializer=parallel._process_initializer
    )


def run_multistart(prob, starts: int, executor, **fit_kw) -> tuple[float, object]:
    s = time.perf_counter()
    if JACOBIAN is not None:
        fit_kw.setdefault("jacobian", JACOBIAN)
    res = multistart(prob, starts, seed=0, executor=executor, progress=False, **fit_kw)
    return time.perf_counter() - s, res


@contextlib.contextmanager
def _one_thread(executor):
    """``executor`` with numba on one thread while it is open."""
    numba.set_num_threads(1)
    try:
        yield executor
    finally:
        numba.set_num_threads(int(numba.config.NUMBA_NUM_THREADS))


def same(a, b) -> bool:
    return (
        np.array_equal(a.ends, b.ends)
        and np.array_equal(a.ssr, b.ssr)
        and sorted(a.failed) == sorted(b.failed)
    )


def chains(path) -> bytes:
    """Every ensemble's chain and log-probabilities in ``chain.h5``, as bytes."""
    import h5py

    with h5py.File(path, "r") as f:
        return b"".join(
            np.asarray(f[k][d][: int(f[k].attrs["iteration"])]).tobytes()
            for k in sorted(f)
            for d in ("chain", "log_prob")
        )


def run_sample(lp, x, folder, a, executor) -> tuple[float, bytes]:
    from rotorbayes.inference import sampling

    s = time.perf_counter()
    sampling.sample(
        lp,
        x,
        folder,
        n_walkers=a.walkers,
        n_steps=a.steps,
        n_ensembles=a.ensembles,
        seed=0,
        progress=False,
        executor=executor,
    )
    return time.perf_counter() - s, chains(folder / "chain.h5")


def main() -> None:
    from threadpoolctl import threadpool_limits

    # One BLAS thread here, as in every worker: numpy may have loaded OpenBLAS before
    # rotorbayes's import could limit it (numba imports numpy), and an SVD on 16 BLAS
    # threads rounds otherwise than on one (the end points would differ by back-end).
    with threadpool_limits(1):
        _main()


def _main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--starts", type=int)
    ap.add_argument("--seconds", type=float)
    ap.add_argument("--workers", type=int, default=os.cpu_count())
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--dask", action="store_true", help="also a local Dask cluster")
    ap.add_argument(
        "--skip", default="", help="back-ends to leave out (parts of their labels), separated by ;"
    )
    ap.add_argument("--ensembles", type=int)
    ap.add_argument("--walkers", type=int)
    ap.add_argument("--steps", type=int)
    ap.add_argument(
        "--quick", action="store_true", help="10 s of data, 16 starts, 2 ensembles of 20 steps"
    )
    ap.add_argument("--json")
    ap.add_argument(
        "--jacobian",
        choices=("differences", "sensitivity"),
        help="every fit's Jacobian method (default: the package's, differences)",
    )
    a = ap.parse_args()
    global JACOBIAN
    JACOBIAN = a.jacobian
    n = a.workers
    skip = set(filter(None, a.skip.split(";")))
    # The sizes not given: issue 34's, or --quick's (any of them can still be given).
    size = (
        dict(seconds=10.0, starts=16, ensembles=2, walkers=16, steps=20)
        if a.quick
        else dict(seconds=30.0, starts=48, ensembles=4, walkers=32, steps=40)
    )
    for k, v in size.items():
        if getattr(a, k) is None:
            setattr(a, k, v)
    if a.quick:
        a.repeat = 1
        skip |= {"startup", "before", "serial, "}
    maxth = int(numba.config.NUMBA_NUM_THREADS)
    out: dict = {
        "cores": os.cpu_count(),
        "workers": n,
        "numba_threads": maxth,
        "cpu": platform.processor() or platform.machine(),
        "python": sys.version.split()[0],
        "numba": numba.__version__,
        "jacobian": a.jacobian or "differences",
    }
    print(
        f"{os.cpu_count()} cores, {maxth} numba threads, N = {n}, Python "
        f"{out['python']}, numba {numba.__version__}; load average "
        f"{os.getloadavg()[0]:.1f}",
        flush=True,
    )
    prob = brake_problem(a.seconds)
    x0 = latin_hypercube(prob, 4, np.random.default_rng(0))[1]
    inference.fit(prob, x0, uncertainty=False, max_nfev=2)  # the threading layer launched
    print(
        f"threading layer {numba.threading_layer()}; {prob.n_residuals} residuals, "
        f"{len(prob.names)} free",
        flush=True,
    )

    # 1. one fit
    fits = {}
    th_n = min(n, maxth)
    kinds = [
        ("1 thread", 1, 1, True),
        (f"{th_n} threads", th_n, 1, True),
        ("1 thread, whole J (before)", 1, 1, False),
        (f"{th_n} threads, whole J (before)", th_n, 1, False),
        (f"{th_n} threads + {n} BLAS, whole J", th_n, n, False),
    ]
    for label, th, blas, comp in kinds:
        if (a.quick and "before" in label) or any(k in label for k in skip):
            continue
        fits[label] = f = one_fit(prob, x0, th, a.repeat, blas, comp)
        ref_label = "1 thread" if comp else "1 thread, whole J (before)"
        ref_fit = fits.get(ref_label, f)
        print(
            f"one fit, {label:>32}: {f['wall']:.3f} s (kernel {f['kernel']:.3f} s, "
            f"optimiser and the rest {f['rest']:.3f} s; nfev {f['nfev']}, njev "
            f"{f['njev']}; SSR {f['ssr']:.6g}) x{ref_fit['wall'] / f['wall']:.2f} over "
            f"{ref_label}; same end point: {f['x'] == ref_fit['x']}",
            flush=True,
        )
    out["one_fit"] = fits
    numba.set_num_threads(maxth)

    # 2. pool start-up
    if "startup" not in skip:
        s_old = startup(lambda: old_process_pool(n), n)
        s_new = startup(
            lambda: parallel._SharingProcessPool(
                max_workers=n,
                mp_context=parallel.process_context(),
                initializer=parallel._process_initializer,
            ),
            n,
        )
        s_again = startup(
            lambda: parallel._SharingProcessPool(
                max_workers=n,
                mp_context=parallel.process_context(),
                initializer=parallel._process_initializer,
            ),
            n,
        )
        out["startup"] = {"spawn": s_old, "forkserver_first": s_new, "forkserver": s_again}
        print(
            f"{n} workers ready: spawned {s_old:.2f} s; forked from the fork server "
            f"{s_new:.2f} s the first time (the server loads the kernel), {s_again:.2f} s "
            "after",
            flush=True,
        )

    # 3. multistart per back-end
    rows = []
    numba.set_num_threads(1)
    wall, ref = run_multistart(prob, a.starts, parallel.SerialExecutor())
    numba.set_num_threads(maxth)
    secs = np.array([f.seconds for f in ref.fits])
    bound = max(secs.sum() / n, secs.max()) if secs.size else float("nan")
    out["starts_seconds"] = secs.tolist()
    print(
        f"reference: {len(ref.fits)} fitted, {len(ref.failed)} failed; per start "
        f"median {np.median(secs):.2f} s, slowest {secs.max():.2f} s, sum {secs.sum():.1f} s;"
        f" no back-end on {n} cores beats max(sum / N, slowest) = {bound:.2f} s "
        f"(x{wall / bound:.1f})",
        flush=True,
    )
    rows.append(("serial, 1 numba thread", 1, wall, True))
    refs = {True: ref}

    def reached(r) -> str:
        best = min(float(np.min(ref.ssr)), float(np.min(r.ssr)))
        at = int(np.sum(r.ssr <= best * (1 + 1e-6) + 1e-300))
        return f"{at} of {len(r.ssr)} starts at the best SSR {best:.6g}"

    print(f"reference: {reached(ref)}", flush=True)

    def backend(label, cores, make, **fit_kw):
        if any(k in label for k in skip):
            return
        try:
            with make() as ex:
                w, r = run_multistart(prob, a.starts, ex, **fit_kw)
        except Exception as exc:  # noqa: BLE001 - a back-end that fails is reported
            print(f"{label}: failed: {type(exc).__name__}: {exc}", flush=True)
            return
        comp = fit_kw.get("compressed", True)
        refs.setdefault(comp, r)
        rows.append((label, cores, w, same(r, refs[comp])))
        print(f"{label}: {w:.2f} s; {reached(r)}", flush=True)

    if not a.quick:
        backend(
            "serial, 1 numba thread, whole J (before)",
            1,
            lambda: _one_thread(parallel.SerialExecutor()),
            compressed=False,
        )

    backend(
        f"serial, {maxth} numba threads",
        maxth,
        lambda: parallel.open_executor(parallel.ExecutorSpec("serial")),
    )
    backend(
        f"threads, {n} (shared cores)",
        n,
        lambda: parallel.open_executor(parallel.ExecutorSpec("threads", n)),
    )
    backend(f"processes, {n}, spawned (before)", n, lambda: old_process_pool(n))
    backend(
        f"processes, {n}, fork server + shared cores",
        n,
        lambda: parallel.open_executor(parallel.ExecutorSpec("processes", n)),
    )
    for split in (2, 4):
        if n // split >= 2:
            backend(
                f"processes, {n // split} x {split} threads, fork server + shared cores",
                n,
                lambda split=split: parallel.open_executor(
                    parallel.ExecutorSpec("processes", n // split)
                ),
            )
    if not a.quick:
        backend(
            f"processes, {n}, fork server + shared cores, whole J (before)",
            n,
            lambda: parallel.open_executor(parallel.ExecutorSpec("processes", n)),
            compressed=False,
        )
    if a.dask:
        backend(
            f"dask LocalCluster, {n} workers",
            n,
            lambda: parallel.open_executor(parallel.ExecutorSpec("dask", n)),
        )

    # 4. sample's ensembles per back-end
    import tempfile
    from pathlib import Path

    from rotorbayes.inference.likelihood import LogPosterior

    lp = LogPosterior(prob, ref.best.x)
    a.walkers = max(a.walkers, 2 * lp.ndim)  # emcee's moves need twice the coordinates
    srows = []
    with tempfile.TemporaryDirectory() as tmp:
        numba.set_num_threads(1)
        sw, sref = run_sample(lp, ref.best.x, Path(tmp) / "ref", a, None)
        numba.set_num_threads(maxth)
        srows.append(("serial loop, 1 numba thread", 1, sw, True))
        print(f"sample, serial loop on 1 numba thread: {sw:.2f} s", flush=True)

        def sample_backend(label, cores, make):
            if any(k in label for k in skip):
                return
            folder = Path(tmp) / f"s{len(srows)}"
            try:
                with make() as ex:
                    w, c = run_sample(lp, ref.best.x, folder, a, ex)
            except Exception as exc:  # noqa: BLE001 - a back-end that fails is reported
                print(f"sample, {label}: failed: {type(exc).__name__}: {exc}", flush=True)
                return
            srows.append((label, cores, w, c == sref))
            print(f"sample, {label}: {w:.2f} s", flush=True)

        sample_backend(
            f"serial loop, {maxth} numba threads (the default)", maxth, contextlib.nullcontext
        )
        sample_backend(
            f"threads, {n} (shared cores)",
            n,
            lambda: parallel.open_executor(parallel.ExecutorSpec("threads", n)),
        )
        sample_backend(
            f"processes, {n}, fork server + shared cores",
            n,
            lambda: parallel.open_executor(parallel.ExecutorSpec("processes", n)),
        )
        if a.dask:
            sample_backend(
                f"dask LocalCluster, {n} workers",
                n,
                lambda: parallel.open_executor(parallel.ExecutorSpec("dask", n)),
            )

    per = prob.n_residuals
    print(
        f"\nthe default here for this multistart: {parallel.default_backend(None, a.starts, per)}"
        f" ({parallel.default_reason(None, a.starts, per)})"
    )
    print(
        f"\n{a.starts}-start multistart, brake {a.seconds:g} s at 1 kHz, {os.cpu_count()} cores:\n"
    )
    print("| back-end | wall s | starts/s | vs 1 core | core efficiency | bit-identical |")
    print("|---|---|---|---|---|---|")
    base = rows[0][2]
    out["multistart"] = []
    for label, cores, w, ok in rows:
        sp = base / w
        print(
            f"| {label} | {w:.2f} | {a.starts / w:.2f} | {sp:.2f}x | "
            f"{100 * sp / cores:.0f} % | {'yes' if ok else 'NO'} |"
        )
        out["multistart"].append(
            {
                "backend": label,
                "cores": cores,
                "wall": w,
                "starts_per_s": a.starts / w,
                "speedup": sp,
                "identical": ok,
            }
        )
    evals = a.ensembles * a.walkers * a.steps
    print(
        f"\nsample, {a.ensembles} ensembles of {a.walkers} walkers x {a.steps} steps "
        f"(brake {a.seconds:g} s), {os.cpu_count()} cores:\n"
    )
    print(
        "| back-end | wall s | ensembles/s | walker evaluations/s | vs 1 core | "
        "core efficiency | bit-identical |"
    )
    print("|---|---|---|---|---|---|---|")
    sbase = srows[0][2]
    out["sample"] = []
    for label, cores, w, ok in srows:
        sp = sbase / w
        print(
            f"| {label} | {w:.2f} | {a.ensembles / w:.3f} | {evals / w:.0f} | {sp:.2f}x | "
            f"{100 * sp / cores:.0f} % | {'yes' if ok else 'NO'} |"
        )
        out["sample"].append(
            {
                "backend": label,
                "cores": cores,
                "wall": w,
                "ensembles_per_s": a.ensembles / w,
                "evals_per_s": evals / w,
                "speedup": sp,
                "identical": ok,
            }
        )
    print(f"\nload average after: {os.getloadavg()[0]:.1f}")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(out, fh, indent=1)


if __name__ == "__main__":
    main()

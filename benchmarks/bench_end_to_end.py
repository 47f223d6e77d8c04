"""End to end: commands with the Jacobian by forward sensitivities against differences.

Each command runs as a user runs it (``rotorbayes.cli.main``), in this one process, once
with :data:`rotorbayes.inference.problem.JACOBIAN_DEFAULT` set to ``'sensitivity'`` and
once to ``'differences'`` (the order alternating from case to case), on data simulated
first (thesis table 4.3 P_ref, estimation input, encoder counts):

* ``fit``: the 30 s brake experiment, from the data (no ``--p0``);
* ``multistart``: the same data, ``--starts`` starts (the issue's figure is 48; on two
  cores a few) spread around the ``fit`` case's end (around P_ref, db_l = 0 spreads into
  starts with b_l < |db_l|, which cannot be simulated), serial;
* ``diagnose``: the brake fit above (score tests of the catalogue, no trials);
* ``design --separate``: three candidate effects, one start, few evaluations;
* ``fit`` of 4 x ``--long`` s coupled experiments (one ``alpha0`` each), ``--max-nfev``
  small (benchmarks/bench_long_data.py makes the same data).

Before any timing both Jacobians are computed once, so the kernels' first compilations
(simulation, residuals, sensitivities) are not in the figures; what a command compiles
beyond those falls to whichever method runs it first (``--warm`` runs every case once
untimed first).  For each case it prints wall and CPU time (``time.process_time``: every
thread of the process) of both, their ratio, and whether the results agree: the fits'
estimates within their standard errors (the largest ``|difference| / stderr``), the
multistart's best SSR, the diagnosis' verdict.  A command's own output goes to
``--log``.

Usage::

    OMP_NUM_THREADS=1 python benchmarks/bench_end_to_end.py [--starts 4] [--long 600]
        [--cases fit,multistart,diagnose,design,long] [--warm]

(the cases run in the order given; ``design`` and ``diagnose`` use the ``fit`` case's
folders, so ``fit`` comes first).

``--against OTHER_SRC`` compares two source trees instead (e.g. main's ``src`` exported
with ``git archive main src | tar -x -C /tmp/main``, against this tree's): every command
runs in a process of its own, as a user runs it (``python -m`` the CLI with
``PYTHONPATH`` set to the tree), the two trees alternating which goes first from round to
round, ``--rounds`` rounds after one untimed round that fills each tree's numba cache.
Per command it prints the medians of wall time and of the process's CPU time (user + system
of the child, every thread) for both trees and their ratios, and compares the results of
the last round (estimates and standard errors, verdicts) number by number::

    python benchmarks/bench_end_to_end.py --against /tmp/main/src [--rounds 3]
        [--cases fit,multistart,diagnose,design,long] [--this-jacobian sensitivity]

(``--this-jacobian`` gives this tree's ``fit`` and ``multistart`` that ``--jacobian``.)
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

METHODS = ("sensitivity", "differences")


def _cli(args: list[str], log) -> int:
    from rotorbayes.cli import main

    with contextlib.redirect_stdout(log), contextlib.redirect_stderr(log):
        return main(args)


def _timed(method: str, args: list[str], log) -> tuple[float, float, int]:
    from rotorbayes.inference import problem

    problem.JACOBIAN_DEFAULT = method
    print(f"\n$ [{method}] rotorbayes {' '.join(args)}", file=log, flush=True)
    w0, c0 = time.perf_counter(), time.process_time()
    rc = _cli(args, log)
    return time.perf_counter() - w0, time.process_time() - c0, rc


def _fit_agreement(a: Path, b: Path) -> str:
    ea = json.loads((a / "fit.json").read_text())["estimates"]
    eb = json.loads((b / "fit.json").read_text())["estimates"]
    worst, name = 0.0, ""
    for n, v in ea.items():
        se = max(v["stderr"], eb[n]["stderr"])
        d = abs(v["value"] - eb[n]["value"]) / se if se > 0 else float("inf")
        if d > worst:
            worst, name = d, n
    ssr = [json.loads((f / "fit.json").read_text())["ssr"] for f in (a, b)]
    return (
        f"{'agree' if worst <= 1.0 else 'DIFFER'} within stderr (largest "
        f"|diff|/stderr {worst:.2g}, {name}); SSR {ssr[0]:.6g} vs {ssr[1]:.6g}"
    )


def _multistart_agreement(a: Path, b: Path) -> str:
    best = []
    for f in (a, b):
        doc = json.loads((f / "multistart.json").read_text())
        ssr = [v for v in doc["ssr"] if v is not None]
        best.append(min(ssr) if ssr else float("nan"))
    rel = abs(best[0] - best[1]) / max(abs(best[1]), 1e-300)
    return f"best SSR {best[0]:.6g} vs {best[1]:.6g} (relative difference {rel:.1e})"


def _diagnose_agreement(a: Path, b: Path) -> str:
    da = json.loads((a / "diagnosis.json").read_text())
    db = json.loads((b / "diagnosis.json").read_text())
    keys = ("verdict", "missing", "best")
    same = {k: da.get(k) == db.get(k) for k in keys if k in da or k in db}
    return "diagnosis.json: " + (
        ", ".join(f"{k} {'same' if v else 'DIFFERS'}" for k, v in same.items()) or "written"
    )


def _design_agreement(a: Path, b: Path) -> str:
    va, vb = (
        min(st["value"] for st in json.loads((f / "design.json").read_text())["starts"])
        for f in (a, b)
    )
    return f"design.json: best objective {va:.6g} vs {vb:.6g}"


def _run_tree(src: str, args: list[str], log) -> tuple[float, float, int]:
    """``rotorbayes ARGS`` in a process of its own on the source tree ``src``: wall and CPU
    seconds (user + system of the child) and the exit status."""
    env = dict(os.environ, PYTHONPATH=src)
    code = "import sys; from rotorbayes.cli import main; sys.exit(main(sys.argv[1:]))"
    print(f"\n$ [{src}] rotorbayes {' '.join(args)}", file=log, flush=True)
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    w0 = time.perf_counter()
    rc = subprocess.call([sys.executable, "-c", code, *args], env=env, stdout=log, stderr=log)
    wall = time.perf_counter() - w0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    return wall, cpu, rc


def _numbers_agreement(a: Path, b: Path, name: str) -> str:
    """Every estimate and standard error of two fit.json (or the diagnosis' verdict, the
    multistart's SSRs, the design's objectives): equal bit for bit, or how far apart."""
    da, db = (json.loads((f / name).read_text()) for f in (a, b))
    if name == "fit.json":
        worst, what, same = 0.0, "", True
        for n, v in da["estimates"].items():
            w = db["estimates"][n]
            for key in ("value", "stderr"):
                same &= v[key] == w[key]
                se = max(v["stderr"], w["stderr"])
                dd = abs(v[key] - w[key]) / se if se > 0 else 0.0
                if dd > worst:
                    worst, what = dd, f"{n} {key}"
        verdict = da["assessment"].get("verdict") == db["assessment"].get("verdict")
        return (
            ("estimates and standard errors bit-identical" if same else "")
            + (f"largest |difference| {worst:.2g} stderr ({what})" if not same else "")
            + f"; verdict {'same' if verdict else 'DIFFERS'}; SSR {da['ssr']!r} vs {db['ssr']!r}"
        )
    if name == "multistart.json":
        if da["ssr"] == db["ssr"]:
            return "SSRs bit-identical"
        ba, bb = (min(v for v in d["ssr"] if v is not None) for d in (da, db))
        return (
            f"SSRs differ (paths part at rounding level); best SSR {ba:.6g} vs {bb:.6g} "
            f"(relative difference {abs(ba - bb) / max(abs(ba), 1e-300):.1e})"
        )
    if name == "design.json":
        va, vb = ([st["value"] for st in d["starts"]] for d in (da, db))
        return "objectives " + ("bit-identical" if va == vb else f"{va} vs {vb}")
    keys = [k for k in ("verdict", "missing", "best") if k in da or k in db]
    return "diagnosis.json " + ", ".join(
        f"{k} {'same' if da.get(k) == db.get(k) else 'DIFFERS'}" for k in keys
    )


def compare_trees(a, work: Path, log, brake: Path, longs: list[Path]) -> None:
    """Each case on both source trees, alternating, medians of ``a.rounds`` rounds."""
    trees = {
        "other": str(Path(a.against).resolve()),
        "this": str(Path(__file__).parents[1] / "src"),
    }
    cases = a.cases.split(",")

    def fit_out(tree):
        return work / f"fit-{tree}"

    def args_of(case: str, tree: str) -> tuple[list[str], str]:
        args, name = _args_of(case, tree)
        if a.this_jacobian and tree == "this" and case in ("fit", "multistart", "long"):
            args = [*args, "--jacobian", a.this_jacobian]
        return args, name

    def _args_of(case: str, tree: str) -> tuple[list[str], str]:
        out = work / f"{case}-{tree}"
        if case == "fit":
            return ["fit", str(brake), "--model", "brake", "--out", str(out), "--force"], "fit.json"
        if case == "multistart":
            return [
                "multistart", str(brake), "--model", "brake", "--starts", str(a.starts),
                "--around", str(fit_out(tree)), "--spread", "0.2", "--backend", "serial",
                "--out", str(out), "--force",
            ], "multistart.json"  # fmt: skip
        if case == "diagnose":
            shutil.rmtree(out, ignore_errors=True)
            shutil.copytree(fit_out(tree), out)  # diagnose writes into the fit folder
            return ["diagnose", str(out), "--no-trials"], "diagnosis.json"
        if case == "design":
            return [
                "design", str(fit_out(tree)), "--separate", a.separate, "--starts", "1",
                "--max-evals", "20", "--no-check", "--backend", "serial",
                "--out", str(out), "--force",
            ], "design.json"  # fmt: skip
        return [
            "fit", *map(str, longs), "--model", "coupled", "--p0", "thesis:4.2:P0",
            "--max-nfev", str(a.nfev), "--out", str(out), "--force",
        ], "fit.json"  # fmt: skip

    labels = {
        "fit": "fit 30 s brake from the data",
        "multistart": f"multistart 30 s brake, {a.starts} starts, serial",
        "diagnose": "diagnose the 30 s brake fit (no trials)",
        "design": "design --separate (3 candidates, 1 start)",
        "long": f"fit 4 x {a.long:g} s coupled (--max-nfev {a.nfev})",
    }
    print(f"trees: other {trees['other']}, this {trees['this']}; {a.rounds} rounds, medians")
    print(
        f"{'case':44s} {'other wall/CPU':>17s} {'this wall/CPU':>17s}  ratio wall, CPU  "
        "(wall and CPU of each round: other | this)"
    )
    for case in (c for c in cases if c in labels):
        times = {t: [] for t in trees}
        for rnd in range(a.rounds + 1):
            order = list(trees) if rnd % 2 == 0 else list(trees)[::-1]
            for t in order:
                args, _ = args_of(case, t)
                w, c, rc = _run_tree(trees[t], args, log)
                # 1: did not converge (the long case's few evaluations), results written
                if rc not in (0, 1):
                    raise SystemExit(f"{case} on {trees[t]} exited {rc}; see --log")
                if rnd > 0:  # the first round fills the numba caches and the file caches
                    times[t].append((w, c))
        med = {t: (statistics.median(x[0] for x in v), statistics.median(x[1] for x in v))
               for t, v in times.items()}  # fmt: skip
        (wo, co), (wt, ct) = med["other"], med["this"]
        rounds = " | ".join(
            " ".join(f"{w:.2f}/{c:.2f}" for w, c in times[t]) for t in ("other", "this")
        )
        print(
            f"{labels[case]:44s} {wo:7.2f} /{co:7.2f} {wt:7.2f} /{ct:7.2f}  "
            f"{wo / wt:5.2f}x {co / ct:5.2f}x  ({rounds})",
            flush=True,
        )
        _, name = args_of(case, "this") if case != "diagnose" else (None, "diagnosis.json")
        try:
            verdict = _numbers_agreement(work / f"{case}-other", work / f"{case}-this", name)
        except Exception as e:  # a result file the comparison does not know
            verdict = f"(results not compared: {type(e).__name__}: {e})"
        print(f"{'':44s} {verdict}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--starts", type=int, default=4)
    ap.add_argument("--long", type=float, default=600.0, help="length of each long run [s]")
    ap.add_argument("--nfev", type=int, default=3, help="--max-nfev of the long fit")
    ap.add_argument(
        "--separate",
        default="string_damping,voltage_offset,input_delay",
        help="the three candidate effects of the design case",
    )
    ap.add_argument("--cases", default="fit,multistart,diagnose,design,long")
    ap.add_argument("--warm", action="store_true", help="run every case once untimed first")
    ap.add_argument("--keep", help="work in this folder (kept) instead of a temporary one")
    ap.add_argument("--log", default=os.devnull, help="where the commands' output goes")
    ap.add_argument("--against", help="another source tree (its src folder) to compare with")
    ap.add_argument("--rounds", type=int, default=3, help="timed rounds of --against")
    ap.add_argument(
        "--this-jacobian",
        choices=("differences", "sensitivity"),
        help="with --against: this tree's fits and multistarts take --jacobian this",
    )
    a = ap.parse_args()
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    import numpy as np

    import rotorbayes as rb
    from rotorbayes import inference

    cases = a.cases.split(",")
    print(
        f"{os.cpu_count()} cores; load average before: "
        + " ".join(f"{v:.1f}" for v in os.getloadavg()),
        flush=True,
    )
    ctx = tempfile.TemporaryDirectory() if a.keep is None else None
    work = Path(ctx.name if ctx else a.keep)
    work.mkdir(parents=True, exist_ok=True)
    log = open(a.log, "a")  # noqa: SIM115 (open for the whole run)
    try:
        brake = work / "brake30.csv"
        if not brake.exists():
            _cli(
                [
                    "simulate",
                    "--model",
                    "brake",
                    "--input",
                    "est",
                    "--duration",
                    "30",
                    "--seed",
                    "1",
                    "--quantize",
                    "--out",
                    str(brake),
                    "--force",
                ],
                log,
            )
        # The kernels' first compilations, outside every figure.
        # (Two trees compared: each command's own process, after an untimed round.)
        if not a.against:
            p = rb.parameters.thesis_set("4.3", "P_ref")
            t, u = rb.signals.estimation_signal(3.0, seed=1)
            ex = rb.simulate(p, u, dt=float(t[1] - t[0]), config="brake", quantize_angles=True)
            prob = inference.Problem("brake", [ex.to_experiment("warm")], base=p)
            for m in METHODS:
                prob.jacobian(prob.x_from(p), method=m)
        longs = [work / f"long{k}.csv" for k in range(1, 5)]
        if "long" in cases:
            for k, f in enumerate(longs, start=1):
                if not f.exists():
                    _cli(
                        [
                            "simulate",
                            "--model",
                            "coupled",
                            "--input",
                            "est",
                            "--duration",
                            str(a.long),
                            "--seed",
                            str(k),
                            "--alpha0",
                            f"{0.05 * (k - 2):.2f}",
                            "--quantize",
                            "--out",
                            str(f),
                            "--force",
                        ],
                        log,
                    )

        if a.against:
            compare_trees(a, work, log, brake, longs)
            return

        def fit_args(out):
            return ["fit", str(brake), "--model", "brake", "--out", str(out), "--force"]

        plan = {
            "fit": ("fit 30 s brake from the data", fit_args, _fit_agreement),
            "multistart": (
                f"multistart 30 s brake, {a.starts} starts, serial",
                lambda out: [
                    "multistart",
                    str(brake),
                    "--model",
                    "brake",
                    "--starts",
                    str(a.starts),
                    "--around",
                    str(work / "fit-sensitivity"),
                    "--spread",
                    "0.2",
                    "--backend",
                    "serial",
                    "--out",
                    str(out),
                    "--force",
                ],
                _multistart_agreement,
            ),
            "diagnose": (
                "diagnose the 30 s brake fit (no trials)",
                lambda out: ["diagnose", str(out), "--no-trials"],
                _diagnose_agreement,
            ),
            "design": (
                "design --separate (3 candidates, 1 start)",
                lambda out: [
                    "design",
                    str(work / "fit-sensitivity"),
                    "--separate",
                    a.separate,
                    "--starts",
                    "1",
                    "--max-evals",
                    "20",
                    "--no-check",
                    "--backend",
                    "serial",
                    "--out",
                    str(out),
                    "--force",
                ],
                _design_agreement,
            ),
            "long": (
                f"fit 4 x {a.long:g} s coupled (--max-nfev {a.nfev})",
                lambda out: [
                    "fit",
                    *map(str, longs),
                    "--model",
                    "coupled",
                    "--p0",
                    "thesis:4.2:P0",
                    "--max-nfev",
                    str(a.nfev),
                    "--out",
                    str(out),
                    "--force",
                ],
                _fit_agreement,
            ),
        }
        print(f"{'case':48s} {'sensitivity':>17s} {'differences':>17s}   ratio (wall, CPU)")
        for j, case in enumerate(c for c in cases if c in plan):
            label, args_of, agree = plan[case]
            order = METHODS if j % 2 == 0 else METHODS[::-1]
            outs = {}
            res = {}
            for m in order:
                out = work / f"{case}-{m}"
                if case == "diagnose":  # diagnose writes into a copy of the fit
                    import shutil

                    src = work / f"fit-{m}"
                    if not src.exists():
                        _timed(m, fit_args(src), log)
                    shutil.rmtree(out, ignore_errors=True)
                    shutil.copytree(src, out)
                if case == "fit":
                    out = work / f"fit-{m}"
                outs[m] = out
                if a.warm:
                    _timed(m, args_of(out), log)
                res[m] = _timed(m, args_of(out), log)
            (ws, cs, rs), (wd, cd, rd) = res["sensitivity"], res["differences"]
            try:
                verdict = agree(outs["sensitivity"], outs["differences"])
            except Exception as e:  # a result file the comparison does not know
                verdict = f"(results not compared: {type(e).__name__}: {e})"
            print(
                f"{label:48s} {ws:6.1f} s {cs:6.1f} cpu {wd:6.1f} s {cd:6.1f} cpu   "
                f"{wd / ws:4.2f}x {cd / cs:4.2f}x  exit {rs}/{rd}",
                flush=True,
            )
            print(f"{'':48s} {verdict}", flush=True)
    finally:
        log.close()
        if ctx is not None:
            ctx.cleanup()
    print("load average after: " + " ".join(f"{v:.1f}" for v in os.getloadavg()))
    _ = np, sys


if __name__ == "__main__":
    main()

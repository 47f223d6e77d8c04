"""How long does a new user's first command wait for numba?  Each command runs in its own
process with a fresh, empty ``NUMBA_CACHE_DIR`` (a fresh install), and the benchmark reports
its wall time and what it compiled: the lines the command itself prints with a cold cache
("rotorbayes: compiling the integrator (...) ... took N s", one per kernel entry point it
uses; :mod:`rotorbayes.util.coldstart`).

The commands (issue 33: "the first command on a fresh machine compiles in at most 20 s on
these 2 cores; a command compiles only what it uses"):

* ``simulate``: ``rotorbayes simulate --model brake --input est --duration 30`` (the first
  command of the README);
* ``fit``: ``rotorbayes fit --model coupled example:coupled_est --validate
  example:coupled_val`` (the first fit of docs/getting_started.md, on bundled data);
* ``import``: ``import rotorbayes`` alone (compiles nothing).

Each is run ``--rounds`` times, the commands alternating, so a passing load hits all alike;
min and median per command.  The compile time is the sum of what the command's
``coldstart.kernel_entry`` measured (the "took N s" figures, unrounded), as wall time and as
the process's CPU time meanwhile (numba compiles on one core; on a shared machine the CPU
time is what an idle core gives, the wall time is not); beside it, the CPU time of every
numba compilation in the process, the few small functions the command compiles outside
the entry points included (the step grid, the parameter check: about 1-1.5 s).

Usage::

    python benchmarks/bench_coldstart.py [--rounds 2] [--only simulate,fit] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: The child: the command line's ``main`` with the command's arguments, then the seconds
#: each entry point took to compile (``coldstart.COMPILE_SECONDS``) to the file named first,
#: and the CPU seconds of every numba compilation in the process (numba's compile events,
#: outermost only): the entry points' and what the command compiles outside them (the step
#: grid, the parameter check).
CHILD = """import json, sys, time
from numba.core import event
from rotorbayes import cli
from rotorbayes.util import coldstart
out = sys.argv.pop(1)
class AllCompiles(event.Listener):
    depth, start, total = 0, 0.0, 0.0
    def on_start(self, e):
        if self.depth == 0:
            self.start = time.process_time()
        self.depth += 1
    def on_end(self, e):
        self.depth -= 1
        if self.depth == 0:
            self.total += time.process_time() - self.start
every = AllCompiles()
event.register("numba:compile", every)
try:
    rc = cli.main(sys.argv[1:]) if len(sys.argv) > 1 else 0
finally:
    open(out, "w").write(json.dumps([coldstart.COMPILE_SECONDS, coldstart.COMPILE_CPU_SECONDS,
                                     every.total]))
sys.exit(rc)
"""

COMMANDS = {
    "import": [],
    "simulate": ["simulate", "--model", "brake", "--input", "est", "--duration", "30",
                 "--out", "{tmp}/sim.csv"],
    "fit": ["fit", "--model", "coupled", "example:coupled_est", "--validate",
            "example:coupled_val", "--out", "{tmp}/fit0"],
}  # fmt: skip


def run_cold(name: str) -> dict:
    """Run command ``name`` once with an empty numba cache; wall time, compile time per
    entry point (from the command's own measurement) and the exit code."""
    with tempfile.TemporaryDirectory(prefix="rb_cold_") as tmp:
        report = Path(tmp) / "compile.json"
        env = dict(os.environ, NUMBA_CACHE_DIR=str(Path(tmp) / "numba"), OMP_NUM_THREADS="1")
        cmd = [
            sys.executable,
            "-c",
            CHILD,
            str(report),
            *(a.replace("{tmp}", tmp) for a in COMMANDS[name]),
        ]
        t0 = time.perf_counter()
        res = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=tmp)
        wall = time.perf_counter() - t0
        compiled, cpu, every = (
            json.loads(report.read_text()) if report.exists() else ({}, {}, float("nan"))
        )
        notices = [line for line in res.stderr.splitlines() if "compiling the integrator" in line]
    return {
        "wall": wall,
        "compiled": compiled,
        "compile": sum(compiled.values()),
        "cpu": cpu,
        "compile_cpu": sum(cpu.values()),
        "every_compile_cpu": every,
        "rc": res.returncode,
        "notices": notices,
        "load": os.getloadavg()[0],
        "stderr_tail": res.stderr[-2000:] if res.returncode else "",
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument(
        "--only", default="simulate,fit", help="commands, comma-separated: " + ", ".join(COMMANDS)
    )
    ap.add_argument("--json", help="write every run's figures here")
    a = ap.parse_args()
    names = a.only.split(",")
    runs: dict[str, list[dict]] = {n: [] for n in names}
    for r in range(a.rounds):
        for n in names:
            out = run_cold(n)
            runs[n].append(out)
            parts = ", ".join(f"{k} {v:.1f} s" for k, v in out["compiled"].items()) or "nothing"
            print(
                f"round {r + 1} {n}: wall {out['wall']:.1f} s, compiled {out['compile']:.1f} s "
                f"(CPU {out['compile_cpu']:.1f} s; all numba compiles "
                f"{out['every_compile_cpu']:.1f} CPU s) "
                f"({parts}), exit {out['rc']}, 1-min load {out['load']:.1f}",
                flush=True,
            )
            if out["rc"]:
                print(out["stderr_tail"], file=sys.stderr)
    print(
        f"\nfresh NUMBA_CACHE_DIR per run, {os.cpu_count()} cores, {a.rounds} alternating "
        "rounds; min / median [s]"
    )
    print(
        "| command | compiling (wall) | compiling (CPU) | all numba compiles (CPU) | whole "
        "command (wall) | entry points compiled |"
    )
    print("|---|---|---|---|---|---|")
    for n in names:
        c = [x["compile"] for x in runs[n]]
        u = [x["compile_cpu"] for x in runs[n]]
        e = [x["every_compile_cpu"] for x in runs[n]]
        w = [x["wall"] for x in runs[n]]
        entries = ", ".join(sorted({k for x in runs[n] for k in x["compiled"]})) or "none"
        print(
            f"| {n} | {min(c):.1f} / {statistics.median(c):.1f} | {min(u):.1f} / "
            f"{statistics.median(u):.1f} | {min(e):.1f} / {statistics.median(e):.1f} | "
            f"{min(w):.1f} / {statistics.median(w):.1f} | "
            f"{entries} |"
        )
    if a.json:
        Path(a.json).write_text(json.dumps(runs, indent=1))


if __name__ == "__main__":
    main()

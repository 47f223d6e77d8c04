"""Peak memory and time of long data (issue 18 item 5): 600 s coupled experiments at 1 kHz.

Every step runs as a user runs it, one ``rotorbayes`` command in its own process under
``/usr/bin/time -v`` (peak resident memory of that process), one after the other:

* simulate 600 s (coupled, estimation input, encoder counts), four times (seeds 1-4);
* fit one 600 s experiment from a start (``--p0``, ``--max-nfev`` small);
* fit the four together (one ``alpha0`` each), the same way;
* multistart on one experiment: 4 starts in 2 threads (each running fit holds its own
  Jacobian);
* sample each fit briefly (``--steps 10``, 32 walkers, 2 ensembles).

The target is 2 GiB peak for each. Run it as

    NUMBA_NUM_THREADS=1 python benchmarks/bench_long_data.py [--duration 600] [--nfev 3]

and read the load average it prints: on a shared machine the times say little, the memory
does not depend on the load.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

GIB = 2**30


def run(label: str, args: list[str], rows: list) -> None:
    """Run ``rotorbayes ARGS`` under /usr/bin/time -v; record peak RSS and wall time."""
    cmd = [
        "/usr/bin/time",
        "-v",
        sys.executable,
        "-c",
        "import sys; from rotorbayes.cli import main; sys.exit(main())",
        *args,
    ]
    t0 = time.perf_counter()
    p = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    m = re.search(r"Maximum resident set size \(kbytes\): (\d+)", p.stderr)
    peak = int(m.group(1)) * 1024 if m else float("nan")
    ok = p.returncode in (0, 1)  # 1: the fit ran but did not converge (a small budget)
    if not ok:
        tail = "\n".join(p.stderr.splitlines()[-15:])
        print(f"{label}: exit code {p.returncode}\n{tail}", file=sys.stderr)
    rows.append((label, peak, wall, p.returncode))
    print(
        f"{label:44s} peak {peak / 2**20:7.0f} MiB  {wall:7.1f} s  exit {p.returncode}  "
        f"{'OK' if peak <= 2 * GIB else 'ABOVE 2 GiB'}",
        flush=True,
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=600.0)
    ap.add_argument("--nfev", type=int, default=3)
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--keep", help="work in this folder (kept) instead of a temporary one")
    a = ap.parse_args()
    print(
        f"{a.duration:g} s coupled experiments at 1 kHz; {os.cpu_count()} cores; "
        f"NUMBA_NUM_THREADS={os.environ.get('NUMBA_NUM_THREADS', 'unset')}; load average "
        "before: " + " ".join(f"{v:.1f}" for v in os.getloadavg()),
        flush=True,
    )
    ctx = tempfile.TemporaryDirectory() if a.keep is None else None
    work = Path(ctx.name if ctx else a.keep)
    work.mkdir(parents=True, exist_ok=True)
    rows: list = []
    try:
        files = []
        for k in range(1, 5):
            f = work / f"long{k}.csv"
            files.append(str(f))
            if f.exists():
                continue
            run(
                f"simulate {a.duration:g} s (seed {k})",
                [
                    "simulate",
                    "--model",
                    "coupled",
                    "--input",
                    "est",
                    "--duration",
                    str(a.duration),
                    "--seed",
                    str(k),
                    "--alpha0",
                    f"{0.05 * (k - 2):.2f}",
                    "--quantize",
                    "--out",
                    str(f),
                    "--force",
                ],
                rows,
            )
        fit_args = [
            "--model",
            "coupled",
            "--p0",
            "thesis:4.2:P0",
            "--max-nfev",
            str(a.nfev),
            "--force",
        ]
        run(
            f"fit 1 x {a.duration:g} s (--max-nfev {a.nfev})",
            ["fit", files[0], *fit_args, "--out", str(work / "fit1")],
            rows,
        )
        run(
            f"fit 4 x {a.duration:g} s (--max-nfev {a.nfev})",
            ["fit", *files, *fit_args, "--out", str(work / "fit4")],
            rows,
        )
        run(
            f"multistart 1 x {a.duration:g} s (4 starts, 2 threads, --max-nfev {a.nfev})",
            [
                "multistart",
                files[0],
                "--model",
                "coupled",
                "--starts",
                "4",
                "--around",
                "thesis:4.2:P0",
                "--spread",
                "0.2",
                "--max-nfev",
                str(a.nfev),
                "--backend",
                "threads",
                "--workers",
                "2",
                "--force",
                "--out",
                str(work / "ms1"),
            ],
            rows,
        )
        for k in (1, 4):
            run(
                f"sample {k} x {a.duration:g} s ({a.steps} steps, 32 walkers, 2 ens.)",
                [
                    "sample",
                    str(work / f"fit{k}"),
                    "--steps",
                    str(a.steps),
                    "--walkers",
                    "32",
                    "--quiet",
                    "--force",
                    "--out",
                    str(work / f"post{k}"),
                ],
                rows,
            )
    finally:
        if ctx is not None:
            ctx.cleanup()
    print("load average after: " + " ".join(f"{v:.1f}" for v in os.getloadavg()))
    worst = max(r[1] for r in rows)
    print(
        f"largest peak {worst / 2**20:.0f} MiB: {'within' if worst <= 2 * GIB else 'ABOVE'} 2 GiB"
    )


if __name__ == "__main__":
    main()

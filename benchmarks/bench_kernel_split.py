"""Speed of the split kernel (terms apart from the solver, effect hooks) against the kernel
before the split, measured side by side in one run.

The earlier kernel is taken from git (``--before``, default the last commit before the
split) into a temporary package and compiled there, so both run on the same machine, input
and parameters, interleaved.  Reported for a 30 s brake experiment at 1 kHz (thesis table
4.3 P_ref, alpha0 = 0.8, stick-slip):

* kernel time per run, before and after, and their ratio;
* the cost of effects that end steps at input kinks (dead zone, delay at 200 Hz) and of a
  user-defined effect (the shipped angle-dependent friction).

Usage::

    python benchmarks/bench_kernel_split.py [--before COMMIT] [--repeats 30]
"""

from __future__ import annotations

import argparse
import importlib
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

import rotorbayes as rb  # noqa: E402
from rotorbayes.kernel.solver import simulate_into  # noqa: E402
from rotorbayes.model.parameters import thesis_set  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
BEFORE = "686ae3a"


def load_old_kernel(commit: str):
    """Import the integrator of ``commit`` from git as a throw-away package."""
    tmp = Path(tempfile.mkdtemp(prefix="rb_old_kernel_"))
    pkg = tmp / "rb_old_kernel"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    for name in ("integrator.py", "friction.py"):
        src = subprocess.run(
            ["git", "show", f"{commit}:src/rotorbayes/{name}"],
            cwd=ROOT, capture_output=True, text=True, check=True,
        ).stdout  # fmt: skip
        (pkg / name).write_text(src)
    sys.path.insert(0, str(tmp))
    return importlib.import_module("rb_old_kernel.integrator")


def median_ms(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", default=BEFORE, help="git commit of the earlier kernel")
    ap.add_argument("--repeats", type=int, default=30)
    a = ap.parse_args()

    t, u = rb.signals.estimation_signal(30.0, seed=3)
    p = dict(thesis_set("4.3", "P_ref"), alpha0=0.8)
    new = rb.Simulator("brake", u, 1e-3, effects=["initial_torsion"])
    kv = new.kernel_vector(p)
    n = u.size

    old = load_old_kernel(a.before)
    kv_old = kv[0].copy()
    outs = [np.empty(n) for _ in range(4)] + [np.empty(n, np.int8) for _ in range(2)]
    ev = np.empty((0, 3))

    def run_old():
        return old.simulate_into(kv_old, u, 1e-3, 1, 0, new.stride, 1, u, *outs, ev)

    outs_new = [np.empty(n) for _ in range(4)] + [np.empty(n, np.int8) for _ in range(2)]
    args_new = new._kernel_args()

    def run_new():  # the same level as run_old: the compiled call, outputs preallocated
        st, _ = simulate_into(kv[0], kv[1], *args_new, *outs_new, ev)
        return st, outs_new[0], outs_new[2]

    t0 = time.perf_counter()
    run_old()
    compile_old = time.perf_counter() - t0
    run_new()
    st_old = run_old()[0]
    old_thl = outs[2].copy()
    st_new, _, new_thl = run_new()
    assert st_old == 0 and st_new == 0

    before, after = [], []
    for _ in range(3):  # interleave to share the machine's noise
        before.append(median_ms(run_old, a.repeats))
        after.append(median_ms(run_new, a.repeats))
    b, f = min(before), min(after)

    full = median_ms(lambda: new.angles(kv), a.repeats)
    rows = [
        ("30 s brake run, kernel before the split", f"{b:.3f} ms"),
        ("30 s brake run, split kernel (hooks off)", f"{f:.3f} ms"),
        ("ratio after / before", f"{f / b:.3f}"),
        ("split kernel through Simulator.angles (allocates outputs)", f"{full:.3f} ms"),
        ("max |theta_l after - before|", f"{np.max(np.abs(new_thl - old_thl)):.2e} rad"),
        ("(compile or cache load of the old kernel)", f"{compile_old:.1f} s"),
    ]
    # Effects that cost something.
    dz = rb.Simulator("brake", u, 1e-3, effects=["initial_torsion", "motor_deadzone"])
    kdz = dz.kernel_vector(dict(p, u_deadzone=0.3))
    rows.append(("  with motor_deadzone 0.3 V (edges located)",
                 f"{median_ms(lambda: dz.angles(kdz), a.repeats):.3f} ms"))  # fmt: skip
    t2, u2 = rb.signals.estimation_signal(30.0, seed=3, rate=200.0)
    base2 = rb.Simulator("brake", u2, t2[1], effects=["initial_torsion"])
    dl = rb.Simulator("brake", u2, t2[1], effects=["initial_torsion", "input_delay"])
    kb2, kd2 = base2.kernel_vector(p), dl.kernel_vector(dict(p, t_delay=0.0123))
    rows.append(
        ("  200 Hz data, no delay", f"{median_ms(lambda: base2.angles(kb2), a.repeats):.3f} ms")
    )
    rows.append(("  200 Hz data, input_delay 12.3 ms (delayed samples located)",
                 f"{median_ms(lambda: dl.angles(kd2), a.repeats):.3f} ms"))  # fmt: skip
    user = rb.Simulator("brake", u, 1e-3, effects=["initial_torsion",
                                                   str(ROOT / "examples/angle_friction.py")
                                                   + ":angle_friction"])  # fmt: skip
    ku = user.kernel_vector(dict(p, a_fric=0.3, phi_fric=0.7))
    user.angles(ku)
    rows.append(("  with the user effect angle_friction (hooks on)",
                 f"{median_ms(lambda: user.angles(ku), a.repeats):.3f} ms"))  # fmt: skip
    w = max(len(r[0]) for r in rows)
    print(f"kernel split benchmark (before = {a.before}), median of {a.repeats} runs, best of 3")
    for k, v in rows:
        print(f"  {k:<{w}}  {v}")


if __name__ == "__main__":
    main()

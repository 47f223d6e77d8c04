"""The diagnosis loop on data rotorbayes did not make: one catalogue effect hidden at a time.

Every data set comes from the independent event-driven reference (``tests/reference.py``,
through ``tests/refdata.py``): the coupled rig, 30 s at 1 kHz, encoder-quantised, driven by
the continuous step-like input (an amplifier that follows the command, not the line
between samples), with parameter sets unlike the thesis tables.  The estimation run uses
input seed 3, the validation run seed 4.  For each case the script writes the two files
and an analysis file and runs ``rotorbayes run`` with the diagnosis loop -- the first fit
from the data, the diagnosis, the effect it names (by score test, or far from the floor by
trial refits) added with the refit search, again until adequate -- and prints where the
first and the last fit ended, on estimation and validation data, and the validation spread
the last fit's own uncertainty predicts.

    python analyses/reference_loop.py                   # every case (about 10 min, 2 cores)
    python analyses/reference_loop.py stribeck deadzone  # some cases
    python analyses/reference_loop.py --duration 10      # shorter records

Writes analyses/out/reference_loop/ (one folder per case, report.txt); ``--force``
replaces an earlier run.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))

import refdata  # noqa: E402  (the reference lives with the tests)

from rotorbayes.io.measurements import save_experiment  # noqa: E402

S0, S1 = refdata.SETS["coupled"]
#: case -> (parameter set, the hidden effect's parameters, alpha0 of the estimation run)
CASES = {
    "stribeck": (S0, dict(Ts_l=0.07, ws_l=0.5, delta_l=1.6), None),
    "stribeck_b": (S1, dict(Ts_l=0.0154, ws_l=0.8, delta_l=1.2), None),
    "asymmetric_coulomb": (S0, dict(dTc_l=0.01), None),
    "asymmetric_viscous": (S1, dict(db_l=0.008), None),
    "string_damping": (S0, dict(c_alpha=0.006), None),
    "input_delay": (S1, dict(t_delay=0.015), None),
    "motor_deadzone": (S0, dict(u_deadzone=0.3), None),
    "voltage_offset": (S1, dict(u_offset=0.08), None),
    "initial_torsion": (S0, {}, 0.25),
    "upper_stribeck": (S1, dict(dTs_u=0.1, ws_u=0.5, delta_u=2.0), None),
    "drive_lag": (S1, dict(tau_drive=0.01), None),
}


def run_case(name: str, folder: Path, duration: float) -> dict:
    base, extra, alpha0 = CASES[name]
    params = dict(base, **extra)
    folder.mkdir(parents=True, exist_ok=True)
    for label, seed in (("est", 3), ("val", 4)):
        ex = refdata.make_experiment(
            "coupled",
            params,
            duration=duration,
            signal="steps",
            hold="continuous",
            seed=seed,
            alpha0=alpha0 if label == "est" else None,
        )
        save_experiment(ex, folder / f"{label}.csv", overwrite=True)
    (folder / "analysis.toml").write_text(
        f'[analysis]\nname = "{name}"\nout = "out"\nconfig = "coupled"\n'
        'data = ["est.csv"]\nvalidate = ["val.csv"]\n[diagnose]\nmax_steps = 4\n'
        "[report]\nhtml = false\n"
    )
    t0 = time.perf_counter()
    cli = "import sys; from rotorbayes.cli import main; sys.exit(main(sys.argv[1:]))"
    proc = subprocess.run(
        [sys.executable, "-c", cli, "run", "analysis.toml", "--force", "--quiet"],
        cwd=folder,
        capture_output=True,
        text=True,
    )
    seconds = time.perf_counter() - t0
    rec = json.loads((folder / "out" / "run.json").read_text())
    first = json.loads((folder / "out" / "fit0" / "fit.json").read_text())["assessment"]
    last = json.loads((Path(rec["final_fit"]) / "fit.json").read_text())["assessment"]
    spread = last.get("validation_spread") or {}
    return {
        "case": name,
        "hidden": extra or {"alpha0": alpha0},
        "exit": proc.returncode,
        "seconds": seconds,
        "added": rec["added_effects"],
        "rejected": [r["effect"] for r in rec["rejected_effects"]],
        "first": first["worst_ratio_to_floor"],
        "first_validation": first["worst_ratio_to_floor_validation"],
        "last": last["worst_ratio_to_floor"],
        "last_validation": last["worst_ratio_to_floor_validation"],
        "spread": [spread.get("q10"), spread.get("q90")],
    }


def line(r: dict) -> str:
    sp = r["spread"]
    spread = f"{sp[0]:.3g}-{sp[1]:.3g}x" if sp[0] is not None else "-"
    return (
        f"{r['case']:<20} {r['first']:>9.4g}x {', '.join(r['added']) or '-':<26} "
        f"{r['last']:>7.3g}x {r['last_validation']:>8.3g}x  {spread:<14} "
        f"{r['seconds']:5.0f} s"
    )


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("cases", nargs="*", help=f"cases (default all: {', '.join(CASES)})")
    ap.add_argument("--duration", type=float, default=30.0, help="record length [s]")
    ap.add_argument("--out", default=str(HERE / "out" / "reference_loop"))
    ap.add_argument("--force", action="store_true", help="replace an earlier run")
    a = ap.parse_args(argv)
    unknown = [c for c in a.cases if c not in CASES]
    if unknown:
        ap.error(f"unknown case(s) {', '.join(unknown)}; choose from {', '.join(CASES)}")
    out = Path(a.out)
    if out.exists() and any(out.iterdir()):
        if not a.force:
            ap.error(f"{out} exists; pass --force to replace it")
        shutil.rmtree(out)
    out.mkdir(parents=True, exist_ok=True)
    head = (
        f"{'case':<20} {'first fit':>10} {'added':<26} {'last':>8} {'val.':>9}  "
        f"{'val. spread':<14} {'time':>7}"
    )
    print(head, flush=True)
    rows = []
    for name in a.cases or list(CASES):
        r = run_case(name, out / name, a.duration)
        rows.append(r)
        print(line(r), flush=True)
    text = "\n".join([head] + [line(r) for r in rows]) + "\n"
    (out / "report.txt").write_text(text)
    (out / "results.json").write_text(json.dumps(rows, indent=1))
    return {"rows": rows}


if __name__ == "__main__":
    main()

"""LuGre held against the switch model, on data rotorbayes did not make.

The independent reference (``tests/reference.py`` through ``tests/refdata.py``, case
``lugre``: the brake rig with a LuGre lower disc, sigma0_l 300 N m/rad, parameters unlike
the thesis tables) makes an estimation run (step input, seed 4) and a validation run
(seed 5), encoder-quantised, at 1 kHz.  Then, as a user would:

    rotorbayes fit --model brake est.csv --add lower_asymmetric_coulomb --validate val.csv \
        --out switch
    rotorbayes fit --model brake est.csv --add lower_asymmetric_coulomb --add lugre \
        --p0 switch/fit.json --validate val.csv --out lugre

and prints each fit's distance from the noise floor on estimation and validation data,
the estimated bristle parameters against the truth, and the time each fit took.

    python analyses/lugre_vs_switch.py [--duration 8] [--force]

Writes analyses/out/lugre_vs_switch/ (data, both fits, report.txt).
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

CLI = "import sys; from rotorbayes.cli import main; sys.exit(main(sys.argv[1:]))"


def fit(folder: Path, out: str, extra: list[str]) -> tuple[dict, float]:
    t0 = time.perf_counter()
    cmd = [
        sys.executable,
        "-c",
        CLI,
        "fit",
        "--model",
        "brake",
        "est.csv",
        "--add",
        "lower_asymmetric_coulomb",
        "--validate",
        "val.csv",
        "--out",
        out,
        "--force",
        *extra,
    ]
    proc = subprocess.run(cmd, cwd=folder, capture_output=True, text=True)
    (folder / f"{out}.log").write_text(proc.stdout + proc.stderr)
    if proc.returncode not in (0, 1):
        raise SystemExit(f"{' '.join(cmd[3:])} failed ({proc.returncode}); see {out}.log")
    return json.loads((folder / out / "fit.json").read_text()), time.perf_counter() - t0


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=8.0, help="record length [s]")
    ap.add_argument("--out", default=str(HERE / "out" / "lugre_vs_switch"))
    ap.add_argument("--force", action="store_true", help="replace an earlier run")
    a = ap.parse_args(argv)
    out = Path(a.out)
    if out.exists() and any(out.iterdir()):
        if not a.force:
            ap.error(f"{out} exists; pass --force to replace it")
        shutil.rmtree(out)
    out.mkdir(parents=True, exist_ok=True)
    case = refdata.CASES["lugre"]
    truth = case["params"]
    for label, seed in (("est", 4), ("val", 5)):
        ex = refdata.make_experiment(
            case["config"], truth, duration=a.duration, signal="steps", seed=seed
        )
        save_experiment(ex, out / f"{label}.csv", overwrite=True)
    rows = []
    sw, t_sw = fit(out, "switch", [])
    lg, t_lg = fit(out, "lugre", ["--add", "lugre", "--p0", "switch/fit.json"])
    for name, doc, secs in (("switch model", sw, t_sw), ("LuGre", lg, t_lg)):
        asm = doc["assessment"]
        rows.append(
            f"{name:<13} estimation {asm['worst_ratio_to_floor']:8.3g}x  "
            f"validation {asm['worst_ratio_to_floor_validation']:8.3g}x  "
            f"({secs:.0f} s)"
        )
    est = lg.get("estimates") or {}
    for n in ("sigma0_l", "sigma1_l", "Tc_l", "Ts_l", "J_l", "k_alpha"):
        e = est.get(n)
        if e is not None:
            rows.append(
                f"  {n:<9} {e['value']:10.4g} +- {e.get('stderr', float('nan')):8.2g}"
                f"   truth {truth[n]:10.4g}"
            )
    text = f"reference case 'lugre', brake, {a.duration:g} s at 1 kHz\n" + "\n".join(rows) + "\n"
    print(text, end="")
    (out / "report.txt").write_text(text)
    return {"switch": sw["assessment"], "lugre": lg["assessment"]}


if __name__ == "__main__":
    main()

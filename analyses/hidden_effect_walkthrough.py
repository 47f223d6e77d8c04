"""Walk-through: from a first fit to the corrected model on the bundled hidden-effect data.

The bundled files ``coupled_hidden_est`` / ``coupled_hidden_val`` hide a physical effect
(revealed in docs/example_data.md, which this walk-through does not need).  The steps are
the commands a user types, run in-process:

1. ``fit`` with no start (a start from the data, every parameter the data determine);
2. ``compare`` — where does the model fail?  ``diagnose`` — is it noise, which effect?
3. ``fit --p0 <fit> --add <the claimed effect>``, then diagnose again: one effect at a
   time, until the verdict is "adequate";
4. ``compare`` of the chain: how the error fell, step by step.

Run from the repository root::

    python analyses/hidden_effect_walkthrough.py [--out DIR] [--force]

It writes every fit folder (fit.json, diagnosis.json, figures) into ``--out`` (default
``analyses/out/walkthrough``) and a copy of what it prints to ``report.txt``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import shutil
import sys
import time
from pathlib import Path

from rotorbayes.cli import main as rotorbayes

EST, VAL = "example:coupled_hidden_est", "example:coupled_hidden_val"


def run(args: list[str], log) -> str:
    """Run one rotorbayes command, echo it and its output; fail loudly on an error."""
    buf = io.StringIO()
    print(f"\n$ rotorbayes {' '.join(args)}", file=log, flush=True)
    with contextlib.redirect_stdout(buf):
        code = rotorbayes(args)
    print(buf.getvalue(), file=log, end="", flush=True)
    if code not in (0,):
        raise SystemExit(f"rotorbayes {' '.join(args)} exited with {code}")
    return buf.getvalue()


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(Path(__file__).parent / "out" / "walkthrough"))
    ap.add_argument("--force", action="store_true", help="replace an earlier walk-through")
    ap.add_argument("--max-steps", type=int, default=4, help="effects to add at most")
    a = ap.parse_args(argv)
    out = Path(a.out)
    if out.exists() and any(out.iterdir()):
        if not a.force:
            raise SystemExit(f"{out}/ already holds a walk-through; pass --force to replace it")
        shutil.rmtree(out)
    out.mkdir(parents=True, exist_ok=True)
    report = io.StringIO()

    class Tee:
        def write(self, s):
            sys.stdout.write(s)
            report.write(s)

        def flush(self):
            sys.stdout.flush()

    log = Tee()
    t0 = time.perf_counter()
    fit = out / "fit0"
    run(["fit", "--model", "coupled", EST, "--validate", VAL, "--out", str(fit)], log)
    run(["compare", str(fit), "--out", str(out / "compare0")], log)
    chain = [{"fit": fit.name, "effects": []}]
    added: list[str] = []
    for step in range(1, a.max_steps + 1):
        run(["diagnose", str(fit)], log)
        diag = json.loads((fit / "diagnosis.json").read_text())
        chain[-1]["diagnosis"] = {
            "adequate": diag["adequate"],
            "claimed": diag["claimed_effect"],
            "rms_over_floor": diag["rms_over_floor"],
        }
        if diag["adequate"] or not diag["claimed_effect"]:
            break
        effect = diag["claimed_effect"]
        added.append(effect)
        nxt = out / f"fit{step}"
        run(
            [
                "fit",
                "--model",
                "coupled",
                EST,
                "--validate",
                VAL,
                "--p0",
                str(fit),
                "--add",
                effect,
                "--out",
                str(nxt),
            ],
            log,
        )
        fit = nxt
        chain.append({"fit": fit.name, "effects": list(added)})
    run(["compare", str(fit), "--out", str(out / "compare_chain")], log)
    seconds = time.perf_counter() - t0
    print(f"\nwalk-through done in {seconds:.1f} s; effects added: {', '.join(added)}", file=log)
    (out / "report.txt").write_text(report.getvalue())
    return {"chain": chain, "added": added, "seconds": seconds, "out": str(out)}


if __name__ == "__main__":
    main()

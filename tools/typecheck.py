"""The type checker's ratchet: mypy on the whole package, counted per subpackage.

    python tools/typecheck.py            # check (CI and the pre-commit hook run this)
    python tools/typecheck.py --update   # rewrite the baseline after errors were fixed

Rules
-----
* ``kernel/`` and ``inference/`` have no mypy error at all, except the modules listed in
  :data:`PENDING` (see there).
* Every other subpackage (``model``, ``io``, ``commands``, ...; the package's top-level modules
  count as ``(top level)``) and every module in :data:`PENDING` may have at most the number of
  errors recorded in ``tools/typecheck_baseline.json``. A count above its baseline fails; a
  count below it passes and says to lower the baseline (``--update``), so a fix stays fixed.

mypy reads its settings from ``[tool.mypy]`` in pyproject.toml; it is run with this
interpreter (``python -m mypy``), so the libraries it sees are the environment's. Their type
information differs between the two interpreters CI runs (numpy's stubs, arviz 0.2x or 1.x),
and so do some counts: the baseline holds one section per interpreter (``"python 3.11"``,
``"python 3.13"``), and ``--update`` writes the running interpreter's section only. An
interpreter without a section is held to the largest count of the recorded ones.
Exit code: 0 when every rule holds, 1 when one does not, 2 when mypy itself failed.
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "src/rotorbayes"
BASELINE = ROOT / "tools" / "typecheck_baseline.json"

# Subpackages that must have no error at all.
STRICT = ("kernel", "inference")

# Modules of the strict subpackages counted against the baseline rather than held at zero,
# while a rewrite is under way on another branch (a module path without ".py": it covers the
# module file and, if the module becomes a subpackage, every file in it). Empty: every module
# of kernel/ and inference/ is held at zero.
PENDING: tuple[str, ...] = ()

_ERROR = re.compile(r"^(?P<path>[^:\n]+\.pyi?):\d+(?::\d+)?: error: ", re.MULTILINE)
_TOP = "(top level)"


def area(path: str) -> str:
    """The key a mypy error at ``path`` is counted under (a subpackage or a pending file)."""
    rel = Path(path).as_posix()
    prefix = PACKAGE + "/"
    if not rel.startswith(prefix):
        return rel
    rel = rel[len(prefix) :]
    for module in PENDING:
        if rel == module + ".py" or rel.startswith(module + "/"):
            return module
    head, sep, _ = rel.partition("/")
    return head if sep else _TOP


def run_mypy() -> tuple[str, int]:
    """mypy's report on the package and its exit code."""
    proc = subprocess.run(
        [sys.executable, "-m", "mypy", PACKAGE],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    return proc.stdout + proc.stderr, proc.returncode


def count(report: str) -> Counter[str]:
    """Errors per area in mypy's report."""
    return Counter(area(m.group("path")) for m in _ERROR.finditer(report))


def check(counts: Counter[str], baseline: dict[str, int]) -> tuple[list[str], list[str]]:
    """The broken rules and the areas whose baseline can come down."""
    failures: list[str] = []
    lower: list[str] = []
    for key in sorted(set(counts) | set(baseline)):
        n = counts.get(key, 0)
        strict = key in STRICT or (key.partition("/")[0] in STRICT and key not in PENDING)
        if strict:
            if n:
                failures.append(f"{key}: {n} error(s); this subpackage must have none")
            continue
        allowed = baseline.get(key, 0)
        if n > allowed:
            failures.append(f"{key}: {n} error(s), baseline {allowed}; fix the new ones")
        elif n < allowed:
            lower.append(f"{key}: {n} error(s), baseline {allowed}")
    return failures, lower


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--update",
        action="store_true",
        help="write the current counts as the baseline (refused if a count rose)",
    )
    args = parser.parse_args(argv)

    report, rc = run_mypy()
    counts = count(report)
    if rc not in (0, 1) or (rc == 1 and not counts):
        print(report, end="")
        print(f"typecheck FAILED: mypy exited with {rc} without a list of errors", file=sys.stderr)
        return 2
    sections = json.loads(BASELINE.read_text()) if BASELINE.exists() else {}
    here = f"python {sys.version_info.major}.{sys.version_info.minor}"
    if here in sections:
        baseline = sections[here]
    elif args.update:  # this interpreter's first record: its counts as they are
        baseline = dict(counts)
    elif sections:
        baseline = {}
        for counts_of in sections.values():
            for key, n in counts_of.items():
                baseline[key] = max(n, baseline.get(key, 0))
        print(f"(no baseline section for {here}: held to the largest recorded counts)")
    else:
        print(
            f"typecheck FAILED: no baseline {BASELINE.relative_to(ROOT)}; record one with "
            "`python tools/typecheck.py --update`",
            file=sys.stderr,
        )
        return 2
    failures, lower = check(counts, baseline)

    if failures:
        # Only the lines of the areas that broke a rule, so the new errors are easy to find.
        broken = {line.partition(":")[0] for line in failures}
        for line in report.splitlines():
            m = _ERROR.match(line)
            if m and area(m.group("path")) in broken:
                print(line)
        print()
        print("typecheck FAILED:")
        for line in failures:
            print(f"  {line}")
        return 1

    total = sum(counts.values())
    if args.update:
        sections[here] = {k: n for k, n in sorted(counts.items()) if n}
        BASELINE.write_text(json.dumps(dict(sorted(sections.items())), indent=2) + "\n")
        print(
            f"baseline written: {BASELINE.relative_to(ROOT)}, section {here!r} "
            f"({total} error(s) in all)"
        )
        return 0
    print(
        f"typecheck passed: no error in {', '.join(s + '/' for s in STRICT)} "
        f"(pending: {len(PENDING)} module(s)); {total} error(s) in all, none above the baseline"
    )
    if lower:
        print(
            f"Fewer errors than the baseline ({here}); lower it with "
            "`python tools/typecheck.py --update` on this interpreter:"
        )
        for line in lower:
            print(f"  {line}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""The type checker's ratchet (tools/typecheck.py): how mypy's errors are counted and judged.

mypy itself is not run here (CI and the pre-commit hook run the script); these are its rules
on made-up reports.
"""

import importlib.util
import json
from collections import Counter
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "tools" / "typecheck.py"

pytestmark = pytest.mark.skipif(not SCRIPT.exists(), reason="tools/ is not in this checkout")


@pytest.fixture(scope="module")
def tc():
    spec = importlib.util.spec_from_file_location("typecheck", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


REPORT = """\
src/rotorbayes/model/simulate.py:104: error: Unsupported operand types  [operator]
src/rotorbayes/model/simulate.py:104: note: a note is not an error
src/rotorbayes/io/glitches.py:7:12: error: Item "None" has no attribute  [union-attr]
src/rotorbayes/cli.py:3: error: Missing return  [return]
src/rotorbayes/inference/problem.py:9: error: Item "str" of "Model | str"  [union-attr]
src/rotorbayes/inference/starts.py:1: error: Incompatible types  [assignment]
src/rotorbayes/inference/sampling/run.py:1: error: Incompatible types  [assignment]
src/rotorbayes/inference/sampling.py:1: error: Incompatible types  [assignment]
src/rotorbayes/kernel/solver.py:2: error: Incompatible types  [assignment]
Found 8 errors in 8 files (checked 87 source files)
"""


#: Modules pending for these made-up reports (the real list may be empty).
SOME_PENDING = ("inference/problem", "inference/sampling")


def test_errors_are_counted_per_subpackage_and_pending_module(tc, monkeypatch):
    monkeypatch.setattr(tc, "PENDING", SOME_PENDING)
    # A pending module that became a subpackage (sampling.py -> sampling/) counts as one.
    assert tc.count(REPORT) == Counter(
        {
            "model": 1,
            "io": 1,
            "(top level)": 1,
            "inference/problem": 1,
            "inference/sampling": 2,
            "inference": 1,
            "kernel": 1,
        }
    )


def test_strict_subpackages_allow_no_error_whatever_the_baseline(tc):
    failures, _ = tc.check(Counter({"kernel": 1, "inference": 2}), {"kernel": 5, "inference": 5})
    assert len(failures) == 2
    assert all("must have none" in f for f in failures)


def test_a_count_above_its_baseline_fails_and_below_asks_to_lower(tc, monkeypatch):
    monkeypatch.setattr(tc, "PENDING", SOME_PENDING)
    baseline = {"model": 3, "io": 2, "inference/problem": 4}
    counts = Counter({"model": 4, "io": 1, "inference/problem": 4, "report": 1})
    failures, lower = tc.check(counts, baseline)
    assert sorted(f.split(":")[0] for f in failures) == ["model", "report"]
    assert [f.split(":")[0] for f in lower] == ["io"]


def test_every_pending_module_is_in_a_strict_subpackage(tc):
    for module in tc.PENDING:
        assert module.partition("/")[0] in tc.STRICT
        where = ROOT / tc.PACKAGE / module
        assert where.with_suffix(".py").exists() or where.is_dir(), module


def test_the_recorded_baseline_has_no_strict_area_but_pending_modules(tc):
    sections = json.loads(tc.BASELINE.read_text())
    assert sections, "the baseline records no interpreter"
    for counts in sections.values():
        for key, n in counts.items():
            assert n > 0
            assert key in tc.PENDING or key.partition("/")[0] not in tc.STRICT, key

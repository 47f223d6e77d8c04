"""What a new user meets in the first hour: one headline number with its data named, the
compile notice, intervals printed with the digits they need."""

from __future__ import annotations

import io
import math
import sys
from pathlib import Path

import pytest

from rotorbayes.inference.assess import Assessment
from rotorbayes.util import coldstart
from rotorbayes.util.numformat import fmt_value, significant_digits


def _row(data, ratio, fitted=True):
    return {
        "data": data,
        "experiment": "e",
        "channel": "theta_l",
        "rms": ratio,
        "floor": 1.0,
        "ratio": ratio,
        "fitted": fitted,
    }


def test_headline_is_the_estimation_data_and_validation_is_named():
    a = Assessment(
        [
            _row("estimation", 710.37),
            _row("validation", 2711.9),
            _row("estimation", 900.0, fitted=False),
        ]
    )
    assert a.worst_ratio == pytest.approx(710.37)  # fitted channels, estimation data only
    assert a.worst_ratio_validation == pytest.approx(2711.9)
    assert a.verdict.startswith("710x the encoder floor on the estimation data")
    assert "validation data: 2712x" in a.verdict and "e+03" not in a.verdict
    d = a.as_dict()
    assert d["worst_ratio_to_floor"] == pytest.approx(710.37)
    assert d["worst_ratio_to_floor_validation"] == pytest.approx(2711.9)
    # At the floor on the estimation data but not on the validation data: said.
    b = Assessment([_row("estimation", 1.01), _row("validation", 40.0)])
    assert b.verdict.startswith("at the encoder floor on the estimation data")
    assert "does not predict others" in b.verdict
    c = Assessment([_row("estimation", 1.2)])
    assert "validation" not in c.verdict and math.isnan(c.worst_ratio_validation)


def test_value_digits_follow_the_spread():
    assert fmt_value(4.3687012, 2.7e-6) == "4.3687012"
    # Trial 11's corner titles: "k_m = 3.2 ± 1.6e-05" beside "b_u = 1.7499982".
    assert fmt_value(3.2, 1.6e-5) == "3.200000" and fmt_value(12.0, 0.5) == "12.00"
    assert significant_digits(1.0, 0.0) == 6  # no spread: the default


def test_compile_notice_only_with_a_cold_cache(tmp_path, monkeypatch):
    # An empty NUMBA_CACHE_DIR is where numba would look first: a cold cache.
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "empty"))
    assert coldstart.cache_is_cold()
    (tmp_path / "empty" / "x").mkdir(parents=True)
    (tmp_path / "empty" / "x" / "solver.simulate_into-1.py399.nbi").write_text("")
    assert coldstart.cache_is_cold()  # another Python's index does not count
    # An index of this numba whose stamp is the solver's content is warm, whatever the
    # file times (a checkout rewrites them; numba >= 0.61 stamps by content); one of an
    # edited solver is cold.  (The trial of 2026-11-24 printed "compiling ... took 0 s".)
    import hashlib
    import pickle
    from importlib.metadata import version

    import rotorbayes.kernel.solver as solver

    tag = f"py{sys.version_info.major}{sys.version_info.minor}"
    index = tmp_path / "empty" / "x" / f"solver.simulate_into-1.{tag}.nbi"
    for content, cold in ((b"edited", True), (Path(solver.__file__).read_bytes(), False)):
        with open(index, "wb") as f:
            pickle.dump(version("numba"), f)
            f.write(pickle.dumps((hashlib.sha256(content).digest(), {})))
        assert coldstart.cache_is_cold() is cold
    # The kernel is imported already in this process: nothing to compile, nothing said.
    buf = io.StringIO()
    assert coldstart.compile_kernel(buf) is None and buf.getvalue() == ""


def test_import_compiles_nothing():
    # Issue 33: a command compiles only what it uses, so importing compiles nothing (every
    # entry point used to be compiled at import: 121 s with a cold cache on 2 cores).
    import subprocess

    code = (
        "import rotorbayes\nfrom rotorbayes.kernel import solver as S\n"
        "print(sum(len(S.compiled(n).overloads) for n in S.SIGNATURES),"
        " len(S._integrate.overloads))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)  # fmt: skip
    assert out.stdout.split() == ["0", "0"]


def test_compile_notice_is_one_line_for_what_a_fit_compiles(monkeypatch):
    # A fit's first residuals compile its Jacobian's batch and its simulation with them:
    # one line, one figure (it said three lines, one per entry point).
    from rotorbayes.kernel import solver

    monkeypatch.setattr(coldstart, "_READY", {})
    monkeypatch.setattr(coldstart, "COMPILE_SECONDS", {})
    monkeypatch.setattr(coldstart, "COMPILE_CPU_SECONDS", {})
    monkeypatch.setattr(coldstart, "cache_is_cold", lambda name="*", module="solver": True)
    monkeypatch.setattr(solver, "is_ready", lambda name: False)
    asked = []
    monkeypatch.setattr(solver, "entry", lambda name: asked.append(name) or "compiled " + name)
    helpers = []  # the least squares' compiled helpers, compiled with the residuals

    class Helper:
        def compile(self, args):
            helpers.append(args)

    fake = ("triangle", "triangle", Helper(), ("D", "r", "scale"))
    monkeypatch.setattr(
        coldstart,
        "_helpers",
        lambda name, parallel: [fake] if parallel and "residuals" in name else [],
    )
    aside = []  # the helpers handed to a second process while the solver compiles
    monkeypatch.setattr(coldstart, "_compile_aside", lambda h: aside.append(h))
    buf = io.StringIO()
    assert coldstart.kernel_entry("residuals_into_plain", buf) == "compiled residuals_into_plain"
    assert aside == [[fake]]
    line = buf.getvalue()
    assert line.startswith(
        coldstart.MESSAGE
        + " (the residuals, their parallel batches and the simulation, plain kernel), once"
    ) and line.rstrip().endswith(" s")
    assert line.count("\n") == 1 and line.count("took") == 1
    group = {"residuals_into_plain", "residuals_batch_into_plain", "simulate_into_plain"}
    assert set(asked) == group and helpers == [("D", "r", "scale")]
    assert set(coldstart.COMPILE_SECONDS) == group | {"triangle.triangle"}
    buf = io.StringIO()  # ready now, the batch too: nothing said, nothing asked of the solver
    assert coldstart.kernel_entry("residuals_batch_into_plain", buf).startswith("compiled")
    assert buf.getvalue() == "" and len(asked) == 3
    # A simulation alone compiles the simulation alone (the first `simulate`).
    buf = io.StringIO()
    assert coldstart.kernel_entry("simulate_into_full", buf) == "compiled simulate_into_full"
    assert buf.getvalue().startswith(coldstart.MESSAGE + " (the simulation, full kernel), once")
    assert asked[3:] == ["simulate_into_full"]
    # A process that forks (a pool's fork server) loads no parallel batch or helper.
    buf = io.StringIO()
    coldstart.kernel_entry("residuals_into_full", buf, parallel=False)
    assert asked[4:] == ["residuals_into_full"] and len(helpers) == 1
    assert "(the residuals, full kernel)" in buf.getvalue()


def test_a_fits_helpers_compiled_aside_land_in_numbas_cache(tmp_path, monkeypatch):
    """The process :func:`coldstart._compile_aside` starts compiles the least squares'
    helpers into the cache this process then loads them from (a fresh cache here)."""
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    monkeypatch.delenv(coldstart.ASIDE_ENV, raising=False)
    monkeypatch.setattr(coldstart, "_cores", lambda: 2)
    helpers = [(m, f, None, None) for m, f, _ in coldstart.FIT_HELPERS]
    assert all(coldstart.cache_is_cold(f, m) for m, f, _, _ in helpers)
    child = coldstart._compile_aside(helpers)
    assert child is not None
    coldstart._await_aside(child)
    assert child.returncode == 0
    assert not any(coldstart.cache_is_cold(f, m) for m, f, _, _ in helpers)
    # Not with one core, nor when switched off: the command compiles them itself.
    monkeypatch.setattr(coldstart, "_cores", lambda: 1)
    assert coldstart._compile_aside(helpers) is None
    monkeypatch.setattr(coldstart, "_cores", lambda: 2)
    monkeypatch.setenv(coldstart.ASIDE_ENV, "0")
    assert coldstart._compile_aside(helpers) is None


def test_the_sensitivity_kernels_first_use_is_said_once_and_waits_for_its_aside(monkeypatch):
    monkeypatch.setattr(coldstart, "_SENS", {"ready": False, "child": None})
    monkeypatch.setattr(coldstart, "COMPILE_SECONDS", {})
    monkeypatch.setattr(coldstart, "cache_is_cold", lambda name="*", module="solver": True)
    started = []
    waited = []

    class Child:
        returncode = 0

        def wait(self, timeout=None):
            waited.append(timeout)

        def kill(self):  # pragma: no cover - only if the call fails
            raise AssertionError("killed")

    monkeypatch.setattr(coldstart, "_spawn_aside", lambda specs: started.append(specs) or Child())
    call = "rotorbayes.inference.problem:compile_sensitivity_kernel"
    coldstart.sensitivity_aside(call)
    coldstart.sensitivity_aside(call)  # once per process
    assert started == [[coldstart.CALL + call]]
    buf = io.StringIO()
    with coldstart.first_sensitivities(buf):
        assert waited == [coldstart.ASIDE_TIMEOUT]  # the aside is done before the call
    with coldstart.first_sensitivities(buf):
        pass
    text = buf.getvalue()
    assert text.startswith(coldstart.MESSAGE + " (the sensitivities, for the Jacobian), once")
    assert text.count("\n") == 1 and text.count("took") == 1
    assert coldstart.SENSITIVITY in coldstart.COMPILE_SECONDS
    # Ready in this process: no second process, nothing said.
    coldstart.sensitivity_aside(call)
    assert len(started) == 1

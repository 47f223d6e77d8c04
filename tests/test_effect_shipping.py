"""User effect files travel with the work (issue 18 item 3): a process or Dask worker gets
the effect file's code with the effect and runs it after checking its SHA-256, so the file
need not be on the worker's disk; altered code is refused."""

from __future__ import annotations

import pickle
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import rotorbayes as rb
from rotorbayes import inference
from rotorbayes.model import effects

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "angle_friction.py"

CHILD = """
import pickle, sys
prob, x = pickle.loads(sys.stdin.buffer.read())
sys.stdout.buffer.write(pickle.dumps(prob.residuals(x)))
"""


def _problem(path: Path) -> inference.Problem:
    ex = rb.load_example("coupled_est")
    n = 401
    short = rb.Experiment(
        t=ex.t[:n],
        u=ex.u[:n],
        theta_u=ex.theta_u[:n],
        theta_l=ex.theta_l[:n],
        name="coupled 2 s",
        path=ex.path,
    )
    return inference.Problem(rb.Model("coupled", [f"{path}:angle_friction"]), [short])


def test_a_worker_without_the_file_runs_the_shipped_code(tmp_path):
    eff_file = tmp_path / "my_effects.py"
    shutil.copy(EXAMPLE, eff_file)
    prob = _problem(eff_file)
    x = prob.x_from(prob.base)
    here = prob.residuals(x)
    blob = pickle.dumps((prob, x))
    eff_file.unlink()  # the worker's disk has no such file
    p = subprocess.run([sys.executable, "-c", CHILD], input=blob, capture_output=True, timeout=600)
    assert p.returncode == 0, p.stderr.decode()[-2000:]
    there = pickle.loads(p.stdout)
    assert there.tobytes() == here.tobytes()


def test_altered_code_is_refused(tmp_path):
    eff_file = tmp_path / "other_effects.py"
    shutil.copy(EXAMPLE, eff_file)
    eff = effects.load_user_effect(f"{eff_file}:angle_friction")
    fn, (path, name, code, sha) = eff.__reduce_ex__(4)
    assert sha == effects.file_sha256(eff_file)
    with pytest.raises(effects.EffectError, match="arrived altered"):
        fn(path, name, code + b"\n# changed\n", sha)
    # The same code arriving again in this process: the effect already loaded.
    assert fn(path, name, code, sha) is eff

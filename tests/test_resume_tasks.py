"""Multistart starts and profile points survive a kill: each finished one is kept beside the
result folder (``.OUT.tasks/``), a re-run with the same ``--out`` skips it, and the result is
bit for bit that of an uninterrupted run; a changed problem or setting reuses nothing.

Small problem: the upper configuration, 5 s at 200 Hz.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

import rotorbayes as rb
from rotorbayes import inference
from rotorbayes.inference import identify, parallel
from rotorbayes.inference.taskstore import TaskStore, store_path


def short_upper(seconds: float = 5.0) -> rb.Experiment:
    ex = rb.load_example("upper_est")
    n = int(round(seconds / ex.dt)) + 1
    return rb.Experiment(
        t=ex.t[:n], u=ex.u[:n], theta_u=ex.theta_u[:n], theta_l=None, name="upper 5 s", path=ex.path
    )


def _cli(args, **kw):
    return subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys; from rotorbayes.cli import main; sys.exit(main())",
            *args,
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "NUMBA_NUM_THREADS": "1"},
        **kw,
    )


def test_multistart_killed_then_rerun_skips_finished_starts(tmp_path):
    data = tmp_path / "upper5.csv"
    rb.save_experiment(short_upper(), data)
    n = 20
    args = [
        "multistart",
        "--model",
        "upper",
        str(data),
        "--starts",
        str(n),
        "--max-nfev",
        "30",
        "--backend",
        "serial",
    ]
    # The reference: one uninterrupted run.
    ref = _cli([*args, "--out", str(tmp_path / "ref")])
    o, e = ref.communicate(timeout=300)
    assert ref.returncode == 0, e
    assert not store_path(tmp_path / "ref").exists()  # complete: the store is gone
    # The same command, SIGKILLed once some starts have finished.
    out = tmp_path / "ms"
    store = store_path(out)
    p = _cli([*args, "--out", str(out)])
    deadline = time.time() + 240
    while time.time() < deadline and p.poll() is None:
        if store.exists() and len(list(store.glob("*.npz"))) >= 3:
            break
        time.sleep(0.02)
    assert p.poll() is None, "the run ended before it could be killed"
    p.send_signal(signal.SIGKILL)
    p.communicate(timeout=60)
    kept = len(list(store.glob("*.npz")))
    assert 3 <= kept < n
    assert not out.exists()
    # The re-run reads them and fits only the rest.
    p = _cli([*args, "--out", str(out)])
    o2, e2 = p.communicate(timeout=300)
    assert p.returncode == 0, e2
    assert f"{kept} of {n} starts had finished in an earlier run" in o2
    assert f"start {kept:3d}/{n} done" not in o2 and f"start {kept + 1:3d}/{n} done" in o2
    a = json.loads((tmp_path / "ref" / "multistart.json").read_text())
    b = json.loads((out / "multistart.json").read_text())
    for k in ("starts", "ends", "ssr", "success", "clusters", "start_index", "failed"):
        assert a[k] == b[k], k
    assert not store.exists()


def test_a_changed_setting_or_problem_reuses_nothing(tmp_path, capsys):
    prob = inference.Problem("upper", [short_upper()])
    folder = tmp_path / ".ms.tasks"
    with parallel.use_executor(parallel.ExecutorSpec("serial")):
        first = inference.multistart(prob, 3, seed=1, max_nfev=10, progress=False, resume=folder)
        assert len(list(folder.glob("*.npz"))) == 3
        # Same problem and settings: every start is read back, bit for bit.
        again = inference.multistart(prob, 3, seed=1, max_nfev=10, progress=True, resume=folder)
        assert "3 of 3 starts had finished in an earlier run" in capsys.readouterr().out
        assert again.ends.tobytes() == first.ends.tobytes()
        assert again.ssr.tobytes() == first.ssr.tobytes()
        assert [f.jac.tobytes() for f in again.fits] == [f.jac.tobytes() for f in first.fits]
        # Another budget: the store is emptied, the starts fitted again.
        other = inference.multistart(prob, 3, seed=1, max_nfev=12, progress=True, resume=folder)
        txt = capsys.readouterr()
        assert "of another problem or other settings" in txt.err
        assert "had finished in an earlier run" not in txt.out
        fresh = inference.multistart(prob, 3, seed=1, max_nfev=12, progress=False)
        assert other.ends.tobytes() == fresh.ends.tobytes()
        # Other data (one sample changed): nothing reused either.
        ex = short_upper()
        ex.theta_u[100] += 1e-4
        prob2 = inference.Problem("upper", [ex])
        inference.multistart(prob2, 3, seed=1, max_nfev=12, progress=True, resume=folder)
        txt = capsys.readouterr()
        assert "of another problem or other settings" in txt.err


def test_a_damaged_record_is_fitted_again(tmp_path):
    prob = inference.Problem("upper", [short_upper()])
    folder = tmp_path / ".ms.tasks"
    with parallel.use_executor(parallel.ExecutorSpec("serial")):
        first = inference.multistart(prob, 2, seed=3, max_nfev=10, progress=False, resume=folder)
        rec = sorted(folder.glob("*.npz"))[0]
        rec.write_bytes(rec.read_bytes()[:50])  # a torn write (cannot happen: renamed whole)
        again = inference.multistart(prob, 2, seed=3, max_nfev=10, progress=False, resume=folder)
    assert again.ends.tobytes() == first.ends.tobytes()


def test_profile_points_resume_bit_for_bit(tmp_path):
    prob = inference.Problem("upper", [short_upper()])
    fit = inference.fit(prob, max_nfev=30, uncertainty=False)
    folder = tmp_path / ".id.tasks"
    with parallel.use_executor(parallel.ExecutorSpec("serial")):
        ref = identify.profile(prob, fit.x, "k_m", n_points=5, max_nfev=10)
        full = identify.profile(prob, fit.x, "k_m", n_points=5, max_nfev=10, resume=folder)
        files = sorted(folder.glob("*.npz"))
        assert len(files) == 5
        for f in files[:2]:
            f.unlink()  # as if the run had been killed after three points
        again = identify.profile(prob, fit.x, "k_m", n_points=5, max_nfev=10, resume=folder)
    assert TaskStore(folder, "another key").reused == 0
    assert not list(folder.glob("*.npz"))  # another key: emptied
    assert np.array(full["delta_chi2"]).tobytes() == np.array(ref["delta_chi2"]).tobytes()
    assert np.array(again["delta_chi2"]).tobytes() == np.array(ref["delta_chi2"]).tobytes()


@pytest.mark.parametrize("bad", ["not json", '{"key": 3}'])
def test_a_foreign_or_damaged_key_file_empties_the_store(tmp_path, bad):
    folder = tmp_path / ".x.tasks"
    folder.mkdir()
    (folder / "key.json").write_text(bad)
    (folder / "000001.npz").write_bytes(b"junk")
    s = TaskStore(folder, "k", "start")
    assert not (folder / "000001.npz").exists()
    assert s.get(1, "t") == (False, None)


def test_first_fit_restarts_resume_after_ctrl_c_to_the_uninterrupted_fit(
    tmp_path, monkeypatch, capsys
):
    """`fit` without --p0 on data the model cannot explain (a hidden effect: 710x the floor)
    restarts around the data start; Ctrl-C during the restarts keeps the fits that had
    finished, and the same command ends with the fit of an uninterrupted run, bit for bit."""
    from rotorbayes.cli import main
    from rotorbayes.inference import first_fit

    args = ["fit", "--model", "coupled", "example:coupled_hidden_est", "--restarts", "4"]
    assert main([*args, "--out", str(tmp_path / "ref")]) == 0
    ref = json.loads((tmp_path / "ref" / "fit.json").read_text())
    assert not store_path(tmp_path / "ref").exists()
    out = tmp_path / "f"
    orig, calls = first_fit._fit_start, []

    def stopped_at_the_third(*a, **kw):  # the third restart is stopped by a Ctrl-C
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return orig(*a, **kw)

    monkeypatch.setattr(first_fit, "_fit_start", stopped_at_the_third)
    capsys.readouterr()
    with parallel.use_executor(parallel.ExecutorSpec("serial")):  # one restart after the other
        assert main([*args, "--out", str(out)]) == 130
    err = capsys.readouterr().err
    assert "nothing was written" in err and "3 fit(s)" in err and "skips them" in err, err
    assert not out.exists() and len(list(store_path(out).glob("*.npz"))) == 3
    monkeypatch.setattr(first_fit, "_fit_start", orig)
    assert main([*args, "--out", str(out)]) == 0
    said = capsys.readouterr().out
    assert "the fit from the data start had finished in an earlier run" in said
    assert "2 of 4 restarts had finished in an earlier run" in said
    got = json.loads((out / "fit.json").read_text())
    for k in ("estimates", "ssr", "start", "nfev"):
        assert got[k] == ref[k], k
    assert got["uncertainty"] == ref["uncertainty"]
    assert not store_path(out).exists()

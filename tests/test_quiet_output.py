"""What the user sees: `rotorbayes demo` prints only what rotorbayes wrote.

The demo runs as a user runs it (a subprocess, Python's default warning filters, output to
a pipe, an empty arviz cache so arviz's once-a-day notice would fire) and every line of its
stdout and stderr is checked for the marks of a library talking: a logging record
(``WARNING:root:...``), a Python warning (``...Warning: ...``), a traceback, a progress bar
written into a pipe. The demo covers fit, diagnose, compare, sample, identify and report.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys

#: Marks of output that rotorbayes did not write.
FOREIGN = [
    (re.compile(r"^(DEBUG|INFO|WARNING|ERROR|CRITICAL):"), "a logging record"),
    (re.compile(r"\b\w*(Warning|Error):"), "a Python warning or exception"),
    (re.compile(r"Traceback \(most recent call last\)"), "a traceback"),
    (re.compile(r"site-packages|dist-packages"), "a library's source line"),
    (re.compile(r"\d+it/s\]|it/s\]|\|#+"), "a progress bar in a pipe"),
]


def foreign_lines(text: str) -> list[str]:
    """Lines of ``text`` that carry a mark of :data:`FOREIGN`, with the reason."""
    out = []
    for line in text.splitlines():
        for pattern, why in FOREIGN:
            if pattern.search(line):
                out.append(f"{why}: {line[:200]}")
                break
    return out


def test_the_marks_are_recognised():
    sample = ("WARNING:root:Too few points to create valid contours\n"
              "/x/site-packages/arviz/__init__.py:56: FutureWarning: \n"
              "Traceback (most recent call last):\n"
              " 10%|#         | 30/300 [00:01<00:08, 30.10it/s]\n"
              "warning: ensemble0: 300 steps are not more than 50 τ\n"
              "verdict: INADEQUATE — the model does not explain the data\n")
    found = foreign_lines(sample)
    assert len(found) == 4
    assert not any("ensemble0" in f or "verdict" in f for f in found)


def test_demo_prints_only_its_own_lines(tmp_path):
    env = dict(os.environ)
    env.pop("PYTHONWARNINGS", None)
    env["XDG_CACHE_HOME"] = str(tmp_path / "cache")  # arviz 0.2x's notice would fire here
    env.setdefault("NUMBA_NUM_THREADS", "2")
    proc = subprocess.run([sys.executable, "-m", "rotorbayes.cli", "demo", "--out",
                           str(tmp_path / "demo")], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=1200)
    assert proc.returncode == 0, proc.stderr[-3000:]
    bad = foreign_lines(proc.stdout) + foreign_lines(proc.stderr)
    assert not bad, "library output reached the user:\n" + "\n".join(bad[:20])
    assert "demo done" in proc.stdout
    assert (tmp_path / "demo" / "report.html").exists()


class _Prob:
    """The two things plot_corner asks of a problem."""

    names = ("k_m", "J_l", "pinned")

    def info(self, name):
        raise KeyError(name)


def test_corner_of_a_short_ragged_posterior_logs_nothing(caplog):
    import matplotlib

    matplotlib.use("Agg")
    import numpy as np

    from rotorbayes.inference import arviz_compat as AZ
    from rotorbayes.posterior_figures import plot_corner

    rng = np.random.default_rng(0)
    post = {"k_m": 4.3687 + 3e-6 * rng.standard_normal((2, 100)),
            "J_l": 0.0414 + 3e-7 * rng.standard_t(2, (2, 100)),  # heavy tails: ragged
            "pinned": np.full((2, 100), 0.5)}  # every draw at one value (a bound)
    for n in (200, 40):  # contours, and too few draws for contours
        idata = AZ.from_groups({"posterior": {k: v[:, : n // 2] for k, v in post.items()}})
        caplog.clear()
        with caplog.at_level("WARNING"):
            fig = plot_corner(idata, _Prob())
            fig.canvas.draw()
        assert not caplog.records, [r.getMessage() for r in caplog.records]
        # No offset text ("1e-6+4.3687"): it collides with the neighbouring labels.
        offsets = [ax.xaxis.get_offset_text().get_text() + ax.yaxis.get_offset_text().get_text()
                   for ax in fig.axes]
        assert not any(offsets), offsets
        titles = [ax.get_title() for ax in fig.axes if ax.get_title()]
        assert any(t.startswith("k_m = 4.3687") for t in titles), titles
        matplotlib.pyplot.close(fig)

"""What the user sees: `rotorbayes demo` prints only what rotorbayes wrote.

The demo runs as a user runs it (a subprocess, Python's default warning filters, output to
a pipe, an empty arviz cache so arviz's once-a-day notice would fire) and every line of its
stdout and stderr is checked for the marks of a library talking: a logging record
(``WARNING:root:...``), a Python warning (``...Warning: ...``), a traceback, a progress bar
written into a pipe. The demo covers fit, diagnose, compare, sample, identify and report.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys

import pytest

#: Marks of output that rotorbayes did not write.
FOREIGN = [
    (re.compile(r"^(DEBUG|INFO|WARNING|ERROR|CRITICAL):"), "a logging record"),
    (re.compile(r"\b\w*(Warning|Error):"), "a Python warning or exception"),
    (re.compile(r"Traceback \(most recent call last\)"), "a traceback"),
    (re.compile(r'File ".*", line \d+'), "a traceback frame"),
    (re.compile(r"\.py:\d+: "), "a warning's source location"),
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
    sample = (
        "WARNING:root:Too few points to create valid contours\n"
        "/x/site-packages/arviz/__init__.py:56: FutureWarning: \n"
        "Traceback (most recent call last):\n"
        " 10%|#         | 30/300 [00:01<00:08, 30.10it/s]\n"
        "warning: ensemble0: 300 steps are not more than 50 τ\n"
        "verdict: INADEQUATE — the model does not explain the data\n"
        "(the analysis file: /v/lib/python3.13/site-packages/rotorbayes/data/demo.toml)\n"
        '  File "/v/site-packages/corner/core.py", line 12, in hist2d\n'
    )
    found = foreign_lines(sample)
    assert len(found) == 5
    assert not any("ensemble0" in f or "verdict" in f for f in found)


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """`rotorbayes demo` run once as a user runs it: (completed process, output folder)."""
    tmp = tmp_path_factory.mktemp("demo")
    env = dict(os.environ)
    env.pop("PYTHONWARNINGS", None)
    env["XDG_CACHE_HOME"] = str(tmp / "cache")  # arviz 0.2x's notice would fire here
    env.setdefault("NUMBA_NUM_THREADS", "2")
    # --out with a trailing slash, as people type it.
    proc = subprocess.run(
        [sys.executable, "-m", "rotorbayes.cli", "demo", "--out", str(tmp / "demo") + "/"],
        cwd=tmp,
        env=env,
        capture_output=True,
        text=True,
        timeout=1800,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc, tmp / "demo"


@pytest.mark.slow
@pytest.mark.every_python
def test_demo_prints_only_its_own_lines(demo):
    proc, _ = demo
    bad = foreign_lines(proc.stdout) + foreign_lines(proc.stderr)
    assert not bad, "library output reached the user:\n" + "\n".join(bad[:20])
    assert "demo done" in proc.stdout
    # The bundled first run ends without telling the user to distrust it: its chains are
    # long enough (50 τ) for its own posterior.
    assert "not more than 50" not in proc.stdout + proc.stderr, proc.stderr[-2000:]


@pytest.mark.slow
@pytest.mark.every_python
def test_demo_says_one_headline_number_and_clean_paths(demo):
    proc, _ = demo
    out = proc.stdout
    assert "//" not in out.replace("://", "")
    # fit0's verdict names its data, and diagnose0 gives the same number for the same fit.
    fit0 = out[out.index("---- fit0") : out.index("---- diagnose0")]
    diag0 = out[out.index("---- diagnose0") : out.index("---- fit1")]
    m = re.search(r"verdict: (\S+)x the encoder floor on the estimation data", fit0)
    assert m, fit0[-800:]
    assert f"{m.group(1)}x" in diag0, (m.group(1), diag0[:600])


@pytest.mark.slow
@pytest.mark.every_python
def test_demo_report_box_and_badges_agree(demo):
    from rotorbayes.report import write_report

    _, folder = demo
    page = (folder / "report.html").read_text()
    box = page[page.index('<div class="verdict') :]
    box = box[: box.index("</div>")]
    diag = json.loads((folder / "fit2" / "diagnosis.json").read_text())
    assert ('class="verdict good"' in box) == bool(diag["adequate"])
    assert ('tag good">adequate' in box) == bool(diag["adequate"])
    # The first (failing) fit's diagnosis and figures come before the final fit's.
    assert page.index("Where the first model fails: fit0") < page.index(
        "<h3>Diagnosis of fit2</h3>"
    )
    assert "The two ESS columns count different things" in page
    # An `immaterial` list is shown as notes, never as a failure.
    diag["adequate"] = True
    diag["immaterial"] = [
        {
            "effect": "string_damping",
            "words": "string_damping: p 0.004, predicted 1.01x -> 1.009x (immaterial)",
        }
    ]
    (folder / "fit2" / "diagnosis.json").write_text(json.dumps(diag))
    write_report(folder, folder / "report2.html")
    page = (folder / "report2.html").read_text()
    box = page[page.index('<div class="verdict') :]
    box = box[: box.index("</div>")]
    assert 'class="verdict good"' in box and "inadequate" not in box
    assert "Detectable but immaterial" in box and "string_damping" in box


class _Prob:
    """The two things plot_corner asks of a problem."""

    names = ("k_m", "J_l", "pinned")

    def info(self, name):
        raise KeyError(name)


def test_corner_of_a_short_ragged_posterior_logs_nothing(caplog):
    import matplotlib

    matplotlib.use("Agg")
    import numpy as np

    from rotorbayes.figures.posterior import plot_corner
    from rotorbayes.inference import arviz_compat

    rng = np.random.default_rng(0)
    post = {
        "k_m": 4.3687 + 3e-6 * rng.standard_normal((2, 100)),
        "J_l": 0.0414 + 3e-7 * rng.standard_t(2, (2, 100)),  # heavy tails: ragged
        "pinned": np.full((2, 100), 0.5),
    }  # every draw at one value (a bound)
    # emcee repeats a walker's position after a rejected proposal: 40 distinct correlated
    # points, each 5 times (corner's default histogram gives coinciding contour levels).
    base = rng.standard_normal((40, 4)) @ rng.standard_normal((4, 4))
    rep = np.repeat(base, 5, axis=0)
    repeated = {n: 1.0 + 1e-6 * rep[:, j].reshape(2, 100) for j, n in enumerate("abcd")}
    four = _Prob()
    four.names = tuple("abcd")  # no pinned parameter: the contours are drawn
    for n, draws, prob in ((200, post, _Prob()), (40, post, _Prob()), (200, repeated, four)):
        idata = arviz_compat.from_groups(
            {"posterior": {k: v[:, : n // 2] for k, v in draws.items()}}
        )
        caplog.clear()
        with caplog.at_level("WARNING"):
            fig = plot_corner(idata, prob)
            fig.canvas.draw()
        assert not caplog.records, [r.getMessage() for r in caplog.records]
        # No offset text ("1e-6+4.3687"): it collides with the neighbouring labels.
        offsets = [
            ax.xaxis.get_offset_text().get_text() + ax.yaxis.get_offset_text().get_text()
            for ax in fig.axes
        ]
        assert not any(offsets), offsets
        titles = [ax.get_title() for ax in fig.axes if ax.get_title()]
        assert any(t.startswith(f"{prob.names[0]} = ") for t in titles), titles
        matplotlib.pyplot.close(fig)

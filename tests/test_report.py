"""report.html: one self-contained page, checked as text and in a real headless Chromium.

The study folder is made with the command line on the bundled hidden-effect data cut to
8 s (fit, diagnose, add an effect, diagnose, compare, sample briefly, identify) plus a
run.json written here in the layout of ``rotorbayes run``.  The browser test needs
/usr/bin/chromium (Debian's package, installed by ``.ci/run``) and the ``playwright``
package (the ``test`` extra); it fails without them unless ROTORBAYES_NO_BROWSER=1.
"""

from __future__ import annotations

import contextlib
import hashlib
import html
import io
import json
import os
import re
import shutil
from pathlib import Path

import pytest

from rotorbayes.cli import main
from rotorbayes.io.examples import example_path
from rotorbayes.report import SECTIONS, ReportError, build_report, write_report
from rotorbayes.report.html import HINTS

CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
SECONDS = 8.0  # of each data file kept (the bundled files are sampled at 200 Hz)
ANALYSIS = """# a study for the report's test <script>alert("toml")</script> & more
[analysis]
name = "report test: <hidden> effect & friends"
out = "study"
config = "coupled"
data = ["data/coupled_hidden_est.csv"]
validate = ["data/coupled_hidden_val.csv"]
seed = 7
"""


def _cli(*argv) -> str:
    """Run a command in this process; its output (stdout and stderr) as text."""
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
        code = main([str(a) for a in argv])
    assert code in (0, 1), f"rotorbayes {' '.join(map(str, argv))} -> {code}\n{buf.getvalue()}"
    return buf.getvalue()


def _short_copy(name: str, dest: Path) -> Path:
    """The bundled example cut to its first SECONDS (header comments kept)."""
    lines = Path(example_path(f"example:{name}")).read_text().splitlines(keepends=True)
    head = [ln for ln in lines if ln.startswith("#")]
    body = [ln for ln in lines if not ln.startswith("#")]
    n = int(SECONDS * 200) + 1
    dest.write_text("".join(head + body[: 1 + n]))
    return dest


@pytest.fixture(scope="module")
def study(tmp_path_factory) -> Path:
    """A small whole-study folder: fit0 -> fit1 (+ an effect), compare, posterior, identify,
    run.json and log.txt, as ``rotorbayes run`` lays it out."""
    root = tmp_path_factory.mktemp("report")
    s = root / "study"
    (root / "data").mkdir()
    est = _short_copy("coupled_hidden_est", root / "data" / "coupled_hidden_est.csv")
    val = _short_copy("coupled_hidden_val", root / "data" / "coupled_hidden_val.csv")
    (root / "analysis.toml").write_text(ANALYSIS)
    fit = ["fit", "--model", "coupled", est, "--validate", val]
    log = _cli(*fit, "--restarts", "0", "--out", s / "fit0")
    log += _cli("diagnose", s / "fit0")
    log += _cli(*fit, "--p0", s / "fit0", "--add", "lower_asymmetric_coulomb", "--out", s / "fit1")
    log += _cli("diagnose", s / "fit1")
    log += _cli("compare", s / "fit1", "--out", s / "compare")
    log += _cli(
        "sample",
        s / "fit1",
        "--walkers",
        20,
        "--steps",
        60,
        "--seed",
        7,
        "--out",
        s / "posterior",
        "--quiet",
    )
    log += _cli(
        "identify",
        s / "fit1",
        "--profiles",
        "J_l",
        "--points",
        5,
        "--posterior",
        s / "posterior",
        "--out",
        s / "identify",
    )
    (s / "log.txt").write_text(log)
    run = {
        "analysis_file": str(root / "analysis.toml"),
        "analysis_text": ANALYSIS,
        "versions": {"python": "3.11.0", "rotorbayes": "0.2.0", "numpy": "2.0"},
        "seeds": {"analysis": 7, "sample": 7},
        "data": [
            {"path": str(p), "sha256": hashlib.sha256(p.read_bytes()).hexdigest()}
            for p in (est, val)
        ],
        "stages": [
            {
                "name": n,
                "folder": str(s / f),
                "seconds": 1.5,
                "input_hash": "ab" * 32,
                "skipped": n == "compare",
                "exit_code": 0,
            }
            for n, f in (
                ("fit0", "fit0"),
                ("diagnose0", "fit0"),
                ("fit1", "fit1"),
                ("diagnose1", "fit1"),
                ("compare", "compare"),
                ("sample", "posterior"),
                ("identify", "identify"),
            )
        ],
        "started": "2026-01-01T10:00:00",
        "finished": "2026-01-01T10:01:00",
        "added_effects": ["lower_asymmetric_coulomb"],
        "final_fit": str(s / "fit1"),
    }
    (s / "run.json").write_text(json.dumps(run, indent=2))
    return s


@pytest.fixture(scope="module")
def report(study) -> Path:
    return build_report(study)


def _sections(text: str) -> list[str]:
    return re.findall(r'<section id="([a-z]+)"', text)


def _external(text: str) -> list[str]:
    """Every src/href/url() that is not a data: URI or an in-page #anchor."""
    refs = re.findall(r'(?:src|href)\s*=\s*"([^"]*)"', text)
    refs += re.findall(r"url\(([^)]*)\)", text)
    refs += re.findall(r"@import", text)
    return [r for r in refs if not (r.startswith("data:") or r.startswith("#"))]


# ------------------------------------------------------------------------- plain HTML
@pytest.mark.slow
@pytest.mark.every_python
def test_study_report_holds_every_section_and_embeds_everything(study, report):
    assert report == study / "report.html"
    text = report.read_text()
    assert _sections(text) == list(SECTIONS)
    # The verdict comes first, after the table of contents that links every section.
    assert text.index('id="contents"') < text.index('<section id="verdict"')
    for sid in SECTIONS:
        assert f'href="#{sid}"' in text
    assert "Not in this report" not in text
    # Self-contained: every figure is a data URI; nothing points elsewhere.
    assert _external(text) == []
    assert not re.search(r"https?://", text)
    imgs = re.findall(r'<img src="([^"]+)"', text)
    assert len(imgs) >= 15 and all(s.startswith("data:image/png;base64,") for s in imgs)
    # The identify folder's corner plot is the posterior's: embedded once, linked once.
    assert text.count("the same figure as") >= 1
    assert len(set(imgs)) == len(imgs)
    # What the sections say, from the files.
    fit1 = json.loads((study / "fit1" / "fit.json").read_text())
    assert fit1["assessment"]["verdict"].split(":")[0] in text
    assert "lower_asymmetric_coulomb" in text and "k_alpha" in text and "N m/rad" in text
    assert "ESS (arviz bulk)" in text and "R-hat" in text  # summary.md as a table
    assert "<table" in text.split('<section id="posterior"')[1].split("</section>")[0]
    assert "Profile likelihoods" in text and "Δχ²" in text
    for d in json.loads((study / "run.json").read_text())["data"]:
        assert d["sha256"] in text
    assert "seed" in text and "2026-01-01T10:00:00" in text
    # The analysis text and names are escaped, not interpreted.
    assert "<script>" not in text and "<hidden>" not in text
    assert "&lt;script&gt;alert(&quot;toml&quot;)&lt;/script&gt;" in text
    assert "report test: &lt;hidden&gt; effect &amp; friends" in text
    # Written atomically: no temporary file is left beside it.
    assert [p.name for p in study.iterdir() if p.name.startswith(".")] == []


@pytest.mark.slow
@pytest.mark.every_python
def test_single_folders_render_what_they_hold(study, tmp_path):
    cases = {
        "fit0": {"verdict", "data", "fit", "diagnosis", "reproducibility"},
        # fit1 has a parent: the chain comes from the parent link (no compare/ inside it).
        "fit1": {"verdict", "data", "fit", "diagnosis", "chain", "reproducibility"},
        "compare": {"verdict", "compare", "chain", "reproducibility"},
        # The posterior of fit1: the fit it came from (settings.json) and its chain too.
        "posterior": {
            "verdict",
            "data",
            "fit",
            "diagnosis",
            "chain",
            "posterior",
            "reproducibility",
        },
        "identify": {"verdict", "identifiability", "reproducibility"},
    }
    for name, want in cases.items():
        rep = write_report(study / name, tmp_path / f"{name}.html")
        text = rep.path.read_text()
        assert set(rep.sections) == want, name
        assert set(_sections(text)) == want, name
        assert set(rep.absent) == set(SECTIONS) - want - {"verdict", "reproducibility"}
        assert "Not in this report" in text
        for sid in rep.absent:  # each absent section is named with the command that makes it
            command = HINTS[sid].split("`")[1]
            assert f"<code>{html.escape(command)}</code>" in text, (name, sid)
        # No run.json in a single folder: versions at report time, said plainly.
        assert "versions below are those at the time of this report" in text
        for pkg in ("python", "numpy", "scipy", "numba", "emcee", "arviz", "rotorbayes"):
            assert f"<td>{pkg}</td>" in text
        assert _external(text) == []
    fit1 = (tmp_path / "fit1.html").read_text()
    assert "following their --p0 parent links" in fit1
    assert "Data hashes (computed now)" in fit1


@pytest.mark.slow
@pytest.mark.every_python
def test_text_from_the_files_is_escaped(study, tmp_path):
    fit = tmp_path / "fit"
    shutil.copytree(study / "fit1", fit)
    doc = json.loads((fit / "fit.json").read_text())
    doc["parent"] = None
    doc["assessment"]["warnings"].append('<img src="http://evil.example/x.png"> & "quoted"')
    doc["parameters"]["k_m"]["unit"] = "N m/V <b>bold</b>"
    (fit / "fit.json").write_text(json.dumps(doc))
    diag = json.loads((fit / "diagnosis.json").read_text())
    diag["advice"] = "add <script>alert(1)</script> now"
    (fit / "diagnosis.json").write_text(json.dumps(diag))
    text = build_report(fit).read_text()
    assert "evil.example" in text and _external(text) == []
    assert "&lt;img src=&quot;http://evil.example/x.png&quot;&gt; &amp; &quot;quoted&quot;" in text
    assert "N m/V &lt;b&gt;bold&lt;/b&gt;" in text and "<b>bold</b>" not in text
    assert "add &lt;script&gt;alert(1)&lt;/script&gt; now" in text
    assert "<script" not in text


@pytest.mark.slow
@pytest.mark.every_python
def test_a_moved_study_still_finds_its_chain(study, tmp_path):
    """Parent links and run.json's final fit are absolute paths of where the study was made;
    a copied or moved study folder finds its fits by name beside each other."""
    moved = tmp_path / "moved"
    shutil.copytree(study, moved, ignore=shutil.ignore_patterns("report.html"))
    gone = tmp_path / "gone"
    for f in moved.glob("fit*/fit.json"):
        doc = json.loads(f.read_text())
        if doc.get("parent"):
            doc["parent"] = str(gone / Path(doc["parent"]).name)
        f.write_text(json.dumps(doc))
    run = json.loads((moved / "run.json").read_text())
    run["final_fit"] = "relative/elsewhere/fit1"
    (moved / "run.json").write_text(json.dumps(run))
    rep = write_report(moved)
    assert rep.sections == list(SECTIONS)
    assert "fit0 → fit1 (+lower_asymmetric_coulomb)" in rep.html


def test_nothing_to_report(tmp_path):
    with pytest.raises(ReportError, match="no such folder"):
        build_report(tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ReportError, match="nothing to report"):
        build_report(tmp_path / "empty")
    (tmp_path / "file.txt").write_text("x")
    with pytest.raises(ReportError, match="not a folder"):
        build_report(tmp_path / "file.txt")


@pytest.mark.slow
@pytest.mark.every_python
def test_report_command(study, tmp_path, capsys):
    out = tmp_path / "study.html"
    assert main(["report", str(study), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    size = out.stat().st_size
    assert f"wrote {out}" in printed and f"{size} bytes" in printed
    assert "sections: " + ", ".join(SECTIONS) in printed
    # A second run replaces the file.
    assert main(["report", str(study / "posterior"), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "absent (not in" in printed
    assert "sections: verdict, data, fit, diagnosis, chain, posterior" in printed
    assert out.stat().st_size != size
    assert [p.name for p in tmp_path.iterdir()] == ["study.html"]
    # Errors: exit 2 with one line, no traceback.
    for folder, words in ((tmp_path / "nope", "no such folder"), (tmp_path, "nothing to report")):
        assert main(["report", str(folder)]) == 2
        err = capsys.readouterr().err
        assert err.startswith("rotorbayes report: error:") and words in err
        assert "Traceback" not in err
    assert main(["report", str(study), "--out", str(tmp_path / "no" / "dir.html")]) == 2
    assert "does not exist" in capsys.readouterr().err


# ---------------------------------------------------------------------------- browser
def _browser_or_fail():
    if os.environ.get("ROTORBAYES_NO_BROWSER") == "1":
        pytest.skip("ROTORBAYES_NO_BROWSER=1: the report is not opened in Chromium")
    if not CHROMIUM.exists():
        pytest.fail(
            f"{CHROMIUM} is missing: the report test opens the page in a real "
            "headless Chromium; .ci/run installs it (apt-get install chromium), or "
            "set ROTORBAYES_NO_BROWSER=1 to skip this test",
            pytrace=False,
        )
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.fail(
            "the playwright package is missing: pip install '.[test]' (.ci/run does "
            "it), or set ROTORBAYES_NO_BROWSER=1 to skip this test",
            pytrace=False,
        )
    return sync_playwright


@pytest.mark.slow
@pytest.mark.every_python
def test_report_renders_in_headless_chromium(study, report, tmp_path):
    sync_playwright = _browser_or_fail()
    requests, blocked, errors = [], [], []

    def route(r):
        url = r.request.url
        if url.startswith(("data:", "file:")):
            r.continue_()
        else:
            blocked.append(url)
            r.abort()

    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 900})
            page.route("**/*", route)
            page.on("request", lambda r: requests.append(r.url))
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(report.resolve().as_uri(), wait_until="load")
            page.evaluate("document.querySelectorAll('details').forEach(d => d.open = true)")
            for sid in SECTIONS:
                sec = page.locator(f"section#{sid}")
                assert sec.count() == 1, sid
                assert sec.is_visible(), sid
                assert sec.bounding_box()["height"] > 40, sid
            imgs = page.evaluate(
                "Promise.all([...document.images].map(i => i.decode().then(() => 0, () => 0)"
                ".then(() => [i.alt, i.complete, i.naturalWidth, i.getBoundingClientRect()"
                ".width])))"
            )
            assert len(imgs) >= 15
            bad = [
                alt for alt, complete, w, shown in imgs if not (complete and w > 0 and shown > 0)
            ]
            assert bad == [], f"images that did not render: {bad}"
            # No table is wider than the page (a table scrolls inside its box if it is).
            assert page.evaluate("document.documentElement.scrollWidth") <= 1280
            page.screenshot(path=str(tmp_path / "report.png"), full_page=True)
        finally:
            browser.close()
    assert blocked == [], f"the page asked for external resources: {blocked}"
    assert all(u.startswith(("data:", "file:")) for u in requests), requests
    assert errors == [], errors
    assert (tmp_path / "report.png").stat().st_size > 50_000

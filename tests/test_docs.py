"""The documentation site builds with warnings as errors (what CI checks).

Runs ``python -m sphinx -W --keep-going -b html docs OUT`` into a temporary folder: a
docstring with broken reST, a page missing from the toctree, a broken link between pages or
an import error in the API reference fails the test with Sphinx's own message.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    try:
        import myst_parser  # noqa: F401
        import sphinx  # noqa: F401
    except ImportError as exc:
        pytest.fail(
            f'{exc.name} is not installed: `pip install ".[test]"` brings Sphinx and '
            "MyST for the documentation build"
        )
    out = tmp_path_factory.mktemp("docs") / "html"
    env = {**os.environ, "PYTHONWARNINGS": "ignore", "MPLBACKEND": "Agg"}
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "sphinx",
            "-W",
            "--keep-going",
            "-E",
            "-q",
            "-b",
            "html",
            "-d",
            str(out.parent / "doctrees"),
            str(DOCS),
            str(out),
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env=env,
        timeout=900,
    )
    warnings = [
        ln
        for ln in (proc.stdout + proc.stderr).splitlines()
        if "WARNING" in ln or "ERROR" in ln or "CRITICAL" in ln
    ]
    assert proc.returncode == 0 and not warnings, (
        f"the docs build failed (exit {proc.returncode}) with {len(warnings)} warning(s):\n"
        + "\n".join(warnings or (proc.stdout + proc.stderr).splitlines()[-40:])
    )
    return out


def test_docs_build_without_warnings(site):
    for page in (
        "index",
        "getting_started",
        "model",
        "diagnosis",
        "effects",
        "example_data",
        "identifiability",
        "sampling",
        "cli",
        "analysis_file",
        "api/index",
    ):
        assert (site / f"{page}.html").exists(), f"{page}.html was not built"


def test_cli_reference_has_every_subcommand(site):
    from rotorbayes.cli import build_parser

    parser = build_parser()
    subs = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    html = (site / "cli.html").read_text(encoding="utf-8")
    for name, sub in subs.choices.items():
        assert f"rotorbayes {name}" in html, f"`rotorbayes {name}` missing from cli.html"
        for action in sub._actions:
            for flag in action.option_strings:
                if flag.startswith("--"):
                    assert flag in html, f"rotorbayes {name} {flag} missing from cli.html"


def test_api_reference_documents_the_public_modules(site):
    api = "".join(p.read_text(encoding="utf-8") for p in (site / "api").glob("*.html"))
    for obj in (
        "rotorbayes.inference.problem.Problem",
        "rotorbayes.inference.identify.fisher",
        "rotorbayes.inference.likelihood.load_priors",
        "rotorbayes.inference.sampling.sample",
        "rotorbayes.diagnosis.diagnose.diagnose",
        "rotorbayes.model.effects.Effect",
        "rotorbayes.io.measurements.load_experiment",
        "rotorbayes.inference.results.load_fit",
        "rotorbayes.io.rigfiles.ReadSpec",
    ):
        assert f'id="{obj}"' in api, f"{obj} is not in the API reference"

"""Sphinx configuration of the rotorbayes documentation.

Build (what CI does in ``tests/test_docs.py``, warnings are errors)::

    python -m sphinx -W --keep-going -b html docs docs/_build/html

Markdown pages through MyST, the API reference from docstrings (autodoc + napoleon for the
numpy-style sections), the CLI reference rendered at build time from the argparse parser
(``_ext/cli_help.py``).  Nothing is fetched from the network: a built-in theme, no
intersphinx.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
# The package from this checkout (also when it is not installed), and the local extension.
sys.path.insert(0, str(HERE.parent / "src"))
sys.path.insert(0, str(HERE / "_ext"))
# Importing the package for autodoc must not start BLAS thread pools on a shared machine.
for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")
os.environ.setdefault("MPLBACKEND", "Agg")

import rotorbayes  # noqa: E402

project = "rotorbayes"
author = "rotorbayes developers"
copyright = "rotorbayes developers"
release = rotorbayes.__version__
version = ".".join(release.split(".")[:2])

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "cli_help",
]

source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
exclude_patterns = ["_build", "_ext", "Thumbs.db", ".DS_Store"]
language = "en"

# ---------------------------------------------------------------------------- MyST
# dollarmath: $...$ and $$...$$; colon_fence: ::: directives; heading anchors so that
# links like [x](model.md#9-parameters) resolve.
myst_enable_extensions = ["dollarmath", "colon_fence"]
myst_heading_anchors = 3

# --------------------------------------------------------------------------- autodoc
autodoc_member_order = "bysource"
autodoc_default_options = {"members": True, "undoc-members": True}
# Signatures show the annotations as written; the descriptions come from the docstrings.
autodoc_typehints = "signature"
autodoc_typehints_format = "short"
autodoc_preserve_defaults = True
autodoc_class_signature = "mixed"
napoleon_google_docstring = False
napoleon_numpy_docstring = True
napoleon_use_rtype = False
# An "Attributes" section becomes :ivar: fields, not attribute entries: with undoc-members
# autodoc documents a dataclass's fields itself, and both would describe the same object.
napoleon_use_ivar = True

# Unresolvable references (numpy.ndarray, arviz.InferenceData, ... without intersphinx,
# which would need the network) are rendered as plain text, not reported.
nitpicky = False
# No warning class is suppressed (suppress_warnings stays empty): every warning is fixed at
# its source, and the build runs with -W.
suppress_warnings: list[str] = []

# ---------------------------------------------------------------------------- HTML
html_theme = "alabaster"
html_title = f"rotorbayes {release}"
html_static_path: list[str] = []
html_theme_options = {
    "description": "Bayesian parameter inference for the TU Eindhoven drill-string rig",
    "fixed_sidebar": False,
    "page_width": "1080px",  # room for 80-column --help text on the CLI page
    "show_relbars": True,
}
html_sidebars = {"**": ["about.html", "navigation.html", "searchbox.html"]}
html_show_sourcelink = False
pygments_style = "sphinx"

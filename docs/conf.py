"""Sphinx configuration of the stablelego-jax docs (``make docs``): the guide
pages (Markdown, MyST), the command line from ``cli.main.build_parser``
(sphinx-argparse) and the API from the docstrings (autodoc, autosummary)."""
import os
import sys

sys.path.insert(0, os.path.abspath(".."))

project = "stablelego-jax"
author = "stablelego-jax developers"
extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",
    "sphinx.ext.viewcode",
    "sphinxarg.ext",
]
source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
exclude_patterns = ["_build", "_extra"]
autosummary_generate = True
autodoc_default_options = {"members": True, "show-inheritance": False}
autodoc_member_order = "bysource"
napoleon_google_docstring = True
napoleon_numpy_docstring = False
myst_heading_anchors = 3
html_theme = "alabaster"
html_title = "stablelego-jax"
html_extra_path = ["_extra"]
# the docstrings use :class:`~...` / :func:`~...` roles; unresolvable ones stay plain text
nitpicky = False
suppress_warnings = ["myst.header", "myst.xref_missing", "autosummary.import_cycle"]

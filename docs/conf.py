"""Sphinx configuration of flocking's documentation site.

Build it from the repository root (``pip install -e ".[docs]"`` first)::

    .venv/bin/python -m sphinx -W -b html docs docs/_build/html

The Markdown pages of docs/ are the sources (MyST); nothing is downloaded at build time.
"""

import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "_ext"))

import flocking  # noqa: E402

project = "flocking"
author = "flocking developers"
copyright = "the flocking developers (BSD-3-Clause)"
release = flocking.__version__
version = release

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "sphinx-mathjax-offline",  # MathJax served from the site itself: the pages read offline
    "sphinx_click",
    "gallery",
    "repolinks",
]

source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
exclude_patterns = ["_build", "_ext", "Thumbs.db", ".DS_Store"]

# MyST: $...$ maths, ::: fences, and heading anchors for the pages' #section links
myst_enable_extensions = ["dollarmath", "colon_fence", "deflist"]
myst_heading_anchors = 3

# the API reference: one entry per public name (each module's __all__), in source order
autodoc_default_options = {"members": True, "member-order": "bysource", "show-inheritance": False}
autodoc_typehints = "description"
autodoc_typehints_format = "short"
autosummary_generate = False
napoleon_numpy_docstring = True
napoleon_google_docstring = False

# MathJax ships with the site (sphinx-mathjax-offline): neither building nor reading the pages
# downloads anything
html_theme = "furo"
html_title = f"flocking {release}"
html_static_path = []
html_show_sourcelink = False
html_last_updated_fmt = None

# no intersphinx: a build must not need the network

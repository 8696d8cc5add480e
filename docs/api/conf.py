"""Sphinx configuration of selfcal's API reference (``make docs``: HTML and the examples run as doctests)."""
import os
import sys

# the selfcal of this tree, whichever selfcal the environment has installed
sys.path.insert(0, os.path.abspath(os.path.join(os.path.dirname(__file__), "..", "..")))

import selfcal  # noqa: E402

project = "selfcal"
author = "selfcal developers"
release = selfcal.__version__
version = ".".join(release.split(".")[:2])

extensions = ["sphinx.ext.autodoc", "sphinx.ext.napoleon", "sphinx.ext.doctest"]
exclude_patterns = ["_build"]

# the docstrings are NumPy style (Parameters / Returns / Attributes sections)
napoleon_google_docstring = False
napoleon_numpy_docstring = True
napoleon_use_ivar = False

autodoc_member_order = "bysource"
autodoc_typehints = "signature"
autodoc_preserve_defaults = True      # defaults as written (AdjustOptions(), not its repr)

html_theme = "alabaster"
html_static_path = []

# every page's examples start from here; the examples of one page share their names
doctest_global_setup = """
import numpy as np
import selfcal
"""


# The docstrings of attributes (``#:`` comments) and properties are prose, often "what: how" in one line; napoleon
# would read the part before the first colon as the type. They are kept as written.
_prose: dict[str, list[str]] = {}


def _keep_prose(app, what, name, obj, options, lines):
    if what in ("attribute", "data", "property"):
        _prose[name] = list(lines)


def _restore_prose(app, what, name, obj, options, lines):
    if name in _prose:
        lines[:] = _prose.pop(name)


def setup(app):
    app.connect("autodoc-process-docstring", _keep_prose, priority=100)       # before napoleon (500)
    app.connect("autodoc-process-docstring", _restore_prose, priority=900)    # after it

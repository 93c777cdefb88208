"""Sphinx configuration: MyST Markdown pages and the Python API from the docstrings.

Built by ``make docs`` (warnings are errors). rosdoc2 builds the same site for docs.ros.org:
``rosdoc2.yaml`` at the package root points it here.
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

project = "neforward_ros"
author = "neforward_ros developers"
copyright = "neforward_ros developers, Apache-2.0"
release = "0.1.0"

extensions = ["myst_parser", "sphinx.ext.autodoc", "sphinx.ext.napoleon", "sphinx.ext.mathjax"]
source_suffix = {".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build"]
myst_heading_anchors = 4
myst_enable_extensions = ["colon_fence"]
autodoc_member_order = "bysource"
autodoc_typehints = "description"
napoleon_google_docstring = True
napoleon_numpy_docstring = False
html_theme = "alabaster"
html_title = "neforward_ros"

"""Sphinx configuration of sb3-mpail's API reference, generated from the docstrings by autodoc.

Build it (from the repository root, with the ``docs`` extra installed)::

    python -m sphinx -b html docs/api docs/_build

The test suite builds it with warnings as errors (tests/test_api_docs.py). Nothing here needs the network: no
intersphinx, and every documented module is imported for real (nothing is mocked), so the build needs sb3-mpail's
dependencies installed: the ``test`` install has them all.
"""

import sys
from pathlib import Path

# the checkout's package, whether or not it is installed (its dependencies must be)
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

import sb3_mpail  # noqa: E402

project = "sb3-mpail"
author = "sb3-mpail contributors"
copyright = "sb3-mpail contributors"
version = release = sb3_mpail.__version__

extensions = ["sphinx.ext.autodoc"]

# the SB3 family's conventions: Sphinx-style ``:param:`` docstrings on the class, members in source order
autoclass_content = "class"
autodoc_member_order = "bysource"
autodoc_typehints = "signature"
autodoc_default_options = {"show-inheritance": True}
# an override without a docstring of its own (an env's ``step``, a module's ``forward``) is left out rather than shown
# with its base class's generic text (gymnasium's docstrings are not reStructuredText)
autodoc_inherit_docstrings = False

exclude_patterns = ["_build"]
html_theme = "alabaster"
html_title = f"sb3-mpail {release} API reference"

"""Sphinx configuration of the drake_contact documentation.

Build it with ``python docs/build.py`` (as the test suite does); the
measured results are the committed snapshots of ``docs/results/``. Pages
are Markdown (MyST); the API reference comes from the docstrings; the
tutorial notebook is executed during the build.
"""

import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
sys.path.insert(0, str(DOCS / "_ext"))

project = "drake_contact"
author = "the drake_contact developers"
copyright = "2026, the drake_contact developers"


from drake_contact_docs import _results_module  # noqa: E402

# The commit the site is built from (docs/results.py stamps snapshots alike).
release = version = _results_module()._commit()

extensions = [
    "myst_nb",  # Markdown pages (it loads myst_parser) and executed notebooks
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    # MathJax 3 copied into the site, so equations render offline too (the
    # default loads it from a CDN).
    "sphinx-mathjax-offline",
    "drake_contact_docs",  # generated references: scenario fields, station signals, studies
]

# .rst first: autosummary writes its generated pages (reStructuredText) with
# the first suffix.
source_suffix = {".rst": "restructuredtext", ".md": "myst-nb", ".ipynb": "myst-nb"}
exclude_patterns = ["_build", "_generated/**", "results/**", "**.ipynb_checkpoints", "jupyter_execute"]

myst_enable_extensions = ["dollarmath", "colon_fence", "deflist"]
myst_heading_anchors = 3

# The tutorial runs in the build (it stores no outputs), in a kernel of the
# interpreter building the docs; an error in a cell fails the build.
nb_execution_mode = "force"
nb_execution_timeout = 600
nb_execution_raise_on_error = True
nb_execution_show_tb = True
nb_kernel_rgx_aliases = {".*": "python3"}

autosummary_generate = True
autosummary_imported_members = True
autodoc_default_options = {"members": True}
# A class page documents the class and its members, without the dataclass's
# generated __init__ (templates/autosummary/class.rst).
templates_path = ["_templates"]
autodoc_typehints = "description"
autodoc_member_order = "bysource"
# pydrake's classes carry C++ docstrings that are not reStructuredText.
autodoc_inherit_docstrings = False
napoleon_google_docstring = False

html_theme = "pydata_sphinx_theme"
html_title = "drake_contact"
html_static_path = ["_static"]
html_css_files = ["custom.css"]
html_theme_options = {
    "navigation_with_keys": False,
    "show_toc_level": 2,
    "header_links_before_dropdown": 5,
    "secondary_sidebar_items": ["page-toc"],
    "footer_start": ["copyright"],
    "footer_end": ["last-updated"],
}
html_last_updated_fmt = f"%Y-%m-%d, at commit {release}"
html_show_sourcelink = False
# Pages without sub-pages get no empty "Section Navigation" column.
html_sidebars = {name: [] for name in (
    "index", "getting-started", "tutorial", "reproduction", "extending", "modelling", "api",
    "changelog")}
html_context = {"default_mode": "light"}

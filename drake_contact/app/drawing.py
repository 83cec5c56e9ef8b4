"""A drawing of a diagram: Drake's Graphviz text, rendered by ``dot``.

Drake describes a diagram's systems and port connections as Graphviz DOT
text (``System.GetGraphvizString``); Graphviz's ``dot -Tsvg`` turns it into
an SVG a browser shows. ``dot`` is an optional system program (Debian:
``apt-get install graphviz``): without it the DOT text is still written.

    drake-contact run SCENARIO --out DIR --graphviz FILE.dot|FILE.svg
"""

import shutil
import subprocess
from pathlib import Path

from drake_contact.errors import ScenarioError

#: File name endings :func:`write_diagram` writes.
DIAGRAM_SUFFIXES = (".dot", ".svg")

#: What makes ``dot`` available, for messages.
INSTALL_HINT = "apt-get install graphviz"


def diagram_dot(diagram, max_depth=1) -> str:
    """Graphviz DOT text of ``diagram``, showing nested diagrams down to
    ``max_depth`` levels (0: the diagram as one block; None: all levels)."""
    return diagram.GetGraphvizString(max_depth=max_depth)


def render_svg(dot_text) -> str | None:
    """``dot_text`` rendered by Graphviz's ``dot -Tsvg``; None when ``dot`` is
    not on the PATH. A DOT syntax error raises ``CalledProcessError``."""
    dot = shutil.which("dot")
    if dot is None:
        return None
    return subprocess.run([dot, "-Tsvg"], input=dot_text, capture_output=True, text=True,
                          check=True).stdout


def check_diagram_path(path) -> Path:
    """Returns ``path`` as a Path if :func:`write_diagram` can write it: it ends
    in .dot, or in .svg with ``dot`` installed; raises ScenarioError naming
    ``graphviz`` otherwise. Called before building, so a bad path fails fast."""
    path = Path(path)
    if path.suffix.lower() not in DIAGRAM_SUFFIXES:
        raise ScenarioError(f"graphviz = '{path}' has an unknown extension: must end in "
                            + " or ".join(DIAGRAM_SUFFIXES))
    if path.suffix.lower() == ".svg" and shutil.which("dot") is None:
        raise ScenarioError(f"graphviz = '{path}' needs Graphviz's dot to render an SVG, "
                            f"which is not installed ({INSTALL_HINT}); or write a .dot file")
    return path


def write_diagram(diagram, path, max_depth=1) -> Path:
    """Writes a drawing of ``diagram`` to ``path``: DOT text (.dot) or an SVG
    rendered by ``dot`` (.svg); creates the folder if needed. Raises
    ScenarioError for another extension, or for .svg without ``dot``."""
    path = check_diagram_path(path)
    dot_text = diagram_dot(diagram, max_depth)
    text = dot_text if path.suffix.lower() == ".dot" else render_svg(dot_text)
    if text is None:  # dot removed since the check
        raise ScenarioError(f"graphviz = '{path}': dot is not installed ({INSTALL_HINT})")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    except OSError as e:
        raise ScenarioError(f"graphviz = '{path}' is not writable: {e.strerror}") from e
    return path

"""docs/tutorial.ipynb runs top to bottom, in a fresh kernel of the
interpreter running the tests, and shows its figures; the committed file
carries no outputs."""

import sys
from pathlib import Path

import pytest

nbformat = pytest.importorskip(
    "nbformat", reason="running the tutorial needs nbformat (pip install '.[test]')")
nbclient = pytest.importorskip(
    "nbclient", reason="running the tutorial needs nbclient (pip install '.[test]')")
pytest.importorskip(
    "ipykernel", reason="running the tutorial needs ipykernel (pip install '.[test]')")

from conftest import needs_tool  # noqa: E402
from jupyter_client import AsyncKernelManager  # noqa: E402 (installed with nbclient)
from jupyter_client.kernelspec import KernelSpecManager  # noqa: E402

DOCS = Path(__file__).resolve().parents[1] / "docs"
NOTEBOOK = DOCS / "tutorial.ipynb"


def this_interpreters_kernel() -> AsyncKernelManager:
    """A manager of ipykernel's own "python3" kernel, which runs
    ``sys.executable``. No kernel folder is searched, so a python3 kernelspec
    installed for the user or the system (another interpreter) cannot be
    picked up, and nothing needs installing."""
    return AsyncKernelManager(kernel_name="python3",
                              kernel_spec_manager=KernelSpecManager(kernel_dirs=[]))


def outputs(nb):
    return [output for cell in nb.cells if cell.cell_type == "code" for output in cell.outputs]


def test_the_committed_notebook_is_valid_and_has_no_outputs():
    nb = nbformat.read(NOTEBOOK, as_version=4)
    nbformat.validate(nb)
    code = [cell for cell in nb.cells if cell.cell_type == "code"]
    assert code
    assert all(cell.outputs == [] and cell.execution_count is None for cell in code), \
        "clear the outputs before committing (Jupyter: Edit > Clear Outputs of All Cells)"


def test_the_tutorial_runs_and_shows_its_figures():
    nb = nbformat.read(NOTEBOOK, as_version=4)
    nb.cells.append(nbformat.v4.new_code_cell("import sys\nprint(sys.executable, end='')"))
    client = nbclient.NotebookClient(nb, km=this_interpreters_kernel(), timeout=600,
                                     resources={"metadata": {"path": str(DOCS)}})
    client.execute()  # raises CellExecutionError, with the cell and traceback, on any error

    assert nb.cells[-1].outputs[0]["text"] == sys.executable
    shown = {mime for output in outputs(nb) for mime in output.get("data", {})}
    assert "image/png" in shown  # the force-tracking figure
    needs_tool("dot", "the tutorial's diagram drawn by Graphviz (its other outputs passed)")
    assert "image/svg+xml" in shown  # the diagram

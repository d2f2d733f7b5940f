"""examples/quickstart.ipynb runs from top to bottom in a fresh kernel and shows what it says."""
from __future__ import annotations

from pathlib import Path

import nbclient
import nbformat

NOTEBOOK = Path(__file__).resolve().parent.parent / "examples" / "quickstart.ipynb"


def _text(cell: nbformat.NotebookNode) -> str:
    """Everything a code cell printed or returned, as text."""
    parts = []
    for output in cell.get("outputs", []):
        parts.append(output.get("text") or output.get("data", {}).get("text/plain", ""))
    return "\n".join(parts)


def test_the_quickstart_notebook_runs_and_its_localizer_agrees_with_the_batch_run(tmp_path: Path) -> None:
    notebook = nbformat.read(NOTEBOOK, as_version=4)
    assert not any(cell.get("outputs") for cell in notebook.cells if cell.cell_type == "code"), \
        "the notebook is stored without outputs"
    nbclient.NotebookClient(notebook, timeout=600, kernel_name="python3",
                            resources={"metadata": {"path": str(tmp_path)}}).execute()  # raises on any error
    code = [cell for cell in notebook.cells if cell.cell_type == "code"]
    table1 = _text(code[1])
    assert "catgraph" in table1 and "online" in table1 and "recall_at_1" in table1
    localizer = _text(code[3])
    assert "same decisions as the batch run: True" in localizer
    assert "confidence" in localizer and "P(new place)" in localizer
    figure = code[4]
    assert any("image/png" in output.get("data", {}) for output in figure.outputs)
    assert "wrong of" in _text(figure)

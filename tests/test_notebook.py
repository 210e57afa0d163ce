"""The quickstart notebook runs top to bottom as a reader would run it, so it cannot go stale."""

from pathlib import Path

import pytest

NOTEBOOK = Path(__file__).parent.parent / "examples" / "quickstart.ipynb"


def test_the_quickstart_notebook_runs_and_shows_what_it_promises():
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    notebook = nbformat.read(NOTEBOOK, as_version=4)
    nbclient.NotebookClient(notebook, timeout=300, kernel_name="python3").execute(cwd=str(NOTEBOOK.parent))
    outputs = [output for cell in notebook.cells if cell.cell_type == "code" for output in cell.get("outputs", [])]
    text = "".join(output.get("text", "") for output in outputs)
    assert 'understood: "Open the microwave door" means microwave' in text
    assert "not understood" in text or "not sure" in text  # the sandwich is not acted on
    assert 'asks for the opposite of "open the microwave door"' in text  # nor is the opposite of a task
    assert 'understood: "Don\'t forget to open the microwave." means microwave' in text  # a request all the same
    assert "success: True" in text
    done_at = next(line for line in text.splitlines() if line.startswith("sub-tasks done at steps:"))
    steps = [int(step) for step in done_at.split(":")[1].strip(" []").split(",")]
    assert len(steps) == 3 and 0 < steps[0] < steps[1] < steps[2]  # the chain's three sub-tasks, one after another
    images = [output for output in outputs if "image/gif" in output.get("data", {})]
    assert images, "the episode's GIF is shown inline"
    assert any("image/png" in output.get("data", {}) for output in outputs), "the env's frame is drawn"

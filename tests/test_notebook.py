"""The quick-start notebook runs top to bottom (nbclient, the current interpreter's kernel) and
shows its plots inline (PNG outputs of the cells, as in Jupyter); it replaces a stage of GCNT's
chain, registers the result as a method and trains that method through the Python API."""

from __future__ import annotations

from pathlib import Path

import pytest

NOTEBOOK = Path(__file__).resolve().parents[1] / "notebooks" / "quickstart.ipynb"


@pytest.mark.slow
def test_quickstart_notebook_executes(tmp_path: Path) -> None:
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    pytest.importorskip("ipykernel")
    nb = nbformat.read(NOTEBOOK, as_version=4)
    client = nbclient.NotebookClient(
        nb, timeout=300, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}
    )
    client.execute()
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])]
    assert not [o for o in outputs if o.get("output_type") == "error"]
    text = "".join(o.get("text", "") for o in outputs if o.get("output_type") == "stream")
    assert "finished: True" in text and "curves.png" in text
    # the replaced stage is the MLP, and the trained run is the method registered in the notebook
    assert "Sequential(" in text and "gcnt_mlp_encoder 0 finished" in text
    images = [o for o in outputs if "image/png" in o.get("data", {})]
    assert len(images) == 2  # the rollout's rewards (matplotlib inline) and the learning curve

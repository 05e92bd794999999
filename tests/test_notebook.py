"""The notebook tutorial (docs/notebooks/) runs from top to bottom, headless, as a user
would run it: a fresh kernel, the smoke preset simulated into a temporary folder, the
cached default model, and Rerun's notebook viewer."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOK = ROOT / "docs" / "notebooks" / "explore-a-dataset.ipynb"


def test_the_notebook_runs_and_shows_its_pictures(tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    nbformat = pytest.importorskip("nbformat", reason="the notebook extra is not installed")
    nbclient = pytest.importorskip("nbclient", reason="the notebook extra is not installed")
    pytest.importorskip("ipykernel", reason="the notebook extra is not installed")
    pytest.importorskip("rerun_notebook", reason="the notebook extra is not installed")
    monkeypatch.setenv("CONTACTKIT_NOTEBOOK_DIR", str(tmp_path))
    notebook = nbformat.read(NOTEBOOK, as_version=4)
    nbclient.NotebookClient(notebook, timeout=900, kernel_name="python3",
                            resources={"metadata": {"path": str(tmp_path)}}).execute()
    outputs = [o for cell in notebook.cells if cell.cell_type == "code" for o in cell.outputs]
    assert not [o for o in outputs if o.output_type == "error"]
    kinds = {kind for o in outputs for kind in o.get("data", {})}
    assert "image/png" in kinds  # the residual plot
    assert "application/vnd.jupyter.widget-view+json" in kinds  # Rerun's notebook viewer
    assert (tmp_path / "replay.rrd").stat().st_size > 0
    text = "".join(o.get("text", "") for o in outputs)
    assert "8 session files" in text and "peak |r| during contact" in text


def test_the_catalog_notebook_queries_and_shows_tables(tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    nbformat = pytest.importorskip("nbformat", reason="the notebook extra is not installed")
    nbclient = pytest.importorskip("nbclient", reason="the notebook extra is not installed")
    pytest.importorskip("ipykernel", reason="the notebook extra is not installed")
    monkeypatch.setenv("CONTACTKIT_NOTEBOOK_DIR", str(tmp_path))
    notebook = nbformat.read(ROOT / "docs" / "notebooks" / "query-a-catalog.ipynb",
                             as_version=4)
    nbclient.NotebookClient(notebook, timeout=900, kernel_name="python3",
                            resources={"metadata": {"path": str(tmp_path)}}).execute()
    outputs = [o for cell in notebook.cells if cell.cell_type == "code" for o in cell.outputs]
    assert not [o for o in outputs if o.output_type == "error"]
    tables = [o["data"]["text/html"] for o in outputs if "text/html" in o.get("data", {})]
    assert len(tables) == 3 and "property:session:action" in tables[-1]
    text = "".join(o.get("text", "") for o in outputs)
    assert "8 replayed" in text
    assert len(list((tmp_path / "smoke-catalog").glob("*.rrd"))) == 8

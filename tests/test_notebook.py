"""The quick-start notebook, ``examples/quickstart.ipynb``: committed without outputs, and run
whole, cell by cell in order, by a fresh Jupyter kernel of this interpreter, as a reader runs it.

The kernel starts in a temporary directory with its own Jupyter and IPython folders, so it
reads no user profile and writes nothing into the repository; the repository goes on its
``PYTHONPATH`` for the trainers of ``baselines/``, which the package does not install. It
inherits the test process's environment otherwise (the JAX compilation cache and compiler
flags of ``tests/conftest.py``).
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient
from nbclient.exceptions import CellExecutionError

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOK = ROOT / "examples" / "quickstart.ipynb"
KERNEL = "chargax-marl-test"


def test_the_notebook_is_committed_without_outputs():
    nb = nbformat.read(NOTEBOOK, as_version=4)
    nbformat.validate(nb)
    code = [cell for cell in nb.cells if cell.cell_type == "code"]
    assert code
    dirty = [i for i, cell in enumerate(code) if cell.outputs or cell.execution_count is not None]
    assert not dirty, f"code cells {dirty} of {NOTEBOOK.name} keep outputs: clear them"


def _kernel_spec(folder: Path) -> None:
    """A kernel spec of this interpreter in ``folder/kernels/`` (a ``JUPYTER_PATH`` entry)."""
    spec = folder / "kernels" / KERNEL
    spec.mkdir(parents=True)
    argv = [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"]
    kernel = {"argv": argv, "display_name": "chargax_marl tests", "language": "python"}
    (spec / "kernel.json").write_text(json.dumps(kernel))


def test_every_cell_of_the_notebook_runs(tmp_path, monkeypatch):
    _kernel_spec(tmp_path / "jupyter")
    monkeypatch.setenv("JUPYTER_PATH", str(tmp_path / "jupyter"))
    monkeypatch.setenv("JUPYTER_RUNTIME_DIR", str(tmp_path / "runtime"))
    monkeypatch.setenv("IPYTHONDIR", str(tmp_path / "ipython"))
    path = os.environ.get("PYTHONPATH")
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(ROOT), *([path] if path else [])]))
    work = tmp_path / "work"
    work.mkdir()
    nb = nbformat.read(NOTEBOOK, as_version=4)
    client = NotebookClient(
        nb, kernel_name=KERNEL, timeout=600, resources={"metadata": {"path": str(work)}}
    )
    try:
        client.execute()
    except CellExecutionError as exc:
        pytest.fail(f"a cell of {NOTEBOOK.name} fails:\n{exc}")
    outputs = [out for cell in nb.cells if cell.cell_type == "code" for out in cell.outputs]
    figures = [out for out in outputs if "image/png" in out.get("data", {})]
    assert len(figures) == 3  # the day, the task's picture, the training curve
    text = "".join(out.get("text", "") for out in outputs)
    assert "score" in text and "EUR/day over always-max" in text
    assert not list(work.iterdir()), "the notebook wrote files"

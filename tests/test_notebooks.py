"""Every notebook in notebooks/ runs from top to bottom without a cell error (at LPY_LIGHT_PHOTONS=2e5)."""
import os
import sys
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))


def _kernel_name():
    """python3 when this interpreter's environment provides it (ipykernel installed), else skip."""
    try:
        from jupyter_client.kernelspec import KernelSpecManager, NoSuchKernel
    except ImportError:
        pytest.skip("jupyter_client is not installed")
    try:
        spec = KernelSpecManager().get_kernel_spec("python3")
    except NoSuchKernel:
        pytest.skip("no python3 Jupyter kernel (pip install ipykernel)")
    return "python3", spec


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_is_stored_without_outputs(path):
    """The test runs it: what the repository stores is the code, not a run's figures (nothing stale to read)."""
    nb = nbformat.read(path, as_version=4)
    assert not [i for i, c in enumerate(nb.cells) if c.cell_type == "code" and (c.get("outputs") or c.execution_count)]


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_runs(path, tmp_path, monkeypatch):
    name, _ = _kernel_name()
    # the kernel must import the lpy_light under test: jupyter_client starts a kernelspec's "python"
    # as sys.executable; this interpreter's bin folder first on PATH covers other launchers
    monkeypatch.setenv("PATH", str(Path(sys.executable).parent) + os.pathsep + os.environ.get("PATH", ""))
    monkeypatch.setenv("LPY_LIGHT_PHOTONS", os.environ.get("LPY_LIGHT_TEST_PHOTONS", "2e5"))
    nb = nbformat.read(path, as_version=4)
    client = nbclient.NotebookClient(nb, timeout=120, kernel_name=name,
                                     resources={"metadata": {"path": str(tmp_path)}})
    client.execute()     # raises CellExecutionError on the first cell that fails
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", []) if o.output_type == "error"]
    assert not errors

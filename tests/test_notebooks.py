"""Every notebook in notebooks/ runs from top to bottom without a cell error (at LPY_LIGHT_PHOTONS=2e5), and the
figures its cells draw show.  A notebook whose first code cell imports openalea.lpy (``grow_rose.ipynb``) runs in
the L-Py suite (marked ``lpy``; skipped where L-Py is not importable)."""
import importlib.util
import os
import re
import sys
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))
HAVE_LPY = importlib.util.find_spec("openalea") is not None and importlib.util.find_spec("openalea.lpy") is not None
#: a cell's time limit (s): a notebook's first lit step may compile the kernel (about a minute on a busy machine)
CELL_TIMEOUT = 600
#: a cell written to show a figure (IPython's display of a PNG, or pyplot's show)
SHOWS_FIGURE = re.compile(r"display\(\s*Image\(|plt\.show\(")


def _needs_lpy(path) -> bool:
    """True when the notebook's first code cell imports openalea.lpy (an L-Py notebook)."""
    nb = nbformat.read(path, as_version=4)
    first = next((c.source for c in nb.cells if c.cell_type == "code"), "")
    return re.search(r"^\s*(from|import)\s+openalea\.lpy\b", first, re.MULTILINE) is not None


def _runs(path):
    """The parameter of test_notebook_runs: an L-Py notebook marked lpy, and skipped without L-Py."""
    if not _needs_lpy(path):
        return pytest.param(path, id=path.name)
    return pytest.param(path, id=path.name, marks=[pytest.mark.lpy, pytest.mark.skipif(
        not HAVE_LPY, reason="L-Py/PlantGL are not importable here (conda, or scripts/test-lpy.sh)")])


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


@pytest.mark.parametrize("path", [_runs(p) for p in NOTEBOOKS])
def test_notebook_runs(path, tmp_path, monkeypatch):
    name, _ = _kernel_name()
    # the kernel must import the lpy_light under test: jupyter_client starts a kernelspec's "python"
    # as sys.executable; this interpreter's bin folder first on PATH covers other launchers
    monkeypatch.setenv("PATH", str(Path(sys.executable).parent) + os.pathsep + os.environ.get("PATH", ""))
    monkeypatch.setenv("LPY_LIGHT_PHOTONS", os.environ.get("LPY_LIGHT_TEST_PHOTONS", "2e5"))
    nb = nbformat.read(path, as_version=4)
    client = nbclient.NotebookClient(nb, timeout=CELL_TIMEOUT, kernel_name=name,
                                     resources={"metadata": {"path": str(tmp_path)}})
    client.execute()     # raises CellExecutionError on the first cell that fails
    code = [c for c in nb.cells if c.cell_type == "code"]
    errors = [o for c in code for o in c.get("outputs", []) if o.output_type == "error"]
    assert not errors
    # its figures show: each cell that displays a PNG or calls plt.show() has at least one image/png output
    blank = [i for i, c in enumerate(code) if SHOWS_FIGURE.search(c.source)
             and not any("image/png" in o.get("data", {}) for o in c.get("outputs", []))]
    assert not blank, "code cells %s show no figure" % blank

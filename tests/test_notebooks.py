"""The notebooks under notebooks/ run from top to bottom and show their figures.

A plotting cell is a code cell that calls a ``plot_...`` function of the
workbench (or ``ct.bode_plot``); each must produce an ``image/png`` output in
the executed notebook: the report modules build their figures with the object
API (no backend forced), and a figure that is the value of a cell displays
itself (:class:`thsa_control.report.figure.ReportFigure`).
"""

import re
from pathlib import Path

import pytest

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.py"))
_PLOT_CALL = re.compile(r"^(?!\s*(from|import)\b).*\b(plot_\w+|bode_plot)\(", re.M)


def plotting_cells(nb) -> list:
    return [c for c in nb.cells if c.cell_type == "code" and _PLOT_CALL.search(c.source)]


def test_every_notebook_has_a_plotting_cell():
    jupytext = pytest.importorskip("jupytext")
    for path in NOTEBOOKS:
        assert plotting_cells(jupytext.read(path)), f"{path.name}: no cell calls a plot function"


@pytest.mark.slow
@pytest.mark.notebooks
@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_executes(path, tmp_path, monkeypatch):
    jupytext = pytest.importorskip("jupytext")
    nbclient = pytest.importorskip("nbclient")
    monkeypatch.delenv("MPLBACKEND", raising=False)  # the kernel's own (inline) backend, as a user has it
    nb = jupytext.read(path)
    client = nbclient.NotebookClient(nb, timeout=600, kernel_name="python3",
                                     resources={"metadata": {"path": str(path.parent)}})
    client.execute()
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", []) if o.get("output_type") == "error"]
    assert not errors
    for cell in plotting_cells(nb):
        images = [o for o in cell.get("outputs", []) if "image/png" in o.get("data", {})]
        assert images, f"{path.name}: the plotting cell shows no figure:\n{cell.source}"

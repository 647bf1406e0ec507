"""The example notebook (`examples/notebook/your_own_recording.ipynb`), executed as a user would
run it (nbclient, a fresh kernel): no cell fails, the diagnosis names the hidden offset, the fit
finds the axis's physics (the notebook's own truth), and the figures come out as images."""

from __future__ import annotations

import ast
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOK = Path(__file__).resolve().parents[2] / "examples" / "notebook" / "your_own_recording.ipynb"
TRUTH = {"M1": 0.05, "b1": 0.2, "Fc1": 0.15, "off1": 0.3}  # the axis the notebook simulates


@pytest.fixture(scope="module")
def cells(tmp_path_factory):
    nb = nbformat.read(NOTEBOOK, as_version=4)
    NotebookClient(
        nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(tmp_path_factory.mktemp("nb"))}}
    ).execute()
    return [c for c in nb.cells if c.cell_type == "code"]


def _output(cell, kind: str) -> str:
    for out in cell.outputs:
        if out.output_type == "error":
            pytest.fail(f"{out.ename}: {out.evalue}")
        data = out.get("data", {})
        if kind in data:
            return data[kind]
        if kind == "text/plain" and out.output_type == "stream" and out.name == "stdout":
            return out.text
    return ""


def _cell(cells, starts: str):
    return next(c for c in cells if c.source.startswith(starts))


def test_the_notebook_names_the_offset_and_fits_the_axis(cells):
    assert not [o for c in cells for o in c.outputs if o.output_type == "error"]
    assert _output(_cell(cells, "d.verdict"), "text/plain") == "'offset'"
    html = _output(_cell(cells, "d = manus.diagnose"), "text/html")
    assert "<table>" in html and "verdict: <b>offset</b>" in html
    params = ast.literal_eval(_output(_cell(cells, "{name: round"), "text/plain"))
    for name, truth in TRUTH.items():
        assert params[name] == pytest.approx(truth, rel=0.02), name
    assert "unit" in _output(_cell(cells, "f = manus.fit"), "text/html")


def test_the_figures_are_images(cells):
    for starts in ('d.figure("resid")', 'f.figure("compare")'):
        png = _output(_cell(cells, starts), "image/png")
        assert len(png) > 10_000, starts  # (base64 of a PNG with something drawn in it)

"""The tutorial notebook (examples/tutorial.ipynb) runs top to bottom on generated shapes (slow: a kernel,
a match, a small benchmark and its report, ~12 s; its figures within the reports' crop rule); by default its
code is checked without running it: every cell parses, every import resolves, every ``st.``/``viz.`` name it
uses exists."""

from __future__ import annotations

import ast
import importlib
import json
import shutil
from pathlib import Path

import pytest
from helpers import panel_empty_fractions

NOTEBOOK = Path(__file__).resolve().parents[1] / "examples" / "tutorial.ipynb"


def _exports(mod, name: str) -> bool:
    """``from mod import name`` works: an attribute, or a submodule of a package."""
    if hasattr(mod, name):
        return True
    try:
        importlib.import_module(f"{mod.__name__}.{name}")
    except ImportError:
        return False
    return True


def test_tutorial_notebook_code_parses_and_every_name_it_imports_exists():
    cells = ["".join(c["source"]) for c in json.loads(NOTEBOOK.read_text())["cells"] if c["cell_type"] == "code"]
    assert len(cells) >= 8
    aliases = {}  # name in the notebook -> module
    used = []  # (alias, attribute) of every alias.attribute the cells use
    for code in cells:
        for node in ast.walk(ast.parse(code)):
            if isinstance(node, ast.ImportFrom):
                mod = importlib.import_module(node.module)
                for a in node.names:
                    assert _exports(mod, a.name), (node.module, a.name)
            elif isinstance(node, ast.Import):
                for a in node.names:
                    if a.name.startswith("shape_toolkit"):
                        aliases[a.asname or a.name] = importlib.import_module(a.name)
            elif isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name):
                used.append((node.value.id, node.attr))
    from shape_toolkit import viz

    aliases["viz"] = viz
    checked = [(n, attr) for n, attr in used if n in aliases]
    assert {n for n, _ in checked} == {"st", "viz"}
    for n, attr in checked:
        assert hasattr(aliases[n], attr), f"{n}.{attr}"


@pytest.mark.slow
def test_tutorial_notebook_executes(tmp_path):
    nbformat = pytest.importorskip("nbformat", reason="nbformat is in the test extra")
    nbclient = pytest.importorskip("nbclient", reason="nbclient is in the test extra")
    pytest.importorskip("ipykernel", reason="ipykernel is in the test extra")
    shutil.copy(NOTEBOOK, tmp_path / NOTEBOOK.name)
    nb = nbformat.read(tmp_path / NOTEBOOK.name, as_version=4)
    nbclient.NotebookClient(nb, timeout=300, kernel_name="python3",  # a cell that hangs fails, after 300 s
                            resources={"metadata": {"path": str(tmp_path)}}).execute()
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", []) if o.output_type == "error"]
    assert not errors
    assert (tmp_path / "tutorial-run" / "report" / "index.html").exists()
    assert (tmp_path / "match.source.ply").exists()
    for name in ("fiedler.png", "match.png", "segmentation.png"):  # upright and cropped tight, as every render
        empty = panel_empty_fractions(tmp_path / name)
        assert empty and max(empty) <= 0.15, (name, empty)

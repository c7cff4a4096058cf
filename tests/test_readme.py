"""Executable documentation: every ```python block of README.md runs (in a fresh folder, on generated
shapes or files the block writes itself). A block whose first line is ``# needs shared data`` runs only
when the shared data is present ($TOOLKIT_DATA or ../shared/data)."""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
BLOCKS = re.findall(r"^```python\n(.*?)^```", README.read_text(encoding="utf-8"), flags=re.S | re.M)


def _data_dir() -> Path | None:
    for d in (os.environ.get("TOOLKIT_DATA"), ROOT.parent / "shared" / "data"):
        if d and Path(d).is_dir():
            return Path(d)
    return None


def test_readme_has_python_blocks():
    assert len(BLOCKS) >= 3


def test_readme_top_is_the_two_commands():
    text = README.read_text(encoding="utf-8")
    first = re.search(r"```bash\n(.*?)```", text, flags=re.S).group(1).strip().splitlines()
    assert first == ['pip install . && shape-toolkit demo', 'pip install ".[test]" && python -m pytest']
    assert "import toolkit" not in text and "from toolkit" not in text


@pytest.mark.parametrize("index", range(len(BLOCKS)))
def test_readme_python_block_runs(index, tmp_path, monkeypatch):
    code = BLOCKS[index]
    if code.lstrip().startswith("# needs shared data") and _data_dir() is None:
        pytest.skip("needs the shared data ($TOOLKIT_DATA or ../shared/data)")
    monkeypatch.chdir(tmp_path)
    namespace = {"__name__": f"readme_block_{index}"}
    exec(compile(code, f"README.md python block {index}", "exec"), namespace)  # noqa: S102

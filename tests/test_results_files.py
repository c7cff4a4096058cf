"""Every shipped results file says how to make it again (issue 28): a runner results file names, in its first
lines, the one ``shape-toolkit bench run CONFIG ... --markdown FILE`` command that writes it, and its CONFIG still
validates; the few that a config cannot express name a tool under ``benchmarks/`` that the benchmarks README
justifies. Every shipped benchmark config validates as is."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

from shape_toolkit.bench.config import load_config

REPO = Path(__file__).resolve().parent.parent
RESULTS = sorted(p for p in (REPO / "benchmarks" / "results").glob("*.md") if not p.stem.endswith("_notes")) + sorted(
    (REPO / "examples").glob("*/results.md"))
CONFIGS = sorted((REPO / "benchmarks" / "configs").glob("*.toml"))


def _command(path: Path) -> list[str] | None:
    """The ``shape-toolkit bench run`` command in the first 12 lines of a results file, as words."""
    for line in path.read_text(encoding="utf-8").splitlines()[:12]:
        m = re.search(r"shape-toolkit bench run [^`]*", line)
        if m:
            return shlex.split(m.group(0))
    return None


@pytest.mark.parametrize("path", RESULTS, ids=[p.relative_to(REPO).as_posix() for p in RESULTS])
def test_results_file_names_the_command_that_writes_it(path, request, monkeypatch):
    words = _command(path)
    rel = path.relative_to(REPO).as_posix()
    if words is None:  # a tool, not a config: it is named in the file and justified in the benchmarks README
        head = "\n".join(path.read_text(encoding="utf-8").splitlines()[:12])
        tools = re.findall(r"benchmarks/(\w+\.py)|python (\w+\.py)", head) + re.findall(r"`(\w+\.py)`", head)
        names = {t for group in tools for t in (group if isinstance(group, tuple) else (group,)) if t}
        assert names, f"{rel} names neither a bench run command nor a tool in its first lines"
        readme = (REPO / "benchmarks" / "README.md").read_text(encoding="utf-8")
        for name in names:
            assert (REPO / "benchmarks" / name).is_file() and f"`{name}`" in readme, (rel, name)
        return
    assert "--markdown" in words and words[words.index("--markdown") + 1] == rel, (rel, words)
    config = REPO / words[3]
    monkeypatch.setenv("TOOLKIT_DATA", str(request.getfixturevalue("shared_data")))  # skips when absent
    assert load_config(config).planned_rows > 0


@pytest.mark.parametrize("config", CONFIGS, ids=[c.name for c in CONFIGS])
def test_shipped_config_validates(config, shared_data, monkeypatch):
    monkeypatch.setenv("TOOLKIT_DATA", str(shared_data))
    assert load_config(config).planned_rows > 0

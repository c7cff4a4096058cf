"""bench compare: what changed between two runs, paired by item and method label (issue 28)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
from helpers import bench_run, segmentation_config, write_config

from shape_toolkit.bench.compare import compare_runs, format_text, write_comparison
from shape_toolkit.cli import main
from shape_toolkit.errors import ParameterError


def _config(name: str, k: int) -> str:
    return segmentation_config(name, limit=3, n_poses=3, methods=f"""
[[tasks.methods]]
plugin = "spectral-clustering"
label = "<b>sc</b>"
params = {{ n_segments = {k} }}
[[tasks.methods]]
plugin = "ncut"
label = "ncut"
params = {{ n_segments = 4 }}
""")


def _run(tmp_path: Path, name: str, k: int) -> Path:
    run = tmp_path / name
    assert bench_run(write_config(tmp_path, _config(name, k), f"{name}.toml"), run, "--quiet") == 0
    return run


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("compare")
    return _run(tmp, "a", 3), _run(tmp, "b", 6)


def test_pairs_rows_by_item_and_label_and_tells_what_changed(runs):
    a, b = runs
    comp = compare_runs(a, b)
    by = {(c.method, c.metric): c for c in comp.changes}
    n = by[("<b>sc</b>", "n_segments")]
    assert n.n_pairs == 3 and n.mean_a == 3 and n.mean_b == 6 and n.mean_diff == 3
    assert n.se_diff == 0 and n.verdict == "changed" and n.direction is None
    same = by[("ncut", "n_segments")]
    assert same.mean_diff == 0 and same.verdict == "same" and same.moved == []
    assert not comp.only_a and not comp.only_b and not comp.newly_failed
    itself = compare_runs(a, a)  # a run against itself: nothing moved
    assert all(c.mean_diff == 0 and c.verdict == "same" for c in itself.changes)
    assert "n_segments" in format_text(comp)


def test_outputs_are_escaped_and_exported(runs, tmp_path):
    a, b = runs
    written = write_comparison(compare_runs(a, b), tmp_path / "cmp")
    assert sorted(Path(p).name for p in written) == ["compare.csv", "compare.html"]
    page = (tmp_path / "cmp" / "compare.html").read_text()
    assert "<b>sc</b>" not in page and "&lt;b&gt;sc&lt;/b&gt;" in page
    rows = list(csv.DictReader((tmp_path / "cmp" / "compare.csv").open()))
    assert {r["method"] for r in rows} == {"<b>sc</b>", "ncut"}
    sc = next(r for r in rows if r["method"] == "<b>sc</b>" and r["metric"] == "n_segments")
    assert sc["moved_most"].count("3 -> 6") == 3  # the items that moved most, as in the HTML (every one: 3 -> 6)
    assert next(r for r in rows if r["method"] == "ncut" and r["metric"] == "n_segments")["moved_most"] == ""


def test_cli_compare(runs, tmp_path, capsys):
    a, b = runs
    capsys.readouterr()
    assert main(["bench", "compare", str(a), str(b), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["run_a"] == str(a) and any(c["verdict"] == "changed" for c in out["changes"])
    assert main(["bench", "compare", str(a), str(b), "-o", str(tmp_path / "o")]) == 0
    assert (tmp_path / "o" / "compare.html").exists()


def test_a_folder_that_is_not_a_run_is_refused(runs, tmp_path, capsys):
    with pytest.raises(ParameterError, match="not a run folder"):
        compare_runs(runs[0], tmp_path)
    capsys.readouterr()
    assert main(["bench", "compare", str(runs[0]), str(tmp_path)]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


@pytest.mark.parametrize("content", ["", "not json {\n"])
def test_a_run_folder_without_a_valid_row_is_neither_reported_nor_compared(runs, tmp_path, capsys, content):
    """An empty results.jsonl, or one whose every line is invalid: one line and exit 2, no empty page or table
    that would read as 'no change' (found by fuzzing: both exited 0)."""
    from shape_toolkit.bench.report import write_report

    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "results.jsonl").write_text(content)
    with pytest.raises(ParameterError, match="holds no valid row"):
        compare_runs(runs[0], empty)
    with pytest.raises(ParameterError, match="holds no valid row"):
        write_report(empty)
    assert not (empty / "report").exists()
    capsys.readouterr()
    assert main(["bench", "report", str(empty), "--quiet"]) == 2
    assert main(["bench", "compare", str(empty), str(runs[0])]) == 2
    err = [x for x in capsys.readouterr().err.strip().splitlines() if "warning:" not in x]
    assert len(err) == 2 and all("holds no valid row" in x for x in err)

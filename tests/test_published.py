"""The thesis's published numbers (shape_toolkit/bench/data/sharma2012.toml): each value is printed on the
line of the thesis's text the file names; a config's ``published`` key is checked before any work; the
report shows the rows beside the measured ones, marked, never best, outside every summary."""

from __future__ import annotations

import csv
import json
import os
import re
from pathlib import Path

import pytest

from shape_toolkit.bench.config import ConfigError, parse_config
from shape_toolkit.bench.published import (
    PUBLISHED_LABEL,
    PublishedKeyError,
    check_published,
    published_rows,
    published_tables,
    reference_rows,
)
from shape_toolkit.bench.report import write_report
from shape_toolkit.bench.runner import run_benchmark

_REPO = Path(__file__).resolve().parent.parent
_NAME = "sharma-2012-thesis.md"


@pytest.fixture(scope="module")
def thesis_lines() -> list[str]:
    """The thesis's Markdown text as lines ($TOOLKIT_THESIS, else reference/ beside $TOOLKIT_DATA, else
    <repo>/../shared/reference); skipped when absent."""
    cands = [os.environ.get("TOOLKIT_THESIS")]
    if os.environ.get("TOOLKIT_DATA"):
        cands.append(str(Path(os.environ["TOOLKIT_DATA"]).parent / "reference" / _NAME))
    cands.append(str(_REPO.parent / "shared" / "reference" / _NAME))
    for c in cands:
        if c and Path(c).is_file():
            return Path(c).read_text(encoding="utf-8").split("\n")
    pytest.skip(f"the thesis's text {_NAME} was not found: set TOOLKIT_THESIS or TOOLKIT_DATA")


def _numbers(line: str) -> list[float]:
    return [float(x) for x in re.findall(r"(?<![\w.])\d+(?:\.\d+)?", line)]


def test_every_value_is_printed_on_its_line(thesis_lines):
    rows = published_rows()
    assert len(rows) == 64
    for r in rows:
        lines = thesis_lines[r.line - 1:(r.line_end or r.line)]
        printed = [x for ln in lines for x in _numbers(ln)]
        for col, v in list(r.values.items()) + list(r.std.items()) + list(r.info.items()):
            assert any(abs(x - v) < 1e-9 for x in printed), (r.table, r.line, r.setting, r.method, col, v)
        assert r.setting.split(" -> ")[0].split()[0] in " ".join(lines) or r.setting.startswith(("eight", "horse"))


def test_values_in_their_columns(thesis_lines):
    """A few values checked by position: the column of the method, the line of the r."""
    def cells(n):
        return thesis_lines[n - 1].split("\t")

    t72 = {(r.setting, r.method): r for r in published_rows("table-7.2")}
    assert t72[("flashkick 117-130", "proposed method")].values["r_smooth@0.8"] == float(cells(2596)[4]) == 65.10
    assert t72[("lucie 340-358", "[Ovsjanikov 2010]")].values["r_smooth@0.3"] == float(cells(2623)[2]) == 10.04
    t51 = {(r.setting, r.method): r for r in published_rows("table-5.1")}
    assert t51[("crane", "SL [Kamvar 2003]")].values["recall"] == float(cells(1643)[9]) == 0.8673
    assert t51[("ben", "CSC")].values["precision"] == float(cells(1646)[6]) == 0.9563
    t52 = {r.condition: r for r in published_rows("table-5.2-II")}
    assert t52["holes"].values == {"label_recall": 0.9644, "label_precision": 0.9896}
    assert t52["sampling"].info["n_vertices_test"] == int(cells(1666)[8]) == 8181
    t73 = {(r.setting, r.method): r for r in published_rows("table-7.3")}
    assert t73[("samba 118-121", "[Mateus 2008]")].values["label_precision"] == float(cells(2636)[4]) == 0.4521
    for tab in published_tables().values():  # each caption is on its line
        assert tab.caption.split(":")[0][:30].lower() in thesis_lines[tab.line - 1].lower().replace("*", ""), tab.id


def test_reference_rows_average_the_thesis_shapes():
    ref = {r.method: r for r in reference_rows("table-7.2")}
    prop = ref[f"{PUBLISHED_LABEL}: proposed method"]
    m, s, n = prop.cells["r_smooth@0.8"]
    assert n == 6 and m == pytest.approx((65.10 + 78.88 + 82.83 + 55.82 + 55.76 + 58.06) / 6)
    fig = reference_rows("figure-3.13")[0]
    assert fig.cells["mean_degree"] == (5.96, 0.016, 8)  # printed as mean +- std over eight shapes
    conds = {r.corruption for r in reference_rows("table-5.2-II")}
    assert conds == {"topology", "sampling", "noise", "holes"}


def _raw(published) -> dict:
    return {
        "datasets": [{"name": "syn", "kind": "synthetic", "params": {"n_poses": 2, "subdivisions": 2}}],
        "tasks": [{"task": "spectrum", "name": "eig", "published": published, "spectrum": {"k": 12},
                   "metrics": ["eigenvalues", "mean_degree"],
                   "methods": [{"plugin": "gaussian"}, {"plugin": "cotangent"}]}],
    }


@pytest.mark.parametrize("value, key", [
    ("table-9.9", "tasks[0].published"),
    (["figure-3.13", "nope"], "tasks[0].published[1]"),
    (["figure-6.7"], "tasks[0].published[0]"),  # a picture: no printed numbers
    ([], "tasks[0].published"),
    (3, "tasks[0].published"),
])
def test_bad_reference_refused_naming_the_key(value, key):
    with pytest.raises(ConfigError) as exc:
        parse_config(_raw(value))
    assert exc.value.key == key
    with pytest.raises(PublishedKeyError):
        check_published(value)


def test_report_shows_published_rows_never_best(tmp_path):
    cfg = parse_config(_raw(["figure-3.13", "figure-3.14"]))
    run_benchmark(cfg, tmp_path / "run", progress=False)
    res = write_report(tmp_path / "run", renders=0, markdown=tmp_path / "r.md")
    page = res["html"].read_text(encoding="utf-8")
    assert page.count("class='published'") == 2  # one mean_degree cell per figure
    md = (tmp_path / "r.md").read_text(encoding="utf-8")
    assert "*5.96" in md and "**5.96" not in md and "*127.6" in md  # italic, never bold in Markdown either
    assert f"{PUBLISHED_LABEL}: gaussian" in page and "not measured here" in page
    mean_csv = next(p for p in res["tables"] if re.fullmatch(r"\d\d-eig\.csv", p.name))
    rows = list(csv.DictReader(mean_csv.open(encoding="utf-8")))
    published = [r for r in rows if r["method"].startswith(PUBLISHED_LABEL)]
    assert [r["mean_degree"] for r in published] == ["5.96", "127.6"]
    assert all(r["seconds"] == "" for r in published)  # no number the thesis did not print
    tex = mean_csv.with_suffix(".tex").read_text(encoding="utf-8")
    assert r"\textit{5.96" in tex and r"\textbf{5.96" not in tex
    summary = page.split("<h2>Task")[0]  # the summary section ranks measured rows only
    assert PUBLISHED_LABEL not in summary
    # the published column is printed beside the measured one, but never decides a best
    assert "class='best'>5.96" not in page and "class='best'>127.6" not in page
    assert json.loads((tmp_path / "run" / "config.json").read_text())["tasks"][0]["published"]


def test_mean_degree_is_the_trace_over_n(tmp_path):
    """Eq. 3.8: with binary weights tr(L)/n is the mean valence, 2 |E| / n."""
    from shape_toolkit.bench.runner import read_rows
    from shape_toolkit.data.datasets import load_item, open_dataset

    raw = _raw("figure-3.13")
    raw["tasks"][0]["methods"] = [{"plugin": "binary"}]
    run_benchmark(parse_config(raw), tmp_path / "run", progress=False)
    items = [load_item(ref) for ref in open_dataset("synthetic", None, n_poses=2, subdivisions=2)]
    shapes = {it.name: it.shape for it in items}
    rows = read_rows(tmp_path / "run")
    assert len(rows) == 2
    for r in rows:
        s = shapes[r["item"]]
        assert r["metrics"]["mean_degree"] == pytest.approx(2 * len(s.edges) / s.n_vertices)

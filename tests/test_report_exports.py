"""Issue 28 item 3: every report table also as CSV and LaTeX (booktabs) with the numbers of the HTML
table, every figure also as PDF, all of them linked from the page and owned through the manifest;
"best" only where it means something (no best on a constant column or on memory within 1 MB, ties
named), GCE and LCE marked as rewarding under-segmentation, and a metric a method cannot produce
shown as n/a with a note (never 0, never best)."""

from __future__ import annotations

import csv
import hashlib
import json
import re
from html.parser import HTMLParser
from pathlib import Path

import pytest
from helpers import run_config

from shape_toolkit.bench.report import MANIFEST, _num, _ranks, _spread, latex_escape, write_report

CONFIG = {
    "run": {"name": "exports", "random_state": 0},
    "datasets": [{"name": "synth", "kind": "synthetic", "limit": 1,
                  "params": {"n_poses": 2, "subdivisions": 2, "random_state": 0}}],
    "corruptions": [{"name": "noise", "kind": "gaussian-noise", "params": {"strength": [0.2]}}],
    "tasks": [
        {"task": "segmentation", "name": "seg", "corruptions": ["none", "noise"],
         "metrics": ["n_segments", "segmentation"],
         "methods": [{"plugin": "spectral-clustering", "params": {"n_segments": 4}},
                     {"plugin": "eigvec-gmm", "params": {"n_segments": 4}}]},
        {"task": "spectrum", "spectrum": {"k": 6}, "metrics": ["eigenvalues", "lambda2"],
         "methods": [{"plugin": "cotangent"}]},
    ],
}


class _Page(HTMLParser):
    """The tables of a report page (cells as text with their class), the hrefs, in page order. The
    parts of a table cut by columns (``data-part='i/n'``, ``data-keys``) are joined into one."""

    def __init__(self):
        super().__init__(convert_charrefs=True)
        self.tables: list[list[list[tuple[str, str]]]] = []
        self.hrefs: list[str] = []
        self.parts: list[str] = []  # the data-part of every <table> seen
        self._cell: list | None = None
        self._cont: list | None = None  # a continued table: [keys to skip, next row, cells seen in the row]

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "table":
            part = a.get("data-part")
            if part:
                self.parts.append(part)
            if part and not part.startswith("1/"):
                self._cont = [int(a["data-keys"]), -1, 0]
            else:
                self._cont = None
                self.tables.append([])
        elif tag == "tr" and self.tables:
            if self._cont is None:
                self.tables[-1].append([])
            else:
                self._cont[1] += 1
                self._cont[2] = 0
        elif tag in ("td", "th"):
            self._cell = ["", a.get("class") or ""]
        elif tag == "a":
            self.hrefs.append(a["href"])

    def handle_endtag(self, tag):
        if tag in ("td", "th") and self._cell is not None:
            cell = (" ".join(self._cell[0].split()), self._cell[1])
            if self._cont is None:
                self.tables[-1][-1].append(cell)
            else:
                self._cont[2] += 1
                if self._cont[2] > self._cont[0]:  # the key columns are repeated in every part
                    self.tables[-1][self._cont[1]].append(cell)
            self._cell = None

    def handle_data(self, data):
        if self._cell is not None:
            self._cell[0] += data


def _page(path: Path) -> _Page:
    p = _Page()
    p.feed(path.read_text(encoding="utf-8"))
    return p


def _tex_rows(text: str) -> list[list[str]]:
    """The cells of a booktabs tabular, header first."""
    body = text.split(r"\toprule")[1].split(r"\bottomrule")[0]
    rows = [r.strip() for r in body.replace(r"\midrule", "").split("\\\\\n") if r.strip()]
    return [[c.strip() for c in r.removesuffix("\\\\").split(" & ")] for r in rows]


_NUMBER = re.compile(r"-?\d+(?:\.\d+)?(?:e[+-]?\d+)?")


def _numbers(cell: str) -> list[str]:
    """The printed numbers of a cell (its ``(n=...)`` left out)."""
    return _NUMBER.findall(re.sub(r"\(n=\d+\)", "", cell))


@pytest.fixture(scope="module")
def report(tmp_path_factory) -> dict:
    return write_report(run_config(CONFIG, tmp_path_factory.mktemp("exports")), renders=1)


def test_every_table_has_csv_and_latex_linked_and_owned(report):
    page = _page(report["html"])
    out = report["html"].parent
    tables = sorted(report["tables"])
    # one CSV and one TeX per table of the page, in page order, each linked right under its table
    assert len(tables) == 2 * len(page.tables) and len(page.tables) >= 4  # mean + per-item table of each task
    links = [h for h in page.hrefs if h.startswith("tables/")]
    assert links == [f"tables/{Path(t).name}" for t in report["tables"]]
    for i, t in enumerate(tables):
        assert Path(t).name.startswith(f"{i // 2:02d}-")
    # every figure also as PDF, linked from its caption
    assert report["figures"] and len(report["vector_figures"]) == len(report["figures"])
    for png, pdf in zip(report["figures"], report["vector_figures"]):
        assert Path(pdf) == Path(png).with_suffix(".pdf") and Path(pdf).read_bytes().startswith(b"%PDF")
        assert f"figures/{Path(pdf).name}" in page.hrefs
    assert any("render" in Path(p).name for p in report["vector_figures"])  # the rendered shapes too
    # all of them the report's own: in the manifest with their digests
    manifest = json.loads((out / MANIFEST).read_text())["files"]
    for f in report["tables"] + report["vector_figures"]:
        rel = Path(f).relative_to(out).as_posix()
        assert manifest[rel] == hashlib.sha256(Path(f).read_bytes()).hexdigest()
    for t in tables:
        if t.suffix == ".tex":
            text = t.read_text()
            assert text.index(r"\toprule") < text.index(r"\midrule") < text.index(r"\bottomrule")


def test_csv_and_latex_hold_the_numbers_of_the_html_tables(report):
    page = _page(report["html"])
    tables = sorted(report["tables"])
    for i, html_table in enumerate(page.tables):
        csv_path, tex_path = tables[2 * i], tables[2 * i + 1]
        assert (csv_path.suffix, tex_path.suffix) == (".csv", ".tex")
        stats = "items" not in csv_path.name  # mean tables: mean, std and n per metric
        rows = list(csv.reader(csv_path.open(encoding="utf-8")))
        tex = _tex_rows(tex_path.read_text(encoding="utf-8"))
        head = [c for c, _ in html_table[0]]
        assert len(rows) == len(tex) == len(html_table)
        n_keys = 3 if stats else 4
        assert rows[0][:n_keys] == head[:n_keys] and [latex_escape(c) for c in head[:n_keys]] == tex[0][:n_keys]
        for h_row, c_row, t_row in zip(html_table[1:], rows[1:], tex[1:]):
            keys = [c for c, _ in h_row[:n_keys]]
            assert keys == c_row[:n_keys] and [latex_escape(c) for c in keys] == t_row[:n_keys]
            for j, (text, cls) in enumerate(h_row[n_keys:]):
                tcell = t_row[n_keys + j]
                values = c_row[n_keys + 3 * j: n_keys + 3 * j + 3] if stats else c_row[n_keys + j: n_keys + j + 1]
                assert _numbers(text) == _numbers(tcell.replace(r"$\pm$", "")), (text, tcell)
                assert ("best" in cls) == tcell.startswith(r"\textbf{"), (text, tcell)
                assert text.endswith("tie") == tcell.endswith(r"\textsuperscript{tie}")
                if text in ("\u2013", "n/a"):
                    assert values[0] == ("" if text == "\u2013" else "n/a")
                    continue
                shown = _numbers(text)
                assert shown[0] == _num(float(values[0]))  # the CSV's full-precision mean, as printed
                if stats and len(shown) > 1 and "\u00b1" in text:
                    assert shown[1] == _spread(float(values[1]))
                    assert f"(n={values[2]})" in text


def test_gce_and_lce_are_marked_as_rewarding_under_segmentation(report):
    page = report["html"].read_text(encoding="utf-8")
    assert re.search(r"gce &darr; &dagger;</th>", page) and re.search(r"lce &darr; &dagger;</th>", page)
    assert "gce, lce: rewards under-segmentation" in page
    assert "(lower is better; rewards under-segmentation)" in page  # in the summary too
    tex = next(t for t in report["tables"] if t.name.endswith("-seg.tex")).read_text()
    assert r"gce $\downarrow$\textsuperscript{\dag}" in tex and "rewards under-segmentation" in tex


# -- the best rules, on rows made for them ---------------------------------------------------
def _row(key, method, item, metrics, *, task="t", kind="segmentation", family="segmenters", memory=10.0,
         seconds=1.0):
    return {"key": key, "status": "ok", "task_name": task, "task_kind": kind, "dataset": "d", "item": item,
            "method_label": method, "family": family, "corruption": "none", "metrics": metrics,
            "seconds": seconds, "peak_memory_mb": memory}


def _write_rows(folder: Path, rows: list[dict]) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "results.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    return folder


def _mean_table(res: dict, index: int = 0) -> tuple[dict[str, dict[str, tuple[str, str]]], str, list[list[str]]]:
    """``{method: {column: (text, class)}}`` of the page's ``index``-th mean table, the page, the TeX rows."""
    page = _page(res["html"])
    table = [t for t in page.tables if t[0][0][0] == "dataset" and t[0][2][0] == "corruption"][index]
    head = [re.split(r" [(\u2191\u2193]", c)[0] for c, _ in table[0]]
    cells = {r[1][0]: dict(zip(head[3:], r[3:])) for r in table[1:]}
    tex = next(t for t in res["tables"] if t.suffix == ".tex" and t.name.startswith(f"{2 * index:02d}-"))
    return cells, res["html"].read_text(encoding="utf-8"), _tex_rows(tex.read_text())


def test_no_best_on_a_constant_column_or_on_memory_noise_and_ties_are_named(tmp_path):
    rows = []
    for m, (acc, rec, gce, mem) in {"A": (0.5, 0.91231, 0.3, 10.0), "B": (0.5, 0.91234, 0.2, 10.004),
                                    "C": (0.5, 0.5, 0.1, 10.9)}.items():
        for item in ("i1", "i2"):
            rows.append(_row(f"{m}{item}", m, item, {"accuracy": acc, "recall": rec, "gce": gce}, memory=mem,
                             seconds={"A": 1.0, "B": 2.0, "C": 3.0}[m]))
    res = write_report(_write_rows(tmp_path / "run", rows), renders=0)
    cells, page, tex = _mean_table(res)
    assert not any("best" in cells[m]["accuracy"][1] for m in "ABC")  # constant: 0.5 everywhere
    assert not any("best" in cells[m]["peak_memory_mb"][1] for m in "ABC")  # 10.0 .. 10.9 MB: within 1 MB
    assert all(cells[m]["recall"][0].endswith("tie") and "best" in cells[m]["recall"][1] for m in "AB")
    assert "best" not in cells["C"]["recall"][1]  # 0.9123 shared by A and B: a tie, named
    assert "best" in cells["C"]["gce"][1] and not cells["C"]["gce"][0].endswith("tie")  # one best
    assert "best" in cells["A"]["seconds"][1]
    assert "tie: A, B</span> 0.9123" in page and "no best: all 3 methods give 0.5000" in page
    # the same in LaTeX: bold only on a best, the tie marked
    by = {r[1]: r for r in tex[1:]}
    col = {c.split(" ")[0].replace("\\_", "_"): i for i, c in enumerate(tex[0])}
    assert by["A"][col["recall"]] == r"\textbf{0.9123}\textsuperscript{tie}"
    assert not any(by[m][col["accuracy"]].startswith(r"\textbf") for m in "ABC")
    assert not any(by[m][col["peak_memory_mb"]].startswith(r"\textbf") for m in "ABC")
    # a memory difference of 1 MB or more is a best
    for r in rows:
        r["peak_memory_mb"] = {"A": 10.0, "B": 12.5, "C": 11.2}[r["method_label"]]
    res = write_report(_write_rows(tmp_path / "run", rows), renders=0)
    cells, _, _ = _mean_table(res)
    assert [m for m in "ABC" if "best" in cells[m]["peak_memory_mb"][1]] == ["A"]


def test_ranks_rules():
    def cells(values, column="recall"):
        return {("d", m, "none"): {column: (v, 0.0, 1)} for m, v in values.items()}

    assert _ranks(cells({"a": 0.3, "b": 0.3}), "recall") == {}  # constant
    # no best memory below 1 MB, even 1.2 MB apart (allocator noise), one from 1 MB on
    assert _ranks(cells({"a": 0.03, "b": 1.28}, "peak_memory_mb"), "peak_memory_mb") == {}
    assert _ranks(cells({"a": 1.5, "b": 3.0}, "peak_memory_mb"), "peak_memory_mb") == {("d", "a", "none"): "best"}
    assert _ranks(cells({"a": 0.30001, "b": 0.30004}), "recall") == {}  # the same as printed: 0.3000
    assert _ranks(cells({"a": 0.3, "b": 0.3, "c": 0.1}), "recall") == {("d", "a", "none"): "tie",
                                                                       ("d", "b", "none"): "tie"}
    assert _ranks(cells({"a": 0.3}), "recall") == {}  # nothing to compare
    assert _ranks(cells({"a": 0.3, "b": 0.2}), "n_segments") == {}  # no better direction
    mem = cells({"a": 100.0, "b": 100.004}, "peak_memory_mb")
    assert _ranks(mem, "peak_memory_mb") == {}
    mem = cells({"a": 100.0, "b": 100.5, "c": 102.0}, "peak_memory_mb")
    assert _ranks(mem, "peak_memory_mb") == {("d", "a", "none"): "tie", ("d", "b", "none"): "tie"}


# -- n/a: a metric a method cannot produce -----------------------------------------------------
def test_a_metric_a_method_cannot_produce_is_na_with_a_note_never_0_or_best(tmp_path):
    rows = []
    for item in ("i1", "i2"):
        rows.append(_row(f"z{item}", "zoomout", item, {"mean_geodesic_error": 0.05, "matched_fraction": 1.0},
                         task="mixed", kind="matching", family="pipelines"))
        rows.append(_row(f"e{item}", "eig", item, {"mean_geodesic_error": 0.2 if item == "i1" else None,
                                                   "matched_fraction": 0.9}, task="mixed", kind="matching",
                         family="dense_matchers"))
        # what the sparse matchers' rows hold when no matched keypoint is a ground-truth point
        for m in ("spectral", "rrwm"):
            sparse = _row(f"{m}{item}", m, item, {"mean_geodesic_error": None, "matched_fraction": 0.0},
                          task="mixed", kind="matching", family="sparse_matchers", memory=1.0, seconds=0.1)
            rows.append(sparse)
            rows.append(dict(sparse, key=f"only-{m}{item}", task_name="sparse"))
    res = write_report(_write_rows(tmp_path / "run", rows), renders=0)
    cells, page, tex = _mean_table(res)
    for m in ("spectral", "rrwm"):
        for c in ("matched_fraction", "mean_geodesic_error"):
            assert cells[m][c] == ("n/a", "na"), (m, c)  # not 0, not best
    assert "best" in cells["zoomout"]["matched_fraction"][1]  # 1.0 against 0.9; the sparse 0s are not in it
    assert "best" in cells["zoomout"]["mean_geodesic_error"][1]
    assert cells["eig"]["mean_geodesic_error"][0] == "0.2000"  # one item of two: the mean of the other
    notes = re.findall(r"<p class='note'>(.*?)</p>", page)
    assert any(n.startswith("matched_fraction: n/a for rrwm, spectral because a sparse matcher matches only its "
                            "keypoints") for n in notes), notes
    assert any(n.startswith("mean_geodesic_error: n/a for rrwm, spectral because no matched keypoint is among "
                            "the ground-truth points evaluated") for n in notes), notes
    assert any(n.startswith("mean_geodesic_error: no value for eig (1 of 2 rows)") for n in notes), notes
    # CSV and LaTeX say n/a too
    mixed_csv = {r["method"]: r for r in csv.DictReader(next(t for t in res["tables"]
                                                                if t.name == "00-mixed.csv").open())}
    assert mixed_csv["spectral"]["matched_fraction"] == "n/a" and mixed_csv["spectral"]["matched_fraction_n"] == "0"
    assert "n/a" in next(r for r in tex if r[1] == "rrwm")
    # a task where no method has a value of a requested column: listed under the table, not dropped silently
    sparse_cells, _, sparse_tex = _mean_table(res, 1)
    assert set(sparse_cells["rrwm"]) == {"seconds", "peak_memory_mb"}
    assert ("mean_geodesic_error: not computed for rrwm, spectral because no matched keypoint is among the "
            "ground-truth points evaluated") in page
    sparse_tex_text = next(t for t in res["tables"] if t.name == "02-sparse.tex").read_text()
    assert r"mean\_geodesic\_error: not computed for rrwm, spectral" in sparse_tex_text
    assert r"matched\_fraction: not computed for rrwm, spectral" in sparse_tex_text
    # the summary never names a method for a metric it has no value of, and says which have none
    assert "matched_fraction</b> (higher is better): <span class='best'>zoomout</span>" in page
    assert "<li><b>mean_geodesic_error</b>: n/a for rrwm, spectral (no value;" in page


def test_latex_escape():
    assert latex_escape(r"a&b%c$d#e_f{g}h~i^j\k") == (r"a\&b\%c\$d\#e\_f\{g\}h\textasciitilde{}i"
                                                     r"\textasciicircum{}j\textbackslash{}k")
    assert latex_escape("x\ny\x07") == "x y?"
    assert latex_escape("<b>|") == r"\textless{}b\textgreater{}\textbar{}"


def test_user_strings_are_escaped_in_the_latex_tables(tmp_path):
    label = r"$\frac{a$ & 50% #1_x {y} ~z ^w \end{tabular}"
    rows = [_row(f"k{m}{i}", m, f"i{i}", {"recall": 0.1 * (k + 1)}) for k, m in enumerate([label, "plain"])
            for i in range(2)]
    res = write_report(_write_rows(tmp_path / "run", rows), renders=0)
    for t in res["tables"]:
        if t.suffix == ".tex":
            text = t.read_text()
            assert latex_escape(label) in text
            assert text.count(r"\end{tabular}") == 1 and text.count(r"\begin{tabular}") == 1
    got = {r["method"] for r in csv.DictReader(next(t for t in res["tables"] if t.suffix == ".csv").open())}
    assert got == {label, "plain"}  # CSV: the strings as they are


def test_a_second_report_replaces_its_own_tables_and_keeps_a_users(tmp_path):
    rows = [_row(f"k{m}", m, "i", {"recall": v}) for m, v in (("A", 0.1), ("B", 0.2))]
    run = _write_rows(tmp_path / "run", rows)
    first = write_report(run, renders=0)
    tables = first["html"].parent / "tables"
    mine = tables / first["tables"][0].name
    mine.write_text("my edits")  # changed by hand: no longer the report's
    second = write_report(run, renders=0)
    assert mine.read_text() == "my edits" and mine not in second["tables"]
    assert {p.name for p in tables.iterdir()} == {mine.name} | {t.name for t in second["tables"]}


def test_the_latex_tables_compile(report, tmp_path):
    """Every .tex table, including one of labels made of LaTeX's special characters, through pdflatex
    with booktabs (skipped where no pdflatex is installed: apt-get install texlive-latex-recommended)."""
    import shutil
    import subprocess

    exe = shutil.which("pdflatex")
    if exe is None:
        pytest.skip("no pdflatex (apt-get install texlive-latex-base texlive-latex-recommended)")
    labels = [r"$\frac{a$", r"\begin{x}", "$x^2$ and $", "_hidden", "a\x00b\x07", "50% & #1 ~z ^w {y} <b>|",
              r"\end{tabular}"]
    rows = [_row(f"k{i}{item}", lab, item, {"gce": 0.1 * (i % 3), f"recall{lab}": 0.5 + 0.1 * i, "x": None},
                 task=f"t{lab}", memory=10.0 + i) for i, lab in enumerate(labels) for item in ("i1", "i2")]
    rows.append(dict(rows[0], key="failed", status="failed", error=r"ValueError: bad \x & 100% {", metrics={}))
    nasty = write_report(_write_rows(tmp_path / "run", rows), renders=0)
    inputs = [t for t in report["tables"] + nasty["tables"] if t.suffix == ".tex"]
    doc = tmp_path / "doc.tex"
    doc.write_text("\\documentclass{article}\\usepackage[T1]{fontenc}\\usepackage{booktabs}"
                   "\\usepackage[paperwidth=100cm,paperheight=40cm,margin=1cm]{geometry}\\begin{document}\n"
                   + "\n".join(f"\\input{{{t.as_posix()}}}\\clearpage" for t in inputs) + "\n\\end{document}\n")
    r = subprocess.run([exe, "-interaction=nonstopmode", "-halt-on-error", doc.name], cwd=tmp_path,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout[-2000:]
    assert (tmp_path / "doc.pdf").stat().st_size > 1000


def test_sparse_seeds_are_pooled_over_items_and_datasets(tmp_path):
    """Issue 28: a sparse matcher's precision pooled over every seed of every pair (correct / seeds), beside
    the per-item means, from the rows' own seed counts."""
    datasets = [{"name": f"s{seed}", "kind": "synthetic", "items": ["pose1"],
                 "params": {"n_poses": 2, "subdivisions": 2, "random_state": seed}} for seed in (0, 1)]
    cfg = {"run": {"name": "pooled", "random_state": 0}, "datasets": datasets,
           "tasks": [{"task": "matching", "name": "seeds", "metrics": ["geodesic_error"],
                      "options": {"geodesic_method": "dijkstra", "truth_sample": 100000},
                      "methods": [{"plugin": "replicator", "keypoints": {"plugin": "adf-maxima"}}]}]}
    run = run_config(cfg, tmp_path / "run")
    rows = [json.loads(line) for line in (run / "results.jsonl").read_text().splitlines()]
    assert len(rows) == 2 and all(r["status"] == "ok" for r in rows)
    n = [r["metrics"]["n_scored"] for r in rows]
    assert all(isinstance(v, int) and v > 0 for v in n), n
    within = [r["metrics"]["within_0.05"] for r in rows]
    res = write_report(run, renders=0)
    pooled = next(t for t in res["tables"] if t.name.endswith("-seeds-pooled.csv"))
    (row,) = list(csv.DictReader(pooled.open(encoding="utf-8")))
    assert row["dataset"] == "all 2" and row["method"] == "replicator" and int(float(row["n_scored"])) == sum(n)
    want = sum(w * c for w, c in zip(within, n)) / sum(n)  # correct seeds / seeds, not the mean of the pairs
    assert float(row["within_0.05"]) == pytest.approx(want, abs=1e-4)
    assert "Pooled: each metric is the mean over all scored points" in res["html"].read_text(encoding="utf-8")

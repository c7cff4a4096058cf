"""Every example config validates as shipped, runs on a small subset, and its report has CSV and
LaTeX tables.

The shipped file is loaded exactly (plugins, metrics, corruptions and dataset paths relative to
$TOOLKIT_DATA are all checked), then run on one item (``--limit 1``) with every method of every task, peers,
published and reference rows included, at most two corruption instances (the first of each grid) and spectra
capped at 20 eigenpairs, to keep the suite short (about 2.5 minutes for the 12 configs).
Examples reading the shared data are skipped when it is absent.
"""

from __future__ import annotations

import copy
import csv
import math
import re
import sys
from pathlib import Path

import numpy as np
import pytest

from shape_toolkit.bench.config import load_config, parse_config
from shape_toolkit.bench.report import method_id, write_report
from shape_toolkit.bench.runner import read_rows, run_benchmark
from shape_toolkit.bench.store import safe_name

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
#: one config per example folder, and examples/thesis/: one config per thesis table or figure
CONFIGS = sorted(EXAMPLES.glob("*/config.toml")) + sorted((EXAMPLES / "thesis").glob("*.toml"))


def _needs_data(raw: dict) -> bool:
    return any(d.get("kind") != "synthetic" for d in raw["datasets"])


def _small(raw: dict) -> dict:
    raw = copy.deepcopy(raw)
    for d in raw["datasets"]:
        d["limit"] = 1
        if d.get("kind") == "synthetic":
            d.setdefault("params", {})["n_poses"] = 2
    for t in raw["tasks"]:
        if "corruptions" in t:
            t["corruptions"] = t["corruptions"][:2]
        for spec in [t.get("spectrum")] + [m.get("spectrum") for m in t["methods"]]:
            if spec and "k" in spec:
                spec["k"] = min(spec["k"], 20)
        opts = t.get("options", {})
        if "truth_sample" in opts:
            opts["truth_sample"] = min(opts["truth_sample"], 100)
    for c in raw.get("corruptions", []):
        for k, v in c.get("params", {}).items():
            if isinstance(v, list):
                c["params"][k] = v[:1]
    return raw


def test_every_example_has_a_config_and_a_command():
    assert len(CONFIGS) >= 12
    for c in CONFIGS:
        readme = (c.parent / "README.md" if c.parent.name == "thesis" else EXAMPLES / "README.md").read_text()
        assert c.relative_to(EXAMPLES.parent).as_posix() in readme
        assert "shape-toolkit bench run" in c.read_text()  # the one command, in the file header
    assert "thesis/README.md" in (EXAMPLES / "README.md").read_text()


@pytest.mark.slow
@pytest.mark.parametrize("config", CONFIGS, ids=[c.relative_to(EXAMPLES).with_suffix("").as_posix() for c in CONFIGS])
def test_example_runs_on_a_subset(config, tmp_path, request, monkeypatch):
    raw = tomllib.loads(config.read_text())
    if _needs_data(raw):
        data = request.getfixturevalue("shared_data")  # skips when absent
        monkeypatch.setenv("TOOLKIT_DATA", str(data))
    full = load_config(config)  # the shipped config validates as is
    assert full.tasks
    cfg = parse_config(_small(raw), base=config.parent, source=str(config))
    summary = run_benchmark(cfg, tmp_path / "run", progress=False)
    rows = read_rows(tmp_path / "run")
    assert summary.rows == len(rows) > 0
    errors = [r["error"] for r in rows if r["status"] != "ok"]
    assert not errors, errors
    for r in rows:
        assert r["metrics"], r
        if r["family"] == "references":  # the ground truth: no method ran, no cost
            assert r["cpu_seconds"] is None, r
            continue
        assert r["cpu_seconds"] is not None and r["cpu_seconds"] >= 0, r  # CPU time of the method's call
    # its report has every table as CSV and LaTeX (booktabs), linked from the page (issue 28)
    res = write_report(tmp_path / "run", renders=0)
    page = res["html"].read_text(encoding="utf-8")
    names = {p.name for p in res["tables"]}
    for task in dict.fromkeys(r["task_name"] for r in rows):
        for suffix in (r"\.csv", r"\.tex", r"-items(?:-.+)?\.csv", r"-items(?:-.+)?\.tex"):  # per category
            hit = [n for n in names if re.fullmatch(rf"\d\d-{re.escape(safe_name(task))}{suffix}", n)]
            assert hit, (task, suffix, sorted(names))
            assert f"href='tables/{hit[0]}'" in page
    for t in res["tables"]:
        text = t.read_text(encoding="utf-8")
        if t.suffix == ".tex":
            assert text.index(r"\toprule") < text.index(r"\midrule") < text.index(r"\bottomrule")
        else:
            head = next(csv.reader(text.splitlines()))
            assert head[:2] == ["dataset", "method"] or head[:2] == ["dataset", "item"]
    for t in res["tables"]:  # a sparse matcher's matched_fraction is never a score (n/a)
        if t.suffix == ".csv" and "matched_fraction" in t.read_text():
            for r in csv.DictReader(t.open(encoding="utf-8")):
                if any(x["family"] == "sparse_matchers" and method_id(x) == r["method"] for x in rows):
                    assert r["matched_fraction"] in ("n/a", ""), r


def test_r_smoothness_equals_eq_7_4_by_hand():
    """Table 7.2's column against a direct implementation of eq. 7.4-7.5 (every vertex, SciPy
    Dijkstra along the edges, neighbourhoods = the ceil(r% n) closest vertices, ties by id): a
    permuted map, an identity (100 %) and a map with unmatched vertices (not smooth)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    from shape_toolkit.data.generate import icosphere
    from shape_toolkit.metrics import r_smoothness_table

    s = icosphere(2)  # 162 vertices
    n = s.n_vertices
    f = np.asarray(s.faces)
    e = np.unique(np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1), axis=0)
    w = np.linalg.norm(np.asarray(s.vertices)[e[:, 0]] - np.asarray(s.vertices)[e[:, 1]], axis=1)
    d = dijkstra(coo_matrix((np.r_[w, w], (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n, n)).tocsr())
    order = np.lexsort((np.broadcast_to(np.arange(n), d.shape), d), axis=1)  # closest first, ties by id

    def by_hand(t, r, theta=0.9):
        c = math.ceil(r / 100 * n)
        smooth = 0
        for i in range(n):
            if t[i] < 0:
                continue
            img = [t[j] for j in order[i, :c] if t[j] >= 0]
            ball = set(order[t[i], :c].tolist())
            smooth += bool(img) and sum(x in ball for x in img) / len(img) >= theta - 1e-12
        return 100.0 * smooth / n

    rng = np.random.default_rng(3)
    noisy = np.arange(n)
    hit = rng.choice(n, n // 6, replace=False)
    noisy[hit] = rng.integers(0, n, hit.size)
    noisy[hit[:5]] = -1
    rs = (2.0, 5.0, 10.0)
    assert r_smoothness_table(s, s, np.arange(n), rs, sample=None) == {r: 100.0 for r in rs}
    got = r_smoothness_table(s, s, noisy, rs, sample=None)
    want = {r: by_hand(noisy, r) for r in rs}
    assert got == pytest.approx(want, abs=1e-9)
    assert all(0 < v < 100 for v in got.values())

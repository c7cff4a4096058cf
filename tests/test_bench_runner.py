"""The benchmark runner: rows, resume without duplicates, failed rows, Dask == local, reports."""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

import numpy as np
import pytest
from helpers import registered

from shape_toolkit.api.interfaces import Segmenter
from shape_toolkit.bench import read_rows, run_benchmark
from shape_toolkit.bench.config import load_config
from shape_toolkit.bench.store import BenchWarning
from shape_toolkit.cli import main
from shape_toolkit.results.segmentation import Segmentation

CONFIG = """
[run]
name = "unit"
[[datasets]]
name = "synth"
kind = "synthetic"
params = { n_poses = 3, subdivisions = 2 }
[[corruptions]]
name = "noise"
kind = "gaussian-noise"
params = { strength = [0.2] }
[[tasks]]
task = "spectrum"
corruptions = ["none", "noise"]
spectrum = { k = 6 }
metrics = ["eigenvalues", "lambda2"]
[[tasks.methods]]
plugin = "gaussian"
[[tasks.methods]]
plugin = "cotangent"
[[tasks]]
task = "segmentation"
name = "seg"
metrics = ["n_segments", "segmentation"]
[[tasks.methods]]
plugin = "spectral-clustering"
preset = "luxburg-unnormalized"
params = { n_segments = [3, 6] }
"""
N_ROWS = 3 * 2 * 2 + 3 * 2


@pytest.fixture
def config_path(tmp_path):
    p = tmp_path / "bench.toml"
    p.write_text(textwrap.dedent(CONFIG))
    return p


def _check_row(r):
    for key in (
        "item",
        "task_name",
        "task_kind",
        "plugin",
        "method_label",
        "spectra",
        "params",
        "status",
        "error",
        "seconds",
        "peak_memory_mb",
        "metrics",
        "versions",
        "random_state",
        "key",
    ):
        assert key in r, key


def test_run_rows_and_resume_without_duplicates(config_path, tmp_path):
    cfg = load_config(config_path)
    run = tmp_path / "run"
    s1 = run_benchmark(cfg, run, limit=1, progress=False)
    assert (s1.rows, s1.reused, s1.failed) == (N_ROWS // 3, 0, 0)
    rows = read_rows(run)
    for r in rows:
        _check_row(r)
        assert r["status"] == "ok" and r["error"] is None
    assert "task" not in rows[0] and "method" not in rows[0]  # one meaning per field name
    seg = [r for r in rows if r["task_name"] == "seg"]
    assert {r["task_kind"] for r in seg} == {"segmentation"}
    assert {r["plugin"] for r in seg} == {"spectral-clustering"}
    assert {r["method_label"] for r in seg} == {"spectral-clustering:luxburg-unnormalized"}
    assert {r["metrics"]["n_segments"] for r in seg} == {3, 6}
    assert all(0 <= r["metrics"]["rand_index_error"] <= 1 for r in seg)
    spec = [r for r in rows if r["task_name"] == "spectrum"]
    assert all(r["metrics"]["eigenvalues"][0][1] < 1e-8 < r["metrics"]["lambda2"] for r in spec)
    # the spectrum task records its subject: the method's weighting with the task's settings
    assert {(r["plugin"], r["spectra"][0]["weighting"], r["spectra"][0]["k"]) for r in spec} == {
        ("gaussian", "gaussian", 6),
        ("cotangent", "cotangent", 6),
    }
    # the segmentation rows reuse the spectrum computed once by the prepare stage
    assert all(r["spectrum_cache_hit"] for r in seg if r["spectra"])

    # simulate a crash mid-write: a torn last line is dropped and its row redone
    text = (run / "results.jsonl").read_text()
    (run / "results.jsonl").write_text(text + text.splitlines()[-1][:40])
    with pytest.warns(BenchWarning, match="invalid line"):
        s2 = run_benchmark(cfg, run, progress=False)
    assert s2.reused == N_ROWS // 3 and s2.rows == N_ROWS - N_ROWS // 3
    rows = read_rows(run)
    keys = [r["key"] for r in rows]
    assert len(keys) == len(set(keys)) == N_ROWS
    s3 = run_benchmark(cfg, run, progress=False)
    assert (s3.rows, s3.reused) == (0, N_ROWS)
    assert len(read_rows(run)) == N_ROWS


class _Flaky(Segmenter):
    """Fails on pose1, else one segment."""

    def __init__(self, n_segments: int = 2):
        self.n_segments = n_segments

    def segment(self, shape, *, spectrum=None, constraints=None):
        if shape.name == "pose1":
            raise RuntimeError("flaky segmenter refuses pose1")
        return Segmentation(np.zeros(shape.n_vertices, dtype=np.int64))


@pytest.fixture
def flaky():
    with registered("segmenters", "flaky-test", _Flaky):
        yield


def test_failed_rows_are_recorded_and_run_goes_on(config_path, tmp_path, flaky, capsys):
    text = config_path.read_text().replace(
        'plugin = "spectral-clustering"\npreset = "luxburg-unnormalized"\nparams = { n_segments = [3, 6] }',
        'plugin = "flaky-test"',
    )
    config_path.write_text(text)
    run = tmp_path / "run"
    assert main(["bench", "run", str(config_path), "-o", str(run), "--json", "--no-progress"]) == 1
    summary = json.loads(capsys.readouterr().out)
    assert summary["failed"] == 1 and summary["rows"] == 3 * 2 * 2 + 3 and summary["reused"] == 0
    failed = [r for r in read_rows(run) if r["status"] == "failed"]
    assert len(failed) == 1 and failed[0]["item"] == "pose1"
    assert "flaky segmenter refuses pose1" in failed[0]["error"]
    # resume: failed rows count as done unless asked to retry
    assert main(["bench", "run", str(config_path), "-o", str(run), "--json", "--no-progress"]) == 1
    assert json.loads(capsys.readouterr().out)["reused"] == summary["rows"]
    assert (
        main(["bench", "run", str(config_path), "-o", str(run), "--json", "--no-progress", "--retry-failed"])
        == 1
    )
    again = json.loads(capsys.readouterr().out)
    assert again["rows"] == 1 and again["failed"] == 1
    assert len(read_rows(run)) == summary["rows"]

    assert main(["bench", "report", str(run), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    html = (run / "report" / "index.html").read_text()
    assert out["figures"] and "data:image/png;base64," in html
    assert "flaky segmenter refuses pose1" in html
    assert "http://" not in html and "https://" not in html  # self-contained


def test_dask_local_cluster_matches_local_run(config_path, tmp_path):
    pytest.importorskip("distributed")
    cfg = load_config(config_path)
    local = run_benchmark(cfg, tmp_path / "local", limit=1, progress=False)
    dask = run_benchmark(cfg, tmp_path / "dask", limit=1, workers=2, progress=False)
    assert local.rows == dask.rows == N_ROWS // 3 and dask.failed == 0
    a = {r["key"]: r for r in read_rows(tmp_path / "local")}
    b = {r["key"]: r for r in read_rows(tmp_path / "dask")}
    assert a.keys() == b.keys()
    for k in a:
        ma, mb = a[k]["metrics"], b[k]["metrics"]
        assert ma.keys() == mb.keys()
        for m in ma:
            np.testing.assert_allclose(
                np.asarray(ma[m], float), np.asarray(mb[m], float), rtol=1e-6, atol=1e-9
            )
    assert len({r["worker"] for r in b.values()}) >= 1


MATCHING = """
[[datasets]]
name = "synth"
kind = "synthetic"
params = { n_poses = 2, subdivisions = 2 }
[[corruptions]]
kind = "holes"
params = { strength = 2, radius = 0.1 }
[[tasks]]
task = "matching"
corruptions = ["none", "holes"]
metrics = ["geodesic_error", "coverage", "label_transfer"]
options = { geodesic_method = "dijkstra" }
[[tasks.methods]]
plugin = "eigvec-alignment"
[[tasks]]
task = "keypoints"
metrics = ["n_keypoints", "repeatability"]
[[tasks.methods]]
plugin = "adf-maxima"
"""


def test_matching_and_keypoint_rows_with_report(tmp_path):
    p = tmp_path / "m.toml"
    p.write_text(MATCHING)
    cfg = load_config(p)
    run = tmp_path / "run"
    s = run_benchmark(cfg, run, limit=1, progress=False)
    rows = read_rows(run)
    assert s.failed == 0, [r["error"] for r in rows]
    m = [r for r in rows if r["task_name"] == "matching"]
    assert len(m) == 2
    for r in m:
        curve = np.asarray(r["metrics"]["geodesic_error_curve"])
        assert np.all(np.diff(curve[:, 1]) >= 0) and 0 <= curve[-1, 1] <= 1
        assert 0 < r["metrics"]["target_coverage"] <= 1
    k = [r for r in rows if r["task_name"] == "keypoints"]
    assert k[0]["metrics"]["n_keypoints"] > 0 and "repeatability_curve" in k[0]["metrics"]
    res = main(["bench", "report", str(run)])
    assert res == 0
    figs = list((run / "report" / "figures").glob("*.png"))
    assert any("render" in f.name for f in figs) and any("geodesic_error_curve" in f.name for f in figs)


def test_a_full_disk_while_cleaning_the_results_file_is_a_run_folder_error(config_path, tmp_path, monkeypatch):
    """The rewrite of results.jsonl (a torn last line moved aside) goes through atomic_output; a
    write failure there is the typed RunFolderError, and the file and folder are left as they were."""
    import os

    from shape_toolkit.bench.store import RunFolderError

    run = tmp_path / "run"
    run.mkdir()
    row = {"key": "k", "status": "ok", "task_name": "t", "task_kind": "x", "item": "i",
           "method_label": "m", "metrics": {}}
    (run / "results.jsonl").write_text(json.dumps(row) + '\n{"key": "to')
    before = (run / "results.jsonl").read_bytes()
    real_replace = os.replace

    def replace(src, dst):
        if str(dst).endswith("results.jsonl"):
            raise OSError(28, "No space left on device")
        return real_replace(src, dst)

    monkeypatch.setattr(os, "replace", replace)
    with pytest.warns(BenchWarning), pytest.raises(RunFolderError, match="cannot write to run folder.*No space left"):
        run_benchmark(load_config(config_path), run, progress=False)
    assert (run / "results.jsonl").read_bytes() == before
    assert not [p.name for p in run.iterdir() if ".tmp" in p.name]


def test_rows_a_changed_config_left_behind_are_not_reported_or_compared(config_path, tmp_path):
    """Re-running a narrower config into the same folder: the report, the failure count and `bench compare`
    see the rows the last config plans (planned.json), and the report says how many it left out."""
    from shape_toolkit.bench import read_rows
    from shape_toolkit.bench.compare import compare_runs
    from shape_toolkit.bench.report import write_report
    from shape_toolkit.bench.store import planned_keys

    run = tmp_path / "run"
    assert main(["bench", "run", str(config_path), "-o", str(run), "-q"]) == 0
    narrow = tmp_path / "narrow.toml"
    narrow.write_text(textwrap.dedent(CONFIG).split("[[tasks]]\ntask = \"segmentation\"")[0])
    assert main(["bench", "run", str(narrow), "-o", str(run), "-q"]) == 0
    assert len(read_rows(run)) == N_ROWS  # nothing is deleted
    current = read_rows(run, planned_only=True)
    assert len(current) == 3 * 2 * 2 and planned_keys(run) == {r["key"] for r in current}
    assert {r["task_name"] for r in current} == {"spectrum"}
    res = write_report(run, renders=0)
    page = Path(res["html"]).read_text()
    assert "6 rows in this folder come from an earlier config" in page and "Task seg" not in page
    assert {c.task for c in compare_runs(run, run).changes} == {"spectrum"}


#: a run folder written by an earlier version (commit 00bddc7): results.jsonl of tests/data/resume_run/bench.toml
#: (spectrum rows with an eigensolver peer and a corruption, a segmentation row with item parameters, a
#: matching row)
RESUME_RUN = Path(__file__).parent / "data" / "resume_run"
#: what a row measures (timings, memory, versions, scores): the rest of a row is its identity and format
MEASURED = ("seconds", "cpu_seconds", "peak_memory_mb", "metrics", "spectrum_seconds", "spectrum_cache_hit",
            "metric_seconds", "total_seconds", "versions", "worker", "blas_threads")


def test_a_run_folder_of_an_earlier_version_resumes_with_no_recomputation(tmp_path):
    """The row keys and the row format hold across versions: an earlier run folder is resumed with
    every row reused and its results file untouched, and a row written now is byte-identical to the
    stored one but for what it measures."""
    import shutil

    from shape_toolkit.validation import dumps_json

    cfg = load_config(RESUME_RUN / "bench.toml")
    stored = (RESUME_RUN / "results.jsonl").read_bytes()
    run = tmp_path / "old"
    run.mkdir()
    shutil.copyfile(RESUME_RUN / "results.jsonl", run / "results.jsonl")
    s = run_benchmark(cfg, run, progress=False)
    assert (s.rows, s.reused, s.planned, s.failed) == (0, 6, 6, 0)
    assert (run / "results.jsonl").read_bytes() == stored

    new = tmp_path / "new"
    assert run_benchmark(cfg, new, progress=False).failed == 0
    old_lines = {json.loads(line)["key"]: line for line in stored.decode().splitlines()}
    rows = read_rows(new)
    assert sorted(r["key"] for r in rows) == sorted(old_lines)
    for r in rows:
        old = json.loads(old_lines[r["key"]])
        assert list(r) == list(old)
        assert dumps_json({k: old[k] if k in MEASURED else v for k, v in r.items()}) == old_lines[r["key"]]


def test_rerun_computes_a_methods_rows_again_and_keeps_the_former(config_path, tmp_path, capsys):
    """Rows are reused by their config, not by the code: ``--rerun LABEL`` computes that method's rows again (after a
    change of code the config cannot see), the other rows are reused, and the former rows move to
    ``results.jsonl.replaced``; a label the config does not plan is one line and exit 2, and nothing is moved."""
    run = tmp_path / "run"
    base = ["bench", "run", str(config_path), "-o", str(run), "--json", "--no-progress", "--limit", "1"]
    assert main(base) == 0
    first = json.loads(capsys.readouterr().out)
    before = {r["key"]: r for r in read_rows(run)}
    label = "spectral-clustering:luxburg-unnormalized"
    n_label = sum(r["method_label"] == label for r in before.values())
    assert n_label == 2
    assert main(base + ["--rerun", label]) == 0
    again = json.loads(capsys.readouterr().out)
    assert again["rows"] == n_label and again["reused"] == first["rows"] - n_label
    after = {r["key"]: r for r in read_rows(run)}
    assert after.keys() == before.keys() and len(read_rows(run)) == len(before)  # one row per key
    replaced = [json.loads(line) for line in (run / "results.jsonl.replaced").read_text().splitlines()]
    assert sorted(r["key"] for r in replaced) == sorted(k for k, r in before.items() if r["method_label"] == label)
    assert all(after[k] == r for k, r in before.items() if r["method_label"] != label)
    # an unknown label: exit 2, one line naming the labels, no row moved
    assert main(base + ["--rerun", "no-such-method"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no-such-method" in err and label in err
    assert len(read_rows(run)) == len(before)
    assert len((run / "results.jsonl.replaced").read_text().splitlines()) == n_label

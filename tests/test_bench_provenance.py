"""Which code produced a result (``bench.worker.code_revision``) and the headers of the benchmark
reports that record it: git state in throw-away repositories, old records still readable, and the
run commands surviving a report-only regeneration."""

from __future__ import annotations

import importlib.util
import json
import shutil
import subprocess
from pathlib import Path

import pytest

from shape_toolkit.bench import worker
from shape_toolkit.bench.worker import code_revision, revision_label

REPO = Path(__file__).resolve().parent.parent

needs_git = pytest.mark.skipif(shutil.which("git") is None, reason="git is not installed")


def _git(cwd: Path, *args: str) -> str:
    return subprocess.run(["git", *args], cwd=cwd, check=True, capture_output=True, text=True).stdout


@pytest.fixture
def repo(tmp_path, monkeypatch):
    """A fresh repository with one committed file (git never looks above ``tmp_path``)."""
    monkeypatch.setenv("GIT_CEILING_DIRECTORIES", str(tmp_path))
    root = tmp_path / "repo"
    (root / "pkg").mkdir(parents=True)
    (root / "pkg" / "a.py").write_text("x = 1\n")
    (root / "notes.txt").write_text("n\n")
    _git(root, "init", "-q")
    _git(root, "add", ".")
    _git(root, "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "first")
    return root


@needs_git
def test_clean_then_dirty(repo):
    head = _git(repo, "rev-parse", "HEAD").strip()
    rev = code_revision(repo)
    assert rev == {"commit": head[:12], "dirty": False, "dirty_files": []}
    assert code_revision(repo / "pkg")["commit"] == head[:12]  # any directory inside the tree
    (repo / "untracked.py").write_text("y = 2\n")
    assert code_revision(repo)["dirty"] is False  # untracked files do not count
    (repo / "pkg" / "a.py").write_text("x = 2\n")
    rev = code_revision(repo / "pkg")
    assert rev["dirty"] is True and rev["dirty_files"] == ["pkg/a.py"]  # top-level relative paths
    assert code_revision(repo, paths=["notes.txt"])["dirty"] is False  # only the paths asked about
    assert code_revision(repo / "pkg", paths=["pkg"])["dirty_files"] == ["pkg/a.py"]
    _git(repo, "add", "pkg/a.py")  # staged edits are still not the commit
    assert code_revision(repo)["dirty"] is True
    assert revision_label(code_revision(repo)) == f"{head[:12]} + uncommitted edits in pkg/a.py"


def test_not_a_repository_is_unknown(tmp_path, monkeypatch):
    monkeypatch.setenv("GIT_CEILING_DIRECTORIES", str(tmp_path))
    plain = tmp_path / "plain"
    plain.mkdir()
    assert code_revision(plain) == {"commit": "unknown", "dirty": False, "dirty_files": []}
    assert code_revision(tmp_path / "missing")["commit"] == "unknown"


def test_git_missing_or_hanging_is_unknown(tmp_path, monkeypatch):
    monkeypatch.setenv("PATH", str(tmp_path))  # no git on PATH
    assert code_revision(tmp_path)["commit"] == "unknown"
    monkeypatch.undo()

    def hang(*args, **kwargs):
        assert kwargs.get("timeout"), "every git call has a timeout"
        raise subprocess.TimeoutExpired(args[0], kwargs["timeout"])

    monkeypatch.setattr(worker.subprocess, "run", hang)
    assert code_revision(REPO)["commit"] == "unknown"


def test_exported_tree(tmp_path):
    (tmp_path / "EXPORTED_COMMIT").write_text("0123456789abcdef\n")
    rev = code_revision(tmp_path)
    assert rev["commit"] == "0123456789ab" and rev["dirty"] is False and rev["exported_to"] == str(tmp_path)


def test_revision_label_reads_old_records():
    assert revision_label({"commit": "cd60e47", "dirty": []}) == "cd60e47"  # trajectory_drift.json
    old_example = {"commit": "c1", "dirty": ["shape_toolkit/x.py"]}  # the TOSCA example's revisions.jsonl
    assert revision_label(old_example) == "c1 + uncommitted edits in shape_toolkit/x.py"
    assert revision_label({"commit": "c1", "dirty": True, "dirty_files": []}) == "c1 + uncommitted edits"
    assert revision_label(None) == revision_label({}) == "not recorded"


def _load_script(name: str, path: Path):
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_tosca_example_reads_old_and_new_revision_records(tmp_path):
    """examples/tosca_matching/results.py: a run log and revision log written before code_revision
    (``dirty`` a list of files) and after it (``dirty`` a bool, ``dirty_files``) both render."""
    res = _load_script("tosca_results", REPO / "examples" / "tosca_matching" / "results.py")
    curve = [[0.0, 0.0], [0.1, 1.0]]
    metrics = {f"r_smooth@{r:g}": 10.0 for r in res.RS}
    metrics.update(label_recall=0.5, label_precision=0.5, mean_geodesic_error=0.1, geodesic_error_curve=curve)
    run = tmp_path / "run"
    run.mkdir()
    rows = [{"key": f"k{i}", "status": "ok", "task_name": "dense", "task_kind": "matching", "item": f"cat0-cat{i}",
             "method_label": "pipeline:zoomout", "metrics": metrics, "seconds": 2.0, "cpu_seconds": 1.0}
            for i in (1, 4)]
    (run / "results.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    old = {"commit": "ef8533952115", "dirty": ["shape_toolkit/a.py"]}
    new = {"commit": "a1e638a00000", "dirty": True, "dirty_files": ["shape_toolkit/b.py"]}
    (run / "revisions.jsonl").write_text(json.dumps({"key": "k1", **old}) + "\n" + json.dumps({"key": "k4", **new}))
    log = {"methods": ["zoomout"], "new_rows": 1, "started": "s", "ended": "e", "wall_seconds": 1.0}
    (run / "runlog.jsonl").write_text(json.dumps({**log, **old}) + "\n" + json.dumps({**log, **new}) + "\n")
    summ = res.write_results([run], tmp_path / "out")
    assert summ["zoomout"]["commits"] == ["a1e638a00000+dirty", "ef8533952115+dirty"]
    md = (tmp_path / "out" / "results.md").read_text()
    assert "code ef8533952115 + uncommitted edits in shape_toolkit/a.py." in md
    assert "code a1e638a00000 + uncommitted edits in shape_toolkit/b.py." in md
    rev = res.git_revision()  # this checkout: a real commit, or "unknown" without git
    assert set(rev) >= {"commit", "dirty", "dirty_files"} and isinstance(rev["dirty"], bool)


def test_trajectory_drift_code_line_old_and_new_meta():
    """benchmarks/trajectory_drift.py: the committed JSON (``code.dirty`` a list) regenerates the
    committed report's code line; a new record (``dirty`` bool + ``dirty_files``) renders too."""
    td = _load_script("trajectory_drift", REPO / "benchmarks" / "trajectory_drift.py")
    saved = json.loads((REPO / "benchmarks" / "results" / "trajectory_drift.json").read_text())
    committed = (REPO / "benchmarks" / "results" / "trajectory_drift.md").read_text()
    meta = dict(saved["meta"], findings=td.findings(saved["rows"]))
    code_line = next(line for line in td.report(saved["rows"], meta).splitlines() if line.startswith("Code:"))
    assert code_line in committed.splitlines()
    meta["code"] = {"commit": "0123456789ab", "dirty": True, "dirty_files": ["shape_toolkit/pipeline.py"]}
    assert ("Code: commit 0123456789ab + uncommitted edits in shape_toolkit/pipeline.py (recorded after the last row)."
            in td.report(saved["rows"], meta))
    assert isinstance(td.code_state()["dirty"], bool)


@pytest.fixture(scope="module")
def psb():
    return _load_script("psb_segmentation_h", REPO / "benchmarks" / "psb_segmentation.py")


def _psb_results() -> list[dict]:
    def row(err: float) -> dict:
        return {"rand_index_error": err, "rand_index_error_area": err, "cut_discrepancy": 0.3, "hamming": 0.2,
                "hamming_rm": 0.2, "hamming_rf": 0.2, "gce": 0.1, "lce": 0.1, "recall": 0.6, "precision": 0.6,
                "seconds": 0.5, "k": 4, "peak_mb": 1.0}

    return [{"mesh": mesh, "category": "human", "split": split, "n_vertices": 100, "n_faces": 196, "k": 4,
             "n_truths": 3, "n_must": 8, "n_cannot": 9, "n_must_1ml": 4, "spectrum_seconds": 0.1,
             "rows": {"human": row(0.1), "human-0": row(0.11), "csc-dual-1ml": row(err),
                      "human-loo": row(0.1), "csc-dual-1ml-loo": row(err)}}
            for mesh, split, err in (("1", "held-out", 0.12), ("2", "tuning", 0.08))]


LEGACY_MACHINE = ("AMD EPYC, 2 cores (shared with other jobs; load average {load} at the start), BLAS: openblas 2 "
                  "threads, openblas 2 threads, process CPU time {cpu} s")


def test_psb_header_from_legacy_json_keeps_every_run_once(psb, tmp_path):
    """A JSON written before the run list (``command`` joined with "; then ", ``machine`` with
    "; the update: ", the commit only in the old report): ``--report-only`` lists each run once as
    a bullet, the machine once with its BLAS libraries de-duplicated, keeps the old commit, and a
    second regeneration is identical (the runs are now in the JSON)."""
    out = tmp_path / "psb.md"
    meta = {"seed": 0, "elapsed": 100.0, "names": ["csc-dual-1ml"], "area_weighted": False,
            "command": "python benchmarks/psb_segmentation.py; then python benchmarks/psb_segmentation.py --update "
                       "--methods csc-dual-1ml",
            "machine": LEGACY_MACHINE.format(load=9.2, cpu=2637) + "; the update: "
                       + LEGACY_MACHINE.format(load=2.0, cpu=706)}
    out.with_suffix(".json").write_text(json.dumps({"meta": meta, "tuned": None, "results": _psb_results()}))
    out.write_text("# old\n\nCommit 7853810 (plus the working tree), random_state 0, 2 meshes\n")
    assert psb.main(["--report-only", "--output", str(out)]) == 0
    md = out.read_text()
    head = md[: md.index("Protocol")]
    assert head.count("\n- `python benchmarks/psb_segmentation.py") == 2
    assert ("- `python benchmarks/psb_segmentation.py`: commit not recorded, process CPU time 2637 s, load average "
            "9.2 at the start." in head)
    assert ("- `python benchmarks/psb_segmentation.py --update --methods csc-dual-1ml`: commit 7853810 (plus the "
            "working tree, not recorded), process CPU time 706 s" in head)
    assert head.count("Machine:") == 1 and head.count("openblas") == 1
    assert "; then " not in head and "the update:" not in head
    saved = json.loads(out.with_suffix(".json").read_text())
    assert [r["command"] for r in saved["meta"]["runs"]] == meta["command"].split("; then ")
    assert psb.main(["--report-only", "--output", str(out)]) == 0
    assert out.read_text() == md  # the old report's commit is now in the JSON
    # human-0 and the -loo rows are saved in ``names``: a regeneration must not list them twice
    assert md.count("\n| human-0 |") == md.count("\n| csc-dual-1ml |") > 0
    assert md.count("\n| csc-dual-1ml-loo |") == md.count("\n| human-loo |") > 0
    assert json.loads(out.with_suffix(".json").read_text())["meta"]["names"].count("human-0") == 1


def test_psb_header_lists_new_runs(psb, tmp_path):
    """Runs recorded by this version: one bullet each with its commit, CPU and wall time; the
    machine once when it is the same, in each bullet when it differs; nothing grows in one line."""
    mach = {"cpu": "AMD EPYC", "cores": 2, "blas": ["openblas 2 threads"]}
    first = psb.run_record("python benchmarks/psb_segmentation.py", {"commit": "0123456789ab", "dirty": False,
                           "dirty_files": []}, 2637.0, 4000.0, 9.2, mach)
    runs = [first]
    for i in range(3):  # three updates, each appended the way main() does
        runs = runs + [psb.run_record(f"python benchmarks/psb_segmentation.py --update --methods m{i}",
                                      {"commit": "abcdef012345", "dirty": True, "dirty_files": ["shape_toolkit/x.py"]},
                                      500.0 + i, 900.0, 2.0, mach)]
    lines = psb.header_lines(runs)
    bullets = [line for line in lines if line.startswith("- ")]
    assert len(bullets) == 4 and max(map(len, lines)) < 250
    assert bullets[0] == ("- `python benchmarks/psb_segmentation.py`: commit 0123456789ab, process CPU time 2637 s, "
                          "wall 4000 s, load average 9.2 at the start.")
    assert "commit abcdef012345 + uncommitted edits in shape_toolkit/x.py, process CPU time 502 s" in bullets[3]
    assert [line for line in lines if line.startswith("Machine:")] == [
        "Machine: AMD EPYC, 2 cores, BLAS: openblas 2 threads; the cores were shared with other jobs."]
    runs[-1] = dict(runs[-1], machine={"cpu": "Intel Xeon", "cores": 8, "blas": ["mkl 1 threads"]})
    lines = psb.header_lines(runs)
    assert not any(line.startswith("Machine:") for line in lines)
    bullets = [line for line in lines if line.startswith("- ")]
    assert bullets[-1].endswith("; machine: Intel Xeon, 8 cores, BLAS: mkl 1 threads.")
    assert bullets[0].endswith("; machine: AMD EPYC, 2 cores, BLAS: openblas 2 threads.")
    assert psb.machine()["blas"] == list(dict.fromkeys(psb.machine()["blas"]))  # this process: no repeats
    psb.write_report(_psb_results(), tmp_path / "r.md", 0, 10.0, None, ["csc-dual-1ml"], runs=runs)
    assert (tmp_path / "r.md").read_text().count("\n- `python benchmarks/psb_segmentation.py") == 4

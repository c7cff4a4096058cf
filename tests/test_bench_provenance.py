"""Which code produced a result (``bench.worker.code_revision``) and the headers of the benchmark
reports that record it: git state in throw-away repositories, old records still readable, and the
run commands surviving a report-only regeneration."""

from __future__ import annotations

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
    assert revision_label({"commit": "cd60e47", "dirty": []}) == "cd60e47"  # the former trajectory_drift.json
    old_example = {"commit": "c1", "dirty": ["shape_toolkit/x.py"]}  # the TOSCA example's revisions.jsonl
    assert revision_label(old_example) == "c1 + uncommitted edits in shape_toolkit/x.py"
    assert revision_label({"commit": "c1", "dirty": True, "dirty_files": []}) == "c1 + uncommitted edits"
    assert revision_label(None) == revision_label({}) == "not recorded"
